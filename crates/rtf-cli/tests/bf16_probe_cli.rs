//! The bf16 probe through the binary (project issue 41): where the CPU has bf16 arithmetic,
//! `--precision bf16` times bf16 against fp32 once, caches the times in `$RTF_CACHE_DIR`, and
//! warns with them when bf16 measured slower. Which way the measurement goes depends on the
//! CPU, so the test edits the cached times to make each outcome decisive on every kind; where
//! bf16 is emulated, the emulation warning is given and nothing is probed.

mod common;
use common::*;
use std::path::Path;
use std::process::{Command, Output};

const SLOWER: &str = "bf16 measured slower than fp32 on this CPU";

fn bench_bf16(cache: &Path) -> Output {
    let out = Command::new(env!("CARGO_BIN_EXE_rtf"))
        .args(["bench", "model", "--model", "mfnet", "--precision", "bf16"])
        .args(["--size", "32x32", "--warmup", "0", "--iterations", "1"])
        .env("RTF_CACHE_DIR", cache)
        .output()
        .expect("rtf runs");
    assert!(out.status.success(), "{}", text(&out));
    out
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Sets every cached measurement's bf16 time to `factor` × its fp32 time.
fn edit_cache(path: &Path, factor: f64) {
    let mut cache: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    for m in cache["measurements"].as_object_mut().unwrap().values_mut() {
        let fp32 = m["fp32_s"].as_f64().unwrap();
        m["bf16_s"] = serde_json::json!(fp32 * factor);
    }
    std::fs::write(path, serde_json::to_string(&cache).unwrap()).unwrap();
}

#[test]
fn bf16_is_measured_once_cached_and_a_slower_bf16_is_said_with_its_times() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let file = cache.join("bf16-probe.json");
    let first = bench_bf16(&cache);
    if rtf_amp::cpu_bf16_arithmetic().is_native() != Some(true) {
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
    edit_cache(&file, 2.0);
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

    edit_cache(&file, 0.5);
    let line = stderr(&bench_bf16(&cache));
    assert!(!line.contains(SLOWER), "{line}");

    // A broken cache costs a measurement, never the run, and is written anew.
    std::fs::write(&file, "{ not json").unwrap();
    bench_bf16(&cache);
    let fresh: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    assert_eq!(fresh["measurements"].as_object().unwrap().len(), 1);
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
