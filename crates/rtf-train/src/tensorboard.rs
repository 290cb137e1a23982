//! TensorBoard event files for a run folder (`RUN/tb/`).
//!
//! The format is TensorFlow's: a TFRecord stream (length, masked CRC-32C of the length,
//! payload, masked CRC-32C of the payload) of `tensorflow.Event` protocol buffers, the first
//! one carrying `file_version = "brain.Event:2"` (TensorFlow `core/util/event.proto`,
//! `summary.proto`; TensorBoard's `EventFileWriter`). The framing and the protos come from the
//! `tboard` crate (by tch's author); this module only names the file and maps a training log
//! record to tags.
//!
//! Each process writes its own file (`events.out.tfevents.<secs>.<host>.<pid>.<n>`, created
//! with `create_new`, so nothing earlier is ever overwritten): a resumed run adds a file and
//! TensorBoard merges all files of the folder by step, as it does for PyTorch's
//! `SummaryWriter`.
//!
//! Tag scheme of [`record_scalars`] (one log line of `RUN/log.jsonl`, step = its `epoch`):
//!
//! | log field                          | tag                          |
//! |------------------------------------|------------------------------|
//! | `train_loss`                       | `loss/total`                 |
//! | `losses.NAME`                      | `loss/NAME`                  |
//! | `lr`                               | `lr/main`                    |
//! | `lrs.ROLE`                         | `lr/ROLE`                    |
//! | `images_per_s`, `data_wait_fraction`, `images`, `seconds` | `train/<field>` |
//! | `metrics.NAME` (e.g. `critic_acc_day`) | `train/NAME`             |
//! | `val_miou`, `val_macc`             | `val/miou`, `val/macc`       |
//! | `val.NAME` (number)                | `val/NAME`                   |
//! | `val.per_class_iou.CLASS`          | `val/iou/CLASS`              |
//! | `val.per_class_iou_day.CLASS`      | `val/iou_day/CLASS`          |
//! | `val.per_class_iou_night.CLASS`    | `val/iou_night/CLASS`        |
//! | any other number `KEY` / map `KEY.SUB` | `KEY` / `KEY/SUB`        |
//!
//! `null` values (an IoU of a class absent from the split) and non-numbers are skipped.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use serde_json::Value;
use tboard::tensorboard::event::What;
use tboard::tensorboard::{summary, Summary};
use tboard::EventWriter;

/// Subfolder of a run folder that holds the event files.
pub const TB_DIR: &str = "tb";

#[derive(Debug, thiserror::Error)]
pub enum TbError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: writing a TensorBoard event: {source}")]
    Event {
        path: PathBuf,
        source: tboard::Error,
    },
    #[error("{tag}: not a PNG image ({reason})")]
    NotPng { tag: String, reason: String },
    #[error("log record without a numeric `epoch` (the TensorBoard step): {0}")]
    NoEpoch(String),
}

/// Appends events to one new event file under `RUN/tb/`.
pub struct TbWriter {
    inner: EventWriter<BufWriter<File>>,
    path: PathBuf,
}

impl TbWriter {
    /// Creates `run_dir/tb/` if needed and a new event file in it (never an existing one).
    pub fn create(run_dir: &Path) -> Result<Self, TbError> {
        let dir = run_dir.join(TB_DIR);
        std::fs::create_dir_all(&dir).map_err(|source| TbError::Io {
            path: dir.clone(),
            source,
        })?;
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let secs = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        let host = hostname();
        let pid = std::process::id();
        let (path, file) = loop {
            let n = COUNTER.fetch_add(1, Ordering::Relaxed);
            let path = dir.join(format!("events.out.tfevents.{secs:010}.{host}.{pid}.{n}"));
            match File::options().write(true).create_new(true).open(&path) {
                Ok(file) => break (path, file),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(source) => return Err(TbError::Io { path, source }),
            }
        };
        let inner = EventWriter::from_writer(BufWriter::new(file), Some(path.clone())).map_err(
            |source| TbError::Event {
                path: path.clone(),
                source,
            },
        )?;
        Ok(Self { inner, path })
    }

    /// The event file this writer appends to.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn event_error(&self) -> impl FnOnce(tboard::Error) -> TbError + '_ {
        |source| TbError::Event {
            path: self.path.clone(),
            source,
        }
    }

    /// One scalar (stored as f32, TensorBoard's `simple_value`).
    pub fn scalar(&mut self, tag: &str, step: i64, value: f64) -> Result<(), TbError> {
        self.inner
            .write_scalar(step, tag, value as f32)
            .map_err(|source| TbError::Event {
                path: self.path.clone(),
                source,
            })
    }

    /// One image, already PNG-encoded (its size and colour type are read from the header).
    pub fn image_png(&mut self, tag: &str, step: i64, png: &[u8]) -> Result<(), TbError> {
        let (width, height, channels) = png_header(png).map_err(|reason| TbError::NotPng {
            tag: tag.to_string(),
            reason,
        })?;
        let value = summary::Value {
            node_name: String::new(),
            tag: tag.to_string(),
            metadata: None,
            value: Some(summary::value::Value::Image(summary::Image {
                width: width as i32,
                height: height as i32,
                colorspace: channels,
                encoded_image_string: png.to_vec(),
            })),
        };
        let what = What::Summary(Summary { value: vec![value] });
        let result = self.inner.write(step, what);
        result.map_err(self.event_error())
    }

    /// Every scalar of one log record (see the module docs for the tags), at step = `epoch`.
    /// Returns how many scalars were written.
    pub fn record(&mut self, record: &Value) -> Result<usize, TbError> {
        let step = record
            .get("epoch")
            .and_then(Value::as_i64)
            .ok_or_else(|| TbError::NoEpoch(record.to_string()))?;
        let scalars = record_scalars(record);
        for (tag, value) in &scalars {
            self.scalar(tag, step, *value)?;
        }
        Ok(scalars.len())
    }

    /// Writes buffered events to the file (call once per epoch; also done on drop).
    pub fn flush(&mut self) -> Result<(), TbError> {
        let result = self.inner.flush();
        result.map_err(self.event_error())
    }
}

impl Drop for TbWriter {
    fn drop(&mut self) {
        let _ = self.inner.flush();
    }
}

fn hostname() -> String {
    let name = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .unwrap_or_default();
    let clean: String = name
        .trim()
        .chars()
        .filter(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_'))
        .collect();
    if clean.is_empty() {
        "localhost".into()
    } else {
        clean
    }
}

/// (width, height, channels) of a PNG from its IHDR chunk.
fn png_header(png: &[u8]) -> Result<(u32, u32, i32), String> {
    const SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];
    if png.len() < 26 || png[..8] != SIGNATURE || &png[12..16] != b"IHDR" {
        return Err("no PNG signature and IHDR chunk".into());
    }
    let be = |i: usize| u32::from_be_bytes([png[i], png[i + 1], png[i + 2], png[i + 3]]);
    let channels = match png[25] {
        0 => 1,
        2 => 3,
        3 => 3,
        4 => 2,
        6 => 4,
        other => return Err(format!("unknown colour type {other}")),
    };
    Ok((be(16), be(20), channels))
}

/// The scalars of one log record by tag (see the module docs), `epoch` excluded.
pub fn record_scalars(record: &Value) -> BTreeMap<String, f64> {
    let mut out = BTreeMap::new();
    let Some(fields) = record.as_object() else {
        return out;
    };
    for (key, value) in fields {
        let prefix = match key.as_str() {
            "epoch" => continue,
            "train_loss" => "loss/total".to_string(),
            "lr" => "lr/main".to_string(),
            "images_per_s" | "data_wait_fraction" | "images" | "seconds" => {
                format!("train/{key}")
            }
            "val_miou" => "val/miou".to_string(),
            "val_macc" => "val/macc".to_string(),
            "losses" => "loss".to_string(),
            "lrs" => "lr".to_string(),
            "metrics" => "train".to_string(),
            other => other.to_string(),
        };
        flatten(&prefix, value, &mut out);
    }
    // The nested `val` map of the new log wins over the flat fields of the old one.
    if let Some(val) = fields.get("val") {
        for (k, tag) in [("miou", "val/miou"), ("macc", "val/macc")] {
            if let Some(v) = val.get(k).and_then(Value::as_f64) {
                out.insert(tag.to_string(), v);
            }
        }
    }
    out
}

fn flatten(prefix: &str, value: &Value, out: &mut BTreeMap<String, f64>) {
    match value {
        Value::Number(n) => {
            if let Some(v) = n.as_f64() {
                out.entry(prefix.to_string()).or_insert(v);
            }
        }
        Value::Object(map) => {
            for (k, v) in map {
                let sub = match (prefix, k.as_str()) {
                    ("val", "per_class_iou") => "iou",
                    ("val", "per_class_iou_day") => "iou_day",
                    ("val", "per_class_iou_night") => "iou_night",
                    (_, k) => k,
                };
                flatten(&format!("{prefix}/{sub}"), v, out);
            }
        }
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;
    use std::process::Command;

    fn old_record(epoch: i64) -> Value {
        json!({"epoch": epoch, "lr": 0.01 / epoch as f64, "train_loss": 1.5 / epoch as f64,
               "images": 64, "seconds": 3.25, "images_per_s": 19.7,
               "data_wait_fraction": 0.125, "val_miou": 0.25 + 0.01 * epoch as f64,
               "val_macc": 0.5})
    }

    fn new_record(epoch: i64) -> Value {
        json!({"epoch": epoch, "lr": 0.001, "train_loss": 0.75,
               "images": 64, "seconds": 2.0, "images_per_s": 32.0, "data_wait_fraction": 0.0625,
               "val_miou": 0.3,
               "losses": {"ce": 0.5, "critic": 0.25},
               "lrs": {"segmenter": 0.001, "critic": 0.0001},
               "metrics": {"critic_acc_day": 0.75, "critic_acc_night": 0.625},
               "val": {"miou": 0.375, "macc": 0.5, "miou_day": 0.4, "miou_night": 0.35,
                       "miou_heatnet": null,
                       "per_class_iou": {"car": 0.5, "person": null},
                       "per_class_iou_day": {"car": 0.625},
                       "per_class_iou_night": {"car": 0.375}}})
    }

    #[test]
    fn tags_follow_the_scheme() {
        let old = record_scalars(&old_record(2));
        assert_eq!(old["loss/total"], 0.75);
        assert_eq!(old["lr/main"], 0.005);
        assert_eq!(old["train/images_per_s"], 19.7);
        assert_eq!(old["train/data_wait_fraction"], 0.125);
        assert_eq!(old["val/miou"], 0.27);
        assert!(!old.contains_key("epoch"));
        assert_eq!(old.len(), 8);

        let new = record_scalars(&new_record(1));
        assert_eq!(new["loss/ce"], 0.5);
        assert_eq!(new["loss/critic"], 0.25);
        assert_eq!(new["lr/segmenter"], 0.001);
        assert_eq!(new["lr/critic"], 0.0001);
        assert_eq!(new["train/critic_acc_night"], 0.625);
        assert_eq!(new["val/miou"], 0.375, "nested val wins over val_miou");
        assert_eq!(new["val/miou_day"], 0.4);
        assert_eq!(new["val/iou/car"], 0.5);
        assert_eq!(new["val/iou_day/car"], 0.625);
        assert_eq!(new["val/iou_night/car"], 0.375);
        assert!(!new.contains_key("val/iou/person"), "null IoU skipped");
        assert!(!new.contains_key("val/miou_heatnet"));
    }

    #[test]
    fn png_header_is_read_and_garbage_rejected() {
        let mut png = Vec::new();
        image::RgbImage::new(5, 3)
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        assert_eq!(png_header(&png), Ok((5, 3, 3)));
        assert!(png_header(b"not a png at all, really not").is_err());
    }

    #[test]
    fn record_without_epoch_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = TbWriter::create(dir.path()).unwrap();
        let err = w.record(&json!({"lr": 0.1})).unwrap_err();
        assert!(err.to_string().contains("epoch"), "{err}");
    }

    /// The folder as TensorBoard's own reader sees it (`scripts/tb_read.py` in the .venv).
    fn read_back(tb: &Path) -> Value {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let python = root.join(".venv/bin/python");
        let output = Command::new(&python)
            .arg(root.join("scripts/tb_read.py"))
            .arg(tb)
            .output()
            .unwrap_or_else(|e| panic!("{}: {e}; run `cargo xtask setup`", python.display()));
        assert!(
            output.status.success(),
            "TensorBoard's reader failed (is `tensorboard` in .venv? `cargo xtask setup` \
             installs it): {}",
            String::from_utf8_lossy(&output.stderr)
        );
        serde_json::from_slice(&output.stdout).unwrap()
    }

    /// Writes an old-schema and a new-schema run across two writers (a resume), then reads
    /// the folder back with TensorBoard's own event reader and compares every tag and value.
    #[test]
    fn tensorboard_reads_back_every_scalar_and_image() {
        let dir = tempfile::tempdir().unwrap();
        let records = [old_record(1), old_record(2), new_record(3)];
        let mut png = Vec::new();
        image::RgbImage::from_pixel(6, 4, image::Rgb([10, 200, 30]))
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        {
            let mut first = TbWriter::create(dir.path()).unwrap();
            for r in &records[..2] {
                first.record(r).unwrap();
            }
            first.image_png("val/predictions", 2, &png).unwrap();
            first.flush().unwrap();
        }
        let mut resumed = TbWriter::create(dir.path()).unwrap();
        resumed.record(&records[2]).unwrap();
        resumed.flush().unwrap();
        let files = std::fs::read_dir(dir.path().join(TB_DIR)).unwrap().count();
        assert_eq!(files, 2, "one event file per writer");

        let read = read_back(&dir.path().join(TB_DIR));

        let mut expected: BTreeMap<String, Vec<(i64, f64)>> = BTreeMap::new();
        for r in &records {
            let step = r["epoch"].as_i64().unwrap();
            for (tag, v) in record_scalars(r) {
                expected.entry(tag).or_default().push((step, v));
            }
        }
        let scalars = read["scalars"].as_object().unwrap();
        let got_tags: Vec<&String> = scalars.keys().collect();
        let want_tags: Vec<&String> = expected.keys().collect();
        assert_eq!(got_tags, want_tags);
        for (tag, points) in &expected {
            let got = scalars[tag].as_array().unwrap();
            assert_eq!(got.len(), points.len(), "{tag}");
            for ((step, v), g) in points.iter().zip(got) {
                assert_eq!(g[0].as_i64().unwrap(), *step, "{tag}");
                let gv = g[1].as_f64().unwrap();
                assert!(
                    (gv - v).abs() <= 1e-6 * v.abs().max(1.0),
                    "{tag}@{step}: {gv} vs {v}"
                );
            }
        }
        let images = &read["images"]["val/predictions"];
        assert_eq!(images, &json!([[2, 6, 4, png.len()]]));
    }
}
