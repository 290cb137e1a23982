use super::*;

/// Decay on convolution and linear weights (≥ 2-D), none on norms' weights and biases.
#[test]
fn the_decay_scope_is_decided_by_shape() {
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let root = vs.root();
    let _conv = tch::nn::conv2d(&root / "conv", 3, 4, 3, Default::default());
    let _linear = tch::nn::linear(&root / "fc", 4, 2, Default::default());
    let _bn = tch::nn::batch_norm2d(&root / "bn", 4, Default::default());
    let _ln = tch::nn::layer_norm(&root / "ln", vec![4], Default::default());
    let decayed: Vec<String> = crate::optim::trainable(&vs)
        .into_iter()
        .filter(|(_, t)| DecayScope::ConvAndLinearWeights.decays(t.dim()))
        .map(|(n, _)| n)
        .collect();
    assert_eq!(decayed, ["conv.weight", "fc.weight"]);
    assert_eq!(crate::optim::trainable(&vs).len(), 8);
}
