//! A street scene seen by a pinhole camera, rendered to RGB (linear radiance), apparent
//! temperature and semantic material per pixel.
//!
//! World frame: camera at the origin, X right, Y up (height above the road), Z forward (depth).
//! The camera is `cam_height` metres above a flat road and looks along +Z; pixel (u, v) with
//! centre (u + 0.5, v + 0.5) sees the ray ((u + 0.5 - cx) / f, -(v + 0.5 - horizon) / f, 1).
//! Objects are placed in 3-D and drawn far to near, so sizes and occlusions follow perspective.

use super::noise::{fbm, hash01};
use crate::augment::gaussian;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// What a pixel shows; mapped to MF or Freiburg ids by the writer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Sem {
    Sky,
    Road,
    Sidewalk,
    Curb,
    Building,
    Fence,
    Pole,
    Vegetation,
    Terrain,
    Person,
    Car,
    Bike,
    CarStop,
    Guardrail,
    Cone,
    Bump,
}

impl Sem {
    /// MF ids (spec §1): 0 unlabeled, 1 car, 2 person, 3 bike, 4 curve (curb), 5 car_stop,
    /// 6 guardrail, 7 color_cone, 8 bump.
    pub fn mf_id(self) -> u8 {
        match self {
            Sem::Car => 1,
            Sem::Person => 2,
            Sem::Bike => 3,
            Sem::Curb => 4,
            Sem::CarStop => 5,
            Sem::Guardrail => 6,
            Sem::Cone => 7,
            Sem::Bump => 8,
            _ => 0,
        }
    }

    /// Freiburg ids (spec §5); painted bumps are road, guardrails fence, the rest background.
    pub fn freiburg_id(self) -> u8 {
        match self {
            Sem::Road | Sem::Bump => 0,
            Sem::Sidewalk => 1,
            Sem::Building => 2,
            Sem::Curb => 3,
            Sem::Fence | Sem::Guardrail => 4,
            Sem::Pole => 5,
            Sem::Vegetation => 6,
            Sem::Terrain => 7,
            Sem::Sky => 8,
            Sem::Person => 9,
            Sem::Car => 10,
            Sem::Bike => 11,
            Sem::CarStop | Sem::Cone => 12,
        }
    }
}

/// Surface properties of one pixel before lighting.
#[derive(Debug, Clone, Copy)]
struct Surface {
    sem: Sem,
    albedo: [f32; 3],
    /// Light emitted (linear radiance), e.g. lamps, headlights, lit windows.
    emission: [f32; 3],
    /// Kinetic temperature, °C.
    temp: f32,
    /// Thermal emissivity; 1 - emissivity of the cold sky is reflected.
    emissivity: f32,
    /// Fraction of direct sunlight received (facing and shadows).
    sun: f32,
    /// World position (for night lighting).
    pos: [f32; 3],
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Kind {
    Person,
    /// Car seen from the front (oncoming, headlights) or the rear (tail lights) or the side.
    Car {
        view: CarView,
        running: bool,
    },
    Bike,
    Cone,
    CarStop,
    Tree,
    Lamp,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CarView {
    Front,
    Rear,
    Side,
}

#[derive(Debug, Clone)]
pub struct Object {
    pub kind: Kind,
    pub x: f32,
    pub z: f32,
    /// Height of the object's bottom above the road (riders on bikes).
    pub lift: f32,
    pub width: f32,
    pub height: f32,
    pub colors: [[f32; 3]; 2],
    /// Ground speed (m/s) along X and Z, for the thermal time offset.
    pub velocity: [f32; 2],
    pub seed: u32,
}

#[derive(Debug, Clone)]
struct Block {
    z0: f32,
    z1: f32,
    kind: BlockKind,
    albedo: [f32; 3],
    seed: u32,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum BlockKind {
    Building { height: f32 },
    Fence,
    Hedge { height: f32 },
    Open,
}

/// Everything random about one frame; rendering it is deterministic.
#[derive(Debug, Clone)]
pub struct Scene {
    pub width: usize,
    pub height: usize,
    pub night: bool,
    focal: f32,
    cx: f32,
    horizon: f32,
    cam_height: f32,
    road_center: f32,
    road_half: f32,
    curb_width: f32,
    sidewalk: f32,
    facade: [f32; 2],
    blocks: [Vec<Block>; 2],
    guardrail: Option<(f32, f32, f32)>,
    bump: Option<(f32, f32)>,
    pub objects: Vec<Object>,
    lamps: Vec<[f32; 3]>,
    /// Air temperature, °C.
    pub ambient: f32,
    sun_strength: f32,
    /// Shadow offset on the ground per metre of object height (X, Z).
    shadow_dir: [f32; 2],
    sky_temp: f32,
    seed: u32,
}

fn rgb(r: f32, g: f32, b: f32) -> [f32; 3] {
    [r, g, b]
}

fn jitter(c: [f32; 3], rng: &mut ChaCha8Rng, amount: f32) -> [f32; 3] {
    c.map(|v| (v * (1.0 + rng.random_range(-amount..amount))).clamp(0.0, 1.0))
}

const CAR_PAINTS: [[f32; 3]; 7] = [
    [0.75, 0.75, 0.75],
    [0.05, 0.05, 0.06],
    [0.55, 0.05, 0.05],
    [0.08, 0.15, 0.45],
    [0.85, 0.85, 0.82],
    [0.35, 0.36, 0.38],
    [0.10, 0.30, 0.15],
];

const CLOTHES: [[f32; 3]; 6] = [
    [0.05, 0.05, 0.08],
    [0.45, 0.08, 0.08],
    [0.10, 0.15, 0.40],
    [0.50, 0.45, 0.35],
    [0.20, 0.35, 0.20],
    [0.60, 0.60, 0.60],
];

impl Scene {
    /// Draws a random scene. Geometry does not depend on `night`; lighting and temperatures do.
    pub fn random(width: usize, height: usize, night: bool, rng: &mut ChaCha8Rng) -> Self {
        let focal = 0.87 * width as f32; // ~60° horizontal field of view
        let horizon = height as f32 * rng.random_range(0.40..0.48);
        let road_half = rng.random_range(3.2..5.5);
        let road_center = rng.random_range(-1.5..1.5);
        let curb_width = 0.25;
        let sidewalk = rng.random_range(1.8..3.5);
        let facade = [
            road_center - road_half - curb_width - sidewalk - rng.random_range(0.0..3.0),
            road_center + road_half + curb_width + sidewalk + rng.random_range(0.0..3.0),
        ];
        let blocks = [Self::blocks(rng), Self::blocks(rng)];
        let ambient = if night {
            rng.random_range(6.0..14.0)
        } else {
            rng.random_range(15.0..26.0)
        };
        let mut scene = Scene {
            width,
            height,
            night,
            focal,
            cx: width as f32 / 2.0,
            horizon,
            cam_height: rng.random_range(1.3..1.7),
            road_center,
            road_half,
            curb_width,
            sidewalk,
            facade,
            blocks,
            guardrail: None,
            bump: None,
            objects: Vec::new(),
            lamps: Vec::new(),
            ambient,
            sun_strength: rng.random_range(0.8..1.2),
            shadow_dir: [rng.random_range(-0.8..0.8), rng.random_range(0.2..0.9)],
            sky_temp: ambient - rng.random_range(25.0..40.0),
            seed: rng.random(),
        };
        if rng.random::<f32>() < 0.15 {
            let side = if rng.random::<bool>() { 1.0 } else { -1.0 };
            let x = road_center + side * (road_half + curb_width + 0.35);
            let z0 = rng.random_range(3.0..10.0);
            scene.guardrail = Some((x, z0, z0 + rng.random_range(10.0..40.0)));
        }
        if rng.random::<f32>() < 0.3 {
            let z0 = rng.random_range(5.0..14.0);
            scene.bump = Some((z0, z0 + rng.random_range(1.2..3.0)));
        }
        scene.populate(rng);
        scene
    }

    fn blocks(rng: &mut ChaCha8Rng) -> Vec<Block> {
        let mut blocks = Vec::new();
        let mut z = rng.random_range(-5.0..5.0);
        while z < 220.0 {
            let len = rng.random_range(8.0..30.0);
            let r: f32 = rng.random();
            let kind = if r < 0.65 {
                BlockKind::Building {
                    height: rng.random_range(4.0..22.0),
                }
            } else if r < 0.75 {
                BlockKind::Fence
            } else if r < 0.9 {
                BlockKind::Hedge {
                    height: rng.random_range(1.0..2.5),
                }
            } else {
                BlockKind::Open
            };
            let base = [
                rgb(0.55, 0.50, 0.45),
                rgb(0.40, 0.38, 0.36),
                rgb(0.65, 0.60, 0.50),
                rgb(0.45, 0.30, 0.25),
                rgb(0.70, 0.70, 0.70),
            ][rng.random_range(0..5)];
            blocks.push(Block {
                z0: z,
                z1: z + len,
                kind,
                albedo: jitter(base, rng, 0.15),
                seed: rng.random(),
            });
            z += len;
        }
        blocks
    }

    /// Places the scene's objects: cars, people, bikes (most with riders), cones, car stops,
    /// then trees and street lamps along the sidewalks. The order of random draws is part of
    /// the generator's output (frame `i` depends only on (seed, i)), so keep it.
    fn populate(&mut self, rng: &mut ChaCha8Rng) {
        self.add_cars(rng);
        self.add_people(rng);
        self.add_bikes(rng);
        self.add_cones(rng);
        self.add_car_stops(rng);
        for side in [-1.0f32, 1.0] {
            self.add_trees(side, rng);
            self.add_lamps(side, rng);
        }
        self.objects.retain(|o| o.z > 2.0);
    }

    /// A random x on either sidewalk.
    fn sidewalk_x(&self, rng: &mut ChaCha8Rng) -> f32 {
        let side = if rng.random::<bool>() { 1.0 } else { -1.0 };
        self.road_center
            + side * (self.road_half + self.curb_width + rng.random_range(0.3..self.sidewalk - 0.2))
    }

    fn add_cars(&mut self, rng: &mut ChaCha8Rng) {
        let (rc, rh) = (self.road_center, self.road_half);
        let n_cars = rng.random_range(1..=4);
        for _ in 0..n_cars {
            let r: f32 = rng.random();
            let paint = jitter(CAR_PAINTS[rng.random_range(0..CAR_PAINTS.len())], rng, 0.1);
            let (view, x, running, vz) = if r < 0.35 {
                // Parked along the curb, seen from the side-ish (long box).
                let side = if rng.random::<bool>() { 1.0 } else { -1.0 };
                (
                    CarView::Side,
                    rc + side * (rh - 1.1),
                    rng.random::<f32>() < 0.2,
                    0.0,
                )
            } else if r < 0.7 {
                (
                    CarView::Rear,
                    rc + rng.random_range(0.2..rh - 1.0),
                    true,
                    rng.random_range(3.0..12.0),
                )
            } else {
                (
                    CarView::Front,
                    rc - rng.random_range(0.8..rh - 0.9),
                    true,
                    -rng.random_range(3.0..12.0),
                )
            };
            let (w, h) = if view == CarView::Side {
                (4.3, 1.5)
            } else {
                (1.8, 1.5)
            };
            self.objects.push(Object {
                kind: Kind::Car { view, running },
                x,
                z: near_biased_depth(rng, 5.0, 45.0),
                lift: 0.0,
                width: w * rng.random_range(0.9..1.1),
                height: h * rng.random_range(0.9..1.15),
                colors: [paint, paint],
                velocity: [0.0, vz],
                seed: rng.random(),
            });
        }
    }

    fn add_people(&mut self, rng: &mut ChaCha8Rng) {
        let (rc, rh) = (self.road_center, self.road_half);
        let n_people = rng.random_range(1..=5);
        for _ in 0..n_people {
            let on_road = rng.random::<f32>() < 0.3;
            let x = if on_road {
                rc + rng.random_range(-rh..rh)
            } else {
                self.sidewalk_x(rng)
            };
            let speed = rng.random_range(-1.5..1.5);
            let z = near_biased_depth(rng, 4.0, 30.0);
            self.objects.push(self.person(x, z, 0.0, [speed, 0.0], rng));
        }
    }

    fn add_bikes(&mut self, rng: &mut ChaCha8Rng) {
        let (rc, rh) = (self.road_center, self.road_half);
        for _ in 0..rng.random_range(0..=2) {
            let x = rc + rng.random_range(-rh + 0.5..rh - 0.5);
            let z = near_biased_depth(rng, 4.0, 28.0);
            let v = rng.random_range(-5.0..5.0);
            let frame = jitter(
                [rgb(0.6, 0.1, 0.1), rgb(0.1, 0.1, 0.1), rgb(0.2, 0.3, 0.6)]
                    [rng.random_range(0..3)],
                rng,
                0.1,
            );
            self.objects.push(Object {
                kind: Kind::Bike,
                x,
                z,
                lift: 0.0,
                width: 1.7,
                height: 1.05,
                colors: [frame, rgb(0.05, 0.05, 0.05)],
                velocity: [v, 0.0],
                seed: rng.random(),
            });
            if rng.random::<f32>() < 0.8 {
                // The rider sits slightly behind the bike so the bike is drawn over the legs.
                self.objects
                    .push(self.person(x, z + 0.05, 0.45, [v, 0.0], rng));
            }
        }
    }

    fn add_cones(&mut self, rng: &mut ChaCha8Rng) {
        let (rc, rh) = (self.road_center, self.road_half);
        if rng.random::<f32>() < 0.35 {
            let x0 = rc + rng.random_range(-rh + 0.5..rh - 0.5);
            let z0 = near_biased_depth(rng, 4.0, 20.0);
            for k in 0..rng.random_range(1..=4) {
                self.objects.push(Object {
                    kind: Kind::Cone,
                    x: x0 + k as f32 * 0.1,
                    z: z0 + k as f32 * 2.0,
                    lift: 0.0,
                    width: 0.4,
                    height: 0.7,
                    colors: [rgb(0.95, 0.30, 0.03), rgb(0.9, 0.9, 0.9)],
                    velocity: [0.0, 0.0],
                    seed: rng.random(),
                });
            }
        }
    }

    fn add_car_stops(&mut self, rng: &mut ChaCha8Rng) {
        if rng.random::<f32>() < 0.3 {
            let x0 = self.sidewalk_x(rng);
            let z0 = near_biased_depth(rng, 4.0, 15.0);
            for k in 0..rng.random_range(1..=3) {
                self.objects.push(Object {
                    kind: Kind::CarStop,
                    x: x0,
                    z: z0 + k as f32 * 2.8,
                    lift: 0.0,
                    width: 1.6,
                    height: 0.18,
                    colors: [rgb(0.85, 0.75, 0.15), rgb(0.6, 0.6, 0.58)],
                    velocity: [0.0, 0.0],
                    seed: rng.random(),
                });
            }
        }
    }

    /// Trees along the sidewalk on `side` (-1 left, +1 right).
    fn add_trees(&mut self, side: f32, rng: &mut ChaCha8Rng) {
        let x = self.road_center + side * (self.road_half + self.curb_width + self.sidewalk * 0.75);
        let mut z = rng.random_range(3.0..15.0);
        while z < 90.0 {
            if rng.random::<f32>() < 0.5 {
                self.objects.push(Object {
                    kind: Kind::Tree,
                    x: x + rng.random_range(-0.3..0.3),
                    z,
                    lift: 0.0,
                    width: rng.random_range(2.5..4.5),
                    height: rng.random_range(4.0..8.0),
                    colors: [
                        jitter(rgb(0.15, 0.30, 0.08), rng, 0.2),
                        rgb(0.25, 0.18, 0.12),
                    ],
                    velocity: [0.0, 0.0],
                    seed: rng.random(),
                });
            }
            z += rng.random_range(8.0..16.0);
        }
    }

    /// Street lamps (objects and light sources) along the curb on `side`.
    fn add_lamps(&mut self, side: f32, rng: &mut ChaCha8Rng) {
        let mut z = rng.random_range(5.0..20.0);
        let lx = self.road_center + side * (self.road_half + self.curb_width + 0.4);
        while z < 160.0 {
            self.lamps.push([lx, 6.0, z]);
            self.objects.push(Object {
                kind: Kind::Lamp,
                x: lx,
                z,
                lift: 0.0,
                width: 0.6,
                height: 6.0,
                colors: [rgb(0.3, 0.3, 0.32), rgb(1.0, 0.85, 0.6)],
                velocity: [0.0, 0.0],
                seed: rng.random(),
            });
            z += rng.random_range(22.0..32.0);
        }
    }

    fn person(
        &self,
        x: f32,
        z: f32,
        lift: f32,
        velocity: [f32; 2],
        rng: &mut ChaCha8Rng,
    ) -> Object {
        let shirt = jitter(CLOTHES[rng.random_range(0..CLOTHES.len())], rng, 0.2);
        let pants = jitter(CLOTHES[rng.random_range(0..CLOTHES.len())], rng, 0.2);
        Object {
            kind: Kind::Person,
            x,
            z,
            lift,
            width: rng.random_range(0.5..0.65),
            height: rng.random_range(1.55..1.9),
            colors: [shirt, pants],
            velocity,
            seed: rng.random(),
        }
    }

    // ---- temperatures (°C) -------------------------------------------------------------------

    /// Road and ground surfaces are warmed by the sun by day and keep a little heat at night.
    fn ground_temp(&self, sem: Sem, sun: f32) -> f32 {
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
    fn clothing_temp(&self) -> f32 {
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
    fn background(&self, u: f32, v: f32, t_offset: f32) -> (Surface, f32) {
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

    // ---- objects ---------------------------------------------------------------------------

    /// Surface of object `o` at local metric coordinates (lx from the left edge, ly from the
    /// top, both in metres), or None where it is transparent.
    fn object_surface(&self, o: &Object, lx: f32, ly: f32, ground_temp: f32) -> Option<Surface> {
        let p = ObjectPoint {
            lx,
            ly,
            s: lx / o.width,
            t: ly / o.height,
            g: fbm(lx * 8.0, ly * 8.0, o.seed),
        };
        match o.kind {
            Kind::Person => self.person_surface(o, &p),
            Kind::Car { view, running } => self.car_surface(o, view, running, &p),
            Kind::Bike => self.bike_surface(o, &p),
            Kind::Cone => Self::cone_surface(o, &p, ground_temp),
            Kind::CarStop => Self::car_stop_surface(o, &p, ground_temp),
            Kind::Tree => self.tree_surface(o, &p),
            Kind::Lamp => self.lamp_surface(o, &p),
        }
    }

    /// A matte surface of object `o` at height fraction `t` from its top (every object but
    /// cars, which have their own sun factor and no lift).
    fn matte(
        o: &Object,
        t: f32,
        sem: Sem,
        albedo: [f32; 3],
        temp: f32,
        emissivity: f32,
    ) -> Surface {
        Surface {
            sem,
            albedo,
            emission: [0.0; 3],
            temp,
            emissivity,
            sun: 0.75,
            pos: [o.x, o.lift + o.height * (1.0 - t), o.z],
        }
    }

    /// A walking person: head and hair, torso and arms with hands, legs in mid-stride.
    fn person_surface(&self, o: &Object, p: &ObjectPoint) -> Option<Surface> {
        let (s, t, g) = (p.s, p.t, p.g);
        let phase = (o.seed % 100) as f32 / 100.0;
        let head = ((s - 0.5) / 0.2).powi(2) + ((t - 0.07) / 0.065).powi(2) <= 1.0;
        let torso = (s - 0.5).abs() < 0.3 && (0.13..0.56).contains(&t);
        let arms = (s - 0.5).abs() < 0.42 && (0.16..0.48).contains(&t) && (s - 0.5).abs() > 0.3;
        let stride = 0.12 * (phase * std::f32::consts::TAU).sin() * (t - 0.55).max(0.0) / 0.45;
        let legs = (0.55..=1.0).contains(&t)
            && ((s - 0.37 - stride).abs() < 0.11 || (s - 0.63 + stride).abs() < 0.11);
        let skin = rgb(0.65, 0.48, 0.38);
        let person =
            |albedo, temp, emissivity| Self::matte(o, t, Sem::Person, albedo, temp, emissivity);
        if head {
            let hair = t < 0.04;
            Some(person(
                if hair { rgb(0.1, 0.07, 0.05) } else { skin },
                if hair { 30.0 } else { 33.5 },
                0.98,
            ))
        } else if torso || arms {
            let hand = arms && t > 0.43;
            let c = if hand {
                skin
            } else {
                o.colors[0].map(|v| v * (0.9 + 0.2 * g))
            };
            Some(person(
                c,
                if hand { 32.0 } else { self.clothing_temp() },
                0.95,
            ))
        } else if legs {
            Some(person(
                o.colors[1].map(|v| v * (0.9 + 0.2 * g)),
                self.clothing_temp() - 1.0,
                0.95,
            ))
        } else {
            None
        }
    }

    /// A bicycle side-on: two tyres with hubs and a frame of thin tubes, saddle and bars.
    fn bike_surface(&self, o: &Object, p: &ObjectPoint) -> Option<Surface> {
        let (w, h, lx, ly) = (o.width, o.height, p.lx, p.ly);
        let r = 0.33;
        let wheel = |cx: f32| ((lx - cx).powi(2) + (ly - (h - r)).powi(2)).sqrt();
        let (d1, d2) = (wheel(0.36), wheel(w - 0.36));
        let tyre = (d1 - r).abs() < 0.05 || (d2 - r).abs() < 0.05;
        let hub = d1 < 0.05 || d2 < 0.05;
        let seg = |ax: f32, ay: f32, bx: f32, by: f32| {
            let (dx, dy) = (bx - ax, by - ay);
            let k = (((lx - ax) * dx + (ly - ay) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
            ((lx - ax - k * dx).powi(2) + (ly - ay - k * dy).powi(2)).sqrt() < 0.035
        };
        let (bb_x, bb_y) = (w * 0.48, h - r);
        let frame = seg(0.36, h - r, bb_x, bb_y)
            || seg(bb_x, bb_y, w * 0.42, 0.3)
            || seg(w * 0.42, 0.3, w - 0.5, 0.32)
            || seg(w - 0.5, 0.32, w - 0.36, h - r)
            || seg(bb_x, bb_y, w - 0.5, 0.32)
            || seg(0.36, h - r, w * 0.42, 0.3)
            || seg(w - 0.5, 0.32, w - 0.55, 0.08)
            || (ly < 0.1 && (lx - (w - 0.55)).abs() < 0.2)
            || (ly > 0.25 && ly < 0.32 && (lx - w * 0.4).abs() < 0.12);
        if tyre {
            // Tyres and hubs roll at air temperature: a bike is faint in thermal.
            Some(Self::matte(
                o,
                p.t,
                Sem::Bike,
                o.colors[1],
                self.ambient + 1.0,
                0.93,
            ))
        } else if frame || hub {
            Some(Self::matte(
                o,
                p.t,
                Sem::Bike,
                o.colors[0],
                self.ambient,
                0.4,
            ))
        } else {
            None
        }
    }

    /// A striped traffic cone on its base.
    fn cone_surface(o: &Object, p: &ObjectPoint, ground_temp: f32) -> Option<Surface> {
        let (s, t) = (p.s, p.t);
        let base = t > 0.9;
        let body = (s - 0.5).abs() < 0.08 + 0.38 * t;
        if !(base || body) {
            return None;
        }
        let stripe = (0.35..0.48).contains(&t) || (0.6..0.7).contains(&t);
        let c = if stripe { o.colors[1] } else { o.colors[0] }.map(|v| v * (0.92 + 0.16 * p.g));
        // Painted plastic at the temperature of the road it stands on.
        Some(Self::matte(o, t, Sem::Cone, c, ground_temp, 0.95))
    }

    /// A striped car stop (parking block) at the road's temperature.
    fn car_stop_surface(o: &Object, p: &ObjectPoint, ground_temp: f32) -> Option<Surface> {
        let stripe = ((p.s * 6.0).floor() as i32) % 2 == 0;
        let c = if stripe { o.colors[0] } else { o.colors[1] }.map(|v| v * (0.9 + 0.2 * p.g));
        Some(Self::matte(o, p.t, Sem::CarStop, c, ground_temp, 0.95))
    }

    /// A tree: a noisy crown a little below air temperature over a trunk.
    fn tree_surface(&self, o: &Object, p: &ObjectPoint) -> Option<Surface> {
        let (s, t, g) = (p.s, p.t, p.g);
        let trunk = (s - 0.5).abs() < 0.06 && t > 0.45;
        let crown =
            ((s - 0.5) / 0.5).powi(2) + ((t - 0.33) / 0.33).powi(2) <= 1.0 - 0.35 * (g - 0.5);
        if crown {
            let leaf = o.colors[0].map(|v| v * (0.6 + 0.8 * g));
            Some(Self::matte(
                o,
                t,
                Sem::Vegetation,
                leaf,
                self.ambient - 1.5,
                0.97,
            ))
        } else if trunk {
            Some(Self::matte(
                o,
                t,
                Sem::Vegetation,
                o.colors[1],
                self.ambient,
                0.95,
            ))
        } else {
            None
        }
    }

    /// A street lamp: a pole under a head that is hot, and lit, at night.
    fn lamp_surface(&self, o: &Object, p: &ObjectPoint) -> Option<Surface> {
        let (w, lx, ly, amb) = (o.width, p.lx, p.ly, self.ambient);
        let pole = (lx - w / 2.0).abs() < 0.07;
        let head = ly < 0.25 && (lx - w / 2.0).abs() < w / 2.0;
        if head {
            let temp = amb + if self.night { 25.0 } else { 2.0 };
            let mut sf = Self::matte(o, p.t, Sem::Pole, o.colors[0], temp, 0.9);
            if self.night && ly > 0.12 {
                sf.emission = o.colors[1].map(|v| v * 15.0);
            }
            Some(sf)
        } else if pole {
            let temp = amb + if self.night { 0.0 } else { 3.0 };
            Some(Self::matte(o, p.t, Sem::Pole, o.colors[0], temp, 0.5))
        } else {
            None
        }
    }

    /// A car, seen from the side or from the front or rear.
    fn car_surface(
        &self,
        o: &Object,
        view: CarView,
        running: bool,
        p: &ObjectPoint,
    ) -> Option<Surface> {
        let amb = self.ambient;
        let car = CarLook {
            // Painted metal: sun-warmed by day, radiatively cooled a little below air at night.
            body_temp: amb + if self.night { -1.0 } else { 8.0 },
            paint: o.colors[0].map(|v| v * (0.92 + 0.16 * p.g)),
            tyre_temp: if running { amb + 18.0 } else { amb + 1.0 },
            amb,
            height: o.height,
            x: o.x,
            z: o.z,
            t: p.t,
        };
        match view {
            CarView::Side => car.side(o.width, running, p),
            _ => car.end(view, running, self.night, p),
        }
    }

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

/// A depth in `lo..hi` biased towards the camera, so objects are not tiny.
fn near_biased_depth(rng: &mut ChaCha8Rng, lo: f32, hi: f32) -> f32 {
    lo + (hi - lo) * rng.random::<f32>().powf(1.6)
}

/// Where on an object a ray lands: metres from its left edge and top, the same as fractions
/// of its width and height, and the object's texture noise there.
struct ObjectPoint {
    lx: f32,
    ly: f32,
    s: f32,
    t: f32,
    g: f32,
}

/// What every part of one car shares at one point: temperatures, paint and where it is.
struct CarLook {
    body_temp: f32,
    paint: [f32; 3],
    tyre_temp: f32,
    amb: f32,
    height: f32,
    x: f32,
    z: f32,
    /// Height fraction from the top of the point being shaded.
    t: f32,
}

impl CarLook {
    fn surface(&self, albedo: [f32; 3], temp: f32, emissivity: f32, emission: [f32; 3]) -> Surface {
        Surface {
            sem: Sem::Car,
            albedo,
            emission,
            temp,
            emissivity,
            sun: 0.8,
            pos: [self.x, self.height * (1.0 - self.t), self.z],
        }
    }

    fn tyre(&self) -> Surface {
        self.surface(rgb(0.04, 0.04, 0.04), self.tyre_temp, 0.95, [0.0; 3])
    }

    /// Glass where `glass`, else the painted frame of the cabin.
    fn cabin(&self, glass: bool) -> Surface {
        if glass {
            self.surface(rgb(0.05, 0.07, 0.09), self.amb + 2.0, 0.8, [0.0; 3])
        } else {
            self.surface(self.paint, self.body_temp, 0.9, [0.0; 3])
        }
    }

    /// Side view: two wheels, the cabin's windows and the body, its engine end hot when running.
    fn side(&self, w: f32, running: bool, p: &ObjectPoint) -> Option<Surface> {
        let (h, s, t, lx, ly) = (self.height, p.s, p.t, p.lx, p.ly);
        let wheel = |cx: f32| ((lx - cx).powi(2) + (ly - (h - 0.33)).powi(2)).sqrt() < 0.33;
        if wheel(0.8) || wheel(w - 0.8) {
            return Some(self.tyre());
        }
        let cabin = t < 0.45
            && t > 0.05
            && s > 0.22 + 0.08 * (0.45 - t) / 0.4
            && s < 0.78 - 0.1 * (0.45 - t) / 0.4;
        let body = (0.42..0.85).contains(&t);
        if cabin {
            return Some(self.cabin(t > 0.1 && (s - 0.5).abs() > 0.02));
        }
        if body {
            let engine = running && s > 0.85;
            let temp = if engine {
                self.amb + 25.0
            } else {
                self.body_temp
            };
            return Some(self.surface(self.paint, temp, 0.9, [0.0; 3]));
        }
        None
    }

    /// Front or rear view: wheels, cabin, lamps (lit at night when running), the plate, and
    /// the hot engine (front) or exhaust (rear) when running.
    fn end(&self, view: CarView, running: bool, night: bool, p: &ObjectPoint) -> Option<Surface> {
        let (s, t) = (p.s, p.t);
        let wheel = t > 0.78 && ((0.04..0.22).contains(&s) || (0.78..0.96).contains(&s));
        if wheel {
            return Some(self.tyre());
        }
        let inset = 0.12 + 0.1 * ((0.42 - t) / 0.37).clamp(0.0, 1.0);
        let cabin = (0.05..0.42).contains(&t) && s > inset && s < 1.0 - inset;
        let body = (0.42..0.8).contains(&t);
        if cabin {
            return Some(self.cabin(t > 0.1 && s > inset + 0.03 && s < 1.0 - inset - 0.03));
        }
        if !body {
            return None;
        }
        let lamp =
            (0.5..0.62).contains(&t) && ((0.04..0.2).contains(&s) || (0.8..0.96).contains(&s));
        let plate = (0.62..0.72).contains(&t) && (s - 0.5).abs() < 0.12;
        if lamp {
            let (albedo, light) = match view {
                CarView::Front => (rgb(0.9, 0.9, 0.85), rgb(1.0, 0.95, 0.85).map(|v| v * 80.0)),
                _ => (rgb(0.7, 0.05, 0.05), rgb(1.0, 0.05, 0.02).map(|v| v * 12.0)),
            };
            let on = running && night;
            let temp = self.amb + if running { 15.0 } else { 0.0 };
            return Some(self.surface(albedo, temp, 0.9, if on { light } else { [0.0; 3] }));
        }
        if plate {
            return Some(self.surface(rgb(0.85, 0.85, 0.8), self.body_temp, 0.9, [0.0; 3]));
        }
        let hot = running
            && match view {
                CarView::Front => (0.55..0.8).contains(&t) && (s - 0.5).abs() < 0.3,
                _ => t > 0.72 && (s - 0.25).abs() < 0.06,
            };
        let temp = if hot { self.amb + 30.0 } else { self.body_temp };
        Some(self.surface(self.paint, temp, 0.9, [0.0; 3]))
    }
}
