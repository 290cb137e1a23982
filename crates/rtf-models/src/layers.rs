//! Building blocks shared by the networks: convolution (+ BatchNorm) (+ activation) units that
//! can fold their BatchNorm for inference, and the activations.
//!
//! A [`ConvBnAct`] owns its variables under the reference names (`<conv>.weight`,
//! `<bn>.running_mean`, …). [`Fuse::fuse`] precomputes, once, the convolution weight and bias
//! with an eval-mode BatchNorm folded in, laid out channels-last and cast to the inference
//! precision; eval-mode forwards then run one convolution and an in-place activation per unit.
//! Training-mode forwards always use the original variables.

use tch::{nn, Kind, Tensor};

pub use crate::bn_defaults::{BN_EPS, BN_MOMENTUM};
pub use crate::sync_bn::BatchNorm;

use crate::aten::{ffi, shim_result};
use crate::onednn::{conv_add_with_post_op, conv_with_post_op, Geometry, PostOp};

mod fold;
pub use fold::batch_norm_affine;

/// BatchNorm2d initialised as PyTorch's (weight 1, bias 0; tch's default weight is U(0, 1)).
pub fn bn2d(p: nn::Path, c: i64) -> BatchNorm {
    bn2d_init(p, c, nn::Init::Const(1.0))
}

/// BatchNorm2d with a given weight initialisation and bias 0.
pub fn bn2d_init(p: nn::Path, c: i64, weight: nn::Init) -> BatchNorm {
    bn2d_with(p, c, weight, BN_EPS)
}

/// BatchNorm2d with a given weight initialisation, bias 0 and eps (momentum [`BN_MOMENTUM`]).
pub fn bn2d_with(p: nn::Path, c: i64, weight: nn::Init, eps: f64) -> BatchNorm {
    let cfg = nn::BatchNormConfig {
        eps,
        momentum: BN_MOMENTUM,
        ws_init: effective_init(weight),
        bs_init: nn::Init::Const(0.0),
        ..Default::default()
    };
    BatchNorm::new(nn::batch_norm2d(p, c, cfg), eps)
}

/// The bf16 convolution of `xs` with `weight` (+ `bias`), computed by fp32 kernels over
/// bf16-rounded operands, its output and operand gradients rounded to bf16: a native bf16
/// kernel's numbers at fp32 kernels' speed (csrc/ops.cpp `Bf16EmulatedConvolution`;
/// [`rtf_amp::Bf16Convolutions::Emulated`]). Differentiable; output bf16, operand gradients in
/// the operands' own types. Units call it inside a CPU bf16 autocast region where
/// [`rtf_amp::emulates_bf16_convolution`] says so.
pub fn bf16_emulated_convolution(
    xs: &Tensor,
    weight: &Tensor,
    bias: Option<&Tensor>,
    geometry: Geometry,
) -> Tensor {
    let g = geometry;
    let pair = |v: i64| [v, v];
    let (stride, padding, dilation) = (pair(g.stride), pair(g.padding), pair(g.dilation));
    let output_padding = [0i64, 0];
    let mut out: *mut torch_sys::C_tensor = std::ptr::null_mut();
    let bias_ptr = bias.map_or(std::ptr::null_mut(), |b| {
        b.as_ptr() as *mut torch_sys::C_tensor
    });
    // SAFETY: the tensors' `as_ptr` are live `at::Tensor*` for the call (bias may be null, which
    // the shim reads as no bias); the geometry arrays hold two values each, as the shim reads.
    unsafe {
        let error = ffi::rtf_bf16_emulated_convolution(
            xs.as_ptr() as *mut torch_sys::C_tensor,
            weight.as_ptr() as *mut torch_sys::C_tensor,
            bias_ptr,
            stride.as_ptr(),
            padding.as_ptr(),
            dilation.as_ptr(),
            std::ffi::c_int::from(g.transposed),
            output_padding.as_ptr(),
            g.groups,
            &mut out,
        );
        shim_result("bf16 emulated convolution", error, out)
    }
}

/// ATen's `leaky_relu(x, slope)` (one pass forward, one backward; tch's binding fixes the
/// slope at 0.01), through csrc/ops.cpp; differentiable. With `in_place` it overwrites `xs`,
/// which autograd allows when nothing saved `xs` for its backward (BatchNorm's and a
/// convolution's outputs: their backwards read their inputs).
fn aten_leaky_relu(xs: &Tensor, slope: f64, in_place: bool) -> Tensor {
    let mut out: *mut torch_sys::C_tensor = std::ptr::null_mut();
    // SAFETY: `as_ptr` is a live `at::Tensor*` for the call; the shim's result is taken as
    // `shim_result` requires.
    unsafe {
        let error = ffi::rtf_leaky_relu(
            xs.as_ptr() as *mut torch_sys::C_tensor,
            slope,
            in_place as std::ffi::c_int,
            &mut out,
        );
        shim_result("leaky_relu", error, out)
    }
}

/// LeakyReLU with a given slope (ATen's, differentiable).
pub fn leaky_relu(xs: &Tensor, slope: f64) -> Tensor {
    aten_leaky_relu(xs, slope, false)
}

/// LeakyReLU in place, for inference: tch exposes no slope on the forward op, but
/// `leaky_relu_backward(grad = x, x)` is `x > 0 ? x : slope·x`, exactly the activation, and its
/// `grad_input` (out) variant writes it over `x` in one pass without allocating.
pub fn leaky_relu_inference(xs: Tensor, slope: f64) -> Tensor {
    xs.leaky_relu_backward_grad_input(&xs, &xs, slope, false)
}

/// Re-lays a 4-D tensor out channels-last (NHWC in memory, NCHW logical shape); libtorch's
/// CPU convolutions, pools and pointwise ops keep that layout.
pub fn to_channels_last(xs: &Tensor) -> Tensor {
    if xs.dim() != 4 {
        return xs.shallow_clone();
    }
    xs.permute([0, 2, 3, 1]).contiguous().permute([0, 3, 1, 2])
}

/// Whether a 4-D tensor is laid out channels-last.
pub fn is_channels_last(xs: &Tensor) -> bool {
    let (size, stride) = (xs.size(), xs.stride());
    size.len() == 4 && (size[1] == 1 || stride[1] == 1) && stride[0] == size[1] * size[2] * size[3]
}

/// Activation after a unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Act {
    Identity,
    Relu,
    LeakyRelu(f64),
    /// The exact (erf) GELU, PyTorch's `gelu(approximate="none")`.
    Gelu,
}

impl Act {
    /// The same activation as a oneDNN post-op.
    fn post_op(self) -> PostOp {
        match self {
            Act::Identity => PostOp::None,
            Act::Relu => PostOp::Relu,
            Act::LeakyRelu(slope) => PostOp::LeakyRelu(slope),
            Act::Gelu => PostOp::Gelu,
        }
    }

    /// Autograd-friendly activation (training and the plain path).
    pub fn apply(self, xs: Tensor) -> Tensor {
        match self {
            Act::Identity => xs,
            Act::Relu => xs.relu(),
            Act::LeakyRelu(slope) => leaky_relu(&xs, slope),
            Act::Gelu => xs.gelu("none"),
        }
    }

    /// Training activation of a tensor this unit just made (a convolution's or BatchNorm's
    /// output, which their backwards do not read): in place, saving a copy of every activation
    /// map (PyTorch's `inplace=True`).
    fn apply_fresh(self, mut xs: Tensor) -> Tensor {
        match self {
            Act::Identity => xs,
            Act::Relu => {
                let _ = xs.relu_();
                xs
            }
            Act::LeakyRelu(slope) => aten_leaky_relu(&xs, slope, true),
            // GELU's backward reads its input: not in place.
            Act::Gelu => xs.gelu("none"),
        }
    }

    /// Inference activation: in place where libtorch allows.
    pub fn apply_inference(self, mut xs: Tensor) -> Tensor {
        match self {
            Act::Identity => xs,
            Act::Relu => {
                let _ = xs.relu_();
                xs
            }
            Act::LeakyRelu(slope) => leaky_relu_inference(xs, slope),
            Act::Gelu => {
                let _ = xs.gelu_("none");
                xs
            }
        }
    }
}

/// How a convolution's weight is initialised when no weights are loaded.
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

thread_local! {
    /// Layout of the weights [`Fuse::fuse`] prepares (see [`with_fused_layout`]).
    static FUSE_CHANNELS_LAST: std::cell::Cell<bool> = const { std::cell::Cell::new(true) };
}

/// Runs `f` (a fuse) preparing channels-last weights or, with `channels_last = false`,
/// contiguous NCHW ones (libtorch picks a convolution's layout from its input *and* weight).
pub fn with_fused_layout<T>(channels_last: bool, f: impl FnOnce() -> T) -> T {
    crate::scoped::with(&FUSE_CHANNELS_LAST, channels_last, f)
}

thread_local! {
    /// Set inside [`with_emulated_bf16`].
    static FUSE_EMULATED_BF16: std::cell::Cell<Option<bool>> = const { std::cell::Cell::new(None) };
}

/// Runs `f` (a fuse) with bf16 folds made as where bf16 is emulated, or not, whatever the CPU
/// (to test both on one machine).
pub fn with_emulated_bf16<T>(on: bool, f: impl FnOnce() -> T) -> T {
    crate::scoped::with(&FUSE_EMULATED_BF16, Some(on), f)
}

/// Whether a bf16 fold on the CPU computes its convolutions with float32 kernels over bf16
/// maps: inside [`with_emulated_bf16`], its setting (the caller's choice: rtf's binaries pass
/// `RTF_BF16_CONVOLUTIONS` and the ISA cap), else where the CPU has no bf16 arithmetic
/// ([`rtf_amp::Bf16Policy::default`]). There oneDNN's bf16
/// kernels convert every product in generic code, tens of times slower than fp32, while fp32
/// kernels with the casts around them cost little more than fp32 and give the numbers of a
/// bf16 kernel (bf16 operands, float sums, bf16 output); docs/src/benchmarks.md, "Where bf16
/// is emulated".
fn emulates_bf16(weight: &Tensor) -> bool {
    weight.device() == tch::Device::Cpu
        && FUSE_EMULATED_BF16.with(|c| c.get()).unwrap_or_else(|| {
            rtf_amp::Bf16Policy::default().in_force(None) == rtf_amp::Bf16Convolutions::Emulated
        })
}

thread_local! {
    /// Set while counting parameters: every variable starts as zeros (lazily allocated), so
    /// building even RTFNet-152 costs next to nothing.
    static ZERO_INIT: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `f` with variable initialisation skipped (for counting parameters).
pub fn with_zero_init<T>(f: impl FnOnce() -> T) -> T {
    crate::scoped::with(&ZERO_INIT, true, f)
}

/// A trainable variable; inside [`with_zero_init`] an uninitialised one (never touched, so
/// the operating system does not even commit its memory).
pub fn new_var(p: &nn::Path, name: &str, dims: &[i64], init: nn::Init) -> Tensor {
    if ZERO_INIT.with(|z| z.get()) {
        p.add(name, Tensor::empty(dims, (p.kind(), p.device())), true)
    } else {
        p.var(name, dims, init)
    }
}

/// `init`, or zeros inside [`with_zero_init`].
pub fn effective_init(init: nn::Init) -> nn::Init {
    if ZERO_INIT.with(|z| z.get()) {
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

/// A folded convolution weight in the form the inference path runs it in.
#[derive(Debug)]
enum FoldedWeight {
    /// Dense, in the layout [`with_fused_layout`] asked for.
    Dense(Tensor),
    /// Packed once into oneDNN's blocked layout ([`crate::onednn::pack_weight`]); only oneDNN's
    /// fused entry points take it, every other use goes through [`FoldedWeight::dense`].
    Packed(Tensor),
    /// Winograd's transformed weight [16, c_in, c_out] ([`crate::winograd`]), in place of the
    /// dense one.
    Winograd(Tensor),
}

impl FoldedWeight {
    /// The weight oneDNN's fused convolutions take (none for the Winograd form).
    fn for_onednn(&self) -> Option<&Tensor> {
        match self {
            FoldedWeight::Dense(w) | FoldedWeight::Packed(w) => Some(w),
            FoldedWeight::Winograd(_) => None,
        }
    }

    /// The dense weight (a copy out of oneDNN's layout where packed; only where oneDNN refused
    /// a fused call). The Winograd form never takes this path.
    fn dense(&self) -> Tensor {
        match self {
            FoldedWeight::Dense(w) => w.shallow_clone(),
            FoldedWeight::Packed(w) => crate::onednn::dense_weight(w),
            FoldedWeight::Winograd(_) => unreachable!("Winograd weights run through winograd.rs"),
        }
    }
}

/// Folded, inference-ready weights of a unit.
#[derive(Debug)]
struct Fused {
    weight: FoldedWeight,
    bias: Option<Tensor>,
    /// bf16 maps, float32 weights and kernels: the maps are cast to float32 on the way in and
    /// rounded to bf16 on the way out ([`emulates_bf16`]; the Winograd forms convert inside
    /// their transforms instead and leave this unset).
    float_arith: bool,
    /// Nearest ×2 upsampling followed by this 3×3 convolution, as the four output phases of
    /// one 2×2 convolution of the small map (see [`ConvBnAct::forward_upsampled`]).
    upsampled: Option<PhaseConv>,
}

/// Weight [4·c_out, c_in, 2, 2] and bias [4·c_out] of the phase form of a 3×3 convolution fed
/// a nearest ×2 upsampled map; channel block 2a + b holds output rows ≡ a, columns ≡ b (mod 2).
#[derive(Debug)]
struct PhaseConv {
    weight: Tensor,
    bias: Option<Tensor>,
}

/// A 3×3 convolution weight [c_out, c_in, 3, 3] (stride 1, padding 1, no dilation) applied
/// after nearest ×2 upsampling, rewritten as one 2×2 convolution (padding 1) of the small map
/// with the four output phases stacked along channels: [4·c_out, c_in, 2, 2]. The same output
/// without building the upsampled map, with 16 instead of 36 multiply-adds per input-output
/// channel pair and source pixel, and as a plain convolution (oneDNN's transposed ones are
/// ~2× slower per multiply-add at MFNet's 9 output channels).
fn nearest_up2_conv3x3_as_phases(weight: &Tensor) -> Tensor {
    // Per axis, output 2m + a reads upsampled rows 2m + a − 1 … 2m + a + 1, i.e. source rows
    // m − 1, m, m (a = 0) or m, m, m + 1 (a = 1). A 2×2 convolution with padding 1 reads source
    // rows r − 1 (tap 0) and r (tap 1) for its output r, so phase a takes output r = m + a and
    // tap t = Σ_k TAPS[a][t][k]·w[k].
    let taps = Tensor::from_slice(&[1f32, 0., 0., 0., 1., 1., 1., 1., 0., 0., 0., 1.])
        .view([2, 2, 3])
        .to_device(weight.device());
    let (c_out, c_in) = (weight.size()[0], weight.size()[1]);
    Tensor::einsum(
        "atk,oikl,bul->aboitu",
        &[&taps, &weight.to_kind(Kind::Float), &taps],
        None::<&[i64]>,
    )
    .reshape([4 * c_out, c_in, 2, 2])
}

/// [`crate::kernels::interleave_phases`] in libtorch ops, differentiable, in the phases' kind:
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

/// Convolution → optional BatchNorm → activation.
#[derive(Debug)]
pub struct ConvBnAct {
    weight: Tensor,
    bias: Option<Tensor>,
    spec: ConvSpec,
    bn: Option<BatchNorm>,
    act: Act,
    fused: Option<Fused>,
}

/// Units and blocks that can prepare folded inference weights.
pub trait Fuse {
    /// Folds eval-mode BatchNorm into the preceding convolution, lays weights out
    /// channels-last and casts them to `kind` (Float or BFloat16). Call again after the
    /// weights change (e.g. after loading) to refresh.
    fn fuse(&mut self, kind: Kind);
}

impl<T: Fuse> Fuse for Vec<T> {
    fn fuse(&mut self, kind: Kind) {
        self.iter_mut().for_each(|u| u.fuse(kind))
    }
}

impl<T: Fuse> Fuse for Option<T> {
    fn fuse(&mut self, kind: Kind) {
        if let Some(u) = self {
            u.fuse(kind)
        }
    }
}

impl ConvBnAct {
    /// Convolution variables under `conv` (`weight`, `bias`), BatchNorm under `bn` if given.
    /// [B, c_in, H, W] -> [B, c_out, H', W']
    pub fn new(
        conv: nn::Path,
        bn: Option<nn::Path>,
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
        Self {
            weight,
            bias,
            spec,
            bn,
            act,
            fused: None,
        }
    }

    pub fn out_channels(&self) -> i64 {
        if self.spec.transposed {
            self.weight.size()[1] * self.spec.groups
        } else {
            self.weight.size()[0]
        }
    }

    fn conv(&self, xs: &Tensor, weight: &Tensor, bias: Option<&Tensor>) -> Tensor {
        let s = &self.spec;
        let spatial = s.kernel > 1 && !s.transposed;
        if rtf_amp::emulates_bf16_convolution(xs.device(), spatial) {
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

    /// The folded weights on the inference path, where the activation (and a residual add) is
    /// fused into the convolution: oneDNN's kernels apply it as they write each output block,
    /// saving a pass over the map, and they take the weights packed once at fold time (fp32
    /// and bf16; with dense weights fp32 gained nothing; docs/src/models.md), or the Winograd
    /// form runs.
    fn fusing_post_ops(&self, train: bool) -> Option<&Fused> {
        self.fused.as_ref().filter(|_| !train)
    }

    /// The folded convolution with the activation fused into it, where oneDNN can (or in the
    /// Winograd form), `None` otherwise.
    fn fused_conv_act(&self, xs: &Tensor, train: bool) -> Option<Tensor> {
        let f = self.fusing_post_ops(train)?;
        let ys = match &f.weight {
            FoldedWeight::Winograd(u) => Some(self.winograd_conv(xs, u, f, None)),
            weight => conv_with_post_op(
                &self.kernel_input(xs),
                weight.for_onednn()?,
                f.bias.as_ref(),
                self.geometry(),
                self.act.post_op(),
            ),
        };
        ys.map(|ys| self.map_output(ys))
    }

    /// A map as this folded unit's kernels take it: float32 where it computes emulated bf16
    /// with float32 kernels ([`Fused::float_arith`]), else as it is.
    fn kernel_input(&self, xs: &Tensor) -> Tensor {
        match &self.fused {
            Some(f) if f.float_arith => xs.to_kind(Kind::Float),
            _ => xs.shallow_clone(),
        }
    }

    /// A folded unit's output in the maps' type: rounded to bf16 where [`Self::kernel_input`]
    /// made it float32.
    fn map_output(&self, ys: Tensor) -> Tensor {
        match &self.fused {
            Some(f) if f.float_arith => ys.to_kind(Kind::BFloat16),
            _ => ys,
        }
    }

    /// The Winograd form of this folded unit: act(conv(xs) + bias (+ residual)).
    fn winograd_conv(
        &self,
        xs: &Tensor,
        u: &Tensor,
        f: &Fused,
        residual: Option<&Tensor>,
    ) -> Tensor {
        let relu = self.act == Act::Relu;
        let d = self.spec.dilation;
        let ys = crate::winograd::conv3x3_dilated(xs, u, f.bias.as_ref(), residual, relu, d);
        if relu {
            ys
        } else {
            self.act.apply_inference(ys)
        }
    }

    fn geometry(&self) -> Geometry {
        let s = &self.spec;
        Geometry {
            stride: s.stride,
            padding: s.padding,
            dilation: s.dilation,
            groups: s.groups,
            transposed: s.transposed,
        }
    }

    /// Convolution and BatchNorm, no activation.
    fn conv_bn(&self, xs: &Tensor, train: bool) -> Tensor {
        match (&self.fused, train) {
            (Some(f), false) => match &f.weight {
                FoldedWeight::Winograd(u) => {
                    let d = self.spec.dilation;
                    crate::winograd::conv3x3_dilated(xs, u, f.bias.as_ref(), None, false, d)
                }
                weight => {
                    let ys = self.conv(&self.kernel_input(xs), &weight.dense(), f.bias.as_ref());
                    self.map_output(ys)
                }
            },
            _ => {
                let ys = match self.winograd_training_conv(xs, train) {
                    Some(ys) => ys,
                    None => self.conv(xs, &self.weight, self.bias.as_ref()),
                };
                self.batch_norm(ys, train)
            }
        }
    }

    /// The training convolution in F(4×4, 3×3) (forward and input gradient; [4× fewer
    /// multiply-adds](crate::winograd)), where it applies: training, float32 channels-last maps
    /// on the CPU (rtf's fp32 training layout on AVX-512 CPUs) outside any autocast region, a
    /// 3×3 stride-1 convolution without bias whose shape gains ([`crate::winograd::trains_in_f43`]).
    /// Never on the plain inference path, which stays the reference's arithmetic.
    fn winograd_training_conv(&self, xs: &Tensor, train: bool) -> Option<Tensor> {
        let dims = self.weight.size();
        let applies = train
            && self.bias.is_none()
            && !self.spec.transposed
            && xs.device() == tch::Device::Cpu
            && xs.kind() == Kind::Float
            && self.weight.kind() == Kind::Float
            && is_channels_last(xs)
            && rtf_amp::state(tch::Device::Cpu).is_ok_and(|s| !s.enabled)
            && crate::winograd::trains_in_f43(
                self.spec.kernel,
                self.geometry(),
                dims[0],
                &xs.size(),
            );
        applies.then(|| crate::winograd::conv3x3_f43_train(xs, &self.weight))
    }

    /// The unit's BatchNorm, if it has one.
    pub fn bn(&self) -> Option<&BatchNorm> {
        self.bn.as_ref()
    }

    /// This unit's BatchNorm of a convolution's output, if it has one (unfolded path).
    fn batch_norm(&self, ys: Tensor, train: bool) -> Tensor {
        match &self.bn {
            Some(bn) => ys.apply_t(bn, train),
            None => ys,
        }
    }

    /// Every caller hands over a tensor it just made (a convolution's, BatchNorm's, pool's or
    /// residual sum's output), so the activation may overwrite it.
    fn activate(&self, ys: Tensor, train: bool) -> Tensor {
        if self.fused.is_some() && !train {
            self.act.apply_inference(ys)
        } else {
            self.act.apply_fresh(ys)
        }
    }

    /// Nearest ×2 upsampling of `xs`, then this unit: [B, c_in, H, W] -> [B, c_out, 2H, 2W].
    /// Folded units built with [`ConvSpec::nearest_upsampled_input`] run it as one 2×2
    /// convolution of `xs` giving the four output phases, then interleave them, without
    /// materialising the upsampled map. That result is float32 and NCHW-contiguous whatever the
    /// inference precision: it is meant for a network's last unit (MFNet's `decode1`), whose
    /// logits are wanted in that form, and writing them so directly saves a pass.
    /// Training takes the same phase form, differentiably (the phase weights are sums of the
    /// 3×3 weights, so the same function up to the order of the sums): MFNet's `decode1` at
    /// 640×480 is 2.2× fewer multiply-adds, in 36 output channels instead of 9.
    pub fn forward_upsampled(&self, xs: &Tensor, train: bool) -> Tensor {
        if train && self.spec.nearest_upsampled_input {
            let weight = nearest_up2_conv3x3_as_phases(&self.weight);
            let bias = self.bias.as_ref().map(|b| b.repeat([4]));
            // [B, c_in, H, W] -> [B, 4·c_out, H + 1, W + 1] -> [B, c_out, 2H, 2W]
            let phases = self.conv(xs, &weight, bias.as_ref());
            let ys = interleave_phases_differentiably(&phases);
            return self.activate(self.batch_norm(ys, train), train);
        }
        if let (
            Some(Fused {
                upsampled: Some(PhaseConv { weight, bias }),
                ..
            }),
            false,
        ) = (&self.fused, train)
        {
            let geometry = Geometry::SAME_3X3;
            let xs = self.kernel_input(xs);
            // [B, c_in, H, W] -> [B, 4·c_out, H + 1, W + 1]
            let phases = self
                .fusing_post_ops(train)
                .and_then(|_| {
                    conv_with_post_op(&xs, weight, bias.as_ref(), geometry, self.act.post_op())
                })
                .unwrap_or_else(|| {
                    let ys = xs.conv2d(weight, bias.as_ref(), [1], [1], [1], 1);
                    self.act.apply_inference(ys)
                });
            // -> [B, c_out, 2H, 2W]
            return crate::kernels::interleave_phases(&phases);
        }
        let (h, w) = (xs.size()[2], xs.size()[3]);
        xs.upsample_nearest2d([2 * h, 2 * w], 2.0, 2.0)
            .apply_t(self, train)
    }

    /// This unit followed by `pool`, a max pooling. On the inference path with the activation
    /// fused into the convolution, that is all (the faster of the two in bf16); otherwise it
    /// pools before the activation, which is monotonic and so commutes with taking
    /// maxima (same values), and activates a map a quarter the size.
    pub fn forward_then_max_pool(
        &self,
        xs: &Tensor,
        train: bool,
        pool: impl FnOnce(&Tensor) -> Tensor,
    ) -> Tensor {
        if let Some(ys) = self.fused_conv_act(xs, train) {
            pool(&ys)
        } else if self.fused.is_some() && !train {
            self.activate(pool(&self.conv_bn(xs, train)), train)
        } else {
            pool(&nn::ModuleT::forward_t(self, xs, train))
        }
    }

    /// conv → bn → (+ residual) → act, the residual add in place on the inference path.
    pub fn forward_add(&self, xs: &Tensor, residual: &Tensor, train: bool) -> Tensor {
        if let Some(f) = self.fusing_post_ops(train) {
            let fused = match &f.weight {
                FoldedWeight::Winograd(u) => Some(self.winograd_conv(xs, u, f, Some(residual))),
                weight => weight.for_onednn().and_then(|w| {
                    let ys = conv_add_with_post_op(
                        &self.kernel_input(xs),
                        &self.kernel_input(residual),
                        w,
                        f.bias.as_ref(),
                        self.geometry(),
                        self.act.post_op(),
                    );
                    ys.map(|ys| self.map_output(ys))
                }),
            };
            if let Some(ys) = fused {
                return ys;
            }
        }
        let ys = self.conv_bn(xs, train);
        let ys = if self.fused.is_some() && !train {
            let mut ys = ys;
            let _ = ys.g_add_(residual);
            ys
        } else {
            ys + residual
        };
        self.activate(ys, train)
    }
}

impl nn::ModuleT for ConvBnAct {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        if let Some(ys) = self.fused_conv_act(xs, train) {
            return ys;
        }
        let ys = self.conv_bn(xs, train);
        self.activate(ys, train)
    }
}

impl Fuse for ConvBnAct {
    fn fuse(&mut self, kind: Kind) {
        self.fuse_with_affine(kind, None);
    }
}

#[cfg(test)]
mod tests;
