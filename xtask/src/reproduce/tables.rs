//! The accuracy tables of the three papers as data: which networks (cells) are trained for a
//! table, which columns it prints, how each measured column is read from `rtf eval --json`, and
//! the paper's numbers, transcribed once from `shared/papers/*.txt` (MFNet: Ha et al., IROS
//! 2017, Tab. II–III; RTFNet: Sun et al., RA-L 2019, Tab. III–VI and Fig. 3; HeatNet: Vertens
//! et al., IROS 2020, Tab. I–II), and CMX's two official MF rows (Zhang et al., IEEE T-ITS
//! 2023; quoted by issue 39, no CMX text in `shared/papers/`). Metric conventions: spec §2.

/// The dataset a cell trains or is evaluated on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Data {
    /// MF (MFNet paper): `--mf` or `rtf synth --format mf`.
    Mf,
    /// Freiburg Thermal: `--freiburg` or `rtf synth --format freiburg`.
    Freiburg,
    /// BDD100K night (RGB only): `--bdd`; never synthesised.
    Bdd,
}

impl Data {
    pub fn flag(self) -> &'static str {
        match self {
            Data::Mf => "--mf",
            Data::Freiburg => "--freiburg",
            Data::Bdd => "--bdd",
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Data::Mf => "MF",
            Data::Freiburg => "Freiburg Thermal",
            Data::Bdd => "BDD100K night",
        }
    }
}

/// How a cell's network is trained.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Train {
    /// `rtf train --model NAME` with the budget's recipe for the table's paper.
    Model(&'static str),
    /// `rtf train --recipe NAME` (HeatNet procedures; `rtf recipes --json` lists them).
    Recipe(&'static str),
}

/// One trained network of a table: `<out>/<table>/<id>/seed<k>/` is its run folder.
#[derive(Clone, Debug)]
pub struct Cell {
    pub id: String,
    pub train: Train,
    /// Training data.
    pub data: Data,
    /// Evaluation data (differs for the cross-dataset rows of HeatNet Tab. I).
    pub eval_on: Data,
    /// `rtf eval --class-map` (a built-in map) where `eval_on`'s classes are not the
    /// network's.
    pub class_map: Option<&'static str>,
    /// Measure the inference time (`rtf bench model`) too.
    pub bench: bool,
    /// Why this cell cannot be run by rtf yet (reported, never silently skipped).
    pub blocked: Option<&'static str>,
}

/// Which frames of the evaluated split a number is computed on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Subset {
    All,
    Day,
    Night,
    /// HeatNet's "Day/Night": the mean of the day and the night score (spec §2).
    DayNight,
}

/// How a measured column is read from `rtf eval --json` (values in percent, like the papers).
#[derive(Clone, Debug, PartialEq)]
pub enum Metric {
    /// RTFNet convention mIoU (eq. 2; 9 classes, unlabeled included, NaN as 0).
    MIoU(Subset),
    /// RTFNet convention mAcc (eq. 1).
    MAcc(Subset),
    /// MFNet paper's mean IoU (unlabeled removed from the sums and from the mean).
    MIoUMfnet(Subset),
    /// Per-class accuracy (recall), class index of the evaluated dataset.
    ClassAcc(Subset, usize),
    /// Per-class IoU.
    ClassIoU(Subset, usize),
    /// Mean IoU of a few classes (HeatNet Tab. I's MF rows: person, car, bike).
    MeanClassIoU(Subset, &'static [usize]),
    /// HeatNet convention mIoU (classes 0–11, undefined skipped) on Freiburg Thermal.
    HeatnetMIoU(Subset),
    /// Median inference time in ms (`rtf bench model`, batch 1, fp32 fast path).
    InferenceMs,
}

/// A measured column: which cell's run and which number of it.
#[derive(Clone, Debug, PartialEq)]
pub struct Measure {
    pub cell: String,
    pub metric: Metric,
}

#[derive(Clone, Debug)]
pub struct Row {
    pub label: String,
    /// The paper's value per column, in percent (ms for times); None where the paper has none.
    pub paper: Vec<Option<f64>>,
    /// How each column is measured; None where rtf measures nothing for it.
    pub measure: Vec<Option<Measure>>,
}

/// A paper's accuracy table (or figure) as rtf reproduces it.
#[derive(Clone, Debug)]
pub struct Table {
    pub id: &'static str,
    pub title: &'static str,
    /// Paper, table and the file its numbers were transcribed from.
    pub source: &'static str,
    /// The paper's recipe family the `paper` budget follows.
    pub recipe: RecipeFamily,
    /// The metric convention(s), named.
    pub convention: &'static str,
    pub columns: Vec<String>,
    pub rows: Vec<Row>,
    pub cells: Vec<Cell>,
    /// Draw the table as a figure (RTFNet Fig. 3).
    pub figure: bool,
}

/// Whose training recipe the `paper` budget uses for `Train::Model` cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecipeFamily {
    Mfnet,
    Rtfnet,
    Heatnet,
    /// CMX's official MF recipe (`rtf train --recipe cmx-mf`); CPU budgets train stand-ins.
    Cmx,
}

impl Table {
    /// The datasets this table reads (training or evaluation).
    pub fn datasets(&self) -> Vec<Data> {
        let mut d: Vec<Data> = self
            .cells
            .iter()
            .flat_map(|c| [c.data, c.eval_on])
            .collect();
        d.sort();
        d.dedup();
        d
    }
    pub fn cell(&self, id: &str) -> Option<&Cell> {
        self.cells.iter().find(|c| c.id == id)
    }
}

/// Ids of every table `reproduce` knows, with the speed tables (see `speed.rs`).
#[cfg(test)]
pub const ACCURACY_IDS: &[&str] = &[
    "mfnet-tab2",
    "mfnet-tab3",
    "rtfnet-tab3",
    "rtfnet-fig3",
    "rtfnet-tab4",
    "rtfnet-tab5",
    "rtfnet-tab6",
    "heatnet-tab1",
    "heatnet-tab2",
    "cmx-mf",
];

/// Every network name a table row uses (checked against `rtf models --json` by a test that
/// runs the binary when it exists, and against [`crate::reproduce::KNOWN_NETWORKS`]).
pub fn networks(tables: &[Table]) -> Vec<&'static str> {
    let mut v: Vec<&'static str> = tables
        .iter()
        .flat_map(|t| t.cells.iter())
        .filter_map(|c| match c.train {
            Train::Model(m) => Some(m),
            Train::Recipe(_) => None,
        })
        .collect();
    v.sort();
    v.dedup();
    v
}

/// Every recipe a `Train::Recipe` cell names (checked against [`crate::reproduce::HEATNET_RECIPES`]).
#[cfg(test)]
pub fn recipes(tables: &[Table]) -> Vec<&'static str> {
    let mut v: Vec<&'static str> = tables
        .iter()
        .flat_map(|t| t.cells.iter())
        .filter_map(|c| match c.train {
            Train::Recipe(r) => Some(r),
            Train::Model(_) => None,
        })
        .collect();
    v.sort();
    v.dedup();
    v
}

fn cell(id: &str, train: Train, data: Data) -> Cell {
    Cell {
        id: id.to_string(),
        train,
        data,
        eval_on: data,
        class_map: None,
        bench: false,
        blocked: None,
    }
}

fn some(v: &[f64]) -> Vec<Option<f64>> {
    v.iter().copied().map(Some).collect()
}

/// Parses a transcribed row where "-" is a cell the paper leaves empty.
fn dashed(v: &[&str]) -> Vec<Option<f64>> {
    v.iter()
        .map(|s| match *s {
            "-" => None,
            s => Some(s.parse().expect("transcribed number")),
        })
        .collect()
}

/// MF class order (spec §1) as the MFNet paper's Tab. II names them.
const MF_CLASSES_MFNET: [&str; 9] = [
    "Unlabeled",
    "Car",
    "Pedestrian",
    "Bike",
    "Curve",
    "Car stop",
    "Guardrail",
    "Color cone",
    "Bump",
];

/// MFNet Tab. II, transcribed from shared/papers/mfnet.txt (fractions as printed): per-class
/// accuracy, class avg., mean IoU; rows all / day / night.
const MFNET_TAB2: [(&str, &str, &str, [f64; 11]); 12] = [
    (
        "SegNet",
        "segnet-3c",
        "",
        [
            0.969, 0.833, 0.721, 0.768, 0.583, 0.319, 0., 0., 0.639, 0.537, 0.583,
        ],
    ),
    (
        "SegNet_4ch (A)",
        "segnet-4c",
        "",
        [
            0.961, 0.890, 0.823, 0., 0.614, 0.217, 0., 0., 0.867, 0.486, 0.504,
        ],
    ),
    (
        "ENet",
        "enet-3c",
        "",
        [
            0.885, 0.586, 0.427, 0.247, 0.301, 0.181, 0.003, 0.458, 0.230, 0.370, 0.449,
        ],
    ),
    (
        "MFNet",
        "mfnet",
        "",
        [
            0.968, 0.829, 0.852, 0.742, 0.615, 0.273, 0., 0.607, 0.433, 0.591, 0.649,
        ],
    ),
    (
        "SegNet",
        "segnet-3c",
        "day",
        [
            0.970, 0.894, 0.769, 0.770, 0.432, 0.316, 0., 0., 0., 0.461, 0.488,
        ],
    ),
    (
        "SegNet",
        "segnet-3c",
        "night",
        [
            0.969, 0.578, 0.627, 0.759, 0.679, 0.323, 0., 0., 0.928, 0.540, 0.552,
        ],
    ),
    (
        "SegNet_4ch (A)",
        "segnet-4c",
        "day",
        [
            0.954, 0.909, 0.801, 0., 0.328, 0.156, 0., 0., 0.260, 0.379, 0.482,
        ],
    ),
    (
        "SegNet_4ch (A)",
        "segnet-4c",
        "night",
        [
            0.968, 0.791, 0.856, 0., 0.696, 0.342, 0., 0., 0.891, 0.505, 0.511,
        ],
    ),
    (
        "MFNet",
        "mfnet",
        "day",
        [
            0.969, 0.885, 0.830, 0.740, 0.379, 0.232, 0., 0.258, 0.003, 0.477, 0.574,
        ],
    ),
    (
        "MFNet",
        "mfnet",
        "night",
        [
            0.967, 0.557, 0.910, 0.752, 0.772, 0.325, 0., 0.724, 0.710, 0.635, 0.621,
        ],
    ),
    // The paper prints no day/night rows for ENet.
    ("ENet", "enet-3c", "day", [f64::NAN; 11]),
    ("ENet", "enet-3c", "night", [f64::NAN; 11]),
];

fn mfnet_tab2() -> Table {
    let mut columns: Vec<String> = MF_CLASSES_MFNET.iter().map(|s| s.to_string()).collect();
    columns.push("Class avg.".into());
    columns.push("mean IoU".into());
    let order = ["segnet-3c", "segnet-4c", "enet-3c", "mfnet"];
    let mut rows = Vec::new();
    for net in order {
        for (subset, tag) in [
            (Subset::All, ""),
            (Subset::Day, "day"),
            (Subset::Night, "night"),
        ] {
            let (label, _, _, values) = MFNET_TAB2
                .iter()
                .find(|(_, n, t, _)| *n == net && *t == tag)
                .expect("every row transcribed");
            let mut measure: Vec<Option<Measure>> = (0..9)
                .map(|c| {
                    Some(Measure {
                        cell: net.into(),
                        metric: Metric::ClassAcc(subset, c),
                    })
                })
                .collect();
            measure.push(Some(Measure {
                cell: net.into(),
                metric: Metric::MAcc(subset),
            }));
            measure.push(Some(Measure {
                cell: net.into(),
                metric: Metric::MIoUMfnet(subset),
            }));
            rows.push(Row {
                label: if tag.is_empty() {
                    label.to_string()
                } else {
                    format!("{label} ({tag})")
                },
                paper: values
                    .iter()
                    .map(|v| (!v.is_nan()).then_some(100.0 * v))
                    .collect(),
                measure,
            });
        }
    }
    Table {
        id: "mfnet-tab2",
        title: "MFNet Tab. II: per-class accuracy, class average and mean IoU; all, day, night",
        source: "Ha et al., MFNet, IROS 2017, Table II (shared/papers/mfnet.txt)",
        recipe: RecipeFamily::Mfnet,
        convention:
            "MFNet paper: per-class columns are accuracy (recall, TP/(TP+FN)); Class avg. = \
                     their mean over all 9 classes; mean IoU over classes 1–8 with unlabeled \
                     removed from the sums (spec §2). Day/night from the frame names (D/N).",
        columns,
        rows,
        cells: order
            .iter()
            .map(|n| cell(n, Train::Model(n), Data::Mf))
            .collect(),
        figure: false,
    }
}

/// MFNet Tab. III (class avg., mean IoU, inference time ms), transcribed from
/// shared/papers/mfnet.txt. Letter models B–N are rtf's `mfnet-b` … `mfnet-n`.
const MFNET_TAB3: [(&str, &str, [f64; 3]); 16] = [
    ("SegNet", "segnet-3c", [0.5368, 0.5833, 119.0]),
    ("MFNet", "mfnet", [0.5910, 0.6486, 18.0]),
    ("SegNet_4ch (A)", "segnet-4c", [0.4858, 0.5041, 120.0]),
    ("MFNet_RGB (B)", "mfnet-b", [0.4971, 0.5835, 14.0]),
    ("MFNet_noInc1 (C)", "mfnet-c", [0.5360, 0.6379, 18.0]),
    ("MFNet_noInc2 (D)", "mfnet-d", [0.5572, 0.6350, 18.0]),
    ("MFNet_2x (E)", "mfnet-e", [0.6493, 0.6861, 43.0]),
    ("MFNet_relu (F)", "mfnet-f", [0.4248, 0.4738, 18.0]),
    ("MFNet_relu_2x (G)", "mfnet-g", [0.5898, 0.6375, 43.0]),
    ("MFNet_idUp (H)", "mfnet-h", [0.3138, 0.1936, 18.0]),
    ("MFNet_idUp_2x (I)", "mfnet-i", [0.5023, 0.4691, 43.0]),
    ("MFNet_noSc (J)", "mfnet-j", [0.5800, 0.6406, 18.0]),
    ("MFNet_sqQuart (K)", "mfnet-k", [0.4964, 0.5882, 17.0]),
    ("MFNet_sqHalf (L)", "mfnet-l", [0.4949, 0.5990, 18.0]),
    ("MFNet_sqHalf_noSc (M)", "mfnet-m", [0.5003, 0.5926, 18.0]),
    ("MFNet_sqSame (N)", "mfnet-n", [0.5405, 0.6484, 19.0]),
];

fn mfnet_tab3() -> Table {
    let rows = MFNET_TAB3
        .iter()
        .map(|(label, net, v)| Row {
            label: label.to_string(),
            paper: vec![Some(100.0 * v[0]), Some(100.0 * v[1]), Some(v[2])],
            measure: [
                Metric::MAcc(Subset::All),
                Metric::MIoUMfnet(Subset::All),
                Metric::InferenceMs,
            ]
            .into_iter()
            .map(|metric| {
                Some(Measure {
                    cell: net.to_string(),
                    metric,
                })
            })
            .collect(),
        })
        .collect();
    Table {
        id: "mfnet-tab3",
        title: "MFNet Tab. III: models A–N, class average, mean IoU and inference time",
        source: "Ha et al., MFNet, IROS 2017, Table III (shared/papers/mfnet.txt)",
        recipe: RecipeFamily::Mfnet,
        convention: "MFNet paper: class avg. = mean per-class accuracy over all 9 classes; mean \
                     IoU over classes 1–8 with unlabeled removed (spec §2). Inference time: the \
                     paper's Titan X at 480×640; measured: `rtf bench model` on this machine \
                     (batch 1, fp32 fast path, random weights).",
        columns: vec![
            "class avg.".into(),
            "mean IoU".into(),
            "Inference time (ms)".into(),
        ],
        rows,
        cells: MFNET_TAB3
            .iter()
            .map(|(_, n, _)| Cell {
                bench: true,
                ..cell(n, Train::Model(n), Data::Mf)
            })
            .collect(),
        figure: false,
    }
}

/// RTFNet Tab. III, transcribed from shared/papers/rtfnet.txt: per class (car … bump) Acc and
/// IoU, then mAcc and mIoU (percent).
const RTFNET_TAB3: [(&str, &str, [f64; 18]); 14] = [
    (
        "ERFNet (4c)",
        "erfnet-4c",
        [
            78.8, 67.1, 62.9, 56.2, 41.6, 34.3, 39.4, 30.6, 12.6, 9.4, 0.0, 0.0, 0.1, 0.1, 33.0,
            30.5, 40.8, 36.1,
        ],
    ),
    (
        "ERFNet (3c)",
        "erfnet-3c",
        [
            75.8, 64.8, 47.5, 36.5, 54.4, 42.4, 26.5, 20.5, 15.7, 10.0, 0.0, 0.0, 0.0, 0.0, 39.2,
            28.8, 39.8, 33.2,
        ],
    ),
    (
        "UNet (4c)",
        "unet-4c",
        [
            71.1, 66.2, 67.2, 60.5, 51.4, 46.2, 47.9, 41.6, 20.7, 17.9, 6.7, 1.8, 34.7, 30.6, 46.5,
            44.2, 49.5, 45.1,
        ],
    ),
    (
        "UNet (3c)",
        "unet-3c",
        [
            73.6, 65.2, 51.6, 42.6, 54.1, 47.8, 34.3, 27.8, 23.7, 20.8, 0.0, 0.0, 42.1, 35.8, 36.1,
            31.0, 46.1, 40.8,
        ],
    ),
    (
        "PSPNet (4c)",
        "pspnet-4c",
        [
            81.0, 74.8, 69.2, 61.3, 63.8, 50.2, 44.7, 38.4, 18.1, 15.8, 0.0, 0.0, 36.4, 33.2, 49.0,
            44.4, 51.3, 46.1,
        ],
    ),
    (
        "PSPNet (3c)",
        "pspnet-3c",
        [
            82.3, 69.0, 48.6, 39.9, 55.3, 46.7, 33.4, 26.9, 11.7, 11.1, 0.0, 0.0, 38.4, 34.1, 35.6,
            26.7, 44.9, 39.0,
        ],
    ),
    (
        "SegNet (4c)",
        "segnet-4c",
        [
            67.5, 65.3, 60.3, 55.7, 61.0, 51.1, 46.3, 38.4, 10.4, 10.0, 0.0, 0.0, 41.9, 12.0, 55.3,
            51.5, 49.1, 42.3,
        ],
    ),
    (
        "SegNet (3c)",
        "segnet-3c",
        [
            58.4, 57.3, 29.8, 27.1, 69.4, 49.9, 18.7, 16.8, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 42.9,
            37.7, 35.4, 31.7,
        ],
    ),
    (
        "DUC-HDC (4c)",
        "duchdc-4c",
        [
            91.5, 84.8, 76.4, 68.8, 66.7, 54.6, 54.7, 41.9, 30.9, 19.2, 12.3, 4.4, 40.2, 34.3,
            61.5, 45.1, 59.3, 50.1,
        ],
    ),
    (
        "DUC-HDC (3c)",
        "duchdc-3c",
        [
            91.0, 82.6, 68.0, 58.2, 68.0, 55.5, 40.4, 31.9, 31.8, 21.9, 39.5, 6.8, 34.7, 31.6,
            58.0, 43.6, 58.9, 47.7,
        ],
    ),
    (
        "MFNet",
        "mfnet",
        [
            77.2, 65.9, 67.0, 58.9, 53.9, 42.9, 36.2, 29.9, 12.5, 9.9, 0.1, 0.0, 30.3, 25.2, 30.0,
            27.7, 45.1, 39.7,
        ],
    ),
    (
        "FuseNet",
        "fusenet",
        [
            81.0, 75.6, 75.2, 66.3, 64.5, 51.9, 51.0, 37.8, 17.4, 15.0, 0.0, 0.0, 31.1, 21.4, 51.9,
            45.0, 52.4, 45.6,
        ],
    ),
    (
        "RTFNet-50",
        "rtfnet50",
        [
            91.3, 86.3, 78.2, 67.8, 71.5, 58.2, 59.8, 43.7, 32.1, 24.3, 13.4, 3.6, 40.4, 26.0,
            73.5, 57.2, 62.2, 51.7,
        ],
    ),
    (
        "RTFNet-152",
        "rtfnet152",
        [
            93.0, 87.4, 79.3, 70.3, 76.8, 62.7, 60.7, 45.3, 38.5, 29.8, 0.0, 0.0, 45.5, 29.1, 74.7,
            55.7, 63.1, 53.2,
        ],
    ),
];

const RTFNET_CLASSES: [&str; 8] = [
    "Car",
    "Person",
    "Bike",
    "Curve",
    "Car Stop",
    "Guardrail",
    "Color Cone",
    "Bump",
];

const RTFNET_CONVENTION: &str = "RTFNet convention (eq. 1–2): Acc = recall, IoU = TP/(TP+FP+FN); \
     mAcc and mIoU average all 9 classes including unlabeled (not shown), a class without true \
     positives counted as 0 (spec §2). Day/night from the frame names (D/N).";

fn rtfnet_cells() -> Vec<Cell> {
    RTFNET_TAB3
        .iter()
        .map(|(_, n, _)| cell(n, Train::Model(n), Data::Mf))
        .collect()
}

fn rtfnet_tab3() -> Table {
    let mut columns = Vec::new();
    for c in RTFNET_CLASSES {
        columns.push(format!("{c} Acc"));
        columns.push(format!("{c} IoU"));
    }
    columns.push("mAcc".into());
    columns.push("mIoU".into());
    let rows = RTFNET_TAB3
        .iter()
        .map(|(label, net, v)| {
            let mut metrics = Vec::new();
            for class in 1..=8 {
                metrics.push(Metric::ClassAcc(Subset::All, class));
                metrics.push(Metric::ClassIoU(Subset::All, class));
            }
            metrics.push(Metric::MAcc(Subset::All));
            metrics.push(Metric::MIoU(Subset::All));
            Row {
                label: label.to_string(),
                paper: some(v),
                measure: measures(net, metrics),
            }
        })
        .collect();
    Table {
        id: "rtfnet-tab3",
        title: "RTFNet Tab. III: per-class Acc and IoU, mAcc, mIoU on the MF test set",
        source: "Sun et al., RTFNet, RA-L 2019, Table III (shared/papers/rtfnet.txt)",
        recipe: RecipeFamily::Rtfnet,
        convention: RTFNET_CONVENTION,
        columns,
        rows,
        cells: rtfnet_cells(),
        figure: false,
    }
}

fn measures(cell: &str, metrics: Vec<Metric>) -> Vec<Option<Measure>> {
    metrics
        .into_iter()
        .map(|metric| {
            Some(Measure {
                cell: cell.to_string(),
                metric,
            })
        })
        .collect()
}

/// RTFNet Tab. VI (daytime mAcc, mIoU; nighttime mAcc, mIoU), shared/papers/rtfnet.txt.
const RTFNET_TAB6: [[f64; 4]; 14] = [
    [37.5, 32.5, 39.3, 34.5],
    [39.5, 32.7, 34.6, 29.6],
    [42.3, 38.0, 47.7, 44.0],
    [43.7, 37.5, 41.0, 37.0],
    [42.6, 37.8, 49.7, 45.2],
    [42.3, 36.7, 41.1, 36.0],
    [39.9, 34.6, 47.4, 41.7],
    [34.2, 29.5, 28.9, 27.4],
    [56.7, 44.3, 55.0, 49.4],
    [55.2, 44.3, 53.3, 44.3],
    [42.6, 36.1, 41.4, 36.8],
    [49.5, 41.0, 48.9, 43.9],
    [57.3, 44.4, 59.4, 52.0],
    [60.0, 45.8, 60.7, 54.8],
];

fn rtfnet_tab6() -> Table {
    let rows = RTFNET_TAB3
        .iter()
        .zip(RTFNET_TAB6)
        .map(|((label, net, _), v)| Row {
            label: label.to_string(),
            paper: some(&v),
            measure: measures(
                net,
                vec![
                    Metric::MAcc(Subset::Day),
                    Metric::MIoU(Subset::Day),
                    Metric::MAcc(Subset::Night),
                    Metric::MIoU(Subset::Night),
                ],
            ),
        })
        .collect();
    Table {
        id: "rtfnet-tab6",
        title: "RTFNet Tab. VI: mAcc and mIoU by day and by night",
        source: "Sun et al., RTFNet, RA-L 2019, Table VI (shared/papers/rtfnet.txt)",
        recipe: RecipeFamily::Rtfnet,
        convention: RTFNET_CONVENTION,
        columns: [
            "Daytime mAcc",
            "Daytime mIoU",
            "Nighttime mAcc",
            "Nighttime mIoU",
        ]
        .map(String::from)
        .to_vec(),
        rows,
        cells: rtfnet_cells(),
        figure: false,
    }
}

/// RTFNet Tab. IV (mAcc: daytime NRE, NTE; nighttime NRE, NTE), shared/papers/rtfnet.txt.
const RTFNET_TAB4: [(i64, [f64; 4]); 2] = [
    (50, [48.16, 52.04, 50.84, 43.51]),
    (152, [50.62, 54.50, 56.84, 49.28]),
];

fn rtfnet_tab4() -> Table {
    let mut cells = Vec::new();
    let rows = RTFNET_TAB4
        .iter()
        .map(|(depth, v)| {
            let nre = format!("rtfnet{depth}-nre");
            let nte = format!("rtfnet{depth}-nte");
            for n in [&nre, &nte] {
                cells.push(cell(n, Train::Model(leak(n)), Data::Mf));
            }
            let m = |c: &String, s| {
                Some(Measure {
                    cell: c.clone(),
                    metric: Metric::MAcc(s),
                })
            };
            Row {
                label: format!("ResNet-{depth}"),
                paper: some(v),
                measure: vec![
                    m(&nre, Subset::Day),
                    m(&nte, Subset::Day),
                    m(&nre, Subset::Night),
                    m(&nte, Subset::Night),
                ],
            }
        })
        .collect();
    Table {
        id: "rtfnet-tab4",
        title: "RTFNet Tab. IV: mAcc of NRE and NTE by day and by night",
        source: "Sun et al., RTFNet, RA-L 2019, Table IV (shared/papers/rtfnet.txt)",
        recipe: RecipeFamily::Rtfnet,
        convention: RTFNET_CONVENTION,
        columns: [
            "Daytime NRE",
            "Daytime NTE",
            "Nighttime NRE",
            "Nighttime NTE",
        ]
        .map(String::from)
        .to_vec(),
        rows,
        cells,
        figure: false,
    }
}

/// RTFNet Tab. V (mAcc, mIoU of ours, OLF, FCI), shared/papers/rtfnet.txt.
const RTFNET_TAB5: [(i64, [f64; 6]); 2] = [
    (50, [62.2, 51.7, 52.2, 46.2, 54.9, 45.5]),
    (152, [63.1, 53.2, 60.5, 51.4, 56.3, 48.8]),
];

fn rtfnet_tab5() -> Table {
    let mut cells = Vec::new();
    let rows = RTFNET_TAB5
        .iter()
        .map(|(depth, v)| {
            let mut measure = Vec::new();
            for suffix in ["", "-olf", "-fci"] {
                let name = format!("rtfnet{depth}{suffix}");
                cells.push(cell(&name, Train::Model(leak(&name)), Data::Mf));
                measure.extend(measures(
                    &name,
                    vec![Metric::MAcc(Subset::All), Metric::MIoU(Subset::All)],
                ));
            }
            Row {
                label: format!("ResNet-{depth}"),
                paper: some(v),
                measure,
            }
        })
        .collect();
    Table {
        id: "rtfnet-tab5",
        title: "RTFNet Tab. V: fusion strategies (RTFNet, OLF, FCI)",
        source: "Sun et al., RTFNet, RA-L 2019, Table V (shared/papers/rtfnet.txt)",
        recipe: RecipeFamily::Rtfnet,
        convention: RTFNET_CONVENTION,
        columns: [
            "Ours mAcc",
            "Ours mIoU",
            "OLF mAcc",
            "OLF mIoU",
            "FCI mAcc",
            "FCI mIoU",
        ]
        .map(String::from)
        .to_vec(),
        rows,
        cells,
        figure: false,
    }
}

pub const FIG3_DEPTHS: [i64; 5] = [18, 34, 50, 101, 152];
pub const FIG3_VARIANTS: [(&str, &str); 4] = [
    ("", "RTFNet"),
    ("-nre", "NRE"),
    ("-nte", "NTE"),
    ("-nub", "NUB"),
];

fn rtfnet_fig3() -> Table {
    let mut cells = Vec::new();
    let mut rows = Vec::new();
    for (suffix, variant) in FIG3_VARIANTS {
        for depth in FIG3_DEPTHS {
            let name = format!("rtfnet{depth}{suffix}");
            cells.push(cell(&name, Train::Model(leak(&name)), Data::Mf));
            rows.push(Row {
                label: format!("{variant}, ResNet-{depth}"),
                // Fig. 3 prints its numbers only as bars; they are not transcribed.
                paper: vec![None, None],
                measure: measures(
                    &name,
                    vec![Metric::MAcc(Subset::All), Metric::MIoU(Subset::All)],
                ),
            });
        }
    }
    Table {
        id: "rtfnet-fig3",
        title: "RTFNet Fig. 3: ablation over ResNet-18…152 (RTFNet, NRE, NTE, NUB)",
        source: "Sun et al., RTFNet, RA-L 2019, Fig. 3 (a plot: its values are not printed in \
                 shared/papers/rtfnet.txt, so no paper column)",
        recipe: RecipeFamily::Rtfnet,
        convention: RTFNET_CONVENTION,
        columns: vec!["mAcc".into(), "mIoU".into()],
        rows,
        cells,
        figure: true,
    }
}

/// Names built at table construction live for the program (a handful of short strings).
fn leak(s: &str) -> &'static str {
    Box::leak(s.to_string().into_boxed_str())
}

/// Freiburg Thermal class order (rtf-core `ClassSet::freiburg`), as HeatNet Tab. I names them.
const HEATNET_CLASSES: [&str; 12] = [
    "Road",
    "Sidewalk",
    "Building",
    "Curb",
    "Fence",
    "Pole",
    "Vegetation",
    "Terrain",
    "Sky",
    "Person",
    "Car",
    "Bicycle",
];

/// HeatNet Tab. I, transcribed from shared/papers/heatnet.txt: (row label, cell, eval subset,
/// 12 class IoUs + Mean, "-" where the paper has a dash).
#[allow(clippy::type_complexity)]
const HEATNET_TAB1: [(&str, &str, &str, [&str; 13]); 16] = [
    (
        "MF→MF: MFNet",
        "mf-mfnet",
        "all",
        [
            "-", "-", "-", "-", "-", "-", "-", "-", "-", "58.9", "65.9", "42.9", "55.9",
        ],
    ),
    (
        "MF→MF: RTFNet-50",
        "mf-rtfnet50",
        "all",
        [
            "-", "-", "-", "-", "-", "-", "-", "-", "-", "67.8", "86.3", "58.2", "70.7",
        ],
    ),
    (
        "MF→MF: HeatNet",
        "mf-heatnet",
        "all",
        [
            "-", "-", "-", "-", "-", "-", "-", "-", "-", "56.4", "68.8", "33.9", "53.0",
        ],
    ),
    (
        "MF→FR-T Day/Night: MFNet",
        "mf-to-fr-mfnet",
        "daynight",
        [
            "-", "-", "-", "-", "-", "-", "-", "-", "-", "42.8", "27.0", "24.5", "31.4",
        ],
    ),
    (
        "MF→FR-T Day/Night: RTFNet-50",
        "mf-to-fr-rtfnet50",
        "daynight",
        [
            "-", "-", "-", "-", "-", "-", "-", "-", "-", "63.2", "61.5", "51.3", "58.6",
        ],
    ),
    (
        "MF→FR-T Day/Night: HeatNet",
        "mf-to-fr-heatnet",
        "daynight",
        [
            "86.7", "57.5", "67.7", "46.4", "41.5", "43.8", "57.9", "44.1", "63.7", "63.1", "85.6",
            "58.2", "59.7",
        ],
    ),
    (
        "FR-T→MF: HeatNet",
        "fr-to-mf-heatnet",
        "all",
        [
            "-", "-", "-", "-", "-", "-", "-", "-", "-", "51.6", "61.8", "30.2", "47.9",
        ],
    ),
    (
        "FR-T Day: RGB Teacher",
        "teacher-rgb",
        "day",
        [
            "89.7", "67.0", "73.8", "56.9", "48.8", "53.8", "73.8", "62.8", "84.3", "72.0", "90.1",
            "60.4", "69.4",
        ],
    ),
    (
        "FR-T Day: HeatNet",
        "heatnet",
        "day",
        [
            "89.4", "65.6", "74.8", "59.7", "52.9", "54.3", "74.1", "65.1", "84.5", "74.0", "91.2",
            "64.1", "70.8",
        ],
    ),
    (
        "FR-T Night: Thermal Teacher",
        "teacher-ir",
        "night",
        [
            "84.9", "60.5", "65.5", "43.1", "31.8", "38.1", "51.8", "40.1", "72.6", "49.6", "87.1",
            "56.9", "57.0",
        ],
    ),
    (
        "FR-T Night: RGB Teacher",
        "teacher-rgb",
        "night",
        [
            "76.3", "22.6", "53.4", "10.8", "14.1", "31.6", "10.4", "13.5", "47.7", "28.0", "74.3",
            "45.2", "35.7",
        ],
    ),
    (
        "FR-T Night: HeatNet",
        "heatnet",
        "night",
        [
            "86.4", "60.9", "65.4", "45.5", "35.5", "42.0", "52.5", "52.3", "73.9", "54.9", "85.7",
            "53.3", "59.0",
        ],
    ),
    (
        "FR-T Day/Night: HeatNet",
        "heatnet",
        "daynight",
        [
            "87.9", "63.3", "70.1", "52.6", "44.2", "48.2", "63.3", "58.9", "79.2", "64.5", "88.5",
            "58.7", "64.9",
        ],
    ),
    (
        "FR-T Day/Night: HeatNet RGB-only",
        "distill",
        "daynight",
        [
            "82.7", "56.0", "66.0", "45.3", "34.0", "37.8", "58.4", "49.5", "71.0", "54.4", "84.2",
            "57.4", "58.0",
        ],
    ),
    // BDD night rows (only with --bdd).
    (
        "BDD Night: RGB Teacher",
        "bdd-teacher-rgb",
        "all",
        [
            "68.8", "21.5", "32.9", "-", "0.0", "12.3", "11.5", "6.6", "27.2", "24.5", "40.4", "-",
            "24.6",
        ],
    ),
    (
        "BDD Night: HeatNet RGB-only",
        "bdd-distill",
        "all",
        [
            "87.1", "40.0", "50.2", "-", "25.9", "22.9", "12.8", "8.5", "25.0", "27.4", "68.3",
            "-", "36.8",
        ],
    ),
];

/// MF class ids of person, car, bike (spec §1), in Tab. I's column order person, car, bicycle.
const MF_PERSON_CAR_BIKE: [usize; 3] = [2, 1, 3];

const BDD_EVAL: &str = "`rtf eval` does not open BDD100K roots yet (RGB-only evaluation of the \
     distilled network)";

fn heatnet_tab1(with_bdd: bool) -> Table {
    let mut columns: Vec<String> = HEATNET_CLASSES.iter().map(|s| s.to_string()).collect();
    columns.push("Mean".into());
    let cells = heatnet_tab1_cells(with_bdd);
    let mut source_rows: Vec<_> = HEATNET_TAB1.to_vec();
    if !with_bdd {
        source_rows.retain(|r| !r.1.starts_with("bdd-"));
    }
    let rows = source_rows
        .iter()
        .map(|source| heatnet_tab1_row(&cells, source))
        .collect();
    Table {
        id: "heatnet-tab1",
        title: "HeatNet Tab. I: teachers, HeatNet RGB-T, distilled RGB-only; FR-T day / night / \
                day-night; MF↔FR-T",
        source: "Vertens et al., HeatNet, IROS 2020, Table I (shared/papers/heatnet.txt)",
        recipe: RecipeFamily::Heatnet,
        convention: "HeatNet convention on Freiburg Thermal: IoU per class 0–11, Mean = \
                     nan-mean over them, ignore (13) dropped, background (12) predictions count \
                     as false positives; Day/Night = mean of the day and the night score (spec \
                     §2). MF rows: RTFNet-convention class IoU of person, car, bicycle and \
                     their mean. MF↔FR-T rows: scored through `rtf eval --class-map` \
                     (mf-to-freiburg, freiburg-to-mf: person, car, bicycle; the other classes' \
                     truth pixels count as false positives where predicted as one of the three, \
                     as the authors' code maps them to MF's unlabeled), the mean over the \
                     three; the MF-trained HeatNet learns MF's classes here, so its row has no \
                     12-class Mean. Freiburg cells report the final weights: its only labelled \
                     held-out part is the test layout, so no checkpoint is picked on it.",
        columns,
        rows,
        cells,
        figure: false,
    }
}

/// The trained networks of HeatNet Tab. I (the BDD100K rows' two only `with_bdd`).
fn heatnet_tab1_cells(with_bdd: bool) -> Vec<Cell> {
    let mut cells = vec![
        cell("mf-mfnet", Train::Model("mfnet"), Data::Mf),
        cell("mf-rtfnet50", Train::Model("rtfnet50"), Data::Mf),
        cell("mf-heatnet", Train::Model("heatnet"), Data::Mf),
        cross("mf-to-fr-mfnet", Train::Model("mfnet"), Data::Mf),
        cross("mf-to-fr-rtfnet50", Train::Model("rtfnet50"), Data::Mf),
        cross("mf-to-fr-heatnet", Train::Model("heatnet"), Data::Mf),
        cross(
            "fr-to-mf-heatnet",
            Train::Recipe("heatnet-v6"),
            Data::Freiburg,
        ),
        cell(
            "teacher-rgb",
            Train::Recipe("heatnet-teacher-rgb"),
            Data::Freiburg,
        ),
        cell(
            "teacher-ir",
            Train::Recipe("heatnet-teacher-ir"),
            Data::Freiburg,
        ),
        cell("heatnet", Train::Recipe("heatnet-v6"), Data::Freiburg),
        cell("distill", Train::Recipe("heatnet-distill"), Data::Freiburg),
    ];
    if with_bdd {
        for (id, recipe) in [
            ("bdd-teacher-rgb", "heatnet-teacher-rgb"),
            ("bdd-distill", "heatnet-distill"),
        ] {
            cells.push(Cell {
                eval_on: Data::Bdd,
                blocked: Some(BDD_EVAL),
                ..cell(id, Train::Recipe(recipe), Data::Freiburg)
            });
        }
    }
    cells
}

/// A cell trained on `data` and scored on the other of MF and Freiburg Thermal through the
/// built-in map of HeatNet Tab. I (person, car, bicycle; `rtf eval --class-map`).
fn cross(id: &str, train: Train, data: Data) -> Cell {
    let (eval_on, map) = match data {
        Data::Mf => (Data::Freiburg, "mf-to-freiburg"),
        _ => (Data::Mf, "freiburg-to-mf"),
    };
    Cell {
        eval_on,
        class_map: Some(map),
        ..cell(id, train, data)
    }
}

/// Indices of person, car, bicycle in a `rtf eval --class-map` scores file of [`cross`]'s
/// maps (the scored classes, in Tab. I's column order).
const MAPPED_PERSON_CAR_BICYCLE: [usize; 3] = [0, 1, 2];

/// One row of HeatNet Tab. I from its transcription `(label, cell, subset, paper values)`:
/// Freiburg rows measure the 12 class IoUs and HeatNet's mean, MF rows person, car, bicycle
/// and their mean (RTFNet-convention IoU).
fn heatnet_tab1_row(
    cells: &[Cell],
    (label, cell_id, subset, paper): &(&str, &str, &str, [&str; 13]),
) -> Row {
    let subset = match *subset {
        "all" => Subset::All,
        "day" => Subset::Day,
        "night" => Subset::Night,
        _ => Subset::DayNight,
    };
    let c = cells.iter().find(|c| c.id == *cell_id).expect("cell");
    let m = |metric| {
        Some(Measure {
            cell: cell_id.to_string(),
            metric,
        })
    };
    let measure: Vec<Option<Measure>> = if c.class_map.is_some() {
        // Through the map: the three shared classes and their mean. The paper's MF-trained
        // HeatNet row scores all 12 FR-T classes (its network learned Freiburg's classes from
        // the teacher on MF images, §V-B); rtf's learns MF's, so that row's Mean (over 12) has
        // no measured counterpart.
        let mut v = vec![None; 9];
        v.extend(
            MAPPED_PERSON_CAR_BICYCLE
                .iter()
                .map(|&k| m(Metric::ClassIoU(subset, k))),
        );
        let twelve = paper[0] != "-";
        v.push(match twelve {
            true => None,
            false => m(Metric::MeanClassIoU(subset, &MAPPED_PERSON_CAR_BICYCLE)),
        });
        v
    } else if c.eval_on == Data::Mf {
        let mut v = vec![None; 9];
        v.extend(
            MF_PERSON_CAR_BIKE
                .iter()
                .map(|&k| m(Metric::ClassIoU(subset, k))),
        );
        v.push(m(Metric::MeanClassIoU(subset, &MF_PERSON_CAR_BIKE)));
        v
    } else {
        let mut v: Vec<_> = (0..12).map(|k| m(Metric::ClassIoU(subset, k))).collect();
        v.push(m(Metric::HeatnetMIoU(subset)));
        v
    };
    Row {
        label: label.to_string(),
        paper: dashed(paper),
        measure,
    }
}

/// HeatNet Tab. II (mIoU day, night, both), shared/papers/heatnet.txt.
const HEATNET_TAB2: [(&str, [f64; 3]); 6] = [
    ("V1", [68.1, 57.0, 62.6]),
    ("V2", [68.3, 25.1, 46.7]),
    ("V3", [67.9, 33.7, 50.8]),
    ("V4", [70.5, 43.2, 56.9]),
    ("V5", [70.6, 56.3, 63.5]),
    ("V6", [70.8, 59.0, 64.9]),
];

fn heatnet_tab2() -> Table {
    let mut cells = Vec::new();
    let rows = HEATNET_TAB2
        .iter()
        .map(|(label, v)| {
            let id = format!("heatnet-{}", label.to_lowercase());
            cells.push(cell(&id, Train::Recipe(leak(&id)), Data::Freiburg));
            Row {
                label: label.to_string(),
                paper: some(v),
                measure: measures(
                    &id,
                    vec![
                        Metric::HeatnetMIoU(Subset::Day),
                        Metric::HeatnetMIoU(Subset::Night),
                        Metric::HeatnetMIoU(Subset::DayNight),
                    ],
                ),
            }
        })
        .collect();
    Table {
        id: "heatnet-tab2",
        title: "HeatNet Tab. II: ablation V1–V6 on Freiburg Thermal",
        source: "Vertens et al., HeatNet, IROS 2020, Table II (shared/papers/heatnet.txt)",
        recipe: RecipeFamily::Heatnet,
        convention: "HeatNet convention (classes 0–11, nan-mean; Both = mean of day and night \
                     mIoU, spec §2). Final weights are reported (see heatnet-tab1).",
        columns: ["Day mIoU", "Night mIoU", "Both mIoU"]
            .map(String::from)
            .to_vec(),
        rows,
        cells,
        figure: false,
    }
}

/// CMX's official MF rows (Zhang et al., CMX, IEEE T-ITS 2023, the RGB-thermal comparison on
/// the MFNet dataset): (row label, cell = network, mIoU in percent as printed). The two numbers
/// are the ones issue 39 quotes; `shared/papers/` holds no CMX text to transcribe from.
const CMX_MF: [(&str, &str, f64); 2] = [
    ("CMX (MiT-B2)", "cmx-mit-b2", 58.2),
    ("CMX (MiT-B4)", "cmx-mit-b4", 59.7),
];

const CMX_CONVENTION: &str = "RTFNet convention (eq. 1–2), which CMX reports on MF: mIoU and \
     mAcc over all 9 classes including unlabeled, a class without true positives counted as 0 \
     (spec §2); whole frames at one scale (on MF's 480×640 frames the official evaluator's \
     480×640 crop runs each frame once). The paper reports mIoU only. The paper budget trains MiT-B2 and MiT-B4 \
     with the `cmx-mf` recipe; the CPU budgets train lighter stand-ins under the same cell \
     names (smoke: cmx-mit-b0 for both rows; quick: cmx-mit-b0 for MiT-B2, cmx-mit-b1 for \
     MiT-B4; each cell's `--model` is in the results JSON).";

fn cmx_mf() -> Table {
    let rows = CMX_MF
        .iter()
        .map(|(label, net, miou)| Row {
            label: label.to_string(),
            paper: vec![Some(*miou), None],
            measure: measures(
                net,
                vec![Metric::MIoU(Subset::All), Metric::MAcc(Subset::All)],
            ),
        })
        .collect();
    Table {
        id: "cmx-mf",
        title: "CMX on MF: the official MiT-B2 and MiT-B4 rows, mIoU and mAcc",
        source: "Zhang et al., CMX, IEEE T-ITS 2023, RGB-thermal results on MFNet (the two \
                 official rows as issue 39 quotes them; no shared/papers/ text)",
        recipe: RecipeFamily::Cmx,
        convention: CMX_CONVENTION,
        columns: vec!["mIoU".into(), "mAcc".into()],
        rows,
        cells: CMX_MF
            .iter()
            .map(|(_, n, _)| cell(n, Train::Model(n), Data::Mf))
            .collect(),
        figure: false,
    }
}

/// Every accuracy table; `with_bdd` adds HeatNet Tab. I's BDD night rows.
pub fn all(with_bdd: bool) -> Vec<Table> {
    vec![
        mfnet_tab2(),
        mfnet_tab3(),
        rtfnet_tab3(),
        rtfnet_fig3(),
        rtfnet_tab4(),
        rtfnet_tab5(),
        rtfnet_tab6(),
        heatnet_tab1(with_bdd),
        heatnet_tab2(),
        cmx_mf(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_table_is_consistent() {
        let tables = all(true);
        assert_eq!(
            tables.iter().map(|t| t.id).collect::<Vec<_>>(),
            ACCURACY_IDS
        );
        for t in &tables {
            assert!(!t.rows.is_empty(), "{}", t.id);
            let mut ids: Vec<&str> = t.cells.iter().map(|c| c.id.as_str()).collect();
            ids.sort();
            let n = ids.len();
            ids.dedup();
            assert_eq!(ids.len(), n, "{}: duplicate cell ids", t.id);
            for row in &t.rows {
                assert_eq!(row.paper.len(), t.columns.len(), "{} {}", t.id, row.label);
                assert_eq!(row.measure.len(), t.columns.len(), "{} {}", t.id, row.label);
                for m in row.measure.iter().flatten() {
                    assert!(
                        t.cell(&m.cell).is_some(),
                        "{} {}: {}",
                        t.id,
                        row.label,
                        m.cell
                    );
                }
            }
            // Every cell is measured by some row.
            for c in &t.cells {
                assert!(
                    t.rows
                        .iter()
                        .flat_map(|r| r.measure.iter().flatten())
                        .any(|m| m.cell == c.id),
                    "{}: cell {} unused",
                    t.id,
                    c.id
                );
                // Folder names are plain.
                assert!(c
                    .id
                    .chars()
                    .all(|ch| ch.is_ascii_alphanumeric() || ch == '-'));
            }
        }
    }

    /// CMX's MF table: the two official rows, measured as RTFNet's tables measure mIoU and
    /// mAcc, each row its own network (the budget may train a stand-in under the cell's name).
    #[test]
    fn cmx_mf_holds_the_official_rows_and_their_networks() {
        let t = cmx_mf();
        assert_eq!((t.id, t.recipe), ("cmx-mf", RecipeFamily::Cmx));
        assert_eq!(t.columns, ["mIoU", "mAcc"]);
        let cells: Vec<(&str, &Train)> =
            t.cells.iter().map(|c| (c.id.as_str(), &c.train)).collect();
        assert_eq!(
            cells,
            [
                ("cmx-mit-b2", &Train::Model("cmx-mit-b2")),
                ("cmx-mit-b4", &Train::Model("cmx-mit-b4"))
            ]
        );
        assert!(t
            .cells
            .iter()
            .all(|c| c.data == Data::Mf && c.eval_on == Data::Mf));
        assert!(t.cells.iter().all(|c| c.blocked.is_none() && !c.bench));
        for (row, net) in t.rows.iter().zip(["cmx-mit-b2", "cmx-mit-b4"]) {
            assert_eq!(row.paper[1], None, "the paper prints no mAcc");
            let m: Vec<&Measure> = row.measure.iter().flatten().collect();
            assert_eq!(m.len(), 2);
            assert!(m.iter().all(|m| m.cell == net));
            assert_eq!(m[0].metric, Metric::MIoU(Subset::All));
            assert_eq!(m[1].metric, Metric::MAcc(Subset::All));
        }
        // The paper's column is labelled as the paper's: the source names CMX and its venue.
        assert!(t.source.contains("CMX") && t.source.contains("T-ITS 2023"));
        assert!(t.convention.contains("stand-ins"));
    }

    /// HeatNet Tab. I's MF↔FR-T rows are measured through the built-in class maps: every
    /// cell runs (none blocked without BDD), the columns read the scored classes.
    #[test]
    fn heatnet_tab1_cross_dataset_rows_go_through_the_class_maps() {
        let t = heatnet_tab1(false);
        assert!(t.cells.iter().all(|c| c.blocked.is_none()));
        let maps: Vec<(&str, Data, Option<&str>)> = t
            .cells
            .iter()
            .filter(|c| c.eval_on != c.data)
            .map(|c| (c.id.as_str(), c.eval_on, c.class_map))
            .collect();
        let to_fr = (Data::Freiburg, Some("mf-to-freiburg"));
        assert_eq!(
            maps,
            [
                ("mf-to-fr-mfnet", to_fr.0, to_fr.1),
                ("mf-to-fr-rtfnet50", to_fr.0, to_fr.1),
                ("mf-to-fr-heatnet", to_fr.0, to_fr.1),
                ("fr-to-mf-heatnet", Data::Mf, Some("freiburg-to-mf")),
            ]
        );
        assert!(t
            .cells
            .iter()
            .all(|c| (c.eval_on != c.data) == c.class_map.is_some()));
        let row = |label: &str| t.rows.iter().find(|r| r.label == label).unwrap();
        let metrics = |label: &str| -> Vec<Option<Metric>> {
            row(label)
                .measure
                .iter()
                .map(|m| m.as_ref().map(|m| m.metric.clone()))
                .collect()
        };
        let mfnet = metrics("MF→FR-T Day/Night: MFNet");
        assert!(mfnet[..9].iter().all(Option::is_none));
        assert_eq!(mfnet[9], Some(Metric::ClassIoU(Subset::DayNight, 0)));
        assert_eq!(mfnet[11], Some(Metric::ClassIoU(Subset::DayNight, 2)));
        assert_eq!(
            mfnet[12],
            Some(Metric::MeanClassIoU(Subset::DayNight, &[0, 1, 2]))
        );
        // The paper's MF-trained HeatNet is scored on 12 classes: no 3-class Mean beside it.
        let heatnet = metrics("MF→FR-T Day/Night: HeatNet");
        assert_eq!(heatnet[10], Some(Metric::ClassIoU(Subset::DayNight, 1)));
        assert_eq!(heatnet[12], None);
        let back = metrics("FR-T→MF: HeatNet");
        assert_eq!(back[9], Some(Metric::ClassIoU(Subset::All, 0)));
        assert_eq!(
            row("FR-T→MF: HeatNet").measure[9].as_ref().unwrap().cell,
            "fr-to-mf-heatnet"
        );
    }

    #[test]
    fn paper_numbers_are_transcribed_as_printed() {
        let t = all(false);
        let get = |id: &str, row: &str, col: &str| {
            let t = t.iter().find(|t| t.id == id).unwrap();
            let c = t.columns.iter().position(|c| c == col).unwrap();
            t.rows.iter().find(|r| r.label == row).unwrap().paper[c]
        };
        let close = |a: Option<f64>, b: f64| (a.unwrap() - b).abs() < 1e-9;
        assert!(close(get("mfnet-tab2", "MFNet (night)", "mean IoU"), 62.1));
        assert!(close(get("mfnet-tab2", "SegNet", "Class avg."), 53.7));
        assert_eq!(get("mfnet-tab2", "ENet (day)", "mean IoU"), None);
        assert!(close(
            get("mfnet-tab3", "MFNet_relu (F)", "mean IoU"),
            47.38
        ));
        assert!(close(
            get("mfnet-tab3", "MFNet_2x (E)", "Inference time (ms)"),
            43.0
        ));
        assert!(close(get("rtfnet-tab3", "RTFNet-152", "mIoU"), 53.2));
        assert!(close(
            get("rtfnet-tab3", "SegNet (4c)", "Color Cone IoU"),
            12.0
        ));
        assert!(close(
            get("rtfnet-tab4", "ResNet-50", "Nighttime NTE"),
            43.51
        ));
        assert!(close(get("rtfnet-tab5", "ResNet-152", "OLF mIoU"), 51.4));
        assert!(close(get("rtfnet-tab6", "FuseNet", "Nighttime mIoU"), 43.9));
        assert!(close(
            get("heatnet-tab1", "FR-T Day/Night: HeatNet", "Mean"),
            64.9
        ));
        assert_eq!(get("heatnet-tab1", "MF→MF: MFNet", "Road"), None);
        assert!(close(get("heatnet-tab2", "V5", "Night mIoU"), 56.3));
        // CMX: the official MF rows, mIoU only (no mAcc printed).
        assert!(close(get("cmx-mf", "CMX (MiT-B2)", "mIoU"), 58.2));
        assert!(close(get("cmx-mf", "CMX (MiT-B4)", "mIoU"), 59.7));
        assert_eq!(get("cmx-mf", "CMX (MiT-B4)", "mAcc"), None);
        // MFNet Tab. II: Class avg. is the mean of the nine per-class accuracies as printed.
        for (label, _, _, v) in MFNET_TAB2.iter().filter(|r| !r.3[0].is_nan()) {
            let mean = v[..9].iter().sum::<f64>() / 9.0;
            assert!((mean - v[9]).abs() < 0.0015, "{label}: {mean} vs {}", v[9]);
        }
        // RTFNet Tab. III: HeatNet Tab. I quotes MFNet's person/car/bike IoU from it.
        assert!(close(get("rtfnet-tab3", "MFNet", "Person IoU"), 58.9));
        assert!(close(get("heatnet-tab1", "MF→MF: MFNet", "Person"), 58.9));
        // HeatNet's Day/Night mean is the mean of day and night (spec §2).
        let d = get("heatnet-tab1", "FR-T Day: HeatNet", "Mean").unwrap();
        let n = get("heatnet-tab1", "FR-T Night: HeatNet", "Mean").unwrap();
        assert!(((d + n) / 2.0 - 64.9).abs() < 0.05);
        let bdd = all(true);
        let t1 = bdd.iter().find(|t| t.id == "heatnet-tab1").unwrap();
        assert_eq!(t1.rows.len(), 16);
        assert!(t1.cells.iter().any(|c| c.eval_on == Data::Bdd));
    }
}
