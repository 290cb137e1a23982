//! ENet (Paszke et al., 2016): its activations, factorised convolutions and bottlenecks.

use tch::{nn, Tensor};

use super::{bn, pool_with_indices, rect_conv, RectConv};
use crate::layers::Path;
use crate::layers::{Act, BatchNorm, ConvBnAct, ConvSpec};

/// ENet's activations: PReLU (one slope) in the encoder, ReLU in the decoder.
#[derive(Debug)]
enum EnetAct {
    Prelu(Tensor),
    Relu,
}

fn enet_act(p: &Path, name: &str, prelu: bool) -> EnetAct {
    if prelu {
        EnetAct::Prelu(crate::layers::new_var(
            &(p / name),
            "weight",
            &[1],
            nn::Init::Const(0.25),
        ))
    } else {
        EnetAct::Relu
    }
}

impl EnetAct {
    fn apply(&self, xs: &Tensor) -> Tensor {
        match self {
            EnetAct::Prelu(w) => xs.prelu(w),
            EnetAct::Relu => xs.relu(),
        }
    }
}

/// conv (no bias) → BN → activation, with a rectangular kernel.
#[derive(Debug)]
struct EnetConv {
    conv: Option<RectConv>,
    strided: Option<ConvBnAct>,
    bn: BatchNorm,
    act: Option<EnetAct>,
}

fn enet_conv(p: &Path, c_in: i64, c_out: i64, k: [i64; 2], d: i64, act: Option<bool>) -> EnetConv {
    let dilation = [if k[0] > 1 { d } else { 1 }, if k[1] > 1 { d } else { 1 }];
    EnetConv {
        conv: Some(rect_conv(p / "conv", c_in, c_out, k, dilation, false)),
        strided: None,
        bn: bn(p / "bn", c_out),
        act: act.map(|prelu| enet_act(p, "act", prelu)),
    }
}

impl EnetConv {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let y = match (&self.conv, &self.strided) {
            (Some(c), _) => xs.apply(c),
            (None, Some(s)) => xs.apply_t(s, train),
            _ => unreachable!(),
        };
        let y = y.apply_t(&self.bn, train);
        match &self.act {
            Some(a) => a.apply(&y),
            None => y,
        }
    }
}

/// One ENet bottleneck (regular, dilated, asymmetric, downsampling or upsampling).
// Built once per network and never moved in a hot loop: the size difference is harmless.
#[allow(clippy::large_enum_variant)]
#[derive(Debug)]
enum EnetBlock {
    Regular {
        ext: Vec<EnetConv>,
        out_act: EnetAct,
        dropout: f64,
    },
    Down {
        ext: Vec<EnetConv>,
        out_act: EnetAct,
        dropout: f64,
        c_out: i64,
    },
    Up {
        main: EnetConv,
        ext1: EnetConv,
        tconv: nn::ConvTranspose2D,
        tbn: BatchNorm,
        tact: EnetAct,
        ext2: EnetConv,
        out_act: EnetAct,
        dropout: f64,
    },
}

/// Regular bottleneck: 1×1 (c→c/4), 3×3 (dilation d) or 5×1 + 1×5 (asymmetric), 1×1 back,
/// Dropout2d, + input. [B, c, H, W] -> [B, c, H, W]
fn enet_regular(p: Path, c: i64, d: i64, asymmetric: bool, dropout: f64, prelu: bool) -> EnetBlock {
    let i = c / 4;
    let mut ext = vec![enet_conv(&(&p / "ext_conv1"), c, i, [1, 1], 1, Some(prelu))];
    if asymmetric {
        ext.push(enet_conv(
            &(&p / "ext_conv2a"),
            i,
            i,
            [5, 1],
            1,
            Some(prelu),
        ));
        ext.push(enet_conv(
            &(&p / "ext_conv2b"),
            i,
            i,
            [1, 5],
            1,
            Some(prelu),
        ));
    } else {
        ext.push(enet_conv(&(&p / "ext_conv2"), i, i, [3, 3], d, Some(prelu)));
    }
    ext.push(enet_conv(&(&p / "ext_conv3"), i, c, [1, 1], 1, Some(prelu)));
    EnetBlock::Regular {
        ext,
        out_act: enet_act(&p, "out_act", prelu),
        dropout,
    }
}

/// Downsampling bottleneck: max-pool (indices kept) with zero-padded channels ‖ 2×2 s2 conv,
/// 3×3, 1×1. [B, c_in, H, W] -> [B, c_out, H/2, W/2]
fn enet_down(p: Path, c_in: i64, c_out: i64, dropout: f64) -> EnetBlock {
    let i = c_in / 4;
    let strided = ConvSpec::new(2).stride(2).padding(0);
    let first = EnetConv {
        conv: None,
        strided: Some(ConvBnAct::new(
            &p / "ext_conv1" / "conv",
            None,
            c_in,
            i,
            strided,
            Act::Identity,
        )),
        bn: bn(&p / "ext_conv1" / "bn", i),
        act: Some(enet_act(&(&p / "ext_conv1"), "act", true)),
    };
    let ext = vec![
        first,
        enet_conv(&(&p / "ext_conv2"), i, i, [3, 3], 1, Some(true)),
        enet_conv(&(&p / "ext_conv3"), i, c_out, [1, 1], 1, Some(true)),
    ];
    EnetBlock::Down {
        ext,
        out_act: enet_act(&p, "out_act", true),
        dropout,
        c_out,
    }
}

/// Upsampling bottleneck: 1×1 conv + unpooling with the matching indices ‖ 1×1, 2×2 s2
/// transposed conv, 1×1. [B, c_in, H, W] -> [B, c_out, 2H, 2W]
fn enet_up(p: Path, c_in: i64, c_out: i64, dropout: f64) -> EnetBlock {
    let i = c_in / 4;
    let cfg = nn::ConvTransposeConfig {
        stride: 2,
        bias: false,
        ..Default::default()
    };
    EnetBlock::Up {
        main: enet_conv(&(&p / "main_conv1"), c_in, c_out, [1, 1], 1, None),
        ext1: enet_conv(&(&p / "ext_conv1"), c_in, i, [1, 1], 1, Some(false)),
        tconv: nn::conv_transpose2d(&p / "ext_tconv1", i, i, 2, cfg),
        tbn: bn(&p / "ext_tconv1_bn", i),
        tact: EnetAct::Relu,
        ext2: enet_conv(&(&p / "ext_conv2"), i, c_out, [1, 1], 1, None),
        out_act: EnetAct::Relu,
        dropout,
    }
}

/// ENet (Paszke et al., 2016): initial block, bottleneck stages 1–3 (PReLU), upsampling
/// stages 4–5 (ReLU), full transposed convolution.
#[derive(Debug)]
pub(super) struct Enet {
    initial_conv: ConvBnAct,
    initial_bn: BatchNorm,
    initial_act: EnetAct,
    blocks: Vec<EnetBlock>,
    fullconv: nn::ConvTranspose2D,
}

pub(super) fn enet(p: Path, c_in: i64, num_classes: i64) -> Enet {
    let spec = ConvSpec::new(3).stride(2);
    let initial_conv = ConvBnAct::new(
        &p / "initial" / "conv",
        None,
        c_in,
        16 - c_in,
        spec,
        Act::Identity,
    );
    let mut blocks = vec![enet_down(&p / "down1_0", 16, 64, 0.01)];
    for i in 1..=4 {
        blocks.push(enet_regular(
            &p / format!("regular1_{i}"),
            64,
            1,
            false,
            0.01,
            true,
        ));
    }
    blocks.push(enet_down(&p / "down2_0", 64, 128, 0.1));
    for stage in [2, 3] {
        // regular, dilated 2, asymmetric 5, dilated 4, regular, dilated 8, asymmetric, dilated 16
        let plan = [
            (1, false),
            (2, false),
            (1, true),
            (4, false),
            (1, false),
            (8, false),
            (1, true),
            (16, false),
        ];
        for (i, (d, asym)) in plan.into_iter().enumerate() {
            blocks.push(enet_regular(
                &p / format!("block{stage}_{}", i + 1),
                128,
                d,
                asym,
                0.1,
                true,
            ));
        }
    }
    blocks.push(enet_up(&p / "up4_0", 128, 64, 0.1));
    blocks.push(enet_regular(&p / "regular4_1", 64, 1, false, 0.1, false));
    blocks.push(enet_regular(&p / "regular4_2", 64, 1, false, 0.1, false));
    blocks.push(enet_up(&p / "up5_0", 64, 16, 0.1));
    blocks.push(enet_regular(&p / "regular5_1", 16, 1, false, 0.1, false));
    let cfg = nn::ConvTransposeConfig {
        stride: 2,
        padding: 1,
        output_padding: 1,
        bias: false,
        ..Default::default()
    };
    Enet {
        initial_conv,
        initial_bn: bn(&p / "initial" / "bn", 16),
        initial_act: enet_act(&(&p / "initial"), "act", true),
        blocks,
        fullconv: nn::conv_transpose2d(&p / "fullconv", 16, num_classes, 3, cfg),
    }
}

impl Enet {
    pub(super) fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        // [B, c_in, H, W] -> [B, 16, H/2, W/2]
        let main = xs.apply_t(&self.initial_conv, train);
        let pooled = xs.max_pool2d([3, 3], [2, 2], [1, 1], [1, 1], false);
        let mut x = self
            .initial_act
            .apply(&Tensor::cat(&[main, pooled], 1).apply_t(&self.initial_bn, train));
        // Pooling indices of the downsampling blocks, consumed by the upsampling ones.
        let mut indices: Vec<(Tensor, Vec<i64>)> = Vec::new();
        for block in &self.blocks {
            x = match block {
                EnetBlock::Regular {
                    ext,
                    out_act,
                    dropout,
                } => {
                    let y = ext
                        .iter()
                        .fold(x.shallow_clone(), |y, c| c.forward_t(&y, train));
                    out_act.apply(&(y.feature_dropout(*dropout, train) + &x))
                }
                EnetBlock::Down {
                    ext,
                    out_act,
                    dropout,
                    c_out,
                } => {
                    let (main, idx) = pool_with_indices(&x);
                    indices.push((idx, x.size()));
                    let s = main.size();
                    let pad = Tensor::zeros(
                        [s[0], c_out - s[1], s[2], s[3]],
                        (main.kind(), main.device()),
                    );
                    let main = Tensor::cat(&[main, pad], 1);
                    let y = ext
                        .iter()
                        .fold(x.shallow_clone(), |y, c| c.forward_t(&y, train));
                    out_act.apply(&(y.feature_dropout(*dropout, train) + main))
                }
                EnetBlock::Up {
                    main,
                    ext1,
                    tconv,
                    tbn,
                    tact,
                    ext2,
                    out_act,
                    dropout,
                } => {
                    let (idx, size) = indices.pop().expect("one downsampling per upsampling");
                    let m = main
                        .forward_t(&x, train)
                        .max_unpool2d(&idx, [size[2], size[3]]);
                    let y = ext1.forward_t(&x, train).apply(tconv).apply_t(tbn, train);
                    let y = ext2
                        .forward_t(&tact.apply(&y), train)
                        .feature_dropout(*dropout, train);
                    out_act.apply(&(y + m))
                }
            };
        }
        // [B, 16, H/2, W/2] -> [B, classes, H, W]
        x.apply(&self.fullconv)
    }
}
