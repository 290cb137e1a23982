//! [`Precision`] (rtf-config's, the schema's) on libtorch: its tensor types and what it means on
//! a device ([`PrecisionOnDevice`]).

use tch::{Device, Kind};

pub use rtf_config::Precision;

use crate::{Bf16Convolutions, Bf16Policy};

/// What a [`Precision`] is in libtorch's terms: its tensor type, its autocast type, and how it
/// runs on a device.
pub trait PrecisionOnDevice: Copy {
    /// The tensor type of this precision.
    fn kind(self) -> Kind;
    /// The autocast type; None = fp32, no autocast region.
    fn autocast_kind(self) -> Option<Kind>;
    /// A warning when this precision will train far slower than fp32 on `device`: bf16 on a CPU
    /// without native bf16 arithmetic (`policy.arithmetic`) where libtorch's own bf16
    /// convolutions were asked for (`RTF_BF16_CONVOLUTIONS=native`) over rtf's emulated ones.
    fn slow_on(self, device: Device, policy: &Bf16Policy) -> Option<String>;
    /// The convolution arithmetic of this precision on `device` with `convolutions` (a CPU bf16
    /// region's choice), for reports: "fp32", "bf16 emulated" / "bf16 native" on a CPU, else
    /// the type.
    fn convolutions_on(self, device: Device, convolutions: Bf16Convolutions) -> String;
}

impl PrecisionOnDevice for Precision {
    fn kind(self) -> Kind {
        match self {
            Precision::Fp32 => Kind::Float,
            Precision::Bf16 => Kind::BFloat16,
            Precision::Fp16 => Kind::Half,
        }
    }

    fn autocast_kind(self) -> Option<Kind> {
        match self {
            Precision::Fp32 => None,
            other => Some(PrecisionOnDevice::kind(other)),
        }
    }

    fn slow_on(self, device: Device, policy: &Bf16Policy) -> Option<String> {
        (self == Precision::Bf16
            && device == Device::Cpu
            && policy.arithmetic.is_native() == Some(false)
            && policy.in_force(None) == Bf16Convolutions::Native)
            .then(|| {
                format!(
                    "this CPU has no native bf16 arithmetic ({}) and RTF_BF16_CONVOLUTIONS=native \
                     picks libtorch's generic bf16 convolutions: several times slower than fp32 \
                     (MFNet at 640x480: about 10x, docs/src/benchmarks.md); unset it for rtf's \
                     emulated bf16 convolutions",
                    policy.arithmetic.reason()
                )
            })
    }

    fn convolutions_on(self, device: Device, convolutions: Bf16Convolutions) -> String {
        match (self, device) {
            (Precision::Bf16, Device::Cpu) => format!("bf16 {}", convolutions.name()),
            _ => self.name().to_owned(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fp32_has_no_autocast() {
        assert_eq!(Precision::Fp32.autocast_kind(), None);
        assert_eq!(Precision::Bf16.autocast_kind(), Some(Kind::BFloat16));
        assert_eq!(Precision::Fp16.kind(), Kind::Half);
    }

    #[test]
    fn only_generic_bf16_kernels_asked_for_without_bf16_arithmetic_are_slow() {
        use crate::{Bf16Arithmetic, IsaCap};
        let policy = |asked, native| Bf16Policy {
            asked,
            arithmetic: Bf16Arithmetic::from_flags(Some(native), IsaCap::NONE),
        };
        let native = Some(Bf16Convolutions::Native);
        let line = Precision::Bf16
            .slow_on(Device::Cpu, &policy(native, false))
            .unwrap();
        assert!(
            line.contains("(no avx512_bf16") && line.contains("=native"),
            "{line}"
        );
        assert_eq!(
            Precision::Bf16.slow_on(Device::Cpu, &policy(None, false)),
            None
        );
        assert_eq!(
            Precision::Bf16.slow_on(Device::Cpu, &policy(native, true)),
            None
        );
        assert_eq!(
            Precision::Fp32.slow_on(Device::Cpu, &policy(native, false)),
            None
        );
        let mixed = Precision::Bf16.convolutions_on(Device::Cpu, Bf16Convolutions::Mixed);
        assert_eq!(mixed, "bf16 mixed");
        let cuda = Precision::Bf16.convolutions_on(Device::Cuda(0), Bf16Convolutions::Mixed);
        assert_eq!(cuda, "bf16");
    }
}
