//! Synthetic pose synthesis (AugSplat §3 and the authors' reference code; docs/design.md,
//! *The method*).
//!
//! The candidate pool has two parts:
//! - **jittered copies** of the training poses: copy `k` perturbs training camera `k mod n`
//!   (round-robin, so every camera gets its share): its centre moves by an offset drawn
//!   uniformly inside a ball of radius `offset_radius × d_nn` (`d_nn` = median over cameras of
//!   the distance to the nearest other camera centre), and it turns by yaw, pitch and roll drawn
//!   uniformly in `[−max, max]` **in the camera frame** (OpenCV axes: yaw about the camera's
//!   y axis, positive looks right; pitch about its x axis, positive looks up; roll about its
//!   optical axis);
//! - **interpolations** between each camera and its `k` nearest neighbours (by centre distance,
//!   ties broken by index) at the given fractions: centre lerp, rotation slerp, intrinsics lerp
//!   (when both cameras have the same image size; otherwise the first camera's). Each unordered
//!   pair is used once (a mutual neighbour pair would otherwise give the same poses twice with
//!   symmetric fractions); fraction `α` runs from the lower-indexed camera to the other.
//!
//! Then `count` poses are drawn without replacement (seeded); when the pool holds fewer, all of
//! it is used. The output keeps pool order (jitter first). Intrinsics are those of the source
//! camera(s) resized to `ceil(w / downscale) × ceil(h / downscale)` with
//! [`Camera::resized`] (the same size [`augsplat_core::ImageF32::downscale`] gives).
//!
//! Random streams: jitter draws from `Rng::stream(seed, 0)`, the final draw from
//! `Rng::stream(seed, 1)`, so the result depends on the seed arg alone.

use augsplat_core::artifacts::PoseView;
use augsplat_core::linalg::{self, Mat3, Vec3};
use augsplat_core::{Camera, Rng};
use serde::{Deserialize, Serialize};

/// Jitter settings (the reference code's values are the defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct JitterParams {
    /// Number of jittered copies in the pool.
    pub copies: usize,
    /// Maximum centre offset, as a multiple of the median nearest-neighbour camera distance.
    pub offset_radius: f64,
    /// Maximum yaw (about the camera y axis), degrees.
    pub yaw_deg: f64,
    /// Maximum pitch (about the camera x axis), degrees.
    pub pitch_deg: f64,
    /// Maximum roll (about the optical axis), degrees.
    pub roll_deg: f64,
}

impl Default for JitterParams {
    fn default() -> Self {
        JitterParams {
            copies: 100,
            offset_radius: 0.2,
            yaw_deg: 10.0,
            pitch_deg: 6.0,
            roll_deg: 2.0,
        }
    }
}

/// Interpolation settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InterpolationParams {
    /// Number of nearest neighbours of each camera to interpolate towards.
    pub neighbours: usize,
    /// Fractions along each pair, each in [0, 1].
    pub fractions: Vec<f64>,
}

impl Default for InterpolationParams {
    fn default() -> Self {
        InterpolationParams {
            neighbours: 3,
            fractions: vec![0.25, 0.5, 0.75],
        }
    }
}

/// Everything that decides the synthetic poses.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseParams {
    /// Number of poses to draw from the pool (N_syn).
    pub count: usize,
    /// Seed of the jitter and of the draw.
    pub seed: u64,
    /// Jittered copies of the training poses.
    pub jitter: JitterParams,
    /// Interpolations between neighbouring training poses.
    pub interpolation: InterpolationParams,
    /// Resolution divisor of the synthetic views relative to the training cameras.
    pub downscale: u32,
}

impl Default for PoseParams {
    fn default() -> Self {
        PoseParams {
            count: 200,
            seed: 0,
            jitter: JitterParams::default(),
            interpolation: InterpolationParams::default(),
            downscale: 8,
        }
    }
}

impl PoseParams {
    /// Checks ranges: finite non-negative radius and angles, fractions in [0, 1], downscale ≥ 1.
    pub fn validate(&self) -> Result<(), String> {
        let j = &self.jitter;
        for (name, v) in [
            ("jitter.offset_radius", j.offset_radius),
            ("jitter.yaw_deg", j.yaw_deg),
            ("jitter.pitch_deg", j.pitch_deg),
            ("jitter.roll_deg", j.roll_deg),
        ] {
            if !v.is_finite() || v < 0.0 {
                return Err(format!("{name} = {v} must be finite and ≥ 0"));
            }
        }
        for (i, f) in self.interpolation.fractions.iter().enumerate() {
            if !f.is_finite() || !(0.0..=1.0).contains(f) {
                return Err(format!(
                    "interpolation.fractions[{i}] = {f} must lie in [0, 1]"
                ));
            }
        }
        if self.downscale == 0 {
            return Err("downscale must be ≥ 1".into());
        }
        if self.count == 0 {
            return Err("count must be ≥ 1".into());
        }
        Ok(())
    }
}

/// Errors of pose synthesis.
#[derive(Debug, thiserror::Error)]
pub enum PoseError {
    /// The training set has no cameras.
    #[error("the training scene has no views: cannot synthesise poses")]
    NoCameras,
    /// A training camera is unusable.
    #[error("training view `{name}` has an invalid camera: {reason}")]
    BadCamera {
        /// The view's name.
        name: String,
        /// What is wrong.
        reason: String,
    },
    /// The pool is empty (no jitter copies and no interpolations).
    #[error("the candidate pool is empty: set jitter.copies > 0 or interpolation.neighbours > 0 with at least one fraction (and ≥ 2 training views)")]
    EmptyPool,
    /// The args are out of range.
    #[error("{0}")]
    Args(String),
}

/// One candidate synthetic pose (full resolution until the final resize).
#[derive(Clone, Debug, PartialEq)]
pub struct Candidate {
    /// The camera.
    pub camera: Camera,
    /// Provenance, e.g. `jitter:DSC01` or `interp:DSC01,DSC02@0.25`.
    pub origin: String,
}

/// The median of `values` (sorted in place); the mean of the two middle values for an even
/// count; NaN for an empty slice.
pub fn median_f64(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_unstable_by(|a, b| a.total_cmp(b));
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}

/// For each centre, the distance to the nearest other centre (∞ when there is only one).
pub fn nearest_neighbour_distances(centers: &[Vec3]) -> Vec<f64> {
    centers
        .iter()
        .enumerate()
        .map(|(i, c)| {
            centers
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, d)| linalg::norm(linalg::sub(*c, *d)))
                .fold(f64::INFINITY, f64::min)
        })
        .collect()
}

/// The median nearest-neighbour distance between camera centres; 0 with fewer than two
/// cameras (then jitter offsets are zero).
pub fn median_nn_distance(centers: &[Vec3]) -> f64 {
    if centers.len() < 2 {
        return 0.0;
    }
    median_f64(&mut nearest_neighbour_distances(centers))
}

/// The indices of the `k` centres nearest to centre `i` (excluding `i`), nearest first,
/// ties broken by lower index.
pub fn nearest_neighbours(centers: &[Vec3], i: usize, k: usize) -> Vec<usize> {
    let mut others: Vec<(f64, usize)> = centers
        .iter()
        .enumerate()
        .filter(|(j, _)| *j != i)
        .map(|(j, c)| (linalg::norm(linalg::sub(*c, centers[i])), j))
        .collect();
    others.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    others.into_iter().take(k).map(|(_, j)| j).collect()
}

/// The rotation `R_y(yaw) · R_x(pitch) · R_z(roll)` (radians), about the camera's own axes.
pub fn camera_frame_rotation(yaw: f64, pitch: f64, roll: f64) -> Mat3 {
    let ry = linalg::axis_angle([0.0, 1.0, 0.0], yaw);
    // About +x, e_z turns towards −y: a positive pitch looks up (OpenCV y points down).
    let rx = linalg::axis_angle([1.0, 0.0, 0.0], pitch);
    let rz = linalg::axis_angle([0.0, 0.0, 1.0], roll);
    linalg::mat3_mul(&linalg::mat3_mul(&ry, &rx), &rz)
}

/// A camera with the same intrinsics whose centre is moved by `offset` (world units) and whose
/// orientation is turned by yaw, pitch and roll (radians) in its own frame:
/// camera-to-world rotation `R_c2w · R_y(yaw) R_x(pitch) R_z(roll)`.
pub fn jitter_camera(cam: &Camera, offset: Vec3, yaw: f64, pitch: f64, roll: f64) -> Camera {
    let r = cam.rotation();
    let local = camera_frame_rotation(yaw, pitch, roll);
    // world-to-camera rotation = (R_c2w · local)ᵀ = localᵀ · R.
    let r_new = linalg::mat3_mul(&linalg::transpose3(&local), &r);
    let c_new = linalg::add(cam.center(), offset);
    let t_new = linalg::scale(linalg::mat3_vec(&r_new, c_new), -1.0);
    Camera {
        world_to_camera: linalg::mat4_from_rt(&r_new, t_new),
        ..cam.clone()
    }
}

/// The camera a fraction `t` of the way from `a` to `b`: centre lerp, rotation slerp,
/// intrinsics lerp when both have the same image size (otherwise `a`'s).
pub fn interpolate_camera(a: &Camera, b: &Camera, t: f64) -> Camera {
    let qa = linalg::mat3_to_quat(&a.rotation());
    let qb = linalg::mat3_to_quat(&b.rotation());
    let r = linalg::quat_to_mat3(linalg::slerp(qa, qb, t));
    let c = linalg::lerp(a.center(), b.center(), t);
    let tr = linalg::scale(linalg::mat3_vec(&r, c), -1.0);
    let mut out = a.clone();
    if a.width == b.width && a.height == b.height {
        let l = |x: f64, y: f64| x + (y - x) * t;
        out.fx = l(a.fx, b.fx);
        out.fy = l(a.fy, b.fy);
        out.cx = l(a.cx, b.cx);
        out.cy = l(a.cy, b.cy);
    }
    out.world_to_camera = linalg::mat4_from_rt(&r, tr);
    out
}

/// A direction drawn uniformly on the unit sphere times a radius drawn so that the point is
/// uniform in the ball of radius `radius`.
fn uniform_in_ball(rng: &mut Rng, radius: f64) -> Vec3 {
    if radius <= 0.0 {
        // Keep the stream length independent of the radius.
        for _ in 0..4 {
            rng.next_f64();
        }
        return [0.0; 3];
    }
    loop {
        let d = [rng.normal(), rng.normal(), rng.normal()];
        let n = linalg::norm(d);
        let u = rng.next_f64();
        if n > 1e-12 {
            return linalg::scale(d, radius * u.cbrt() / n);
        }
    }
}

/// The full candidate pool (jitter copies, then interpolations) at full resolution.
pub fn candidate_pool(
    views: &[(String, Camera)],
    params: &PoseParams,
) -> Result<Vec<Candidate>, PoseError> {
    if views.is_empty() {
        return Err(PoseError::NoCameras);
    }
    for (name, cam) in views {
        cam.validate().map_err(|reason| PoseError::BadCamera {
            name: name.clone(),
            reason,
        })?;
    }
    let centers: Vec<Vec3> = views.iter().map(|(_, c)| c.center()).collect();
    let d_nn = median_nn_distance(&centers);
    let j = &params.jitter;
    let mut pool = Vec::new();
    let mut rng = Rng::stream(params.seed, 0);
    for k in 0..j.copies {
        let (name, cam) = &views[k % views.len()];
        let offset = uniform_in_ball(&mut rng, j.offset_radius * d_nn);
        let yaw = rng.uniform(-1.0, 1.0) * j.yaw_deg.to_radians();
        let pitch = rng.uniform(-1.0, 1.0) * j.pitch_deg.to_radians();
        let roll = rng.uniform(-1.0, 1.0) * j.roll_deg.to_radians();
        pool.push(Candidate {
            camera: jitter_camera(cam, offset, yaw, pitch, roll),
            origin: format!("jitter:{name}"),
        });
    }
    let interp = &params.interpolation;
    let mut pairs: Vec<(usize, usize)> = Vec::new();
    for i in 0..views.len() {
        for nb in nearest_neighbours(&centers, i, interp.neighbours) {
            let pair = (i.min(nb), i.max(nb));
            if !pairs.contains(&pair) {
                pairs.push(pair);
            }
        }
    }
    for (a, b) in pairs {
        for &t in &interp.fractions {
            pool.push(Candidate {
                camera: interpolate_camera(&views[a].1, &views[b].1, t),
                origin: format!("interp:{},{}@{t}", views[a].0, views[b].0),
            });
        }
    }
    if pool.is_empty() {
        return Err(PoseError::EmptyPool);
    }
    Ok(pool)
}

/// Pool indices of the drawn poses: `count` drawn without replacement with
/// `Rng::stream(seed, 1)`, returned in increasing order; all of them when `count ≥ pool`.
pub fn draw_indices(pool_len: usize, count: usize, seed: u64) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..pool_len).collect();
    if count >= pool_len {
        return idx;
    }
    let mut rng = Rng::stream(seed, 1);
    // Partial Fisher–Yates: the first `count` slots are a uniform sample.
    for i in 0..count {
        let j = i + rng.below((pool_len - i) as u64) as usize;
        idx.swap(i, j);
    }
    idx.truncate(count);
    idx.sort_unstable();
    idx
}

/// The synthetic poses: pool, draw, resize. Names are `syn0000`, `syn0001`, … in output order.
pub fn synthesize_poses(
    views: &[(String, Camera)],
    params: &PoseParams,
) -> Result<Vec<PoseView>, PoseError> {
    params.validate().map_err(PoseError::Args)?;
    let pool = candidate_pool(views, params)?;
    let chosen = draw_indices(pool.len(), params.count, params.seed);
    let ds = params.downscale;
    Ok(chosen
        .into_iter()
        .enumerate()
        .map(|(k, i)| {
            let c = &pool[i];
            let w = c.camera.width.div_ceil(ds).max(1);
            let h = c.camera.height.div_ceil(ds).max(1);
            PoseView {
                name: format!("syn{k:04}"),
                camera: c.camera.resized(w, h),
                origin: c.origin.clone(),
            }
        })
        .collect())
}

/// Minimum, median and maximum of a sample (all NaN when empty).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Spread {
    /// Smallest value.
    pub min: f64,
    /// Median (mean of the two middle values for an even count).
    pub median: f64,
    /// Largest value.
    pub max: f64,
}

impl Spread {
    /// The spread of `values`.
    pub fn of(values: &[f64]) -> Spread {
        let mut v = values.to_vec();
        let median = median_f64(&mut v);
        Spread {
            min: v.first().copied().unwrap_or(f64::NAN),
            median,
            max: v.last().copied().unwrap_or(f64::NAN),
        }
    }
}

/// How near the synthetic poses stay to the observed camera distribution (`poses_report.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PosesReport {
    /// Training cameras.
    pub training_views: usize,
    /// Median nearest-neighbour distance between training camera centres (world units).
    pub median_nn_distance: f64,
    /// Candidates in the pool: jittered copies.
    pub pool_jitter: usize,
    /// Candidates in the pool: interpolations.
    pub pool_interpolated: usize,
    /// Poses requested.
    pub requested: usize,
    /// Poses drawn (the pool size when it was smaller than the request).
    pub drawn: usize,
    /// Drawn poses that are jittered copies.
    pub drawn_jitter: usize,
    /// Drawn poses that are interpolations.
    pub drawn_interpolated: usize,
    /// Distance from each drawn pose's centre to the nearest training centre, divided by the
    /// median nearest-neighbour distance (raw distance when that median is 0).
    pub nearest_distance_rel: Spread,
    /// Angle between each drawn pose's view direction and that of the training camera with
    /// the nearest centre, degrees.
    pub nearest_view_angle_deg: Spread,
    /// Smallest angle between each drawn pose's view direction and any training camera's,
    /// degrees.
    pub min_view_angle_deg: Spread,
}

/// Measures how near `poses` stay to the training cameras.
pub fn proximity_report(
    views: &[(String, Camera)],
    pool: (usize, usize),
    requested: usize,
    poses: &[PoseView],
) -> PosesReport {
    let centers: Vec<Vec3> = views.iter().map(|(_, c)| c.center()).collect();
    let forwards: Vec<Vec3> = views.iter().map(|(_, c)| c.forward()).collect();
    let d_nn = median_nn_distance(&centers);
    let angle = |a: Vec3, b: Vec3| linalg::dot(a, b).clamp(-1.0, 1.0).acos().to_degrees();
    let mut dist = Vec::with_capacity(poses.len());
    let mut near_angle = Vec::with_capacity(poses.len());
    let mut min_angle = Vec::with_capacity(poses.len());
    for p in poses {
        let c = p.camera.center();
        let f = p.camera.forward();
        let (best, d) = centers
            .iter()
            .enumerate()
            .map(|(i, t)| (i, linalg::norm(linalg::sub(c, *t))))
            .fold(
                (0, f64::INFINITY),
                |acc, x| if x.1 < acc.1 { x } else { acc },
            );
        dist.push(if d_nn > 0.0 { d / d_nn } else { d });
        near_angle.push(forwards.get(best).map_or(f64::NAN, |t| angle(f, *t)));
        min_angle.push(
            forwards
                .iter()
                .map(|t| angle(f, *t))
                .fold(f64::INFINITY, f64::min),
        );
    }
    let drawn_jitter = poses
        .iter()
        .filter(|p| p.origin.starts_with("jitter:"))
        .count();
    PosesReport {
        training_views: views.len(),
        median_nn_distance: d_nn,
        pool_jitter: pool.0,
        pool_interpolated: pool.1,
        requested,
        drawn: poses.len(),
        drawn_jitter,
        drawn_interpolated: poses.len() - drawn_jitter,
        nearest_distance_rel: Spread::of(&dist),
        nearest_view_angle_deg: Spread::of(&near_angle),
        min_view_angle_deg: Spread::of(&min_angle),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use augsplat_core::linalg::{axis_angle, mat4_from_rt};

    /// A ring of cameras looking at the origin.
    pub(crate) fn ring(n: usize) -> Vec<(String, Camera)> {
        (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                let c = [3.0 * a.cos(), 0.3 * (i as f64).sin(), 3.0 * a.sin()];
                // Look at the origin: forward = −c/|c|, y down ≈ world −y.
                let f = linalg::normalize(linalg::scale(c, -1.0));
                let x = linalg::normalize(linalg::cross([0.0, -1.0, 0.0], f));
                let y = linalg::cross(f, x);
                let r = [x, y, f];
                let t = linalg::scale(linalg::mat3_vec(&r, c), -1.0);
                (
                    format!("v{i}"),
                    Camera {
                        width: 64,
                        height: 48,
                        fx: 60.0,
                        fy: 60.0,
                        cx: 32.0,
                        cy: 24.0,
                        world_to_camera: mat4_from_rt(&r, t),
                    },
                )
            })
            .collect()
    }

    fn angle_between(a: Vec3, b: Vec3) -> f64 {
        linalg::dot(a, b).clamp(-1.0, 1.0).acos()
    }

    #[test]
    fn median_even_and_odd() {
        assert_eq!(median_f64(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median_f64(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median_f64(&mut []).is_nan());
    }

    #[test]
    fn counts_and_pool_sizes() {
        let views = ring(8);
        let p = PoseParams {
            count: 50,
            ..PoseParams::default()
        };
        let pool = candidate_pool(&views, &p).unwrap();
        // Independent count: unordered pairs {i, j} with j among the 3 nearest centres of i.
        let cs: Vec<Vec3> = views.iter().map(|(_, c)| c.center()).collect();
        let mut pairs = std::collections::BTreeSet::new();
        for i in 0..cs.len() {
            let mut d: Vec<(f64, usize)> = (0..cs.len())
                .filter(|&j| j != i)
                .map(|j| (linalg::norm(linalg::sub(cs[i], cs[j])), j))
                .collect();
            d.sort_by(|a, b| a.partial_cmp(b).unwrap());
            for &(_, j) in &d[..3] {
                pairs.insert((i.min(j), i.max(j)));
            }
        }
        assert!(pairs.len() >= 12 && pairs.len() <= 24);
        assert_eq!(pool.len(), 100 + 3 * pairs.len());
        assert_eq!(
            pool.iter()
                .filter(|c| c.origin.starts_with("interp:"))
                .count(),
            3 * pairs.len()
        );
        let poses = synthesize_poses(&views, &p).unwrap();
        assert_eq!(poses.len(), 50);
        let names: std::collections::BTreeSet<_> = poses.iter().map(|p| &p.name).collect();
        assert_eq!(names.len(), 50);
        // Too few candidates: the whole pool.
        let p2 = PoseParams {
            count: 10_000,
            ..PoseParams::default()
        };
        assert_eq!(synthesize_poses(&views, &p2).unwrap().len(), pool.len());
    }

    #[test]
    fn deterministic_by_seed() {
        let views = ring(6);
        let p = PoseParams {
            count: 40,
            seed: 3,
            ..PoseParams::default()
        };
        let a = synthesize_poses(&views, &p).unwrap();
        let b = synthesize_poses(&views, &p).unwrap();
        assert_eq!(a, b);
        let c = synthesize_poses(
            &views,
            &PoseParams {
                seed: 4,
                ..p.clone()
            },
        )
        .unwrap();
        assert_ne!(a, c);
    }

    #[test]
    fn draw_is_a_sample_without_replacement() {
        let idx = draw_indices(100, 30, 9);
        assert_eq!(idx.len(), 30);
        assert!(idx.windows(2).all(|w| w[0] < w[1]));
        assert!(idx.iter().all(|&i| i < 100));
        // Every index gets drawn sometimes (uniformity, roughly).
        let mut hits = [0u32; 20];
        for s in 0..400 {
            for i in draw_indices(20, 5, s) {
                hits[i] += 1;
            }
        }
        // Expected 100 each.
        assert!(hits.iter().all(|&h| (60..140).contains(&h)), "{hits:?}");
    }

    #[test]
    fn slerp_interpolation_endpoints_and_midpoint() {
        let views = ring(5);
        let (a, b) = (&views[0].1, &views[2].1);
        for (t, target) in [(0.0, a), (1.0, b)] {
            let c = interpolate_camera(a, b, t);
            for i in 0..4 {
                for j in 0..4 {
                    let d = c.world_to_camera[i][j] - target.world_to_camera[i][j];
                    assert!(d.abs() < 1e-9, "t={t} [{i}][{j}] {d}");
                }
            }
        }
        // Midpoint: centre is the midpoint; rotation is equally far (geodesically) from both.
        let m = interpolate_camera(a, b, 0.5);
        let mid = linalg::scale(linalg::add(a.center(), b.center()), 0.5);
        assert!(linalg::norm(linalg::sub(m.center(), mid)) < 1e-9);
        let geo = |x: &Camera, y: &Camera| {
            let r = linalg::mat3_mul(&x.rotation(), &linalg::transpose3(&y.rotation()));
            ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0)
                .clamp(-1.0, 1.0)
                .acos()
        };
        let (da, db, dab) = (geo(&m, a), geo(&m, b), geo(a, b));
        assert!((da - db).abs() < 1e-9 && (da + db - dab).abs() < 1e-9);
        // The rotation stays orthonormal.
        assert!((linalg::det3(&m.rotation()) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn jitter_turns_in_the_camera_frame() {
        let cam = &ring(4)[1].1;
        let yaw = 0.2;
        let j = jitter_camera(cam, [0.0; 3], yaw, 0.0, 0.0);
        // Yaw keeps the camera's y axis and turns the forward axis towards +x by `yaw`.
        let (r0, r1) = (cam.rotation(), j.rotation());
        assert!(linalg::norm(linalg::sub(r0[1], r1[1])) < 1e-12);
        assert!((angle_between(r0[2], r1[2]) - yaw).abs() < 1e-12);
        assert!(linalg::dot(r1[2], r0[0]) > 0.0, "positive yaw looks right");
        let p = jitter_camera(cam, [0.0; 3], 0.0, 0.1, 0.0);
        assert!(
            linalg::dot(p.rotation()[2], r0[1]) < 0.0,
            "positive pitch looks up"
        );
        let r = jitter_camera(cam, [0.0; 3], 0.0, 0.0, 0.3);
        assert!(linalg::norm(linalg::sub(r.rotation()[2], r0[2])) < 1e-12);
        // Pure offset moves the centre by exactly the offset.
        let o = jitter_camera(cam, [0.1, -0.2, 0.05], 0.0, 0.0, 0.0);
        let d = linalg::sub(o.center(), cam.center());
        assert!(linalg::norm(linalg::sub(d, [0.1, -0.2, 0.05])) < 1e-12);
    }

    #[test]
    fn jitter_bounds_are_respected() {
        let views = ring(7);
        let p = PoseParams {
            interpolation: InterpolationParams {
                neighbours: 0,
                fractions: vec![],
            },
            ..PoseParams::default()
        };
        let pool = candidate_pool(&views, &p).unwrap();
        assert_eq!(pool.len(), 100);
        let centers: Vec<Vec3> = views.iter().map(|(_, c)| c.center()).collect();
        let d_nn = median_nn_distance(&centers);
        let (ymax, pmax, rmax) = (10f64.to_radians(), 6f64.to_radians(), 2f64.to_radians());
        let mut max_off = 0f64;
        for (k, c) in pool.iter().enumerate() {
            let src = &views[k % views.len()];
            assert_eq!(c.origin, format!("jitter:{}", src.0));
            let off = linalg::norm(linalg::sub(c.camera.center(), src.1.center()));
            assert!(off <= 0.2 * d_nn + 1e-12, "offset {off} > {}", 0.2 * d_nn);
            max_off = max_off.max(off);
            // Forward turned by acos(cos(yaw) cos(pitch)) at most.
            let turn = angle_between(c.camera.forward(), src.1.forward());
            assert!(turn <= (ymax.cos() * pmax.cos()).acos() + 1e-12);
            // Total rotation angle bounded by the sum of the three.
            let r = linalg::mat3_mul(&c.camera.rotation(), &linalg::transpose3(&src.1.rotation()));
            let total = ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0)
                .clamp(-1.0, 1.0)
                .acos();
            assert!(total <= ymax + pmax + rmax + 1e-12);
            // Intrinsics unchanged.
            assert_eq!(c.camera.fx, src.1.fx);
        }
        // The ball is used, not just its centre.
        assert!(max_off > 0.1 * d_nn, "{max_off} vs {d_nn}");
    }

    #[test]
    fn intrinsics_follow_downscale() {
        let views = ring(4);
        let poses = synthesize_poses(
            &views,
            &PoseParams {
                count: 5,
                downscale: 5,
                ..PoseParams::default()
            },
        )
        .unwrap();
        for p in poses {
            assert_eq!((p.camera.width, p.camera.height), (13, 10));
            assert!((p.camera.fx - 60.0 * 13.0 / 64.0).abs() < 1e-12);
            assert!((p.camera.cy - 24.0 * 10.0 / 48.0).abs() < 1e-12);
        }
    }

    #[test]
    fn degenerate_inputs_give_errors_or_clean_results() {
        assert!(matches!(
            synthesize_poses(&[], &PoseParams::default()),
            Err(PoseError::NoCameras)
        ));
        // One camera: no interpolations, zero offsets, still valid poses.
        let one = ring(1);
        let poses = synthesize_poses(&one, &PoseParams::default()).unwrap();
        assert_eq!(poses.len(), 100);
        for p in &poses {
            assert!(linalg::norm(linalg::sub(p.camera.center(), one[0].1.center())) < 1e-12);
            assert!(p.camera.validate().is_ok());
        }
        let empty = PoseParams {
            jitter: JitterParams {
                copies: 0,
                ..JitterParams::default()
            },
            ..PoseParams::default()
        };
        assert!(matches!(
            synthesize_poses(&one, &empty),
            Err(PoseError::EmptyPool)
        ));
        let mut bad = ring(3);
        bad[1].1.fx = f64::NAN;
        let e = synthesize_poses(&bad, &PoseParams::default()).unwrap_err();
        assert!(e.to_string().contains("v1"), "{e}");
        let p = PoseParams {
            downscale: 0,
            ..PoseParams::default()
        };
        assert!(p.validate().is_err());
        let p = PoseParams {
            interpolation: InterpolationParams {
                neighbours: 3,
                fractions: vec![1.5],
            },
            ..PoseParams::default()
        };
        assert!(p.validate().unwrap_err().contains("fractions[0]"));
    }

    #[test]
    fn report_measures_proximity() {
        let views = ring(8);
        let p = PoseParams::default();
        let poses = synthesize_poses(&views, &p).unwrap();
        let rep = proximity_report(&views, (100, 0), p.count, &poses);
        assert_eq!(rep.drawn, poses.len());
        assert_eq!(rep.drawn_jitter + rep.drawn_interpolated, rep.drawn);
        // Interpolations between neighbours lie at most half a pair distance from an end;
        // jitters at most 0.2 d_nn. Ring neighbours at distance 2 are ~1.85 d_nn apart.
        assert!(rep.nearest_distance_rel.max <= 1.0 + 1e-9, "{rep:?}");
        assert!(rep.nearest_distance_rel.min >= 0.0);
        assert!(rep.min_view_angle_deg.max <= rep.nearest_view_angle_deg.max + 1e-9);
        // Training cameras themselves are at distance 0 and angle 0.
        let train: Vec<PoseView> = views
            .iter()
            .map(|(n, c)| PoseView {
                name: n.clone(),
                camera: c.clone(),
                origin: String::new(),
            })
            .collect();
        let self_rep = proximity_report(&views, (0, 0), 8, &train);
        assert!(self_rep.nearest_distance_rel.max < 1e-12);
        assert!(self_rep.nearest_view_angle_deg.max < 1e-5);
        let _ = axis_angle([1.0, 0.0, 0.0], 0.0);
    }
}
