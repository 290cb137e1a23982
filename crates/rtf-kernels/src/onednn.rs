//! Convolutions with their activation (and a residual add) fused in, through the oneDNN entry
//! points libtorch exports for its own compiler (the `aoti_torch_cpu_mkldnn_*` C functions,
//! which run `mkldnn::_convolution_pointwise`): the convolution kernel applies them as it writes
//! each output block, so the separate passes over the output map disappear.
//!
//! CPU tensors only. The entry points are looked up when first needed; where libtorch lacks
//! them (builds without oneDNN) or refuses a call, the functions return `None` and callers
//! take the plain path, and a refused entry point stays off for the rest of the process
//! (libtorch logs why, once).

use std::ffi::{c_char, c_void, CStr};
use std::ptr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::OnceLock;

use tch::{Device, Tensor};
use torch_sys::C_tensor;

type Handle = *mut C_tensor;
/// libtorch's `AOTITorchError`: 0 on success.
type Status = i32;

/// `aoti_torch_cpu_mkldnn__convolution_pointwise` (shim_cpu.h).
type ConvPointwise = unsafe extern "C" fn(
    x: Handle,
    w: Handle,
    b: *mut Handle,
    padding: *const i64,
    padding_len: i64,
    stride: *const i64,
    stride_len: i64,
    dilation: *const i64,
    dilation_len: i64,
    groups: i64,
    attr: *const c_char,
    scalars: *const *const f64,
    scalars_len: i64,
    algorithm: *const *const c_char,
    ret0: *mut Handle,
) -> Status;

/// `aoti_torch_cpu_mkldnn__convolution_pointwise_binary`.
type ConvPointwiseBinary = unsafe extern "C" fn(
    x: Handle,
    other: Handle,
    w: Handle,
    b: *mut Handle,
    padding: *const i64,
    padding_len: i64,
    stride: *const i64,
    stride_len: i64,
    dilation: *const i64,
    dilation_len: i64,
    groups: i64,
    binary_attr: *const c_char,
    alpha: *mut f64,
    unary_attr: *const *const c_char,
    unary_scalars: *const *const f64,
    unary_scalars_len: i64,
    unary_algorithm: *const *const c_char,
    ret0: *mut Handle,
) -> Status;

/// One libtorch entry point, looked up at run time (libtorch builds without oneDNN lack it,
/// and rtf must still link and run there), and turned off after its first refusal so a
/// failing call is not retried on every frame.
struct Entry<F> {
    function: Option<F>,
    refused: AtomicBool,
}

impl<F: Copy> Entry<F> {
    fn lookup(name: &CStr) -> Self {
        // SAFETY: dlsym with RTLD_DEFAULT searches the libraries already loaded (libtorch_cpu
        // is linked in); a non-null result is that exported C function, whose signature `F`
        // restates from libtorch's shim_cpu.h.
        let address = unsafe { libc::dlsym(libc::RTLD_DEFAULT, name.as_ptr()) };
        let function = (!address.is_null())
            .then(|| unsafe { std::mem::transmute_copy::<*mut c_void, F>(&address) });
        Self {
            function,
            refused: AtomicBool::new(false),
        }
    }

    fn get(&self) -> Option<F> {
        self.function
            .filter(|_| !self.refused.load(Ordering::Relaxed))
    }

    /// Wraps a call's outcome; a refusal turns the entry off.
    fn finish(&self, status: Status, out: Handle) -> Option<Tensor> {
        if status != 0 || out.is_null() {
            // In this crate's unit tests every call is tried: tests run in parallel threads of
            // one process, and one test's refused geometry must not turn the path off for the
            // test that checks the fused kernel.
            if !cfg!(test) {
                self.refused.store(true, Ordering::Relaxed);
            }
            return None;
        }
        // SAFETY: on success libtorch hands over a new `at::Tensor*`, owned from here on.
        Some(unsafe { Tensor::from_ptr(out) })
    }
}

struct Entries {
    conv: Entry<ConvPointwise>,
    conv_binary: Entry<ConvPointwiseBinary>,
}

fn entries() -> &'static Entries {
    static ENTRIES: OnceLock<Entries> = OnceLock::new();
    ENTRIES.get_or_init(|| Entries {
        conv: Entry::lookup(c"aoti_torch_cpu_mkldnn__convolution_pointwise"),
        conv_binary: Entry::lookup(c"aoti_torch_cpu_mkldnn__convolution_pointwise_binary"),
    })
}

/// The activation a fused convolution applies to its output.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PostOp {
    None,
    Relu,
    LeakyRelu(f64),
    /// The exact (erf) GELU.
    Gelu,
}

impl PostOp {
    fn attr(self) -> &'static CStr {
        match self {
            PostOp::None => c"none",
            PostOp::Relu => c"relu",
            PostOp::LeakyRelu(_) => c"leaky_relu",
            PostOp::Gelu => c"gelu",
        }
    }
    /// The post-op's algorithm argument: libtorch reads one for GELU only ("none": erf, as
    /// opposed to "tanh").
    fn algorithm(self) -> Option<&'static CStr> {
        match self {
            PostOp::Gelu => Some(c"none"),
            _ => None,
        }
    }
    fn scalar(self) -> Option<f64> {
        match self {
            PostOp::LeakyRelu(slope) => Some(slope),
            _ => None,
        }
    }
}

pub use crate::geometry::Geometry;

/// The arguments every fused call shares, as the C functions take them.
struct Args {
    padding: [i64; 2],
    stride: [i64; 2],
    dilation: [i64; 2],
    groups: i64,
    /// `post_op`'s scalar (LeakyReLU slope), pointed to by `scalars`.
    scalar: Option<f64>,
    attr: &'static CStr,
}

impl Args {
    fn new(geometry: Geometry, post_op: PostOp) -> Self {
        Self {
            padding: [geometry.padding; 2],
            stride: [geometry.stride; 2],
            dilation: [geometry.dilation; 2],
            groups: geometry.groups,
            scalar: post_op.scalar(),
            attr: post_op.attr(),
        }
    }
    fn attr(&self) -> *const c_char {
        self.attr.as_ptr()
    }
    /// The array of optional scalars (one pointer, or none).
    fn scalars(&self) -> ([*const f64; 1], i64) {
        match &self.scalar {
            Some(s) => ([s as *const f64], 1),
            None => ([ptr::null()], 0),
        }
    }
}

/// An optional tensor argument: a pointer to its handle, or null.
fn optional(tensor: Option<&Tensor>, slot: &mut Handle) -> *mut Handle {
    match tensor {
        Some(t) => {
            *slot = t.as_ptr() as Handle;
            slot
        }
        None => ptr::null_mut(),
    }
}

/// `weight` (a dense float or bf16 convolution weight [c_out, c_in/groups, k, k] on the CPU)
/// reordered once into oneDNN's blocked layout, for [`conv_with_post_op`] and
/// [`conv_add_with_post_op`]: given a dense weight, each of their calls reorders it first,
/// most costly for the widest kernels. `None` for transposed convolutions, 1×1 kernels
/// (packed without the input's size, oneDNN picks a layout its 1×1 kernels then reorder
/// again, slower than the dense weight), other devices, or where libtorch refuses (no oneDNN);
/// callers then keep the dense weight. Measurements: docs/src/models.md, "Weights packed
/// once".
/// The packed tensor is an MKLDNN tensor: only the fused entry points above take it
/// ([`dense_weight`] gives the dense form back).
pub fn pack_weight(weight: &Tensor, geometry: Geometry) -> Option<Tensor> {
    let size = weight.size();
    let one_by_one = size.len() == 4 && size[2] == 1 && size[3] == 1;
    if weight.device() != Device::Cpu || geometry.transposed || one_by_one || size.len() != 4 {
        return None;
    }
    let pair = |v: i64| [v, v];
    let (padding, stride, dilation) = (
        pair(geometry.padding),
        pair(geometry.stride),
        pair(geometry.dilation),
    );
    let mut out: Handle = ptr::null_mut();
    // SAFETY: `weight.as_ptr()` is a live `at::Tensor*` for the call; the arrays hold the two
    // values the shim reads; on success `out` is a new `at::Tensor*` owned from here on, on
    // failure the shim's malloc'd message is freed here.
    unsafe {
        let error = crate::aten::ffi::rtf_pack_conv_weight(
            weight.as_ptr() as Handle,
            padding.as_ptr(),
            stride.as_ptr(),
            dilation.as_ptr(),
            geometry.groups,
            &mut out,
        );
        if !error.is_null() {
            crate::aten::ffi::rtf_ops_free_error(error);
            return None;
        }
        (!out.is_null()).then(|| Tensor::from_ptr(out))
    }
}

/// The dense form of a weight [`pack_weight`] may have packed (a copy if it did).
pub fn dense_weight(weight: &Tensor) -> Tensor {
    if weight.is_mkldnn() {
        weight.to_dense(None, false)
    } else {
        weight.shallow_clone()
    }
}

/// `post_op(conv(xs, weight) + bias)` in one oneDNN primitive, or `None` where the fused path
/// is unavailable (not CPU, a transposed convolution, a libtorch without it, or libtorch
/// refused the call).
pub fn conv_with_post_op(
    xs: &Tensor,
    weight: &Tensor,
    bias: Option<&Tensor>,
    geometry: Geometry,
    post_op: PostOp,
) -> Option<Tensor> {
    if xs.device() != Device::Cpu || geometry.transposed {
        return None;
    }
    let args = Args::new(geometry, post_op);
    let (scalars, scalars_len) = args.scalars();
    let algorithm: Option<*const c_char> = post_op.algorithm().map(CStr::as_ptr);
    let mut bias_slot: Handle = ptr::null_mut();
    let bias = optional(bias, &mut bias_slot);
    let mut out: Handle = ptr::null_mut();
    let entry = &entries().conv;
    let f = entry.get()?;
    let a = &args;
    // SAFETY: the handles are live `at::Tensor*` owned by `xs`, `weight` and the bias for the
    // call's duration (libtorch only reads them); every array outlives the call.
    let status = unsafe {
        f(
            xs.as_ptr() as Handle,
            weight.as_ptr() as Handle,
            bias,
            a.padding.as_ptr(),
            2,
            a.stride.as_ptr(),
            2,
            a.dilation.as_ptr(),
            2,
            a.groups,
            a.attr(),
            scalars.as_ptr(),
            scalars_len,
            algorithm
                .as_ref()
                .map_or(ptr::null(), |a| a as *const *const c_char),
            &mut out,
        )
    };
    entry.finish(status, out)
}

/// `post_op(conv(xs, weight) + bias + other)` in one oneDNN primitive (a residual add), or
/// `None` as [`conv_with_post_op`]. libtorch fuses no activation but ReLU after the add, and
/// no transposed convolution: `None` for those too.
pub fn conv_add_with_post_op(
    xs: &Tensor,
    other: &Tensor,
    weight: &Tensor,
    bias: Option<&Tensor>,
    geometry: Geometry,
    post_op: PostOp,
) -> Option<Tensor> {
    let unary_attr: *const c_char = match post_op {
        PostOp::None => ptr::null(),
        PostOp::Relu => c"relu".as_ptr(),
        PostOp::LeakyRelu(_) | PostOp::Gelu => return None,
    };
    if xs.device() != Device::Cpu || geometry.transposed {
        return None;
    }
    let entry = &entries().conv_binary;
    let f = entry.get()?;
    let args = Args::new(geometry, post_op);
    let mut bias_slot: Handle = ptr::null_mut();
    let bias = optional(bias, &mut bias_slot);
    let mut out: Handle = ptr::null_mut();
    let a = &args;
    // SAFETY: as in `conv_with_post_op`; `other` is read only ("add", not the in-place "sum").
    let status = unsafe {
        f(
            xs.as_ptr() as Handle,
            other.as_ptr() as Handle,
            weight.as_ptr() as Handle,
            bias,
            a.padding.as_ptr(),
            2,
            a.stride.as_ptr(),
            2,
            a.dilation.as_ptr(),
            2,
            a.groups,
            c"add".as_ptr(),
            ptr::null_mut(),
            if unary_attr.is_null() {
                ptr::null()
            } else {
                &unary_attr
            },
            ptr::null(),
            0,
            ptr::null(),
            &mut out,
        )
    };
    entry.finish(status, out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::to_channels_last;
    use tch::Kind;

    #[test]
    fn fused_convolutions_equal_convolution_then_activation() {
        let opts = (Kind::Float, Device::Cpu);
        let x = Tensor::randn([2, 6, 10, 14], opts);
        let w = Tensor::randn([5, 6, 3, 3], opts);
        let b = Tensor::randn([5], opts);
        let wt = Tensor::randn([6, 5, 2, 2], opts);
        let residual = Tensor::randn([2, 5, 10, 14], opts);
        let residual_before = residual.copy();
        for channels_last in [true, false] {
            let lay = |t: &Tensor| {
                if channels_last {
                    to_channels_last(t)
                } else {
                    t.shallow_clone()
                }
            };
            let (xl, wl, wtl) = (lay(&x), lay(&w), lay(&wt));
            for (post_op, act) in [
                (
                    PostOp::None,
                    Box::new(|t: Tensor| t) as Box<dyn Fn(Tensor) -> Tensor>,
                ),
                (PostOp::Relu, Box::new(|t: Tensor| t.relu())),
                (
                    PostOp::LeakyRelu(0.2),
                    Box::new(|t: Tensor| t.maximum(&(&t * 0.2))),
                ),
                (PostOp::Gelu, Box::new(|t: Tensor| t.gelu("none"))),
            ] {
                let plain = act(x.conv2d(&w, Some(&b), [1], [2], [2], 1));
                let fused = conv_with_post_op(
                    &xl,
                    &wl,
                    Some(&b),
                    Geometry::ungrouped(1, 2, 2, false),
                    post_op,
                )
                .expect("this libtorch has the fused convolution");
                assert!(plain.allclose(&fused, 1e-4, 1e-4, false), "{post_op:?}");

                // Transposed convolutions are left to the plain path.
                assert!(conv_with_post_op(
                    &xl,
                    &wtl,
                    None,
                    Geometry::ungrouped(2, 0, 1, true),
                    post_op
                )
                .is_none());

                let plain = act(x.conv2d(&w, Some(&b), [1], [1], [1], 1) + &residual);
                let fused = conv_add_with_post_op(
                    &xl,
                    &lay(&residual),
                    &wl,
                    Some(&b),
                    Geometry::ungrouped(1, 1, 1, false),
                    post_op,
                );
                match (post_op, fused) {
                    (PostOp::LeakyRelu(_) | PostOp::Gelu, fused) => assert!(fused.is_none()),
                    (_, Some(fused)) => {
                        assert!(plain.allclose(&fused, 1e-4, 1e-4, false), "{post_op:?}")
                    }
                    (_, None) => panic!("this libtorch has the fused convolution with an add"),
                }
            }
        }
        // The residual is read, not written (the NCHW round passed it itself).
        assert!(residual.equal(&residual_before));
    }
}
