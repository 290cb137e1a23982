//! Helpers for the networks' unit tests.

use std::path::PathBuf;

use tch::nn::{ModuleT, VarStore};
use tch::{Device, Kind, Tensor};

/// `shared/spec/keys/<file>` beside the repository, if present.
pub fn reference_keys_path(file: &str) -> Option<PathBuf> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/spec/keys")
        .join(file);
    path.is_file().then_some(path)
}

/// Sorted `name\t[shape]` lines of the reference file, without `num_batches_tracked`.
pub fn reference_keys(file: &str) -> Option<Vec<String>> {
    let Some(path) = reference_keys_path(file) else {
        eprintln!("notice: shared/spec/keys/{file} not found; reference-name check skipped");
        return None;
    };
    let text = std::fs::read_to_string(&path).unwrap();
    let mut lines: Vec<String> = text
        .lines()
        .filter(|l| {
            !l.trim().is_empty()
                && !crate::io::weights::is_ignored_name(l.split('\t').next().unwrap())
        })
        .map(|l| l.trim_end().to_string())
        .collect();
    lines.sort();
    Some(lines)
}

/// Sorted `name\t[shape]` lines of a VarStore, formatted as the reference files.
pub fn var_store_keys(vs: &VarStore) -> Vec<String> {
    let mut lines: Vec<String> = vs
        .variables()
        .iter()
        .map(|(name, t)| {
            let dims: Vec<String> = t.size().iter().map(|d| d.to_string()).collect();
            format!("{name}\t[{}]", dims.join(", "))
        })
        .collect();
    lines.sort();
    lines
}

/// Asserts that `vs` holds exactly the reference names and shapes (prints the differences).
pub fn assert_matches_reference_keys(vs: &VarStore, file: &str) {
    let Some(expected) = reference_keys(file) else {
        return;
    };
    let actual = var_store_keys(vs);
    let missing: Vec<_> = expected.iter().filter(|l| !actual.contains(l)).collect();
    let extra: Vec<_> = actual.iter().filter(|l| !expected.contains(l)).collect();
    assert!(
        missing.is_empty() && extra.is_empty(),
        "{file}: {} reference entries missing: {missing:#?}\n{} entries not in the reference: {extra:#?}",
        missing.len(),
        extra.len()
    );
}

/// Output shape of an eval-mode forward pass on random input.
pub fn forward_shape(net: &dyn ModuleT, shape: [i64; 4]) -> Vec<i64> {
    let _guard = tch::no_grad_guard();
    let x = Tensor::rand(shape, (Kind::Float, Device::Cpu));
    net.forward_t(&x, false).size()
}

/// Every way a fold for `precision` computes: fp32 one; bf16 with oneDNN's bf16 convolutions
/// and emulated (float32 kernels over bf16 maps), so that each machine tests both forms
/// whatever its CPU (the choice is a fold option, passed in; nothing is read from the process).
pub fn fold_options_each(precision: crate::fast::Precision) -> Vec<crate::fast::FoldOptions> {
    use crate::fast::{FoldOptions, InferenceKernels, Precision};
    use rtf_amp::Bf16Convolutions;
    let with = |bf16_convolutions| {
        FoldOptions::new(precision).kernels(InferenceKernels {
            bf16_convolutions,
            ..InferenceKernels::unmeasured()
        })
    };
    match precision {
        Precision::Bf16 => vec![
            with(Bf16Convolutions::Native),
            with(Bf16Convolutions::Emulated),
        ],
        _ => vec![FoldOptions::new(precision)],
    }
}
