//! `rtf report` on run folders in every state: in progress, log.jsonl truncated, corrupt,
//! empty or missing, config.json of another version, hundreds of epochs, an output that
//! collides with the run's own files.

use std::path::{Path, PathBuf};

use crate::common::*;
use crate::verdict::*;
use crate::Fixture;

/// A finished three-epoch run without validation (made once, copied per case).
fn three_epochs(f: &Fixture) -> PathBuf {
    let run = f.t.join("report_base");
    let args = [
        "train",
        "--data",
        s(&f.data),
        "--out",
        s(&run),
        "--epochs",
        "3",
        "--batch-size",
        "2",
        "--max-steps",
        "1",
        "--val-split",
        "none",
        "--tb-images-every",
        "0",
    ];
    ok(&args);
    run
}

/// A copy of `base` at `t/name` changed by `mutate`.
fn variant(f: &Fixture, base: &Path, name: &str, mutate: &dyn Fn(&Path)) -> PathBuf {
    let run = f.t.join(name);
    copy_dir(base, &run);
    mutate(&run);
    run
}

fn report(name: &str, run: &Path, out: &Path, must: &[&str]) -> Case {
    let written = out.to_path_buf();
    case(
        &format!("report: {name}"),
        &["report", s(run), "--out", s(out), "--frames", "0"],
        must,
    )
    .intact(move || !written.exists())
}

/// The report is written and it is an HTML page below `max` bytes naming `names`.
fn page(out: &Path, max: u64, names: &[&str]) -> Box<dyn Fn() -> bool> {
    let (out, names) = (out.to_path_buf(), strings(names));
    Box::new(move || {
        let Ok(text) = std::fs::read_to_string(&out) else {
            return false;
        };
        text.len() as u64 <= max
            && text.contains("</html>")
            && names.iter().all(|n| text.contains(n.as_str()))
    })
}

fn edit_log(run: &Path, edit: impl Fn(String) -> String) {
    let log = run.join("log.jsonl");
    std::fs::write(&log, edit(std::fs::read_to_string(&log).unwrap())).unwrap();
}

/// log.jsonl with `n` epochs: the first record repeated, numbered from 0, its training loss
/// 1 / (epoch + 1) (the last one 1/n).
fn many_epochs(run: &Path, n: usize) {
    edit_log(run, |text| {
        let first: serde_json::Value = serde_json::from_str(text.lines().next().unwrap()).unwrap();
        (0..n)
            .map(|e| {
                let mut r = first.clone();
                r["epoch"] = e.into();
                r["train_loss"] = (1.0 / (e + 1) as f64).into();
                format!("{r}\n")
            })
            .collect()
    });
}

fn broken_logs(f: &Fixture, base: &Path) -> Vec<Case> {
    let out = |n: &str| f.t.join(format!("report_{n}.html"));
    let truncated = variant(f, base, "rp_truncated", &|r| {
        edit_log(r, |t| t[..t.len() - 20].to_string())
    });
    let corrupt = variant(f, base, "rp_corrupt", &|r| {
        edit_log(r, |t| t.replacen('\n', "\n\u{0}\u{1}garbage{\n", 1))
    });
    let no_epoch = variant(f, base, "rp_noepoch", &|r| {
        edit_log(r, |t| t.replace("\"epoch\"", "\"epoch_index\""))
    });
    let missing = variant(f, base, "rp_nolog", &|r| {
        std::fs::remove_file(r.join("log.jsonl")).unwrap()
    });
    let bad_config = variant(f, base, "rp_badconfig", &|r| {
        std::fs::write(r.join("config.json"), b"{\"model\": [").unwrap()
    });
    let no_config = variant(f, base, "rp_noconfig", &|r| {
        std::fs::remove_file(r.join("config.json")).unwrap()
    });
    vec![
        report(
            "log.jsonl cut mid-line",
            &truncated,
            &out("a"),
            &["log.jsonl:3"],
        ),
        report(
            "log.jsonl with a garbage line",
            &corrupt,
            &out("b"),
            &["log.jsonl:2"],
        ),
        report(
            "log records without `epoch` (another schema)",
            &no_epoch,
            &out("c"),
            &["log.jsonl:1", "epoch"],
        ),
        report("log.jsonl missing", &missing, &out("d"), &["log.jsonl"]),
        report(
            "config.json not JSON",
            &bad_config,
            &out("e"),
            &["config.json"],
        ),
        report(
            "config.json missing",
            &no_config,
            &out("f"),
            &["config.json"],
        ),
        report("not a run folder", &f.data, &out("g"), &["log.jsonl"]),
    ]
}

fn odd_runs(f: &Fixture, base: &Path) -> Vec<Case> {
    let out = |n: &str| f.t.join(format!("report_{n}.html"));
    let empty = variant(f, base, "rp_empty", &|r| {
        std::fs::write(r.join("log.jsonl"), b"").unwrap()
    });
    let future = variant(f, base, "rp_future", &|r| {
        let mut config = json_file(&r.join("config.json"));
        config["schema"] = "rtf-run/99".into();
        config["rtf_version"] = "99.0.0".into();
        config["a_field_from_the_future"] = serde_json::json!({"x": 1});
        std::fs::write(r.join("config.json"), config.to_string()).unwrap();
    });
    let long = variant(f, base, "rp_long", &|r| many_epochs(r, 600));
    let nulls = variant(f, base, "rp_nulls", &|r| {
        edit_log(r, |t| {
            t.replacen("\"train_loss\":", "\"train_loss\":null,\"was\":", 1)
        })
    });
    vec![
        recovers(
            "report: a run with no epoch yet (empty log.jsonl)",
            &["report", s(&empty), "--out", s(&out("h")), "--frames", "0"],
            &["report:"],
            page(&out("h"), 5 << 20, &[]),
        ),
        recovers(
            "report: config.json of another version",
            &["report", s(&future), "--out", s(&out("i")), "--frames", "0"],
            &["report:"],
            page(&out("i"), 5 << 20, &["rtf-run/99"]),
        ),
        recovers(
            "report: 600 epochs",
            &["report", s(&long), "--out", s(&out("j")), "--frames", "0"],
            &["report:"],
            page(&out("j"), 3 << 20, &["0.0017"]),
        ),
        recovers(
            "report: a null loss in the log",
            &["report", s(&nulls), "--out", s(&out("k")), "--frames", "0"],
            &["report:"],
            page(&out("k"), 5 << 20, &[]),
        ),
    ]
}

/// The page written over the run's own files, or into a folder.
fn collisions(f: &Fixture, base: &Path) -> Vec<Case> {
    let run = variant(f, base, "rp_collide", &|_| {});
    let log = run.join("log.jsonl");
    let before = std::fs::read(&log).unwrap();
    let kept = log.clone();
    vec![
        case(
            "report: --out is the run's log.jsonl",
            &["report", s(&run), "--out", s(&log), "--frames", "0"],
            &["log.jsonl"],
        )
        .intact(move || std::fs::read(&kept).unwrap() == before),
        case(
            "report: --out is a folder",
            &["report", s(&run), "--out", s(&f.t), "--frames", "0"],
            &[s(&f.t)],
        ),
    ]
}

/// A run in progress: the report is written while `rtf train` runs, and says so.
fn in_progress(f: &Fixture) -> Case {
    let run = f.t.join("rp_live");
    let out = f.t.join("report_live.html");
    let train = long_train(&f.data, &run, &[]);
    let (log, o, r) = (run.join("log.jsonl"), out.clone(), run.clone());
    recovers(
        "report: a run in progress",
        &[],
        &["report:"],
        page(&out, 5 << 20, &[]),
    )
    .runner(move || {
        let child = spawn(&train);
        wait_for(120, || lines(&log) >= 2);
        let output = run_limited(
            &strings(&["report", s(&r), "--out", s(&o), "--frames", "0"]),
            None,
        );
        // SAFETY: signals the training this case started.
        unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
        wait_at_most(child, std::time::Duration::from_secs(60));
        output
    })
}

pub fn cases(f: &Fixture) -> Vec<Case> {
    let base = three_epochs(f);
    let mut cases = broken_logs(f, &base);
    cases.extend(odd_runs(f, &base));
    cases.extend(collisions(f, &base));
    cases.push(in_progress(f));
    cases
}
