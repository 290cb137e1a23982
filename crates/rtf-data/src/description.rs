//! A dataset description: where a dataset's RGB, thermal and label files are, its class set,
//! how labels and thermal are encoded, and which frames are night. Written by the user as
//! `ROOT/dataset.yaml` (the plain layout; docs/src/data.md "Your own data"), or built in code
//! for the field's layouts a root is recognised by ([`crate::layouts`]).
//!
//! ```yaml
//! classes:                      # id = label value = network output; ids 0..N-1
//!   - {id: 0, name: background, color: [0, 0, 0]}
//!   - {id: 1, name: pedestrian, color: "#DC143C"}   # or [220, 20, 60]
//! ignore_id: 255                # optional
//! label_encoding: ids           # or colors (RGB labels mapped through the palette)
//! thermal:
//!   range: [21800, 25000]       # 16-bit raw counts mapped linearly to [0, 1], clipped
//! splits:                       # optional; default {train,val,test}/{rgb,thermal,labels}
//!   train: {rgb: train/rgb, thermal: "train/ir/{name}_ir.png", labels: train/labels}
//! night: {suffix: N}            # or {list: night.txt} or {list: [a.txt, b.txt]}; default none
//! day: {list: [train_day.txt, test_day.txt]}   # optional, with night lists
//! unmatched_lines: error        # or warn: a list line naming no frame (default: error)
//! ```
//!
//! Unknown keys and contradictions are refused with the file and the line: a description
//! that rtf silently reads differently from what its writer meant costs a training run.

use std::collections::{BTreeMap, HashMap};
use std::path::{Component, Path, PathBuf};

use rtf_core::{ClassInfo, ClassSet};
use serde::{Deserialize, Serialize};

use crate::images::Format;
pub use crate::pattern::FilePattern;
use crate::thermal::{TemperatureMap, ThermalNormalisation};
use crate::DataError;

/// The file name of a plain-layout description.
pub const DESCRIPTION_FILE: &str = "dataset.yaml";

/// The layouts rtf reads through a description (module docs of [`crate::layouts`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LayoutKind {
    /// `ROOT/dataset.yaml` and the folders it names.
    Plain,
    Msrs,
    Pst900,
    Fmb,
}

impl LayoutKind {
    /// The layout's name as `rtf data check` prints it (its [`crate::DatasetFormat`]'s).
    pub fn name(self) -> &'static str {
        crate::DatasetFormat::from(self).name()
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LabelEncoding {
    /// One channel, the value is the class id (or the ignore id).
    #[default]
    Ids,
    /// RGB, each colour is a class's palette colour (or the ignore colour).
    Colors,
}

/// Which frames are night.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum NightRule {
    /// Day/night unknown (no day/night metrics).
    #[default]
    None,
    /// Names ending in this suffix are night, all others day (MF/MSRS: `N`).
    Suffix(String),
    /// The frames the lines of these list files name (in the formats of split lists,
    /// [`crate::split_list`]): with night lists only, the others are day; with day lists
    /// only, the others are night; with both, a frame in neither has no condition. Every line
    /// must name one frame of the dataset, and no frame may be both.
    Lists {
        day: Vec<PathBuf>,
        night: Vec<PathBuf>,
    },
}

/// What a list line that names no frame of the dataset is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UnmatchedLines {
    /// An error naming the list and the line (the default: never silently nothing).
    #[default]
    Error,
    /// Skipped, counted in a warning per list ([`crate::DescribedSplit::warnings`]).
    Warn,
}

/// One split: its files and, optionally, the list files whose union names its frames.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SplitSpec {
    pub name: String,
    pub rgb: FilePattern,
    pub thermal: FilePattern,
    /// `None`: the split has no labels (unlabelled frames).
    pub labels: Option<FilePattern>,
    /// Empty: every frame the patterns find.
    pub lists: Vec<PathBuf>,
}

/// A dataset as rtf reads it, whichever way it was described.
#[derive(Debug, Clone, PartialEq)]
pub struct DatasetDescription {
    pub root: PathBuf,
    /// The dataset.yaml, or the root of a built-in layout: what errors name.
    pub origin: PathBuf,
    pub layout: LayoutKind,
    pub class_set: ClassSet,
    pub labels: LabelEncoding,
    /// The colour of ignored pixels in colour-coded labels.
    pub ignore_color: Option<[u8; 3]>,
    pub thermal: ThermalNormalisation,
    pub splits: Vec<SplitSpec>,
    pub night: NightRule,
    pub unmatched_lines: UnmatchedLines,
}

impl DatasetDescription {
    pub fn split(&self, name: &str) -> Option<&SplitSpec> {
        self.splits.iter().find(|s| s.name == name)
    }

    pub fn split_names(&self) -> Vec<&str> {
        self.splits.iter().map(|s| s.name.as_str()).collect()
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDescription {
    name: Option<String>,
    classes: Vec<RawClass>,
    ignore_id: Option<OneOrMany>,
    ignore_color: Option<Colour>,
    #[serde(default)]
    label_encoding: LabelEncoding,
    #[serde(default)]
    thermal: RawThermal,
    splits: Option<BTreeMap<String, RawSplit>>,
    #[serde(default)]
    night: RawNight,
    day: Option<RawDay>,
    #[serde(default)]
    unmatched_lines: UnmatchedLines,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawClass {
    id: u8,
    name: String,
    color: Colour,
}

/// `ignore_id: 255` or `ignore_id: [0, 255]`.
#[derive(Deserialize, Clone)]
#[serde(untagged)]
enum OneOrMany {
    One(u8),
    Many(Vec<u8>),
}

impl OneOrMany {
    fn values(&self) -> Vec<u8> {
        match self {
            Self::One(v) => vec![*v],
            Self::Many(v) => v.clone(),
        }
    }
}

/// A colour as datasets write them: `[r, g, b]` or `"#RRGGBB"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Colour([u8; 3]);

impl<'de> Deserialize<'de> for Colour {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(ColourVisitor)
    }
}

struct ColourVisitor;

impl<'de> serde::de::Visitor<'de> for ColourVisitor {
    type Value = Colour;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a colour as [r, g, b] (0-255 each) or \"#RRGGBB\"")
    }

    fn visit_str<E: serde::de::Error>(self, text: &str) -> Result<Colour, E> {
        let hex = text.strip_prefix('#').filter(|h| h.len() == 6);
        let parse = |h: &str| -> Option<[u8; 3]> {
            let byte = |i: usize| u8::from_str_radix(h.get(i..i + 2)?, 16).ok();
            Some([byte(0)?, byte(2)?, byte(4)?])
        };
        hex.and_then(parse).map(Colour).ok_or_else(|| {
            E::custom(format!(
                "colour '{text}' is not \"#RRGGBB\" (six hex digits) or [r, g, b]"
            ))
        })
    }

    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Colour, A::Error> {
        let mut rgb = [0u8; 3];
        for (i, slot) in rgb.iter_mut().enumerate() {
            *slot = seq
                .next_element()?
                .ok_or_else(|| serde::de::Error::invalid_length(i, &self))?;
        }
        if seq.next_element::<serde::de::IgnoredAny>()?.is_some() {
            return Err(serde::de::Error::invalid_length(4, &self));
        }
        Ok(Colour(rgb))
    }
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RawThermal {
    range: Option<[f64; 2]>,
    #[serde(default)]
    min_max: bool,
    percentile: Option<[f64; 2]>,
    to_temperature: Option<TemperatureMap>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSplit {
    rgb: String,
    thermal: String,
    labels: Option<String>,
    list: Option<Paths>,
}

/// `list: a.txt` or `list: [a.txt, b.txt]`.
#[derive(Deserialize, Clone)]
#[serde(untagged)]
enum Paths {
    One(String),
    Many(Vec<String>),
}

impl Paths {
    fn written(&self) -> Vec<&str> {
        match self {
            Self::One(p) => vec![p.as_str()],
            Self::Many(p) => p.iter().map(String::as_str).collect(),
        }
    }
}

/// `{suffix: N}` or `{list: night.txt}` (or several lists); absent: day/night unknown.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RawNight {
    suffix: Option<String>,
    list: Option<Paths>,
}

/// `{list: day.txt}` (or several lists).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDay {
    list: Paths,
}

/// Reads and checks `ROOT/dataset.yaml` (or any description file; paths in it are relative
/// to its folder).
pub fn read_description(file: &Path) -> Result<DatasetDescription, DataError> {
    let text = std::fs::read_to_string(file).map_err(|e| DataError::io(file, e))?;
    parse_description(&text, file)
}

/// Parses description `text` read from `file`.
pub fn parse_description(text: &str, file: &Path) -> Result<DatasetDescription, DataError> {
    let raw: RawDescription =
        serde_yaml_ng::from_str(text).map_err(|e| DataError::Description {
            path: file.to_path_buf(),
            message: e.to_string(),
        })?;
    let root = file
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf();
    let at = Located { file, text };
    let name = raw.name.clone().unwrap_or_else(|| folder_name(&root));
    let class_set = class_set(&raw, name, &at)?;
    check_label_encoding(&raw, &at)?;
    let thermal = thermal_rule(&raw.thermal, &at)?;
    let splits = match &raw.splits {
        Some(splits) => described_splits(splits, &root, &at)?,
        None => plain_splits(&root, &at)?,
    };
    let night = night_rule(&raw.night, raw.day.as_ref(), &root, &at)?;
    Ok(DatasetDescription {
        origin: file.to_path_buf(),
        root,
        layout: LayoutKind::Plain,
        class_set,
        labels: raw.label_encoding,
        ignore_color: raw.ignore_color.map(|c| c.0),
        thermal,
        splits,
        night,
        unmatched_lines: raw.unmatched_lines,
    })
}

fn folder_name(root: &Path) -> String {
    std::fs::canonicalize(root)
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| "dataset".into())
}

/// The description's text, to name the line of a problem found after parsing.
struct Located<'a> {
    file: &'a Path,
    text: &'a str,
}

impl Located<'_> {
    /// An error naming the file and, when found, the line.
    fn error(&self, line: Option<usize>, message: impl std::fmt::Display) -> DataError {
        DataError::Description {
            path: self.file.to_path_buf(),
            message: match line {
                Some(line) => format!("line {line}: {message}"),
                None => message.to_string(),
            },
        }
    }

    /// The first line whose content starts with `key:` (after indentation, `- ` or `{`).
    fn key_line(&self, key: &str) -> Option<usize> {
        self.text
            .lines()
            .position(|l| {
                let l = l.trim_start().trim_start_matches(['-', '{', ' ']);
                l.strip_prefix(key)
                    .is_some_and(|rest| rest.trim_start().starts_with(':'))
            })
            .map(|i| i + 1)
    }

    /// The first line containing `needle` (a path or a value as written).
    fn line_with(&self, needle: &str) -> Option<usize> {
        self.text
            .lines()
            .position(|l| l.contains(needle))
            .map(|i| i + 1)
    }

    /// The line of each entry of the `classes:` list, in order.
    fn class_lines(&self) -> Vec<usize> {
        let Some(start) = self.key_line("classes") else {
            return Vec::new();
        };
        let lines: Vec<&str> = self.text.lines().collect();
        let indent = |l: &str| l.len() - l.trim_start().len();
        let key_indent = indent(lines[start - 1]);
        let mut out = Vec::new();
        let mut item_indent = None;
        for (i, line) in lines.iter().enumerate().skip(start) {
            let content = line.trim_start();
            if content.is_empty() || content.starts_with('#') {
                continue;
            }
            if !content.starts_with('-') && indent(line) <= key_indent {
                break;
            }
            if content.starts_with('-') && *item_indent.get_or_insert(indent(line)) == indent(line)
            {
                out.push(i + 1);
            }
        }
        out
    }
}

/// The class list: distinct ids 0–255 and unique names; the ignore values distinct and not
/// class ids. Ids exactly 0..N-1 are the network's outputs themselves (output k = id k);
/// any other ids make the outputs follow the list's order, with the label values recorded
/// ([`rtf_core::LabelValues`]), as are several ignore values (read as ignore id 255).
fn class_set(raw: &RawDescription, name: String, at: &Located) -> Result<ClassSet, DataError> {
    let lines = at.class_lines();
    let line = |k: usize| lines.get(k).copied().or_else(|| at.key_line("classes"));
    if raw.classes.is_empty() {
        return Err(at.error(at.key_line("classes"), "the class list is empty"));
    }
    let mut by_id: HashMap<u8, usize> = HashMap::new();
    let mut by_name: HashMap<&str, usize> = HashMap::new();
    for (k, class) in raw.classes.iter().enumerate() {
        if let Some(first) = by_id.insert(class.id, k) {
            let message = format!(
                "class id {} is given twice (also entry {})",
                class.id,
                first + 1
            );
            return Err(at.error(line(k), message));
        }
        if let Some(first) = by_name.insert(class.name.as_str(), k) {
            let message = format!(
                "class name '{}' is given twice (also entry {})",
                class.name,
                first + 1
            );
            return Err(at.error(line(k), message));
        }
    }
    let ignored = ignore_values(raw, &by_id, at)?;
    let n = raw.classes.len();
    let identity = (0..n).all(|i| by_id.contains_key(&(i as u8))) && n <= 256 && ignored.len() <= 1;
    let mut classes: Vec<&RawClass> = raw.classes.iter().collect();
    if identity {
        classes.sort_by_key(|c| c.id);
    }
    let label_values = (!identity).then(|| rtf_core::LabelValues {
        classes: classes.iter().map(|c| c.id).collect(),
        ignored: ignored.clone(),
    });
    let ignore_id = match identity {
        true => ignored.first().copied(),
        false => (!ignored.is_empty()).then_some(u8::MAX),
    };
    Ok(ClassSet {
        name,
        classes: classes
            .iter()
            .enumerate()
            .map(|(k, c)| ClassInfo {
                id: k as u8,
                name: c.name.clone(),
                color: c.color.0,
            })
            .collect(),
        ignore_id,
        label_values,
    })
}

/// The ignore values: distinct, none a class id.
fn ignore_values(
    raw: &RawDescription,
    by_id: &HashMap<u8, usize>,
    at: &Located,
) -> Result<Vec<u8>, DataError> {
    let values = raw
        .ignore_id
        .as_ref()
        .map(OneOrMany::values)
        .unwrap_or_default();
    let line = at.key_line("ignore_id");
    for (k, value) in values.iter().enumerate() {
        if by_id.contains_key(value) {
            return Err(at.error(line, format!("ignore_id {value} is also a class id")));
        }
        if values[..k].contains(value) {
            return Err(at.error(line, format!("ignore_id {value} is given twice")));
        }
    }
    Ok(values)
}

/// Colour-coded labels need distinct colours; an ignore colour needs an ignore id and colour
/// labels.
fn check_label_encoding(raw: &RawDescription, at: &Located) -> Result<(), DataError> {
    let line = at.key_line("ignore_color");
    if raw.ignore_color.is_some() && raw.ignore_id.as_ref().is_none_or(|i| i.values().is_empty()) {
        return Err(at.error(
            line,
            "ignore_color without ignore_id: which id do ignored pixels get?",
        ));
    }
    if raw.ignore_color.is_some() && raw.label_encoding == LabelEncoding::Ids {
        return Err(at.error(line, "ignore_color has no effect with label_encoding: ids"));
    }
    if raw.label_encoding != LabelEncoding::Colors {
        return Ok(());
    }
    let mut seen: HashMap<[u8; 3], &str> = HashMap::new();
    let ignore = raw.ignore_color.map(|c| (c.0, "the ignore colour"));
    for (color, name) in raw
        .classes
        .iter()
        .map(|c| (c.color.0, c.name.as_str()))
        .chain(ignore)
    {
        if let Some(other) = seen.insert(color, name) {
            let message = format!(
                "colour {color:?} is both '{other}' and '{name}': colour-coded labels need distinct colours"
            );
            return Err(at.error(at.line_with(name), message));
        }
    }
    Ok(())
}

/// The thermal rule: at most one of `range`, `min_max` and `percentile`; a temperature map
/// only with a range (it is the range's unit); ranges and percentiles ordered.
fn thermal_rule(raw: &RawThermal, at: &Located) -> Result<ThermalNormalisation, DataError> {
    let given = [raw.range.is_some(), raw.min_max, raw.percentile.is_some()];
    if given.iter().filter(|&&g| g).count() > 1 {
        let line = [
            ("percentile", raw.percentile.is_some()),
            ("min_max", raw.min_max),
        ]
        .iter()
        .find(|(_, g)| *g)
        .and_then(|(key, _)| at.key_line(key));
        let message = "thermal: give one of range, min_max and percentile";
        return Err(at.error(line, message));
    }
    if raw.to_temperature.is_some() && raw.range.is_none() {
        let message =
            "thermal.to_temperature sets the unit of thermal.range, and there is no range";
        return Err(at.error(at.key_line("to_temperature"), message));
    }
    if let Some([lo, hi]) = raw.range {
        if lo.partial_cmp(&hi) != Some(std::cmp::Ordering::Less) {
            let message =
                format!("thermal.range [{lo}, {hi}]: the low end must be below the high end");
            return Err(at.error(at.key_line("range"), message));
        }
        let map = raw.to_temperature;
        return Ok(ThermalNormalisation::Range { lo, hi, map });
    }
    if let Some([lo, hi]) = raw.percentile {
        if !(0.0 <= lo && lo < hi && hi <= 100.0) {
            let message = format!("thermal.percentile [{lo}, {hi}]: need 0 <= low < high <= 100");
            return Err(at.error(at.key_line("percentile"), message));
        }
        return Ok(ThermalNormalisation::Percentile { lo, hi });
    }
    Ok(match raw.min_max {
        true => ThermalNormalisation::MinMax,
        false => ThermalNormalisation::Byte,
    })
}

/// A path written in the description, relative to its folder: never absolute or through `..`
/// (a typo must not silently read another dataset), and it must exist.
fn inside(root: &Path, written: &str, want_dir: bool, at: &Located) -> Result<PathBuf, DataError> {
    let line = at.line_with(written);
    let relative = Path::new(written);
    let escapes = relative.is_absolute()
        || relative
            .components()
            .any(|c| matches!(c, Component::ParentDir | Component::Prefix(_)));
    if escapes {
        let message = format!(
            "'{written}' points outside the dataset folder {}",
            root.display()
        );
        return Err(at.error(line, message));
    }
    let path = root.join(relative);
    let exists = if want_dir {
        path.is_dir()
    } else {
        path.is_file()
    };
    if !exists {
        let what = if want_dir { "folder" } else { "file" };
        let message = format!("'{written}': no such {what} {}", path.display());
        return Err(at.error(line, message));
    }
    Ok(path)
}

/// A split's pattern as written: a folder (`train/rgb`: its `{name}.<ext>` files of the role's
/// formats) or a path template with `{field}`s in its file name and folders
/// (`color/{seq}_eo-{n}.jpg`, `images/{set}/{video}/visible/{frame}.jpg`): the folders before
/// the first field must exist.
fn file_pattern(
    root: &Path,
    written: &str,
    formats: &[Format],
    at: &Located,
) -> Result<FilePattern, DataError> {
    if !written.contains('{') && !written.contains('}') {
        return Ok(FilePattern::folder(
            inside(root, written, true, at)?,
            formats,
        ));
    }
    let components: Vec<&str> = written.split('/').collect();
    let fixed = components
        .iter()
        .position(|c| c.contains('{') || c.contains('}'))
        .unwrap_or(components.len());
    let dir = match fixed {
        0 => root.to_path_buf(),
        _ => inside(root, &components[..fixed].join("/"), true, at)?,
    };
    let template = components[fixed..].join("/");
    let pattern = FilePattern::parse(dir, &template)
        .map_err(|message| at.error(at.line_with(written), message))?;
    let file = components.last().copied().unwrap_or_default();
    let allowed = Format::all_extensions(formats);
    let ext = file.rsplit_once('.').map(|(_, e)| e.to_ascii_lowercase());
    if !ext.as_deref().is_some_and(|e| allowed.contains(&e)) {
        let message = format!(
            "'{written}': the file name must end in one of .{} (the formats this role reads)",
            allowed.join(", .")
        );
        return Err(at.error(at.line_with(written), message));
    }
    Ok(pattern)
}

/// A partner's pattern has exactly the RGB pattern's fields (it is filled from them).
fn same_fields(
    rgb: &FilePattern,
    partner: &FilePattern,
    role: &str,
    written: &str,
    at: &Located,
) -> Result<(), DataError> {
    let (mut a, mut b) = (rgb.fields(), partner.fields());
    a.sort_unstable();
    b.sort_unstable();
    if a == b {
        return Ok(());
    }
    let message = format!(
        "'{written}': the {role} pattern has fields {{{}}} but the RGB pattern has {{{}}}: a partner is found by filling the RGB file's fields, so both need the same",
        b.join("}, {"),
        a.join("}, {")
    );
    Err(at.error(at.line_with(written), message))
}

fn described_split(
    name: &str,
    split: &RawSplit,
    root: &Path,
    at: &Located,
) -> Result<SplitSpec, DataError> {
    let rgb = file_pattern(root, &split.rgb, Format::RGB, at)?;
    let thermal = file_pattern(root, &split.thermal, Format::THERMAL, at)?;
    same_fields(&rgb, &thermal, "thermal", &split.thermal, at)?;
    let labels = match split.labels.as_deref() {
        Some(l) => {
            let labels = file_pattern(root, l, Format::LABEL, at)?;
            same_fields(&rgb, &labels, "labels", l, at)?;
            Some(labels)
        }
        None => None,
    };
    Ok(SplitSpec {
        name: name.to_string(),
        rgb,
        thermal,
        labels,
        lists: list_files(split.list.as_ref(), root, at)?,
    })
}

fn described_splits(
    raw: &BTreeMap<String, RawSplit>,
    root: &Path,
    at: &Located,
) -> Result<Vec<SplitSpec>, DataError> {
    if raw.is_empty() {
        return Err(at.error(at.key_line("splits"), "splits: no split given"));
    }
    raw.iter()
        .map(|(name, split)| described_split(name, split, root, at))
        .collect()
}

/// The plain layout's splits: each of `{train,val,test}` that has an `rgb/` folder, with its
/// `thermal/` (required) and `labels/` (optional: unlabelled frames).
fn plain_splits(root: &Path, at: &Located) -> Result<Vec<SplitSpec>, DataError> {
    let mut splits = Vec::new();
    for name in ["train", "val", "test"] {
        let dir = root.join(name);
        if !dir.join("rgb").is_dir() {
            continue;
        }
        if !dir.join("thermal").is_dir() {
            let message = format!("{}/rgb has no {name}/thermal folder beside it", name);
            return Err(at.error(None, message));
        }
        let labels = dir.join("labels");
        splits.push(SplitSpec {
            name: name.into(),
            rgb: FilePattern::folder(dir.join("rgb"), Format::RGB),
            thermal: FilePattern::folder(dir.join("thermal"), Format::THERMAL),
            labels: labels
                .is_dir()
                .then(|| FilePattern::folder(labels, Format::LABEL)),
            lists: Vec::new(),
        });
    }
    if splits.is_empty() {
        let message = "no splits: give `splits:`, or put the frames in {train,val,test}/{rgb,thermal,labels}/NAME.png beside dataset.yaml";
        return Err(at.error(None, message));
    }
    Ok(splits)
}

fn night_rule(
    raw: &RawNight,
    day: Option<&RawDay>,
    root: &Path,
    at: &Located,
) -> Result<NightRule, DataError> {
    let day = list_files(day.map(|d| &d.list), root, at)?;
    Ok(match (&raw.suffix, &raw.list) {
        (Some(_), _) if !day.is_empty() => {
            let message = "day: lists go with night lists, not with a night suffix";
            return Err(at.error(at.key_line("day"), message));
        }
        (None, None) if day.is_empty() => NightRule::None,
        (Some(_), Some(_)) => {
            let message = "night: give either suffix or list, not both";
            return Err(at.error(at.key_line("night"), message));
        }
        (Some(s), None) if s.is_empty() => {
            return Err(at.error(at.key_line("suffix"), "night suffix is empty"));
        }
        (Some(s), None) => NightRule::Suffix(s.clone()),
        (None, night) => NightRule::Lists {
            day,
            night: list_files(night.as_ref(), root, at)?,
        },
    })
}

/// The list files written (one or several), each inside the dataset and existing.
fn list_files(raw: Option<&Paths>, root: &Path, at: &Located) -> Result<Vec<PathBuf>, DataError> {
    let written = raw.map(Paths::written).unwrap_or_default();
    if raw.is_some() && written.is_empty() {
        return Err(at.error(at.key_line("list"), "list: [] names no list file"));
    }
    written
        .into_iter()
        .map(|w| inside(root, w, false, at))
        .collect()
}

#[cfg(test)]
#[path = "description_tests.rs"]
pub(crate) mod tests;
