//! Training-step throughput: steady-state images/s of full supervised steps (forward, loss,
//! backward, optimiser update) of a network on random frames, the step the trainer runs
//! ([`crate::procedure::Student`], the configured loss, [`crate::procedure::Trained`]'s
//! update), and the process's peak resident memory. The frames are made once, in memory, so
//! no data pipeline is timed (`rtf bench data` times that). `lab/bench/bench_torch_train.py`
//! runs the same step in PyTorch.

use rtf_amp::PrecisionOnDevice;
use std::time::Instant;

use serde::Serialize;
use tch::{Device, Kind, Tensor};

use crate::config::{OptimizerConfig, Precision, TrainConfig};
use crate::error::TrainError;
use crate::procedure::Student;
use rtf_kernels::aten::{count_ops, OpCounts};
use rtf_models::ModelError;

/// What to time.
#[derive(Debug, Clone)]
pub struct TrainBenchOptions {
    pub model: String,
    pub batch: usize,
    /// (width, height).
    pub size: (usize, usize),
    pub precision: Precision,
    pub device: Device,
    /// Untimed steps first (allocator and oneDNN caches warm up).
    pub warmup: usize,
    /// Timed steps.
    pub steps: usize,
    pub optimizer: OptimizerConfig,
    /// After the timed steps, one more with its operators counted ([`StepOpCounts`]).
    pub count_ops: bool,
    /// fp32: the layout of the feature maps (None: the faster on the device).
    pub fp32_layout: Option<crate::config::Fp32Layout>,
    /// bf16 on the CPU: the convolutions (None: [`crate::config::bf16_convolutions_in_force`]'s
    /// default; `rtf bench train` passes the choice `rtf train` would make).
    pub bf16_convolutions: Option<rtf_amp::Bf16Convolutions>,
    /// The Winograd forms the training convolutions may take (`rtf bench train` passes the
    /// policy's, as `rtf train` records it).
    pub winograd: rtf_kernels::winograd::Forms,
}

/// The operators one step runs, part by part ([`rtf_kernels::aten::count_ops`]): the host's
/// share of a step, which on a GPU is one or more kernel launches each.
/// `lab/bench/profile_train_torch.py --counts` counts PyTorch's step the same way.
#[derive(Debug, Clone, Serialize)]
pub struct StepOpCounts {
    /// Forward and loss.
    pub forward: OpCounts,
    /// Zeroing the gradients and the backward pass.
    pub backward: OpCounts,
    pub optimizer: OpCounts,
}

/// Timings of the steps (the `rtf bench train --json` record).
#[derive(Debug, Clone, Serialize)]
pub struct TrainBenchReport {
    pub model: String,
    pub batch: usize,
    /// "WxH".
    pub size: String,
    pub precision: String,
    /// The convolutions' arithmetic ("fp32", "bf16 emulated", "bf16 native", ...).
    pub convolutions: String,
    pub device: String,
    pub threads: i32,
    /// Images per second over all timed steps.
    pub images_per_s: f64,
    /// Median seconds of one step, and of its parts (on CUDA the parts come from further
    /// steps synchronised between parts; the step and the rate from steps timed whole).
    pub step_s: f64,
    pub forward_s: f64,
    pub backward_s: f64,
    pub optimizer_s: f64,
    /// Peak resident memory of the process (Linux `VmHWM`), MiB; None where unknown.
    pub peak_rss_mb: Option<f64>,
    pub steps: usize,
    /// The CPU the steps ran on (identity and kernel-deciding flags).
    pub cpu: rtf_core::host::CpuInfo,
    /// With [`TrainBenchOptions::count_ops`]: the operators of one further step.
    pub op_counts: Option<StepOpCounts>,
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    match values.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => values[n / 2],
        n => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

pub use rtf_core::host::peak_rss_mb;

/// Waits for the device's queued work (a no-op on the CPU), so step times are real.
fn sync(device: Device) {
    if let Device::Cuda(i) = device {
        tch::Cuda::synchronize(i as i64);
    }
}

/// Times `opts.steps` training steps after `opts.warmup` untimed ones. On CUDA the steps are
/// timed whole, as PyTorch's loop runs them (the host queues the next part while the device
/// works), and the parts are timed in as many further steps, synchronised between parts.
pub fn bench_train(opts: &TrainBenchOptions) -> Result<TrainBenchReport, TrainError> {
    let cfg = bench_config(opts)?;
    tch::manual_seed(0);
    let mut bench = Bench {
        student: Student::build(&cfg, opts.device)?,
        loss_fn: crate::loss::build(&cfg.learning.loss, None, opts.device),
        // The base rate: a schedule's first step may be 0 (a warm-up), and time does not care.
        lr: cfg.learning.optimizer.lr,
        device: opts.device,
        steps_run: 0,
    };
    let (w, h) = (opts.size.0 as i64, opts.size.1 as i64);
    let b = opts.batch as i64;
    let input = Tensor::rand([b, 4, h, w], (Kind::Float, opts.device));
    let target = Tensor::randint(9, [b, h, w], (Kind::Int64, opts.device));
    let batch = (&input, &target);
    let split_apart = opts.device.is_cuda();
    bench.run(batch, opts.warmup, true)?;
    let whole = bench.run(batch, opts.steps, !split_apart)?;
    let parts = match split_apart {
        true => bench.run(batch, opts.steps, true)?,
        false => whole.clone(),
    };
    let op_counts = opts.count_ops.then(|| counted_step(&mut bench, batch));
    let mut steps: Vec<f64> = whole.iter().map(|p| p.iter().sum()).collect();
    let total: f64 = steps.iter().sum();
    let part = |i: usize| median(&mut parts.iter().map(|p| p[i]).collect::<Vec<_>>());
    Ok(TrainBenchReport {
        model: opts.model.clone(),
        batch: opts.batch,
        size: format!("{}x{}", opts.size.0, opts.size.1),
        precision: opts.precision.name().into(),
        convolutions: opts.precision.convolutions_on(
            opts.device,
            crate::config::bf16_convolutions_in_force(&cfg.compute),
        ),
        device: cfg.compute.device.clone(),
        threads: tch::get_num_threads(),
        images_per_s: (opts.steps * opts.batch) as f64 / total,
        step_s: median(&mut steps),
        forward_s: part(0),
        backward_s: part(1),
        optimizer_s: part(2),
        peak_rss_mb: peak_rss_mb(),
        steps: opts.steps,
        cpu: rtf_core::host::CpuInfo::read(),
        op_counts,
    })
}

/// The network, loss and rate being timed, and the steps run so far.
struct Bench {
    student: Student,
    loss_fn: Box<dyn crate::loss::Loss>,
    lr: f64,
    device: Device,
    steps_run: u64,
}

impl Bench {
    /// `count` steps; each one's [forward and loss, backward, optimiser] seconds, the parts
    /// synchronised apart where `split` (else only the sum is a time).
    fn run(
        &mut self,
        batch: (&Tensor, &Tensor),
        count: usize,
        split: bool,
    ) -> Result<Vec<[f64; 3]>, TrainError> {
        (0..count)
            .map(|_| {
                self.steps_run += 1;
                timed_step(self, batch, split).map_err(|what| TrainError::Diverged {
                    epoch: 0,
                    step: self.steps_run - 1,
                    what,
                })
            })
            .collect()
    }
}

/// The supervised training config the benchmark's options describe (MFNet's paper recipe
/// with the network, optimiser, precision, batch and device replaced).
fn bench_config(opts: &TrainBenchOptions) -> Result<TrainConfig, TrainError> {
    if opts.batch == 0 || opts.steps == 0 || opts.size.0 == 0 || opts.size.1 == 0 {
        return Err(TrainError::Config(
            "bench train: batch, steps, width and height must be at least 1".into(),
        ));
    }
    let mut cfg = TrainConfig::mfnet_paper("unused".into());
    cfg.network.model =
        rtf_models::ModelConfig::from_name(&opts.model, 9).map_err(ModelError::from)?;
    cfg.learning.optimizer = opts.optimizer.clone();
    cfg.learning.precision = opts.precision;
    cfg.schedule.batch_size = opts.batch;
    cfg.compute.fp32_layout = opts.fp32_layout;
    cfg.compute.bf16_convolutions = opts.bf16_convolutions;
    cfg.compute.winograd = opts.winograd;
    cfg.compute.device = match opts.device {
        Device::Cpu => "cpu".into(),
        Device::Cuda(i) => format!("cuda:{i}"),
        other => {
            return Err(TrainError::Config(format!(
                "bench train: unsupported device {other:?}"
            )))
        }
    };
    cfg.validate()?;
    Ok(cfg)
}

/// One step of `Supervised::step`, timed part by part: [forward and loss, backward,
/// optimiser] in seconds, synchronised between parts where `split` (the last part always ends
/// synchronised: the loss's value is read); the loss's value when it is not finite.
fn timed_step(
    bench: &mut Bench,
    batch: (&Tensor, &Tensor),
    split: bool,
) -> Result<[f64; 3], String> {
    let between_parts = |device| {
        if split {
            sync(device)
        }
    };
    let t0 = Instant::now();
    let loss = bench.forward_loss(batch);
    between_parts(bench.device);
    let t1 = Instant::now();
    bench.backward(&loss);
    between_parts(bench.device);
    let t2 = Instant::now();
    bench.update();
    let value = f64::try_from(&loss).unwrap_or(f64::NAN);
    sync(bench.device);
    let t3 = Instant::now();
    if !value.is_finite() {
        return Err(format!("loss is {value}"));
    }
    Ok([t1 - t0, t2 - t1, t3 - t2].map(|d| d.as_secs_f64()))
}

/// The same step's parts, each with its operators counted instead of timed.
fn counted_step(bench: &mut Bench, batch: (&Tensor, &Tensor)) -> StepOpCounts {
    let (loss, forward) = count_ops(|| bench.forward_loss(batch));
    let ((), backward) = count_ops(|| bench.backward(&loss));
    let ((), optimizer) = count_ops(|| bench.update());
    sync(bench.device);
    StepOpCounts {
        forward,
        backward,
        optimizer,
    }
}

impl Bench {
    /// A step's first part: the network's logits and the loss.
    fn forward_loss(&self, (input, target): (&Tensor, &Tensor)) -> Tensor {
        let logits = self.student.logits(input);
        self.loss_fn.compute(&logits, target)
    }

    /// Its second: the gradients zeroed, the (scaled) loss back-propagated.
    fn backward(&mut self, loss: &Tensor) {
        let trained = &mut self.student.trained;
        trained.optimizer.zero_grad(&trained.vs);
        trained.optimizer.scale_loss(loss).backward();
    }

    /// Its third: the optimiser's update at the base rate.
    fn update(&mut self) {
        let trained = &mut self.student.trained;
        trained.optimizer.step(&trained.vs, self.lr);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options(precision: Precision) -> TrainBenchOptions {
        TrainBenchOptions {
            model: "mfnet".into(),
            batch: 2,
            size: (64, 32),
            precision,
            device: Device::Cpu,
            warmup: 1,
            steps: 2,
            optimizer: OptimizerConfig::mfnet_paper(),
            count_ops: false,
            fp32_layout: None,
            bf16_convolutions: None,
            winograd: rtf_kernels::winograd::Forms::All,
        }
    }

    /// The counted step's parts hold what each part runs: convolutions forward, their
    /// backward nodes and the gradients' zeroing (one call for them all) in the backward part,
    /// the fused SGD update (one call per decay group, not one per parameter) in the optimiser,
    /// and nothing else there.
    #[test]
    fn counts_the_operators_of_each_part_of_a_step() {
        let report = bench_train(&TrainBenchOptions {
            count_ops: true,
            ..options(Precision::Fp32)
        })
        .unwrap();
        let counts = report.op_counts.expect("counted");
        let outermost = |part: &OpCounts, name: &str| part.get(name).map_or(0, |c| c.1);
        assert!(
            counts.forward.get("aten::conv2d").is_some_and(|c| c.0 > 10),
            "{:?}",
            counts.forward
        );
        assert!(
            counts
                .backward
                .keys()
                .any(|k| k.contains("ConvolutionBackward")),
            "{:?}",
            counts.backward
        );
        assert_eq!(outermost(&counts.backward, "aten::_foreach_zero_"), 1);
        assert_eq!(outermost(&counts.backward, "aten::zero_"), 0);
        let fused = outermost(&counts.optimizer, "aten::_fused_sgd_");
        assert!((1..=2).contains(&fused), "{:?}", counts.optimizer);
        // Every parameter in the fused calls, none written out (a 1×1 kernel's gradient may
        // differ from it in the strides of its size-1 dimensions only).
        let updates: u64 = counts.optimizer.values().map(|c| c.1).sum();
        assert_eq!(updates, fused, "{:?}", counts.optimizer);
    }

    #[test]
    fn reports_consistent_numbers_on_a_small_input() {
        for precision in [Precision::Fp32, Precision::Bf16] {
            let report = bench_train(&options(precision)).unwrap();
            assert_eq!(report.size, "64x32");
            assert_eq!(report.precision, precision.name());
            assert!(report.images_per_s > 0.0 && report.images_per_s.is_finite());
            let parts = report.forward_s + report.backward_s + report.optimizer_s;
            assert!(parts > 0.0 && report.step_s > 0.0);
            assert!(report.peak_rss_mb.is_some_and(|m| m > 1.0));
        }
    }

    #[test]
    fn bad_options_are_refused() {
        let err = bench_train(&TrainBenchOptions {
            steps: 0,
            ..options(Precision::Fp32)
        })
        .unwrap_err();
        assert!(err.to_string().contains("steps"), "{err}");
        let err = bench_train(&TrainBenchOptions {
            model: "nonet".into(),
            ..options(Precision::Fp32)
        })
        .unwrap_err();
        assert!(err.to_string().contains("nonet"), "{err}");
        let err = bench_train(&options(Precision::Fp16)).unwrap_err();
        assert!(err.to_string().contains("fp16"), "{err}");
    }
}
