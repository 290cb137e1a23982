//! The path a network is built under: tch's [`nn::Path`] (where its variables go, under the
//! reference names) with the build's options ([`BuildOptions`]), which every unit built under
//! it keeps. How a network's plain units compute is so a value given when it is built
//! ([`crate::build_with`]), never a setting of the thread or the process that a forward pass
//! reads.

use std::sync::Arc;

use tch::nn;

use rtf_amp::Bf16Convolutions;
use rtf_kernels::winograd::Forms;

use crate::sync_bn::StatsAllReduce;

/// How a network's plain units (its training forward and its plain eval forward) compute. A
/// folded network takes its kernels from its fold instead ([`crate::fast::InferenceKernels`]).
#[derive(Clone)]
pub struct UnitKernels {
    /// The Winograd forms its training convolutions may take (F(4×4, 3×3) where it applies:
    /// [`rtf_kernels::winograd::trains_in_f43`]).
    pub winograd: Forms,
    /// How its convolutions compute in bf16 inside a CPU bf16 autocast region (libtorch's
    /// bf16 kernels, or fp32 kernels over bf16-rounded operands where the CPU has no bf16
    /// arithmetic: [`rtf_amp::Bf16Convolutions`]).
    pub bf16_convolutions: Bf16Convolutions,
    /// Data-parallel training with synchronised BatchNorm: the sum over the ranks its
    /// training-mode BatchNorms take their statistics with ([`crate::sync_bn`]); None: each
    /// process's own batch.
    pub sync: Option<Arc<dyn StatsAllReduce>>,
}

impl Default for UnitKernels {
    /// Every Winograd form, libtorch's bf16 kernels, per-process BatchNorm statistics.
    fn default() -> Self {
        Self {
            winograd: Forms::All,
            bf16_convolutions: Bf16Convolutions::Native,
            sync: None,
        }
    }
}

impl std::fmt::Debug for UnitKernels {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UnitKernels")
            .field("winograd", &self.winograd)
            .field("bf16_convolutions", &self.bf16_convolutions)
            .field("synchronised_batch_norm", &self.sync.is_some())
            .finish()
    }
}

/// What a network is built with besides its configuration.
#[derive(Debug, Clone, Default)]
pub struct BuildOptions {
    /// How its plain units compute.
    pub kernels: UnitKernels,
    /// Its variables left uninitialised (never touched, so the operating system does not even
    /// commit their memory): for counting parameters or reading shapes, where building even
    /// RTFNet-152 then costs next to nothing. Weights loaded afterwards overwrite them.
    pub uninitialised: bool,
}

impl BuildOptions {
    /// The default kernels, variables uninitialised.
    pub fn uninitialised() -> Self {
        Self {
            uninitialised: true,
            ..Self::default()
        }
    }
}

/// A [`nn::Path`] with the options of the build it belongs to; it reads as the `nn::Path` it
/// holds (`p.var(…)`, `&p / "conv1"`).
#[derive(Debug, Clone)]
pub struct Path<'a> {
    nn: nn::Path<'a>,
    options: Arc<BuildOptions>,
}

impl<'a> Path<'a> {
    pub fn new(nn: nn::Path<'a>, options: &BuildOptions) -> Self {
        Self {
            nn,
            options: Arc::new(options.clone()),
        }
    }

    /// The tch path (for tch's own layers).
    pub fn nn(&self) -> &nn::Path<'a> {
        &self.nn
    }

    pub fn options(&self) -> &BuildOptions {
        &self.options
    }

    pub fn kernels(&self) -> &UnitKernels {
        &self.options.kernels
    }

    /// The sub-path `name`, with the same options.
    pub fn sub<T: ToString>(&self, name: T) -> Path<'a> {
        Path {
            nn: self.nn.sub(name),
            options: Arc::clone(&self.options),
        }
    }
}

/// A path of a build with the default options.
impl<'a> From<nn::Path<'a>> for Path<'a> {
    fn from(nn: nn::Path<'a>) -> Self {
        Self::new(nn, &BuildOptions::default())
    }
}

impl<'a> std::ops::Deref for Path<'a> {
    type Target = nn::Path<'a>;
    fn deref(&self) -> &nn::Path<'a> {
        &self.nn
    }
}

/// tch's own layers (`nn::conv`, …) take it as the `nn::Path` it holds.
impl<'a> std::borrow::Borrow<nn::Path<'a>> for Path<'a> {
    fn borrow(&self) -> &nn::Path<'a> {
        &self.nn
    }
}

impl<'a, T: ToString> std::ops::Div<T> for &Path<'a> {
    type Output = Path<'a>;
    fn div(self, name: T) -> Path<'a> {
        self.sub(name)
    }
}

impl<'a, T: ToString> std::ops::Div<T> for Path<'a> {
    type Output = Path<'a>;
    fn div(self, name: T) -> Path<'a> {
        self.sub(name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sub_paths_name_variables_as_tch_and_keep_the_options() {
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let root = Path::new(vs.root(), &BuildOptions::uninitialised());
        let p = &(&root / "layer1") / 0;
        let _w = p.sub("conv1").var("weight", &[2, 3], nn::Init::Const(0.0));
        assert!(p.options().uninitialised);
        assert!(vs.variables().contains_key("layer1.0.conv1.weight"));
        assert!(!Path::from(vs.root()).options().uninitialised);
    }
}
