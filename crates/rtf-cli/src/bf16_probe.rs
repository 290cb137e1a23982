//! This binary's edge of the kernel policy (project issues 41 and 61): the policy read from the
//! environment, once ([`policy`]), and the kernel measurements made in a child process, so that
//! the command's own memory peak, allocator, oneDNN caches and random state are what they would
//! be without them. What is measured, when, and what is said of it is the library's
//! (`rtf_eval::kernels` for inference, `rtf_train::kernels` for training), so a library caller
//! (the Python package) gets the same kernels and warnings; this module only hands it the
//! measurements.

use anyhow::{Context, Result};
use rtf_amp::Bf16Convolutions;
use rtf_eval::kernels::probe::{self, Measured, Probe};
use rtf_eval::kernels::warning::Probed;
use rtf_eval::kernels::KernelPolicy;
use rtf_models::fast::InferenceKernels;

/// Which kind of work the probe times (`rtf bench bf16-probe --work inference|training|conv3x3`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Work {
    /// [`probe::Work::Inference`].
    Inference,
    /// [`probe::Work::Training`].
    Training,
    /// [`probe::Work::Conv3x3Training`]: decides whether bf16 training takes
    /// [`Bf16Convolutions::Mixed`] ([`training_choice`]).
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
}

/// The kernel policy of this process's environment (`RTF_WINOGRAD`, `RTF_BF16_WINOGRAD`,
/// `RTF_BF16_CONVOLUTIONS`, oneDNN's ISA cap): rtf's commands read it here, at their edge, and
/// pass it into the library.
pub fn policy() -> Result<KernelPolicy> {
    Ok(KernelPolicy::from_vars(|var| std::env::var(var).ok())?)
}

/// The cache of kernel measurements, from this process's environment
/// ([`Probe::from_vars`]: `$RTF_CACHE_DIR`, `$XDG_CACHE_HOME/rtf` or `~/.cache/rtf`).
pub fn probe() -> Probe {
    Probe::from_vars(|var| std::env::var_os(var))
}

/// [`probe::Work::Inference`] with `kernels`: cached, else measured in a child process.
pub fn measured_inference(kernels: &InferenceKernels) -> Probed {
    let probe = probe();
    let key = probe::inference_key(&probe, kernels);
    let on = if kernels.bf16_winograd { "on" } else { "off" };
    let env = [(rtf_eval::kernels::BF16_WINOGRAD_VAR, on)];
    probe.measured(&key, || in_child(Work::Inference, &env))
}

/// [`probe::Work::Training`] with `convolutions`: cached, else measured in a child process.
pub fn measured_training(convolutions: Bf16Convolutions) -> Probed {
    let probe = probe();
    let key = rtf_train::kernels::training_key(&probe, convolutions);
    let env = [(rtf_amp::BF16_CONVOLUTIONS_VAR, convolutions.name())];
    probe.measured(&key, || in_child(Work::Training, &env))
}

/// Before bf16 training on the CPU: the run's convolution kernels chosen by the cached
/// [`probe::Work::Conv3x3Training`] measurement (measured first, in a child process, where
/// there is none; rtf_train::kernels::choose_training_convolutions says when it decides).
pub fn training_choice(policy: &KernelPolicy) -> Option<rtf_train::kernels::Choice> {
    rtf_train::kernels::choose_training_convolutions(&policy.bf16, || {
        let probe = probe();
        let key = probe.key(probe::Work::Conv3x3Training.name());
        probe.measured(&key, || in_child(Work::Conv3x3Training, &[]))
    })
}

/// [`measure`] in a child process (`rtf bench bf16-probe`), with `env` set on top of this
/// process's environment and this process's thread count.
fn in_child(work: Work, env: &[(&str, &str)]) -> Result<Measured, String> {
    in_child_or_error(work, env).map_err(|e| format!("{e:#}"))
}

fn in_child_or_error(work: Work, env: &[(&str, &str)]) -> Result<Measured> {
    let exe = std::env::current_exe().context("cannot find the rtf binary for the bf16 probe")?;
    let mut child = std::process::Command::new(&exe);
    child
        .args(["bench", "bf16-probe", "--work", work.name()])
        .env("OMP_NUM_THREADS", tch::get_num_threads().to_string())
        .envs(env.iter().copied())
        .stderr(std::process::Stdio::inherit());
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

/// Times `work` in this process (the child's side): inference with the kernels and training
/// with the convolutions this process's policy gives (the parent sets them in its environment).
pub fn measure(work: Work) -> Result<Measured> {
    let policy = policy()?;
    let measured = match work {
        Work::Inference => {
            let native = policy.bf16.arithmetic.is_native();
            let kernels = InferenceKernels {
                winograd: policy.winograd,
                bf16_winograd: policy.bf16_winograd.unwrap_or(native == Some(false)),
                bf16_convolutions: policy.inference_convolutions(),
            };
            probe::measure_inference(kernels)
        }
        Work::Training => {
            rtf_train::kernels::measure_training(policy.bf16.in_force(None), policy.winograd)
        }
        Work::Conv3x3Training => probe::measure_conv3x3_training(),
    };
    measured.map_err(anyhow::Error::msg)
}
