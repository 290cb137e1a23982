//! RTFNet (Sun et al., RA-L 2019), as the authors' published code (spec §4), and the paper's
//! ablations (IV-D): NRE, NTE, NUB, OLF, FCI.
//!
//! Two torchvision ResNets without avgpool/fc; the thermal features are added into the RGB
//! path after the stem (before max-pool) and after layer1..3, and the two layer4 outputs are
//! summed into the decoder: five stages of Upception A (C→C, residual) and Upception B
//! (C→C', ×2 by transposed convolutions). Logits are post-ReLU, as in the reference.

use tch::nn::ModuleT;
use tch::Tensor;

use crate::error::ModelError;
use crate::layers::Path;
use crate::layers::{Act, ConvBnAct, ConvSpec, Fold, Folder, InitScheme, WeightInit};
use crate::resnet::{self, ResNetEncoder};
use crate::Network;

/// RTFNet's options: the schema's (rtf-config), read without libtorch.
pub use rtf_config::network::rtfnet::{Config, ThermalInit, Variant};

/// Upception A (`TransBottleneck`, stride 1): 1×1 → 3×3 → 3×3, + identity, ReLU.
/// [B, C, H, W] -> [B, C, H, W]
#[derive(Debug)]
struct UpceptionA {
    conv1: ConvBnAct,
    conv2: ConvBnAct,
    conv3: ConvBnAct,
}

fn decoder_conv(
    p: &Path,
    conv: &str,
    bn: &str,
    c_in: i64,
    c_out: i64,
    spec: ConvSpec,
    act: Act,
) -> ConvBnAct {
    ConvBnAct::new(
        p / conv,
        Some(p / bn),
        c_in,
        c_out,
        spec.init(WeightInit::XavierUniform),
        act,
    )
}

fn upception_a(p: Path, c: i64) -> UpceptionA {
    UpceptionA {
        conv1: decoder_conv(&p, "conv1", "bn1", c, c, ConvSpec::new(1), Act::Relu),
        conv2: decoder_conv(&p, "conv2", "bn2", c, c, ConvSpec::new(3), Act::Relu),
        conv3: decoder_conv(&p, "conv3", "bn3", c, c, ConvSpec::new(3), Act::Relu),
    }
}

impl ModuleT for UpceptionA {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let out = xs.apply_t(&self.conv1, train).apply_t(&self.conv2, train);
        self.conv3.forward_add(&out, xs, train)
    }
}

/// Upception B (`TransBottleneck` with upsample): 1×1 C→C' → 3×3 → ConvTranspose 2×2 s2,
/// + ConvTranspose 2×2 s2 shortcut (`upsample.0/1`), ReLU. [B, C, H, W] -> [B, C', 2H, 2W]
#[derive(Debug)]
struct UpceptionB {
    conv1: ConvBnAct,
    conv2: ConvBnAct,
    conv3: ConvBnAct,
    upsample: ConvBnAct,
}

fn upception_b(p: Path, c_in: i64, c_out: i64) -> UpceptionB {
    let up = ConvSpec::new(2).stride(2).transposed();
    UpceptionB {
        conv1: decoder_conv(&p, "conv1", "bn1", c_in, c_out, ConvSpec::new(1), Act::Relu),
        conv2: decoder_conv(
            &p,
            "conv2",
            "bn2",
            c_out,
            c_out,
            ConvSpec::new(3),
            Act::Relu,
        ),
        conv3: decoder_conv(&p, "conv3", "bn3", c_out, c_out, up, Act::Relu),
        upsample: decoder_conv(&(&p / "upsample"), "0", "1", c_in, c_out, up, Act::Identity),
    }
}

impl ModuleT for UpceptionB {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let shortcut = xs.apply_t(&self.upsample, train);
        let out = xs.apply_t(&self.conv1, train).apply_t(&self.conv2, train);
        self.conv3.forward_add(&out, &shortcut, train)
    }
}

/// One decoder stage `deconvN`: Upception A then B, or (NUB) a single ConvT → BN → ReLU.
// Built once per network and never moved in a hot loop: the size difference is harmless.
#[allow(clippy::large_enum_variant)]
#[derive(Debug)]
enum DecoderStage {
    Upception(UpceptionA, UpceptionB),
    Plain(ConvBnAct),
}

impl ModuleT for DecoderStage {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        match self {
            DecoderStage::Upception(a, b) => xs.apply_t(a, train).apply_t(b, train),
            DecoderStage::Plain(unit) => xs.apply_t(unit, train),
        }
    }
}

impl Fold for DecoderStage {
    fn folded(&self, f: &Folder) -> Self {
        match self {
            DecoderStage::Upception(a, b) => DecoderStage::Upception(
                UpceptionA {
                    conv1: a.conv1.folded(f),
                    conv2: a.conv2.folded(f),
                    conv3: a.conv3.folded(f),
                },
                UpceptionB {
                    conv1: b.conv1.folded(f),
                    conv2: b.conv2.folded(f),
                    conv3: b.conv3.folded(f),
                    upsample: b.upsample.folded(f),
                },
            ),
            DecoderStage::Plain(unit) => DecoderStage::Plain(unit.folded(f)),
        }
    }
}

#[derive(Debug)]
pub struct RtfNet {
    config: Config,
    rgb: Option<ResNetEncoder>,
    thermal: Option<ResNetEncoder>,
    /// FCI's single 4-channel encoder.
    joint: Option<ResNetEncoder>,
    decoder: Vec<DecoderStage>,
}

/// `a + b`, in place on the inference path (the fusion adds).
fn fuse_add(a: Tensor, b: &Tensor, train: bool) -> Tensor {
    if train {
        a + b
    } else {
        let mut a = a;
        let _ = a.g_add_(b);
        a
    }
}

impl RtfNet {
    pub fn new(p: Path, cfg: &Config) -> Result<Self, ModelError> {
        cfg.validate()?;
        let init = InitScheme::TORCHVISION;
        let encoder = |prefix: &str, c_in: i64| {
            ResNetEncoder::new(&p, prefix, c_in, cfg.depth, init).expect("depth validated")
        };
        let (has_rgb, has_thermal) = cfg.encoders();
        let rgb = has_rgb.then(|| encoder("encoder_rgb_", 3));
        let thermal = has_thermal.then(|| encoder("encoder_thermal_", 1));
        let joint = (cfg.variant == Variant::Fci).then(|| encoder("encoder_", 4));
        let c0 = [&rgb, &thermal, &joint]
            .iter()
            .find_map(|e| e.as_ref())
            .unwrap()
            .out_channels();
        // 2048→1024→512→256→128→classes (50/101/152) or 512→…→32→classes (18/34).
        let widths = [c0, c0 / 2, c0 / 4, c0 / 8, c0 / 16, cfg.num_classes];
        let decoder = (0..5)
            .map(|i| {
                let sp = &p / format!("deconv{}", i + 1);
                let (c_in, c_out) = (widths[i], widths[i + 1]);
                if cfg.variant == Variant::Nub {
                    let spec = ConvSpec::new(2).stride(2).transposed();
                    DecoderStage::Plain(decoder_conv(&sp, "0", "1", c_in, c_out, spec, Act::Relu))
                } else {
                    DecoderStage::Upception(
                        upception_a(&sp / 0, c_in),
                        upception_b(&sp / 1, c_in, c_out),
                    )
                }
            })
            .collect();
        Ok(Self {
            config: cfg.clone(),
            rgb,
            thermal,
            joint,
            decoder,
        })
    }

    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Encoder features at 1/32: [B, 4, H, W] -> [B, c0, H/32, W/32]
    fn encode(&self, xs: &Tensor, train: bool) -> Tensor {
        let single = |enc: &ResNetEncoder, x: &Tensor| {
            let x = resnet::stem_pool(&x.apply_t(&enc.stem, train));
            enc.layers.iter().fold(x, |x, l| x.apply_t(l, train))
        };
        let rgb_in = xs.narrow(1, 0, 3);
        let thermal_in = xs.narrow(1, 3, 1);
        match (&self.rgb, &self.thermal, &self.joint) {
            (_, _, Some(joint)) => single(joint, xs),
            (Some(rgb), None, _) => single(rgb, &rgb_in),
            (None, Some(thermal), _) => single(thermal, &thermal_in),
            (Some(rgb), Some(thermal), _) => {
                let every = self.config.variant != Variant::Olf;
                // [B, 3|1, H, W] -> [B, 64, H/2, W/2]; fusion before the max-pool.
                let t = thermal_in.apply_t(&thermal.stem, train);
                let mut r = rgb_in.apply_t(&rgb.stem, train);
                if every {
                    r = fuse_add(r, &t, train);
                }
                // -> [B, 64, H/4, W/4]
                let (mut r, mut t) = (resnet::stem_pool(&r), resnet::stem_pool(&t));
                // layer1..4: -> [B, c0/8, H/4, W/4] … [B, c0, H/32, W/32]
                for (i, (rl, tl)) in rgb.layers.iter().zip(&thermal.layers).enumerate() {
                    r = r.apply_t(rl, train);
                    t = t.apply_t(tl, train);
                    if every || i == 3 {
                        r = fuse_add(r, &t, train);
                    }
                }
                r
            }
            (None, None, None) => unreachable!("every variant has an encoder"),
        }
    }
}

impl ModuleT for RtfNet {
    /// [B, 4, H, W] (R, G, B, T in [0, 1]) -> post-ReLU logits [B, classes, 32⌈H/32⌉, 32⌈W/32⌉]
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        let fused = self.encode(xs, train);
        // Each stage doubles H and W: [B, c0, H/32, W/32] -> [B, classes, H, W]
        self.decoder
            .iter()
            .fold(fused, |x, stage| x.apply_t(stage, train))
    }
}

impl Fold for RtfNet {
    fn folded(&self, f: &Folder) -> Self {
        Self {
            config: self.config.clone(),
            rgb: self.rgb.folded(f),
            thermal: self.thermal.folded(f),
            joint: self.joint.folded(f),
            decoder: self.decoder.folded(f),
        }
    }
}

impl Network for RtfNet {
    fn input_convention(&self) -> rtf_core::InputConvention {
        self.config.input
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

    /// Spec §4 parameter counts for 9 classes.
    fn reference_count(depth: i64) -> i64 {
        match depth {
            18 => 30_995_525,
            34 => 51_211_845,
            50 => 185_238_501,
            101 => 223_222_757,
            152 => 254_510_053,
            _ => unreachable!(),
        }
    }

    /// Count, reference names/shapes and a small forward for one depth (one build: the deep
    /// networks take a while to initialise).
    fn check_depth(depth: i64) {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = RtfNet::new(vs.root().into(), &Config::new(depth, 9, Variant::Full)).unwrap();
        assert_eq!(
            weights::count_trainable(&vs),
            reference_count(depth),
            "rtfnet{depth}"
        );
        assert_matches_reference_keys(&vs, &format!("rtfnet{depth}.txt"));
        assert_eq!(forward_shape(&net, [1, 4, 64, 64]), vec![1, 9, 64, 64]);
    }

    #[test]
    fn rtfnet18_matches_reference() {
        check_depth(18);
    }
    #[test]
    fn rtfnet34_matches_reference() {
        check_depth(34);
    }
    #[test]
    fn rtfnet50_matches_reference() {
        check_depth(50);
    }
    #[test]
    fn rtfnet101_matches_reference() {
        check_depth(101);
    }
    #[test]
    fn rtfnet152_matches_reference() {
        check_depth(152);
    }

    #[test]
    fn output_rounds_up_to_multiples_of_32() {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = RtfNet::new(vs.root().into(), &Config::new(18, 9, Variant::Full)).unwrap();
        // Spec §4: 360×500 -> 384×512; here the same rule on a small input.
        assert_eq!(forward_shape(&net, [1, 4, 40, 70]), vec![1, 9, 64, 96]);
        let logits = tch::no_grad(|| {
            net.forward_t(
                &Tensor::rand([1, 4, 64, 64], (Kind::Float, Device::Cpu)),
                false,
            )
        });
        assert!(
            logits.min().double_value(&[]) >= 0.0,
            "reference logits are post-ReLU"
        );
    }

    #[test]
    fn ablations_build_run_and_differ_from_full() {
        let full = {
            let vs = nn::VarStore::new(Device::Cpu);
            let _ = RtfNet::new(vs.root().into(), &Config::new(18, 9, Variant::Full)).unwrap();
            weights::count_trainable(&vs)
        };
        for variant in Variant::ALL.into_iter().filter(|v| *v != Variant::Full) {
            let vs = nn::VarStore::new(Device::Cpu);
            let net = RtfNet::new(vs.root().into(), &Config::new(18, 9, variant)).unwrap();
            assert_eq!(
                forward_shape(&net, [2, 4, 64, 96]),
                vec![2, 9, 64, 96],
                "{variant:?}"
            );
            let names = vs.variables();
            let count = weights::count_trainable(&vs);
            match variant {
                // One encoder fewer.
                Variant::Nre | Variant::Nte | Variant::Fci => assert!(count < full, "{variant:?}"),
                // Same encoders, decoder without Upception blocks.
                Variant::Nub => assert!(count < full && names.contains_key("deconv1.0.weight")),
                // Same parameters, fewer fusions.
                Variant::Olf => assert_eq!(count, full),
                Variant::Full => unreachable!(),
            }
            let has = |prefix: &str| names.keys().any(|k| k.starts_with(prefix));
            match variant {
                Variant::Nre => assert!(!has("encoder_rgb_") && has("encoder_thermal_")),
                Variant::Nte => assert!(has("encoder_rgb_") && !has("encoder_thermal_")),
                Variant::Fci => assert_eq!(names["encoder_conv1.weight"].size(), vec![64, 4, 7, 7]),
                _ => assert!(has("encoder_rgb_") && has("encoder_thermal_")),
            }
        }
    }

    #[test]
    fn olf_shares_full_weights_but_fuses_differently() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("full.safetensors");
        tch::manual_seed(0);
        let vs_full = nn::VarStore::new(Device::Cpu);
        let full = RtfNet::new(vs_full.root().into(), &Config::new(18, 9, Variant::Full)).unwrap();
        weights::save_safetensors(
            &vs_full,
            &crate::ModelConfig::Rtfnet(Config::new(18, 9, Variant::Full)),
            crate::Modality::RgbT,
            &file,
        )
        .unwrap();
        let mut vs_olf = nn::VarStore::new(Device::Cpu);
        let olf = RtfNet::new(vs_olf.root().into(), &Config::new(18, 9, Variant::Olf)).unwrap();
        weights::load_safetensors(&mut vs_olf, &file).unwrap();
        let x = Tensor::rand([1, 4, 64, 64], (Kind::Float, Device::Cpu));
        let (a, b) = tch::no_grad(|| (full.forward_t(&x, false), olf.forward_t(&x, false)));
        assert!((a - b).abs().max().double_value(&[]) > 0.0);
    }

    #[test]
    fn fused_inference_agrees_with_plain_path() {
        use crate::fast::{max_relative_difference, InferenceNet, Precision, FUSED_FP32_TOLERANCE};
        tch::manual_seed(5);
        let vs = nn::VarStore::new(Device::Cpu);
        let net: Box<dyn Network> =
            Box::new(RtfNet::new(vs.root().into(), &Config::new(18, 9, Variant::Full)).unwrap());
        for _ in 0..2 {
            let _ = net.forward_t(
                &Tensor::rand([2, 4, 64, 64], (Kind::Float, Device::Cpu)),
                true,
            );
        }
        let x = Tensor::rand([1, 4, 64, 96], (Kind::Float, Device::Cpu));
        let plain = tch::no_grad(|| net.forward_t(&x, false));
        let fast = InferenceNet::new(net, Precision::Fp32).unwrap();
        let fused = fast.forward(&x).unwrap();
        let rel = max_relative_difference(&plain, &fused);
        assert!(rel < FUSED_FP32_TOLERANCE, "max relative difference {rel}");
    }
}
