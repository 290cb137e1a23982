//! Budgets: how much data and training each cell gets. `smoke` checks the pipeline in CI,
//! `quick` gives small but meaningful numbers on a 2-core CPU, `paper` follows the papers'
//! recipes (MFNet Sec. IV: SGD lr 0.01 ×0.94/epoch, 80 epochs, batch 6, flips, 480×640; RTFNet
//! Sec. IV-B: SGD lr 0.01, momentum 0.9, weight decay 5e-4, exponential decay, flips, "until
//! convergence"; HeatNet Sec. IV: the `rtf recipes` procedures) and is meant for a GPU.

use super::tables::{Data, RecipeFamily};
use anyhow::{bail, Result};
use serde_json::json;

/// The network every role of a HeatNet recipe uses on the CPU budgets (stated in the results).
pub const RECIPE_CPU_MODEL: &str = "mfnet";

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Budget {
    Smoke,
    Quick,
    Paper,
}

impl Budget {
    pub fn parse(s: &str) -> Result<Self> {
        Ok(match s {
            "smoke" => Budget::Smoke,
            "quick" => Budget::Quick,
            "paper" => Budget::Paper,
            other => bail!("--budget: unknown budget `{other}` (expected smoke, quick or paper)"),
        })
    }
    pub fn name(self) -> &'static str {
        match self {
            Budget::Smoke => "smoke",
            Budget::Quick => "quick",
            Budget::Paper => "paper",
        }
    }

    /// Synthetic data for this budget: (`rtf synth` frame count, WxH).
    pub fn synth(self, data: Data) -> (usize, &'static str) {
        match (self, data) {
            (Budget::Smoke, _) => (12, "96x64"),
            (Budget::Quick, Data::Mf) => (160, "96x64"),
            (Budget::Quick, _) => (120, "192x96"),
            // The MF dataset's size (1569 frames at 640×480); Freiburg: its labelled count is
            // far larger, the synthetic stand-in keeps a GPU run under a day.
            (Budget::Paper, Data::Mf) => (1569, "640x480"),
            (Budget::Paper, _) => (2000, "640x320"),
        }
    }

    /// `rtf train` flags (after --model/--data/--out/--seed) for a `Train::Model` cell.
    pub fn train_args(self, family: RecipeFamily, real_data: bool) -> Vec<String> {
        let v: Vec<&str> = match (self, family) {
            (Budget::Smoke, _) => vec![
                "--epochs",
                "1",
                "--batch-size",
                "2",
                "--max-steps",
                "2",
                "--workers",
                "1",
            ],
            // 80 training frames at 96×64, 3 epochs of batch 4 (SGD lr 0.01, decay ×0.8 per
            // epoch): sized for the 2 CPU cores this project shares with other jobs (SegNet
            // trained at 0.33 images/s at 128×96 under a load of 9).
            (Budget::Quick, RecipeFamily::Mfnet | RecipeFamily::Rtfnet) => vec![
                "--epochs",
                QUICK_EPOCHS,
                "--batch-size",
                "4",
                "--lr-decay",
                "0.8",
            ],
            (Budget::Quick, RecipeFamily::Heatnet) => vec![
                "--epochs",
                QUICK_EPOCHS,
                "--batch-size",
                "4",
                "--optimizer",
                "rmsprop",
            ],
            (Budget::Paper, RecipeFamily::Mfnet) => vec![
                "--epochs",
                "80",
                "--batch-size",
                "6",
                "--optimizer",
                "sgd",
                "--lr",
                "0.01",
                "--lr-decay",
                "0.94",
                "--momentum",
                "0.9",
                "--weight-decay",
                "0.0005",
            ],
            (Budget::Paper, RecipeFamily::Rtfnet) => vec![
                "--epochs",
                "100",
                "--batch-size",
                "2",
                "--optimizer",
                "sgd",
                "--lr",
                "0.01",
                "--lr-decay",
                "0.95",
                "--momentum",
                "0.9",
                "--weight-decay",
                "0.0005",
            ],
            (Budget::Paper, RecipeFamily::Heatnet) => vec![
                "--epochs",
                "100",
                "--batch-size",
                "8",
                "--optimizer",
                "rmsprop",
            ],
        };
        let mut v: Vec<String> = v.into_iter().map(String::from).collect();
        // Real MF frames are 480×640; the quick budget shrinks them like its synthetic data.
        if real_data && self != Budget::Paper {
            v.extend(["--resize".to_string(), self.synth(Data::Mf).1.to_string()]);
        }
        v
    }

    /// Extra flags for a `Train::Recipe` cell (the recipes take their paper schedule by
    /// default; CPU budgets shorten it).
    pub fn recipe_args(self) -> Vec<String> {
        // CPU budgets: MFNet in every role at the synthetic frames' size, RMSprop at 1e-3
        // (the paper's 1e-4 barely moves in a few epochs).
        let cpu = |epochs: &str| {
            let size = self.synth(Data::Freiburg).1;
            [
                "--epochs",
                epochs,
                "--model",
                RECIPE_CPU_MODEL,
                "--resize",
                size,
                "--lr",
                "1e-3",
            ]
            .map(String::from)
            .to_vec()
        };
        match self {
            Budget::Smoke => {
                let mut v = cpu("1");
                v.extend(["--max-steps".to_string(), "2".to_string()]);
                v
            }
            Budget::Quick => cpu(QUICK_EPOCHS),
            Budget::Paper => vec![],
        }
    }

    /// `rtf eval` flags beyond model/weights/data/split/json.
    pub fn eval_args(self, real_data: bool) -> Vec<String> {
        let mut v = vec!["--batch-size".to_string(), "4".to_string()];
        if real_data && self != Budget::Paper {
            v.extend(["--resize".to_string(), self.synth(Data::Mf).1.to_string()]);
        }
        v
    }

    /// `rtf bench model` flags for inference times (MFNet Tab. III): the paper's 480×640.
    pub fn bench_args(self) -> Vec<String> {
        let (size, warmup, iterations) = match self {
            Budget::Smoke => ("96x64", "0", "1"),
            Budget::Quick => ("640x480", "1", "3"),
            Budget::Paper => ("640x480", "3", "20"),
        };
        [
            "--size",
            size,
            "--warmup",
            warmup,
            "--iterations",
            iterations,
        ]
        .map(String::from)
        .to_vec()
    }

    /// The budget as written into each result.
    pub fn describe(self, family: RecipeFamily, real_data: bool) -> serde_json::Value {
        let (frames, size) = self.synth(match family {
            RecipeFamily::Heatnet => Data::Freiburg,
            _ => Data::Mf,
        });
        json!({
            "name": self.name(),
            "synthetic_frames": if real_data { serde_json::Value::Null } else { json!(frames) },
            "synthetic_size": if real_data { serde_json::Value::Null } else { json!(size) },
            "rtf_train_flags": self.train_args(family, real_data).join(" "),
            "rtf_recipe_flags": self.recipe_args().join(" "),
            "rtf_eval_flags": self.eval_args(real_data).join(" "),
            "notes": match (self, family) {
                (Budget::Paper, RecipeFamily::Mfnet) => "MFNet paper: SGD lr 0.01 ×0.94 per epoch, 80 epochs, batch 6, horizontal flips, 480×640",
                (Budget::Paper, RecipeFamily::Rtfnet) => "RTFNet paper: SGD lr 0.01, momentum 0.9, weight decay 5e-4, exponential decay, flips; the paper trains \"until convergence\" and adapts the batch to an 11 GB GPU: 100 epochs, ×0.95 and batch 2 are rtf's choice; the paper's encoders start from ImageNet (pass --backbone-weights)",
                (Budget::Paper, RecipeFamily::Heatnet) => "HeatNet paper: RMSprop lr 1e-4 halved every 30 epochs, 100 epochs, batch 8 (the recipes' defaults)",
                (Budget::Quick, _) => "quick: a few epochs on small frames, for trends on a 2-core CPU, not the papers' numbers",
                (Budget::Smoke, _) => "smoke: checks the pipeline only; the numbers mean nothing",
            },
        })
    }
}

/// Epochs of the quick budget (see `train_args`).
pub const QUICK_EPOCHS: &str = "3";
