//! CMX's fusion modules: the Feature Rectify Module (`FRMs.i`) and the Feature Fusion Module
//! (`FFMs.i`: cross-attention paths, then the channel embedding).

use tch::nn::ModuleT;
use tch::{Kind, Tensor};

use super::{
    add_residual, depthwise3x3, encoder_conv, feature_map, layer_norm, linear, tokens, LayerNorm,
    Linear, LinearInit, LN_EPS, RECTIFY_LAMBDA,
};
use crate::layers::Path;
use crate::layers::{batch_norm_affine, bn2d, Act, BatchNorm, ConvBnAct, ConvSpec, Fold, Folder};

/// Feature Rectify Module (`FRMs.i`): channel weights from the average- and max-pooled
/// concatenation (`channel_weights.mlp.{0,2}`: 4C -> 4C -> 2C, sigmoid) and spatial weights
/// from the concatenated maps (`spatial_weights.mlp.{0,2}`: 1×1 2C -> C -> 2, sigmoid).
#[derive(Debug)]
pub(super) struct Rectify {
    channel1: Linear,
    channel2: Linear,
    spatial1: ConvBnAct,
    spatial2: ConvBnAct,
}

pub(super) fn rectify(p: Path, dim: i64) -> Rectify {
    let channel = &p / "channel_weights" / "mlp";
    let spatial = &p / "spatial_weights" / "mlp";
    let one = ConvSpec::new(1).bias(true);
    Rectify {
        channel1: linear(&channel / 0, 4 * dim, 4 * dim, true, LinearInit::Normal002),
        channel2: linear(&channel / 2, 4 * dim, 2 * dim, true, LinearInit::Normal002),
        spatial1: encoder_conv(&spatial / 0, None, 2 * dim, dim, one, Act::Relu),
        spatial2: encoder_conv(&spatial / 2, None, dim, 2, one, Act::Identity),
    }
}

impl Rectify {
    /// 2 × [B, C, H, W] -> 2 × [B, C, H, W]: x1 + λ·(w_c1 + w_s1)·x2, x2 + λ·(w_c0 + w_s0)·x1
    pub(super) fn forward(&self, x1: &Tensor, x2: &Tensor, train: bool) -> (Tensor, Tensor) {
        let (b, c) = (x1.size()[0], x1.size()[1]);
        let x = Tensor::cat(&[x1, x2], 1);
        // [B, 2C] average ‖ [B, 2C] max -> [B, 4C] -> [B, 2C] -> [B, 2, C, 1, 1]
        let pooled = Tensor::cat(
            &[
                x.mean_dim(&[2i64, 3][..], false, None::<Kind>),
                x.amax([2, 3], false),
            ],
            1,
        );
        let channel = pooled
            .apply_t(&self.channel1, train)
            .relu()
            .apply_t(&self.channel2, train)
            .sigmoid()
            .reshape([b, 2, c, 1, 1])
            * RECTIFY_LAMBDA;
        // [B, 2C, H, W] -> [B, C, H, W] -> [B, 2, H, W]
        let spatial = x
            .apply_t(&self.spatial1, train)
            .apply_t(&self.spatial2, train)
            .sigmoid()
            * RECTIFY_LAMBDA;
        // x1 + λ·c1·x2 + λ·s1·x2 in two passes (the official expression takes five).
        let rectified = |x: &Tensor, other: &Tensor, i: i64| {
            let out = x.addcmul(other, &channel.select(1, i));
            if train {
                out.addcmul(other, &spatial.narrow(1, i, 1))
            } else {
                let mut out = out;
                let _ = out.addcmul_(other, &spatial.narrow(1, i, 1));
                out
            }
        };
        (rectified(x1, x2, 1), rectified(x2, x1, 0))
    }
}

impl Fold for Rectify {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            channel1: self.channel1.folded(f),
            channel2: self.channel2.folded(f),
            spatial1: self.spatial1.folded(f),
            spatial2: self.spatial2.folded(f),
        }
    }
}

/// The channel embedding of the fusion (`channel_emb`): BN(1×1 residual (no bias) +
/// BN(1×1 ∘ ReLU ∘ dw3×3 ∘ 1×1)). [B, 2C, H, W] -> [B, C, H, W]
///
/// On the fast path the outer BatchNorm (`norm`) is folded into both branches' last
/// convolutions (it is affine, so it distributes over the sum), and the expansion convolution
/// adds the residual branch as it writes its output.
#[derive(Debug)]
pub(super) struct ChannelEmbed {
    residual: ConvBnAct,
    reduce: ConvBnAct,
    depthwise: ConvBnAct,
    expand: ConvBnAct,
    /// The BatchNorm after the sum; none once folded (into `residual` and `expand`).
    pub(super) norm: Option<BatchNorm>,
}

fn channel_embed(p: Path, c_in: i64, c: i64) -> ChannelEmbed {
    let e = &p / "channel_embed";
    let one = ConvSpec::new(1).bias(true);
    ChannelEmbed {
        residual: encoder_conv(
            &p / "residual",
            None,
            c_in,
            c,
            ConvSpec::new(1),
            Act::Identity,
        ),
        reduce: encoder_conv(&e / 0, None, c_in, c, one, Act::Identity),
        depthwise: encoder_conv(&e / 1, None, c, c, depthwise3x3(c), Act::Relu),
        expand: encoder_conv(&e / 3, Some(&e / 4), c, c, one, Act::Identity),
        norm: Some(bn2d(&p / "norm", c)),
    }
}

impl ModuleT for ChannelEmbed {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let reduced = xs
            .apply_t(&self.reduce, train)
            .apply_t(&self.depthwise, train);
        let residual = xs.apply_t(&self.residual, train);
        match &self.norm {
            Some(norm) => (residual + reduced.apply_t(&self.expand, train)).apply_t(norm, train),
            // norm(residual + expand(reduced)) with norm folded into both convolutions.
            None => self.expand.forward_add(&reduced, &residual, train),
        }
    }
}

impl Fold for ChannelEmbed {
    fn folded(&self, f: &Folder) -> Self {
        let norm = self
            .norm
            .as_ref()
            .expect("a folded channel embedding cannot fold again");
        let (scale, shift) = batch_norm_affine(norm);
        Self {
            residual: (self.residual).folded_with_affine(f, Some((&scale, &shift.zeros_like()))),
            reduce: self.reduce.folded(f),
            depthwise: self.depthwise.folded(f),
            expand: self.expand.folded_with_affine(f, Some((&scale, &shift))),
            norm: None,
        }
    }
}

/// Feature Fusion Module (`FFMs.i`): the cross path (`cross.*`) over both streams' tokens, then
/// the channel embedding of their concatenation.
#[derive(Debug)]
pub(super) struct Fusion {
    heads: i64,
    /// `cross.channel_proj{1,2}`: C -> 2C (residual half ‖ attention half), ReLU.
    channel_proj: [Linear; 2],
    /// `cross.cross_attn.kv{1,2}`: C -> 2C, no bias.
    kv: [Linear; 2],
    /// `cross.end_proj{1,2}`: 2C -> C.
    end_proj: [Linear; 2],
    /// `cross.norm{1,2}`.
    norm: [LayerNorm; 2],
    pub(super) embed: ChannelEmbed,
}

pub(super) fn fusion(p: Path, dim: i64, heads: i64) -> Fusion {
    let cross = &p / "cross";
    let lin = |p: Path, c_in, c_out, bias| linear(p, c_in, c_out, bias, LinearInit::Normal002);
    Fusion {
        heads,
        channel_proj: [1, 2].map(|i| lin(&cross / format!("channel_proj{i}"), dim, 2 * dim, true)),
        kv: [1, 2].map(|i| {
            lin(
                &cross / "cross_attn" / format!("kv{i}"),
                dim,
                2 * dim,
                false,
            )
        }),
        end_proj: [1, 2].map(|i| lin(&cross / format!("end_proj{i}"), 2 * dim, dim, true)),
        norm: [1, 2].map(|i| layer_norm(&cross / format!("norm{i}"), dim, LN_EPS)),
        embed: channel_embed(&p / "channel_emb", 2 * dim, dim),
    }
}

impl Fusion {
    /// 2 × [B, C, H, W] -> [B, C, H, W]
    pub(super) fn forward(&self, x1: &Tensor, x2: &Tensor, train: bool) -> Tensor {
        let (h, w) = (x1.size()[2], x1.size()[3]);
        let xs = [tokens(x1), tokens(x2)];
        // [B, N, C] -> 2 × [B, N, C] (kept half y, attended half u)
        let halves: Vec<Vec<Tensor>> = (0..2)
            .map(|i| {
                // ReLU in place on the projection's fresh output (its backward needs no input).
                let mut projected = xs[i].apply_t(&self.channel_proj[i], train);
                let _ = projected.relu_();
                projected.chunk(2, -1)
            })
            .collect();
        let attended = self.cross_attention(&halves[0][1], &halves[1][1], train);
        let out: Vec<Tensor> = (0..2)
            .map(|i| {
                let ys = Tensor::cat(&[&halves[i][0], &attended[i]], -1)
                    .apply_t(&self.end_proj[i], train);
                add_residual(&xs[i], ys, train).apply_t(&self.norm[i], train)
            })
            .collect();
        // [B, N, 2C] -> [B, 2C, H, W] -> [B, C, H, W]
        feature_map(&Tensor::cat(&out, -1), h, w).apply_t(&self.embed, train)
    }

    /// Each stream's queries (its tokens, split into heads) read the other stream's global
    /// context softmax(Kᵀ·V / √d) [B, heads, d, d] (softmax over the key dimension).
    /// 2 × [B, N, C] -> 2 × [B, N, C]
    ///
    /// Not libtorch's fused attention: as q·softmax(kᵀ·v) this is attention over channels,
    /// whose "sequence" is the d channels and whose "head dimension" the N tokens, a shape
    /// for which libtorch has no fused CPU kernel (its unfused math path is slower than these
    /// two small products: docs/src/speed-by-kind.md).
    fn cross_attention(&self, u1: &Tensor, u2: &Tensor, train: bool) -> [Tensor; 2] {
        let size = u1.size();
        let (b, n, c) = (size[0], size[1], size[2]);
        let d = c / self.heads;
        let context = |i: usize, u: &Tensor| {
            // [B, N, 2C] -> [2, B, heads, N, d]
            let kv = u
                .apply_t(&self.kv[i], train)
                .reshape([b, n, 2, self.heads, d])
                .permute([2, 0, 3, 1, 4]);
            let ctx = kv.get(0).transpose(-2, -1).matmul(&kv.get(1)) * (d as f64).powf(-0.5);
            ctx.softmax(-2, None::<Kind>)
        };
        let read = |u: &Tensor, ctx: &Tensor| {
            let q = u.reshape([b, n, self.heads, d]).transpose(1, 2);
            q.matmul(ctx).transpose(1, 2).reshape([b, n, c])
        };
        let (ctx1, ctx2) = (context(0, u1), context(1, u2));
        [read(u1, &ctx2), read(u2, &ctx1)]
    }
}

impl Fold for Fusion {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            heads: self.heads,
            channel_proj: self.channel_proj.each_ref().map(|l| l.folded(f)),
            kv: self.kv.each_ref().map(|l| l.folded(f)),
            end_proj: self.end_proj.each_ref().map(|l| l.folded(f)),
            norm: self.norm.each_ref().map(|n| n.folded(f)),
            embed: self.embed.folded(f),
        }
    }
}
