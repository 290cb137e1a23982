//! `--backbone-weights` for CMX: SegFormer's ImageNet-pretrained Mix Transformer (`mit_bX`,
//! a state_dict with `patch_embedN.*`, `blockN.i.*`, `normN.*` and the classifier `head.*`,
//! saved as safetensors, e.g. by `cargo xtask convert-pth`) loaded into both encoders as the
//! official `load_dualpath_model` does (huaaaliu/RGBX_Semantic_Segmentation,
//! `models/encoders/dual_segformer.py`): every `patch_embed`, `block` and `norm` tensor goes to
//! the RGB encoder under its own name and to the X (thermal) encoder under `extra_…`; other
//! tensors (the ImageNet classifier) are left out. The rectify and fusion modules and the
//! decoder keep their own initialisation.
//!
//! Stricter than the official `strict=False`: every encoder parameter must come from the file
//! with its shape (weights of another MiT size fail naming the tensors and both shapes), so a
//! wrong file cannot leave an encoder half-initialised without a word.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use tch::nn::VarStore;
use tch::Tensor;

use crate::error::{ModelError, ShapeMismatch};
use crate::io::weights::{is_ignored_name, read_safetensors};

/// The network's names of a SegFormer tensor (`None`: not an encoder tensor).
fn targets(name: &str) -> Option<[String; 2]> {
    let extra = ["patch_embed", "block", "norm"]
        .into_iter()
        .find(|part| name.contains(part))
        .map(|part| name.replacen(part, &format!("extra_{part}"), 1))?;
    Some([format!("backbone.{name}"), format!("backbone.{extra}")])
}

/// Whether a network variable belongs to one of the two MiT encoders.
fn is_encoder_var(name: &str) -> bool {
    let Some(rest) = name.strip_prefix("backbone.") else {
        return false;
    };
    let rest = rest.strip_prefix("extra_").unwrap_or(rest);
    ["patch_embed", "block", "norm"]
        .iter()
        .any(|p| rest.starts_with(p))
}

/// Loads SegFormer MiT weights from `path` into both encoders of the CMX network in `vs`
/// (module docs). Returns what loaded, for the run's log.
pub fn load_mit_weights(vs: &mut VarStore, path: &Path) -> Result<String, ModelError> {
    let file: BTreeMap<String, Tensor> = read_safetensors(path)?
        .into_iter()
        .filter(|(n, _)| !is_ignored_name(n))
        .collect();
    let vars: BTreeMap<String, Tensor> = vs.variables().into_iter().collect();
    let (mut plan, mut mismatched, mut unexpected, mut left_out) = (vec![], vec![], vec![], vec![]);
    let mut covered = BTreeSet::new();
    for (name, src) in &file {
        let Some(names) = targets(name) else {
            left_out.push(name.clone());
            continue;
        };
        for target in names {
            match vars.get(&target) {
                None => unexpected.push(name.clone()),
                Some(var) if var.size() != src.size() => mismatched.push(ShapeMismatch {
                    name: target.clone(),
                    expected: var.size(),
                    found: src.size(),
                }),
                Some(var) => plan.push((var.shallow_clone(), src.shallow_clone())),
            }
            covered.insert(target);
        }
    }
    let missing: Vec<String> = vars
        .keys()
        .filter(|n| is_encoder_var(n) && !covered.contains(*n))
        .cloned()
        .collect();
    unexpected.dedup();
    crate::error::check_names(path, missing, unexpected, mismatched)?;
    tch::no_grad(|| {
        for (mut var, src) in plan.iter().map(|(v, s)| (v.shallow_clone(), s)) {
            var.copy_(&src.to_kind(var.kind()).to_device(var.device()));
        }
    });
    let left = match left_out.is_empty() {
        true => String::new(),
        false => format!("; left out: {}", left_out.join(", ")),
    };
    Ok(format!(
        "backbone weights: {}: {} MiT tensors into the RGB and the thermal encoder ({} variables){left}",
        path.display(),
        file.len() - left_out.len(),
        plan.len()
    ))
}

/// A CMX network's RGB encoder under SegFormer's names (`patch_embedN.*`, `blockN.i.*`,
/// `normN.*`): what [`load_mit_weights`] reads, e.g. to hand a fine-tuned encoder to a
/// SegFormer user or to write test fixtures.
pub fn segformer_state_dict(vs: &VarStore) -> Vec<(String, Tensor)> {
    crate::io::weights::state_dict(vs)
        .into_iter()
        .filter(|(n, _)| is_encoder_var(n) && !n.starts_with("backbone.extra_"))
        .map(|(n, t)| (n["backbone.".len()..].to_string(), t))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::weights;
    use crate::{build, ModelConfig};
    use tch::{nn, Device, Kind};

    /// A SegFormer-named `mit_b0` state_dict (with the ImageNet head) from a CMX network's RGB
    /// encoder, written to `file`; returns its tensors.
    fn segformer_b0(file: &Path) -> BTreeMap<String, Tensor> {
        tch::manual_seed(5);
        let vs = nn::VarStore::new(Device::Cpu);
        build(
            &vs.root(),
            &ModelConfig::from_name("cmx-mit-b0", 9).unwrap(),
        )
        .unwrap();
        let mut named = segformer_state_dict(&vs);
        named.push((
            "head.weight".into(),
            Tensor::zeros([1000, 256], (Kind::Float, Device::Cpu)),
        ));
        named.push((
            "head.bias".into(),
            Tensor::zeros([1000], (Kind::Float, Device::Cpu)),
        ));
        weights::save_named(&named, file).unwrap();
        named.into_iter().collect()
    }

    #[test]
    fn both_encoders_get_the_rgb_weights_and_the_rest_keeps_its_init() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("mit_b0.safetensors");
        let source = segformer_b0(&file);
        tch::manual_seed(6);
        let mut vs = nn::VarStore::new(Device::Cpu);
        build(
            &vs.root(),
            &ModelConfig::from_name("cmx-mit-b0", 9).unwrap(),
        )
        .unwrap();
        let before = vs.variables()["backbone.FRMs.0.channel_weights.mlp.0.weight"].copy();
        let report = load_mit_weights(&mut vs, &file).unwrap();
        assert!(
            report.contains("left out: head.bias, head.weight"),
            "{report}"
        );
        let vars = vs.variables();
        for (name, extra) in [
            ("patch_embed1.proj.weight", "extra_patch_embed1.proj.weight"),
            ("block2.1.attn.q.weight", "extra_block2.1.attn.q.weight"),
            ("norm4.bias", "extra_norm4.bias"),
        ] {
            let want = &source[name];
            assert!(vars[&format!("backbone.{name}")].equal(want), "{name}");
            assert!(vars[&format!("backbone.{extra}")].equal(want), "{extra}");
        }
        assert!(vars["backbone.FRMs.0.channel_weights.mlp.0.weight"].equal(&before));
    }

    #[test]
    fn another_mit_size_is_refused_naming_the_file_tensors_and_shapes() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("mit_b0.safetensors");
        segformer_b0(&file);
        let mut vs = nn::VarStore::new(Device::Cpu);
        build(
            &vs.root(),
            &ModelConfig::from_name("cmx-mit-b1", 9).unwrap(),
        )
        .unwrap();
        let err = load_mit_weights(&mut vs, &file).unwrap_err().to_string();
        assert!(err.contains("mit_b0.safetensors"), "{err}");
        assert!(
            err.contains("backbone.patch_embed1.proj.weight")
                && err.contains("[64, 3, 7, 7]")
                && err.contains("[32, 3, 7, 7]"),
            "{err}"
        );
    }
}
