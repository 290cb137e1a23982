//! The compute section: where a run computes ([`ComputeConfig`], on a device as users name it:
//! [`DeviceName`]), and the kernel choices it recorded so that a resume computes the same
//! numbers: bf16 convolutions, fp32's feature-map layout ([`Fp32Layout`]) and the Winograd
//! forms ([`Forms`]). Which of them is faster on a machine is decided by rtf-train and
//! rtf-kernels, which measure.
use serde::{Deserialize, Serialize};

use crate::Bf16Convolutions;

/// Where a run computes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ComputeConfig {
    /// "cpu", "cuda" or "cuda:N".
    pub device: String,
    /// Processes of a data-parallel run (`torchrun`), recorded by rank 0 when the run starts; a
    /// resume needs as many. None = a single-process run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub world_size: Option<usize>,
    /// bf16 on the CPU: which convolution kernels the run started with
    /// ([`Bf16Convolutions`], chosen by measurement where the CPU has bf16 arithmetic and the
    /// caller's policy leaves it open: `RTF_BF16_CONVOLUTIONS` unset for rtf's binaries;
    /// rtf-train's `kernels::settle_for_run`), recorded so that a resume computes the same
    /// numbers (a `--config` may set it). None = not recorded (fp32, another device, or a
    /// configuration not settled).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bf16_convolutions: Option<Bf16Convolutions>,
    /// fp32 stages: the layout of the feature maps the run started with
    /// ([`Fp32Layout`]; chosen by the caller, `RTF_TRAIN_LAYOUT` for rtf's binaries, else the
    /// faster on the device), recorded so that a resume computes the same sums. None = not
    /// recorded (the faster on the device then: rtf-train's `fp32_layout_faster_on`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fp32_layout: Option<Fp32Layout>,
    /// The Winograd forms the run's training convolutions may take (rtf-kernels `winograd`:
    /// F(4×4, 3×3) for wide fp32 channels-last 3×3 layers): the caller's choice
    /// (`RTF_WINOGRAD` for rtf's binaries, rtf-train's `kernels::settle_winograd`), recorded so
    /// that a resume computes the same sums. Absent from runs recorded before it: all forms.
    #[serde(default)]
    pub winograd: Forms,
}

/// How fp32 training lays out its feature maps. Convolutional networks only: CMX (attention)
/// keeps NCHW.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fp32Layout {
    Nchw,
    ChannelsLast,
}

impl Fp32Layout {
    /// A layout as users name it: `nchw`, or `nhwc` / `channels_last`; `auto` (or nothing)
    /// leaves the choice open (None).
    pub fn parse(text: &str) -> Result<Option<Self>, String> {
        match text.trim() {
            "" | "auto" => Ok(None),
            "nchw" => Ok(Some(Fp32Layout::Nchw)),
            "nhwc" | "channels_last" => Ok(Some(Fp32Layout::ChannelsLast)),
            other => Err(format!(
                "unknown training layout `{other}` (expected nchw, nhwc or auto)"
            )),
        }
    }
}

/// A device as users name it: `cpu`, `cuda` (the first GPU) or `cuda:N`. Whether this machine
/// has it is for libtorch to say (rtf-eval's `available_device`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceName {
    Cpu,
    /// The CUDA device of this index.
    Cuda(usize),
}

impl DeviceName {
    /// `cpu`, `cuda` or `cuda:N`; anything else is an error naming the text.
    pub fn parse(name: &str) -> Result<Self, String> {
        match name {
            "cpu" => Ok(DeviceName::Cpu),
            "cuda" => Ok(DeviceName::Cuda(0)),
            _ => name
                .strip_prefix("cuda:")
                .and_then(|i| i.parse().ok())
                .map(DeviceName::Cuda)
                .ok_or_else(|| format!("unknown device `{name}` (expected cpu, cuda or cuda:N)")),
        }
    }
}

/// Which Winograd forms rtf may take, a kernel choice passed in by the caller (the CLI's
/// `RTF_WINOGRAD`): both (the default), F(2×2, 3×3) only, or none (to compare speeds).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Forms {
    #[default]
    All,
    F23,
    Off,
}

impl Forms {
    /// (F(2×2, 3×3), F(4×4, 3×3)) allowed.
    pub fn enabled(self) -> (bool, bool) {
        match self {
            Forms::All => (true, true),
            Forms::F23 => (true, false),
            Forms::Off => (false, false),
        }
    }
}

impl std::str::FromStr for Forms {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "on" | "all" => Ok(Forms::All),
            "f23" => Ok(Forms::F23),
            "off" => Ok(Forms::Off),
            other => Err(format!("{other:?}: expected on, f23 or off")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_parse_as_users_name_them() {
        assert_eq!(DeviceName::parse("cpu"), Ok(DeviceName::Cpu));
        assert_eq!(DeviceName::parse("cuda"), Ok(DeviceName::Cuda(0)));
        assert_eq!(DeviceName::parse("cuda:1"), Ok(DeviceName::Cuda(1)));
        for bad in ["gpu", "cuda:x", "cuda:"] {
            let err = DeviceName::parse(bad).unwrap_err();
            assert!(err.contains(bad), "{err}");
        }
    }

    #[test]
    fn winograd_forms_read_as_named() {
        assert_eq!("on".parse::<Forms>(), Ok(Forms::All));
        assert_eq!(" f23".parse::<Forms>(), Ok(Forms::F23));
        assert_eq!(
            "off".parse::<Forms>().map(Forms::enabled),
            Ok((false, false))
        );
        assert!("yes".parse::<Forms>().is_err());
    }
}
