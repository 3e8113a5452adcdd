//! Initialisation of a Gaussian set, as gsplat `simple_trainer`: from the scene's sparse
//! points (opacity 0.1, isotropic scale = root-mean-square distance to the 3 nearest
//! neighbours, SH DC from the point colour, higher SH zero, quaternions uniform in [0,1)⁴) or,
//! without points, from random points: by default on random training-camera rays between the
//! scene's near and far bounds ([`RandomInit::Frusta`]), or uniformly in a cube around the
//! cameras as gsplat's `init_type = "random"` ([`RandomInit::Cube`]).
//!
//! A pipeline with a radiance-field prior may connect the prior's depth at the training views
//! (`init_depth`): a scene without sparse points then starts from points back-projected from
//! that depth ([`from_prior_depth`]) instead of random ones — an augsplat option, not the
//! paper's.
//!
//! The nearest neighbours come from a uniform grid (cell ≈ bounding-box volume / N, searched
//! in growing shells) so initialisation is O(N) for well-spread clouds, not O(N²).

use crate::Gaussians;
use augsplat_core::{Camera, PointCloud, Rng, Scene};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::constants::C0 as SH_C0;

/// Initialisation parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InitArgs {
    /// Initial opacity (after the sigmoid).
    pub opacity: f64,
    /// Multiplier on the nearest-neighbour scale.
    pub scale_factor: f64,
    /// Number of random points when the scene has none (gsplat uses 100k; a CPU-sized
    /// default here).
    pub random_points: usize,
    /// Half-extent of the random cube, in scene scales (gsplat `init_extent`); used by
    /// [`RandomInit::Cube`].
    pub random_extent: f64,
    /// Where random points are drawn when the scene has no sparse points.
    pub random_in: RandomInit,
}

/// Where random initial points are drawn when the scene has no sparse points.
///
/// gsplat's cube (half-side 3 scene scales around the cameras' mean) suits captures whose
/// content surrounds the cameras. For forward-facing captures (LLFF) the content lies far in
/// front of cameras that barely move — fern's bounds are 3.3–15 in units where the cameras fit
/// in a unit ball — so the cube holds almost nothing that is visible at the right depth, and
/// the mean learning rate (∝ scene scale) cannot carry points there. `Frusta` puts the points
/// where the training views can see them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum RandomInit {
    /// On rays through uniformly random pixels of uniformly drawn training views, at a depth
    /// (along the optical axis) uniform in disparity between the scene's near and far
    /// bounds, coloured by the pixel the ray passes through. Falls back to `Cube` when the
    /// bounds are not finite with 0 < near < far.
    #[default]
    Frusta,
    /// Uniform in the cube of half-side `random_extent · scene_scale` around the cameras'
    /// mean, random colours (gsplat `init_type = "random"`).
    Cube,
}

impl Default for InitArgs {
    fn default() -> Self {
        InitArgs {
            opacity: 0.1,
            scale_factor: 1.0,
            random_points: 20_000,
            random_extent: 3.0,
            random_in: RandomInit::Frusta,
        }
    }
}

impl InitArgs {
    /// Checks ranges.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.opacity > 0.0 && self.opacity < 1.0) {
            return Err(format!("init.opacity = {} must be in (0, 1)", self.opacity));
        }
        if !(self.scale_factor.is_finite() && self.scale_factor > 0.0) {
            return Err(format!(
                "init.scale_factor = {} must be positive",
                self.scale_factor
            ));
        }
        if !(self.random_extent.is_finite() && self.random_extent > 0.0) {
            return Err(format!(
                "init.random_extent = {} must be positive",
                self.random_extent
            ));
        }
        Ok(())
    }
}

/// logit(p) = ln(p / (1 − p)).
pub fn logit(p: f64) -> f64 {
    (p / (1.0 - p)).ln()
}

/// For each point, the root-mean-square distance to its `k` nearest other points (gsplat:
/// `sqrt(mean(knn_dist²))`). Points with fewer than `k` others use the ones available; a
/// lone point gets `fallback`. Duplicated points give 0. Non-finite points are ignored as
/// neighbours and get `fallback`.
pub fn knn_rms_distance(points: &[[f32; 3]], k: usize, fallback: f64) -> Vec<f64> {
    let n = points.len();
    let finite: Vec<bool> = points
        .iter()
        .map(|p| p.iter().all(|v| v.is_finite()))
        .collect();
    let valid: Vec<usize> = (0..n).filter(|&i| finite[i]).collect();
    if valid.len() <= 1 || k == 0 {
        return vec![fallback; n];
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &i in &valid {
        for a in 0..3 {
            lo[a] = lo[a].min(points[i][a] as f64);
            hi[a] = hi[a].max(points[i][a] as f64);
        }
    }
    let ext: Vec<f64> = (0..3).map(|a| (hi[a] - lo[a]).max(1e-12)).collect();
    // Cell size so that there are about 2 points per cell (cube root of volume per point);
    // cap the grid at ~4M cells (degenerate flat clouds get a coarser grid).
    let vol: f64 = ext.iter().product();
    let mut cell = (2.0 * vol / valid.len() as f64).cbrt();
    let max_ext = ext.iter().cloned().fold(0.0, f64::max);
    cell = cell.max(max_ext / 256.0).max(1e-12);
    let dims: [usize; 3] = std::array::from_fn(|a| ((ext[a] / cell).floor() as usize + 1).max(1));
    let cell_of = |p: &[f32; 3]| -> [usize; 3] {
        std::array::from_fn(|a| (((p[a] as f64 - lo[a]) / cell) as usize).min(dims[a] - 1))
    };
    let lin = |c: [usize; 3]| (c[2] * dims[1] + c[1]) * dims[0] + c[0];
    let ncell = dims[0] * dims[1] * dims[2];
    // Counting sort of the valid points by cell.
    let mut start = vec![0u32; ncell + 1];
    let cells: Vec<usize> = valid.iter().map(|&i| lin(cell_of(&points[i]))).collect();
    for &c in &cells {
        start[c + 1] += 1;
    }
    for c in 0..ncell {
        start[c + 1] += start[c];
    }
    let mut fill = start.clone();
    let mut order = vec![0u32; valid.len()];
    for (j, &c) in cells.iter().enumerate() {
        order[fill[c] as usize] = valid[j] as u32;
        fill[c] += 1;
    }
    let kk = k.min(valid.len() - 1);
    (0..n)
        .into_par_iter()
        .map(|i| {
            if !finite[i] {
                return fallback;
            }
            let p = points[i];
            let c = cell_of(&p);
            // Best kk squared distances, ascending (small fixed k: insertion).
            let mut best = vec![f64::INFINITY; kk];
            let mut r = 0usize;
            loop {
                // Visit the shell at Chebyshev radius r.
                let lo_c: [isize; 3] = std::array::from_fn(|a| c[a] as isize - r as isize);
                let hi_c: [isize; 3] = std::array::from_fn(|a| c[a] as isize + r as isize);
                for z in lo_c[2].max(0)..=hi_c[2].min(dims[2] as isize - 1) {
                    for y in lo_c[1].max(0)..=hi_c[1].min(dims[1] as isize - 1) {
                        for x in lo_c[0].max(0)..=hi_c[0].min(dims[0] as isize - 1) {
                            let on_shell = x == lo_c[0]
                                || x == hi_c[0]
                                || y == lo_c[1]
                                || y == hi_c[1]
                                || z == lo_c[2]
                                || z == hi_c[2];
                            if !on_shell {
                                continue;
                            }
                            let cc = lin([x as usize, y as usize, z as usize]);
                            for &j in &order[start[cc] as usize..start[cc + 1] as usize] {
                                let j = j as usize;
                                if j == i {
                                    continue;
                                }
                                let q = points[j];
                                let d2: f64 = (0..3)
                                    .map(|a| {
                                        let d = p[a] as f64 - q[a] as f64;
                                        d * d
                                    })
                                    .sum();
                                if d2 < best[kk - 1] {
                                    let mut s = kk - 1;
                                    while s > 0 && best[s - 1] > d2 {
                                        best[s] = best[s - 1];
                                        s -= 1;
                                    }
                                    best[s] = d2;
                                }
                            }
                        }
                    }
                }
                // Every unvisited point is at least r·cell away (beyond the shell r).
                let reach = r as f64 * cell;
                let covered = (0..3).all(|a| c[a] < r + 1 && c[a] + r + 1 >= dims[a]);
                if covered || (best[kk - 1].is_finite() && best[kk - 1] <= reach * reach) {
                    break;
                }
                r += 1;
            }
            (best.iter().sum::<f64>() / kk as f64).sqrt()
        })
        .collect()
}

/// Gaussians from a point cloud: one per finite point, at `sh_degree` storage. The scale of a
/// point is `max(rms 3-NN distance · scale_factor, 1e-7 · scene_scale)` (so duplicate points
/// do not give log(0)); a single point uses 0.01 · scene_scale.
pub fn from_points(
    cloud: &PointCloud,
    sh_degree: u32,
    args: &InitArgs,
    scene_scale: f64,
    seed: u64,
) -> Gaussians {
    let keep: Vec<usize> = (0..cloud.len())
        .filter(|&i| cloud.positions[i].iter().all(|v| v.is_finite()))
        .collect();
    let positions: Vec<[f32; 3]> = keep.iter().map(|&i| cloud.positions[i]).collect();
    let colors: Vec<[f32; 3]> = keep
        .iter()
        .map(|&i| cloud.colors.get(i).copied().unwrap_or([0.5; 3]))
        .collect();
    build(positions, colors, sh_degree, args, scene_scale, seed)
}

/// Gaussians at `args.random_points` points uniform in the cube of half-side
/// `random_extent · scene_scale` around `center`, with uniform random colours (gsplat's
/// `init_type = "random"`).
pub fn random(
    center: [f64; 3],
    sh_degree: u32,
    args: &InitArgs,
    scene_scale: f64,
    seed: u64,
) -> Gaussians {
    let mut rng = Rng::stream(seed, 0x1417);
    let half = args.random_extent * scene_scale;
    let mut positions = Vec::with_capacity(args.random_points);
    let mut colors = Vec::with_capacity(args.random_points);
    for _ in 0..args.random_points {
        positions.push(std::array::from_fn(|a| {
            (center[a] + half * (2.0 * rng.next_f64() - 1.0)) as f32
        }));
        colors.push(std::array::from_fn(|_| rng.next_f32()));
    }
    build(positions, colors, sh_degree, args, scene_scale, seed)
}

/// One training view for [`random_in_frusta`]: its camera and interleaved RGB image of the
/// camera's size.
pub struct InitView<'a> {
    /// The camera.
    pub camera: &'a Camera,
    /// Interleaved RGB, `height · width · 3`.
    pub image: &'a [f32],
}

/// Gaussians at `args.random_points` points on rays through uniformly random pixels of
/// uniformly drawn `views`, at a depth along the optical axis uniform in disparity between
/// `near` and `far`, with the colour of the pixel the ray passes through. Views whose image
/// does not match their camera's size are given a grey colour.
pub fn random_in_frusta(
    views: &[InitView<'_>],
    near: f64,
    far: f64,
    sh_degree: u32,
    args: &InitArgs,
    scene_scale: f64,
    seed: u64,
) -> Gaussians {
    let mut rng = Rng::stream(seed, 0x1418);
    let mut positions = Vec::with_capacity(args.random_points);
    let mut colors = Vec::with_capacity(args.random_points);
    if views.is_empty() {
        return build(positions, colors, sh_degree, args, scene_scale, seed);
    }
    let (d_near, d_far) = (1.0 / near, 1.0 / far);
    for _ in 0..args.random_points {
        let v = &views[((rng.next_f64() * views.len() as f64) as usize).min(views.len() - 1)];
        let cam = v.camera;
        let u = rng.next_f64() * cam.width as f64;
        let w = rng.next_f64() * cam.height as f64;
        let disparity = d_far + (d_near - d_far) * rng.next_f64();
        let z = 1.0 / disparity;
        positions.push(point_at_depth(cam, u, w, z));
        colors.push(colour_at(v, u, w));
    }
    build(positions, colors, sh_degree, args, scene_scale, seed)
}

/// The point at depth `z` along the optical axis on `cam`'s ray through image position
/// (`u`, `w`).
fn point_at_depth(cam: &Camera, u: f64, w: f64, z: f64) -> [f32; 3] {
    let (origin, dir) = cam.ray(u, w);
    // `dir` is unit; the camera-space direction with z = 1 is |(x, y, 1)| long.
    let (x, y) = ((u - cam.cx) / cam.fx, (w - cam.cy) / cam.fy);
    let dist = z * (x * x + y * y + 1.0).sqrt();
    std::array::from_fn(|a| (origin[a] + dir[a] * dist) as f32)
}

/// The photo's colour at image position (`u`, `w`); grey when the image does not match its
/// camera's size.
fn colour_at(v: &InitView<'_>, u: f64, w: f64) -> [f32; 3] {
    let cam = v.camera;
    let (px, py) = (
        (u as usize).min(cam.width as usize - 1),
        (w as usize).min(cam.height as usize - 1),
    );
    let idx = (py * cam.width as usize + px) * 3;
    if v.image.len() == cam.width as usize * cam.height as usize * 3 {
        [v.image[idx], v.image[idx + 1], v.image[idx + 2]]
    } else {
        [0.5; 3]
    }
}

fn build(
    positions: Vec<[f32; 3]>,
    colors: Vec<[f32; 3]>,
    sh_degree: u32,
    args: &InitArgs,
    scene_scale: f64,
    seed: u64,
) -> Gaussians {
    let n = positions.len();
    let floor = 1e-7 * scene_scale.max(1e-12);
    let dists = knn_rms_distance(&positions, 3, 0.01 * scene_scale);
    let mut g = Gaussians::empty(sh_degree);
    let k = g.coeffs();
    let mut rng = Rng::stream(seed, 0x9a7);
    let op = logit(args.opacity) as f32;
    g.sh = vec![0.0; n * k * 3];
    for i in 0..n {
        let s = (dists[i] * args.scale_factor).max(floor).ln() as f32;
        g.log_scales.push([s; 3]);
        g.quats.push(std::array::from_fn(|_| rng.next_f32()));
        g.opacity_logits.push(op);
        for (c, &col) in colors[i].iter().enumerate() {
            g.sh[i * k * 3 + c] = ((col as f64 - 0.5) / SH_C0) as f32;
        }
    }
    g.means = positions;
    g
}

/// The radiance-field prior's depth at one training view, for [`from_prior_depth`]: depth
/// along the optical axis (`RenderField`'s D: expected depth, 0 where nothing was hit) and
/// accumulated opacity, row-major at `width × height` — the view's camera scaled by any
/// factor (a render at 1/4 of the training size samples the same view).
pub struct PriorDepth<'a> {
    /// Index of the training view in the `views` given with it.
    pub view: usize,
    /// Width of the maps.
    pub width: u32,
    /// Height of the maps.
    pub height: u32,
    /// Expected depth (not divided by the opacity).
    pub depth: &'a [f32],
    /// Accumulated opacity.
    pub alpha: &'a [f32],
}

/// Opacity a prior pixel needs before its depth is trusted.
pub const PRIOR_MIN_ALPHA: f32 = 0.5;

/// Gaussians at up to `args.random_points` points back-projected from the prior's depth:
/// each draws a map uniformly, then a pixel uniformly within it; a pixel with opacity below
/// [`PRIOR_MIN_ALPHA`] or no finite positive depth is drawn again (at most 20 draws per
/// point). The point lies on the training camera's ray through that pixel at depth D / A
/// along the optical axis, coloured by the training photo there.
pub fn from_prior_depth(
    views: &[InitView<'_>],
    prior: &[PriorDepth<'_>],
    sh_degree: u32,
    args: &InitArgs,
    scene_scale: f64,
    seed: u64,
) -> Gaussians {
    let mut rng = Rng::stream(seed, 0xde97);
    let mut positions = Vec::with_capacity(args.random_points);
    let mut colors = Vec::with_capacity(args.random_points);
    let usable: Vec<&PriorDepth<'_>> = prior
        .iter()
        .filter(|p| {
            p.view < views.len()
                && p.width > 0
                && p.height > 0
                && p.depth.len() == (p.width * p.height) as usize
                && p.alpha.len() == p.depth.len()
        })
        .collect();
    if !usable.is_empty() {
        let mut draws = 0usize;
        while positions.len() < args.random_points && draws < 20 * args.random_points {
            draws += 1;
            let p = usable[((rng.next_f64() * usable.len() as f64) as usize).min(usable.len() - 1)];
            let (fu, fw) = (
                rng.next_f64() * p.width as f64,
                rng.next_f64() * p.height as f64,
            );
            let i = (fw as usize).min(p.height as usize - 1) * p.width as usize
                + (fu as usize).min(p.width as usize - 1);
            let (d, a) = (p.depth[i], p.alpha[i]);
            if !(a >= PRIOR_MIN_ALPHA && d.is_finite() && d > 0.0) {
                continue;
            }
            let z = (d / a) as f64;
            let v = &views[p.view];
            // The same continuous image position in the training camera.
            let u = fu * v.camera.width as f64 / p.width as f64;
            let w = fw * v.camera.height as f64 / p.height as f64;
            positions.push(point_at_depth(v.camera, u, w, z));
            colors.push(colour_at(v, u, w));
        }
    }
    build(positions, colors, sh_degree, args, scene_scale, seed)
}

/// The initial Gaussians [`initial_gaussians`] chose, and why.
#[derive(Clone, Debug)]
pub struct Initial {
    /// The Gaussians to start training from.
    pub gaussians: Gaussians,
    /// What was chosen, in words, when the scene had no sparse points (`None` when the
    /// Gaussians come from the points).
    pub note: Option<String>,
    /// Whether the choice is a poor last resort the user must hear about (no points, no
    /// prior depth and no usable bounds: a cube around the cameras).
    pub warn: bool,
}

impl Initial {
    /// The note with what to do about it, when the choice is a poor last resort
    /// ([`Initial::warn`]).
    pub fn terminal_warning(&self) -> Option<String> {
        let note = self.note.as_ref().filter(|_| self.warn)?;
        Some(format!(
            "{note}; connect `init_depth` (a radiance field's renders at the training views) \
             or give the scene SfM points or near/far bounds"
        ))
    }
}

/// The initialisation policy of a training run: the scene's sparse points when it has any
/// ([`from_points`]); otherwise the prior's depth when given and it yields at least 1 % of
/// `args.random_points` points ([`from_prior_depth`]); otherwise `args.random_points` random
/// Gaussians, on the training views'
/// rays between the scene's `near` and `far` bounds ([`random_in_frusta`]) when
/// `args.random_in` is [`RandomInit::Frusta`] and those bounds are usable (finite,
/// 0 < near < far), else in a cube around the training cameras' mean ([`random`]).
#[allow(clippy::too_many_arguments)]
pub fn initial_gaussians(
    cloud: &PointCloud,
    scene: &Scene,
    views: &[InitView<'_>],
    prior: &[PriorDepth<'_>],
    sh_degree: u32,
    args: &InitArgs,
    scene_scale: f64,
    seed: u64,
) -> Initial {
    if !cloud.is_empty() {
        return Initial {
            gaussians: from_points(cloud, sh_degree, args, scene_scale, seed),
            note: None,
            warn: false,
        };
    }
    if !prior.is_empty() {
        let g = from_prior_depth(views, prior, sh_degree, args, scene_scale, seed);
        if g.len() * 100 >= args.random_points.max(1) {
            return Initial {
                note: Some(format!(
                    "no sparse points: {} Gaussians back-projected from the radiance field's depth at {} training view(s)",
                    g.len(),
                    prior.len()
                )),
                gaussians: g,
                warn: false,
            };
        }
    }
    let (near, far) = (scene.near, scene.far);
    let bounds_ok = near.is_finite() && far.is_finite() && near > 0.0 && far > near;
    match args.random_in {
        RandomInit::Frusta if bounds_ok => Initial {
            note: Some(format!(
                "no sparse points: {} random Gaussians on training rays, depth {near:.3}–{far:.3} (uniform in disparity)",
                args.random_points
            )),
            gaussians: random_in_frusta(views, near, far, sh_degree, args, scene_scale, seed),
            warn: false,
        },
        mode => {
            let cs: Vec<[f64; 3]> = views.iter().map(|v| v.camera.center()).collect();
            let center =
                std::array::from_fn(|k| cs.iter().map(|c| c[k]).sum::<f64>() / cs.len() as f64);
            Initial {
                note: Some(format!(
                    "no sparse points: {} random Gaussians in a cube of half-side {} scene scales{}",
                    args.random_points,
                    args.random_extent,
                    if mode == RandomInit::Frusta {
                        format!(" (the scene's bounds {near}–{far} are unusable for Frusta)")
                    } else {
                        String::new()
                    }
                )),
                gaussians: random(center, sh_degree, args, scene_scale, seed),
                warn: mode == RandomInit::Frusta,
            }
        }
    }
}
