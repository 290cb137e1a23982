//! Whole-dataset validation (`rtf data check`) and statistics (`rtf data stats`).
//!
//! `check` never stops at the first problem: it decodes every file (in parallel) and returns
//! every problem with its file name.

use crate::described::DescribedDataset;
use crate::description::DatasetDescription;
use crate::freiburg::{FreiburgPreprocess, FreiburgSplit};
use crate::mf::parse_split;
use crate::{DataError, FrameSource, MfDataset};
use rayon::prelude::*;
use rtf_core::{ClassSet, Daytime};
use serde::Serialize;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};

use crate::dataset::{bdd_splits, Dataset, Layout};
pub use crate::dataset::{recognise as detect_format, DatasetFormat, NOT_A_DATASET};

/// The BDD split folder holding a list's first frame (HeatNet uses `val`).
fn bdd_split_of(root: &Path, list: &str) -> Option<String> {
    let names = crate::mf::read_split_file(&root.join(format!("{list}.txt"))).ok()?;
    let first = &names.first()?.1;
    bdd_splits(root).into_iter().find(|s| {
        ["jpg", "jpeg", "png"].iter().any(|e| {
            root.join("images")
                .join(s)
                .join(format!("{first}.{e}"))
                .is_file()
        })
    })
}

fn check_bdd(root: &Path) -> (usize, Vec<Problem>) {
    let mut problems = Vec::new();
    let lists = crate::bdd::lists(root);
    if lists.is_empty() {
        problems.push(problem(
            root,
            "no list file (<list>.txt, e.g. bdd_night.txt)",
        ));
    }
    let mut frames = 0;
    for list in lists {
        let file = root.join(format!("{list}.txt"));
        let Some(split) = bdd_split_of(root, &list) else {
            problems.push(problem(
                &file,
                "its first frame is in no images/<split>/ folder",
            ));
            continue;
        };
        // Per-line problems (missing files, duplicates) first, then decode what exists.
        let names = match crate::mf::read_split_file(&file) {
            Ok(n) => n,
            Err(e) => {
                problems.push(from_error(&file, e));
                continue;
            }
        };
        let mut seen: HashMap<&str, usize> = HashMap::new();
        for (line, name) in &names {
            if let Some(prev) = seen.insert(name, *line) {
                problems.push(problem(
                    &file,
                    format!("line {line}: '{name}' duplicates line {prev}"),
                ));
            }
        }
        let (split_ok, missing) = crate::bdd::BddSplit::scan(root, &split, names, &file);
        problems.extend(missing.into_iter().map(|e| from_error(&file, e)));
        frames += split_ok.len();
        let decoded: Vec<Problem> = (0..split_ok.len())
            .into_par_iter()
            .filter_map(|i| split_ok.load(i).err().map(|e| from_error(&file, e)))
            .collect();
        problems.extend(decoded);
    }
    (frames, problems)
}

#[derive(Debug, Clone, Serialize)]
pub struct Problem {
    pub path: PathBuf,
    pub message: String,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.message)
    }
}

fn problem(path: impl Into<PathBuf>, message: impl Into<String>) -> Problem {
    Problem {
        path: path.into(),
        message: message.into(),
    }
}

/// A data error as a problem (its message already names the file).
fn from_error(fallback: &Path, e: DataError) -> Problem {
    let path = match &e {
        DataError::Io { path, .. }
        | DataError::Png { path, .. }
        | DataError::Channels { path, .. }
        | DataError::BitDepth { path, .. }
        | DataError::LabelOutOfRange { path, .. }
        | DataError::EmptySplit { path }
        | DataError::ThermalNormalisation { path, .. }
        | DataError::Description { path, .. }
        | DataError::LabelColor { path, .. }
        | DataError::MissingPartner { path, .. }
        | DataError::Format { path, .. } => path.clone(),
        DataError::PartnerSize { partner, .. } => partner.clone(),
        DataError::SizeMismatch { label, .. } => label.clone(),
        DataError::MissingFrame { split_file, .. } => split_file.clone(),
        DataError::Layout { root, .. } | DataError::UnknownSplit { root, .. } => root.clone(),
        _ => fallback.to_path_buf(),
    };
    // The problem prints its path first: the message names it no second time.
    let text = e.to_string();
    let shown = path.display().to_string();
    let message = [": ", ", "]
        .iter()
        .find_map(|sep| text.strip_prefix(&format!("{shown}{sep}")))
        .unwrap_or(&text);
    Problem {
        message: message.to_string(),
        path,
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct CheckReport {
    pub root: PathBuf,
    pub format: Option<DatasetFormat>,
    /// Frames decoded and checked.
    pub frames: usize,
    pub problems: Vec<Problem>,
    /// The classes the layout reads (none when the root or its description is unreadable).
    pub class_set: Option<ClassSet>,
    /// How thermal becomes [0, 1] (described layouts only).
    pub thermal: Option<String>,
    /// A root of no known layout: a dataset.yaml skeleton from what it holds
    /// ([`crate::unknown`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub skeleton: Option<String>,
}

impl CheckReport {
    pub fn is_ok(&self) -> bool {
        self.problems.is_empty()
    }
}

/// Validates a dataset completely; every problem is listed (sorted by path).
pub fn check(root: &Path) -> CheckReport {
    let format = detect_format(root);
    let fault = match format.map(|f| Dataset::open_as(root, f)) {
        Some(Ok(dataset)) => return check_opened(&dataset),
        Some(Err(e)) => from_error(root, e),
        None if root.is_dir() => problem(root, crate::unknown::verdict(root)),
        None => problem(root, NOT_A_DATASET),
    };
    CheckReport {
        root: root.to_path_buf(),
        format,
        frames: 0,
        problems: vec![fault],
        class_set: None,
        thermal: None,
        skeleton: (format.is_none() && root.is_dir()).then(|| crate::unknown::skeleton(root)),
    }
}

/// Validates an opened dataset completely; every problem is listed (sorted by path).
pub fn check_opened(dataset: &Dataset) -> CheckReport {
    let root = dataset.root();
    let (frames, mut problems) = match dataset.layout() {
        Layout::Mf => check_mf(root),
        Layout::Freiburg => check_freiburg(root),
        Layout::Bdd => check_bdd(root),
        Layout::Described(d) => check_described(d),
    };
    problems.sort_by(|a, b| a.path.cmp(&b.path).then(a.message.cmp(&b.message)));
    // One problem found by two splits (a condition list both read) is said once.
    problems.dedup_by(|a, b| a.path == b.path && a.message == b.message);
    CheckReport {
        root: root.to_path_buf(),
        format: Some(dataset.format()),
        frames,
        problems,
        class_set: Some(dataset.class_set()),
        thermal: dataset.description().map(|d| d.thermal.describe()),
        skeleton: None,
    }
}

/// Every split of a described dataset opened (pairing) and every frame decoded (sizes,
/// label ids or colours, thermal normalisation), in parallel.
fn check_described(description: &DatasetDescription) -> (usize, Vec<Problem>) {
    let dataset = DescribedDataset::new(description.clone());
    let mut problems = Vec::new();
    let mut frames = 0;
    for name in description.split_names() {
        let split = match dataset.split(name) {
            Ok(split) => split,
            Err(e) => {
                problems.push(from_error(&description.root, e));
                continue;
            }
        };
        frames += split.len();
        let decoded: Vec<Problem> = (0..split.len())
            .into_par_iter()
            .filter_map(|i| {
                split
                    .load(i)
                    .err()
                    .map(|e| from_error(&description.root, e))
            })
            .collect();
        problems.extend(decoded);
    }
    (frames, problems)
}

fn stems(dir: &Path, problems: &mut Vec<Problem>) -> Vec<String> {
    let mut out = Vec::new();
    match std::fs::read_dir(dir) {
        Err(e) => problems.push(problem(dir, e.to_string())),
        Ok(entries) => {
            for e in entries.flatten() {
                let p = e.path();
                if p.is_dir() {
                    if p.extension().is_some_and(|x| x == "png") {
                        problems.push(problem(&p, "is a directory, expected a PNG file"));
                    }
                    continue;
                }
                if !p.is_file() {
                    continue;
                }
                match (
                    p.extension().and_then(|x| x.to_str()),
                    p.file_stem().and_then(|s| s.to_str()),
                ) {
                    (Some("png"), Some(stem)) => out.push(stem.to_string()),
                    _ => problems.push(problem(&p, "not a .png file (ignored by the reader)")),
                }
            }
        }
    }
    out.sort();
    out
}

fn check_mf(root: &Path) -> (usize, Vec<Problem>) {
    let mut problems = Vec::new();
    let images = stems(&root.join("images"), &mut problems);
    let labels = stems(&root.join("labels"), &mut problems);
    let image_set: HashSet<&String> = images.iter().collect();
    let label_set: HashSet<&String> = labels.iter().collect();
    problems.extend(unpaired_mf_files(root, &images, &labels));
    let pairs = PairSets {
        images: &image_set,
        labels: &label_set,
    };
    let splits = check_mf_split_files(root, &pairs, &mut problems);
    problems.extend(unlisted_or_undated_frames(root, &images, &splits));
    let paired: Vec<&String> = images.iter().filter(|n| label_set.contains(n)).collect();
    let decoded = decode_mf_pairs(root, &paired);
    let mut sizes: BTreeMap<(usize, usize), Vec<&str>> = BTreeMap::new();
    for (name, _, result) in &decoded {
        match result {
            Ok(size) => sizes.entry(*size).or_default().push(name),
            Err(p) => problems.push(p.clone()),
        }
    }
    problems.extend(odd_sizes(root, &sizes));
    let hashes: Vec<(&str, [u8; 32])> = decoded
        .iter()
        .filter_map(|(n, h, _)| h.map(|h| (n.as_str(), h)))
        .collect();
    problems.extend(duplicate_frames(root, &hashes, &splits.members));
    (paired.len(), problems)
}

/// Frame names present in `images/` and in `labels/` of an MF root.
struct PairSets<'a> {
    images: &'a HashSet<&'a String>,
    labels: &'a HashSet<&'a String>,
}

/// What the split files of an MF root say: which splits list each frame, and each split's
/// file with its names and lines (for the leak check).
#[derive(Default)]
struct MfSplitFiles {
    listed: HashMap<String, Vec<String>>,
    members: SplitMembers,
    any_file: bool,
}

/// An image without its label or a label without its image.
fn unpaired_mf_files(root: &Path, images: &[String], labels: &[String]) -> Vec<Problem> {
    let label_set: HashSet<&String> = labels.iter().collect();
    let image_set: HashSet<&String> = images.iter().collect();
    let mut problems = Vec::new();
    for name in images.iter().filter(|n| !label_set.contains(n)) {
        problems.push(problem(
            root.join("labels").join(format!("{name}.png")),
            "missing (image has no label)",
        ));
    }
    for name in labels.iter().filter(|n| !image_set.contains(n)) {
        problems.push(problem(
            root.join("images").join(format!("{name}.png")),
            "missing (label has no image)",
        ));
    }
    problems
}

/// Paths under `root` (not recursive) with extension `.txt` that are files (`want_dirs`
/// false) or directories (true), sorted.
fn txt_entries(root: &Path, want_dirs: bool) -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(root)
        .map(|rd| {
            rd.flatten()
                .map(|e| e.path())
                .filter(|p| p.is_dir() == want_dirs && p.extension().is_some_and(|x| x == "txt"))
                .filter(|p| want_dirs || p.is_file())
                .collect()
        })
        .unwrap_or_default();
    out.sort();
    out
}

/// Split files: unreadable, empty, duplicate lines, names without files; a directory where a
/// split file belongs; no split file at all.
fn check_mf_split_files(
    root: &Path,
    pairs: &PairSets,
    problems: &mut Vec<Problem>,
) -> MfSplitFiles {
    let split_files = txt_entries(root, false);
    let split_dirs = txt_entries(root, true);
    for dir in &split_dirs {
        problems.push(problem(
            dir,
            "is a directory, expected a split file (one frame name per line)",
        ));
    }
    if split_files.is_empty() && split_dirs.is_empty() {
        problems.push(problem(
            root,
            "no split files (<split>.txt, e.g. train.txt)",
        ));
    }
    let mut out = MfSplitFiles {
        any_file: !split_files.is_empty(),
        ..Default::default()
    };
    for file in &split_files {
        let split = file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let Some(names) = read_mf_split_file(file, problems) else {
            continue;
        };
        check_mf_split_names(file, &names, pairs, problems);
        for (_, name) in &names {
            out.listed
                .entry(name.clone())
                .or_default()
                .push(split.clone());
        }
        out.members.insert(split, (file.clone(), names));
    }
    out
}

/// The names of one split file with their lines, or `None` (and a problem) if unreadable.
fn read_mf_split_file(file: &Path, problems: &mut Vec<Problem>) -> Option<Vec<(usize, String)>> {
    let text = match std::fs::read(file).map(String::from_utf8) {
        Err(e) => {
            problems.push(problem(file, e.to_string()));
            return None;
        }
        Ok(Err(_)) => {
            problems.push(problem(file, "not UTF-8 text"));
            return None;
        }
        Ok(Ok(t)) => t,
    };
    match parse_split(&text, file) {
        Ok(names) => Some(names),
        Err(e) => {
            problems.push(from_error(file, e));
            None
        }
    }
}

/// An empty split, a name listed twice, a name without its image or label.
fn check_mf_split_names(
    file: &Path,
    names: &[(usize, String)],
    pairs: &PairSets,
    problems: &mut Vec<Problem>,
) {
    if names.is_empty() {
        problems.push(problem(file, "split is empty (no frame names)"));
    }
    let mut first_line: HashMap<&str, usize> = HashMap::new();
    for (line, name) in names {
        if let Some(prev) = first_line.insert(name, *line) {
            problems.push(problem(
                file,
                format!("line {line}: '{name}' duplicates line {prev}"),
            ));
        }
        if !pairs.images.contains(name) {
            problems.push(problem(
                file,
                format!("line {line}: frame '{name}' has no image images/{name}.png"),
            ));
        } else if !pairs.labels.contains(name) {
            problems.push(problem(
                file,
                format!("line {line}: frame '{name}' has no label labels/{name}.png"),
            ));
        }
    }
}

/// Images in no split file (when there are split files), and names without the D/N suffix.
fn unlisted_or_undated_frames(
    root: &Path,
    images: &[String],
    splits: &MfSplitFiles,
) -> Vec<Problem> {
    let mut problems = Vec::new();
    for name in images {
        let path = root.join("images").join(format!("{name}.png"));
        if splits.any_file && !splits.listed.contains_key(name) {
            problems.push(problem(&path, "frame is in no split file"));
        }
        if Daytime::from_mf_name(name).is_none() {
            problems.push(problem(
                &path,
                "name does not end in D or N (day/night unknown)",
            ));
        }
    }
    problems
}

/// Decodes every image/label pair in parallel: its size or the problem, and the hash of the
/// image bytes for the duplicate check.
fn decode_mf_pairs(root: &Path, pairs: &[&String]) -> Vec<Decoded> {
    let classes = ClassSet::mf();
    pairs
        .par_iter()
        .map(|name| {
            let img = root.join("images").join(format!("{name}.png"));
            let lab = root.join("labels").join(format!("{name}.png"));
            let read = |p: &Path| std::fs::read(p).map_err(|e| DataError::io(p, e));
            let image_bytes = read(&img);
            let hash = image_bytes
                .as_ref()
                .ok()
                .map(|b| crate::hash::hash_bytes(b));
            let result = image_bytes
                .and_then(|ib| read(&lab).map(|lb| (ib, lb)))
                .and_then(|(ib, lb)| {
                    crate::mf::decode_mf_frame(name, &ib, &img, &lb, &lab, &classes)
                })
                .map(|f| (f.width, f.height))
                .map_err(|e| from_error(&img, e));
            (name.to_string(), hash, result)
        })
        .collect()
}

/// A decoded pair: frame name, hash of the image bytes (if read), size or the problem.
type Decoded = (String, Option<[u8; 32]>, Result<(usize, usize), Problem>);

/// Split name -> (split file, frame names with their line numbers).
type SplitMembers = BTreeMap<String, (PathBuf, Vec<(usize, String)>)>;

/// Frames whose size differs from the most common one: `rtf train` and `rtf eval` batch
/// frames of one size only (unless told to --resize), so such a frame fails a run later.
fn odd_sizes(root: &Path, sizes: &BTreeMap<(usize, usize), Vec<&str>>) -> Vec<Problem> {
    let total: usize = sizes.values().map(Vec::len).sum();
    let Some((&(w0, h0), common)) = sizes.iter().max_by_key(|(_, names)| names.len()) else {
        return Vec::new();
    };
    sizes
        .iter()
        .filter(|(&size, _)| size != (w0, h0))
        .flat_map(|(&(w, h), names)| {
            names.iter().map(move |name| {
                problem(
                    root.join("images").join(format!("{name}.png")),
                    format!(
                        "is {w}x{h} but {} of {total} frames are {w0}x{h0}: training and \
                         evaluation batch frames of one size (without --resize they stop at \
                         this frame)",
                        common.len()
                    ),
                )
            })
        })
        .collect()
}

/// Byte-identical images under different names, and frames (by content) shared between
/// two splits where neither split contains the other (test_day ⊂ test is by design; a frame
/// of test also in train is a leak).
fn duplicate_frames(
    root: &Path,
    hashes: &[(&str, [u8; 32])],
    members: &SplitMembers,
) -> Vec<Problem> {
    let mut problems = Vec::new();
    let mut by_hash: BTreeMap<[u8; 32], Vec<&str>> = BTreeMap::new();
    for (name, hash) in hashes {
        by_hash.entry(*hash).or_default().push(name);
    }
    let image = |name: &str| root.join("images").join(format!("{name}.png"));
    for names in by_hash.values().filter(|n| n.len() > 1) {
        let mut names = names.clone();
        names.sort();
        for other in &names[1..] {
            problems.push(problem(
                image(other),
                format!(
                    "same bytes as {}: one frame under two names",
                    image(names[0]).display()
                ),
            ));
        }
    }
    let hash_of: HashMap<&str, [u8; 32]> = hashes.iter().copied().collect();
    type SplitSet<'a> = (
        &'a String,
        &'a PathBuf,
        HashSet<&'a str>,
        &'a Vec<(usize, String)>,
    );
    let split_sets: Vec<SplitSet> = members
        .iter()
        .map(|(split, (file, names))| {
            let set = names.iter().map(|(_, n)| n.as_str()).collect();
            (split, file, set, names)
        })
        .collect();
    for (i, (a, file_a, set_a, lines_a)) in split_sets.iter().enumerate() {
        for (b, _, set_b, lines_b) in &split_sets[i + 1..] {
            if set_a.is_subset(set_b) || set_b.is_subset(set_a) {
                continue;
            }
            let in_b: HashMap<[u8; 32], &str> = lines_b
                .iter()
                .filter_map(|(_, n)| hash_of.get(n.as_str()).map(|h| (*h, n.as_str())))
                .collect();
            for (line, name) in lines_a.iter() {
                let shared = if set_b.contains(name.as_str()) {
                    Some(format!("frame '{name}' is also in split '{b}'"))
                } else {
                    hash_of
                        .get(name.as_str())
                        .and_then(|h| in_b.get(h))
                        .map(|other| {
                            format!(
                                "frame '{name}' has the same content as '{other}' of split '{b}'"
                            )
                        })
                };
                if let Some(what) = shared {
                    problems.push(problem(
                        *file_a,
                        format!(
                            "line {line}: {what}: a frame shared between splits '{a}' and '{b}'"
                        ),
                    ));
                }
            }
        }
    }
    problems
}

fn check_freiburg(root: &Path) -> (usize, Vec<Problem>) {
    let (split, errors) = match FreiburgSplit::scan(root, FreiburgPreprocess::native()) {
        Ok(r) => r,
        Err(e) => return (0, vec![from_error(root, e)]),
    };
    let mut problems: Vec<Problem> = errors.into_iter().map(|e| from_error(root, e)).collect();
    let decode: Vec<Problem> = (0..split.len())
        .into_par_iter()
        .filter_map(|i| {
            split
                .load_raw(i)
                .err()
                .map(|e| from_error(&split.files(i).0, e))
        })
        .collect();
    problems.extend(decode);
    // The same RGB image under two names (copied frames, leaks between train and test).
    let hashed: Vec<(PathBuf, Option<[u8; 32]>)> = (0..split.len())
        .into_par_iter()
        .map(|i| {
            let rgb = split.files(i).0;
            let hash = crate::hash::hash_file(&rgb).ok();
            (rgb, hash)
        })
        .collect();
    let mut by_hash: BTreeMap<[u8; 32], Vec<&PathBuf>> = BTreeMap::new();
    for (path, hash) in &hashed {
        if let Some(h) = hash {
            by_hash.entry(*h).or_default().push(path);
        }
    }
    for paths in by_hash.values().filter(|p| p.len() > 1) {
        let mut paths = paths.clone();
        paths.sort();
        for other in &paths[1..] {
            problems.push(problem(
                *other,
                format!(
                    "same bytes as {}: one frame under two names",
                    paths[0].display()
                ),
            ));
        }
    }
    (split.len(), problems)
}

#[derive(Debug, Clone, Serialize)]
pub struct SplitStats {
    pub name: String,
    pub frames: usize,
    pub day: usize,
    pub night: usize,
}

#[derive(Debug, Clone, Serialize)]
pub struct ClassShare {
    pub id: u8,
    pub name: String,
    pub pixels: u64,
    /// Fraction of all labelled pixels (MFNet Fig. 4).
    pub share: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct Stats {
    pub root: PathBuf,
    pub format: DatasetFormat,
    pub splits: Vec<SplitStats>,
    /// Distinct frames with labels that were counted for the class shares.
    pub labelled_frames: usize,
    pub classes: Vec<ClassShare>,
    /// Pixels with the ignore id (Freiburg), not part of the shares.
    pub ignored_pixels: u64,
}

/// Frames per split and day/night, and per-class pixel shares over all distinct labelled frames.
pub fn stats(root: &Path) -> Result<Stats, DataError> {
    stats_opened(&crate::dataset::open(root)?)
}

/// [`stats`] of an opened dataset.
pub fn stats_opened(dataset: &Dataset) -> Result<Stats, DataError> {
    let root = dataset.root();
    let counted = match dataset.layout() {
        Layout::Mf => mf_counts(root)?,
        Layout::Freiburg => freiburg_counts(root)?,
        Layout::Bdd => bdd_counts(root)?,
        Layout::Described(description) => described_counts(description)?,
    };
    let Counted {
        splits,
        classes,
        counts,
        labelled,
        ignored,
    } = counted;
    let total: u64 = counts.iter().take(classes.len()).sum();
    let classes = classes
        .classes
        .iter()
        .map(|c| {
            let pixels = counts[c.id as usize];
            ClassShare {
                id: c.id,
                name: c.name.clone(),
                pixels,
                share: if total > 0 {
                    pixels as f64 / total as f64
                } else {
                    0.0
                },
            }
        })
        .collect();
    Ok(Stats {
        root: root.to_path_buf(),
        format: dataset.format(),
        splits,
        labelled_frames: labelled,
        classes,
        ignored_pixels: ignored,
    })
}

/// What one layout's statistics counted: splits, the class set, pixels per label value (256),
/// labelled frames and ignored pixels.
struct Counted {
    splits: Vec<SplitStats>,
    classes: ClassSet,
    counts: Vec<u64>,
    labelled: usize,
    ignored: u64,
}

fn count_days(src: &dyn FrameSource) -> (usize, usize) {
    let day = (0..src.len())
        .filter(|&i| src.daytime(i) == Some(Daytime::Day))
        .count();
    let night = (0..src.len())
        .filter(|&i| src.daytime(i) == Some(Daytime::Night))
        .count();
    (day, night)
}

fn split_stats(name: &str, src: &dyn FrameSource) -> SplitStats {
    let (day, night) = count_days(src);
    SplitStats {
        name: name.to_string(),
        frames: src.len(),
        day,
        night,
    }
}

fn ignored_pixels(classes: &ClassSet, counts: &[u64]) -> u64 {
    classes
        .ignore_id
        .map_or(0, |id| counts.get(id as usize).copied().unwrap_or(0))
}

fn mf_counts(root: &Path) -> Result<Counted, DataError> {
    let ds = MfDataset::open(root)?;
    let mut splits = Vec::new();
    let mut frames: BTreeMap<String, ()> = BTreeMap::new();
    for name in ds.split_names() {
        let split = ds.split(name)?;
        splits.push(split_stats(name, &split));
        for n in split.names() {
            frames.insert(n.clone(), ());
        }
    }
    let names: Vec<String> = frames.into_keys().collect();
    let classes = ds.class_set().clone();
    let counts = count_pixels(&classes, names.len(), |i| {
        ds.load_frame(&names[i]).map(|f| f.label)
    })?;
    Ok(Counted {
        splits,
        classes,
        counts,
        labelled: names.len(),
        ignored: 0,
    })
}

fn freiburg_counts(root: &Path) -> Result<Counted, DataError> {
    let split = FreiburgSplit::open(root, FreiburgPreprocess::native())?;
    let mut groups: BTreeMap<String, (usize, usize, usize)> = BTreeMap::new();
    for i in 0..split.len() {
        let name = split.frame_name(i);
        // Group by the first path component (train / test/day …).
        let group = Path::new(name)
            .parent()
            .and_then(|p| p.components().next())
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .unwrap_or_default();
        let g = groups.entry(group).or_default();
        g.0 += 1;
        match split.daytime(i) {
            Some(Daytime::Day) => g.1 += 1,
            _ => g.2 += 1,
        }
    }
    let splits = groups
        .into_iter()
        .map(|(name, (frames, day, night))| SplitStats {
            name,
            frames,
            day,
            night,
        })
        .collect();
    let classes = split.class_set().clone();
    let labelled: Vec<usize> = (0..split.len()).filter(|&i| split.is_labelled(i)).collect();
    let counts = count_pixels(&classes, labelled.len(), |i| {
        split.load_raw(labelled[i]).map(|f| f.label)
    })?;
    Ok(Counted {
        splits,
        ignored: ignored_pixels(&classes, &counts),
        classes,
        counts,
        labelled: labelled.len(),
    })
}

fn bdd_counts(root: &Path) -> Result<Counted, DataError> {
    let classes = ClassSet::freiburg();
    let mut counts = vec![0u64; 256];
    let mut seen: BTreeMap<String, ()> = BTreeMap::new();
    let (mut labelled, mut splits) = (0, Vec::new());
    for list in crate::bdd::lists(root) {
        let split_name = bdd_split_of(root, &list).ok_or_else(|| DataError::Layout {
            root: root.to_path_buf(),
            message: format!("{list}.txt: its first frame is in no images/<split>/ folder"),
        })?;
        let split = crate::bdd::BddSplit::open(root, &list, &split_name, None)?;
        splits.push(SplitStats {
            name: list.clone(),
            frames: split.len(),
            day: 0,
            night: split.len(),
        });
        let fresh: Vec<usize> = (0..split.len())
            .filter(|&i| seen.insert(split.frame_name(i).to_string(), ()).is_none())
            .collect();
        let c = count_pixels(&classes, fresh.len(), |i| {
            split.load(fresh[i]).map(|f| f.label)
        })?;
        counts.iter_mut().zip(c).for_each(|(a, b)| *a += b);
        labelled += fresh.len();
    }
    let ignored = counts[13];
    Ok(Counted {
        splits,
        classes,
        counts,
        labelled,
        ignored,
    })
}

/// A described dataset: every split, the labels of every labelled split counted (a frame in
/// two splits is counted once per split: splits of these layouts are folders, not lists).
fn described_counts(description: &DatasetDescription) -> Result<Counted, DataError> {
    let dataset = DescribedDataset::new(description.clone());
    let classes = description.class_set.clone();
    let mut counts = vec![0u64; 256];
    let (mut labelled, mut splits) = (0, Vec::new());
    for name in description.split_names() {
        let split = dataset.split(name)?;
        splits.push(split_stats(name, &split));
        if !split.labelled() {
            continue;
        }
        let c = count_pixels(&classes, split.len(), |i| split.load(i).map(|f| f.label))?;
        counts.iter_mut().zip(c).for_each(|(a, b)| *a += b);
        labelled += split.len();
    }
    Ok(Counted {
        splits,
        ignored: ignored_pixels(&classes, &counts),
        classes,
        counts,
        labelled,
    })
}

fn count_pixels(
    classes: &ClassSet,
    n: usize,
    load: impl Fn(usize) -> Result<Option<Vec<u8>>, DataError> + Sync,
) -> Result<Vec<u64>, DataError> {
    let size = 256;
    let _ = classes;
    (0..n)
        .into_par_iter()
        .map(|i| {
            let mut c = vec![0u64; size];
            if let Some(l) = load(i)? {
                for v in l {
                    c[v as usize] += 1;
                }
            }
            Ok(c)
        })
        .try_reduce(
            || vec![0u64; size],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                Ok(a)
            },
        )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fingerprint::fingerprint;
    use crate::synth::{generate, SynthConfig, SynthFormat};
    use crate::testutil::*;

    #[test]
    fn clean_synthetic_datasets_pass() {
        for format in [SynthFormat::Mf, SynthFormat::Freiburg] {
            let dir = tempfile::tempdir().unwrap();
            generate(
                dir.path(),
                &SynthConfig {
                    count: 8,
                    width: 64,
                    height: 48,
                    format,
                    ..SynthConfig::default()
                },
            )
            .unwrap();
            let report = check(dir.path());
            assert!(report.is_ok(), "{format:?}: {:?}", report.problems);
            assert_eq!(report.frames, 8);
        }
    }

    #[test]
    fn check_reports_every_problem_with_file_names() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        mf_dataset(
            root,
            &["00001D", "00002N", "00003D", "00004N", "00005D"],
            8,
            6,
        );
        // 1: truncated image; 2: label with an id out of range; 3: RGB (3-channel) image;
        // 4: label missing; 5: 16-bit label; plus a duplicate and a missing split entry and
        // a frame in no split.
        let img1 = std::fs::read(root.join("images/00001D.png")).unwrap();
        write(&root.join("images/00001D.png"), &img1[..img1.len() / 2]);
        write(&root.join("labels/00002N.png"), &png_u8(8, 6, 1, &[12; 48]));
        write(&root.join("images/00003D.png"), &png_u8(8, 6, 3, &[1; 144]));
        std::fs::remove_file(root.join("labels/00004N.png")).unwrap();
        write(&root.join("labels/00005D.png"), &png_u16(8, 6, 1, &[1; 48]));
        write(
            &root.join("train.txt"),
            b"00001D\n00002N\n00003D\n00004N\n00002N\n00009D\n",
        );
        write(&root.join("images/00006N.png"), &png_u8(8, 6, 4, &[1; 192]));
        write(&root.join("labels/00006N.png"), &png_u8(8, 6, 1, &[1; 48]));
        let report = check(root);
        let text: Vec<String> = report.problems.iter().map(|p| p.to_string()).collect();
        let has = |needle: &[&str]| text.iter().any(|t| needle.iter().all(|n| t.contains(n)));
        assert!(
            has(&["images/00001D.png", "not a readable PNG"]),
            "{text:#?}"
        );
        assert!(has(&["labels/00002N.png", "label id 12"]), "{text:#?}");
        assert!(
            has(&["images/00003D.png", "expected 4 channel"]),
            "{text:#?}"
        );
        assert!(has(&["labels/00004N.png", "missing"]), "{text:#?}");
        assert!(has(&["labels/00005D.png", "16-bit"]), "{text:#?}");
        assert!(
            has(&["train.txt", "line 5", "duplicates line 2"]),
            "{text:#?}"
        );
        assert!(has(&["train.txt", "line 6", "00009D"]), "{text:#?}");
        assert!(has(&["images/00006N.png", "in no split"]), "{text:#?}");
        assert_eq!(report.frames, 5, "every pair with both files was decoded");
    }

    #[test]
    fn bdd_roots_are_recognised_checked_and_counted() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        write(&root.join("images/val/a.png"), &png_u8(4, 2, 3, &[50; 24]));
        write(
            &root.join("labels/val/a_train_id.png"),
            &png_u8(4, 2, 1, &[0, 0, 11, 11, 13, 13, 255, 255]),
        );
        write(&root.join("bdd_night.txt"), b"a\n");
        assert_eq!(detect_format(root), Some(DatasetFormat::Bdd));
        assert!(check(root).is_ok(), "{:?}", check(root).problems);
        let s = stats(root).unwrap();
        assert_eq!((s.splits[0].frames, s.splits[0].night), (1, 1));
        assert_eq!(
            (
                s.classes[0].pixels,
                s.classes[9].pixels,
                s.classes[10].pixels,
                s.ignored_pixels
            ),
            (2, 2, 2, 2)
        );
        write(&root.join("bdd_night.txt"), b"a\nb\na\n");
        let text: Vec<String> = check(root).problems.iter().map(|p| p.to_string()).collect();
        assert!(
            text.iter()
                .any(|t| t.contains("line 2") && t.contains("'b'")),
            "{text:?}"
        );
        assert!(
            text.iter()
                .any(|t| t.contains("line 3") && t.contains("duplicates line 1")),
            "{text:?}"
        );
    }

    #[test]
    fn stats_count_frames_and_class_shares() {
        let dir = tempfile::tempdir().unwrap();
        generate(
            dir.path(),
            &SynthConfig {
                count: 16,
                width: 64,
                height: 48,
                ..SynthConfig::default()
            },
        )
        .unwrap();
        let s = stats(dir.path()).unwrap();
        let train = s.splits.iter().find(|x| x.name == "train").unwrap();
        assert_eq!((train.frames, train.day, train.night), (8, 4, 4));
        assert_eq!(s.labelled_frames, 16);
        let total: f64 = s.classes.iter().map(|c| c.share).sum();
        assert!((total - 1.0).abs() < 1e-9);
        let pixels: u64 = s.classes.iter().map(|c| c.pixels).sum();
        assert_eq!(pixels, 16 * 64 * 48);
        assert!(
            s.classes[0].share > 0.5,
            "unlabeled is the majority, as in MF"
        );
    }

    #[test]
    fn odd_sized_frames_and_directories_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        mf_dataset(root, &["00001D", "00002N", "00003D"], 8, 6);
        // One frame of another size, image and label consistent: decodes, but cannot batch.
        write(
            &root.join("images/00004N.png"),
            &png_u8(10, 6, 4, &rgba(10, 6, 9)),
        );
        write(&root.join("labels/00004N.png"), &png_u8(10, 6, 1, &[1; 60]));
        write(&root.join("train.txt"), b"00001D\n00002N\n00003D\n00004N\n");
        // A split "file" that is a directory, and an image path that is a directory.
        std::fs::create_dir_all(root.join("val.txt")).unwrap();
        std::fs::create_dir_all(root.join("images/00005D.png")).unwrap();
        let report = check(root);
        let text: Vec<String> = report.problems.iter().map(|p| p.to_string()).collect();
        let has = |needle: &[&str]| text.iter().any(|t| needle.iter().all(|n| t.contains(n)));
        assert!(
            has(&[
                "images/00004N.png",
                "is 10x6",
                "3 of 4 frames are 8x6",
                "--resize"
            ]),
            "{text:#?}"
        );
        assert!(
            has(&["val.txt", "is a directory", "split file"]),
            "{text:#?}"
        );
        assert!(
            has(&["images/00005D.png", "is a directory", "PNG"]),
            "{text:#?}"
        );
        assert!(
            !text.iter().any(|t| t.contains("no split files")),
            "no misleading message: {text:#?}"
        );
    }

    #[test]
    fn frames_shared_between_splits_and_duplicates_are_reported() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        mf_dataset(root, &["00001D", "00002N", "00003D", "00004N"], 8, 6);
        // 00004N is a byte copy of 00001D under another name.
        std::fs::copy(
            root.join("images/00001D.png"),
            root.join("images/00004N.png"),
        )
        .unwrap();
        write(&root.join("train.txt"), b"00001D\n00002N\n");
        // test: 00002N leaks by name, 00004N by content; test_day is a subset of test.
        write(&root.join("test.txt"), b"00002N\n00003D\n00004N\n");
        write(&root.join("test_day.txt"), b"00003D\n");
        let report = check(root);
        let text: Vec<String> = report.problems.iter().map(|p| p.to_string()).collect();
        let has = |needle: &[&str]| text.iter().any(|t| needle.iter().all(|n| t.contains(n)));
        assert!(
            has(&["images/00004N.png", "same bytes as", "00001D.png"]),
            "{text:#?}"
        );
        assert!(
            has(&["test.txt", "line 1", "'00002N' is also in split 'train'"]),
            "{text:#?}"
        );
        assert!(
            has(&[
                "test.txt",
                "line 3",
                "'00004N' has the same content as '00001D'"
            ]),
            "{text:#?}"
        );
        assert!(
            !text.iter().any(|t| t.contains("test_day")),
            "a subset split is no leak: {text:#?}"
        );
    }

    #[test]
    fn check_and_stats_name_a_described_layout_and_its_classes() {
        let dir = tempfile::tempdir().unwrap();
        let pst = RgbtFolders {
            rgb: "rgb",
            thermal: "thermal",
            labels: "labels",
        };
        for (split, name) in [("train", "f1"), ("test", "f2")] {
            let d = dir.path().join(split);
            write_rgbt_frame(&d, &pst, name, (5, 2), ThermalFixture::Grey8, 5);
        }
        let report = check(dir.path());
        assert!(report.is_ok(), "{:?}", report.problems);
        assert_eq!(report.format, Some(DatasetFormat::Pst900));
        assert_eq!(report.frames, 2);
        assert_eq!(report.class_set.as_ref().unwrap().names()[4], "survivor");
        assert_eq!(report.thermal.as_deref(), Some("8-bit / 255"));
        let s = stats(dir.path()).unwrap();
        assert_eq!(s.labelled_frames, 2);
        // ids(5, 2, 5) = 0,0,0,1,1,1,2,2,2,3: per frame 3+3+3+1+0 pixels.
        let pixels: Vec<(&str, u64)> = s
            .classes
            .iter()
            .map(|c| (c.name.as_str(), c.pixels))
            .collect();
        assert_eq!(
            pixels,
            [
                ("background", 6),
                ("fire_extinguisher", 6),
                ("backpack", 6),
                ("hand_drill", 2),
                ("survivor", 0)
            ]
        );
        // A label id outside the class list is a problem naming the file and the id.
        let label = dir.path().join("test/labels/f2.png");
        write(&label, &png_u8(5, 2, 1, &[9; 10]));
        let report = check(dir.path());
        assert_eq!(report.problems.len(), 1, "{:?}", report.problems);
        assert_eq!(report.problems[0].path, label);
        assert!(
            report.problems[0].message.contains("label id 9"),
            "{}",
            report.problems[0]
        );
        assert_eq!(fingerprint(dir.path()).unwrap().splits.len(), 2);
    }
}
