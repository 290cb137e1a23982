//! Training procedures: each an explicit step body over the networks it trains. The loop
//! mechanics they share (epochs, reseeding, checkpoints, validation, logging) live once in
//! [`crate::trainer`]. Every trained network has its own [`Trained`] (VarStore, optimiser,
//! schedule) saved under its role; teachers are [`Frozen`]: eval mode, no gradient, never saved.

mod adversarial;
mod build;
mod supervised;
mod teacher_student;

use rtf_amp::PrecisionOnDevice;
use std::collections::BTreeMap;

use rtf_data::Batch;
use rtf_models::{BuildOptions, Masked, Network, UnitKernels};
use tch::{nn::VarStore, Device, Kind, Tensor};

pub use crate::plan::teachers::check_teachers;
pub use adversarial::Adversarial;
pub use build::{adversarial_from, build_from, Spec};
pub use supervised::Supervised;
pub use teacher_student::TeacherStudent;

use crate::config::{Fp32Layout, OptimizerConfig, Precision, StepAt, TrainConfig};
use crate::error::TrainError;
use crate::loss::PseudoTargets;
use crate::optim::Optimizer;
use crate::plan::{CheckedTeacher, Teachers};

/// Role of the segmentation network every procedure trains (and validation scores).
pub const STUDENT: &str = "student";
/// Role of HeatNet's day/night critic.
pub const CRITIC: &str = "critic";

/// A network being trained: its variables, optimiser and learning-rate schedule, and the
/// arithmetic of its forward passes.
pub struct Trained {
    pub role: &'static str,
    pub vs: VarStore,
    pub optimizer: Optimizer,
    pub schedule: OptimizerConfig,
    pub precision: Precision,
    /// In a data-parallel run, the group whose ranks average this network's gradients.
    pub ddp: Option<std::sync::Arc<crate::ddp::Ddp>>,
    /// Whether fp32 training runs channels-last ([`fp32_channels_last`](Self::fp32_channels_last)).
    fp32_channels_last: bool,
    /// How this network's units compute, given to it when it is built ([`build_options`](
    /// Self::build_options)): the run's recorded Winograd forms
    /// ([`crate::config::ComputeConfig::winograd`]) and bf16 convolutions
    /// ([`crate::config::bf16_convolutions_in_force`]), and in a data-parallel
    /// run with synchronised BatchNorm, the group its BatchNorms sum their statistics over.
    pub kernels: UnitKernels,
}

impl Trained {
    /// An fp32 network (see [`mixed`](Self::mixed)).
    pub fn new(role: &'static str, device: Device, schedule: &OptimizerConfig) -> Self {
        Self {
            role,
            vs: VarStore::new(device),
            optimizer: Optimizer::new(schedule),
            schedule: schedule.clone(),
            precision: Precision::Fp32,
            ddp: None,
            fp32_channels_last: false,
            kernels: UnitKernels::default(),
        }
    }

    /// The same network with its units computing as `kernels` say (set before it is built).
    pub fn computing(mut self, kernels: UnitKernels) -> Self {
        self.kernels = kernels;
        self
    }

    /// What this network is built with ([`rtf_models::build_with`]): its kernels, its
    /// variables initialised.
    pub fn build_options(&self) -> BuildOptions {
        BuildOptions {
            kernels: self.kernels.clone(),
            uninitialised: false,
        }
    }

    /// Lays this network out channels-last in fp32 too where `on` (convolutional networks,
    /// [`Student::build`]) and the run's layout is channels-last ([`Fp32Layout`]).
    pub fn fp32_layout(self, on: bool, layout: Fp32Layout) -> Self {
        self.laid_out_fp32(on && layout == Fp32Layout::ChannelsLast)
    }

    /// fp32 channels-last (`true`) or NCHW, whatever the CPU.
    fn laid_out_fp32(mut self, channels_last: bool) -> Self {
        self.fp32_channels_last = channels_last;
        self
    }

    /// The same network trained in `precision`: its forward passes ([`autocast`](Self::autocast))
    /// in an autocast region, its loss scaled under fp16. Weights and optimiser state stay fp32.
    /// Fails where libtorch has no autocast of that type on the device (fp16 on a CPU).
    pub fn mixed(mut self, precision: Precision) -> Result<Self, TrainError> {
        if let Some(kind) = precision.autocast_kind() {
            let refused =
                |e: rtf_amp::AmpError| TrainError::Config(format!("--precision {precision}: {e}"));
            // Entered once here, so the regions of the steps cannot fail later.
            drop(rtf_amp::AutocastGuard::enter(self.vs.device(), kind).map_err(refused)?);
        }
        self.precision = precision;
        self.optimizer.set_loss_scaling(precision.scales_loss());
        Ok(self)
    }

    /// Whether this network's convolutions run channels-last: under mixed precision with
    /// libtorch's own reduced-precision kernels, which on the CPU take oneDNN's fast path only
    /// for channels-last operands (PyTorch users: `model.to(memory_format=channels_last)`);
    /// in fp32 where [`fp32_channels_last`](Self::fp32_channels_last) set it. Not with emulated
    /// bf16 convolutions (NCHW measured faster for them).
    pub fn channels_last(&self) -> bool {
        let emulated = self.precision == Precision::Bf16
            && self.vs.device() == Device::Cpu
            && self.kernels.bf16_convolutions == rtf_amp::Bf16Convolutions::Emulated;
        match self.precision {
            Precision::Fp32 => self.fp32_channels_last,
            _ => !emulated,
        }
    }

    /// Where [`channels_last`](Self::channels_last), lays the 4-D weights (convolution
    /// kernels) out channels-last (the weights' values and their checkpoints are unchanged).
    pub fn channels_last_weights(&self) {
        if !self.channels_last() {
            return;
        }
        tch::no_grad(|| {
            for (_, mut var) in self.vs.variables() {
                if var.dim() == 4 {
                    let laid_out = rtf_models::layers::to_channels_last(&var);
                    var.set_data(&laid_out);
                }
            }
        });
    }

    /// `f` (forward passes) in this network's arithmetic: as is in fp32, else inside an
    /// autocast region to bf16 / fp16 on the network's device.
    pub fn autocast<T>(&self, f: impl FnOnce() -> T) -> T {
        match self.precision.autocast_kind() {
            None => f(),
            Some(kind) => {
                let _region = rtf_amp::AutocastGuard::enter(self.vs.device(), kind)
                    .expect("autocast on this device was entered once in Trained::mixed");
                f()
            }
        }
    }

    /// Gradients of `loss` into this network's variables (averaged over the ranks of a
    /// data-parallel run), then one update at the rate of step `at` (under fp16 the loss is scaled,
    /// and a step whose gradients overflowed is skipped; the scaled gradients are averaged and
    /// unscaled in the step).
    pub fn minimise(&mut self, loss: &Tensor, at: StepAt) {
        self.optimizer.zero_grad(&self.vs);
        self.optimizer.scale_loss(loss).backward();
        // A failed all-reduce (a dead rank) skips the update; the trainer then stops.
        if self
            .ddp
            .as_ref()
            .is_some_and(|d| !d.average_gradients(&self.vs))
        {
            return;
        }
        self.optimizer.step(&self.vs, self.schedule.lr_at(at));
    }
}

/// The segmentation network a procedure trains, with the channels it sees.
pub struct Student {
    pub trained: Trained,
    pub net: Masked,
}

impl Student {
    /// Built under `seed` as the supervised loop always did (same initial weights), in one
    /// process (its BatchNorms not synchronised).
    pub fn build(cfg: &TrainConfig, device: Device) -> Result<Self, TrainError> {
        Self::of(&cfg.network, &cfg.learning, &cfg.compute, None, device)
    }

    /// Training-mode logits for `input` [B, 4, H, W]; sizes that are not a multiple of the
    /// network's stride are padded (replicating the border) and the logits cropped back.
    /// Under mixed precision the forward pass runs in its autocast region and the logits come
    /// back as fp32, so every loss is computed in fp32.
    pub fn logits(&self, input: &Tensor) -> Tensor {
        // Channels-last activations from the first layer on where the kernels want them
        // (`Trained::channels_last`).
        let input = match self.trained.channels_last() {
            true => rtf_models::layers::to_channels_last(input),
            false => input.shallow_clone(),
        };
        match self.trained.precision {
            Precision::Fp32 => forward_padded(&self.net, &input, true),
            _ => self
                .trained
                .autocast(|| forward_padded(&self.net, &input, true).to_kind(Kind::Float)),
        }
    }
}

/// `net` on `x`, padded up to its size multiple and cropped back.
pub fn forward_padded(net: &dyn Network, x: &Tensor, train: bool) -> Tensor {
    let size = x.size();
    let (h, w) = (size[2], size[3]);
    let m = net.size_multiple().max(1);
    let (ph, pw) = ((m - h % m) % m, (m - w % m) % m);
    if ph == 0 && pw == 0 {
        return net.forward_t(x, train);
    }
    let padded = x.pad([0, pw, 0, ph], "replicate", None);
    net.forward_t(&padded, train)
        .narrow(2, 0, h)
        .narrow(3, 0, w)
}

/// A teacher: a trained network that labels frames for a student. Eval mode, no gradient,
/// never saved.
pub struct Frozen {
    _vs: VarStore,
    net: Masked,
}

impl Frozen {
    /// Loads a teacher checked to teach the student ([`crate::plan::Teachers`]): its
    /// weights into its network, behind its input mask.
    pub fn load(teacher: &CheckedTeacher, device: Device) -> Result<Self, TrainError> {
        let mut vs = VarStore::new(device);
        let inner = rtf_models::build(&vs.root(), &teacher.model)?;
        rtf_models::io::weights::load_checked(&mut vs, &teacher.model, &teacher.path, false)?;
        vs.freeze();
        Ok(Self {
            _vs: vs,
            net: Masked {
                inner,
                inputs: teacher.inputs,
            },
        })
    }

    /// The teacher's targets for `input` (HeatNet eq. 1's M_D(I)).
    pub fn targets(&self, input: &Tensor, threshold: Option<f64>) -> PseudoTargets {
        let logits = tch::no_grad(|| forward_padded(&self.net, input, false).to_kind(Kind::Float));
        PseudoTargets::from_logits(&logits, threshold)
    }
}

/// The batches of one step: the main stream's (labelled frames for supervised training, day
/// frames otherwise) and, for procedures that use them, the night stream's.
pub struct StepBatches {
    pub main: Batch,
    pub night: Option<Batch>,
}

/// What one step reports: the student's total objective (checked for divergence, logged as
/// `train_loss`), every loss term by name, and training metrics (the critic's accuracies).
#[derive(Debug, Default)]
pub struct StepReport {
    pub total: f64,
    pub terms: BTreeMap<String, f64>,
    pub metrics: BTreeMap<String, f64>,
}

/// Where a batch's targets come from: its teacher, run now, or the teacher's cached labels the
/// batch carries.
pub struct Labeller {
    pub teacher: Frozen,
    /// The ignore id of cached labels; None = run the teacher.
    pub cached: Option<i64>,
}

impl Labeller {
    pub fn targets(&self, batch: &Batch, threshold: Option<f64>) -> PseudoTargets {
        match self.cached {
            Some(ignore) => PseudoTargets::from_labels(&batch.target, ignore),
            None => self.teacher.targets(&batch.input, threshold),
        }
    }
}

/// One training procedure's networks and step body.
pub trait Procedure {
    /// The networks it trains (checkpointed under their roles), student first.
    fn trained(&self) -> Vec<&Trained>;
    fn trained_mut(&mut self) -> Vec<&mut Trained>;
    /// The network validation scores and whose weights `best`/`final` hold.
    fn student(&self) -> &Student;
    /// One optimisation step (inputs already on the device) at `at` in the run.
    fn step(&mut self, batches: &StepBatches, at: StepAt) -> Result<StepReport, TrainError>;
    /// The day and night labellers, for a label cache.
    fn labellers(&self) -> (Option<&Labeller>, Option<&Labeller>) {
        (None, None)
    }
    /// The run's steps done before this process (a resumed run), for procedures whose step
    /// body depends on the step count.
    fn resume_at(&mut self, _steps_done: u64) {}
}

/// Builds the procedure `cfg` names, its teachers (weights files) checked first
/// ([`build_from`], which the trainer calls with its run plan's parts).
pub fn build(
    cfg: &TrainConfig,
    ignore_id: Option<u8>,
    device: Device,
) -> Result<Box<dyn Procedure>, TrainError> {
    let teachers = Teachers::check(&cfg.learning.procedure, &cfg.network.model)?;
    build_from(&Spec::of(cfg, &teachers), ignore_id, device)
}

/// [`build`] of an adversarial `cfg`, as its own type (whose two step halves can be driven
/// one at a time).
pub fn build_adversarial(
    cfg: &TrainConfig,
    ignore_id: Option<u8>,
    device: Device,
) -> Result<Adversarial, TrainError> {
    let teachers = Teachers::check(&cfg.learning.procedure, &cfg.network.model)?;
    adversarial_from(&Spec::of(cfg, &teachers), ignore_id, device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtf_models::ModelConfig;

    /// One fp32 SGD step of a randomly initialised RTFNet-18, channels-last and NCHW, from the
    /// same weights on the same batch: every variable's update the same up to rounding (the
    /// training parity run's larger drift over 4 steps is that rounding amplified by a chaotic
    /// start, docs/src/training.md, not another computation).
    #[test]
    fn fp32_channels_last_step_equals_the_nchw_step() {
        let mut cfg = TrainConfig::mfnet_paper("unused".into());
        cfg.network.model = ModelConfig::from_name("rtfnet18", 9).unwrap();
        let build = |channels_last: bool| {
            let trained = Trained::new(STUDENT, Device::Cpu, &cfg.learning.optimizer)
                .laid_out_fp32(channels_last);
            let inner = rtf_models::build(&trained.vs.root(), &cfg.network.model).unwrap();
            trained.channels_last_weights();
            let inputs = cfg.network.inputs;
            Student {
                trained,
                net: Masked { inner, inputs },
            }
        };
        let (mut nchw, mut nhwc) = (build(false), build(true));
        nhwc.trained.vs.copy(&nchw.trained.vs).unwrap();
        assert!(nhwc.trained.channels_last() && !nchw.trained.channels_last());
        let before: BTreeMap<String, Tensor> = (nchw.trained.vs.variables().into_iter())
            .map(|(k, v)| (k, v.copy()))
            .collect();
        tch::manual_seed(7);
        let x = Tensor::rand([2, 4, 64, 96], (Kind::Float, Device::Cpu));
        let y = Tensor::randint(9, [2, 64, 96], (Kind::Int64, Device::Cpu));
        let loss_fn = crate::loss::build(&cfg.learning.loss, None, Device::Cpu);
        for student in [&mut nchw, &mut nhwc] {
            let loss = loss_fn.compute(&student.logits(&x), &y);
            let trained = &mut student.trained;
            trained.optimizer.zero_grad(&trained.vs);
            loss.backward();
            trained.optimizer.step(&trained.vs, 0.01);
        }
        let (a, b) = (nchw.trained.vs.variables(), nhwc.trained.vs.variables());
        let (mut diff, mut norm) = (0.0, 0.0);
        for (name, w0) in &before {
            let (da, db) = (&a[name] - w0, &b[name] - w0);
            diff += f64::try_from((&da - &db).square().sum(Kind::Double)).unwrap();
            norm += f64::try_from(da.square().sum(Kind::Double)).unwrap();
        }
        let relative = (diff / norm).sqrt();
        // The two layouts sum in other orders, and one step of a BatchNorm network already
        // shows it: the biases before a BatchNorm have a true gradient of 0 and get rounding
        // alone (measured 1.2e-3 of the whole update on a Xeon model 167, other draws and
        // kinds round otherwise). A wrong layout (weights or maps read in the other order) is
        // a difference of order 1; the bound is the step-for-step comparison's with PyTorch.
        println!("channels-last against NCHW: update difference {relative:.2e}");
        assert!(
            norm > 0.0 && relative < 1e-2,
            "update difference {relative:.2e}"
        );
    }

    fn student(precision: Precision) -> Student {
        student_convolving(precision, None)
    }

    fn student_convolving(
        precision: Precision,
        convolutions: Option<rtf_amp::Bf16Convolutions>,
    ) -> Student {
        let mut cfg = TrainConfig::mfnet_paper("unused".into());
        cfg.learning.precision = precision;
        cfg.compute.bf16_convolutions = convolutions;
        Student::build(&cfg, Device::Cpu).unwrap()
    }

    /// The run's recorded Winograd forms and bf16 convolutions are the kernels its student is
    /// built with (every unit keeps its build's: rtf-models' `layers::Path`).
    #[test]
    fn the_recorded_kernels_are_those_the_networks_are_built_with() {
        use rtf_amp::Bf16Convolutions::*;
        use rtf_kernels::winograd::Forms;
        for (forms, choice) in [
            (Forms::All, Native),
            (Forms::Off, Emulated),
            (Forms::F23, Mixed),
        ] {
            let mut cfg = TrainConfig::mfnet_paper("unused".into());
            cfg.learning.precision = Precision::Bf16;
            cfg.compute.bf16_convolutions = Some(choice);
            cfg.compute.winograd = forms;
            let s = Student::build(&cfg, Device::Cpu).unwrap();
            let built = s.trained.build_options();
            assert_eq!(built.kernels.winograd, forms);
            assert_eq!(built.kernels.bf16_convolutions, choice);
            assert!(built.kernels.sync.is_none() && !built.uninitialised);
            assert_eq!(s.trained.channels_last(), choice != Emulated);
        }
    }

    /// Under bf16 the forward pass runs in bf16 (its logits differ from fp32's by bf16's
    /// rounding, not more), the logits come back fp32, and the BatchNorm statistics it updates
    /// stay fp32; with each choice of convolutions.
    #[test]
    fn bf16_logits_are_fp32_and_close_to_fp32_logits() {
        use rtf_amp::Bf16Convolutions::*;
        for choice in [Native, Emulated, Mixed] {
            bf16_logits_are_close_with(choice);
        }
    }

    fn bf16_logits_are_close_with(choice: rtf_amp::Bf16Convolutions) {
        let fp32 = student(Precision::Fp32);
        let mut bf16 = student_convolving(Precision::Bf16, Some(choice));
        // The seed is process-wide and other tests train beside this one: the same seed does
        // not promise the same weights, so the bf16 student gets the fp32 one's (the CI run of
        // stop 36 compared two different networks).
        bf16.trained.vs.copy(&fp32.trained.vs).unwrap();
        let x = Tensor::rand([2, 4, 32, 32], (Kind::Float, Device::Cpu));
        let (a, b) = (fp32.logits(&x), bf16.logits(&x));
        assert_eq!(b.kind(), Kind::Float);
        assert!(b.requires_grad());
        let diff = f64::try_from((&a - &b).abs().max()).unwrap();
        let scale = f64::try_from(a.abs().max()).unwrap();
        assert!(diff > 0.0, "bf16 arithmetic leaves a trace");
        assert!(diff < 0.1 * scale, "max |Δ| {diff} vs max |logit| {scale}");
        let stats: Vec<_> = bf16
            .trained
            .vs
            .variables()
            .into_iter()
            .filter(|(n, _)| n.ends_with("running_mean") || n.ends_with("running_var"))
            .collect();
        assert!(!stats.is_empty());
        for (name, t) in stats {
            assert_eq!(t.kind(), Kind::Float, "{name}");
        }
        // Gradients reach the fp32 master weights.
        b.sum(Kind::Float).backward();
        let grads = optim_grads(&bf16.trained.vs);
        assert!(grads > 0 && grads == crate::optim::trainable(&bf16.trained.vs).len());
    }

    fn optim_grads(vs: &VarStore) -> usize {
        crate::optim::trainable(vs)
            .into_iter()
            .filter(|(_, t)| t.grad().defined() && t.grad().kind() == Kind::Float)
            .count()
    }

    #[test]
    fn fp16_student_on_a_cpu_is_refused() {
        let mut cfg = TrainConfig::mfnet_paper("unused".into());
        cfg.learning.precision = Precision::Fp16;
        let err = Student::build(&cfg, Device::Cpu).err().unwrap().to_string();
        assert!(err.contains("fp16"), "{err}");
    }
}
