//! HeatNet's segmentation network options (Vertens et al., IROS 2020; spec §5): which inputs
//! it fuses. The network is rtf-models' `heatnet`.

use serde::{Deserialize, Serialize};

/// Which inputs the segmentation network takes.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum Inputs {
    /// Separate RGB and IR stem + layer1 + layer2, concatenated into a shared layer3.
    #[default]
    Late,
    /// One backbone on the 4-channel RGB-T image.
    Early,
    Rgb,
    Ir,
}

impl Inputs {
    pub const ALL: [Inputs; 4] = [Inputs::Late, Inputs::Early, Inputs::Rgb, Inputs::Ir];

    pub fn suffix(self) -> &'static str {
        match self {
            Inputs::Late => "",
            Inputs::Early => "-early",
            Inputs::Rgb => "-rgb",
            Inputs::Ir => "-ir",
        }
    }
}

/// The reference preprocessing: both modalities in [0, 1], then (x − 0.5) / 0.5.
pub fn freiburg_input() -> rtf_core::InputConvention {
    rtf_core::InputConvention::MeanStd {
        mean: 0.5,
        std: 0.5,
    }
}

#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub num_classes: i64,
    #[serde(default)]
    pub inputs: Inputs,
    #[serde(default = "freiburg_input")]
    pub input: rtf_core::InputConvention,
}

impl Config {
    pub fn new(inputs: Inputs, num_classes: i64) -> Self {
        Self {
            num_classes,
            inputs,
            input: freiburg_input(),
        }
    }

    pub fn name(&self) -> String {
        format!("heatnet{}", self.inputs.suffix())
    }
}
