//! One line before bf16 training on a CPU where bf16 is slow (`rtf train`, `rtf bench train`
//! and the Python package's `rtf.train` alike): libtorch's generic bf16 convolutions asked for
//! on a CPU without bf16 arithmetic ([`Precision::slow_on`]), rtf's emulated convolutions, or
//! bf16 native but measured slower than fp32 ([`Work::Training`]; rtf_eval::kernels says why
//! each is worth a warning).

use rtf_amp::PrecisionOnDevice;
use rtf_amp::{Bf16Arithmetic, Bf16Convolutions, Bf16Policy};
use rtf_eval::kernels::probe::{Measured, Probe, Work};
use rtf_eval::kernels::warning::{emulated_because, native_but_slower, Probed};
use tch::Device;

use crate::config::Precision;

/// The warning for training in `precision` on `device` with `convolutions` (the run's choice,
/// [`super::settle_for_run`]) under `policy`, if any. `measured` ([`Work::Training`] with those
/// convolutions, [`measured_training`] or a caller's own) is called only where bf16 is native
/// and not emulated.
pub fn training_warning(
    policy: &Bf16Policy,
    convolutions: Bf16Convolutions,
    precision: Precision,
    device: Device,
    measured: impl FnOnce() -> Probed,
) -> Option<String> {
    let bf16 = precision == Precision::Bf16;
    let arithmetic = &policy.arithmetic;
    precision
        .slow_on(device, policy)
        .or_else(|| training_message(bf16, device, arithmetic, convolutions))
        .or_else(|| {
            // rtf's emulated convolutions forced on a native CPU already have their warning;
            // native and mixed get the probe's.
            let emulated = convolutions == Bf16Convolutions::Emulated;
            native_but_slower(
                bf16 && !emulated,
                device,
                arithmetic,
                Work::Training,
                measured,
            )
        })
}

fn training_message(
    bf16: bool,
    device: Device,
    arithmetic: &Bf16Arithmetic,
    convolutions: Bf16Convolutions,
) -> Option<String> {
    if !bf16 || device != Device::Cpu || convolutions != Bf16Convolutions::Emulated {
        return None;
    }
    let why = emulated_because(arithmetic);
    Some(format!(
        "bf16 is emulated on this CPU ({why}): rtf runs its bf16 convolutions on fp32 kernels, \
         so a bf16 step is slower than fp32 (MFNet ~1.4x with emulation forced on an AVX-512 \
         EPYC; not measured on AVX2) and saves only activation memory; use --precision fp32"
    ))
}

/// The key of [`Work::Training`] with `convolutions` ([`Probe::key`]).
pub fn training_key(probe: &Probe, convolutions: Bf16Convolutions) -> String {
    probe.key(&format!("training | {} convolutions", convolutions.name()))
}

/// [`Work::Training`] timed in this process: an MFNet training step at 320×240, batch 2
/// ([`crate::bench::bench_train`]), fp32 then bf16 with `convolutions`, the training
/// convolutions within the Winograd `forms`.
pub fn measure_training(
    convolutions: Bf16Convolutions,
    forms: rtf_kernels::winograd::Forms,
) -> Result<Measured, String> {
    let seconds = |precision| -> Result<f64, String> {
        let opts = crate::bench::TrainBenchOptions {
            model: "mfnet".into(),
            batch: 2,
            size: (320, 240),
            precision,
            device: Device::Cpu,
            warmup: 1,
            steps: 3,
            optimizer: crate::OptimizerConfig::mfnet_paper(),
            count_ops: false,
            fp32_layout: None,
            bf16_convolutions: Some(convolutions),
            winograd: forms,
        };
        let report = crate::bench::bench_train(&opts).map_err(|e| e.to_string())?;
        Ok(report.step_s)
    };
    let fp32 = seconds(Precision::Fp32)?;
    Ok(Measured::now(fp32, seconds(Precision::Bf16)?))
}

/// [`Work::Training`] with `convolutions` and every Winograd form (a run's default), cached by
/// `probe` under [`training_key`] (the key `rtf` uses), measured in this process where there is
/// none.
pub fn measured_training(probe: &Probe, convolutions: Bf16Convolutions) -> Probed {
    probe.measured(&training_key(probe, convolutions), || {
        measure_training(convolutions, rtf_kernels::winograd::Forms::All)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtf_amp::IsaCap;

    fn capped() -> Bf16Arithmetic {
        Bf16Arithmetic::CappedBy {
            var: "ONEDNN_MAX_CPU_ISA",
            isa: "AVX2",
        }
    }

    fn never() -> Probed {
        panic!("measured")
    }

    #[test]
    fn training_warns_where_the_convolutions_are_emulated_and_says_why() {
        use Bf16Convolutions::*;
        let line = training_message(true, Device::Cpu, &capped(), Emulated).unwrap();
        assert!(
            line.contains("(ONEDNN_MAX_CPU_ISA=AVX2 keeps oneDNN"),
            "{line}"
        );
        assert!(line.ends_with("use --precision fp32") && !line.contains('\n'));
        // Forced on a CPU with bf16: the variable is the reason.
        let line = training_message(true, Device::Cpu, &Bf16Arithmetic::Native, Emulated);
        assert!(line.unwrap().contains("(RTF_BF16_CONVOLUTIONS=emulated)"));
        let native = Bf16Arithmetic::Native;
        assert_eq!(training_message(true, Device::Cpu, &native, Native), None);
        assert_eq!(
            training_message(false, Device::Cpu, &capped(), Emulated),
            None
        );
        assert_eq!(
            training_message(true, Device::Cuda(0), &capped(), Emulated),
            None
        );
    }

    /// libtorch's generic kernels asked for without bf16 arithmetic: rtf-amp's single warning;
    /// a native CPU with native convolutions: the probe's.
    #[test]
    fn each_case_gives_one_warning() {
        use Bf16Convolutions::*;
        let generic = Bf16Policy {
            asked: Some(Native),
            arithmetic: capped(),
        };
        let line = training_warning(&generic, Native, Precision::Bf16, Device::Cpu, never);
        assert!(line.unwrap().contains("RTF_BF16_CONVOLUTIONS=native picks"));
        let open = Bf16Policy {
            asked: None,
            arithmetic: Bf16Arithmetic::from_flags(Some(true), IsaCap::NONE),
        };
        let slower = || -> Probed { Ok((Measured::now(1.0, 2.0), None)) };
        let line = training_warning(&open, Mixed, Precision::Bf16, Device::Cpu, slower);
        assert!(line.unwrap().contains("an MFNet training step"));
        assert_eq!(
            training_warning(&open, Native, Precision::Fp32, Device::Cpu, never),
            None
        );
    }
}
