//! HeatNet (Vertens et al., IROS 2020) networks (spec §5): PSPNet on a dilated ResNet-50
//! (output stride 8) with late fusion, early fusion, RGB-only or IR-only input, and the
//! fully-convolutional critic.
//!
//! Names follow the published `models/pspnet.py` (`psp.stages.i.1`, `psp.bottleneck`,
//! `up_1.conv.{0,1,2}`, `final.0`); its extractor module is not published, so the backbone
//! is named torchvision-style under `feats.` (late fusion: `feats.rgb.*` and `feats.ir.*` for
//! the replicated stem, layer1 and layer2, then the shared `feats.layer3`, `feats.layer4`).

use serde::{Deserialize, Serialize};
use tch::nn::{self, ModuleT};
use tch::{Kind, Tensor};

use crate::error::ModelError;
use crate::layers::Path;
use crate::layers::{Act, ConvBnAct, ConvSpec, Fold, Folder, InitScheme};
use crate::resnet::{self, BlockKind, LayerSpec, ResLayer};
use crate::Network;

/// HeatNet's options: the schema's (rtf-config), read without libtorch.
pub use rtf_config::network::heatnet::{freiburg_input, Config, Inputs};

/// Dropout probabilities of the reference head.
const DROP_PSP: f64 = 0.3;
const DROP_UP: f64 = 0.15;
/// Pyramid bins of the PSP module.
const BINS: [i64; 4] = [1, 2, 3, 6];

/// Stem + layer1 + layer2 of a ResNet-50 (stride 8 overall).
/// [B, c_in, H, W] -> [B, 512, H/8, W/8]
#[derive(Debug)]
struct Front {
    stem: ConvBnAct,
    layer1: ResLayer,
    layer2: ResLayer,
}

fn front(p: Path, c_in: i64) -> Front {
    let init = InitScheme::NORMAL_002;
    let spec = |planes, blocks, stride| LayerSpec {
        planes,
        blocks,
        stride,
        dilation_first: 1,
        dilation_rest: 1,
    };
    Front {
        stem: resnet::stem(&p / "conv1", &p / "bn1", c_in, init),
        layer1: resnet::layer(
            &p / "layer1",
            BlockKind::Bottleneck,
            64,
            spec(64, 3, 1),
            init,
        ),
        layer2: resnet::layer(
            &p / "layer2",
            BlockKind::Bottleneck,
            256,
            spec(128, 4, 2),
            init,
        ),
    }
}

impl ModuleT for Front {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        resnet::stem_pool(&xs.apply_t(&self.stem, train))
            .apply_t(&self.layer1, train)
            .apply_t(&self.layer2, train)
    }
}

impl Fold for Front {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            stem: self.stem.folded(f),
            layer1: self.layer1.folded(f),
            layer2: self.layer2.folded(f),
        }
    }
}

/// Dilated layer3 (dilation 2) and layer4 (dilation 4), no striding; the first block of each
/// keeps dilation 1. [B, c_in, H/8, W/8] -> [B, 2048, H/8, W/8]
fn back(p: &Path, c_in: i64) -> (ResLayer, ResLayer) {
    let init = InitScheme::NORMAL_002;
    let l3 = LayerSpec {
        planes: 256,
        blocks: 6,
        stride: 1,
        dilation_first: 1,
        dilation_rest: 2,
    };
    let l4 = LayerSpec {
        planes: 512,
        blocks: 3,
        stride: 1,
        dilation_first: 1,
        dilation_rest: 4,
    };
    (
        resnet::layer(p / "layer3", BlockKind::Bottleneck, c_in, l3, init),
        resnet::layer(p / "layer4", BlockKind::Bottleneck, 1024, l4, init),
    )
}

/// Pyramid pooling: per bin adaptive average pool → 1×1 conv (no bias) → bilinear up;
/// concat with the input → 1×1 conv → ReLU. [B, 2048, h, w] -> [B, 1024, h, w]
#[derive(Debug)]
enum PspModule {
    /// The trained stages and bottleneck.
    Plain {
        stages: Vec<ConvBnAct>,
        bottleneck: ConvBnAct,
    },
    /// The inference form ([`Fold::folded`]).
    Folded(PspFolded),
}

/// The PSP module's inference form, the same function with a fifth of the bottleneck's work.
/// The stages end without an activation, and a 1×1 convolution (mixing channels per pixel)
/// commutes with bilinear upsampling (mixing pixels per channel with weights that sum to 1), so
/// the bottleneck's columns over bin i's prior compose with that stage:
/// `B_i·up(C_i·pool_i(x)) = up((B_i·C_i)·pool_i(x))`. The 4 × 2048 prior columns then run on
/// 1 + 4 + 9 + 36 pooled pixels instead of h×w upsampled ones; only the input's 2048 columns
/// run at full size, with the summed priors added before the ReLU. (At 640×480 the
/// bottleneck is HeatNet's largest convolution: 10240 → 1024 at 80×60.)
#[derive(Debug)]
struct PspFolded {
    /// ReLU(B_x·x + bias + priors): 1×1, features → out.
    main: ConvBnAct,
    /// Per bin, B_i·C_i as a 1×1 weight [out, features, 1, 1], float32.
    priors: Vec<Tensor>,
}

/// One 1×1 convolution `features → features` per bin, under `p / i / 1` (`psp.stages.i.1`).
fn psp_stages(p: &Path, features: i64, spec: ConvSpec) -> Vec<ConvBnAct> {
    (0..BINS.len())
        .map(|i| ConvBnAct::new(p / i / 1, None, features, features, spec, Act::Identity))
        .collect()
}

fn psp_module(p: Path, features: i64, out: i64) -> PspModule {
    let spec = ConvSpec::new(1).scheme(InitScheme::NORMAL_002);
    let stages = psp_stages(&(&p / "stages"), features, spec);
    let c_cat = features * (BINS.len() as i64 + 1);
    let bottleneck = ConvBnAct::new(
        &p / "bottleneck",
        None,
        c_cat,
        out,
        spec.bias(true),
        Act::Relu,
    );
    PspModule::Plain { stages, bottleneck }
}

fn bilinear(xs: &Tensor, h: i64, w: i64) -> Tensor {
    xs.upsample_bilinear2d([h, w], false, None, None)
}

impl ModuleT for PspModule {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let (stages, bottleneck) = match self {
            PspModule::Plain { stages, bottleneck } => (stages, bottleneck),
            PspModule::Folded(folded) => {
                assert!(!train, "a folded PSP module cannot train");
                return folded.forward(xs);
            }
        };
        let (h, w) = (xs.size()[2], xs.size()[3]);
        let mut priors: Vec<Tensor> = BINS
            .iter()
            .zip(stages)
            .map(|(&bin, conv)| {
                bilinear(
                    &xs.adaptive_avg_pool2d([bin, bin]).apply_t(conv, train),
                    h,
                    w,
                )
            })
            .collect();
        priors.push(xs.shallow_clone());
        Tensor::cat(&priors, 1).apply_t(bottleneck, train)
    }
}

impl Fold for PspModule {
    fn folded(&self, f: &Folder) -> Self {
        let PspModule::Plain { stages, bottleneck } = self else {
            panic!("a folded PSP module cannot be folded again");
        };
        let _guard = tch::no_grad_guard();
        let (weight, bias) = bottleneck.folded_float();
        let (out, features) = (weight.size()[0], weight.size()[1] / (BINS.len() as i64 + 1));
        // The reference concatenates [prior_1, …, prior_4, x]: B_i and B_x are column blocks.
        // -> [out, features]
        let columns = |i: usize| {
            weight
                .flatten(1, 3)
                .narrow(1, i as i64 * features, features)
        };
        let mut bias = bias.unwrap_or_else(|| Tensor::zeros([out], (Kind::Float, weight.device())));
        let mut priors = Vec::with_capacity(BINS.len());
        for (i, stage) in stages.iter().enumerate() {
            let (stage_weight, stage_bias) = stage.folded_float();
            // A stage's bias is constant over pixels, which upsampling keeps: it joins the bias.
            if let Some(stage_bias) = stage_bias {
                bias += columns(i).mv(&stage_bias);
            }
            let composed = columns(i).matmul(&stage_weight.flatten(1, 3));
            priors.push(composed.view([out, features, 1, 1]));
        }
        let main_weight = columns(BINS.len()).contiguous().view([out, features, 1, 1]);
        let main = ConvBnAct::folded_from(main_weight, Some(bias), ConvSpec::new(1), Act::Relu, f);
        PspModule::Folded(PspFolded { main, priors })
    }
}

impl PspFolded {
    /// [B, features, h, w] -> [B, out, h, w]
    fn forward(&self, xs: &Tensor) -> Tensor {
        let (h, w) = (xs.size()[2], xs.size()[3]);
        // Σ_i up((B_i·C_i)·pool_i(x)) in float32 -> [B, out, h, w]
        let mut priors = BINS.iter().zip(&self.priors).map(|(&bin, weight)| {
            let pooled = xs.adaptive_avg_pool2d([bin, bin]).to_kind(Kind::Float);
            bilinear(
                &pooled.conv2d(weight, None::<Tensor>, [1], [0], [1], 1),
                h,
                w,
            )
        });
        let mut sum = priors.next().expect("PSP has bins");
        for prior in priors {
            let _ = sum.g_add_(&prior);
        }
        let sum = sum.to_kind(xs.kind());
        let sum = if crate::layers::is_channels_last(xs) {
            crate::layers::to_channels_last(&sum)
        } else {
            sum.contiguous()
        };
        self.main.forward_add(xs, &sum, false)
    }
}

/// Bilinear ×2 → 3×3 conv (bias) → BN → PReLU (`up_N.conv.{0,1,2}`).
/// [B, c_in, H, W] -> [B, c_out, 2H, 2W]
#[derive(Debug)]
struct PspUpsample {
    conv: ConvBnAct,
    /// The slope (the variable; folded, cast to the inference type).
    prelu: Tensor,
}

fn psp_upsample(p: Path, c_in: i64, c_out: i64) -> PspUpsample {
    let spec = ConvSpec::new(3).bias(true).scheme(InitScheme::NORMAL_002);
    let conv = ConvBnAct::new(
        &p / "conv" / 0,
        Some(&p / "conv" / 1),
        c_in,
        c_out,
        spec,
        Act::Identity,
    );
    // nn.PReLU(): one slope, 0.25.
    let prelu = crate::layers::new_var(&(&p / "conv" / 2), "weight", &[1], nn::Init::Const(0.25));
    PspUpsample { conv, prelu }
}

impl ModuleT for PspUpsample {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let (h, w) = (xs.size()[2], xs.size()[3]);
        let ys = bilinear(xs, 2 * h, 2 * w).apply_t(&self.conv, train);
        ys.prelu(&self.prelu)
    }
}

impl Fold for PspUpsample {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            conv: self.conv.folded(f),
            prelu: tch::no_grad(|| self.prelu.to_kind(f.kind())),
        }
    }
}

// Built once per network and never moved in a hot loop: the size difference is harmless.
#[allow(clippy::large_enum_variant)]
#[derive(Debug)]
enum Backbone {
    Late { rgb: Front, ir: Front },
    Single(Front),
}

#[derive(Debug)]
pub struct HeatNet {
    config: Config,
    backbone: Backbone,
    layer3: ResLayer,
    layer4: ResLayer,
    psp: PspModule,
    up: Vec<PspUpsample>,
    last: ConvBnAct,
}

impl HeatNet {
    pub fn new(p: Path, cfg: &Config) -> Result<Self, ModelError> {
        if cfg.num_classes < 1 {
            return Err(ModelError::InvalidConfig {
                network: cfg.name(),
                reason: format!("num_classes must be ≥ 1, got {}", cfg.num_classes),
            });
        }
        let feats = &p / "feats";
        let (backbone, c_mid) = match cfg.inputs {
            Inputs::Late => (
                Backbone::Late {
                    rgb: front(&feats / "rgb", 3),
                    ir: front(&feats / "ir", 1),
                },
                1024,
            ),
            Inputs::Early => (Backbone::Single(front(feats.clone(), 4)), 512),
            Inputs::Rgb => (Backbone::Single(front(feats.clone(), 3)), 512),
            Inputs::Ir => (Backbone::Single(front(feats.clone(), 1)), 512),
        };
        let (layer3, layer4) = back(&feats, c_mid);
        let up = [(1024, 256), (256, 64), (64, 64)]
            .iter()
            .enumerate()
            .map(|(i, &(c_in, c_out))| psp_upsample(&p / format!("up_{}", i + 1), c_in, c_out))
            .collect();
        let final_spec = ConvSpec::new(1).bias(true).scheme(InitScheme::NORMAL_002);
        let last = ConvBnAct::new(
            &p / "final" / 0,
            None,
            64,
            cfg.num_classes,
            final_spec,
            Act::Identity,
        );
        Ok(Self {
            config: cfg.clone(),
            backbone,
            layer3,
            layer4,
            psp: psp_module(&p / "psp", 2048, 1024),
            up,
            last,
        })
    }

    pub fn config(&self) -> &Config {
        &self.config
    }
}

impl ModuleT for HeatNet {
    /// [B, 4, H, W] (R, G, B, T normalised to [−1, 1]) -> logits [B, classes, H, W]
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        // -> [B, 512 | 1024, H/8, W/8]
        let mid = match (&self.backbone, self.config.inputs) {
            (Backbone::Late { rgb, ir }, _) => Tensor::cat(
                &[
                    xs.narrow(1, 0, 3).apply_t(rgb, train),
                    xs.narrow(1, 3, 1).apply_t(ir, train),
                ],
                1,
            ),
            (Backbone::Single(f), Inputs::Rgb) => xs.narrow(1, 0, 3).apply_t(f, train),
            (Backbone::Single(f), Inputs::Ir) => xs.narrow(1, 3, 1).apply_t(f, train),
            (Backbone::Single(f), _) => xs.apply_t(f, train),
        };
        // -> [B, 2048, H/8, W/8] -> [B, 1024, H/8, W/8]
        let p = mid
            .apply_t(&self.layer3, train)
            .apply_t(&self.layer4, train)
            .apply_t(&self.psp, train);
        // Channel dropouts (Dropout2d); each up block doubles H and W: -> [B, 64, H, W]
        let p = p.feature_dropout(DROP_PSP, train);
        let p = self.up.iter().fold(p, |p, up| {
            p.apply_t(up, train).feature_dropout(DROP_UP, train)
        });
        // -> [B, classes, H, W]
        p.apply_t(&self.last, train)
    }
}

impl Fold for HeatNet {
    fn folded(&self, f: &Folder) -> Self {
        let backbone = match &self.backbone {
            Backbone::Late { rgb, ir } => Backbone::Late {
                rgb: rgb.folded(f),
                ir: ir.folded(f),
            },
            Backbone::Single(front) => Backbone::Single(front.folded(f)),
        };
        Self {
            config: self.config.clone(),
            backbone,
            layer3: self.layer3.folded(f),
            layer4: self.layer4.folded(f),
            psp: self.psp.folded(f),
            up: self.up.folded(f),
            last: self.last.folded(f),
        }
    }
}

impl Network for HeatNet {
    fn input_convention(&self) -> rtf_core::InputConvention {
        self.config.input
    }
    fn num_classes(&self) -> i64 {
        self.config.num_classes
    }
    fn size_multiple(&self) -> i64 {
        8
    }
    fn name(&self) -> String {
        self.config.name()
    }
    fn folded(&self, folder: &Folder) -> Option<Box<dyn Network>> {
        Some(Box::new(Fold::folded(self, folder)))
    }
}

/// The critic's options: it reads the segmentation logits.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CriticConfig {
    pub in_channels: i64,
}

/// HeatNet's critic (`FCDiscriminator`): five 4×4 stride-2 convolutions (bias)
/// in→64→128→256→512→1, LeakyReLU(0.2) after the first four, no normalisation, no sigmoid,
/// bilinear ×32 back to the input size. [B, in, H, W] -> [B, 1, H, W]
#[derive(Debug)]
pub struct Critic {
    config: CriticConfig,
    convs: Vec<ConvBnAct>,
}

/// Critic LeakyReLU slope.
const CRITIC_SLOPE: f64 = 0.2;

impl Critic {
    pub fn new(p: Path, cfg: &CriticConfig) -> Result<Self, ModelError> {
        if cfg.in_channels < 1 {
            return Err(ModelError::InvalidConfig {
                network: "heatnet-critic".into(),
                reason: format!("in_channels must be ≥ 1, got {}", cfg.in_channels),
            });
        }
        let widths = [cfg.in_channels, 64, 128, 256, 512, 1];
        let names = ["conv1", "conv2", "conv3", "conv4", "classifier"];
        let spec = ConvSpec::new(4).stride(2).padding(1).bias(true);
        let convs = (0..5)
            .map(|i| {
                let act = if i < 4 {
                    Act::LeakyRelu(CRITIC_SLOPE)
                } else {
                    Act::Identity
                };
                ConvBnAct::new(&p / names[i], None, widths[i], widths[i + 1], spec, act)
            })
            .collect();
        Ok(Self {
            config: cfg.clone(),
            convs,
        })
    }
}

impl ModuleT for Critic {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        // [B, in, H, W] -> [B, 1, H/32, W/32] -> [B, 1, H, W]
        let ys = self
            .convs
            .iter()
            .fold(xs.shallow_clone(), |x, c| x.apply_t(c, train));
        let (h, w) = (ys.size()[2], ys.size()[3]);
        bilinear(&ys, 32 * h, 32 * w)
    }
}

impl Critic {
    /// The critic's output stride: H and W must be multiples of it.
    pub const SIZE_MULTIPLE: i64 = 32;

    pub fn config(&self) -> &CriticConfig {
        &self.config
    }

    /// Checks an input shape before forward (which panics inside libtorch on bad shapes).
    pub fn check_input(&self, shape: &[i64]) -> Result<(), ModelError> {
        let m = Self::SIZE_MULTIPLE;
        let ok = shape.len() == 4
            && shape[1] == self.config.in_channels
            && shape[0] >= 1
            && shape[2] >= m
            && shape[3] >= m
            && shape[2] % m == 0
            && shape[3] % m == 0;
        if ok {
            Ok(())
        } else {
            Err(ModelError::InvalidInput {
                network: "heatnet-critic".into(),
                shape: shape.to_vec(),
                reason: format!(
                    "expected [B, {}, H, W] with H and W positive multiples of {m}",
                    self.config.in_channels
                ),
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::weights;
    use crate::test_util::forward_shape;
    use tch::Device;

    fn count(inputs: Inputs) -> (nn::VarStore, HeatNet) {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = HeatNet::new(vs.root().into(), &Config::new(inputs, 13)).unwrap();
        (vs, net)
    }

    #[test]
    fn late_fusion_count_and_shape() {
        let (vs, net) = count(Inputs::Late);
        assert_eq!(weights::count_trainable(&vs), 54_361_040);
        assert_eq!(forward_shape(&net, [1, 4, 64, 96]), vec![1, 13, 64, 96]);
        let names = vs.variables();
        // The shared layer3 takes the 1024 concatenated channels without a downsample branch.
        assert_eq!(
            names["feats.layer3.0.conv1.weight"].size(),
            vec![256, 1024, 1, 1]
        );
        assert!(!names.contains_key("feats.layer3.0.downsample.0.weight"));
        assert_eq!(names["feats.ir.conv1.weight"].size(), vec![64, 1, 7, 7]);
        assert_eq!(
            names["psp.bottleneck.weight"].size(),
            vec![1024, 10240, 1, 1]
        );
        assert_eq!(names["up_1.conv.2.weight"].size(), vec![1]);
    }

    #[test]
    fn early_fusion_and_ir_only_counts() {
        let (vs, _) = count(Inputs::Early);
        assert_eq!(weights::count_trainable(&vs), 53_320_784);
        let (vs, _) = count(Inputs::Ir);
        assert_eq!(weights::count_trainable(&vs), 53_311_376);
    }

    #[test]
    fn single_input_variants_run() {
        for inputs in [Inputs::Early, Inputs::Rgb, Inputs::Ir] {
            let (_vs, net) = count(inputs);
            assert_eq!(
                forward_shape(&net, [2, 4, 48, 64]),
                vec![2, 13, 48, 64],
                "{inputs:?}"
            );
        }
    }

    #[test]
    fn rgb_only_ignores_thermal_and_ir_only_ignores_rgb() {
        let x = Tensor::rand([1, 4, 32, 32], (Kind::Float, Device::Cpu));
        let other_t = x.copy();
        let _ = other_t.narrow(1, 3, 1).fill_(0.0);
        let other_rgb = x.copy();
        let _ = other_rgb.narrow(1, 0, 3).fill_(0.0);
        let (_a, rgb) = count(Inputs::Rgb);
        let (_b, ir) = count(Inputs::Ir);
        tch::no_grad(|| {
            assert!(rgb
                .forward_t(&x, false)
                .equal(&rgb.forward_t(&other_t, false)));
            assert!(!rgb
                .forward_t(&x, false)
                .equal(&rgb.forward_t(&other_rgb, false)));
            assert!(ir
                .forward_t(&x, false)
                .equal(&ir.forward_t(&other_rgb, false)));
        });
    }

    #[test]
    fn critic_count_and_shape() {
        let vs = nn::VarStore::new(Device::Cpu);
        let critic = Critic::new(vs.root().into(), &CriticConfig { in_channels: 13 }).unwrap();
        assert_eq!(weights::count_trainable(&vs), 2_774_977);
        let _guard = tch::no_grad_guard();
        let out = critic.forward_t(
            &Tensor::rand([2, 13, 64, 96], (Kind::Float, Device::Cpu)),
            false,
        );
        assert_eq!(out.size(), vec![2, 1, 64, 96]);
        assert!(critic.check_input(&[2, 13, 64, 96]).is_ok());
        assert!(critic.check_input(&[2, 4, 64, 96]).is_err());
    }

    /// HeatNet's PSP module on `features` channels, its stages with a bias if `stage_bias`
    /// (the reference's have none; the fold takes one into the bottleneck's bias).
    fn psp_for_test(p: Path, features: i64, out: i64, stage_bias: bool) -> PspModule {
        let psp = psp_module(&p / "psp", features, out);
        match (stage_bias, psp) {
            (true, PspModule::Plain { bottleneck, .. }) => PspModule::Plain {
                stages: psp_stages(&(&p / "biased"), features, ConvSpec::new(1).bias(true)),
                bottleneck,
            },
            (_, psp) => psp,
        }
    }

    #[test]
    fn folded_psp_module_is_the_same_function() {
        use crate::fast::{max_relative_difference, Precision, FUSED_FP32_TOLERANCE};
        use crate::layers::to_channels_last;
        tch::manual_seed(11);
        for stage_bias in [false, true] {
            let vs = nn::VarStore::new(Device::Cpu);
            let psp = psp_for_test(vs.root().into(), 16, 8, stage_bias);
            let fold = |p| psp.folded(&Folder::new(&crate::fast::FoldOptions::new(p)));
            // Weights of unit gain and inputs with per-channel offsets, so that every bin's
            // prior weighs as much as the input's own columns (the reference init, std 0.02,
            // would leave the priors too small for a lost bin to show).
            tch::no_grad(|| {
                for mut var in vs.trainable_variables() {
                    let fan_in = if var.dim() == 4 { var.size()[1] } else { 1 };
                    var.copy_(&(var.randn_like() / (fan_in as f64).sqrt()));
                }
            });
            // Odd sizes: the 6-bin pool overlaps windows, bilinear weights are uneven.
            let offsets = Tensor::randn([1, 16, 1, 1], (Kind::Float, Device::Cpu)) * 2.0;
            let x = Tensor::randn([2, 16, 13, 7], (Kind::Float, Device::Cpu)) + offsets;
            let plain = tch::no_grad(|| psp.forward_t(&x, false));
            let folded = fold(Precision::Fp32);
            let folded = tch::no_grad(|| folded.forward_t(&to_channels_last(&x), false));
            let rel = max_relative_difference(&plain, &folded);
            assert!(
                rel < FUSED_FP32_TOLERANCE,
                "fp32, stage bias {stage_bias}: {rel}"
            );
            // Training never takes the fold: gradients reach the stages' own weights.
            psp.forward_t(&x, true).sum(Kind::Float).backward();
            let stages = if stage_bias { "biased." } else { "psp.stages." };
            for (name, var) in vs.variables() {
                if name.starts_with(stages) {
                    let grad = var.grad().abs().sum(Kind::Float).double_value(&[]);
                    assert!(grad > 0.0, "{name} has no gradient");
                }
            }

            // bf16: against float32 of the same bf16 input; the weights' and output's bf16
            // rounding (2⁻⁹ relative each) stays far below what a lost or misplaced bin costs.
            let x16 = to_channels_last(&x.to_kind(Kind::BFloat16));
            let plain = tch::no_grad(|| psp.forward_t(&x16.to_kind(Kind::Float), true));
            let folded = fold(Precision::Bf16);
            let folded = tch::no_grad(|| folded.forward_t(&x16, false));
            assert_eq!(folded.kind(), Kind::BFloat16);
            let rel = max_relative_difference(&plain, &folded.to_kind(Kind::Float));
            assert!(rel < 2e-2, "bf16, stage bias {stage_bias}: {rel}");
        }
    }

    #[test]
    fn fused_inference_agrees_with_plain_path() {
        use crate::fast::{max_relative_difference, InferenceNet, Precision, FUSED_FP32_TOLERANCE};
        tch::manual_seed(7);
        let (_vs, net) = count(Inputs::Late);
        let net: Box<dyn Network> = Box::new(net);
        let _ = net.forward_t(
            &Tensor::rand([2, 4, 32, 32], (Kind::Float, Device::Cpu)),
            true,
        );
        let x = Tensor::rand([1, 4, 32, 48], (Kind::Float, Device::Cpu)) * 2.0 - 1.0;
        let plain = tch::no_grad(|| net.forward_t(&x, false));
        let fast = InferenceNet::new(net, Precision::Fp32).unwrap();
        let rel = max_relative_difference(&plain, &fast.forward(&x).unwrap());
        assert!(rel < FUSED_FP32_TOLERANCE, "max relative difference {rel}");
    }
}
