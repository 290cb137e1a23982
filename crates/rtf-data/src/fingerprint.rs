//! Content fingerprints of a dataset, so that a result says which data it came from
//! (`rtf data fingerprint`, the `data_fingerprint` of eval JSON and of a run's config.json).
//!
//! Every file a split reads is hashed with SHA-256 (FIPS 180-4, via the `sha2` crate). A
//! split's hash covers, in split order, each frame's name and the relative path and hash of
//! each of its files; the dataset's hash covers every split's name and hash, sorted by name.
//! Renaming, reordering, adding or editing a frame changes the hash; copying the root
//! elsewhere does not. Layouts: MF (one split per `<split>.txt`) and Freiburg Thermal
//! (`train`: the training tree, `test`: the test layout, as `rtf eval --split` names them).

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use sha2::{Digest, Sha256};

pub use crate::hash::{hash_bytes, hash_file};

use crate::dataset::{Dataset, DatasetFormat, Layout};
use crate::description::DatasetDescription;
use crate::{
    DataError, DescribedDataset, FrameSource, FreiburgPart, FreiburgPreprocess, FreiburgSplit,
    MfDataset,
};

/// A dataset's fingerprint as results record it: the schema's (rtf-config).
pub use rtf_config::data::{Fingerprint, SplitFingerprint, ALGORITHM};

pub fn hex(hash: &[u8]) -> String {
    hash.iter().map(|b| format!("{b:02x}")).collect()
}

/// One frame of a split: its name and the files it reads.
struct FrameFiles {
    name: String,
    files: Vec<PathBuf>,
}

fn mf_frames(root: &Path) -> Result<Vec<(String, Vec<FrameFiles>)>, DataError> {
    let ds = MfDataset::open(root)?;
    ds.split_names()
        .iter()
        .map(|name| {
            let split = ds.split(name)?;
            let frames = split
                .names()
                .iter()
                .map(|n| FrameFiles {
                    name: n.clone(),
                    files: vec![ds.image_path(n), ds.label_path(n)],
                })
                .collect();
            Ok((name.clone(), frames))
        })
        .collect()
}

fn freiburg_frames(root: &Path) -> Result<Vec<(String, Vec<FrameFiles>)>, DataError> {
    let all = FreiburgSplit::open(root, FreiburgPreprocess::native())?;
    Ok([
        ("test", FreiburgPart::TestLayout),
        ("train", FreiburgPart::TrainTree),
        ("val", FreiburgPart::Validation),
    ]
    .into_iter()
    .map(|(name, part)| {
        let split = all.clone().part(part);
        let frames = (0..split.len())
            .map(|i| {
                let (rgb, ir, label) = split.files(i);
                let mut files = vec![rgb, ir];
                files.extend(label);
                FrameFiles {
                    name: split.frame_name(i).to_string(),
                    files,
                }
            })
            .collect::<Vec<_>>();
        (name.to_string(), frames)
    })
    .filter(|(_, frames)| !frames.is_empty())
    .collect())
}

/// The frames of a described layout; with a dataset.yaml, each frame also reads it (it decides
/// how the frame's files become a frame).
fn described_frames(
    description: &DatasetDescription,
) -> Result<Vec<(String, Vec<FrameFiles>)>, DataError> {
    let yaml = Some(description.origin.clone()).filter(|p| p.is_file());
    let dataset = DescribedDataset::new(description.clone());
    description
        .split_names()
        .into_iter()
        .map(|name| {
            let split = dataset.split(name)?;
            let frames = (0..split.len())
                .map(|i| {
                    let mut files: Vec<PathBuf> =
                        split.files(i).into_iter().map(Path::to_path_buf).collect();
                    files.extend(yaml.clone());
                    FrameFiles {
                        name: split.frame_name(i).to_string(),
                        files,
                    }
                })
                .collect();
            Ok((name.to_string(), frames))
        })
        .collect()
}

/// Fingerprints the dataset under `root` (module docs), opened once ([`crate::dataset`]).
pub fn fingerprint(root: &Path) -> Result<Fingerprint, DataError> {
    fingerprint_opened(&crate::dataset::open(root)?)
}

/// Fingerprints an opened dataset (MF, Freiburg Thermal or described layout; module docs).
/// Reads every file once, in parallel; a missing or unreadable file is an error naming it.
pub fn fingerprint_opened(dataset: &Dataset) -> Result<Fingerprint, DataError> {
    let root = dataset.root();
    let splits: Vec<(String, Vec<FrameFiles>)> = match dataset.layout() {
        Layout::Mf => mf_frames(root)?,
        Layout::Freiburg => freiburg_frames(root)?,
        Layout::Bdd => {
            return Err(DataError::Layout {
                root: root.to_path_buf(),
                message:
                    "fingerprints cover the MF, Freiburg Thermal and described layouts, not BDD"
                        .into(),
            })
        }
        Layout::Described(description) => described_frames(description)?,
    };
    digest(root, dataset.format(), &splits)
}

/// Hashes every distinct file of `splits` once (in parallel), then each split and the dataset.
fn digest(
    root: &Path,
    format: DatasetFormat,
    splits: &[(String, Vec<FrameFiles>)],
) -> Result<Fingerprint, DataError> {
    let distinct: Vec<&PathBuf> = {
        let mut seen = HashSet::new();
        splits
            .iter()
            .flat_map(|(_, frames)| frames.iter().flat_map(|f| &f.files))
            .filter(|p| seen.insert(*p))
            .collect()
    };
    let hashed: BTreeMap<&PathBuf, ([u8; 32], u64)> = distinct
        .par_iter()
        .map(|p| {
            let size = std::fs::metadata(p)
                .map_err(|e| DataError::io(*p, e))?
                .len();
            Ok((*p, (hash_file(p)?, size)))
        })
        .collect::<Result<_, DataError>>()?;
    let mut out = Vec::with_capacity(splits.len());
    for (name, frames) in splits {
        let mut h = Sha256::new();
        for frame in frames {
            h.update(frame.name.as_bytes());
            h.update(b"\n");
            for file in &frame.files {
                let rel = file.strip_prefix(root).unwrap_or(file);
                h.update(rel.to_string_lossy().as_bytes());
                h.update(b"\n");
                h.update(hashed[file].0);
            }
        }
        out.push(SplitFingerprint {
            name: name.clone(),
            frames: frames.len(),
            hash: hex(&h.finalize()),
        });
    }
    out.sort_by(|a, b| a.name.cmp(&b.name));
    let mut h = Sha256::new();
    for s in &out {
        h.update(s.name.as_bytes());
        h.update(b"\n");
        h.update(s.hash.as_bytes());
        h.update(b"\n");
    }
    Ok(Fingerprint {
        format,
        algorithm: ALGORITHM.into(),
        hash: hex(&h.finalize()),
        splits: out,
        files: hashed.len(),
        bytes: hashed.values().map(|v| v.1).sum(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{generate, SynthConfig, SynthFormat};

    fn synth(dir: &Path, format: SynthFormat, seed: u64) {
        generate(
            dir,
            &SynthConfig {
                count: 8,
                width: 64,
                height: 48,
                format,
                seed,
                ..SynthConfig::default()
            },
        )
        .unwrap();
    }

    #[test]
    fn sha256_of_known_bytes() {
        // FIPS 180-4 test vector "abc".
        assert_eq!(
            hex(&hash_bytes(b"abc")),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn mf_fingerprint_follows_content_not_location() {
        let tmp = tempfile::tempdir().unwrap();
        let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
        synth(&a, SynthFormat::Mf, 1);
        synth(&b, SynthFormat::Mf, 1);
        let fa = fingerprint(&a).unwrap();
        assert_eq!(fa, fingerprint(&b).unwrap(), "same content, other folder");
        assert_eq!(fa.algorithm, "sha256");
        assert_eq!(fa.hash.len(), 64);
        let names: Vec<&str> = fa.splits.iter().map(|s| s.name.as_str()).collect();
        assert!(
            names.contains(&"train") && names.contains(&"test"),
            "{names:?}"
        );
        assert_eq!(fa.files, 16, "8 images + 8 labels, each hashed once");

        // One byte of one test label: test (and the overall hash) change, train does not.
        let test_frame = std::fs::read_to_string(b.join("test.txt")).unwrap();
        let name = test_frame.lines().next().unwrap().trim();
        let label = b.join("labels").join(format!("{name}.png"));
        let mut bytes = std::fs::read(&label).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 1;
        std::fs::write(&label, bytes).unwrap();
        let fb = fingerprint(&b).unwrap();
        assert_ne!(fa.hash, fb.hash);
        assert_ne!(
            fa.split("test").unwrap().hash,
            fb.split("test").unwrap().hash
        );
        assert_eq!(
            fa.split("train").unwrap().hash,
            fb.split("train").unwrap().hash
        );

        // Reordering a split file changes that split.
        let train = std::fs::read_to_string(a.join("train.txt")).unwrap();
        let mut lines: Vec<&str> = train.lines().collect();
        lines.reverse();
        std::fs::write(a.join("train.txt"), lines.join("\n")).unwrap();
        let fr = fingerprint(&a).unwrap();
        assert_ne!(
            fa.split("train").unwrap().hash,
            fr.split("train").unwrap().hash
        );
    }

    #[test]
    fn freiburg_fingerprint_has_train_and_test() {
        let tmp = tempfile::tempdir().unwrap();
        synth(tmp.path(), SynthFormat::Freiburg, 2);
        let f = fingerprint(tmp.path()).unwrap();
        assert_eq!(f.format, DatasetFormat::Freiburg);
        let names: Vec<&str> = f.splits.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["test", "train", "val"]);
        assert_eq!(f.splits.iter().map(|s| s.frames).sum::<usize>(), 8);
    }

    #[test]
    fn missing_files_and_non_datasets_are_errors_naming_the_path() {
        let tmp = tempfile::tempdir().unwrap();
        let err = fingerprint(tmp.path()).unwrap_err().to_string();
        assert!(err.contains("not a dataset root"), "{err}");
        synth(tmp.path(), SynthFormat::Mf, 3);
        let name = std::fs::read_to_string(tmp.path().join("train.txt"))
            .unwrap()
            .lines()
            .next()
            .unwrap()
            .trim()
            .to_string();
        std::fs::remove_file(tmp.path().join("images").join(format!("{name}.png"))).unwrap();
        let err = fingerprint(tmp.path()).unwrap_err().to_string();
        assert!(err.contains(&name), "{err}");
    }
}
