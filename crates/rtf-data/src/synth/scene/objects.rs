//! Surfaces of the objects (people, bikes, cones, car stops, trees, lamps, cars) at a point
//! where a ray lands on them.

use super::{rgb, CarView, Kind, Object, Scene, Sem, Surface};
use crate::synth::noise::fbm;

impl Scene {
    // ---- objects ---------------------------------------------------------------------------

    /// Surface of object `o` at local metric coordinates (lx from the left edge, ly from the
    /// top, both in metres), or None where it is transparent.
    pub(super) fn object_surface(
        &self,
        o: &Object,
        lx: f32,
        ly: f32,
        ground_temp: f32,
    ) -> Option<Surface> {
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
