//! The geometry of CMX's training augmentation ([`ScaleCrop`]), read from the official code
//! (huaaaliu/RGBX_Semantic_Segmentation: `dataloader/dataloader.py` `random_scale`,
//! `utils/transforms.py` `generate_random_crop_pos`, `random_crop_pad_to_shape`,
//! `pad_image_to_shape`):
//!
//! - one factor `s` drawn uniformly from the set; the scaled size is `int(h·s) × int(w·s)`;
//! - the crop's top-left corner: `randint(0, H − h_c + 1)` rows where the scaled height `H`
//!   exceeds the crop height `h_c`, else 0 (Python's `randint` includes both ends, so the last
//!   position leaves the crop one row short, padded like any shortfall), the same for columns,
//!   rows drawn first;
//! - what the crop holds of the scaled frame is padded to the crop size with `pad // 2` before
//!   and the rest after, in both directions.
//!
//! Scaling and cropping are one resampling here, from the frame straight to the crop: the image
//! bilinear without antialiasing at pixel centres (OpenCV's `INTER_LINEAR`), in floating point
//! where OpenCV resizes the 8-bit image; the label by OpenCV's `INTER_NEAREST` rule, scaled pixel
//! x taking frame pixel ⌊x · w / W⌋ (w the frame's width, W the scaled one; rows alike).

use rand::Rng;

use crate::augment::{resample, Filter, Planar, ScaleCrop, Window};
use crate::DataError;

/// One frame's draw: where the crop's content comes from and where it goes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// The factor drawn from the set.
    pub scale: f32,
    /// The content's window in frame pixels.
    pub window: Window,
    /// (width, height) of the scaled frame.
    pub scaled: (usize, usize),
    /// (column, row) of the crop's corner in the scaled frame.
    pub origin: (usize, usize),
    /// (width, height) of the content in the crop (the crop size unless the scaled frame ends
    /// inside it).
    pub content: (usize, usize),
    /// (left, top) of the content in the crop; the rest is padding.
    pub offset: (usize, usize),
}

/// The crop's (start, length of content, padding before) along one axis: `scaled` pixels of
/// the scaled frame, a crop of `crop` pixels.
fn axis(scaled: usize, crop: usize, rng: &mut impl Rng) -> (usize, usize, usize) {
    let start = match scaled > crop {
        // The official range, clamped so that at least one pixel stays inside (a crop of 1).
        true => rng.random_range(0..=scaled - crop + 1).min(scaled - 1),
        false => 0,
    };
    let content = (start + crop).min(scaled) - start;
    (start, content, (crop - content) / 2)
}

/// Draws the scale of `sc`, then the crop's row and column, for a `frame` (width, height)
/// seen at `base` size before scaling (a resize, or the frame's own size). Configuration
/// errors name what is wrong: an empty scale set, a factor that is not positive, a scaled
/// frame with no pixel.
pub fn draw(
    sc: &ScaleCrop,
    frame: (usize, usize),
    base: (usize, usize),
    rng: &mut impl Rng,
) -> Result<Placement, DataError> {
    if sc.scales.is_empty() {
        return Err(DataError::Config(
            "augment.scale_crop.scales is empty".into(),
        ));
    }
    let scale = sc.scales[rng.random_range(0..sc.scales.len())];
    let scaled = |n: usize| (n as f64 * scale as f64) as usize;
    let (sw, sh) = (scaled(base.0), scaled(base.1));
    if !(scale.is_finite() && scale > 0.0) || sw == 0 || sh == 0 {
        return Err(DataError::Config(format!(
            "augment.scale_crop: scale {scale} leaves no pixel of a {}x{} frame",
            base.0, base.1
        )));
    }
    let (cw, ch) = sc.crop_size(base);
    let (y, kh, top) = axis(sh, ch, rng);
    let (x, kw, left) = axis(sw, cw, rng);
    let (fx, fy) = (frame.0 as f32 / sw as f32, frame.1 as f32 / sh as f32);
    Ok(Placement {
        scale,
        window: Window {
            x0: x as f32 * fx,
            y0: y as f32 * fy,
            x1: (x + kw) as f32 * fx,
            y1: (y + kh) as f32 * fy,
        },
        scaled: (sw, sh),
        origin: (x, y),
        content: (kw, kh),
        offset: (left, top),
    })
}

/// Writes the crop of `image` (planar, in [0, 1]) and its `label` (`image`'s size) described
/// by `place` into `dst` (`image.channels` planes of `out`) and `dst_label` (`out`): the content
/// at its offset, `fill` per plane and `label_fill` around it.
pub fn crop_into(
    image: &Planar,
    label: &[u8],
    place: &Placement,
    (fill, label_fill): (&[f32; 4], u8),
    out: (usize, usize),
    dst: &mut [f32],
    dst_label: &mut [u8],
) {
    let ((kw, kh), (left, top), (ow, oh)) = (place.content, place.offset, out);
    let content = resample(image, place.window, kw, kh, Filter::Linear);
    let ids = nearest(label, (image.width, image.height), place);
    for c in 0..image.channels {
        let plane = &mut dst[c * ow * oh..(c + 1) * ow * oh];
        plane.fill(fill[c.min(3)]);
        let src = content.plane(c);
        for r in 0..kh {
            plane[(top + r) * ow + left..][..kw].copy_from_slice(&src[r * kw..][..kw]);
        }
    }
    dst_label.fill(label_fill);
    for r in 0..kh {
        dst_label[(top + r) * ow + left..][..kw].copy_from_slice(&ids[r * kw..][..kw]);
    }
}

/// The crop's content of `label` (frame size `frame`) by OpenCV's `INTER_NEAREST`: scaled pixel
/// (x, y) takes frame pixel (⌊x · w / W⌋, ⌊y · h / H⌋), in exact integer arithmetic.
fn nearest(label: &[u8], (fw, fh): (usize, usize), place: &Placement) -> Vec<u8> {
    let ((kw, kh), (ox, oy), (sw, sh)) = (place.content, place.origin, place.scaled);
    let cols: Vec<usize> = (ox..ox + kw).map(|x| (x * fw / sw).min(fw - 1)).collect();
    let mut out = Vec::with_capacity(kw * kh);
    for y in oy..oy + kh {
        let row = &label[(y * fh / sh).min(fh - 1) * fw..][..fw];
        out.extend(cols.iter().map(|&x| row[x]));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn cmx() -> ScaleCrop {
        ScaleCrop::cmx([0.1, 0.2, 0.3, 0.4])
    }

    /// Every factor of the set comes up, and each crop position stays in the official range:
    /// a crop wholly inside the scaled frame, or one row/column short at the last position
    /// (padded after), or centred padding where the scaled frame is smaller.
    #[test]
    fn draws_follow_the_official_ranges() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut seen = std::collections::BTreeSet::new();
        for _ in 0..600 {
            let p = draw(&cmx(), (64, 48), (64, 48), &mut rng).unwrap();
            seen.insert((p.scale * 100.0) as i32);
            let (sw, sh) = ((64.0 * p.scale) as usize, (48.0 * p.scale) as usize);
            let (kw, kh) = p.content;
            let (left, top) = p.offset;
            match sw > 64 {
                true => assert!(kw == 64 || (kw == 63 && left == 0), "{p:?}"),
                false => assert_eq!((kw, left), (sw, (64 - sw) / 2), "{p:?}"),
            }
            match sh > 48 {
                true => assert!(kh == 48 || (kh == 47 && top == 0), "{p:?}"),
                false => assert_eq!((kh, top), (sh, (48 - sh) / 2), "{p:?}"),
            }
            // The window's size in frame pixels is the content's divided by the scale.
            let width = p.window.x1 - p.window.x0;
            assert!((width - kw as f32 * 64.0 / sw as f32).abs() < 1e-3, "{p:?}");
            assert!(p.window.x0 >= 0.0 && p.window.x1 <= 64.0 + 1e-3, "{p:?}");
            assert!(p.window.y0 >= 0.0 && p.window.y1 <= 48.0 + 1e-3, "{p:?}");
        }
        assert_eq!(seen.len(), 6, "every factor drawn: {seen:?}");
    }

    /// At scale 1 with the crop at the frame's size the frame comes through unchanged, and a
    /// bad set is refused by name.
    #[test]
    fn scale_one_is_the_identity_and_bad_sets_are_refused() {
        let one = ScaleCrop {
            scales: vec![1.0],
            ..cmx()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let p = draw(&one, (8, 6), (8, 6), &mut rng).unwrap();
        assert_eq!((p.content, p.offset), ((8, 6), (0, 0)));
        let image = Planar {
            channels: 4,
            width: 8,
            height: 6,
            data: (0..4 * 48).map(|v| v as f32 / 192.0).collect(),
        };
        let label: Vec<u8> = (0..48).map(|v| (v % 9) as u8).collect();
        let (mut dst, mut ids) = (vec![0.0; 4 * 48], vec![0u8; 48]);
        crop_into(
            &image,
            &label,
            &p,
            (&[0.5; 4], 255),
            (8, 6),
            &mut dst,
            &mut ids,
        );
        assert_eq!((dst, ids), (image.data, label));
        for scales in [vec![], vec![0.0], vec![0.01]] {
            let bad = ScaleCrop { scales, ..cmx() };
            let err = draw(&bad, (8, 6), (8, 6), &mut rng)
                .unwrap_err()
                .to_string();
            assert!(err.contains("scale"), "{err}");
        }
    }

    /// Halved into a crop of the frame's size: the content (bilinear without antialiasing:
    /// each output pixel the mean of a 2×2 block) in the middle, the fill and the label's fill
    /// around it.
    #[test]
    fn a_smaller_scaled_frame_is_centred_in_padding() {
        let half = ScaleCrop {
            scales: vec![0.5],
            ..cmx()
        };
        let p = draw(&half, (8, 4), (8, 4), &mut ChaCha8Rng::seed_from_u64(3)).unwrap();
        assert_eq!((p.content, p.offset), ((4, 2), (2, 1)));
        let image = Planar {
            channels: 1,
            width: 8,
            height: 4,
            data: (0..32).map(|v| v as f32).collect(),
        };
        let label: Vec<u8> = (0..32).map(|v| v as u8).collect();
        let (mut dst, mut ids) = (vec![-1.0; 32], vec![0u8; 32]);
        crop_into(
            &image,
            &label,
            &p,
            (&[0.25; 4], 255),
            (8, 4),
            &mut dst,
            &mut ids,
        );
        // Row 1, columns 2..6: means of rows 0-1, columns (0,1), (2,3), ...
        assert_eq!(&dst[8 + 2..8 + 6], &[4.5, 6.5, 8.5, 10.5]);
        assert_eq!(&dst[16 + 2..16 + 6], &[20.5, 22.5, 24.5, 26.5]);
        assert!(dst[..8].iter().chain(&dst[24..]).all(|&v| v == 0.25));
        assert_eq!([dst[8], dst[9], dst[14], dst[15]], [0.25; 4]);
        // Labels: OpenCV's nearest, scaled pixel x from frame pixel 2x (even rows and columns).
        assert_eq!(&ids[8 + 2..8 + 6], &[0, 2, 4, 6]);
        assert_eq!(&ids[16 + 2..16 + 6], &[16, 18, 20, 22]);
        assert_eq!(ids.iter().filter(|&&v| v == 255).count(), 32 - 8);
    }

    /// Enlarged, the crop is a window of the scaled frame: its content matches the frame's
    /// pixels at the window's position (labels), and no padding appears unless the crop runs
    /// one pixel past the end.
    #[test]
    fn a_larger_scaled_frame_is_cropped_at_the_drawn_position() {
        let double = ScaleCrop {
            scales: vec![2.0],
            ..cmx()
        };
        let label: Vec<u8> = (0..48).map(|v| v as u8).collect();
        let image = Planar {
            channels: 1,
            width: 8,
            height: 6,
            data: label.iter().map(|&v| v as f32).collect(),
        };
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for _ in 0..50 {
            let p = draw(&double, (8, 6), (8, 6), &mut rng).unwrap();
            let (mut dst, mut ids) = (vec![0.0; 48], vec![0u8; 48]);
            crop_into(
                &image,
                &label,
                &p,
                (&[0.0; 4], 255),
                (8, 6),
                &mut dst,
                &mut ids,
            );
            let (x0, y0) = p.origin;
            assert_eq!(
                (x0 as f32 / 2.0, y0 as f32 / 2.0),
                (p.window.x0, p.window.y0)
            );
            for (r, c) in [(0usize, 0usize), (2, 5), (p.content.1 - 1, p.content.0 - 1)] {
                let (sx, sy) = ((x0 + c) / 2, (y0 + r) / 2);
                assert_eq!(ids[r * 8 + c], label[sy * 8 + sx], "{p:?} at ({r}, {c})");
            }
            let padded = ids.iter().filter(|&&v| v == 255).count();
            assert_eq!(padded, 48 - p.content.0 * p.content.1, "{p:?}");
        }
    }
}
