//! Process-wide settings that make repeated tensor work fast: the allocator's policy on the
//! CPU, cuDNN's algorithm autotuning on CUDA.
//!
//! libtorch's CPU tensors come from `malloc`. glibc serves large blocks with fresh `mmap`s
//! and hands freed heap tops back to the kernel, so a network that allocates the same
//! multi-megabyte activations every forward pass page-faults them in again every time:
//! measured on MFNet at 480×640 (2 cores, fp32 fast path), 66 ms per frame with glibc's
//! defaults against 45 ms with freed memory kept (docs/src/models.md). PyTorch's CPU
//! performance guides reach for jemalloc/tcmalloc for the same reason.

/// Keeps freed memory in the process for reuse: no `mmap`-served blocks, no trimming of
/// the heap. The resident size then stays at its peak, which suits a tool that repeats the
/// same tensor work (training, evaluation, benchmarks). Process-wide; call it once at start
/// of a program, before the tensor work. Returns whether the policy was applied (glibc only;
/// other C libraries keep their own policy and this returns false).
pub fn retain_freed_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt only changes glibc's allocation parameters; it is thread-safe.
        unsafe {
            libc::mallopt(libc::M_MMAP_MAX, 0) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX) == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

/// On a CUDA device, lets cuDNN time its convolution algorithms on the first pass of each
/// input shape and keep the fastest (PyTorch's `cudnn.benchmark`). It pays when the same sizes
/// repeat (evaluation, prediction, training on fixed crops): measured on an H100, MFNet fp32
/// at 480×640 went from 2.83 to 1.87 ms per frame, RTFNet-50 from 8.68 to 7.62
/// (docs/src/getting-started.md). The chosen algorithms may differ between runs, so results on
/// the GPU are reproducible to float rounding, not bit for bit. Process-wide; no effect on
/// the CPU.
pub fn autotune_cuda_convolutions(device: tch::Device) {
    if device.is_cuda() {
        tch::Cuda::cudnn_set_benchmark(true);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn policy_applies_on_glibc_and_allocation_still_works() {
        let applied = retain_freed_memory();
        assert_eq!(applied, cfg!(all(target_os = "linux", target_env = "gnu")));
        // A block far above glibc's mmap threshold now comes from the heap, and is usable.
        let t = tch::Tensor::ones([64, 1024, 1024], (tch::Kind::Float, tch::Device::Cpu));
        assert_eq!(
            t.sum(tch::Kind::Double).double_value(&[]),
            (64 * 1024 * 1024) as f64
        );
    }
}
