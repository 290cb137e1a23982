//! torchvision-style ResNet pieces (BasicBlock, Bottleneck, layers, the 7×7 stem) used as
//! encoders by RTFNet, HeatNet and the baselines. Parameter names follow torchvision
//! (`conv1`, `bn1`, `layerN.i.conv1`, `layerN.i.downsample.0`, …) under a caller's prefix.

use tch::nn::ModuleT;
use tch::Tensor;

use crate::layers::Path;
use crate::layers::{Act, ConvBnAct, ConvSpec, Fold, Folder, InitScheme};

/// Residual block type of a ResNet depth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlockKind {
    Basic,
    Bottleneck,
}

impl BlockKind {
    /// Output channels per "planes" of a block.
    pub fn expansion(self) -> i64 {
        match self {
            BlockKind::Basic => 1,
            BlockKind::Bottleneck => 4,
        }
    }
}

/// Block type and blocks per layer of the torchvision depths 18, 34, 50, 101, 152.
pub fn layout(depth: i64) -> Option<(BlockKind, [i64; 4])> {
    match depth {
        18 => Some((BlockKind::Basic, [2, 2, 2, 2])),
        34 => Some((BlockKind::Basic, [3, 4, 6, 3])),
        50 => Some((BlockKind::Bottleneck, [3, 4, 6, 3])),
        101 => Some((BlockKind::Bottleneck, [3, 4, 23, 3])),
        152 => Some((BlockKind::Bottleneck, [3, 8, 36, 3])),
        _ => None,
    }
}

/// A residual block: conv1 → conv2 (→ conv3), plus the identity or a 1×1 downsample branch.
#[derive(Debug)]
pub struct ResBlock {
    conv1: ConvBnAct,
    conv2: ConvBnAct,
    /// Bottleneck only.
    conv3: Option<ConvBnAct>,
    downsample: Option<ConvBnAct>,
}

/// Geometry of one block: stride of its 3×3 conv and its dilation.
#[derive(Debug, Clone, Copy)]
pub struct BlockGeometry {
    pub stride: i64,
    pub dilation: i64,
}

fn conv_bn(
    p: &Path,
    conv: &str,
    bn: &str,
    c_in: i64,
    c_out: i64,
    spec: ConvSpec,
    act: Act,
) -> ConvBnAct {
    ConvBnAct::new(p / conv, Some(p / bn), c_in, c_out, spec, act)
}

/// torchvision BasicBlock. [B, c_in, H, W] -> [B, planes, H/s, W/s]
pub fn basic_block(
    p: Path,
    c_in: i64,
    planes: i64,
    g: BlockGeometry,
    init: InitScheme,
) -> ResBlock {
    let k3 = ConvSpec::new(3).dilation(g.dilation).scheme(init);
    ResBlock {
        conv1: conv_bn(
            &p,
            "conv1",
            "bn1",
            c_in,
            planes,
            k3.stride(g.stride),
            Act::Relu,
        ),
        conv2: conv_bn(&p, "conv2", "bn2", planes, planes, k3, Act::Relu),
        conv3: None,
        downsample: downsample(&p, c_in, planes, g.stride, init),
    }
}

/// torchvision Bottleneck (stride on the 3×3 conv, "ResNet v1.5").
/// [B, c_in, H, W] -> [B, 4·planes, H/s, W/s]
pub fn bottleneck(p: Path, c_in: i64, planes: i64, g: BlockGeometry, init: InitScheme) -> ResBlock {
    let k1 = ConvSpec::new(1).scheme(init);
    let k3 = ConvSpec::new(3)
        .dilation(g.dilation)
        .stride(g.stride)
        .scheme(init);
    let c_out = planes * BlockKind::Bottleneck.expansion();
    ResBlock {
        conv1: conv_bn(&p, "conv1", "bn1", c_in, planes, k1, Act::Relu),
        conv2: conv_bn(&p, "conv2", "bn2", planes, planes, k3, Act::Relu),
        conv3: Some(conv_bn(&p, "conv3", "bn3", planes, c_out, k1, Act::Relu)),
        downsample: downsample(&p, c_in, c_out, g.stride, init),
    }
}

/// 1×1 conv (stride s) → BN when the block changes shape; `downsample.0`, `downsample.1`.
fn downsample(p: &Path, c_in: i64, c_out: i64, stride: i64, init: InitScheme) -> Option<ConvBnAct> {
    (stride != 1 || c_in != c_out).then(|| {
        let spec = ConvSpec::new(1).stride(stride).scheme(init);
        conv_bn(
            &(p / "downsample"),
            "0",
            "1",
            c_in,
            c_out,
            spec,
            Act::Identity,
        )
    })
}

impl ModuleT for ResBlock {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let residual = match &self.downsample {
            Some(d) => xs.apply_t(d, train),
            None => xs.shallow_clone(),
        };
        // The last conv's BN output gets the residual added before its ReLU.
        match &self.conv3 {
            Some(conv3) => {
                let out = xs.apply_t(&self.conv1, train).apply_t(&self.conv2, train);
                conv3.forward_add(&out, &residual, train)
            }
            None => self
                .conv2
                .forward_add(&xs.apply_t(&self.conv1, train), &residual, train),
        }
    }
}

impl Fold for ResBlock {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            conv1: self.conv1.folded(f),
            conv2: self.conv2.folded(f),
            conv3: self.conv3.folded(f),
            downsample: self.downsample.folded(f),
        }
    }
}

/// A sequence of residual blocks (`layerN`).
#[derive(Debug)]
pub struct ResLayer {
    blocks: Vec<ResBlock>,
    pub out_channels: i64,
}

/// Options of one ResNet layer.
#[derive(Debug, Clone, Copy)]
pub struct LayerSpec {
    pub planes: i64,
    pub blocks: i64,
    pub stride: i64,
    /// Dilation of the first block and of the others (HeatNet's dilated layers).
    pub dilation_first: i64,
    pub dilation_rest: i64,
}

/// `layerN`: block 0 takes `c_in` and the stride, the rest keep the shape.
/// [B, c_in, H, W] -> [B, planes·expansion, H/s, W/s]
pub fn layer(p: Path, kind: BlockKind, c_in: i64, spec: LayerSpec, init: InitScheme) -> ResLayer {
    let geometries: Vec<BlockGeometry> = (0..spec.blocks)
        .map(|i| {
            if i == 0 {
                BlockGeometry {
                    stride: spec.stride,
                    dilation: spec.dilation_first,
                }
            } else {
                BlockGeometry {
                    stride: 1,
                    dilation: spec.dilation_rest,
                }
            }
        })
        .collect();
    layer_with(p, kind, c_in, spec.planes, &geometries, init)
}

/// A layer with an explicit stride/dilation per block (e.g. hybrid dilated convolution).
pub fn layer_with(
    p: Path,
    kind: BlockKind,
    c_in: i64,
    planes: i64,
    geometries: &[BlockGeometry],
    init: InitScheme,
) -> ResLayer {
    let c_out = planes * kind.expansion();
    let blocks = geometries
        .iter()
        .enumerate()
        .map(|(i, &g)| {
            let block_in = if i == 0 { c_in } else { c_out };
            match kind {
                BlockKind::Basic => basic_block(&p / i, block_in, planes, g, init),
                BlockKind::Bottleneck => bottleneck(&p / i, block_in, planes, g, init),
            }
        })
        .collect();
    ResLayer {
        blocks,
        out_channels: c_out,
    }
}

impl ModuleT for ResLayer {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        self.blocks
            .iter()
            .fold(xs.shallow_clone(), |x, b| x.apply_t(b, train))
    }
}

impl Fold for ResLayer {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            blocks: self.blocks.folded(f),
            out_channels: self.out_channels,
        }
    }
}

/// The stem convolution: 7×7 stride 2 pad 3 (no bias) → BN → ReLU, at `conv` / `bn`.
/// [B, c_in, H, W] -> [B, 64, H/2, W/2]
pub fn stem(conv: Path, bn: Path, c_in: i64, init: InitScheme) -> ConvBnAct {
    let spec = ConvSpec::new(7).stride(2).scheme(init);
    ConvBnAct::new(conv, Some(bn), c_in, 64, spec, Act::Relu)
}

/// The stem's 3×3 stride-2 max-pool. [B, C, H, W] -> [B, C, ⌈H/2⌉, ⌈W/2⌉]
pub fn stem_pool(xs: &Tensor) -> Tensor {
    xs.max_pool2d([3, 3], [2, 2], [1, 1], [1, 1], false)
}

/// A plain torchvision ResNet encoder without avgpool/fc: stem, max-pool, layer1..4, with
/// the parameters at `<prefix>conv1`, `<prefix>bn1`, `<prefix>layerN` (RTFNet's
/// `encoder_rgb_` / `encoder_thermal_`, or "" for torchvision names).
#[derive(Debug)]
pub struct ResNetEncoder {
    pub stem: ConvBnAct,
    pub layers: Vec<ResLayer>,
}

impl ResNetEncoder {
    pub fn new(p: &Path, prefix: &str, c_in: i64, depth: i64, init: InitScheme) -> Option<Self> {
        let (kind, blocks) = layout(depth)?;
        let stem = stem(
            p / format!("{prefix}conv1"),
            p / format!("{prefix}bn1"),
            c_in,
            init,
        );
        let mut c = 64;
        let layers = (0..4)
            .map(|i| {
                let spec = LayerSpec {
                    planes: 64 << i,
                    blocks: blocks[i],
                    stride: if i == 0 { 1 } else { 2 },
                    dilation_first: 1,
                    dilation_rest: 1,
                };
                let l = layer(p / format!("{prefix}layer{}", i + 1), kind, c, spec, init);
                c = l.out_channels;
                l
            })
            .collect();
        Some(Self { stem, layers })
    }

    /// Channels out of layer4 (512 or 2048).
    pub fn out_channels(&self) -> i64 {
        self.layers[3].out_channels
    }
}

impl Fold for ResNetEncoder {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            stem: self.stem.folded(f),
            layers: self.layers.folded(f),
        }
    }
}
