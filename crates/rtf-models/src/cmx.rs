//! CMX (Zhang et al., "CMX: Cross-Modal Fusion for RGB-X Semantic Segmentation with
//! Transformers", IEEE T-ITS 2023) with SegFormer MiT-B0…B5 dual encoders and the MLP decoder,
//! as the official code builds it for MF (github.com/huaaaliu/RGBX_Semantic_Segmentation:
//! `models/builder.py`, `models/encoders/dual_segformer.py`, `models/net_utils.py`,
//! `models/decoders/MLPDecoder.py`), under its state_dict names.
//!
//! Two MiT encoders, RGB (`backbone.patch_embedN`, `backbone.blockN.i`, `backbone.normN`) and
//! thermal (the same under `backbone.extra_`), of four stages: an overlapping patch embedding
//! (strided convolution, LayerNorm), transformer blocks (efficient self-attention, whose keys
//! and values come from the map reduced by a stride-`sr` convolution and LayerNorm; Mix-FFN
//! with a depth-wise 3×3 convolution and GELU), LayerNorm. After every stage the Feature
//! Rectify Module (`backbone.FRMs.i`) adds to each stream the other one weighted by channel and
//! spatial weights, and the rectified maps go on to the next stage; the Feature Fusion Module
//! (`backbone.FFMs.i`: cross-attention paths over the tokens, then a channel embedding with
//! BatchNorm) merges them into the stage's output. The MLP decoder (`decode_head`, width 512)
//! projects the four outputs, upsamples them to 1/4, fuses them (1×1 conv, BatchNorm, ReLU) and
//! classifies; the logits are upsampled bilinearly (align_corners false) to the input size.
//!
//! Input: rtf's `[B, 4, H, W]` (R, G, B, T in [0, 1]:
//! [`UnitRange`](rtf_core::InputConvention::UnitRange)). The network's first step is the
//! official pipeline's preprocessing, so the data pipeline stays in unit range: the colour
//! planes in B, G, R order (the official loader reads images with `cv2.imread(path, 4)`, which
//! keeps OpenCV's BGR order; [`ColorOrder::Rgb`] feeds R, G, B instead), normalised with the
//! ImageNet mean (0.485, 0.456, 0.406) and std (0.229, 0.224, 0.225) per channel; the thermal
//! plane replicated to 3 channels and normalised the same way.
//!
//! Where this differs from the official code:
//! - `cmx-mit-b1` is SegFormer's B1 (embed dims 64, 128, 320, 512; depths 2, 2, 2, 2): the
//!   official builder's `mit_b1` branch builds B0's encoder with B1's channel list for the
//!   decoder, a network that cannot run. `cmx-mit-b3` is the official `mit_b3` encoder, which
//!   the official builder never builds (an unknown backbone name falls through to B2).
//! - BatchNorm eps is PyTorch's 1e-5 everywhere, as the official evaluation builds the network;
//!   the official training sets the decoder's to 1e-3 (`config.bn_eps`).
//!
//! Training mode has the official stochastic depth ([`drop_path_rates`]) and Dropout2d(0.1)
//! before the classifier. Fresh weights follow the official init: encoder and fusion modules'
//! linear layers N(0, 0.02) (timm's `trunc_normal_`, whose ±2 bounds lie 100σ out), their
//! convolutions N(0, √(2 / fan_out)) with fan_out = k²·c_out / groups, biases 0; the decoder's
//! convolutions Kaiming-normal (fan-in) and its linear layers PyTorch's default.

use tch::nn::{self, ModuleT};
use tch::{Kind, Tensor};

use crate::error::ModelError;
use crate::layers::Path;
use crate::layers::{new_var, Act, ConvBnAct, ConvSpec, Fold, Folder, WeightInit};
use crate::Network;

mod decoder;
mod fusion;

use decoder::{decoder, Head};
use fusion::{fusion, rectify, Fusion, Rectify};

/// Attention heads per stage (self-attention and the fusion's cross-attention).
const HEADS: [i64; 4] = [1, 2, 5, 8];
/// Spatial reduction of the keys and values per stage.
const SR_RATIOS: [i64; 4] = [8, 4, 2, 1];
const MLP_RATIO: i64 = 4;
/// LayerNorm eps of the transformer blocks and the stage norms.
const BLOCK_LN_EPS: f64 = 1e-6;
/// LayerNorm eps of the patch embeddings, the attention's reduction and the cross paths.
const LN_EPS: f64 = 1e-5;
/// Stochastic-depth rate of the last block.
const DROP_PATH_RATE: f64 = 0.1;
/// Weight of the other stream in the Feature Rectify Module (λ_C = λ_S).
const RECTIFY_LAMBDA: f64 = 0.5;
/// Decoder width (`config.decoder_embed_dim`) and its dropout before the classifier.
pub const DECODER_DIM: i64 = 512;
const DECODER_DROPOUT: f64 = 0.1;

/// CMX's options: the schema's (rtf-config), read without libtorch.
pub use rtf_config::network::cmx::{ColorOrder, Config, Layout, Size, IMAGENET_MEAN, IMAGENET_STD};

/// The official stochastic-depth rates of one stream's blocks in `stage` (0-based):
/// `linspace(0, 0.1, Σ depths)` over the blocks in order, except that stage 2 gives all its RGB
/// blocks the stage's first rate and all its thermal blocks the second (`dpr[cur]` and
/// `dpr[cur + 1]` in the official code). Empty for a stage past the fourth.
pub fn drop_path_rates(depths: [i64; 4], stage: usize, thermal: bool) -> Vec<f64> {
    let Some(&blocks) = depths.get(stage) else {
        return Vec::new();
    };
    let total: i64 = depths.iter().sum();
    let rate = |i: i64| DROP_PATH_RATE * i as f64 / (total - 1).max(1) as f64;
    let first: i64 = depths[..stage].iter().sum();
    (0..blocks)
        .map(|j| match (stage, thermal) {
            (1, false) => rate(first),
            (1, true) => rate(first + 1),
            _ => rate(first + j),
        })
        .collect()
}

/// [B, C, H, W] -> [B, H·W, C]: a view of a map laid out channels-last in memory (every map
/// made from tokens, and the fast path's), a copy of any other.
fn tokens(xs: &Tensor) -> Tensor {
    let size = xs.size();
    xs.permute([0, 2, 3, 1])
        .reshape([size[0], size[2] * size[3], size[1]])
}

/// [B, H·W, C] -> [B, C, H, W]: a view of contiguous tokens, laid out channels-last in memory,
/// so the convolutions that read it run channels-last and [`tokens`] of their output is a
/// view again.
fn feature_map(xs: &Tensor, h: i64, w: i64) -> Tensor {
    let size = xs.size();
    xs.reshape([size[0], h, w, size[2]]).permute([0, 3, 1, 2])
}

/// `branch + xs`, a residual sum: in place on `branch` (a fresh output) outside training.
fn add_residual(xs: &Tensor, branch: Tensor, train: bool) -> Tensor {
    if train {
        xs + branch
    } else {
        let mut branch = branch;
        let _ = branch.g_add_(xs);
        branch
    }
}

/// A weight for the fast path: `kind`, contiguous, no autograd (the variable itself, not a
/// copy, where it already is all that).
fn inference_copy(t: &Tensor, kind: Kind) -> Tensor {
    tch::no_grad(|| t.detach().to_kind(kind).contiguous())
}

fn bilinear(xs: &Tensor, h: i64, w: i64) -> Tensor {
    xs.upsample_bilinear2d([h, w], false, None, None)
}

/// Stochastic depth on a residual branch [B, N, C]: in training each sample's branch is dropped
/// with probability `rate`, the kept ones scaled by 1 / (1 − rate) (timm's `DropPath`).
fn drop_path(xs: Tensor, rate: f64, train: bool) -> Tensor {
    if !train || rate <= 0.0 {
        return xs;
    }
    let keep = 1.0 - rate;
    let mut mask = Tensor::empty([xs.size()[0], 1, 1], (xs.kind(), xs.device()));
    let _ = mask.bernoulli_float_(keep);
    xs * (mask / keep)
}

/// `nn.Linear` over the last dimension: [.., c_in] -> [.., c_out].
#[derive(Debug)]
struct Linear {
    weight: Tensor,
    bias: Option<Tensor>,
    /// Folded for inference: the type the weight is cast to per call (as autocast does),
    /// rather than holding a second copy of it (docs/src/models.md, "CMX's linear layers"); a
    /// float32 weight is used as it is. The folded layer's handle on the float32 weight is what
    /// tells [`crate::fast::InferenceNet::releasing_plain_weights`] that the fast path reads it.
    cast: Option<Kind>,
}

/// How a fresh linear layer is drawn.
#[derive(Clone, Copy)]
enum LinearInit {
    /// Encoder and fusion modules: N(0, 0.02), bias 0.
    Normal002,
    /// PyTorch's default (the decoder): weight and bias U(±1/√c_in).
    TorchDefault,
}

fn linear(p: Path, c_in: i64, c_out: i64, bias: bool, init: LinearInit) -> Linear {
    let bound = 1.0 / (c_in as f64).sqrt();
    let uniform = nn::Init::Uniform {
        lo: -bound,
        up: bound,
    };
    let (weight_init, bias_init) = match init {
        LinearInit::Normal002 => (
            nn::Init::Randn {
                mean: 0.0,
                stdev: 0.02,
            },
            nn::Init::Const(0.0),
        ),
        LinearInit::TorchDefault => (uniform, uniform),
    };
    Linear {
        weight: new_var(&p, "weight", &[c_out, c_in], weight_init),
        bias: bias.then(|| new_var(&p, "bias", &[c_out], bias_init)),
        cast: None,
    }
}

impl ModuleT for Linear {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        match self.cast {
            Some(kind) => {
                assert!(!train, "a folded linear layer cannot train");
                xs.linear(&self.weight.to_kind(kind), self.bias.as_ref())
            }
            None => xs.linear(&self.weight, self.bias.as_ref()),
        }
    }
}

impl Fold for Linear {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            weight: self.weight.shallow_clone(),
            bias: self.bias.as_ref().map(|b| inference_copy(b, f.kind())),
            cast: Some(f.kind()),
        }
    }
}

/// `nn.LayerNorm` over the last dimension (weight 1, bias 0 when fresh).
#[derive(Debug)]
struct LayerNorm {
    weight: Tensor,
    bias: Tensor,
    eps: f64,
}

fn layer_norm(p: Path, dim: i64, eps: f64) -> LayerNorm {
    LayerNorm {
        weight: new_var(&p, "weight", &[dim], nn::Init::Const(1.0)),
        bias: new_var(&p, "bias", &[dim], nn::Init::Const(0.0)),
        eps,
    }
}

impl ModuleT for LayerNorm {
    fn forward_t(&self, xs: &Tensor, _train: bool) -> Tensor {
        let (weight, bias) = (&self.weight, &self.bias);
        xs.layer_norm([weight.size()[0]], Some(weight), Some(bias), self.eps, true)
    }
}

impl Fold for LayerNorm {
    /// The affine in the fold's type.
    fn folded(&self, f: &Folder) -> Self {
        Self {
            weight: inference_copy(&self.weight, f.kind()),
            bias: inference_copy(&self.bias, f.kind()),
            eps: self.eps,
        }
    }
}

/// A convolution with bias (+ BatchNorm under `bn`) drawn as the official encoder and fusion
/// modules draw it: N(0, √(2 / fan_out)), fan_out = k²·c_out / groups, bias 0.
fn encoder_conv(
    p: Path,
    bn: Option<Path>,
    c_in: i64,
    c_out: i64,
    spec: ConvSpec,
    act: Act,
) -> ConvBnAct {
    let fan_out = (spec.kernel * spec.kernel * c_out / spec.groups) as f64;
    let spec = spec.init(WeightInit::Normal((2.0 / fan_out).sqrt()));
    let unit = ConvBnAct::new(p.clone(), bn, c_in, c_out, spec, act);
    if let Some(mut bias) = p.get("bias") {
        tch::no_grad(|| {
            let _ = bias.zero_();
        });
    }
    unit
}

/// 3×3 depth-wise convolution with bias.
fn depthwise3x3(c: i64) -> ConvSpec {
    ConvSpec {
        groups: c,
        ..ConvSpec::new(3).bias(true)
    }
}

/// Overlapping patch embedding (`patch_embedN`): strided k×k convolution, LayerNorm on tokens.
#[derive(Debug)]
struct PatchEmbed {
    proj: ConvBnAct,
    norm: LayerNorm,
}

fn patch_embed(p: Path, c_in: i64, dim: i64, kernel: i64, stride: i64) -> PatchEmbed {
    let spec = ConvSpec::new(kernel).stride(stride).bias(true);
    PatchEmbed {
        proj: encoder_conv(&p / "proj", None, c_in, dim, spec, Act::Identity),
        norm: layer_norm(&p / "norm", dim, LN_EPS),
    }
}

impl PatchEmbed {
    /// [B, c_in, H, W] -> ([B, h·w, dim], h, w) with h, w = H, W / stride
    fn forward(&self, xs: &Tensor, train: bool) -> (Tensor, i64, i64) {
        let ys = xs.apply_t(&self.proj, train);
        let (h, w) = (ys.size()[2], ys.size()[3]);
        (tokens(&ys).apply_t(&self.norm, train), h, w)
    }
}

impl Fold for PatchEmbed {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            proj: self.proj.folded(f),
            norm: self.norm.folded(f),
        }
    }
}

/// Efficient self-attention (`attn`): queries from every token, keys and values from the map
/// reduced by a stride-`sr` convolution and LayerNorm (`sr`, `norm`; none at sr = 1).
#[derive(Debug)]
struct Attention {
    heads: i64,
    q: Linear,
    kv: Linear,
    proj: Linear,
    reduce: Option<(ConvBnAct, LayerNorm)>,
}

fn attention(p: Path, dim: i64, heads: i64, sr: i64) -> Attention {
    let lin = |name: &str, c_out| linear(&p / name, dim, c_out, true, LinearInit::Normal002);
    let reduce = (sr > 1).then(|| {
        let spec = ConvSpec::new(sr).stride(sr).padding(0).bias(true);
        (
            encoder_conv(&p / "sr", None, dim, dim, spec, Act::Identity),
            layer_norm(&p / "norm", dim, LN_EPS),
        )
    });
    Attention {
        heads,
        q: lin("q", dim),
        kv: lin("kv", 2 * dim),
        proj: lin("proj", dim),
        reduce,
    }
}

impl Attention {
    /// [B, N, C] (N = h·w) -> [B, N, C]: softmax(q·kᵀ / √d)·v per head, the official
    /// computation, in libtorch's fused attention (`scaled_dot_product_attention`, default
    /// scale 1/√d): flash attention on the CPU, which never holds the [N, M] scores.
    fn forward(&self, xs: &Tensor, h: i64, w: i64, train: bool) -> Tensor {
        let size = xs.size();
        let (b, n, c) = (size[0], size[1], size[2]);
        let d = c / self.heads;
        // -> [B, heads, N, d]
        let q = xs
            .apply_t(&self.q, train)
            .reshape([b, n, self.heads, d])
            .transpose(1, 2);
        // Keys and values from [B, M, C], M = N / sr².
        let source = match &self.reduce {
            Some((sr, norm)) => {
                tokens(&feature_map(xs, h, w).apply_t(sr, train)).apply_t(norm, train)
            }
            None => xs.shallow_clone(),
        };
        // -> [2, B, heads, M, d]
        let kv = source
            .apply_t(&self.kv, train)
            .reshape([b, -1, 2, self.heads, d])
            .permute([2, 0, 3, 1, 4]);
        let (k, v) = (kv.get(0), kv.get(1));
        // [B, heads, N, d] -> [B, N, heads, d] (how the CPU kernel lays its output out) -> [B, N, C]
        Tensor::scaled_dot_product_attention(&q, &k, &v, None::<Tensor>, 0.0, false, None, false)
            .transpose(1, 2)
            .reshape([b, n, c])
            .apply_t(&self.proj, train)
    }
}

impl Fold for Attention {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            heads: self.heads,
            q: self.q.folded(f),
            kv: self.kv.folded(f),
            proj: self.proj.folded(f),
            reduce: (self.reduce.as_ref()).map(|(sr, norm)| (sr.folded(f), norm.folded(f))),
        }
    }
}

/// Mix-FFN (`mlp`): fc1 (C -> 4C), depth-wise 3×3 (`dwconv.dwconv`), GELU, fc2 (4C -> C).
/// The GELU is the depth-wise unit's activation (fused into its convolution on the fast path).
#[derive(Debug)]
struct MixFfn {
    fc1: Linear,
    dwconv: ConvBnAct,
    fc2: Linear,
}

fn mix_ffn(p: Path, dim: i64) -> MixFfn {
    let hidden = dim * MLP_RATIO;
    let dw = &p / "dwconv" / "dwconv";
    MixFfn {
        fc1: linear(&p / "fc1", dim, hidden, true, LinearInit::Normal002),
        dwconv: encoder_conv(dw, None, hidden, hidden, depthwise3x3(hidden), Act::Gelu),
        fc2: linear(&p / "fc2", hidden, dim, true, LinearInit::Normal002),
    }
}

impl MixFfn {
    /// [B, N, C] -> [B, N, C]
    fn forward(&self, xs: &Tensor, h: i64, w: i64, train: bool) -> Tensor {
        let hidden = feature_map(&xs.apply_t(&self.fc1, train), h, w).apply_t(&self.dwconv, train);
        tokens(&hidden).apply_t(&self.fc2, train)
    }
}

impl Fold for MixFfn {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            fc1: self.fc1.folded(f),
            dwconv: self.dwconv.folded(f),
            fc2: self.fc2.folded(f),
        }
    }
}

/// Pre-norm transformer block (`blockN.i`): x + attn(norm1(x)), then + mlp(norm2(x)).
#[derive(Debug)]
struct Block {
    norm1: LayerNorm,
    attn: Attention,
    norm2: LayerNorm,
    mlp: MixFfn,
    drop_path: f64,
}

fn block(p: Path, stage: usize, dim: i64, drop_path: f64) -> Block {
    Block {
        norm1: layer_norm(&p / "norm1", dim, BLOCK_LN_EPS),
        attn: attention(&p / "attn", dim, HEADS[stage], SR_RATIOS[stage]),
        norm2: layer_norm(&p / "norm2", dim, BLOCK_LN_EPS),
        mlp: mix_ffn(&p / "mlp", dim),
        drop_path,
    }
}

impl Block {
    /// [B, N, C] -> [B, N, C]
    fn forward(&self, xs: &Tensor, h: i64, w: i64, train: bool) -> Tensor {
        let attn = self
            .attn
            .forward(&xs.apply_t(&self.norm1, train), h, w, train);
        let xs = add_residual(xs, drop_path(attn, self.drop_path, train), train);
        let mlp = self
            .mlp
            .forward(&xs.apply_t(&self.norm2, train), h, w, train);
        add_residual(&xs, drop_path(mlp, self.drop_path, train), train)
    }
}

impl Fold for Block {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            norm1: self.norm1.folded(f),
            attn: self.attn.folded(f),
            norm2: self.norm2.folded(f),
            mlp: self.mlp.folded(f),
            drop_path: self.drop_path,
        }
    }
}

/// One stage of one stream: `{prefix}patch_embedN`, `{prefix}blockN.*`, `{prefix}normN`.
#[derive(Debug)]
struct Stage {
    embed: PatchEmbed,
    blocks: Vec<Block>,
    norm: LayerNorm,
}

/// Stage `stage` (0-based) of the RGB (`prefix` "") or thermal (`prefix` "extra_") stream.
fn stage(p: &Path, layout: &Layout, stage: usize, thermal: bool) -> Stage {
    let prefix = if thermal { "extra_" } else { "" };
    let n = stage + 1;
    let dim = layout.dims[stage];
    let (c_in, kernel, stride) = match stage {
        0 => (3, 7, 4),
        _ => (layout.dims[stage - 1], 3, 2),
    };
    let blocks = drop_path_rates(layout.depths, stage, thermal)
        .into_iter()
        .enumerate()
        .map(|(i, rate)| block(p / format!("{prefix}block{n}") / i, stage, dim, rate))
        .collect();
    Stage {
        embed: patch_embed(
            p / format!("{prefix}patch_embed{n}"),
            c_in,
            dim,
            kernel,
            stride,
        ),
        blocks,
        norm: layer_norm(p / format!("{prefix}norm{n}"), dim, BLOCK_LN_EPS),
    }
}

impl Stage {
    /// [B, c_in, H, W] -> [B, dim, H / stride, W / stride]
    fn forward(&self, xs: &Tensor, train: bool) -> Tensor {
        let (ys, h, w) = self.embed.forward(xs, train);
        let ys = self
            .blocks
            .iter()
            .fold(ys, |ys, block| block.forward(&ys, h, w, train));
        feature_map(&ys.apply_t(&self.norm, train), h, w)
    }
}

impl Fold for Stage {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            embed: self.embed.folded(f),
            blocks: self.blocks.folded(f),
            norm: self.norm.folded(f),
        }
    }
}

/// The dual encoder (`backbone`).
#[derive(Debug)]
struct Encoder {
    rgb: Vec<Stage>,
    thermal: Vec<Stage>,
    rectify: Vec<Rectify>,
    fusion: Vec<Fusion>,
}

fn encoder(p: Path, layout: &Layout) -> Encoder {
    Encoder {
        rgb: (0..4).map(|i| stage(&p, layout, i, false)).collect(),
        thermal: (0..4).map(|i| stage(&p, layout, i, true)).collect(),
        rectify: (0..4)
            .map(|i| rectify(&p / "FRMs" / i, layout.dims[i]))
            .collect(),
        fusion: (0..4)
            .map(|i| fusion(&p / "FFMs" / i, layout.dims[i], HEADS[i]))
            .collect(),
    }
}

impl Encoder {
    /// 2 × [B, 3, H, W] -> fused [B, dims[i], H / 2^(i+2), W / 2^(i+2)] for i = 0..4
    fn forward(&self, rgb: &Tensor, thermal: &Tensor, train: bool) -> Vec<Tensor> {
        let (mut r, mut t) = (rgb.shallow_clone(), thermal.shallow_clone());
        let mut fused = Vec::with_capacity(4);
        for i in 0..4 {
            let (r_i, t_i) = (
                self.rgb[i].forward(&r, train),
                self.thermal[i].forward(&t, train),
            );
            (r, t) = self.rectify[i].forward(&r_i, &t_i, train);
            fused.push(self.fusion[i].forward(&r, &t, train));
        }
        fused
    }
}

impl Fold for Encoder {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            rgb: self.rgb.folded(f),
            thermal: self.thermal.folded(f),
            rectify: self.rectify.folded(f),
            fusion: self.fusion.folded(f),
        }
    }
}

#[derive(Debug)]
pub struct Cmx {
    config: Config,
    encoder: Encoder,
    decoder: Head,
    /// ImageNet's mean and std as [1, 3, 1, 1], made once on the weights' device (and, folded,
    /// in the folded type): a tensor filled from host memory inside `forward` would reach a JIT
    /// trace as an uninitialised `aten::empty` (the copy into it is not an op), so exports
    /// would read garbage, and on a GPU it would be a copy from host memory at every pass.
    mean: Tensor,
    std: Tensor,
}

impl Cmx {
    pub fn new(p: Path, cfg: &Config) -> Result<Self, ModelError> {
        cfg.validate()?;
        let layout = cfg.size.layout();
        Ok(Self {
            config: cfg.clone(),
            encoder: encoder(&p / "backbone", &layout),
            decoder: Head::Plain(decoder(&p / "decode_head", &layout, cfg)),
            mean: Tensor::from_slice(&IMAGENET_MEAN)
                .view([1, 3, 1, 1])
                .to_device(p.device()),
            std: Tensor::from_slice(&IMAGENET_STD)
                .view([1, 3, 1, 1])
                .to_device(p.device()),
        })
    }

    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The official preprocessing (see the module doc): [B, 4, H, W] (R, G, B, T in [0, 1]) ->
    /// the encoders' inputs, colour [B, 3, H, W] and thermal [B, 3, H, W].
    fn normalise(&self, xs: &Tensor) -> (Tensor, Tensor) {
        let on_input = |t: &Tensor| t.to_device(xs.device()).to_kind(xs.kind());
        let (mean, std) = (on_input(&self.mean), on_input(&self.std));
        let rgb = xs.narrow(1, 0, 3);
        let colour = match self.config.color_order {
            ColorOrder::Bgr => rgb.flip([1]),
            ColorOrder::Rgb => rgb,
        };
        // [B, 1, H, W] broadcast against [1, 3, 1, 1]: the replicated thermal plane.
        let thermal = xs.narrow(1, 3, 1);
        ((colour - &mean) / &std, (thermal - &mean) / &std)
    }
}

impl ModuleT for Cmx {
    /// [B, 4, H, W] (R, G, B, T in [0, 1]) -> logits [B, classes, H, W]; on the fast path
    /// float32 and NCHW-contiguous whatever its kind (upsampled from float32 logits at 1/4).
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let (h, w) = (xs.size()[2], xs.size()[3]);
        let (colour, thermal) = self.normalise(xs);
        let features = self.encoder.forward(&colour, &thermal, train);
        match &self.decoder {
            Head::Plain(decoder) => bilinear(&decoder.forward(&features, train), h, w),
            Head::Folded(decoder) => {
                assert!(!train, "a folded network cannot train");
                let logits = decoder.forward(&features);
                bilinear(&logits.to_kind(Kind::Float).contiguous(), h, w)
            }
        }
    }
}

impl Network for Cmx {
    fn input_convention(&self) -> rtf_core::InputConvention {
        self.config.input()
    }
    fn num_classes(&self) -> i64 {
        self.config.num_classes
    }
    fn size_multiple(&self) -> i64 {
        32
    }
    fn name(&self) -> String {
        self.config.name()
    }
    /// BatchNorm folded (decoder, fusion modules), the decoder in its folded form, oneDNN
    /// convolutions with their activations (GELU, ReLU) and residual adds fused in, in-place
    /// residual sums; convolution weights folded in the fold's type, linear weights cast to it
    /// per call; maps channels-last, so tokens and maps are views of one another.
    fn folded(&self, folder: &Folder) -> Option<Box<dyn Network>> {
        let Head::Plain(decoder) = &self.decoder else {
            return None;
        };
        Some(Box::new(Self {
            config: self.config.clone(),
            encoder: self.encoder.folded(folder),
            decoder: Head::Folded(decoder.folded_for_inference(folder)),
            mean: self.mean.to_kind(folder.kind()),
            std: self.std.to_kind(folder.kind()),
        }))
    }
}

#[cfg(test)]
mod tests;
