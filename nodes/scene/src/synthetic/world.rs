//! The generated scene's fixed world: its objects, their textures and shading, and exact
//! ray intersection.

use augsplat_core::linalg::{self, Mat3, Vec3};

/// A surface hit.
#[derive(Clone, Copy, Debug)]
pub(super) struct Hit {
    pub(super) t: f64,
    pub(super) p: Vec3,
    n: Vec3,
    obj: u8,
}

const DOME_RADIUS: f64 = 6.0;
const GROUND_RADIUS: f64 = 3.2;
const OBJ_DOME: u8 = 0;
const OBJ_GROUND: u8 = 1;

pub(super) struct Sphere {
    pub(super) c: Vec3,
    pub(super) r: f64,
}

/// The fixed world.
pub(super) struct World {
    pub(super) spheres: [Sphere; 3],
    box_c: Vec3,
    box_h: Vec3,
    /// World-to-box rotation.
    box_r: Mat3,
    light: Vec3,
    specular: f64,
}

impl World {
    pub(super) fn new(specular: f64) -> World {
        World {
            spheres: [
                Sphere {
                    c: [0.6, 0.3, 0.45],
                    r: 0.45,
                },
                Sphere {
                    c: [-0.7, 0.55, 0.3],
                    r: 0.3,
                },
                Sphere {
                    c: [0.15, -0.25, 0.16],
                    r: 0.16,
                },
            ],
            box_c: [-0.25, -0.75, 0.35],
            box_h: [0.35, 0.25, 0.35],
            box_r: linalg::transpose3(&linalg::axis_angle([0.0, 0.0, 1.0], 0.5)),
            light: linalg::normalize([0.5, -0.4, 0.8]),
            specular,
        }
    }

    /// The nearest hit along the ray (every ray from inside the dome hits something).
    pub(super) fn trace(&self, o: Vec3, d: Vec3) -> Hit {
        let mut best = dome_hit(o, d);
        // Ground plane z = 0 (disk).
        if d[2] < -1e-12 {
            let t = -o[2] / d[2];
            if t > 1e-9 && t < best.t {
                let p = linalg::add(o, linalg::scale(d, t));
                if p[0] * p[0] + p[1] * p[1] < GROUND_RADIUS * GROUND_RADIUS {
                    best = Hit {
                        t,
                        p,
                        n: [0.0, 0.0, 1.0],
                        obj: OBJ_GROUND,
                    };
                }
            }
        }
        for (k, s) in self.spheres.iter().enumerate() {
            if let Some(t) = sphere_near(o, d, s.c, s.r) {
                if t < best.t {
                    let p = linalg::add(o, linalg::scale(d, t));
                    best = Hit {
                        t,
                        p,
                        n: linalg::scale(linalg::sub(p, s.c), 1.0 / s.r),
                        obj: 2 + k as u8,
                    };
                }
            }
        }
        // Oriented box: slab test in box coordinates.
        let ol = linalg::mat3_vec(&self.box_r, linalg::sub(o, self.box_c));
        let dl = linalg::mat3_vec(&self.box_r, d);
        let (mut t0, mut t1, mut axis, mut sign) = (f64::NEG_INFINITY, f64::INFINITY, 0usize, 1.0);
        let mut ok = true;
        for a in 0..3 {
            if dl[a].abs() < 1e-15 {
                if ol[a].abs() > self.box_h[a] {
                    ok = false;
                }
                continue;
            }
            let ta = (-self.box_h[a] - ol[a]) / dl[a];
            let tb = (self.box_h[a] - ol[a]) / dl[a];
            let (lo, hi) = if ta < tb { (ta, tb) } else { (tb, ta) };
            if lo > t0 {
                t0 = lo;
                axis = a;
                sign = if dl[a] > 0.0 { -1.0 } else { 1.0 };
            }
            t1 = t1.min(hi);
        }
        if ok && t0 <= t1 && t0 > 1e-9 && t0 < best.t {
            let mut nl = [0.0; 3];
            nl[axis] = sign;
            best = Hit {
                t: t0,
                p: linalg::add(o, linalg::scale(d, t0)),
                n: linalg::mat3_vec(&linalg::transpose3(&self.box_r), nl),
                obj: 5 + axis as u8 * 2 + (sign > 0.0) as u8,
            };
        }
        best
    }

    /// Albedo (or emitted colour for the dome) at a hit.
    fn albedo(&self, h: &Hit) -> Vec3 {
        let p = h.p;
        match h.obj {
            OBJ_DOME => {
                let dir = linalg::scale(p, 1.0 / DOME_RADIUS);
                let el = dir[2].clamp(-1.0, 1.0);
                let az = dir[1].atan2(dir[0]);
                if el >= 0.0 {
                    let s = el.powf(0.6);
                    let tint = 0.05 * (3.0 * az).sin();
                    [
                        lerp(0.85, 0.25, s) + tint,
                        lerp(0.88, 0.45, s) + 0.5 * tint,
                        lerp(0.92, 0.85, s) - tint,
                    ]
                } else {
                    let band = 0.5 + 0.5 * (2.0 * az).cos();
                    let s = (-el).powf(0.5);
                    [
                        lerp(0.55, 0.3, s) + 0.06 * band,
                        lerp(0.5, 0.28, s) + 0.04 * band,
                        lerp(0.45, 0.25, s),
                    ]
                }
            }
            OBJ_GROUND => {
                let c = soft_checker(p[0] / 0.5, p[1] / 0.5, 0.12);
                let g = 0.5 + 0.5 * (0.7 * p[0] - 0.5 * p[1]).sin();
                let base_a = [0.82, 0.74, 0.58];
                let base_b = [0.45, 0.5, 0.38];
                let a = lerp3(base_a, base_b, c);
                [
                    a[0] * (0.85 + 0.15 * g),
                    a[1],
                    a[2] * (0.9 + 0.1 * (1.0 - g)),
                ]
            }
            2 => {
                // Big sphere: soft latitude stripes, red/yellow.
                let n = h.n;
                let lat = n[2].clamp(-1.0, 1.0).asin();
                let s = 0.5 + 0.5 * (lat * 8.0).sin();
                lerp3([0.85, 0.2, 0.15], [0.95, 0.8, 0.25], s)
            }
            3 => {
                // Blue sphere: checker in longitude/latitude.
                let n = h.n;
                let lat = n[2].clamp(-1.0, 1.0).asin();
                let lon = n[1].atan2(n[0]);
                let c = soft_checker(
                    lon * 4.0 / std::f64::consts::PI,
                    lat * 4.0 / std::f64::consts::PI,
                    0.1,
                );
                lerp3([0.15, 0.3, 0.8], [0.75, 0.85, 0.95], c)
            }
            4 => {
                // Small sphere: smooth green gradient.
                let s = 0.5 + 0.5 * h.n[2];
                lerp3([0.1, 0.45, 0.15], [0.6, 0.9, 0.4], s)
            }
            _ => {
                // Box faces: a hue per face and a soft grid.
                let face = (h.obj - 5) as usize;
                let hues = [
                    [0.7, 0.35, 0.75],
                    [0.35, 0.7, 0.7],
                    [0.9, 0.55, 0.3],
                    [0.5, 0.5, 0.85],
                    [0.8, 0.8, 0.8],
                    [0.6, 0.75, 0.35],
                ];
                let pl = linalg::mat3_vec(&self.box_r, linalg::sub(p, self.box_c));
                let axis = face / 2;
                let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
                let g = soft_grid(pl[a] / 0.2333, pl[b] / 0.2333, 0.15);
                let c = hues[face];
                lerp3(c, linalg::scale(c, 0.45), g)
            }
        }
    }

    /// Shaded colour seen along direction `d` at hit `h`.
    pub(super) fn shade(&self, h: &Hit, d: Vec3) -> Vec3 {
        let a = self.albedo(h);
        if h.obj == OBJ_DOME {
            return a;
        }
        let ndl = linalg::dot(h.n, self.light).max(0.0);
        let lit = 0.4 + 0.6 * ndl;
        let mut c = linalg::scale(a, lit);
        if (2..=4).contains(&h.obj) && self.specular > 0.0 {
            let half = linalg::normalize(linalg::sub(self.light, d));
            let s = linalg::dot(h.n, half).max(0.0).powi(8) * self.specular;
            c = linalg::add(c, [s, s, s]);
        }
        c
    }
}

fn lerp(a: f64, b: f64, t: f64) -> f64 {
    a + (b - a) * t
}

fn lerp3(a: Vec3, b: Vec3, t: f64) -> Vec3 {
    linalg::lerp(a, b, t)
}

/// A checker in [0, 1] with smoothed edges (`soft` is the edge half-width in cells).
pub(super) fn soft_checker(u: f64, v: f64, soft: f64) -> f64 {
    let su = smooth_square(u, soft);
    let sv = smooth_square(v, soft);
    // XOR of two soft square waves in [0, 1].
    su + sv - 2.0 * su * sv
}

/// A square wave of period 2 in [0, 1] with linear ramps of half-width `soft`.
fn smooth_square(x: f64, soft: f64) -> f64 {
    let f = x.rem_euclid(2.0);
    if f < 1.0 {
        ramp(f, soft)
    } else {
        1.0 - ramp(f - 1.0, soft)
    }
}

/// 0 in the middle of [0, 1], rising to 0.5 at the edges over `soft` (continuous across them).
fn ramp(f: f64, soft: f64) -> f64 {
    let d = f.min(1.0 - f);
    if d >= soft {
        0.0
    } else {
        0.5 * (1.0 - d / soft)
    }
}

/// 1 on grid lines (unit spacing), 0 between, with soft edges of half-width `w`.
fn soft_grid(u: f64, v: f64, w: f64) -> f64 {
    let line = |x: f64| {
        let d = (x - x.round()).abs();
        (1.0 - d / w).clamp(0.0, 1.0)
    };
    line(u).max(line(v))
}

fn dome_hit(o: Vec3, d: Vec3) -> Hit {
    // Far root of |o + t d| = R (o is inside the dome).
    let b = linalg::dot(o, d);
    let c = linalg::dot(o, o) - DOME_RADIUS * DOME_RADIUS;
    let t = -b + (b * b - c).max(0.0).sqrt();
    let p = linalg::add(o, linalg::scale(d, t));
    Hit {
        t,
        p,
        n: linalg::scale(p, -1.0 / DOME_RADIUS),
        obj: OBJ_DOME,
    }
}

fn sphere_near(o: Vec3, d: Vec3, c: Vec3, r: f64) -> Option<f64> {
    let oc = linalg::sub(o, c);
    let b = linalg::dot(oc, d);
    let cc = linalg::dot(oc, oc) - r * r;
    let disc = b * b - cc;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    let t = -b - s;
    if t > 1e-9 {
        Some(t)
    } else {
        let t2 = -b + s;
        (t2 > 1e-9).then_some(t2)
    }
}
