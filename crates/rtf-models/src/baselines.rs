//! The papers' baseline networks (RTFNet Tab. III, MFNet Tab. II/IV), each as in its original
//! paper, with a 3-channel (RGB) and a 4-channel (RGB-T) input: SegNet, U-Net, PSPNet,
//! DUC-HDC, ERFNet, ENet; and FuseNet, two-stream by design (RGB + thermal in place of depth).
//! No reference weights exist for these in rtf, so their parameter names are ours
//! (torchvision-style for the ResNet backbones, under `backbone.`).

use tch::nn::{self, ModuleT};
use tch::Tensor;

use crate::error::ModelError;
use crate::layers::Path;
use crate::layers::{Act, BatchNorm, ConvBnAct, ConvSpec, Fold, Folder, InitScheme, WeightInit};
use crate::resnet::{self, BlockGeometry, BlockKind, ResLayer};
use crate::Network;

mod enet;

use enet::{enet, Enet};

/// The baselines' options: the schema's (rtf-config), read without libtorch.
pub use rtf_config::network::baselines::{Arch, Config};

/// Conv 3×3 → BN → ReLU at `p.conv` / `p.bn`.
fn cbr(p: Path, c_in: i64, c_out: i64) -> ConvBnAct {
    ConvBnAct::new(
        &p / "conv",
        Some(&p / "bn"),
        c_in,
        c_out,
        ConvSpec::new(3).bias(true),
        Act::Relu,
    )
}

fn bilinear(xs: &Tensor, h: i64, w: i64) -> Tensor {
    xs.upsample_bilinear2d([h, w], false, None, None)
}

// ------------------------------------------------------------------------------ SegNet

/// VGG16-BN stages: (convs, width).
const VGG16: [(usize, i64); 5] = [(2, 64), (2, 128), (3, 256), (3, 512), (3, 512)];

/// A VGG16-BN encoder (13 conv-BN-ReLU, 2×2 max-pools with indices).
#[derive(Debug)]
struct VggEncoder {
    stages: Vec<Vec<ConvBnAct>>,
}

fn vgg_encoder(p: Path, c_in: i64) -> VggEncoder {
    let mut c = c_in;
    let stages = VGG16
        .iter()
        .enumerate()
        .map(|(s, &(n, width))| {
            (0..n)
                .map(|i| {
                    let unit = cbr(&p / s / i, c, width);
                    c = width;
                    unit
                })
                .collect()
        })
        .collect();
    VggEncoder { stages }
}

/// SegNet's mirrored decoder: per stage unpool (indices), then conv-BN-ReLU; the last conv
/// is a plain classifier. Stage widths mirror VGG16.
#[derive(Debug)]
struct SegnetDecoder {
    stages: Vec<Vec<ConvBnAct>>,
}

fn segnet_decoder(p: Path, num_classes: i64) -> SegnetDecoder {
    // From the deepest stage up: (input width, output widths of its convs).
    let plan: [(i64, Vec<i64>); 5] = [
        (512, vec![512, 512, 512]),
        (512, vec![512, 512, 256]),
        (256, vec![256, 256, 128]),
        (128, vec![128, 64]),
        (64, vec![64, num_classes]),
    ];
    let stages = plan
        .iter()
        .enumerate()
        .map(|(s, (c_in, widths))| {
            let mut c = *c_in;
            widths
                .iter()
                .enumerate()
                .map(|(i, &w)| {
                    let last = s == 4 && i == widths.len() - 1;
                    let unit = if last {
                        let spec = ConvSpec::new(3).bias(true);
                        ConvBnAct::new(&p / s / i / "conv", None, c, w, spec, Act::Identity)
                    } else {
                        cbr(&p / s / i, c, w)
                    };
                    c = w;
                    unit
                })
                .collect()
        })
        .collect();
    SegnetDecoder { stages }
}

fn pool_with_indices(x: &Tensor) -> (Tensor, Tensor) {
    x.max_pool2d_with_indices([2, 2], [2, 2], [0, 0], [1, 1], false)
}

impl SegnetDecoder {
    /// `pooled` = per encoder stage (indices, size before pooling), shallow first.
    fn forward_t(&self, x: Tensor, pooled: &[(Tensor, Vec<i64>)], train: bool) -> Tensor {
        self.stages
            .iter()
            .zip(pooled.iter().rev())
            .fold(x, |x, (stage, (indices, size))| {
                // [B, C, h, w] -> [B, C, 2h, 2w]
                let x = x.max_unpool2d(indices, [size[2], size[3]]);
                stage.iter().fold(x, |x, unit| x.apply_t(unit, train))
            })
    }
}

/// SegNet (Badrinarayanan et al., TPAMI 2017): VGG16-BN encoder, decoder with pooling-index
/// unpooling. [B, 3|4, H, W] -> [B, classes, H, W]
#[derive(Debug)]
struct Segnet {
    encoder: VggEncoder,
    decoder: SegnetDecoder,
}

impl Segnet {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let mut pooled = Vec::new();
        let x = self
            .encoder
            .stages
            .iter()
            .fold(xs.shallow_clone(), |x, stage| {
                let x = stage.iter().fold(x, |x, unit| x.apply_t(unit, train));
                let (y, indices) = pool_with_indices(&x);
                pooled.push((indices, x.size()));
                y
            });
        self.decoder.forward_t(x, &pooled, train)
    }
}

// ------------------------------------------------------------------------------ FuseNet

/// FuseNet (Hazirbas et al., ACCV 2016): a VGG16-BN RGB encoder and one for the second
/// modality (here thermal, 1 channel); after each stage the thermal features are added into
/// the RGB path (the thermal path stays pure); SegNet decoder on the fused path. Dropout 0.4
/// after the deeper pools, as the original.
#[derive(Debug)]
struct Fusenet {
    rgb: VggEncoder,
    thermal: VggEncoder,
    decoder: SegnetDecoder,
}

const FUSENET_DROPOUT: f64 = 0.4;

impl Fusenet {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let mut rgb = xs.narrow(1, 0, 3);
        let mut th = xs.narrow(1, 3, 1);
        let mut pooled = Vec::new();
        for (s, (rs, ts)) in self.rgb.stages.iter().zip(&self.thermal.stages).enumerate() {
            let t = ts.iter().fold(th, |x, u| x.apply_t(u, train));
            let r = rs.iter().fold(rgb, |x, u| x.apply_t(u, train)) + &t;
            let (r, indices) = pool_with_indices(&r);
            pooled.push((indices, t.size()));
            let t = t.max_pool2d_default(2);
            let drop = |x: Tensor| {
                if s >= 2 {
                    x.dropout(FUSENET_DROPOUT, train)
                } else {
                    x
                }
            };
            rgb = drop(r);
            th = drop(t);
        }
        self.decoder.forward_t(rgb, &pooled, train)
    }
}

// ------------------------------------------------------------------------------ U-Net

/// U-Net (Ronneberger et al., MICCAI 2015) with padded 3×3 convolutions (the original's are
/// unpadded and crop the skips; padding keeps the output at the input size). No BatchNorm, so
/// the paper's initialisation matters (§3: N(0, √(2/N)), N the incoming connections): with
/// PyTorch's default U(±1/√N) the 23 ReLU layers shrink the signal and the network never
/// leaves the all-background answer (measured: lab/training/quick_budget_curves.sh, sweep).
#[derive(Debug)]
struct Unet {
    down: Vec<(ConvBnAct, ConvBnAct)>,
    up: Vec<(ConvBnAct, ConvBnAct, ConvBnAct)>,
    out: ConvBnAct,
}

/// U-Net's initialisation (paper §3).
const UNET_INIT: WeightInit = WeightInit::KaimingNormalFanIn;

fn double_conv(p: &Path, c_in: i64, c_out: i64) -> (ConvBnAct, ConvBnAct) {
    let spec = ConvSpec::new(3).bias(true).init(UNET_INIT);
    (
        ConvBnAct::new(p / "conv1", None, c_in, c_out, spec, Act::Relu),
        ConvBnAct::new(p / "conv2", None, c_out, c_out, spec, Act::Relu),
    )
}

fn unet(p: Path, c_in: i64, num_classes: i64) -> Unet {
    let widths = [64, 128, 256, 512, 1024];
    let down = (0..5)
        .map(|i| {
            double_conv(
                &(&p / "down" / i),
                if i == 0 { c_in } else { widths[i - 1] },
                widths[i],
            )
        })
        .collect();
    let up = (0..4)
        .map(|i| {
            let (c, half) = (widths[4 - i], widths[3 - i]);
            let sp = &p / "up" / i;
            let spec = ConvSpec::new(2)
                .stride(2)
                .transposed()
                .bias(true)
                .init(UNET_INIT);
            let upconv = ConvBnAct::new(&sp / "upconv", None, c, half, spec, Act::Identity);
            let (a, b) = double_conv(&sp, c, half);
            (upconv, a, b)
        })
        .collect();
    let out = ConvBnAct::new(
        &p / "out",
        None,
        64,
        num_classes,
        ConvSpec::new(1).bias(true).init(UNET_INIT),
        Act::Identity,
    );
    Unet { down, up, out }
}

impl Unet {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let mut skips = Vec::new();
        let mut x = xs.shallow_clone();
        for (i, (a, b)) in self.down.iter().enumerate() {
            if i > 0 {
                x = x.max_pool2d_default(2);
            }
            x = x.apply_t(a, train).apply_t(b, train);
            skips.push(x.shallow_clone());
        }
        // [B, 1024, H/16, W/16] -> … -> [B, 64, H, W]
        for ((upconv, a, b), skip) in self.up.iter().zip(skips.iter().rev().skip(1)) {
            x = Tensor::cat(&[skip, &x.apply_t(upconv, train)], 1)
                .apply_t(a, train)
                .apply_t(b, train);
        }
        x.apply_t(&self.out, train)
    }
}

// ------------------------------------------------------------------------------ dilated ResNets

/// A dilated ResNet trunk (output stride 8) under `backbone.` with torchvision names.
#[derive(Debug)]
struct DilatedResNet {
    stem: ConvBnAct,
    layers: Vec<ResLayer>,
}

/// layer3/layer4 dilations per block; layer1/2 are plain (stride 1, 2).
fn dilated_resnet(p: Path, c_in: i64, blocks: [i64; 4], l3: &[i64], l4: &[i64]) -> DilatedResNet {
    let init = InitScheme::TORCHVISION;
    let stem = resnet::stem(&p / "conv1", &p / "bn1", c_in, init);
    let plain = |n: i64, stride: i64| -> Vec<BlockGeometry> {
        (0..n)
            .map(|i| BlockGeometry {
                stride: if i == 0 { stride } else { 1 },
                dilation: 1,
            })
            .collect()
    };
    let dilated = |d: &[i64]| -> Vec<BlockGeometry> {
        d.iter()
            .map(|&dilation| BlockGeometry {
                stride: 1,
                dilation,
            })
            .collect()
    };
    let geometries = [
        plain(blocks[0], 1),
        plain(blocks[1], 2),
        dilated(l3),
        dilated(l4),
    ];
    let mut c = 64;
    let layers = geometries
        .iter()
        .enumerate()
        .map(|(i, g)| {
            let l = resnet::layer_with(
                &p / format!("layer{}", i + 1),
                BlockKind::Bottleneck,
                c,
                64 << i,
                g,
                init,
            );
            c = l.out_channels;
            l
        })
        .collect();
    DilatedResNet { stem, layers }
}

impl DilatedResNet {
    /// [B, c_in, H, W] -> [B, 2048, H/8, W/8]
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let x = resnet::stem_pool(&xs.apply_t(&self.stem, train));
        self.layers.iter().fold(x, |x, l| x.apply_t(l, train))
    }
}

impl Fold for DilatedResNet {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            stem: self.stem.folded(f),
            layers: self.layers.folded(f),
        }
    }
}

/// PSPNet (Zhao et al., CVPR 2017) on a dilated ResNet-50: pyramid pooling (bins 1, 2, 3, 6;
/// 1×1 conv 2048→512-BN-ReLU each), concat (4096) → 3×3 conv 512-BN-ReLU → dropout 0.1 →
/// 1×1 classifier → bilinear ×8. The training-only auxiliary head is left out.
#[derive(Debug)]
struct Pspnet {
    backbone: DilatedResNet,
    ppm: Vec<ConvBnAct>,
    head: ConvBnAct,
    classifier: ConvBnAct,
}

const PSP_BINS: [i64; 4] = [1, 2, 3, 6];

fn pspnet(p: Path, c_in: i64, num_classes: i64) -> Pspnet {
    // torchvision's replace_stride_with_dilation: first block keeps the previous dilation.
    let backbone = dilated_resnet(
        &p / "backbone",
        c_in,
        [3, 4, 6, 3],
        &[1, 2, 2, 2, 2, 2],
        &[2, 4, 4],
    );
    let k1 = ConvSpec::new(1);
    let ppm = (0..PSP_BINS.len())
        .map(|i| {
            ConvBnAct::new(
                &p / "ppm" / i / 1,
                Some(&p / "ppm" / i / 2),
                2048,
                512,
                k1,
                Act::Relu,
            )
        })
        .collect();
    let head = ConvBnAct::new(
        &p / "final" / 0,
        Some(&p / "final" / 1),
        4096,
        512,
        ConvSpec::new(3),
        Act::Relu,
    );
    let classifier = ConvBnAct::new(
        &p / "final" / 4,
        None,
        512,
        num_classes,
        k1.bias(true),
        Act::Identity,
    );
    Pspnet {
        backbone,
        ppm,
        head,
        classifier,
    }
}

impl Pspnet {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let (h, w) = (xs.size()[2], xs.size()[3]);
        let f = self.backbone.forward_t(xs, train);
        let (fh, fw) = (f.size()[2], f.size()[3]);
        let mut parts = vec![f.shallow_clone()];
        for (&bin, conv) in PSP_BINS.iter().zip(&self.ppm) {
            parts.push(bilinear(
                &f.adaptive_avg_pool2d([bin, bin]).apply_t(conv, train),
                fh,
                fw,
            ));
        }
        let x = Tensor::cat(&parts, 1)
            .apply_t(&self.head, train)
            .dropout(0.1, train);
        bilinear(&x.apply_t(&self.classifier, train), h, w)
    }
}

/// DUC-HDC (Wang et al., WACV 2018) on ResNet-101: hybrid dilated convolution in layer3
/// (rates 1, 2, 3 repeated) and layer4 (3, 4, 5), then dense upsampling convolution: a 3×3
/// conv to classes·8² channels and a ×8 pixel shuffle.
#[derive(Debug)]
struct DucHdc {
    backbone: DilatedResNet,
    duc: ConvBnAct,
}

const DUC_FACTOR: i64 = 8;

fn duchdc(p: Path, c_in: i64, num_classes: i64) -> DucHdc {
    let l3: Vec<i64> = (0..23).map(|i| [1, 2, 3][i % 3]).collect();
    let backbone = dilated_resnet(&p / "backbone", c_in, [3, 4, 23, 3], &l3, &[3, 4, 5]);
    let c = num_classes * DUC_FACTOR * DUC_FACTOR;
    let duc = ConvBnAct::new(
        &p / "duc" / "conv",
        Some(&p / "duc" / "bn"),
        2048,
        c,
        ConvSpec::new(3),
        Act::Relu,
    );
    DucHdc { backbone, duc }
}

impl DucHdc {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        // [B, 2048, H/8, W/8] -> [B, classes·64, H/8, W/8] -> [B, classes, H, W]
        self.backbone
            .forward_t(xs, train)
            .apply_t(&self.duc, train)
            .pixel_shuffle(DUC_FACTOR)
    }
}

// ------------------------------------------------------------------------------ ERFNet

/// A 2-D convolution with separate kernel height/width (ERFNet, ENet's factorised convs).
#[derive(Debug)]
struct RectConv {
    conv: nn::Conv2D,
}

fn rect_conv(
    p: Path,
    c_in: i64,
    c_out: i64,
    k: [i64; 2],
    dilation: [i64; 2],
    bias: bool,
) -> RectConv {
    let padding = [dilation[0] * (k[0] - 1) / 2, dilation[1] * (k[1] - 1) / 2];
    let cfg = nn::ConvConfigND::<[i64; 2]> {
        padding,
        dilation,
        bias,
        ..Default::default()
    };
    RectConv {
        conv: nn::conv(p, c_in, c_out, k, cfg),
    }
}

impl nn::Module for RectConv {
    fn forward(&self, xs: &Tensor) -> Tensor {
        xs.apply(&self.conv)
    }
}

fn bn(p: Path, c: i64) -> BatchNorm {
    crate::layers::bn2d_init(p, c, nn::Init::Const(1.0))
}

/// ERFNet / ENet downsampler: 3×3 s2 conv (c_out − c_in channels) ‖ 2×2 max-pool, concat,
/// BN, ReLU. [B, c_in, H, W] -> [B, c_out, H/2, W/2]
#[derive(Debug)]
struct Downsampler {
    conv: ConvBnAct,
    bn: BatchNorm,
}

fn downsampler(p: Path, c_in: i64, c_out: i64) -> Downsampler {
    let spec = ConvSpec::new(3).stride(2).bias(true);
    Downsampler {
        conv: ConvBnAct::new(&p / "conv", None, c_in, c_out - c_in, spec, Act::Identity),
        bn: bn(&p / "bn", c_out),
    }
}

impl ModuleT for Downsampler {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        Tensor::cat(
            &[xs.apply_t(&self.conv, train), xs.max_pool2d_default(2)],
            1,
        )
        .apply_t(&self.bn, train)
        .relu()
    }
}

/// ERFNet non-bottleneck-1D: 3×1, 1×3 (BN), 3×1 and 1×3 dilated (BN), dropout, + input.
#[derive(Debug)]
struct NonBottleneck1d {
    convs: [RectConv; 4],
    bn1: BatchNorm,
    bn2: BatchNorm,
    dropout: f64,
}

fn non_bottleneck_1d(p: Path, c: i64, dropout: f64, d: i64) -> NonBottleneck1d {
    NonBottleneck1d {
        convs: [
            rect_conv(&p / "conv3x1_1", c, c, [3, 1], [1, 1], true),
            rect_conv(&p / "conv1x3_1", c, c, [1, 3], [1, 1], true),
            rect_conv(&p / "conv3x1_2", c, c, [3, 1], [d, 1], true),
            rect_conv(&p / "conv1x3_2", c, c, [1, 3], [1, d], true),
        ],
        bn1: bn(&p / "bn1", c),
        bn2: bn(&p / "bn2", c),
        dropout,
    }
}

impl ModuleT for NonBottleneck1d {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let [a, b, c, d] = &self.convs;
        let y = xs.apply(a).relu().apply(b).apply_t(&self.bn1, train).relu();
        let y = y.apply(c).relu().apply(d).apply_t(&self.bn2, train);
        let y = if self.dropout > 0.0 {
            y.feature_dropout(self.dropout, train)
        } else {
            y
        };
        (y + xs).relu()
    }
}

/// ERFNet upsampler: 3×3 s2 transposed conv (output padding 1) → BN → ReLU.
#[derive(Debug)]
struct Upsampler {
    conv: nn::ConvTranspose2D,
    bn: BatchNorm,
}

fn upsampler(p: Path, c_in: i64, c_out: i64) -> Upsampler {
    let cfg = nn::ConvTransposeConfig {
        stride: 2,
        padding: 1,
        output_padding: 1,
        ..Default::default()
    };
    Upsampler {
        conv: nn::conv_transpose2d(&p / "conv", c_in, c_out, 3, cfg),
        bn: bn(&p / "bn", c_out),
    }
}

impl ModuleT for Upsampler {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        xs.apply(&self.conv).apply_t(&self.bn, train).relu()
    }
}

/// ERFNet (Romera et al., T-ITS 2018): downsamplers, non-bottleneck-1D blocks with dilations
/// 2, 4, 8, 16, and a small upsampling decoder ending in a 2×2 s2 transposed conv.
#[derive(Debug)]
struct Erfnet {
    encoder: Vec<Box<dyn ModuleT>>,
    decoder: Vec<Box<dyn ModuleT>>,
    output: nn::ConvTranspose2D,
}

fn erfnet(p: Path, c_in: i64, num_classes: i64) -> Erfnet {
    let e = &p / "encoder";
    let mut encoder: Vec<Box<dyn ModuleT>> = vec![
        Box::new(downsampler(&e / 0, c_in, 16)),
        Box::new(downsampler(&e / 1, 16, 64)),
    ];
    for i in 0..5 {
        encoder.push(Box::new(non_bottleneck_1d(&e / (2 + i), 64, 0.03, 1)));
    }
    encoder.push(Box::new(downsampler(&e / 7, 64, 128)));
    for i in 0..8 {
        let d = [2, 4, 8, 16][i % 4];
        encoder.push(Box::new(non_bottleneck_1d(&e / (8 + i), 128, 0.3, d)));
    }
    let d = &p / "decoder";
    let decoder: Vec<Box<dyn ModuleT>> = vec![
        Box::new(upsampler(&d / 0, 128, 64)),
        Box::new(non_bottleneck_1d(&d / 1, 64, 0.0, 1)),
        Box::new(non_bottleneck_1d(&d / 2, 64, 0.0, 1)),
        Box::new(upsampler(&d / 3, 64, 16)),
        Box::new(non_bottleneck_1d(&d / 4, 16, 0.0, 1)),
        Box::new(non_bottleneck_1d(&d / 5, 16, 0.0, 1)),
    ];
    let cfg = nn::ConvTransposeConfig {
        stride: 2,
        ..Default::default()
    };
    let output = nn::conv_transpose2d(&d / "output", 16, num_classes, 2, cfg);
    Erfnet {
        encoder,
        decoder,
        output,
    }
}

impl Erfnet {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let x = self
            .encoder
            .iter()
            .fold(xs.shallow_clone(), |x, m| m.forward_t(&x, train));
        let x = self.decoder.iter().fold(x, |x, m| m.forward_t(&x, train));
        x.apply(&self.output)
    }
}

// ------------------------------------------------------------------------------ the network

// Built once per network and never moved in a hot loop: the size difference is harmless.
#[allow(clippy::large_enum_variant)]
#[derive(Debug)]
enum Body {
    Segnet(Segnet),
    Fusenet(Fusenet),
    Unet(Unet),
    Pspnet(Pspnet),
    Duchdc(DucHdc),
    Erfnet(Erfnet),
    Enet(Enet),
}

/// A baseline network; input always [B, 4, H, W] (R, G, B, T), of which 3-channel variants
/// use the RGB channels.
#[derive(Debug)]
pub struct Baseline {
    config: Config,
    body: Body,
}

impl Baseline {
    pub fn new(p: Path, cfg: &Config) -> Result<Self, ModelError> {
        cfg.validate()?;
        let (c, n) = (cfg.in_channels, cfg.num_classes);
        let body = match cfg.arch {
            Arch::Segnet => Body::Segnet(Segnet {
                encoder: vgg_encoder(&p / "encoder", c),
                decoder: segnet_decoder(&p / "decoder", n),
            }),
            Arch::Fusenet => Body::Fusenet(Fusenet {
                rgb: vgg_encoder(&p / "encoder_rgb", 3),
                thermal: vgg_encoder(&p / "encoder_thermal", 1),
                decoder: segnet_decoder(&p / "decoder", n),
            }),
            Arch::Unet => Body::Unet(unet(p, c, n)),
            Arch::Pspnet => Body::Pspnet(pspnet(p, c, n)),
            Arch::Duchdc => Body::Duchdc(duchdc(p, c, n)),
            Arch::Erfnet => Body::Erfnet(erfnet(p, c, n)),
            Arch::Enet => Body::Enet(enet(p, c, n)),
        };
        Ok(Self {
            config: cfg.clone(),
            body,
        })
    }
}

impl ModuleT for Baseline {
    /// [B, 4, H, W] -> logits [B, classes, H, W]
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let x = if self.config.in_channels == 3 {
            xs.narrow(1, 0, 3)
        } else {
            xs.shallow_clone()
        };
        match &self.body {
            Body::Segnet(m) => m.forward_t(&x, train),
            Body::Fusenet(m) => m.forward_t(&x, train),
            Body::Unet(m) => m.forward_t(&x, train),
            Body::Pspnet(m) => m.forward_t(&x, train),
            Body::Duchdc(m) => m.forward_t(&x, train),
            Body::Erfnet(m) => m.forward_t(&x, train),
            Body::Enet(m) => m.forward_t(&x, train),
        }
    }
}

impl Fold for VggEncoder {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            stages: self.stages.folded(f),
        }
    }
}

impl Fold for SegnetDecoder {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            stages: self.stages.folded(f),
        }
    }
}

impl Baseline {
    /// The folded body where the network is built from [`ConvBnAct`] units; ERFNet and ENet
    /// (factorised kernels, PReLU) keep their plain forward.
    fn folded_body(&self, f: &Folder) -> Option<Body> {
        Some(match &self.body {
            Body::Segnet(m) => Body::Segnet(Segnet {
                encoder: m.encoder.folded(f),
                decoder: m.decoder.folded(f),
            }),
            Body::Fusenet(m) => Body::Fusenet(Fusenet {
                rgb: m.rgb.folded(f),
                thermal: m.thermal.folded(f),
                decoder: m.decoder.folded(f),
            }),
            Body::Unet(m) => Body::Unet(Unet {
                down: m
                    .down
                    .iter()
                    .map(|(a, b)| (a.folded(f), b.folded(f)))
                    .collect(),
                up: m
                    .up
                    .iter()
                    .map(|(u, a, b)| (u.folded(f), a.folded(f), b.folded(f)))
                    .collect(),
                out: m.out.folded(f),
            }),
            Body::Pspnet(m) => Body::Pspnet(Pspnet {
                backbone: m.backbone.folded(f),
                ppm: m.ppm.folded(f),
                head: m.head.folded(f),
                classifier: m.classifier.folded(f),
            }),
            Body::Duchdc(m) => Body::Duchdc(DucHdc {
                backbone: m.backbone.folded(f),
                duc: m.duc.folded(f),
            }),
            Body::Erfnet(_) | Body::Enet(_) => return None,
        })
    }
}

impl Network for Baseline {
    fn folded(&self, folder: &Folder) -> Option<Box<dyn Network>> {
        let body = self.folded_body(folder)?;
        Some(Box::new(Self {
            config: self.config.clone(),
            body,
        }))
    }
    fn input_convention(&self) -> rtf_core::InputConvention {
        self.config.input
    }
    fn num_classes(&self) -> i64 {
        self.config.num_classes
    }
    fn size_multiple(&self) -> i64 {
        self.config.arch.size_multiple()
    }
    fn name(&self) -> String {
        self.config.name()
    }
}

#[cfg(test)]
mod tests;
