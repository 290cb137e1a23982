//! Which convolution kernels bf16 training takes on the CPU, chosen once per run and recorded
//! (project issues 41 and 61; `rtf train` and the Python package's `rtf.train` both settle a
//! run here).
//!
//! On an Intel AVX-512 CPU without AMX, oneDNN's bf16 3×3 kernels lose to its fp32 ones while
//! its 1×1 kernels do not (docs/src/benchmarks.md); with AMX, or on AMD Zen 4, the bf16
//! kernels win. Every way computes bf16 training (bf16 operands, float sums, bf16 outputs);
//! only the speed differs, and the summation order inside the kernels.
//!
//! What decides is a [`Bf16Policy`] the caller resolves at its edge (rtf's binaries and the
//! Python package from `RTF_BF16_CONVOLUTIONS` and oneDNN's ISA cap): the library reads no
//! variable and keeps no process-wide choice; the choice is recorded in the run's
//! configuration and each autocast region of its steps computes with it
//! ([`crate::procedure::Trained::autocast`]).
//!
//! So where the CPU has bf16 arithmetic and the caller leaves the choice open, a new run takes
//! [`Bf16Convolutions::Mixed`] where one wide 3×3 layer's forward and backward measured faster
//! on fp32 kernels ([`choose_training_convolutions`] over a measurement the caller makes and
//! caches: `rtf` in a child process, the Python package in its own), and records the choice
//! in its configuration (`compute.bf16_convolutions`) before the first step: a resume
//! computes with the kernels the run started with.
//!
//! Not measured: data-parallel runs (each rank would measure on its own; they record the
//! choice in force) and resumes of runs from before the record (they record the choice in
//! force, which is what they started with).

mod warning;

pub use warning::{measure_training, measured_training, training_key, training_warning};

use std::path::{Path, PathBuf};

use rtf_amp::{Bf16Convolutions, Bf16Policy};
use rtf_eval::kernels::probe::{Measured, Probe, Work};
use tch::Device;

use crate::config::{available_device, Fp32Layout, Precision, TrainConfig};
use crate::RunConfig;

/// A choice of bf16 convolutions with the line that says it, if any.
pub type Choice = (Bf16Convolutions, Option<String>);

/// Makes the choice for `cfg`'s bf16 CPU stages under `policy` and records it in them; returns
/// the lines to print (a measured mixed choice, a record that stands or is overridden, a failed
/// probe). `choose` is called only for a new single-process run: the measured choice
/// ([`choose_training_convolutions`]), or None to keep the choice in force.
pub fn settle_for_run(
    cfg: &mut RunConfig,
    resume: bool,
    data_parallel: bool,
    policy: &Bf16Policy,
    choose: impl FnOnce() -> Option<Choice>,
) -> Vec<String> {
    let mut stages: Vec<&mut TrainConfig> = cfg
        .stages_mut()
        .into_iter()
        .filter(|s| trains_bf16_on_cpu(s))
        .collect();
    if stages.is_empty() {
        return Vec::new();
    }
    let recorded = stages.iter().find_map(|s| s.compute.bf16_convolutions);
    let mut lines = Vec::new();
    let choice = match recorded {
        Some(recorded) => {
            let in_force = policy.in_force(Some(recorded));
            lines.extend(record_message(recorded, in_force, policy));
            in_force
        }
        // A run from before the record started with the choice in force without one.
        None if resume || data_parallel => policy.in_force(None),
        None => {
            let (choice, line) = measured_or_in_force(policy, choose);
            lines.extend(line);
            choice
        }
    };
    for stage in &mut stages {
        stage.compute.bf16_convolutions = Some(choice);
    }
    lines
}

/// Records the fp32 stages' layout: `asked` (the caller's choice: `RTF_TRAIN_LAYOUT` for rtf's
/// binaries) where given, else the layout a stage recorded when it started, else for a new run
/// the faster on its device ([`crate::config::fp32_layout_faster_on`]). A resume of a run from before the
/// record keeps none (the faster on the device, as it started).
pub fn settle_fp32_layout(cfg: &mut RunConfig, resume: bool, asked: Option<Fp32Layout>) {
    for stage in cfg.stages_mut() {
        if stage.learning.precision != Precision::Fp32 {
            continue;
        }
        let device = available_device(&stage.compute.device).unwrap_or(Device::Cpu);
        let recorded = stage.compute.fp32_layout;
        stage.compute.fp32_layout = match (asked, recorded, resume) {
            (Some(asked), ..) => Some(asked),
            (None, Some(recorded), _) => Some(recorded),
            (None, None, true) => None,
            (None, None, false) => Some(crate::config::fp32_layout_faster_on(device)),
        };
    }
}

/// Records the Winograd forms every stage's training convolutions may take: `asked` (the
/// caller's choice: `RTF_WINOGRAD` for rtf's binaries, where set) where given, else what the
/// stage recorded (all forms for a new run or one recorded before the choice was).
pub fn settle_winograd(cfg: &mut RunConfig, asked: Option<rtf_kernels::winograd::Forms>) {
    if let Some(forms) = asked {
        for stage in cfg.stages_mut() {
            stage.compute.winograd = forms;
        }
    }
}

fn trains_bf16_on_cpu(stage: &TrainConfig) -> bool {
    stage.learning.precision == Precision::Bf16
        && available_device(&stage.compute.device).is_ok_and(|d| d == Device::Cpu)
}

/// The choice in force under `policy` with `choose`'s choice, where it makes one.
pub fn measured_or_in_force(
    policy: &Bf16Policy,
    choose: impl FnOnce() -> Option<Choice>,
) -> Choice {
    match choose() {
        Some((choice, line)) => (policy.in_force(Some(choice)), line),
        None => (policy.in_force(None), None),
    }
}

/// Where `policy` leaves the choice open and bf16 is native ([`Bf16Policy::open_to_measure`]):
/// [`Bf16Convolutions::Mixed`] if `measured` ([`Work::Conv3x3Training`], cached) found fp32
/// kernels faster for a wide 3×3 layer, else native; with the line that says a mixed choice.
/// `None` where nothing is measured (the choice in force stands); a failed measurement is a
/// warning, and the bf16 kernels run.
pub fn choose_training_convolutions(
    policy: &Bf16Policy,
    measured: impl FnOnce() -> Result<(Measured, Option<PathBuf>), String>,
) -> Option<Choice> {
    if !policy.open_to_measure() {
        return None;
    }
    match measured() {
        // `fp32_s` is the emulated layer's: below 1, the fp32 kernels were the faster.
        Ok((m, cache)) if m.speedup() < 1.0 => Some((
            Bf16Convolutions::Mixed,
            Some(mixed_choice_message(&m, cache.as_deref())),
        )),
        Ok(_) => Some((Bf16Convolutions::Native, None)),
        Err(e) => Some((
            Bf16Convolutions::Native,
            Some(format!(
                "warning: could not measure which bf16 convolutions train faster on this CPU \
                 ({e}); oneDNN's bf16 kernels run"
            )),
        )),
    }
}

/// [`Work::Conv3x3Training`] measured in this process, cached by `probe` (under the key `rtf`
/// uses, so that both share the measurement).
pub fn measured_here(probe: &Probe) -> Result<(Measured, Option<PathBuf>), String> {
    let key = probe.key(Work::Conv3x3Training.name());
    probe.measured(&key, rtf_eval::kernels::probe::measure_conv3x3_training)
}

/// The line that says bf16 training runs its spatial convolutions on fp32 kernels.
fn mixed_choice_message(m: &Measured, cache: Option<&Path>) -> String {
    let cached = cache.map_or("not cached".to_string(), |p| {
        format!("cached in {}", p.display())
    });
    format!(
        "bf16 training runs its 3x3 and larger convolutions on fp32 kernels over bf16 operands \
         here ({}=mixed): {} took {:.1} ms so against {:.1} ms on oneDNN's bf16 kernels (bf16 \
         operands, float sums either way; {cached}; {}=native|emulated|mixed decides instead)",
        rtf_amp::BF16_CONVOLUTIONS_VAR,
        Work::Conv3x3Training.workload(),
        1000.0 * m.fp32_s,
        1000.0 * m.bf16_s,
        rtf_amp::BF16_CONVOLUTIONS_VAR
    )
}

/// What to say of a resumed run's recorded choice: that it stands where it differs from the
/// default, or that the user's choice (or a CPU without bf16 arithmetic) overrides it.
fn record_message(
    recorded: Bf16Convolutions,
    in_force: Bf16Convolutions,
    policy: &Bf16Policy,
) -> Option<String> {
    if in_force != recorded {
        return Some(format!(
            "warning: the run started with {} bf16 convolutions (compute.bf16_convolutions in its \
             config.json); {} run now ({}), so the resumed steps do not compute the same sums",
            recorded.name(),
            in_force.name(),
            match policy.asked.is_some() {
                true => format!("{} is set", rtf_amp::BF16_CONVOLUTIONS_VAR),
                false => "this CPU has no bf16 arithmetic".into(),
            }
        ));
    }
    (recorded != Bf16Convolutions::Native && policy.arithmetic.is_native() == Some(true)).then(
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

    fn never() -> Option<Choice> {
        panic!("measured where nothing is chosen")
    }

    fn policy(asked: Option<Bf16Convolutions>, native: bool) -> Bf16Policy {
        Bf16Policy {
            asked,
            arithmetic: rtf_amp::Bf16Arithmetic::from_flags(Some(native), rtf_amp::IsaCap::NONE),
        }
    }

    #[test]
    fn only_bf16_on_the_cpu_is_settled_and_an_old_run_resumed_records_the_choice_in_force() {
        let open = policy(None, true);
        let mut fp32 = run(Precision::Fp32, "cpu");
        assert!(settle_for_run(&mut fp32, false, false, &open, never).is_empty());
        assert_eq!(recorded(&fp32), None);
        let mut resumed = run(Precision::Bf16, "cpu");
        assert!(settle_for_run(&mut resumed, true, false, &policy(None, false), never).is_empty());
        assert_eq!(
            recorded(&resumed),
            Some(Bf16Convolutions::Emulated),
            "what it started with"
        );
        // Data-parallel: the choice in force, recorded, nothing measured.
        let mut ddp = run(Precision::Bf16, "cpu");
        let asked = policy(Some(Bf16Convolutions::Mixed), true);
        settle_for_run(&mut ddp, false, true, &asked, never);
        assert_eq!(recorded(&ddp), Some(Bf16Convolutions::Mixed));
    }

    /// A new run measures only where the policy leaves the choice open; the user's choice
    /// overrides a record, and says so.
    #[test]
    fn a_new_run_measures_only_where_left_open_and_the_users_choice_wins() {
        let mut new = run(Precision::Bf16, "cpu");
        let mixed = || Some((Bf16Convolutions::Mixed, Some("mixed".to_owned())));
        let lines = settle_for_run(&mut new, false, false, &policy(None, true), mixed);
        assert_eq!(
            (recorded(&new), lines),
            (Some(Bf16Convolutions::Mixed), vec!["mixed".into()])
        );
        let native = policy(Some(Bf16Convolutions::Native), true);
        let lines = settle_for_run(&mut new, true, false, &native, never);
        assert_eq!(recorded(&new), Some(Bf16Convolutions::Native));
        assert!(
            lines[0].contains("RTF_BF16_CONVOLUTIONS is set"),
            "{lines:?}"
        );
        let measure = || -> Result<(Measured, Option<PathBuf>), String> { panic!("measured") };
        assert_eq!(choose_training_convolutions(&native, measure), None);
        assert_eq!(
            choose_training_convolutions(&policy(None, false), measure),
            None
        );
        let failed = choose_training_convolutions(&policy(None, true), || Err("x".into()));
        assert_eq!(failed.unwrap().0, Bf16Convolutions::Native);
    }

    #[test]
    fn the_winograd_forms_asked_are_recorded_and_a_record_stands_otherwise() {
        use rtf_kernels::winograd::Forms;
        let forms = |cfg: &RunConfig| cfg.stages()[0].1.compute.winograd;
        let mut new = run(Precision::Fp32, "cpu");
        settle_winograd(&mut new, None);
        assert_eq!(forms(&new), Forms::All, "a new run: every form");
        settle_winograd(&mut new, Some(Forms::Off));
        assert_eq!(forms(&new), Forms::Off, "asked");
        settle_winograd(&mut new, None);
        assert_eq!(forms(&new), Forms::Off, "recorded, kept on resume");
        let json = serde_json::to_string(&new).unwrap();
        assert!(json.contains(r#""winograd":"off""#), "{json}");
    }

    #[test]
    fn the_layout_asked_wins_a_record_stands_and_a_new_run_takes_the_faster() {
        let layout = |cfg: &RunConfig| cfg.stages()[0].1.compute.fp32_layout;
        let mut new = run(Precision::Fp32, "cpu");
        settle_fp32_layout(&mut new, false, None);
        assert_eq!(
            layout(&new),
            Some(crate::config::fp32_layout_faster_on(Device::Cpu))
        );
        settle_fp32_layout(&mut new, true, Some(Fp32Layout::Nchw));
        assert_eq!(layout(&new), Some(Fp32Layout::Nchw), "asked");
        settle_fp32_layout(&mut new, true, None);
        assert_eq!(layout(&new), Some(Fp32Layout::Nchw), "recorded");
        let mut old = run(Precision::Fp32, "cpu");
        settle_fp32_layout(&mut old, true, None);
        assert_eq!(layout(&old), None, "a run from before the record");
        let mut bf16 = run(Precision::Bf16, "cpu");
        settle_fp32_layout(&mut bf16, false, Some(Fp32Layout::Nchw));
        assert_eq!(layout(&bf16), None, "fp32 stages only");
    }

    #[test]
    fn a_record_that_stands_is_said_only_where_it_is_emulation_by_choice() {
        use Bf16Convolutions::*;
        let open = policy(None, true);
        assert_eq!(record_message(Native, Native, &open), None);
        let overridden = record_message(Emulated, Native, &policy(None, false)).unwrap();
        assert!(
            overridden.starts_with("warning: the run started with emulated")
                && overridden.contains("native run now"),
            "{overridden}"
        );
        assert!(
            overridden.contains("this CPU has no bf16 arithmetic"),
            "{overridden}"
        );
        assert!(record_message(Emulated, Emulated, &open).is_some());
        assert_eq!(
            record_message(Emulated, Emulated, &policy(None, false)),
            None
        );
    }

    #[test]
    fn a_mixed_choice_is_said_with_both_times_and_the_way_to_decide_instead() {
        let m = Measured {
            fp32_s: 0.120,
            bf16_s: 0.180,
            unix_time: 0,
        };
        let line = mixed_choice_message(&m, Some(Path::new("/c/p.json")));
        assert!(
            line.contains("forward and backward took 120.0 ms so against 180.0 ms"),
            "{line}"
        );
        assert!(
            line.contains("cached in /c/p.json") && line.contains("(RTF_BF16_CONVOLUTIONS=mixed)")
        );
        assert!(!line.contains('\n'));
    }
}
