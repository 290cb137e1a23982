//! Frames of a dataset read through a [`DatasetDescription`] (the plain layout's dataset.yaml,
//! or a built-in layout: MSRS, PST900, FMB). Every split is a [`FrameSource`].
//!
//! Opening a split pairs its files by name and refuses, naming the file, an RGB without its
//! thermal partner (or the reverse), a label without its RGB, and a list naming missing files;
//! loading a frame refuses partners of different sizes, label ids outside the class list,
//! colours outside the palette and 16-bit thermal without a normalisation.

use crate::thermal::Normalise;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use rtf_core::{ClassSet, Daytime};

use crate::description::{
    DatasetDescription, FilePattern, LabelEncoding, SplitSpec, UnmatchedLines,
};
use crate::frame::check_label_ids;
use crate::images::{read_label, read_rgb, read_thermal, RgbImage};
use crate::pattern::{frame_key, frame_name, value, Fields};
use crate::pngio::{PngImage, Samples};
use crate::split_list::{line_error, read_split_list, PartialIndex};
use crate::{DataError, Frame, FrameSource};

/// A described dataset; [`Self::split`] opens one of its splits.
#[derive(Debug, Clone)]
pub struct DescribedDataset {
    description: Arc<DatasetDescription>,
}

impl DescribedDataset {
    pub fn new(description: DatasetDescription) -> Self {
        Self {
            description: Arc::new(description),
        }
    }

    pub fn description(&self) -> &DatasetDescription {
        &self.description
    }

    pub fn class_set(&self) -> &ClassSet {
        &self.description.class_set
    }

    /// The training split and the validation frames: a named split, or `holdout:N`
    /// ([`parse_holdout`]): every N-th training frame, taken out of training.
    pub fn training_splits(
        &self,
        train: &str,
        val: Option<&str>,
    ) -> Result<(DescribedSplit, Option<DescribedSplit>), DataError> {
        let train = self.split(train)?;
        if let Some(every) = val.and_then(parse_holdout) {
            let (kept, held) = train.hold_out(every);
            return Ok((kept, Some(held)));
        }
        let val = val.map(|name| self.split(name)).transpose()?;
        Ok((train, val))
    }

    /// The frames of split `name`, paired and checked (module docs).
    pub fn split(&self, name: &str) -> Result<DescribedSplit, DataError> {
        let spec = self
            .description
            .split(name)
            .ok_or_else(|| DataError::UnknownSplit {
                root: self.description.root.clone(),
                name: name.to_string(),
                available: self.description.split_names().join(", "),
            })?;
        let mut warnings = Vec::new();
        let unmatched = self.description.unmatched_lines;
        let mut entries = match spec.lists.is_empty() {
            true => paired_entries(spec)?,
            false => listed_entries(spec, unmatched, &mut warnings)?,
        };
        let frames = crate::conditions::SplitFrames {
            split: name,
            names: entries.iter().map(|e| e.name.as_str()).collect(),
            fields: entries.iter().map(|e| &e.fields).collect(),
            rgb: entries.iter().map(|e| e.rgb.as_path()).collect(),
        };
        let (daytimes, more) = crate::conditions::daytimes(&self.description, &frames)?;
        warnings.extend(more);
        for (e, daytime) in entries.iter_mut().zip(daytimes) {
            e.daytime = daytime;
        }
        Ok(DescribedSplit {
            description: self.description.clone(),
            split: name.to_string(),
            entries,
            palette: palette(&self.description),
            warnings,
        })
    }
}

/// Decodes every frame of `split` (in parallel) and returns the first problem in frame order
/// (a label id outside the class list, a colour outside the palette, partners of different
/// sizes, 16-bit thermal without a rule, …) with the number of frames: what `rtf train` runs
/// before it writes a run folder, so that bad data stops it there and not mid-epoch.
pub fn check_frames(split: &dyn FrameSource) -> Result<usize, DataError> {
    use rayon::prelude::*;
    let first = (0..split.len())
        .into_par_iter()
        .filter_map(|i| split.load(i).err().map(|e| (i, e)))
        .min_by_key(|(i, _)| *i);
    match first {
        Some((_, e)) => Err(e),
        None => Ok(split.len()),
    }
}

/// The held-out validation part named as `--val-split holdout:N`: every N-th training frame
/// (N >= 2), taken out of training.
pub fn parse_holdout(val_split: &str) -> Option<usize> {
    val_split
        .strip_prefix("holdout:")
        .and_then(|n| n.parse().ok())
        .filter(|&n: &usize| n >= 2)
}

/// The files of one frame.
#[derive(Debug, Clone)]
struct Entry {
    name: String,
    fields: Fields,
    rgb: PathBuf,
    thermal: PathBuf,
    label: Option<PathBuf>,
    daytime: Option<Daytime>,
}

fn palette(d: &DatasetDescription) -> HashMap<[u8; 3], u8> {
    let mut map: HashMap<[u8; 3], u8> = d
        .class_set
        .classes
        .iter()
        .map(|c| (c.color, c.id))
        .collect();
    if let (Some(color), Some(id)) = (d.ignore_color, d.class_set.ignore_id) {
        map.insert(color, id);
    }
    map
}

/// Frames named by the split's list files (their union, each frame once, in list order):
/// each must have every file of the split. A line naming no frame is an error naming the list
/// and the line (or, with `unmatched_lines: warn`, skipped and counted in a warning).
fn listed_entries(
    spec: &SplitSpec,
    unmatched: UnmatchedLines,
    warnings: &mut Vec<String>,
) -> Result<Vec<Entry>, DataError> {
    let mut scan: Option<(Vec<(Fields, PathBuf)>, PartialIndex)> = None;
    let mut seen = HashSet::new();
    let mut out = Vec::new();
    for list in &spec.lists {
        let mut skipped = 0;
        for (line, fields) in read_split_list(spec, list)? {
            let entry = match listed_entry(spec, &fields, &mut scan)? {
                Ok(entry) => entry,
                Err(_) if unmatched == UnmatchedLines::Warn => {
                    skipped += 1;
                    continue;
                }
                Err(message) => return Err(line_error(list, line, message)),
            };
            let missing = entry
                .files()
                .into_iter()
                .find(|p| !p.is_file())
                .map(Path::to_path_buf);
            if let Some(missing) = missing {
                if unmatched == UnmatchedLines::Warn {
                    skipped += 1;
                    continue;
                }
                return Err(DataError::MissingFrame {
                    split_file: list.to_path_buf(),
                    line,
                    name: entry.name,
                    missing,
                });
            }
            if seen.insert(entry.name.clone()) {
                out.push(entry);
            }
        }
        if skipped > 0 {
            warnings.push(format!(
                "{}: {skipped} line(s) name no frame of split '{}' (skipped: unmatched_lines: warn)",
                list.display(),
                spec.name
            ));
        }
    }
    if out.is_empty() {
        return Err(DataError::EmptySplit {
            path: spec.lists[0].clone(),
        });
    }
    Ok(out)
}

/// The frame of a list line's fields: all of them, or the one frame of the split that agrees
/// with some of them (the split's RGB files scanned once, when a line needs it).
fn listed_entry(
    spec: &SplitSpec,
    fields: &Fields,
    scan: &mut Option<(Vec<(Fields, PathBuf)>, PartialIndex)>,
) -> Result<Result<Entry, String>, DataError> {
    if fields.len() == spec.rgb.fields().len() {
        return Ok(Ok(entry_of(spec, fields)));
    }
    if scan.is_none() {
        *scan = Some((spec.rgb.find()?, PartialIndex::default()));
    }
    let (found, index) = scan.as_mut().expect("scanned above");
    let hits: Vec<&Fields> = (index.lookup(found.iter().map(|(f, _)| f), fields).iter())
        .map(|&i| &found[i].0)
        .collect();
    Ok(match hits.as_slice() {
        [one] => Ok(entry_of(spec, one)),
        [] => Err(format!(
            "'{}' names no frame of split '{}' ({})",
            frame_name(fields),
            spec.name,
            spec.rgb.describe()
        )),
        many => Err(format!(
            "names {} frames of split '{}' ({}): write more of the path",
            many.len(),
            spec.name,
            many.iter()
                .map(|f| frame_name(f))
                .collect::<Vec<_>>()
                .join(", ")
        )),
    })
}

fn entry_of(spec: &SplitSpec, fields: &Fields) -> Entry {
    Entry {
        name: frame_name(fields),
        fields: fields.clone(),
        rgb: spec.rgb.path(fields),
        thermal: spec.thermal.path(fields),
        label: spec.labels.as_ref().map(|l| l.path(fields)),
        daytime: None,
    }
}

impl Entry {
    fn files(&self) -> Vec<&Path> {
        let label = self.label.as_deref();
        [
            Some(self.rgb.as_path()),
            Some(self.thermal.as_path()),
            label,
        ]
        .into_iter()
        .flatten()
        .collect()
    }
}

/// Frames found by walking the folders: every RGB needs its thermal (and label, when the split
/// has labels), and every thermal or label its RGB; no file may match two roles' patterns.
fn paired_entries(spec: &SplitSpec) -> Result<Vec<Entry>, DataError> {
    let rgb_files = spec.rgb.find()?;
    if rgb_files.is_empty() {
        return Err(DataError::EmptySplit {
            path: spec.rgb.dir.clone(),
        });
    }
    let mut roles: HashMap<PathBuf, &'static str> =
        rgb_files.iter().map(|(_, p)| (p.clone(), "RGB")).collect();
    let rgb_keys: HashSet<String> = rgb_files.iter().map(|(f, _)| frame_key(f)).collect();
    let mut thermal = None;
    let mut labels = None;
    let partners = [
        Some((&spec.thermal, "thermal", &mut thermal)),
        spec.labels.as_ref().map(|l| (l, "label", &mut labels)),
    ];
    for (pattern, what, slot) in partners.into_iter().flatten() {
        let found = pattern.find()?;
        for (_, path) in &found {
            if let Some(other) = roles.insert(path.clone(), what) {
                return Err(DataError::Format {
                    path: path.clone(),
                    message: format!("matches both the {other} and the {what} pattern ({}): make the patterns tell the roles apart", pattern.describe()),
                });
            }
        }
        if let Some((fields, path)) = found
            .iter()
            .find(|(f, _)| !rgb_keys.contains(&frame_key(f)))
        {
            return Err(DataError::MissingPartner {
                path: path.clone(),
                what: "RGB",
                partner: spec.rgb.path(&reorder(fields, &spec.rgb)),
            });
        }
        let by_key: HashMap<String, PathBuf> =
            found.into_iter().map(|(f, p)| (frame_key(&f), p)).collect();
        if let Some((fields, path)) = rgb_files
            .iter()
            .find(|(f, _)| !by_key.contains_key(&frame_key(f)))
        {
            return Err(DataError::MissingPartner {
                path: path.clone(),
                what,
                partner: pattern.path(fields),
            });
        }
        *slot = Some(by_key);
    }
    Ok(rgb_files
        .iter()
        .map(|(fields, path)| {
            let key = frame_key(fields);
            let partner =
                |m: &Option<HashMap<String, PathBuf>>| m.as_ref().map(|m| m[&key].clone());
            Entry {
                name: frame_name(fields),
                fields: fields.clone(),
                rgb: path.clone(),
                thermal: partner(&thermal).expect("a split has thermal"),
                label: partner(&labels),
                daytime: None,
            }
        })
        .collect())
}

/// `fields` in `pattern`'s field order.
fn reorder(fields: &Fields, pattern: &FilePattern) -> Fields {
    pattern
        .fields()
        .into_iter()
        .map(|f| (f.to_string(), value(fields, f).to_string()))
        .collect()
}

/// One split of a described dataset.
#[derive(Debug, Clone)]
pub struct DescribedSplit {
    description: Arc<DatasetDescription>,
    split: String,
    entries: Vec<Entry>,
    palette: HashMap<[u8; 3], u8>,
    warnings: Vec<String>,
}

impl DescribedSplit {
    pub fn name(&self) -> &str {
        &self.split
    }

    pub fn description(&self) -> &DatasetDescription {
        &self.description
    }

    /// Splits off every `every`-th frame (indices `every-1`, `2*every-1`, …) as a held-out
    /// validation part: (the frames kept for training, the held-out frames). For datasets that
    /// ship no val split (validation must never be the test split unless asked).
    pub fn hold_out(&self, every: usize) -> (DescribedSplit, DescribedSplit) {
        let held = |i: usize| every > 0 && i % every == every - 1;
        let part = |keep_held: bool, suffix: &str| DescribedSplit {
            description: self.description.clone(),
            split: format!("{}{suffix}", self.split),
            entries: (self.entries.iter().enumerate())
                .filter(|(i, _)| held(*i) == keep_held)
                .map(|(_, e)| e.clone())
                .collect(),
            palette: self.palette.clone(),
            warnings: self.warnings.clone(),
        };
        (
            part(false, ""),
            part(true, &format!(" (held out: 1 in {every})")),
        )
    }

    /// What opening the split skipped (list lines naming no frame, with
    /// `unmatched_lines: warn`): for the commands to print.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// Whether the split's frames have labels.
    pub fn labelled(&self) -> bool {
        self.entries.first().is_some_and(|e| e.label.is_some())
    }

    /// The files frame `index` reads (for fingerprints and checks).
    pub fn files(&self, index: usize) -> Vec<&Path> {
        self.entries[index].files()
    }

    fn read(&self, index: usize, with_label: bool) -> Result<Frame, DataError> {
        let entry = self.entries.get(index).ok_or_else(|| DataError::Frame {
            name: format!("#{index}"),
            message: format!("index out of range (len {})", self.entries.len()),
        })?;
        let RgbImage { width, height, rgb } = read_rgb(&entry.rgb)?;
        let thermal_image = read_thermal(&entry.thermal)?;
        same_size(
            &entry.rgb,
            (width, height),
            &entry.thermal,
            (thermal_image.width, thermal_image.height),
        )?;
        let thermal = self
            .description
            .thermal
            .apply_samples(&thermal_image.samples, &entry.thermal)?;
        let label = match (&entry.label, with_label) {
            (Some(path), true) => Some(self.read_label(path, &entry.rgb, (width, height))?),
            _ => None,
        };
        Ok(Frame {
            name: entry.name.clone(),
            daytime: entry.daytime,
            width,
            height,
            rgb,
            thermal,
            label,
        })
    }

    fn read_label(
        &self,
        path: &Path,
        rgb: &Path,
        size: (usize, usize),
    ) -> Result<Vec<u8>, DataError> {
        let png = read_label(path)?;
        same_size(rgb, size, path, (png.width, png.height))?;
        let Samples::U8(samples) = &png.samples else {
            return Err(DataError::BitDepth {
                path: path.to_path_buf(),
                expected: "8".into(),
                found: png.bit_depth(),
            });
        };
        let classes = &self.description.class_set;
        match self.description.labels {
            LabelEncoding::Ids => {
                crate::pngio::check_channels(&png, path, 1, "label of class ids")?;
                match &classes.label_values {
                    Some(values) => map_label_values(samples, png.width, classes, values, path),
                    None => {
                        check_label_ids(samples, png.width, classes, path)?;
                        Ok(samples.clone())
                    }
                }
            }
            LabelEncoding::Colors => colour_label(&png, samples, &self.palette, classes, path),
        }
    }
}

fn same_size(
    path: &Path,
    (w, h): (usize, usize),
    partner: &Path,
    (partner_w, partner_h): (usize, usize),
) -> Result<(), DataError> {
    if (partner_w, partner_h) == (w, h) {
        return Ok(());
    }
    Err(DataError::PartnerSize {
        path: path.to_path_buf(),
        partner: partner.to_path_buf(),
        w,
        h,
        partner_w,
        partner_h,
    })
}

/// A label of the dataset's own values mapped to output indices (ignored values to the ignore
/// id); a value that is neither a class nor ignored is an error naming the file, the value and
/// the pixel.
fn map_label_values(
    samples: &[u8],
    width: usize,
    classes: &ClassSet,
    values: &rtf_core::LabelValues,
    path: &Path,
) -> Result<Vec<u8>, DataError> {
    let table = values.lookup(classes.ignore_id);
    let mut out = Vec::with_capacity(samples.len());
    for (i, &v) in samples.iter().enumerate() {
        let Some(mapped) = table[v as usize] else {
            let list = |v: &[u8]| v.iter().map(u8::to_string).collect::<Vec<_>>().join(", ");
            return Err(DataError::LabelOutOfRange {
                path: path.to_path_buf(),
                id: v as u16,
                x: i % width.max(1),
                y: i / width.max(1),
                class_set: classes.name.clone(),
                classes: classes.len(),
                ignore: format!(
                    " with label values {}; ignored: {}",
                    list(&values.classes),
                    if values.ignored.is_empty() {
                        "none".into()
                    } else {
                        list(&values.ignored)
                    }
                ),
            });
        };
        out.push(mapped);
    }
    Ok(out)
}

fn colour_label(
    png: &PngImage,
    samples: &[u8],
    palette: &HashMap<[u8; 3], u8>,
    classes: &ClassSet,
    path: &Path,
) -> Result<Vec<u8>, DataError> {
    let c = png.channels;
    if !(c == 3 || c == 4) || png.indexed {
        return Err(DataError::Channels {
            path: path.to_path_buf(),
            what: "colour-coded label",
            expected: "3 or 4".into(),
            found: c,
        });
    }
    samples
        .chunks_exact(c)
        .enumerate()
        .map(|(i, p)| {
            let color = [p[0], p[1], p[2]];
            palette
                .get(&color)
                .copied()
                .ok_or_else(|| DataError::LabelColor {
                    path: path.to_path_buf(),
                    color,
                    x: i % png.width.max(1),
                    y: i / png.width.max(1),
                    class_set: classes.name.clone(),
                })
        })
        .collect()
}

impl FrameSource for DescribedSplit {
    fn len(&self) -> usize {
        self.entries.len()
    }
    fn frame_name(&self, index: usize) -> &str {
        &self.entries[index].name
    }
    fn daytime(&self, index: usize) -> Option<Daytime> {
        self.entries[index].daytime
    }
    fn class_set(&self) -> &ClassSet {
        &self.description.class_set
    }
    fn load(&self, index: usize) -> Result<Frame, DataError> {
        self.read(index, true)
    }
    fn load_unlabelled(&self, index: usize) -> Result<Frame, DataError> {
        self.read(index, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::description::tests::{plain_root, EXAMPLE};
    use crate::description::{read_description, DESCRIPTION_FILE};
    use crate::testutil::*;

    fn open(root: &Path, split: &str) -> Result<DescribedSplit, DataError> {
        let d = read_description(&root.join(DESCRIPTION_FILE))?;
        DescribedDataset::new(d).split(split)
    }

    /// The error's text, which must name `path`.
    fn names(err: DataError, path: &Path) -> String {
        let text = err.to_string();
        assert!(text.contains(&path.display().to_string()), "{text}");
        text
    }

    #[test]
    fn sixteen_bit_thermal_is_read_through_the_range() {
        let dir = plain_root(EXAMPLE);
        let train = open(dir.path(), "train").unwrap();
        assert_eq!(train.len(), 2);
        assert_eq!(train.class_set().len(), 2);
        let f = train.load(0).unwrap();
        // Counts 21800 + i over [21800, 25000].
        assert_eq!(f.thermal[0], 0.0);
        assert!(
            (f.thermal[11] - 11.0 / 3200.0).abs() < 1e-6,
            "{}",
            f.thermal[11]
        );
        assert_eq!(f.label.unwrap(), ids(4, 3, 2));
    }

    #[test]
    fn sixteen_bit_thermal_without_a_normalisation_names_the_file() {
        let no_rule = EXAMPLE.replace("thermal:\n  range: [21800, 25000]", "");
        let dir = plain_root(&no_rule);
        let err = open(dir.path(), "train").unwrap().load(0).unwrap_err();
        assert!(matches!(
            err,
            DataError::ThermalNormalisation { bits: 16, .. }
        ));
        names(err, &dir.path().join("train/thermal/a.png"));
    }

    #[test]
    fn a_frame_without_its_partner_names_both_files() {
        let dir = plain_root(EXAMPLE);
        std::fs::remove_file(dir.path().join("train/thermal/b.png")).unwrap();
        let text = names(
            open(dir.path(), "train").unwrap_err(),
            &dir.path().join("train/rgb/b.png"),
        );
        assert!(
            text.contains("no thermal partner") && text.contains("thermal/b.png"),
            "{text}"
        );
        std::fs::remove_file(dir.path().join("val/rgb/a.png")).unwrap();
        let err = open(dir.path(), "val").unwrap_err();
        let text = names(err, &dir.path().join("val/thermal/a.png"));
        assert!(text.contains("no RGB partner"), "{text}");
    }

    #[test]
    fn partners_of_different_sizes_are_refused() {
        let dir = plain_root(EXAMPLE);
        let thermal = dir.path().join("train/thermal/a.png");
        write(&thermal, &png_u16(5, 3, 1, &[22000; 15]));
        let err = open(dir.path(), "train").unwrap().load(0).unwrap_err();
        let text = names(err, &thermal);
        assert!(text.contains("5x3") && text.contains("4x3"), "{text}");
    }

    #[test]
    fn a_colour_outside_the_palette_names_the_file_and_colour() {
        let yaml = format!("{EXAMPLE}label_encoding: colors\n");
        let dir = plain_root(&yaml);
        let label = dir.path().join("train/labels/a.png");
        let mut pixels: Vec<u8> = [[0u8, 0, 0], [220, 20, 60]].repeat(6).concat();
        write(&label, &png_u8(4, 3, 3, &pixels));
        let f = open(dir.path(), "train").unwrap().load(0).unwrap();
        assert_eq!(f.label.unwrap(), [0, 1].repeat(6));
        pixels[9..12].copy_from_slice(&[1, 2, 3]);
        write(&label, &png_u8(4, 3, 3, &pixels));
        let err = open(dir.path(), "train").unwrap().load(0).unwrap_err();
        let text = names(err, &label);
        assert!(
            text.contains("[1, 2, 3]") && text.contains("x 3, y 0"),
            "{text}"
        );
    }

    #[test]
    fn a_split_list_naming_a_missing_frame_names_the_list_and_line() {
        let dir = plain_root(EXAMPLE);
        let list = dir.path().join("train.txt");
        write(&list, b"a\nc\n");
        let yaml = format!("{EXAMPLE}splits:\n  train: {{rgb: train/rgb, thermal: train/thermal, labels: train/labels, list: train.txt}}\n");
        write(&dir.path().join(DESCRIPTION_FILE), yaml.as_bytes());
        let err = open(dir.path(), "train").unwrap_err();
        let text = names(err, &list);
        assert!(
            text.contains("line 2") && text.contains("rgb/c.png"),
            "{text}"
        );
    }

    #[test]
    fn hold_out_takes_every_nth_frame_out_of_training() {
        let dir = plain_root(EXAMPLE);
        let train = open(dir.path(), "train").unwrap();
        let (kept, held) = train.hold_out(2);
        assert_eq!((kept.len(), held.len()), (1, 1));
        assert_eq!((kept.frame_name(0), held.frame_name(0)), ("a", "b"));
        assert_eq!(parse_holdout("holdout:10"), Some(10));
        assert_eq!(parse_holdout("holdout:1"), None);
        assert_eq!(parse_holdout("val"), None);
    }

    #[test]
    fn night_frames_follow_the_suffix() {
        let yaml = format!("{EXAMPLE}night: {{suffix: b}}\n");
        let dir = plain_root(&yaml);
        let train = open(dir.path(), "train").unwrap();
        assert_eq!(train.daytime(0), Some(Daytime::Day));
        assert_eq!(train.daytime(1), Some(Daytime::Night));
    }
}
