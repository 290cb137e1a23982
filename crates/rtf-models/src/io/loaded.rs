//! A network ready for inference from a weights file, as `rtf eval`, `rtf predict` and
//! `rtf export` load one: built by name, loaded strictly under reference names and checked
//! against the file's model metadata ([`crate::io::weights::load_checked`]), seeing the inputs it
//! was trained on, optionally on the fast path ([`crate::fast::InferenceNet`]), behind its
//! input mask ([`crate::masked`]). What a user should be told (weights without metadata) comes
//! back as warnings for the caller to print.

use std::path::Path;

use tch::nn::VarStore;

use crate::fast::{FoldOptions, InferenceKernels, InferenceNet, Precision};
use crate::{Modality, ModelConfig, ModelError, Network};

/// What to load, and how far to trust the file.
#[derive(Debug, Clone, Copy)]
pub struct NetworkRequest<'a> {
    /// The network's name (`rtf models`).
    pub name: &'a str,
    pub num_classes: i64,
    pub weights: &'a Path,
    pub device: tch::Device,
    /// The fast path's precision (BatchNorm folded, channels-last); None: the network as built.
    pub precision: Option<Precision>,
    /// The fast path's kernels where there is a choice (`rtf_eval::kernels` chooses them as
    /// the commands do).
    pub kernels: InferenceKernels,
    /// Loads weights saved for another network, or with other inputs, than the one asked.
    pub foreign_weights: bool,
    /// `--inputs`: the channels the network sees, when the file does not say (or, with
    /// `foreign_weights`, over what it says).
    pub inputs: Option<Modality>,
}

/// A network loaded for inference, behind the input mask it was trained with.
pub struct LoadedNetwork {
    /// The network's variables; with a fast-path `precision`, those the folded path does not
    /// read are emptied ([`InferenceNet::releasing_plain_weights`]), so this is not for saving.
    pub vs: VarStore,
    pub net: Box<dyn Network>,
    /// The channels the network sees: the weights file's record (`rtf.inputs`), else the
    /// request's, else all four.
    pub inputs: Modality,
    /// What the caller should tell its user (e.g. a file without rtf's metadata).
    pub warnings: Vec<String>,
}

/// Loads `request.weights` into the network `request.name`. An `inputs` that contradicts the
/// file's record is refused unless `foreign_weights`: it would score an RGB-only network on
/// RGB-T input, or the reverse, without a word.
pub fn load_network(request: &NetworkRequest) -> Result<LoadedNetwork, ModelError> {
    if let Some(precision) = request.precision {
        crate::fast::check_precision_on(precision, request.device)?;
    }
    let cfg = ModelConfig::from_name(request.name, request.num_classes)?;
    let mut vs = VarStore::new(request.device);
    let net = crate::build(&vs.root(), &cfg)?;
    let loaded =
        crate::io::weights::load_checked(&mut vs, &cfg, request.weights, request.foreign_weights)?;
    let warnings: Vec<String> =
        crate::io::weights::provenance_warning(request.weights, &loaded.provenance)
            .into_iter()
            .collect();
    let inputs = match (loaded.inputs, request.inputs) {
        (Some(saved), Some(asked)) if saved != asked && !request.foreign_weights => {
            return Err(ModelError::InputsContradict {
                path: request.weights.to_path_buf(),
                saved: saved.to_string(),
                asked: asked.to_string(),
            })
        }
        (_, Some(asked)) => asked,
        (Some(saved), None) => saved,
        (None, None) => Modality::RgbT,
    };
    let net = match request.precision {
        Some(p) => {
            let options = FoldOptions::new(p).kernels(request.kernels);
            let (fast, _) = InferenceNet::releasing_plain_weights(net, &options, &vs)?;
            Box::new(fast) as Box<dyn Network>
        }
        None => net,
    };
    Ok(LoadedNetwork {
        vs,
        net: crate::masked(net, inputs),
        inputs,
        warnings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An MFNet saved as trained on RGB alone, and the request for it.
    fn saved_rgb_mfnet(dir: &Path) -> std::path::PathBuf {
        let cfg = ModelConfig::from_name("mfnet", 9).unwrap();
        let vs = VarStore::new(tch::Device::Cpu);
        crate::build(&vs.root(), &cfg).unwrap();
        let path = dir.join("rgb.safetensors");
        crate::io::weights::save_safetensors(&vs, &cfg, Modality::Rgb, &path).unwrap();
        path
    }

    fn request(weights: &Path, inputs: Option<Modality>, foreign: bool) -> NetworkRequest<'_> {
        NetworkRequest {
            name: "mfnet",
            num_classes: 9,
            weights,
            device: tch::Device::Cpu,
            precision: None,
            kernels: InferenceKernels::unmeasured(),
            foreign_weights: foreign,
            inputs,
        }
    }

    #[test]
    fn the_network_sees_the_inputs_it_was_trained_on_and_a_contradiction_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let weights = saved_rgb_mfnet(dir.path());
        let loaded = load_network(&request(&weights, None, false)).unwrap();
        assert_eq!(loaded.inputs, Modality::Rgb);
        assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
        let refused = load_network(&request(&weights, Some(Modality::RgbT), false));
        let message = refused.err().unwrap().to_string();
        assert!(
            message.contains("rgb.safetensors") && message.contains("trained on `rgb` inputs"),
            "{message}"
        );
        let forced = load_network(&request(&weights, Some(Modality::RgbT), true)).unwrap();
        assert_eq!(forced.inputs, Modality::RgbT);
    }
}
