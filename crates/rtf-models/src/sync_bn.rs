//! Synchronised BatchNorm for data-parallel training (`torch.nn.SyncBatchNorm`, Peng et al.,
//! "MegDet", CVPR 2018): in training mode every [`BatchNorm`] normalises with the mean and
//! variance of the *whole* data-parallel batch, all ranks' shards together, and updates its
//! running statistics with them, so that N processes of batch b train like one process of
//! batch N·b (the default, as in PyTorch DDP, is per-rank statistics).
//!
//! The networks need no change: every BatchNorm of rtf-models is a [`BatchNorm`], made by
//! [`crate::layers::bn2d_with`] with the [`StatsAllReduce`] its build gives
//! ([`crate::layers::UnitKernels::sync`]: the trainer's data-parallel group when the run asks
//! for synchronised BatchNorm), which sums its statistics over the ranks. The sum must be
//! differentiable (its backward sums the gradients over the ranks too), which is how the
//! gradient of one rank's samples reaches the others through the shared statistics.

use std::sync::Arc;

use tch::nn::{self, ModuleT};
use tch::{Kind, Tensor};

use crate::bn_defaults::BN_MOMENTUM;

/// A differentiable sum over every process of a data-parallel job.
pub trait StatsAllReduce: Send + Sync {
    /// Σ over the ranks of `t` (same shape on every rank), in the autograd graph: the backward
    /// sums the gradient over the ranks. On a failed collective, return `t` itself and keep the
    /// error for the trainer, which stops after the step (a forward cannot return an error).
    fn all_reduce_sum(&self, t: &Tensor) -> Tensor;
}

/// BatchNorm (tch's, with its variables under the reference names, momentum
/// [`BN_MOMENTUM`], eps [`crate::bn_defaults::BN_EPS`] unless a network sets its own) that
/// synchronises its training-mode statistics over the ranks where built with a
/// [`StatsAllReduce`]. Made by [`crate::layers::bn2d`].
pub struct BatchNorm {
    inner: nn::BatchNorm,
    /// tch keeps its layer's eps private; folding and synchronising need it.
    eps: f64,
    /// The sum over the ranks its training-mode statistics take (None: this process's own).
    sync: Option<Arc<dyn StatsAllReduce>>,
}

impl std::fmt::Debug for BatchNorm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BatchNorm")
            .field("inner", &self.inner)
            .field("eps", &self.eps)
            .field("synchronised", &self.sync.is_some())
            .finish()
    }
}

impl BatchNorm {
    /// `inner`, made with `eps`, its training-mode statistics summed by `sync` if given.
    pub(crate) fn new(
        inner: nn::BatchNorm,
        eps: f64,
        sync: Option<Arc<dyn StatsAllReduce>>,
    ) -> Self {
        Self { inner, eps, sync }
    }

    /// The eps added to the variance.
    pub fn eps(&self) -> f64 {
        self.eps
    }

    /// Its tensors (running statistics, affine), for the fast path's release of what a fold
    /// has taken in ([`crate::release`]).
    pub(crate) fn tensors(&self) -> Vec<&Tensor> {
        let bn = &self.inner;
        let mut tensors = vec![&bn.running_mean, &bn.running_var];
        tensors.extend(bn.ws.as_ref());
        tensors.extend(bn.bs.as_ref());
        tensors
    }
}

impl std::ops::Deref for BatchNorm {
    type Target = nn::BatchNorm;
    fn deref(&self) -> &nn::BatchNorm {
        &self.inner
    }
}

impl ModuleT for BatchNorm {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        match &self.sync {
            Some(reduce) if train => synchronised(self, xs, &**reduce),
            _ => self.inner.forward_t(xs, train),
        }
    }
}

/// Training-mode BatchNorm over the whole data-parallel batch. Two passes, as a single
/// process computes them (mean, then the mean squared deviation), each summed over the ranks,
/// in fp32 whatever the input's precision; running statistics take the unbiased variance with
/// the layer's momentum, as `torch.nn.SyncBatchNorm`.
// `x = x * y` on tensors, not `x *= y`: the compound forms are in-place ops, which autograd
// cannot differentiate through.
#[allow(clippy::assign_op_pattern)]
fn synchronised(bn: &BatchNorm, xs: &Tensor, reduce: &dyn StatsAllReduce) -> Tensor {
    let c = bn.running_mean.size()[0];
    // Per-channel shape for broadcasting: [1, C, 1, ...].
    let mut shape = vec![1i64; xs.dim()];
    shape[1] = c;
    let reduced: Vec<i64> = (0..xs.dim() as i64).filter(|&d| d != 1).collect();
    let x = xs.to_kind(Kind::Float);
    let local = (x.numel() as i64 / c) as f64;
    // [C] sums + the count: one all-reduce for the mean.
    let sum_count = Tensor::cat(
        &[
            x.sum_dim_intlist(reduced.as_slice(), false, Kind::Float),
            Tensor::from_slice(&[local as f32]).to_device(x.device()),
        ],
        0,
    );
    let sum_count = reduce.all_reduce_sum(&sum_count);
    let count = sum_count.narrow(0, c, 1);
    let mean = sum_count.narrow(0, 0, c) / &count;
    let centred = &x - mean.view(shape.as_slice());
    let squares = centred
        .square()
        .sum_dim_intlist(reduced.as_slice(), false, Kind::Float);
    let var = reduce.all_reduce_sum(&squares) / &count;
    tch::no_grad(|| {
        let n = count.double_value(&[0]);
        let momentum = BN_MOMENTUM;
        let unbiased = &var * (n / (n - 1.0).max(1.0));
        let mut running_mean = bn.running_mean.shallow_clone();
        let mut running_var = bn.running_var.shallow_clone();
        running_mean.copy_(&(&running_mean * (1.0 - momentum) + mean.detach() * momentum));
        running_var.copy_(&(&running_var * (1.0 - momentum) + unbiased.detach() * momentum));
    });
    let mut ys = centred * (var + bn.eps).rsqrt().view(shape.as_slice());
    if let Some(w) = &bn.ws {
        ys = ys * w.view(shape.as_slice());
    }
    if let Some(b) = &bn.bs {
        ys = ys + b.view(shape.as_slice());
    }
    ys.to_kind(xs.kind())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    /// One process: the sum over the ranks is the identity.
    struct Alone;
    impl StatsAllReduce for Alone {
        fn all_reduce_sum(&self, t: &Tensor) -> Tensor {
            t.shallow_clone()
        }
    }

    /// A BatchNorm of 3 channels, synchronised (over one rank) where `sync`.
    fn layer(vs: &nn::VarStore, sync: bool) -> BatchNorm {
        let options = crate::layers::BuildOptions {
            kernels: crate::layers::UnitKernels {
                sync: sync.then(|| Arc::new(Alone) as Arc<dyn StatsAllReduce>),
                ..Default::default()
            },
            uninitialised: false,
        };
        let bn = crate::layers::bn2d_init(
            crate::layers::Path::new(vs.root(), &options) / "bn",
            3,
            nn::Init::Randn {
                mean: 1.0,
                stdev: 0.3,
            },
        );
        tch::no_grad(|| {
            let _ = bn.bs.as_ref().unwrap().shallow_clone().fill_(0.2);
        });
        bn
    }

    /// With one rank the synchronised path is ordinary training-mode BatchNorm: output,
    /// gradients of the input and the affine parameters, and running statistics.
    #[test]
    fn one_rank_synchronised_batch_norm_equals_batch_norm() {
        tch::manual_seed(4);
        let x = Tensor::randn([4, 3, 5, 6], (Kind::Float, Device::Cpu)) * 3.0 + 1.5;
        // Both runs get the same affine weights by copy: the global generator is shared with
        // the tests running beside this one, so reseeding it would not make them equal.
        let gamma = Tensor::from_slice(&[0.8f32, 1.1, 1.3]);
        let run = |sync: bool| {
            let vs = nn::VarStore::new(Device::Cpu);
            let bn = layer(&vs, sync);
            tch::no_grad(|| bn.ws.as_ref().unwrap().shallow_clone().copy_(&gamma));
            let x = x.copy().set_requires_grad(true);
            let y = bn.forward_t(&x, true);
            (y.square() * x.ones_like().cumsum(3, Kind::Float))
                .sum(Kind::Float)
                .backward();
            let eval = bn.forward_t(&x, false);
            (
                y.detach(),
                x.grad(),
                bn.ws.as_ref().unwrap().grad(),
                eval.detach(),
            )
        };
        let (a, b) = (run(false), run(true));
        let close = |u: &Tensor, v: &Tensor| (u - v).abs().max().double_value(&[]);
        assert!(close(&a.0, &b.0) < 1e-5, "outputs {}", close(&a.0, &b.0));
        assert!(
            close(&a.1, &b.1) < 1e-4,
            "input gradients {}",
            close(&a.1, &b.1)
        );
        assert!(
            close(&a.2, &b.2) < 1e-3,
            "weight gradients {}",
            close(&a.2, &b.2)
        );
        // Eval mode reads the running statistics the training forward updated.
        assert!(
            close(&a.3, &b.3) < 1e-5,
            "running statistics {}",
            close(&a.3, &b.3)
        );
    }
}
