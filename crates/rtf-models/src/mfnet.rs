//! MFNet (Ha et al., IROS 2017), as the authors' published code (spec §3), and the paper's
//! Tab. III variants as options.
//!
//! Two encoders (RGB, thermal) of conv-BN-LeakyReLU blocks and mini-inception modules, a
//! decoder that adds the encoders' concatenated skips after each nearest-neighbour ×2
//! upsampling. Parameter paths are the reference state_dict names (`conv1_rgb.conv.weight`, …).

use tch::nn::ModuleT;
use tch::{Kind, Tensor};

use crate::error::ModelError;
use crate::layers::Path;
use crate::layers::{Act, ConvBnAct, ConvSpec, Fold, Folder};
use crate::Network;

/// LeakyReLU slope of every MFNet block.
pub const NEGATIVE_SLOPE: f64 = 0.2;

/// MFNet's options: the schema's (rtf-config), read without libtorch.
pub use rtf_config::network::mfnet::{
    Activation, Config, Inception, Squeeze, Upsampling, VARIANT_LETTERS,
};

/// The activation of every block of `cfg`.
fn block_act(cfg: &Config) -> Act {
    match cfg.activation {
        Activation::LeakyRelu => Act::LeakyRelu(NEGATIVE_SLOPE),
        Activation::Relu => Act::Relu,
    }
}

/// Conv k×k (bias, padding = dilation·(k−1)/2) → BatchNorm → LeakyReLU(0.2) (or ReLU);
/// `ConvBnLeakyRelu2d`. [B, c_in, H, W] -> [B, c_out, H, W]
fn conv_bn_act(p: Path, c_in: i64, c_out: i64, kernel: i64, dilation: i64, act: Act) -> ConvBnAct {
    let spec = ConvSpec::new(kernel).dilation(dilation).bias(true);
    ConvBnAct::new(&p / "conv", Some(&p / "bn"), c_in, c_out, spec, act)
}

/// One block of a conv4/conv5 stage.
// Built once per network and never moved in a hot loop: the size difference is harmless.
#[allow(clippy::large_enum_variant)]
#[derive(Debug)]
enum StageBlock {
    /// Optional 1×1 squeeze, then 3×3 ‖ 3×3 dilation 2 of c_out/2 each, concatenated.
    Mini {
        squeeze: Option<ConvBnAct>,
        left: ConvBnAct,
        right: ConvBnAct,
    },
    Single(ConvBnAct),
}

/// The conv4/conv5 stage: three blocks (mini-inception in the published network).
/// [B, c_in, H, W] -> [B, c_out, H, W]
#[derive(Debug)]
struct InceptionStage {
    blocks: Vec<StageBlock>,
}

fn inception_stage(p: Path, c_in: i64, c_out: i64, cfg: &Config) -> InceptionStage {
    let act = block_act(cfg);
    let blocks = (1..=3)
        .map(|i| {
            let block_in = if i == 1 { c_in } else { c_out };
            match cfg.inception {
                Inception::Mini => {
                    let (squeeze, c) = match cfg.squeeze {
                        Some(sq) => {
                            let c = sq.width(block_in);
                            (
                                Some(conv_bn_act(
                                    &p / format!("conv{i}_squeeze"),
                                    block_in,
                                    c,
                                    1,
                                    1,
                                    act,
                                )),
                                c,
                            )
                        }
                        None => (None, block_in),
                    };
                    StageBlock::Mini {
                        squeeze,
                        left: conv_bn_act(&p / format!("conv{i}_left"), c, c_out / 2, 3, 1, act),
                        right: conv_bn_act(&p / format!("conv{i}_right"), c, c_out / 2, 3, 2, act),
                    }
                }
                Inception::Conv3x3 => StageBlock::Single(conv_bn_act(
                    &p / format!("conv{i}"),
                    block_in,
                    c_out,
                    3,
                    1,
                    act,
                )),
                Inception::Dilated3x3 => StageBlock::Single(conv_bn_act(
                    &p / format!("conv{i}"),
                    block_in,
                    c_out,
                    3,
                    2,
                    act,
                )),
            }
        })
        .collect();
    InceptionStage { blocks }
}

impl ModuleT for InceptionStage {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        self.blocks
            .iter()
            .fold(xs.shallow_clone(), |x, block| match block {
                StageBlock::Mini {
                    squeeze,
                    left,
                    right,
                } => {
                    let x = match squeeze {
                        Some(sq) => x.apply_t(sq, train),
                        None => x,
                    };
                    Tensor::cat(&[x.apply_t(left, train), x.apply_t(right, train)], 1)
                }
                StageBlock::Single(unit) => x.apply_t(unit, train),
            })
    }
}

impl Fold for InceptionStage {
    fn folded(&self, f: &Folder) -> Self {
        let blocks = self.blocks.iter().map(|block| match block {
            StageBlock::Mini {
                squeeze,
                left,
                right,
            } => StageBlock::Mini {
                squeeze: squeeze.folded(f),
                left: left.folded(f),
                right: right.folded(f),
            },
            StageBlock::Single(unit) => StageBlock::Single(unit.folded(f)),
        });
        Self {
            blocks: blocks.collect(),
        }
    }
}

/// One modality's encoder; keeps the skips at 1/2, 1/4 and 1/8.
#[derive(Debug)]
struct Encoder {
    conv1: ConvBnAct,
    conv2_1: ConvBnAct,
    conv2_2: ConvBnAct,
    conv3_1: ConvBnAct,
    conv3_2: ConvBnAct,
    conv4: InceptionStage,
    conv5: InceptionStage,
    /// Keep max-pooling indices (for unpooling decoders).
    with_indices: bool,
}

/// Encoder output: the 1/16 features, the skips at 1/2, 1/4, 1/8 and, when asked for, the
/// indices of the four 2×2 max-pools (full → 1/2, …, 1/8 → 1/16).
struct Encoded {
    x5: Tensor,
    s2: Tensor,
    s3: Tensor,
    s4: Tensor,
    indices: Vec<Tensor>,
}

impl Encoder {
    /// `suffix` is `rgb` or `inf`, as in the reference names (`conv2_1_rgb`, `conv4_inf`).
    fn new(p: &Path, suffix: &str, c_in: i64, c: [i64; 5], cfg: &Config) -> Self {
        let path = |name: &str| p / format!("{name}_{suffix}");
        let act = block_act(cfg);
        Self {
            conv1: conv_bn_act(path("conv1"), c_in, c[0], 3, 1, act),
            conv2_1: conv_bn_act(path("conv2_1"), c[0], c[1], 3, 1, act),
            conv2_2: conv_bn_act(path("conv2_2"), c[1], c[1], 3, 1, act),
            conv3_1: conv_bn_act(path("conv3_1"), c[1], c[2], 3, 1, act),
            conv3_2: conv_bn_act(path("conv3_2"), c[2], c[2], 3, 1, act),
            conv4: inception_stage(path("conv4"), c[2], c[3], cfg),
            conv5: inception_stage(path("conv5"), c[3], c[4], cfg),
            with_indices: cfg.upsampling == Upsampling::Indices,
        }
    }

    fn forward_t(&self, xs: &Tensor, train: bool) -> Encoded {
        let mut indices = Vec::new();
        let plain_pool = |x: &Tensor| {
            if train {
                x.max_pool2d_default(2)
            } else {
                max_pool_2x2(x)
            }
        };
        let mut pool = |x: &Tensor| {
            if self.with_indices {
                let (y, i) = x.max_pool2d_with_indices([2, 2], [2, 2], [0, 0], [1, 1], false);
                indices.push(i);
                y
            } else {
                plain_pool(x)
            }
        };
        // [B, c_in, H, W] -> [B, c0, H/2, W/2]. conv1's output is no skip, so inference may
        // pool before activating (not with indices: ReLU ties would move them).
        let x = if self.with_indices {
            pool(&xs.apply_t(&self.conv1, train))
        } else {
            self.conv1.forward_then_max_pool(xs, train, plain_pool)
        };
        // -> s2 [B, c1, H/2, W/2] -> [B, c1, H/4, W/4]
        let s2 = x
            .apply_t(&self.conv2_1, train)
            .apply_t(&self.conv2_2, train);
        let x = pool(&s2);
        // -> s3 [B, c2, H/4, W/4] -> [B, c2, H/8, W/8]
        let s3 = x
            .apply_t(&self.conv3_1, train)
            .apply_t(&self.conv3_2, train);
        let x = pool(&s3);
        // -> s4 [B, c3, H/8, W/8] -> [B, c3, H/16, W/16] -> [B, c4, H/16, W/16]
        let s4 = x.apply_t(&self.conv4, train);
        let x5 = pool(&s4).apply_t(&self.conv5, train);
        Encoded {
            x5,
            s2,
            s3,
            s4,
            indices,
        }
    }
}

impl Fold for Encoder {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            conv1: self.conv1.folded(f),
            conv2_1: self.conv2_1.folded(f),
            conv2_2: self.conv2_2.folded(f),
            conv3_1: self.conv3_1.folded(f),
            conv3_2: self.conv3_2.folded(f),
            conv4: self.conv4.folded(f),
            conv5: self.conv5.folded(f),
            with_indices: self.with_indices,
        }
    }
}

/// 2×2 max pooling with stride 2 for even H and W: the maximum of the even and odd rows
/// (whole rows, contiguous in channels-last memory), then of the even and odd columns. The
/// same values as `max_pool2d` without computing indices, and faster on MFNet's large
/// channels-last maps (docs/src/models.md). Eval only (ties route gradients differently).
/// [B, C, H, W] -> [B, C, H/2, W] -> [B, C, H/2, W/2]
fn max_pool_2x2(x: &Tensor) -> Tensor {
    let (h, w) = (x.size()[2], x.size()[3]);
    let rows = x.slice(2, 0, h, 2).maximum(&x.slice(2, 1, h, 2));
    rows.slice(3, 0, w, 2).maximum(&rows.slice(3, 1, w, 2))
}

/// Nearest-neighbour ×2 upsampling. [B, C, H, W] -> [B, C, 2H, 2W]
fn upsample2(xs: &Tensor) -> Tensor {
    let (h, w) = (xs.size()[2], xs.size()[3]);
    xs.upsample_nearest2d([2 * h, 2 * w], 2.0, 2.0)
}

/// `x + cat(a, b)` along channels, the decoder's skip merge. For fp32 inference the two
/// parts are added in place into the channel ranges of `x` (no concatenation built);
/// libtorch 2.13's bf16 adds on such strided channel slices are slower than the plain form,
/// so bf16 and training use that (docs/src/models.md, "Skip merges by precision").
fn add_skips(mut x: Tensor, a: &Tensor, b: Option<&Tensor>, train: bool) -> Tensor {
    match b {
        Some(b) if train || x.kind() != Kind::Float => x + Tensor::cat(&[a, b], 1),
        Some(b) => {
            let ca = a.size()[1];
            let _ = x.narrow(1, 0, ca).g_add_(a);
            let _ = x.narrow(1, ca, b.size()[1]).g_add_(b);
            x
        }
        None if train => x + a,
        None => {
            let _ = x.g_add_(a);
            x
        }
    }
}

#[derive(Debug)]
pub struct MfNet {
    config: Config,
    rgb: Encoder,
    thermal: Option<Encoder>,
    decode4: ConvBnAct,
    decode3: ConvBnAct,
    decode2: ConvBnAct,
    decode1: ConvBnAct,
}

impl MfNet {
    pub fn new(p: Path, cfg: &Config) -> Result<Self, ModelError> {
        cfg.validate()?;
        let (r, t) = (cfg.rgb_channels, cfg.thermal_channels);
        let fused = r[4] + t[4];
        let d4 = r[2] + t[2];
        let d3 = r[1] + t[1];
        let d2 = cfg.decode2_channels;
        let act = block_act(cfg);
        Ok(Self {
            config: cfg.clone(),
            rgb: Encoder::new(&p, "rgb", 3, r, cfg),
            thermal: cfg
                .has_thermal()
                .then(|| Encoder::new(&p, "inf", 1, t, cfg)),
            decode4: conv_bn_act(&p / "decode4", fused, d4, 3, 1, act),
            decode3: conv_bn_act(&p / "decode3", d4, d3, 3, 1, act),
            decode2: conv_bn_act(&p / "decode2", d3, d2, 3, 1, act),
            decode1: {
                // Always fed a ×2 upsampled map; nearest upsampling folds into the convolution.
                let spec = ConvSpec::new(3).bias(true);
                let spec = match cfg.upsampling {
                    Upsampling::Nearest => spec.nearest_upsampled_input(),
                    Upsampling::Indices => spec,
                };
                let p = &p / "decode1";
                ConvBnAct::new(&p / "conv", Some(&p / "bn"), d2, cfg.num_classes, spec, act)
            },
        })
    }

    pub fn config(&self) -> &Config {
        &self.config
    }
}

/// `cat(a, b)` along channels, or `a` alone when there is no thermal encoder.
fn cat_opt(a: &Tensor, b: Option<&Tensor>) -> Tensor {
    match b {
        Some(b) => Tensor::cat(&[a, b], 1),
        None => a.shallow_clone(),
    }
}

impl ModuleT for MfNet {
    /// [B, 4, H, W] (R, G, B, T in [0, 1]) -> logits [B, classes, H, W]
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let rgb = self.rgb.forward_t(&xs.narrow(1, 0, 3), train);
        let thermal = self
            .thermal
            .as_ref()
            .map(|e| e.forward_t(&xs.narrow(1, 3, 1), train));
        let th = thermal.as_ref();
        let shortcuts = self.config.shortcuts;
        // ×2 by nearest neighbour, or by unpooling with pool `level`'s indices (3 = 1/8→1/16).
        let up = |x: &Tensor, level: usize| match self.config.upsampling {
            Upsampling::Nearest => upsample2(x),
            Upsampling::Indices => {
                let indices = cat_opt(&rgb.indices[level], th.map(|t| &t.indices[level]));
                let (h, w) = (x.size()[2], x.size()[3]);
                x.max_unpool2d(&indices, [2 * h, 2 * w])
            }
        };
        let skip = |x: Tensor, a: &Tensor, b: Option<&Tensor>| {
            if shortcuts {
                add_skips(x, a, b, train)
            } else {
                x
            }
        };
        // [B, r4 + t4, H/16, W/16] -> [B, r4 + t4, H/8, W/8]
        let x = up(&cat_opt(&rgb.x5, th.map(|t| &t.x5)), 3);
        // -> [B, r2 + t2, H/8, W/8] -> [B, r2 + t2, H/4, W/4]
        let x = skip(x, &rgb.s4, th.map(|t| &t.s4)).apply_t(&self.decode4, train);
        // -> [B, r1 + t1, H/4, W/4] -> [B, r1 + t1, H/2, W/2]
        let x = skip(up(&x, 2), &rgb.s3, th.map(|t| &t.s3)).apply_t(&self.decode3, train);
        // -> [B, d2, H/2, W/2] -> [B, d2, H, W]
        let x = skip(up(&x, 1), &rgb.s2, th.map(|t| &t.s2)).apply_t(&self.decode2, train);
        // decode1 is a full block in the reference: logits pass BN and LeakyReLU.
        match self.config.upsampling {
            Upsampling::Nearest => self.decode1.forward_upsampled(&x, train),
            Upsampling::Indices => up(&x, 0).apply_t(&self.decode1, train),
        }
    }
}

impl Fold for MfNet {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            config: self.config.clone(),
            rgb: self.rgb.folded(f),
            thermal: self.thermal.folded(f),
            decode4: self.decode4.folded(f),
            decode3: self.decode3.folded(f),
            decode2: self.decode2.folded(f),
            decode1: self.decode1.folded(f),
        }
    }
}

impl Network for MfNet {
    fn input_convention(&self) -> rtf_core::InputConvention {
        self.config.input
    }
    fn num_classes(&self) -> i64 {
        self.config.num_classes
    }
    fn size_multiple(&self) -> i64 {
        16
    }
    fn name(&self) -> String {
        self.config.name()
    }
    fn folded(&self, folder: &Folder) -> Option<Box<dyn Network>> {
        Some(Box::new(Fold::folded(self, folder)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::weights;
    use crate::test_util::{assert_matches_reference_keys, forward_shape};
    use tch::{nn, Device, Kind};

    fn build(cfg: &Config) -> (nn::VarStore, MfNet) {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = MfNet::new(vs.root().into(), cfg).unwrap();
        (vs, net)
    }

    #[test]
    fn reference_parameter_count_is_736275() {
        let (vs, _) = build(&Config::reference(9));
        assert_eq!(weights::count_trainable(&vs), 736_275);
    }

    #[test]
    fn paper_widths_are_smaller() {
        let (vs, _) = build(&Config::paper(9));
        assert!(weights::count_trainable(&vs) < 736_275);
    }

    #[test]
    fn parameter_names_and_shapes_match_reference_keys() {
        let (vs, _) = build(&Config::reference(9));
        assert_matches_reference_keys(&vs, "mfnet.txt");
    }

    #[test]
    fn strided_max_pool_equals_max_pool2d() {
        let x = Tensor::randn([2, 3, 8, 12], (Kind::Float, Device::Cpu));
        assert!(max_pool_2x2(&x).equal(&x.max_pool2d_default(2)));
        let nhwc = crate::layers::to_channels_last(&x.to_kind(Kind::BFloat16));
        assert!(max_pool_2x2(&nhwc).equal(&nhwc.max_pool2d_default(2)));
    }

    #[test]
    fn forward_keeps_size_and_gives_class_channels() {
        let (_vs, net) = build(&Config::reference(9));
        assert_eq!(forward_shape(&net, [2, 4, 64, 80]), vec![2, 9, 64, 80]);
        assert_eq!(forward_shape(&net, [1, 4, 32, 48]), vec![1, 9, 32, 48]);
    }

    #[test]
    fn train_mode_forward_backward_updates_running_stats() {
        let (vs, net) = build(&Config::reference(5));
        let x = Tensor::rand([2, 4, 32, 32], (Kind::Float, Device::Cpu));
        let y = net.forward_t(&x, true);
        assert_eq!(y.size(), vec![2, 5, 32, 32]);
        y.mean(Kind::Float).backward();
        let mean = vs.variables()["decode1.bn.running_mean"]
            .abs()
            .sum(Kind::Float);
        assert!(
            mean.double_value(&[]) > 0.0,
            "BN running mean must move in training mode"
        );
        let grad = vs.variables()["conv1_inf.conv.weight"].grad();
        assert!(grad.defined() && grad.abs().sum(Kind::Float).double_value(&[]) > 0.0);
    }

    #[test]
    fn invalid_widths_are_refused() {
        let cfg = Config {
            thermal_channels: [16, 16, 16, 36, 32],
            ..Config::reference(9)
        };
        let vs = nn::VarStore::new(Device::Cpu);
        let err = MfNet::new(vs.root().into(), &cfg).unwrap_err().to_string();
        assert!(err.contains("conv4 skip width"), "{err}");
    }

    #[test]
    fn config_serde_round_trip_with_defaults() {
        let cfg = Config::reference(9);
        let json = serde_json::to_string(&cfg).unwrap();
        assert_eq!(serde_json::from_str::<Config>(&json).unwrap(), cfg);
        let minimal: Config = serde_json::from_str(r#"{"num_classes": 9}"#).unwrap();
        assert_eq!(minimal, cfg);
    }

    #[test]
    fn fused_inference_agrees_with_plain_path() {
        use crate::fast::{
            argmax_agreement, max_relative_difference, InferenceNet, Precision,
            FUSED_FP32_TOLERANCE,
        };
        tch::manual_seed(3);
        let vs = nn::VarStore::new(Device::Cpu);
        let cfg = crate::ModelConfig::from_name("mfnet", 9).unwrap();
        let net = crate::build(&vs.root(), &cfg).unwrap();
        // Training-mode passes give the BN layers non-trivial running statistics.
        for _ in 0..3 {
            let _ = net.forward_t(
                &Tensor::rand([2, 4, 64, 80], (Kind::Float, Device::Cpu)),
                true,
            );
        }
        let x = Tensor::rand([2, 4, 64, 80], (Kind::Float, Device::Cpu));
        let plain = tch::no_grad(|| net.forward_t(&x, false));
        let fast = InferenceNet::new(net, Precision::Fp32).unwrap();
        assert!(fast.is_fused());
        let fused = fast.forward(&x).unwrap();
        assert_eq!(fused.size(), plain.size());
        let rel = max_relative_difference(&plain, &fused);
        assert!(rel < FUSED_FP32_TOLERANCE, "max relative difference {rel}");
        // The NCHW layout gives the same result, in NCHW.
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("w.safetensors");
        weights::save_safetensors(
            &vs,
            &crate::ModelConfig::Mfnet(Config::reference(9)),
            crate::Modality::RgbT,
            &file,
        )
        .unwrap();
        let (mut vs2, net2) = build(&Config::reference(9));
        weights::load_safetensors(&mut vs2, &file).unwrap();
        let nchw =
            InferenceNet::with_layout(Box::new(net2), Precision::Fp32, crate::fast::Layout::Nchw)
                .unwrap();
        let out = nchw.forward(&x).unwrap();
        let rel = max_relative_difference(&plain, &out);
        assert!(
            rel < FUSED_FP32_TOLERANCE,
            "NCHW: max relative difference {rel}"
        );
        let err = fast.forward(&Tensor::rand([1, 4, 60, 80], (Kind::Float, Device::Cpu)));
        assert!(err.is_err(), "sizes must be multiples of 16");
        // bfloat16 (activations fused into the convolutions, decode1 as phases): float NCHW
        // logits that still pick the plain path's class almost everywhere.
        let (mut vs3, net3) = build(&Config::reference(9));
        weights::load_safetensors(&mut vs3, &file).unwrap();
        let bf16 = InferenceNet::new(Box::new(net3), Precision::Bf16).unwrap();
        let out = bf16.forward(&x).unwrap();
        assert_eq!(out.kind(), Kind::Float);
        assert!(out.is_contiguous());
        let agreement = argmax_agreement(&plain, &out);
        assert!(agreement >= 0.98, "bf16 agreement {agreement}");
    }

    #[test]
    fn paper_table_iii_variants_build_run_and_name_themselves() {
        let reference = {
            let (vs, _) = build(&Config::reference(9));
            weights::count_trainable(&vs)
        };
        for letter in VARIANT_LETTERS {
            let cfg = Config::variant(letter, 9).unwrap();
            assert_eq!(cfg.name(), format!("mfnet-{letter}"));
            let (vs, net) = build(&cfg);
            assert_eq!(
                forward_shape(&net, [1, 4, 32, 48]),
                vec![1, 9, 32, 48],
                "mfnet-{letter}"
            );
            let count = weights::count_trainable(&vs);
            let names = vs.variables();
            match letter {
                'b' => assert!(
                    !names
                        .keys()
                        .any(|k| k.ends_with("_inf") || k.contains("_inf."))
                        && count < reference
                ),
                // Doubling every width roughly quadruples the parameters.
                'e' | 'g' | 'i' => assert!(count > 3 * reference, "mfnet-{letter}: {count}"),
                // Same parameters as a mini-inception block (paper Sec. V-B).
                'c' | 'd' => {
                    assert!(names.contains_key("conv4_rgb.conv1.conv.weight") && count == reference)
                }
                'k' | 'l' | 'm' | 'n' => {
                    assert!(names.contains_key("conv5_inf.conv2_squeeze.conv.weight"))
                }
                _ => assert_eq!(count, reference, "mfnet-{letter} only changes the wiring"),
            }
        }
        assert!(Config::variant('a', 9).is_none() && Config::variant('o', 9).is_none());
    }

    /// The fused path's unpooling uses its own pooling's indices: it computes the plain path's
    /// function. Up to rounding, which can flip a max-pool's choice where two values of a
    /// window are within it, and the unpooled map then differs at that pixel and spreads: 1
    /// draw in 150 of weights and input here (measured, max relative difference 1.1e-2 against
    /// ≤ 4.2e-7 for the others). So three inputs, of which at least two must agree; wrong
    /// indices would fail all three.
    #[test]
    fn unpooling_variant_uses_pooling_indices_and_fuses() {
        use crate::fast::{max_relative_difference, InferenceNet, Precision, FUSED_FP32_TOLERANCE};
        let cfg = Config::variant('h', 9).unwrap();
        let (_vs, net) = build(&cfg);
        let net: Box<dyn Network> = Box::new(net);
        let inputs: Vec<Tensor> = (0..3)
            .map(|_| Tensor::rand([1, 4, 32, 32], (Kind::Float, Device::Cpu)))
            .collect();
        let plain: Vec<Tensor> = inputs
            .iter()
            .map(|x| tch::no_grad(|| net.forward_t(x, false)))
            .collect();
        let fast = InferenceNet::new(net, Precision::Fp32).unwrap();
        let rel: Vec<f64> = inputs
            .iter()
            .zip(&plain)
            .map(|(x, p)| max_relative_difference(p, &fast.forward(x).unwrap()))
            .collect();
        let agreeing = rel.iter().filter(|&&r| r < FUSED_FP32_TOLERANCE).count();
        assert!(agreeing >= 2, "max relative differences {rel:?}");
    }
}
