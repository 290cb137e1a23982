//! [`Precision`]: the arithmetic a network runs in, for training (an autocast region over fp32
//! master weights) and for the fast inference path (weights folded into that type). One type
//! for both, so a run's `config.json`, a benchmark report and a weights file's metadata name
//! a precision the same way ("fp32", "bf16", "fp16"). And [`Bf16Convolutions`]: how
//! convolutions inside a CPU bf16 region compute, as a run records it. Their tensor types and
//! the policy that decides are rtf-amp's.

use serde::{Deserialize, Serialize};

/// The arithmetic of a training step (PyTorch's automatic mixed precision) or of inference.
///
/// Training: the forward passes and losses run inside an autocast region of the given type
/// (convolutions and matrix products in it, reductions, losses and BatchNorm statistics in
/// fp32); weights, gradients and optimiser state stay fp32. fp16 also scales the loss (a
/// dynamic loss scale, PyTorch's `GradScaler`) so small gradients do not flush to zero; bf16
/// has fp32's exponent range and needs none.
///
/// Inference (rtf-models `fast`): the folded weights and activations are of this type; the
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

/// How convolutions inside a CPU bf16 autocast region are computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Bf16Convolutions {
    /// libtorch's own bf16 kernels (oneDNN's where the CPU has bf16 arithmetic).
    Native,
    /// Operands rounded to bf16, multiply-accumulated by fp32 kernels, outputs and operand
    /// gradients rounded to bf16: a native kernel's numbers (bf16 products are exact in fp32,
    /// native kernels accumulate in fp32) at fp32 kernels' speed, on CPUs whose libtorch bf16
    /// kernels are generic (no avx512_bf16 / AMX: many times slower than fp32; measured:
    /// docs/src/benchmarks.md, section "What bf16 costs on a CPU without bf16 arithmetic"). rtf's
    /// networks route their convolutions through it (rtf-models `layers`).
    Emulated,
    /// Spatial convolutions (3×3 and larger, not transposed) emulated, the others (1×1,
    /// transposed) on libtorch's bf16 kernels: on Intel AVX-512 without AMX, oneDNN's bf16 3×3
    /// kernels lose to its fp32 ones while its 1×1 kernels do not (issue 41; chosen there by
    /// measurement, rtf-train `kernels`).
    Mixed,
}

impl Bf16Convolutions {
    pub fn name(self) -> &'static str {
        match self {
            Bf16Convolutions::Native => "native",
            Bf16Convolutions::Emulated => "emulated",
            Bf16Convolutions::Mixed => "mixed",
        }
    }

    /// A choice as users name it (`native`, `emulated`, `mixed`; spaces around ignored).
    pub fn from_name(text: &str) -> Option<Self> {
        match text.trim() {
            "native" => Some(Bf16Convolutions::Native),
            "emulated" => Some(Bf16Convolutions::Emulated),
            "mixed" => Some(Bf16Convolutions::Mixed),
            _ => None,
        }
    }

    /// Whether a convolution with a spatial kernel (`spatial`: larger than 1×1, not transposed)
    /// or not is computed emulated under this choice.
    pub fn emulates(self, spatial: bool) -> bool {
        match self {
            Bf16Convolutions::Native => false,
            Bf16Convolutions::Emulated => true,
            Bf16Convolutions::Mixed => spatial,
        }
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
        assert!(Precision::Fp16.scales_loss() && !Precision::Bf16.scales_loss());
    }

    #[test]
    fn convolution_choices_read_as_named_and_emulate_as_they_say() {
        use Bf16Convolutions::*;
        assert_eq!(Bf16Convolutions::from_name(" native"), Some(Native));
        assert_eq!(Bf16Convolutions::from_name("mixed"), Some(Mixed));
        assert_eq!(Bf16Convolutions::from_name("fast"), None);
        for c in [Native, Emulated, Mixed] {
            assert_eq!(Bf16Convolutions::from_name(c.name()), Some(c));
        }
        assert!(Mixed.emulates(true) && !Mixed.emulates(false));
        assert!(Emulated.emulates(false) && !Native.emulates(true));
    }
}
