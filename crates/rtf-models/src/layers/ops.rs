//! The operations units are made of, below both the training units ([`super::ConvBnAct`]) and
//! the folded inference units ([`crate::fast::unit`]): activations, channels-last layout, and
//! the phase form of a 3×3 convolution of a nearest-upsampled map.

use tch::{Device, Kind, Tensor};

use rtf_kernels::aten::aten_leaky_relu;
use rtf_kernels::onednn::PostOp;

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

pub use rtf_kernels::layout::{is_channels_last, to_channels_last};

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
    pub(crate) fn post_op(self) -> PostOp {
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
    pub(crate) fn apply_fresh(self, mut xs: Tensor) -> Tensor {
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

/// The taps of [`nearest_up2_conv3x3_as_phases`], [2 phases, 2 taps, 3 kernel rows], on
/// `device`. Per axis, output 2m + a reads upsampled rows 2m + a − 1 … 2m + a + 1, i.e. source
/// rows m − 1, m, m (a = 0) or m, m, m + 1 (a = 1). A 2×2 convolution with padding 1 reads
/// source rows r − 1 (tap 0) and r (tap 1) for its output r, so phase a takes output r = m + a
/// and tap t = Σ_k TAPS[a][t][k]·w[k]. Made once by the unit that trains in the phase form: a
/// tensor filled from host memory at every step would be a copy to the GPU at every step, and
/// from pageable memory one that waits for the device's queue to drain (docs/src/gpu.md).
pub(crate) fn phase_taps(device: Device) -> Tensor {
    Tensor::from_slice(&[1f32, 0., 0., 0., 1., 1., 1., 1., 0., 0., 0., 1.])
        .view([2, 2, 3])
        .to_device(device)
}

/// A 3×3 convolution weight [c_out, c_in, 3, 3] (stride 1, padding 1, no dilation) applied
/// after nearest ×2 upsampling, rewritten as one 2×2 convolution (padding 1) of the small map
/// with the four output phases stacked along channels: [4·c_out, c_in, 2, 2]. The same output
/// without building the upsampled map, with 16 instead of 36 multiply-adds per input-output
/// channel pair and source pixel, and as a plain convolution (oneDNN's transposed ones are
/// ~2× slower per multiply-add at MFNet's 9 output channels). `taps`: [`phase_taps`], on the
/// weight's device.
pub(crate) fn nearest_up2_conv3x3_as_phases(weight: &Tensor, taps: &Tensor) -> Tensor {
    let (c_out, c_in) = (weight.size()[0], weight.size()[1]);
    Tensor::einsum(
        "atk,oikl,bul->aboitu",
        &[taps, &weight.to_kind(Kind::Float), taps],
        None::<&[i64]>,
    )
    .reshape([4 * c_out, c_in, 2, 2])
}
