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

    /// `rtf train` flags (after --model/--data/--out/--seed) for a `Train::Model` cell of
    /// `network`.
    pub fn train_args(self, family: RecipeFamily, network: &str, real_data: bool) -> Vec<String> {
        let e = quick_epochs(network);
        let flags = match (self, family) {
            (Budget::Smoke, _) => "--epochs 1 --batch-size 2 --max-steps 2 --workers 1".into(),
            // 80 training frames at 96×64 in batches of 4 with the paper's SGD schedule
            // (MFNet: lr 0.01 ×0.94 per epoch, rtf train's default; RTFNet: ×0.95), for as many
            // epochs as the network needs to leave the all-unlabelled answer (`quick_epochs`).
            (Budget::Quick, RecipeFamily::Mfnet) => format!("--epochs {e} --batch-size 4"),
            (Budget::Quick, RecipeFamily::Rtfnet) => {
                format!("--epochs {e} --batch-size 4 --lr-decay 0.95")
            }
            (Budget::Quick, RecipeFamily::Heatnet) => {
                format!("--epochs {e} --batch-size 4 --optimizer rmsprop")
            }
            (Budget::Paper, RecipeFamily::Mfnet) => "--epochs 80 --batch-size 6 --optimizer sgd \
                --lr 0.01 --lr-decay 0.94 --momentum 0.9 --weight-decay 0.0005"
                .into(),
            (Budget::Paper, RecipeFamily::Rtfnet) => "--epochs 100 --batch-size 2 --optimizer \
                sgd --lr 0.01 --lr-decay 0.95 --momentum 0.9 --weight-decay 0.0005"
                .into(),
            (Budget::Paper, RecipeFamily::Heatnet) => {
                "--epochs 100 --batch-size 8 --optimizer rmsprop".into()
            }
        };
        let mut v: Vec<String> = flags.split_whitespace().map(String::from).collect();
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
            Budget::Quick => cpu(&QUICK_RECIPE_EPOCHS.to_string()),
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

    /// The budget as written into each result (`networks`: the table's trained networks).
    pub fn describe(
        self,
        family: RecipeFamily,
        networks: &[&str],
        real_data: bool,
    ) -> serde_json::Value {
        let (frames, size) = self.synth(match family {
            RecipeFamily::Heatnet => Data::Freiburg,
            _ => Data::Mf,
        });
        json!({
            "name": self.name(),
            "synthetic_frames": if real_data { serde_json::Value::Null } else { json!(frames) },
            "synthetic_size": if real_data { serde_json::Value::Null } else { json!(size) },
            "rtf_train_flags": networks
                .iter()
                .map(|n| (n.to_string(), json!(self.train_args(family, n, real_data).join(" "))))
                .collect::<serde_json::Map<_, _>>(),
            "rtf_recipe_flags": self.recipe_args().join(" "),
            "rtf_eval_flags": self.eval_args(real_data).join(" "),
            "notes": match (self, family) {
                (Budget::Paper, RecipeFamily::Mfnet) => "MFNet paper: SGD lr 0.01 ×0.94 per epoch, 80 epochs, batch 6, horizontal flips, 480×640",
                (Budget::Paper, RecipeFamily::Rtfnet) => "RTFNet paper: SGD lr 0.01, momentum 0.9, weight decay 5e-4, exponential decay, flips; the paper trains \"until convergence\" and adapts the batch to an 11 GB GPU: 100 epochs, ×0.95 and batch 2 are rtf's choice; the paper's encoders start from ImageNet (pass --backbone-weights)",
                (Budget::Paper, RecipeFamily::Heatnet) => "HeatNet paper: RMSprop lr 1e-4 halved every 30 epochs, 100 epochs, batch 8 (the recipes' defaults)",
                (Budget::Quick, _) => "quick: small frames and few frames, each network trained for the epochs it needs to leave the all-unlabelled answer on this data (scripts/quick_budget_curves.sh); for trends on a CPU, not the papers' numbers",
                (Budget::Smoke, _) => "smoke: checks the pipeline only; the numbers mean nothing",
            },
        })
    }
}

/// Quick-budget epochs, read off the validation curves of `scripts/quick_budget_curves.sh`
/// (modes curves and sweep; measured on a lent H200; docs/src/quick-budget.md). The MFNet
/// variants that learn stay above twice the all-unlabelled mIoU from epoch 3–7 and are at
/// 27–33 % by epoch 20, hence [`QUICK_EPOCHS_DEFAULT`]. MFNet-B (RGB only) creeps along the
/// threshold (21.0 % at 10 epochs, 21.6 % at 40) and gets more. The ablations H, I, J, M and
/// every other network (SegNet, ENet, ERFNet, U-Net, PSPNet, DUC-HDC, FuseNet, RTFNet) did not
/// leave the all-unlabelled answer within 20–40 epochs under any lever tried (SGD lr 0.01 or
/// 0.05, RMSprop 1e-3, 160×128 frames): they get the budget they were measured at, and the
/// claims on them read `untested` (see `report::learned`).
const QUICK_EPOCHS: &[(&str, u32)] = &[("mfnet-b", 30)];

/// Quick-budget epochs of every network [`QUICK_EPOCHS`] does not list.
const QUICK_EPOCHS_DEFAULT: u32 = 20;

/// Epochs of each stage of a HeatNet recipe on the quick budget (MFNet in every role, 192×96,
/// RMSprop 1e-3). Measured on this CPU with the quick Freiburg data (validation mIoU, HeatNet
/// convention; twice the all-unlabelled answer is about 6 %): the RGB teacher reaches 17 %
/// (day 32 %) after 15 epochs; V1 (thermal only) stays at 1–5 % for 10 epochs and reaches
/// 8–9 % at 12–15; 3 epochs, the old budget, left every variant at the trivial level.
pub const QUICK_RECIPE_EPOCHS: u32 = 15;

/// The quick budget's epochs for `network` (see [`QUICK_EPOCHS`]).
pub fn quick_epochs(network: &str) -> u32 {
    QUICK_EPOCHS
        .iter()
        .find(|(n, _)| *n == network)
        .map_or(QUICK_EPOCHS_DEFAULT, |(_, e)| *e)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn epochs_flag(args: &[String]) -> &str {
        let i = args.iter().position(|a| a == "--epochs").expect("--epochs");
        &args[i + 1]
    }

    #[test]
    fn the_quick_budget_gives_each_network_its_own_epochs() {
        let q = Budget::Quick;
        assert_eq!(
            epochs_flag(&q.train_args(RecipeFamily::Mfnet, "mfnet", false)),
            "20"
        );
        assert_eq!(
            epochs_flag(&q.train_args(RecipeFamily::Mfnet, "mfnet-b", false)),
            "30"
        );
        let rtfnet = q.train_args(RecipeFamily::Rtfnet, "rtfnet50", false);
        assert_eq!(epochs_flag(&rtfnet), QUICK_EPOCHS_DEFAULT.to_string());
        // Each paper's schedule: RTFNet's ×0.95, MFNet's ×0.94 (rtf train's default).
        assert!(rtfnet.join(" ").contains("--lr-decay 0.95"));
        assert!(!q
            .train_args(RecipeFamily::Mfnet, "mfnet", false)
            .contains(&"--lr-decay".into()));
        // Smoke and paper budgets do not depend on the network.
        for b in [Budget::Smoke, Budget::Paper] {
            assert_eq!(
                b.train_args(RecipeFamily::Rtfnet, "mfnet", false),
                b.train_args(RecipeFamily::Rtfnet, "rtfnet152", false)
            );
        }
        let paper = Budget::Paper
            .train_args(RecipeFamily::Rtfnet, "rtfnet50", false)
            .join(" ");
        assert_eq!(
            paper,
            "--epochs 100 --batch-size 2 --optimizer sgd --lr 0.01 --lr-decay 0.95 --momentum 0.9 \
             --weight-decay 0.0005"
        );
        let described = q.describe(RecipeFamily::Mfnet, &["mfnet", "mfnet-b"], false);
        assert!(described["rtf_train_flags"]["mfnet-b"]
            .as_str()
            .unwrap()
            .contains("--epochs 30"));
    }
}
