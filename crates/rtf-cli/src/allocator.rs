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
use rtf_train::config::Fp32Layout;

/// `mi_option_purge_delay` in mimalloc v3's `mimalloc.h` (milliseconds before freed memory is
/// returned to the OS; −1: never). `libmimalloc-sys` 0.1.49 declares no constant for it.
const MI_OPTION_PURGE_DELAY: mi_option_t = 15;

/// Milliseconds freed memory stays mapped before mimalloc returns it (module docs).
pub const PURGE_DELAY_MS: i64 = 5000;

/// The delay for training on a CPU (`rtf train`, `rtf bench train`) in bf16, and in fp32 where
/// it runs channels-last (`rtf_train::config::Fp32Layout`: AVX-512 CPUs by default). A
/// ResNet-50 network's pass is 6–13 s (bf16) or 10–20 s (fp32) on 2 cores, and with 5 s the
/// memory a backward pass freed was returned and faulted back in by the next forward (page
/// zeroing: PSPNet-50 bf16 20–45 % of the samples at each step's start; RTFNet-50 fp32 16 %
/// of a steady step). 640×480, batch 4, 2 threads (docs/src/benchmarks.md): bf16 on an
/// avx512_bf16 EPYC (round 5), RTFNet-50 0.22 images/s at 7260 MiB with 5 s, 0.24 at 7453 with
/// 20 s, 0.26 at 7851 (above PyTorch's 7830) with purging off; PSPNet-50 0.15 at 6431, 0.21 at
/// 6504, 0.20 at 7278. fp32 channels-last on a Xeon model 167 (issue 41): RTFNet-50 0.150 →
/// 0.163 at 10554 → 11227 MiB (PyTorch's best 11288), PSPNet-50 0.110 → 0.124 at 11191 →
/// 12017 (PyTorch's best 12026). fp32 NCHW (AVX2 CPUs) keeps 5 s: longer delays raised
/// RTFNet-50's and PSPNet-50's peaks above PyTorch's there (round 3).
pub const TRAINING_PURGE_DELAY_MS: i64 = 20_000;

/// Sets mimalloc's purge delay to [`PURGE_DELAY_MS`] unless the user set
/// `MIMALLOC_PURGE_DELAY` (mimalloc's own variable; `-1` never returns memory, `0` at once).
/// Call once, at the start of `main`, before the tensor work. Returns the delay in force.
pub fn set_purge_delay() -> i64 {
    set_purge_delay_ms(PURGE_DELAY_MS)
}

/// Sets mimalloc's purge delay to `ms` unless the user set `MIMALLOC_PURGE_DELAY`; returns the
/// delay in force. mimalloc reads the option each time it considers a purge, so a command may
/// change it once it knows its work (before that work starts).
pub fn set_purge_delay_ms(ms: i64) -> i64 {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: mi_option_set only stores an option value; mimalloc reads it atomically.
        unsafe { mi_option_set(MI_OPTION_PURGE_DELAY, ms as std::ffi::c_long) };
    }
    // SAFETY: reading an option value has no preconditions.
    unsafe { mi_option_get(MI_OPTION_PURGE_DELAY) as i64 }
}

/// Training in `precision` on `device`, fp32 in `layout`: [`TRAINING_PURGE_DELAY_MS`] where it
/// applies (a CPU, bf16 or channels-last fp32).
pub fn set_purge_delay_for_training(
    precision: rtf_train::config::Precision,
    device: tch::Device,
    layout: Fp32Layout,
) {
    let fp32_channels_last =
        precision == rtf_train::config::Precision::Fp32 && layout == Fp32Layout::ChannelsLast;
    let bf16 = precision == rtf_train::config::Precision::Bf16;
    if device == tch::Device::Cpu && (bf16 || fp32_channels_last) {
        set_purge_delay_ms(TRAINING_PURGE_DELAY_MS);
    }
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
            // SAFETY (both reads): as in set_purge_delay.
            let current = || unsafe { mi_option_get(MI_OPTION_PURGE_DELAY) as i64 };
            let (fp32, cpu) = (rtf_train::config::Precision::Fp32, tch::Device::Cpu);
            set_purge_delay_for_training(fp32, cpu, Fp32Layout::Nchw);
            assert_eq!(
                current(),
                PURGE_DELAY_MS,
                "fp32: the longer delay only channels-last"
            );
            set_purge_delay_for_training(fp32, cpu, Fp32Layout::ChannelsLast);
            assert_eq!(current(), TRAINING_PURGE_DELAY_MS);
            assert_eq!(set_purge_delay(), PURGE_DELAY_MS);
            let bf16 = rtf_train::config::Precision::Bf16;
            set_purge_delay_for_training(bf16, cpu, Fp32Layout::Nchw);
            assert_eq!(current(), TRAINING_PURGE_DELAY_MS);
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
