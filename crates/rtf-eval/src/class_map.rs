//! Scoring a network on a dataset whose class set is not the network's (HeatNet Tab. I's
//! MF ↔ Freiburg Thermal rows): a [`ClassMap`] names the classes that are scored and, for
//! each, which output classes of the network and which label classes of the dataset count as
//! it (many-to-one on either side). [`ClassMap::resolve`] checks it against both class sets
//! and gives the [`ClassMapping`] that [`crate::evaluate_mapped`] scores through.
//!
//! Pixels of no scored class ("other"): the matrix is (scored + 1)², the last row and column
//! being "other". A prediction of a network class that the map leaves out is "other": on a
//! pixel of a scored class it is a miss (false negative) of that class. A truth pixel of a
//! dataset class that the map leaves out is, by default ([`OtherPixels::Counted`]), an
//! "other" row: predicted as a scored class, it is a false positive of that class. This is
//! what the authors' code does (spec §5: Freiburg ids mapped to MF's, everything else to MF's
//! unlabeled, which RTFNet's convention keeps in the matrix) and HeatNet's convention on
//! Freiburg (background predictions count as false positives, spec §2). With
//! [`OtherPixels::Ignored`] those truth pixels are dropped like the dataset's ignore id, so a
//! scored class only loses IoU to pixels of the other scored classes. Either way "other"
//! itself is never one of the scored classes ([`ClassMapScores`] averages the scored ones).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rtf_core::ClassSet;
use serde::{Deserialize, Serialize};

use crate::{EvalReport, Scores};

/// The built-in maps, by name: HeatNet Tab. I's person, car, bicycle between MF and Freiburg
/// Thermal (network side first).
pub const BUILT_IN: [&str; 2] = ["mf-to-freiburg", "freiburg-to-mf"];

/// Name of the last row and column of a mapped confusion matrix.
pub const OTHER: &str = "other";

/// Truth label value a mapped matrix drops (the dataset's ignore id and, with
/// [`OtherPixels::Ignored`], unscored classes).
const DROPPED: u8 = u8::MAX;

/// Which classes are scored, and which classes of the network and of the dataset count as
/// each. Read from YAML ([`ClassMap::from_yaml`]) or built in ([`ClassMap::built_in`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassMap {
    /// Shown in reports; a file's stem when the file gives none.
    #[serde(default)]
    pub name: String,
    /// The network's class set (`mf` or `freiburg`) for weights that do not record theirs;
    /// weights that do are read with their own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub network_classes: Option<String>,
    /// The scored classes, in the order they are reported.
    pub classes: Vec<ScoredClass>,
    /// What truth pixels of no scored class are (see the module docs).
    #[serde(default)]
    pub other_pixels: OtherPixels,
    /// Where the map came from: `built-in` or its file (set by the constructors).
    #[serde(skip)]
    pub source: String,
}

/// One scored class: its name and the classes (names or ids) that count as it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScoredClass {
    pub name: String,
    /// Output classes of the network.
    pub network: Vec<ClassRef>,
    /// Label classes of the dataset.
    pub data: Vec<ClassRef>,
}

/// A class by name or by id (index in its class set).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ClassRef {
    Id(u64),
    Name(String),
}

impl std::fmt::Display for ClassRef {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ClassRef::Id(id) => write!(f, "id {id}"),
            ClassRef::Name(name) => write!(f, "`{name}`"),
        }
    }
}

/// Truth pixels of a dataset class that no scored class takes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OtherPixels {
    /// Kept as the "other" row: a false positive of the scored class they are predicted as.
    #[default]
    Counted,
    /// Dropped, as the dataset's ignore id.
    Ignored,
}

#[derive(Debug, thiserror::Error)]
pub enum ClassMapError {
    #[error(
        "class map `{spec}` is neither a built-in map ({}) nor a file",
        BUILT_IN.join(", ")
    )]
    Unknown { spec: String },
    #[error("{}: {message}", path.display())]
    File { path: PathBuf, message: String },
    /// A map that does not fit the class sets; `map` is its file (or built-in name).
    #[error("class map {map}: {message}")]
    Invalid { map: String, message: String },
}

impl ClassMap {
    /// A built-in map ([`BUILT_IN`]) by name, else the YAML file at `spec`.
    pub fn load(spec: &str) -> Result<Self, ClassMapError> {
        if let Some(map) = Self::built_in(spec) {
            return Ok(map);
        }
        let path = Path::new(spec);
        if !path.is_file() {
            return Err(ClassMapError::Unknown {
                spec: spec.to_string(),
            });
        }
        Self::from_file(path)
    }

    /// The YAML file at `path`.
    pub fn from_file(path: &Path) -> Result<Self, ClassMapError> {
        let text = std::fs::read_to_string(path).map_err(|e| ClassMapError::File {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let mut map = Self::from_yaml(&text).map_err(|message| ClassMapError::File {
            path: path.to_path_buf(),
            message,
        })?;
        map.source = path.display().to_string();
        if map.name.is_empty() {
            map.name = path
                .file_stem()
                .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
        }
        Ok(map)
    }

    /// A map from YAML text; the error says where it does not parse.
    pub fn from_yaml(text: &str) -> Result<Self, String> {
        let map: ClassMap = serde_yaml_ng::from_str(text).map_err(|e| e.to_string())?;
        if map.classes.is_empty() {
            return Err("`classes` lists no scored class".into());
        }
        Ok(map)
    }

    /// HeatNet Tab. I's evaluation between MF and Freiburg Thermal (paper §V-B: "the classes
    /// *Car*, *Person*, and *Bike*", columns Person, Car, Bicycle): Freiburg's person
    /// (person/rider), car (car/truck/bus/train) and bicycle (bicycle/motorcycle) against MF's
    /// person, car and bike; the authors' code maps every other Freiburg class to MF's
    /// unlabeled (spec §5), hence [`OtherPixels::Counted`].
    pub fn built_in(name: &str) -> Option<Self> {
        let (network, mf_side) = match name {
            "mf-to-freiburg" => ("mf", true),
            "freiburg-to-mf" => ("freiburg", false),
            _ => return None,
        };
        let pair = |scored: &str, mf: &str, freiburg: &str| {
            let (n, d) = if mf_side {
                (mf, freiburg)
            } else {
                (freiburg, mf)
            };
            ScoredClass {
                name: scored.into(),
                network: vec![ClassRef::Name(n.into())],
                data: vec![ClassRef::Name(d.into())],
            }
        };
        Some(Self {
            name: name.into(),
            network_classes: Some(network.into()),
            classes: vec![
                pair("person", "person", "person"),
                pair("car", "car", "car"),
                pair("bicycle", "bike", "bicycle"),
            ],
            other_pixels: OtherPixels::Counted,
            source: "built-in".into(),
        })
    }

    /// The class set named by `network_classes` (`mf`, `freiburg`); None when the map names
    /// none. An unknown name is an error.
    pub fn network_class_set(&self) -> Result<Option<ClassSet>, ClassMapError> {
        match self.network_classes.as_deref() {
            None => Ok(None),
            Some("mf") => Ok(Some(ClassSet::mf())),
            Some("freiburg") => Ok(Some(ClassSet::freiburg())),
            Some(other) => Err(self.invalid(format!(
                "network_classes `{other}` is not a class set rtf knows (mf, freiburg)"
            ))),
        }
    }

    /// An error naming the map's file (a built-in map: its name).
    fn invalid(&self, message: String) -> ClassMapError {
        let map = match self.source.as_str() {
            "" | "built-in" => format!("`{}`", self.name),
            file => file.to_string(),
        };
        ClassMapError::Invalid { map, message }
    }

    /// Checks the map against the network's and the dataset's class sets: every class it
    /// names must be one of its side's (by name or id), none may count twice, and each
    /// scored class needs a class on both sides.
    pub fn resolve(
        &self,
        network: &ClassSet,
        data: &ClassSet,
    ) -> Result<ClassMapping, ClassMapError> {
        let k = self.classes.len();
        if k == 0 || k >= DROPPED as usize {
            return Err(self.invalid(format!("{k} scored classes (1 to 254 possible)")));
        }
        let mut seen = Vec::new();
        for c in &self.classes {
            if c.name == OTHER || seen.contains(&&c.name) {
                return Err(self.invalid(format!(
                    "scored class `{}` is named twice or is the reserved `{OTHER}`",
                    c.name
                )));
            }
            seen.push(&c.name);
        }
        let network_to_scored = self.side(network, "network", |c| &c.network)?;
        let data_to_scored = self.side(data, "data", |c| &c.data)?;
        let other = k as u8;
        let data_lookup = (0..256usize)
            .map(|v| match data_to_scored.get(v) {
                Some(Some(s)) => *s,
                _ if data.ignore_id == Some(v as u8) || v >= data.len() => DROPPED,
                _ if self.other_pixels == OtherPixels::Ignored => DROPPED,
                _ => other,
            })
            .collect();
        Ok(ClassMapping {
            map: self.clone(),
            scored: self.classes.iter().map(|c| c.name.clone()).collect(),
            network_classes: network.names().iter().map(|s| s.to_string()).collect(),
            data_classes: data.names().iter().map(|s| s.to_string()).collect(),
            network_lookup: network_to_scored
                .iter()
                .map(|s| s.unwrap_or(other))
                .collect(),
            data_lookup,
        })
    }

    /// The scored class of each class of `set` (None: none), from one side of the map.
    fn side(
        &self,
        set: &ClassSet,
        which: &str,
        refs: fn(&ScoredClass) -> &[ClassRef],
    ) -> Result<Vec<Option<u8>>, ClassMapError> {
        let mut to_scored: Vec<Option<u8>> = vec![None; set.len()];
        let listing = listing(set);
        for (s, scored) in self.classes.iter().enumerate() {
            if refs(scored).is_empty() {
                return Err(self.invalid(format!(
                    "scored class `{}` lists no {which} class",
                    scored.name
                )));
            }
            for r in refs(scored) {
                let id = match r {
                    ClassRef::Id(id) => Some(*id as usize).filter(|&i| i < set.len()),
                    ClassRef::Name(name) => set.names().iter().position(|n| n == name),
                };
                let Some(id) = id else {
                    return Err(self.invalid(format!(
                        "{which} class {r} (under `{}`) is not one of the {which}'s {listing}",
                        scored.name
                    )));
                };
                if let Some(before) = to_scored[id] {
                    return Err(self.invalid(format!(
                        "{which} class {r} counts as both `{}` and `{}`",
                        self.classes[before as usize].name, scored.name
                    )));
                }
                to_scored[id] = Some(s as u8);
            }
        }
        Ok(to_scored)
    }
}

/// `9 classes (mf: 0 unlabeled, 1 car, …)`.
fn listing(set: &ClassSet) -> String {
    let names: Vec<String> = set
        .names()
        .iter()
        .enumerate()
        .map(|(i, n)| format!("{i} {n}"))
        .collect();
    format!("{} classes ({}: {})", set.len(), set.name, names.join(", "))
}

/// A [`ClassMap`] checked against a network's and a dataset's class sets: the lookup tables
/// [`crate::evaluate_mapped`] translates predictions and labels through.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ClassMapping {
    pub map: ClassMap,
    /// The scored classes' names; the matrix has one more class, [`OTHER`], last.
    pub scored: Vec<String>,
    pub network_classes: Vec<String>,
    pub data_classes: Vec<String>,
    /// Scored index (or `scored.len()`: other) of each network output.
    #[serde(skip)]
    network_lookup: Vec<u8>,
    /// Scored index, other, or dropped of each label value 0..=255.
    #[serde(skip)]
    data_lookup: Vec<u8>,
}

impl ClassMapping {
    /// Classes of the mapped matrix: the scored ones, then [`OTHER`].
    pub fn matrix_names(&self) -> Vec<&str> {
        let mut names: Vec<&str> = self.scored.iter().map(String::as_str).collect();
        names.push(OTHER);
        names
    }

    /// Label value a mapped truth tensor uses for dropped pixels (the matrix's ignore id).
    pub fn dropped(&self) -> u8 {
        DROPPED
    }

    /// Scored index (or other) of network output `id`.
    pub fn network_to_scored(&self, id: usize) -> Option<u8> {
        self.network_lookup.get(id).copied()
    }

    /// Scored index, other, or [`Self::dropped`] of label value `value`.
    pub fn data_to_scored(&self, value: u8) -> u8 {
        self.data_lookup[value as usize]
    }

    /// Network class ids [any shape] → mapped ids (same shape, int64, same device).
    pub fn map_prediction(&self, prediction: &tch::Tensor) -> tch::Tensor {
        let lut: Vec<i64> = self.network_lookup.iter().map(|&v| v as i64).collect();
        let n = lut.len() as i64;
        lookup(&lut, &prediction.clamp(0, n - 1), prediction.device())
    }

    /// Label values [any shape] → mapped ids, dropped pixels [`Self::dropped`].
    pub fn map_truth(&self, truth: &tch::Tensor) -> tch::Tensor {
        let lut: Vec<i64> = self.data_lookup.iter().map(|&v| v as i64).collect();
        // Values outside 0..=255 (none in a label file) are dropped with the rest.
        let inside = truth.ge(0).logical_and(&truth.le(255));
        let mapped = lookup(&lut, &truth.clamp(0, 255), truth.device());
        mapped.where_self(&inside, &mapped.full_like(DROPPED as i64))
    }
}

fn lookup(lut: &[i64], ids: &tch::Tensor, device: tch::Device) -> tch::Tensor {
    let table = tch::Tensor::from_slice(lut).to_device(device);
    let flat = ids.to_kind(tch::Kind::Int64).flatten(0, -1);
    table.index_select(0, &flat).view(ids.size().as_slice())
}

/// What the scores file and the report say about a mapped evaluation: the map, what it was
/// checked against, and the mean IoU over the scored classes (a class without pixels in truth
/// or prediction skipped, as HeatNet's convention; "other" never counted).
#[derive(Debug, Clone, Serialize)]
pub struct ClassMapScores {
    pub name: String,
    /// `built-in` or the file it was read from.
    pub source: String,
    pub scored: Vec<String>,
    pub other_pixels: OtherPixels,
    /// Scored class → the network's and the dataset's classes that count as it.
    pub network: BTreeMap<String, Vec<String>>,
    pub data: BTreeMap<String, Vec<String>>,
    pub miou: Option<f64>,
    pub day_miou: Option<f64>,
    pub night_miou: Option<f64>,
    /// Mean of the day and the night mIoU (HeatNet's Day/Night).
    pub day_night_miou: Option<f64>,
}

impl ClassMapScores {
    pub fn of(mapping: &ClassMapping, report: &EvalReport) -> Self {
        let k = mapping.scored.len();
        let miou = |s: &Scores| s.miou_heatnet(k);
        let day_miou = report.day.as_ref().and_then(miou);
        let night_miou = report.night.as_ref().and_then(miou);
        let by_scored = |classes: &[String], lookup: &dyn Fn(usize) -> Option<u8>| {
            let mut out: BTreeMap<String, Vec<String>> = BTreeMap::new();
            for (id, name) in classes.iter().enumerate() {
                if let Some(s) = lookup(id).filter(|&s| (s as usize) < k) {
                    out.entry(mapping.scored[s as usize].clone())
                        .or_default()
                        .push(name.clone());
                }
            }
            out
        };
        Self {
            name: mapping.map.name.clone(),
            source: mapping.map.source.clone(),
            scored: mapping.scored.clone(),
            other_pixels: mapping.map.other_pixels,
            network: by_scored(&mapping.network_classes, &|i| mapping.network_to_scored(i)),
            data: by_scored(&mapping.data_classes, &|i| {
                Some(mapping.data_to_scored(i as u8))
            }),
            miou: miou(&report.all),
            day_miou,
            night_miou,
            day_night_miou: day_miou.zip(night_miou).map(|(d, n)| (d + n) / 2.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{evaluate_mapped, EvalOptions};
    use rtf_core::{ClassInfo, Daytime};
    use rtf_data::{Frame, FrameSource, MemorySource};
    use rtf_models::Network;
    use std::sync::Arc;
    use tch::nn::ModuleT;
    use tch::{Device, Kind, Tensor};

    fn set(name: &str, names: &[&str], ignore_id: Option<u8>) -> ClassSet {
        ClassSet {
            name: name.into(),
            classes: names
                .iter()
                .enumerate()
                .map(|(i, n)| ClassInfo {
                    id: i as u8,
                    name: n.to_string(),
                    color: [i as u8; 3],
                })
                .collect(),
            ignore_id,
            label_values: None,
        }
    }

    /// The network's 4 outputs and the data's 5 classes (9 = ignore): other lists, other ids.
    fn network_set() -> ClassSet {
        set("net", &["bg", "car", "person", "bike"], None)
    }
    fn data_set() -> ClassSet {
        set(
            "data",
            &["road", "person", "rider", "vehicle", "sky"],
            Some(9),
        )
    }

    /// person ← person / person + rider; vehicle ← car + bike (by id) / vehicle.
    const MAP: &str = "
classes:
  - name: person
    network: [person]
    data: [person, rider]
  - name: vehicle
    network: [car, 3]
    data: [vehicle]
";

    /// Predicts, per pixel, the class id written in its thermal channel (id / 10).
    #[derive(Debug)]
    struct ThermalSaysClass;

    impl ModuleT for ThermalSaysClass {
        fn forward_t(&self, xs: &Tensor, _train: bool) -> Tensor {
            let ids = (xs.narrow(1, 3, 1) * 10.0).round().to_kind(Kind::Int64);
            ids.squeeze_dim(1)
                .one_hot(4)
                .permute([0, 3, 1, 2])
                .to_kind(Kind::Float)
        }
    }

    impl Network for ThermalSaysClass {
        fn input_convention(&self) -> rtf_core::InputConvention {
            rtf_core::InputConvention::UnitRange
        }
        fn num_classes(&self) -> i64 {
            4
        }
        fn size_multiple(&self) -> i64 {
            1
        }
        fn name(&self) -> String {
            "thermal-says-class".into()
        }
    }

    fn frame(name: &str, daytime: Daytime, truth: &[u8], predicted: &[u8]) -> Frame {
        Frame {
            name: name.into(),
            daytime: Some(daytime),
            width: truth.len(),
            height: 1,
            rgb: vec![0; 3 * truth.len()],
            thermal: predicted.iter().map(|&p| p as f32 / 10.0).collect(),
            label: Some(truth.to_vec()),
        }
    }

    fn evaluate_through(map: &ClassMap) -> EvalReport {
        let source: Arc<dyn FrameSource> = Arc::new(MemorySource {
            frames: vec![
                // Data ids (9 ignored) against network ids.
                frame(
                    "d",
                    Daytime::Day,
                    &[1, 2, 3, 3, 0, 4, 9, 1],
                    &[2, 2, 1, 3, 2, 0, 2, 0],
                ),
                frame("n", Daytime::Night, &[3, 1], &[0, 2]),
            ],
            class_set: data_set(),
        });
        let mapping = map.resolve(&network_set(), &data_set()).unwrap();
        let options = EvalOptions {
            batch_size: 1,
            workers: 1,
            ..Default::default()
        };
        let net = ThermalSaysClass;
        evaluate_mapped(&net, source, &options, None, Some(&mapping), Device::Cpu).unwrap()
    }

    fn iou(scores: &Scores, class: usize) -> f64 {
        scores.per_class[class].iou.unwrap()
    }

    #[test]
    fn a_map_scores_two_class_lists_as_the_matrix_by_hand() {
        let map = ClassMap::from_yaml(MAP).unwrap();
        let report = evaluate_through(&map);
        // Mapped (truth → prediction), scored 0 person, 1 vehicle, 2 other; the ignored pixel
        // dropped. Day: p→p p→p v→v v→v o→p o→o p→o; night: v→o p→p.
        let rows = [[3, 0, 1], [0, 2, 1], [1, 0, 1]];
        for (t, row) in rows.iter().enumerate() {
            for (p, &count) in row.iter().enumerate() {
                assert_eq!(
                    report.confusion.get(t, p),
                    count,
                    "truth {t} prediction {p}"
                );
            }
        }
        // person: TP 3, truth 4, predicted 4 (one road pixel taken for a person).
        assert!((iou(&report.all, 0) - 3.0 / 5.0).abs() < 1e-12);
        // vehicle: TP 2, truth 3, predicted 2.
        assert!((iou(&report.all, 1) - 2.0 / 3.0).abs() < 1e-12);
        let day = report.day.as_ref().unwrap();
        assert!((iou(day, 0) - 2.0 / 4.0).abs() < 1e-12);
        assert!((iou(day, 1) - 1.0).abs() < 1e-12);
        let night = report.night.as_ref().unwrap();
        assert_eq!((iou(night, 0), iou(night, 1)), (1.0, 0.0));
        let mapping = map.resolve(&network_set(), &data_set()).unwrap();
        let scores = ClassMapScores::of(&mapping, &report);
        assert!((scores.miou.unwrap() - (3.0 / 5.0 + 2.0 / 3.0) / 2.0).abs() < 1e-12);
        assert!((scores.day_night_miou.unwrap() - (0.75 + 0.5) / 2.0).abs() < 1e-12);
        assert_eq!(scores.network["vehicle"], ["car", "bike"]);
        assert_eq!(scores.data["person"], ["person", "rider"]);
        assert_eq!(report.all.per_class[2].name, OTHER);
    }

    #[test]
    fn ignored_other_pixels_cost_no_false_positives() {
        let mut map = ClassMap::from_yaml(MAP).unwrap();
        map.other_pixels = OtherPixels::Ignored;
        let report = evaluate_through(&map);
        // The road and sky pixels are dropped: person 3 / (4 + 3 - 3).
        assert_eq!(report.confusion.get(2, 0) + report.confusion.get(2, 2), 0);
        assert!((iou(&report.all, 0) - 3.0 / 4.0).abs() < 1e-12);
        assert!((iou(&report.all, 1) - 2.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn the_built_in_maps_fit_mf_and_freiburg_both_ways() {
        let (mf, fr) = (ClassSet::mf(), ClassSet::freiburg());
        let to_fr = ClassMap::load("mf-to-freiburg")
            .unwrap()
            .resolve(&mf, &fr)
            .unwrap();
        assert_eq!(to_fr.scored, ["person", "car", "bicycle"]);
        // MF bike (3) → bicycle (2); MF curve → other; Freiburg bicycle (11) → 2, road →
        // other, ignore (13) dropped.
        assert_eq!(to_fr.network_to_scored(3), Some(2));
        assert_eq!(to_fr.network_to_scored(4), Some(3));
        assert_eq!(to_fr.data_to_scored(11), 2);
        assert_eq!(to_fr.data_to_scored(0), 3);
        assert_eq!(to_fr.data_to_scored(13), to_fr.dropped());
        let to_mf = ClassMap::load("freiburg-to-mf")
            .unwrap()
            .resolve(&fr, &mf)
            .unwrap();
        assert_eq!(to_mf.network_to_scored(9), Some(0));
        assert_eq!(to_mf.data_to_scored(1), 1);
        assert_eq!(
            ClassMap::built_in("freiburg-to-mf")
                .unwrap()
                .network_class_set()
                .unwrap(),
            Some(fr)
        );
    }

    fn resolve_error(yaml: &str) -> String {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mine.yaml");
        std::fs::write(&path, yaml).unwrap();
        let err = ClassMap::load(path.to_str().unwrap())
            .and_then(|m| m.resolve(&network_set(), &data_set()))
            .unwrap_err()
            .to_string();
        assert!(err.contains("mine.yaml"), "the file is not named: {err}");
        err
    }

    #[test]
    fn bad_maps_name_the_file_and_the_class() {
        let err = resolve_error(&MAP.replace("[person, rider]", "[person, cyclist]"));
        assert!(err.contains("`cyclist`") && err.contains("data"), "{err}");
        assert!(
            err.contains("0 road"),
            "the data's classes are listed: {err}"
        );
        let err = resolve_error(&MAP.replace("[car, 3]", "[car, 7]"));
        assert!(err.contains("id 7") && err.contains("network"), "{err}");
        let err = resolve_error(&MAP.replace("[vehicle]", "[vehicle, rider]"));
        assert!(err.contains("`rider`") && err.contains("both"), "{err}");
        let err = resolve_error(&MAP.replace("    data: [vehicle]\n", "    data: []\n"));
        assert!(
            err.contains("`vehicle`") && err.contains("no data class"),
            "{err}"
        );
        let err = resolve_error("classes:\n  - name: person\n    network: [person\n");
        assert!(err.contains("line"), "where it does not parse: {err}");
        let err = resolve_error(&MAP.replace("classes:", "clases:"));
        assert!(err.contains("clases"), "{err}");
        let unknown = ClassMap::load("no-such-map").unwrap_err().to_string();
        assert!(unknown.contains("mf-to-freiburg"), "{unknown}");
    }
}
