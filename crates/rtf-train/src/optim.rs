//! SGD with momentum and weight decay (PyTorch semantics) whose state can be saved: tch's
//! `nn::Optimizer` cannot export its momentum buffers, which an exact `--resume` needs.

use std::collections::BTreeMap;

use tch::{nn::VarStore, Tensor};

/// Momentum buffers keyed by parameter name.
#[derive(Debug, Default)]
pub struct Sgd {
    pub momentum: f64,
    pub weight_decay: f64,
    buffers: BTreeMap<String, Tensor>,
}

impl Sgd {
    pub fn new(momentum: f64, weight_decay: f64) -> Self {
        Self {
            momentum,
            weight_decay,
            buffers: BTreeMap::new(),
        }
    }

    /// One update of every trainable variable of `vs` that has a gradient:
    /// g += wd·p; b = μ·b + g (b = g on the first step); p -= lr·b.
    pub fn step(&mut self, vs: &VarStore, lr: f64) {
        tch::no_grad(|| {
            for (name, mut param) in trainable(vs) {
                let grad = param.grad();
                if !grad.defined() {
                    continue;
                }
                let grad = if self.weight_decay != 0.0 {
                    grad + &param * self.weight_decay
                } else {
                    grad
                };
                let update = if self.momentum != 0.0 {
                    match self.buffers.get_mut(&name) {
                        Some(buffer) => {
                            let _ = buffer.g_mul_scalar_(self.momentum).g_add_(&grad);
                            buffer.shallow_clone()
                        }
                        None => {
                            let buffer = grad.detach().copy();
                            self.buffers.insert(name.clone(), buffer.shallow_clone());
                            buffer
                        }
                    }
                } else {
                    grad
                };
                let _ = param.g_sub_(&(update * lr));
            }
        });
    }

    /// Clears the gradients of every trainable variable.
    pub fn zero_grad(&self, vs: &VarStore) {
        for (_, mut param) in trainable(vs) {
            param.zero_grad();
        }
    }

    /// Momentum buffers (for checkpoints).
    pub fn buffers(&self) -> &BTreeMap<String, Tensor> {
        &self.buffers
    }

    /// Restores momentum buffers saved by [`buffers`](Self::buffers).
    pub fn set_buffers(&mut self, buffers: BTreeMap<String, Tensor>) {
        self.buffers = buffers;
    }
}

/// Trainable variables sorted by name (BatchNorm running statistics excluded).
pub fn trainable(vs: &VarStore) -> Vec<(String, Tensor)> {
    let mut vars: Vec<_> = vs
        .variables()
        .into_iter()
        .filter(|(_, t)| t.requires_grad())
        .collect();
    vars.sort_by(|a, b| a.0.cmp(&b.0));
    vars
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{nn, Device, Kind};

    /// Two steps on a quadratic, checked against the update rule written out by hand.
    #[test]
    fn matches_pytorch_update_rule() {
        let vs = VarStore::new(Device::Cpu);
        let w = vs
            .root()
            .var_copy("w", &Tensor::from_slice(&[1.0f32, -2.0]));
        let mut sgd = Sgd::new(0.9, 0.1);
        let mut expected = [1.0f64, -2.0];
        let mut buffer = [0.0f64; 2];
        for step in 0..2 {
            sgd.zero_grad(&vs);
            (&w * &w).sum(Kind::Float).backward(); // grad = 2w
            sgd.step(&vs, 0.5);
            for i in 0..2 {
                let g = 2.0 * expected[i] + 0.1 * expected[i];
                buffer[i] = if step == 0 { g } else { 0.9 * buffer[i] + g };
                expected[i] -= 0.5 * buffer[i];
            }
        }
        let got = Vec::<f32>::try_from(&w).unwrap();
        for i in 0..2 {
            assert!(
                (got[i] as f64 - expected[i]).abs() < 1e-5,
                "{got:?} vs {expected:?}"
            );
        }
        assert_eq!(sgd.buffers().len(), 1);
    }

    #[test]
    fn running_stats_are_not_trainable() {
        let vs = VarStore::new(Device::Cpu);
        let _bn = nn::batch_norm2d(vs.root() / "bn", 3, Default::default());
        let names: Vec<String> = trainable(&vs).into_iter().map(|(n, _)| n).collect();
        assert_eq!(names, vec!["bn.bias".to_string(), "bn.weight".to_string()]);
    }
}
