//! rtf-kernels: the compute kernels rtf's networks (rtf-models) are built on, and nothing of
//! the networks themselves.
//!
//! - [`aten`]: the C++ shim over libtorch (`csrc/ops.cpp`): operators tch does not bind as
//!   needed, the fused SGD step, tensor holder counts and the operator counter;
//! - [`onednn`]: convolutions with their activation and residual add fused in, through the
//!   oneDNN entry points libtorch exports;
//! - [`winograd`]: 3×3 convolutions by Winograd's minimal filtering, inference and training;
//! - [`phases`]: the interleave of an upsampling convolution's output phases;
//! - [`geometry`]: a 2-D convolution's stride, padding, dilation and groups;
//! - [`layout`]: channels-last layout of 4-D maps;
//! - [`allocator`]: the process allocator's policy for tensor work;
//!
//! Which kernel a network takes is decided by the caller and passed in (rtf-models'
//! `fast::InferenceKernels`); nothing here reads the environment.

pub mod allocator;
pub mod aten;
pub mod geometry;
pub mod layout;
pub mod onednn;
pub mod phases;
pub mod winograd;
