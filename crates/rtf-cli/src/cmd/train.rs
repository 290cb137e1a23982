use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Result;
use rtf_train::config::{available_device, Fp32Layout};
use rtf_train::launch::{Ended, Plan};
use rtf_train::progress::Epochs;
use rtf_train::RunConfig;

pub use rtf_train::args::TrainArgs as Args;

pub fn run(args: Args) -> Result<()> {
    let mut plan = Plan::new(&args.request()?)?;
    let ddp = join_job(&mut plan.cfg, args.dist_timeout)?;
    let root = ddp.as_ref().is_none_or(|d| d.is_root());
    // Exit 0 with nothing to do, so a scheduler's resume-until-done loop ends.
    if let Some(finished) = plan.finished()? {
        if root {
            eprintln!("{finished}");
            println!("{}", finished.weights.display());
        }
        return Ok(());
    }
    // Before the trainer records the configuration: bf16 CPU stages record their kernels.
    let policy = crate::bf16_probe::policy()?;
    let (cfg, resume) = (&mut plan.cfg, plan.resume);
    let lines =
        rtf_train::kernels::settle_for_run(cfg, resume, ddp.is_some(), &policy.bf16, || {
            crate::bf16_probe::training_choice(&policy)
        });
    for line in lines.iter().filter(|_| root) {
        eprintln!("{line}");
    }
    rtf_train::kernels::settle_fp32_layout(&mut plan.cfg, plan.resume, layout_asked()?);
    let winograd_asked = std::env::var_os(rtf_eval::kernels::WINOGRAD_VAR).map(|_| policy.winograd);
    rtf_train::kernels::settle_winograd(&mut plan.cfg, winograd_asked);
    prepare_arithmetic(&plan.cfg, &policy.bf16, root)?;
    let stop = stop_on_signals();
    if root {
        eprintln!("{}", announcement(&plan));
    }
    match plan.train(&mut Epochs(print_epoch), stop, ddp)? {
        Ended::Trained(path) if root => println!("{}", path.display()),
        Ended::Trained(_) => {}
        Ended::Interrupted { stage, state } => interrupted(&plan.run_dir, stage, &state),
    }
    Ok(())
}

/// The fp32 training layout `RTF_TRAIN_LAYOUT` asks for (`nchw`, `nhwc`; unset or `auto`:
/// None, the faster on the device).
pub fn layout_asked() -> Result<Option<Fp32Layout>> {
    let var = std::env::var("RTF_TRAIN_LAYOUT").unwrap_or_default();
    Fp32Layout::parse(&var).map_err(|e| anyhow::anyhow!("RTF_TRAIN_LAYOUT: {e}"))
}

/// What the run about to train is, said before its first step.
fn announcement(plan: &Plan) -> String {
    match &plan.cfg {
        RunConfig::Single(single) => format!(
            "training {} ({}) for {} epochs into {}",
            single.network.model.name(),
            single.learning.procedure.name(),
            single.schedule.epochs,
            plan.run_dir.display()
        ),
        RunConfig::Pipeline(pipeline) => {
            let names: Vec<&str> = pipeline.stages.iter().map(|s| s.name.as_str()).collect();
            format!(
                "training {} stage(s) ({}) into {}",
                names.len(),
                names.join(" → "),
                plan.run_dir.display()
            )
        }
    }
}

/// Warns (on the root process) when a stage's precision will train slowly on its device, and
/// sets the allocator's policy for the first stage's arithmetic (process-wide).
fn prepare_arithmetic(cfg: &RunConfig, policy: &rtf_amp::Bf16Policy, root: bool) -> Result<()> {
    let mut slow = None;
    for (i, (_, stage)) in cfg.stages().into_iter().enumerate() {
        let device = available_device(&stage.compute.device).map_err(anyhow::Error::msg)?;
        // Only the root process warns, so only it may run the bf16 probe (issue 41).
        if root {
            let convolutions = rtf_train::config::bf16_convolutions_in_force(&stage.compute);
            let measured = || crate::bf16_probe::measured_training(convolutions);
            let precision = stage.learning.precision;
            slow = slow.or_else(|| {
                rtf_train::kernels::training_warning(
                    policy,
                    convolutions,
                    precision,
                    device,
                    measured,
                )
            });
        }
        if i == 0 {
            let layout = stage.compute.fp32_layout;
            let layout = layout.unwrap_or_else(|| rtf_train::config::fp32_layout_faster_on(device));
            crate::allocator::set_purge_delay_for_training(
                stage.learning.precision,
                device,
                layout,
            );
        }
    }
    if let Some(warning) = slow {
        eprintln!("warning: {warning}");
    }
    Ok(())
}

type Group = Option<std::sync::Arc<rtf_train::ddp::Ddp>>;

/// A run stopped by a signal: its checkpoint is written; says how to continue, exits 130.
fn interrupted(
    run_dir: &Path,
    stage: Option<String>,
    state: &rtf_train::checkpoint::TrainState,
) -> ! {
    let batch = state.partial.as_ref().map_or(0, |p| p.batches);
    let stage = stage.map_or(String::new(), |s| format!(" (stage {s})"));
    eprintln!(
        "interrupted{stage} in epoch {} after batch {batch}: checkpoint written; continue with \
         `rtf train --resume {}`",
        state.epochs_done + 1,
        run_dir.display()
    );
    std::process::exit(130);
}

/// A rank's sockets to its peers: when a peer dies, a write to its socket must fail with
/// EPIPE, which gloo reports as an error (the survivors then stop with a clear message and
/// rank 0 checkpoints), not kill this rank with SIGPIPE, whose default `main` restores for
/// `rtf … | head`. Which of the two a killed peer caused depended on whether this rank was
/// reading or writing at that moment (a flaky CI failure: rank 0 died of signal 13).
fn ignore_broken_pipes() {
    #[cfg(unix)]
    // SAFETY: sets the process-wide disposition of one signal to "ignore"; no handler runs,
    // so no code is executed in signal context.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_IGN);
    }
}

/// Under a launcher (torchrun, Slurm, a PyTorchJob: `WORLD_SIZE` set), joins the job's c10d
/// group (rtf_train::ddp::join), this rank's broken pipes ignored first.
fn join_job(cfg: &mut RunConfig, timeout_s: u64) -> Result<Group> {
    let Some(env) = rtf_dist::DistEnv::from_vars(|name| std::env::var(name).ok())? else {
        return Ok(None);
    };
    ignore_broken_pipes();
    let timeout = std::time::Duration::from_secs(timeout_s.max(1));
    Ok(Some(rtf_train::ddp::join(&env, cfg, timeout)?))
}

/// An epoch's line on stderr.
fn print_epoch(stage: &str, r: &rtf_train::EpochRecord) {
    {
        let val = r.val.as_ref().map_or(String::new(), |v| {
            let dn = match (v.miou_day, v.miou_night) {
                (Some(d), Some(n)) => format!(" (day {:.1}, night {:.1})", 100.0 * d, 100.0 * n),
                _ => String::new(),
            };
            format!("  val mIoU {:.1}{dn}", 100.0 * v.miou)
        });
        let terms: Vec<String> = r
            .losses
            .iter()
            .filter(|(k, _)| r.losses.len() > 1 || k.as_str() != "ce")
            .map(|(k, v)| format!("{k} {v:.4}"))
            .chain(
                r.metrics
                    .iter()
                    .map(|(k, v)| format!("{k} {:.0}%", 100.0 * v)),
            )
            .collect();
        let terms = match terms.is_empty() {
            true => String::new(),
            false => format!(" [{}]", terms.join(", ")),
        };
        let prefix = match stage.is_empty() {
            true => String::new(),
            false => format!("{stage}: "),
        };
        eprintln!(
            "{prefix}epoch {:>3}  lr {:.5}  loss {:.4}{terms}  {:.1} img/s  data wait {:.0}%{val}",
            r.epoch + 1,
            r.lr,
            r.train_loss,
            r.images_per_s,
            100.0 * r.data_wait_fraction
        );
    }
}

/// Set by the first Ctrl-C or SIGTERM (what schedulers and preemption send); training then
/// checkpoints and stops after the step in flight.
static STOP: AtomicBool = AtomicBool::new(false);

/// Installs SIGINT and SIGTERM handlers that set [`STOP`] (a second signal kills as usual).
fn stop_on_signals() -> &'static AtomicBool {
    #[cfg(unix)]
    {
        extern "C" fn on_signal(signal: libc::c_int) {
            STOP.store(true, Ordering::SeqCst);
            // SAFETY: signal() is async-signal-safe; restores the default for a second signal.
            unsafe {
                libc::signal(signal, libc::SIG_DFL);
            }
        }
        for signal in [libc::SIGINT, libc::SIGTERM] {
            // SAFETY: the handler only stores an atomic and calls signal(), both allowed in
            // a signal handler.
            unsafe {
                libc::signal(signal, on_signal as *const () as libc::sighandler_t);
            }
        }
    }
    &STOP
}
