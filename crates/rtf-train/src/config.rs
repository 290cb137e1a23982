//! The full, serialisable description of a training run (written to `RUN/config.json`).

use std::path::PathBuf;

use rtf_data::{AugmentConfig, FreiburgPreprocess};
use rtf_models::ModelConfig;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    pub model: ModelConfig,
    pub dataset: DatasetConfig,
    pub epochs: usize,
    pub batch_size: usize,
    pub seed: u64,
    pub optimizer: OptimizerConfig,
    pub loss: LossConfig,
    pub augment: AugmentConfig,
    /// Resize frames to (width, height) for training and validation; None = as stored.
    pub resize: Option<(usize, usize)>,
    /// Stop each epoch after this many steps (quick experiments); None = full epochs.
    pub max_steps_per_epoch: Option<usize>,
    /// Also write the checkpoint every this many steps inside an epoch (long epochs,
    /// preemptible machines); None = at the end of each epoch only.
    #[serde(default)]
    pub checkpoint_every: Option<usize>,
    /// Decode/augment threads.
    pub workers: usize,
    /// "cpu", "cuda" or "cuda:N".
    pub device: String,
    /// ImageNet ResNet weights (torchvision names, safetensors) loaded into the encoders before
    /// the first step (RTFNet and the ResNet-based baselines).
    #[serde(default)]
    pub backbone_weights: Option<PathBuf>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "format", rename_all = "snake_case")]
pub enum DatasetConfig {
    /// MF layout (spec §1).
    Mf {
        root: PathBuf,
        train_split: String,
        val_split: Option<String>,
    },
    /// Freiburg Thermal (spec §5), supervised: trains on the labelled frames of the training
    /// tree under `root`, validates on the test layout under `root` (if any), each with its
    /// own preprocessing (reference: 960×320, columns 150..850 / 148..852, IR clip).
    Freiburg {
        root: PathBuf,
        #[serde(default = "FreiburgPreprocess::reference_train")]
        train_preprocess: FreiburgPreprocess,
        #[serde(default = "FreiburgPreprocess::reference_test")]
        val_preprocess: FreiburgPreprocess,
        /// Evaluate the test layout after every epoch.
        #[serde(default = "yes")]
        validate: bool,
    },
}

fn yes() -> bool {
    true
}

impl DatasetConfig {
    /// A Freiburg Thermal root with the reference preprocessing.
    pub fn freiburg(root: PathBuf, validate: bool) -> Self {
        DatasetConfig::Freiburg {
            root,
            train_preprocess: FreiburgPreprocess::reference_train(),
            val_preprocess: FreiburgPreprocess::reference_test(),
            validate,
        }
    }
}

/// Which update rule [`crate::optim::Optimizer`] applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OptimizerKind {
    /// SGD with momentum (MFNet, RTFNet).
    #[default]
    Sgd,
    /// RMSprop (HeatNet).
    Rmsprop,
}

/// Optimiser and learning-rate schedule: the rate is multiplied by `lr_decay` every
/// `decay_every` epochs (MFNet: ×0.94 every epoch; HeatNet: ×0.5 every 30).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OptimizerConfig {
    #[serde(default)]
    pub kind: OptimizerKind,
    pub lr: f64,
    pub momentum: f64,
    pub weight_decay: f64,
    pub lr_decay: f64,
    #[serde(default = "one")]
    pub decay_every: usize,
    /// RMSprop's smoothing constant (PyTorch: 0.99).
    #[serde(default = "rmsprop_alpha")]
    pub alpha: f64,
    /// RMSprop's denominator term (PyTorch: 1e-8).
    #[serde(default = "rmsprop_eps")]
    pub eps: f64,
}

fn one() -> usize {
    1
}
fn rmsprop_alpha() -> f64 {
    0.99
}
fn rmsprop_eps() -> f64 {
    1e-8
}

impl OptimizerConfig {
    /// MFNet paper: SGD, lr 0.01, momentum 0.9, weight decay 5e-4, ×0.94 per epoch.
    pub fn mfnet_paper() -> Self {
        Self {
            kind: OptimizerKind::Sgd,
            lr: 0.01,
            momentum: 0.9,
            weight_decay: 5e-4,
            lr_decay: 0.94,
            decay_every: 1,
            alpha: rmsprop_alpha(),
            eps: rmsprop_eps(),
        }
    }

    /// HeatNet paper (spec §5): RMSprop, lr 1e-4, halved every 30 epochs; PyTorch's RMSprop
    /// defaults otherwise (no momentum, no weight decay).
    pub fn heatnet_paper() -> Self {
        Self {
            kind: OptimizerKind::Rmsprop,
            lr: 1e-4,
            momentum: 0.0,
            weight_decay: 0.0,
            lr_decay: 0.5,
            decay_every: 30,
            ..Self::mfnet_paper()
        }
    }

    /// Learning rate of a (0-based) epoch.
    pub fn lr_at(&self, epoch: usize) -> f64 {
        self.lr * self.lr_decay.powi((epoch / self.decay_every.max(1)) as i32)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum LossConfig {
    /// Pixel-wise cross-entropy over all classes; the class set's ignore id is skipped.
    CrossEntropy { class_weights: Option<Vec<f64>> },
}

impl TrainConfig {
    /// MFNet paper's recipe on an MF-layout dataset (spec §3): 80 epochs, batch 6, SGD ×0.94,
    /// horizontal flips.
    pub fn mfnet_paper(root: PathBuf) -> Self {
        Self {
            model: ModelConfig::from_name("mfnet", 9).expect("mfnet is a known network"),
            dataset: DatasetConfig::Mf {
                root,
                train_split: "train".into(),
                val_split: Some("val".into()),
            },
            epochs: 80,
            batch_size: 6,
            seed: 0,
            optimizer: OptimizerConfig::mfnet_paper(),
            loss: LossConfig::CrossEntropy {
                class_weights: None,
            },
            augment: AugmentConfig {
                hflip: true,
                ..Default::default()
            },
            resize: None,
            max_steps_per_epoch: None,
            checkpoint_every: None,
            workers: 2,
            device: "cpu".into(),
            backbone_weights: None,
        }
    }

    /// The configured device, checked to exist on this machine.
    pub fn device(&self) -> Result<tch::Device, String> {
        available_device(&self.device)
    }
}

/// "cpu", "cuda" (first GPU) or "cuda:N".
pub fn parse_device(name: &str) -> Result<tch::Device, String> {
    match name {
        "cpu" => Ok(tch::Device::Cpu),
        "cuda" => Ok(tch::Device::Cuda(0)),
        _ => name
            .strip_prefix("cuda:")
            .and_then(|i| i.parse().ok())
            .map(tch::Device::Cuda)
            .ok_or_else(|| format!("unknown device `{name}` (expected cpu, cuda or cuda:N)")),
    }
}

/// [`parse_device`], then checks libtorch can use it here, so a missing GPU is a clear error
/// rather than a libtorch panic at the first tensor.
pub fn available_device(name: &str) -> Result<tch::Device, String> {
    let device = parse_device(name)?;
    if let tch::Device::Cuda(index) = device {
        let count = tch::Cuda::device_count();
        if index as i64 >= count {
            return Err(format!(
                "device `{name}` is not available: libtorch sees {count} CUDA device(s) here{}",
                if tch::Cuda::is_available() {
                    ""
                } else {
                    " (no usable NVIDIA driver, or a CPU-only libtorch)"
                }
            ));
        }
    }
    Ok(device)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule_decays_per_epoch() {
        let sgd = OptimizerConfig::mfnet_paper();
        assert_eq!(sgd.lr_at(0), 0.01);
        assert!((sgd.lr_at(2) - 0.01 * 0.94 * 0.94).abs() < 1e-15);
        let heatnet = OptimizerConfig::heatnet_paper();
        assert_eq!(heatnet.lr_at(29), 1e-4);
        assert_eq!(heatnet.lr_at(30), 0.5e-4);
        assert_eq!(heatnet.lr_at(99), 0.125e-4);
    }

    #[test]
    fn optimizer_configs_written_before_rmsprop_still_read() {
        let old = r#"{"lr": 0.01, "momentum": 0.9, "weight_decay": 0.0005, "lr_decay": 0.94}"#;
        let cfg: OptimizerConfig = serde_json::from_str(old).unwrap();
        assert_eq!(cfg, OptimizerConfig::mfnet_paper());
    }

    #[test]
    fn config_round_trips_through_json() {
        let cfg = TrainConfig::mfnet_paper("data/mf".into());
        let json = serde_json::to_string_pretty(&cfg).unwrap();
        assert_eq!(serde_json::from_str::<TrainConfig>(&json).unwrap(), cfg);
        assert!(json.contains("\"seed\""));
    }

    #[test]
    fn freiburg_dataset_round_trips_and_defaults_to_the_reference_preprocessing() {
        let cfg = DatasetConfig::freiburg("data/freiburg".into(), true);
        let json = serde_json::to_string(&cfg).unwrap();
        assert_eq!(serde_json::from_str::<DatasetConfig>(&json).unwrap(), cfg);
        let short = r#"{"format": "freiburg", "root": "data/freiburg"}"#;
        assert_eq!(serde_json::from_str::<DatasetConfig>(short).unwrap(), cfg);
    }

    #[test]
    fn devices_parse() {
        assert_eq!(parse_device("cpu"), Ok(tch::Device::Cpu));
        assert_eq!(parse_device("cuda:1"), Ok(tch::Device::Cuda(1)));
        assert!(parse_device("tpu").is_err());
    }

    #[test]
    fn unavailable_gpus_are_a_clear_error() {
        assert_eq!(available_device("cpu"), Ok(tch::Device::Cpu));
        let count = tch::Cuda::device_count();
        let missing = format!("cuda:{count}");
        let err = available_device(&missing).unwrap_err();
        assert!(
            err.contains(&missing) && err.contains("not available"),
            "{err}"
        );
    }
}
