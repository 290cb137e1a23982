//! `--backbone-weights`: ImageNet ResNet weights (a torchvision `resnetNN` state_dict saved as
//! safetensors: `conv1.weight`, `bn1.*`, `layerN.i.*`, `fc.*`) loaded into every ResNet encoder
//! of a network. The decoders keep their own initialisation.
//!
//! An encoder with other than three input channels gets its stem derived from the RGB one:
//! the thermal stem is the mean of the RGB kernel over its input channels (the RTFNet
//! reference) or, as the RTFNet paper says, Xavier-uniform; a 4-channel stem (FCI) takes the
//! RGB kernel plus that mean as its fourth channel.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use tch::nn::VarStore;
use tch::{Kind, Tensor};

use crate::error::{ModelError, ShapeMismatch};
use crate::io::weights::{is_ignored_name, read_safetensors};
use crate::rtfnet::ThermalInit;
use crate::ModelConfig;

/// One encoder of a network: its parameter prefix and input channels.
#[derive(Debug, Clone, PartialEq)]
pub struct EncoderSlot {
    pub prefix: String,
    pub in_channels: i64,
}

/// The ResNet encoders of a configuration that accept torchvision weights.
pub fn encoder_slots(cfg: &ModelConfig) -> Result<(Vec<EncoderSlot>, ThermalInit), ModelError> {
    let slot = |prefix: &str, in_channels| EncoderSlot {
        prefix: prefix.into(),
        in_channels,
    };
    match cfg {
        ModelConfig::Rtfnet(c) => {
            let (rgb, thermal) = c.encoders();
            let mut slots = Vec::new();
            if rgb {
                slots.push(slot("encoder_rgb_", 3));
            }
            if thermal {
                slots.push(slot("encoder_thermal_", 1));
            }
            if c.variant == crate::rtfnet::Variant::Fci {
                slots.push(slot("encoder_", 4));
            }
            Ok((slots, c.thermal_init))
        }
        ModelConfig::Baseline(b)
            if matches!(
                b.arch,
                crate::baselines::Arch::Pspnet | crate::baselines::Arch::Duchdc
            ) =>
        {
            Ok((
                vec![slot("backbone.", b.in_channels)],
                ThermalInit::MeanOfRgb,
            ))
        }
        other => Err(ModelError::InvalidConfig {
            network: other.name(),
            reason: "has no torchvision ResNet encoder for --backbone-weights \
                     (HeatNet's reference trains from scratch; CMX takes SegFormer MiT weights)"
                .into(),
        }),
    }
}

/// The stem kernel of an encoder with `in_channels` inputs, from the RGB one [64, 3, 7, 7].
fn derived_stem(rgb: &Tensor, in_channels: i64, init: ThermalInit) -> Option<Tensor> {
    let mean = rgb.mean_dim(1, true, Kind::Float);
    match (in_channels, init) {
        (3, _) => Some(rgb.shallow_clone()),
        (1, ThermalInit::MeanOfRgb) => Some(mean),
        // None: keep (re-draw) a Xavier-uniform kernel.
        (1, ThermalInit::Xavier) => None,
        (4, ThermalInit::MeanOfRgb) => Some(Tensor::cat(&[rgb, &mean], 1)),
        (4, ThermalInit::Xavier) => None,
        _ => None,
    }
}

/// Xavier-uniform redraw of a conv kernel in place.
fn xavier_(weight: &mut Tensor) {
    let size = weight.size();
    let receptive: i64 = size[2..].iter().product();
    let bound = (6.0 / ((size[0] + size[1]) * receptive) as f64).sqrt();
    let _ = weight.uniform_(-bound, bound);
}

/// Loads ImageNet encoder weights from `path` into every encoder of `cfg` built in `vs`:
/// torchvision ResNet weights for the ResNet encoders, SegFormer MiT weights for CMX
/// ([`crate::io::mit_pretrained`]). Returns what loaded, for the run's log.
pub fn load_backbone_weights(
    vs: &mut VarStore,
    cfg: &ModelConfig,
    path: &Path,
) -> Result<String, ModelError> {
    if matches!(cfg, ModelConfig::Cmx(_)) {
        return crate::io::mit_pretrained::load_mit_weights(vs, path);
    }
    let slots = load_resnet_weights(vs, cfg, path)?;
    let prefixes: Vec<&str> = slots.iter().map(|s| s.prefix.as_str()).collect();
    Ok(format!(
        "backbone weights: {}: torchvision ResNet into {}",
        path.display(),
        prefixes.join(", ")
    ))
}

/// Loads torchvision ResNet weights from `path` into every ResNet encoder of `cfg` built in
/// `vs`; returns the encoders. Strict like [`crate::io::weights::load_safetensors`]: every
/// encoder parameter must be in the file with its shape and every file tensor (but `fc.*`)
/// must be used; errors list them all.
fn load_resnet_weights(
    vs: &mut VarStore,
    cfg: &ModelConfig,
    path: &Path,
) -> Result<Vec<EncoderSlot>, ModelError> {
    let (slots, thermal_init) = encoder_slots(cfg)?;
    let file: BTreeMap<String, Tensor> = read_safetensors(path)?
        .into_iter()
        .filter(|(n, _)| !is_ignored_name(n) && !n.starts_with("fc."))
        .collect();
    let vars: BTreeMap<String, Tensor> = vs.variables().into_iter().collect();
    let mut used = BTreeSet::new();
    let mut missing = Vec::new();
    let mut mismatched = Vec::new();
    // (variable, source) pairs; source None = Xavier redraw.
    let mut plan: Vec<(Tensor, Option<Tensor>)> = Vec::new();
    for slot in &slots {
        for (name, var) in vars.iter().filter(|(n, _)| n.starts_with(&slot.prefix)) {
            let torchvision = &name[slot.prefix.len()..];
            // FCI's `encoder_` prefix must not swallow other encoders' names.
            if slots
                .iter()
                .any(|s| s.prefix.len() > slot.prefix.len() && name.starts_with(&s.prefix))
            {
                continue;
            }
            let Some(src) = file.get(torchvision) else {
                missing.push(torchvision.to_string());
                continue;
            };
            used.insert(torchvision.to_string());
            let src = if torchvision == "conv1.weight" && slot.in_channels != 3 {
                if src.size().len() != 4 || src.size()[1] != 3 {
                    mismatched.push(ShapeMismatch {
                        name: torchvision.into(),
                        expected: vec![64, 3, 7, 7],
                        found: src.size(),
                    });
                    continue;
                }
                derived_stem(&src.to_kind(Kind::Float), slot.in_channels, thermal_init)
            } else {
                Some(src.shallow_clone())
            };
            match src {
                Some(s) if s.size() != var.size() => mismatched.push(ShapeMismatch {
                    name: torchvision.into(),
                    expected: var.size(),
                    found: s.size(),
                }),
                s => plan.push((var.shallow_clone(), s)),
            }
        }
    }
    missing.sort();
    missing.dedup();
    let unexpected: Vec<String> = file
        .keys()
        .filter(|k| !used.contains(*k))
        .cloned()
        .collect();
    crate::error::check_names(path, missing, unexpected, mismatched)?;
    tch::no_grad(|| {
        for (mut var, src) in plan {
            match src {
                Some(src) => {
                    let src = src.to_kind(var.kind()).to_device(var.device());
                    var.copy_(&src);
                }
                None => xavier_(&mut var),
            }
        }
    });
    Ok(slots)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::weights;
    use crate::resnet::ResNetEncoder;
    use crate::rtfnet::{Config, Variant};
    use crate::{build, layers::InitScheme};
    use tch::{nn, Device};

    /// A torchvision-named resnet18 state_dict (with fc) written to `file`.
    fn torchvision_resnet18(file: &Path) -> BTreeMap<String, Tensor> {
        tch::manual_seed(11);
        let vs = nn::VarStore::new(Device::Cpu);
        let _ = ResNetEncoder::new(&vs.root().into(), "", 3, 18, InitScheme::TORCHVISION).unwrap();
        let mut named = weights::state_dict(&vs);
        named.push((
            "fc.weight".into(),
            Tensor::zeros([1000, 512], (Kind::Float, Device::Cpu)),
        ));
        named.push((
            "fc.bias".into(),
            Tensor::zeros([1000], (Kind::Float, Device::Cpu)),
        ));
        named.push(("bn1.num_batches_tracked".into(), Tensor::from(3i64)));
        weights::save_named(&named, file).unwrap();
        named.into_iter().collect()
    }

    #[test]
    fn both_encoders_get_the_backbone_and_thermal_stem_is_the_rgb_mean() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("resnet18.safetensors");
        let reference = torchvision_resnet18(&file);
        let cfg = ModelConfig::Rtfnet(Config::new(18, 9, Variant::Full));
        let mut vs = nn::VarStore::new(Device::Cpu);
        let _net = build(&vs.root(), &cfg).unwrap();
        let decoder_before = vs.variables()["deconv1.0.conv1.weight"].copy();
        load_backbone_weights(&mut vs, &cfg, &file).unwrap();
        let vars = vs.variables();
        assert!(
            vars["encoder_rgb_layer3.1.conv2.weight"].equal(&reference["layer3.1.conv2.weight"])
        );
        assert!(vars["encoder_thermal_layer4.0.downsample.1.running_var"]
            .equal(&reference["layer4.0.downsample.1.running_var"]));
        assert!(vars["encoder_rgb_conv1.weight"].equal(&reference["conv1.weight"]));
        let mean = reference["conv1.weight"].mean_dim(1, true, Kind::Float);
        assert!(vars["encoder_thermal_conv1.weight"].allclose(&mean, 1e-6, 1e-7, false));
        assert!(
            vars["deconv1.0.conv1.weight"].equal(&decoder_before),
            "decoder untouched"
        );
    }

    #[test]
    fn xavier_option_and_fci_stem() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("resnet18.safetensors");
        let reference = torchvision_resnet18(&file);
        let mut config = Config::new(18, 9, Variant::Full);
        config.thermal_init = ThermalInit::Xavier;
        let cfg = ModelConfig::Rtfnet(config);
        let mut vs = nn::VarStore::new(Device::Cpu);
        let _net = build(&vs.root(), &cfg).unwrap();
        load_backbone_weights(&mut vs, &cfg, &file).unwrap();
        let thermal = &vs.variables()["encoder_thermal_conv1.weight"];
        let bound = (6.0f64 / ((64 + 1) * 49) as f64).sqrt();
        assert!(thermal.abs().max().double_value(&[]) <= bound);

        let cfg = ModelConfig::Rtfnet(Config::new(18, 9, Variant::Fci));
        let mut vs = nn::VarStore::new(Device::Cpu);
        let _net = build(&vs.root(), &cfg).unwrap();
        load_backbone_weights(&mut vs, &cfg, &file).unwrap();
        let stem = &vs.variables()["encoder_conv1.weight"];
        assert!(stem.narrow(1, 0, 3).equal(&reference["conv1.weight"]));
    }

    #[test]
    fn wrong_depth_is_refused_with_names() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("resnet18.safetensors");
        torchvision_resnet18(&file);
        let cfg = ModelConfig::Rtfnet(Config::new(34, 9, Variant::Full));
        let mut vs = nn::VarStore::new(Device::Cpu);
        let _net = build(&vs.root(), &cfg).unwrap();
        let err = load_backbone_weights(&mut vs, &cfg, &file)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("resnet18.safetensors") && err.contains("layer1.2.conv1.weight"),
            "{err}"
        );
        let mfnet = ModelConfig::from_name("mfnet", 9).unwrap();
        assert!(load_backbone_weights(&mut vs, &mfnet, &file).is_err());
    }
}
