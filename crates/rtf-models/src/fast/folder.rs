//! How a network folds: [`Fold`] builds a new, inference-only value from a trained one, as a
//! [`Folder`] says (precision, layout, kernels, and whether the plain weights are released as
//! their units fold).

use rtf_amp::PrecisionOnDevice;
use std::collections::HashMap;

use tch::{Device, Kind, Tensor};

use super::{FoldOptions, InferenceKernels, Layout};

/// A module's inference form, built anew from it: its convolutions folded
/// ([`crate::fast::unit::FoldedConv`]), everything else shared with it.
pub trait Fold {
    fn folded(&self, folder: &Folder) -> Self;
}

impl<T: Fold> Fold for Vec<T> {
    fn folded(&self, folder: &Folder) -> Self {
        self.iter().map(|u| u.folded(folder)).collect()
    }
}

impl<T: Fold> Fold for Option<T> {
    fn folded(&self, folder: &Folder) -> Self {
        self.as_ref().map(|u| u.folded(folder))
    }
}

impl<T: Fold> Fold for Box<T> {
    fn folded(&self, folder: &Folder) -> Self {
        Box::new((**self).folded(folder))
    }
}

/// The fold's settings, and the plain variables it may free as units fold.
#[derive(Debug)]
pub struct Folder<'a> {
    options: FoldOptions,
    /// Each releasable variable's holders before the fold, by the address of its data
    /// ([`crate::release::PlainWeights`]); `None`: nothing is released.
    release: Option<&'a HashMap<usize, (i64, i64)>>,
}

impl<'a> Folder<'a> {
    /// A fold as `options` say that frees nothing.
    pub fn new(options: &FoldOptions) -> Self {
        Self {
            options: *options,
            release: None,
        }
    }

    /// A fold that frees each unit's plain tensors once it has folded, where `recorded` lists
    /// them as held before the fold (so nothing that took a handle since is freed).
    pub(crate) fn releasing(
        options: &FoldOptions,
        recorded: &'a HashMap<usize, (i64, i64)>,
    ) -> Self {
        Self {
            options: *options,
            release: Some(recorded),
        }
    }

    pub fn options(&self) -> &FoldOptions {
        &self.options
    }

    /// The type the folded weights and maps are in (Float, BFloat16 or Half).
    pub fn kind(&self) -> Kind {
        self.options.precision.kind()
    }

    pub fn channels_last(&self) -> bool {
        self.options.layout == Layout::ChannelsLast
    }

    pub fn kernels(&self) -> &InferenceKernels {
        &self.options.kernels
    }

    /// Whether a bf16 fold on `device` computes its convolutions with float32 kernels over bf16
    /// maps: a CPU fold in bf16 with [`rtf_amp::Bf16Convolutions::Emulated`] chosen. Where the
    /// CPU has no bf16 arithmetic, oneDNN's bf16 kernels convert every product in generic code,
    /// while fp32 kernels with the casts around them give a bf16 kernel's numbers (bf16
    /// operands, float sums, bf16 output) at about fp32's cost (docs/src/benchmarks.md, "Where
    /// bf16 is emulated").
    pub fn emulates_bf16(&self, device: Device) -> bool {
        self.kind() == Kind::BFloat16
            && device == Device::Cpu
            && self.options.kernels.bf16_convolutions == rtf_amp::Bf16Convolutions::Emulated
    }

    /// Frees those of a folded unit's plain `tensors` that were recorded and are held as
    /// recorded (a no-op for a fold that releases nothing). Call it once the unit's folded
    /// copies are made: nothing reads its plain tensors again.
    pub fn release<'t>(&self, tensors: impl IntoIterator<Item = &'t Tensor>) {
        if let Some(recorded) = self.release {
            crate::release::release_unheld_of(recorded, tensors);
        }
    }
}
