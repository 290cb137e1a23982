//! Building blocks shared by the networks: convolution (+ BatchNorm) (+ activation) units that
//! can fold their BatchNorm for inference, and the activations.
//!
//! A [`ConvBnAct`] owns its variables under the reference names (`<conv>.weight`,
//! `<bn>.running_mean`, …) and has one forward, training or eval. [`Fold::folded`] builds a new
//! unit from it for inference: the convolution weight and bias with an eval-mode BatchNorm
//! folded in, laid out and cast as the fold says, run by [`crate::fast::unit::FoldedConv`]
//! (one convolution with the activation fused in).

use tch::{nn, Kind, Tensor};

pub use crate::bn_defaults::{BN_EPS, BN_MOMENTUM};
pub use crate::sync_bn::BatchNorm;

use crate::fast::unit::FoldedConv;
use rtf_amp::Bf16Convolutions;
pub use rtf_kernels::aten::bf16_emulated_convolution;
use rtf_kernels::onednn::Geometry;
use rtf_kernels::winograd::Forms;

mod fold;
pub mod ops;
mod path;
pub use crate::fast::folder::{Fold, Folder};
pub use fold::batch_norm_affine;
pub use ops::{is_channels_last, leaky_relu, leaky_relu_inference, to_channels_last, Act};
use ops::{nearest_up2_conv3x3_as_phases, phase_taps};
pub use path::{BuildOptions, Path, UnitKernels};

/// BatchNorm2d initialised as PyTorch's (weight 1, bias 0; tch's default weight is U(0, 1)).
pub fn bn2d(p: Path, c: i64) -> BatchNorm {
    bn2d_init(p, c, nn::Init::Const(1.0))
}

/// BatchNorm2d with a given weight initialisation and bias 0.
pub fn bn2d_init(p: Path, c: i64, weight: nn::Init) -> BatchNorm {
    bn2d_with(p, c, weight, BN_EPS)
}

/// BatchNorm2d with a given weight initialisation, bias 0 and eps (momentum [`BN_MOMENTUM`]),
/// its training-mode statistics synchronised where the build's kernels say
/// ([`UnitKernels::sync`]).
pub fn bn2d_with(p: Path, c: i64, weight: nn::Init, eps: f64) -> BatchNorm {
    let cfg = nn::BatchNormConfig {
        eps,
        momentum: BN_MOMENTUM,
        ws_init: effective_init(&p, weight),
        bs_init: nn::Init::Const(0.0),
        ..Default::default()
    };
    let sync = p.kernels().sync.clone();
    BatchNorm::new(nn::batch_norm2d(p.nn(), c, cfg), eps, sync)
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WeightInit {
    /// PyTorch's `Conv2d` default: U(±1/√fan_in) (kaiming_uniform with a = √5).
    TorchDefault,
    /// torchvision ResNet: kaiming_normal, fan_out, ReLU gain.
    KaimingNormalFanOut,
    /// kaiming_normal, fan_in, ReLU gain: N(0, √(2/N)) with N the incoming connections
    /// (U-Net, Ronneberger et al. 2015, §3).
    KaimingNormalFanIn,
    /// Xavier/Glorot uniform (RTFNet decoder).
    XavierUniform,
    /// N(0, std) (HeatNet).
    Normal(f64),
}

/// Initialisation of a convolution and its BatchNorm, as one network's reference applies it.
#[derive(Debug, Clone, Copy)]
pub struct InitScheme {
    pub conv: WeightInit,
    pub bn_weight: nn::Init,
}

impl InitScheme {
    /// torchvision ResNet: kaiming-normal fan-out convolutions, BN weight 1.
    pub const TORCHVISION: InitScheme = InitScheme {
        conv: WeightInit::KaimingNormalFanOut,
        bn_weight: nn::Init::Const(1.0),
    };
    /// HeatNet's `weights_init_normal`: conv N(0, 0.02), BN weight N(1, 0.02).
    pub const NORMAL_002: InitScheme = InitScheme {
        conv: WeightInit::Normal(0.02),
        bn_weight: nn::Init::Randn {
            mean: 1.0,
            stdev: 0.02,
        },
    };
}

/// Shape and options of a 2-D (possibly transposed) convolution.
#[derive(Debug, Clone, Copy)]
pub struct ConvSpec {
    pub kernel: i64,
    pub stride: i64,
    pub padding: i64,
    pub dilation: i64,
    pub groups: i64,
    pub bias: bool,
    pub transposed: bool,
    pub init: WeightInit,
    /// Initialisation of the following BatchNorm's weight (PyTorch: 1).
    pub bn_weight_init: nn::Init,
    /// The following BatchNorm's eps (PyTorch: [`BN_EPS`]).
    pub bn_eps: f64,
    /// The unit is always fed a nearest ×2 upsampled map (through
    /// [`ConvBnAct::forward_upsampled`]), so folding also prepares the transposed-convolution
    /// form of that pair.
    pub nearest_upsampled_input: bool,
}

impl ConvSpec {
    /// k×k, stride 1, "same" padding for odd k, no bias, PyTorch's default init.
    pub fn new(kernel: i64) -> Self {
        Self {
            kernel,
            stride: 1,
            padding: kernel / 2,
            dilation: 1,
            groups: 1,
            bias: false,
            transposed: false,
            init: WeightInit::TorchDefault,
            bn_weight_init: nn::Init::Const(1.0),
            bn_eps: BN_EPS,
            nearest_upsampled_input: false,
        }
    }
    pub fn bn_eps(self, bn_eps: f64) -> Self {
        Self { bn_eps, ..self }
    }
    pub fn bn_weight_init(self, bn_weight_init: nn::Init) -> Self {
        Self {
            bn_weight_init,
            ..self
        }
    }
    pub fn scheme(self, scheme: InitScheme) -> Self {
        Self {
            init: scheme.conv,
            bn_weight_init: scheme.bn_weight,
            ..self
        }
    }
    pub fn stride(self, stride: i64) -> Self {
        Self { stride, ..self }
    }
    pub fn padding(self, padding: i64) -> Self {
        Self { padding, ..self }
    }
    /// Dilation d with padding d·(k−1)/2, keeping the size for stride 1.
    pub fn dilation(self, dilation: i64) -> Self {
        Self {
            dilation,
            padding: dilation * (self.kernel - 1) / 2,
            ..self
        }
    }
    pub fn bias(self, bias: bool) -> Self {
        Self { bias, ..self }
    }
    pub fn init(self, init: WeightInit) -> Self {
        Self { init, ..self }
    }
    /// See [`ConvSpec::nearest_upsampled_input`]; only for 3×3, stride-1, padding-1,
    /// undilated, ungrouped convolutions.
    pub fn nearest_upsampled_input(self) -> Self {
        assert!(
            self.kernel == 3
                && self.stride == 1
                && self.padding == 1
                && self.dilation == 1
                && self.groups == 1
                && !self.transposed,
            "nearest_upsampled_input needs a plain 3×3 convolution, got {self:?}"
        );
        Self {
            nearest_upsampled_input: true,
            ..self
        }
    }
    /// Transposed convolution (padding 0 unless set after).
    pub fn transposed(self) -> Self {
        Self {
            transposed: true,
            padding: 0,
            ..self
        }
    }

    fn weight_dims(&self, c_in: i64, c_out: i64) -> Vec<i64> {
        let k = self.kernel;
        if self.transposed {
            vec![c_in, c_out / self.groups, k, k]
        } else {
            vec![c_out, c_in / self.groups, k, k]
        }
    }
}

/// A trainable variable; in an uninitialised build ([`BuildOptions::uninitialised`]) an
/// uninitialised one (never touched, so the operating system does not even commit its memory).
pub fn new_var(p: &Path, name: &str, dims: &[i64], init: nn::Init) -> Tensor {
    if p.options().uninitialised {
        p.add(name, Tensor::empty(dims, (p.kind(), p.device())), true)
    } else {
        p.var(name, dims, init)
    }
}

/// `init`, or zeros in an uninitialised build.
pub fn effective_init(p: &Path, init: nn::Init) -> nn::Init {
    if p.options().uninitialised {
        nn::Init::Const(0.0)
    } else {
        init
    }
}

fn weight_init(init: WeightInit, dims: &[i64]) -> nn::Init {
    let receptive: i64 = dims[2..].iter().product();
    // PyTorch computes fans from the weight tensor as stored (dim 1 = fan-in side).
    let fan_in = (dims[1] * receptive) as f64;
    let fan_out = (dims[0] * receptive) as f64;
    match init {
        WeightInit::TorchDefault => {
            let bound = 1.0 / fan_in.sqrt();
            nn::Init::Uniform {
                lo: -bound,
                up: bound,
            }
        }
        WeightInit::KaimingNormalFanOut => nn::Init::Randn {
            mean: 0.0,
            stdev: (2.0 / fan_out).sqrt(),
        },
        WeightInit::KaimingNormalFanIn => nn::Init::Randn {
            mean: 0.0,
            stdev: (2.0 / fan_in).sqrt(),
        },
        WeightInit::XavierUniform => {
            let bound = (6.0 / (fan_in + fan_out)).sqrt();
            nn::Init::Uniform {
                lo: -bound,
                up: bound,
            }
        }
        WeightInit::Normal(stdev) => nn::Init::Randn { mean: 0.0, stdev },
    }
}

/// [`rtf_kernels::phases::interleave_phases`] in libtorch ops, differentiable, in the phases' kind:
/// `out[n, c, 2i + a, 2j + b] = phases[n, (2a + b)·C + c, i + a, j + b]`.
/// [B, 4C, H + 1, W + 1] -> [B, C, 2H, 2W]
fn interleave_phases_differentiably(phases: &Tensor) -> Tensor {
    let size = phases.size();
    let (b, c, h, w) = (size[0], size[1] / 4, size[2] - 1, size[3] - 1);
    let phase = |a: i64, col: i64| {
        phases
            .narrow(1, (2 * a + col) * c, c)
            .narrow(2, a, h)
            .narrow(3, col, w)
    };
    // 4 × [B, C, H, W] -> [B, C, H, W, 2 (a), 2 (b)] -> [B, C, H, a, W, b] -> [B, C, 2H, 2W]
    Tensor::stack(&[phase(0, 0), phase(0, 1), phase(1, 0), phase(1, 1)], -1)
        .view([b, c, h, w, 2, 2])
        .permute([0, 1, 2, 4, 3, 5])
        .reshape([b, c, 2 * h, 2 * w])
}

/// Convolution → optional BatchNorm → activation: the trained variables, or their folded
/// inference form ([`Fold::folded`] returns a new unit; [`crate::fast::unit`]).
#[derive(Debug)]
pub struct ConvBnAct {
    spec: ConvSpec,
    act: Act,
    out_channels: i64,
    form: Form,
}

#[derive(Debug)]
enum Form {
    /// The variables under the reference names: training and the plain eval forward.
    Plain(Plain),
    /// Folded for inference only.
    Folded(FoldedConv),
}

#[derive(Debug)]
struct Plain {
    weight: Tensor,
    bias: Option<Tensor>,
    bn: Option<BatchNorm>,
    /// The Winograd forms its training convolution may take (its build's [`UnitKernels`]).
    winograd: Forms,
    /// How it convolves in bf16 inside a CPU bf16 autocast region (its build's kernels).
    bf16_convolutions: Bf16Convolutions,
    /// The phase form's taps on the weight's device ([`phase_taps`]), for a unit built with
    /// [`ConvSpec::nearest_upsampled_input`].
    phase_taps: Option<Tensor>,
}

impl Plain {
    /// Every tensor of the unit (for releasing them once folded).
    fn tensors(&self) -> Vec<&Tensor> {
        let mut tensors = vec![&self.weight];
        tensors.extend(self.bias.as_ref());
        tensors.extend(self.bn.iter().flat_map(BatchNorm::tensors));
        tensors
    }
}

impl ConvBnAct {
    /// Convolution variables under `conv` (`weight`, `bias`), BatchNorm under `bn` if given.
    /// [B, c_in, H, W] -> [B, c_out, H', W']
    pub fn new(
        conv: Path,
        bn: Option<Path>,
        c_in: i64,
        c_out: i64,
        spec: ConvSpec,
        act: Act,
    ) -> Self {
        let dims = spec.weight_dims(c_in, c_out);
        let weight = new_var(&conv, "weight", &dims, weight_init(spec.init, &dims));
        let bias = spec.bias.then(|| {
            let bound = 1.0 / ((dims[1] * dims[2] * dims[3]) as f64).sqrt();
            new_var(
                &conv,
                "bias",
                &[c_out],
                nn::Init::Uniform {
                    lo: -bound,
                    up: bound,
                },
            )
        });
        let bn = bn.map(|p| bn2d_with(p, c_out, spec.bn_weight_init, spec.bn_eps));
        let kernels = conv.kernels();
        let phase_taps = spec
            .nearest_upsampled_input
            .then(|| phase_taps(weight.device()));
        let plain = Plain {
            weight,
            bias,
            bn,
            winograd: kernels.winograd,
            bf16_convolutions: kernels.bf16_convolutions,
            phase_taps,
        };
        Self {
            spec,
            act,
            out_channels: c_out,
            form: Form::Plain(plain),
        }
    }

    pub fn out_channels(&self) -> i64 {
        self.out_channels
    }

    /// The unit's BatchNorm, if it has one (none once folded).
    pub fn bn(&self) -> Option<&BatchNorm> {
        match &self.form {
            Form::Plain(p) => p.bn.as_ref(),
            Form::Folded(_) => None,
        }
    }

    fn geometry(&self) -> Geometry {
        Self::plain_geometry(&self.spec)
    }

    fn plain_geometry(s: &ConvSpec) -> Geometry {
        Geometry {
            stride: s.stride,
            padding: s.padding,
            dilation: s.dilation,
            groups: s.groups,
            transposed: s.transposed,
        }
    }

    /// Nearest ×2 upsampling of `xs`, then this unit: [B, c_in, H, W] -> [B, c_out, 2H, 2W].
    /// Units built with [`ConvSpec::nearest_upsampled_input`] train it in the phase form: one
    /// 2×2 convolution of `xs` giving the four output phases, then interleaved (the phase
    /// weights are sums of the 3×3 weights, so the same function up to the order of the sums),
    /// without materialising the upsampled map; folded, they run it so too
    /// ([`FoldedConv::forward_upsampled`]).
    pub fn forward_upsampled(&self, xs: &Tensor, train: bool) -> Tensor {
        let p = match &self.form {
            Form::Folded(f) => return inference_only(f, train).forward_upsampled(xs),
            Form::Plain(p) => p,
        };
        if let (true, Some(taps)) = (train, &p.phase_taps) {
            let weight = nearest_up2_conv3x3_as_phases(&p.weight, taps);
            let bias = p.bias.as_ref().map(|b| b.repeat([4]));
            // [B, c_in, H, W] -> [B, 4·c_out, H + 1, W + 1] -> [B, c_out, 2H, 2W]
            let phases = self.conv(p, xs, &weight, bias.as_ref());
            let ys = interleave_phases_differentiably(&phases);
            return self.act.apply_fresh(batch_norm(p, ys, train));
        }
        let (h, w) = (xs.size()[2], xs.size()[3]);
        xs.upsample_nearest2d([2 * h, 2 * w], 2.0, 2.0)
            .apply_t(self, train)
    }

    /// This unit followed by `pool`, a max pooling.
    pub fn forward_then_max_pool(
        &self,
        xs: &Tensor,
        train: bool,
        pool: impl FnOnce(&Tensor) -> Tensor,
    ) -> Tensor {
        match &self.form {
            Form::Folded(f) => inference_only(f, train).forward_then_max_pool(xs, pool),
            Form::Plain(_) => pool(&nn::ModuleT::forward_t(self, xs, train)),
        }
    }

    /// conv → bn → (+ residual) → act.
    pub fn forward_add(&self, xs: &Tensor, residual: &Tensor, train: bool) -> Tensor {
        match &self.form {
            Form::Folded(f) => inference_only(f, train).forward_add(xs, residual),
            Form::Plain(p) => self.act.apply_fresh(self.conv_bn(p, xs, train) + residual),
        }
    }

    /// Convolution and BatchNorm, no activation.
    fn conv_bn(&self, p: &Plain, xs: &Tensor, train: bool) -> Tensor {
        let ys = match self.winograd_training_conv(p, xs, train) {
            Some(ys) => ys,
            None => self.conv(p, xs, &p.weight, p.bias.as_ref()),
        };
        batch_norm(p, ys, train)
    }

    /// The plain convolution of `xs` with `weight` (+ `bias`): emulated bf16 where `p`'s
    /// kernels say so inside a CPU bf16 autocast region, else libtorch's.
    fn conv(&self, p: &Plain, xs: &Tensor, weight: &Tensor, bias: Option<&Tensor>) -> Tensor {
        let s = &self.spec;
        let spatial = s.kernel > 1 && !s.transposed;
        if rtf_amp::emulates_bf16_convolution(xs.device(), spatial, p.bf16_convolutions) {
            return bf16_emulated_convolution(xs, weight, bias, self.geometry());
        }
        if s.transposed {
            xs.conv_transpose2d(
                weight,
                bias,
                [s.stride],
                [s.padding],
                [0],
                s.groups,
                [s.dilation],
            )
        } else {
            xs.conv2d(
                weight,
                bias,
                [s.stride],
                [s.padding],
                [s.dilation],
                s.groups,
            )
        }
    }

    /// The training convolution in F(4×4, 3×3) (forward and input gradient; [4× fewer
    /// multiply-adds](rtf_kernels::winograd)), where it applies: training, float32
    /// channels-last maps on the CPU (rtf's fp32 training layout on AVX-512 CPUs) outside any
    /// autocast region, a 3×3 stride-1 convolution without bias whose shape gains within the
    /// unit's forms ([`rtf_kernels::winograd::trains_in_f43`]). Never on the plain eval path,
    /// which stays the reference's arithmetic.
    fn winograd_training_conv(&self, p: &Plain, xs: &Tensor, train: bool) -> Option<Tensor> {
        self.trains_in_winograd(p, xs, train)
            .then(|| rtf_kernels::winograd::conv3x3_f43_train(xs, &p.weight))
    }

    /// Whether [`winograd_training_conv`](Self::winograd_training_conv) applies to `xs`.
    fn trains_in_winograd(&self, p: &Plain, xs: &Tensor, train: bool) -> bool {
        train
            && p.bias.is_none()
            && !self.spec.transposed
            && xs.device() == tch::Device::Cpu
            && xs.kind() == Kind::Float
            && p.weight.kind() == Kind::Float
            && is_channels_last(xs)
            && rtf_amp::state(tch::Device::Cpu).is_ok_and(|s| !s.enabled)
            && rtf_kernels::winograd::trains_in_f43(
                p.winograd,
                self.spec.kernel,
                self.geometry(),
                p.weight.size()[0],
                &xs.size(),
            )
    }
}

/// The folded unit; a folded unit asked to train is a caller's bug.
fn inference_only(f: &FoldedConv, train: bool) -> &FoldedConv {
    assert!(
        !train,
        "a folded convolution cannot train (fold a copy for inference)"
    );
    f
}

/// The unit's BatchNorm of a convolution's output, if it has one.
fn batch_norm(p: &Plain, ys: Tensor, train: bool) -> Tensor {
    match &p.bn {
        Some(bn) => ys.apply_t(bn, train),
        None => ys,
    }
}

impl nn::ModuleT for ConvBnAct {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        match &self.form {
            Form::Folded(f) => inference_only(f, train).forward(xs),
            // Every path hands the activation a tensor it just made, so it may overwrite it.
            Form::Plain(p) => self.act.apply_fresh(self.conv_bn(p, xs, train)),
        }
    }
}

#[cfg(test)]
impl ConvBnAct {
    /// The folded unit (tests).
    fn folded_unit(&self) -> &FoldedConv {
        match &self.form {
            Form::Folded(f) => f,
            Form::Plain(_) => panic!("not folded"),
        }
    }

    /// The convolution's weight and bias variables (tests).
    fn plain_vars(&self) -> (&Tensor, Option<&Tensor>) {
        match &self.form {
            Form::Plain(p) => (&p.weight, p.bias.as_ref()),
            Form::Folded(_) => panic!("folded"),
        }
    }
}

#[cfg(test)]
mod tests;
