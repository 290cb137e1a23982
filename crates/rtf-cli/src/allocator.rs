//! The `rtf` binary's allocator: mimalloc in place of the C library's `malloc`, for libtorch's
//! tensors too, with freed memory returned to the system only after 5 s unused.
//!
//! libtorch's CPU tensors come from `malloc`. With glibc's defaults every multi-megabyte
//! activation is a fresh `mmap`, page-faulted in again on every pass (MFNet fp32 inference 66
//! against 45 ms per frame with memory kept: docs/src/models.md). Keeping glibc's freed memory
//! instead (`rtf_models::allocator::retain_freed_memory`) fixed the speed but not training's
//! memory: a training step's many differently sized activations fragment glibc's one heap, and
//! MFNet at 640×480, batch 4 peaked at 3.0–4.1 GB against PyTorch's 2.9–3.1 GB. mimalloc serves
//! large blocks from size-segregated segments that it reuses without fragmenting.
//!
//! How long freed memory stays mapped decides speed against peak memory (docs/src/benchmarks.md,
//! 640×480, batch 4, 2 threads, quiet machine): MFNet (a 3 s step) 0.90 images/s with mimalloc's
//! default 1 s purge delay, 1.28–1.52 with purging off or a 5 s delay, at 2.5–2.6 GB; RTFNet-50
//! (a 45 s step) 0.101 images/s at 12.5 GB with purging off (above PyTorch's 11.5 GB), 0.084 at
//! 10.8 GB with 1 s, **0.088 at 10.9 GB with 5 s**; PSPNet-50 0.075 at 13.2 GB off, 0.081 at
//! 11.2 GB with 5 s. A delay longer than a small network's whole step keeps its buffers for the
//! next step; shorter than a big network's forward or backward pass, it returns the blocks that
//! pass freed and will not reuse, which is what fragmented the peak.
//!
//! The `override` feature of `libmimalloc-sys` links mimalloc's `malloc`, `free`,
//! `posix_memalign`, … into this executable, so the dynamic linker resolves libtorch's calls to
//! them for the whole life of the process (no `LD_PRELOAD`). Rust's own allocations go through
//! the same `malloc`.

use libmimalloc_sys::{mi_option_get, mi_option_set, mi_option_t};

/// `mi_option_purge_delay` in mimalloc v3's `mimalloc.h` (milliseconds before freed memory is
/// returned to the OS; −1: never). `libmimalloc-sys` 0.1.49 declares no constant for it.
const MI_OPTION_PURGE_DELAY: mi_option_t = 15;

/// Milliseconds freed memory stays mapped before mimalloc returns it (module docs).
pub const PURGE_DELAY_MS: i64 = 5000;

/// Sets mimalloc's purge delay to [`PURGE_DELAY_MS`] unless the user set
/// `MIMALLOC_PURGE_DELAY` (mimalloc's own variable; `-1` never returns memory, `0` at once).
/// Call once, at the start of `main`, before the tensor work. Returns the delay in force.
pub fn set_purge_delay() -> i64 {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: mi_option_set only stores an option value; mimalloc reads it atomically.
        unsafe { mi_option_set(MI_OPTION_PURGE_DELAY, PURGE_DELAY_MS as std::ffi::c_long) };
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
        // SAFETY: as in set_purge_delay.
        let before = unsafe { mi_option_get(MI_OPTION_PURGE_DELAY) };
        if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
            assert_eq!(
                before, 1000,
                "option {MI_OPTION_PURGE_DELAY} is not purge_delay"
            );
            assert_eq!(set_purge_delay(), PURGE_DELAY_MS);
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
