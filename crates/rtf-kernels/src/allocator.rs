//! The process allocator's policy for tensor work.
//!
//! libtorch's CPU tensors come from `malloc`. glibc serves large blocks with fresh `mmap`s
//! and hands freed heap tops back to the kernel, so a network that allocates the same
//! multi-megabyte activations every forward pass page-faults them in again every time, a
//! large share of a small network's pass (measured in docs/src/models.md). PyTorch's CPU
//! performance guides reach for jemalloc/tcmalloc for the same reason.
//!
//! This is the policy for library users on glibc. The `rtf` binary goes further: it links
//! mimalloc in place of `malloc` (rtf-cli's `allocator` module), which keeps freed memory
//! without the fragmentation that this policy lets a training step build up in glibc's heap.

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
