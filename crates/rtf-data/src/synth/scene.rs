//! A street scene seen by a pinhole camera, rendered to RGB (linear radiance), apparent
//! temperature and semantic material per pixel.
//!
//! World frame: camera at the origin, X right, Y up (height above the road), Z forward (depth).
//! The camera is `cam_height` metres above a flat road and looks along +Z; pixel (u, v) with
//! centre (u + 0.5, v + 0.5) sees the ray ((u + 0.5 - cx) / f, -(v + 0.5 - horizon) / f, 1).
//! Objects are placed in 3-D and drawn far to near, so sizes and occlusions follow perspective.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

mod background;
mod objects;
mod populate;
mod render;

pub use render::{box_blur, RenderedPlanes};

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
