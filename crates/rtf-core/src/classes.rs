//! Class sets: ids, names and palettes of the datasets rtf knows.

use serde::{Deserialize, Serialize};

/// One semantic class.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ClassInfo {
    pub id: u8,
    pub name: String,
    /// Palette colour, RGB.
    pub color: [u8; 3],
}

/// An ordered set of classes (id = index = network output), plus an optional label id that
/// means "ignore".
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ClassSet {
    pub name: String,
    pub classes: Vec<ClassInfo>,
    /// Label id excluded from training and metrics (Freiburg: 13); None for MF.
    pub ignore_id: Option<u8>,
    /// The values a dataset's label files use, when they are not the output indices (ids from
    /// 1, ids with gaps, several values ignored); `None`: label value = output index.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label_values: Option<LabelValues>,
}

/// How a dataset's label values map to the network's outputs (and back, for predictions
/// written with the dataset's ids).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LabelValues {
    /// The label value of each output, in output order.
    pub classes: Vec<u8>,
    /// Label values excluded from training and metrics (read as the set's `ignore_id`).
    pub ignored: Vec<u8>,
}

impl LabelValues {
    /// Output index (or the ignore id) of each label value 0..=255; `None`: not in the set.
    pub fn lookup(&self, ignore_id: Option<u8>) -> [Option<u8>; 256] {
        let mut table = [None; 256];
        for (output, &value) in self.classes.iter().enumerate() {
            table[value as usize] = Some(output as u8);
        }
        for &value in &self.ignored {
            table[value as usize] = ignore_id;
        }
        table
    }
}

const MF: [(&str, [u8; 3]); 9] = [
    ("unlabeled", [0, 0, 0]),
    ("car", [64, 0, 128]),
    ("person", [64, 64, 0]),
    ("bike", [0, 128, 192]),
    ("curve", [0, 0, 192]),
    ("car_stop", [128, 128, 0]),
    ("guardrail", [64, 64, 128]),
    ("color_cone", [192, 128, 128]),
    ("bump", [192, 64, 0]),
];

const FREIBURG: [(&str, [u8; 3]); 13] = [
    ("road", [128, 64, 128]),
    ("sidewalk", [244, 35, 232]),
    ("building", [70, 70, 70]),
    ("curb", [196, 196, 196]),
    ("fence", [190, 153, 153]),
    ("pole_sign", [220, 220, 0]),
    ("vegetation", [107, 142, 35]),
    ("terrain", [152, 251, 152]),
    ("sky", [70, 130, 180]),
    ("person", [220, 20, 60]),
    ("car", [0, 0, 142]),
    ("bicycle", [119, 11, 32]),
    ("background", [0, 0, 0]),
];

impl ClassSet {
    fn from_table(name: &str, table: &[(&str, [u8; 3])], ignore_id: Option<u8>) -> Self {
        let classes = table
            .iter()
            .enumerate()
            .map(|(id, (n, c))| ClassInfo {
                id: id as u8,
                name: n.to_string(),
                color: *c,
            })
            .collect();
        Self {
            name: name.to_string(),
            classes,
            ignore_id,
            label_values: None,
        }
    }

    /// What a label file's values mean beyond the class ids, for messages: ", ignore id 255",
    /// or for mapped values ", label values 1, 2, 3; ignored 0"; empty when neither applies.
    pub fn values_note(&self) -> String {
        let list = |v: &[u8]| v.iter().map(u8::to_string).collect::<Vec<_>>().join(", ");
        match (&self.label_values, self.ignore_id) {
            (Some(values), _) if values.ignored.is_empty() => {
                format!(", label values {}", list(&values.classes))
            }
            (Some(values), _) => format!(
                ", label values {}; ignored {}",
                list(&values.classes),
                list(&values.ignored)
            ),
            (None, Some(id)) => format!(", ignore id {id}"),
            (None, None) => String::new(),
        }
    }

    /// The label value a dataset file uses for output `index` (the index itself unless the
    /// set maps values; the ignore id maps to the first ignored value).
    pub fn label_value(&self, index: u8) -> u8 {
        let Some(values) = &self.label_values else {
            return index;
        };
        match values.classes.get(index as usize) {
            Some(&value) => value,
            None => values.ignored.first().copied().unwrap_or(index),
        }
    }

    /// The MF dataset's 9 classes (MFNet paper; spec §1).
    pub fn mf() -> Self {
        Self::from_table("mf", &MF, None)
    }

    /// Freiburg Thermal's 13 classes, 13 = ignore (HeatNet; spec §5).
    pub fn freiburg() -> Self {
        Self::from_table("freiburg", &FREIBURG, Some(13))
    }

    pub fn len(&self) -> usize {
        self.classes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.classes.is_empty()
    }

    pub fn names(&self) -> Vec<&str> {
        self.classes.iter().map(|c| c.name.as_str()).collect()
    }

    /// Whether class 0 is "unlabelled" (named unlabeled, unlabelled or void, as MF's is and as
    /// a dataset.yaml declares it): the condition of the MFNet paper's mIoU, which leaves
    /// class 0 out of the sums ([`first_is_unlabelled`]).
    pub fn first_is_unlabelled(&self) -> bool {
        self.classes
            .first()
            .is_some_and(|c| first_is_unlabelled(&[&c.name]))
    }

    /// Palette colour of a label id; ids outside the set (e.g. ignore) are drawn white.
    pub fn color(&self, id: u8) -> [u8; 3] {
        self.classes
            .get(id as usize)
            .map_or([255, 255, 255], |c| c.color)
    }

    /// Colourises a label map (row-major ids) into packed RGB bytes.
    pub fn colorize(&self, ids: &[u8]) -> Vec<u8> {
        ids.iter().flat_map(|&id| self.color(id)).collect()
    }
}

/// Whether the first of class `names` names unlabelled pixels: `unlabeled`, `unlabelled` or
/// `void` (any case). Only then is the MFNet paper's mIoU (class 0 out of the sums) a score
/// of the set; for a set whose class 0 is a class (road, background, …) it would silently drop
/// that class.
pub fn first_is_unlabelled(names: &[&str]) -> bool {
    names.first().is_some_and(|n| {
        let n = n.to_ascii_lowercase();
        matches!(n.as_str(), "unlabeled" | "unlabelled" | "void")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn label_values_map_both_ways_and_old_records_read_without_them() {
        let mut set = ClassSet::mf();
        assert_eq!(set.label_value(3), 3);
        set.label_values = Some(LabelValues {
            classes: (1..=9).collect(),
            ignored: vec![0, 200],
        });
        set.ignore_id = Some(255);
        let table = set.label_values.as_ref().unwrap().lookup(set.ignore_id);
        assert_eq!(
            (table[1], table[9], table[0], table[200], table[10]),
            (Some(0), Some(8), Some(255), Some(255), None)
        );
        assert_eq!(
            (set.label_value(0), set.label_value(8), set.label_value(255)),
            (1, 9, 0)
        );
        let old = r#"{"name": "mf", "classes": [], "ignore_id": null}"#;
        let read: ClassSet = serde_json::from_str(old).unwrap();
        assert_eq!(read.label_values, None);
        assert!(!serde_json::to_string(&ClassSet::mf())
            .unwrap()
            .contains("label_values"));
    }

    #[test]
    fn mf_set_matches_the_paper() {
        let mf = ClassSet::mf();
        assert_eq!(mf.len(), 9);
        assert_eq!(mf.classes[2].name, "person");
        assert_eq!(mf.color(1), [64, 0, 128]);
        assert_eq!(mf.color(8), [192, 64, 0]);
        assert_eq!(mf.ignore_id, None);
    }

    #[test]
    fn freiburg_set_has_ignore() {
        let fr = ClassSet::freiburg();
        assert_eq!(fr.len(), 13);
        assert_eq!(fr.ignore_id, Some(13));
        assert_eq!(fr.color(13), [255, 255, 255]);
    }

    #[test]
    fn colorize_packs_rgb() {
        let mf = ClassSet::mf();
        assert_eq!(mf.colorize(&[0, 1]), vec![0, 0, 0, 64, 0, 128]);
    }
}
