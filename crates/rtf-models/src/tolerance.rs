//! Comparing two floating-point computations of one quantity at the scale of what was summed.
//!
//! Two correct summation orders of one sum differ by rounding noise proportional to the
//! magnitude of the terms summed (about ε·Σ|terms|), not to the magnitude of the result. A
//! quantity that is zero in exact arithmetic — a convolution's bias gradient behind
//! training-mode BatchNorm, say — is all noise, and how large that noise comes out depends on
//! how the CPU's kernels block their sums (AVX2 and AVX-512 kernels differ). A fixed absolute
//! tolerance then compares noise with noise and passes on one CPU and fails on another, so
//! tests state the scale their comparison is made at.

use tch::{Kind, Tensor};

/// Largest |a − b| over all elements (in f64).
pub fn max_abs_diff(a: &Tensor, b: &Tensor) -> f64 {
    (a.to_kind(Kind::Double) - b.to_kind(Kind::Double))
        .abs()
        .max()
        .double_value(&[])
}

/// Largest |t| over all elements (in f64); 0 for an empty tensor.
pub fn max_abs(t: &Tensor) -> f64 {
    if t.numel() == 0 {
        return 0.0;
    }
    t.to_kind(Kind::Double).abs().max().double_value(&[])
}

/// Checks `max |actual − expected| ≤ rel · max(scale, max |expected|)`: `scale` is the
/// magnitude of the terms whose sum was computed (pass 0 where the result's own magnitude is
/// the right scale). The error names `what`, the difference and the bound.
pub fn close_at_scale(
    what: &str,
    actual: &Tensor,
    expected: &Tensor,
    scale: f64,
    rel: f64,
) -> Result<(), String> {
    if actual.size() != expected.size() {
        return Err(format!(
            "{what}: shapes {:?} and {:?}",
            actual.size(),
            expected.size()
        ));
    }
    let bound = rel * scale.max(max_abs(expected));
    let diff = max_abs_diff(actual, expected);
    match diff <= bound {
        true => Ok(()),
        false => Err(format!(
            "{what}: max |difference| {diff:.3e} over the bound {bound:.3e} \
             ({rel:e} × scale {:.3e})",
            scale.max(max_abs(expected))
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_judged_against_the_scale_of_the_terms() {
        let zero_ish = Tensor::from_slice(&[7.6e-6f32, -3.0e-6]);
        let other = Tensor::from_slice(&[-3.0e-6f32, 2.0e-6]);
        // At its own scale (1e-5) the noise is a 100 % difference ...
        assert!(close_at_scale("bias", &zero_ish, &other, 0.0, 1e-4).is_err());
        // ... at the scale of the summed terms (54) it is far below 1e-5 relative.
        assert!(close_at_scale("bias", &zero_ish, &other, 54.0, 1e-5).is_ok());
        let err = close_at_scale("w", &Tensor::from_slice(&[1.0f32]), &other, 0.0, 1e-5);
        assert!(err.unwrap_err().contains("shapes"));
    }

    #[test]
    fn a_real_difference_fails_at_any_reasonable_scale() {
        let a = Tensor::from_slice(&[10.0f32, 20.0]);
        let b = Tensor::from_slice(&[10.0f32, 20.5]);
        let err = close_at_scale("out", &a, &b, 0.0, 1e-4).unwrap_err();
        assert!(err.contains("out") && err.contains("5.000e-1"), "{err}");
        assert_eq!(max_abs_diff(&a, &b), 0.5);
        assert_eq!(max_abs(&b), 20.5);
    }
}
