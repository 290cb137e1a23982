//! CMX's MLP decoder (`decode_head`) and its folded form.

use tch::{nn, Kind, Tensor};

use super::{
    bilinear, feature_map, inference_copy, linear, tokens, Config, Layout, Linear, LinearInit,
    DECODER_DIM, DECODER_DROPOUT,
};
use crate::layers::Path;
use crate::layers::{
    batch_norm_affine, bn2d_with, new_var, Act, BatchNorm, ConvBnAct, ConvSpec, Fold, Folder,
    WeightInit,
};

/// The MLP decoder (`decode_head`): per stage a linear projection to [`DECODER_DIM`]
/// (`linear_cN.proj`), bilinear to 1/4, concatenated (c4, c3, c2, c1), `linear_fuse` (1×1
/// conv, BatchNorm, ReLU), Dropout2d, `linear_pred` (1×1 conv).
///
/// Projection, bilinear upsampling and the 1×1 convolution are all linear, and bilinear
/// weights sum to 1, so `linear_fuse`'s convolution of the concatenation equals
/// Σᵢ up(Aᵢ·fᵢ) + a with Aᵢ = Wᵢ·Pᵢ (Wᵢ the convolution's 512 input columns of stage i, Pᵢ
/// its projection) and a = b + Σᵢ Wᵢ·pᵢ: 512-wide products at each stage's own resolution
/// instead of a 2048 -> 512 convolution of a 2048-channel map at 1/4 (the decoder's largest
/// cost by far). Training and the fast path compute that form (training forms Aᵢ and a from
/// the variables each step, so gradients reach them as before; the fast path forms them once
/// with the BatchNorm folded in); the plain eval forward keeps the official order.
#[derive(Debug)]
pub(super) struct Decoder {
    proj: Vec<Linear>,
    /// `linear_fuse.0` (weight [512, 4·512, 1, 1], bias) and `linear_fuse.1`.
    fuse_weight: Tensor,
    fuse_bias: Tensor,
    pub(super) fuse_bn: BatchNorm,
    pred: ConvBnAct,
}

/// The decoder, trained or folded.
#[derive(Debug)]
pub(super) enum Head {
    Plain(Decoder),
    Folded(FoldedDecoder),
}

/// The decoder's inference form ([`Decoder::folded_for_inference`]): the folded Aᵢ (with
/// BatchNorm's scale in) and bias, in the fold's type, then ReLU and `pred`.
#[derive(Debug)]
pub(super) struct FoldedDecoder {
    proj: Vec<Tensor>,
    bias: Tensor,
    pred: ConvBnAct,
}

pub(super) fn decoder(p: Path, layout: &Layout, cfg: &Config) -> Decoder {
    let num_classes = cfg.num_classes;
    let proj = (0..4)
        .map(|i| {
            let sp = &p / format!("linear_c{}", i + 1) / "proj";
            linear(
                sp,
                layout.dims[i],
                DECODER_DIM,
                true,
                LinearInit::TorchDefault,
            )
        })
        .collect();
    // As a ConvBnAct draws a 1×1 convolution with bias: Kaiming-normal (fan-in) weight,
    // U(±1/√fan_in) bias, then the BatchNorm.
    let fuse = &p / "linear_fuse";
    let fan_in = 4 * DECODER_DIM;
    let weight = nn::Init::Randn {
        mean: 0.0,
        stdev: (2.0 / fan_in as f64).sqrt(),
    };
    let bound = 1.0 / (fan_in as f64).sqrt();
    let bias = nn::Init::Uniform {
        lo: -bound,
        up: bound,
    };
    let dims = [DECODER_DIM, fan_in, 1, 1];
    let spec = ConvSpec::new(1)
        .bias(true)
        .init(WeightInit::KaimingNormalFanIn);
    Decoder {
        proj,
        fuse_weight: new_var(&(&fuse / 0), "weight", &dims, weight),
        fuse_bias: new_var(&(&fuse / 0), "bias", &[DECODER_DIM], bias),
        fuse_bn: bn2d_with(
            &fuse / 1,
            DECODER_DIM,
            nn::Init::Const(1.0),
            cfg.decoder_bn_eps,
        ),
        pred: ConvBnAct::new(
            &p / "linear_pred",
            None,
            DECODER_DIM,
            num_classes,
            spec,
            Act::Identity,
        ),
    }
}

impl FoldedDecoder {
    pub(super) fn forward(&self, features: &[Tensor]) -> Tensor {
        let mut fused = folded_sum(features, &self.proj, &self.bias, false);
        let _ = fused.relu_();
        fused.apply_t(&self.pred, false)
    }
}

impl Decoder {
    /// 4 stage outputs -> [B, classes, H/4, W/4]
    pub(super) fn forward(&self, features: &[Tensor], train: bool) -> Tensor {
        let fused = if train {
            let (proj, bias) = self.folded();
            folded_sum(features, &proj, &bias, true)
        } else {
            self.official_sum(features)
        };
        // [B, 512, H/4, W/4] -> [B, classes, H/4, W/4]
        fused
            .apply_t(&self.fuse_bn, train)
            .relu()
            .feature_dropout(DECODER_DROPOUT, train)
            .apply_t(&self.pred, train)
    }

    /// `linear_fuse`'s convolution as the official code runs it: the projections, bilinear
    /// to 1/4, concatenated -> [B, 4·512, H/4, W/4] -> [B, 512, H/4, W/4].
    pub(super) fn official_sum(&self, features: &[Tensor]) -> Tensor {
        let (h, w) = (features[0].size()[2], features[0].size()[3]);
        let maps: Vec<Tensor> = (0..4)
            .rev()
            .map(|i| {
                let f = &features[i];
                let m = tokens(f).apply_t(&self.proj[i], false);
                let m = feature_map(&m, f.size()[2], f.size()[3]);
                if i > 0 {
                    bilinear(&m, h, w)
                } else {
                    m
                }
            })
            .collect();
        Tensor::cat(&maps, 1).conv2d(&self.fuse_weight, Some(&self.fuse_bias), [1], [0], [1], 1)
    }

    /// (Aᵢ [512, dims[i]] for each stage, a [512]): see the type's doc. Differentiable.
    pub(super) fn folded(&self) -> (Vec<Tensor>, Tensor) {
        let weight = self.fuse_weight.reshape([DECODER_DIM, 4 * DECODER_DIM]);
        let mut bias = self.fuse_bias.shallow_clone();
        let proj = (0..4)
            .map(|i| {
                // The concatenation holds the stages in the order c4, c3, c2, c1.
                let columns = weight.narrow(1, (3 - i as i64) * DECODER_DIM, DECODER_DIM);
                if let Some(b) = &self.proj[i].bias {
                    bias = &bias + columns.mv(b);
                }
                columns.matmul(&self.proj[i].weight)
            })
            .collect();
        (proj, bias)
    }
}

/// Σᵢ up(Aᵢ·fᵢ) + a over the four stage outputs `features` (see [`Decoder`]): each product
/// at its stage's resolution, then bilinear to the first's and summed (in place outside
/// training). -> [B, 512, H/4, W/4], channels-last in memory.
pub(super) fn folded_sum(
    features: &[Tensor],
    proj: &[Tensor],
    bias: &Tensor,
    train: bool,
) -> Tensor {
    let (h, w) = (features[0].size()[2], features[0].size()[3]);
    let first = tokens(&features[0]).linear(&proj[0], Some(bias));
    let mut sum = feature_map(&first, h, w);
    for i in 1..4 {
        let f = &features[i];
        let m = tokens(f).linear(&proj[i], None::<Tensor>);
        let up = bilinear(&feature_map(&m, f.size()[2], f.size()[3]), h, w);
        if train {
            sum = &sum + up;
        } else {
            let _ = sum.g_add_(&up);
        }
    }
    sum
}

impl Decoder {
    /// The inference form, as `f` says: BatchNorm folded into the composed projections.
    pub(super) fn folded_for_inference(&self, f: &Folder) -> FoldedDecoder {
        let _guard = tch::no_grad_guard();
        let kind = f.kind();
        let (scale, shift) = batch_norm_affine(&self.fuse_bn);
        let (proj, bias) = self.folded();
        let proj = proj
            .iter()
            .map(|a| inference_copy(&(a.to_kind(Kind::Float) * scale.view([-1, 1])), kind))
            .collect();
        let bias = inference_copy(&(bias.to_kind(Kind::Float) * &scale + shift), kind);
        FoldedDecoder {
            proj,
            bias,
            pred: self.pred.folded(f),
        }
    }
}
