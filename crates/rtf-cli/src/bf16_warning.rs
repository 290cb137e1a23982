//! One line on stderr before bf16 work on a CPU where bf16 is emulated (project issue 31):
//! `rtf train`, `eval`, `predict`, `bench model` and `bench train` with `--precision bf16`.
//!
//! Where the CPU has no bf16 instructions (no `avx512_bf16`, `amx_bf16` or Arm `bf16`, or
//! oneDNN capped below `AVX512_CORE_BF16` by `ONEDNN_MAX_CPU_ISA`:
//! [`rtf_amp::cpu_bf16_arithmetic`]) every bf16 product is computed by converting to fp32 and
//! back. For inference (the fast path's bf16 weights and activations) that is libtorch's and
//! oneDNN's generic bf16 kernels: an AVX2 EPYC, batch 1, 640×480, 2 threads, measured MFNet at
//! 1.16 s against 102 ms in fp32 (~11×) and RTFNet-50 at 75 s against 2.28 s (~33×) (issue 31).
//! Training routes its bf16 convolutions through fp32 kernels instead
//! ([`rtf_amp::Bf16Convolutions::Emulated`]), which keeps a native kernel's numbers at fp32
//! kernels' speed plus the casts: slower than fp32 (MFNet, 320×240, batch 2: 5.45 against 7.67
//! images/s with emulation forced on an AVX-512 EPYC, docs/src/benchmarks.md round 5), saving
//! only activation memory. Neither is expected to beat fp32 on such a CPU, hence the advice.
//!
//! Where bf16 is native, it can still be slower than fp32 (Intel AVX-512 without AMX, issue
//! 41): [`crate::bf16_probe`] measures it once per CPU kind and the warning gives the times.
//!
//! No `--precision auto`: the precision stays what the user typed (default fp32), so the same
//! command gives the same numbers and weights on every machine; docs/src/benchmarks.md says why.

use crate::bf16_probe::Work;
use rtf_amp::{Bf16Arithmetic, Bf16Convolutions};
use rtf_train::config::Precision;
use tch::Device;

/// The warning for bf16 inference (`eval`, `predict`, `bench model`) on `device`, if any:
/// bf16 emulated, or native but measured slower than fp32 ([`crate::bf16_probe`]).
pub fn inference(bf16: bool, device: Device) -> Option<String> {
    let arithmetic = rtf_amp::cpu_bf16_arithmetic();
    inference_message(bf16, device, &arithmetic)
        .or_else(|| native_but_slower(bf16, device, &arithmetic, Work::Inference))
}

/// Where bf16 is native on the CPU: the probe's warning if bf16 measured slower than fp32
/// there. A probe that fails is said as such (the work itself goes on).
fn native_but_slower(
    bf16: bool,
    device: Device,
    arithmetic: &Bf16Arithmetic,
    work: Work,
) -> Option<String> {
    if !bf16 || device != Device::Cpu || arithmetic.is_native() != Some(true) {
        return None;
    }
    match crate::bf16_probe::measured(work) {
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
            // rtf's emulated convolutions forced on a native CPU already have their warning.
            let native = convolutions == Some(Bf16Convolutions::Native);
            native_but_slower(bf16 && native, device, &arithmetic, Work::Training)
        })
}

fn inference_message(bf16: bool, device: Device, arithmetic: &Bf16Arithmetic) -> Option<String> {
    (bf16 && device == Device::Cpu && arithmetic.is_native() == Some(false)).then(|| {
        format!(
            "bf16 is emulated on this CPU ({}): bf16 inference runs far slower than fp32 \
             (measured on an AVX2 EPYC, batch 1, 640x480: MFNet ~11x, RTFNet-50 ~33x); use \
             --precision fp32",
            arithmetic.reason()
        )
    })
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
    let why = match arithmetic.is_native() {
        Some(false) => arithmetic.reason(),
        _ => format!("{}=emulated", rtf_amp::BF16_CONVOLUTIONS_VAR),
    };
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
    fn inference_warns_for_bf16_on_a_cpu_without_bf16_only() {
        let line = inference_message(true, Device::Cpu, &Bf16Arithmetic::MissingFromCpu).unwrap();
        assert!(
            line.contains("no avx512_bf16") && line.contains("~33x"),
            "{line}"
        );
        assert!(line.ends_with("use --precision fp32") && !line.contains('\n'));
        let line = inference_message(true, Device::Cpu, &capped()).unwrap();
        assert!(line.contains("ONEDNN_MAX_CPU_ISA=AVX2"), "{line}");
        assert_eq!(inference_message(false, Device::Cpu, &capped()), None);
        assert_eq!(inference_message(true, Device::Cuda(0), &capped()), None);
        assert_eq!(
            inference_message(true, Device::Cpu, &Bf16Arithmetic::Native),
            None
        );
        assert_eq!(
            inference_message(true, Device::Cpu, &Bf16Arithmetic::Unknown),
            None
        );
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
