//! Autocast regions (automatic mixed precision) on every libtorch device, CPU included.
//!
//! Inside a region, libtorch's autocast dispatch runs the ops that profit from lower precision
//! (convolutions, matrix products) in a reduced float type and keeps the precision-sensitive
//! ones (reductions, losses, BatchNorm statistics) in fp32, with fp32 master weights cast once
//! per region (PyTorch's `torch.autocast`, "Automatic Mixed Precision" in the PyTorch docs;
//! Micikevicius et al., "Mixed Precision Training", ICLR 2018). tch 0.26's `tch::autocast`
//! drives only CUDA's state, so the state of any device type is set through a small C++ shim
//! (`csrc/amp_shim.cpp`) over `at::autocast::{set_autocast_enabled, set_autocast_dtype}`.
//!
//! [`autocast`] enters a region for one closure; [`AutocastGuard`] restores the previous state
//! when dropped, also when the closure panics. How a network's convolutions compute in bf16
//! inside a CPU region ([`Bf16Convolutions`], decided by a [`Bf16Policy`] the caller
//! resolves) is the network's own value (rtf-models' `UnitKernels`), which it asks
//! [`emulates_bf16_convolution`] with: a value passed in, not a switch of the thread.

use std::ffi::c_int;

mod convolutions;
mod cpu;
mod precision;
pub use convolutions::{Bf16Convolutions, Bf16Policy, BF16_CONVOLUTIONS_VAR};
pub use cpu::{Bf16Arithmetic, IsaCap, ONEDNN_ISA_VARS};
pub use precision::{Precision, PrecisionOnDevice};

use tch::{Device, Kind};

extern "C" {
    fn rtf_amp_get(device_type: c_int, enabled: *mut c_int, dtype: *mut c_int) -> c_int;
    fn rtf_amp_set(device_type: c_int, enabled: c_int, dtype: c_int) -> c_int;
    fn rtf_amp_enter() -> c_int;
    fn rtf_amp_exit() -> c_int;
}

/// Errors of the autocast shim and of a bad bf16 convolution choice.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum AmpError {
    #[error("libtorch refused to {0} autocast")]
    Refused(&'static str),
    #[error("autocast to {kind:?} is not supported on {device:?} (CPU: bf16; CUDA: bf16, fp16)")]
    Unsupported { device: Device, kind: Kind },
    #[error("environment variable {BF16_CONVOLUTIONS_VAR}=`{0}`: expected `native`, `emulated` or `mixed`")]
    BadConvolutionChoice(String),
}

/// c10::DeviceType code of `device` (c10/core/DeviceType.h: CPU = 0, CUDA = 1, MPS = 13,
/// Vulkan = 10).
fn device_type(device: Device) -> c_int {
    match device {
        Device::Cpu => 0,
        Device::Cuda(_) => 1,
        Device::Vulkan => 10,
        Device::Mps => 13,
    }
}

/// c10::ScalarType code of the float kinds autocast casts to (torch/headeronly/core/ScalarType.h).
fn scalar_type(kind: Kind) -> c_int {
    match kind {
        Kind::Half => 5,
        Kind::Float => 6,
        Kind::BFloat16 => 15,
        // Never reached: only supported kinds are set, and Float is the neutral value.
        _ => 6,
    }
}

fn kind_of(code: c_int) -> Option<Kind> {
    match code {
        5 => Some(Kind::Half),
        6 => Some(Kind::Float),
        15 => Some(Kind::BFloat16),
        _ => None,
    }
}

/// Autocast state of one device type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct State {
    pub enabled: bool,
    /// The reduced type autocast casts to (libtorch's defaults: bf16 on CPU, fp16 on CUDA;
    /// Float for a type this crate does not name).
    pub dtype: Kind,
}

/// The calling thread's autocast state for `device`'s type.
pub fn state(device: Device) -> Result<State, AmpError> {
    let (mut enabled, mut dtype) = (0, 0);
    // SAFETY: the shim writes two ints through valid pointers and catches every C++ exception.
    let status = unsafe { rtf_amp_get(device_type(device), &mut enabled, &mut dtype) };
    if status != 0 {
        return Err(AmpError::Refused("read"));
    }
    Ok(State {
        enabled: enabled != 0,
        dtype: kind_of(dtype).unwrap_or(Kind::Float),
    })
}

fn set_state(device: Device, state: State) -> Result<(), AmpError> {
    // SAFETY: plain values in; the shim catches every C++ exception.
    let status = unsafe {
        rtf_amp_set(
            device_type(device),
            c_int::from(state.enabled),
            scalar_type(state.dtype),
        )
    };
    if status != 0 {
        return Err(AmpError::Refused("set"));
    }
    Ok(())
}

/// Whether `kind` is an autocast type libtorch supports on `device`.
pub fn supported(device: Device, kind: Kind) -> bool {
    match device {
        Device::Cpu => kind == Kind::BFloat16,
        Device::Cuda(_) => matches!(kind, Kind::BFloat16 | Kind::Half),
        _ => false,
    }
}

/// Whether a convolution of an input on `device` made now, on this thread, computes as the
/// emulated bf16 one: inside a CPU bf16 autocast region, where `convolutions` (the network's
/// choice) emulates such a convolution (`spatial`: a kernel larger than 1×1, not transposed;
/// [`Bf16Convolutions::emulates`]). Outside any region, nothing is.
pub fn emulates_bf16_convolution(
    device: Device,
    spatial: bool,
    convolutions: Bf16Convolutions,
) -> bool {
    device == Device::Cpu
        && convolutions.emulates(spatial)
        && state(Device::Cpu).is_ok_and(|s| s.enabled && s.dtype == Kind::BFloat16)
}

/// An open autocast region on one device type; dropping it leaves the region and restores the
/// state before it (the weight-cast cache is dropped when the outermost region ends).
#[derive(Debug)]
pub struct AutocastGuard {
    device: Device,
    previous: State,
}

impl AutocastGuard {
    /// Enters an autocast region to `kind` on `device`'s type for this thread.
    pub fn enter(device: Device, kind: Kind) -> Result<Self, AmpError> {
        if !supported(device, kind) {
            return Err(AmpError::Unsupported { device, kind });
        }
        let previous = state(device)?;
        set_state(
            device,
            State {
                enabled: true,
                dtype: kind,
            },
        )?;
        // SAFETY: no arguments; the shim catches every C++ exception.
        if unsafe { rtf_amp_enter() } != 0 {
            let _ = set_state(device, previous);
            return Err(AmpError::Refused("enter"));
        }
        Ok(Self { device, previous })
    }
}

impl Drop for AutocastGuard {
    fn drop(&mut self) {
        // SAFETY: no arguments; the shim catches every C++ exception. Failures cannot be
        // reported from drop; the state setter below is the part that matters.
        let _ = unsafe { rtf_amp_exit() };
        let _ = set_state(self.device, self.previous);
    }
}

/// `f` inside an autocast region to `kind` on `device` (`None`: `f` as is, no region).
pub fn autocast<T>(
    device: Device,
    kind: Option<Kind>,
    f: impl FnOnce() -> T,
) -> Result<T, AmpError> {
    let _guard = match kind {
        Some(kind) => Some(AutocastGuard::enter(device, kind)?),
        None => None,
    };
    Ok(f())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Tensor;

    #[test]
    fn only_cpu_bf16_regions_emulate_and_only_as_the_network_chose() {
        use Bf16Convolutions::*;
        for choice in [Native, Emulated, Mixed] {
            assert!(
                !emulates_bf16_convolution(Device::Cpu, true, choice),
                "no region open"
            );
            autocast(Device::Cpu, Some(Kind::BFloat16), || {
                for spatial in [true, false] {
                    assert_eq!(
                        emulates_bf16_convolution(Device::Cpu, spatial, choice),
                        choice.emulates(spatial)
                    );
                    assert!(!emulates_bf16_convolution(Device::Cuda(0), spatial, choice));
                }
            })
            .unwrap();
            assert!(
                !emulates_bf16_convolution(Device::Cpu, true, choice),
                "region left"
            );
        }
        let result = std::panic::catch_unwind(|| {
            autocast(Device::Cpu, Some(Kind::BFloat16), || panic!("inside"))
        });
        assert!(result.is_err());
        assert!(
            !emulates_bf16_convolution(Device::Cpu, true, Emulated),
            "region left after a panic"
        );
    }

    fn conv_output_kind() -> Kind {
        let x = Tensor::ones([1, 2, 5, 5], (Kind::Float, Device::Cpu));
        let w = Tensor::ones([3, 2, 3, 3], (Kind::Float, Device::Cpu));
        x.conv2d(&w, None::<Tensor>, [1, 1], [1, 1], [1, 1], 1)
            .kind()
    }

    #[test]
    fn cpu_region_runs_convolutions_in_bf16_and_restores_the_state() {
        let before = state(Device::Cpu).unwrap();
        assert!(!before.enabled);
        assert_eq!(conv_output_kind(), Kind::Float);
        let inside = autocast(Device::Cpu, Some(Kind::BFloat16), || {
            assert!(state(Device::Cpu).unwrap().enabled);
            conv_output_kind()
        })
        .unwrap();
        assert_eq!(inside, Kind::BFloat16);
        assert_eq!(state(Device::Cpu).unwrap(), before);
        assert_eq!(conv_output_kind(), Kind::Float);
    }

    #[test]
    fn nested_regions_restore_the_outer_one() {
        let outer = AutocastGuard::enter(Device::Cpu, Kind::BFloat16).unwrap();
        {
            let _inner = AutocastGuard::enter(Device::Cpu, Kind::BFloat16).unwrap();
        }
        assert!(
            state(Device::Cpu).unwrap().enabled,
            "outer region still open"
        );
        drop(outer);
        assert!(!state(Device::Cpu).unwrap().enabled);
    }

    #[test]
    fn a_panic_inside_the_region_still_restores_the_state() {
        let result = std::panic::catch_unwind(|| {
            autocast(Device::Cpu, Some(Kind::BFloat16), || panic!("inside")).unwrap()
        });
        assert!(result.is_err());
        assert!(!state(Device::Cpu).unwrap().enabled);
    }

    #[test]
    fn no_kind_means_no_region() {
        let kind = autocast(Device::Cpu, None, conv_output_kind).unwrap();
        assert_eq!(kind, Kind::Float);
    }

    #[test]
    fn fp16_on_cpu_is_refused() {
        let err = AutocastGuard::enter(Device::Cpu, Kind::Half).unwrap_err();
        assert!(matches!(err, AmpError::Unsupported { .. }), "{err}");
    }
}
