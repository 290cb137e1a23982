//! The folded convolution, the inference unit of the fast path: a convolution with its
//! BatchNorm (and any affine after it) folded into weight and bias, in the form inference runs
//! it in (dense, packed for oneDNN, or Winograd's), its activation and a residual add fused
//! into the kernel where oneDNN or the Winograd form can. Built from a training unit by
//! [`crate::layers::ConvBnAct::folded`], never trained.

use tch::{Kind, Tensor};

use super::folder::Folder;
use crate::layers::ops::{nearest_up2_conv3x3_as_phases, phase_taps, to_channels_last, Act};
use rtf_kernels::onednn::{conv_add_with_post_op, conv_with_post_op, Geometry};

/// A folded convolution weight in the form the inference path runs it in.
#[derive(Debug)]
enum FoldedWeight {
    /// Dense, in the fold's layout ([`Folder::channels_last`]).
    Dense(Tensor),
    /// Packed once into oneDNN's blocked layout ([`rtf_kernels::onednn::pack_weight`]); only oneDNN's
    /// fused entry points take it, every other use goes through [`FoldedWeight::dense`].
    Packed(Tensor),
    /// Winograd's transformed weight [16, c_in, c_out] ([`rtf_kernels::winograd`]), in place of the
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
            FoldedWeight::Packed(w) => rtf_kernels::onednn::dense_weight(w),
            FoldedWeight::Winograd(_) => unreachable!("Winograd weights run through winograd.rs"),
        }
    }
}

/// Weight [4·c_out, c_in, 2, 2] and bias [4·c_out] of the phase form of a 3×3 convolution fed
/// a nearest ×2 upsampled map; channel block 2a + b holds output rows ≡ a, columns ≡ b (mod 2).
#[derive(Debug)]
struct PhaseConv {
    weight: Tensor,
    bias: Option<Tensor>,
}

/// A folded convolution → activation (→ + residual), inference only.
#[derive(Debug)]
pub struct FoldedConv {
    weight: FoldedWeight,
    bias: Option<Tensor>,
    geometry: Geometry,
    act: Act,
    /// bf16 maps, float32 weights and kernels: the maps are cast to float32 on the way in and
    /// rounded to bf16 on the way out ([`Folder::emulates_bf16`]; the Winograd forms convert
    /// inside their transforms instead and leave this unset).
    float_arith: bool,
    /// Nearest ×2 upsampling followed by this 3×3 convolution, as the four output phases of
    /// one 2×2 convolution of the small map (see [`FoldedConv::forward_upsampled`]).
    upsampled: Option<PhaseConv>,
}

impl FoldedConv {
    /// The unit of the folded float32 `weight` and `bias` (BatchNorm already in them), laid out
    /// for inference as `folder` says; `upsampled`: the unit is fed a nearest ×2 upsampled map
    /// (a plain 3×3 convolution), so it also takes the phase form.
    pub fn new(
        weight: Tensor,
        bias: Option<Tensor>,
        geometry: Geometry,
        upsampled: bool,
        act: Act,
        folder: &Folder,
    ) -> Self {
        let _guard = tch::no_grad_guard();
        let kind = folder.kind();
        let emulated = folder.emulates_bf16(weight.device());
        // Emulated bf16 keeps float32 weights of bf16 values (what a bf16 kernel would take).
        let stored_kind = if emulated { Kind::Float } else { kind };
        let lay_out = |w: Tensor| {
            let w = w.to_kind(kind).to_kind(stored_kind);
            if folder.channels_last() {
                to_channels_last(&w)
            } else {
                w.contiguous()
            }
        };
        let upsampled = upsampled.then(|| PhaseConv {
            weight: lay_out(nearest_up2_conv3x3_as_phases(
                &weight,
                &phase_taps(weight.device()),
            )),
            bias: bias.as_ref().map(|b| b.repeat([4]).to_kind(stored_kind)),
        });
        let weight = inference_form(weight, geometry, folder, lay_out);
        let winograd = matches!(weight, FoldedWeight::Winograd(_));
        // The Winograd forms add a float32 bias whatever the maps' type.
        let bias_kind = if winograd { Kind::Float } else { stored_kind };
        Self {
            weight,
            bias: bias.map(|b| b.to_kind(bias_kind)),
            geometry,
            act,
            float_arith: emulated && !winograd,
            upsampled,
        }
    }

    /// act(conv(xs)): [B, c_in, H, W] -> [B, c_out, H', W'].
    pub fn forward(&self, xs: &Tensor) -> Tensor {
        match self.fused_conv_act(xs) {
            Some(ys) => ys,
            None => self.act.apply_inference(self.conv(xs)),
        }
    }

    /// `pool` (a max pooling) of this unit's output. Where the activation cannot be fused into
    /// the convolution it pools before activating: the activation is monotonic, so it commutes
    /// with taking maxima (same values), and it then runs over a map a quarter the size.
    pub fn forward_then_max_pool(
        &self,
        xs: &Tensor,
        pool: impl FnOnce(&Tensor) -> Tensor,
    ) -> Tensor {
        match self.fused_conv_act(xs) {
            Some(ys) => pool(&ys),
            None => self.act.apply_inference(pool(&self.conv(xs))),
        }
    }

    /// act(conv(xs) + residual), the add fused into the convolution where it can be, else in
    /// place.
    pub fn forward_add(&self, xs: &Tensor, residual: &Tensor) -> Tensor {
        let fused = match &self.weight {
            FoldedWeight::Winograd(u) => Some(self.winograd_conv(xs, u, Some(residual))),
            weight => weight.for_onednn().and_then(|w| {
                let ys = conv_add_with_post_op(
                    &self.kernel_input(xs),
                    &self.kernel_input(residual),
                    w,
                    self.bias.as_ref(),
                    self.geometry,
                    self.act.post_op(),
                );
                ys.map(|ys| self.map_output(ys))
            }),
        };
        if let Some(ys) = fused {
            return ys;
        }
        let mut ys = self.conv(xs);
        let _ = ys.g_add_(residual);
        self.act.apply_inference(ys)
    }

    /// Nearest ×2 upsampling of `xs`, then this unit: [B, c_in, H, W] -> [B, c_out, 2H, 2W].
    /// Units folded with the phase form run it as one 2×2 convolution of `xs` giving the four
    /// output phases, then interleave them, without materialising the upsampled map. That
    /// result is float32 and NCHW-contiguous whatever the inference precision: it is meant for
    /// a network's last unit (MFNet's `decode1`), whose logits are wanted in that form.
    pub fn forward_upsampled(&self, xs: &Tensor) -> Tensor {
        let Some(PhaseConv { weight, bias }) = &self.upsampled else {
            let (h, w) = (xs.size()[2], xs.size()[3]);
            return self.forward(&xs.upsample_nearest2d([2 * h, 2 * w], 2.0, 2.0));
        };
        let xs = self.kernel_input(xs);
        // [B, c_in, H, W] -> [B, 4·c_out, H + 1, W + 1]
        let geometry = Geometry::SAME_3X3;
        let phases = conv_with_post_op(&xs, weight, bias.as_ref(), geometry, self.act.post_op())
            .unwrap_or_else(|| {
                let ys = xs.conv2d(weight, bias.as_ref(), [1], [1], [1], 1);
                self.act.apply_inference(ys)
            });
        // -> [B, c_out, 2H, 2W]
        rtf_kernels::phases::interleave_phases(&phases)
    }

    /// The convolution with the activation fused into it, where oneDNN can (or in the Winograd
    /// form), `None` otherwise.
    fn fused_conv_act(&self, xs: &Tensor) -> Option<Tensor> {
        let ys = match &self.weight {
            FoldedWeight::Winograd(u) => Some(self.winograd_conv(xs, u, None)),
            weight => conv_with_post_op(
                &self.kernel_input(xs),
                weight.for_onednn()?,
                self.bias.as_ref(),
                self.geometry,
                self.act.post_op(),
            ),
        };
        ys.map(|ys| self.map_output(ys))
    }

    /// The convolution alone (bias included, no activation).
    fn conv(&self, xs: &Tensor) -> Tensor {
        match &self.weight {
            FoldedWeight::Winograd(u) => {
                let d = self.geometry.dilation;
                rtf_kernels::winograd::conv3x3_dilated(xs, u, self.bias.as_ref(), None, false, d)
            }
            weight => {
                let ys = plain_conv(
                    &self.kernel_input(xs),
                    &weight.dense(),
                    self.bias.as_ref(),
                    self.geometry,
                );
                self.map_output(ys)
            }
        }
    }

    /// The Winograd form: act(conv(xs) + bias (+ residual)).
    fn winograd_conv(&self, xs: &Tensor, u: &Tensor, residual: Option<&Tensor>) -> Tensor {
        let relu = self.act == Act::Relu;
        let d = self.geometry.dilation;
        let ys =
            rtf_kernels::winograd::conv3x3_dilated(xs, u, self.bias.as_ref(), residual, relu, d);
        if relu {
            ys
        } else {
            self.act.apply_inference(ys)
        }
    }

    /// A map as this unit's kernels take it: float32 where it computes emulated bf16 with
    /// float32 kernels ([`Self::float_arith`]), else as it is.
    fn kernel_input(&self, xs: &Tensor) -> Tensor {
        if self.float_arith {
            xs.to_kind(Kind::Float)
        } else {
            xs.shallow_clone()
        }
    }

    /// An output in the maps' type: rounded to bf16 where [`Self::kernel_input`] made it float32.
    fn map_output(&self, ys: Tensor) -> Tensor {
        if self.float_arith {
            ys.to_kind(Kind::BFloat16)
        } else {
            ys
        }
    }
}

/// What a folded weight became, for tests: the form, its Winograd positions and type.
#[cfg(test)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum WeightForm {
    Dense(Kind),
    Packed(Kind),
    Winograd { positions: i64, kind: Kind },
}

#[cfg(test)]
impl FoldedConv {
    pub(crate) fn weight_form(&self) -> WeightForm {
        match &self.weight {
            FoldedWeight::Dense(w) => WeightForm::Dense(w.kind()),
            FoldedWeight::Packed(w) => WeightForm::Packed(w.kind()),
            FoldedWeight::Winograd(u) => WeightForm::Winograd {
                positions: u.size()[0],
                kind: u.kind(),
            },
        }
    }

    pub(crate) fn bias_kind(&self) -> Option<Kind> {
        self.bias.as_ref().map(Tensor::kind)
    }

    pub(crate) fn float_arith(&self) -> bool {
        self.float_arith
    }
}

/// libtorch's convolution (or transposed convolution) of `geometry`.
fn plain_conv(xs: &Tensor, weight: &Tensor, bias: Option<&Tensor>, g: Geometry) -> Tensor {
    if g.transposed {
        xs.conv_transpose2d(
            weight,
            bias,
            [g.stride],
            [g.padding],
            [0],
            g.groups,
            [g.dilation],
        )
    } else {
        xs.conv2d(
            weight,
            bias,
            [g.stride],
            [g.padding],
            [g.dilation],
            g.groups,
        )
    }
}

/// The folded float32 `weight` in the form inference runs it in: Winograd's where
/// [`rtf_kernels::winograd::form`] has one within the fold's forms, on the CPU, in fp32 and, where
/// the fold takes the bf16 Winograd forms, in bf16 (of the bf16-rounded weight, as bf16
/// kernels would take it); else laid out by `lay_out` (in the fold's type) and packed for
/// oneDNN where it can be.
fn inference_form(
    weight: Tensor,
    geometry: Geometry,
    folder: &Folder,
    lay_out: impl Fn(Tensor) -> Tensor,
) -> FoldedWeight {
    let kind = folder.kind();
    let dims = weight.size();
    let winograd_kind = match kind {
        Kind::Float => true,
        Kind::BFloat16 => folder.kernels().bf16_winograd,
        _ => false,
    };
    let forms = folder.kernels().winograd;
    let winograd = (winograd_kind && weight.device() == tch::Device::Cpu)
        .then(|| rtf_kernels::winograd::form(forms, dims[2], geometry, dims[1], dims[0]))
        .flatten();
    if let (Some(form), false) = (winograd, geometry.transposed) {
        let weight = match kind {
            Kind::BFloat16 => weight.to_kind(kind).to_kind(Kind::Float),
            _ => weight,
        };
        return FoldedWeight::Winograd(rtf_kernels::winograd::weight_transform(&weight, form));
    }
    let dense = lay_out(weight);
    match rtf_kernels::onednn::pack_weight(&dense, geometry) {
        Some(packed) => FoldedWeight::Packed(packed),
        None => FoldedWeight::Dense(dense),
    }
}
