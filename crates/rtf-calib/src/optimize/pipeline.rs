//! The default recipe's staged coarse-to-fine pipeline (ours; HeatNet §IV-A fits everything
//! at once at full resolution, see the [module doc](super)).
//!
//! A [`Pipeline`] builds the pyramid levels once ([`super::levels`], the finer ones on a
//! pixel subset), searches an image shift exhaustively at the coarsest level
//! ([`Pipeline::search`]) and refines level by level with Levenberg-Marquardt
//! ([`super::lm`]), freeing the parameters in stages ([`Staging`], [`staged_params`]):
//! first the image-plane model, then rotation, translation and k1, at the finest level
//! everything. The wrong-basin check that reruns it from perturbed starts is
//! `restart.rs`; the recipe that drives both is `default_recipe.rs`.

use super::levels::{cost, depth_samples, pyramid_factors, Level, Scaling, MAX_LEVEL_PIXELS};
use super::lm::{directions, lm_level};
use super::prior::Priors;
use super::settings::Settings;
use crate::frames::Frame;
use crate::model::{self, NUM_PARAMS};
use crate::rig::Rig;
use tch::Tensor;

/// The default recipe's coarse-to-fine pipeline over a fixed set of frames: the pyramid
/// levels (built once), the parameter scaling and the staging, so that the main run and the
/// restarts of the wrong-basin check ([`crate::quality`]) share them.
pub struct Pipeline<'a> {
    pub rig: &'a Rig,
    pub used: Vec<&'a Frame>,
    pub scaling: Scaling,
    pub square: bool,
    pub factors: Vec<usize>,
    pub levels: Vec<Level>,
    pub iterations: usize,
    pub lambda0: f64,
    /// RGB pixels with depth (u, v, metres), ~400 per frame, for map distances.
    pub samples: Vec<(f64, f64, f64)>,
    pub staging: Staging,
}

/// How [`Pipeline::params`] frees the parameters over the coarse levels. Both fit the
/// image-plane model (f, c, roll) at the coarsest levels, add rotation, translation and k1 at
/// the level before the finest and free everything at the finest; they differ in when the
/// translation is freed. On the 640×480 real-imagery trials neither is right for every rig:
/// a rig whose thermal camera sits 10–17 cm to the side ends 3–4 px off when the translation
/// stays fixed down to the 320-px level (the principal point absorbs the parallax), while on
/// night rigs with little shared structure a translation freed at 80 px wanders off. So
/// the default recipe (`calibrate_default`) runs both up to the check level and goes on with
/// the early one only where it costs clearly less there (by more than
/// [`RESTART_TIE`](super::RESTART_TIE)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Staging {
    /// Rotation, translation and k1 from the first level at least 80 px wide.
    Early,
    /// Rotation, translation and k1 only from the level before the finest.
    Late,
}

/// The parameters [`Staging`] frees at a level `above_finest` levels above the finest one
/// and `width` px wide: the image-plane model (f, c, roll), that plus rotation, translation
/// and k1, or everything.
pub fn staged_params(staging: Staging, above_finest: usize, width: usize) -> Vec<usize> {
    let image_plane = vec![0, 1, 2, 3, 13];
    let middle = vec![0, 1, 2, 3, 4, 8, 9, 10, 11, 12, 13];
    match (above_finest, staging) {
        (0, _) => (0..NUM_PARAMS).collect(),
        (1, _) => middle,
        (_, Staging::Early) if width >= 80 => middle,
        _ => image_plane,
    }
}

/// Result of [`Pipeline::refine`].
pub struct Refined {
    pub theta: [f64; NUM_PARAMS],
    /// Final cost (data + priors) at the last level run.
    pub cost: f64,
    pub iterations: usize,
    /// The level factor where the loss became non-finite, if it did.
    pub non_finite: Option<usize>,
}

impl<'a> Pipeline<'a> {
    pub fn new(
        rig: &'a Rig,
        used: Vec<&'a Frame>,
        p0: [f64; NUM_PARAMS],
        settings: &Settings,
    ) -> Self {
        let samples = depth_samples(&used);
        let scaling = Scaling {
            p0,
            scale: model::pixel_scales(&rig.rgb, &p0, &samples),
        };
        let factors = pyramid_factors(rig.rgb.width);
        let levels = factors
            .iter()
            .enumerate()
            .map(|(li, &factor)| {
                // A wide blur only where the basin must be wide (the coarsest level, after the
                // shift search); finer levels use the features unblurred, since blur lets edges
                // present in one band only pull on shared edges (σ = 1 / 0.6 / 0 at full and
                // half resolution: 0.32 / 0.22 / 0.18 px mean map error on a 160×120 rig).
                let (sigma, taps) = if li == 0 { (2.0, 13) } else { (0.0, 1) };
                let level = Level::build(&rig.rgb, &used, factor, false, sigma, taps);
                // Levels larger than MAX_LEVEL_PIXELS use a random subset of that many pixels
                // per frame, at full feature resolution.
                if li > 0 && (level.h * level.w) as usize > MAX_LEVEL_PIXELS {
                    level.subsample(MAX_LEVEL_PIXELS, settings.seed ^ factor as u64)
                } else {
                    level
                }
            })
            .collect();
        Self {
            rig,
            used,
            scaling,
            square: rig.thermal.square_pixels.unwrap_or(true),
            factors,
            levels,
            iterations: settings.iterations,
            lambda0: 1e-5 / settings.learning_rate,
            samples,
            staging: Staging::Late,
        }
    }

    /// A copy sharing the level tensors (for other threads).
    pub fn shallow(&self) -> Pipeline<'a> {
        Pipeline {
            rig: self.rig,
            used: self.used.clone(),
            scaling: Scaling {
                p0: self.scaling.p0,
                scale: self.scaling.scale,
            },
            square: self.square,
            factors: self.factors.clone(),
            levels: self.levels.iter().map(Level::shallow).collect(),
            iterations: self.iterations,
            lambda0: self.lambda0,
            samples: self.samples.clone(),
            staging: self.staging,
        }
    }

    /// [`Pipeline::refine`] over levels `from..=to` only.
    pub fn refine_between(
        &self,
        theta: [f64; NUM_PARAMS],
        from: usize,
        to: usize,
        on_iteration: &mut dyn FnMut(usize, f64),
    ) -> [f64; NUM_PARAMS] {
        self.refine_levels(theta, from, to + 1, on_iteration).theta
    }

    pub(super) fn all(&self) -> Vec<i64> {
        (0..self.used.len() as i64).collect()
    }

    /// Exhaustive search at the coarsest level over an image shift (cx, cy) around `theta`:
    /// the largest, most non-convex part of the initial misalignment (rotation and
    /// principal-point offsets). Returns the `k` best shifts that are local minima of the
    /// search grid, best first, with their costs.
    pub fn search(&self, theta: [f64; NUM_PARAMS], k: usize) -> Vec<(f64, [f64; NUM_PARAMS])> {
        let level = &self.levels[0];
        let factor = level.factor;
        let idx = Tensor::from_slice(&self.all());
        let range = (0.1 * self.rig.thermal.width as f64 / factor as f64).ceil() as i64;
        let n = (2 * range + 1) as usize;
        let mut grid = vec![f64::INFINITY; n * n];
        for dy in -range..=range {
            for dx in -range..=range {
                let mut t = theta;
                t[2] += (dx * factor as i64) as f64;
                t[3] += (dy * factor as i64) as f64;
                grid[(dy + range) as usize * n + (dx + range) as usize] =
                    cost(level, &self.scaling, &t, &idx);
            }
        }
        let mut minima: Vec<(f64, [f64; NUM_PARAMS])> = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let c = grid[y * n + x];
                let is_min = (-1i64..=1).all(|ey| {
                    (-1i64..=1).all(|ex| {
                        let (yy, xx) = (y as i64 + ey, x as i64 + ex);
                        (ey == 0 && ex == 0)
                            || yy < 0
                            || xx < 0
                            || yy >= n as i64
                            || xx >= n as i64
                            || grid[yy as usize * n + xx as usize] >= c
                    })
                });
                if is_min && c.is_finite() {
                    let mut t = theta;
                    t[2] += ((x as i64 - range) * factor as i64) as f64;
                    t[3] += ((y as i64 - range) * factor as i64) as f64;
                    minima.push((c, t));
                }
            }
        }
        minima.sort_by(|a, b| a.0.total_cmp(&b.0));
        if minima.is_empty() {
            minima.push((cost(level, &self.scaling, &theta, &idx), theta));
        }
        minima.truncate(k.max(1));
        minima
    }

    /// Staged parameters of level `li` ([`Staging`]): at coarse levels pan/tilt are
    /// indistinguishable from the principal point and translation from both, and letting
    /// them drift along that valley leads to wrong minima; so the coarsest levels fit an
    /// image-plane model (f, c, roll), then rotation, translation and k1 are added, and the
    /// finest level frees everything.
    pub fn params(&self, li: usize) -> Vec<usize> {
        let (above_finest, width) = self.level_place(li);
        staged_params(self.staging, above_finest, width)
    }

    /// Level `li`'s place for [`staged_params`]: levels above the finest, width in px.
    fn level_place(&self, li: usize) -> (usize, usize) {
        (
            self.factors.len() - 1 - li,
            self.rig.rgb.width / self.factors[li],
        )
    }

    /// Whether the two stagings free the same parameters at every level up to `to`.
    pub(super) fn stagings_agree(&self, to: usize) -> bool {
        (0..=to).all(|li| {
            let (above_finest, width) = self.level_place(li);
            staged_params(Staging::Early, above_finest, width)
                == staged_params(Staging::Late, above_finest, width)
        })
    }

    /// Levenberg-Marquardt from `theta` at levels `from..` (coarse to fine).
    pub fn refine(
        &self,
        theta: [f64; NUM_PARAMS],
        from: usize,
        on_iteration: &mut dyn FnMut(usize, f64),
    ) -> Refined {
        self.refine_levels(theta, from, self.levels.len(), on_iteration)
    }

    pub(super) fn refine_levels(
        &self,
        mut theta: [f64; NUM_PARAMS],
        from: usize,
        to: usize,
        on_iteration: &mut dyn FnMut(usize, f64),
    ) -> Refined {
        let all = self.all();
        let mut out = Refined {
            theta,
            cost: f64::NAN,
            iterations: 0,
            non_finite: None,
        };
        for li in from..to {
            let level = &self.levels[li];
            let dirs = directions(&self.params(li), &self.scaling, self.square);
            let mut priors = Priors::new(self.rig);
            let run = lm_level(
                level,
                &self.scaling,
                &mut priors,
                theta,
                &dirs,
                &all,
                self.iterations,
                self.lambda0,
                &mut |loss| on_iteration(level.factor, loss),
            );
            theta = run.theta;
            out.theta = theta;
            out.cost = run.cost;
            out.iterations += run.iterations;
            if run.non_finite {
                out.non_finite = Some(level.factor);
                break;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stagings_differ_only_where_a_level_of_80_px_lies_above_the_last_two() {
        let widths = |w: usize| -> Vec<(usize, usize)> {
            let f = pyramid_factors(w);
            (0..f.len())
                .map(|li| (f.len() - 1 - li, w / f[li]))
                .collect()
        };
        let plan = |s: Staging, w: usize| -> Vec<usize> {
            widths(w)
                .into_iter()
                .map(|(above, width)| staged_params(s, above, width).len())
                .collect()
        };
        // 160 px wide (40, 80, 160): one schedule, so calibrate_default runs it once.
        assert_eq!(plan(Staging::Late, 160), plan(Staging::Early, 160));
        assert_eq!(plan(Staging::Late, 160), vec![5, 11, NUM_PARAMS]);
        // 640 px wide (40, 80, 160, 320, 640): the early staging frees the translation and
        // k1 at 80 and 160 px, the late one only at 320.
        assert_eq!(plan(Staging::Late, 640), vec![5, 5, 5, 11, NUM_PARAMS]);
        assert_eq!(plan(Staging::Early, 640), vec![5, 11, 11, 11, NUM_PARAMS]);
        for (above, width) in widths(640) {
            let (early, late) = (
                staged_params(Staging::Early, above, width),
                staged_params(Staging::Late, above, width),
            );
            // Focal length, principal point and roll are free everywhere; translation
            // (8..=10) never in the image-plane model.
            assert!([0, 1, 2, 3, 13]
                .iter()
                .all(|p| early.contains(p) && late.contains(p)));
            assert_eq!(late.contains(&8), above <= 1);
        }
    }
}
