//! Rendering a scene to radiance, apparent temperature and semantics, exposing the RGB
//! camera, and the box blur used for the thermal optics.

use super::{Object, Scene, Sem, Surface};
use crate::augment::gaussian;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

impl Scene {
    // ---- rendering ---------------------------------------------------------------------------

    /// Renders the scene: linear RGB radiance (3 per pixel), apparent temperature (°C) and
    /// semantics. `t_offset` moves every object by its velocity × t (thermal time offset).
    pub fn render(&self, t_offset: f32) -> RenderedPlanes {
        let (w, h) = (self.width, self.height);
        let mut surfaces: Vec<Surface> = Vec::with_capacity(w * h);
        let mut depth = Vec::with_capacity(w * h);
        for v in 0..h {
            for u in 0..w {
                let (s, d) = self.background(u as f32 + 0.5, v as f32 + 0.5, t_offset);
                surfaces.push(s);
                depth.push(d);
            }
        }
        let mut order: Vec<&Object> = self.objects.iter().collect();
        order.sort_by(|a, b| b.z.total_cmp(&a.z));
        for o in order {
            let ox = o.x + o.velocity[0] * t_offset;
            let oz = o.z + o.velocity[1] * t_offset;
            if oz < 1.0 {
                continue;
            }
            let px_per_m = self.focal / oz;
            let u0 = self.cx + (ox - o.width / 2.0 - self.cam_height * 0.0) * px_per_m;
            let u1 = u0 + o.width * px_per_m;
            let v_bottom = self.horizon + (self.cam_height - o.lift) * px_per_m;
            let v_top = v_bottom - o.height * px_per_m;
            let (iu0, iu1) = (
                u0.floor().max(0.0) as usize,
                (u1.ceil().max(0.0) as usize).min(w),
            );
            let (iv0, iv1) = (
                v_top.floor().max(0.0) as usize,
                (v_bottom.ceil().max(0.0) as usize).min(h),
            );
            let ground_temp = self.ground_temp(
                if (ox - self.road_center).abs() < self.road_half {
                    Sem::Road
                } else {
                    Sem::Sidewalk
                },
                1.0,
            );
            for v in iv0..iv1 {
                for u in iu0..iu1 {
                    let i = v * w + u;
                    if oz >= depth[i] {
                        continue;
                    }
                    let lx = (u as f32 + 0.5 - u0) / px_per_m;
                    let ly = (v as f32 + 0.5 - v_top) / px_per_m;
                    if lx < 0.0 || ly < 0.0 || lx > o.width || ly > o.height {
                        continue;
                    }
                    if let Some(s) = self.object_surface(o, lx, ly, ground_temp) {
                        surfaces[i] = s;
                    }
                }
            }
        }
        let mut radiance = Vec::with_capacity(3 * w * h);
        let mut temp = Vec::with_capacity(w * h);
        let mut sem = Vec::with_capacity(w * h);
        for s in &surfaces {
            let light = self.illumination(s);
            radiance.extend((0..3).map(|c| s.albedo[c] * light[c] + s.emission[c]));
            // Apparent temperature: emitted plus reflected sky (linearised radiometry).
            temp.push(
                s.emissivity * s.temp
                    + (1.0 - s.emissivity) * self.sky_temp.max(self.ambient - 30.0),
            );
            sem.push(s.sem);
        }
        RenderedPlanes {
            radiance,
            temperature: temp,
            sem,
        }
    }

    fn illumination(&self, s: &Surface) -> [f32; 3] {
        if s.sem == Sem::Sky {
            return [1.0; 3];
        }
        if !self.night {
            let l = 0.35 + 0.75 * self.sun_strength * s.sun;
            return [l, l * 0.98, l * 0.95];
        }
        // Night: faint sky glow plus sodium-ish street lamps falling off with distance².
        let mut l = [0.004, 0.0045, 0.006];
        for lamp in &self.lamps {
            let d2 = (lamp[0] - s.pos[0]).powi(2)
                + (lamp[1] - s.pos[1]).powi(2)
                + (lamp[2] - s.pos[2]).powi(2);
            let e = 0.5 / (d2 + 4.0);
            l[0] += e;
            l[1] += e * 0.8;
            l[2] += e * 0.5;
        }
        l
    }

    /// Camera model for RGB: exposure, bloom around over-exposed lights, shot and read noise,
    /// gamma and 8-bit quantisation. Night frames get a higher gain, hence more noise.
    pub fn expose_rgb(&self, radiance: &[f32], rng: &mut ChaCha8Rng) -> Vec<u8> {
        let (w, h) = (self.width, self.height);
        let gain = if self.night {
            rng.random_range(3.0..6.0)
        } else {
            rng.random_range(0.85..1.15)
        };
        let mut lin: Vec<f32> = radiance.iter().map(|v| v * gain).collect();
        // Blooming: light above saturation spreads into a wide halo (glare of headlights/lamps).
        let mut excess: Vec<f32> = lin.iter().map(|v| (v - 1.0).max(0.0)).collect();
        if excess.iter().any(|&v| v > 0.0) {
            let radius = (w / 80).max(1);
            for c in 0..3 {
                let mut plane: Vec<f32> = (0..w * h).map(|i| excess[3 * i + c]).collect();
                for _ in 0..3 {
                    box_blur(&mut plane, w, h, radius);
                }
                for i in 0..w * h {
                    excess[3 * i + c] = plane[i];
                }
            }
            for (l, e) in lin.iter_mut().zip(&excess) {
                *l += 0.8 * e;
            }
        }
        let read = if self.night { 0.006 * gain } else { 0.002 };
        let shot = if self.night { 0.02 * gain } else { 0.004 };
        lin.iter()
            .map(|&v| {
                let v = v.max(0.0);
                let noisy = v + gaussian(rng) * (read * read + shot * v.min(1.0)).sqrt();
                (noisy.clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8
            })
            .collect()
    }
}

pub struct RenderedPlanes {
    pub radiance: Vec<f32>,
    pub temperature: Vec<f32>,
    pub sem: Vec<Sem>,
}

/// In-place box blur (horizontal then vertical) with clamped edges.
pub fn box_blur(plane: &mut [f32], w: usize, h: usize, r: usize) {
    let mut tmp = vec![0.0f32; plane.len()];
    let norm = 1.0 / (2 * r + 1) as f32;
    for y in 0..h {
        let row = &plane[y * w..(y + 1) * w];
        for x in 0..w {
            let mut acc = 0.0;
            for k in 0..=2 * r {
                let xx = (x + k).saturating_sub(r).min(w - 1);
                acc += row[xx];
            }
            tmp[y * w + x] = acc * norm;
        }
    }
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0.0;
            for k in 0..=2 * r {
                let yy = (y + k).saturating_sub(r).min(h - 1);
                acc += tmp[yy * w + x];
            }
            plane[y * w + x] = acc * norm;
        }
    }
}
