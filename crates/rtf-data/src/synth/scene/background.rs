//! The static background: ground and clothing temperatures, the road, sidewalks and
//! terrain with shadows, the facades, fences and hedges of the blocks, the guardrail and the sky.

use super::{rgb, Block, BlockKind, CarView, Kind, Scene, Sem, Surface};
use crate::synth::noise::{fbm, hash01};

impl Scene {
    // ---- temperatures (°C) -------------------------------------------------------------------

    /// Road and ground surfaces are warmed by the sun by day and keep a little heat at night.
    pub(super) fn ground_temp(&self, sem: Sem, sun: f32) -> f32 {
        let heat = match (sem, self.night) {
            (Sem::Road | Sem::Bump, false) => 4.0 + 6.0 * sun,
            (Sem::Road | Sem::Bump, true) => 2.0,
            (Sem::Sidewalk | Sem::Curb | Sem::CarStop, false) => 2.0 + 5.0 * sun,
            (Sem::Sidewalk | Sem::Curb | Sem::CarStop, true) => 1.0,
            (Sem::Terrain, false) => 1.0 + 3.0 * sun,
            (Sem::Terrain, true) => -1.0,
            _ => 0.0,
        };
        self.ambient + heat
    }

    /// Clothing surface between skin (34 °C) and air (warmer coats by night); sun adds by day.
    pub(super) fn clothing_temp(&self) -> f32 {
        let insulation = if self.night { 0.45 } else { 0.55 };
        self.ambient + insulation * (34.0 - self.ambient) + if self.night { 0.0 } else { 3.0 }
    }

    // ---- background ----------------------------------------------------------------------

    fn block_at(&self, side: usize, z: f32) -> Option<&Block> {
        self.blocks[side].iter().find(|b| z >= b.z0 && z < b.z1)
    }

    fn in_shadow(&self, x: f32, z: f32, t_offset: f32) -> bool {
        if self.night {
            return false;
        }
        self.objects.iter().any(|o| {
            if matches!(o.kind, Kind::Lamp) {
                return false;
            }
            let (ox, oz) = (
                o.x + o.velocity[0] * t_offset,
                o.z + o.velocity[1] * t_offset,
            );
            let depth = if matches!(
                o.kind,
                Kind::Car {
                    view: CarView::Side,
                    ..
                }
            ) {
                1.8
            } else {
                o.width.min(1.8)
            };
            let len = o.height + o.lift;
            let (sx, sz) = (self.shadow_dir[0] * len, self.shadow_dir[1] * len);
            let half = o.width / 2.0;
            // Shadow = the footprint swept along the sun direction.
            let t = ((z - oz) / sz.max(1e-3)).clamp(0.0, 1.0);
            let cx = ox + sx * t;
            z >= oz - depth / 2.0 && z <= oz + sz + depth / 2.0 && (x - cx).abs() <= half
        })
    }

    fn ground(&self, x: f32, z: f32, t_offset: f32) -> Surface {
        let d = x - self.road_center;
        let ad = d.abs();
        let seed = self.seed;
        let grain = fbm(x * 3.0, z * 3.0, seed);
        let sem = if ad < self.road_half {
            match self.bump {
                Some((z0, z1)) if z >= z0 && z < z1 => Sem::Bump,
                _ => Sem::Road,
            }
        } else if ad < self.road_half + self.curb_width {
            Sem::Curb
        } else if ad < self.road_half + self.curb_width + self.sidewalk {
            Sem::Sidewalk
        } else {
            Sem::Terrain
        };
        let mut albedo = match sem {
            Sem::Road => {
                let marking = (d.abs() < 0.08 && (z / 6.0).fract() < 0.5)
                    || (ad > self.road_half - 0.3 && ad < self.road_half - 0.18);
                if marking {
                    rgb(0.75, 0.75, 0.72)
                } else {
                    rgb(0.13, 0.13, 0.14).map(|v| v * (0.8 + 0.4 * grain))
                }
            }
            Sem::Bump => {
                if ((x - self.road_center) / 0.5).rem_euclid(2.0) < 1.0 {
                    rgb(0.85, 0.70, 0.05)
                } else {
                    rgb(0.06, 0.06, 0.06)
                }
            }
            Sem::Curb => rgb(0.55, 0.55, 0.52),
            Sem::Sidewalk => {
                let tile = ((x * 2.0).floor() + (z * 2.0).floor()).rem_euclid(2.0);
                rgb(0.42, 0.40, 0.38).map(|v| v * (0.9 + 0.1 * tile + 0.15 * grain))
            }
            _ => rgb(0.20, 0.32, 0.10).map(|v| v * (0.7 + 0.6 * grain)),
        };
        if sem == Sem::Bump {
            albedo = albedo.map(|v| v * (0.9 + 0.2 * grain));
        }
        let sun = if self.in_shadow(x, z, t_offset) {
            0.0
        } else {
            1.0
        };
        // Painted bumps share the road's temperature and emissivity: invisible in thermal.
        let temp = self.ground_temp(sem, sun);
        Surface {
            sem,
            albedo,
            emission: [0.0; 3],
            temp,
            emissivity: 0.95,
            sun,
            pos: [x, 0.0, z],
        }
    }

    /// Vertical structures along the street at X = facade or the guardrail line.
    fn vertical(&self, side: usize, block: &Block, y: f32, z: f32) -> Option<Surface> {
        let x = self.facade[side];
        let sun = if (side == 0) == (self.shadow_dir[0] > 0.0) {
            0.85
        } else {
            0.35
        };
        let g = fbm(z * 2.0, y * 2.0, block.seed);
        match block.kind {
            BlockKind::Building { height } if y <= height => {
                let (fz, fy) = ((z / 3.0).fract(), (y / 3.0).fract());
                let window = y > 2.5 && (0.25..0.75).contains(&fz) && (0.3..0.8).contains(&fy);
                let lit = self.night
                    && window
                    && hash01((z / 3.0) as i32, (y / 3.0) as i32, block.seed) < 0.25;
                let albedo = if window {
                    rgb(0.08, 0.10, 0.12)
                } else {
                    block.albedo.map(|v| v * (0.85 + 0.3 * g))
                };
                let emission = if lit { rgb(0.3, 0.22, 0.12) } else { [0.0; 3] };
                // Windows reflect the cold sky (low emissivity glass at grazing angles).
                let (temp, emissivity) = if window {
                    (self.ambient + 1.0, 0.75)
                } else {
                    (
                        self.ambient + if self.night { 2.5 } else { 1.5 + 4.0 * sun },
                        0.93,
                    )
                };
                Some(Surface {
                    sem: Sem::Building,
                    albedo,
                    emission,
                    temp,
                    emissivity,
                    sun,
                    pos: [x, y, z],
                })
            }
            BlockKind::Fence if y <= 1.6 => {
                let bar = (z / 0.15).rem_euclid(1.0) < 0.35
                    || (y - 1.5).abs() < 0.06
                    || (y - 0.2).abs() < 0.06;
                bar.then(|| Surface {
                    sem: Sem::Fence,
                    albedo: block.albedo.map(|v| v * 0.6),
                    emission: [0.0; 3],
                    temp: self.ambient + if self.night { 0.0 } else { 2.0 },
                    emissivity: 0.9,
                    sun,
                    pos: [x, y, z],
                })
            }
            BlockKind::Hedge { height } if y <= height => Some(Surface {
                sem: Sem::Vegetation,
                albedo: rgb(0.10, 0.25, 0.06).map(|v| v * (0.6 + 0.8 * g)),
                emission: [0.0; 3],
                temp: self.ambient - 1.0,
                emissivity: 0.97,
                sun,
                pos: [x, y, z],
            }),
            _ => None,
        }
    }

    fn guardrail(&self, y: f32, z: f32) -> Option<Surface> {
        let (x, z0, z1) = self.guardrail?;
        if z < z0 || z > z1 {
            return None;
        }
        let rail = (0.45..0.8).contains(&y);
        let post = y < 0.8 && (z / 2.0).rem_euclid(1.0) < 0.06;
        (rail || post).then(|| Surface {
            sem: Sem::Guardrail,
            albedo: rgb(0.6, 0.62, 0.64)
                .map(|v| v * if (0.55..0.7).contains(&y) { 1.1 } else { 0.8 }),
            emission: [0.0; 3],
            // Galvanised steel: low emissivity, so it mostly reflects the cold sky.
            temp: self.ambient + if self.night { 0.0 } else { 3.0 },
            emissivity: 0.35,
            sun: 0.8,
            pos: [x, y, z],
        })
    }

    fn sky(&self, v: f32) -> Surface {
        let elev = ((self.horizon - v) / self.height as f32).clamp(0.0, 1.0);
        let albedo = if self.night {
            rgb(0.002, 0.003, 0.006).map(|c| c * (1.0 + 3.0 * (1.0 - elev)))
        } else {
            rgb(0.55 - 0.3 * elev, 0.70 - 0.25 * elev, 0.95)
        };
        Surface {
            sem: Sem::Sky,
            albedo,
            emission: [0.0; 3],
            temp: self.sky_temp,
            emissivity: 1.0,
            sun: 0.0,
            pos: [0.0, 1e3, 1e3],
        }
    }

    /// Background surface seen through pixel (u, v), with its depth (∞ for ground and sky, so
    /// objects always draw over them).
    pub(super) fn background(&self, u: f32, v: f32, t_offset: f32) -> (Surface, f32) {
        let xn = (u - self.cx) / self.focal;
        let yn = (v - self.horizon) / self.focal; // > 0 below the horizon
                                                  // Guardrail plane (nearer than facades).
        if let Some((gx, _, _)) = self.guardrail {
            if xn.abs() > 1e-6 && gx.signum() == xn.signum() {
                let z = gx / xn;
                let y = self.cam_height - yn * z;
                if y >= 0.0 {
                    if let Some(s) = self.guardrail(y, z) {
                        return (s, z);
                    }
                }
            }
        }
        let side = if xn < 0.0 { 0 } else { 1 };
        if xn.abs() > 1e-6 {
            let z = self.facade[side] / xn;
            let y = self.cam_height - yn * z;
            if z > 0.0 && y >= 0.0 {
                if let Some(block) = self.block_at(side, z) {
                    if let Some(s) = self.vertical(side, block, y, z) {
                        return (s, z);
                    }
                }
            }
        }
        if yn > 1e-6 {
            let z = self.cam_height / yn;
            let x = xn * z;
            (self.ground(x, z, t_offset), f32::INFINITY)
        } else {
            (self.sky(v), f32::INFINITY)
        }
    }
}
