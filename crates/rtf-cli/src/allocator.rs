//! The `rtf` binary's allocator: mimalloc in place of the C library's `malloc`, for libtorch's
//! tensors too, with freed memory kept in the process.
//!
//! libtorch's CPU tensors come from `malloc`. With glibc's defaults every multi-megabyte
//! activation is a fresh `mmap`, page-faulted in again on every pass (MFNet fp32 inference 66
//! against 45 ms per frame with memory kept: docs/src/models.md). Keeping glibc's freed memory
//! instead (`rtf_models::allocator::retain_freed_memory`) fixed the speed but not training's
//! memory: a training step's many differently sized activations fragment glibc's one heap, and
//! MFNet at 640×480, batch 4 peaked at 3.0–4.1 GB against PyTorch's 2.9–3.1 GB. mimalloc serves
//! large blocks from size-segregated segments that it reuses without fragmenting, and with
//! purging off it keeps them mapped: measured in one run (docs/src/benchmarks.md) 1.52 images/s
//! at 2.6 GB peak RSS, against glibc kept 1.51 at 3.0 GB, glibc defaults 0.90 at 2.5 GB and
//! mimalloc's default 1 s purge delay 1.22 at 2.5 GB.
//!
//! The `override` feature of `libmimalloc-sys` links mimalloc's `malloc`, `free`,
//! `posix_memalign`, … into this executable, so the dynamic linker resolves libtorch's calls to
//! them for the whole life of the process (no `LD_PRELOAD`). Rust's own allocations go through
//! the same `malloc`.

use libmimalloc_sys::{mi_option_get, mi_option_set, mi_option_t};

/// `mi_option_purge_delay` in mimalloc v3's `mimalloc.h` (milliseconds before freed memory is
/// returned to the OS; −1: never). `libmimalloc-sys` 0.1.49 declares no constant for it.
const MI_OPTION_PURGE_DELAY: mi_option_t = 15;

/// Keeps freed memory mapped for reuse (no purging) unless the user set
/// `MIMALLOC_PURGE_DELAY` (mimalloc's own variable) to choose otherwise. Call once, at the start
/// of `main`, before the tensor work. Returns the purge delay in force.
pub fn keep_freed_memory() -> i64 {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: mi_option_set only stores an option value; mimalloc reads it atomically.
        unsafe { mi_option_set(MI_OPTION_PURGE_DELAY, -1) };
    }
    // SAFETY: reading an option value has no preconditions.
    unsafe { mi_option_get(MI_OPTION_PURGE_DELAY) as i64 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn purge_delay_option_is_the_one_set() {
        // The constant names the right option: its default in mimalloc v3's options.c is 1000 ms
        // (the header's comment still says 10).
        // SAFETY: as in keep_freed_memory.
        let before = unsafe { mi_option_get(MI_OPTION_PURGE_DELAY) };
        if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
            assert_eq!(
                before, 1000,
                "option {MI_OPTION_PURGE_DELAY} is not purge_delay"
            );
            assert_eq!(keep_freed_memory(), -1);
        }
    }

    #[test]
    fn libtorch_allocates_through_mimalloc() {
        // A tensor's storage comes from the overriding malloc: mimalloc knows its block.
        let t = tch::Tensor::ones([16, 1024, 1024], (tch::Kind::Float, tch::Device::Cpu));
        let ptr = t.data_ptr();
        // SAFETY: mi_is_in_heap_region only inspects the address.
        assert!(unsafe { libmimalloc_sys::mi_is_in_heap_region(ptr) });
        assert_eq!(
            t.sum(tch::Kind::Double).double_value(&[]),
            (16 * 1024 * 1024) as f64
        );
    }
}
