//! Data movement libtorch has no single fast op for, written as plain loops over CPU memory.

use tch::{Device, Kind, Tensor};

/// Interleaves the four output phases of an upsampling convolution (see
/// rtf-models' `ConvBnAct::forward_upsampled`) into the full-size map:
/// `out[n, c, 2i + a, 2j + b] = phases[n, (2a + b)·C + c, i + a, j + b]`.
/// [B, 4C, H + 1, W + 1] (any float kind) -> float32 NCHW-contiguous [B, C, 2H, 2W].
///
/// Channels-last float32/bfloat16 maps on the CPU (the fast path's) take one pass in Rust;
/// anything else takes four strided libtorch copies (about twice as long on the CPU).
pub fn interleave_phases(phases: &Tensor) -> Tensor {
    let size = phases.size();
    assert!(
        size.len() == 4 && size[1] % 4 == 0 && size[2] >= 1 && size[3] >= 1,
        "interleave_phases: expected [B, 4C, H + 1, W + 1], got {size:?}"
    );
    let (batch, channels, h, w) = (size[0], size[1] / 4, size[2] - 1, size[3] - 1);
    let out = Tensor::empty(
        [batch, channels, 2 * h, 2 * w],
        (Kind::Float, phases.device()),
    );
    let dense_channels_last =
        phases.stride() == [size[1] * size[2] * size[3], 1, size[1] * size[3], size[1]];
    if phases.device() == Device::Cpu && dense_channels_last && out.numel() > 0 {
        let dims = [batch, channels, h, w].map(|d| d as usize);
        let n_in = phases.numel();
        // SAFETY: `phases` is a dense channels-last CPU tensor of `n_in` elements of the
        // matched kind, `out` a fresh contiguous float tensor of `out.numel()` elements; both
        // outlive the slices, which do not overlap.
        let dst =
            unsafe { std::slice::from_raw_parts_mut(out.data_ptr() as *mut f32, out.numel()) };
        match phases.kind() {
            Kind::Float => {
                let src =
                    unsafe { std::slice::from_raw_parts(phases.data_ptr() as *const f32, n_in) };
                interleave_nhwc(src, dst, dims, |v| v);
                return out;
            }
            Kind::BFloat16 => {
                let src =
                    unsafe { std::slice::from_raw_parts(phases.data_ptr() as *const u16, n_in) };
                // bfloat16 is the upper half of a float32: widening is exact.
                interleave_nhwc(src, dst, dims, |v| f32::from_bits(u32::from(v) << 16));
                return out;
            }
            _ => {}
        }
    }
    for a in 0..2 {
        for b in 0..2 {
            let mut dst = out.slice(2, a, 2 * h, 2).slice(3, b, 2 * w, 2);
            let src = phases
                .narrow(1, (2 * a + b) * channels, channels)
                .narrow(2, a, h)
                .narrow(3, b, w);
            dst.copy_(&src);
        }
    }
    out
}

/// [`interleave_phases`] on raw memory: `src` NHWC [B, H + 1, W + 1, 4C], `dst` NCHW
/// [B, C, 2H, 2W]; `dims` = [B, C, H, W].
fn interleave_nhwc<T: Copy>(
    src: &[T],
    dst: &mut [f32],
    [batch, channels, h, w]: [usize; 4],
    widen: impl Fn(T) -> f32,
) {
    let src_pixel = 4 * channels;
    let src_row = (w + 1) * src_pixel;
    let src_image = (h + 1) * src_row;
    let dst_row = 2 * w;
    let dst_plane = 2 * h * dst_row;
    for n in 0..batch {
        for c in 0..channels {
            let plane = &mut dst[(n * channels + c) * dst_plane..][..dst_plane];
            for (r, out_row) in plane.chunks_exact_mut(dst_row).enumerate() {
                let (i, a) = (r / 2, r % 2);
                // Phase (a, 0) at source column j, phase (a, 1) at column j + 1.
                let row = &src[n * src_image + (i + a) * src_row..][..src_row];
                let even = &row[(2 * a) * channels + c..];
                let odd = &row[src_pixel + (2 * a + 1) * channels + c..];
                for (j, pair) in out_row.chunks_exact_mut(2).enumerate() {
                    pair[0] = widen(even[j * src_pixel]);
                    pair[1] = widen(odd[j * src_pixel]);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::to_channels_last;

    /// The definition, element by element.
    fn reference(phases: &Tensor) -> Tensor {
        let size = phases.size();
        let (batch, channels, h, w) = (size[0], size[1] / 4, size[2] - 1, size[3] - 1);
        let p = phases.to_kind(Kind::Float);
        let out = Tensor::zeros([batch, channels, 2 * h, 2 * w], (Kind::Float, Device::Cpu));
        for n in 0..batch {
            for c in 0..channels {
                for y in 0..2 * h {
                    for x in 0..2 * w {
                        let (i, a, j, b) = (y / 2, y % 2, x / 2, x % 2);
                        let v = p.double_value(&[n, (2 * a + b) * channels + c, i + a, j + b]);
                        let _ = out.get(n).get(c).get(y).get(x).fill_(v);
                    }
                }
            }
        }
        out
    }

    #[test]
    fn every_layout_and_kind_interleaves_as_defined() {
        let phases = Tensor::randn([2, 12, 4, 6], (Kind::Float, Device::Cpu));
        let expected = reference(&phases);
        for kind in [Kind::Float, Kind::BFloat16] {
            let p = phases.to_kind(kind);
            let expected = reference(&p);
            for input in [to_channels_last(&p), p.shallow_clone()] {
                let out = interleave_phases(&input);
                assert_eq!(out.size(), [2, 3, 6, 10]);
                assert_eq!(out.kind(), Kind::Float);
                assert!(out.is_contiguous());
                assert!(out.equal(&expected), "{kind:?}");
            }
        }
        assert!(interleave_phases(&to_channels_last(&phases)).equal(&expected));
    }
}
