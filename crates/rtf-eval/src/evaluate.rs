//! Evaluation of any network on any frame source: one confusion matrix for the split and one
//! per daytime, accumulated batch by batch.
//!
//! Frame sizes come from outside (a 4000×3000 photo, a memory limit), so the forward pass is
//! guarded: its memory is estimated before a large batch ([`check_memory`]) and an allocation
//! failure inside libtorch, which tch's infallible ops turn into a panic, comes back as
//! [`EvalError::OutOfMemory`] with the size, the estimate and a hint ([`forward_guarded`]).
//!
//! Missing-modality robustness ([`evaluate_with_drop`]): the RGB or the thermal channels of
//! every input are replaced before the network, by zero (a black / coldest image) or by the
//! split's mean of that modality, as in the modality-dropout protocols of the RGB-T literature
//! (e.g. HeatNet's single-modality ablations, spec §3); the labels are unchanged.

use std::cell::Cell;
use std::panic::AssertUnwindSafe;
use std::sync::{Arc, Once};

use rtf_core::Daytime;
use rtf_data::{DataError, FrameSource, Loader, LoaderConfig};
use rtf_models::Network;
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};

use crate::class_map::ClassMapping;
use crate::metrics::{ConfusionMatrix, Scores};

pub mod inference;
use inference::InferenceOptions;

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(transparent)]
    Data(#[from] DataError),
    #[error("{0}")]
    Shape(String),
    /// Inference options that cannot run (an empty crop, a scale of 0, ...).
    #[error("inference options: {0}")]
    Inference(String),
    #[error(transparent)]
    Torch(#[from] tch::TchError),
    #[error(transparent)]
    ClassMap(#[from] crate::class_map::ClassMapError),
    #[error(
        "out of memory: {network} on a batch of {batch} frame(s) of {width}x{height} needs {}, \
         {}{detail}; run at a smaller size (--resize WxH, e.g. 640x480) or with a smaller \
         --batch-size",
        estimate.map_or("more memory than there is".to_string(), |b| format!("about {} (estimate)", gib(b))),
        available.map_or("memory available unknown".to_string(), |b| format!("{} available", gib(b)))
    )]
    OutOfMemory {
        network: String,
        batch: usize,
        width: usize,
        height: usize,
        estimate: Option<u64>,
        available: Option<u64>,
        /// libtorch's own words, when it failed (empty when refused beforehand).
        detail: String,
    },
    #[error("{network}: forward pass failed on input {shape:?}: {message}")]
    Forward {
        network: String,
        shape: Vec<i64>,
        message: String,
    },
}

fn gib(bytes: u64) -> String {
    format!("{:.2} GiB", bytes as f64 / (1u64 << 30) as f64)
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalOptions {
    pub batch_size: usize,
    /// Resize frames to (width, height) before the network (labels nearest); None = as stored.
    pub resize: Option<(usize, usize)>,
    pub workers: usize,
    /// Whole image or sliding windows, scales, flip ([`inference`]); default: the whole
    /// image once.
    #[serde(default)]
    pub inference: InferenceOptions,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            batch_size: 4,
            resize: None,
            workers: 2,
            inference: InferenceOptions::default(),
        }
    }
}

/// A modality of the 4-channel input (R, G, B, T): the one type the training masks
/// (`--inputs`) and the robustness drops (`--drop`) share.
pub use rtf_models::Modality;

/// What replaces a dropped modality.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DropFill {
    /// Pixel value 0 in every channel of the modality (then the network's input convention).
    Zero,
    /// The split's per-channel mean of the modality (then the input convention).
    Mean,
}

/// A modality replaced in every input of an evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ModalityDrop {
    pub modality: Modality,
    pub fill: DropFill,
}

/// Per-channel mean (R, G, B, T, in [0, 1]) over every frame of `source`.
pub fn channel_means(source: &dyn FrameSource) -> Result<[f64; 4], EvalError> {
    let mut sums = [0f64; 4];
    let mut pixels = 0u64;
    for i in 0..source.len() {
        let frame = source.load(i)?;
        for px in frame.rgb.chunks_exact(3) {
            for c in 0..3 {
                sums[c] += px[c] as f64 / 255.0;
            }
        }
        sums[3] += frame.thermal.iter().map(|&t| t as f64).sum::<f64>();
        pixels += (frame.width * frame.height) as u64;
    }
    if pixels == 0 {
        return Err(EvalError::Shape("no pixels to average".into()));
    }
    Ok(sums.map(|s| s / pixels as f64))
}

/// Scores of a split, its day and night frames separately, and the raw matrices.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalReport {
    pub frames: usize,
    pub all: Scores,
    pub day: Option<Scores>,
    pub night: Option<Scores>,
    pub confusion: ConfusionMatrix,
}

/// Runs `network` (eval mode, no autograd) over every frame of `source`.
pub fn evaluate(
    network: &dyn Network,
    source: Arc<dyn FrameSource>,
    options: &EvalOptions,
    device: Device,
) -> Result<EvalReport, EvalError> {
    evaluate_with_drop(network, source, options, None, device)
}

/// [`evaluate`] with one modality replaced in every input (see the module docs).
pub fn evaluate_with_drop(
    network: &dyn Network,
    source: Arc<dyn FrameSource>,
    options: &EvalOptions,
    drop: Option<ModalityDrop>,
    device: Device,
) -> Result<EvalReport, EvalError> {
    evaluate_mapped(network, source, options, drop, None, device)
}

/// [`evaluate_with_drop`] through a class map: predictions and labels translated to the
/// map's scored classes (then "other"), so a network is scored on a dataset with another
/// class set (`crate::class_map`). The report's classes are the map's
/// ([`ClassMapping::matrix_names`]); without a map it is [`evaluate_with_drop`].
pub fn evaluate_mapped(
    network: &dyn Network,
    source: Arc<dyn FrameSource>,
    options: &EvalOptions,
    drop: Option<ModalityDrop>,
    map: Option<&ClassMapping>,
    device: Device,
) -> Result<EvalReport, EvalError> {
    if let Some(map) = map {
        check_mapping(network, source.as_ref(), map)?;
    }
    let loader = split_loader(source, options, network.input_convention());
    evaluate_loader_inner(network, &loader, drop, &options.inference, map, device)
}

/// Refuses a map resolved for other class sets than the network's outputs and the split's.
fn check_mapping(
    network: &dyn Network,
    source: &dyn FrameSource,
    map: &ClassMapping,
) -> Result<(), EvalError> {
    let data = source.class_set().names();
    if network.num_classes() as usize != map.network_classes.len() || data != map.data_classes {
        return Err(EvalError::Shape(format!(
            "class map `{}` was checked against a network of {} classes and data of classes \
             {:?}; this network has {} and the data {:?}",
            map.map.name,
            map.network_classes.len(),
            map.data_classes,
            network.num_classes(),
            data
        )));
    }
    Ok(())
}

/// The loader that [`evaluate_loader`] reads a split through (in order, every frame, no
/// augmentation). A caller that evaluates the same split again and again (training's
/// validation after every epoch) builds it once: each loader starts its own decoding threads,
/// and every thread that ends leaves its allocator heap behind in the `rtf` binary, so a new
/// loader per validation grows resident memory epoch by epoch (measured:
/// docs/src/reliability.md, section "Memory across epochs").
pub fn split_loader(
    source: Arc<dyn FrameSource>,
    options: &EvalOptions,
    input: rtf_core::InputConvention,
) -> Loader {
    Loader::new(
        source,
        LoaderConfig {
            batch_size: options.batch_size,
            shuffle: false,
            drop_last: false,
            seed: 0,
            workers: options.workers,
            prefetch: 2,
            augment: Default::default(),
            resize: options.resize,
        },
        input,
    )
}

/// [`evaluate_with_drop`] over the frames of `loader` (built by [`split_loader`] for this
/// network's input convention), the whole image once per frame.
pub fn evaluate_loader(
    network: &dyn Network,
    loader: &Loader,
    drop: Option<ModalityDrop>,
    device: Device,
) -> Result<EvalReport, EvalError> {
    evaluate_loader_with(network, loader, drop, &InferenceOptions::default(), device)
}

/// [`evaluate_loader`] with the inference mode, scales and flip of `inference`.
pub fn evaluate_loader_with(
    network: &dyn Network,
    loader: &Loader,
    drop: Option<ModalityDrop>,
    inference: &InferenceOptions,
    device: Device,
) -> Result<EvalReport, EvalError> {
    evaluate_loader_inner(network, loader, drop, inference, None, device)
}

/// [`evaluate_loader_with`], through `map` when given ([`evaluate_mapped`]).
fn evaluate_loader_inner(
    network: &dyn Network,
    loader: &Loader,
    drop: Option<ModalityDrop>,
    inference: &InferenceOptions,
    map: Option<&ClassMapping>,
    device: Device,
) -> Result<EvalReport, EvalError> {
    inference.validate()?;
    let fill = drop_fill_values(network, loader, drop)?;
    let source = loader.source();
    let classes = source.class_set();
    // Without a map the split's classes; with one the scored classes, then "other".
    let (names, ignore): (Vec<&str>, Option<u8>) = match map {
        None => (classes.names(), classes.ignore_id),
        Some(m) => (m.matrix_names(), Some(m.dropped())),
    };
    let n = names.len();
    let mut day = ConfusionMatrix::new(n, ignore);
    let mut night = ConfusionMatrix::new(n, ignore);
    let mut unknown = ConfusionMatrix::new(n, ignore);
    check_split_memory(network, loader, inference, device)?;
    let mut frames = 0;
    let _guard = tch::no_grad_guard();
    for batch in loader.epoch(0) {
        let batch = batch?;
        let input = batch.input.to_device(device);
        if let Some((first, values)) = &fill {
            for (c, &v) in values.iter().enumerate() {
                let _ = input.narrow(1, (first + c) as i64, 1).fill_(v);
            }
        }
        let mut prediction = inference::predict(network, &input, inference)?;
        let mut target = batch.target.to_device(device);
        if let Some(m) = map {
            (target, prediction) = (m.map_truth(&target), m.map_prediction(&prediction));
        }
        for (i, daytime) in batch.daytimes.iter().enumerate() {
            let matrix = match daytime {
                Some(Daytime::Day) => &mut day,
                Some(Daytime::Night) => &mut night,
                None => &mut unknown,
            };
            matrix.update(&target.get(i as i64), &prediction.get(i as i64));
        }
        frames += batch.names.len();
    }
    let mut all = day.clone();
    all.merge(&night);
    all.merge(&unknown);
    let scores_if_any = |m: &ConfusionMatrix| (m.total() > 0).then(|| m.compute(&names));
    Ok(EvalReport {
        frames,
        all: all.compute(&names),
        day: scores_if_any(&day),
        night: scores_if_any(&night),
        confusion: all,
    })
}

/// The first channel and the values (in the network's input scale) that replace a dropped
/// modality; None without a drop.
fn drop_fill_values(
    network: &dyn Network,
    loader: &Loader,
    drop: Option<ModalityDrop>,
) -> Result<Option<(usize, Vec<f64>)>, EvalError> {
    let Some(d) = drop else { return Ok(None) };
    let (first, count) = d.modality.channels();
    let unit = match d.fill {
        DropFill::Zero => vec![0.0; count],
        DropFill::Mean => channel_means(loader.source().as_ref())?[first..first + count].to_vec(),
    };
    let convention = network.input_convention();
    let values = unit
        .iter()
        .map(|&u| convention.apply(u as f32) as f64)
        .collect();
    Ok(Some((first, values)))
}

/// [`check_memory`] for the largest forward pass of an evaluation of `loader`'s frames.
fn check_split_memory(
    network: &dyn Network,
    loader: &Loader,
    inference: &InferenceOptions,
    device: Device,
) -> Result<(), EvalError> {
    let (source, options) = (loader.source(), loader.config());
    let batch = options.batch_size.min(source.len());
    let (h, w) = match options.resize {
        Some((w, h)) => (h, w),
        None if source.is_empty() => return Ok(()),
        None => {
            // Frames of a split share one size (the loader refuses others): the first tells it.
            let first = source.load(0)?;
            (first.height, first.width)
        }
    };
    let (h, w) = inference.largest_pass(h, w);
    check_memory(network, batch, h, w, device)
}

/// Class ids [B, H, W] for an input [B, C, H, W]: H and W are padded up to the network's size
/// multiple (replicating the border) and the logits cropped back.
pub fn predict_ids(network: &dyn Network, input: &Tensor) -> Result<Tensor, EvalError> {
    Ok(logits(network, input)?.f_argmax(1, false)?)
}

/// Logits [B, classes, H, W] at the input's resolution, in eval mode.
pub fn logits(network: &dyn Network, input: &Tensor) -> Result<Tensor, EvalError> {
    let (h, w) = match input.size().as_slice() {
        [_, _, h, w] => (*h, *w),
        other => {
            return Err(EvalError::Shape(format!(
                "expected input [B, C, H, W], got {other:?}"
            )))
        }
    };
    let m = network.size_multiple().max(1);
    let (ph, pw) = ((m - h % m) % m, (m - w % m) % m);
    let padded = if ph > 0 || pw > 0 {
        input.f_pad([0, pw, 0, ph], "replicate", None)?
    } else {
        input.shallow_clone()
    };
    let out = forward_guarded(network, &padded.f_to_kind(Kind::Float)?)?;
    Ok(out.f_narrow(2, 0, h)?.f_narrow(3, 0, w)?)
}

thread_local! {
    /// Set while [`forward_guarded`] runs a forward pass on this thread.
    static GUARDED: Cell<bool> = const { Cell::new(false) };
}

/// Makes the process's panic hook quiet for panics that [`forward_guarded`] catches and turns
/// into errors (others are reported as before). Programs call it once at start; idempotent.
pub fn install_quiet_panic_hook() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !GUARDED.with(Cell::get) {
                previous(info);
            }
        }));
    });
}

/// `network.forward_t(input, false)`, with a failure inside libtorch (which tch's infallible
/// ops report by panicking) returned as an error: [`EvalError::OutOfMemory`] for a failed
/// allocation, [`EvalError::Forward`] otherwise.
pub fn forward_guarded(network: &dyn Network, input: &Tensor) -> Result<Tensor, EvalError> {
    let previous = GUARDED.with(|g| g.replace(true));
    // Unwind safety: on a panic nothing of the network's state is used again by this call,
    // and its weights are only read by an eval-mode forward.
    let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
        tch::no_grad(|| network.forward_t(input, false))
    }));
    GUARDED.with(|g| g.set(previous));
    let payload = match result {
        Ok(out) => return Ok(out),
        Err(payload) => payload,
    };
    let message = payload
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "panic without a message".into());
    let shape = input.size();
    if is_allocation_failure(&message) {
        let (batch, height, width) = match shape.as_slice() {
            [b, _, h, w] => (*b as usize, *h as usize, *w as usize),
            _ => (0, 0, 0),
        };
        return Err(EvalError::OutOfMemory {
            network: network.name(),
            batch,
            width,
            height,
            estimate: estimate_forward_bytes(network, batch, height, width),
            available: available_memory(input.device()),
            detail: format!(" (libtorch: {})", first_line(&message)),
        });
    }
    Err(EvalError::Forward {
        network: network.name(),
        shape,
        message: first_line(&message).to_string(),
    })
}

fn is_allocation_failure(message: &str) -> bool {
    let m = message.to_ascii_lowercase();
    [
        "can't allocate",
        "out of memory",
        "bad_alloc",
        "failed to allocate",
    ]
    .iter()
    .any(|n| m.contains(n))
}

/// The part of a libtorch message worth showing: its first line, without tch's wrapping
/// (tch quotes libtorch's message with escaped newlines, then its C++ backtrace).
fn first_line(message: &str) -> &str {
    let line = message.lines().next().unwrap_or(message);
    let line = line.split_once("Torch(\"").map_or(line, |(_, rest)| rest);
    let line = line.split_once("\\n").map_or(line, |(head, _)| head);
    line.trim_end_matches("\")").trim_end()
}

/// Batches above this many input pixels get their memory estimated before they run.
pub const ESTIMATE_ABOVE_PIXELS: usize = 1 << 22;

/// Refuses, before any work, a forward pass on `batch` frames of `width`×`height` whose
/// estimated memory ([`estimate_forward_bytes`]) exceeds what the process can still get
/// ([`available_memory`]). Small batches are not checked (nothing to gain); neither is memory
/// that cannot be measured (non-Linux, accelerators).
pub fn check_memory(
    network: &dyn Network,
    batch: usize,
    height: usize,
    width: usize,
    device: Device,
) -> Result<(), EvalError> {
    let pixels = batch.saturating_mul(height).saturating_mul(width);
    if pixels <= ESTIMATE_ABOVE_PIXELS || device != Device::Cpu {
        return Ok(());
    }
    let (Some(estimate), Some(available)) = (
        estimate_forward_bytes(network, batch, height, width),
        available_memory(device),
    ) else {
        return Ok(());
    };
    if estimate > available {
        return Err(EvalError::OutOfMemory {
            network: network.name(),
            batch,
            width,
            height,
            estimate: Some(estimate),
            available: Some(available),
            detail: String::new(),
        });
    }
    Ok(())
}

/// Memory of an eval forward pass on `batch` frames of `width`×`height`, extrapolated
/// linearly in pixels from the peak resident size of two probe passes (128×128 and 256×256,
/// after a warm-up pass that pays libtorch's one-time allocations; Linux: the kernel's
/// `VmHWM`, reset through `/proc/self/clear_refs`). Activations of these fully
/// convolutional networks grow with the pixel count, so this is an estimate, not a bound
/// (compared with real runs for MFNet: docs/src/reliability.md, section "Frames larger than
/// memory"). None where it cannot be measured.
pub fn estimate_forward_bytes(
    network: &dyn Network,
    batch: usize,
    height: usize,
    width: usize,
) -> Option<u64> {
    let m = network.size_multiple().max(1) as usize;
    let probe = |side: usize| -> Option<(f64, f64)> {
        let side = side.div_ceil(m) * m;
        let input =
            Tensor::f_zeros([1, 4, side as i64, side as i64], (Kind::Float, Device::Cpu)).ok()?;
        release_free_memory();
        std::fs::write("/proc/self/clear_refs", "5").ok()?;
        let before = proc_status_kib("VmRSS")?;
        drop(forward_guarded(network, &input).ok()?);
        let peak = proc_status_kib("VmHWM")?.saturating_sub(before) * 1024;
        Some(((side * side) as f64, peak as f64))
    };
    probe(64)?; // warm-up
    let (px1, peak1) = probe(128)?;
    let (px2, peak2) = probe(256)?;
    let per_pixel = ((peak2 - peak1) / (px2 - px1)).max(0.0);
    let fixed = (peak1 - per_pixel * px1).max(0.0);
    let pixels = (batch * height * width) as f64;
    Some((fixed + per_pixel * pixels) as u64)
}

/// Bytes the process can still allocate on `device`: the smaller of the system's available
/// memory and what the address-space limit (`ulimit -v`) leaves. None off Linux or off CPU.
pub fn available_memory(device: Device) -> Option<u64> {
    if device != Device::Cpu {
        return None;
    }
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
    let available = field_kib(&meminfo, "MemAvailable")? * 1024;
    let mut limit = libc_rlimit_as();
    if let (Some(l), Some(size)) = (limit, proc_status_kib("VmSize")) {
        limit = Some(l.saturating_sub(size * 1024));
    }
    Some(limit.map_or(available, |l| l.min(available)))
}

fn libc_rlimit_as() -> Option<u64> {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes one rlimit struct we own.
    let ok = unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut limit) } == 0;
    (ok && limit.rlim_cur != libc::RLIM_INFINITY).then_some(limit.rlim_cur)
}

/// Hands free heap pages back to the kernel, so that a probe's allocations show in the peak
/// resident size (the CLI keeps freed memory, `rtf_kernels::allocator`).
fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns unused heap memory to the kernel.
    unsafe {
        libc::malloc_trim(0);
    }
}

fn proc_status_kib(key: &str) -> Option<u64> {
    field_kib(&std::fs::read_to_string("/proc/self/status").ok()?, key)
}

/// `Key:   123 kB` → 123.
fn field_kib(text: &str, key: &str) -> Option<u64> {
    text.lines()
        .find_map(|l| l.strip_prefix(key)?.strip_prefix(':'))?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtf_models::{build, ModelConfig};

    fn mfnet() -> (tch::nn::VarStore, Box<dyn Network>) {
        let _rng = crate::seeded_rng_lock();
        tch::manual_seed(0);
        let vs = tch::nn::VarStore::new(Device::Cpu);
        let net = build(&vs.root(), &ModelConfig::from_name("mfnet", 9).unwrap()).unwrap();
        (vs, net)
    }

    #[test]
    fn proc_fields_parse() {
        assert_eq!(
            field_kib("VmHWM:\t  1234 kB\nVmRSS: 5 kB", "VmRSS"),
            Some(5)
        );
        assert_eq!(field_kib("VmHWM: 1 kB", "VmSize"), None);
        assert!(is_allocation_failure(
            "called `Result::unwrap()` on an `Err` value: Torch(\"[enforce fail at alloc_cpu.cpp:117] \
             data. DefaultCPUAllocator: can't allocate memory: you tried to allocate 1 bytes\")"
        ));
        assert!(!is_allocation_failure("shape mismatch"));
        assert_eq!(
            first_line(
                "called `Result::unwrap()` on an `Err` value: Torch(\"[enforce fail] can't \
                 allocate memory: you tried to allocate 8 bytes.\\nframe #0: c10::f\\n\")"
            ),
            "[enforce fail] can't allocate memory: you tried to allocate 8 bytes."
        );
    }

    #[test]
    fn a_failing_forward_is_an_error_not_a_panic() {
        install_quiet_panic_hook();
        let (_vs, net) = mfnet();
        // Two channels where MFNet needs four: libtorch refuses inside forward_t.
        let bad = Tensor::zeros([1, 2, 32, 32], (Kind::Float, Device::Cpu));
        let err = forward_guarded(net.as_ref(), &bad).unwrap_err();
        assert!(matches!(err, EvalError::Forward { .. }), "{err}");
        assert!(err.to_string().contains("[1, 2, 32, 32]"), "{err}");
        // The guard is released: a good input runs.
        let good = Tensor::zeros([1, 4, 32, 32], (Kind::Float, Device::Cpu));
        assert_eq!(
            forward_guarded(net.as_ref(), &good).unwrap().size(),
            [1, 9, 32, 32]
        );
    }

    #[test]
    fn huge_batches_are_refused_before_they_run_with_size_and_estimate() {
        let _memory = crate::memory_lock();
        let (_vs, net) = mfnet();
        if available_memory(Device::Cpu).is_none() {
            return; // not Linux: nothing to compare the estimate with
        }
        let Some(estimate) = estimate_forward_bytes(net.as_ref(), 1, 480, 640) else {
            eprintln!("/proc/self/clear_refs not writable here: no estimate to test");
            return;
        };
        // MFNet at 480×640: the input and logits alone are 16 MB, activations add more;
        // far from gigabytes.
        let io = 480 * 640 * 4 * (4 + 9);
        assert!(
            estimate > io + (1 << 20) && estimate < 4 << 30,
            "estimate {estimate}"
        );
        // 64 frames of 30000×40000 would need terabytes.
        let err = check_memory(net.as_ref(), 64, 30_000, 40_000, Device::Cpu).unwrap_err();
        let text = err.to_string();
        for needle in [
            "40000x30000",
            "64 frame",
            "estimate",
            "--resize",
            "--batch-size",
        ] {
            assert!(text.contains(needle), "{needle} not in: {text}");
        }
        check_memory(net.as_ref(), 1, 480, 640, Device::Cpu).unwrap();
    }
}

#[cfg(test)]
mod drop_tests {
    use super::*;
    use rtf_core::ClassSet;
    use tch::nn::ModuleT;

    /// Predicts class 1 where the thermal channel is above 0.5, else class 0 (RGB ignored).
    #[derive(Debug)]
    struct ThermalThreshold;

    impl ModuleT for ThermalThreshold {
        fn forward_t(&self, xs: &Tensor, _train: bool) -> Tensor {
            let t = xs.narrow(1, 3, 1);
            let one = t.gt(0.5).to_kind(Kind::Float);
            Tensor::cat(&[one.ones_like() - &one, one], 1)
        }
    }

    impl Network for ThermalThreshold {
        fn input_convention(&self) -> rtf_core::InputConvention {
            rtf_core::InputConvention::UnitRange
        }
        fn num_classes(&self) -> i64 {
            2
        }
        fn size_multiple(&self) -> i64 {
            1
        }
        fn name(&self) -> String {
            "thermal-threshold".into()
        }
    }

    /// Two 2x2 frames whose label is "thermal > 0.5" (class 1), one day, one night.
    fn frames() -> rtf_data::MemorySource {
        let frame = |index: usize| {
            let thermal: Vec<f32> = if index == 0 {
                vec![0.9, 0.1, 0.9, 0.1]
            } else {
                vec![0.1, 0.1, 0.9, 0.9]
            };
            rtf_data::Frame {
                name: format!("f{index}"),
                daytime: Some(if index == 0 {
                    Daytime::Day
                } else {
                    Daytime::Night
                }),
                width: 2,
                height: 2,
                rgb: vec![200; 12],
                label: Some(thermal.iter().map(|&t| (t > 0.5) as u8).collect()),
                thermal,
            }
        };
        rtf_data::MemorySource {
            frames: vec![frame(0), frame(1)],
            class_set: ClassSet::mf(),
        }
    }

    #[test]
    fn dropping_a_modality_changes_only_what_uses_it() {
        let net = ThermalThreshold;
        let source: Arc<dyn FrameSource> = Arc::new(frames());
        let options = EvalOptions {
            batch_size: 2,
            resize: None,
            workers: 1,
            ..Default::default()
        };
        let run =
            |drop| evaluate_with_drop(&net, source.clone(), &options, drop, Device::Cpu).unwrap();
        let full = run(None);
        assert_eq!(full.all.pixel_acc, 1.0);
        let no_rgb = run(Some(ModalityDrop {
            modality: Modality::Rgb,
            fill: DropFill::Zero,
        }));
        assert_eq!(no_rgb.all.pixel_acc, 1.0);
        assert_eq!(no_rgb.day.unwrap().pixel_acc, 1.0);
        for fill in [DropFill::Zero, DropFill::Mean] {
            let no_t = run(Some(ModalityDrop {
                modality: Modality::Thermal,
                fill,
            }));
            // Every pixel predicted cold: half the pixels right.
            assert_eq!(no_t.all.pixel_acc, 0.5, "{fill:?}");
            assert_eq!(no_t.confusion.get(1, 0), 4, "{fill:?}");
        }
        let means = channel_means(source.as_ref()).unwrap();
        assert!((means[0] - 200.0 / 255.0).abs() < 1e-9);
        assert!((means[3] - 0.5).abs() < 1e-6);
    }

    #[test]
    fn one_loader_evaluates_a_split_again_and_again_as_a_fresh_one_does() {
        // Training validates every epoch through one loader (split_loader's docs).
        let net = ThermalThreshold;
        let source: Arc<dyn FrameSource> = Arc::new(frames());
        let options = EvalOptions {
            batch_size: 1,
            resize: None,
            workers: 2,
            ..Default::default()
        };
        let fresh = evaluate(&net, source.clone(), &options, Device::Cpu).unwrap();
        let loader = split_loader(source, &options, net.input_convention());
        for _ in 0..3 {
            let again = evaluate_loader(&net, &loader, None, Device::Cpu).unwrap();
            assert_eq!(again.frames, 2);
            assert_eq!(again.confusion, fresh.confusion);
            assert_eq!(again.night.unwrap().pixel_acc, 1.0);
        }
    }
}
