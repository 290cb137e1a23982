//! Tests of the baseline networks ([`super`]): shapes, parameter counts, names.

use super::*;
use crate::io::weights;
use crate::test_util::forward_shape;
use tch::{Device, Kind};

#[test]
fn every_baseline_builds_and_keeps_the_input_size() {
    for arch in Arch::ALL {
        for &c in arch.channel_options() {
            let cfg = Config::new(arch, c, 9);
            let vs = nn::VarStore::new(Device::Cpu);
            let net = Baseline::new(vs.root().into(), &cfg).unwrap();
            let shape = forward_shape(&net, [1, 4, 64, 96]);
            assert_eq!(shape, vec![1, 9, 64, 96], "{}", cfg.name());
            let names = vs.variables();
            let stem = names
                .iter()
                .find(|(n, t)| !n.contains("thermal") && t.dim() == 4 && t.size()[1] == c);
            assert!(
                stem.is_some() || arch == Arch::Fusenet,
                "{}: a {c}-channel first layer",
                cfg.name()
            );
        }
    }
}

#[test]
fn parameter_counts_are_those_of_the_original_architectures() {
    let count = |arch, c| {
        let vs = nn::VarStore::new(Device::Cpu);
        let root = crate::layers::Path::new(vs.root(), &crate::BuildOptions::uninitialised());
        Baseline::new(root, &Config::new(arch, c, 9)).unwrap();
        weights::count_trainable(&vs)
    };
    // The sizes the papers state (MFNet paper Tab. IV: SegNet 29.42M, ENet 0.37M; ERFNet
    // paper ≈ 2.07M; U-Net ≈ 31.0M). ENet's stated size is rounded and implementations
    // differ in biases, hence its wider band.
    let near = |n: i64, paper: f64, tol: f64| ((n as f64 - paper) / paper).abs() < tol;
    let segnet = count(Arch::Segnet, 3);
    assert!(near(segnet, 29.42e6, 0.03), "segnet {segnet}");
    let enet = count(Arch::Enet, 3);
    assert!(near(enet, 0.37e6, 0.06), "enet {enet}");
    let erfnet = count(Arch::Erfnet, 3);
    assert!(near(erfnet, 2.07e6, 0.03), "erfnet {erfnet}");
    let unet = count(Arch::Unet, 3);
    assert!(near(unet, 31.04e6, 0.03), "unet {unet}");
    // The 4-channel variant only widens the first layer.
    assert!(count(Arch::Segnet, 4) - count(Arch::Segnet, 3) == 64 * 9);
}

/// Max relative difference between the fused fp32 path and the plain path of one random
/// draw of `arch` (weights and input).
fn fused_against_plain(arch: Arch, seed: i64) -> f64 {
    use crate::fast::{max_relative_difference, InferenceNet, Precision};
    tch::manual_seed(seed);
    let vs = nn::VarStore::new(Device::Cpu);
    let net: Box<dyn Network> =
        Box::new(Baseline::new(vs.root().into(), &Config::new(arch, 4, 9)).unwrap());
    let x = Tensor::rand([1, 4, 32, 64], (Kind::Float, Device::Cpu));
    let plain = tch::no_grad(|| net.forward_t(&x, false));
    let fast = InferenceNet::new(net, Precision::Fp32).unwrap();
    assert_eq!(fast.is_fused(), arch != Arch::Erfnet);
    max_relative_difference(&plain, &fast.forward(&x).unwrap())
}

#[test]
fn fused_baselines_agree_with_their_plain_path() {
    use crate::fast::FUSED_FP32_TOLERANCE;
    for arch in [Arch::Unet, Arch::Pspnet, Arch::Erfnet] {
        let rel = fused_against_plain(arch, 1);
        assert!(
            rel < FUSED_FP32_TOLERANCE,
            "{arch:?}: max relative difference {rel}"
        );
    }
    // SegNet and FuseNet route values through max-pooling indices. Where two activations
    // of a 2×2 window are equal to within rounding, the fused path's other (equally
    // correct) summation order may pick the other one, and the decoder then receives that
    // value one pixel away: up to ~1e-3 of the output's scale, in about 1 random draw of
    // 300 (measured: FuseNet, seeds 0–299; CI met one on seed 1, whose draws other tests
    // running beside it change). Draws are independent chances of such a tie; a wrong
    // fold fails every draw, so two of three must agree to the fp32 tolerance.
    for arch in [Arch::Segnet, Arch::Fusenet] {
        let rels: Vec<f64> = (1..=3)
            .map(|seed| fused_against_plain(arch, seed))
            .collect();
        let agreeing = rels.iter().filter(|&&r| r < FUSED_FP32_TOLERANCE).count();
        assert!(agreeing >= 2, "{arch:?}: max relative differences {rels:?}");
    }
}

#[test]
fn unet_starts_from_its_papers_initialisation() {
    // U-Net §3: N(0, √(2/N)), N = incoming connections (k·k·c_in). With PyTorch's default
    // U(±1/√N) (std √(1/(3N))) the BatchNorm-free network stayed at the all-background
    // answer on the quick budget's data.
    tch::manual_seed(3);
    let vs = nn::VarStore::new(Device::Cpu);
    Baseline::new(vs.root().into(), &Config::new(Arch::Unet, 3, 9)).unwrap();
    let vars = vs.variables();
    for (name, fan_in) in [
        ("down.0.conv1.weight", 3.0 * 9.0),
        ("down.3.conv2.weight", 512.0 * 9.0),
        ("out.weight", 64.0),
    ] {
        let w = vars.get(name).unwrap_or_else(|| panic!("no {name}"));
        let std = w.std(true).double_value(&[]);
        let expected = (2.0f64 / fan_in).sqrt();
        assert!(
            (std / expected - 1.0).abs() < 0.1,
            "{name}: std {std} vs {expected}"
        );
    }
}

#[test]
fn three_channel_variants_ignore_thermal() {
    let vs = nn::VarStore::new(Device::Cpu);
    let net = Baseline::new(vs.root().into(), &Config::new(Arch::Erfnet, 3, 9)).unwrap();
    let x = Tensor::rand([1, 4, 32, 32], (Kind::Float, Device::Cpu));
    let y = x.copy();
    let _ = y.narrow(1, 3, 1).fill_(0.0);
    tch::no_grad(|| assert!(net.forward_t(&x, false).equal(&net.forward_t(&y, false))));
}
