//! Deterministic value noise for procedural textures (no RNG state: a pure function of the
//! coordinates and a seed, so textures follow world coordinates under perspective).

/// Hash of an integer lattice point to [0, 1).
pub fn hash01(x: i32, y: i32, seed: u32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8DA6_B343)
        ^ (y as u32).wrapping_mul(0xD816_3841)
        ^ seed.wrapping_mul(0xCB1A_B31F);
    h ^= h >> 13;
    h = h.wrapping_mul(0x5bd1_e995);
    h ^= h >> 15;
    (h >> 8) as f32 / (1u32 << 24) as f32
}

fn value(x: f32, y: f32, seed: u32) -> f32 {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let (ix, iy) = (x0 as i32, y0 as i32);
    let a = hash01(ix, iy, seed);
    let b = hash01(ix + 1, iy, seed);
    let c = hash01(ix, iy + 1, seed);
    let d = hash01(ix + 1, iy + 1, seed);
    a + (b - a) * sx + (c - a) * sy + (a - b - c + d) * sx * sy
}

/// Two octaves of value noise in [0, 1].
pub fn fbm(x: f32, y: f32, seed: u32) -> f32 {
    (value(x, y, seed) * 2.0 + value(x * 2.7, y * 2.7, seed ^ 0x9E37)) / 3.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_deterministic_and_bounded() {
        for i in 0..100 {
            let (x, y) = (i as f32 * 0.37, i as f32 * -1.3);
            let v = fbm(x, y, 7);
            assert_eq!(v, fbm(x, y, 7));
            assert!((0.0..=1.0).contains(&v));
        }
        assert_ne!(fbm(0.5, 0.5, 1), fbm(0.5, 0.5, 2));
    }
}
