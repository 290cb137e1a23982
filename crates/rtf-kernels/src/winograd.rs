//! 3×3 convolutions (stride 1, no groups, padding equal to the dilation) by Winograd's minimal
//! filtering F(2×2, 3×3) (Lavin & Gray, CVPR 2016), for the inference path's widest layers;
//! dilated ones through their phase sub-maps ([`conv3x3_dilated`]).
//!
//! Each 2×2 output tile is `Aᵀ [(G g Gᵀ) ⊙ (Bᵀ d B)] A` of the 4×4 input tile `d` around it:
//! summed over input channels, the elementwise product becomes 16 independent matrix products
//! [tiles × C] · [C × K], 16 multiply-adds per tile and channel pair instead of 36 (2.25×
//! fewer). The weight transform `G g Gᵀ` is made once, when the network is folded; the input
//! and output transforms are additions over the (small) maps. The transform matrices hold only
//! 0, ±1 and ½, so the rounding is that of a direct convolution's sums (relative 1e-6 on
//! RTFNet-50's layers); F(4×4, 3×3)'s hold up to 8 and 1/24, a little more (tests: 1e-4).
//!
//! Two forms ([`form`] picks by width): F(2×2, 3×3) by libtorch ops for the widest layers
//! (RTFNet-50's decoder at 1/32 and 1/16: 2048 and 1024 channels on 15×20 and 30×40 maps at
//! 480×640), where the matrix products dominate and whole-map transforms cost little; and
//! F(4×4, 3×3) (36 products per 4×4 tile, 4× fewer multiply-adds than direct) for 64 to 1023
//! channels, whose larger maps need the transforms done in cache-sized chunks of tiles, in C++
//! (csrc/ops.cpp `wino43_conv`: F(2×2, 3×3) by libtorch ops over whole maps made these layers
//! slower; docs/src/models.md).
//! [`MIN_CHANNELS_F43`] is where the vectorised form overtakes oneDNN's direct kernels (the
//! lab's `winograd_layers` measures it per shape; docs/src/speed-by-kind.md).
//!
//! bf16 inference can take the same forms over bf16 maps (where the fold's
//! rtf-models' `fast::InferenceKernels::bf16_winograd` says so): the maps are read
//! and written in bf16 (F(4×4, 3×3) converts them inside its transforms), the weights are the
//! bf16-rounded folded weights, and the arithmetic is float32. Where a CPU's bf16 kernels do no
//! more multiply-adds per cycle than its fp32 ones (Intel AVX-512 without AMX, where oneDNN's
//! bf16 3×3 kernels are slower than its fp32 direct ones: docs/src/benchmarks.md), Winograd's
//! 4× fewer multiply-adds win; with AMX, oneDNN's bf16 kernels do.
//! So the choice is measured per CPU (rtf-eval's `kernels` probe), never assumed, and passed in.
//!
//! fp32 training takes F(4×4, 3×3) too, in all three passes ([`conv3x3_f43_train`]: forward,
//! input gradient, weight gradient), for the shapes where it is faster than oneDNN's direct
//! kernels ([`trains_in_f43`]; measured in docs/src/speed-by-kind.md).

use tch::{Kind, Tensor};

use crate::geometry::Geometry;

/// Input and output channels from which [`form`] takes F(2×2, 3×3).
pub const MIN_CHANNELS: i64 = 1024;
/// Input and output channels from which (up to [`MIN_CHANNELS`]) [`form`] takes F(4×4, 3×3).
pub const MIN_CHANNELS_F43: i64 = 64;

/// The forms' implementation, counted up whenever their speed changes (which layers take them,
/// how fast they run), so that timings cached against them (rtf-cli's bf16 probe, which picks
/// between these forms and oneDNN's bf16 kernels) are measured again rather than reused.
/// 2: transforms vectorised, F(4×4, 3×3) from 64 channels (issue 41).
pub const REVISION: u32 = 2;

/// Which Winograd form a convolution takes on the inference path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Form {
    /// F(2×2, 3×3): 16 products, libtorch ops (maps of the widest layers are small).
    F23,
    /// F(4×4, 3×3): 36 products per 4×4 tile, 4× fewer multiply-adds than direct, with the
    /// transforms in C++ (csrc/ops.cpp `wino43_conv`) over chunks of tiles kept in cache.
    F43,
}

/// The Winograd form of a convolution of this shape on the inference path, if any: 3×3,
/// stride 1, padding equal to the dilation (the size kept: dilated ones run as
/// [`conv3x3_dilated`]), no groups, not transposed; F(2×2, 3×3) from [`MIN_CHANNELS`] input
/// and output channels, F(4×4, 3×3) from [`MIN_CHANNELS_F43`], as far as `forms` allow (a
/// fold's rtf-models' `fast::InferenceKernels::winograd`).
pub fn form(forms: Forms, kernel: i64, geometry: Geometry, c_in: i64, c_out: i64) -> Option<Form> {
    let g = geometry;
    let plain =
        kernel == 3 && (g.stride, g.groups) == (1, 1) && g.dilation >= 1 && g.padding == g.dilation;
    let channels = c_in.min(c_out);
    let (f23, f43) = forms.enabled();
    if !plain || g.transposed || channels < MIN_CHANNELS_F43 {
        None
    } else if channels >= MIN_CHANNELS {
        f23.then_some(Form::F23)
    } else {
        f43.then_some(Form::F43)
    }
}

/// Which Winograd forms rtf may take, a kernel choice passed in by the caller (the schema's,
/// rtf-config: a run records it).
pub use rtf_config::compute::Forms;

/// Without a measurement, the bf16 forms only where the CPU has no bf16 arithmetic: there
/// oneDNN's bf16 kernels convert every product, and the fp32 Winograd form beats them. The
/// CPU's flags without an ISA cap: a caller that knows its process's cap chooses instead
/// (rtf_eval::kernels).
pub fn bf16_default() -> bool {
    rtf_amp::Bf16Arithmetic::of_cpu(rtf_amp::IsaCap::NONE).is_native() == Some(false)
}

/// Bᵀ (input transform), row-major 4×4.
const BT: [f32; 16] = [
    1., 0., -1., 0., //
    0., 1., 1., 0., //
    0., -1., 1., 0., //
    0., 1., 0., -1.,
];
/// G (weight transform), row-major 4×3.
const G: [f32; 12] = [
    1., 0., 0., //
    0.5, 0.5, 0.5, //
    0.5, -0.5, 0.5, //
    0., 0., 1.,
];
/// Aᵀ (output transform), row-major 2×4.
const AT: [f32; 8] = [
    1., 1., 1., 0., //
    0., 1., -1., -1.,
];
/// F(4×4, 3×3)'s G, row-major 6×3 (its Bᵀ and Aᵀ are in csrc/ops.cpp).
const G43: [f32; 18] = [
    1. / 4.,
    0.,
    0., //
    -1. / 6.,
    -1. / 6.,
    -1. / 6., //
    -1. / 6.,
    1. / 6.,
    -1. / 6., //
    1. / 24.,
    1. / 12.,
    1. / 6., //
    1. / 24.,
    -1. / 12.,
    1. / 6., //
    0.,
    0.,
    1.,
];

fn matrix(values: &[f32], rows: i64, xs: &Tensor) -> Tensor {
    Tensor::from_slice(values)
        .view([rows, -1])
        .to_device(xs.device())
}

/// The transformed weight: [K, C, 3, 3] -> float32 [α², C, K] (`G g Gᵀ` per channel pair, its
/// α×α positions first; α = 4 for F(2×2, 3×3), 6 for F(4×4, 3×3)).
pub fn weight_transform(weight: &Tensor, form: Form) -> Tensor {
    let size = weight.size();
    assert!(
        size.len() == 4 && size[2] == 3 && size[3] == 3,
        "winograd::weight_transform: expected [K, C, 3, 3], got {size:?}"
    );
    let (g, alpha) = match form {
        Form::F23 => (matrix(&G, 4, weight), 4),
        Form::F43 => (matrix(&G43, 6, weight), 6),
    };
    Tensor::einsum(
        "ai,kcij,bj->abck",
        &[&g, &weight.to_kind(Kind::Float), &g],
        None::<&[i64]>,
    )
    .reshape([alpha * alpha, size[1], size[0]])
    .contiguous()
}

/// `act(conv3x3(xs) + bias (+ residual))` with `u` from [`weight_transform`] (either form):
/// input [N, C, H, W] float32 or bf16 (any layout; channels-last avoids a copy), `residual`
/// [N, K, H, W] of the same type, float32 `bias`; output [N, K, H, W] in the input's type, laid
/// out channels-last, computed in float32. `relu` applies a ReLU last.
pub fn conv3x3(
    xs: &Tensor,
    u: &Tensor,
    bias: Option<&Tensor>,
    residual: Option<&Tensor>,
    relu: bool,
) -> Tensor {
    if u.size()[0] == 36 {
        conv3x3_f43(xs, u, bias, residual, relu)
    } else if xs.kind() == Kind::BFloat16 {
        // The widest layers' maps are small (15×20 and 30×40 at 480×640): casting them costs
        // little beside the products.
        let float = |t: &Tensor| t.to_kind(Kind::Float);
        let residual = residual.map(float);
        conv3x3_f23(&float(xs), u, bias, residual.as_ref(), relu).to_kind(Kind::BFloat16)
    } else {
        conv3x3_f23(xs, u, bias, residual, relu)
    }
}

/// [`conv3x3`] of a 3×3 convolution with dilation `d` and padding `d` (PSPNet's dilated
/// ResNet layers: HeatNet's layer3 and layer4 at 1/8 resolution). Such a convolution reads
/// only pixels of its output's phase (y mod d, x mod d), so it is d² plain 3×3 convolutions
/// (padding 1) of the phase sub-maps, run as one batch of N·d² maps in the Winograd form and
/// interleaved back (the space-to-batch of dilated convolutions). Maps whose sides are not
/// multiples of d are zero-padded after, which is the convolution's own zero padding, and the
/// output is cropped.
pub fn conv3x3_dilated(
    xs: &Tensor,
    u: &Tensor,
    bias: Option<&Tensor>,
    residual: Option<&Tensor>,
    relu: bool,
    d: i64,
) -> Tensor {
    if d == 1 {
        return conv3x3(xs, u, bias, residual, relu);
    }
    let (n, _, h, w) = xs
        .size4()
        .expect("winograd::conv3x3_dilated takes [N, C, H, W]");
    let residual = residual.map(|r| to_phases(r, d));
    let ys = conv3x3(&to_phases(xs, d), u, bias, residual.as_ref(), relu);
    from_phases(&ys, n, d, h, w)
}

/// [N, C, H, W] -> [N·d², C, ⌈H/d⌉, ⌈W/d⌉], channels-last: batch entry n·d² + py·d + px holds
/// the pixels (d·u + py, d·v + px), zero where past the map.
fn to_phases(xs: &Tensor, d: i64) -> Tensor {
    let (n, c, h, w) = xs.size4().expect("[N, C, H, W]");
    let (hs, ws) = ((h + d - 1) / d, (w + d - 1) / d);
    // [N, H, W, C] (a view of a channels-last map), zero-padded after to whole phases
    let nhwc = xs.permute([0, 2, 3, 1]);
    let nhwc = match (hs * d - h, ws * d - w) {
        (0, 0) => nhwc,
        (ph, pw) => nhwc.constant_pad_nd([0, 0, 0, pw, 0, ph]),
    };
    // [N, hs, d, ws, d, C] -> [N, d, d, hs, ws, C] -> [N·d², hs, ws, C] -> NCHW view
    nhwc.reshape([n, hs, d, ws, d, c])
        .permute([0, 2, 4, 1, 3, 5])
        .contiguous()
        .view([n * d * d, hs, ws, c])
        .permute([0, 3, 1, 2])
}

/// The inverse of [`to_phases`], cropped to [N, K, H, W], channels-last.
fn from_phases(ys: &Tensor, n: i64, d: i64, h: i64, w: i64) -> Tensor {
    let (_, k, hs, ws) = ys.size4().expect("[N·d², K, hs, ws]");
    // [N·d², hs, ws, K] -> [N, d, d, hs, ws, K] -> [N, hs, d, ws, d, K] -> [N, hs·d, ws·d, K]
    let nhwc = ys
        .permute([0, 2, 3, 1])
        .reshape([n, d, d, hs, ws, k])
        .permute([0, 3, 1, 4, 2, 5])
        .contiguous()
        .view([n, hs * d, ws * d, k]);
    let nhwc = match (hs * d == h, ws * d == w) {
        (true, true) => nhwc,
        _ => nhwc.narrow(1, 0, h).narrow(2, 0, w).contiguous(),
    };
    nhwc.permute([0, 3, 1, 2])
}

/// [`conv3x3`] in F(4×4, 3×3), by csrc/ops.cpp (CPU float32 tensors).
fn conv3x3_f43(
    xs: &Tensor,
    u: &Tensor,
    bias: Option<&Tensor>,
    residual: Option<&Tensor>,
    relu: bool,
) -> Tensor {
    let ptr = |t: Option<&Tensor>| {
        t.map_or(std::ptr::null_mut(), |t| {
            t.as_ptr() as *mut torch_sys::C_tensor
        })
    };
    let mut out: *mut torch_sys::C_tensor = std::ptr::null_mut();
    // SAFETY: the `as_ptr` are live `at::Tensor*` for the call (bias and residual may be null,
    // which the shim reads as absent); the result is taken as `shim_result` requires.
    unsafe {
        let error = crate::aten::ffi::rtf_winograd43_conv(
            ptr(Some(xs)),
            ptr(Some(u)),
            ptr(bias),
            ptr(residual),
            std::ffi::c_int::from(relu),
            &mut out,
        );
        crate::aten::shim_result("winograd F(4x4, 3x3)", error, out)
    }
}

/// Channels (input and output) from which, up to [`TRAIN_MAX_CHANNELS`], a training
/// convolution takes [`conv3x3_f43_train`]: below, the transforms cost what the products save.
pub const TRAIN_MIN_CHANNELS: i64 = 128;
/// The most channels a training convolution takes [`conv3x3_f43_train`] with: wider layers
/// transform weights and weight gradients of 36·C·K floats in every pass, which costs more
/// than their few tiles save (2048 channels at 15×20: 2× slower).
pub const TRAIN_MAX_CHANNELS: i64 = 1024;
/// The fewest 4×4 output tiles (over the batch) for [`conv3x3_f43_train`]: with fewer, its 36
/// products are too thin to run fast (512 channels at 15×20, batch 4: 80 tiles, slower).
pub const TRAIN_MIN_TILES: i64 = 256;

/// Whether a training convolution of this shape, over an input [N, C, H, W], takes
/// [`conv3x3_f43_train`]: a 3×3 convolution that keeps the size, undilated, of
/// [`TRAIN_MIN_CHANNELS`]–[`TRAIN_MAX_CHANNELS`] channels and at least [`TRAIN_MIN_TILES`]
/// tiles. Measured per shape with the lab's `winograd_training_layers` (docs/src/speed-by-
/// kind.md). Only within `forms` (the training unit's: [`Forms::Off`] or [`Forms::F23`] turns
/// it off).
pub fn trains_in_f43(
    forms: Forms,
    kernel: i64,
    geometry: Geometry,
    c_out: i64,
    input: &[i64],
) -> bool {
    let [n, c_in, h, w] = input else {
        return false;
    };
    let channels = (*c_in).min(c_out)..=(*c_in).max(c_out);
    let tiles = n * ((h + 3) / 4) * ((w + 3) / 4);
    geometry.dilation == 1
        && forms.enabled().1
        && form(forms, kernel, geometry, *c_in, c_out).is_some()
        && channels.start() >= &TRAIN_MIN_CHANNELS
        && channels.end() <= &TRAIN_MAX_CHANNELS
        && tiles >= TRAIN_MIN_TILES
}

/// A 3×3 convolution (stride 1, padding 1, no bias) of float32 maps for training, in
/// F(4×4, 3×3) and differentiable: the forward pass and the input's gradient by the form, the
/// weight's gradient by libtorch's kernels (csrc/ops.cpp `Winograd43Convolution`).
/// [N, C, H, W] (channels-last avoids a copy), weight [K, C, 3, 3] -> [N, K, H, W],
/// channels-last.
pub fn conv3x3_f43_train(xs: &Tensor, weight: &Tensor) -> Tensor {
    let g = matrix(&G43, 6, weight);
    let mut out: *mut torch_sys::C_tensor = std::ptr::null_mut();
    // SAFETY: the `as_ptr` are live `at::Tensor*` for the call; the result is taken as
    // `shim_result` requires.
    unsafe {
        let error = crate::aten::ffi::rtf_winograd43_train_conv(
            xs.as_ptr() as *mut torch_sys::C_tensor,
            weight.as_ptr() as *mut torch_sys::C_tensor,
            g.as_ptr() as *mut torch_sys::C_tensor,
            &mut out,
        );
        crate::aten::shim_result("winograd F(4x4, 3x3) training", error, out)
    }
}

/// [`conv3x3`] in F(2×2, 3×3), by libtorch ops.
fn conv3x3_f23(
    xs: &Tensor,
    u: &Tensor,
    bias: Option<&Tensor>,
    residual: Option<&Tensor>,
    relu: bool,
) -> Tensor {
    let (n, c, h, w) = xs.size4().expect("winograd::conv3x3 takes [N, C, H, W]");
    let k = u.size()[2];
    // Tiles of 2×2 outputs; the padded map holds every tile's 4×4 input.
    let (th, tw) = ((h + 1) / 2, (w + 1) / 2);
    let (hp, wp) = (2 * th + 2, 2 * tw + 2);
    // [N, H, W, C] (a view of a channels-last map), zero-padded by 1 before and to whole tiles
    // after: [N, Hp, Wp, C]
    let padded = xs
        .permute([0, 2, 3, 1])
        .constant_pad_nd([0, 0, 1, wp - w - 1, 1, hp - h - 1]);
    // Tile (t, u)'s input: rows 2t..2t+3, columns 2u..2u+3. [4, 4, N, th, tw, C]
    let tiles = padded.as_strided(
        [4, 4, n, th, tw, c],
        [wp * c, c, hp * wp * c, 2 * wp * c, 2 * c, 1],
        None,
    );
    let bt = matrix(&BT, 4, xs);
    // Bᵀ d B: [16, N·th·tw, C]
    let v = Tensor::einsum("ai,bj,ijntuc->abntuc", &[&bt, &bt, &tiles], None::<&[i64]>).reshape([
        16,
        n * th * tw,
        c,
    ]);
    // The 16 products over the channels: [16, N·th·tw, K]
    let m = v.bmm(u).view([4, 4, n, th, tw, k]);
    let at = matrix(&AT, 2, xs);
    // Aᵀ m A, tiles back in place: [N, 2·th, 2·tw, K], cropped to [N, H, W, K]
    let y = Tensor::einsum("ai,bj,ijntuk->ntaubk", &[&at, &at, &m], None::<&[i64]>)
        .reshape([n, 2 * th, 2 * tw, k])
        .narrow(1, 0, h)
        .narrow(2, 0, w);
    // A fresh dense [N, H, W, K] map from here on, changed in place.
    let mut out = match bias {
        Some(b) => y + b,
        None => y.contiguous(),
    };
    if let Some(r) = residual {
        let _ = out.g_add_(&r.permute([0, 2, 3, 1]));
    }
    if relu {
        let _ = out.relu_();
    }
    out.permute([0, 3, 1, 2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::to_channels_last;
    use tch::Device;

    /// Laid out [N, H, W, C] in memory, in libtorch's sense (a size-1 dimension's stride does
    /// not count: a cropped map of one frame keeps its uncropped batch stride).
    fn is_channels_last(xs: &Tensor) -> bool {
        xs.permute([0, 2, 3, 1]).is_contiguous()
    }

    #[test]
    fn equals_the_direct_convolution_at_odd_and_even_sizes() {
        tch::manual_seed(11);
        let opts = (Kind::Float, Device::Cpu);
        for (n, c, k, h, w) in [(1, 5, 7, 6, 8), (2, 3, 4, 7, 5), (1, 8, 6, 1, 1)] {
            let x = Tensor::randn([n, c, h, w], opts);
            let weight = Tensor::randn([k, c, 3, 3], opts);
            let bias = Tensor::randn([k], opts);
            let residual = Tensor::randn([n, k, h, w], opts);
            let direct = x.conv2d(&weight, Some(&bias), [1], [1], [1], 1);
            for (form, alpha) in [(Form::F23, 4), (Form::F43, 6)] {
                let u = weight_transform(&weight, form);
                assert_eq!(u.size(), [alpha * alpha, c, k]);
                for input in [x.shallow_clone(), to_channels_last(&x)] {
                    let y = conv3x3(&input, &u, Some(&bias), None, false);
                    assert_eq!(y.size(), [n, k, h, w]);
                    assert!(is_channels_last(&y));
                    let scale = direct.abs().max().double_value(&[]);
                    let worst = (&y - &direct).abs().max().double_value(&[]);
                    // F(4×4, 3×3)'s transforms hold 4, 5, 1/6, 1/24: a little more rounding.
                    let tolerance = if form == Form::F23 { 1e-5 } else { 1e-4 };
                    assert!(
                        worst <= tolerance * scale,
                        "{form:?} {n}x{c}x{h}x{w}: {worst} of {scale}"
                    );
                    let y = conv3x3(&input, &u, Some(&bias), Some(&residual), true);
                    let expected = (&direct + &residual).relu();
                    let close = |a: &Tensor, b: &Tensor| {
                        let scale = b.abs().max().double_value(&[]);
                        (a - b).abs().max().double_value(&[]) <= tolerance * scale
                    };
                    assert!(close(&y, &expected), "{form:?} + residual, ReLU");
                    let y = conv3x3(&input, &u, None, None, true);
                    let expected = x.conv2d(&weight, None::<Tensor>, [1], [1], [1], 1).relu();
                    assert!(close(&y, &expected), "{form:?} no bias");
                }
            }
        }
    }

    /// Dilated 3×3 convolutions (padding = dilation) through the phase sub-maps equal the
    /// direct dilated convolution, at sides that are and are not multiples of the dilation,
    /// with a residual, in both forms and over bf16 maps.
    #[test]
    fn dilated_equals_the_direct_dilated_convolution() {
        tch::manual_seed(13);
        let opts = (Kind::Float, Device::Cpu);
        for (n, c, k, h, w, d) in [
            (1, 5, 6, 12, 16, 2),
            (2, 3, 4, 13, 18, 4),
            (1, 4, 3, 3, 2, 2),
        ] {
            let x = to_channels_last(&Tensor::randn([n, c, h, w], opts));
            let weight = Tensor::randn([k, c, 3, 3], opts);
            let bias = Tensor::randn([k], opts);
            let residual = to_channels_last(&Tensor::randn([n, k, h, w], opts));
            let direct = x.conv2d(&weight, Some(&bias), [1], [d], [d], 1);
            let expected = (&direct + &residual).relu();
            let scale = expected.abs().max().double_value(&[]);
            for form in [Form::F23, Form::F43] {
                let u = weight_transform(&weight, form);
                let y = conv3x3_dilated(&x, &u, Some(&bias), Some(&residual), true, d);
                assert_eq!(y.size(), [n, k, h, w]);
                assert!(is_channels_last(&y), "{form:?} d={d}");
                let worst = (&y - &expected).abs().max().double_value(&[]);
                assert!(
                    worst <= 1e-4 * scale,
                    "{form:?} {h}x{w} d={d}: {worst} of {scale}"
                );
                // Over bf16 maps: the direct convolution of the same bf16 values, up to the
                // output's rounding to bf16 (2^-8 relative) and the float sums' order.
                let (xb, rb) = (x.to_kind(Kind::BFloat16), residual.to_kind(Kind::BFloat16));
                let y = conv3x3_dilated(&xb, &u, Some(&bias), Some(&rb), true, d);
                assert_eq!((y.kind(), y.size()), (Kind::BFloat16, vec![n, k, h, w]));
                let float = |t: &Tensor| t.to_kind(Kind::Float);
                let direct = float(&xb).conv2d(&weight, Some(&bias), [1], [d], [d], 1);
                let expected = (direct + float(&rb)).relu();
                let worst = (float(&y) - &expected).abs().max().double_value(&[]);
                assert!(
                    worst <= scale / 128.0,
                    "{form:?} bf16 d={d}: {worst} of {scale}"
                );
            }
        }
    }

    /// Training takes the form only where it measured faster: 128–1024 channels, enough tiles.
    #[test]
    fn training_takes_the_form_by_channels_and_tiles() {
        let same = Geometry::SAME_3X3;
        let takes = |c_out, input: [i64; 4]| trains_in_f43(Forms::All, 3, same, c_out, &input);
        assert!(takes(512, [4, 512, 60, 80]));
        assert!(takes(128, [4, 128, 240, 320]));
        assert!(takes(1024, [4, 1024, 30, 40]));
        // 80 tiles; 2048 channels; 64 channels.
        assert!(!takes(512, [4, 512, 15, 20]));
        assert!(!takes(2048, [4, 2048, 30, 40]));
        assert!(!takes(64, [4, 64, 120, 160]));
        let strided = Geometry { stride: 2, ..same };
        let dilated = Geometry {
            dilation: 2,
            padding: 2,
            ..same
        };
        for geometry in [strided, dilated] {
            assert!(!trains_in_f43(
                Forms::All,
                3,
                geometry,
                256,
                &[4, 256, 120, 160]
            ));
        }
        assert!(!trains_in_f43(
            Forms::All,
            1,
            Geometry { padding: 0, ..same },
            256,
            &[4, 256, 120, 160]
        ));
    }

    /// The training form is the direct convolution with its gradients: output, input gradient
    /// (by the form, of the flipped and transposed weight) and weight gradient, at sides that
    /// are and are not multiples of the 4×4 tile, NCHW and channels-last inputs; an input that
    /// needs no gradient gets none.
    #[test]
    fn training_form_has_the_direct_convolutions_gradients() {
        tch::manual_seed(14);
        let opts = (Kind::Float, Device::Cpu);
        for (n, c, k, h, w, channels_last) in [
            (2, 5, 7, 9, 14, true),
            (1, 3, 4, 8, 8, false),
            (4, 64, 96, 61, 83, true),
        ] {
            let x = Tensor::randn([n, c, h, w], opts);
            let x = if channels_last {
                to_channels_last(&x)
            } else {
                x
            };
            let weight = Tensor::randn([k, c, 3, 3], opts);
            let upstream = Tensor::randn([n, k, h, w], opts);
            let run = |conv: &dyn Fn(&Tensor, &Tensor) -> Tensor| {
                let leaf = |t: &Tensor| t.detach().copy().set_requires_grad(true);
                let (x, weight) = (leaf(&x), leaf(&weight));
                let y = conv(&x, &weight);
                (&y * &upstream).sum(Kind::Float).backward();
                [y.detach(), x.grad(), weight.grad()]
            };
            let direct = run(&|x, w| x.conv2d(w, None::<Tensor>, [1], [1], [1], 1));
            let form = run(&|x, w| conv3x3_f43_train(x, w));
            assert!(is_channels_last(&form[0]));
            for (what, (a, b)) in ["output", "input gradient", "weight gradient"]
                .iter()
                .zip(direct.iter().zip(&form))
            {
                let scale = a.abs().max().double_value(&[]);
                let worst = (a - b).abs().max().double_value(&[]);
                assert!(worst <= 1e-4 * scale, "{what} {h}x{w}: {worst} of {scale}");
            }
            let frozen = Tensor::randn([n, c, h, w], opts);
            let weight = weight.set_requires_grad(true);
            conv3x3_f43_train(&frozen, &weight)
                .sum(Kind::Float)
                .backward();
            assert!(!frozen.grad().defined() && weight.grad().defined());
        }
    }

    /// Over bf16 maps both forms compute in float32 and round once, on the way out: the
    /// float32 form's output of the same bf16 values, rounded to bf16, up to the float sums'
    /// order (a rounding boundary may fall between them: one bf16 step, 2^-8 relative).
    #[test]
    fn over_bf16_maps_is_the_float_form_rounded_once() {
        tch::manual_seed(12);
        let opts = (Kind::Float, Device::Cpu);
        let bf16 = |t: &Tensor| to_channels_last(&t.to_kind(Kind::BFloat16));
        for (n, c, k, h, w) in [(1, 6, 5, 9, 7), (2, 4, 3, 5, 6)] {
            let x = bf16(&Tensor::randn([n, c, h, w], opts));
            let residual = bf16(&Tensor::randn([n, k, h, w], opts));
            let weight = Tensor::randn([k, c, 3, 3], opts);
            let bias = Tensor::randn([k], opts);
            for form in [Form::F23, Form::F43] {
                let u = weight_transform(&weight, form);
                let float = |t: &Tensor| t.to_kind(Kind::Float);
                let y = conv3x3(&x, &u, Some(&bias), Some(&residual), true);
                assert_eq!(y.kind(), Kind::BFloat16);
                assert!(is_channels_last(&y), "{form:?}");
                let expected = conv3x3(&float(&x), &u, Some(&bias), Some(&float(&residual)), true);
                let scale = expected.abs().max().double_value(&[]);
                let worst = (float(&y) - &expected).abs().max().double_value(&[]);
                assert!(worst <= scale / 256.0, "{form:?}: {worst} of {scale}");
                let rounded = float(&expected.to_kind(Kind::BFloat16));
                let exact = float(&y)
                    .eq_tensor(&rounded)
                    .to_kind(Kind::Float)
                    .mean(Kind::Float);
                assert!(exact.double_value(&[]) > 0.95, "{form:?}: rounded once");
            }
        }
    }

    #[test]
    fn the_forms_given_limit_the_forms_taken() {
        let plain = Geometry::ungrouped(1, 1, 1, false);
        let both = |forms| {
            (
                form(forms, 3, plain, 1024, 2048),
                form(forms, 3, plain, 512, 512),
            )
        };
        assert_eq!(both(Forms::All), (Some(Form::F23), Some(Form::F43)));
        assert_eq!(both(Forms::F23), (Some(Form::F23), None));
        assert_eq!(both(Forms::Off), (None, None));
        let training = |forms| trains_in_f43(forms, 3, plain, 256, &[4, 256, 120, 160]);
        assert!(training(Forms::All));
        assert!(!training(Forms::F23) && !training(Forms::Off));
        assert_eq!("on".parse(), Ok(Forms::All));
        assert_eq!(" f23".parse(), Ok(Forms::F23));
        assert!("maybe"
            .parse::<Forms>()
            .unwrap_err()
            .contains("on, f23 or off"));
    }

    #[test]
    fn forms_by_width_and_only_for_plain_3x3_convolutions() {
        let plain = Geometry::ungrouped(1, 1, 1, false);
        assert_eq!(form(Forms::All, 3, plain, 1024, 2048), Some(Form::F23));
        assert_eq!(form(Forms::All, 3, plain, 512, 2048), Some(Form::F43));
        assert_eq!(form(Forms::All, 3, plain, 2048, 128), Some(Form::F43));
        assert_eq!(form(Forms::All, 3, plain, 64, 64), Some(Form::F43));
        assert_eq!(form(Forms::All, 3, plain, 32, 64), None);
        assert_eq!(
            form(
                Forms::All,
                3,
                Geometry::ungrouped(2, 1, 1, false),
                2048,
                2048
            ),
            None
        );
        // Dilated with the size kept (padding = dilation): the phase form; else none.
        assert_eq!(
            form(
                Forms::All,
                3,
                Geometry::ungrouped(1, 2, 2, false),
                2048,
                2048
            ),
            Some(Form::F23)
        );
        assert_eq!(
            form(Forms::All, 3, Geometry::ungrouped(1, 4, 4, false), 512, 512),
            Some(Form::F43)
        );
        assert_eq!(
            form(Forms::All, 3, Geometry::ungrouped(1, 1, 2, false), 512, 512),
            None
        );
        assert_eq!(
            form(Forms::All, 3, Geometry::ungrouped(2, 2, 2, false), 512, 512),
            None
        );
        assert_eq!(
            form(
                Forms::All,
                1,
                Geometry::ungrouped(1, 0, 1, false),
                2048,
                2048
            ),
            None
        );
        assert_eq!(
            form(
                Forms::All,
                3,
                Geometry::ungrouped(1, 1, 1, true),
                2048,
                2048
            ),
            None
        );
        let grouped = Geometry { groups: 2, ..plain };
        assert_eq!(form(Forms::All, 3, grouped, 2048, 2048), None);
    }
}
