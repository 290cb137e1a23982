//! The MF dataset (MFNet; spec §1): `images/<name>.png` RGBA 8-bit with thermal in alpha,
//! `labels/<name>.png` 8-bit class ids, split files `<split>.txt` in the root.

use crate::frame::check_label_ids;
use crate::pngio::{decode_u8, Samples};
use crate::{DataError, Frame, FrameSource};
use rtf_core::{ClassSet, Daytime};
use std::path::{Path, PathBuf};

/// An MF-layout dataset root.
#[derive(Debug, Clone)]
pub struct MfDataset {
    root: PathBuf,
    splits: Vec<String>,
    class_set: ClassSet,
}

impl MfDataset {
    /// Opens a root: `images/`, `labels/` and at least one `<split>.txt` must exist.
    pub fn open(root: impl AsRef<Path>) -> Result<Self, DataError> {
        let root = root.as_ref().to_path_buf();
        let layout = |message: String| DataError::Layout {
            root: root.clone(),
            message,
        };
        if !root.is_dir() {
            return Err(layout("not a directory".into()));
        }
        for sub in ["images", "labels"] {
            if !root.join(sub).is_dir() {
                return Err(layout(format!(
                    "missing '{sub}/' directory (MF layout: images/, labels/, <split>.txt)"
                )));
            }
        }
        let mut splits = Vec::new();
        for entry in std::fs::read_dir(&root).map_err(|e| DataError::io(&root, e))? {
            let path = entry.map_err(|e| DataError::io(&root, e))?.path();
            if path.is_file() && path.extension().is_some_and(|e| e == "txt") {
                if let Some(stem) = path.file_stem().and_then(|s| s.to_str()) {
                    splits.push(stem.to_string());
                }
            }
        }
        if splits.is_empty() {
            return Err(layout(
                "no split files (<split>.txt, e.g. train.txt) — empty dataset".into(),
            ));
        }
        splits.sort();
        Ok(Self {
            root,
            splits,
            class_set: ClassSet::mf(),
        })
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Names of the split files found, sorted (`test`, `test_day`, `train`, …).
    pub fn split_names(&self) -> &[String] {
        &self.splits
    }

    pub fn class_set(&self) -> &ClassSet {
        &self.class_set
    }

    pub fn image_path(&self, name: &str) -> PathBuf {
        self.root.join("images").join(format!("{name}.png"))
    }

    pub fn label_path(&self, name: &str) -> PathBuf {
        self.root.join("labels").join(format!("{name}.png"))
    }

    /// Reads `<name>.txt`; every listed frame must have its image and label.
    pub fn split(&self, name: &str) -> Result<MfSplit, DataError> {
        self.split_with(name, true)
    }

    /// Like [`Self::split`], but only images must exist (label-free training: night labels
    /// may be absent and are never opened).
    pub fn split_images_only(&self, name: &str) -> Result<MfSplit, DataError> {
        self.split_with(name, false)
    }

    fn split_with(&self, name: &str, labels: bool) -> Result<MfSplit, DataError> {
        if !self.splits.iter().any(|s| s == name) {
            return Err(DataError::UnknownSplit {
                root: self.root.clone(),
                name: name.to_string(),
                available: self.splits.join(", "),
            });
        }
        let file = self.root.join(format!("{name}.txt"));
        let names = read_split_file(&file)?;
        for (line, frame) in &names {
            let label = labels.then(|| self.label_path(frame));
            for path in std::iter::once(self.image_path(frame)).chain(label) {
                if !path.is_file() {
                    return Err(DataError::MissingFrame {
                        split_file: file.clone(),
                        line: *line,
                        name: frame.clone(),
                        missing: path,
                    });
                }
            }
        }
        let names: Vec<String> = names.into_iter().map(|(_, n)| n).collect();
        let daytimes = names.iter().map(|n| Daytime::from_mf_name(n)).collect();
        Ok(MfSplit {
            dataset: self.clone(),
            split: name.to_string(),
            names,
            daytimes,
        })
    }

    /// The training split (images only unless `labels`) and the validation split, if named.
    pub fn training_splits(
        &self,
        train: &str,
        val: Option<&str>,
        labels: bool,
    ) -> Result<(MfSplit, Option<MfSplit>), DataError> {
        let train = self.split_with(train, labels)?;
        let val = val.map(|name| self.split(name)).transpose()?;
        Ok((train, val))
    }

    /// Decodes one frame's image alone (its label file is not opened).
    pub fn load_image_frame(&self, name: &str) -> Result<Frame, DataError> {
        let mut frame = read_mf_image(&self.image_path(name))?;
        frame.name = name.to_string();
        Ok(frame)
    }

    /// Decodes one frame by name (image + label), with every check of spec §1.
    pub fn load_frame(&self, name: &str) -> Result<Frame, DataError> {
        let image_path = self.image_path(name);
        let label_path = self.label_path(name);
        let image_bytes = std::fs::read(&image_path).map_err(|e| DataError::io(&image_path, e))?;
        let label_bytes = std::fs::read(&label_path).map_err(|e| DataError::io(&label_path, e))?;
        decode_mf_frame(
            name,
            &image_bytes,
            &image_path,
            &label_bytes,
            &label_path,
            &self.class_set,
        )
    }
}

/// Decodes an MF image (8-bit RGBA, thermal in alpha) into (width, height, interleaved RGB,
/// thermal / 255). Errors name `path` and what is wrong (channels, bit depth, corruption).
pub fn decode_mf_image(
    bytes: &[u8],
    path: &Path,
) -> Result<(usize, usize, Vec<u8>, Vec<f32>), DataError> {
    // Fast path for the common case; anything unusual goes through the checked general path.
    if let Some(decoded) = crate::pngio::decode_rgba8_split(bytes, path) {
        return decoded;
    }
    let image = decode_u8(bytes, path, 4, "RGBA image, thermal in alpha")?;
    let Samples::U8(rgba) = image.samples else {
        unreachable!("decode_u8 checked 8-bit samples")
    };
    let rgb = rgba
        .chunks_exact(4)
        .flat_map(|px| [px[0], px[1], px[2]])
        .collect();
    let thermal = rgba
        .chunks_exact(4)
        .map(|px| px[3] as f32 / 255.0)
        .collect();
    Ok((image.width, image.height, rgb, thermal))
}

/// Reads one MF-style RGBA image (no label) as an unlabelled frame named after the file stem.
pub fn read_mf_image(path: &Path) -> Result<Frame, DataError> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    let (width, height, rgb, thermal) = decode_mf_image(&bytes, path)?;
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok(Frame {
        daytime: Daytime::from_mf_name(&name),
        name,
        width,
        height,
        rgb,
        thermal,
        label: None,
    })
}

/// Decodes an MF image/label pair from bytes (the fuzzed entry point).
pub fn decode_mf_frame(
    name: &str,
    image_bytes: &[u8],
    image_path: &Path,
    label_bytes: &[u8],
    label_path: &Path,
    classes: &ClassSet,
) -> Result<Frame, DataError> {
    let (width, height, rgb, thermal) = decode_mf_image(image_bytes, image_path)?;
    let label = decode_u8(label_bytes, label_path, 1, "label of class ids")?;
    if (label.width, label.height) != (width, height) {
        return Err(DataError::SizeMismatch {
            image: image_path.to_path_buf(),
            label: label_path.to_path_buf(),
            image_w: width,
            image_h: height,
            label_w: label.width,
            label_h: label.height,
        });
    }
    let Samples::U8(ids) = label.samples else {
        unreachable!("decode_u8 checked 8-bit samples")
    };
    check_label_ids(&ids, label.width, classes, label_path)?;
    Ok(Frame {
        name: name.to_string(),
        daytime: Daytime::from_mf_name(name),
        width,
        height,
        rgb,
        thermal,
        label: Some(ids),
    })
}

/// Parses a split file: one frame name per line (no extension); blank lines are skipped.
/// Returns (1-based line number, name).
pub fn read_split_file(path: &Path) -> Result<Vec<(usize, String)>, DataError> {
    let text = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    let text = String::from_utf8(text).map_err(|_| DataError::Format {
        path: path.to_path_buf(),
        message: "split file is not UTF-8 text".into(),
    })?;
    let names = parse_split(&text, path)?;
    if names.is_empty() {
        return Err(DataError::EmptySplit {
            path: path.to_path_buf(),
        });
    }
    Ok(names)
}

pub(crate) fn parse_split(text: &str, path: &Path) -> Result<Vec<(usize, String)>, DataError> {
    let mut names = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let name = line.trim();
        if name.is_empty() {
            continue;
        }
        if name.contains('/')
            || name.contains('\\')
            || name == "."
            || name == ".."
            || name.contains('\0')
        {
            return Err(DataError::Format {
                path: path.to_path_buf(),
                message: format!("line {}: '{name}' is not a frame name", i + 1),
            });
        }
        names.push((i + 1, name.to_string()));
    }
    Ok(names)
}

/// One split of an MF dataset.
#[derive(Debug, Clone)]
pub struct MfSplit {
    dataset: MfDataset,
    split: String,
    names: Vec<String>,
    daytimes: Vec<Option<Daytime>>,
}

impl MfSplit {
    pub fn name(&self) -> &str {
        &self.split
    }
    pub fn names(&self) -> &[String] {
        &self.names
    }
    pub fn dataset(&self) -> &MfDataset {
        &self.dataset
    }
}

impl FrameSource for MfSplit {
    fn len(&self) -> usize {
        self.names.len()
    }
    fn frame_name(&self, index: usize) -> &str {
        &self.names[index]
    }
    fn daytime(&self, index: usize) -> Option<Daytime> {
        self.daytimes[index]
    }
    fn class_set(&self) -> &ClassSet {
        &self.dataset.class_set
    }
    fn load(&self, index: usize) -> Result<Frame, DataError> {
        let name = self.names.get(index).ok_or_else(|| DataError::Frame {
            name: format!("#{index}"),
            message: format!(
                "index out of range in split '{}' ({} frames)",
                self.split,
                self.names.len()
            ),
        })?;
        self.dataset.load_frame(name)
    }
    fn load_unlabelled(&self, index: usize) -> Result<Frame, DataError> {
        let name = self.names.get(index).ok_or_else(|| DataError::Frame {
            name: format!("#{index}"),
            message: format!("index out of range in split '{}'", self.split),
        })?;
        self.dataset.load_image_frame(name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;

    fn fixture() -> (tempfile::TempDir, MfDataset) {
        let dir = tempfile::tempdir().unwrap();
        mf_dataset(dir.path(), &["00001D", "00002N", "00003D"], 8, 6);
        let ds = MfDataset::open(dir.path()).unwrap();
        (dir, ds)
    }

    fn load_err(ds: &MfDataset, name: &str) -> String {
        ds.load_frame(name).unwrap_err().to_string()
    }

    #[test]
    fn reads_frames_daytime_and_thermal_from_alpha() {
        let (_dir, ds) = fixture();
        assert_eq!(ds.split_names(), ["train"]);
        let split = ds.split("train").unwrap();
        assert_eq!(split.len(), 3);
        assert_eq!(split.daytime(0), Some(Daytime::Day));
        assert_eq!(split.daytime(1), Some(Daytime::Night));
        let f = split.load(1).unwrap();
        assert_eq!((f.width, f.height, f.name.as_str()), (8, 6, "00002N"));
        let rgba = rgba(8, 6, 1);
        assert_eq!(&f.rgb[..3], &rgba[..3]);
        assert_eq!(f.thermal[0], rgba[3] as f32 / 255.0);
        assert_eq!(f.label.unwrap(), ids(8, 6, 9));
    }

    #[test]
    fn any_split_file_name_is_a_split() {
        let (dir, ds) = fixture();
        write(&dir.path().join("my_subset.txt"), b"00003D\n\n00001D\n");
        let ds2 = MfDataset::open(dir.path()).unwrap();
        assert_eq!(
            ds2.split("my_subset").unwrap().names(),
            ["00003D", "00001D"]
        );
        let err = ds.split("nope").unwrap_err().to_string();
        assert!(
            err.contains("no split 'nope'") && err.contains("train"),
            "{err}"
        );
    }

    #[test]
    fn missing_and_truncated_png_name_the_file() {
        let (dir, ds) = fixture();
        let img = ds.image_path("00001D");
        let bytes = std::fs::read(&img).unwrap();
        std::fs::write(&img, &bytes[..bytes.len() / 2]).unwrap();
        let err = load_err(&ds, "00001D");
        assert!(
            err.contains("00001D.png") && err.contains("not a readable PNG"),
            "{err}"
        );
        std::fs::remove_file(dir.path().join("labels/00002N.png")).unwrap();
        let err = load_err(&ds, "00002N");
        assert!(err.contains("labels/00002N.png"), "{err}");
    }

    #[test]
    fn three_channel_image_is_refused() {
        let (dir, ds) = fixture();
        write(
            &dir.path().join("images/00001D.png"),
            &png_u8(8, 6, 3, &[7; 8 * 6 * 3]),
        );
        let err = load_err(&ds, "00001D");
        assert!(
            err.contains("images/00001D.png")
                && err.contains("expected 4 channel")
                && err.contains("found 3"),
            "{err}"
        );
    }

    #[test]
    fn sixteen_bit_label_is_refused() {
        let (dir, ds) = fixture();
        write(
            &dir.path().join("labels/00001D.png"),
            &png_u16(8, 6, 1, &[1; 48]),
        );
        let err = load_err(&ds, "00001D");
        assert!(
            err.contains("labels/00001D.png")
                && err.contains("expected 8-bit")
                && err.contains("16-bit"),
            "{err}"
        );
    }

    #[test]
    fn rgb_label_is_refused() {
        let (dir, ds) = fixture();
        write(
            &dir.path().join("labels/00001D.png"),
            &png_u8(8, 6, 3, &[1; 144]),
        );
        let err = load_err(&ds, "00001D");
        assert!(
            err.contains("labels/00001D.png") && err.contains("expected 1 channel"),
            "{err}"
        );
    }

    #[test]
    fn size_mismatch_is_refused() {
        let (dir, ds) = fixture();
        write(
            &dir.path().join("labels/00001D.png"),
            &png_u8(8, 5, 1, &[1; 40]),
        );
        let err = load_err(&ds, "00001D");
        assert!(
            err.contains("labels/00001D.png") && err.contains("8x5") && err.contains("8x6"),
            "{err}"
        );
    }

    #[test]
    fn label_id_out_of_range_is_refused() {
        let (dir, ds) = fixture();
        let mut l = ids(8, 6, 9);
        l[8 * 2 + 5] = 9;
        write(&dir.path().join("labels/00001D.png"), &png_u8(8, 6, 1, &l));
        let err = load_err(&ds, "00001D");
        assert!(
            err.contains("label id 9 at (x 5, y 2)") && err.contains("9 classes"),
            "{err}"
        );
    }

    #[test]
    fn split_naming_a_missing_frame_is_refused() {
        let (dir, ds) = fixture();
        write(&dir.path().join("train.txt"), b"00001D\n00009N\n");
        let err = ds.split("train").unwrap_err().to_string();
        assert!(
            err.contains("train.txt, line 2")
                && err.contains("'00009N'")
                && err.contains("images/00009N.png"),
            "{err}"
        );
    }

    #[test]
    fn empty_split_and_empty_dataset_are_refused() {
        let (dir, ds) = fixture();
        write(&dir.path().join("train.txt"), b"\n  \n");
        let err = ds.split("train").unwrap_err().to_string();
        assert!(err.contains("train.txt") && err.contains("empty"), "{err}");
        let empty = tempfile::tempdir().unwrap();
        let err = MfDataset::open(empty.path()).unwrap_err().to_string();
        assert!(err.contains("missing 'images/'"), "{err}");
        std::fs::create_dir_all(empty.path().join("images")).unwrap();
        std::fs::create_dir_all(empty.path().join("labels")).unwrap();
        let err = MfDataset::open(empty.path()).unwrap_err().to_string();
        assert!(err.contains("no split files"), "{err}");
    }

    #[test]
    fn split_lines_with_paths_are_refused() {
        let (dir, ds) = fixture();
        write(&dir.path().join("train.txt"), b"../etc/passwd\n");
        let err = ds.split("train").unwrap_err().to_string();
        assert!(
            err.contains("line 1") && err.contains("not a frame name"),
            "{err}"
        );
    }
}
