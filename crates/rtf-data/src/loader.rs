//! Batched loading: shuffling, decoding and augmentation in worker threads with bounded
//! prefetch. A batch depends only on (seed, epoch, batch index): each frame's augmentation RNG
//! is derived from its position in the epoch, never from thread timing.

use crate::augment::{self, AugmentConfig, Filter, Planar, Window};
use crate::{DataError, Frame, FrameSource};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rtf_core::{Daytime, InputConvention};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::{Duration, Instant};

#[derive(Serialize, Deserialize, Clone, Debug)]
pub struct LoaderConfig {
    pub batch_size: usize,
    pub shuffle: bool,
    pub drop_last: bool,
    pub seed: u64,
    /// Decode/augment threads; 0 = everything on the consumer's thread, no prefetch.
    pub workers: usize,
    /// Finished batches queued ahead of the consumer (bounded).
    pub prefetch: usize,
    pub augment: AugmentConfig,
    /// (width, height) of every batch: image resampled (bilinear, bicubic when cropping),
    /// label nearest. None = native size (all frames must then share it).
    pub resize: Option<(usize, usize)>,
}

impl LoaderConfig {
    /// (width, height) of what a `frame` (width, height) becomes: the scale-crop's crop, else
    /// the resize, else the augmentation window, else the frame's own size.
    pub fn output_size(&self, frame: (usize, usize)) -> (usize, usize) {
        let base = self.resize.unwrap_or(frame);
        match &self.augment.scale_crop {
            Some(sc) => sc.crop_size(base),
            None => self.resize.or(self.augment.window).unwrap_or(frame),
        }
    }

    /// Whether every frame becomes the same size, whatever its own.
    fn fixed_size(&self) -> bool {
        let crop = self.augment.scale_crop.as_ref().and_then(|s| s.size);
        self.resize.is_some() || self.augment.window.is_some() || crop.is_some()
    }
}

impl Default for LoaderConfig {
    fn default() -> Self {
        Self {
            batch_size: 8,
            shuffle: true,
            drop_last: false,
            seed: 0,
            workers: 2,
            prefetch: 2,
            augment: AugmentConfig::default(),
            resize: None,
        }
    }
}

/// One batch, ready for the network.
#[derive(Debug)]
pub struct Batch {
    /// [B, 4, H, W] f32: R, G, B, T in [0, 1] mapped by the input convention.
    pub input: tch::Tensor,
    /// [B, H, W] i64 class ids (unlabelled frames: the ignore id).
    pub target: tch::Tensor,
    pub names: Vec<String>,
    pub daytimes: Vec<Option<Daytime>>,
    /// How long the consumer waited for this batch (0 when it was already prefetched).
    pub wait: Duration,
}

pub struct Loader {
    source: Arc<dyn FrameSource>,
    cfg: LoaderConfig,
    input: InputConvention,
    /// None with `workers: 0` (or when no thread could be started): batches load inline.
    producer: Option<Producer>,
}

impl Loader {
    pub fn new(source: Arc<dyn FrameSource>, cfg: LoaderConfig, input: InputConvention) -> Self {
        // A pool that cannot be built (resource exhaustion) degrades to the synchronous path.
        let pool = (cfg.workers > 0)
            .then(|| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(cfg.workers)
                    .thread_name(|i| format!("rtf-data-{i}"))
                    .build()
                    .ok()
            })
            .flatten()
            .map(Arc::new);
        let producer = pool.and_then(Producer::start);
        Self {
            source,
            cfg,
            input,
            producer,
        }
    }

    pub fn config(&self) -> &LoaderConfig {
        &self.cfg
    }

    pub fn source(&self) -> &Arc<dyn FrameSource> {
        &self.source
    }

    pub fn num_batches(&self) -> usize {
        let (n, b) = (self.source.len(), self.cfg.batch_size);
        match (b, self.cfg.drop_last) {
            (0, _) => 0,
            (_, true) => n / b,
            (_, false) => n.div_ceil(b),
        }
    }

    /// Frame indices of one epoch, in order.
    pub fn epoch_order(&self, epoch: u64) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.source.len()).collect();
        if self.cfg.shuffle {
            order.shuffle(&mut ChaCha8Rng::seed_from_u64(mix(
                self.cfg.seed,
                epoch,
                u64::MAX,
            )));
        }
        order
    }

    /// Batches of one epoch; order and augmentation depend only on (seed, epoch), so a resumed
    /// run sees exactly the batches it would have seen.
    pub fn epoch(&self, epoch: u64) -> impl Iterator<Item = Result<Batch, DataError>> + '_ {
        self.epoch_from(epoch, 0)
    }

    /// The batches of `epoch` from batch `first_batch` on (those before are not loaded): a run
    /// resumed inside an epoch continues with exactly the batches it had left.
    pub fn epoch_from(
        &self,
        epoch: u64,
        first_batch: usize,
    ) -> impl Iterator<Item = Result<Batch, DataError>> + '_ {
        let job = Arc::new(EpochJob {
            source: self.source.clone(),
            cfg: self.cfg.clone(),
            input: self.input,
            order: self.epoch_order(epoch),
            epoch,
            num_batches: self.num_batches(),
        });
        let mode = if self.cfg.batch_size == 0 {
            Mode::Failed(Some(DataError::Config(
                "batch_size must be at least 1".into(),
            )))
        } else {
            let threaded = self
                .producer
                .as_ref()
                .and_then(|p| p.submit(job.clone(), first_batch, self.cfg.prefetch));
            threaded.unwrap_or(Mode::Inline { next: first_batch })
        };
        EpochIter {
            job,
            mode,
            done: false,
        }
    }
}

/// The thread that produces one loader's batches (on the loader's pool), epoch after epoch. It
/// lives as long as the loader: a thread started per epoch leaked its heap in the `rtf`
/// binary, where mimalloc never learns that such a thread ended (its thread-exit hook is lost
/// behind libtorch's pthread keys; docs/src/reliability.md, "Memory across epochs").
struct Producer {
    jobs: Option<crossbeam_channel::Sender<ProducerJob>>,
    handle: Option<std::thread::JoinHandle<()>>,
}

/// One epoch's work for the [`Producer`].
struct ProducerJob {
    job: Arc<EpochJob>,
    first_batch: usize,
    batches: crossbeam_channel::Sender<Result<Batch, DataError>>,
    /// Dropped once the producer has left this epoch: what the consumer waits on to know it
    /// stopped (as it joined the per-epoch thread before).
    _finished: crossbeam_channel::Sender<()>,
}

impl Producer {
    fn start(pool: Arc<rayon::ThreadPool>) -> Option<Self> {
        let (jobs, queue) = crossbeam_channel::unbounded::<ProducerJob>();
        let handle = std::thread::Builder::new()
            .name("rtf-data-batches".into())
            .spawn(move || queue.into_iter().for_each(|work| produce(&pool, work)))
            .ok()?;
        Some(Self {
            jobs: Some(jobs),
            handle: Some(handle),
        })
    }

    /// Queues the batches of `job` from `first_batch` on; None when the thread is gone.
    fn submit(&self, job: Arc<EpochJob>, first_batch: usize, prefetch: usize) -> Option<Mode> {
        let (batches, rx) = crossbeam_channel::bounded(prefetch);
        let (finished, finished_rx) = crossbeam_channel::bounded(0);
        let work = ProducerJob {
            job,
            first_batch,
            batches,
            _finished: finished,
        };
        self.jobs.as_ref()?.send(work).ok()?;
        Some(Mode::Threaded {
            rx: Some(rx),
            finished: Some(finished_rx),
        })
    }
}

/// Produces one epoch's batches until the epoch ends, a batch fails or the consumer left; a
/// panic is reported to the consumer as [`DataError::WorkerGone`], never as a short epoch.
fn produce(pool: &rayon::ThreadPool, work: ProducerJob) {
    let ProducerJob {
        job,
        first_batch,
        batches,
        _finished,
    } = work;
    let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        for b in first_batch..job.num_batches {
            let batch = pool.install(|| job.batch(b, true));
            let failed = batch.is_err();
            if batches.send(batch).is_err() || failed {
                break;
            }
        }
    }));
    if run.is_err() {
        let _ = batches.send(Err(DataError::WorkerGone));
    }
}

impl Drop for Producer {
    fn drop(&mut self) {
        drop(self.jobs.take());
        if let Some(handle) = self.handle.take() {
            let _ = handle.join();
        }
    }
}

struct EpochJob {
    source: Arc<dyn FrameSource>,
    cfg: LoaderConfig,
    input: InputConvention,
    order: Vec<usize>,
    epoch: u64,
    num_batches: usize,
}

impl EpochJob {
    fn batch(&self, b: usize, parallel: bool) -> Result<Batch, DataError> {
        let bs = self.cfg.batch_size;
        let positions: Vec<usize> = (b * bs..((b + 1) * bs).min(self.order.len())).collect();
        let frames = self.load(&positions, parallel)?;
        let (w, h) = self.output_size(&frames)?;
        self.assemble(frames, &positions, (w, h), parallel)
    }

    /// The frames at these positions of the epoch's order, decoded and validated.
    fn load(&self, positions: &[usize], parallel: bool) -> Result<Vec<Frame>, DataError> {
        use rayon::prelude::*;
        let load = |&pos: &usize| -> Result<Frame, DataError> {
            let frame = self.source.load(self.order[pos])?;
            frame.validate()?;
            Ok(frame)
        };
        if parallel {
            positions.par_iter().map(load).collect()
        } else {
            positions.iter().map(load).collect()
        }
    }

    /// The batch's (width, height): [`LoaderConfig::output_size`] of the first frame; without
    /// a fixed size the frames' own, which must then be the same for all.
    fn output_size(&self, frames: &[Frame]) -> Result<(usize, usize), DataError> {
        let first = frames
            .first()
            .ok_or_else(|| DataError::Config("empty batch".into()))?;
        let (w, h) = self.cfg.output_size((first.width, first.height));
        if w == 0 || h == 0 {
            return Err(DataError::Config(format!("resize to {w}x{h}")));
        }
        if !self.cfg.fixed_size() {
            if let Some(odd) = frames.iter().find(|f| (f.width, f.height) != (w, h)) {
                return Err(DataError::Frame {
                    name: odd.name.clone(),
                    message: format!(
                        "is {}x{} but '{}' is {w}x{h}; set a resize to batch frames of different sizes",
                        odd.width, odd.height, first.name
                    ),
                });
            }
        }
        Ok((w, h))
    }

    /// The batch tensors: each frame prepared (with its own seeded generator) straight into
    /// its slot of the input [N, 4, H, W] and target [N, H, W].
    fn assemble(
        &self,
        frames: Vec<Frame>,
        positions: &[usize],
        (w, h): (usize, usize),
        parallel: bool,
    ) -> Result<Batch, DataError> {
        use rayon::prelude::*;
        let n = frames.len();
        let input = tch::Tensor::f_empty(
            [n as i64, 4, h as i64, w as i64],
            (tch::Kind::Float, tch::Device::Cpu),
        )?;
        let target = tch::Tensor::f_empty(
            [n as i64, h as i64, w as i64],
            (tch::Kind::Int64, tch::Device::Cpu),
        )?;
        // SAFETY: both tensors were just allocated by libtorch as contiguous CPU tensors of
        // exactly these element counts and kinds; nothing else references them until they
        // are returned, and every element is written below before that.
        let (input_data, target_data) = unsafe {
            (
                std::slice::from_raw_parts_mut(input.data_ptr() as *mut f32, n * 4 * w * h),
                std::slice::from_raw_parts_mut(target.data_ptr() as *mut i64, n * w * h),
            )
        };
        let ignore = self.source.class_set().ignore_id;
        let work = |((frame, &pos), (dst, dst_label)): ((Frame, &usize), BatchSlot)| {
            let mut rng = ChaCha8Rng::seed_from_u64(mix(self.cfg.seed, self.epoch, pos as u64));
            prepare_into(
                frame,
                &self.cfg,
                ignore,
                &mut rng,
                self.input,
                (w, h),
                dst,
                dst_label,
            )
        };
        let meta: Vec<(String, Option<Daytime>)> = if parallel {
            frames
                .into_par_iter()
                .zip(positions.par_iter())
                .zip(
                    input_data
                        .par_chunks_mut(4 * w * h)
                        .zip(target_data.par_chunks_mut(w * h)),
                )
                .map(work)
                .collect::<Result<_, _>>()?
        } else {
            frames
                .into_iter()
                .zip(positions.iter())
                .zip(
                    input_data
                        .chunks_mut(4 * w * h)
                        .zip(target_data.chunks_mut(w * h)),
                )
                .map(work)
                .collect::<Result<_, _>>()?
        };
        let (names, daytimes) = meta.into_iter().unzip();
        Ok(Batch {
            input,
            target,
            names,
            daytimes,
            wait: Duration::ZERO,
        })
    }
}

/// A frame after geometry and photometry, in [0, 1] (no input convention applied).
pub struct Prepared {
    pub name: String,
    pub daytime: Option<Daytime>,
    pub image: Planar,
    pub label: Vec<u8>,
}

/// [`prepare_into`] with its own buffers, output at `cfg.resize` or the native size.
pub fn prepare_frame(
    frame: Frame,
    cfg: &LoaderConfig,
    ignore: Option<u8>,
    rng: &mut impl Rng,
) -> Result<Prepared, DataError> {
    let (w, h) = cfg.output_size((frame.width, frame.height));
    let mut image = Planar {
        channels: 4,
        width: w,
        height: h,
        data: vec![0.0; 4 * w * h],
    };
    let mut label = vec![0i64; w * h];
    let (name, daytime) = prepare_into(
        frame,
        cfg,
        ignore,
        rng,
        InputConvention::UnitRange,
        (w, h),
        &mut image.data,
        &mut label,
    )?;
    Ok(Prepared {
        name,
        daytime,
        image,
        // Scale-crop padding without an ignore id (NO_LABEL) comes back as 255.
        label: label
            .into_iter()
            .map(|v| u8::try_from(v).unwrap_or(SCALE_CROP_PAD))
            .collect(),
    })
}

/// Turns one decoded frame into the network's input at `size` (width, height): crop or scale
/// and crop, rotation, resize, flip, photometry, then the input convention, written into
/// `dst` ([4, H, W]) and `dst_label` ([H, W]).
#[allow(clippy::too_many_arguments)]
pub fn prepare_into(
    mut frame: Frame,
    cfg: &LoaderConfig,
    ignore: Option<u8>,
    rng: &mut impl Rng,
    input: InputConvention,
    (out_w, out_h): (usize, usize),
    dst: &mut [f32],
    dst_label: &mut [i64],
) -> Result<(String, Option<Daytime>), DataError> {
    frame.validate()?;
    let label = take_label(&mut frame, ignore)?;
    if out_w == 0
        || out_h == 0
        || dst.len() != 4 * out_w * out_h
        || dst_label.len() != out_w * out_h
    {
        return Err(DataError::Config(format!(
            "output size {out_w}x{out_h} does not match the buffers"
        )));
    }
    let image = unit_planes(&frame);
    let aug = &cfg.augment;
    // Random draws happen in a fixed order whether or not an augmentation changes anything.
    let geometry = draw_geometry(cfg, (frame.width, frame.height), rng, &frame.name)?;
    let angle = aug
        .rotation_deg
        .map(|d| rng.random_range(-d.abs()..=d.abs()));
    let flip = aug.hflip && rng.random::<bool>();
    let pad_label = ignore.unwrap_or(SCALE_CROP_PAD);
    let mut label = geometry.apply(&image, &label, (aug, pad_label), (out_w, out_h), dst);
    if let Some(deg) = angle {
        let resized = Planar {
            channels: 4,
            width: out_w,
            height: out_h,
            data: dst.to_vec(),
        };
        let (img, lab) = augment::rotate(&resized, Some(&label), deg, ignore.unwrap_or(0));
        dst.copy_from_slice(&img.data);
        label = lab.unwrap_or_default();
    }
    augment::put_scratch(image.data);
    if flip {
        dst.chunks_exact_mut(out_w).for_each(|row| row.reverse());
        augment::hflip_label(&mut label, out_w);
    }
    augment::photometric_data(dst, 4, out_w, out_h, aug, rng);
    if input != InputConvention::UnitRange {
        dst.iter_mut().for_each(|v| *v = input.apply(*v));
    }
    // Padding of a class set without an ignore id: the loss's "no label".
    let padded = |id: u8| ignore.is_none() && aug.scale_crop.is_some() && id == SCALE_CROP_PAD;
    for (d, &id) in dst_label.iter_mut().zip(&label) {
        *d = if padded(id) { NO_LABEL } else { id as i64 };
    }
    Ok((frame.name, frame.daytime))
}

/// The target of pixels without a label where the class set has no ignore id (scale-crop
/// padding): PyTorch's default `ignore_index`, which rtf's cross-entropy skips then.
pub const NO_LABEL: i64 = -100;

/// The label byte of scale-crop padding inside the pipeline when the class set has no ignore
/// id (the official code's 255), written out as [`NO_LABEL`].
const SCALE_CROP_PAD: u8 = 255;

/// The frame's label, or one of the ignore id where the frame has none.
fn take_label(frame: &mut Frame, ignore: Option<u8>) -> Result<Vec<u8>, DataError> {
    match (frame.label.take(), ignore) {
        (Some(l), _) => Ok(l),
        (None, Some(id)) => Ok(vec![id; frame.width * frame.height]),
        (None, None) => Err(DataError::Frame {
            name: frame.name.clone(),
            message: "frame has no label and the class set has no ignore id".into(),
        }),
    }
}

/// Where the output's pixels come from: a window of the frame resampled to the output size,
/// or CMX's scale and crop with padding.
enum Geometry {
    Window(Window),
    ScaleCrop(crate::scale_crop::Placement),
}

/// Draws the geometry of a `frame` (width, height): scale and crop when configured, else
/// [`draw_window`]'s window.
fn draw_geometry(
    cfg: &LoaderConfig,
    frame: (usize, usize),
    rng: &mut impl Rng,
    name: &str,
) -> Result<Geometry, DataError> {
    let aug = &cfg.augment;
    let Some(sc) = &aug.scale_crop else {
        return draw_window(aug, frame.0, frame.1, rng, name).map(Geometry::Window);
    };
    if aug.crop.is_some() || aug.window.is_some() {
        return Err(DataError::Config(
            "augment.scale_crop, augment.crop and augment.window are alternatives; set one".into(),
        ));
    }
    let base = cfg.resize.unwrap_or(frame);
    crate::scale_crop::draw(sc, frame, base, rng).map(Geometry::ScaleCrop)
}

impl Geometry {
    /// The image into `dst` at `out` (width, height); returns the label there. RTFNet's crop
    /// resamples bicubic, anything else bilinear; scale-crop padding gets the configured fill
    /// and `pad_label`.
    fn apply(
        &self,
        image: &Planar,
        label: &[u8],
        (aug, pad_label): (&AugmentConfig, u8),
        (out_w, out_h): (usize, usize),
        dst: &mut [f32],
    ) -> Vec<u8> {
        let (w, h) = (image.width, image.height);
        match self {
            Geometry::Window(window) => {
                let filter = match aug.crop.is_some() {
                    true => Filter::Bicubic,
                    false => Filter::Bilinear,
                };
                augment::resample_into(image, *window, out_w, out_h, filter, dst);
                augment::resample_nearest(label, w, h, *window, out_w, out_h)
            }
            Geometry::ScaleCrop(place) => {
                let fill = aug.scale_crop.as_ref().map_or([0.0; 4], |s| s.fill);
                let mut ids = vec![pad_label; out_w * out_h];
                let out = (out_w, out_h);
                crate::scale_crop::crop_into(
                    image,
                    label,
                    place,
                    (&fill, pad_label),
                    out,
                    dst,
                    &mut ids,
                );
                ids
            }
        }
    }
}

/// The frame as four planes in [0, 1]: R, G, B (bytes / 255), thermal; in a scratch buffer
/// that the caller returns with `augment::put_scratch`.
fn unit_planes(frame: &Frame) -> Planar {
    let n = frame.width * frame.height;
    let mut data = augment::take_scratch(4 * n);
    let (rgb_planes, t_plane) = data.split_at_mut(3 * n);
    for (i, px) in frame.rgb.chunks_exact(3).enumerate() {
        rgb_planes[i] = px[0] as f32 / 255.0;
        rgb_planes[n + i] = px[1] as f32 / 255.0;
        rgb_planes[2 * n + i] = px[2] as f32 / 255.0;
    }
    t_plane.copy_from_slice(&frame.thermal);
    Planar {
        channels: 4,
        width: frame.width,
        height: frame.height,
        data,
    }
}

/// The source window of a `w`×`h` frame: RTFNet's random crop, a random fixed-size window,
/// or the whole frame. Draws from `rng` in the same order whatever the result.
fn draw_window(
    aug: &AugmentConfig,
    w: usize,
    h: usize,
    rng: &mut impl Rng,
    name: &str,
) -> Result<Window, DataError> {
    let window = match aug.crop {
        Some(f) if f > 0.0 => Window::random_crop(w, h, f, rng),
        _ => Window::full(w, h),
    };
    match aug.window {
        None => Ok(window),
        Some(_) if aug.crop.is_some() => Err(DataError::Config(
            "augment.crop and augment.window are alternatives; set one".into(),
        )),
        Some((ww, wh)) if ww > w || wh > h || ww == 0 || wh == 0 => Err(DataError::Frame {
            name: name.to_string(),
            message: format!("{w}x{h} is smaller than the {ww}x{wh} augmentation window"),
        }),
        Some((ww, wh)) => {
            let x0 = rng.random_range(0..=w - ww) as f32;
            let y0 = rng.random_range(0..=h - wh) as f32;
            Ok(Window {
                x0,
                y0,
                x1: x0 + ww as f32,
                y1: y0 + wh as f32,
            })
        }
    }
}

/// One frame's place in the batch tensors: input [4, H, W] and target [H, W].
type BatchSlot<'a> = (&'a mut [f32], &'a mut [i64]);

enum Mode {
    Inline {
        next: usize,
    },
    Threaded {
        rx: Option<crossbeam_channel::Receiver<Result<Batch, DataError>>>,
        finished: Option<crossbeam_channel::Receiver<()>>,
    },
    Failed(Option<DataError>),
}

struct EpochIter {
    job: Arc<EpochJob>,
    mode: Mode,
    done: bool,
}

impl Iterator for EpochIter {
    type Item = Result<Batch, DataError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let start = Instant::now();
        let item = match &mut self.mode {
            Mode::Failed(err) => err.take().map(Err),
            Mode::Inline { next } => {
                if *next >= self.job.num_batches {
                    None
                } else {
                    *next += 1;
                    Some(self.job.batch(*next - 1, false))
                }
            }
            // Channel closed: the producer finished the epoch (a panic there arrives first as
            // WorkerGone, never as a silently short epoch).
            Mode::Threaded { rx, .. } => rx.as_ref().and_then(|r| r.recv().ok()),
        };
        match item {
            Some(Ok(mut batch)) => {
                batch.wait = start.elapsed();
                Some(Ok(batch))
            }
            Some(Err(e)) => {
                self.done = true;
                Some(Err(e))
            }
            None => {
                self.done = true;
                None
            }
        }
    }
}

impl Drop for EpochIter {
    fn drop(&mut self) {
        if let Mode::Threaded { rx, finished } = &mut self.mode {
            // Closing the channel makes the producer's next send fail, so it stops; wait until
            // it has left the epoch.
            drop(rx.take());
            if let Some(finished) = finished.take() {
                let _ = finished.recv();
            }
        }
    }
}

/// SplitMix64-style mixing of three words into one seed.
pub fn mix(a: u64, b: u64, c: u64) -> u64 {
    let mut z = a ^ b.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ c.wrapping_mul(0xD1B5_4A32_D192_ED03);
    for _ in 0..2 {
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
    }
    z
}

#[cfg(test)]
mod tests;
