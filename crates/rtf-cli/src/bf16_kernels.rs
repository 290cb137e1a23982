//! Which convolution kernels bf16 training takes on the CPU, chosen once per run and recorded
//! (project issue 41).
//!
//! On an Intel AVX-512 CPU without AMX, oneDNN's bf16 3×3 kernels lose to its fp32 ones, its
//! 1×1 kernels do not: with AMX capped off on a Xeon (family 6 model 167), RTFNet-50's bf16
//! training step ran 1.12–1.17× and MFNet's 1.12× faster with their 3×3 and larger
//! convolutions on fp32 kernels over bf16 operands and the rest on the bf16 kernels
//! ([`rtf_amp::Bf16Convolutions::Mixed`]) than all on the bf16 kernels, and faster than all on
//! fp32 kernels ([`rtf_amp::Bf16Convolutions::Emulated`]; docs/src/benchmarks.md). With AMX,
//! oneDNN's bf16 kernels win by far. Every way computes bf16 training (bf16 operands, float
//! sums, bf16 outputs); only the speed differs, and the summation order inside the kernels.
//!
//! So where the CPU has bf16 arithmetic and `RTF_BF16_CONVOLUTIONS` is unset, a new run takes
//! mixed where one wide 3×3 layer's forward and backward measured faster on fp32 kernels here
//! ([`crate::bf16_probe::choose_training_convolutions`], cached per CPU model, caps, libtorch
//! and thread count), and records the choice in its configuration
//! (`compute.bf16_convolutions`) before the first step, as the trainer records the number of
//! processes: a resume computes with the kernels the run started with.
//!
//! Not measured: data-parallel runs (each rank would measure on its own; they keep the choice
//! in force, recorded the same way) and resumes of runs from before the record (they keep the
//! choice in force without one, which is what they started with).

use rtf_amp::Bf16Convolutions;
use rtf_train::config::{available_device, Precision, TrainConfig};
use rtf_train::RunConfig;
use tch::Device;

/// Makes this process's choice for `cfg`'s bf16 CPU stages and records it in them; returns the
/// lines to print (a measured mixed choice, a record that stands or is overridden, a failed
/// probe).
pub fn settle_for_run(
    cfg: &mut RunConfig,
    resume: bool,
    data_parallel: bool,
) -> anyhow::Result<Vec<String>> {
    let mut stages: Vec<&mut TrainConfig> = cfg
        .stages_mut()
        .into_iter()
        .filter(|s| trains_bf16_on_cpu(s))
        .collect();
    if stages.is_empty() {
        return Ok(Vec::new());
    }
    let recorded = stages.iter().find_map(|s| s.compute.bf16_convolutions);
    let mut lines = Vec::new();
    let choice = match recorded {
        Some(recorded) => {
            let in_force = rtf_amp::choose_process_bf16_convolutions(recorded)?;
            lines.extend(record_message(recorded, in_force));
            in_force
        }
        // A run from before the record started with the choice in force without one.
        None if resume => return Ok(Vec::new()),
        None if data_parallel => rtf_amp::cpu_bf16_convolutions()?,
        None => {
            let (choice, line) = measured_or_in_force()?;
            lines.extend(line);
            choice
        }
    };
    for stage in &mut stages {
        stage.compute.bf16_convolutions = Some(choice);
    }
    Ok(lines)
}

/// `rtf bench train`: the choice `rtf train` would make for a new run, made for this process;
/// returns the line to print, if any.
pub fn settle_for_bench(precision: Precision, device: Device) -> anyhow::Result<Option<String>> {
    if precision != Precision::Bf16 || device != Device::Cpu {
        return Ok(None);
    }
    Ok(measured_or_in_force()?.1)
}

fn trains_bf16_on_cpu(stage: &TrainConfig) -> bool {
    stage.learning.precision == Precision::Bf16
        && available_device(&stage.compute.device).is_ok_and(|d| d == Device::Cpu)
}

/// The measured choice, made for this process, where a measurement decides
/// ([`crate::bf16_probe::choose_training_convolutions`]); else the choice in force.
fn measured_or_in_force() -> anyhow::Result<(Bf16Convolutions, Option<String>)> {
    match crate::bf16_probe::choose_training_convolutions() {
        Some((choice, line)) => Ok((rtf_amp::choose_process_bf16_convolutions(choice)?, line)),
        None => Ok((rtf_amp::cpu_bf16_convolutions()?, None)),
    }
}

/// What to say of a resumed run's recorded choice: that it stands where it differs from the
/// default, or that the variable (or a CPU without bf16 arithmetic) overrides it.
fn record_message(recorded: Bf16Convolutions, in_force: Bf16Convolutions) -> Option<String> {
    if in_force != recorded {
        return Some(format!(
            "warning: the run started with {} bf16 convolutions (compute.bf16_convolutions in its \
             config.json); {} run now ({}), so the resumed steps do not compute the same sums",
            recorded.name(),
            in_force.name(),
            match rtf_amp::bf16_convolutions_set_by_env() {
                true => format!("{} is set", rtf_amp::BF16_CONVOLUTIONS_VAR),
                false => "this CPU has no bf16 arithmetic".into(),
            }
        ));
    }
    (recorded != Bf16Convolutions::Native && rtf_amp::cpu_has_native_bf16() == Some(true)).then(
        || {
            format!(
                "bf16 training runs {} convolutions on fp32 kernels over bf16 operands, as the \
                 run started (compute.bf16_convolutions: {} in its config.json)",
                match recorded {
                    Bf16Convolutions::Mixed => "its 3x3 and larger",
                    _ => "all its",
                },
                recorded.name()
            )
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(precision: Precision, device: &str) -> RunConfig {
        let mut cfg = TrainConfig::mfnet_paper("data".into());
        cfg.learning.precision = precision;
        cfg.compute.device = device.into();
        RunConfig::Single(Box::new(cfg))
    }

    fn recorded(cfg: &RunConfig) -> Option<Bf16Convolutions> {
        cfg.stages()[0].1.compute.bf16_convolutions
    }

    #[test]
    fn only_bf16_on_the_cpu_is_settled_and_nothing_for_an_old_run_resumed() {
        let mut fp32 = run(Precision::Fp32, "cpu");
        assert!(settle_for_run(&mut fp32, false, false).unwrap().is_empty());
        assert_eq!(recorded(&fp32), None);
        let mut resumed = run(Precision::Bf16, "cpu");
        assert!(settle_for_run(&mut resumed, true, false)
            .unwrap()
            .is_empty());
        assert_eq!(recorded(&resumed), None, "a run from before the record");
        // Data-parallel: the choice in force, recorded, nothing measured.
        let mut ddp = run(Precision::Bf16, "cpu");
        settle_for_run(&mut ddp, false, true).unwrap();
        assert_eq!(
            recorded(&ddp),
            Some(rtf_amp::cpu_bf16_convolutions().unwrap())
        );
    }

    #[test]
    fn a_record_that_stands_is_said_only_where_it_is_emulation_by_choice() {
        use Bf16Convolutions::*;
        assert_eq!(record_message(Native, Native), None);
        let overridden = record_message(Emulated, Native).unwrap();
        assert!(
            overridden.starts_with("warning: the run started with emulated")
                && overridden.contains("native run now"),
            "{overridden}"
        );
        let stands = record_message(Emulated, Emulated);
        assert_eq!(
            stands.is_some(),
            rtf_amp::cpu_has_native_bf16() == Some(true)
        );
    }
}
