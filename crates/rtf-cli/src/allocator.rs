//! The `rtf` binary's allocator: mimalloc in place of the C library's `malloc`, for libtorch's
//! tensors too, with freed memory returned to the system only after 5 s unused.
//!
//! libtorch's CPU tensors come from `malloc`. With glibc's defaults every multi-megabyte
//! activation is a fresh `mmap`, page-faulted in again on every pass, which slows inference
//! against keeping the memory (measured: docs/src/models.md, section "Fast inference").
//! Keeping glibc's freed memory instead (`rtf_kernels::allocator::retain_freed_memory`) fixed
//! the speed but not training's memory: a training step's many differently sized activations
//! fragment glibc's one heap, and MFNet's training peak rose above PyTorch's (measured:
//! docs/src/benchmarks.md, section "Allocator (commit 7647062)"). mimalloc serves large blocks
//! from size-segregated segments that it reuses without fragmenting.
//!
//! How long freed memory stays mapped decides speed against peak memory: mimalloc's default
//! 1 s purge delay slowed training, purging off raised the ResNet-50 networks' peaks above
//! PyTorch's, and a 5 s delay kept a small network's speed and brought the big ones' peaks
//! under PyTorch's (measured: docs/src/benchmarks.md, sections "Round 3: the issue's size on a
//! quiet machine" and "Round 4: a 5 s purge delay"). A delay longer than a small network's
//! whole step keeps its buffers for the next step; shorter than a big network's forward or
//! backward pass, it returns the blocks that pass freed and will not reuse, which is what
//! fragmented the peak.
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
/// ResNet-50 network's forward or backward pass on 2 cores lasts longer than 5 s in either
/// precision, so with 5 s the memory a backward pass freed was returned and faulted back in
/// (zeroed) by the next forward, a large share of the step. 20 s keeps it for the next pass,
/// faster, at a peak still below PyTorch's best configuration, where purging off goes above
/// it (measured: docs/src/benchmarks.md, the purge-delay sweep under "Round 5: a CPU with bf16
/// arithmetic" for bf16, and section "Before and after (interleaved A/B)" for fp32
/// channels-last). fp32 NCHW (AVX2 CPUs) keeps 5 s: longer delays raised RTFNet-50's and
/// PSPNet-50's peaks above PyTorch's there (same page, sections "Round 3: the issue's size on
/// a quiet machine" and "Round 4: a 5 s purge delay").
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
