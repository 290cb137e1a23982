//! Budgets: how much data and training each cell gets. `smoke` checks the pipeline in CI,
//! `quick` gives small but meaningful numbers on a 2-core CPU, `paper` follows the papers'
//! recipes (MFNet Sec. IV: SGD lr 0.01 ×0.94/epoch, 80 epochs, batch 6, flips, 480×640; RTFNet
//! Sec. IV-B: SGD lr 0.01, momentum 0.9, weight decay 5e-4, exponential decay, flips, "until
//! convergence"; HeatNet Sec. IV: the `rtf recipes` procedures; CMX, Zhang et al., IEEE T-ITS
//! 2023, official code: the `cmx-mf` recipe) and is meant for a GPU.

use super::tables::{Data, RecipeFamily};
use anyhow::{bail, Result};
use serde_json::json;

/// The network every role of a HeatNet recipe uses on the CPU budgets (stated in the results).
pub const RECIPE_CPU_MODEL: &str = "mfnet";

/// The `rtf train --recipe` the paper budget gives CMX's cells: the official MF training (AdamW
/// lr 6e-5, weight decay 0.01, poly 0.9 after 10 warm-up epochs, batch 8, 500 epochs, 480×640
/// crops with random scale and mirror). It is named, not spelled out as flags: rtf's flags
/// have no AdamW, poly schedule, warm-up or random scale; `--model` picks MiT-B2 or B4 as for
/// any supervised recipe. An rtf without it reports the cells as not measured.
pub const CMX_RECIPE: &str = "cmx-mf";

/// CPU stand-ins: (paper network, smoke's network, quick's network). On the shared 2-core CPU
/// B0 trains at 4.3 and B1 at 1.8 images/s at 96×64 (batch 4, RMSprop, load 6–13;
/// docs/src/quick-budget.md, "CMX"); B2 and B4, 1.5× and 3.1× B1's parameters, were not
/// timed. Smoke trains the lightest for both rows (the second cell re-uses the first's run).
const CPU_STAND_INS: &[(&str, &str, &str)] = &[
    ("cmx-mit-b2", "cmx-mit-b0", "cmx-mit-b0"),
    ("cmx-mit-b4", "cmx-mit-b0", "cmx-mit-b1"),
];

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
            // 640 training frames: on 80 most networks never left the all-unlabelled answer
            // (docs/src/quick-budget.md, "Round 2").
            (Budget::Quick, Data::Mf) => (1280, "96x64"),
            (Budget::Quick, _) => (120, "192x96"),
            // The MF dataset's size (1569 frames at 640×480); Freiburg: its labelled count is
            // far larger, the synthetic stand-in keeps a GPU run under a day.
            (Budget::Paper, Data::Mf) => (1569, "640x480"),
            (Budget::Paper, _) => (2000, "640x320"),
        }
    }

    /// The network this budget trains for a table's `network`: itself, or on the CPU budgets
    /// its stand-in ([`CPU_STAND_INS`]).
    pub fn network(self, network: &str) -> &str {
        let stand_in = CPU_STAND_INS.iter().find(|(paper, _, _)| *paper == network);
        match (self, stand_in) {
            (Budget::Smoke, Some((_, smoke, _))) => smoke,
            (Budget::Quick, Some((_, _, quick))) => quick,
            _ => network,
        }
    }

    /// The recipe (`rtf train --recipe`) this budget's `Train::Model` cells of `family` need.
    pub fn model_recipe(self, family: RecipeFamily) -> Option<&'static str> {
        (self == Budget::Paper && family == RecipeFamily::Cmx).then_some(CMX_RECIPE)
    }

    /// `rtf train` flags (after --model/--data/--out/--seed) for a `Train::Model` cell of
    /// `network` (the network trained, a stand-in on the CPU budgets).
    pub fn train_args(self, family: RecipeFamily, network: &str, real_data: bool) -> Vec<String> {
        let e = quick_epochs(network);
        let flags = match (self, family) {
            (Budget::Smoke, _) => "--epochs 1 --batch-size 2 --max-steps 2 --workers 1".into(),
            // 640 training frames at 96×64 in batches of 4, RMSprop lr 1e-3 for every network of
            // a table (from scratch, the papers' SGD at lr 0.01 leaves most networks at the
            // all-unlabelled answer on a CPU budget: docs/src/quick-budget.md), for as many
            // epochs as the network needs to leave that answer (`quick_epochs`).
            // CMX's stand-ins too (its paper's AdamW at 6e-5 is no flag of rtf's here), for
            // the epochs that fit the CPU (`QUICK_EPOCHS`). HeatNet Tab. I's MF-trained cells
            // as well (HeatNet's own lr 1e-4 barely moves in a CPU budget's epochs, as for
            // its recipes, `recipe_args`).
            (Budget::Quick, _) => format!("--epochs {e} --batch-size 4 {QUICK_OPTIMIZER}"),
            (Budget::Paper, RecipeFamily::Mfnet) => "--epochs 80 --batch-size 6 --optimizer sgd \
                --lr 0.01 --lr-decay 0.94 --momentum 0.9 --weight-decay 0.0005"
                .into(),
            (Budget::Paper, RecipeFamily::Rtfnet) => "--epochs 100 --batch-size 2 --optimizer \
                sgd --lr 0.01 --lr-decay 0.95 --momentum 0.9 --weight-decay 0.0005"
                .into(),
            (Budget::Paper, RecipeFamily::Heatnet) => {
                "--epochs 100 --batch-size 8 --optimizer rmsprop".into()
            }
            (Budget::Paper, RecipeFamily::Cmx) => format!("--recipe {CMX_RECIPE}"),
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
                .map(|n| (n.to_string(), json!(self.train_args(family, self.network(n), real_data).join(" "))))
                .collect::<serde_json::Map<_, _>>(),
            // The network each cell trains where the budget puts a stand-in in its place.
            "stand_ins": networks
                .iter()
                .filter(|n| self.network(n) != **n)
                .map(|n| (n.to_string(), json!(self.network(n))))
                .collect::<serde_json::Map<_, _>>(),
            "rtf_recipe_flags": self.recipe_args().join(" "),
            "rtf_eval_flags": self.eval_args(real_data).join(" "),
            "notes": match (self, family) {
                (Budget::Paper, RecipeFamily::Mfnet) => "MFNet paper: SGD lr 0.01 ×0.94 per epoch, 80 epochs, batch 6, horizontal flips, 480×640",
                (Budget::Paper, RecipeFamily::Rtfnet) => "RTFNet paper: SGD lr 0.01, momentum 0.9, weight decay 5e-4, exponential decay, flips; the paper trains \"until convergence\" and adapts the batch to an 11 GB GPU: 100 epochs, ×0.95 and batch 2 are rtf's choice; the paper's encoders start from ImageNet (pass --backbone-weights)",
                (Budget::Paper, RecipeFamily::Heatnet) => "HeatNet paper: RMSprop lr 1e-4 halved every 30 epochs, 100 epochs, batch 8 (the recipes' defaults)",
                (Budget::Paper, RecipeFamily::Cmx) => "CMX official MF training, `rtf train --recipe cmx-mf`: AdamW lr 6e-5, weight decay 0.01, poly 0.9 after 10 warm-up epochs, batch 8, 500 epochs, 480×640 crops with random scale and mirror; the paper's encoders start from SegFormer's ImageNet MiT weights: give them with `--mit-weights DIR` (DIR/mit_b2.safetensors, mit_b4.safetensors; recorded in each cell's rtf_train)",
                (Budget::Quick, RecipeFamily::Cmx) => QUICK_CMX_NOTE,
                (Budget::Quick, _) => "quick: small frames (96×64, 640 training frames), RMSprop lr 1e-3 for every network instead of the papers' SGD, each network trained for the epochs it needs to leave the all-unlabelled answer on this data (lab/training/quick_budget_curves.sh, docs/src/quick-budget.md); for trends on a CPU, not the papers' numbers",
                (Budget::Smoke, _) => "smoke: checks the pipeline only; the numbers mean nothing",
            },
        })
    }
}

/// The quick budget's optimiser for the MF tables (RMSprop, no momentum or weight decay, as
/// HeatNet's recipe, at the CPU recipes' lr 1e-3).
const QUICK_OPTIMIZER: &str = "--optimizer rmsprop --lr 1e-3";

/// Quick-budget epochs, read off the validation curves of `lab/training/quick_budget_curves.sh` mode
/// `frames` (640 training frames, RMSprop 1e-3; measured on a lent H200, 2026-11-26; validation
/// mIoU on 80 frames; twice the all-unlabelled answer is 20.2 %; docs/src/quick-budget.md):
/// the first epoch after which the curve stays above that, with a margin. MFNet (above from
/// epoch 2, 48 % at 10), MFNet-B, H, I, J (from 4–7) and ERFNet-4c, FuseNet (from 4–6) take the
/// default; the others are listed. Not measured with this lever (they take the default):
/// MFNet C–G, K, L, N (they learned on 80 frames with SGD), U-Net, PSPNet-4c, DUC-HDC-4c, the
/// RTFNet variants. Measured not to learn within what ran: DUC-HDC-3c (16.9 % at 17 epochs),
/// RTFNet-50 (14.3 % at 10, rising), RTFNet-152 (10.7 % at 3): given 40, unverified.
const QUICK_EPOCHS: &[(&str, u32)] = &[
    ("mfnet-m", 20),   // 20.4 % at 10, 21–22.5 % to 16
    ("segnet-3c", 40), // above from 29: 22–27 % at 30–40
    ("segnet-4c", 30), // 20–25 % from 10, noisy
    ("enet-3c", 25),   // above from 12–13: 23 % at 16–20
    ("erfnet-3c", 25), // above from 12: 22.8 % at 16
    ("pspnet-3c", 20), // above from 9: 24.8 % at 20
    ("duchdc-3c", 40),
    ("duchdc-4c", 40),
    // CMX's CPU stand-ins (`CPU_STAND_INS`): what fits about 40 minutes for 2 seeds on the
    // loaded 2-core CPU, not what they need (validation mIoU of B0, seed 0: 20.6, 28.8,
    // 35.4 % after epochs 1–3; B1: 21.5 % after 1; docs/src/quick-budget.md, "CMX").
    ("cmx-mit-b0", 3),
    ("cmx-mit-b1", 2),
];

/// What the quick budget trains for CMX (written into its results).
const QUICK_CMX_NOTE: &str = "quick, CMX: the stand-ins cmx-mit-b0 (for MiT-B2) and \
     cmx-mit-b1 (for MiT-B4), from scratch (no ImageNet MiT weights), 96×64 frames (640 \
     training frames), batch 4, RMSprop lr 1e-3 as the MF tables instead of the paper's AdamW \
     6e-5 with poly decay, for the few epochs a 2-core CPU affords (docs/src/quick-budget.md, \
     \"CMX\"); for whether the pipeline learns, not the paper's numbers";

/// Quick-budget epochs of every network [`QUICK_EPOCHS`] does not list.
const QUICK_EPOCHS_DEFAULT: u32 = 15;

/// Quick-budget epochs of every RTFNet variant (any depth, fusion or ablation): RTFNet-50 was
/// still climbing at 10 epochs (see [`QUICK_EPOCHS`]).
const QUICK_EPOCHS_RTFNET: u32 = 40;

/// Epochs of each stage of a HeatNet recipe on the quick budget (MFNet in every role, 192×96,
/// RMSprop 1e-3). Measured on this CPU with the quick Freiburg data (validation mIoU, HeatNet
/// convention; twice the all-unlabelled answer is about 6 %): the RGB teacher reaches 17 %
/// (day 32 %) after 15 epochs; V1 (thermal only) stays at 1–5 % for 10 epochs and reaches
/// 8–9 % at 12–15; 3 epochs, the old budget, left every variant at the trivial level.
pub const QUICK_RECIPE_EPOCHS: u32 = 15;

/// The quick budget's epochs for `network` (see [`QUICK_EPOCHS`]).
pub fn quick_epochs(network: &str) -> u32 {
    match QUICK_EPOCHS.iter().find(|(n, _)| *n == network) {
        Some((_, e)) => *e,
        None if network.starts_with("rtfnet") => QUICK_EPOCHS_RTFNET,
        None => QUICK_EPOCHS_DEFAULT,
    }
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
        let epochs = |family, net| epochs_flag(&q.train_args(family, net, false)).to_string();
        assert_eq!(epochs(RecipeFamily::Mfnet, "mfnet"), "15");
        assert_eq!(epochs(RecipeFamily::Mfnet, "segnet-3c"), "40");
        assert_eq!(epochs(RecipeFamily::Mfnet, "mfnet-m"), "20");
        // Every RTFNet variant, listed or not, takes the RTFNet epochs.
        for net in ["rtfnet50", "rtfnet18-nub", "rtfnet152-nte"] {
            assert_eq!(epochs(RecipeFamily::Rtfnet, net), "40", "{net}");
        }
        // One optimiser for every network of a table, on both families.
        for (family, net) in [
            (RecipeFamily::Mfnet, "mfnet"),
            (RecipeFamily::Rtfnet, "fusenet"),
        ] {
            let flags = q.train_args(family, net, false).join(" ");
            assert!(flags.ends_with("--optimizer rmsprop --lr 1e-3"), "{flags}");
        }
        assert_eq!(q.synth(Data::Mf), (1280, "96x64"));
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
        let described = q.describe(RecipeFamily::Mfnet, &["mfnet", "segnet-3c"], false);
        assert!(described["rtf_train_flags"]["segnet-3c"]
            .as_str()
            .unwrap()
            .contains("--epochs 40"));
    }

    /// CMX: the paper budget names the `cmx-mf` recipe and trains MiT-B2 and B4; the CPU
    /// budgets train stand-ins under the MF tables' quick optimiser.
    #[test]
    fn cmx_trains_stand_ins_on_the_cpu_and_its_recipe_on_the_paper_budget() {
        let (b2, b4) = ("cmx-mit-b2", "cmx-mit-b4");
        assert_eq!(Budget::Paper.network(b2), b2);
        assert_eq!(Budget::Paper.network(b4), b4);
        assert_eq!(Budget::Smoke.network(b2), "cmx-mit-b0");
        assert_eq!(Budget::Smoke.network(b4), "cmx-mit-b0");
        assert_eq!(Budget::Quick.network(b2), "cmx-mit-b0");
        assert_eq!(Budget::Quick.network(b4), "cmx-mit-b1");
        for b in [Budget::Smoke, Budget::Quick, Budget::Paper] {
            assert_eq!(
                b.network("mfnet"),
                "mfnet",
                "other networks train themselves"
            );
        }
        assert_eq!(
            Budget::Paper.model_recipe(RecipeFamily::Cmx),
            Some("cmx-mf")
        );
        assert_eq!(Budget::Quick.model_recipe(RecipeFamily::Cmx), None);
        assert_eq!(Budget::Paper.model_recipe(RecipeFamily::Rtfnet), None);
        assert_eq!(
            Budget::Paper.train_args(RecipeFamily::Cmx, b4, false),
            ["--recipe", "cmx-mf"]
        );
        let quick = Budget::Quick.train_args(RecipeFamily::Cmx, "cmx-mit-b1", true);
        let quick = quick.join(" ");
        assert!(quick.contains("--optimizer rmsprop --lr 1e-3"), "{quick}");
        assert!(
            quick.ends_with("--resize 96x64"),
            "real frames shrink: {quick}"
        );
        assert_eq!(
            epochs_flag(&Budget::Quick.train_args(RecipeFamily::Cmx, "cmx-mit-b0", false)),
            quick_epochs("cmx-mit-b0").to_string()
        );
        let d = Budget::Quick.describe(RecipeFamily::Cmx, &[b2, b4], false);
        assert_eq!(d["stand_ins"][b2], "cmx-mit-b0");
        assert_eq!(d["stand_ins"][b4], "cmx-mit-b1");
        assert!(d["rtf_train_flags"][b4]
            .as_str()
            .unwrap()
            .contains("rmsprop"));
        assert!(d["notes"].as_str().unwrap().contains("stand-ins"));
        let p = Budget::Paper.describe(RecipeFamily::Cmx, &[b2, b4], false);
        assert_eq!(p["stand_ins"], json!({}));
        assert_eq!(p["rtf_train_flags"][b2], "--recipe cmx-mf");
        assert!(p["notes"].as_str().unwrap().contains("AdamW lr 6e-5"));
    }
}
