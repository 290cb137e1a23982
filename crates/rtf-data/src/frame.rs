//! One RGB-thermal frame as decoded from a dataset, and the trait every dataset split implements.

use std::sync::Arc;

use crate::DataError;
use rtf_core::{ClassSet, Daytime};

/// A decoded frame, before augmentation. All planes are row-major, `width * height` pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub name: String,
    pub daytime: Option<Daytime>,
    pub width: usize,
    pub height: usize,
    /// Interleaved R, G, B bytes (`3 * width * height`).
    pub rgb: Vec<u8>,
    /// Thermal in [0, 1] after the dataset's own scaling (MF: byte / 255; Freiburg: clipped
    /// counts), one value per pixel.
    pub thermal: Vec<f32>,
    /// Class ids, one per pixel; `None` for unlabelled frames (Freiburg night training frames).
    pub label: Option<Vec<u8>>,
}

impl Frame {
    /// Checks that the planes have the sizes the header claims.
    pub fn validate(&self) -> Result<(), DataError> {
        let n = self.width * self.height;
        let bad = |message: String| {
            Err(DataError::Frame {
                name: self.name.clone(),
                message,
            })
        };
        if n == 0 {
            return bad(format!("empty frame {}x{}", self.width, self.height));
        }
        if self.rgb.len() != 3 * n {
            return bad(format!(
                "rgb has {} bytes, expected {}",
                self.rgb.len(),
                3 * n
            ));
        }
        if self.thermal.len() != n {
            return bad(format!(
                "thermal has {} values, expected {n}",
                self.thermal.len()
            ));
        }
        if let Some(l) = &self.label {
            if l.len() != n {
                return bad(format!("label has {} values, expected {n}", l.len()));
            }
        }
        Ok(())
    }
}

/// A list of frames that can be loaded by index from any thread.
pub trait FrameSource: Send + Sync {
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    fn frame_name(&self, index: usize) -> &str;
    fn daytime(&self, index: usize) -> Option<Daytime>;
    fn class_set(&self) -> &ClassSet;
    fn load(&self, index: usize) -> Result<Frame, DataError>;
    /// The frame without its label. Sources whose labels are separate files override this so
    /// that the label file is never opened (label-free training must not read night labels).
    fn load_unlabelled(&self, index: usize) -> Result<Frame, DataError> {
        let mut frame = self.load(index)?;
        frame.label = None;
        Ok(frame)
    }
}

/// Some frames of another source (e.g. its day or its night frames), with or without their
/// labels. Without labels, frames come from [`FrameSource::load_unlabelled`] and the class set
/// gains an ignore id if it has none, so the loader's targets are "ignore" everywhere.
pub struct Subset {
    inner: Arc<dyn FrameSource>,
    indices: Vec<usize>,
    labelled: bool,
    class_set: ClassSet,
}

/// The ignore id given to unlabelled subsets of class sets without one (MF).
pub const UNLABELLED_IGNORE_ID: u8 = 255;

impl Subset {
    /// The frames of `inner` for which `keep(index)` holds.
    pub fn new(inner: Arc<dyn FrameSource>, keep: impl Fn(usize) -> bool, labelled: bool) -> Self {
        let indices = (0..inner.len()).filter(|&i| keep(i)).collect();
        let mut class_set = inner.class_set().clone();
        if !labelled && class_set.ignore_id.is_none() {
            class_set.ignore_id = Some(UNLABELLED_IGNORE_ID);
        }
        Self {
            inner,
            indices,
            labelled,
            class_set,
        }
    }

    /// The frames of `inner` taken at `daytime`.
    pub fn of_daytime(inner: Arc<dyn FrameSource>, daytime: Daytime, labelled: bool) -> Self {
        let source = inner.clone();
        Self::new(inner, move |i| source.daytime(i) == Some(daytime), labelled)
    }
}

impl FrameSource for Subset {
    fn len(&self) -> usize {
        self.indices.len()
    }
    fn frame_name(&self, index: usize) -> &str {
        self.inner.frame_name(self.indices[index])
    }
    fn daytime(&self, index: usize) -> Option<Daytime> {
        self.inner.daytime(self.indices[index])
    }
    fn class_set(&self) -> &ClassSet {
        &self.class_set
    }
    fn load(&self, index: usize) -> Result<Frame, DataError> {
        let inner = *self.indices.get(index).ok_or_else(|| DataError::Frame {
            name: format!("#{index}"),
            message: format!("index out of range (len {})", self.indices.len()),
        })?;
        match self.labelled {
            true => self.inner.load(inner),
            false => self.inner.load_unlabelled(inner),
        }
    }
    fn load_unlabelled(&self, index: usize) -> Result<Frame, DataError> {
        let inner = *self.indices.get(index).ok_or_else(|| DataError::Frame {
            name: format!("#{index}"),
            message: format!("index out of range (len {})", self.indices.len()),
        })?;
        self.inner.load_unlabelled(inner)
    }
}

/// Frames kept in memory (tests, generated data).
pub struct MemorySource {
    pub frames: Vec<Frame>,
    pub class_set: ClassSet,
}

impl FrameSource for MemorySource {
    fn len(&self) -> usize {
        self.frames.len()
    }
    fn frame_name(&self, index: usize) -> &str {
        &self.frames[index].name
    }
    fn daytime(&self, index: usize) -> Option<Daytime> {
        self.frames[index].daytime
    }
    fn class_set(&self) -> &ClassSet {
        &self.class_set
    }
    fn load(&self, index: usize) -> Result<Frame, DataError> {
        self.frames
            .get(index)
            .cloned()
            .ok_or_else(|| DataError::Frame {
                name: format!("#{index}"),
                message: format!("index out of range (len {})", self.frames.len()),
            })
    }
}

/// Checks every label id against the class set (ids < len, or the ignore id).
pub(crate) fn check_label_ids(
    ids: &[u8],
    width: usize,
    classes: &ClassSet,
    path: &std::path::Path,
) -> Result<(), DataError> {
    let n = classes.len();
    if let Some(pos) = ids
        .iter()
        .position(|&id| (id as usize) >= n && Some(id) != classes.ignore_id)
    {
        return Err(DataError::LabelOutOfRange {
            path: path.to_path_buf(),
            id: ids[pos] as u16,
            x: pos % width.max(1),
            y: pos / width.max(1),
            class_set: classes.name.clone(),
            classes: n,
            ignore: classes
                .ignore_id
                .map(|i| format!(", ignore id {i}"))
                .unwrap_or_default(),
        });
    }
    Ok(())
}
