//! Freeing a network's plain weights once the fast path has folded them
//! ([`crate::fast::InferenceNet::releasing_plain_weights`]).
//!
//! Why: the folded path computes its own weights, so without this a fused network keeps both
//! (RTFNet-50: 707 MiB of float32 weights beside its folded copies; docs/src/gpu.md's memory
//! miss in fp16/bf16). Why by holders: a fold may return a variable itself (a float32
//! convolution without BatchNorm, already in its layout) or a view of it, and a network may run
//! a part it does not fold on the plain weights by a handle of its own (CMX's linear layers);
//! a variable that no fold took a handle on is dead weight.
//!
//! Two moments: while folding, each unit frees its own plain tensors as soon as it has folded
//! them ([`crate::fast::folder::Folder::release`], called by [`crate::layers::ConvBnAct`] on a
//! folder made by [`crate::fast::folder::Folder::releasing`]), so the fold never holds
//! two copies of the network; after folding, [`PlainWeights::release_unheld`] frees the rest
//! (BatchNorms folded into a neighbour, parts folded by composition).
//!
//! This module sits below [`crate::layers`] and [`crate::fast`], which both use it.

use std::collections::HashMap;

use tch::Tensor;

use rtf_kernels::aten::tensor_holders;

/// The plain network's variables (weights, biases, BatchNorm statistics) and who held each one
/// before folding: [`record`](Self::record) it before the fold, fold with a folder releasing
/// what it [`recorded`](Self::recorded), then [`release_unheld`](Self::release_unheld).
pub(crate) struct PlainWeights {
    vars: Vec<RecordedVar>,
}

/// A variable (a shallow copy: the same TensorImpl as the VarStore's and the module's), its
/// holders ([`tensor_holders`]) and its bytes when recorded.
struct RecordedVar {
    var: Tensor,
    holders: (i64, i64),
    bytes: i64,
}

/// What a release did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Released {
    /// Variables emptied, and the bytes they held.
    pub variables: usize,
    pub bytes: i64,
    /// Variables the folded path still holds (kept).
    pub kept: usize,
}

impl Released {
    /// [`bytes`](Self::bytes) in MiB.
    pub fn mib(&self) -> f64 {
        self.bytes as f64 / (1024.0 * 1024.0)
    }
}

impl PlainWeights {
    /// Snapshot of `vs`'s variables and their holders, to be taken before folding.
    pub(crate) fn record(vs: &tch::nn::VarStore) -> Self {
        let variables = vs.variables_.lock().unwrap_or_else(|e| e.into_inner());
        let vars = variables
            .named_variables
            .values()
            .map(|t| {
                let var = t.shallow_clone();
                RecordedVar {
                    holders: tensor_holders(&var),
                    bytes: (var.numel() * var.kind().elt_size_in_bytes()) as i64,
                    var,
                }
            })
            .collect();
        Self { vars }
    }

    /// Each recorded variable's holders by the address of its data, for a releasing fold
    /// ([`crate::fast::folder::Folder::releasing`]).
    pub(crate) fn recorded(&self) -> HashMap<usize, (i64, i64)> {
        self.vars
            .iter()
            .filter(|v| v.bytes > 0)
            .map(|v| (v.var.data_ptr() as usize, v.holders))
            .collect()
    }

    /// Empties each variable whose holders are those recorded; keeps the others. Counts what
    /// the units freed while folding too.
    pub(crate) fn release_unheld(self) -> Released {
        let mut released = Released::default();
        for RecordedVar {
            mut var,
            holders,
            bytes,
        } in self.vars
        {
            if tensor_holders(&var) != holders {
                released.kept += 1;
                continue;
            }
            released.variables += 1;
            released.bytes += bytes;
            if var.numel() > 0 {
                empty(&mut var);
            }
        }
        released
    }
}

/// Frees those of `tensors` that `recorded` lists and that are held as recorded: nothing took
/// a handle on them since. A unit's plain tensors, once its folded copies are made.
pub(crate) fn release_unheld_of<'a>(
    recorded: &HashMap<usize, (i64, i64)>,
    tensors: impl IntoIterator<Item = &'a Tensor>,
) {
    for t in tensors {
        let unheld =
            t.numel() > 0 && recorded.get(&(t.data_ptr() as usize)) == Some(&tensor_holders(t));
        if unheld {
            // A handle of our own (after the check, which it would change): `set_data` empties
            // the TensorImpl every handle shares.
            empty(&mut t.shallow_clone());
        }
    }
}

/// Replaces `t`'s data (in every handle on its TensorImpl) by an empty tensor: its memory goes.
fn empty(t: &mut Tensor) {
    let _guard = tch::no_grad_guard();
    t.set_data(&Tensor::empty([0], (t.kind(), t.device())));
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    /// A variable something took a handle on, or a view of, after the record is kept; one
    /// nothing took is emptied, in the VarStore and in every handle on it (a module's).
    #[test]
    fn release_frees_what_nothing_took_and_keeps_what_something_holds() {
        let vs = tch::nn::VarStore::new(Device::Cpu);
        let root = vs.root();
        let module_handle = root.zeros("unheld", &[64, 32]);
        let aliased = root.ones("aliased", &[8]);
        let viewed = root.ones("viewed", &[4, 4]);
        let plain = PlainWeights::record(&vs);
        // What folds do: return the variable itself, or a view of it.
        let fold_alias = aliased.to_kind(Kind::Float);
        let fold_view = viewed.view([-1]);
        let released = plain.release_unheld();
        assert_eq!(
            released,
            Released {
                variables: 1,
                bytes: 64 * 32 * 4,
                kept: 2
            }
        );
        assert_eq!(module_handle.size(), [0]);
        assert_eq!(vs.variables()["unheld"].size(), [0]);
        assert_eq!(fold_alias.sum(Kind::Float).double_value(&[]), 8.0);
        assert_eq!(fold_view.sum(Kind::Float).double_value(&[]), 16.0);
    }

    /// A releasing fold frees a unit's recorded tensors that nothing else took, in every
    /// handle; a tensor something holds, or one not recorded, it keeps.
    #[test]
    fn a_unit_frees_its_own_tensors_only_when_recorded_and_unheld() {
        let vs = tch::nn::VarStore::new(Device::Cpu);
        let root = vs.root();
        let weight = root.ones("weight", &[16, 8]);
        let held = root.ones("held", &[4]);
        let plain = PlainWeights::record(&vs);
        let unrecorded = Tensor::ones([8], (Kind::Float, Device::Cpu));
        let fold_alias = held.shallow_clone();
        let recorded = plain.recorded();
        release_unheld_of(&recorded, [&weight, &held, &unrecorded]);
        assert_eq!(weight.size(), [0]);
        assert_eq!(vs.variables()["weight"].size(), [0]);
        assert_eq!(held.size(), [4]);
        assert_eq!(unrecorded.size(), [8]);
        drop(fold_alias);
        let released = plain.release_unheld();
        assert_eq!(
            released,
            Released {
                variables: 2,
                bytes: (16 * 8 + 4) * 4,
                kept: 0
            }
        );
        assert_eq!(held.size(), [0]);
    }
}
