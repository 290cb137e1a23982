//! The compute section: where a run computes ([`ComputeConfig`]), fp32's feature-map layout
//! ([`Fp32Layout`]), devices as users name them, and cuDNN's autotuner switch.
use serde::{Deserialize, Serialize};

/// Where a run computes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ComputeConfig {
    /// "cpu", "cuda" or "cuda:N".
    pub device: String,
    /// Processes of a data-parallel run (`torchrun`), recorded by rank 0 when the run starts; a
    /// resume needs as many. None = a single-process run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub world_size: Option<usize>,
    /// bf16 on the CPU: which convolution kernels the run started with
    /// ([`rtf_amp::Bf16Convolutions`], chosen by measurement where the CPU has bf16 arithmetic
    /// and the caller's policy leaves it open: `RTF_BF16_CONVOLUTIONS` unset for rtf's
    /// binaries; [`crate::kernels::settle_for_run`]), recorded so that a resume computes the
    /// same numbers (a `--config` may set it). None = not recorded (fp32, another device, or a
    /// configuration not settled).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bf16_convolutions: Option<rtf_amp::Bf16Convolutions>,
    /// fp32 stages: the layout of the feature maps the run started with
    /// ([`Fp32Layout`]; chosen by the caller, `RTF_TRAIN_LAYOUT` for rtf's binaries, else the
    /// faster on the device), recorded so that a resume computes the same sums. None = not
    /// recorded ([`Fp32Layout::faster_on`] the device then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fp32_layout: Option<Fp32Layout>,
    /// The Winograd forms the run's training convolutions may take (rtf-models `winograd`:
    /// F(4×4, 3×3) for wide fp32 channels-last 3×3 layers): the caller's choice
    /// (`RTF_WINOGRAD` for rtf's binaries, [`crate::kernels::settle_winograd`]), recorded so
    /// that a resume computes the same sums. Absent from runs recorded before it: all forms.
    #[serde(default)]
    pub winograd: rtf_kernels::winograd::Forms,
}

impl ComputeConfig {
    /// The bf16 convolutions the run's CPU autocast regions compute with: the recorded choice,
    /// else (a configuration not settled by [`crate::kernels::settle_for_run`]) the default of
    /// this CPU's flags without a user's choice or an ISA cap ([`rtf_amp::Bf16Policy::default`]).
    pub fn bf16_convolutions_in_force(&self) -> rtf_amp::Bf16Convolutions {
        self.bf16_convolutions
            .unwrap_or_else(|| rtf_amp::Bf16Policy::default().in_force(None))
    }
}

/// How fp32 training lays out its feature maps. Convolutional networks only: CMX (attention)
/// keeps NCHW.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fp32Layout {
    Nchw,
    ChannelsLast,
}

impl Fp32Layout {
    /// The layout fp32 training measured faster in on `device`: channels-last on CUDA (cuDNN's
    /// TF32 convolutions are laid out for NHWC; docs/src/gpu.md) and on CPUs with AVX-512
    /// (`avx512f`: oneDNN's fp32 training kernels take channels-last operands without
    /// reorders); NCHW on CPUs without (docs/src/benchmarks.md).
    pub fn faster_on(device: tch::Device) -> Self {
        let avx512 = || {
            rtf_core::host::CpuInfo::read()
                .flags
                .iter()
                .any(|f| f == "avx512f")
        };
        match device {
            tch::Device::Cpu if !avx512() => Fp32Layout::Nchw,
            _ => Fp32Layout::ChannelsLast,
        }
    }

    /// A layout as users name it: `nchw`, or `nhwc` / `channels_last`; `auto` (or nothing)
    /// leaves the choice open (None).
    pub fn parse(text: &str) -> Result<Option<Self>, String> {
        match text.trim() {
            "" | "auto" => Ok(None),
            "nchw" => Ok(Some(Fp32Layout::Nchw)),
            "nhwc" | "channels_last" => Ok(Some(Fp32Layout::ChannelsLast)),
            other => Err(format!(
                "unknown training layout `{other}` (expected nchw, nhwc or auto)"
            )),
        }
    }
}

/// Devices as users name them ("cpu", "cuda", "cuda:N"), found on this machine: rtf-eval's,
/// where every command that runs a network (and `rtf report`) finds them.
pub use rtf_eval::device::{available_device, parse_device};

/// Whether cuDNN's autotuner runs (PyTorch's `torch.backends.cudnn.benchmark = True`): each
/// convolution shape is timed once over cuDNN's algorithms and the fastest kept, which pays
/// for rtf's fixed frame sizes. On unless the caller's `RTF_CUDNN_BENCHMARK` (read by `get`,
/// the binary's environment) is `0`. A libtorch setting of the whole process: the binary sets
/// it (`tch::Cuda::cudnn_set_benchmark`).
pub fn cudnn_benchmark(get: impl Fn(&str) -> Option<String>) -> bool {
    get("RTF_CUDNN_BENCHMARK").as_deref() != Some("0")
}
