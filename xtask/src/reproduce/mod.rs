//! `cargo xtask reproduce <table>|all`: orchestrates the experiments behind the papers' tables
//! with the release `rtf` binary (`rtf synth`, `rtf train`, `rtf eval`, `rtf bench model`) and
//! writes each table with the paper's numbers beside the measured ones (project issue 11).
//!
//! Every cell is an ordinary run folder `<out>/<table>/<cell>/seed<k>/`; a re-run skips
//! finished cells and resumes interrupted ones; a failed cell is reported and the others go on.
//! Protocol: train on train, pick the checkpoint on validation (never on test), report test.

mod budget;
mod cells;
mod figure;
mod io;
mod paper_time;
mod report;
mod speed;
mod tables;

use anyhow::{bail, Context as _, Result};
use budget::Budget;
use cells::{Context, Outcome};
use serde_json::Value;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;
use tables::{Data, Table, Train};

/// Network names `rtf models --json` lists that the tables use, compiled in so the table
/// definitions are checked without libtorch; a test compares them with the binary's list when
/// `target/release/rtf` exists.
#[cfg(test)]
pub const KNOWN_NETWORKS: &[&str] = &[
    "cmx-mit-b0",
    "cmx-mit-b1",
    "cmx-mit-b2",
    "cmx-mit-b4",
    "duchdc-3c",
    "duchdc-4c",
    "enet-3c",
    "erfnet-3c",
    "erfnet-4c",
    "fusenet",
    "heatnet",
    "mfnet",
    "mfnet-b",
    "mfnet-c",
    "mfnet-d",
    "mfnet-e",
    "mfnet-f",
    "mfnet-g",
    "mfnet-h",
    "mfnet-i",
    "mfnet-j",
    "mfnet-k",
    "mfnet-l",
    "mfnet-m",
    "mfnet-n",
    "pspnet-3c",
    "pspnet-4c",
    "rtfnet101",
    "rtfnet101-nre",
    "rtfnet101-nte",
    "rtfnet101-nub",
    "rtfnet152",
    "rtfnet152-fci",
    "rtfnet152-nre",
    "rtfnet152-nte",
    "rtfnet152-nub",
    "rtfnet152-olf",
    "rtfnet18",
    "rtfnet18-nre",
    "rtfnet18-nte",
    "rtfnet18-nub",
    "rtfnet34",
    "rtfnet34-nre",
    "rtfnet34-nte",
    "rtfnet34-nub",
    "rtfnet50",
    "rtfnet50-fci",
    "rtfnet50-nre",
    "rtfnet50-nte",
    "rtfnet50-nub",
    "rtfnet50-olf",
    "segnet-3c",
    "segnet-4c",
    "unet-3c",
    "unet-4c",
];

/// The HeatNet recipes the HeatNet tables call (`rtf recipes --json`).
#[cfg(test)]
pub const HEATNET_RECIPES: &[&str] = &[
    "heatnet-distill",
    "heatnet-teacher-ir",
    "heatnet-teacher-rgb",
    "heatnet-v1",
    "heatnet-v2",
    "heatnet-v3",
    "heatnet-v4",
    "heatnet-v5",
    "heatnet-v6",
];

fn usage() -> String {
    let mut text = String::from(
        "usage: cargo xtask reproduce <table>|all [options]
       cargo xtask reproduce --list
       cargo xtask reproduce docs [--out DIR] [--note TEXT]   write docs/src/reproduction.md
                                     from DIR's quick results (TEXT: why some are missing)
       cargo xtask reproduce smoke   `all --budget smoke` afresh into target/reproduce-smoke,
                                     then check every table's files (run by `cargo xtask test`)

options:
  --budget smoke|quick|paper  smoke: CI pipeline check; quick: small runs for a CPU (default);
                              paper: the papers' recipes, for a GPU (--device cuda)
  --seeds N                   seeds 0..N-1 per cell (default 1); results as mean ± std
  --out DIR                   results folder (default results/): <table>.md/.json/.csv, cells
  --mf DIR | --freiburg DIR | --bdd DIR   real datasets (default: synthetic, from `rtf synth`)
  --device cpu|cuda           (default cpu)
  --jobs N                    cells trained at once (default 1; more for a GPU or many cores:
                              each `rtf train` process also takes the threads it is given)
  --cells ID[,ID...]          only these cells of the table (e.g. mfnet,enet-3c); the others
                              are reported as not selected
  --no-build                  use target/release/rtf as it is instead of building it with
                              cargo (a machine without the Rust toolchain, e.g. a lent GPU)
  --dry-run                   print every cell run's `rtf train` and `rtf eval` command (the
                              synthetic data named by the folder a run makes) and run nothing
  --backbone-weights FILE     ImageNet ResNet weights for RTFNet encoders (paper budget)
  --mit-weights DIR           SegFormer's ImageNet MiT weights for the CMX cells, one file a
                              size: DIR/mit_bX.safetensors for cmx-mit-bX (paper budget: B2, B4)
  speed tables: --precision fp32|bf16, --warmup N, --iterations N

tables:
",
    );
    for (id, title) in list() {
        let _ = writeln!(text, "  {id:<13} {title}");
    }
    text += "  all           every table above\n";
    text
}

/// (id, title) of every table, in `all`'s order.
fn list() -> Vec<(&'static str, &'static str)> {
    let mut v: Vec<_> = tables::all(false).iter().map(|t| (t.id, t.title)).collect();
    v.extend(speed::TABLES.iter().map(|t| (t.id, t.title)));
    v
}

#[derive(Debug)]
struct Options {
    ids: Vec<&'static str>,
    all: bool,
    budget: Budget,
    seeds: usize,
    out: PathBuf,
    roots: BTreeMap<Data, PathBuf>,
    device: String,
    jobs: usize,
    no_build: bool,
    /// `--cells`: only these cells of the selected tables (None: every cell).
    cells: Option<Vec<String>>,
    /// `--dry-run`: print each cell run's commands, run nothing.
    dry_run: bool,
    backbone_weights: Option<PathBuf>,
    /// `--mit-weights DIR`: SegFormer's ImageNet MiT weights for the CMX cells.
    mit_weights: Option<PathBuf>,
    precision: String,
    warmup: Option<usize>,
    iterations: Option<usize>,
}

fn parse(args: &[String]) -> Result<Options> {
    let Some(first) = args.first().filter(|a| !a.starts_with('-')) else {
        bail!("{}", usage());
    };
    let known = list();
    let (ids, all) = if first == "all" {
        (known.iter().map(|(id, _)| *id).collect(), true)
    } else {
        let Some((id, _)) = known.iter().find(|(id, _)| id == first) else {
            bail!("unknown table `{first}`\n\n{}", usage());
        };
        (vec![*id], false)
    };
    let mut o = Options {
        ids,
        all,
        budget: Budget::Quick,
        seeds: 1,
        out: PathBuf::from("results"),
        roots: BTreeMap::new(),
        device: "cpu".into(),
        jobs: 1,
        no_build: false,
        cells: None,
        dry_run: false,
        backbone_weights: None,
        mit_weights: None,
        precision: "fp32".into(),
        warmup: None,
        iterations: None,
    };
    let mut it = args[1..].iter();
    while let Some(flag) = it.next() {
        let mut value = || it.next().with_context(|| format!("{flag} needs a value"));
        let number = |v: &String, what: &str| -> Result<usize> {
            v.parse()
                .with_context(|| format!("{what}: `{v}` is not a whole number"))
        };
        match flag.as_str() {
            "--budget" => o.budget = Budget::parse(value()?)?,
            "--seeds" => {
                o.seeds = number(value()?, "--seeds")?;
                if o.seeds == 0 {
                    bail!("--seeds must be at least 1");
                }
            }
            "--out" => o.out = PathBuf::from(value()?),
            "--mf" => {
                o.roots.insert(Data::Mf, PathBuf::from(value()?));
            }
            "--freiburg" => {
                o.roots.insert(Data::Freiburg, PathBuf::from(value()?));
            }
            "--bdd" => {
                o.roots.insert(Data::Bdd, PathBuf::from(value()?));
            }
            "--device" => o.device = value()?.clone(),
            "--jobs" => {
                o.jobs = number(value()?, "--jobs")?;
                if o.jobs == 0 {
                    bail!("--jobs must be at least 1");
                }
            }
            "--no-build" => o.no_build = true,
            "--dry-run" => o.dry_run = true,
            "--cells" => o.cells = Some(value()?.split(',').map(String::from).collect()),
            "--backbone-weights" => o.backbone_weights = Some(PathBuf::from(value()?)),
            "--mit-weights" => o.mit_weights = Some(PathBuf::from(value()?)),
            "--precision" => o.precision = value()?.clone(),
            "--warmup" => o.warmup = Some(number(value()?, "--warmup")?),
            "--iterations" => o.iterations = Some(number(value()?, "--iterations")?),
            other => bail!("reproduce: unknown option `{other}`\n\n{}", usage()),
        }
    }
    Ok(o)
}

/// `--cells` names only cells of the selected tables.
fn check_cells(cells: Option<&[String]>, selected: &[Table]) -> Result<()> {
    let known: Vec<&str> = selected
        .iter()
        .flat_map(|t| t.cells.iter().map(|c| c.id.as_str()))
        .collect();
    for cell in cells.unwrap_or_default() {
        if !known.contains(&cell.as_str()) {
            bail!(
                "--cells: `{cell}` is not a cell of {} (its cells: {})",
                selected.iter().map(|t| t.id).collect::<Vec<_>>().join(", "),
                known.join(", ")
            );
        }
    }
    Ok(())
}

/// Checks a dataset root's layout (the folders `rtf` recognises it by; spec §1, §6).
fn check_root(data: Data, root: &Path) -> Result<()> {
    if !root.is_dir() {
        bail!("{} {}: no such folder", data.flag(), root.display());
    }
    match data {
        Data::Mf => {
            let missing: Vec<&str> = ["images/", "labels/", "train.txt", "val.txt", "test.txt"]
                .into_iter()
                .filter(|p| !root.join(p.trim_end_matches('/')).exists())
                .collect();
            if !missing.is_empty() {
                bail!(
                    "--mf {}: not an MF dataset root: missing {} (an MF root holds images/, \
                     labels/ and the split files train.txt, val.txt, test.txt)",
                    root.display(),
                    missing.join(", ")
                );
            }
        }
        Data::Freiburg => {
            if !has_dir_named(root, &["fl_rgb", "ImagesRGB"], 6) {
                bail!(
                    "--freiburg {}: not a Freiburg Thermal root: no fl_rgb/ or ImagesRGB/ folder \
                     within 6 levels",
                    root.display()
                );
            }
        }
        Data::Bdd => {
            let splits = std::fs::read_dir(root.join("images"))
                .map(|rd| {
                    rd.flatten()
                        .filter(|e| root.join("labels").join(e.file_name()).is_dir())
                        .count()
                })
                .unwrap_or(0);
            if splits == 0 {
                bail!(
                    "--bdd {}: not a BDD100K root: needs images/<split>/ with a matching \
                     labels/<split>/",
                    root.display()
                );
            }
        }
    }
    Ok(())
}

fn has_dir_named(dir: &Path, names: &[&str], depth: usize) -> bool {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return false;
    };
    rd.flatten().filter(|e| e.path().is_dir()).any(|e| {
        names.iter().any(|n| e.file_name() == *n)
            || (depth > 1 && has_dir_named(&e.path(), names, depth - 1))
    })
}

/// The checks that need no binary: roots' layouts and which tables read them.
fn check_inputs(o: &Options, selected: &[Table]) -> Result<()> {
    check_cells(o.cells.as_deref(), selected)?;
    for (data, root) in &o.roots {
        check_root(*data, root)?;
        if o.all {
            continue;
        }
        let users: Vec<&str> = selected
            .iter()
            .filter(|t| t.datasets().contains(data))
            .map(|t| t.id)
            .collect();
        if users.is_empty() {
            let ids: Vec<&str> = o.ids.clone();
            let reads: Vec<String> = selected
                .iter()
                .map(|t| {
                    let d: Vec<&str> = t.datasets().iter().map(|d| d.name()).collect();
                    format!(
                        "{} reads {}",
                        t.id,
                        if d.is_empty() {
                            "no dataset".to_string()
                        } else {
                            d.join(", ")
                        }
                    )
                })
                .collect();
            bail!(
                "{} {} given, but {} does not use the {} dataset ({})",
                data.flag(),
                root.display(),
                ids.join(", "),
                data.name(),
                if reads.is_empty() {
                    "a speed table reads no dataset".to_string()
                } else {
                    reads.join("; ")
                }
            );
        }
    }
    if let Some(w) = &o.backbone_weights {
        if !w.is_file() {
            bail!("--backbone-weights {}: no such file", w.display());
        }
    }
    check_mit_weights(o, selected)
}

/// `--mit-weights DIR` holds the MiT weights of every CMX network the budget trains.
fn check_mit_weights(o: &Options, selected: &[Table]) -> Result<()> {
    let Some(dir) = &o.mit_weights else {
        return Ok(());
    };
    if !dir.is_dir() {
        bail!("--mit-weights {}: no such folder", dir.display());
    }
    for n in tables::networks(selected) {
        let trained = o.budget.network(n);
        if let Some(f) = cells::mit_file(dir, trained).filter(|f| !f.is_file()) {
            bail!(
                "--mit-weights {}: no {} for {trained} (SegFormer's ImageNet MiT weights, \
                 converted by `cargo xtask convert-pth`)",
                dir.display(),
                f.display()
            );
        }
    }
    Ok(())
}

/// One run of a cell: its table, the cell and the seed.
type Job<'a> = (&'a Table, &'a tables::Cell, usize);

/// A cell of a table that has no result, and why (reported under `Not measured`).
type MissingCell = (String, report::Missing);

pub fn reproduce(root: &Path, args: &[String]) -> Result<()> {
    if let Some(done) = subcommand(root, args) {
        return done;
    }
    let o = parse(args)?;
    let out = root.join(&o.out);
    let command = format!("cargo xtask reproduce {}", args.join(" "));
    let selected: Vec<Table> = tables::all(o.roots.contains_key(&Data::Bdd))
        .into_iter()
        .filter(|t| o.ids.contains(&t.id))
        .collect();
    check_inputs(&o, &selected)?;
    if o.dry_run {
        print!("{}", dry_run(root, &o, &selected)?);
        return Ok(());
    }

    let rtf = if o.no_build {
        prebuilt_rtf(root, &selected)?
    } else {
        build_rtf(root, &selected)?
    };
    let recipes = available_recipes(root);
    check_recipes(&o, &selected, &recipes)?;
    let (jobs, mut missing) = plan(&selected, &recipes, o.budget, o.seeds, o.cells.as_deref());
    let data = datasets(root, &rtf, &out, &o, &jobs)?;
    let ctx = Context {
        root: root.to_path_buf(),
        rtf,
        out: out.clone(),
        budget: o.budget,
        device: o.device.clone(),
        backbone_weights: o.backbone_weights.clone(),
        mit_weights: o.mit_weights.clone(),
        data,
        recipes,
    };
    // A folder made with another recipe stops everything before anything runs.
    for (t, c, s) in &jobs {
        cells::check_spec(&ctx.cell_dir(t, c, *s), &ctx.spec(t, c, *s)?)?;
    }

    let progress = run_jobs(&ctx, &jobs, o.jobs, &mut missing);
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    write_tables(&ctx, &selected, o.seeds, &missing, &command)?;
    if !progress.interrupted {
        speed_tables(root, &o, &out, &command)?;
    }
    finish(&progress, jobs.len(), &missing, &out)
}

/// The commands that are not a table run (`--help`, `--list`, `docs`, `smoke`); `None` for a
/// table run.
fn subcommand(root: &Path, args: &[String]) -> Option<Result<()>> {
    match args.first().map(String::as_str) {
        None | Some("-h" | "--help" | "help") => {
            print!("{}", usage());
            Some(Ok(()))
        }
        Some("--list") => {
            for (id, title) in list() {
                println!("{id:<13} {title}");
            }
            Some(Ok(()))
        }
        Some("docs") => Some(docs(root, &args[1..])),
        Some("smoke") if args.len() == 1 => Some(smoke(root)),
        _ => None,
    }
}

/// Builds the release `rtf` (and libtorch first when missing) and checks that it builds every
/// network of the selected tables; returns the binary's path.
fn build_rtf(root: &Path, selected: &[Table]) -> Result<PathBuf> {
    crate::setup::ensure_libtorch(root)?;
    crate::run(root, "cargo", &["build", "--release", "-p", "rtf-cli"])?;
    check_networks(root, selected)?;
    Ok(root.join("target/release/rtf"))
}

/// `--no-build`: the `rtf` already in target/release, which must build every network of the
/// selected tables.
fn prebuilt_rtf(root: &Path, selected: &[Table]) -> Result<PathBuf> {
    let rtf = root.join("target/release/rtf");
    if !rtf.is_file() {
        bail!(
            "--no-build: {} does not exist (build it, or leave out --no-build)",
            rtf.display()
        );
    }
    check_networks(root, selected)?;
    Ok(rtf)
}

/// The `rtf train --recipe` a cell needs on `budget`: its own (`Train::Recipe`), or the one the
/// budget gives its table's `Train::Model` cells (CMX's `cmx-mf` on the paper budget).
fn needed_recipe(budget: Budget, t: &Table, c: &tables::Cell) -> Option<&'static str> {
    match c.train {
        Train::Recipe(r) => Some(r),
        Train::Model(_) => budget.model_recipe(t.recipe),
    }
}

/// A single table whose recipes this rtf lacks stops here; under `all` their cells are
/// reported as not measured instead (see [`plan`]).
fn check_recipes(o: &Options, selected: &[Table], recipes: &BTreeMap<String, Value>) -> Result<()> {
    let mut lacking: Vec<&str> = selected
        .iter()
        .flat_map(|t| t.cells.iter().map(move |c| (t, c)))
        .filter_map(|(t, c)| needed_recipe(o.budget, t, c))
        .filter(|r| !recipes.contains_key(*r))
        .collect();
    lacking.sort();
    lacking.dedup();
    if !lacking.is_empty() && !o.all {
        bail!(
            "{} needs the recipes {} of `rtf train --recipe` (budget {}), which this rtf does \
             not list (`rtf recipes --json`); the HeatNet ones land with the HeatNet-training \
             issue, `{}` with CMX's training (issue 39)",
            o.ids.join(", "),
            lacking.join(", "),
            o.budget.name(),
            budget::CMX_RECIPE
        );
    }
    Ok(())
}

/// `--dry-run`: the commands of every selected cell run, seed by seed, without building,
/// synthesising or training; a cell that cannot run says why, and one whose recipe this rtf
/// (`target/release/rtf`, if built) does not list still shows its commands, marked.
fn dry_run(root: &Path, o: &Options, selected: &[Table]) -> Result<String> {
    let out = root.join(&o.out);
    let mut data = BTreeMap::new();
    for d in selected.iter().flat_map(|t| t.datasets()) {
        let entry = match o.roots.get(&d) {
            Some(r) => (r.clone(), true),
            None => (synth_dir(&out, o.budget, d)?.1, false),
        };
        data.insert(d, entry);
    }
    let ctx = Context {
        root: root.to_path_buf(),
        rtf: root.join("target/release/rtf"),
        out,
        budget: o.budget,
        device: o.device.clone(),
        backbone_weights: o.backbone_weights.clone(),
        mit_weights: o.mit_weights.clone(),
        data,
        recipes: available_recipes(root),
    };
    let mut text = String::new();
    for t in selected {
        for c in &t.cells {
            let _ = writeln!(text, "# {}/{}", t.id, c.id);
            if let Some(why) = c.blocked {
                let _ = writeln!(text, "#   not run: {why}");
                continue;
            }
            if let Some(r) = needed_recipe(o.budget, t, c).filter(|r| !ctx.recipes.contains_key(*r))
            {
                let _ = writeln!(
                    text,
                    "#   needs the recipe `{r}`, which this rtf does not list"
                );
            }
            for seed in 0..o.seeds {
                text += &dry_run_cell(&ctx, t, c, seed)?;
            }
        }
    }
    Ok(text)
}

/// One cell run's `rtf train` and `rtf eval` lines (the weights the protocol evaluates: the
/// checkpoint picked on validation, the final ones where a Freiburg cell has no validation).
fn dry_run_cell(ctx: &Context, t: &Table, c: &tables::Cell, seed: usize) -> Result<String> {
    let dir = ctx.cell_dir(t, c, seed);
    let spec = ctx.spec(t, c, seed)?;
    let weights = dir.join(match c.data {
        Data::Freiburg => "final.safetensors",
        _ => "best.safetensors",
    });
    let train = cells::train_command(&dir, &spec)?;
    // A recipe this rtf does not list gives no network name to evaluate.
    let network = ctx
        .network(c)
        .unwrap_or_else(|_| "<the recipe's network>".into());
    let mut text = format!("rtf {}\n", train.join(" "));
    for run in cells::eval_runs(&spec) {
        let eval = cells::eval_command(ctx, &dir, &spec, &network, &weights, run)?;
        text += &format!("rtf {}\n", eval.join(" "));
    }
    Ok(text)
}

/// The reason recorded for a cell that `--cells` leaves out.
const NOT_SELECTED: &str = "not selected (--cells)";

/// The cells to run (each seed a job), and the ones that cannot run with the reason.
fn plan<'a>(
    selected: &'a [Table],
    recipes: &BTreeMap<String, Value>,
    budget: Budget,
    seeds: usize,
    only: Option<&[String]>,
) -> (Vec<Job<'a>>, Vec<MissingCell>) {
    let mut jobs = Vec::new();
    let mut missing = Vec::new();
    for t in selected {
        for c in &t.cells {
            let chosen = only.is_none_or(|cells| cells.contains(&c.id));
            let reason =
                c.blocked
                    .map(String::from)
                    .or_else(|| match needed_recipe(budget, t, c) {
                        _ if !chosen => Some(NOT_SELECTED.to_string()),
                        Some(r) if !recipes.contains_key(r) => Some(format!(
                            "needs the recipe `{r}` (`rtf recipes` does not list it yet)"
                        )),
                        _ => None,
                    });
            match reason {
                Some(reason) => missing.push((
                    t.id.to_string(),
                    report::Missing {
                        cell: c.id.clone(),
                        reason,
                    },
                )),
                None => jobs.extend((0..seeds).map(|s| (t, c, s))),
            }
        }
    }
    (jobs, missing)
}

/// Dataset roots by dataset, each with whether it is real: the given roots, else synthetic ones
/// (made once under `<out>/data/`) for what the runnable cells read.
fn datasets(
    root: &Path,
    rtf: &Path,
    out: &Path,
    o: &Options,
    jobs: &[Job],
) -> Result<BTreeMap<Data, (PathBuf, bool)>> {
    let mut data = BTreeMap::new();
    for (d, r) in &o.roots {
        let abs = std::fs::canonicalize(r).with_context(|| format!("{}", r.display()))?;
        data.insert(*d, (abs, true));
    }
    let mut needed: Vec<Data> = jobs
        .iter()
        .flat_map(|(_, c, _)| [c.data, c.eval_on])
        .collect();
    needed.sort();
    needed.dedup();
    for d in needed {
        if data.contains_key(&d) {
            continue;
        }
        if d == Data::Bdd {
            bail!("BDD100K cannot be synthesised: give --bdd");
        }
        let dir = synthesise(root, rtf, out, o.budget, d)?;
        data.insert(d, (dir, false));
    }
    Ok(data)
}

/// How the cell runs went: for the ETA, the closing line and whether to stop.
struct Progress {
    started: Instant,
    /// Cells trained or evaluated now (not skipped, reused or interrupted), and their time.
    ran: usize,
    ran_seconds: f64,
    /// Cells run at once (`--jobs`): the ETA divides by it.
    workers: usize,
    interrupted: bool,
}

/// Runs every job: skips finished cells, resumes interrupted ones, records failures in
/// `missing` and goes on; stops taking new cells at the first interrupted one. `workers` cells
/// run at once, taken in order (1: one after the other).
fn run_jobs(
    ctx: &Context,
    jobs: &[Job],
    workers: usize,
    missing: &mut Vec<MissingCell>,
) -> Progress {
    let progress = std::sync::Mutex::new(Progress {
        started: Instant::now(),
        ran: 0,
        ran_seconds: 0.0,
        workers: workers.max(1),
        interrupted: false,
    });
    let failed = std::sync::Mutex::new(Vec::new());
    let next = std::sync::atomic::AtomicUsize::new(0);
    std::thread::scope(|scope| {
        for _ in 0..workers.min(jobs.len()).max(1) {
            scope.spawn(|| loop {
                let k = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                if k >= jobs.len() || lock(&progress).interrupted {
                    break;
                }
                if let Some(m) = run_job(ctx, jobs, k, &progress) {
                    lock(&failed).push(m);
                }
            });
        }
    });
    missing.extend(failed.into_inner().unwrap_or_else(|e| e.into_inner()));
    progress.into_inner().unwrap_or_else(|e| e.into_inner())
}

/// A mutex's guard, also after a panicking holder (the data are counters and lists).
fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Runs job `k`; its failure, if it failed.
fn run_job(
    ctx: &Context,
    jobs: &[Job],
    k: usize,
    progress: &std::sync::Mutex<Progress>,
) -> Option<MissingCell> {
    let (t, c, s) = jobs[k];
    let dir = ctx.cell_dir(t, c, s);
    let st = cells::state(&dir, c.bench);
    let at = format!("[{}/{}] {}/{}/seed{s}", k + 1, jobs.len(), t.id, c.id);
    if st == cells::State::Done {
        eprintln!("{at}: done, skipped");
        return None;
    }
    let (eta, elapsed) = {
        let p = lock(progress);
        let eta = if p.ran > 0 {
            let left = trainings_left(ctx, &jobs[k..]) as f64;
            format!(
                ", about {} left",
                duration(p.ran_seconds / p.ran as f64 * left / p.workers as f64)
            )
        } else {
            String::new()
        };
        (eta, duration(p.started.elapsed().as_secs_f64()))
    };
    let doing = match st {
        cells::State::Resume => "resuming training",
        cells::State::Evaluate => "evaluating",
        _ => "training",
    };
    eprintln!("{at}: {doing} (elapsed {elapsed}{eta})");
    let t0 = Instant::now();
    match cells::run(ctx, t, c, s) {
        Ok(Outcome::Ran) => {
            let mut p = lock(progress);
            p.ran += 1;
            p.ran_seconds += t0.elapsed().as_secs_f64();
        }
        Ok(Outcome::Reused(from)) => eprintln!("{at}: same training as {}: reused", from.display()),
        Ok(Outcome::Interrupted) => {
            eprintln!(
                "interrupted: checkpoint written in {}; run the same command again to resume",
                dir.display()
            );
            lock(progress).interrupted = true;
        }
        Err(e) => {
            eprintln!("{at}: FAILED: {e:#}");
            return Some((
                t.id.to_string(),
                report::Missing {
                    cell: c.id.clone(),
                    reason: format!("failed (seed {s}): {e:#}"),
                },
            ));
        }
    }
    None
}

/// Cells of `jobs` left to train: identical ones (another table's same run) count once.
fn trainings_left(ctx: &Context, jobs: &[Job]) -> usize {
    let mut keys: Vec<String> = jobs
        .iter()
        .filter(|(t, c, s)| cells::state(&ctx.cell_dir(t, c, *s), c.bench) != cells::State::Done)
        .filter_map(|(t, c, s)| ctx.spec(t, c, *s).ok())
        .map(|v| {
            ["budget", "train_data", "eval_data", "rtf_train", "rtf_eval"]
                .map(|key| v[key].to_string())
                .join("|")
        })
        .collect();
    keys.sort();
    keys.dedup();
    keys.len()
}

/// Writes every selected table (`<id>.json/.md/.csv`, and Fig. 3's PNG) from its cell folders,
/// with its missing cells and the time estimate of the budgets not run.
fn write_tables(
    ctx: &Context,
    selected: &[Table],
    seeds: usize,
    missing: &[MissingCell],
    command: &str,
) -> Result<()> {
    for t in selected {
        let mine: Vec<report::Missing> = missing
            .iter()
            .filter(|(id, _)| id == t.id)
            .map(|(_, m)| report::Missing {
                cell: m.cell.clone(),
                reason: m.reason.clone(),
            })
            .collect();
        let mut v = report::collect(ctx, t, seeds, &mine, command);
        if let Some(e) = report::estimate(ctx, t) {
            v["estimate"] = e;
        }
        if t.figure {
            let png = ctx.out.join(format!("{}.png", t.id));
            fig3(&v, &png)?;
            v["figure"] = Value::String(png.display().to_string());
        }
        report::write(&ctx.out, &v)?;
        eprintln!(
            "reproduce: wrote {}",
            ctx.out.join(format!("{}.md", t.id)).display()
        );
    }
    Ok(())
}

/// Runs the selected speed tables (`rtf bench model`), with the budget's warm-up and
/// iteration counts unless given.
fn speed_tables(root: &Path, o: &Options, out: &Path, command: &str) -> Result<()> {
    let (warmup, iterations) = match o.budget {
        Budget::Smoke => (0, 1),
        Budget::Quick => (1, 5),
        Budget::Paper => (3, 20),
    };
    let options = speed::Options {
        size: match o.budget {
            Budget::Smoke => "96x64".into(),
            _ => "640x480".into(),
        },
        device: o.device.clone(),
        precision: o.precision.clone(),
        warmup: o.warmup.unwrap_or(warmup),
        iterations: o.iterations.unwrap_or(iterations),
    };
    for id in &o.ids {
        if let Some(t) = speed::TABLES.iter().find(|t| t.id == *id) {
            speed::run(root, t, &options, out, command, o.budget.name())?;
        }
    }
    Ok(())
}

/// The closing lines; an error when the run was interrupted or a cell failed.
fn finish(p: &Progress, total: usize, missing: &[MissingCell], out: &Path) -> Result<()> {
    let failed: Vec<String> = missing
        .iter()
        .filter(|(_, m)| m.reason.starts_with("failed"))
        .map(|(t, m)| format!("{t}/{}: {}", m.cell, m.reason))
        .collect();
    let unselected = missing
        .iter()
        .filter(|(_, m)| m.reason == NOT_SELECTED)
        .count();
    let unavailable = missing.len() - failed.len() - unselected;
    eprintln!(
        "reproduce: {total} cell runs ({} trained or evaluated now) in {}; results in {}",
        p.ran,
        duration(p.started.elapsed().as_secs_f64()),
        out.display()
    );
    if unavailable > 0 {
        eprintln!("reproduce: {unavailable} cells cannot run with this rtf yet (see `Not measured` in the tables)");
    }
    if unselected > 0 {
        eprintln!("reproduce: {unselected} cells left out by --cells");
    }
    if p.interrupted {
        bail!("interrupted; re-run the same command to resume");
    }
    if !failed.is_empty() {
        bail!("{} cells failed:\n{}", failed.len(), failed.join("\n"));
    }
    Ok(())
}

/// Where `cargo xtask test` runs `reproduce all --budget smoke`.
pub const SMOKE_OUT: &str = "target/reproduce-smoke";

/// `reproduce all --budget smoke` from scratch, then checks that every table wrote its
/// Markdown, CSV and schema-valid JSON (and Fig. 3 its PNG). Numbers are not asserted.
pub fn smoke(root: &Path) -> Result<()> {
    let out = root.join(SMOKE_OUT);
    if out.exists() {
        std::fs::remove_dir_all(&out).with_context(|| format!("removing {}", out.display()))?;
    }
    let args: Vec<String> = ["all", "--budget", "smoke", "--out", SMOKE_OUT]
        .map(String::from)
        .to_vec();
    reproduce(root, &args)?;
    for (id, _) in list() {
        for ext in ["md", "json"] {
            let path = out.join(format!("{id}.{ext}"));
            if !path.is_file() {
                bail!("reproduce smoke: {} was not written", path.display());
            }
        }
        let path = out.join(format!("{id}.json"));
        let v: Value = serde_json::from_slice(&std::fs::read(&path)?)
            .with_context(|| format!("{}: not JSON", path.display()))?;
        report::validate(&v).with_context(|| format!("{}", path.display()))?;
        if v["budget"]["name"] != "smoke" {
            bail!("{}: budget is not smoke", path.display());
        }
    }
    for t in tables::all(false) {
        if !out.join(format!("{}.csv", t.id)).is_file() {
            bail!("reproduce smoke: {}.csv was not written", t.id);
        }
    }
    if !out.join("rtfnet-fig3.png").is_file() {
        bail!("reproduce smoke: rtfnet-fig3.png was not drawn");
    }
    eprintln!("reproduce smoke: every table written and its JSON valid ({SMOKE_OUT})");
    Ok(())
}

fn duration(s: f64) -> String {
    let s = s.max(0.0) as u64;
    if s >= 3600 {
        format!("{}h{:02}m", s / 3600, s % 3600 / 60)
    } else {
        format!("{}m{:02}s", s / 60, s % 60)
    }
}

/// Every network of the selected tables must be one `rtf models --json` lists.
fn check_networks(root: &Path, selected: &[Table]) -> Result<()> {
    let models: Value = serde_json::from_str(&crate::rtf_stdout(root, &["models", "--json"])?)
        .context("parsing `rtf models --json`")?;
    let names: Vec<&str> = models
        .as_array()
        .map(|a| a.iter().filter_map(|m| m["name"].as_str()).collect())
        .unwrap_or_default();
    let unknown: Vec<&str> = tables::networks(selected)
        .into_iter()
        .filter(|n| !names.contains(n))
        .collect();
    if !unknown.is_empty() {
        bail!(
            "`rtf models` does not list {} (used by the tables)",
            unknown.join(", ")
        );
    }
    Ok(())
}

/// `rtf recipes --json` by name; empty when this rtf has no `recipes` command yet.
fn available_recipes(root: &Path) -> BTreeMap<String, Value> {
    let Ok(text) = crate::rtf_stdout(root, &["recipes", "--json"]) else {
        return BTreeMap::new();
    };
    let Ok(Value::Array(list)) = serde_json::from_str::<Value>(&text) else {
        return BTreeMap::new();
    };
    list.into_iter()
        .filter_map(|e| Some((e.get("name")?.as_str()?.to_string(), e)))
        .collect()
}

/// The `rtf synth --format` and folder of a budget's synthetic `data` under `out`.
fn synth_dir(out: &Path, budget: Budget, data: Data) -> Result<(&'static str, PathBuf)> {
    let format = match data {
        Data::Mf => "mf",
        Data::Freiburg => "freiburg",
        Data::Bdd => bail!("BDD100K cannot be synthesised"),
    };
    // The count and size in the name: a results folder of an older budget keeps its data apart.
    let (count, size) = budget.synth(data);
    let dir = out
        .join("data")
        .join(format!("{format}-{}-{count}-{size}", budget.name()));
    Ok((format, dir))
}

/// `rtf synth` into `<out>/data/<format>-<budget>-<count>-<size>/` (written beside and renamed,
/// so an interrupted synthesis is redone).
fn synthesise(root: &Path, rtf: &Path, out: &Path, budget: Budget, data: Data) -> Result<PathBuf> {
    let (format, dir) = synth_dir(out, budget, data)?;
    let (count, size) = budget.synth(data);
    if !dir.exists() {
        let tmp = dir.with_extension("partial");
        if tmp.exists() {
            std::fs::remove_dir_all(&tmp).with_context(|| format!("removing {}", tmp.display()))?;
        }
        std::fs::create_dir_all(out.join("data"))?;
        eprintln!(
            "reproduce: synthesising {count} {format} frames at {size} into {}",
            dir.display()
        );
        let status = std::process::Command::new(rtf)
            .args(["synth", "--out"])
            .arg(&tmp)
            .args([
                "--count",
                &count.to_string(),
                "--size",
                size,
                "--seed",
                "0",
                "--format",
                format,
            ])
            .current_dir(root)
            .stdout(std::process::Stdio::null())
            .status()
            .context("starting rtf synth")?;
        if !status.success() {
            bail!("`rtf synth` failed ({status})");
        }
        std::fs::rename(&tmp, &dir).with_context(|| format!("renaming to {}", dir.display()))?;
    }
    std::fs::canonicalize(&dir).with_context(|| format!("{}", dir.display()))
}

/// RTFNet Fig. 3 from the table's measured means.
fn fig3(v: &Value, png: &Path) -> Result<()> {
    let mut panels: [Vec<Vec<Option<f64>>>; 2] = [Vec::new(), Vec::new()];
    for (p, col) in ["mAcc", "mIoU"].iter().enumerate() {
        for (_, variant) in tables::FIG3_VARIANTS {
            panels[p].push(
                tables::FIG3_DEPTHS
                    .iter()
                    .map(|d| {
                        let label = format!("{variant}, ResNet-{d}");
                        v["rows"]
                            .as_array()?
                            .iter()
                            .find(|r| r["label"] == label.as_str())?["measured"][col]["mean"]
                            .as_f64()
                    })
                    .collect(),
            );
        }
    }
    figure::draw(&panels, png)
}

/// `reproduce docs`: docs/src/reproduction.md from the results under `--out`.
fn docs(root: &Path, args: &[String]) -> Result<()> {
    let mut out = PathBuf::from("results");
    let mut note = String::new();
    let mut it = args.iter();
    while let Some(flag) = it.next() {
        match flag.as_str() {
            "--out" => out = PathBuf::from(it.next().context("--out needs a value")?),
            "--note" => note = it.next().context("--note needs a value")?.clone(),
            other => bail!("reproduce docs: unknown option `{other}`"),
        }
    }
    let dir = root.join(&out);
    let mut text = String::from(DOCS_HEAD);
    let mut found = 0;
    let mut absent = Vec::new();
    for (id, _) in list() {
        let path = dir.join(format!("{id}.json"));
        let Ok(bytes) = std::fs::read(&path) else {
            absent.push(id);
            continue;
        };
        let v: Value = serde_json::from_slice(&bytes)
            .with_context(|| format!("{}: not JSON", path.display()))?;
        if v["budget"]["name"] != "quick" && v["budget"] != "quick" {
            absent.push(id);
            continue;
        }
        let md = std::fs::read_to_string(dir.join(format!("{id}.md")))
            .with_context(|| format!("{}: no Markdown beside it", path.display()))?;
        let _ = writeln!(text, "\n## `{id}`\n");
        text += &md.replacen("### ", "#### ", 1);
        found += 1;
    }
    if found == 0 {
        bail!("{}: no quick-budget results (run `cargo xtask reproduce <table> --budget quick` first)", dir.display());
    }
    if !absent.is_empty() {
        let _ = writeln!(
            text,
            "\n## Not run with the quick budget here\n\n{}: no quick results on this machine. \
             {note}",
            absent
                .iter()
                .map(|id| format!("`{id}`"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let path = root.join("docs/src/reproduction.md");
    io::write_atomic(&path, text.as_bytes())?;
    eprintln!(
        "reproduce docs: wrote {} from {found} tables",
        path.display()
    );
    Ok(())
}

const DOCS_HEAD: &str = "# Reproducing the papers' tables

<!-- Generated by `cargo xtask reproduce docs` from the results of this machine's quick runs;
     edit xtask/src/reproduce/mod.rs (DOCS_HEAD) or re-run the tables instead. -->

`cargo xtask reproduce <table>` runs the experiments behind one table of the MFNet, RTFNet or
HeatNet paper (or CMX's two official MF rows, `cmx-mf`) with the release `rtf` binary and
writes it with the paper's numbers beside the measured ones; `cargo xtask reproduce --list`
names the tables, `all` runs every one, `--dry-run` prints every cell run's commands.

```sh
cargo xtask reproduce mfnet-tab3 --budget quick            # synthetic data, this CPU
cargo xtask reproduce rtfnet-tab3 --mf /data/MF --budget paper --device cuda --seeds 3
cargo xtask reproduce heatnet-tab1 --freiburg /data/FR --mf /data/MF --bdd /data/BDD
cargo xtask reproduce cmx-mf --mf /data/MF --budget paper --device cuda --mit-weights /data/mit
cargo xtask reproduce cmx-mf --budget paper --dry-run     # the commands only
cargo xtask reproduce all --budget smoke --out target/reproduce-smoke   # CI
cargo xtask reproduce docs --out results                   # regenerate this page
```

**Data.** `--mf`, `--freiburg`, `--bdd` give the real datasets (their layout is checked first;
a root that no selected table reads is an error). Without them the tables run on synthetic
data from `rtf synth` and every title and JSON says so (`\"data\": \"synthetic\"`): synthetic
numbers show the pipeline and the trends, not the papers' values.

**Budgets.** `smoke` checks the pipeline (CI runs `reproduce all --budget smoke` inside `cargo
xtask test`). `quick` trains the MF tables' networks on 96×64 frames (1280 synthetic frames,
640 for training) in batches of 4 with RMSprop lr 1e-3 for every network (not the papers'
SGD: from scratch on a CPU budget it leaves most networks at the all-unlabelled answer), for
as many epochs as the network was measured to need to leave that answer: 15 by default, 20–40
for the slow learners (SegNet-3c 40, RTFNet 40). A claim judged on a cell that still did not
learn reads `untested` ([Sizing the quick budget](quick-budget.md)). The HeatNet recipes run
MFNet in every role at 192×96 with RMSprop 1e-3, 15 epochs a stage. `paper` follows the papers'
recipes (MFNet: SGD lr 0.01 ×0.94, 80 epochs, batch 6, flips, 480×640; RTFNet: SGD lr 0.01,
momentum 0.9, weight decay 5e-4, exponential decay ×0.95, flips, 100 epochs, batch 2 — the
paper trains \"until convergence\"; HeatNet: the `rtf recipes` procedures; CMX: `rtf train
--recipe cmx-mf` with MiT-B2 and MiT-B4) and is meant for a GPU. CMX's cells train lighter
stand-ins on the CPU budgets (smoke: `cmx-mit-b0` for both rows; quick: `cmx-mit-b0` for
MiT-B2, `cmx-mit-b1` for MiT-B4), named above each of its tables. The budget and each
cell's exact `rtf train` / `rtf eval` flags are written into the results. `--jobs N` trains
N cells at once (a GPU or many cores); `--cells a,b` runs only those cells of the table;
`--no-build` uses the `rtf` already in `target/release` (a machine without the Rust
toolchain).

**Protocol** (written into every result): train on the training split, pick the checkpoint
on validation (`best.safetensors`, never on test), report the test split; MF day/night from
the frame names; MFNet's mIoU convention for MFNet's tables, RTFNet's for RTFNet's, HeatNet's
on Freiburg Thermal, each named in the table (spec §2). Freiburg Thermal's only labelled
held-out part is its test layout, so Freiburg cells report their final weights.

**Across datasets** (HeatNet Tab. I's MF→FR-T and FR-T→MF rows): the network trained on one
dataset is scored on the other's test split with `rtf eval --class-map` and the built-in map
of the paper's comparison (`mf-to-freiburg` / `freiburg-to-mf`: person, car, bicycle; MF's
`bike` is Freiburg's `bicycle`, Freiburg's person and bicycle classes already hold riders and
motorcycles), at the evaluated dataset's CPU-budget frame size. The columns are the IoUs of
the three classes and their mean (Day/Night: the mean of the day and the night value). Truth
pixels of the other classes count as false positives where predicted as one of the three, as
in the authors' code, which maps Freiburg's other classes to MF's unlabeled (spec §5). The
paper's MF-trained HeatNet learned Freiburg's classes from its teacher on MF images and is
scored on all 12; rtf's `mf-heatnet` learns MF's labels, so that row measures the three shared
classes and leaves the paper's 12-class Mean without a measured counterpart. These cells
train their network again (the same recipe as the MF→MF or FR-T row's cell), once per seed,
and also score it on its own dataset's test split (`eval-own.json`): whether it learned is
judged there, against the same all-unlabelled bar as every other cell.

**Cells.** Each trained network is an ordinary run folder `<out>/<table>/<cell>/seed<k>/`
(`rtf train` files plus `cell.json`, the exact commands, `eval.json`, `xtask.log`). A re-run
skips finished cells, resumes interrupted ones (`rtf train --resume`; Ctrl-C checkpoints),
and refuses a folder made with another budget or dataset. A cell whose training and
evaluation equal a finished cell of another table (e.g. RTFNet Tab. VI re-uses Tab. III's
runs) copies its `eval.json` instead of training again (`reused_from` in its `cell.json`). A
failed cell is reported and the others go on.

**Outputs** (in `--out`, default `results/`): `<table>.md`, `<table>.json` —
`{table, budget, data, protocol, rows: [{label, paper: {COLUMN: value}, measured: {COLUMN:
{mean, std, seeds}}}], claims, …}` with COLUMN spelled as in the paper and values in percent
(times in ms) — `<table>.csv`, and `rtfnet-fig3.png`. A table written while some seeds of a
cell are still to run averages the finished ones and says so (`57.4 ± 4.1 (2 of 3 seeds)`;
`null` in the JSON's `seeds`).

Below: this machine's quick runs (2 shared CPU cores, so every time is disturbed by other jobs).
";

#[cfg(test)]
mod tests {
    use super::*;

    fn args(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn every_row_names_a_network_rtf_builds() {
        let all = tables::all(true);
        for n in tables::networks(&all) {
            assert!(KNOWN_NETWORKS.contains(&n), "{n} is not a known network");
        }
        for r in tables::recipes(&all) {
            assert!(HEATNET_RECIPES.contains(&r), "{r} is not a HeatNet recipe");
        }
        // The CPU budgets' stand-ins (CMX) are networks rtf builds too.
        for n in tables::networks(&all) {
            for b in [Budget::Smoke, Budget::Quick] {
                let trained = b.network(n);
                assert!(KNOWN_NETWORKS.contains(&trained), "{n}: stand-in {trained}");
            }
        }
        // The compiled-in list matches the binary's where it is built (release build of the
        // same tree; CI builds it before the tests run).
        let rtf = crate::project_root().join("target/release/rtf");
        if rtf.exists() {
            let out = std::process::Command::new(&rtf)
                .args(["models", "--json"])
                .output()
                .unwrap();
            assert!(out.status.success());
            let v: Value = serde_json::from_slice(&out.stdout).unwrap();
            let names: Vec<&str> = v
                .as_array()
                .unwrap()
                .iter()
                .filter_map(|m| m["name"].as_str())
                .collect();
            for n in KNOWN_NETWORKS {
                assert!(names.contains(n), "`rtf models` lacks {n}");
            }
        }
    }

    #[test]
    fn options_and_bad_input() {
        let o = parse(&args(&["mfnet-tab3", "--budget", "smoke", "--seeds", "3"])).unwrap();
        assert_eq!(
            (o.ids.clone(), o.budget, o.seeds),
            (vec!["mfnet-tab3"], Budget::Smoke, 3)
        );
        assert_eq!(o.out, PathBuf::from("results"));
        let all = parse(&args(&["all"])).unwrap();
        assert!(all.all && all.ids.len() == tables::ACCURACY_IDS.len() + speed::TABLES.len());
        let err = parse(&args(&["table99"])).unwrap_err().to_string();
        assert!(
            err.contains("unknown table `table99`") && err.contains("mfnet-tab2"),
            "{err}"
        );
        assert!(parse(&args(&["mfnet-tab2", "--budget", "huge"]))
            .unwrap_err()
            .to_string()
            .contains("unknown budget"));
        assert!(parse(&args(&["mfnet-tab2", "--seeds", "0"])).is_err());
        assert!(parse(&args(&["mfnet-tab2", "--bogus"])).is_err());
        assert!(parse(&args(&["mfnet-tab2", "--mf"]))
            .unwrap_err()
            .to_string()
            .contains("needs a value"));
    }

    #[test]
    fn parallel_jobs_run_every_cell_once() {
        let tmp = tempfile::tempdir().unwrap();
        let ctx = cells::tests::fake_context(tmp.path());
        let selected: Vec<Table> = tables::all(false)
            .into_iter()
            .filter(|t| t.id == "mfnet-tab2")
            .collect();
        let (jobs, _) = plan(&selected, &BTreeMap::new(), Budget::Smoke, 2, None);
        let mut missing = Vec::new();
        let p = run_jobs(&ctx, &jobs, 3, &mut missing);
        assert!(missing.is_empty() && !p.interrupted);
        assert_eq!(p.ran, jobs.len());
        for (t, c, s) in &jobs {
            assert_eq!(
                cells::state(&ctx.cell_dir(t, c, *s), c.bench),
                cells::State::Done
            );
        }
        let calls = std::fs::read_to_string(tmp.path().join("bin/calls.txt")).unwrap();
        let trains = calls.lines().filter(|l| l.starts_with("train ")).count();
        assert_eq!(trains, jobs.len(), "each cell trained once:\n{calls}");
        // A second run finds every cell done.
        let again = run_jobs(&ctx, &jobs, 3, &mut missing);
        assert_eq!(again.ran, 0);
        // --cells plans only the cells it names; the others are reported, an unknown one refused.
        let (only, left_out) = plan(
            &selected,
            &BTreeMap::new(),
            Budget::Smoke,
            2,
            Some(&["enet-3c".into()]),
        );
        assert_eq!(only.len(), 2);
        assert!(only.iter().all(|(_, c, _)| c.id == "enet-3c"));
        assert!(left_out.iter().any(|(_, m)| m.reason.contains("--cells")));
        let o = parse(&args(&["mfnet-tab2", "--cells", "mfnet,enet"])).unwrap();
        let err = check_cells(o.cells.as_deref(), &selected).unwrap_err();
        assert!(
            err.to_string()
                .contains("`enet` is not a cell of mfnet-tab2"),
            "{err}"
        );
        let o = parse(&args(&["mfnet-tab2", "--jobs", "4", "--no-build"])).unwrap();
        assert_eq!((o.jobs, o.no_build), (4, true));
        assert!(parse(&args(&["mfnet-tab2", "--jobs", "0"])).is_err());
    }

    #[test]
    fn dataset_roots_are_checked_before_anything_runs() {
        let tmp = tempfile::tempdir().unwrap();
        let mf = tmp.path().join("mf");
        std::fs::create_dir_all(mf.join("images")).unwrap();
        std::fs::create_dir_all(mf.join("labels")).unwrap();
        let selected = |id: &str| -> Vec<Table> {
            tables::all(false)
                .into_iter()
                .filter(|t| t.id == id)
                .collect()
        };
        let mut o = parse(&args(&["mfnet-tab2"])).unwrap();
        o.roots.insert(Data::Mf, mf.clone());
        let err = check_inputs(&o, &selected("mfnet-tab2"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("not an MF dataset root") && err.contains("train.txt"),
            "{err}"
        );
        for f in ["train.txt", "val.txt", "test.txt"] {
            std::fs::write(mf.join(f), "").unwrap();
        }
        check_inputs(&o, &selected("mfnet-tab2")).unwrap();
        // A Freiburg root given to an MF-only table.
        let fr = tmp.path().join("fr");
        std::fs::create_dir_all(fr.join("train/seq_00_day/00/fl_rgb")).unwrap();
        let mut o = parse(&args(&["mfnet-tab2"])).unwrap();
        o.roots.insert(Data::Freiburg, fr.clone());
        let err = check_inputs(&o, &selected("mfnet-tab2"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("--freiburg") && err.contains("does not use the Freiburg Thermal dataset"),
            "{err}"
        );
        // Wrong layout for Freiburg; a root for a speed table.
        let mut o = parse(&args(&["heatnet-tab2"])).unwrap();
        o.roots.insert(Data::Freiburg, mf.clone());
        let err = check_inputs(&o, &selected("heatnet-tab2"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("not a Freiburg Thermal root"), "{err}");
        o.roots.insert(Data::Freiburg, fr);
        check_inputs(&o, &selected("heatnet-tab2")).unwrap();
        let mut o = parse(&args(&["mfnet-tab4"])).unwrap();
        o.roots.insert(Data::Mf, mf);
        assert!(check_inputs(&o, &[])
            .unwrap_err()
            .to_string()
            .contains("speed table"));
        let mut o = parse(&args(&["mfnet-tab2"])).unwrap();
        o.roots.insert(Data::Mf, tmp.path().join("nowhere"));
        assert!(check_inputs(&o, &selected("mfnet-tab2"))
            .unwrap_err()
            .to_string()
            .contains("no such folder"));
    }

    #[test]
    fn docs_page_is_made_from_quick_results_only() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path();
        std::fs::create_dir_all(root.join("docs/src")).unwrap();
        let res = root.join("res");
        std::fs::create_dir_all(&res).unwrap();
        let err = docs(root, &args(&["--out", "res"]))
            .unwrap_err()
            .to_string();
        assert!(err.contains("no quick-budget results"), "{err}");
        for (id, budget) in [("mfnet-tab3", "quick"), ("rtfnet-tab4", "smoke")] {
            let v = serde_json::json!({"table": id, "budget": {"name": budget}});
            std::fs::write(res.join(format!("{id}.json")), v.to_string()).unwrap();
            std::fs::write(
                res.join(format!("{id}.md")),
                format!("### {id} table\n\nrows\n"),
            )
            .unwrap();
        }
        docs(root, &args(&["--out", "res"])).unwrap();
        let page = std::fs::read_to_string(root.join("docs/src/reproduction.md")).unwrap();
        assert!(page.starts_with("# Reproducing the papers' tables"));
        assert!(page.contains("## `mfnet-tab3`") && page.contains("#### mfnet-tab3 table"));
        assert!(
            !page.contains("rtfnet-tab4 table"),
            "smoke results stay out"
        );
    }

    #[test]
    fn list_names_every_table_of_the_issue() {
        let ids: Vec<&str> = list().iter().map(|(id, _)| *id).collect();
        for id in [
            "mfnet-tab2",
            "mfnet-tab3",
            "mfnet-tab4",
            "rtfnet-tab3",
            "rtfnet-fig3",
            "rtfnet-tab4",
            "rtfnet-tab5",
            "rtfnet-tab6",
            "rtfnet-tab7",
            "heatnet-tab1",
            "heatnet-tab2",
        ] {
            assert!(ids.contains(&id), "{id}");
        }
        assert!(usage().contains("all"));
    }

    /// CMX's paper budget needs the `cmx-mf` recipe: without it its cells are not measured
    /// (under `all`) or the table stops (alone); the dry run still shows the commands, marked.
    /// The CPU budgets need no recipe.
    #[test]
    fn cmx_paper_cells_need_the_recipe_and_the_dry_run_shows_their_commands() {
        let selected: Vec<Table> = tables::all(false)
            .into_iter()
            .filter(|t| t.id == "cmx-mf")
            .collect();
        let none = BTreeMap::new();
        let (jobs, missing) = plan(&selected, &none, Budget::Paper, 1, None);
        assert!(jobs.is_empty());
        assert_eq!(missing.len(), 2);
        assert!(missing.iter().all(|(_, m)| m.reason.contains("`cmx-mf`")));
        let listed = BTreeMap::from([("cmx-mf".to_string(), Value::Null)]);
        assert_eq!(plan(&selected, &listed, Budget::Paper, 2, None).0.len(), 4);
        assert_eq!(plan(&selected, &none, Budget::Quick, 2, None).0.len(), 4);
        let o = parse(&args(&["cmx-mf", "--budget", "paper", "--dry-run"])).unwrap();
        assert!(o.dry_run);
        let err = check_recipes(&o, &selected, &none).unwrap_err().to_string();
        assert!(
            err.contains("cmx-mf") && err.contains("budget paper"),
            "{err}"
        );
        check_recipes(&o, &selected, &listed).unwrap();

        let tmp = tempfile::tempdir().unwrap();
        let text = dry_run(tmp.path(), &o, &selected).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 2 * 4, "{text}");
        assert!(lines[1].contains("needs the recipe `cmx-mf`"), "{text}");
        assert!(
            lines[2].starts_with("rtf train --data ")
                && lines[2].contains("mf-paper-1569-640x480")
                && lines[2].contains(
                    "cmx-mf/cmx-mit-b2/seed0 --model cmx-mit-b2 --recipe cmx-mf --seed 0"
                ),
            "{text}"
        );
        assert!(
            lines[3].starts_with("rtf eval --model cmx-mit-b2 --weights ")
                && lines[3].contains("cmx-mit-b2/seed0/best.safetensors")
                && lines[3].contains("--split test"),
            "{text}"
        );
        assert!(
            lines[6].contains("--model cmx-mit-b4 --recipe cmx-mf"),
            "{text}"
        );
        assert!(
            !tmp.path().join("results").exists(),
            "a dry run writes nothing"
        );
        // --mit-weights: each CMX cell starts from its own size's ImageNet MiT weights.
        let mit = tmp.path().join("mit");
        std::fs::create_dir_all(&mit).unwrap();
        std::fs::write(mit.join("mit_b2.safetensors"), "x").unwrap();
        let mut o = o;
        o.mit_weights = Some(mit.clone());
        let err = check_inputs(&o, &selected).unwrap_err().to_string();
        assert!(
            err.contains("mit_b4.safetensors") && err.contains("cmx-mit-b4"),
            "{err}"
        );
        std::fs::write(mit.join("mit_b4.safetensors"), "x").unwrap();
        check_inputs(&o, &selected).unwrap();
        let text = dry_run(tmp.path(), &o, &selected).unwrap();
        let b4 = format!(
            "--backbone-weights {}",
            mit.join("mit_b4.safetensors").display()
        );
        assert!(text.contains(&b4), "{text}");
        // The quick budget: the stand-ins, no recipe.
        let q = parse(&args(&["cmx-mf", "--dry-run", "--seeds", "2"])).unwrap();
        let text = dry_run(tmp.path(), &q, &selected).unwrap();
        assert_eq!(text.matches("rtf train ").count(), 4, "{text}");
        assert_eq!(
            text.matches("--model cmx-mit-b1 --epochs").count(),
            2,
            "{text}"
        );
        assert!(
            !text.contains("--recipe") && !text.contains("needs the recipe"),
            "{text}"
        );
    }
}
