//! The one-line warning before bf16 work on a CPU without bf16 arithmetic (project issue 31),
//! through the binary. `ONEDNN_MAX_CPU_ISA=AVX2` caps oneDNN below AVX512_CORE_BF16, so rtf
//! takes bf16 as emulated on any machine, an AVX-512 one included.

mod common;
use common::*;
use std::process::{Command, Output};

/// `rtf args` with oneDNN capped to AVX2 (and `extra` variables); requires success.
fn capped(args: &[&str], extra: &[(&str, &str)]) -> Output {
    let out = Command::new(env!("CARGO_BIN_EXE_rtf"))
        .args(args)
        .env("ONEDNN_MAX_CPU_ISA", "AVX2")
        .envs(extra.iter().copied())
        .output()
        .expect("rtf runs");
    assert!(out.status.success(), "rtf {args:?} failed:\n{}", text(&out));
    out
}

/// The stderr lines that warn of emulated bf16.
fn warnings(out: &Output) -> Vec<String> {
    String::from_utf8_lossy(&out.stderr)
        .lines()
        .filter(|l| l.contains("bf16 is emulated on this CPU"))
        .map(String::from)
        .collect()
}

/// Exactly one warning line, naming the cap and the way out; returns it.
fn one_warning(out: &Output) -> String {
    let lines = warnings(out);
    assert_eq!(lines.len(), 1, "{}", text(out));
    let line = &lines[0];
    assert!(line.starts_with("warning: "), "{line}");
    assert!(line.contains("ONEDNN_MAX_CPU_ISA=AVX2"), "{line}");
    assert!(line.ends_with("use --precision fp32"), "{line}");
    line.clone()
}

#[test]
fn bf16_under_an_avx2_cap_warns_once_in_every_command_and_fp32_never() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, run) = (tmp.path().join("data"), tmp.path().join("run"));
    synth_mf(&data, "6", "0", "32x32");

    // Training: rtf's emulated convolutions, its cost in training terms.
    let out = capped(
        &short_train(&data, &run, "1", &["--precision", "bf16"]),
        &[],
    );
    assert!(one_warning(&out).contains("bf16 step is slower than fp32"));
    assert_eq!(
        json_file(&run.join("config.json"))["learning"]["precision"],
        "bf16"
    );
    let weights = run.join("final.safetensors");
    let bench_train = |precision| {
        let mut a = vec!["bench", "train", "--model", "mfnet", "--batch", "1"];
        a.extend(["--size", "32x32", "--warmup", "0", "--steps", "1"]);
        a.extend(["--precision", precision, "--json"]);
        a
    };
    one_warning(&capped(&bench_train("bf16"), &[]));
    assert!(warnings(&capped(&bench_train("fp32"), &[])).is_empty());

    // Inference: the fast path's bf16, the measured inference cost.
    let eval = |precision| {
        let mut a = vec!["eval", "--model", "mfnet", "--weights", s(&weights)];
        a.extend([
            "--data",
            s(&data),
            "--split",
            "test",
            "--precision",
            precision,
        ]);
        a
    };
    assert!(one_warning(&capped(&eval("bf16"), &[])).contains("bf16 inference on fp32 kernels"));
    assert!(warnings(&capped(&eval("fp32"), &[])).is_empty());
    let test_names = std::fs::read_to_string(data.join("test.txt")).unwrap();
    let name = test_names.lines().next().unwrap().trim().to_string();
    let image = data.join("images").join(format!("{name}.png"));
    let pred = tmp.path().join("pred");
    let mut predict = vec!["predict", "--model", "mfnet", "--weights", s(&weights)];
    predict.extend(["--out", s(&pred), "--precision", "bf16", s(&image)]);
    one_warning(&capped(&predict, &[]));
    let bench_model = |precision| {
        let mut a = vec!["bench", "model", "--model", "mfnet", "--size", "32x32"];
        a.extend([
            "--warmup",
            "0",
            "--iterations",
            "1",
            "--precision",
            precision,
        ]);
        a
    };
    one_warning(&capped(&bench_model("bf16"), &[]));
    assert!(warnings(&capped(&bench_model("fp32"), &[])).is_empty());
}

#[test]
fn libtorchs_generic_bf16_convolutions_on_such_a_cpu_keep_their_own_single_warning() {
    // RTF_BF16_CONVOLUTIONS=native where bf16 is not native: rtf-train's warning, not both.
    let out = capped(
        &[
            "bench",
            "train",
            "--model",
            "mfnet",
            "--batch",
            "1",
            "--size",
            "32x32",
            "--warmup",
            "0",
            "--steps",
            "1",
            "--precision",
            "bf16",
            "--json",
        ],
        &[("RTF_BF16_CONVOLUTIONS", "native")],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = stderr
        .lines()
        .filter(|l| l.starts_with("warning:"))
        .collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    assert!(
        lines[0].contains("RTF_BF16_CONVOLUTIONS=native"),
        "{stderr}"
    );
}
