//! Teacher labels written once (HeatNet eq. 1 without a teacher forward per step): each frame
//! of a stream is labelled by the frozen teacher at its own size, without augmentation, into
//! `RUN/labels/<stream>/<index>.png` (8-bit ids, the class set's ignore id below the confidence
//! threshold); the stream then yields its frames with these labels, which the loader augments
//! together with the image. An interrupted cache resumes where it stopped (each label file is
//! written atomically); hard labels only (soft targets need the teacher's softmax).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rtf_core::{ClassSet, Daytime};
use rtf_data::pngio::{write_png_u8, Samples};
use rtf_data::{DataError, Frame, FrameSource, Loader, LoaderConfig};
use tch::{Device, Kind};

use crate::error::TrainError;
use crate::procedure::Frozen;

/// Labels every frame of `source` with `teacher` into `dir` (frames already there are skipped).
pub fn write(
    teacher: &Frozen,
    source: Arc<dyn FrameSource>,
    dir: &Path,
    threshold: Option<f64>,
    input: rtf_core::InputConvention,
    device: Device,
) -> Result<(), TrainError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| crate::run::run_error(dir, format!("cannot create: {e}")))?;
    let ignore = source.class_set().ignore_id.ok_or_else(|| {
        TrainError::Config("a label cache needs a class set with an ignore id".into())
    })?;
    let loader = Loader::new(
        source.clone(),
        LoaderConfig {
            batch_size: 1,
            shuffle: false,
            workers: 1,
            ..LoaderConfig::default()
        },
        input,
    );
    let todo: Vec<usize> = (0..source.len())
        .filter(|&i| !path_of(dir, i).is_file())
        .collect();
    if todo.is_empty() {
        return Ok(());
    }
    eprintln!("labelling {} frames into {}", todo.len(), dir.display());
    for (index, batch) in loader.epoch(0).enumerate() {
        if !todo.contains(&index) {
            continue;
        }
        let batch = batch?;
        let targets = teacher.targets(&batch.input.to_device(device), threshold);
        let ids = targets.ids.get(0).to_device(Device::Cpu);
        let (h, w) = (ids.size()[0] as usize, ids.size()[1] as usize);
        let ids = ids
            .masked_fill(&ids.lt(0), ignore as i64)
            .to_kind(Kind::Uint8);
        let bytes = Vec::<u8>::try_from(ids.flatten(0, -1))
            .map_err(|e| TrainError::Config(format!("teacher labels of frame {index}: {e}")))?;
        write_png_u8(&path_of(dir, index), w, h, 1, &bytes)?;
    }
    Ok(())
}

fn path_of(dir: &Path, index: usize) -> PathBuf {
    dir.join(format!("{index:06}.png"))
}

/// The frames of `inner` (loaded without their own labels) with the cached teacher labels.
pub struct CachedLabels {
    inner: Arc<dyn FrameSource>,
    dir: PathBuf,
}

impl CachedLabels {
    pub fn new(inner: Arc<dyn FrameSource>, dir: PathBuf) -> Self {
        Self { inner, dir }
    }
}

impl FrameSource for CachedLabels {
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
        self.inner.class_set()
    }
    fn load(&self, index: usize) -> Result<Frame, DataError> {
        let mut frame = self.inner.load_unlabelled(index)?;
        let path = path_of(&self.dir, index);
        let png = rtf_data::pngio::read_png(&path)?;
        if png.channels != 1 || png.bit_depth() != 8 {
            return Err(DataError::Format {
                path,
                message: "not an 8-bit single-channel label (delete the labels folder to relabel)"
                    .into(),
            });
        }
        if (png.width, png.height) != (frame.width, frame.height) {
            return Err(DataError::Format {
                path,
                message: format!(
                    "cached label is {}×{}, the frame {}×{} (delete the labels folder to relabel)",
                    png.width, png.height, frame.width, frame.height
                ),
            });
        }
        let Samples::U8(ids) = png.samples else {
            unreachable!("decode_u8 checked 8-bit samples")
        };
        frame.label = Some(ids);
        Ok(frame)
    }
}
