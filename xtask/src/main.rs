//! Project tasks: `cargo xtask <task>`. A plain binary without libtorch, so it builds on a
//! fresh machine and can install libtorch itself.

mod calib_check;
mod convert;
mod disk;
mod hostile;
mod reproduce;
mod setup;
mod wheel;

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

const USAGE: &str = "usage: cargo xtask <task>

tasks:
  setup    install libtorch (PyPI torch==2.13.0) into .venv and link .libtorch (idempotent)
  test     setup, then run the whole test suite (release build), then the Python package's
           tests (wheel built and installed into .venv, pytest)
  wheel    build the Python package: target/wheels/rtf-*.whl (--python PATH: another
           interpreter with torch==2.13.0 and maturin; default .venv)
  demo     setup, build, synthesise a small RGB-T dataset, train MFNet, evaluate, draw predictions
  convert-pth IN.pth OUT.safetensors  convert a PyTorch checkpoint (published weights) for rtf
  calib-check  full-size accuracy/timing run of `rtf calibrate` on real-imagery and synthetic rigs with ground truth
  reproduce <table>|all  run the experiments behind a paper's table, beside the paper's numbers
           (--list: the tables; --help: options)
  hostile  replay bad inputs and interruptions (broken files, NaN weights, huge frames, kill -9
           mid-recipe, a killed DDP rank, bad dataset.yaml...) against rtf; counts
";

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let root = project_root();
    match args.first().map(String::as_str) {
        Some("setup") => setup::ensure_libtorch(&root).map(|_| ()),
        Some("test") => test(&root, &args[1..]),
        Some("wheel") => wheel::wheel(&root, &args[1..]).map(|_| ()),
        Some("demo") => demo(&root, &args[1..]),
        Some("convert-pth") => convert::convert_pth(&root, &args[1..]),
        Some("calib-check") => calib_check::calib_check(&root, &args[1..]),
        Some("hostile") => hostile::hostile(&root, &args[1..]),
        Some("reproduce") => reproduce::reproduce(&root, &args[1..]),
        Some("-h" | "--help" | "help") | None => {
            print!("{USAGE}");
            Ok(())
        }
        Some(other) => bail!("unknown task `{other}`\n\n{USAGE}"),
    }
}

/// The repository root (xtask lives one level below it).
fn project_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask has a parent")
        .to_path_buf()
}

/// Runs the release `rtf` binary to the end and returns what it printed and its status.
fn rtf_output<S: AsRef<str>>(root: &Path, args: &[S]) -> Result<std::process::Output> {
    let args: Vec<&str> = args.iter().map(AsRef::as_ref).collect();
    Command::new(root.join("target/release/rtf"))
        .args(&args)
        .current_dir(root)
        .output()
        .context("cannot start target/release/rtf")
}

/// Runs the release `rtf` binary and returns its stdout, failing with its stderr.
fn rtf_stdout<S: AsRef<str>>(root: &Path, args: &[S]) -> Result<String> {
    let args: Vec<&str> = args.iter().map(AsRef::as_ref).collect();
    let output = rtf_output(root, &args)?;
    if !output.status.success() {
        bail!(
            "`rtf {}` failed:\n{}",
            args.join(" "),
            String::from_utf8_lossy(&output.stderr)
        );
    }
    Ok(String::from_utf8_lossy(&output.stdout).into_owned())
}

/// Runs a command in the project root, failing with the command line if it fails.
fn run(root: &Path, program: &str, args: &[&str]) -> Result<()> {
    let status = Command::new(program)
        .args(args)
        .current_dir(root)
        .status()
        .with_context(|| format!("cannot start `{program}`"))?;
    if !status.success() {
        bail!("`{program} {}` failed ({status})", args.join(" "));
    }
    Ok(())
}

fn test(root: &Path, extra: &[String]) -> Result<()> {
    setup::ensure_libtorch(root)?;
    // rtf-py (the Python extension) is left out: its python-extension features of tch would
    // be unified into every test binary, which would then need libpython; its tests are the
    // pytest pass below.
    let mut args = vec!["test", "--workspace", "--exclude", "rtf-py", "--release"];
    args.extend(extra.iter().map(String::as_str));
    // The ONNX export check (PyTorch exporter + onnxruntime, which `setup` installs) runs in
    // the whole suite; a plain `cargo test` skips it (about 40 s).
    if std::env::var_os("RTF_TEST_ONNX").is_none() {
        std::env::set_var("RTF_TEST_ONNX", "1");
    }
    disk::note(root, "the build and the tests", 0);
    run(root, "cargo", &args)?;
    // Skipped when the suite is filtered: the mixed-precision tests (synthetic and real
    // frames) once more with each CPU bf16 convolution choice (emulated where the CPU lacks
    // bf16 arithmetic, else native or, for training where measured faster, mixed; the main
    // run covered one; the tests read the variable, as rtf's binaries do, and pass the choice
    // into the run), so all three are trained, stopped, resumed and checked
    // on real imagery wherever the suite runs; and issue 11's smoke reproduction: every table's
    // pipeline end to end on a tiny budget (files and JSON schema are checked; no number is
    // asserted).
    if extra.is_empty() {
        for choice in ["emulated", "native", "mixed"] {
            let status = Command::new("cargo")
                .args([
                    "test",
                    "--release",
                    "-p",
                    "rtf-train",
                    "--test",
                    "mixed_precision",
                    "--test",
                    "real_frames_bf16",
                ])
                .env("RTF_BF16_CONVOLUTIONS", choice)
                .current_dir(root)
                .status()
                .context("cannot start `cargo`")?;
            if !status.success() {
                bail!("the mixed-precision tests with RTF_BF16_CONVOLUTIONS={choice} failed ({status})");
            }
        }
        emulated_kind_passes(root)?;
        disk::note(root, "the smoke reproduction", disk::SMOKE_PEAK);
        reproduce::smoke(root)?;
        disk::note(root, "the Python package's tests", 0);
        wheel::pytest(root)?;
    }
    Ok(())
}

/// A CPU kind this machine stands in for by capping the instruction sets that libtorch
/// (`ATEN_CPU_CAPABILITY`), oneDNN (`ONEDNN_MAX_CPU_ISA`) and MKL (`MKL_ENABLE_INSTRUCTIONS`)
/// dispatch to. Caps only go down, so each kind is emulated on the CPUs above it.
struct EmulatedKind {
    name: &'static str,
    /// `/proc/cpuinfo` flags, any of which makes the caps change this CPU's kernels.
    above_if_any: &'static [&'static str],
    caps: &'static [(&'static str, &'static str)],
    /// What a machine of this kind decides where rtf measures or reads its flags (issue 57):
    /// the caps change the kernels, not the flags the decisions read nor what a probe measures,
    /// so each outcome the kind can reach is forced. The first runs every kernel-dependent
    /// test, the others the tests whose code the decision changes ([`DECISION_DEPENDENT`]).
    outcomes: &'static [Outcome],
}

/// One outcome of the machine-dependent decisions, forced by the variables that override them.
struct Outcome {
    name: &'static str,
    env: &'static [(&'static str, &'static str)],
}

/// The kinds developers and CI run on (issues 33, 44 and 57): AMD AVX2-only; AMD AVX-512 with
/// bf16; Intel AVX-512 with bf16/fp16, with AMX usable on some. MKL takes its AVX-512 paths on
/// Intel only: issue 44's hostile calibration case ended `failed` there and `ok` on AMD, and
/// capping MKL alone at AVX2 turned it to `uncertain` on an Intel machine; the cap gives an
/// Intel machine a non-AVX-512 MKL path, as on AMD.
const EMULATED_KINDS: [EmulatedKind; 2] = [
    EmulatedKind {
        name: "AVX2 only (libtorch, oneDNN and MKL capped at AVX2)",
        above_if_any: &["avx512f"],
        caps: &[
            ("ATEN_CPU_CAPABILITY", "avx2"),
            ("ONEDNN_MAX_CPU_ISA", "AVX2"),
            ("MKL_ENABLE_INSTRUCTIONS", "AVX2"),
        ],
        // Without bf16 arithmetic nothing is probed; fp32 training stays NCHW without avx512f.
        outcomes: &[Outcome {
            name: "bf16 convolutions emulated, bf16 3x3 in Winograd form, fp32 training NCHW",
            env: &[
                ("RTF_BF16_CONVOLUTIONS", "emulated"),
                ("RTF_BF16_WINOGRAD", "on"),
                ("RTF_TRAIN_LAYOUT", "nchw"),
            ],
        }],
    },
    EmulatedKind {
        name: "AVX-512 with bf16, without AMX or AVX-512 fp16 (oneDNN capped at AVX512_CORE_BF16)",
        above_if_any: &["amx_bf16", "amx_tile", "avx512_fp16"],
        caps: &[("ONEDNN_MAX_CPU_ISA", "AVX512_CORE_BF16")],
        // The probes' two outcomes on such CPUs: Intel family 6 model 207 measured fp32 kernels
        // faster for bf16 3x3 convolutions (issue 57), Zen 4 measured oneDNN's bf16 faster.
        outcomes: &[
            Outcome {
                name:
                    "bf16 convolutions mixed, bf16 3x3 in Winograd form (Intel model 207's probe)",
                env: &[
                    ("RTF_BF16_CONVOLUTIONS", "mixed"),
                    ("RTF_BF16_WINOGRAD", "on"),
                ],
            },
            Outcome {
                name: "bf16 convolutions native, bf16 3x3 on oneDNN (Zen 4's probe)",
                env: &[
                    ("RTF_BF16_CONVOLUTIONS", "native"),
                    ("RTF_BF16_WINOGRAD", "off"),
                ],
            },
        ],
    },
];

/// The tests whose code a forced outcome changes: bf16 folds and training (the whole networks'
/// fused paths, the bf16 units), training in both layouts.
const DECISION_DEPENDENT: [&[&str]; 2] = [
    &[
        "-p",
        "rtf-models",
        "--lib",
        "--",
        "bf16",
        "fused",
        "released_networks",
    ],
    &[
        "-p",
        "rtf-train",
        "--lib",
        "--test",
        "mixed_precision",
        "--test",
        "real_frames_bf16",
    ],
];

/// The tests whose outcome depends on the CPU's kernels: numbers compared with a tolerance,
/// decisions taken on computed figures (calibration verdicts, training that must learn).
const KERNEL_DEPENDENT: [&[&str]; 4] = [
    &[
        "-p",
        "rtf-kernels",
        "-p",
        "rtf-models",
        "-p",
        "rtf-amp",
        "-p",
        "rtf-train",
        "-p",
        "rtf-calib",
        "--lib",
    ],
    &[
        "-p",
        "rtf-models",
        "--test",
        "torch_parity",
        "--test",
        "cmx_parity",
    ],
    &[
        "-p",
        "rtf-train",
        "--test",
        "procedures",
        "--test",
        "resume",
        "--test",
        "mixed_precision",
        "--test",
        "real_frames_bf16",
    ],
    &[
        "-p",
        "rtf-cli",
        "--test",
        "calibrate_cli",
        "--test",
        "train_parity",
        "--test",
        "hostile",
        // CMX's step parity (about a minute) runs in the main pass only: its 1 % line is far
        // above what the kernels change, and the suite keeps to its 30-minute budget.
        "--",
        "--skip",
        "cmx_trains_by_the_official_recipe",
    ],
];

/// The kernel-dependent tests once more for every kind this CPU can emulate (see
/// [`EMULATED_KINDS`]), so a suite run on one kind of machine also covers the kinds below it
/// (issue 33: a tolerance tuned on AVX-512 kernels failed on AVX2 ones; issue 44: a verdict
/// that turned on MKL's Intel paths). The hostile catalogue runs its calibration cases only.
fn emulated_kind_passes(root: &Path) -> Result<()> {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let flags: Vec<&str> = cpuinfo
        .lines()
        .find(|line| line.starts_with("flags"))
        .map(|line| line.split_whitespace().collect())
        .unwrap_or_default();
    for kind in &EMULATED_KINDS {
        if !kind.above_if_any.iter().any(|flag| flags.contains(flag)) {
            continue;
        }
        for (i, outcome) in kind.outcomes.iter().enumerate() {
            println!(
                "xtask test: the kernel-dependent tests once more as on {}, {}",
                kind.name, outcome.name
            );
            let selections: &[&[&str]] = match i {
                0 => &KERNEL_DEPENDENT,
                _ => &DECISION_DEPENDENT,
            };
            for selection in selections {
                let status = Command::new("cargo")
                    .args(["test", "--release"])
                    .args(*selection)
                    .envs(kind.caps.iter().copied())
                    .envs(outcome.env.iter().copied())
                    .env("RTF_HOSTILE_ONLY", "calib")
                    .current_dir(root)
                    .status()
                    .context("cannot start `cargo`")?;
                if !status.success() {
                    bail!(
                        "the kernel-dependent tests as on {}, {}, failed ({status})",
                        kind.name,
                        outcome.name
                    );
                }
            }
        }
    }
    Ok(())
}

/// The demo's dataset and schedule: sized to train in a few minutes on 2 CPU cores.
const DEMO_FRAMES: &str = "240";
const DEMO_SIZE: &str = "160x128";
const DEMO_EPOCHS: &str = "40";

fn demo(root: &Path, extra: &[String]) -> Result<()> {
    setup::ensure_libtorch(root)?;
    run(root, "cargo", &["build", "--release", "-p", "rtf-cli"])?;
    let rtf_path = root.join("target/release/rtf");
    let rtf = rtf_path.to_str().context("non-UTF-8 path")?;
    let out = root.join("demo");
    if out.exists() {
        println!("demo: replacing the previous demo/ folder");
        std::fs::remove_dir_all(&out)
            .with_context(|| format!("cannot remove {}", out.display()))?;
    }
    let step = |args: &[&str]| -> Result<()> {
        println!("\n$ rtf {}", args.join(" "));
        run(root, rtf, args)
    };
    step(&[
        "synth",
        "--out",
        "demo/data",
        "--count",
        DEMO_FRAMES,
        "--seed",
        "0",
        "--size",
        DEMO_SIZE,
    ])?;
    let mut train = vec![
        "train",
        "--model",
        "mfnet",
        "--data",
        "demo/data",
        "--out",
        "demo/run",
    ];
    train.extend([
        "--epochs",
        DEMO_EPOCHS,
        "--batch-size",
        "6",
        "--lr-decay",
        "0.94",
    ]);
    train.extend(extra.iter().map(String::as_str));
    step(&train)?;
    let weights = "demo/run/final.safetensors";
    step(&[
        "eval",
        "--model",
        "mfnet",
        "--weights",
        weights,
        "--data",
        "demo/data",
        "--split",
        "test",
        "--json",
        "demo/eval_test.json",
        "--figure",
        "demo/predictions.png",
        "--figure-frames",
        "6",
    ])?;
    let images = demo_test_images(&out, 4)?;
    let mut predict = vec![
        "predict",
        "--model",
        "mfnet",
        "--weights",
        weights,
        "--out",
        "demo/predict",
    ];
    predict.extend(images.iter().map(String::as_str));
    step(&predict)?;
    println!("\ndemo: scores in demo/eval_test.json, prediction grid in demo/predictions.png, run in demo/run");
    Ok(())
}

/// The image paths (relative to the root) of the first `count` test frames of the demo data.
fn demo_test_images(out: &Path, count: usize) -> Result<Vec<String>> {
    let split =
        std::fs::read_to_string(out.join("data/test.txt")).context("reading demo/data/test.txt")?;
    Ok(split
        .lines()
        .take(count)
        .map(|n| format!("demo/data/images/{}.png", n.trim()))
        .collect())
}
