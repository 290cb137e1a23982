//! The configuration of a run: rtf-config's schema (re-exported here, where the trainer reads
//! it), and what of it needs libtorch or this machine: the device it names, found here; the
//! fp32 layout that is faster on a device; the bf16 convolutions in force; cuDNN's autotuner.

pub use rtf_config::compute::Forms;
pub use rtf_config::train::*;

/// Devices as users name them ("cpu", "cuda", "cuda:N"), found on this machine: rtf-eval's,
/// where every command that runs a network (and `rtf report`) finds them.
pub use rtf_eval::device::{available_device, parse_device};

/// The layout fp32 training measured faster in on `device`: channels-last on CUDA (cuDNN's
/// TF32 convolutions are laid out for NHWC; docs/src/gpu.md) and on CPUs with AVX-512
/// (`avx512f`: oneDNN's fp32 training kernels take channels-last operands without reorders);
/// NCHW on CPUs without (docs/src/benchmarks.md).
pub fn fp32_layout_faster_on(device: tch::Device) -> Fp32Layout {
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

/// The bf16 convolutions a run's CPU autocast regions compute with: the recorded choice, else
/// (a configuration not settled by [`crate::kernels::settle_for_run`]) the default of this
/// CPU's flags without a user's choice or an ISA cap ([`rtf_amp::Bf16Policy::default`]).
pub fn bf16_convolutions_in_force(compute: &ComputeConfig) -> rtf_amp::Bf16Convolutions {
    compute
        .bf16_convolutions
        .unwrap_or_else(|| rtf_amp::Bf16Policy::default().in_force(None))
}

/// Whether cuDNN's autotuner runs (PyTorch's `torch.backends.cudnn.benchmark = True`): each
/// convolution shape is timed once over cuDNN's algorithms and the fastest kept, which pays
/// for rtf's fixed frame sizes. On unless the caller's `RTF_CUDNN_BENCHMARK` (read by `get`,
/// the binary's environment) is `0`. A libtorch setting of the whole process: the binary sets
/// it (`tch::Cuda::cudnn_set_benchmark`).
pub fn cudnn_benchmark(get: impl Fn(&str) -> Option<String>) -> bool {
    get("RTF_CUDNN_BENCHMARK").as_deref() != Some("0")
}

#[cfg(test)]
mod tests;
