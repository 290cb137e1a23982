//! Inference speed of a network (`rtf bench model`): random weights and input of the given
//! size, warm-up passes, then timed passes; median, 95th percentile and minimum milliseconds
//! per frame, the process's peak resident memory, and the CPU they were measured on.

use std::path::PathBuf;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use tch::{nn, Device, Kind, Tensor};

use rtf_core::host::{peak_rss_mb, CpuInfo};
use rtf_models::fast::{
    argmax_agreement, FoldOptions, InferenceKernels, InferenceNet, Layout, Precision,
};
use rtf_models::{ModelConfig, ModelError, Network};

#[derive(Debug, thiserror::Error)]
pub enum SpeedError {
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error("invalid benchmark options: {0}")]
    Options(String),
}

/// Which forward is timed.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum ForwardPath {
    /// Folded BatchNorm, channels-last, in-place activations ([`InferenceNet`]).
    #[default]
    Fast,
    /// The training network's eval-mode forward under no_grad (NCHW, BatchNorm as is).
    Plain,
}

#[derive(Clone, Debug)]
pub struct BenchOptions {
    pub model: String,
    /// Outputs of the network (a dataset's class count); None = the network's usual count.
    pub num_classes: Option<i64>,
    pub batch: i64,
    pub precision: Precision,
    pub path: ForwardPath,
    /// Activation layout of the fast path.
    pub layout: Layout,
    /// The fast path's kernels where there is a choice ([`crate::kernels`]).
    pub kernels: InferenceKernels,
    pub height: i64,
    pub width: i64,
    pub warmup: usize,
    pub iterations: usize,
    /// Weights to load (random initialisation otherwise; speed does not depend on them).
    pub weights: Option<PathBuf>,
    /// Where the network runs; CUDA passes are timed to completion (synchronised).
    pub device: Device,
    /// Compare the fast path's labels with the plain path's after the timing (a second
    /// network and a plain fp32 pass, which count in the process's memory, not in the times).
    pub agreement: bool,
    /// bf16 on the CPU's fast path: the folds' convolutions on fp32 kernels over bf16 maps
    /// (`Emulated`) or on oneDNN's bf16 kernels (any other choice;
    /// [`crate::kernels::KernelPolicy::inference_convolutions`]).
    pub bf16_convolutions: rtf_amp::Bf16Convolutions,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            model: "mfnet".into(),
            num_classes: None,
            batch: 1,
            precision: Precision::Fp32,
            path: ForwardPath::Fast,
            layout: Layout::ChannelsLast,
            kernels: InferenceKernels::unmeasured(),
            height: 480,
            width: 640,
            warmup: 3,
            iterations: 10,
            weights: None,
            device: Device::Cpu,
            agreement: true,
            bf16_convolutions: rtf_amp::Bf16Policy::default().in_force(None),
        }
    }
}

#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct BenchReport {
    pub model: String,
    /// Outputs of the network timed (reports written before it was recorded: 0).
    #[serde(default)]
    pub num_classes: i64,
    pub batch: i64,
    pub precision: Precision,
    /// Median milliseconds per frame (one pass / batch).
    pub median_ms: f64,
    /// Fastest pass, milliseconds per frame.
    pub min_ms: f64,
    /// Frames per second at the median.
    pub fps: f64,
    pub path: ForwardPath,
    pub layout: Layout,
    pub height: i64,
    pub width: i64,
    pub iterations: usize,
    /// `cpu` or `cuda:N`.
    pub device: String,
    /// libtorch intra-op threads.
    pub threads: i32,
    /// Fast path only: fraction of pixels whose arg-max class equals the plain fp32 path's on
    /// the benchmark input (random weights, BatchNorm statistics as initialised).
    pub agreement_with_plain: Option<f64>,
    /// 95th percentile (nearest rank) of the timed passes, milliseconds per frame.
    #[serde(default)]
    pub p95_ms: f64,
    /// Every timed pass in order, milliseconds per frame.
    #[serde(default)]
    pub samples_ms: Vec<f64>,
    /// Peak resident memory of the process by the end of the timed passes (Linux `VmHWM`),
    /// MiB: libtorch, the network's weights (and the fast path's folded copies), the input and
    /// the passes' activations. The arg-max agreement is computed after it is read (on a
    /// second, plain copy of the network). None where unknown.
    #[serde(default)]
    pub peak_rss_mb: Option<f64>,
    /// The CPU the passes ran on (identity and kernel-deciding flags).
    #[serde(default)]
    pub cpu: CpuInfo,
    /// bf16 on the CPU's fast path: how its wide 3×3 convolutions ran, `winograd` (fp32
    /// arithmetic over bf16 maps) or `onednn` (oneDNN's bf16 kernels), as
    /// [`BenchReport::kernels`] says. None otherwise.
    #[serde(default)]
    pub bf16_3x3: Option<String>,
    /// Fast path: the kernels the fold took where there is a choice. None on the plain path.
    #[serde(default)]
    pub kernels: Option<InferenceKernels>,
    /// bf16 on the CPU's fast path: how the folds' convolutions ran, `emulated` (fp32 kernels
    /// over bf16 maps) or `native` (oneDNN's bf16 kernels). None otherwise.
    #[serde(default)]
    pub bf16_convolutions: Option<rtf_amp::Bf16Convolutions>,
    /// Fast path: MiB of the plain network's weights freed once folded (those the folded path
    /// does not read; `InferenceNet::releasing_plain_weights`). None on the plain path.
    #[serde(default)]
    pub plain_weights_released_mb: Option<f64>,
}

/// Median and minimum of a non-empty sample.
pub fn median_min(samples: &[f64]) -> (f64, f64) {
    let mut sorted = samples.to_vec();
    sorted.sort_by(|a, b| a.total_cmp(b));
    let n = sorted.len();
    let median = if n % 2 == 1 {
        sorted[n / 2]
    } else {
        (sorted[n / 2 - 1] + sorted[n / 2]) / 2.0
    };
    (median, sorted[0])
}

/// The 95th percentile of a non-empty sample (nearest rank: the ⌈0.95·n⌉-th smallest).
pub fn p95(samples: &[f64]) -> f64 {
    let mut sorted = samples.to_vec();
    sorted.sort_by(|a, b| a.total_cmp(b));
    let rank = (0.95 * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

/// The forward a benchmark times.
enum Timed {
    Fast(InferenceNet),
    Plain(Box<dyn Network>),
}

impl Timed {
    fn run(&self, input: &Tensor) -> Result<Tensor, ModelError> {
        match self {
            Timed::Fast(fast) => fast.forward_unchecked(input),
            Timed::Plain(net) => Ok(tch::no_grad(|| net.forward_t(input, false))),
        }
    }
}

/// The network `cfg` with weights drawn from libtorch's generator seeded with 0 (or loaded
/// from `opts.weights`): the same weights every time it is called.
fn seeded_network(
    opts: &BenchOptions,
    cfg: &ModelConfig,
) -> Result<(nn::VarStore, Box<dyn Network>), SpeedError> {
    tch::manual_seed(0);
    let mut vs = nn::VarStore::new(opts.device);
    let net = rtf_models::build(&vs.root(), cfg)?;
    if let Some(path) = &opts.weights {
        // Checked against the file's model metadata: timing mfnet-f with mfnet's file is refused.
        rtf_models::io::weights::load_checked(&mut vs, cfg, path, false)?;
    }
    Ok((vs, net))
}

/// Milliseconds per frame of `opts.iterations` timed passes after `opts.warmup` untimed ones.
fn time_passes(opts: &BenchOptions, timed: &Timed, input: &Tensor) -> Result<Vec<f64>, ModelError> {
    // CUDA kernels run asynchronously: wait for them before reading the clock.
    let synchronize = || {
        if let Device::Cuda(index) = opts.device {
            tch::Cuda::synchronize(index as i64);
        }
    };
    for _ in 0..opts.warmup {
        let _ = timed.run(input)?;
    }
    synchronize();
    let mut per_frame_ms = Vec::with_capacity(opts.iterations);
    for _ in 0..opts.iterations {
        let start = Instant::now();
        let out = timed.run(input)?;
        synchronize();
        drop(out);
        per_frame_ms.push(start.elapsed().as_secs_f64() * 1e3 / opts.batch as f64);
    }
    Ok(per_frame_ms)
}

fn check_options(opts: &BenchOptions) -> Result<(), SpeedError> {
    if opts.batch < 1 || opts.iterations < 1 {
        return Err(SpeedError::Options(
            "batch and iterations must be ≥ 1".into(),
        ));
    }
    if opts.path == ForwardPath::Plain && opts.precision != Precision::Fp32 {
        return Err(SpeedError::Options(
            "the plain path runs in fp32 only".into(),
        ));
    }
    rtf_models::fast::check_precision_on(opts.precision, opts.device)?;
    Ok(())
}

/// Builds the named network and times its forward on a random `[batch, 4, H, W]` input.
/// Weights (unless loaded) and input come from libtorch's generator seeded with 0, so runs
/// time the same computation and report the same agreement. The fast path's agreement with
/// the plain one is checked after the timing and the peak-memory reading, on a second copy of
/// the network built the same way, so neither the plain pass nor that copy counts in either.
pub fn bench_model(opts: &BenchOptions) -> Result<BenchReport, SpeedError> {
    check_options(opts)?;
    let classes = opts
        .num_classes
        .unwrap_or_else(|| rtf_models::default_num_classes(&opts.model));
    let cfg = ModelConfig::from_name(&opts.model, classes).map_err(ModelError::from)?;
    let (vs, net) = seeded_network(opts, &cfg)?;
    let mut released_mb = None;
    let shape = [opts.batch, 4, opts.height, opts.width];
    net.check_input(&shape)?;
    let input = Tensor::rand(shape, (Kind::Float, opts.device));
    let timed = match opts.path {
        ForwardPath::Fast => {
            let bf16_convolutions = match folds_emulated(opts) {
                true => rtf_amp::Bf16Convolutions::Emulated,
                false => rtf_amp::Bf16Convolutions::Native,
            };
            let kernels = InferenceKernels {
                bf16_convolutions,
                ..opts.kernels
            };
            let fold = FoldOptions::new(opts.precision)
                .layout(opts.layout)
                .kernels(kernels);
            let (fast, released) = InferenceNet::releasing_plain_weights(net, &fold, &vs)?;
            released_mb = Some(released.mib());
            Timed::Fast(fast)
        }
        ForwardPath::Plain => Timed::Plain(net),
    };
    let per_frame_ms = time_passes(opts, &timed, &input)?;
    let peak_rss_mb = peak_rss_mb();
    let agreement_with_plain = match &timed {
        Timed::Fast(_) if opts.agreement => {
            let (_plain_vs, plain_net) = seeded_network(opts, &cfg)?;
            let plain = Timed::Plain(plain_net).run(&input)?;
            Some(argmax_agreement(&plain, &timed.run(&input)?))
        }
        _ => None,
    };
    let (median_ms, min_ms) = median_min(&per_frame_ms);
    Ok(BenchReport {
        model: cfg.name(),
        num_classes: classes,
        batch: opts.batch,
        precision: opts.precision,
        median_ms,
        min_ms,
        fps: 1e3 / median_ms,
        path: opts.path,
        layout: opts.layout,
        height: opts.height,
        width: opts.width,
        iterations: opts.iterations,
        device: match opts.device {
            Device::Cuda(index) => format!("cuda:{index}"),
            _ => "cpu".into(),
        },
        threads: tch::get_num_threads(),
        agreement_with_plain,
        p95_ms: p95(&per_frame_ms),
        samples_ms: per_frame_ms,
        peak_rss_mb,
        cpu: CpuInfo::read(),
        bf16_3x3: bf16_3x3_kernels(opts),
        kernels: (opts.path == ForwardPath::Fast).then_some(opts.kernels),
        bf16_convolutions: fast_bf16_cpu(opts).then_some(match folds_emulated(opts) {
            true => rtf_amp::Bf16Convolutions::Emulated,
            false => rtf_amp::Bf16Convolutions::Native,
        }),
        plain_weights_released_mb: released_mb,
    })
}

/// Whether these options time bf16 on the CPU's fast path.
fn fast_bf16_cpu(opts: &BenchOptions) -> bool {
    opts.precision == Precision::Bf16
        && opts.path == ForwardPath::Fast
        && opts.device == Device::Cpu
}

/// Whether the fold computes its bf16 convolutions on fp32 kernels ([`BenchOptions::bf16_convolutions`]).
fn folds_emulated(opts: &BenchOptions) -> bool {
    opts.bf16_convolutions == rtf_amp::Bf16Convolutions::Emulated
}

/// [`BenchReport::bf16_3x3`] for these options.
fn bf16_3x3_kernels(opts: &BenchOptions) -> Option<String> {
    fast_bf16_cpu(opts).then(|| {
        (if opts.kernels.bf16_winograd {
            "winograd"
        } else {
            "onednn"
        })
        .to_string()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_and_min() {
        assert_eq!(median_min(&[3.0, 1.0, 2.0]), (2.0, 1.0));
        assert_eq!(median_min(&[4.0, 1.0, 2.0, 3.0]), (2.5, 1.0));
    }

    #[test]
    fn p95_is_the_nearest_rank() {
        let twenty: Vec<f64> = (1..=20).rev().map(f64::from).collect();
        assert_eq!(p95(&twenty), 19.0);
        assert_eq!(p95(&[5.0, 1.0, 3.0]), 5.0);
        assert_eq!(p95(&[2.0]), 2.0);
    }

    #[test]
    fn bench_reports_consistent_numbers_on_a_small_input() {
        // bench_model seeds, builds and draws its input: the lock keeps other tests' draws out.
        let _rng = crate::seeded_rng_lock();
        let opts = BenchOptions {
            height: 32,
            width: 48,
            warmup: 1,
            iterations: 3,
            batch: 2,
            ..Default::default()
        };
        let report = bench_model(&opts).unwrap();
        assert_eq!(report.model, "mfnet");
        assert_eq!(report.num_classes, 9);
        assert!(report.min_ms > 0.0 && report.min_ms <= report.median_ms);
        assert!((report.fps - 1e3 / report.median_ms).abs() < 1e-9);
        let json = serde_json::to_value(&report).unwrap();
        for key in [
            "model",
            "batch",
            "precision",
            "median_ms",
            "min_ms",
            "fps",
            "p95_ms",
            "cpu",
        ] {
            assert!(json.get(key).is_some(), "{key}");
        }
        assert_eq!(report.samples_ms.len(), 3);
        assert!(report.min_ms <= report.p95_ms && report.median_ms <= report.p95_ms);
        assert!(report.peak_rss_mb.is_some_and(|m| m > 1.0));
        assert_eq!(json["precision"], "fp32");
        assert!(report.agreement_with_plain.unwrap() >= 0.999);
        // Seeded weights and input: a bf16 run reports the same agreement (here ≈ 99.6 %, so a
        // different draw would show) every time.
        let bf16 = BenchOptions {
            precision: Precision::Bf16,
            iterations: 1,
            ..opts
        };
        let agreement = |o: &BenchOptions| bench_model(o).unwrap().agreement_with_plain.unwrap();
        let first = agreement(&bf16);
        assert_eq!(first, agreement(&bf16));
        let unchecked = BenchOptions {
            agreement: false,
            ..bf16
        };
        assert_eq!(bench_model(&unchecked).unwrap().agreement_with_plain, None);
    }

    #[test]
    fn bad_options_are_refused() {
        let _rng = crate::seeded_rng_lock();
        let opts = BenchOptions {
            height: 30,
            width: 48,
            ..Default::default()
        };
        assert!(bench_model(&opts)
            .unwrap_err()
            .to_string()
            .contains("multiples of 16"));
        let opts = BenchOptions {
            model: "nope".into(),
            ..Default::default()
        };
        assert!(bench_model(&opts).is_err());
        let opts = BenchOptions {
            path: ForwardPath::Plain,
            precision: Precision::Bf16,
            ..Default::default()
        };
        assert!(bench_model(&opts).is_err());
    }
}
