//! BatchNorm folding: the folded, inference-ready weights of a [`ConvBnAct`]
//! ([`Fuse::fuse`](super::Fuse::fuse), [`ConvBnAct::fuse_with_affine`]) and the forms inference
//! runs them in.

use tch::{Kind, Tensor};

use super::{
    emulates_bf16, nearest_up2_conv3x3_as_phases, to_channels_last, Act, BatchNorm, ConvBnAct,
    ConvSpec, FoldedWeight, Fused, PhaseConv, FUSE_CHANNELS_LAST,
};

/// An eval-mode BatchNorm as the per-channel affine it applies, `x·scale + shift` (float32).
pub fn batch_norm_affine(bn: &BatchNorm) -> (Tensor, Tensor) {
    let _guard = tch::no_grad_guard();
    let var = bn.running_var.to_kind(Kind::Float);
    let mean = bn.running_mean.to_kind(Kind::Float);
    let gamma = bn
        .ws
        .as_ref()
        .map_or_else(|| var.ones_like(), |w| w.to_kind(Kind::Float));
    let beta = bn
        .bs
        .as_ref()
        .map_or_else(|| var.zeros_like(), |b| b.to_kind(Kind::Float));
    let scale = &gamma / (var + bn.eps()).sqrt();
    let shift = beta - mean * &scale;
    (scale, shift)
}

impl ConvBnAct {
    /// [`Fuse::fuse`], with `affine` = (scale, shift) per output channel applied after this
    /// unit's own BatchNorm and before its activation folded in as well (a BatchNorm that
    /// follows the unit outside it, e.g. after a residual sum: see
    /// [`batch_norm_affine`]).
    pub fn fuse_with_affine(&mut self, kind: Kind, affine: Option<(&Tensor, &Tensor)>) {
        let _guard = tch::no_grad_guard();
        let (weight, bias) = self.fold_affines(affine);
        self.store_fused(weight, bias, kind);
        // Under InferenceNet::releasing_plain_weights, the plain tensors go now, not after
        // the whole network has folded: the fold never holds two copies of the network.
        let bn = self.bn.as_mut().map(BatchNorm::tensors_mut);
        let own = [Some(&mut self.weight), self.bias.as_mut()]
            .into_iter()
            .flatten();
        crate::release::release_folded(own.chain(bn.into_iter().flatten()));
    }

    /// This unit's convolution with its eval-mode BatchNorm folded in, float32: (weight,
    /// bias). For folds that combine several units into one (e.g. HeatNet's PSP module).
    pub fn folded_float(&self) -> (Tensor, Option<Tensor>) {
        self.fold_affines(None)
    }

    /// A unit of the given folded float32 `weight` and `bias`, in no VarStore and without a
    /// BatchNorm, prepared for inference in `kind`: a convolution the fast path derives from a
    /// network's own (e.g. a block of a wider one's input columns). Inference only.
    pub fn folded_from(
        weight: Tensor,
        bias: Option<Tensor>,
        spec: ConvSpec,
        act: Act,
        kind: Kind,
    ) -> Self {
        let mut unit = Self {
            weight: weight.shallow_clone(),
            bias: bias.as_ref().map(Tensor::shallow_clone),
            spec: spec.bias(bias.is_some()),
            bn: None,
            act,
            fused: None,
        };
        tch::no_grad(|| unit.store_fused(weight, bias, kind));
        unit
    }

    /// The float32 convolution weight and bias with this unit's BatchNorm and then `affine`
    /// folded in.
    fn fold_affines(&self, affine: Option<(&Tensor, &Tensor)>) -> (Tensor, Option<Tensor>) {
        let _guard = tch::no_grad_guard();
        let weight = self.weight.to_kind(Kind::Float);
        let bias = self.bias.as_ref().map(|b| b.to_kind(Kind::Float));
        let mut folds: Vec<(Tensor, Tensor)> = self.bn.iter().map(batch_norm_affine).collect();
        folds.extend(affine.map(|(s, t)| (s.to_kind(Kind::Float), t.to_kind(Kind::Float))));
        let (mut weight, mut bias) = (weight, bias);
        for (scale, shift) in folds {
            // Output channels are dim 0 of a convolution weight, dim 1 of a transposed one.
            let per_channel = if self.spec.transposed {
                scale.view([1, -1, 1, 1])
            } else {
                scale.view([-1, 1, 1, 1])
            };
            bias = Some(match &bias {
                Some(b) => b * &scale + shift,
                None => shift,
            });
            // Out of place: `weight` may be the variable itself (`to_kind` of a float one).
            weight = &weight * per_channel;
        }
        (weight, bias)
    }

    /// Lays the folded float32 `weight` and `bias` out for inference in `kind`.
    fn store_fused(&mut self, weight: Tensor, bias: Option<Tensor>, kind: Kind) {
        let channels_last = FUSE_CHANNELS_LAST.with(|c| c.get());
        let emulated = kind == Kind::BFloat16 && emulates_bf16(&weight);
        // Emulated bf16 keeps float32 weights of bf16 values (what a bf16 kernel would take).
        let stored_kind = if emulated { Kind::Float } else { kind };
        let lay_out = |w: Tensor| {
            let w = w.to_kind(kind).to_kind(stored_kind);
            if channels_last {
                to_channels_last(&w)
            } else {
                w.contiguous()
            }
        };
        let upsampled = self.spec.nearest_upsampled_input.then(|| PhaseConv {
            weight: lay_out(nearest_up2_conv3x3_as_phases(&weight)),
            bias: bias.as_ref().map(|b| b.repeat([4]).to_kind(stored_kind)),
        });
        let weight = self.inference_form(weight, kind, lay_out);
        let winograd = matches!(weight, FoldedWeight::Winograd(_));
        // The Winograd forms add a float32 bias whatever the maps' type.
        let bias_kind = if winograd { Kind::Float } else { stored_kind };
        self.fused = Some(Fused {
            weight,
            bias: bias.map(|b| b.to_kind(bias_kind)),
            upsampled,
            float_arith: emulated && !winograd,
        });
    }
}

impl ConvBnAct {
    /// The folded float32 `weight` in the form inference runs it in: Winograd's where
    /// [`crate::winograd::form`] has one, on the CPU, in fp32 and, where
    /// [`crate::winograd::bf16_applies`], in bf16 (of the bf16-rounded weight, as bf16 kernels
    /// would take it); else laid out by `lay_out` (in `kind`) and packed for oneDNN where it can
    /// be.
    fn inference_form(
        &self,
        weight: Tensor,
        kind: Kind,
        lay_out: impl Fn(Tensor) -> Tensor,
    ) -> FoldedWeight {
        let geometry = self.geometry();
        let dims = weight.size();
        let winograd_kind = match kind {
            Kind::Float => true,
            Kind::BFloat16 => crate::winograd::bf16_applies(),
            _ => false,
        };
        let winograd = (winograd_kind && weight.device() == tch::Device::Cpu)
            .then(|| crate::winograd::form(self.spec.kernel, geometry, dims[1], dims[0]))
            .flatten();
        if let (Some(form), false) = (winograd, self.spec.transposed) {
            let weight = match kind {
                Kind::BFloat16 => weight.to_kind(kind).to_kind(Kind::Float),
                _ => weight,
            };
            return FoldedWeight::Winograd(crate::winograd::weight_transform(&weight, form));
        }
        let dense = lay_out(weight);
        match crate::onednn::pack_weight(&dense, geometry) {
            Some(packed) => FoldedWeight::Packed(packed),
            None => FoldedWeight::Dense(dense),
        }
    }
}
