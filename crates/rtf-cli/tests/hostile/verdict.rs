//! A case of the catalogue, how it runs and how its outcome is judged.

use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};

use crate::common::text;

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Verdict {
    Clear,
    Panic,
    Silent,
    Unclear,
}

type Check = Box<dyn Fn() -> bool>;
type Runner = Box<dyn Fn() -> Output>;

pub struct Case {
    pub name: String,
    pub args: Vec<String>,
    /// Strings the output must contain (the path at fault, the tensor, ...).
    pub must_name: Vec<String>,
    /// Address-space limit (bytes) for the run, as `ulimit -v`.
    pub limit_as: Option<u64>,
    /// A side-effect check: false = the refusal still did damage, or the recovery's result is
    /// wrong (silent wrong).
    pub intact: Option<Check>,
    /// Work done just before the command (copying a run folder, editing a file): cases run in
    /// order, so it sees what the cases before it left.
    pub before: Option<Box<dyn Fn()>>,
    /// Runs instead of `rtf ARGS` (torchrun, a signal sent mid-run).
    pub runner: Option<Runner>,
    /// None: a refusal (exit 1 or 2) is expected. Some(code): this exit code is the right
    /// outcome (0: a recovery or a warning; 130: an interrupted run), with `must_name` in the
    /// output and `intact` holding.
    pub expect: Option<i32>,
    /// A second exit code that is as right an outcome as `expect` (with the same
    /// `must_name` and `intact`): where what the command decides may honestly go either way.
    pub or_exit: Option<i32>,
}

/// A refusal: exit 1 or 2 with every string of `must_name` in the output.
pub fn case(name: &str, args: &[&str], must_name: &[&str]) -> Case {
    Case {
        name: name.into(),
        args: args.iter().map(|s| s.to_string()).collect(),
        must_name: must_name.iter().map(|s| s.to_string()).collect(),
        limit_as: None,
        intact: None,
        before: None,
        runner: None,
        expect: None,
        or_exit: None,
    }
}

/// A run that must succeed (exit 0), name `must_name` and pass `check`.
pub fn recovers(name: &str, args: &[&str], must_name: &[&str], check: Check) -> Case {
    let mut c = case(name, args, must_name);
    c.expect = Some(0);
    c.intact = Some(check);
    c
}

impl Case {
    pub fn before(mut self, f: impl Fn() + 'static) -> Case {
        self.before = Some(Box::new(f));
        self
    }

    pub fn runner(mut self, f: impl Fn() -> Output + 'static) -> Case {
        self.runner = Some(Box::new(f));
        self
    }

    /// `code` is as right an outcome as the expected one (see [`Case::or_exit`]).
    pub fn or_exit(mut self, code: i32) -> Case {
        self.or_exit = Some(code);
        self
    }

    pub fn intact(mut self, f: impl Fn() -> bool + 'static) -> Case {
        self.intact = Some(Box::new(f));
        self
    }

    pub fn run(&self) -> Output {
        if let Some(before) = &self.before {
            before();
        }
        match &self.runner {
            Some(runner) => runner(),
            None => run_limited(&self.args, self.limit_as),
        }
    }

    pub fn judge(&self, out: &Output) -> Verdict {
        let code = out.status.code();
        let expect = match self.or_exit {
            Some(other) if code == Some(other) => Some(other),
            _ => self.expect,
        };
        let verdict = classify(out, &self.must_name, expect);
        let intact = || self.intact.as_ref().is_none_or(|check| check());
        match (verdict, expect) {
            (Verdict::Panic, _) => Verdict::Panic,
            // A refusal that did damage.
            (_, None) if !intact() => Verdict::Silent,
            // The expected outcome (a recovery, an interruption) with a wrong result.
            (_, Some(want)) if code == Some(want) && !intact() => Verdict::Silent,
            (v, _) => v,
        }
    }
}

pub fn run_limited(args: &[String], limit_as: Option<u64>) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_rtf"));
    cmd.args(args);
    if let Some(limit) = limit_as {
        // SAFETY: setrlimit is async-signal-safe; it runs in the child before exec.
        unsafe {
            cmd.pre_exec(move || {
                let rl = libc::rlimit {
                    rlim_cur: limit as libc::rlim_t,
                    rlim_max: limit as libc::rlim_t,
                };
                if libc::setrlimit(libc::RLIMIT_AS, &rl) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    }
    cmd.output().expect("rtf runs")
}

/// The verdict from the exit code and the output alone.
pub fn classify(out: &Output, must_name: &[String], expect: Option<i32>) -> Verdict {
    // `rtf data check` lists its problems on stdout, other commands report on stderr.
    let all = text(out);
    let named = must_name.iter().all(|n| all.contains(n.as_str())) && !all.contains("panicked");
    match (out.status.code(), expect) {
        (None | Some(101), _) => Verdict::Panic,
        (Some(0), None) => Verdict::Silent,
        (Some(1 | 2), None) if named => Verdict::Clear,
        (Some(code), Some(want)) if code == want && named => Verdict::Clear,
        // Exit 0 without what it must say (a warning, the run it resumed).
        (Some(0), Some(0)) => Verdict::Silent,
        _ => Verdict::Unclear,
    }
}

/// Waits for `child` at most `limit`; kills it (its process group) past that. The output of
/// a killed child says so (exit by signal: judged a hang, not a clear outcome).
pub fn wait_at_most(mut child: Child, limit: Duration) -> Output {
    let started = Instant::now();
    while child.try_wait().expect("child state").is_none() {
        if started.elapsed() > limit {
            eprintln!("hostile: still running after {limit:?}: killing it");
            // SAFETY: signals a process this test started.
            unsafe { libc::kill(child.id() as i32, libc::SIGKILL) };
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child.wait_with_output().expect("child output")
}

/// Polls `ready` every 20 ms for at most `secs` seconds.
pub fn wait_for(secs: u64, ready: impl Fn() -> bool) -> bool {
    let started = Instant::now();
    while !ready() {
        if started.elapsed().as_secs() >= secs {
            return false;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    true
}

/// Lines of a text file (0 when it does not exist).
pub fn lines(path: &Path) -> usize {
    std::fs::read_to_string(path).map_or(0, |t| t.lines().count())
}

pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.path().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), target).unwrap();
        }
    }
}

/// Starts `rtf ARGS` (output captured).
pub fn spawn(args: &[String]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_rtf"))
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("rtf starts")
}

/// Runs `rtf ARGS`, sends `signal` once `ready` holds (within 120 s), and returns its output
/// (waiting at most 120 s more).
pub fn signal_when(args: &[String], ready: impl Fn() -> bool, signal: i32) -> Output {
    let child = spawn(args);
    let pid = child.id() as i32;
    let started = Instant::now();
    let mut child = child;
    while !ready() && started.elapsed().as_secs() < 120 {
        if child.try_wait().expect("child state").is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    // SAFETY: signals a process this test started (a no-op if it has ended).
    unsafe { libc::kill(pid, signal) };
    wait_at_most(child, Duration::from_secs(120))
}

/// `rtf train --resume RUN --epochs N`, N one more than `log` holds now.
pub fn resume_one_more(run: &Path, log: &Path) -> Output {
    let epochs = (lines(log) + 1).to_string();
    let args = [
        "train",
        "--resume",
        run.to_str().unwrap(),
        "--epochs",
        &epochs,
    ];
    run_limited(&args.map(String::from), None)
}

/// The epochs of a log.jsonl are 0, 1, … n-1 (the log counts from 0) without gaps or
/// repeats: Some(n).
pub fn epochs_in_order(log: &Path) -> Option<usize> {
    let records = rtf_run::log::read(log).ok()?;
    let mut n = 0;
    for record in records {
        if record.epoch != n {
            return None;
        }
        n += 1;
    }
    Some(n)
}

pub fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|s| s.to_string()).collect()
}

/// `rtf train` of 300 one-step epochs without validation (a run to interrupt), then `extra`.
pub fn long_train(data: &Path, run: &Path, extra: &[&str]) -> Vec<String> {
    let mut args = strings(&[
        "train",
        "--data",
        data.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--epochs",
        "300",
        "--batch-size",
        "2",
        "--max-steps",
        "1",
        "--val-split",
        "none",
        "--tb-images-every",
        "0",
    ]);
    args.extend(strings(extra));
    args
}

/// `rtf ARGS` stopped by SIGTERM once `log` has a line: exit 130 naming `must`.
pub fn interrupted(name: &str, args: Vec<String>, log: std::path::PathBuf, must: &[&str]) -> Case {
    let mut c = case(name, &[], must)
        .runner(move || signal_when(&args, || lines(&log) >= 1, libc::SIGTERM));
    c.expect = Some(130);
    c
}
