//! The bf16 probe through the binary (project issue 41): where the CPU has bf16 arithmetic,
//! `--precision bf16` times bf16 against fp32 once, caches the times in `$RTF_CACHE_DIR`, and
//! warns with them when bf16 measured slower. Which way the measurement goes depends on the
//! CPU, so the test edits the cached times to make each outcome decisive on every kind; where
//! bf16 is emulated, the emulation warning is given and nothing is probed. The same holds for
//! the measurement that picks bf16's 3×3 kernels.

mod common;
use common::*;
use std::path::Path;
use std::process::{Command, Output};

const SLOWER: &str = "bf16 measured slower than fp32 on this CPU";

fn bench_bf16_with(cache: &Path, vars: &[(&str, &str)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rtf"))
        .args(["bench", "model", "--model", "mfnet", "--precision", "bf16"])
        .args([
            "--size",
            "32x32",
            "--warmup",
            "0",
            "--iterations",
            "1",
            "--json",
        ])
        .env("RTF_CACHE_DIR", cache)
        .env_remove(WINOGRAD_VAR)
        .envs(vars.iter().copied())
        .output()
        .expect("rtf runs")
}

fn bench_bf16(cache: &Path) -> Output {
    let out = bench_bf16_with(cache, &[]);
    assert!(out.status.success(), "{}", text(&out));
    out
}

const WINOGRAD_VAR: &str = "RTF_BF16_WINOGRAD";

/// The report's `bf16_3x3`: which kernels the wide 3×3 convolutions took.
fn kernels(out: &Output) -> String {
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON report");
    report["bf16_3x3"].as_str().unwrap_or("none").to_string()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Sets the bf16 time of every cached measurement whose key starts with `work` to `factor` ×
/// its fp32 time.
fn edit_cache(path: &Path, work: &str, factor: f64) {
    let mut cache: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    for (key, m) in cache["measurements"].as_object_mut().unwrap() {
        if key.starts_with(work) {
            let fp32 = m["fp32_s"].as_f64().unwrap();
            m["bf16_s"] = serde_json::json!(fp32 * factor);
        }
    }
    std::fs::write(path, serde_json::to_string(&cache).unwrap()).unwrap();
}

/// A fresh cache folder, its probe file's path, and a first bf16 run that fills it.
fn first_bf16_run(tmp: &Path) -> (std::path::PathBuf, std::path::PathBuf, Output) {
    let cache = tmp.join("cache");
    let file = cache.join("bf16-probe.json");
    let first = bench_bf16(&cache);
    (cache, file, first)
}

#[test]
fn bf16_is_measured_once_cached_and_a_slower_bf16_is_said_with_its_times() {
    let tmp = tempfile::tempdir().unwrap();
    let (cache, file, first) = first_bf16_run(tmp.path());
    if bf16_arithmetic().is_native() != Some(true) {
        assert!(
            stderr(&first).contains("bf16 is emulated"),
            "{}",
            text(&first)
        );
        assert!(!file.exists(), "no probe where bf16 is emulated");
        return;
    }
    let text0 = std::fs::read_to_string(&file).expect("the probe's cache is written");
    assert!(
        text0.contains("inference | ") && text0.contains("libtorch "),
        "{text0}"
    );

    // Read back, not measured again: the edited times are the ones reported.
    edit_cache(&file, "inference | ", 2.0);
    let line = stderr(&bench_bf16(&cache));
    assert!(
        line.contains(SLOWER) && line.contains("(0.50x fp32's speed"),
        "{line}"
    );
    assert!(
        line.contains(&format!("cached in {}", file.display())),
        "{line}"
    );
    assert_eq!(
        line.lines().filter(|l| l.starts_with("warning:")).count(),
        1,
        "{line}"
    );

    edit_cache(&file, "inference | ", 0.5);
    let line = stderr(&bench_bf16(&cache));
    assert!(!line.contains(SLOWER), "{line}");

    // A broken cache costs a measurement, never the run, and is written anew.
    std::fs::write(&file, "{ not json").unwrap();
    bench_bf16(&cache);
    let fresh: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    let keys: Vec<&String> = fresh["measurements"].as_object().unwrap().keys().collect();
    assert_eq!(
        keys.len(),
        2,
        "the 3x3 kernels' and the inference measurement: {keys:?}"
    );
}

/// bf16 inference's wide 3×3 convolutions take the Winograd form (fp32 arithmetic over bf16
/// maps) or oneDNN's bf16 kernels as the cached measurement of the two says (edited here to
/// decide each way on every CPU), `RTF_BF16_WINOGRAD=on|off` overrides it, and any other value
/// is refused naming the variable. Where bf16 is emulated, the Winograd form without a probe.
#[test]
fn the_bf16_3x3_kernels_follow_the_measurement_and_the_variable() {
    let tmp = tempfile::tempdir().unwrap();
    let (cache, file, first) = first_bf16_run(tmp.path());
    if bf16_arithmetic().is_native() != Some(true) {
        assert_eq!(kernels(&first), "winograd", "{}", text(&first));
        assert!(!file.exists(), "no probe where bf16 is emulated");
    } else {
        let written = std::fs::read_to_string(&file).expect("the probe's cache is written");
        assert!(written.contains("conv3x3 | "), "{written}");
        // Measured as "bf16" slower: the fp32-arithmetic Winograd form runs.
        edit_cache(&file, "conv3x3 | ", 2.0);
        assert_eq!(kernels(&bench_bf16(&cache)), "winograd");
        edit_cache(&file, "conv3x3 | ", 0.5);
        assert_eq!(kernels(&bench_bf16(&cache)), "onednn");
        // A narrow win of the Winograd form on the probe's layer is not enough.
        edit_cache(&file, "conv3x3 | ", 1.1);
        assert_eq!(kernels(&bench_bf16(&cache)), "onednn");
    }
    for (value, expected) in [("on", "winograd"), ("off", "onednn")] {
        let out = bench_bf16_with(&cache, &[(WINOGRAD_VAR, value)]);
        assert!(out.status.success(), "{}", text(&out));
        assert_eq!(kernels(&out), expected, "{WINOGRAD_VAR}={value}");
    }
    let out = bench_bf16_with(&cache, &[(WINOGRAD_VAR, "maybe")]);
    assert!(!out.status.success());
    let said = stderr(&out);
    assert!(
        said.contains("RTF_BF16_WINOGRAD=\"maybe\": expected on or off"),
        "{said}"
    );
}

/// `rtf bench model --json` records how its bf16 folds computed their convolutions: emulated
/// where the CPU has no bf16 arithmetic or `RTF_BF16_CONVOLUTIONS=emulated` says so, else on
/// oneDNN's kernels; with the kernels it took.
#[test]
fn the_bench_report_records_its_bf16_convolutions() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let report = |vars: &[(&str, &str)]| -> serde_json::Value {
        let out = bench_bf16_with(&cache, vars);
        assert!(out.status.success(), "{}", text(&out));
        serde_json::from_slice(&out.stdout).expect("JSON report")
    };
    let asked = [("RTF_BF16_CONVOLUTIONS", "emulated"), (WINOGRAD_VAR, "off")];
    let emulated = report(&asked);
    assert_eq!(emulated["bf16_convolutions"], "emulated", "{emulated}");
    assert_eq!(emulated["kernels"]["bf16_winograd"], false, "{emulated}");
    let native = report(&[("RTF_BF16_CONVOLUTIONS", "native"), (WINOGRAD_VAR, "off")]);
    assert_eq!(native["bf16_convolutions"], "native", "{native}");
}

#[test]
fn fp32_never_probes() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let out = Command::new(env!("CARGO_BIN_EXE_rtf"))
        .args(["bench", "model", "--model", "mfnet", "--size", "32x32"])
        .args(["--warmup", "0", "--iterations", "1"])
        .env("RTF_CACHE_DIR", &cache)
        .output()
        .expect("rtf runs");
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        !cache.exists() && !stderr(&out).contains("warning:"),
        "{}",
        text(&out)
    );
}

/// bf16 training's convolution kernels (issue 41): where bf16 is native, a new run takes
/// mixed (spatial convolutions on fp32 kernels) or native as the cached `conv3x3-training`
/// measurement says (edited here to decide each way on every CPU) and records the choice in its
/// config.json; a resume keeps the record whatever the measurement says now, and the variable
/// overrides it with a warning. Where bf16 is emulated nothing is probed and emulated is
/// recorded.
#[test]
fn bf16_training_records_the_measured_kernels_and_a_resume_keeps_them() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    synth_mf(&data, "6", "0", "32x32");
    let cache = tmp.path().join("cache");
    let file = cache.join("bf16-probe.json");
    let train = |args: &[&str], vars: &[(&str, &str)]| {
        let out = Command::new(env!("CARGO_BIN_EXE_rtf"))
            .args(args)
            .env("RTF_CACHE_DIR", &cache)
            .env_remove("RTF_BF16_CONVOLUTIONS")
            .envs(vars.iter().copied())
            .output()
            .expect("rtf runs");
        assert!(out.status.success(), "{}", text(&out));
        out
    };
    let new_run = |name: &str| {
        let run = tmp.path().join(name);
        let out = train(
            &short_train(&data, &run, "1", &["--precision", "bf16"]),
            &[],
        );
        (run, stderr(&out))
    };
    let recorded = |run: &Path| {
        json_file(&run.join("config.json"))["compute"]["bf16_convolutions"]
            .as_str()
            .unwrap_or("none")
            .to_string()
    };
    let (first, _) = new_run("first");
    if bf16_arithmetic().is_native() != Some(true) {
        assert_eq!(recorded(&first), "emulated");
        assert!(!file.exists(), "no probe where bf16 is emulated");
        return;
    }
    let written = std::fs::read_to_string(&file).expect("the probe's cache is written");
    assert!(written.contains("conv3x3-training | "), "{written}");

    edit_cache(&file, "conv3x3-training | ", 2.0);
    let (mixed, said) = new_run("mixed");
    assert_eq!(recorded(&mixed), "mixed");
    assert!(said.contains("(RTF_BF16_CONVOLUTIONS=mixed)"), "{said}");
    edit_cache(&file, "conv3x3-training | ", 0.5);
    let (native, said) = new_run("native");
    assert_eq!(recorded(&native), "native");
    assert!(!said.contains("on fp32 kernels"), "{said}");

    // The resume keeps the run's kernels though the measurement now says native ...
    let resume = ["train", "--resume", s(&mixed), "--epochs", "2"];
    let said = stderr(&train(&resume, &[]));
    assert!(
        said.contains("as the run started (compute.bf16_convolutions: mixed"),
        "{said}"
    );
    assert_eq!(recorded(&mixed), "mixed");
    // ... and the variable overrides the record, saying what that costs.
    let resume = ["train", "--resume", s(&mixed), "--epochs", "3"];
    let said = stderr(&train(&resume, &[("RTF_BF16_CONVOLUTIONS", "native")]));
    assert!(
        said.contains("warning: the run started with mixed bf16 convolutions")
            && said.contains("RTF_BF16_CONVOLUTIONS is set"),
        "{said}"
    );
}
