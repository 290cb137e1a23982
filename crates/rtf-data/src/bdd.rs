//! BDD100K night images, RGB only (HeatNet Tab. I), as HeatNet's evaluation reads them:
//! `<root>/<list>.txt` (reference: `bdd_night.txt`, one name per line),
//! `<root>/images/<split>/<name>.jpg` (or `.png`) and
//! `<root>/labels/<split>/<name>_train_id.png` (Cityscapes train ids 0–18, 255 = ignore).
//! Labels are mapped to the Freiburg classes with the reference table; thermal is absent (0).

use crate::augment::{resample, resample_nearest, Filter, Planar, Window};
use crate::mf::read_split_file;
use crate::pngio::{decode_u8, Samples};
use crate::{DataError, Frame, FrameSource};
use rtf_core::{ClassSet, Daytime};
use std::path::{Path, PathBuf};

/// BDD (Cityscapes train id) → Freiburg id, as in the HeatNet evaluation code: wall →
/// building, traffic light/sign → pole/sign, rider → person, truck/bus/train → car,
/// motorcycle → bicycle, 255 → ignore (13); anything else → background (12).
pub fn bdd_to_freiburg(id: u8) -> u8 {
    match id {
        0 => 0,
        1 => 1,
        2 | 3 => 2,
        4 => 4,
        5..=7 => 5,
        8 => 6,
        9 => 7,
        10 => 8,
        11 | 12 => 9,
        13..=16 => 10,
        17 | 18 => 11,
        255 => 13,
        _ => 12,
    }
}

#[derive(Debug, Clone)]
pub struct BddSplit {
    root: PathBuf,
    split: String,
    names: Vec<String>,
    /// (width, height) images are resized to (reference: 704×320); None = native.
    resize: Option<(usize, usize)>,
    class_set: ClassSet,
}

impl BddSplit {
    /// Opens `<root>/<list>.txt` over `images/<split>/` and `labels/<split>/`; every listed
    /// frame must have its image and label.
    pub fn open(
        root: impl AsRef<Path>,
        list: &str,
        split: &str,
        resize: Option<(usize, usize)>,
    ) -> Result<Self, DataError> {
        let root = root.as_ref().to_path_buf();
        let file = root.join(format!("{list}.txt"));
        let names = read_split_file(&file)?;
        let this = Self {
            root,
            split: split.to_string(),
            names: Vec::new(),
            resize,
            class_set: ClassSet::freiburg(),
        };
        for (line, name) in &names {
            let missing = if this.image_path(name).is_none() {
                Some(
                    this.root
                        .join("images")
                        .join(split)
                        .join(format!("{name}.jpg")),
                )
            } else if !this.label_path(name).is_file() {
                Some(this.label_path(name))
            } else {
                None
            };
            if let Some(missing) = missing {
                return Err(DataError::MissingFrame {
                    split_file: file,
                    line: *line,
                    name: name.clone(),
                    missing,
                });
            }
        }
        Ok(Self {
            names: names.into_iter().map(|(_, n)| n).collect(),
            ..this
        })
    }

    /// The listed frames that have both files, and a `MissingFrame` error for each that does
    /// not (for `rtf data check`); native size.
    pub fn scan(
        root: &Path,
        split: &str,
        names: Vec<(usize, String)>,
        list_file: &Path,
    ) -> (Self, Vec<DataError>) {
        let mut this = Self {
            root: root.to_path_buf(),
            split: split.to_string(),
            names: Vec::new(),
            resize: None,
            class_set: ClassSet::freiburg(),
        };
        let mut problems = Vec::new();
        for (line, name) in names {
            let missing = if this.image_path(&name).is_none() {
                Some(
                    this.root
                        .join("images")
                        .join(split)
                        .join(format!("{name}.jpg")),
                )
            } else if !this.label_path(&name).is_file() {
                Some(this.label_path(&name))
            } else {
                None
            };
            match missing {
                Some(missing) => problems.push(DataError::MissingFrame {
                    split_file: list_file.to_path_buf(),
                    line,
                    name,
                    missing,
                }),
                None => this.names.push(name),
            }
        }
        (this, problems)
    }

    fn image_path(&self, name: &str) -> Option<PathBuf> {
        let dir = self.root.join("images").join(&self.split);
        ["jpg", "jpeg", "png"]
            .iter()
            .map(|e| dir.join(format!("{name}.{e}")))
            .find(|p| p.is_file())
    }

    fn label_path(&self, name: &str) -> PathBuf {
        self.root
            .join("labels")
            .join(&self.split)
            .join(format!("{name}_train_id.png"))
    }
}

/// Decodes an 8-bit RGB JPEG or PNG into interleaved RGB bytes.
pub fn decode_rgb(bytes: &[u8], path: &Path) -> Result<(usize, usize, Vec<u8>), DataError> {
    if bytes.starts_with(b"\x89PNG") {
        let img = decode_u8(bytes, path, 3, "RGB image")?;
        let Samples::U8(data) = img.samples else {
            unreachable!("8-bit checked")
        };
        return Ok((img.width, img.height, data));
    }
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes));
    reader.set_format(image::ImageFormat::Jpeg);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(crate::pngio::MAX_DECODED_BYTES as u64);
    reader.limits(limits);
    let img = reader.decode().map_err(|e| DataError::Png {
        path: path.to_path_buf(),
        message: format!("not a readable JPEG: {e}"),
    })?;
    let rgb = img.to_rgb8();
    Ok((rgb.width() as usize, rgb.height() as usize, rgb.into_raw()))
}

impl FrameSource for BddSplit {
    fn len(&self) -> usize {
        self.names.len()
    }
    fn frame_name(&self, index: usize) -> &str {
        &self.names[index]
    }
    fn daytime(&self, _index: usize) -> Option<Daytime> {
        Some(Daytime::Night)
    }
    fn class_set(&self) -> &ClassSet {
        &self.class_set
    }
    fn load(&self, index: usize) -> Result<Frame, DataError> {
        let name = self.names.get(index).ok_or_else(|| DataError::Frame {
            name: format!("#{index}"),
            message: "index out of range".into(),
        })?;
        let image_path = self.image_path(name).unwrap_or_else(|| {
            self.root
                .join("images")
                .join(&self.split)
                .join(format!("{name}.jpg"))
        });
        let label_path = self.label_path(name);
        let image_bytes = std::fs::read(&image_path).map_err(|e| DataError::io(&image_path, e))?;
        let label_bytes = std::fs::read(&label_path).map_err(|e| DataError::io(&label_path, e))?;
        let (w, h, rgb) = decode_rgb(&image_bytes, &image_path)?;
        let label = decode_u8(&label_bytes, &label_path, 1, "label of train ids")?;
        if (label.width, label.height) != (w, h) {
            return Err(DataError::SizeMismatch {
                image: image_path,
                label: label_path,
                image_w: w,
                image_h: h,
                label_w: label.width,
                label_h: label.height,
            });
        }
        let Samples::U8(ids) = label.samples else {
            unreachable!("8-bit checked")
        };
        let ids: Vec<u8> = ids.into_iter().map(bdd_to_freiburg).collect();
        let mut frame = Frame {
            name: name.clone(),
            daytime: Some(Daytime::Night),
            width: w,
            height: h,
            rgb,
            thermal: vec![0.0; w * h],
            label: Some(ids),
        };
        if let Some((rw, rh)) = self.resize.filter(|&s| s != (w, h)) {
            let n = w * h;
            let mut data = vec![0.0f32; 3 * n];
            for (i, px) in frame.rgb.chunks_exact(3).enumerate() {
                for c in 0..3 {
                    data[c * n + i] = px[c] as f32;
                }
            }
            let out = resample(
                &Planar {
                    channels: 3,
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
            frame.rgb = (0..m)
                .flat_map(|i| (0..3).map(move |c| (i, c)))
                .map(|(i, c)| out.data[c * m + i].round().clamp(0.0, 255.0) as u8)
                .collect();
            frame.label = frame
                .label
                .map(|l| resample_nearest(&l, w, h, Window::full(w, h), rw, rh));
            frame.thermal = vec![0.0; m];
            (frame.width, frame.height) = (rw, rh);
        }
        Ok(frame)
    }
}

/// The list files (`*.txt`) of a BDD root, by stem, sorted (one split each).
pub fn lists(root: &Path) -> Vec<String> {
    let mut out: Vec<String> = std::fs::read_dir(root)
        .map(|rd| {
            rd.flatten()
                .map(|e| e.path())
                .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == "txt"))
                .filter_map(|p| p.file_stem().map(|n| n.to_string_lossy().into_owned()))
                .collect()
        })
        .unwrap_or_default();
    out.sort();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;

    #[test]
    fn reads_jpeg_night_frames_and_maps_labels_to_freiburg() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        let (w, h) = (16, 8);
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new(&mut jpeg)
            .encode(
                &vec![90u8; 3 * w * h],
                w as u32,
                h as u32,
                image::ExtendedColorType::Rgb8,
            )
            .unwrap();
        write(&root.join("images/val/a1.jpg"), &jpeg);
        let ids: Vec<u8> = (0..w * h).map(|i| [0, 3, 12, 14, 18, 255][i % 6]).collect();
        write(
            &root.join("labels/val/a1_train_id.png"),
            &png_u8(w, h, 1, &ids),
        );
        write(&root.join("bdd_night.txt"), b"a1\n");
        let split = BddSplit::open(root, "bdd_night", "val", Some((8, 4))).unwrap();
        assert_eq!(split.daytime(0), Some(Daytime::Night));
        let f = split.load(0).unwrap();
        assert_eq!((f.width, f.height), (8, 4));
        assert!(
            f.rgb.iter().all(|&v| (85..=95).contains(&v)),
            "JPEG grey decoded"
        );
        let native = BddSplit::open(root, "bdd_night", "val", None)
            .unwrap()
            .load(0)
            .unwrap();
        assert_eq!(&native.label.unwrap()[..6], &[0, 2, 9, 10, 11, 13]);
        write(&root.join("bdd_night.txt"), b"a1\nb2\n");
        let err = BddSplit::open(root, "bdd_night", "val", None)
            .unwrap_err()
            .to_string();
        assert!(err.contains("line 2") && err.contains("b2"), "{err}");
        write(&root.join("images/val/a1.jpg"), &jpeg[..jpeg.len() / 3]);
        write(&root.join("bdd_night.txt"), b"a1\n");
        let err = BddSplit::open(root, "bdd_night", "val", None)
            .unwrap()
            .load(0)
            .unwrap_err()
            .to_string();
        assert!(err.contains("a1.jpg"), "{err}");
    }
}
