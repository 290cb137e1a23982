//! Semi-global matching (Hirschmüller 2008) on a rectified RGB pair: 5×5 census costs, eight
//! aggregation paths, winner-takes-all with a uniqueness test and parabolic sub-pixel
//! refinement, a left-right consistency check and a 3×3 median. Depth = f·B / d; rejected
//! pixels get depth 0 (unknown), which the calibration loss leaves out.

use crate::imageio::Plane;
use rayon::prelude::*;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SgmParams {
    /// Nearest depth searched (metres); sets the disparity range f·B / min_depth.
    pub min_depth_m: f64,
    /// Penalty for a ±1 disparity change between neighbours (census units).
    pub p1: u16,
    /// Penalty for larger jumps.
    pub p2: u16,
    /// The best cost must beat the second best (outside ±1) by this factor.
    pub uniqueness: f32,
}

impl Default for SgmParams {
    fn default() -> Self {
        Self {
            min_depth_m: 1.5,
            p1: 3,
            p2: 20,
            uniqueness: 0.95,
        }
    }
}

fn census(p: &Plane) -> Vec<u32> {
    let (w, h) = (p.width as isize, p.height as isize);
    let at = |x: isize, y: isize| p.at(x.clamp(0, w - 1) as usize, y.clamp(0, h - 1) as usize);
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..w).map(move |x| {
                let c = at(x, y);
                let mut bits = 0u32;
                for dy in -2..=2 {
                    for dx in -2..=2 {
                        if dx != 0 || dy != 0 {
                            bits = (bits << 1) | u32::from(at(x + dx, y + dy) < c);
                        }
                    }
                }
                bits
            })
        })
        .collect()
}

/// Adds the path costs L_r along direction (dx, dy) to `sum`.
fn aggregate(
    cost: &[u16],
    w: usize,
    h: usize,
    nd: usize,
    dir: (isize, isize),
    prm: &SgmParams,
    sum: &mut [u16],
) {
    let (dx, dy) = dir;
    let mut prev_row = vec![0u16; w * nd];
    let mut cur_row = vec![0u16; w * nd];
    let rows: Vec<usize> = if dy >= 0 {
        (0..h).collect()
    } else {
        (0..h).rev().collect()
    };
    let cols: Vec<usize> = if dx >= 0 {
        (0..w).collect()
    } else {
        (0..w).rev().collect()
    };
    let mut lp = vec![0u16; nd];
    for (ri, &y) in rows.iter().enumerate() {
        for &x in &cols {
            let (px, py) = (x as isize - dx, y as isize - dy);
            let inside =
                px >= 0 && px < w as isize && py >= 0 && py < h as isize && (dy == 0 || ri > 0);
            let c = &cost[(y * w + x) * nd..(y * w + x + 1) * nd];
            let out_base = x * nd;
            if !inside {
                cur_row[out_base..out_base + nd].copy_from_slice(c);
            } else {
                let src = if dy == 0 { &cur_row } else { &prev_row };
                lp.copy_from_slice(&src[px as usize * nd..(px as usize + 1) * nd]);
                let min_prev = *lp.iter().min().unwrap();
                for d in 0..nd {
                    let mut best = lp[d];
                    if d > 0 {
                        best = best.min(lp[d - 1] + prm.p1);
                    }
                    if d + 1 < nd {
                        best = best.min(lp[d + 1] + prm.p1);
                    }
                    best = best.min(min_prev + prm.p2);
                    cur_row[out_base + d] = c[d] + best - min_prev;
                }
            }
            let s = &mut sum[(y * w + x) * nd..(y * w + x + 1) * nd];
            for d in 0..nd {
                s[d] += cur_row[out_base + d];
            }
        }
        if dy != 0 {
            std::mem::swap(&mut prev_row, &mut cur_row);
        }
    }
}

/// Disparity of the left image (pixels, NaN = rejected): census matching costs, aggregated
/// along eight paths, winner-take-all both ways, left–right checked, 3×3 median.
pub fn disparity(left: &Plane, right: &Plane, max_disparity: usize, prm: &SgmParams) -> Vec<f32> {
    let (w, h) = (left.width, left.height);
    let nd = max_disparity.max(2) + 1;
    let cost = census_costs(left, right, nd);
    let sum = aggregate_all(&cost, w, h, nd, prm);
    drop(cost);
    let left_disp = left_disparities(&sum, w, h, nd, prm);
    let right_disp = right_disparities(&sum, w, h, nd);
    let checked = left_right_checked(&left_disp, &right_disp, w);
    median3(&checked, w, h)
}

/// Hamming distances of the census codes, `[y][x][d]` (24, the maximum, where x − d < 0).
fn census_costs(left: &Plane, right: &Plane, nd: usize) -> Vec<u16> {
    let w = left.width;
    let (cl, cr) = (census(left), census(right));
    let mut cost = vec![24u16; w * left.height * nd];
    cost.par_chunks_mut(w * nd)
        .enumerate()
        .for_each(|(y, row)| {
            for x in 0..w {
                for d in 0..nd.min(x + 1) {
                    row[x * nd + d] = (cl[y * w + x] ^ cr[y * w + x - d]).count_ones() as u16;
                }
            }
        });
    cost
}

/// The costs aggregated along the eight SGM paths and summed.
fn aggregate_all(cost: &[u16], w: usize, h: usize, nd: usize, prm: &SgmParams) -> Vec<u16> {
    let dirs = [
        (1, 0),
        (-1, 0),
        (0, 1),
        (0, -1),
        (1, 1),
        (-1, 1),
        (1, -1),
        (-1, -1),
    ];
    let partial: Vec<Vec<u16>> = dirs
        .par_iter()
        .map(|&dir| {
            let mut s = vec![0u16; w * h * nd];
            aggregate(cost, w, h, nd, dir, prm, &mut s);
            s
        })
        .collect();
    let mut sum = vec![0u16; w * h * nd];
    for p in &partial {
        sum.par_iter_mut()
            .zip(p.par_iter())
            .for_each(|(a, b)| *a += b);
    }
    sum
}

/// Left disparities with the uniqueness test and parabolic sub-pixel refinement.
fn left_disparities(sum: &[u16], w: usize, h: usize, nd: usize, prm: &SgmParams) -> Vec<f32> {
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let s = &sum[i * nd..(i + 1) * nd];
            let x = i % w;
            let valid = nd.min(x + 1);
            let (mut best, mut bd) = (u16::MAX, 0);
            for (d, &cost) in s.iter().enumerate().take(valid) {
                if cost < best {
                    best = cost;
                    bd = d;
                }
            }
            let second = (0..valid)
                .filter(|&d| d + 1 < bd || d > bd + 1)
                .map(|d| s[d])
                .min()
                .unwrap_or(u16::MAX);
            if (best as f32) > prm.uniqueness * second as f32 || bd == 0 || bd + 1 >= valid {
                return f32::NAN;
            }
            let (a, b, c) = (s[bd - 1] as f32, s[bd] as f32, s[bd + 1] as f32);
            let denom = a - 2.0 * b + c;
            let offset = if denom > 0.0 {
                ((a - c) / (2.0 * denom)).clamp(-0.5, 0.5)
            } else {
                0.0
            };
            bd as f32 + offset
        })
        .collect()
}

/// Right disparities from the same aggregated costs: d_R(x) = argmin_d S(x + d, d).
fn right_disparities(sum: &[u16], w: usize, h: usize, nd: usize) -> Vec<f32> {
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let (mut best, mut bd) = (u16::MAX, usize::MAX);
            for d in 0..nd {
                if x + d >= w {
                    break;
                }
                let v = sum[(y * w + x + d) * nd + d];
                if v < best {
                    best = v;
                    bd = d;
                }
            }
            if bd == usize::MAX {
                f32::NAN
            } else {
                bd as f32
            }
        })
        .collect()
}

/// Left disparities that the right image confirms within 1 px, the others rejected.
fn left_right_checked(left_disp: &[f32], right_disp: &[f32], w: usize) -> Vec<f32> {
    (0..left_disp.len())
        .map(|i| {
            let d = left_disp[i];
            if d.is_nan() {
                return f32::NAN;
            }
            let (x, y) = (i % w, i / w);
            let xr = (x as f32 - d).round();
            if xr < 0.0 {
                return f32::NAN;
            }
            let dr = right_disp[y * w + xr as usize];
            if (dr - d).abs() <= 1.0 {
                d
            } else {
                f32::NAN
            }
        })
        .collect()
}

/// 3×3 median over valid neighbours (needs at least 5 valid, else rejected).
fn median3(d: &[f32], w: usize, h: usize) -> Vec<f32> {
    (0..w * h)
        .map(|i| {
            if d[i].is_nan() {
                return f32::NAN;
            }
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            let mut v: Vec<f32> = Vec::with_capacity(9);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx >= 0 && ny >= 0 && (nx as usize) < w && (ny as usize) < h {
                        let s = d[ny as usize * w + nx as usize];
                        if !s.is_nan() {
                            v.push(s);
                        }
                    }
                }
            }
            if v.len() < 5 {
                return f32::NAN;
            }
            v.sort_by(f32::total_cmp);
            v[v.len() / 2]
        })
        .collect()
}

/// z-depth (metres, 0 = unknown) of the left image from a rectified pair.
pub fn depth_from_stereo(
    left: &Plane,
    right: &Plane,
    focal_px: f64,
    baseline_m: f64,
    prm: &SgmParams,
) -> Plane {
    let max_d =
        ((focal_px * baseline_m / prm.min_depth_m).ceil() as usize).clamp(4, left.width / 2);
    let disp = disparity(left, right, max_d, prm);
    let data = disp
        .iter()
        .map(|&d| {
            if d.is_nan() || d < 0.5 {
                0.0
            } else {
                (focal_px * baseline_m / d as f64) as f32
            }
        })
        .collect();
    Plane::new(left.width, left.height, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_depth_of_a_textured_fronto_parallel_scene() {
        // Random texture; the near square is shifted by 8 px, the background by 3 px.
        let (w, h) = (96, 64);
        let tex = |x: i64, y: i64| (((x * 7919 + y * 104729) ^ (x * y * 31)) % 97) as f32 / 97.0;
        let disp_at = |x: usize, y: usize| {
            if (30..60).contains(&x) && (20..44).contains(&y) {
                8
            } else {
                3
            }
        };
        let mut left = vec![0.0; w * h];
        let mut right = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                left[y * w + x] = tex(x as i64, y as i64);
            }
        }
        for y in 0..h {
            for xr in 0..w {
                // Right pixel xr sees left pixel xr + d of whichever surface is in front.
                let near = xr + 8;
                let xl = if near < w && disp_at(near, y) == 8 {
                    near
                } else {
                    xr + 3
                };
                right[y * w + xr] = tex(xl as i64, y as i64);
            }
        }
        let (l, r) = (Plane::new(w, h, left), Plane::new(w, h, right));
        let depth = depth_from_stereo(
            &l,
            &r,
            100.0,
            0.3,
            &SgmParams {
                min_depth_m: 2.0,
                ..Default::default()
            },
        );
        let (mut good, mut total) = (0, 0);
        for y in 4..h - 4 {
            for x in 20..w - 4 {
                let truth = 30.0 / disp_at(x, y) as f32;
                let d = depth.at(x, y);
                total += 1;
                if d > 0.0 && (d - truth).abs() < 0.05 * truth {
                    good += 1;
                }
            }
        }
        assert!(
            good as f64 > 0.8 * total as f64,
            "{good}/{total} pixels within 5 %"
        );
    }
}
