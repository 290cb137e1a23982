//! The hostile-input catalogue (project issues 15 and 30): bad inputs and interruptions for
//! every surface of `rtf`, each run through the binary and classified as
//!
//! - **clear error**: exit 1 or 2, output naming the path (or value) at fault, no panic text;
//!   for the cases whose right outcome is not a refusal (a resume after `kill -9`, an
//!   interrupted run, a warning), that exact exit code with what it must say and a correct
//!   result;
//! - **panic**: exit 101 (a Rust panic) or a signal (abort, segfault, OOM kill, a hang killed);
//! - **silent wrong**: exit 0 where the input must be refused, or a side effect the refusal
//!   must not have (an input overwritten, a file written), or an expected outcome whose
//!   result is wrong (a resumed run with missing or doubled epochs);
//! - **unclear**: any other failure (a message that does not name the path).
//!
//! The test prints the table, the counts per group and in all (`cargo xtask hostile` shows
//! them) and fails on any panic, silent wrong result or unclear error. Huge frames under
//! `ulimit -v` need a few GB of address space and ~10 s each: they run with
//! `RTF_HOSTILE_MEMORY=1` (the xtask sets it). The DDP cases need the venv's torchrun
//! (`cargo xtask setup`); without it they are skipped, and said so.
//!
//! One module per surface: `inputs` (predict, eval, data, memory: issue 15), `recipes`,
//! `report`, `export`, `modality` (`--drop`, `--precision`), `ddp`, `owndata` (dataset.yaml),
//! `sequences` (fields in folders, JPEG thermal, per-condition lists),
//! `calib` (rig.yaml's prior) and `cmx` (CMX weights that do not fit).

#[path = "../common/mod.rs"]
mod common;
#[path = "../../../rtf-dist/tests/launcher/mod.rs"]
mod launcher;

mod calib;
mod cmx;
mod ddp;
mod distributed;
mod export;
mod inputs;
mod modality;
mod owndata;
mod recipes;
mod report;
mod sequences;
mod verdict;

use std::path::PathBuf;
use std::time::Instant;

use common::*;
use verdict::{Case, Verdict};

/// What every surface starts from: a tiny MF dataset and a one-step mfnet run on it.
pub struct Fixture {
    pub t: PathBuf,
    pub data: PathBuf,
    pub run: PathBuf,
    pub weights: PathBuf,
    pub frame: String,
    pub good_image: PathBuf,
}

fn fixture(t: &std::path::Path) -> Fixture {
    let data = t.join("data");
    let run = t.join("run");
    synth_mf(&data, "8", "1", "32x32");
    ok(&short_train(&data, &run, "1", &["--val-split", "none"]));
    let frame = std::fs::read_to_string(data.join("test.txt"))
        .unwrap()
        .lines()
        .next()
        .unwrap()
        .trim()
        .to_string();
    Fixture {
        t: t.to_path_buf(),
        weights: run.join("final.safetensors"),
        good_image: data.join("images").join(format!("{frame}.png")),
        data,
        run,
        frame,
    }
}

#[test]
fn hostile_inputs_get_clear_errors_never_panics_or_silent_results() {
    let tmp = tempfile::tempdir().unwrap();
    let f = fixture(tmp.path());
    type Surface = (&'static str, fn(&Fixture) -> Vec<Case>);
    let surfaces: [Surface; 16] = [
        ("inputs", inputs::predict_images),
        ("inputs", inputs::predict_outputs),
        ("inputs", inputs::weights),
        ("cmx", cmx::cases),
        ("inputs", inputs::datasets),
        ("inputs", inputs::memory),
        ("recipes", recipes::cases),
        ("stages", recipes::stage_folders),
        ("report", report::cases),
        ("export", export::cases),
        ("modality", modality::cases),
        ("ddp", ddp::cases),
        ("owndata", owndata::cases),
        ("sequences", sequences::cases),
        ("distributed", distributed::cases),
        ("calib", calib::cases),
    ];
    // RTF_HOSTILE_ONLY=recipes,report runs those modules alone (while working on them);
    // `stages` is the stage-folder half of the recipes.
    let only = std::env::var("RTF_HOSTILE_ONLY").unwrap_or_default();
    let slow = std::env::var_os("RTF_HOSTILE_SLOW").is_some();
    let started = Instant::now();
    let mut rows = Vec::new();
    for (module, surface) in surfaces {
        if !only.is_empty() && !only.split(',').any(|m| m == module) {
            continue;
        }
        // The multi-stage and data-parallel cases train several runs each (minutes on two
        // cores): `cargo xtask hostile` runs them (RTF_HOSTILE_SLOW=1); the plain test suite
        // keeps to the fast surfaces so it stays within its time budget.
        if only.is_empty() && !slow && SLOW_MODULES.contains(&module) {
            println!("hostile: {module} cases skipped (RTF_HOSTILE_SLOW=1 or `cargo xtask hostile` runs them)");
            continue;
        }
        for c in surface(&f) {
            let output = c.run();
            let verdict = c.judge(&output);
            print_row(&c, verdict, &output);
            rows.push((c, verdict, output));
        }
    }
    summary(&rows, started.elapsed().as_secs());
}

/// Modules that only `cargo xtask hostile` (RTF_HOSTILE_SLOW=1) or RTF_HOSTILE_ONLY runs.
const SLOW_MODULES: [&str; 3] = ["recipes", "stages", "ddp"];

fn print_row(c: &Case, verdict: Verdict, output: &std::process::Output) {
    let code = output
        .status
        .code()
        .map_or("signal".to_string(), |c| c.to_string());
    println!("{:<72} {code:>6}  {verdict:?}", c.name);
}

/// The group of a case: its name up to the first `:`.
fn group(c: &Case) -> &str {
    c.name.split(':').next().unwrap_or(&c.name)
}

type Row = (Case, Verdict, std::process::Output);

fn summary(rows: &[Row], seconds: u64) {
    let count = |rows: &[&Row], v: Verdict| rows.iter().filter(|r| r.1 == v).count();
    let mut groups: Vec<&str> = Vec::new();
    for r in rows {
        if !groups.contains(&group(&r.0)) {
            groups.push(group(&r.0));
        }
    }
    println!(
        "\n| group | cases | clear | panic | silent wrong | unclear |\n|---|---|---|---|---|---|"
    );
    for g in groups.iter().chain(std::iter::once(&"**total**")) {
        let of: Vec<&Row> = rows
            .iter()
            .filter(|r| *g == "**total**" || group(&r.0) == *g)
            .collect();
        println!(
            "| {g} | {} | {} | {} | {} | {} |",
            of.len(),
            count(&of, Verdict::Clear),
            count(&of, Verdict::Panic),
            count(&of, Verdict::Silent),
            count(&of, Verdict::Unclear)
        );
    }
    let all: Vec<&Row> = rows.iter().collect();
    println!(
        "\nhostile: {} cases tried in {seconds} s, {} clear, {} panics, {} silent wrong, {} unclear",
        rows.len(),
        count(&all, Verdict::Clear),
        count(&all, Verdict::Panic),
        count(&all, Verdict::Silent),
        count(&all, Verdict::Unclear)
    );
    let bad: Vec<String> = rows
        .iter()
        .filter(|r| r.1 != Verdict::Clear)
        .map(|(c, v, o)| {
            format!(
                "{} ({v:?}, exit {:?}, expected {:?} naming {:?}):\n{}",
                c.name,
                o.status.code(),
                c.expect,
                c.must_name,
                text(o)
            )
        })
        .collect();
    assert!(bad.is_empty(), "{}", bad.join("\n---\n"));
}
