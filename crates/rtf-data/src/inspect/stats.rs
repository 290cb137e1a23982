//! Dataset statistics (`rtf data stats`): frames per split and day/night, and per-class pixel
//! shares over all distinct labelled frames, counted per layout.

use super::{bdd_split_of, DatasetFormat};
use crate::dataset::{Dataset, Layout};
use crate::described::DescribedDataset;
use crate::description::DatasetDescription;
use crate::freiburg::{FreiburgPreprocess, FreiburgSplit};
use crate::{DataError, FrameSource, MfDataset};
use rayon::prelude::*;
use rtf_core::{ClassSet, Daytime};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

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
