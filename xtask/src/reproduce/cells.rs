//! One cell = one trained network and its evaluation, in an ordinary `rtf train` run folder
//! `<out>/<table>/<cell>/seed<k>/` that also holds `cell.json` (what the cell runs) and
//! `eval.json` (`rtf eval --json`). What is on disk decides what is left to do, so a re-run
//! skips finished cells and resumes interrupted ones (`rtf train --resume`).

use super::budget::{Budget, RECIPE_CPU_MODEL};
use super::io::write_json;
use super::tables::{Cell, Data, Table, Train};
use anyhow::{bail, Context as _, Result};
use rtf_run::Weights;
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

pub const CELL_FILE: &str = "cell.json";
pub const EVAL_FILE: &str = "eval.json";
/// A cross-dataset cell's evaluation on its training dataset's test split (no class map):
/// whether its network learned is judged on it, as for every other cell.
pub const OWN_EVAL_FILE: &str = "eval-own.json";
pub const BENCH_FILE: &str = "bench.json";
const LOG_FILE: &str = "xtask.log";

/// What a cell folder holds, hence what is left to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// `eval.json` is there (and `bench.json` where the table times the network).
    Done,
    /// Training finished (`final.safetensors`); evaluate (and time).
    Evaluate,
    /// An interrupted run (a checkpoint, or only the config of a run killed before its first
    /// checkpoint, which `rtf train` refuses to start over without `--resume`):
    /// `rtf train --resume`, which continues it or starts it again from its saved config.
    Resume,
    /// Nothing usable: train from the start.
    Fresh,
}

pub fn state(dir: &Path, bench: bool) -> State {
    let evaluated = std::fs::read(dir.join(EVAL_FILE))
        .ok()
        .and_then(|b| serde_json::from_slice::<Value>(&b).ok())
        .is_some();
    let timed = !bench
        || dir
            .parent()
            .is_some_and(|cell| cell.join(BENCH_FILE).exists());
    if evaluated && timed {
        State::Done
    } else if Weights::of(dir).last.is_some() {
        State::Evaluate
    } else if rtf_run::holds_run(dir) {
        // The files by which `rtf train` says a folder "already holds a run" (a pipeline
        // keeps its checkpoints in its stage folders and only config.json at the top).
        State::Resume
    } else {
        State::Fresh
    }
}

/// Everything a run needs to know beyond the table.
pub struct Context {
    pub root: PathBuf,
    pub rtf: PathBuf,
    pub out: PathBuf,
    pub budget: Budget,
    pub device: String,
    pub backbone_weights: Option<PathBuf>,
    /// `--mit-weights`: a folder of SegFormer's ImageNet MiT weights, `mit_bX.safetensors`.
    pub mit_weights: Option<PathBuf>,
    /// Dataset roots (given or synthesised) and whether they are real.
    pub data: BTreeMap<Data, (PathBuf, bool)>,
    /// `rtf recipes --json` entries by name (empty when rtf has no recipes yet).
    pub recipes: BTreeMap<String, Value>,
}

impl Context {
    pub fn cell_dir(&self, table: &Table, cell: &Cell, seed: usize) -> PathBuf {
        self.out
            .join(table.id)
            .join(&cell.id)
            .join(format!("seed{seed}"))
    }

    fn root_of(&self, data: Data) -> Result<&(PathBuf, bool)> {
        self.data
            .get(&data)
            .with_context(|| format!("no {} root (give {})", data.name(), data.flag()))
    }

    /// The network `rtf eval` builds for a cell.
    pub fn network(&self, cell: &Cell) -> Result<String> {
        match &cell.train {
            // The table's network, or the budget's stand-in for it (CMX on a CPU budget).
            Train::Model(m) => Ok(self.budget.network(m).to_string()),
            // CPU budgets put one light network in every role of a recipe.
            Train::Recipe(_) if self.budget != Budget::Paper => Ok(RECIPE_CPU_MODEL.to_string()),
            Train::Recipe(r) => self
                .recipes
                .get(*r)
                .and_then(|e| e.get("model").and_then(Value::as_str))
                .map(String::from)
                .with_context(|| format!("`rtf recipes --json` gives no `model` for `{r}`")),
        }
    }

    /// What the cell runs, as written to `cell.json`: a changed recipe makes the folder
    /// someone else's (checked before anything runs).
    pub fn spec(&self, table: &Table, cell: &Cell, seed: usize) -> Result<Value> {
        let (train_root, train_real) = self.root_of(cell.data)?;
        let (eval_root, _) = self.root_of(cell.eval_on)?;
        let mut train: Vec<String> = match &cell.train {
            Train::Model(m) => {
                let m = self.budget.network(m);
                let mut v = vec!["--model".to_string(), m.to_string()];
                v.extend(self.budget.train_args(table.recipe, m, *train_real));
                if cell.data == Data::Freiburg {
                    // Freiburg's only labelled held-out part is its test layout: no
                    // validation on it (the protocol never picks a checkpoint on test).
                    v.extend(["--val-split".into(), "none".into()]);
                }
                if let (Some(w), true) = (&self.backbone_weights, m.contains("rtfnet")) {
                    v.extend(["--backbone-weights".into(), w.display().to_string()]);
                }
                if let Some(w) = self.mit_weights.as_deref().and_then(|d| mit_file(d, m)) {
                    v.extend(["--backbone-weights".into(), w.display().to_string()]);
                }
                v
            }
            Train::Recipe(r) => {
                let mut v = vec!["--recipe".to_string(), r.to_string()];
                v.extend(self.budget.recipe_args());
                v
            }
        };
        let eval = self.eval_flags(cell, cell.eval_on, *train_real);
        train.extend(["--seed".into(), seed.to_string()]);
        train.extend(["--device".into(), self.device.clone()]);
        let mut spec = json!({
            "table": table.id,
            "cell": cell.id,
            "seed": seed,
            "budget": self.budget.name(),
            "train_data": train_root,
            "eval_data": eval_root,
            "rtf_train": train,
            "rtf_eval": eval,
        });
        if cell.class_map.is_some() {
            spec["rtf_eval_own"] = json!(self.eval_flags(cell, cell.data, *train_real));
        }
        Ok(spec)
    }

    /// `rtf eval` flags of the cell's network on `target`'s test split: the budget's, the
    /// recipe's inputs and the CPU budgets' frame size, and the class map where `target` is
    /// not the training dataset.
    fn eval_flags(&self, cell: &Cell, target: Data, train_real: bool) -> Vec<String> {
        let mut eval = self.budget.eval_args(train_real);
        if let Train::Recipe(r) = &cell.train {
            // The recipe's last stage sees these channels; the CPU budgets' frame size.
            let inputs = self
                .recipes
                .get(*r)
                .and_then(|e| e.get("inputs").and_then(Value::as_str))
                .unwrap_or("rgb_t");
            eval.extend(["--inputs".to_string(), inputs.to_string()]);
        }
        let other = target != cell.data;
        let resized = eval.iter().any(|a| a == "--resize");
        // Recipes on the CPU budgets, and any network on the other dataset (Freiburg's test
        // preprocessing would give 320×704): that dataset's synthetic frame size.
        if self.budget != Budget::Paper
            && !resized
            && (other || matches!(cell.train, Train::Recipe(_)))
        {
            eval.extend([
                "--resize".to_string(),
                self.budget.synth(target).1.to_string(),
            ]);
        }
        if let (true, Some(map)) = (other, cell.class_map) {
            eval.extend(["--class-map".to_string(), map.to_string()]);
        }
        eval
    }
}

/// The ImageNet MiT weights in `dir` for a CMX `network` (`cmx-mit-bX` → `mit_bX.safetensors`,
/// the name SegFormer publishes them under); None for other networks.
pub fn mit_file(dir: &Path, network: &str) -> Option<PathBuf> {
    let size = network.strip_prefix("cmx-mit-")?;
    Some(dir.join(format!("mit_{size}.safetensors")))
}

/// Fails when `dir` holds a cell made with another recipe (another budget or dataset).
pub fn check_spec(dir: &Path, spec: &Value) -> Result<()> {
    let path = dir.join(CELL_FILE);
    let Ok(bytes) = std::fs::read(&path) else {
        return Ok(());
    };
    let old: Value = serde_json::from_slice(&bytes)
        .with_context(|| format!("{}: not valid JSON", path.display()))?;
    let keys = ["budget", "train_data", "eval_data", "rtf_train", "rtf_eval"];
    for k in keys {
        if old.get(k) != spec.get(k) {
            bail!(
                "{} was made with another recipe ({k}: {} here, {} now); use another --out or \
                 remove that folder",
                path.display(),
                old.get(k).unwrap_or(&Value::Null),
                spec.get(k).unwrap_or(&Value::Null)
            );
        }
    }
    Ok(())
}

/// How a cell run ended.
#[derive(Debug, PartialEq, Eq)]
pub enum Outcome {
    Ran,
    /// Copied from an identical finished cell of another table.
    Reused(PathBuf),
    /// `rtf train` stopped on Ctrl-C (exit 130) after writing a checkpoint.
    Interrupted,
}

/// Runs what is left of one cell.
pub fn run(ctx: &Context, table: &Table, cell: &Cell, seed: usize) -> Result<Outcome> {
    let dir = ctx.cell_dir(table, cell, seed);
    let outcome = run_cell(ctx, table, cell, seed, &dir);
    if outcome.is_err() && ctx.budget == Budget::Smoke && dir.is_dir() {
        // A failed smoke cell must not keep its gigabytes either: a full disk would otherwise
        // fail every cell after it. Its config.json and logs stay, so it still resumes.
        if let Err(e) = remove_weights(&dir) {
            eprintln!("    (could not remove the failed cell's weights: {e:#})");
        }
    }
    outcome
}

fn run_cell(ctx: &Context, table: &Table, cell: &Cell, seed: usize, dir: &Path) -> Result<Outcome> {
    let spec = ctx.spec(table, cell, seed)?;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    write_json(&dir.join(CELL_FILE), &spec)?;
    let mut st = state(dir, cell.bench);
    if st == State::Fresh {
        if let Some(other) = find_identical(ctx, dir, &spec) {
            return reuse(ctx, cell, dir, &spec, other);
        }
    }
    let network = ctx.network(cell)?;
    if matches!(st, State::Fresh | State::Resume) {
        if let Outcome::Interrupted = train(ctx, dir, &spec, st == State::Resume)? {
            return Ok(Outcome::Interrupted);
        }
        st = State::Evaluate;
    }
    if st == State::Evaluate {
        evaluate(ctx, dir, &spec, &network)?;
        if cell.bench {
            bench(ctx, cell, dir)?;
        }
    }
    if ctx.budget == Budget::Smoke {
        // Smoke checks the pipeline, not the weights: a finished cell keeps its logs and
        // scores but not its weights and checkpoints (RTFNet-152's alone take gigabytes).
        remove_weights(dir)?;
    }
    Ok(Outcome::Ran)
}

/// Takes the scores of `other`, a finished cell with the same training and evaluation, instead
/// of training again (recorded as `reused_from` in the cell's spec).
fn reuse(ctx: &Context, cell: &Cell, dir: &Path, spec: &Value, other: PathBuf) -> Result<Outcome> {
    if other.join(OWN_EVAL_FILE).is_file() {
        std::fs::copy(other.join(OWN_EVAL_FILE), dir.join(OWN_EVAL_FILE))
            .with_context(|| format!("copying {}", other.join(OWN_EVAL_FILE).display()))?;
    }
    std::fs::copy(other.join(EVAL_FILE), dir.join(EVAL_FILE))
        .with_context(|| format!("copying {}", other.join(EVAL_FILE).display()))?;
    let mut spec = spec.clone();
    spec["reused_from"] = json!(other);
    write_json(&dir.join(CELL_FILE), &spec)?;
    if cell.bench {
        bench(ctx, cell, dir)?;
    }
    Ok(Outcome::Reused(other))
}

/// `rtf train` into the cell's folder (`--resume` it when `resume`): `Outcome::Interrupted`
/// when the user stopped it, `Outcome::Ran` when it finished.
fn train(ctx: &Context, dir: &Path, spec: &Value, resume: bool) -> Result<Outcome> {
    let args = if resume {
        vec!["train".into(), "--resume".into(), dir.display().to_string()]
    } else {
        train_command(dir, spec)?
    };
    match rtf(ctx, dir, &args)? {
        Ended::Exit(0) => Ok(Outcome::Ran),
        Ended::Exit(130) | Ended::Signal(SIGINT) => Ok(Outcome::Interrupted),
        ended => bail!(
            "`rtf {}` failed ({ended}); its output: {}{}",
            args.join(" "),
            dir.join(LOG_FILE).display(),
            log_tail(dir)
        ),
    }
}

/// `rtf eval` of the cell's weights on the test split into `eval.json` (a cross-dataset cell:
/// first on its own dataset's into `eval-own.json`; `eval.json` comes last, as it marks the
/// cell done). The protocol: the checkpoint picked on validation where a validation split was
/// used (MF), else the final weights.
fn evaluate(ctx: &Context, dir: &Path, spec: &Value, network: &str) -> Result<()> {
    let weights = Weights::of(dir)
        .selected()
        .map_or_else(|| dir.join(rtf_run::FINAL_FILE), Path::to_path_buf);
    for run in eval_runs(spec) {
        let args = eval_command(ctx, dir, spec, network, &weights, run)?;
        let ended = rtf(ctx, dir, &args)?;
        if ended != Ended::Exit(0) {
            bail!(
                "`rtf {}` failed ({ended}); its output: {}{}",
                args.join(" "),
                dir.join(LOG_FILE).display(),
                log_tail(dir)
            );
        }
    }
    Ok(())
}

/// A cell's evaluations in the order they run, as (data key, flags key, file) of its spec:
/// a cross-dataset cell's on its own dataset first, then the table's into `eval.json`.
pub fn eval_runs(spec: &Value) -> Vec<(&'static str, &'static str, &'static str)> {
    let mut runs = Vec::new();
    if spec.get("rtf_eval_own").is_some() {
        runs.push(("train_data", "rtf_eval_own", OWN_EVAL_FILE));
    }
    runs.push(("eval_data", "rtf_eval", EVAL_FILE));
    runs
}

/// The `rtf` arguments of a fresh training of the cell in `dir`.
pub fn train_command(dir: &Path, spec: &Value) -> Result<Vec<String>> {
    let train_root = spec["train_data"].as_str().context("train_data")?;
    let mut args: Vec<String> = vec!["train".into(), "--data".into(), train_root.into()];
    args.extend(["--out".into(), dir.display().to_string()]);
    args.extend(strings(&spec["rtf_train"]));
    Ok(args)
}

/// The `rtf` arguments of the cell's evaluation of `weights` on the test split of the spec's
/// `data` root with its `flags`, into `file` (`("eval_data", "rtf_eval", EVAL_FILE)`: the
/// table's evaluation).
pub fn eval_command(
    ctx: &Context,
    dir: &Path,
    spec: &Value,
    network: &str,
    weights: &Path,
    (data, flags, file): (&str, &str, &str),
) -> Result<Vec<String>> {
    let mut args: Vec<String> = [
        "eval",
        "--model",
        network,
        "--weights",
        &weights.display().to_string(),
        "--data",
        spec[data].as_str().context("eval data")?,
        "--split",
        "test",
        "--json",
        &dir.join(file).display().to_string(),
        "--device",
        &ctx.device,
    ]
    .map(String::from)
    .to_vec();
    args.extend(strings(&spec[flags]));
    Ok(args)
}

/// Removes every `.safetensors` file under `dir` (stage folders included).
fn remove_weights(dir: &Path) -> Result<()> {
    for entry in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let path = entry?.path();
        if path.is_dir() {
            remove_weights(&path)?;
        } else if path.extension().is_some_and(|e| e == "safetensors") {
            std::fs::remove_file(&path).with_context(|| format!("removing {}", path.display()))?;
        }
    }
    Ok(())
}

/// Times the cell's network once per cell (`<cell>/bench.json`, not per seed).
fn bench(ctx: &Context, cell: &Cell, dir: &Path) -> Result<()> {
    let cell_dir = dir.parent().context("cell folder")?;
    let path = cell_dir.join(BENCH_FILE);
    if path.exists() {
        return Ok(());
    }
    let network = ctx.network(cell)?;
    let mut args: Vec<String> = [
        "bench",
        "model",
        "--model",
        &network,
        "--device",
        &ctx.device,
        "--json",
    ]
    .map(String::from)
    .to_vec();
    args.extend(ctx.budget.bench_args());
    let out = rtf_command(ctx)
        .args(&args)
        .stderr(Stdio::inherit())
        .output()
        .context("starting rtf bench")?;
    if !out.status.success() {
        bail!("`rtf {}` failed", args.join(" "));
    }
    let v: Value = serde_json::from_slice(&out.stdout).context("parsing `rtf bench --json`")?;
    let mut v = v;
    v["command"] = json!(format!("rtf {}", args.join(" ")));
    write_json(&path, &v)
}

/// A finished cell elsewhere under `--out` with the same training and evaluation.
fn find_identical(ctx: &Context, dir: &Path, spec: &Value) -> Option<PathBuf> {
    let seed = dir.file_name()?;
    for table in std::fs::read_dir(&ctx.out).ok()?.flatten() {
        // Result files (`<table>.md`, …) sit beside the table folders.
        let Ok(cells) = std::fs::read_dir(table.path()) else {
            continue;
        };
        for cell in cells.flatten() {
            let other = cell.path().join(seed);
            if other == dir || state(&other, false) != State::Done {
                continue;
            }
            let Ok(bytes) = std::fs::read(other.join(CELL_FILE)) else {
                continue;
            };
            let Ok(o) = serde_json::from_slice::<Value>(&bytes) else {
                continue;
            };
            let same = ["budget", "train_data", "eval_data", "rtf_train", "rtf_eval"]
                .iter()
                .all(|k| o.get(k) == spec.get(k));
            if same && o.get("reused_from").is_none() {
                return Some(other);
            }
        }
    }
    None
}

fn strings(v: &Value) -> Vec<String> {
    v.as_array()
        .map(|a| {
            a.iter()
                .filter_map(|s| s.as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default()
}

/// Runs `rtf ARGS`, output appended to the cell's log; returns the exit code.
/// How an `rtf` process ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ended {
    Exit(i32),
    /// Killed by a signal: the kernel's out-of-memory killer sends SIGKILL.
    Signal(i32),
}

const SIGINT: i32 = 2;
const SIGKILL: i32 = 9;

impl std::fmt::Display for Ended {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Ended::Exit(code) => write!(f, "exit {code}"),
            Ended::Signal(SIGKILL) => {
                write!(f, "killed by signal 9, as the out-of-memory killer does")
            }
            Ended::Signal(sig) => write!(f, "killed by signal {sig}"),
        }
    }
}

/// The last lines of a cell's `xtask.log`, so that a failure says why where it is printed
/// (a CI log, say) without the folder at hand.
fn log_tail(dir: &Path) -> String {
    const LINES: usize = 6;
    let Ok(text) = std::fs::read_to_string(dir.join(LOG_FILE)) else {
        return String::new();
    };
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    let tail = &lines[lines.len().saturating_sub(LINES)..];
    tail.iter().map(|l| format!("\n      | {l}")).collect()
}

fn rtf(ctx: &Context, dir: &Path, args: &[String]) -> Result<Ended> {
    use std::io::Write;
    let log_path = dir.join(LOG_FILE);
    let mut log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .with_context(|| format!("opening {}", log_path.display()))?;
    writeln!(log, "$ rtf {}", args.join(" "))?;
    let err = log.try_clone()?;
    let status = rtf_command(ctx)
        .args(args)
        .stdout(log.try_clone()?)
        .stderr(err)
        .status()
        .with_context(|| format!("cannot start {}", ctx.rtf.display()))?;
    use std::os::unix::process::ExitStatusExt;
    Ok(match (status.code(), status.signal()) {
        (Some(code), _) => Ended::Exit(code),
        (None, Some(sig)) => Ended::Signal(sig),
        (None, None) => Ended::Exit(-1),
    })
}

/// `rtf` in the project root. OpenMP threads wait passively unless the caller chose
/// otherwise: libgomp's default spinning made training ~10× slower on this shared 2-core
/// machine (MFNet 0.4 vs 5–7 images/s at 128×96, measured under a load of 8–10).
fn rtf_command(ctx: &Context) -> Command {
    let mut c = Command::new(&ctx.rtf);
    c.current_dir(&ctx.root);
    if std::env::var_os("OMP_WAIT_POLICY").is_none() {
        c.env("OMP_WAIT_POLICY", "PASSIVE");
    }
    c
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    #[test]
    fn state_follows_the_files_of_the_run_folder() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("cell/seed0");
        assert_eq!(state(&dir, false), State::Fresh);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join(CELL_FILE), "{}").unwrap();
        assert_eq!(
            state(&dir, false),
            State::Fresh,
            "the cell spec alone is no run"
        );
        // Killed before its first checkpoint: `rtf train` would refuse a fresh start there.
        std::fs::write(dir.join("config.json"), "{}").unwrap();
        assert_eq!(state(&dir, false), State::Resume);
        std::fs::write(dir.join("checkpoint.safetensors"), "x").unwrap();
        assert_eq!(state(&dir, false), State::Resume);
        std::fs::write(dir.join("final.safetensors"), "x").unwrap();
        assert_eq!(state(&dir, false), State::Evaluate);
        std::fs::write(dir.join(EVAL_FILE), "{\"miou\": 0.").unwrap();
        assert_eq!(state(&dir, false), State::Evaluate, "a torn eval.json");
        std::fs::write(dir.join(EVAL_FILE), "{\"miou\": 0.5}").unwrap();
        assert_eq!(state(&dir, false), State::Done);
        assert_eq!(state(&dir, true), State::Evaluate, "timing missing");
        std::fs::write(dir.parent().unwrap().join(BENCH_FILE), "{}").unwrap();
        assert_eq!(state(&dir, true), State::Done);
    }

    /// A stand-in `rtf` (shell script) that records its calls and writes the files the real
    /// one writes; `interrupt` / `fail` / `oom` files next to it make `train` stop on Ctrl-C /
    /// fail / be killed.
    const FAKE_RTF: &str = r#"#!/bin/sh
here=$(dirname "$0")
echo "$*" >> "$here/calls.txt"
arg() { key=$1; shift; while [ $# -gt 0 ]; do [ "$1" = "$key" ] && { echo "$2"; return; }; shift; done; }
case "$1" in
  train)
    if [ "$2" = "--resume" ]; then out=$3; else out=$(arg --out "$@")
      [ -f "$out/config.json" ] && { echo "$out: already holds a run" >&2; exit 1; }; fi
    mkdir -p "$out"; echo '{}' > "$out/config.json"
    [ -f "$here/fail" ] && { echo x > "$out/checkpoint.safetensors"; echo "$out: No space left on device" >&2; exit 3; }
    [ -f "$here/oom" ] && kill -9 $$
    if [ -f "$here/interrupt" ]; then echo x > "$out/checkpoint.safetensors"; exit 130; fi
    echo x > "$out/checkpoint.safetensors"; echo x > "$out/final.safetensors"
    echo '{"epoch":0,"lr":0.01,"train_loss":1.0,"images":8,"seconds":0.8,"images_per_s":10.0,"data_wait_fraction":0.0,"val_miou":null,"val_macc":null}' > "$out/log.jsonl" ;;
  eval)
    echo '{"miou": 0.5, "macc": 0.6, "miou_mfnet": 0.4, "per_class": [], "day": null, "night": null}' > "$(arg --json "$@")" ;;
  bench)
    echo '{"median_ms": 3.5}' ;;
esac
"#;

    pub(in crate::reproduce) fn fake_context(tmp: &Path) -> Context {
        use std::os::unix::fs::PermissionsExt;
        let bin = tmp.join("bin");
        std::fs::create_dir_all(&bin).unwrap();
        let rtf = bin.join("rtf");
        std::fs::write(&rtf, FAKE_RTF).unwrap();
        std::fs::set_permissions(&rtf, std::fs::Permissions::from_mode(0o755)).unwrap();
        let data = tmp.join("data");
        std::fs::create_dir_all(&data).unwrap();
        Context {
            root: tmp.to_path_buf(),
            rtf,
            out: tmp.join("out"),
            budget: Budget::Smoke,
            device: "cpu".into(),
            backbone_weights: None,
            mit_weights: None,
            data: BTreeMap::from([(Data::Mf, (data, false))]),
            recipes: BTreeMap::new(),
        }
    }

    fn calls(tmp: &Path) -> Vec<String> {
        std::fs::read_to_string(tmp.join("bin/calls.txt"))
            .unwrap_or_default()
            .lines()
            .map(|l| l.split(' ').take(2).collect::<Vec<_>>().join(" "))
            .collect()
    }

    #[test]
    fn cells_train_resume_skip_and_reuse() {
        let tmp = tempfile::tempdir().unwrap();
        let tmp = tmp.path();
        let ctx = fake_context(tmp);
        let tables = crate::reproduce::tables::all(false);
        let tab3 = tables.iter().find(|t| t.id == "mfnet-tab3").unwrap();
        let tab2 = tables.iter().find(|t| t.id == "mfnet-tab2").unwrap();
        let mfnet3 = tab3.cell("mfnet").unwrap();
        let dir = ctx.cell_dir(tab3, mfnet3, 0);

        // Interrupted training leaves a checkpoint; the next run resumes it.
        std::fs::write(tmp.join("bin/interrupt"), "").unwrap();
        assert_eq!(run(&ctx, tab3, mfnet3, 0).unwrap(), Outcome::Interrupted);
        assert_eq!(state(&dir, true), State::Resume);
        std::fs::remove_file(tmp.join("bin/interrupt")).unwrap();
        assert_eq!(run(&ctx, tab3, mfnet3, 0).unwrap(), Outcome::Ran);
        assert_eq!(
            calls(tmp),
            [
                "train --data",
                "train --resume",
                "eval --model",
                "bench model"
            ]
        );
        assert_eq!(state(&dir, true), State::Done);
        let bench: Value =
            serde_json::from_slice(&std::fs::read(dir.parent().unwrap().join(BENCH_FILE)).unwrap())
                .unwrap();
        assert_eq!(bench["median_ms"], 3.5);
        // The eval used the final weights (no best.safetensors) on the test split.
        let log = std::fs::read_to_string(tmp.join("bin/calls.txt")).unwrap();
        assert!(
            log.contains("final.safetensors") && log.contains("--split test"),
            "{log}"
        );

        // The same network with the same recipe in another table: copied, not trained.
        // (Result files of finished tables sit beside the table folders.)
        std::fs::write(ctx.out.join("mfnet-tab3.md"), "x").unwrap();
        let mfnet2 = tab2.cell("mfnet").unwrap();
        let before = calls(tmp).len();
        let reused = run(&ctx, tab2, mfnet2, 0).unwrap();
        assert_eq!(reused, Outcome::Reused(dir.clone()));
        assert_eq!(calls(tmp).len(), before, "nothing ran");
        let dir2 = ctx.cell_dir(tab2, mfnet2, 0);
        assert_eq!(state(&dir2, false), State::Done);

        // A failing cell reports the command, its log and the log's last lines; a smoke
        // cell's weights go (a full disk must not fail the cells after it); the folder stays
        // resumable.
        std::fs::write(tmp.join("bin/fail"), "").unwrap();
        let segnet = tab2.cell("segnet-3c").unwrap();
        let err = run(&ctx, tab2, segnet, 0).unwrap_err().to_string();
        assert!(
            err.contains("rtf train")
                && err.contains("exit 3")
                && err.contains("xtask.log")
                && err.contains("No space left on device"),
            "{err}"
        );
        let seg_dir = ctx.cell_dir(tab2, segnet, 0);
        assert!(!seg_dir.join("checkpoint.safetensors").exists());
        assert_eq!(state(&seg_dir, false), State::Resume);
        // Killed by a signal (the OOM killer's SIGKILL): a failure that says so, not an
        // interruption.
        std::fs::remove_file(tmp.join("bin/fail")).unwrap();
        std::fs::write(tmp.join("bin/oom"), "").unwrap();
        let err = run(&ctx, tab2, segnet, 0).unwrap_err().to_string();
        assert!(err.contains("signal 9"), "{err}");
        // It failed before its first checkpoint, leaving config.json: the re-run resumes it
        // (a fresh `rtf train` would refuse the folder).
        std::fs::remove_file(tmp.join("bin/oom")).unwrap();
        let before = calls(tmp).len();
        assert_eq!(run(&ctx, tab2, segnet, 0).unwrap(), Outcome::Ran);
        assert_eq!(calls(tmp)[before], "train --resume");

        // A finished folder written with another budget is refused.
        let mut quick = ctx;
        quick.budget = Budget::Quick;
        let err = check_spec(&dir, &quick.spec(tab3, mfnet3, 0).unwrap()).unwrap_err();
        assert!(err.to_string().contains("another recipe"), "{err}");
    }

    #[test]
    fn a_folder_made_with_another_recipe_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let spec = json!({"budget": "quick", "train_data": "d", "eval_data": "d",
                          "rtf_train": ["--model", "mfnet"], "rtf_eval": []});
        check_spec(tmp.path(), &spec).unwrap();
        write_json(&tmp.path().join(CELL_FILE), &spec).unwrap();
        check_spec(tmp.path(), &spec).unwrap();
        let mut other = spec.clone();
        other["budget"] = json!("smoke");
        let err = check_spec(tmp.path(), &other).unwrap_err().to_string();
        assert!(
            err.contains("another recipe") && err.contains("budget"),
            "{err}"
        );
        std::fs::write(tmp.path().join(CELL_FILE), "nope").unwrap();
        assert!(check_spec(tmp.path(), &spec).is_err());
    }

    /// HeatNet Tab. I's cross-dataset cells train on one dataset and are scored on the other
    /// through the built-in map, at the evaluated dataset's CPU-budget size.
    #[test]
    fn cross_dataset_cells_evaluate_the_other_dataset_through_the_map() {
        let tmp = tempfile::tempdir().unwrap();
        let mut ctx = fake_context(tmp.path());
        ctx.budget = Budget::Quick;
        let fr = tmp.path().join("fr");
        ctx.data.insert(Data::Freiburg, (fr.clone(), false));
        let tables = crate::reproduce::tables::all(false);
        let tab1 = tables.iter().find(|t| t.id == "heatnet-tab1").unwrap();
        let spec = |id: &str| ctx.spec(tab1, tab1.cell(id).unwrap(), 0).unwrap();
        let to_fr = spec("mf-to-fr-mfnet");
        assert_eq!(to_fr["train_data"], json!(tmp.path().join("data")));
        assert_eq!(to_fr["eval_data"], json!(fr));
        let eval = strings(&to_fr["rtf_eval"]).join(" ");
        assert!(
            eval.ends_with("--resize 192x96 --class-map mf-to-freiburg"),
            "{eval}"
        );
        let back = strings(&spec("fr-to-mf-heatnet")["rtf_eval"]).join(" ");
        assert!(back.contains("--resize 96x64"), "{back}");
        assert!(back.ends_with("--class-map freiburg-to-mf"), "{back}");
        // Whether the network learned is judged on its own dataset, without the map.
        assert_eq!(strings(&to_fr["rtf_eval_own"]).join(" "), "--batch-size 4");
        let own_back = strings(&spec("fr-to-mf-heatnet")["rtf_eval_own"]).join(" ");
        assert!(own_back.ends_with("--resize 192x96"), "{own_back}");
        let runs: Vec<_> = eval_runs(&to_fr).into_iter().map(|r| r.2).collect();
        assert_eq!(runs, [OWN_EVAL_FILE, EVAL_FILE]);
        // The Freiburg rows keep their evaluation as before.
        let own = spec("heatnet");
        let flags = strings(&own["rtf_eval"]).join(" ");
        assert!(flags.ends_with("--resize 192x96"), "{flags}");
        assert!(own.get("rtf_eval_own").is_none());
        assert_eq!(eval_runs(&own).len(), 1);
    }
}
