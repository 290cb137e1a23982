//! One line before bf16 work on a CPU where bf16 is slow (project issues 31, 41 and 61; kept in
//! the library so that `rtf eval/predict/bench model` and the Python package say the same):
//! bf16 emulated, or native but measured slower than fp32.
//!
//! Where the CPU has no bf16 instructions (no `avx512_bf16`, `amx_bf16` or Arm `bf16`, or
//! oneDNN capped below `AVX512_CORE_BF16` by `ONEDNN_MAX_CPU_ISA`: [`Bf16Arithmetic`]) every
//! bf16 product is computed by converting to fp32 and back. libtorch's and oneDNN's generic
//! bf16 kernels do that slowly, an order of magnitude or more behind fp32 (measured:
//! docs/src/benchmarks.md, section "The warning where bf16 is emulated, and no `--precision
//! auto`"). So rtf routes bf16 convolutions through fp32 kernels there
//! ([`Bf16Convolutions::Emulated`]), which keeps a native kernel's numbers (bf16 operands,
//! float sums, bf16 outputs) at fp32 kernels' speed plus the casts, in training and in
//! inference (the fast path's folds; measured: same page, same section, and section "bf16's
//! wide 3×3 convolutions in fp32 Winograd, where that is faster"). Slower than fp32 either way,
//! saving only activation memory, hence the advice; with `RTF_BF16_CONVOLUTIONS=native` the
//! generic kernels run and the warning gives their cost.
//!
//! bf16 instructions do not make bf16 fast everywhere. On an Intel AVX-512 CPU without AMX
//! (oneDNN's `avx512_core_bf16` / `avx10_1_512` kernels) rtf's bf16 inference ran slower than
//! its fp32, and PyTorch's bf16 autocast was slower than its fp32 too: the bf16 dot-product
//! instruction there has the throughput of the fp32 FMAs it replaces, so bf16 saves memory
//! traffic only and pays for conversions and reorders. With AMX on the same CPU, and on AMD
//! Zen 4 with `avx512_bf16`, bf16 ran faster than fp32 (measured: docs/src/benchmarks.md,
//! section "Native bf16 that is slower than fp32, and the probe that says so"). So where bf16
//! is native, a small fixed workload is timed once in each precision ([`Work::Inference`],
//! [`Work::Training`]) and cached ([`super::probe`]); where bf16 measured slower, the warning
//! gives the times. The caller makes the measurement (`rtf` in a child process, so its own
//! memory peak is untouched; the Python package in its own).
//!
//! No `--precision auto`: the precision stays what the user typed (default fp32), so the same
//! command gives the same numbers and weights on every machine; docs/src/benchmarks.md says why.

use std::path::{Path, PathBuf};

use rtf_amp::{Bf16Arithmetic, Bf16Convolutions};
use rtf_models::fast::Precision;
use tch::Device;

use super::probe::{Measured, Work};
use super::KernelPolicy;

/// A measurement as the probe gives it: the times and the cache file they were read from or
/// written to.
pub type Probed = Result<(Measured, Option<PathBuf>), String>;

/// The warning for inference in `precision` on `device` under `policy`, if any: bf16 emulated,
/// or native but slower than fp32 as `measured` ([`Work::Inference`] with the fold's kernels,
/// called only where bf16 is native and runs on oneDNN's kernels) found.
pub fn inference_warning(
    policy: &KernelPolicy,
    precision: Precision,
    device: Device,
    measured: impl FnOnce() -> Probed,
) -> Option<String> {
    let bf16 = precision == Precision::Bf16;
    let arithmetic = &policy.bf16.arithmetic;
    let convolutions = policy.inference_convolutions();
    inference_message(bf16, device, arithmetic, convolutions).or_else(|| {
        let native = policy.bf16.in_force(None) == Bf16Convolutions::Native;
        native_but_slower(
            bf16 && native,
            device,
            arithmetic,
            Work::Inference,
            measured,
        )
    })
}

/// Where bf16 is native on the CPU: the probe's warning if bf16 measured slower than fp32
/// there for `work`. A probe that fails is said as such (the work itself goes on).
pub fn native_but_slower(
    bf16: bool,
    device: Device,
    arithmetic: &Bf16Arithmetic,
    work: Work,
    measured: impl FnOnce() -> Probed,
) -> Option<String> {
    if !bf16 || device != Device::Cpu || arithmetic.is_native() != Some(true) {
        return None;
    }
    match measured() {
        Ok((m, cache)) => slower_message(work, &m, cache.as_deref()),
        Err(e) => Some(format!(
            "could not measure whether bf16 pays on this CPU ({e}); bf16 may be slower than fp32 here"
        )),
    }
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

fn inference_message(
    bf16: bool,
    device: Device,
    arithmetic: &Bf16Arithmetic,
    convolutions: Bf16Convolutions,
) -> Option<String> {
    if !bf16 || device != Device::Cpu {
        return None;
    }
    match convolutions {
        Bf16Convolutions::Emulated => Some(format!(
            "bf16 is emulated on this CPU ({}): rtf runs bf16 inference on fp32 kernels, a \
             little slower than fp32 (measured under AVX2 caps, batch 1, 640x480: MFNet 0.91x, \
             RTFNet-50 0.93x fp32's speed) and saving only activation memory; use --precision \
             fp32",
            emulated_because(arithmetic)
        )),
        _ if arithmetic.is_native() == Some(false) => Some(format!(
            "bf16 is emulated on this CPU ({}; {}=native): libtorch's generic bf16 kernels run \
             far slower than fp32 (measured on an AVX2 EPYC, batch 1, 640x480: MFNet ~11x, \
             RTFNet-50 ~33x); use --precision fp32",
            arithmetic.reason(),
            rtf_amp::BF16_CONVOLUTIONS_VAR
        )),
        _ => None,
    }
}

/// Why rtf emulates bf16 convolutions: the CPU's missing arithmetic, else the user's choice.
pub fn emulated_because(arithmetic: &Bf16Arithmetic) -> String {
    match arithmetic.is_native() {
        Some(false) => arithmetic.reason(),
        _ => format!("{}=emulated", rtf_amp::BF16_CONVOLUTIONS_VAR),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn capped() -> Bf16Arithmetic {
        Bf16Arithmetic::CappedBy {
            var: "ONEDNN_MAX_CPU_ISA",
            isa: "AVX2",
        }
    }

    fn m(fp32_s: f64, bf16_s: f64) -> Measured {
        Measured {
            fp32_s,
            bf16_s,
            unix_time: 0,
        }
    }

    #[test]
    fn inference_warns_where_bf16_is_emulated_with_the_cost_of_the_kernels_that_run() {
        use Bf16Convolutions::*;
        let missing = Bf16Arithmetic::MissingFromCpu;
        let line = inference_message(true, Device::Cpu, &missing, Emulated).unwrap();
        assert!(
            line.contains("no avx512_bf16")
                && line.contains("on fp32 kernels")
                && line.contains("0.93x"),
            "{line}"
        );
        assert!(line.ends_with("use --precision fp32") && !line.contains('\n'));
        let line = inference_message(true, Device::Cpu, &capped(), Emulated).unwrap();
        assert!(line.contains("ONEDNN_MAX_CPU_ISA=AVX2"), "{line}");
        // libtorch's generic kernels forced: their own cost.
        let line = inference_message(true, Device::Cpu, &capped(), Native).unwrap();
        assert!(
            line.contains("RTF_BF16_CONVOLUTIONS=native") && line.contains("~33x"),
            "{line}"
        );
        // Emulation forced on a CPU with bf16 arithmetic: said, with the variable.
        let line = inference_message(true, Device::Cpu, &Bf16Arithmetic::Native, Emulated);
        assert!(line.unwrap().contains("(RTF_BF16_CONVOLUTIONS=emulated)"));
        assert_eq!(
            inference_message(false, Device::Cpu, &capped(), Emulated),
            None
        );
        assert_eq!(
            inference_message(true, Device::Cuda(0), &capped(), Emulated),
            None
        );
        for arithmetic in [Bf16Arithmetic::Native, Bf16Arithmetic::Unknown] {
            assert_eq!(
                inference_message(true, Device::Cpu, &arithmetic, Native),
                None
            );
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

    /// Measured only where bf16 is native and on oneDNN's kernels; a failed measurement is
    /// said.
    #[test]
    fn the_probe_runs_only_where_bf16_is_native_and_a_failure_is_said() {
        let native = Bf16Arithmetic::Native;
        let never = || -> Probed { panic!("measured") };
        assert_eq!(
            native_but_slower(true, Device::Cpu, &capped(), Work::Inference, never),
            None
        );
        assert_eq!(
            native_but_slower(false, Device::Cpu, &native, Work::Inference, never),
            None
        );
        assert_eq!(
            native_but_slower(true, Device::Cuda(0), &native, Work::Inference, never),
            None
        );
        let failed = native_but_slower(true, Device::Cpu, &native, Work::Inference, || {
            Err("no rtf binary".into())
        });
        assert!(failed
            .unwrap()
            .contains("could not measure whether bf16 pays on this CPU (no rtf binary)"));
        let slower = native_but_slower(true, Device::Cpu, &native, Work::Inference, || {
            Ok((m(0.06, 0.08), None))
        });
        assert!(slower.unwrap().contains("bf16 measured slower"));
        let policy = KernelPolicy {
            bf16: rtf_amp::Bf16Policy {
                asked: Some(Bf16Convolutions::Emulated),
                arithmetic: native,
            },
            ..KernelPolicy::default()
        };
        let line = inference_warning(&policy, Precision::Bf16, Device::Cpu, never).unwrap();
        assert!(line.contains("(RTF_BF16_CONVOLUTIONS=emulated)"), "{line}");
        assert_eq!(
            inference_warning(&policy, Precision::Fp32, Device::Cpu, never),
            None
        );
    }
}
