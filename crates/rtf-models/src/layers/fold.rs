//! BatchNorm folding: a [`ConvBnAct`]'s inference form, built anew from its trained variables
//! ([`Fold::folded`], [`ConvBnAct::folded_with_affine`]).

use tch::{Kind, Tensor};

use super::{Act, BatchNorm, ConvBnAct, ConvSpec, Form, Plain};
use crate::fast::folder::{Fold, Folder};
use crate::fast::unit::FoldedConv;

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

impl Fold for ConvBnAct {
    fn folded(&self, folder: &Folder) -> Self {
        self.folded_with_affine(folder, None)
    }
}

impl ConvBnAct {
    /// [`Fold::folded`], with `affine` = (scale, shift) per output channel applied after this
    /// unit's own BatchNorm and before its activation folded in as well (a BatchNorm that
    /// follows the unit outside it, e.g. after a residual sum: see [`batch_norm_affine`]).
    pub fn folded_with_affine(&self, folder: &Folder, affine: Option<(&Tensor, &Tensor)>) -> Self {
        let (weight, bias) = self.fold_affines(affine);
        let geometry = self.geometry();
        let upsampled = self.spec.nearest_upsampled_input;
        let unit = FoldedConv::new(weight, bias, geometry, upsampled, self.act, folder);
        // In a releasing fold the plain tensors go now, not after the whole network has
        // folded: the fold never holds two copies of the network.
        folder.release(self.plain().tensors());
        Self {
            spec: self.spec,
            act: self.act,
            out_channels: self.out_channels,
            form: Form::Folded(unit),
        }
    }

    /// This unit's convolution with its eval-mode BatchNorm folded in, float32: (weight,
    /// bias). For folds that combine several units into one (e.g. HeatNet's PSP module).
    pub fn folded_float(&self) -> (Tensor, Option<Tensor>) {
        self.fold_affines(None)
    }

    /// A folded unit of the given folded float32 `weight` and `bias`, without a BatchNorm: a
    /// convolution the fast path derives from a network's own (e.g. a block of a wider one's
    /// input columns). Inference only.
    pub fn folded_from(
        weight: Tensor,
        bias: Option<Tensor>,
        spec: ConvSpec,
        act: Act,
        folder: &Folder,
    ) -> Self {
        let spec = spec.bias(bias.is_some());
        let out_channels = weight.size()[0];
        let geometry = Self::plain_geometry(&spec);
        let unit = FoldedConv::new(
            weight,
            bias,
            geometry,
            spec.nearest_upsampled_input,
            act,
            folder,
        );
        Self {
            spec,
            act,
            out_channels,
            form: Form::Folded(unit),
        }
    }

    /// The trained variables; folding a folded unit again is a caller's bug.
    pub(super) fn plain(&self) -> &Plain {
        match &self.form {
            Form::Plain(p) => p,
            Form::Folded(_) => panic!("a folded convolution cannot be folded again"),
        }
    }

    /// The float32 convolution weight and bias with this unit's BatchNorm and then `affine`
    /// folded in.
    fn fold_affines(&self, affine: Option<(&Tensor, &Tensor)>) -> (Tensor, Option<Tensor>) {
        let _guard = tch::no_grad_guard();
        let plain = self.plain();
        let weight = plain.weight.to_kind(Kind::Float);
        let bias = plain.bias.as_ref().map(|b| b.to_kind(Kind::Float));
        let mut folds: Vec<(Tensor, Tensor)> = plain.bn.iter().map(batch_norm_affine).collect();
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
}
