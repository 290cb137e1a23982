//! Freiburg Thermal (HeatNet; spec §5).
//!
//! Training tree: `<root>/<run>/<seq>/fl_rgb/*.png` (8-bit RGB), `fl_ir_aligned/*.png` (16-bit
//! IR, aligned to RGB), `fl_rgb_labels/*.png` (8-bit ids, day only); any path containing
//! `night` is a night frame. Test layout: `<dir>/ImagesRGB/*_rgb.png`, `ImagesIR/*_ir.png`,
//! `SegmentationClass/*.npy`, one `<dir>` per day/night. Both can sit under one root.
//! 13 classes, id 13 = ignore.

use crate::augment::{resample, resample_nearest, Filter, Planar, Window};
use crate::frame::check_label_ids;
use crate::npy::decode_label_npy;
use crate::pngio::{decode_png, Samples};
use crate::{DataError, Frame, FrameSource};
use rtf_core::{ClassSet, Daytime};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The reference preprocessing: the schema's (rtf-config).
pub use rtf_config::data::FreiburgPreprocess;

#[derive(Debug, Clone)]
enum LabelFile {
    Png(PathBuf),
    Npy(PathBuf),
}

#[derive(Debug, Clone)]
struct Entry {
    name: String,
    rgb: PathBuf,
    ir: PathBuf,
    label: Option<LabelFile>,
    daytime: Daytime,
    part: FreiburgPart,
}

impl Entry {
    /// An entry whose day or night is read from the RGB path.
    fn new(
        name: String,
        rgb: PathBuf,
        ir: PathBuf,
        label: Option<LabelFile>,
        part: FreiburgPart,
    ) -> Self {
        Entry {
            name,
            daytime: daytime_of(&rgb),
            rgb,
            ir,
            label,
            part,
        }
    }
}

/// Which of the two Freiburg layouts a frame comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FreiburgPart {
    /// `<run>/<seq>/fl_rgb/…`: the training tree (day frames labelled, night ones not).
    TrainTree,
    /// `ImagesRGB/…_rgb.png`: the labelled test layout.
    TestLayout,
    /// The test layout's format under `<root>/val/`: labelled day and night frames held out for
    /// validation (checkpoint selection never looks at the test layout).
    Validation,
}

/// Frames of a Freiburg Thermal root (training tree and/or test layout).
#[derive(Debug, Clone)]
pub struct FreiburgSplit {
    root: PathBuf,
    entries: Vec<Entry>,
    preprocess: FreiburgPreprocess,
    class_set: ClassSet,
}

fn daytime_of(path: &Path) -> Daytime {
    if path.to_string_lossy().to_lowercase().contains("night") {
        Daytime::Night
    } else {
        Daytime::Day
    }
}

fn list_pngs(dir: &Path, ext: &str) -> Result<Vec<PathBuf>, DataError> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).map_err(|e| DataError::io(dir, e))? {
        let p = e.map_err(|e| DataError::io(dir, e))?.path();
        if p.is_file() && p.extension().is_some_and(|x| x.eq_ignore_ascii_case(ext)) {
            out.push(p);
        }
    }
    out.sort();
    Ok(out)
}

/// Every PNG in each directory named `dir_name` under `root` (up to `depth` levels), made an
/// entry by `entry` (given the directory's parent, the PNG and its file name); what `entry`
/// refuses becomes a problem, not an error.
fn scan_frames(
    root: &Path,
    (dir_name, depth): (&str, usize),
    entries: &mut Vec<Entry>,
    problems: &mut Vec<DataError>,
    entry: impl Fn(&Path, PathBuf, &str) -> Result<Entry, DataError>,
) -> Result<(), DataError> {
    let mut dirs = Vec::new();
    find_dirs(root, dir_name, depth, &mut dirs)?;
    for rgb_dir in dirs {
        let parent = rgb_dir.parent().unwrap_or(root).to_path_buf();
        for rgb in list_pngs(&rgb_dir, "png")? {
            let fname = file_name(&rgb);
            match entry(&parent, rgb, &fname) {
                Ok(e) => entries.push(e),
                Err(problem) => problems.push(problem),
            }
        }
    }
    Ok(())
}

/// The first of `candidates` that is a file.
fn first_file(candidates: impl IntoIterator<Item = PathBuf>) -> Option<PathBuf> {
    candidates.into_iter().find(|p| p.is_file())
}

/// A training-tree frame `<seq>/fl_rgb/fl_rgb_<stamp>.png`, with `fl_ir_aligned` and optional
/// `fl_rgb_labels` beside it; without an aligned IR image it is a problem.
fn train_tree_entry(
    root: &Path,
    seq: &Path,
    rgb: PathBuf,
    fname: &str,
) -> Result<Entry, DataError> {
    let stamp = fname.strip_prefix("fl_rgb_").unwrap_or(fname);
    let ir_dir = seq.join("fl_ir_aligned");
    let ir_candidates = [
        ir_dir.join(format!("fl_ir_aligned_{stamp}")),
        ir_dir.join(fname),
    ];
    let Some(ir) = first_file(ir_candidates.clone()) else {
        return Err(DataError::Format {
            path: rgb,
            message: format!(
                "no aligned IR image (looked for {})",
                ir_candidates[0].display()
            ),
        });
    };
    let labels = seq.join("fl_rgb_labels");
    let label = first_file([
        labels.join(fname),
        labels.join(format!("fl_rgb_labels_{stamp}")),
    ])
    .map(LabelFile::Png);
    let name = rgb
        .strip_prefix(root)
        .unwrap_or(&rgb)
        .with_extension("")
        .to_string_lossy()
        .into_owned();
    Ok(Entry::new(name, rgb, ir, label, FreiburgPart::TrainTree))
}

/// A test-layout frame `<dir>/ImagesRGB/<stem>_rgb.png`, with `ImagesIR` and optional
/// `SegmentationClass/*.npy`; under `val/` it belongs to the validation part; without its IR
/// image it is a problem.
fn test_layout_entry(
    root: &Path,
    dir: &Path,
    rgb: PathBuf,
    fname: &str,
) -> Result<Entry, DataError> {
    let stem = fname
        .strip_suffix("_rgb.png")
        .unwrap_or(fname.trim_end_matches(".png"));
    let ir = dir.join("ImagesIR").join(format!("{stem}_ir.png"));
    if !ir.is_file() {
        return Err(DataError::Format {
            path: rgb,
            message: format!("no IR image {}", ir.display()),
        });
    }
    let labels = dir.join("SegmentationClass");
    let label = first_file([
        labels.join(format!("{stem}.npy")),
        labels.join(format!("{stem}_rgb.npy")),
    ])
    .map(LabelFile::Npy);
    let rel = dir.strip_prefix(root).unwrap_or(dir);
    let name = rel.join(stem).to_string_lossy().into_owned();
    let in_val = rel
        .components()
        .next()
        .is_some_and(|c| c.as_os_str() == "val");
    let part = if in_val {
        FreiburgPart::Validation
    } else {
        FreiburgPart::TestLayout
    };
    Ok(Entry::new(name, rgb, ir, label, part))
}

/// Directories under `root` (inclusive, up to `depth` levels) named `name`.
fn find_dirs(
    root: &Path,
    name: &str,
    depth: usize,
    out: &mut Vec<PathBuf>,
) -> Result<(), DataError> {
    let entries = std::fs::read_dir(root).map_err(|e| DataError::io(root, e))?;
    let mut dirs: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    for d in dirs {
        if d.file_name().is_some_and(|n| n == name) {
            out.push(d);
        } else if depth > 0 {
            find_dirs(&d, name, depth - 1, out)?;
        }
    }
    Ok(())
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

impl FreiburgSplit {
    /// Finds every frame under `root`. Every RGB image needs its IR partner; labels are
    /// optional (night training frames have none).
    pub fn open(root: impl AsRef<Path>, preprocess: FreiburgPreprocess) -> Result<Self, DataError> {
        let (split, mut problems) = Self::scan(root, preprocess)?;
        match problems.is_empty() {
            true => Ok(split),
            false => Err(problems.remove(0)),
        }
    }

    /// Like `open`, but frames whose partner file is missing are returned as problems
    /// (for `rtf data check`, which reports every problem) instead of failing the whole root.
    pub fn scan(
        root: impl AsRef<Path>,
        preprocess: FreiburgPreprocess,
    ) -> Result<(Self, Vec<DataError>), DataError> {
        let root = root.as_ref().to_path_buf();
        let mut problems = Vec::new();
        if !root.is_dir() {
            return Err(DataError::Layout {
                root,
                message: "not a directory".into(),
            });
        }
        let mut entries = Vec::new();
        let (e, p) = (&mut entries, &mut problems);
        scan_frames(&root, ("fl_rgb", 6), e, p, |seq, rgb, fname| {
            train_tree_entry(&root, seq, rgb, fname)
        })?;
        scan_frames(&root, ("ImagesRGB", 4), e, p, |dir, rgb, fname| {
            test_layout_entry(&root, dir, rgb, fname)
        })?;
        if entries.is_empty() && problems.is_empty() {
            return Err(DataError::Layout {
                root,
                message:
                    "no Freiburg Thermal frames (expected */fl_rgb/*.png or */ImagesRGB/*_rgb.png)"
                        .into(),
            });
        }
        let split = Self {
            root,
            entries,
            preprocess,
            class_set: ClassSet::freiburg(),
        };
        Ok((split, problems))
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Keeps only the frames of one layout (e.g. the training tree for training, the test
    /// layout for evaluation).
    pub fn part(mut self, part: FreiburgPart) -> Self {
        self.entries.retain(|e| e.part == part);
        self
    }

    /// Keeps only frames matching `keep` (e.g. labelled day frames, or night).
    pub fn filter(mut self, keep: impl Fn(&str, Daytime, bool) -> bool) -> Self {
        self.entries
            .retain(|e| keep(&e.name, e.daytime, e.label.is_some()));
        self
    }

    pub fn is_labelled(&self, index: usize) -> bool {
        self.entries[index].label.is_some()
    }

    /// The files of frame `index` (rgb, ir, label).
    pub fn files(&self, index: usize) -> (PathBuf, PathBuf, Option<PathBuf>) {
        let e = &self.entries[index];
        let label = e.label.as_ref().map(|l| match l {
            LabelFile::Png(p) | LabelFile::Npy(p) => p.clone(),
        });
        (e.rgb.clone(), e.ir.clone(), label)
    }

    /// Decodes a frame without preprocessing: RGB bytes, raw IR counts, label ids.
    pub fn load_raw(&self, index: usize) -> Result<RawFreiburgFrame, DataError> {
        self.read_raw(index, true)
    }

    /// [`Self::load_raw`]; without `labels` the label file is not opened.
    fn read_raw(&self, index: usize, labels: bool) -> Result<RawFreiburgFrame, DataError> {
        let e = self.entries.get(index).ok_or_else(|| DataError::Frame {
            name: format!("#{index}"),
            message: "index out of range".into(),
        })?;
        let rgb_bytes = std::fs::read(&e.rgb).map_err(|err| DataError::io(&e.rgb, err))?;
        let ir_bytes = std::fs::read(&e.ir).map_err(|err| DataError::io(&e.ir, err))?;
        let label = match e.label.as_ref().filter(|_| labels) {
            None => None,
            Some(LabelFile::Png(p)) => Some((
                std::fs::read(p).map_err(|err| DataError::io(p, err))?,
                p.clone(),
                false,
            )),
            Some(LabelFile::Npy(p)) => Some((
                std::fs::read(p).map_err(|err| DataError::io(p, err))?,
                p.clone(),
                true,
            )),
        };
        decode_raw(
            &e.name,
            e.daytime,
            &rgb_bytes,
            &e.rgb,
            &ir_bytes,
            &e.ir,
            label
                .as_ref()
                .map(|(b, p, npy)| (b.as_slice(), p.as_path(), *npy)),
            &self.class_set,
        )
    }
}

/// How a Freiburg root is read by name: training (its training tree and validation part)
/// and evaluation (`test` or `train`).
impl FreiburgSplit {
    /// The training tree (its labelled frames when `labels`) and, when `validate`, the
    /// labelled frames of the validation part; each with its own preprocessing.
    pub fn training_parts(
        root: &Path,
        (train, val): (&FreiburgPreprocess, &FreiburgPreprocess),
        validate: bool,
        labels: bool,
    ) -> Result<(Self, Option<Self>), DataError> {
        let tree = Self::open(root, train.clone())?.part(FreiburgPart::TrainTree);
        let tree = match labels {
            true => tree.filter(|_, _, labelled| labelled),
            false => tree,
        };
        if tree.is_empty() {
            return Err(DataError::Layout {
                root: root.to_path_buf(),
                message: match labels {
                    true => "no labelled frames in a Freiburg training tree (<run>/<seq>/fl_rgb + fl_rgb_labels)",
                    false => "no frames in a Freiburg training tree (<run>/<seq>/fl_rgb)",
                }
                .into(),
            });
        }
        let val = match validate {
            true => Some(
                Self::open(root, val.clone())?
                    .part(FreiburgPart::Validation)
                    .filter(|_, _, labelled| labelled),
            ),
            false => None,
        };
        Ok((tree, val.filter(|v| !v.is_empty())))
    }

    /// The frames of the part named `name` (`test`: the test layout, `train`: the training
    /// tree), only its labelled ones when `labels` (then at least one).
    pub fn named_part(
        root: &Path,
        name: &str,
        preprocess: FreiburgPreprocess,
        labels: bool,
    ) -> Result<Self, DataError> {
        let layout = |message: String| DataError::Layout {
            root: root.to_path_buf(),
            message,
        };
        let part = match name {
            "test" => FreiburgPart::TestLayout,
            "train" => FreiburgPart::TrainTree,
            other => {
                return Err(layout(format!(
                    "a Freiburg Thermal root has the splits `test` and `train`, not `{other}`"
                )))
            }
        };
        let frames = Self::open(root, preprocess)?.part(part);
        if !labels {
            return Ok(frames);
        }
        let frames = frames.filter(|_, _, labelled| labelled);
        match frames.is_empty() {
            true => Err(layout(format!("no labelled frames in its `{name}` part"))),
            false => Ok(frames),
        }
    }
}

/// A Freiburg frame as stored.
#[derive(Debug, Clone)]
pub struct RawFreiburgFrame {
    pub name: String,
    pub daytime: Daytime,
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
    pub ir: Vec<u16>,
    pub label: Option<Vec<u8>>,
}

/// Decodes RGB (8-bit, 3 channels), IR (16-bit, 1 channel) and an optional label (8-bit PNG or
/// `.npy`); the fuzzed entry point of this format.
#[allow(clippy::too_many_arguments)]
pub fn decode_raw(
    name: &str,
    daytime: Daytime,
    rgb_bytes: &[u8],
    rgb_path: &Path,
    ir_bytes: &[u8],
    ir_path: &Path,
    label: Option<(&[u8], &Path, bool)>,
    classes: &ClassSet,
) -> Result<RawFreiburgFrame, DataError> {
    let rgb = crate::pngio::decode_u8(rgb_bytes, rgb_path, 3, "RGB image")?;
    let ir = decode_png(ir_bytes, ir_path)?;
    crate::pngio::check_channels(&ir, ir_path, 1, "IR image")?;
    let Samples::U16(ir_counts) = ir.samples else {
        return Err(DataError::BitDepth {
            path: ir_path.to_path_buf(),
            expected: "16".into(),
            found: ir.bit_depth(),
        });
    };
    if (ir.width, ir.height) != (rgb.width, rgb.height) {
        return Err(DataError::SizeMismatch {
            image: rgb_path.to_path_buf(),
            label: ir_path.to_path_buf(),
            image_w: rgb.width,
            image_h: rgb.height,
            label_w: ir.width,
            label_h: ir.height,
        });
    }
    let label = match label {
        None => None,
        Some((bytes, path, npy)) => {
            let (w, h, ids) = if npy {
                let (w, h, ids) = decode_label_npy(bytes, path)?;
                let pos = ids.iter().position(|&v| v > u8::MAX as u16);
                if let Some(pos) = pos {
                    return Err(DataError::LabelOutOfRange {
                        path: path.to_path_buf(),
                        id: ids[pos],
                        x: pos % w,
                        y: pos / w,
                        class_set: classes.name.clone(),
                        classes: classes.len(),
                        ignore: classes
                            .ignore_id
                            .map(|i| format!(", ignore id {i}"))
                            .unwrap_or_default(),
                    });
                }
                (w, h, ids.into_iter().map(|v| v as u8).collect::<Vec<u8>>())
            } else {
                let img = crate::pngio::decode_u8(bytes, path, 1, "label of class ids")?;
                let Samples::U8(ids) = img.samples else {
                    unreachable!("8-bit checked")
                };
                (img.width, img.height, ids)
            };
            if (w, h) != (rgb.width, rgb.height) {
                return Err(DataError::SizeMismatch {
                    image: rgb_path.to_path_buf(),
                    label: path.to_path_buf(),
                    image_w: rgb.width,
                    image_h: rgb.height,
                    label_w: w,
                    label_h: h,
                });
            }
            check_label_ids(&ids, w, classes, path)?;
            Some(ids)
        }
    };
    let Samples::U8(rgb_bytes) = rgb.samples else {
        unreachable!("8-bit checked")
    };
    Ok(RawFreiburgFrame {
        name: name.to_string(),
        daytime,
        width: rgb.width,
        height: rgb.height,
        rgb: rgb_bytes,
        ir: ir_counts,
        label,
    })
}

/// Applies the preprocessing: IR clip/scale, resize, column crop.
pub fn preprocess(raw: RawFreiburgFrame, pre: &FreiburgPreprocess) -> Result<Frame, DataError> {
    let (lo, hi) = pre.ir_clip;
    if hi <= lo {
        return Err(DataError::Config(format!("IR clip [{lo}, {hi}] is empty")));
    }
    let span = (hi - lo) as f32;
    let thermal: Vec<f32> = raw
        .ir
        .iter()
        .map(|&v| (v.clamp(lo, hi) - lo) as f32 / span)
        .collect();
    let (mut w, mut h) = (raw.width, raw.height);
    let mut rgb = raw.rgb;
    let mut thermal = thermal;
    let mut label = raw.label;
    if let Some((rw, rh)) = pre.resize.filter(|&s| s != (w, h)) {
        let n = w * h;
        let mut data = vec![0.0f32; 4 * n];
        for (i, px) in rgb.chunks_exact(3).enumerate() {
            for c in 0..3 {
                data[c * n + i] = px[c] as f32;
            }
        }
        data[3 * n..].copy_from_slice(&thermal);
        let out = resample(
            &Planar {
                channels: 4,
                width: w,
                height: h,
                data,
            },
            Window::full(w, h),
            rw,
            rh,
            Filter::Bilinear,
        );
        let m = rw * rh;
        rgb = (0..m)
            .flat_map(|i| (0..3).map(move |c| (i, c)))
            .map(|(i, c)| out.data[c * m + i].round().clamp(0.0, 255.0) as u8)
            .collect();
        thermal = out.data[3 * m..].to_vec();
        label = label.map(|l| resample_nearest(&l, w, h, Window::full(w, h), rw, rh));
        (w, h) = (rw, rh);
    }
    if let Some((c0, c1)) = pre.columns {
        if c0 >= c1 || c1 > w {
            return Err(DataError::Frame {
                name: raw.name,
                message: format!("column crop {c0}..{c1} does not fit width {w}"),
            });
        }
        let cw = c1 - c0;
        rgb = (0..h)
            .flat_map(|y| rgb[3 * (y * w + c0)..3 * (y * w + c1)].to_vec())
            .collect();
        thermal = (0..h)
            .flat_map(|y| thermal[y * w + c0..y * w + c1].to_vec())
            .collect();
        label = label.map(|l| {
            (0..h)
                .flat_map(|y| l[y * w + c0..y * w + c1].to_vec())
                .collect()
        });
        w = cw;
    }
    Ok(Frame {
        name: raw.name,
        daytime: Some(raw.daytime),
        width: w,
        height: h,
        rgb,
        thermal,
        label,
    })
}

impl FrameSource for FreiburgSplit {
    fn len(&self) -> usize {
        self.entries.len()
    }
    fn frame_name(&self, index: usize) -> &str {
        &self.entries[index].name
    }
    fn daytime(&self, index: usize) -> Option<Daytime> {
        Some(self.entries[index].daytime)
    }
    fn class_set(&self) -> &ClassSet {
        &self.class_set
    }
    fn load(&self, index: usize) -> Result<Frame, DataError> {
        preprocess(self.load_raw(index)?, &self.preprocess)
    }
    fn load_unlabelled(&self, index: usize) -> Result<Frame, DataError> {
        preprocess(self.read_raw(index, false)?, &self.preprocess)
    }
}

/// Freiburg id → MF id (spec §5): curb → curve, person, car, bicycle → bike, all else (and
/// ignore) → unlabeled.
pub fn freiburg_to_mf(id: u8) -> u8 {
    match id {
        3 => 4,
        9 => 2,
        10 => 1,
        11 => 3,
        _ => 0,
    }
}

/// MF id → Freiburg id: the shared classes map back; MF unlabeled is unknown in Freiburg
/// terms (→ ignore 13); car stops and cones → background; guardrail → fence; bump → road.
pub fn mf_to_freiburg(id: u8) -> u8 {
    match id {
        1 => 10,
        2 => 9,
        3 => 11,
        4 => 3,
        5 | 7 => 12,
        6 => 4,
        8 => 0,
        _ => 13,
    }
}

/// A frame source whose labels are mapped into another class set (e.g. Freiburg frames
/// evaluated with MF classes).
pub struct ClassMapped<S> {
    pub inner: S,
    pub map: fn(u8) -> u8,
    pub class_set: ClassSet,
}

impl<S: FrameSource> FrameSource for ClassMapped<S> {
    fn len(&self) -> usize {
        self.inner.len()
    }
    fn frame_name(&self, index: usize) -> &str {
        self.inner.frame_name(index)
    }
    fn daytime(&self, index: usize) -> Option<Daytime> {
        self.inner.daytime(index)
    }
    fn class_set(&self) -> &ClassSet {
        &self.class_set
    }
    fn load(&self, index: usize) -> Result<Frame, DataError> {
        let mut f = self.inner.load(index)?;
        if let Some(l) = f.label.as_mut() {
            l.iter_mut().for_each(|v| *v = (self.map)(*v));
        }
        Ok(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{generate, SynthConfig, SynthFormat};
    use crate::testutil::*;

    #[test]
    fn synthetic_freiburg_layout_reads_back_with_reference_preprocessing() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = SynthConfig {
            count: 8,
            seed: 2,
            width: 96,
            height: 64,
            format: SynthFormat::Freiburg,
            misalignment: None,
        };
        generate(dir.path(), &cfg).unwrap();
        let all = FreiburgSplit::open(dir.path(), FreiburgPreprocess::native()).unwrap();
        assert_eq!(all.len(), 8);
        let night_train_labelled = (0..all.len())
            .filter(|&i| {
                all.frame_name(i).starts_with("train")
                    && all.daytime(i) == Some(Daytime::Night)
                    && all.is_labelled(i)
            })
            .count();
        assert_eq!(
            night_train_labelled, 0,
            "night training frames are unlabelled, as in the real data"
        );
        let tree = all.clone().part(FreiburgPart::TrainTree);
        let test_layout = all.clone().part(FreiburgPart::TestLayout);
        let val = all.clone().part(FreiburgPart::Validation);
        // Validation frames (day and night, labelled) sit in `val/`, apart from test.
        assert_eq!((tree.len(), val.len(), test_layout.len()), (4, 2, 2));
        assert!((0..val.len()).all(|i| val.is_labelled(i)));
        assert!((0..tree.len()).all(|i| tree.frame_name(i).starts_with("train")));
        assert!((0..test_layout.len()).all(|i| test_layout.is_labelled(i)));
        let test = FreiburgSplit::open(
            dir.path().join("test"),
            FreiburgPreprocess {
                resize: Some((120, 40)),
                columns: Some((10, 110)),
                ..FreiburgPreprocess::native()
            },
        )
        .unwrap();
        assert_eq!(test.len(), 2);
        let f = test.load(0).unwrap();
        assert_eq!((f.width, f.height), (100, 40));
        assert!(f.label.as_ref().unwrap().iter().all(|&id| id < 13));
        assert!(f.thermal.iter().all(|t| (0.0..=1.0).contains(t)));
        // Sky is colder than −10 °C apparent: clipped to 0 by the reference clip.
        assert!(f.thermal.contains(&0.0));
        let mut days: Vec<_> = (0..test.len()).map(|i| test.daytime(i).unwrap()).collect();
        days.sort_by_key(|d| *d == Daytime::Night);
        assert_eq!(days, [Daytime::Day, Daytime::Night]);
    }

    #[test]
    fn loader_batches_freiburg_with_window_and_ignore_for_unlabelled_nights() {
        use crate::{AugmentConfig, Loader, LoaderConfig};
        let dir = tempfile::tempdir().unwrap();
        let cfg = SynthConfig {
            count: 8,
            seed: 5,
            width: 96,
            height: 64,
            format: SynthFormat::Freiburg,
            misalignment: None,
        };
        generate(dir.path(), &cfg).unwrap();
        let pre = FreiburgPreprocess {
            resize: Some((120, 40)),
            columns: Some((10, 110)),
            ..FreiburgPreprocess::native()
        };
        let train = FreiburgSplit::open(dir.path().join("train"), pre).unwrap();
        let source: std::sync::Arc<dyn FrameSource> = std::sync::Arc::new(train);
        let loader_cfg = LoaderConfig {
            batch_size: 6,
            shuffle: false,
            augment: AugmentConfig {
                hflip: true,
                window: Some((64, 32)),
                ..Default::default()
            },
            ..LoaderConfig::default()
        };
        let loader = Loader::new(
            source.clone(),
            loader_cfg,
            rtf_core::InputConvention::MeanStd {
                mean: 0.5,
                std: 0.5,
            },
        );
        let batch = loader.epoch(0).next().unwrap().unwrap();
        // The 4 frames of the training tree (val and test frames live in their own layouts).
        assert_eq!(batch.input.size(), [4, 4, 32, 64]);
        let (lo, hi) = (
            batch.input.min().double_value(&[]),
            batch.input.max().double_value(&[]),
        );
        assert!(
            lo >= -1.0 && hi <= 1.0 && lo < 0.0,
            "[-1, 1] input, got {lo}..{hi}"
        );
        for (i, daytime) in batch.daytimes.iter().enumerate() {
            let target = Vec::<i64>::try_from(batch.target.get(i as i64).flatten(0, -1)).unwrap();
            if *daytime == Some(Daytime::Night) {
                assert!(
                    target.iter().all(|&t| t == 13),
                    "unlabelled night frame -> ignore"
                );
            } else {
                assert!(target.iter().all(|&t| t < 13), "labelled day frame");
            }
        }
    }

    #[test]
    fn eight_bit_ir_and_missing_partner_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let seq = dir.path().join("run/seq_day/00");
        write(&seq.join("fl_rgb/fl_rgb_1.png"), &png_u8(4, 3, 3, &[9; 36]));
        let err = FreiburgSplit::open(dir.path(), FreiburgPreprocess::native())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("fl_rgb_1.png") && err.contains("no aligned IR"),
            "{err}"
        );
        write(
            &seq.join("fl_ir_aligned/fl_ir_aligned_1.png"),
            &png_u8(4, 3, 1, &[9; 12]),
        );
        let split = FreiburgSplit::open(dir.path(), FreiburgPreprocess::native()).unwrap();
        let err = split.load(0).unwrap_err().to_string();
        assert!(
            err.contains("fl_ir_aligned_1.png") && err.contains("expected 16-bit"),
            "{err}"
        );
        write(
            &seq.join("fl_ir_aligned/fl_ir_aligned_1.png"),
            &png_u16(4, 3, 1, &[22000; 12]),
        );
        write(
            &seq.join("fl_rgb_labels/fl_rgb_labels_1.png"),
            &png_u8(4, 3, 1, &[14; 12]),
        );
        let split = FreiburgSplit::open(dir.path(), FreiburgPreprocess::native()).unwrap();
        let err = split.load(0).unwrap_err().to_string();
        assert!(
            err.contains("label id 14") && err.contains("ignore id 13"),
            "{err}"
        );
        write(
            &seq.join("fl_rgb_labels/fl_rgb_labels_1.png"),
            &png_u8(4, 3, 1, &[13; 12]),
        );
        let split = FreiburgSplit::open(dir.path(), FreiburgPreprocess::native()).unwrap();
        let f = split.load(0).unwrap();
        assert_eq!(f.thermal[0], 200.0 / 3200.0);
    }

    #[test]
    fn class_maps_follow_the_spec() {
        let to_mf: Vec<u8> = (0..14).map(freiburg_to_mf).collect();
        assert_eq!(to_mf, [0, 0, 0, 4, 0, 0, 0, 0, 0, 2, 1, 3, 0, 0]);
        for shared in [1, 2, 3, 4] {
            assert_eq!(freiburg_to_mf(mf_to_freiburg(shared)), shared);
        }
    }
}
