//! [`Precision`]: the arithmetic a network runs in, for training (an autocast region over fp32
//! master weights) and for the fast inference path (weights folded into that type). One type
//! for both, so a run's `config.json`, a benchmark report and a weights file's metadata name
//! a precision the same way ("fp32", "bf16", "fp16").

use serde::{Deserialize, Serialize};
use tch::{Device, Kind};

use crate::{Bf16Convolutions, Bf16Policy};

/// The arithmetic of a training step (PyTorch's automatic mixed precision) or of inference.
///
/// Training: the forward passes and losses run inside an autocast region of the given type
/// (convolutions and matrix products in it, reductions, losses and BatchNorm statistics in
/// fp32); weights, gradients and optimiser state stay fp32. fp16 also scales the loss (a
/// dynamic loss scale, PyTorch's `GradScaler`) so small gradients do not flush to zero; bf16
/// has fp32's exponent range and needs none.
///
/// Inference (rtf_models::fast): the folded weights and activations are of this type; the
/// fast path runs fp16 on CUDA only (`rtf_models::fast::check_precision_on`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Precision {
    #[default]
    Fp32,
    Bf16,
    Fp16,
}

impl Precision {
    pub fn name(self) -> &'static str {
        match self {
            Precision::Fp32 => "fp32",
            Precision::Bf16 => "bf16",
            Precision::Fp16 => "fp16",
        }
    }

    /// Any precision (training: `rtf train --precision`, `rtf bench train`).
    pub fn parse(text: &str) -> Result<Self, String> {
        match text {
            "fp32" | "float32" => Ok(Precision::Fp32),
            "bf16" | "bfloat16" => Ok(Precision::Bf16),
            "fp16" | "float16" | "half" => Ok(Precision::Fp16),
            other => Err(format!(
                "unknown precision `{other}` (expected fp32, bf16 or fp16)"
            )),
        }
    }

    /// A precision the fast inference path runs: `rtf eval/predict/export/bench model
    /// --precision`. fp16 runs on CUDA only; the device is checked where it is known
    /// (`rtf_models::fast::check_precision_on`).
    pub fn parse_inference(text: &str) -> Result<Self, String> {
        Self::parse(text)
            .map_err(|_| format!("unknown precision {text:?} (expected fp32, bf16 or fp16 (CUDA))"))
    }

    /// The tensor type of this precision.
    pub fn kind(self) -> Kind {
        match self {
            Precision::Fp32 => Kind::Float,
            Precision::Bf16 => Kind::BFloat16,
            Precision::Fp16 => Kind::Half,
        }
    }

    /// The autocast type; None = fp32, no autocast region.
    pub fn autocast_kind(self) -> Option<Kind> {
        match self {
            Precision::Fp32 => None,
            other => Some(other.kind()),
        }
    }

    /// A warning when this precision will train far slower than fp32 on `device`: bf16 on a CPU
    /// without native bf16 arithmetic (`policy.arithmetic`) where libtorch's own bf16
    /// convolutions were asked for (`RTF_BF16_CONVOLUTIONS=native`) over rtf's emulated ones.
    pub fn slow_on(self, device: Device, policy: &Bf16Policy) -> Option<String> {
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

    /// The convolution arithmetic of this precision on `device` with `convolutions` (a CPU bf16
    /// region's choice), for reports: "fp32", "bf16 emulated" / "bf16 native" on a CPU, else
    /// the type.
    pub fn convolutions_on(self, device: Device, convolutions: Bf16Convolutions) -> String {
        match (self, device) {
            (Precision::Bf16, Device::Cpu) => format!("bf16 {}", convolutions.name()),
            _ => self.name().to_owned(),
        }
    }

    /// Whether the loss is scaled (fp16 only).
    pub fn scales_loss(self) -> bool {
        self == Precision::Fp16
    }
}

impl std::fmt::Display for Precision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Precision {
    type Err = String;
    fn from_str(text: &str) -> Result<Self, String> {
        Self::parse(text)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The strings of config.json files (snake_case) and of weights metadata / benchmark
    /// reports (lowercase) are the same three: both kinds of files written before the two
    /// enums became one still read.
    #[test]
    fn serialized_names_are_the_ones_written_before() {
        for (p, text) in [
            (Precision::Fp32, "\"fp32\""),
            (Precision::Bf16, "\"bf16\""),
            (Precision::Fp16, "\"fp16\""),
        ] {
            assert_eq!(serde_json::to_string(&p).unwrap(), text);
            assert_eq!(serde_json::from_str::<Precision>(text).unwrap(), p);
            assert_eq!(format!("\"{p}\""), text);
            assert_eq!(Precision::parse(p.name()), Ok(p));
        }
        assert!(serde_json::from_str::<Precision>("\"Fp32\"").is_err());
    }

    #[test]
    fn inference_parsing_names_the_inference_precisions() {
        assert_eq!(Precision::parse_inference("bfloat16"), Ok(Precision::Bf16));
        assert_eq!(Precision::parse_inference("half"), Ok(Precision::Fp16));
        assert_eq!(
            Precision::parse_inference("fp8").unwrap_err(),
            "unknown precision \"fp8\" (expected fp32, bf16 or fp16 (CUDA))"
        );
        assert_eq!(
            Precision::parse("fp8").unwrap_err(),
            "unknown precision `fp8` (expected fp32, bf16 or fp16)"
        );
        assert_eq!(Precision::parse("half"), Ok(Precision::Fp16));
    }

    #[test]
    fn only_fp16_scales_the_loss_and_fp32_has_no_autocast() {
        assert_eq!(Precision::Fp32.autocast_kind(), None);
        assert_eq!(Precision::Bf16.autocast_kind(), Some(Kind::BFloat16));
        assert_eq!(Precision::Fp16.kind(), Kind::Half);
        assert!(Precision::Fp16.scales_loss() && !Precision::Bf16.scales_loss());
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
