//! Whether bf16 pays on this CPU where it has bf16 arithmetic, measured once (project issue 41).
//!
//! bf16 instructions do not make bf16 fast everywhere. On an Intel AVX-512 CPU without AMX
//! (oneDNN's `avx512_core_bf16` / `avx10_1_512` kernels), measured on family 6 model 167 with
//! AMX capped off by `ONEDNN_MAX_CPU_ISA`, rtf's bf16 inference ran at 0.72× (MFNet) and 0.54×
//! (RTFNet-50) of its fp32 speed, and PyTorch's bf16 autocast was slower than its fp32 too: the
//! bf16 dot-product instruction there has the throughput of the fp32 FMAs it replaces, so bf16
//! saves memory traffic only and pays for conversions and reorders (the wide 3×3 layers now
//! take fp32 Winograd over bf16 maps there, below, which left RTFNet-50 at 0.86× its fp32).
//! With AMX on the same CPU bf16 ran 2.7× and 4.4× faster
//! than fp32; on AMD Zen 4 with `avx512_bf16` 1.6–1.9× (docs/src/benchmarks.md).
//!
//! So where bf16 is native, `--precision bf16` on the CPU times a small fixed workload once in
//! each precision — MFNet at 320×240: the fast path's forward for inference, a training step
//! (batch 2) for training — and caches the result per CPU model, oneDNN/libtorch/MKL caps,
//! libtorch build, revision of rtf's Winograd forms and thread count in `$RTF_CACHE_DIR`
//! (default `$XDG_CACHE_HOME/rtf`, else `~/.cache/rtf`), `bf16-probe.json`. The probe runs in
//! a child process (about a second for inference, a few for training), so the command's own
//! memory peak and state are untouched. Where bf16 measured slower, the command says so on
//! stderr with the measured times before its work; the precision stays what the user typed.
//!
//! Before bf16 inference a third measurement, cached the same way, picks the kernels of the
//! wide 3×3 convolutions: the library's (`rtf_eval::kernels`, so that a library caller gets
//! the kernels `rtf predict` gets), made in this process through [`policy`] and [`probe`],
//! this binary's reading of its environment.
//!
//! Before bf16 training a fourth, [`Work::Conv3x3Training`], times such a layer's forward and
//! backward on fp32 kernels over bf16 operands against oneDNN's bf16 kernels and so picks the
//! run's convolution kernels ([`training_choice`], rtf_train::kernels).

use anyhow::{Context, Result};
use rtf_eval::kernels::probe::{Measured, Probe};
use rtf_eval::kernels::KernelPolicy;
use rtf_models::fast::InferenceKernels;
use std::path::{Path, PathBuf};

/// Which kind of work the probe times (`rtf bench bf16-probe --work inference|training|conv3x3`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Work {
    Inference,
    Training,
    /// One wide 3×3 convolution's forward and backward over bf16 operands, as training runs
    /// it: fp32 kernels (rtf's emulated convolutions) against oneDNN's bf16 kernels. Decides
    /// whether bf16 training takes [`rtf_amp::Bf16Convolutions::Mixed`]
    /// ([`training_choice`]).
    Conv3x3Training,
}

impl Work {
    fn name(self) -> &'static str {
        match self {
            Work::Inference => "inference",
            Work::Training => "training",
            Work::Conv3x3Training => "conv3x3-training",
        }
    }

    /// What was timed, for the message.
    pub fn workload(self) -> &'static str {
        match self {
            Work::Inference => "MFNet's fast-path forward at 320x240, batch 1",
            Work::Training => "an MFNet training step at 320x240, batch 2",
            Work::Conv3x3Training => {
                "a 3x3 convolution of 256 channels at 80x60, batch 2, forward and backward"
            }
        }
    }
}

/// The kernel policy of this process's environment (`RTF_WINOGRAD`, `RTF_BF16_WINOGRAD`):
/// rtf's commands read it here, at their edge, and pass it into the library.
pub fn policy() -> Result<KernelPolicy> {
    Ok(KernelPolicy::from_vars(|var| std::env::var(var).ok())?)
}

/// The cache of kernel measurements, from this process's environment
/// ([`Probe::from_vars`]: `$RTF_CACHE_DIR`, `$XDG_CACHE_HOME/rtf` or `~/.cache/rtf`).
pub fn probe() -> Probe {
    Probe::from_vars(|var| std::env::var_os(var))
}

/// What decides which kernels `work` runs besides the machine ([`Probe::key`]): for
/// [`Work::Training`], the bf16 convolutions in force (rtf_train::kernels has made the run's
/// choice by then); for [`Work::Inference`], the kernels of its wide 3×3 convolutions.
pub fn key(work: Work, inference: Option<&InferenceKernels>) -> String {
    let what = match (work, rtf_amp::cpu_bf16_convolutions(), inference) {
        (Work::Training, Ok(choice), _) => format!("training | {} convolutions", choice.name()),
        (Work::Inference, _, Some(k)) if k.bf16_winograd => "inference | winograd 3x3".into(),
        (work, ..) => work.name().to_string(),
    };
    probe().key(&what)
}

/// The cached measurement for `work` on this machine, measuring (and caching) it first in a
/// child process if there is none; inference with `inference`'s kernels.
pub fn measured(
    work: Work,
    inference: Option<&InferenceKernels>,
) -> Result<(Measured, Option<PathBuf>)> {
    probe()
        .measured(&key(work, inference), || {
            measure_in_child(work, inference).map_err(|e| format!("{e:#}"))
        })
        .map_err(anyhow::Error::msg)
}

/// [`measure`] in a child process (`rtf bench bf16-probe`), so this process's peak memory,
/// allocator, oneDNN caches and random state are what they would be without the probe. The
/// child inherits the environment and runs with this process's thread count.
fn measure_in_child(work: Work, inference: Option<&InferenceKernels>) -> Result<Measured> {
    let exe = std::env::current_exe().context("cannot find the rtf binary for the bf16 probe")?;
    let mut child = std::process::Command::new(&exe);
    child
        .args(["bench", "bf16-probe", "--work", work.name()])
        .env("OMP_NUM_THREADS", tch::get_num_threads().to_string())
        .stderr(std::process::Stdio::inherit());
    // Inference runs with this process's choice of bf16 3×3 kernels, training with its bf16
    // convolutions (the 3×3 probes set each way themselves).
    if let (Work::Training, Ok(choice)) = (work, rtf_amp::cpu_bf16_convolutions()) {
        child.env(rtf_amp::BF16_CONVOLUTIONS_VAR, choice.name());
    }
    if let (Work::Inference, Some(k)) = (work, inference) {
        let on = if k.bf16_winograd { "on" } else { "off" };
        child.env(rtf_eval::kernels::BF16_WINOGRAD_VAR, on);
    }
    let out = child
        .output()
        .with_context(|| format!("cannot start {}", exe.display()))?;
    anyhow::ensure!(
        out.status.success(),
        "the bf16 probe failed ({})",
        out.status
    );
    serde_json::from_slice(&out.stdout).context("the bf16 probe printed no measurement")
}

/// Times the work once in each precision (seconds per unit, median).
pub fn measure(work: Work) -> Result<Measured> {
    let (fp32_s, bf16_s) = match work {
        Work::Inference => (inference_s(false)?, inference_s(true)?),
        Work::Training => (training_s(false)?, training_s(true)?),
        Work::Conv3x3Training => {
            return rtf_eval::kernels::probe::measure_conv3x3_training().map_err(anyhow::Error::msg)
        }
    };
    Ok(Measured::now(fp32_s, bf16_s))
}

fn inference_s(bf16: bool) -> Result<f64> {
    use rtf_models::fast::Precision;
    // The parent passes its kernels in the environment (measure_in_child).
    let policy = policy()?;
    let kernels = InferenceKernels {
        winograd: policy.winograd,
        bf16_winograd: policy
            .bf16_winograd
            .unwrap_or_else(rtf_models::winograd::bf16_default),
        ..InferenceKernels::unmeasured()
    };
    let opts = rtf_eval::speed::BenchOptions {
        kernels,
        precision: if bf16 {
            Precision::Bf16
        } else {
            Precision::Fp32
        },
        width: 320,
        height: 240,
        warmup: 2,
        iterations: 5,
        agreement: false,
        ..Default::default()
    };
    Ok(rtf_eval::speed::bench_model(&opts)?.median_ms / 1000.0)
}

fn training_s(bf16: bool) -> Result<f64> {
    use rtf_train::config::Precision;
    let opts = rtf_train::bench::TrainBenchOptions {
        model: "mfnet".into(),
        batch: 2,
        size: (320, 240),
        precision: if bf16 {
            Precision::Bf16
        } else {
            Precision::Fp32
        },
        device: tch::Device::Cpu,
        warmup: 1,
        steps: 3,
        optimizer: rtf_train::OptimizerConfig::mfnet_paper(),
        count_ops: false,
        fp32_layout: None,
    };
    Ok(rtf_train::bench::bench_train(&opts)?.step_s)
}

/// Before bf16 training on the CPU: the run's convolution kernels chosen by the cached
/// [`Work::Conv3x3Training`] measurement (measured first, in a child process, where there is
/// none; rtf_train::kernels::choose_training_convolutions says when it decides).
pub fn training_choice() -> Option<rtf_train::kernels::Choice> {
    rtf_train::kernels::choose_training_convolutions(|| {
        measured(Work::Conv3x3Training, None).map_err(|e| format!("{e:#}"))
    })
}

/// The warning for a measurement, if bf16 measured slower than fp32.
pub fn slower_message(work: Work, m: &Measured, cache: Option<&Path>) -> Option<String> {
    (m.speedup() < 1.0).then(|| {
        let cached = cache.map_or("not cached".to_string(), |p| {
            format!("cached in {}", p.display())
        });
        format!(
            "bf16 measured slower than fp32 on this CPU: {} took {:.1} ms in bf16 against {:.1} ms \
             in fp32 ({:.2}x fp32's speed; measured once for this CPU model, libtorch and thread \
             count, {cached}); use --precision fp32",
            work.workload(),
            1000.0 * m.bf16_s,
            1000.0 * m.fp32_s,
            m.speedup()
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(fp32_s: f64, bf16_s: f64) -> Measured {
        Measured {
            fp32_s,
            bf16_s,
            unix_time: 0,
        }
    }

    #[test]
    fn only_a_slower_bf16_is_a_warning_and_it_names_the_times_and_the_cache() {
        let line = slower_message(
            Work::Inference,
            &m(0.060, 0.084),
            Some(Path::new("/c/p.json")),
        )
        .unwrap();
        assert!(
            line.contains("84.0 ms in bf16 against 60.0 ms in fp32 (0.71x"),
            "{line}"
        );
        assert!(line.contains("cached in /c/p.json") && line.ends_with("use --precision fp32"));
        assert!(!line.contains('\n'));
        let line = slower_message(Work::Training, &m(1.0, 2.0), None).unwrap();
        assert!(
            line.contains("training step") && line.contains("not cached"),
            "{line}"
        );
        assert_eq!(
            slower_message(Work::Inference, &m(0.060, 0.020), None),
            None
        );
        assert_eq!(
            slower_message(Work::Inference, &m(0.060, 0.060), None),
            None
        );
    }
}
