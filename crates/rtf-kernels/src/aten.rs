//! ATen operators rtf needs that tch 0.26 does not bind as needed, through the C++ shim
//! `csrc/ops.cpp`: LeakyReLU with its slope, the emulated bf16 convolution, the fused SGD
//! and AdamW steps, gradient zeroing, tensor holder counts and the operator counter.

use tch::Tensor;

use crate::geometry::Geometry;

pub(crate) mod ffi {
    use std::ffi::{c_char, c_int};
    extern "C" {
        pub fn rtf_leaky_relu(
            x: *mut torch_sys::C_tensor,
            slope: f64,
            in_place: c_int,
            out: *mut *mut torch_sys::C_tensor,
        ) -> *mut c_char;
        pub fn rtf_bf16_emulated_convolution(
            x: *mut torch_sys::C_tensor,
            w: *mut torch_sys::C_tensor,
            b: *mut torch_sys::C_tensor,
            stride: *const i64,
            padding: *const i64,
            dilation: *const i64,
            transposed: c_int,
            output_padding: *const i64,
            groups: i64,
            out: *mut *mut torch_sys::C_tensor,
        ) -> *mut c_char;
        pub fn rtf_fused_sgd(
            params: *const *mut torch_sys::C_tensor,
            grads: *const *mut torch_sys::C_tensor,
            bufs: *const *mut torch_sys::C_tensor,
            n: i64,
            weight_decay: f64,
            momentum: f64,
            lr: f64,
            is_first_step: c_int,
        ) -> *mut c_char;
        pub fn rtf_fused_adamw(
            params: *const *mut torch_sys::C_tensor,
            grads: *const *mut torch_sys::C_tensor,
            exp_avgs: *const *mut torch_sys::C_tensor,
            exp_avg_sqs: *const *mut torch_sys::C_tensor,
            steps: *const *mut torch_sys::C_tensor,
            n: i64,
            lr: f64,
            beta1: f64,
            beta2: f64,
            weight_decay: f64,
            eps: f64,
        ) -> *mut c_char;
        pub fn rtf_zero_grads(params: *const *mut torch_sys::C_tensor, n: i64) -> *mut c_char;
        pub fn rtf_pack_conv_weight(
            w: *mut torch_sys::C_tensor,
            padding: *const i64,
            stride: *const i64,
            dilation: *const i64,
            groups: i64,
            out: *mut *mut torch_sys::C_tensor,
        ) -> *mut c_char;
        pub fn rtf_winograd43_conv(
            x: *mut torch_sys::C_tensor,
            u: *mut torch_sys::C_tensor,
            b: *mut torch_sys::C_tensor,
            residual: *mut torch_sys::C_tensor,
            relu: c_int,
            out: *mut *mut torch_sys::C_tensor,
        ) -> *mut c_char;
        pub fn rtf_winograd43_train_conv(
            x: *mut torch_sys::C_tensor,
            w: *mut torch_sys::C_tensor,
            g: *mut torch_sys::C_tensor,
            out: *mut *mut torch_sys::C_tensor,
        ) -> *mut c_char;
        pub fn rtf_tensor_holders(
            t: *mut torch_sys::C_tensor,
            handles: *mut i64,
            storage_users: *mut i64,
        ) -> *mut c_char;
        pub fn rtf_op_counter_start(handle: *mut u64) -> *mut c_char;
        pub fn rtf_op_counter_stop(handle: u64, table: *mut *mut c_char) -> *mut c_char;
        pub fn rtf_ops_free_error(error: *mut c_char);
    }
}

/// Panics with the shim's message if `error` is not null (a failure is a programming error, as
/// in tch's own ops).
///
/// # Safety
/// `error` is null or a NUL-terminated string the shim malloc'd (read once, freed here).
pub(crate) unsafe fn check(op: &str, error: *mut std::ffi::c_char) {
    if !error.is_null() {
        // SAFETY: per the contract above.
        let message = unsafe {
            let m = std::ffi::CStr::from_ptr(error)
                .to_string_lossy()
                .into_owned();
            ffi::rtf_ops_free_error(error);
            m
        };
        panic!("{op}: {message}");
    }
}

/// Takes a shim's result: the new tensor in `out`, or panics with the shim's message.
///
/// # Safety
/// As [`check`]; on success, `out` is a new heap `at::Tensor*` the shim made, which the
/// returned `Tensor` then owns (tch deletes it).
pub(crate) unsafe fn shim_result(
    op: &str,
    error: *mut std::ffi::c_char,
    out: *mut torch_sys::C_tensor,
) -> Tensor {
    // SAFETY: per the contract above.
    unsafe {
        check(op, error);
        Tensor::from_ptr(out)
    }
}

/// ATen's `leaky_relu(x, slope)` (one pass forward, one backward; tch's binding fixes the
/// slope at 0.01), through csrc/ops.cpp; differentiable. With `in_place` it overwrites `xs`,
/// which autograd allows when nothing saved `xs` for its backward (BatchNorm's and a
/// convolution's outputs: their backwards read their inputs).
pub fn aten_leaky_relu(xs: &Tensor, slope: f64, in_place: bool) -> Tensor {
    let mut out: *mut torch_sys::C_tensor = std::ptr::null_mut();
    // SAFETY: `as_ptr` is a live `at::Tensor*` for the call; the shim's result is taken as
    // `shim_result` requires.
    unsafe {
        let error = ffi::rtf_leaky_relu(
            xs.as_ptr() as *mut torch_sys::C_tensor,
            slope,
            in_place as std::ffi::c_int,
            &mut out,
        );
        shim_result("leaky_relu", error, out)
    }
}

/// The bf16 convolution of `xs` with `weight` (+ `bias`), computed by fp32 kernels over
/// bf16-rounded operands, its output and operand gradients rounded to bf16: a native bf16
/// kernel's numbers at fp32 kernels' speed (csrc/ops.cpp `Bf16EmulatedConvolution`;
/// [`rtf_amp::Bf16Convolutions::Emulated`]). Differentiable; output bf16, operand gradients in
/// the operands' own types. Units call it inside a CPU bf16 autocast region where
/// [`rtf_amp::emulates_bf16_convolution`] says so, and folded units where their fold says so.
pub fn bf16_emulated_convolution(
    xs: &Tensor,
    weight: &Tensor,
    bias: Option<&Tensor>,
    geometry: Geometry,
) -> Tensor {
    let g = geometry;
    let pair = |v: i64| [v, v];
    let (stride, padding, dilation) = (pair(g.stride), pair(g.padding), pair(g.dilation));
    let output_padding = [0i64, 0];
    let mut out: *mut torch_sys::C_tensor = std::ptr::null_mut();
    let bias_ptr = bias.map_or(std::ptr::null_mut(), |b| {
        b.as_ptr() as *mut torch_sys::C_tensor
    });
    // SAFETY: the tensors' `as_ptr` are live `at::Tensor*` for the call (bias may be null, which
    // the shim reads as no bias); the geometry arrays hold two values each, as the shim reads.
    unsafe {
        let error = ffi::rtf_bf16_emulated_convolution(
            xs.as_ptr() as *mut torch_sys::C_tensor,
            weight.as_ptr() as *mut torch_sys::C_tensor,
            bias_ptr,
            stride.as_ptr(),
            padding.as_ptr(),
            dilation.as_ptr(),
            std::ffi::c_int::from(g.transposed),
            output_padding.as_ptr(),
            g.groups,
            &mut out,
        );
        shim_result("bf16 emulated convolution", error, out)
    }
}

/// One SGD update of each of `params` in place, PyTorch's rules (no dampening, no Nesterov),
/// as ATen's fused kernel computes it in one pass: g = grad + weight_decay·param; buf = g on
/// the first step (`first_step`), else momentum·buf + g; param −= lr·buf (with momentum 0,
/// param −= lr·g and `bufs` is not read). `grads[i]` and `bufs[i]` are shaped and laid out
/// like `params[i]`; all on one device, of one type. Instead of the five passes and three
/// temporaries of the same update in tensor ops (docs/src/benchmarks.md, "The SGD update"),
/// and in one call for them all: on CUDA a few multi-tensor launches, not one per tensor
/// (docs/src/gpu.md).
pub fn fused_sgd_(
    params: &[Tensor],
    grads: &[Tensor],
    bufs: &[Tensor],
    weight_decay: f64,
    momentum: f64,
    lr: f64,
    first_step: bool,
) {
    assert!(params.len() == grads.len() && (momentum == 0.0 || bufs.len() == params.len()));
    let ptrs = |ts: &[Tensor]| -> Vec<*mut torch_sys::C_tensor> {
        ts.iter()
            .map(|t| t.as_ptr() as *mut torch_sys::C_tensor)
            .collect()
    };
    let (params_, grads_, bufs_) = (ptrs(params), ptrs(grads), ptrs(bufs));
    // SAFETY: the pointer arrays hold live `at::Tensor*` (borrowed from the slices) for the
    // call, `n` of each (`bufs` only read with momentum); the shim updates their storage in
    // place (no tensor is made) and returns null or a message, as `check` requires.
    unsafe {
        let error = ffi::rtf_fused_sgd(
            params_.as_ptr(),
            grads_.as_ptr(),
            bufs_.as_ptr(),
            params.len() as i64,
            weight_decay,
            momentum,
            lr,
            std::ffi::c_int::from(first_step),
        );
        check("fused SGD", error);
    }
}

/// The tensors of one fused AdamW call, index by index: each parameter, its gradient, its two
/// moments (shaped and laid out like it) and its step count (one float element on its device).
pub struct AdamwTensors<'a> {
    pub params: &'a [Tensor],
    pub grads: &'a [Tensor],
    pub exp_avgs: &'a [Tensor],
    pub exp_avg_sqs: &'a [Tensor],
    pub steps: &'a [Tensor],
}

/// AdamW's hyper-parameters for [`fused_adamw_`].
#[derive(Clone, Copy, Debug)]
pub struct AdamwRule {
    pub lr: f64,
    pub betas: (f64, f64),
    pub weight_decay: f64,
    pub eps: f64,
}

/// One AdamW update of each parameter in place, as `torch.optim.AdamW(fused=True)` computes it
/// (no amsgrad): the step counts go up by one, p ·= 1 − lr·wd, m = lerp(m, g, 1 − β1),
/// v = β2·v + (1 − β2)·g², p −= lr / (1 − β1ᵗ) · m / (√v / √(1 − β2ᵗ) + ε). In one call for
/// them all (on CUDA a few multi-tensor launches, not fourteen per tensor). All on one
/// device, of one type.
pub fn fused_adamw_(t: &AdamwTensors<'_>, rule: AdamwRule) {
    let n = t.params.len();
    assert!([t.grads, t.exp_avgs, t.exp_avg_sqs, t.steps]
        .iter()
        .all(|list| list.len() == n));
    let ptrs = |ts: &[Tensor]| -> Vec<*mut torch_sys::C_tensor> {
        ts.iter()
            .map(|t| t.as_ptr() as *mut torch_sys::C_tensor)
            .collect()
    };
    let lists = [t.params, t.grads, t.exp_avgs, t.exp_avg_sqs, t.steps].map(ptrs);
    // SAFETY: each pointer array holds `n` live `at::Tensor*` borrowed from the slices for the
    // call; the shim updates their storage in place (no tensor is made) and returns null or a
    // message, as `check` requires.
    unsafe {
        let error = ffi::rtf_fused_adamw(
            lists[0].as_ptr(),
            lists[1].as_ptr(),
            lists[2].as_ptr(),
            lists[3].as_ptr(),
            lists[4].as_ptr(),
            n as i64,
            rule.lr,
            rule.betas.0,
            rule.betas.1,
            rule.weight_decay,
            rule.eps,
        );
        check("fused AdamW", error);
    }
}

/// Zeroes the gradients of `params` as PyTorch's `zero_grad(set_to_none=False)` does (a
/// gradient with a history detached, one without no longer requiring grad), in one
/// `_foreach_zero_` per device and type: on CUDA a few launches, not one per parameter.
/// Parameters without a gradient are left alone.
pub fn zero_grads(params: &[Tensor]) {
    let ptrs: Vec<*mut torch_sys::C_tensor> = params
        .iter()
        .map(|t| t.as_ptr() as *mut torch_sys::C_tensor)
        .collect();
    // SAFETY: `ptrs` holds live `at::Tensor*` (borrowed from `params`) for the call; the shim
    // zeroes their gradients in place and returns null or a message, as `check` requires.
    unsafe {
        check(
            "zero grads",
            ffi::rtf_zero_grads(ptrs.as_ptr(), ptrs.len() as i64),
        )
    };
}

/// Who holds `t`'s memory: (handles on its TensorImpl, TensorImpls on its storage). Counts,
/// not identities: meaningful compared with the same tensor's counts at another time.
pub fn tensor_holders(t: &Tensor) -> (i64, i64) {
    let (mut handles, mut storage_users) = (0i64, 0i64);
    // SAFETY: `as_ptr` is a live `at::Tensor*` for the call; the shim only reads reference
    // counts into the two locals and returns null or a message, as `check` requires.
    unsafe {
        let error = ffi::rtf_tensor_holders(
            t.as_ptr() as *mut torch_sys::C_tensor,
            &mut handles,
            &mut storage_users,
        );
        check("tensor holders", error);
    }
    (handles, storage_users)
}

/// How often each operator ran: (in all, at the outermost level), by name. ATen operators
/// (`aten::…`) and autograd nodes as libtorch records them for its profiler (the events
/// `torch.profiler` counts), so PyTorch's counts of the same work compare name by name.
pub type OpCounts = std::collections::BTreeMap<String, (u64, u64)>;

/// Runs `f` with every operator it runs counted (on this thread, and on the autograd
/// engine's threads for its backward passes; other threads' operators do not count; one
/// counter at a time per process). On a GPU each operator is one or more kernel launches, so
/// this is the host's share of a step, device-independent.
pub fn count_ops<T>(f: impl FnOnce() -> T) -> (T, OpCounts) {
    let mut handle = 0u64;
    // SAFETY: the shim writes the callback's handle into the local and returns null or a
    // message, as `check` requires.
    unsafe { check("op counter", ffi::rtf_op_counter_start(&mut handle)) };
    let out = f();
    let mut table: *mut std::ffi::c_char = std::ptr::null_mut();
    // SAFETY: `handle` came from the start call; on success `table` is a NUL-terminated
    // string the shim malloc'd, read once and freed here.
    let text = unsafe {
        check("op counter", ffi::rtf_op_counter_stop(handle, &mut table));
        let text = std::ffi::CStr::from_ptr(table)
            .to_string_lossy()
            .into_owned();
        ffi::rtf_ops_free_error(table);
        text
    };
    (out, parse_op_counts(&text))
}

/// The shim's table: "name\tall\toutermost" lines.
fn parse_op_counts(text: &str) -> OpCounts {
    text.lines()
        .filter_map(|line| {
            let mut fields = line.rsplitn(3, '\t');
            let outermost = fields.next()?.parse().ok()?;
            let all = fields.next()?.parse().ok()?;
            Some((fields.next()?.to_string(), (all, outermost)))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    /// The counter sees the operators a forward and a backward run, nested ones too, and
    /// counts the outermost once each; nothing outside its closure.
    #[test]
    fn counts_the_operators_of_a_forward_and_a_backward() {
        let x = Tensor::rand([4, 3], (Kind::Float, Device::Cpu)).set_requires_grad(true);
        let before = x.exp();
        let (_, counts) = count_ops(|| {
            let y = (&x * 2.0).mm(&x.tr()).sum(Kind::Float);
            y.backward();
        });
        let _after = before.sin();
        let get = |name: &str| counts.get(name).copied().unwrap_or_default();
        assert_eq!(get("aten::mm").1, 1, "{counts:?}");
        assert_eq!(get("aten::sum").1, 1, "{counts:?}");
        assert!(get("aten::mul").0 >= 1, "{counts:?}");
        let outside = get("aten::exp").0 + get("aten::sin").0;
        assert_eq!(outside, 0, "counted outside the closure: {counts:?}");
        assert!(
            counts.keys().any(|k| k.contains("MmBackward")),
            "no backward node: {counts:?}"
        );
        let all: u64 = counts.values().map(|c| c.0).sum();
        let outermost: u64 = counts.values().map(|c| c.1).sum();
        assert!(all > outermost && outermost >= 4, "{all} {outermost}");
    }
}
