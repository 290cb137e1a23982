//! A bf16 training step on real imagery: the two raw MF frames (../shared/data/mf-samples,
//! 640×480, thermal in alpha) through the published MFNet weights in training mode, fp32
//! against bf16 autocast (libtorch's bf16 kernels, rtf's emulated ones or the two mixed,
//! whichever this CPU gets; `cargo xtask test` runs all three). It covers what random frames could hide: real
//! activation ranges through the bf16 convolutions and MFNet's phase-form `decode1`.
//! Labels are the fp32 network's own predictions (the samples carry none).

use std::path::PathBuf;

use rtf_data::pngio::{read_png, Samples};
use rtf_models::ModelConfig;
use tch::{nn, Device, Kind, Tensor};

fn samples() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/mf-samples")
}

/// [2, 4, 480, 640] in [0, 1]: R, G, B, thermal.
fn real_batch() -> Tensor {
    let frames: Vec<Tensor> = ["01234N.png", "01477D.png"]
        .iter()
        .map(|name| {
            let png = read_png(&samples().join(name)).unwrap();
            assert_eq!(png.channels, 4, "{name}: RGBA expected");
            let Samples::U8(bytes) = png.samples else {
                panic!("{name}: 8-bit expected")
            };
            let (h, w) = (png.height as i64, png.width as i64);
            Tensor::from_slice(&bytes)
                .view([h, w, 4])
                .permute([2, 0, 1])
                .to_kind(Kind::Float)
                / 255.0
        })
        .collect();
    Tensor::stack(&frames, 0)
}

/// The bf16 convolutions this test process is asked for: `RTF_BF16_CONVOLUTIONS` and oneDNN's
/// ISA cap (`cargo xtask test` runs each choice), resolved as rtf's binaries resolve them.
fn convolutions() -> rtf_amp::Bf16Convolutions {
    rtf_amp::Bf16Policy::from_vars(|var| std::env::var(var).ok())
        .expect("RTF_BF16_CONVOLUTIONS")
        .in_force(None)
}

/// (logits, loss, gradient of every trainable variable, flattened) of one training-mode
/// step of the published MFNet, in bf16 autocast or fp32.
fn step(input: &Tensor, labels: Option<&Tensor>, bf16: bool) -> (Tensor, f64, Tensor) {
    let cfg = ModelConfig::from_name("mfnet", 9).unwrap();
    let mut vs = nn::VarStore::new(Device::Cpu);
    // The network computes its bf16 convolutions as asked (3×3 ones emulated or not).
    let options = rtf_models::BuildOptions {
        kernels: rtf_models::UnitKernels {
            bf16_convolutions: convolutions(),
            ..Default::default()
        },
        uninitialised: false,
    };
    let net = rtf_models::build_with(&vs.root(), &cfg, &options).unwrap();
    rtf_models::io::weights::load_safetensors(&mut vs, &samples().join("mfnet_final.safetensors"))
        .unwrap();
    let kind = bf16.then_some(Kind::BFloat16);
    let logits = rtf_amp::autocast(Device::Cpu, kind, || {
        let emulated = rtf_amp::emulates_bf16_convolution(Device::Cpu, true, convolutions());
        assert_eq!(emulated, bf16 && convolutions().emulates(true));
        net.forward_t(input, true)
    })
    .unwrap()
    .to_kind(Kind::Float);
    let labels = labels.map_or_else(|| logits.argmax(1, false), Tensor::shallow_clone);
    let loss = logits.cross_entropy_loss::<Tensor>(&labels, None, tch::Reduction::Mean, -100, 0.0);
    loss.backward();
    let mut grads: Vec<(String, Tensor)> = vs
        .variables()
        .into_iter()
        .filter(|(_, t)| t.requires_grad())
        .map(|(name, t)| (name, t.grad().flatten(0, -1)))
        .collect();
    grads.sort_by(|a, b| a.0.cmp(&b.0));
    let flat = Tensor::cat(&grads.iter().map(|g| &g.1).collect::<Vec<_>>(), 0);
    (logits.detach(), loss.double_value(&[]), flat)
}

#[test]
fn bf16_training_step_on_real_frames_follows_fp32() {
    let input = real_batch();
    let (fp32_logits, fp32_loss, fp32_grads) = step(&input, None, false);
    let labels = fp32_logits.argmax(1, false);
    let (bf16_logits, bf16_loss, bf16_grads) = step(&input, Some(&labels), true);
    // The pseudo-labels are a real segmentation, not one class.
    let classes =
        Vec::<i64>::try_from(labels.flatten(0, -1).unique_dim(0, false, false, false).0).unwrap();
    assert!(classes.len() > 2, "classes: {classes:?}");
    // Same predictions almost everywhere, close losses, gradients pointing the same way.
    let agree = bf16_logits
        .argmax(1, false)
        .eq_tensor(&labels)
        .to_kind(Kind::Float)
        .mean(Kind::Float);
    let agree = agree.double_value(&[]);
    assert!(agree > 0.97, "bf16 predicts the fp32 classes at {agree}");
    assert!(
        (bf16_loss - fp32_loss).abs() < 0.05 * fp32_loss.max(0.05),
        "loss {bf16_loss} against {fp32_loss}"
    );
    assert!(
        bf16_grads.isfinite().all().int64_value(&[]) == 1,
        "non-finite gradients"
    );
    let cosine = (&bf16_grads * &fp32_grads).sum(Kind::Double)
        / (bf16_grads.norm().to_kind(Kind::Double) * fp32_grads.norm().to_kind(Kind::Double));
    let cosine = cosine.double_value(&[]);
    eprintln!(
        "real frames, {:?}: agreement {agree:.4}, loss {bf16_loss:.4} against {fp32_loss:.4}, \
         gradient cosine {cosine:.4}",
        convolutions()
    );
    assert!(cosine > 0.95, "gradient cosine {cosine}");
}
