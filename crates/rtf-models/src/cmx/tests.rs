//! Tests of CMX ([`super`]): parameter counts, state_dict names, configs, the fast path.

use super::decoder::folded_sum;
use super::*;
use crate::io::weights;
use crate::layers::{BuildOptions, Path};
use crate::test_util::forward_shape;
use tch::Device;

/// Trainable parameters of the official network for 9 classes, from
/// `lab/parity/cmx_reference.py --count` (its module tree has the official names and shapes;
/// B0, B2, B4, B5 also counted on the official `EncoderDecoder`, which cannot build B1 and
/// B3, see the module doc).
fn official_count(size: Size) -> i64 {
    match size {
        Size::B0 => 12_114_641,
        Size::B1 => 44_475_793,
        Size::B2 => 66_565_521,
        Size::B3 => 106_317_201,
        Size::B4 => 139_858_321,
        Size::B5 => 181_058_961,
    }
}

#[test]
fn parameter_counts_match_the_official_network() {
    for size in Size::ALL {
        let vs = nn::VarStore::new(Device::Cpu);
        let root = Path::new(vs.root(), &BuildOptions::uninitialised());
        Cmx::new(root, &Config::new(size, 9)).unwrap();
        let count = weights::count_trainable(&vs);
        assert_eq!(count, official_count(size), "{size:?}");
    }
}

#[test]
fn tensor_names_are_the_official_ones() {
    let vs = nn::VarStore::new(Device::Cpu);
    Cmx::new(vs.root().into(), &Config::new(Size::B0, 9)).unwrap();
    let vars = vs.variables();
    let shape = |name: &str| {
        vars.get(name)
            .unwrap_or_else(|| panic!("{name} missing"))
            .size()
    };
    for (name, expected) in [
        ("backbone.patch_embed1.proj.weight", vec![32, 3, 7, 7]),
        ("backbone.extra_patch_embed2.norm.bias", vec![64]),
        ("backbone.block1.1.attn.sr.weight", vec![32, 32, 8, 8]),
        ("backbone.extra_block3.0.attn.kv.weight", vec![320, 160]),
        (
            "backbone.block4.1.mlp.dwconv.dwconv.weight",
            vec![1024, 1, 3, 3],
        ),
        ("backbone.extra_norm4.weight", vec![256]),
        (
            "backbone.FRMs.0.channel_weights.mlp.2.weight",
            vec![64, 128],
        ),
        ("backbone.FRMs.3.spatial_weights.mlp.2.bias", vec![2]),
        ("backbone.FFMs.1.cross.cross_attn.kv2.weight", vec![128, 64]),
        (
            "backbone.FFMs.2.channel_emb.channel_embed.1.weight",
            vec![160, 1, 3, 3],
        ),
        (
            "backbone.FFMs.3.channel_emb.channel_embed.4.running_var",
            vec![256],
        ),
        ("backbone.FFMs.3.channel_emb.norm.running_mean", vec![256]),
        ("decode_head.linear_c4.proj.weight", vec![512, 256]),
        ("decode_head.linear_fuse.0.weight", vec![512, 2048, 1, 1]),
        ("decode_head.linear_fuse.1.running_var", vec![512]),
        ("decode_head.linear_pred.weight", vec![9, 512, 1, 1]),
    ] {
        assert_eq!(shape(name), expected, "{name}");
    }
    for absent in [
        "backbone.block4.0.attn.sr.weight",
        "backbone.FFMs.0.cross.cross_attn.kv1.bias",
        "backbone.FFMs.0.channel_emb.residual.bias",
    ] {
        assert!(!vars.contains_key(absent), "{absent}");
    }
}

#[test]
fn b0_keeps_the_input_size_for_any_class_count() {
    tch::manual_seed(0);
    for (classes, shape) in [(9, [1, 4, 64, 64]), (5, [2, 4, 64, 96])] {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = Cmx::new(vs.root().into(), &Config::new(Size::B0, classes)).unwrap();
        assert_eq!(
            forward_shape(&net, shape),
            vec![shape[0], classes, shape[2], shape[3]]
        );
    }
}

#[test]
fn training_mode_reaches_every_parameter() {
    tch::manual_seed(1);
    let vs = nn::VarStore::new(Device::Cpu);
    let net = Cmx::new(vs.root().into(), &Config::new(Size::B0, 3)).unwrap();
    let x = Tensor::rand([2, 4, 64, 64], (Kind::Float, Device::Cpu));
    let logits = net.forward_t(&x, true);
    assert_eq!(logits.size(), vec![2, 3, 64, 64]);
    logits.square().mean(Kind::Float).backward();
    for (name, var) in vs.variables() {
        if var.requires_grad() {
            assert!(var.grad().defined(), "{name} has no gradient");
        }
    }
}

#[test]
fn preprocessing_is_the_official_one() {
    let vs = nn::VarStore::new(Device::Cpu);
    let mut cfg = Config::new(Size::B0, 9);
    let x = Tensor::from_slice(&[0.2f32, 0.4, 0.6, 0.8]).view([1, 4, 1, 1]);
    let value = |t: &Tensor, c: i64| t.double_value(&[0, c, 0, 0]);
    let near = |a: f64, b: f64| (a - b).abs() < 1e-5;
    let (colour, thermal) = Cmx::new(vs.root().into(), &cfg).unwrap().normalise(&x);
    // B, G, R planes, each normalised with the ImageNet statistics of its position.
    assert!(near(value(&colour, 0), (0.6 - 0.485) / 0.229));
    assert!(near(value(&colour, 2), (0.2 - 0.406) / 0.225));
    for c in 0..3 {
        let expected = (0.8 - IMAGENET_MEAN[c as usize] as f64) / IMAGENET_STD[c as usize] as f64;
        assert!(near(value(&thermal, c), expected), "thermal plane {c}");
    }
    cfg.color_order = ColorOrder::Rgb;
    let vs = nn::VarStore::new(Device::Cpu);
    let (colour, _) = Cmx::new(vs.root().into(), &cfg).unwrap().normalise(&x);
    assert!(near(value(&colour, 0), (0.2 - 0.485) / 0.229));
}

#[test]
fn drop_path_rates_follow_the_official_schedule() {
    // B2: 16 blocks, rates k·0.1/15.
    let depths = Size::B2.layout().depths;
    let rate = |k: i64| 0.1 * k as f64 / 15.0;
    let close = |a: &[f64], b: &[f64]| {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12)
    };
    assert!(close(
        &drop_path_rates(depths, 0, true),
        &[0.0, rate(1), rate(2)]
    ));
    assert!(close(&drop_path_rates(depths, 1, false), &[rate(3); 4]));
    assert!(close(&drop_path_rates(depths, 1, true), &[rate(4); 4]));
    let stage3: Vec<f64> = (7..13).map(rate).collect();
    assert!(close(&drop_path_rates(depths, 2, false), &stage3));
    assert!(close(
        &drop_path_rates(depths, 3, false),
        &[rate(13), rate(14), rate(15)]
    ));
}

/// The training eps reaches the decoder's BatchNorm only (the fusion modules' keep
/// PyTorch's), changes the training-mode output, is written to the config only when set,
/// and a bad one is refused.
#[test]
fn the_decoder_batchnorm_takes_the_training_eps() {
    let plain = Config::new(Size::B0, 9);
    let trained = Config {
        decoder_bn_eps: 1e-3,
        ..plain.clone()
    };
    let build = |cfg: &Config| {
        let vs = nn::VarStore::new(tch::Device::Cpu);
        tch::manual_seed(3);
        let net = Cmx::new(vs.root().into(), cfg).unwrap();
        (vs, net)
    };
    let ((_a, a), (_b, b)) = (build(&plain), build(&trained));
    let fuse_bn = |net: &Cmx| match &net.decoder {
        Head::Plain(decoder) => decoder.fuse_bn.eps(),
        Head::Folded(_) => unreachable!("built, not folded"),
    };
    assert_eq!(fuse_bn(&b), 1e-3);
    assert_eq!(fuse_bn(&a), 1e-5);
    assert_eq!(b.encoder.fusion[0].embed.norm.as_ref().unwrap().eps(), 1e-5);
    let x = Tensor::rand([2, 4, 64, 64], (Kind::Float, tch::Device::Cpu));
    tch::manual_seed(4);
    let ya = a.forward_t(&x, true);
    tch::manual_seed(4);
    let yb = b.forward_t(&x, true);
    assert!(
        !ya.allclose(&yb, 1e-7, 1e-7, false),
        "eps changes the output"
    );
    assert!(
        (&ya - &yb).isfinite().all().int64_value(&[]) == 1,
        "both outputs finite"
    );
    let json = serde_json::to_value(&trained).unwrap();
    assert_eq!(json["decoder_bn_eps"], 1e-3);
    assert!(serde_json::to_value(&plain)
        .unwrap()
        .get("decoder_bn_eps")
        .is_none());
    let bad = Config {
        decoder_bn_eps: 0.0,
        ..plain
    };
    assert!(bad
        .validate()
        .unwrap_err()
        .to_string()
        .contains("decoder_bn_eps"));
}

/// The unit-range values the network normalises to 0: the colour planes in the encoder's
/// order, the thermal plane nearest to 0 in its three normalised channels.
#[test]
fn normalised_zero_is_what_the_preprocessing_maps_to_zero() {
    for order in [ColorOrder::Bgr, ColorOrder::Rgb] {
        let cfg = Config {
            color_order: order,
            ..Config::new(Size::B0, 9)
        };
        let net = Cmx::new(nn::VarStore::new(tch::Device::Cpu).root().into(), &cfg).unwrap();
        let zero = cfg.normalised_zero();
        let x = Tensor::from_slice(&zero).view([1, 4, 1, 1]);
        let (colour, thermal) = net.normalise(&x);
        assert!(colour.abs().max().double_value(&[]) < 1e-6, "{order:?}");
        let t = Vec::<f32>::try_from(thermal.flatten(0, -1)).unwrap();
        assert!(t.iter().all(|v| v.abs() < 0.2), "{t:?}");
        // No other value brings the three thermal channels nearer to 0.
        let norm = |v: &[f32]| v.iter().map(|x| x * x).sum::<f32>();
        for delta in [-0.01f32, 0.01] {
            let mut moved = zero;
            moved[3] += delta;
            let (_, th) = net.normalise(&Tensor::from_slice(&moved).view([1, 4, 1, 1]));
            let moved_t = Vec::<f32>::try_from(th.flatten(0, -1)).unwrap();
            assert!(norm(&moved_t) > norm(&t), "{delta}");
        }
    }
}

/// A seeded B0 whose normalisation layers are all off their neutral init (LayerNorm and
/// BatchNorm affines, BatchNorm statistics), so folding them is tested for real.
fn b0_with_random_norms(vs: &nn::VarStore, classes: i64) -> Cmx {
    tch::manual_seed(5);
    let net = Cmx::new(vs.root().into(), &Config::new(Size::B0, classes)).unwrap();
    tch::no_grad(|| {
        for (name, mut var) in vs.variables() {
            let (lo, hi) = match name.rsplit('.').next() {
                Some("running_var") => (0.5, 1.5),
                Some("running_mean") => (-0.2, 0.2),
                Some("weight") if var.dim() == 1 => (0.5, 1.5),
                Some("bias") if var.dim() == 1 => (-0.2, 0.2),
                _ => continue,
            };
            let _ = var.uniform_(lo, hi);
        }
    });
    net
}

/// The fast path (folded BatchNorm and decoder, fused convolutions, channels-last,
/// in-place sums) computes the plain path's logits: in fp32 to rounding (relative
/// difference below [`crate::fast::FUSED_FP32_TOLERANCE`], 1e-4), in bf16 to bf16's
/// precision (below 5 %; measured ≈ 1 %).
#[test]
fn the_fast_path_computes_the_plain_logits() {
    use crate::fast::{max_relative_difference, InferenceNet, Precision, FUSED_FP32_TOLERANCE};
    let x = Tensor::rand([2, 4, 64, 96], (Kind::Float, Device::Cpu));
    for (precision, bound) in [
        (Precision::Fp32, FUSED_FP32_TOLERANCE),
        (Precision::Bf16, 0.05),
    ] {
        for options in crate::test_util::fold_options_each(precision) {
            let vs = nn::VarStore::new(Device::Cpu);
            let net = b0_with_random_norms(&vs, 9);
            let plain = tch::no_grad(|| net.forward_t(&x, false));
            let fast = InferenceNet::fold(Box::new(net), &options).unwrap();
            assert!(fast.is_fused());
            let logits = fast.forward(&x).unwrap();
            assert_eq!(logits.kind(), Kind::Float);
            let rel = max_relative_difference(&plain, &logits);
            let case = format!("{precision} {:?}", options.kernels.bf16_convolutions);
            eprintln!("{case}: max relative difference {rel:.2e}");
            assert!(rel < bound, "{case}: max relative difference {rel}");
        }
    }
}

/// Training's folded decoder sum equals the official concatenate-then-convolve order.
#[test]
fn the_folded_decoder_sum_is_the_official_one() {
    tch::manual_seed(6);
    let vs = nn::VarStore::new(Device::Cpu);
    let layout = Size::B0.layout();
    let dec = decoder(vs.root().into(), &layout, &Config::new(Size::B0, 9));
    let features: Vec<Tensor> = (0..4)
        .map(|i| {
            let (h, w) = (16 >> i, 24 >> i);
            Tensor::randn([2, layout.dims[i], h, w], (Kind::Float, Device::Cpu))
        })
        .collect();
    let official = tch::no_grad(|| dec.official_sum(&features));
    let (proj, bias) = dec.folded();
    let folded = tch::no_grad(|| folded_sum(&features, &proj, &bias, true));
    let rel = crate::fast::max_relative_difference(&official, &folded);
    assert!(rel < 1e-5, "max relative difference {rel}");
}

#[test]
fn names_and_configs_round_trip() {
    for size in Size::ALL {
        let cfg = Config::new(size, 9);
        assert_eq!(Size::from_name(&cfg.name()), Some(size));
    }
    assert_eq!(Size::from_name("cmx-mit-b6"), None);
    let cfg: Config = serde_json::from_str(r#"{"size": "b2", "num_classes": 4}"#).unwrap();
    assert_eq!(cfg, Config::new(Size::B2, 4));
    let err = Cmx::new(
        nn::VarStore::new(Device::Cpu).root().into(),
        &Config::new(Size::B0, 0),
    )
    .unwrap_err();
    assert!(err.to_string().contains("cmx-mit-b0"), "{err}");
}
