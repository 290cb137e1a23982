//! `rtf.train`: `rtf train` (rtf_train::launch, the same call the command makes) with the
//! command's options by name. The options are `rtf train`'s own flags (rtf_train::args), so
//! both take the same options with the same checks. Steps and epochs are reported to a
//! Python callback; Ctrl-C stops the run as it stops the command: the step in flight
//! finishes, its checkpoint is written, and `rtf.train(resume=...)` continues it exactly.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::{CommandFactory, Parser};
use pyo3::exceptions::PyKeyboardInterrupt;
use pyo3::prelude::*;
use rtf_eval::kernels::probe::Probe;
use rtf_train::args::TrainArgs;
use rtf_train::config::Fp32Layout;
use rtf_train::launch::{Ended, Plan};
use rtf_train::progress::Progress;
use rtf_train::step_log::StepRecord;
use rtf_train::EpochRecord;

use crate::errors::{input, PyResultExt};

/// `rtf train`'s flags, parsed from the options Python passed (`--name value`, `--flag`).
#[derive(Parser)]
#[command(name = "rtf.train", no_binary_name = true, disable_help_flag = true)]
struct Options {
    #[command(flatten)]
    args: TrainArgs,
}

/// `rtf train`'s options: (name with `_` for `-`, whether it takes a value).
#[pyfunction]
pub fn train_options() -> Vec<(String, bool)> {
    Options::command()
        .get_arguments()
        .filter_map(|arg| {
            let name = arg.get_long()?.replace('-', "_");
            Some((name, arg.get_action().takes_values()))
        })
        .collect()
}

/// The library's warning where a stage's bf16 will train slowly on its device (as `rtf train`
/// says it; measured in this process where bf16 is native), on stderr.
fn warn_if_slow(
    cfg: &rtf_train::RunConfig,
    policy: &rtf_amp::Bf16Policy,
    probe: &Probe,
) -> PyResult<()> {
    for (_, stage) in cfg.stages() {
        let device = rtf_train::config::available_device(&stage.compute.device)
            .map_err(|e| input(format!("device: {e}")))?;
        let convolutions = rtf_train::config::bf16_convolutions_in_force(&stage.compute);
        let measured = || rtf_train::kernels::measured_training(probe, convolutions);
        let precision = stage.learning.precision;
        let warning =
            rtf_train::kernels::training_warning(policy, convolutions, precision, device, measured);
        if let Some(warning) = warning {
            eprintln!("warning: {warning}");
            break;
        }
    }
    Ok(())
}

/// Trains as `rtf train ARGV` does; `env`: the process's variables (the kernel measurement
/// cache, as the command reads it); `progress(kind, stage, json)` is called after every step
/// ("step") and epoch ("epoch"). Returns (run folder, final weights).
#[pyfunction]
#[pyo3(signature = (argv, env, progress=None))]
pub fn train(
    py: Python<'_>,
    argv: Vec<String>,
    env: HashMap<String, String>,
    progress: Option<PyObject>,
) -> PyResult<(String, String)> {
    let options = Options::try_parse_from(&argv)
        .map_err(|e| input(format!("rtf.train: {}", e.render().to_string().trim())))?;
    let mut plan = py
        .allow_threads(|| Plan::new(&options.args.request()?))
        .py()?;
    let run_dir = plan.run_dir.display().to_string();
    if let Some(finished) = plan.finished().py()? {
        eprintln!("{finished}");
        return Ok((run_dir, finished.weights.display().to_string()));
    }
    let probe = Probe::from_vars(|var| env.get(var).map(Into::into));
    let policy = rtf_amp::Bf16Policy::from_vars(|var| env.get(var).cloned())
        .map_err(|e| input(e.to_string()))?;
    let (cfg, resume) = (&mut plan.cfg, plan.resume);
    let lines = py.allow_threads(|| {
        rtf_train::kernels::settle_for_run(cfg, resume, false, &policy, || {
            rtf_train::kernels::choose_training_convolutions(&policy, || {
                rtf_train::kernels::measured_here(&probe)
            })
        })
    });
    for line in lines {
        eprintln!("{line}");
    }
    py.allow_threads(|| warn_if_slow(&plan.cfg, &policy, &probe))?;
    let layout = env.get("RTF_TRAIN_LAYOUT").map_or("", String::as_str);
    let layout = Fp32Layout::parse(layout).map_err(|e| input(format!("RTF_TRAIN_LAYOUT: {e}")))?;
    rtf_train::kernels::settle_fp32_layout(&mut plan.cfg, plan.resume, layout);
    let kernels = rtf_eval::kernels::KernelPolicy::from_vars(|var| env.get(var).cloned())
        .map_err(|e| input(e.to_string()))?;
    let winograd_asked = env
        .contains_key(rtf_eval::kernels::WINOGRAD_VAR)
        .then_some(kernels.winograd);
    rtf_train::kernels::settle_winograd(&mut plan.cfg, winograd_asked);
    // cuDNN's autotuner for a run on CUDA, as `rtf` sets it (RTF_CUDNN_BENCHMARK=0: off).
    if plan
        .cfg
        .stages()
        .iter()
        .any(|(_, s)| s.compute.device.starts_with("cuda"))
    {
        let on = rtf_train::config::cudnn_benchmark(|var| env.get(var).cloned());
        tch::Cuda::cudnn_set_benchmark(on);
    }
    let mut observer = Observer {
        callback: progress,
        raised: None,
    };
    let ended = {
        let _signals = StopOnSignals::install();
        py.allow_threads(|| plan.train(&mut observer, &STOP, None))
    };
    if let Some(err) = observer.raised {
        return Err(err);
    }
    match ended.py()? {
        Ended::Trained(path) => Ok((run_dir, path.display().to_string())),
        Ended::Interrupted { stage, state } => {
            let batch = state.partial.as_ref().map_or(0, |p| p.batches);
            let stage = stage.map_or(String::new(), |s| format!(" (stage {s})"));
            Err(PyKeyboardInterrupt::new_err(format!(
                "interrupted{stage} in epoch {} after batch {batch}: checkpoint written; \
                 continue with rtf.train(resume={run_dir:?})",
                state.epochs_done + 1,
            )))
        }
    }
}

/// The user's callback, called with the GIL held; an exception it raises stops the run (after
/// the step in flight, checkpointed) and is raised by `rtf.train`.
struct Observer {
    callback: Option<PyObject>,
    raised: Option<PyErr>,
}

impl Observer {
    fn call(&mut self, kind: &str, stage: &str, record: serde_json::Value) {
        let Some(callback) = &self.callback else {
            return;
        };
        if self.raised.is_some() {
            return;
        }
        let result = Python::with_gil(|py| {
            callback
                .call1(py, (kind, stage, record.to_string()))
                .and_then(|_| py.check_signals())
        });
        if let Err(err) = result {
            self.raised = Some(err);
            STOP.store(true, Ordering::SeqCst);
        }
    }
}

impl Progress for Observer {
    fn epoch(&mut self, stage: &str, record: &EpochRecord) {
        let record = serde_json::to_value(record).unwrap_or_default();
        self.call("epoch", stage, record)
    }

    fn step(&mut self, stage: &str, record: &StepRecord) {
        let record = serde_json::json!({
            "epoch": record.epoch,
            "step": record.step,
            "loss": record.loss,
            "losses": record.terms,
        });
        self.call("step", stage, record)
    }
}

/// Set by Ctrl-C or SIGTERM while `rtf.train` runs (or by the callback's exception).
static STOP: AtomicBool = AtomicBool::new(false);

/// SIGINT and SIGTERM set [`STOP`] while this lives; the handlers before it (Python's) are
/// restored when it is dropped, and the flag cleared for the next run.
struct StopOnSignals {
    before: [(libc::c_int, libc::sigaction); 2],
}

impl StopOnSignals {
    fn install() -> Self {
        extern "C" fn on_signal(_: libc::c_int) {
            STOP.store(true, Ordering::SeqCst);
        }
        STOP.store(false, Ordering::SeqCst);
        let install = |signal| {
            // SAFETY: sigaction with a zeroed, then filled, struct; the handler only stores
            // an atomic, which is async-signal-safe. The previous action is kept to restore.
            unsafe {
                let mut action: libc::sigaction = std::mem::zeroed();
                action.sa_sigaction = on_signal as *const () as libc::sighandler_t;
                libc::sigemptyset(&mut action.sa_mask);
                let mut before: libc::sigaction = std::mem::zeroed();
                libc::sigaction(signal, &action, &mut before);
                (signal, before)
            }
        };
        Self {
            before: [install(libc::SIGINT), install(libc::SIGTERM)],
        }
    }
}

impl Drop for StopOnSignals {
    fn drop(&mut self) {
        for (signal, before) in &self.before {
            // SAFETY: restores the action saved by `install` for the same signal.
            unsafe {
                libc::sigaction(*signal, before, std::ptr::null_mut());
            }
        }
        STOP.store(false, Ordering::SeqCst);
    }
}
