//! The optimisers of the papers with PyTorch's update rules and state that can be saved: SGD
//! with momentum (MFNet, RTFNet), RMSprop (HeatNet) and AdamW (CMX). tch's `nn::Optimizer`
//! cannot export its buffers, which an exact `--resume` needs. Weight decay applies to the
//! tensors of the configured [`DecayScope`] (CMX: convolution and linear weights only).
//!
//! Under fp16 mixed precision the optimiser also owns the dynamic loss scale (PyTorch's
//! `torch.amp.GradScaler`; Micikevicius et al., "Mixed Precision Training", ICLR 2018, §3.2):
//! the loss is multiplied by the scale before backward, the gradients divided by it before the
//! update; a step whose gradients hold an inf or NaN is skipped and the scale halved, and after
//! [`SCALE_GROWTH_INTERVAL`] clean steps in a row it doubles. The scale and the count of clean
//! steps are state like the momentum buffers (keys [`SCALE_KEY`], [`GROWTH_KEY`]), so a resume
//! continues with them.

use std::collections::BTreeMap;

use tch::{nn::VarStore, Kind, Tensor};

use rtf_kernels::aten::{AdamwRule, AdamwTensors};

use crate::config::{DecayScope, OptimizerConfig, OptimizerKind};

/// State key of the loss scale (a one-element fp32 tensor).
pub const SCALE_KEY: &str = "amp/loss_scale";
/// State key of the count of clean steps since the scale last changed.
pub const GROWTH_KEY: &str = "amp/growth_tracker";
/// State key prefixes of AdamW's moments (PyTorch's names).
const EXP_AVG: &str = "exp_avg";
const EXP_AVG_SQ: &str = "exp_avg_sq";
/// The first loss scale, 2¹⁶ (GradScaler's `init_scale`).
pub const INITIAL_SCALE: f64 = 65536.0;
/// Clean steps in a row before the scale doubles (GradScaler's `growth_interval`).
pub const SCALE_GROWTH_INTERVAL: f64 = 2000.0;

/// An optimiser and its per-parameter state, keyed `momentum/<parameter>`,
/// `square_avg/<parameter>`, and for AdamW `exp_avg/<parameter>`, `exp_avg_sq/<parameter>` and
/// `step/<parameter>` (PyTorch's names; checkpoints store them so), plus the loss scale when it
/// scales the loss.
#[derive(Debug)]
pub struct Optimizer {
    config: OptimizerConfig,
    state: BTreeMap<String, Tensor>,
    scaling: bool,
}

impl Optimizer {
    pub fn new(config: &OptimizerConfig) -> Self {
        Self {
            config: config.clone(),
            state: BTreeMap::new(),
            scaling: false,
        }
    }

    /// Turns dynamic loss scaling on or off (on for fp16 mixed precision).
    pub fn set_loss_scaling(&mut self, on: bool) {
        self.scaling = on;
    }

    /// The current loss scale (1 when the loss is not scaled).
    pub fn loss_scale(&self) -> f64 {
        match self.scaling {
            false => 1.0,
            true => self.scalar(SCALE_KEY).unwrap_or(INITIAL_SCALE),
        }
    }

    fn scalar(&self, key: &str) -> Option<f64> {
        self.state
            .get(key)
            .and_then(|t| f64::try_from(t.reshape([-1]).get(0)).ok())
    }

    fn set_scalar(&mut self, key: &str, value: f64) {
        self.state
            .insert(key.to_string(), Tensor::from_slice(&[value as f32]));
    }

    /// The tensor to call `backward` on: `loss` times the loss scale when scaling, else `loss`
    /// itself.
    pub fn scale_loss(&self, loss: &Tensor) -> Tensor {
        match self.scaling {
            false => loss.shallow_clone(),
            true => loss * self.loss_scale(),
        }
    }

    /// Divides the gradients of `vs` by the loss scale and updates the scale; false when a
    /// gradient holds an inf or NaN (the step must be skipped). One fused check-and-unscale per
    /// gradient (PyTorch's GradScaler kernel) into one flag on the device, read once: a read
    /// per gradient waited for the device each time, which made fp16's optimiser step on a GPU
    /// many times fp32's (measured: docs/src/gpu-2026-11-27.md, section "Training, 480×640";
    /// after the fusion: docs/src/gpu.md, section "Training, 480×640").
    fn unscale(&mut self, vs: &VarStore) -> bool {
        let scale = self.loss_scale();
        let device = vs.device();
        let mut found_inf = Tensor::zeros([1], (Kind::Float, device));
        // The scale is a power of two: multiplying by its inverse is exact, as dividing is.
        // Filled on the device: no copy from host memory (on a GPU one more wait a step).
        let inv_scale = Tensor::full([1], 1.0 / scale, (Kind::Float, device));
        tch::no_grad(|| {
            for (_, param) in trainable(vs) {
                let mut grad = param.grad();
                if grad.defined() {
                    grad.internal_amp_non_finite_check_and_unscale(&mut found_inf, &inv_scale);
                }
            }
        });
        let finite = f64::try_from(&found_inf).is_ok_and(|v| v == 0.0);
        let growth = self.scalar(GROWTH_KEY).unwrap_or(0.0);
        let (scale, growth) = match (finite, growth + 1.0 >= SCALE_GROWTH_INTERVAL) {
            (false, _) => (scale * 0.5, 0.0),
            (true, true) => (scale * 2.0, 0.0),
            (true, false) => (scale, growth + 1.0),
        };
        self.set_scalar(SCALE_KEY, scale);
        self.set_scalar(GROWTH_KEY, growth);
        finite
    }

    /// One update of every trainable variable of `vs` that has a gradient, PyTorch's rules,
    /// with `wd` = the weight decay where the [`DecayScope`] applies, else 0:
    /// - SGD: g += wd·p; b = μ·b + g (b = g on the first step), p −= lr·b;
    /// - RMSprop: g += wd·p; v = α·v + (1 − α)·g² (v starts at 0), d = g / (√v + ε);
    ///   with momentum b = μ·b + d (b starts at 0), p −= lr·b; else p −= lr·d;
    /// - AdamW ([`adamw_step`](Self::adamw_step)): p −= lr·wd·p, then Adam's update.
    ///
    /// When scaling the loss, the gradients are first divided by the scale, and the update is
    /// skipped if one of them is not finite.
    pub fn step(&mut self, vs: &VarStore, lr: f64) {
        if self.scaling && !self.unscale(vs) {
            return;
        }
        let scope = self.config.decay_scope;
        let mut sgd = FusedGroups::<3>::default();
        let mut adamw = FusedGroups::<5>::default();
        tch::no_grad(|| {
            for (name, param) in trainable(vs) {
                let grad = param.grad();
                if !grad.defined() {
                    continue;
                }
                let wd = decay_of(scope, &param, self.config.weight_decay);
                match self.config.kind {
                    OptimizerKind::Sgd if fusable(&param, &grad) => {
                        let (buffer, first_step) = self.sgd_buffer(&name, &param, &grad);
                        sgd.add(wd, first_step, [param, grad, buffer]);
                    }
                    OptimizerKind::Adamw if fusable(&param, &grad) => {
                        let [m, v] = [EXP_AVG, EXP_AVG_SQ]
                            .map(|moment| self.laid_like(format!("{moment}/{name}"), &param).0);
                        let step = self.step_count(&name, &param);
                        adamw.add(wd, false, [param, grad, m, v, step]);
                    }
                    OptimizerKind::Adamw => self.adamw_step(&name, &param, &grad, lr, wd),
                    _ => self.step_written_out(&name, param, grad, lr, wd),
                }
            }
            for (wd, first_step, [params, grads, buffers]) in sgd.groups() {
                let momentum = self.config.momentum;
                rtf_kernels::aten::fused_sgd_(
                    &params, &grads, &buffers, wd, momentum, lr, first_step,
                );
            }
            for (weight_decay, _, [params, grads, exp_avgs, exp_avg_sqs, steps]) in adamw.groups() {
                let (betas, eps) = (self.config.betas, self.config.eps);
                let rule = AdamwRule {
                    lr,
                    betas,
                    weight_decay,
                    eps,
                };
                let tensors = AdamwTensors {
                    params: &params,
                    grads: &grads,
                    exp_avgs: &exp_avgs,
                    exp_avg_sqs: &exp_avg_sqs,
                    steps: &steps,
                };
                rtf_kernels::aten::fused_adamw_(&tensors, rule);
            }
        });
    }

    /// PyTorch's AdamW (`torch.optim.AdamW`, single-tensor path, no amsgrad), state per
    /// parameter, for the tensors ATen's fused kernel does not take ([`fusable`]): t += 1;
    /// p ·= 1 − lr·wd; m = lerp(m, g, 1 − β1); v = β2·v + (1 − β2)·g²;
    /// p −= (lr / (1 − β1ᵗ)) · m / (√v / √(1 − β2ᵗ) + ε).
    fn adamw_step(&mut self, name: &str, param: &Tensor, grad: &Tensor, lr: f64, wd: f64) {
        let (b1, b2) = self.config.betas;
        let eps = self.config.eps;
        let step_key = format!("step/{name}");
        let t = self.scalar(&step_key).unwrap_or(0.0) + 1.0;
        self.set_scalar(&step_key, t);
        let mut param = param.shallow_clone();
        if wd != 0.0 {
            let _ = param.g_mul_scalar_(1.0 - lr * wd);
        }
        let mut m = self.buffer(format!("{EXP_AVG}/{name}"), grad);
        let mut v = self.buffer(format!("{EXP_AVG_SQ}/{name}"), grad);
        let _ = m.lerp_(grad, 1.0 - b1);
        // PyTorch's `addcmul_(g, g, value)` and `addcdiv_(m, d, value)` multiply the value in
        // first: the same products here.
        let _ = v.g_mul_scalar_(b2).addcmul_(&(grad * (1.0 - b2)), grad);
        let (bias1, bias2) = (1.0 - b1.powf(t), 1.0 - b2.powf(t));
        let mut denom = v.sqrt() / bias2.sqrt();
        let _ = denom.g_add_scalar_(eps);
        let _ = param.addcdiv_(&(&m * (-lr / bias1)), &denom);
    }

    /// The momentum buffer of `param` for the fused SGD kernel, and whether this is its first
    /// step (the buffer then starts as the gradient; with momentum 0, the gradient itself).
    fn sgd_buffer(&mut self, name: &str, param: &Tensor, grad: &Tensor) -> (Tensor, bool) {
        match self.config.momentum {
            0.0 => (grad.shallow_clone(), false),
            _ => self.laid_like(format!("momentum/{name}"), param),
        }
    }

    /// The state tensor `key` laid out like `param` on its device, as the fused kernels walk
    /// them (zeros on first use, then true); one restored with another layout (a checkpoint is
    /// laid out contiguous) is re-laid like the parameter, same values.
    fn laid_like(&mut self, key: String, param: &Tensor) -> (Tensor, bool) {
        match self.state.get(&key) {
            Some(t) if t.stride() == param.stride() && t.device() == param.device() => {
                (t.shallow_clone(), false)
            }
            Some(t) => {
                let mut relaid = param.empty_like();
                relaid.copy_(t);
                self.state.insert(key, relaid.shallow_clone());
                (relaid, false)
            }
            None => {
                let zeros = param.zeros_like();
                self.state.insert(key, zeros.shallow_clone());
                (zeros, true)
            }
        }
    }

    /// AdamW's step count of `name` for the fused kernel: one fp32 element on the parameter's
    /// device (where the CUDA kernel reads it), 0 before the first step.
    fn step_count(&mut self, name: &str, param: &Tensor) -> Tensor {
        let key = format!("step/{name}");
        let device = param.device();
        let count = match self.state.get(&key) {
            Some(t) if t.device() == device && t.kind() == Kind::Float => t.shallow_clone(),
            Some(t) => t.to_kind(Kind::Float).to_device(device).reshape([1]),
            None => Tensor::zeros([1], (Kind::Float, device)),
        };
        self.state.insert(key, count.shallow_clone());
        count
    }

    /// The update rules written out (RMSprop; SGD where the fused kernel does not apply).
    fn step_written_out(&mut self, name: &str, mut param: Tensor, grad: Tensor, lr: f64, wd: f64) {
        let cfg = self.config.clone();
        let grad = if wd != 0.0 { grad + &param * wd } else { grad };
        let direction = match cfg.kind {
            // AdamW has its own step (adamw_step) and never comes here.
            OptimizerKind::Sgd | OptimizerKind::Adamw => grad,
            OptimizerKind::Rmsprop => {
                let square_avg = self.buffer(format!("square_avg/{name}"), &grad);
                let _ = square_avg
                    .shallow_clone()
                    .g_mul_scalar_(cfg.alpha)
                    .g_add_(&(&grad * &grad * (1.0 - cfg.alpha)));
                grad / (square_avg.sqrt() + cfg.eps)
            }
        };
        let update = if cfg.momentum == 0.0 {
            direction
        } else {
            let key = format!("momentum/{name}");
            match self.state.get_mut(&key) {
                Some(buffer) => {
                    let _ = buffer.g_mul_scalar_(cfg.momentum).g_add_(&direction);
                    buffer.shallow_clone()
                }
                // SGD starts its buffer at the first direction; RMSprop starts at 0 and
                // adds it, which is the same.
                None => {
                    let buffer = direction.detach().copy();
                    self.state.insert(key, buffer.shallow_clone());
                    buffer
                }
            }
        };
        let _ = param.g_sub_(&(update * lr));
    }

    /// The state tensor `key`, created as zeros shaped like `like` on first use.
    fn buffer(&mut self, key: String, like: &Tensor) -> Tensor {
        self.state
            .entry(key)
            .or_insert_with(|| like.zeros_like())
            .shallow_clone()
    }

    /// Clears the gradients of every trainable variable (in place, as the papers' PyTorch
    /// code did: `zero_grad(set_to_none=False)`), all in one call
    /// ([`rtf_kernels::aten::zero_grads`]).
    pub fn zero_grad(&self, vs: &VarStore) {
        let params: Vec<Tensor> = trainable(vs).into_iter().map(|(_, p)| p).collect();
        rtf_kernels::aten::zero_grads(&params);
    }

    /// The per-parameter state (for checkpoints).
    pub fn state(&self) -> &BTreeMap<String, Tensor> {
        &self.state
    }

    /// Restores state saved from [`state`](Self::state).
    pub fn set_state(&mut self, state: BTreeMap<String, Tensor>) {
        self.state = state;
    }
}

/// The weight decay of `param`: `weight_decay` where `scope` applies to it, else 0.
fn decay_of(scope: DecayScope, param: &Tensor, weight_decay: f64) -> f64 {
    match scope.decays(param.dim()) {
        true => weight_decay,
        false => 0.0,
    }
}

/// The parameters a step updates in one of ATen's fused kernels, `N` tensors each (the
/// parameter first), grouped by what one call shares (weight decay, first step, device), so
/// that each group is one call: on CUDA a few multi-tensor launches instead of several per
/// parameter (docs/src/gpu.md, MFNet's host-bound step).
struct FusedGroups<const N: usize> {
    /// (weight decay's bits, first step, CUDA index or −1) → the tensors, list by list.
    groups: BTreeMap<(u64, bool, i64), [Vec<Tensor>; N]>,
}

impl<const N: usize> Default for FusedGroups<N> {
    fn default() -> Self {
        Self {
            groups: BTreeMap::new(),
        }
    }
}

impl<const N: usize> FusedGroups<N> {
    fn add(&mut self, wd: f64, first_step: bool, tensors: [Tensor; N]) {
        let device = match tensors[0].device() {
            tch::Device::Cuda(i) => i as i64,
            _ => -1,
        };
        let lists = self
            .groups
            .entry((wd.to_bits(), first_step, device))
            .or_insert_with(|| std::array::from_fn(|_| Vec::new()));
        for (list, t) in lists.iter_mut().zip(tensors) {
            list.push(t);
        }
    }

    /// (weight decay, first step, the tensors) of each call.
    fn groups(self) -> impl Iterator<Item = (f64, bool, [Vec<Tensor>; N])> {
        self.groups
            .into_iter()
            .map(|((wd, first_step, _), lists)| (f64::from_bits(wd), first_step, lists))
    }
}

/// Whether ATen's fused SGD and AdamW kernels may update `param` with `grad`: both on the CPU
/// or CUDA, fp32, dense in the same layout (the kernels walk their memory in step). Strides of
/// dimensions of size 1 do not place an element, and autograd leaves them as it likes (a
/// depthwise kernel [C, 1, 3, 3] and its gradient differ there): they are not compared.
fn fusable(param: &Tensor, grad: &Tensor) -> bool {
    let dense = param.is_contiguous() || rtf_models::layers::is_channels_last(param);
    let placing = |t: &Tensor| -> Vec<(i64, i64)> {
        let placed = t.size().into_iter().zip(t.stride());
        placed.filter(|&(size, _)| size > 1).collect()
    };
    matches!(param.device(), tch::Device::Cpu | tch::Device::Cuda(_))
        && param.kind() == tch::Kind::Float
        && grad.kind() == tch::Kind::Float
        && param.size() == grad.size()
        && placing(param) == placing(grad)
        && dense
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
    use crate::config::OptimizerConfig;
    use tch::{nn, Device, Kind};

    fn quadratic_steps(cfg: &OptimizerConfig, steps: usize, lr: f64) -> (Vec<f32>, usize) {
        let vs = VarStore::new(Device::Cpu);
        let w = vs
            .root()
            .var_copy("w", &Tensor::from_slice(&[1.0f32, -2.0]));
        let mut optimizer = Optimizer::new(cfg);
        for _ in 0..steps {
            optimizer.zero_grad(&vs);
            (&w * &w).sum(Kind::Float).backward(); // grad = 2w
            optimizer.step(&vs, lr);
        }
        (Vec::<f32>::try_from(&w).unwrap(), optimizer.state().len())
    }

    fn assert_close(got: &[f32], expected: &[f64]) {
        for (g, e) in got.iter().zip(expected) {
            assert!((*g as f64 - e).abs() < 1e-5, "{got:?} vs {expected:?}");
        }
    }

    /// Two SGD steps on a quadratic, checked against the update rule written out by hand.
    #[test]
    fn sgd_matches_pytorch_update_rule() {
        let cfg = OptimizerConfig {
            momentum: 0.9,
            weight_decay: 0.1,
            ..OptimizerConfig::mfnet_paper()
        };
        let mut expected = [1.0f64, -2.0];
        let mut buffer = [0.0f64; 2];
        for step in 0..2 {
            for i in 0..2 {
                let g = 2.0 * expected[i] + 0.1 * expected[i];
                buffer[i] = if step == 0 { g } else { 0.9 * buffer[i] + g };
                expected[i] -= 0.5 * buffer[i];
            }
        }
        let (got, state) = quadratic_steps(&cfg, 2, 0.5);
        assert_close(&got, &expected);
        assert_eq!(state, 1, "one momentum buffer");
    }

    /// The fused SGD kernel on a channels-last 4-D parameter (bf16 runs lay kernels out so),
    /// with and without momentum, and after its momentum buffer came back from a checkpoint laid
    /// out contiguous: the update rule, element for element.
    #[test]
    fn fused_sgd_follows_the_rule_in_any_layout_and_after_a_restore() {
        for momentum in [0.9, 0.0] {
            let cfg = OptimizerConfig {
                momentum,
                weight_decay: 0.05,
                ..OptimizerConfig::mfnet_paper()
            };
            let vs = VarStore::new(Device::Cpu);
            let start = Tensor::randn([3, 4, 2, 5], (Kind::Float, Device::Cpu));
            let mut w = vs.root().var_copy("w", &start);
            tch::no_grad(|| w.set_data(&rtf_models::layers::to_channels_last(&w)));
            assert!(rtf_models::layers::is_channels_last(&w));
            let target = Tensor::randn([3, 4, 2, 5], (Kind::Float, Device::Cpu));
            let mut optimizer = Optimizer::new(&cfg);
            let (mut expected, mut buffer) = (start.copy(), start.zeros_like());
            for step in 0..4 {
                if step == 2 {
                    // A resume: the state as a checkpoint hands it back, contiguous.
                    let restored = optimizer
                        .state()
                        .iter()
                        .map(|(k, v)| (k.clone(), v.contiguous()))
                        .collect();
                    optimizer = Optimizer::new(&cfg);
                    optimizer.set_state(restored);
                }
                optimizer.zero_grad(&vs);
                (&w - &target).square().sum(Kind::Float).backward(); // grad = 2(w − target)
                optimizer.step(&vs, 0.1);
                let g = (&expected - &target) * 2.0 + &expected * 0.05;
                buffer = match (momentum, step) {
                    (0.0, _) => g.shallow_clone(),
                    (_, 0) => g.shallow_clone(),
                    _ => &buffer * momentum + &g,
                };
                expected = &expected - &buffer * 0.1;
                assert!(
                    w.allclose(&expected, 1e-5, 1e-6, false),
                    "momentum {momentum}, step {step}"
                );
            }
            assert_eq!(optimizer.state().len(), usize::from(momentum != 0.0));
        }
    }

    /// One fused call per group: a decaying weight matrix, a non-decaying bias (CMX's decay
    /// scope), and a parameter that joins at the second step (its buffer's first step while the
    /// others' is not), each following SGD's rule; the gradients zeroed in between, a
    /// parameter without a gradient left without one.
    #[test]
    fn fused_sgd_groups_follow_the_rule_per_parameter() {
        let cfg = OptimizerConfig {
            momentum: 0.9,
            weight_decay: 0.05,
            decay_scope: crate::config::DecayScope::ConvAndLinearWeights,
            ..OptimizerConfig::mfnet_paper()
        };
        let vs = VarStore::new(Device::Cpu);
        let starts = [
            vec![1.0f32, -2.0, 0.5, 3.0],
            vec![0.25, -1.0],
            vec![2.0, 4.0],
        ];
        let w = vs
            .root()
            .var_copy("w", &Tensor::from_slice(&starts[0]).view([2, 2]));
        let b = vs.root().var_copy("b", &Tensor::from_slice(&starts[1]));
        let late = vs.root().var_copy("late", &Tensor::from_slice(&starts[2]));
        let idle = vs.root().var_copy("idle", &Tensor::from_slice(&[1.0f32]));
        let mut optimizer = Optimizer::new(&cfg);
        // Expected, per parameter: (values, buffer, weight decay).
        let mut expected: Vec<(Vec<f64>, Vec<f64>, f64)> = starts
            .iter()
            .zip([0.05, 0.0, 0.0])
            .map(|(s, wd)| (s.iter().map(|&v| v as f64).collect(), vec![], wd))
            .collect();
        for step in 0..3 {
            optimizer.zero_grad(&vs);
            let mut loss = (&w * &w).sum(Kind::Float) + (&b * &b).sum(Kind::Float);
            if step > 0 {
                loss += (&late * &late).sum(Kind::Float);
            }
            loss.backward(); // grad = 2p
            optimizer.step(&vs, 0.1);
            for (i, (values, buffer, wd)) in expected.iter_mut().enumerate() {
                if i == 2 && step == 0 {
                    continue;
                }
                let g: Vec<f64> = values.iter().map(|v| 2.0 * v + *wd * v).collect();
                *buffer = match buffer.is_empty() {
                    true => g,
                    false => buffer.iter().zip(&g).map(|(b, g)| 0.9 * b + g).collect(),
                };
                values
                    .iter_mut()
                    .zip(buffer.iter())
                    .for_each(|(v, b)| *v -= 0.1 * b);
            }
        }
        for (tensor, (values, _, _)) in [&w, &b, &late].into_iter().zip(&expected) {
            let got = Vec::<f32>::try_from(&tensor.flatten(0, -1)).unwrap();
            assert_close(&got, values);
        }
        assert!(
            !idle.grad().defined(),
            "a parameter no loss reached has no gradient"
        );
        assert_eq!(optimizer.state().len(), 3, "a buffer per updated parameter");
        optimizer.zero_grad(&vs);
        assert_eq!(w.grad().abs().sum(Kind::Float).double_value(&[]), 0.0);
        assert!(!w.grad().requires_grad());
    }

    /// Three RMSprop steps (PyTorch's `torch.optim.RMSprop` rule), with and without momentum.
    #[test]
    fn rmsprop_matches_pytorch_update_rule() {
        for momentum in [0.0, 0.5] {
            let cfg = OptimizerConfig {
                momentum,
                weight_decay: 0.1,
                ..OptimizerConfig::heatnet_paper()
            };
            let (alpha, eps, lr) = (cfg.alpha, cfg.eps, 0.01);
            let mut expected = [1.0f64, -2.0];
            let (mut square_avg, mut buffer) = ([0.0f64; 2], [0.0f64; 2]);
            for _ in 0..3 {
                for i in 0..2 {
                    let g = 2.0 * expected[i] + 0.1 * expected[i];
                    square_avg[i] = alpha * square_avg[i] + (1.0 - alpha) * g * g;
                    let d = g / (square_avg[i].sqrt() + eps);
                    buffer[i] = momentum * buffer[i] + d;
                    expected[i] -= lr * if momentum > 0.0 { buffer[i] } else { d };
                }
            }
            let (got, state) = quadratic_steps(&cfg, 3, lr);
            assert_close(&got, &expected);
            assert_eq!(state, if momentum > 0.0 { 2 } else { 1 });
        }
    }

    /// Three AdamW steps (`torch.optim.AdamW`'s rule written out in f64) on a weight matrix
    /// and a bias under CMX's scope: the matrix decays, the bias does not; then three more
    /// after the state went through a checkpoint's f32 copy, as a resume hands it back.
    #[test]
    fn adamw_matches_pytorch_update_rule_with_decay_on_weights_only() {
        let cfg = OptimizerConfig {
            weight_decay: 0.5,
            ..OptimizerConfig::cmx_code()
        };
        let ((b1, b2), eps, lr) = (cfg.betas, cfg.eps, 0.1);
        let vs = VarStore::new(Device::Cpu);
        let start = [1.0f64, -2.0, 0.5];
        let fc = vs.root() / "fc";
        let w = fc.var_copy("weight", &Tensor::from_slice(&[1.0f32, -2.0]).view([2, 1]));
        let b = fc.var_copy("bias", &Tensor::from_slice(&[0.5f32]));
        let mut optimizer = Optimizer::new(&cfg);
        let (mut p, mut m, mut v) = (start, [0.0f64; 3], [0.0f64; 3]);
        for t in 1..=6 {
            if t == 4 {
                let saved: BTreeMap<String, Tensor> = optimizer
                    .state()
                    .iter()
                    .map(|(k, v)| (k.clone(), v.to_kind(Kind::Float).copy()))
                    .collect();
                optimizer = Optimizer::new(&cfg);
                optimizer.set_state(saved);
            }
            optimizer.zero_grad(&vs);
            // grad = 2·p for every element.
            ((&w * &w).sum(Kind::Float) + (&b * &b).sum(Kind::Float)).backward();
            optimizer.step(&vs, lr);
            for i in 0..3 {
                let g = 2.0 * p[i];
                if i < 2 {
                    p[i] *= 1.0 - lr * cfg.weight_decay;
                }
                m[i] = b1 * m[i] + (1.0 - b1) * g;
                v[i] = b2 * v[i] + (1.0 - b2) * g * g;
                let (c1, c2) = (1.0 - b1.powi(t), 1.0 - b2.powi(t));
                p[i] -= lr / c1 * m[i] / ((v[i] / c2).sqrt() + eps);
            }
            let got: Vec<f32> =
                Vec::try_from(Tensor::cat(&[w.view([-1]), b.shallow_clone()], 0)).unwrap();
            assert_close(&got, &p);
        }
        assert_eq!(
            optimizer.state().len(),
            6,
            "exp_avg, exp_avg_sq, step per parameter"
        );
        assert_eq!(optimizer.scalar("step/fc.bias"), Some(6.0));
    }

    /// AdamW in ATen's fused kernel: a channels-last 4-D weight and a depthwise kernel
    /// [C, 1, 3, 3] (whose gradient autograd lays out with other strides on its size-1
    /// dimension) that decay, and a bias that does not (CMX's scope); four steps with the state
    /// handed back contiguous after two (a resume): the update rule, element for element, and
    /// one `_fused_adamw_` call per decay group, not fourteen operators per tensor.
    #[test]
    fn fused_adamw_follows_the_rule_in_any_layout_after_a_restore_in_one_call_per_group() {
        let cfg = OptimizerConfig {
            weight_decay: 0.2,
            ..OptimizerConfig::cmx_code()
        };
        let ((b1, b2), eps, lr) = (cfg.betas, cfg.eps, 0.01);
        let vs = VarStore::new(Device::Cpu);
        let randn = |s: &[i64]| Tensor::randn(s, (Kind::Float, Device::Cpu));
        let mut w = vs.root().var_copy("w", &randn(&[3, 4, 2, 5]));
        tch::no_grad(|| w.set_data(&rtf_models::layers::to_channels_last(&w)));
        let dw = vs.root().var_copy("dw", &randn(&[4, 1, 3, 3]));
        let b = vs.root().var_copy("b", &randn(&[3]));
        // A channels-last input, as CMX's blocks run: its depthwise gradient comes out so.
        let x = rtf_models::layers::to_channels_last(&randn(&[1, 4, 6, 6]));
        let target = randn(&[3, 4, 2, 5]);
        let params = [&w, &dw, &b];
        let mut expected = params.map(|p| p.copy());
        let mut moments = params.map(|p| [p.zeros_like(), p.zeros_like()]);
        let mut optimizer = Optimizer::new(&cfg);
        for step in 1..=4 {
            if step == 3 {
                let restored = optimizer.state().iter();
                let restored = restored.map(|(k, v)| (k.clone(), v.contiguous())).collect();
                optimizer = Optimizer::new(&cfg);
                optimizer.set_state(restored);
            }
            optimizer.zero_grad(&vs);
            let depthwise = x.conv2d(&dw, None::<Tensor>, [1, 1], [0, 0], [1, 1], 4);
            let loss = (&w - &target).square().sum(Kind::Float) + b.square().sum(Kind::Float);
            (loss + depthwise.square().sum(Kind::Float)).backward();
            assert_ne!(
                dw.grad().stride(),
                dw.stride(),
                "the case of a size-1 dimension"
            );
            let grads = params.map(|p| p.grad().copy());
            let ((), counts) = rtf_kernels::aten::count_ops(|| optimizer.step(&vs, lr));
            let fused = counts.get("aten::_fused_adamw_").map(|c| c.1);
            assert_eq!(fused, Some(2), "{counts:?}");
            assert!(
                !counts.contains_key("aten::lerp_"),
                "none written out: {counts:?}"
            );
            for (i, g) in grads.iter().enumerate() {
                let [m, v] = &mut moments[i];
                *m = &*m * b1 + g * (1.0 - b1);
                *v = &*v * b2 + g * g * (1.0 - b2);
                let decay = if i < 2 {
                    1.0 - lr * cfg.weight_decay
                } else {
                    1.0
                };
                let (c1, c2) = (1.0 - b1.powi(step), 1.0 - b2.powi(step));
                let update = &*m * (lr / c1) / ((&*v / c2).sqrt() + eps);
                expected[i] = &expected[i] * decay - update;
                let close = params[i].allclose(&expected[i], 1e-5, 1e-6, false);
                assert!(close, "parameter {i}, step {step}");
            }
        }
        assert_eq!(optimizer.scalar("step/dw"), Some(4.0));
    }

    /// The dynamic loss scale: a clean step unscales the gradients (the update equals the
    /// unscaled one) and counts; an overflowing (inf or NaN) step is skipped and halves the
    /// scale.
    #[test]
    fn loss_scaling_unscales_and_skips_overflowing_steps() {
        let cfg = OptimizerConfig {
            momentum: 0.0,
            weight_decay: 0.0,
            ..OptimizerConfig::mfnet_paper()
        };
        let vs = VarStore::new(Device::Cpu);
        let w = vs
            .root()
            .var_copy("w", &Tensor::from_slice(&[1.0f32, -2.0]));
        let mut optimizer = Optimizer::new(&cfg);
        optimizer.set_loss_scaling(true);
        assert_eq!(optimizer.loss_scale(), INITIAL_SCALE);
        // Clean step: grad = 2w, scaled by 2^16 in backward, divided back before the update.
        optimizer.zero_grad(&vs);
        optimizer.scale_loss(&(&w * &w).sum(Kind::Float)).backward();
        optimizer.step(&vs, 0.25);
        assert_close(&Vec::<f32>::try_from(&w).unwrap(), &[0.5, -1.0]);
        assert_eq!(optimizer.loss_scale(), INITIAL_SCALE);
        assert_eq!(optimizer.scalar(GROWTH_KEY), Some(1.0));
        // Overflow: an infinite, then a NaN gradient skips the update and halves the scale.
        for (bad, scale) in [(f64::INFINITY, 0.5), (f64::NAN, 0.25)] {
            optimizer.zero_grad(&vs);
            optimizer
                .scale_loss(&(&w * bad).sum(Kind::Float))
                .backward();
            optimizer.step(&vs, 0.25);
            assert_close(&Vec::<f32>::try_from(&w).unwrap(), &[0.5, -1.0]);
            assert_eq!(optimizer.loss_scale(), INITIAL_SCALE * scale);
            assert_eq!(optimizer.scalar(GROWTH_KEY), Some(0.0));
        }
        // The scale is state a checkpoint carries.
        assert!(optimizer.state().contains_key(SCALE_KEY));
        // Without scaling nothing of this exists.
        let plain = Optimizer::new(&cfg);
        assert_eq!(plain.loss_scale(), 1.0);
    }

    /// The scale doubles after SCALE_GROWTH_INTERVAL clean steps in a row.
    #[test]
    fn loss_scale_grows_after_the_interval() {
        let vs = VarStore::new(Device::Cpu);
        let w = vs.root().var_copy("w", &Tensor::from_slice(&[1.0f32]));
        let mut optimizer = Optimizer::new(&OptimizerConfig::mfnet_paper());
        optimizer.set_loss_scaling(true);
        optimizer.set_scalar(GROWTH_KEY, SCALE_GROWTH_INTERVAL - 1.0);
        optimizer.zero_grad(&vs);
        optimizer
            .scale_loss(&(&w * 1.0).sum(Kind::Float))
            .backward();
        optimizer.step(&vs, 0.0);
        assert_eq!(optimizer.loss_scale(), 2.0 * INITIAL_SCALE);
        assert_eq!(optimizer.scalar(GROWTH_KEY), Some(0.0));
    }

    #[test]
    fn running_stats_are_not_trainable() {
        let vs = VarStore::new(Device::Cpu);
        let _bn = nn::batch_norm2d(vs.root() / "bn", 3, Default::default());
        let names: Vec<String> = trainable(&vs).into_iter().map(|(n, _)| n).collect();
        assert_eq!(names, vec!["bn.bias".to_string(), "bn.weight".to_string()]);
    }
}
