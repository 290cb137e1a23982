//! One line on stderr before bf16 work on a CPU where bf16 is emulated (project issue 31):
//! `rtf train`, `eval`, `predict`, `bench model` and `bench train` with `--precision bf16`.
//!
//! Where the CPU has no bf16 instructions (no `avx512_bf16`, `amx_bf16` or Arm `bf16`, or
//! oneDNN capped below `AVX512_CORE_BF16` by `ONEDNN_MAX_CPU_ISA`:
//! [`rtf_amp::cpu_bf16_arithmetic`]) every bf16 product is computed by converting to fp32 and
//! back. libtorch's and oneDNN's generic bf16 kernels do that slowly: an AVX2 EPYC, batch 1,
//! 640×480, 2 threads, measured the fast path's bf16 MFNet at 1.16 s against 102 ms in fp32
//! (~11×) and RTFNet-50 at 75 s against 2.28 s (~33×) (issue 31). So rtf routes bf16
//! convolutions through fp32 kernels there ([`rtf_amp::Bf16Convolutions::Emulated`]), which
//! keeps a native kernel's numbers (bf16 operands, float sums, bf16 outputs) at fp32 kernels'
//! speed plus the casts: in training (MFNet, 320×240, batch 2: 5.45 against 7.67 images/s with
//! emulation forced on an AVX-512 EPYC, docs/src/benchmarks.md round 5) and, since issue 41, in
//! inference (the fast path's folds: MFNet 97 against 88 ms, RTFNet-50 1.61 against 1.50 s in
//! fp32, under AVX2 caps on an Intel Xeon). Slower than fp32 either way, saving only activation
//! memory, hence the advice; with `RTF_BF16_CONVOLUTIONS=native` the generic kernels run and
//! the warning gives their cost.
//!
//! Where bf16 is native, it can still be slower than fp32 (Intel AVX-512 without AMX, issue
//! 41): [`crate::bf16_probe`] measures it once per CPU kind and the warning gives the times.
//!
//! No `--precision auto`: the precision stays what the user typed (default fp32), so the same
//! command gives the same numbers and weights on every machine; docs/src/benchmarks.md says why.

use crate::bf16_probe::Work;
use rtf_amp::{Bf16Arithmetic, Bf16Convolutions};
use rtf_models::fast::InferenceKernels;
use rtf_train::config::Precision;
use tch::Device;

/// The warning for bf16 inference (`eval`, `predict`, `bench model`) on `device`, if any:
/// bf16 emulated, or native but measured slower than fp32 ([`crate::bf16_probe`]).
pub fn inference(bf16: bool, device: Device, kernels: &InferenceKernels) -> Option<String> {
    let arithmetic = rtf_amp::cpu_bf16_arithmetic();
    let convolutions = rtf_amp::cpu_bf16_convolutions().ok();
    inference_message(bf16, device, &arithmetic, convolutions).or_else(|| {
        let native = convolutions == Some(Bf16Convolutions::Native);
        let work = (Work::Inference, Some(kernels));
        native_but_slower(bf16 && native, device, &arithmetic, work)
    })
}

/// Where bf16 is native on the CPU: the probe's warning if bf16 measured slower than fp32
/// there. A probe that fails is said as such (the work itself goes on).
fn native_but_slower(
    bf16: bool,
    device: Device,
    arithmetic: &Bf16Arithmetic,
    (work, kernels): (Work, Option<&InferenceKernels>),
) -> Option<String> {
    if !bf16 || device != Device::Cpu || arithmetic.is_native() != Some(true) {
        return None;
    }
    match crate::bf16_probe::measured(work, kernels) {
        Ok((m, cache)) => crate::bf16_probe::slower_message(work, &m, cache.as_deref()),
        Err(e) => Some(format!(
            "could not measure whether bf16 pays on this CPU ({e:#}); bf16 may be slower than fp32 here"
        )),
    }
}

/// The warning for training in `precision` on `device` (`train`, `bench train`), if any:
/// rtf-train's own ([`Precision::slow_on`]: libtorch's generic bf16 convolutions chosen on a
/// CPU without bf16) or, where rtf emulates the convolutions, this module's.
pub fn training(precision: Precision, device: Device) -> Option<String> {
    let bf16 = precision == Precision::Bf16;
    let arithmetic = rtf_amp::cpu_bf16_arithmetic();
    let convolutions = rtf_amp::cpu_bf16_convolutions().ok();
    precision
        .slow_on(device)
        .or_else(|| training_message(bf16, device, &arithmetic, convolutions))
        .or_else(|| {
            // rtf's emulated convolutions forced on a native CPU already have their warning;
            // native and mixed (rtf_train::kernels) get the probe's.
            let emulated = convolutions == Some(Bf16Convolutions::Emulated);
            native_but_slower(
                bf16 && !emulated,
                device,
                &arithmetic,
                (Work::Training, None),
            )
        })
}

fn inference_message(
    bf16: bool,
    device: Device,
    arithmetic: &Bf16Arithmetic,
    convolutions: Option<Bf16Convolutions>,
) -> Option<String> {
    if !bf16 || device != Device::Cpu {
        return None;
    }
    let native = arithmetic.is_native();
    match convolutions {
        Some(Bf16Convolutions::Emulated) => Some(format!(
            "bf16 is emulated on this CPU ({}): rtf runs bf16 inference on fp32 kernels, a \
             little slower than fp32 (measured under AVX2 caps, batch 1, 640x480: MFNet 0.91x, \
             RTFNet-50 0.93x fp32's speed) and saving only activation memory; use --precision \
             fp32",
            emulated_because(arithmetic)
        )),
        _ if native == Some(false) => Some(format!(
            "bf16 is emulated on this CPU ({}; {}=native): libtorch's generic bf16 kernels run \
             far slower than fp32 (measured on an AVX2 EPYC, batch 1, 640x480: MFNet ~11x, \
             RTFNet-50 ~33x); use --precision fp32",
            arithmetic.reason(),
            rtf_amp::BF16_CONVOLUTIONS_VAR
        )),
        _ => None,
    }
}

/// Why rtf emulates bf16 convolutions: the CPU's missing arithmetic, else the variable.
fn emulated_because(arithmetic: &Bf16Arithmetic) -> String {
    match arithmetic.is_native() {
        Some(false) => arithmetic.reason(),
        _ => format!("{}=emulated", rtf_amp::BF16_CONVOLUTIONS_VAR),
    }
}

fn training_message(
    bf16: bool,
    device: Device,
    arithmetic: &Bf16Arithmetic,
    convolutions: Option<Bf16Convolutions>,
) -> Option<String> {
    if !bf16 || device != Device::Cpu || convolutions != Some(Bf16Convolutions::Emulated) {
        return None;
    }
    let why = emulated_because(arithmetic);
    Some(format!(
        "bf16 is emulated on this CPU ({why}): rtf runs its bf16 convolutions on fp32 kernels, \
         so a bf16 step is slower than fp32 (MFNet ~1.4x with emulation forced on an AVX-512 \
         EPYC; not measured on AVX2) and saves only activation memory; use --precision fp32"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn capped() -> Bf16Arithmetic {
        Bf16Arithmetic::CappedBy {
            var: "ONEDNN_MAX_CPU_ISA",
            isa: "AVX2".into(),
        }
    }

    #[test]
    fn inference_warns_where_bf16_is_emulated_with_the_cost_of_the_kernels_that_run() {
        let emulated = Some(Bf16Convolutions::Emulated);
        let native = Some(Bf16Convolutions::Native);
        let missing = Bf16Arithmetic::MissingFromCpu;
        let line = inference_message(true, Device::Cpu, &missing, emulated).unwrap();
        assert!(
            line.contains("no avx512_bf16")
                && line.contains("on fp32 kernels")
                && line.contains("0.93x"),
            "{line}"
        );
        assert!(line.ends_with("use --precision fp32") && !line.contains('\n'));
        let line = inference_message(true, Device::Cpu, &capped(), emulated).unwrap();
        assert!(line.contains("ONEDNN_MAX_CPU_ISA=AVX2"), "{line}");
        // libtorch's generic kernels forced: their own cost.
        let line = inference_message(true, Device::Cpu, &capped(), native).unwrap();
        assert!(
            line.contains("RTF_BF16_CONVOLUTIONS=native") && line.contains("~33x"),
            "{line}"
        );
        // Emulation forced on a CPU with bf16 arithmetic: said, with the variable.
        let line = inference_message(true, Device::Cpu, &Bf16Arithmetic::Native, emulated);
        assert!(line.unwrap().contains("(RTF_BF16_CONVOLUTIONS=emulated)"));
        assert_eq!(
            inference_message(false, Device::Cpu, &capped(), emulated),
            None
        );
        assert_eq!(
            inference_message(true, Device::Cuda(0), &capped(), emulated),
            None
        );
        for arithmetic in [Bf16Arithmetic::Native, Bf16Arithmetic::Unknown] {
            assert_eq!(
                inference_message(true, Device::Cpu, &arithmetic, native),
                None
            );
        }
    }

    #[test]
    fn training_warns_where_the_convolutions_are_emulated_and_says_why() {
        use Bf16Convolutions::*;
        let line = training_message(true, Device::Cpu, &capped(), Some(Emulated)).unwrap();
        assert!(
            line.contains("(ONEDNN_MAX_CPU_ISA=AVX2 keeps oneDNN"),
            "{line}"
        );
        assert!(line.ends_with("use --precision fp32") && !line.contains('\n'));
        // Forced on a CPU with bf16: the variable is the reason.
        let line = training_message(true, Device::Cpu, &Bf16Arithmetic::Native, Some(Emulated));
        assert!(line.unwrap().contains("(RTF_BF16_CONVOLUTIONS=emulated)"));
        assert_eq!(
            training_message(true, Device::Cpu, &Bf16Arithmetic::Native, Some(Native)),
            None
        );
        assert_eq!(
            training_message(false, Device::Cpu, &capped(), Some(Emulated)),
            None
        );
        assert_eq!(
            training_message(true, Device::Cuda(0), &capped(), Some(Emulated)),
            None
        );
        assert_eq!(training_message(true, Device::Cpu, &capped(), None), None);
    }
}
