//! Drawing a random scene: the camera, the street blocks on both sides and the objects
//! (cars, people, bikes, cones, car stops, trees, lamps) placed in 3-D.

use super::{jitter, rgb, Block, BlockKind, CarView, Kind, Object, Scene, CAR_PAINTS, CLOTHES};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

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
}

/// A depth in `lo..hi` biased towards the camera, so objects are not tiny.
fn near_biased_depth(rng: &mut ChaCha8Rng, lo: f32, hi: f32) -> f32 {
    lo + (hi - lo) * rng.random::<f32>().powf(1.6)
}
