//! MFNet (Ha et al., IROS 2017), as the authors' published code (spec §3).
//!
//! Two encoders (RGB, thermal) of conv-BN-LeakyReLU blocks and mini-inception modules, a
//! decoder that adds the encoders' concatenated skips after each nearest-neighbour ×2
//! upsampling. Parameter paths are the reference state_dict names (`conv1_rgb.conv.weight`, …).

use serde::{Deserialize, Serialize};
use tch::nn::{self, ModuleT};
use tch::{Kind, Tensor};

use crate::error::ModelError;
use crate::layers::{Act, ConvBnAct, ConvSpec, Fuse};
use crate::Network;

/// LeakyReLU slope of every MFNet block.
pub const NEGATIVE_SLOPE: f64 = 0.2;

/// Channel widths of MFNet. Defaults are the published weights' (thermal conv4/conv5 = 36; the
/// paper's table says 32, see [`Config::paper`]).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub num_classes: i64,
    /// Output widths of conv1, conv2_x, conv3_x, conv4, conv5 of the RGB encoder.
    #[serde(default = "default_rgb_channels")]
    pub rgb_channels: [i64; 5],
    /// Output widths of conv1, conv2_x, conv3_x, conv4, conv5 of the thermal encoder.
    #[serde(default = "default_thermal_channels")]
    pub thermal_channels: [i64; 5],
    /// Output width of decode2 (decode4/decode3 widths follow from the skips).
    #[serde(default = "default_decode2_channels")]
    pub decode2_channels: i64,
    #[serde(default)]
    pub input: rtf_core::InputConvention,
}

fn default_rgb_channels() -> [i64; 5] {
    [16, 48, 48, 96, 96]
}
fn default_thermal_channels() -> [i64; 5] {
    [16, 16, 16, 36, 36]
}
fn default_decode2_channels() -> i64 {
    32
}

impl Config {
    /// The published code and weights (736,275 parameters for 9 classes).
    pub fn reference(num_classes: i64) -> Self {
        Self {
            num_classes,
            rgb_channels: default_rgb_channels(),
            thermal_channels: default_thermal_channels(),
            decode2_channels: default_decode2_channels(),
            input: rtf_core::InputConvention::UnitRange,
        }
    }

    /// The paper's Tab. I widths (thermal conv4/conv5 = 32).
    pub fn paper(num_classes: i64) -> Self {
        Self {
            thermal_channels: [16, 16, 16, 32, 32],
            ..Self::reference(num_classes)
        }
    }

    /// Checks that the skips' widths line up with the decoder (they are added, not concatenated).
    pub fn validate(&self) -> Result<(), ModelError> {
        let err = |reason: String| ModelError::InvalidConfig {
            network: "mfnet".into(),
            reason,
        };
        let (r, t) = (self.rgb_channels, self.thermal_channels);
        if self.num_classes < 1 {
            return Err(err(format!(
                "num_classes must be ≥ 1, got {}",
                self.num_classes
            )));
        }
        if r.iter()
            .chain(t.iter())
            .chain([&self.decode2_channels])
            .any(|&c| c < 1)
        {
            return Err(err("every channel width must be ≥ 1".into()));
        }
        if r[3] % 2 != 0 || r[4] % 2 != 0 || t[3] % 2 != 0 || t[4] % 2 != 0 {
            return Err(err(
                "mini-inception widths (conv4, conv5) must be even".into()
            ));
        }
        if r[3] + t[3] != r[4] + t[4] {
            return Err(err(format!(
                "conv4 skip width {} must equal the fused conv5 width {}",
                r[3] + t[3],
                r[4] + t[4]
            )));
        }
        Ok(())
    }
}

/// Conv 3×3 (bias, padding = dilation) → BatchNorm → LeakyReLU(0.2); `ConvBnLeakyRelu2d`.
/// [B, c_in, H, W] -> [B, c_out, H, W]
fn conv_bn_leaky(p: nn::Path, c_in: i64, c_out: i64, dilation: i64) -> ConvBnAct {
    let spec = ConvSpec::new(3).dilation(dilation).bias(true);
    ConvBnAct::new(
        &p / "conv",
        Some(&p / "bn"),
        c_in,
        c_out,
        spec,
        Act::LeakyRelu(NEGATIVE_SLOPE),
    )
}

/// Mini-inception: three stages, each the concatenation of a 3×3 block and a dilation-2 3×3
/// block of c_out/2 channels. [B, c_in, H, W] -> [B, c_out, H, W]
#[derive(Debug)]
struct MiniInception {
    stages: Vec<(ConvBnAct, ConvBnAct)>,
}

fn mini_inception(p: nn::Path, c_in: i64, c_out: i64) -> MiniInception {
    let half = c_out / 2;
    let stages = (1..=3)
        .map(|i| {
            let stage_in = if i == 1 { c_in } else { c_out };
            (
                conv_bn_leaky(&p / format!("conv{i}_left"), stage_in, half, 1),
                conv_bn_leaky(&p / format!("conv{i}_right"), stage_in, half, 2),
            )
        })
        .collect();
    MiniInception { stages }
}

impl ModuleT for MiniInception {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        self.stages
            .iter()
            .fold(xs.shallow_clone(), |x, (left, right)| {
                Tensor::cat(&[x.apply_t(left, train), x.apply_t(right, train)], 1)
            })
    }
}

impl Fuse for MiniInception {
    fn fuse(&mut self, kind: Kind) {
        for (left, right) in &mut self.stages {
            left.fuse(kind);
            right.fuse(kind);
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
    conv4: MiniInception,
    conv5: MiniInception,
}

/// Encoder output: the 1/16 features and the skips at 1/2, 1/4, 1/8.
struct Encoded {
    x5: Tensor,
    s2: Tensor,
    s3: Tensor,
    s4: Tensor,
}

impl Encoder {
    /// `suffix` is `rgb` or `inf`, as in the reference names (`conv2_1_rgb`, `conv4_inf`).
    fn new(p: &nn::Path, suffix: &str, c_in: i64, c: [i64; 5]) -> Self {
        let path = |name: &str| p / format!("{name}_{suffix}");
        Self {
            conv1: conv_bn_leaky(path("conv1"), c_in, c[0], 1),
            conv2_1: conv_bn_leaky(path("conv2_1"), c[0], c[1], 1),
            conv2_2: conv_bn_leaky(path("conv2_2"), c[1], c[1], 1),
            conv3_1: conv_bn_leaky(path("conv3_1"), c[1], c[2], 1),
            conv3_2: conv_bn_leaky(path("conv3_2"), c[2], c[2], 1),
            conv4: mini_inception(path("conv4"), c[2], c[3]),
            conv5: mini_inception(path("conv5"), c[3], c[4]),
        }
    }

    fn forward_t(&self, xs: &Tensor, train: bool) -> Encoded {
        // [B, c_in, H, W] -> [B, c0, H/2, W/2]
        let x = xs.apply_t(&self.conv1, train).max_pool2d_default(2);
        // -> s2 [B, c1, H/2, W/2] -> [B, c1, H/4, W/4]
        let s2 = x
            .apply_t(&self.conv2_1, train)
            .apply_t(&self.conv2_2, train);
        let x = s2.max_pool2d_default(2);
        // -> s3 [B, c2, H/4, W/4] -> [B, c2, H/8, W/8]
        let s3 = x
            .apply_t(&self.conv3_1, train)
            .apply_t(&self.conv3_2, train);
        let x = s3.max_pool2d_default(2);
        // -> s4 [B, c3, H/8, W/8] -> [B, c3, H/16, W/16] -> [B, c4, H/16, W/16]
        let s4 = x.apply_t(&self.conv4, train);
        let x5 = s4.max_pool2d_default(2).apply_t(&self.conv5, train);
        Encoded { x5, s2, s3, s4 }
    }
}

impl Fuse for Encoder {
    fn fuse(&mut self, kind: Kind) {
        for unit in [
            &mut self.conv1,
            &mut self.conv2_1,
            &mut self.conv2_2,
            &mut self.conv3_1,
            &mut self.conv3_2,
        ] {
            unit.fuse(kind);
        }
        self.conv4.fuse(kind);
        self.conv5.fuse(kind);
    }
}

/// Nearest-neighbour ×2 upsampling. [B, C, H, W] -> [B, C, 2H, 2W]
fn upsample2(xs: &Tensor) -> Tensor {
    let (h, w) = (xs.size()[2], xs.size()[3]);
    xs.upsample_nearest2d([2 * h, 2 * w], 2.0, 2.0)
}

/// `x + cat(a, b)` along channels, the decoder's skip merge. Not training: added in place
/// into the two channel ranges of `x`, without materialising the concatenation.
fn add_skips(x: Tensor, a: &Tensor, b: &Tensor, train: bool) -> Tensor {
    if train {
        return x + Tensor::cat(&[a, b], 1);
    }
    let ca = a.size()[1];
    let _ = x.narrow(1, 0, ca).g_add_(a);
    let _ = x.narrow(1, ca, b.size()[1]).g_add_(b);
    x
}

#[derive(Debug)]
pub struct MfNet {
    config: Config,
    rgb: Encoder,
    thermal: Encoder,
    decode4: ConvBnAct,
    decode3: ConvBnAct,
    decode2: ConvBnAct,
    decode1: ConvBnAct,
}

impl MfNet {
    pub fn new(p: nn::Path, cfg: &Config) -> Result<Self, ModelError> {
        cfg.validate()?;
        let (r, t) = (cfg.rgb_channels, cfg.thermal_channels);
        let fused = r[4] + t[4];
        let d4 = r[2] + t[2];
        let d3 = r[1] + t[1];
        let d2 = cfg.decode2_channels;
        Ok(Self {
            config: cfg.clone(),
            rgb: Encoder::new(&p, "rgb", 3, r),
            thermal: Encoder::new(&p, "inf", 1, t),
            decode4: conv_bn_leaky(&p / "decode4", fused, d4, 1),
            decode3: conv_bn_leaky(&p / "decode3", d4, d3, 1),
            decode2: conv_bn_leaky(&p / "decode2", d3, d2, 1),
            decode1: conv_bn_leaky(&p / "decode1", d2, cfg.num_classes, 1),
        })
    }

    pub fn config(&self) -> &Config {
        &self.config
    }
}

impl ModuleT for MfNet {
    /// [B, 4, H, W] (R, G, B, T in [0, 1]) -> logits [B, classes, H, W]
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let rgb = self.rgb.forward_t(&xs.narrow(1, 0, 3), train);
        let thermal = self.thermal.forward_t(&xs.narrow(1, 3, 1), train);
        // [B, r4 + t4, H/16, W/16] -> [B, r4 + t4, H/8, W/8]
        let x = upsample2(&Tensor::cat(&[&rgb.x5, &thermal.x5], 1));
        // -> [B, r2 + t2, H/8, W/8] -> [B, r2 + t2, H/4, W/4]
        let x = add_skips(x, &rgb.s4, &thermal.s4, train).apply_t(&self.decode4, train);
        // -> [B, r1 + t1, H/4, W/4] -> [B, r1 + t1, H/2, W/2]
        let x = add_skips(upsample2(&x), &rgb.s3, &thermal.s3, train).apply_t(&self.decode3, train);
        // -> [B, d2, H/2, W/2] -> [B, d2, H, W]
        let x = add_skips(upsample2(&x), &rgb.s2, &thermal.s2, train).apply_t(&self.decode2, train);
        // decode1 is a full block in the reference: logits pass BN and LeakyReLU.
        upsample2(&x).apply_t(&self.decode1, train)
    }
}

impl Fuse for MfNet {
    fn fuse(&mut self, kind: Kind) {
        self.rgb.fuse(kind);
        self.thermal.fuse(kind);
        for unit in [
            &mut self.decode4,
            &mut self.decode3,
            &mut self.decode2,
            &mut self.decode1,
        ] {
            unit.fuse(kind);
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
        "mfnet".into()
    }
    fn fuse_for_inference(&mut self, kind: Kind) -> bool {
        self.fuse(kind);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{assert_matches_reference_keys, forward_shape};
    use crate::weights;
    use tch::{Device, Kind};

    fn build(cfg: &Config) -> (nn::VarStore, MfNet) {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = MfNet::new(vs.root(), cfg).unwrap();
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
        let err = MfNet::new(vs.root(), &cfg).unwrap_err().to_string();
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
        use crate::fast::{argmax_agreement, InferenceNet, Precision};
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
        let agreement = argmax_agreement(&plain, &fused);
        assert!(agreement >= 0.999, "fp32 agreement {agreement}");
        let max_diff = (&plain - &fused).abs().max().double_value(&[]);
        assert!(max_diff < 1e-3, "max |diff| {max_diff}");
        let err = fast.forward(&Tensor::rand([1, 4, 60, 80], (Kind::Float, Device::Cpu)));
        assert!(err.is_err(), "sizes must be multiples of 16");
    }
}
