//! Whole-dataset validation (`rtf data check`) and statistics (`rtf data stats`).
//!
//! `check` never stops at the first problem: it decodes every file (in parallel) and returns
//! every problem with its file name.

use crate::described::DescribedDataset;
use crate::description::DatasetDescription;
use crate::freiburg::{FreiburgPreprocess, FreiburgSplit};
use crate::mf::parse_split;
use crate::{DataError, FrameSource};
use rayon::prelude::*;
use rtf_core::{ClassSet, Daytime};
use serde::Serialize;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};

use crate::dataset::{bdd_splits, Dataset, Layout};
pub use crate::dataset::{recognise as detect_format, DatasetFormat, NOT_A_DATASET};

mod stats;
pub use stats::{stats, stats_opened, ClassShare, SplitStats, Stats};

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

#[cfg(test)]
mod tests;
