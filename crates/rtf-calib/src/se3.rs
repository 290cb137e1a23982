//! Rigid transforms in se(3) exponential coordinates ξ = (v, ω), with the exact exponential and
//! logarithm (t = V(ω)·v), in f64. The differentiable tensor version lives in `model`.

pub type Mat3 = [[f64; 3]; 3];
pub type Vec3 = [f64; 3];

pub fn skew(w: Vec3) -> Mat3 {
    [[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]]
}

pub fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

pub fn mat_vec(a: &Mat3, x: Vec3) -> Vec3 {
    [0, 1, 2].map(|i| a[i][0] * x[0] + a[i][1] * x[1] + a[i][2] * x[2])
}

pub fn transpose(a: &Mat3) -> Mat3 {
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| a[j][i]))
}

fn add_scaled(acc: &mut Mat3, m: &Mat3, s: f64) {
    for i in 0..3 {
        for j in 0..3 {
            acc[i][j] += s * m[i][j];
        }
    }
}

fn identity() -> Mat3 {
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
}

/// Coefficients A = sinθ/θ, B = (1−cosθ)/θ², C = (θ−sinθ)/θ³, with series near 0.
pub fn coefficients(theta2: f64) -> (f64, f64, f64) {
    if theta2 < 1e-8 {
        let t2 = theta2;
        (
            1.0 - t2 / 6.0 + t2 * t2 / 120.0,
            0.5 - t2 / 24.0 + t2 * t2 / 720.0,
            1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0,
        )
    } else {
        let t = theta2.sqrt();
        (
            t.sin() / t,
            (1.0 - t.cos()) / theta2,
            (t - t.sin()) / (theta2 * t),
        )
    }
}

/// A rigid transform X' = R·X + t.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid {
    pub rotation: Mat3,
    pub translation: Vec3,
}

impl Rigid {
    pub fn identity() -> Self {
        Self {
            rotation: identity(),
            translation: [0.0; 3],
        }
    }

    pub fn apply(&self, x: Vec3) -> Vec3 {
        let r = mat_vec(&self.rotation, x);
        [
            r[0] + self.translation[0],
            r[1] + self.translation[1],
            r[2] + self.translation[2],
        ]
    }

    /// The inverse transform: X = Rᵀ·(X' − t).
    pub fn inverse(&self) -> Self {
        let rt = transpose(&self.rotation);
        let t = mat_vec(&rt, self.translation);
        Self {
            rotation: rt,
            translation: [-t[0], -t[1], -t[2]],
        }
    }

    /// Exponential map of ξ = [v1, v2, v3, ω1, ω2, ω3].
    pub fn exp(xi: [f64; 6]) -> Self {
        let v = [xi[0], xi[1], xi[2]];
        let w = [xi[3], xi[4], xi[5]];
        let theta2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
        let (a, b, c) = coefficients(theta2);
        let k = skew(w);
        let k2 = mat_mul(&k, &k);
        let mut r = identity();
        add_scaled(&mut r, &k, a);
        add_scaled(&mut r, &k2, b);
        let mut vm = identity();
        add_scaled(&mut vm, &k, b);
        add_scaled(&mut vm, &k2, c);
        Self {
            rotation: r,
            translation: mat_vec(&vm, v),
        }
    }

    /// Exact logarithm: ω from R (robust near θ = π), then v = V(ω)⁻¹·t.
    pub fn log(&self) -> [f64; 6] {
        let r = &self.rotation;
        let cos = ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0).clamp(-1.0, 1.0);
        let theta = cos.acos();
        let vee = [r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]];
        let w = if theta < 1e-6 {
            // sinθ/θ ≈ 1 − θ²/6: ω ≈ vee/2 with a second-order correction.
            let s = 0.5 * (1.0 + theta * theta / 6.0);
            vee.map(|x| x * s)
        } else if std::f64::consts::PI - theta < 1e-4 {
            // Near π the antisymmetric part vanishes: take the axis from R + I.
            let diag = [r[0][0], r[1][1], r[2][2]];
            let i = (0..3).max_by(|&a, &b| diag[a].total_cmp(&diag[b])).unwrap();
            let mut axis = [0.0; 3];
            let denom = (2.0 * (1.0 + r[i][i])).sqrt();
            for j in 0..3 {
                axis[j] = (r[j][i] + r[i][j]) / (2.0 * denom);
            }
            axis[i] = denom / 2.0;
            let sign = if axis[0] * vee[0] + axis[1] * vee[1] + axis[2] * vee[2] < 0.0 {
                -1.0
            } else {
                1.0
            };
            axis.map(|x| sign * x * theta)
        } else {
            let s = theta / (2.0 * theta.sin());
            vee.map(|x| x * s)
        };
        let theta2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
        let (a, b, _) = coefficients(theta2);
        // V⁻¹ = I − K/2 + (1/θ²)(1 − A/(2B)) K².
        let coef = if theta2 < 1e-8 {
            1.0 / 12.0 + theta2 / 720.0
        } else {
            (1.0 - a / (2.0 * b)) / theta2
        };
        let k = skew(w);
        let k2 = mat_mul(&k, &k);
        let mut vinv = identity();
        add_scaled(&mut vinv, &k, -0.5);
        add_scaled(&mut vinv, &k2, coef);
        let v = mat_vec(&vinv, self.translation);
        [v[0], v[1], v[2], w[0], w[1], w[2]]
    }

    /// Rotation angle of R in radians.
    pub fn angle(&self) -> f64 {
        let r = &self.rotation;
        ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos()
    }

    /// Rotation angle (degrees) and translation distance (metres) between two transforms.
    pub fn difference(&self, other: &Rigid) -> (f64, f64) {
        let rel = mat_mul(&self.rotation, &transpose(&other.rotation));
        let angle = Rigid {
            rotation: rel,
            translation: [0.0; 3],
        }
        .angle()
        .to_degrees();
        let d: f64 = (0..3)
            .map(|i| (self.translation[i] - other.translation[i]).powi(2))
            .sum();
        (angle, d.sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &[f64], b: &[f64], tol: f64) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < tol)
    }

    #[test]
    fn exp_log_round_trip_over_angles() {
        for (i, scale) in [0.0, 1e-9, 1e-5, 0.01, 0.3, 1.5, 3.0].iter().enumerate() {
            let xi = [
                0.05 * i as f64,
                -0.02,
                0.3,
                0.6 * scale,
                -0.3 * scale,
                0.74 * scale,
            ];
            let back = Rigid::exp(xi).log();
            assert!(close(&xi, &back, 1e-9), "{xi:?} -> {back:?}");
        }
    }

    #[test]
    fn log_exp_round_trip_and_rotation_is_orthonormal() {
        let t = Rigid::exp([0.1, 0.2, -0.05, 0.02, -0.04, 0.01]);
        let rtr = mat_mul(&transpose(&t.rotation), &t.rotation);
        assert!(close(&rtr.concat(), &identity().concat(), 1e-12));
        let again = Rigid::exp(t.log());
        assert!(close(&again.rotation.concat(), &t.rotation.concat(), 1e-12));
        assert!(close(&again.translation, &t.translation, 1e-12));
    }

    #[test]
    fn log_near_pi_recovers_rotation() {
        let xi = [0.1, 0.0, 0.0, 0.0, 0.0, std::f64::consts::PI - 1e-6];
        let t = Rigid::exp(xi);
        let again = Rigid::exp(t.log());
        assert!(close(&again.rotation.concat(), &t.rotation.concat(), 1e-6));
    }

    #[test]
    fn inverse_composes_to_identity() {
        let t = Rigid::exp([0.1, 0.2, -0.05, 0.2, -0.4, 0.1]);
        let x = [1.0, -2.0, 5.0];
        let back = t.inverse().apply(t.apply(x));
        assert!(close(&back, &x, 1e-12));
        let (angle, dist) = t.difference(&t);
        assert!(angle < 1e-6 && dist < 1e-12);
    }
}
