//! Near/far bounds from the cameras alone, for captures with neither sparse points nor
//! per-view bounds (most transforms.json captures, COLMAP exports without points).
//!
//! An inward-facing capture looks at its subject: the optical axes pass close to one point,
//! the **focus** `p` minimising `Σ_i ‖(I − a_i a_iᵀ)(p − c_i)‖²` (camera centres `c_i`, unit
//! axes `a_i`). What every view sees lies in the frusta's common volume; around the focus,
//! camera `i` sees a ball of radius `d_i · sin θ_i` (`d_i` the focus's depth, `θ_i` the
//! smallest half field of view), and the subject is taken to fill the median such ball,
//! radius `R`. Then `near = min d_i − R`, `far = max d_i + R` (depths along the optical axis,
//! as the point-based bounds).
//!
//! These are the subject's bounds: a 360° capture's background (a room, a landscape) lies
//! beyond `far` (bonsai: 0.25–1.17 from the cameras against 0.49–5.46 from its points).
//!
//! The estimate is refused — and the importer warns — when the axes are nearly parallel (a
//! forward-facing capture: they converge nowhere), or when the focus lies behind a camera.

use augsplat_core::linalg::{self, Vec3};
use augsplat_core::{Camera, PointCloud};
use serde::{Deserialize, Serialize};

/// The axes must spread by at least this angle (degrees) for their meeting point to mean
/// anything: the smallest eigenvalue of `Σ (I − a aᵀ)` per camera must reach `sin²` of it.
pub const MIN_AXIS_SPREAD_DEGREES: f64 = 5.0;

/// Bounds estimated from the cameras.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraBounds {
    /// Near bound (depth along the optical axis).
    pub near: f64,
    /// Far bound.
    pub far: f64,
    /// Where the optical axes converge.
    pub focus: Vec3,
    /// Radius of the ball around the focus that the views share.
    pub radius: f64,
    /// Smallest and largest depth of the focus over the cameras.
    pub focus_depths: (f64, f64),
}

/// Estimates near/far from camera poses and intrinsics (see the module docs). The error says
/// why the cameras do not determine bounds.
pub fn from_cameras(cams: &[Camera]) -> Result<CameraBounds, String> {
    if cams.len() < 2 {
        return Err(format!(
            "{} camera(s): at least two are needed for their axes to converge",
            cams.len()
        ));
    }
    let mut a_sum = [[0f64; 3]; 3];
    let mut b_sum = [0f64; 3];
    for cam in cams {
        let a = linalg::normalize(cam.forward());
        let c = cam.center();
        for r in 0..3 {
            for k in 0..3 {
                let m = if r == k { 1.0 } else { 0.0 } - a[r] * a[k];
                a_sum[r][k] += m;
                b_sum[r] += m * c[k];
            }
        }
    }
    let n = cams.len() as f64;
    let spread = symmetric_min_eigenvalue(&a_sum) / n;
    let min_spread = MIN_AXIS_SPREAD_DEGREES.to_radians().sin().powi(2);
    if spread.is_nan() || spread < min_spread {
        return Err(format!(
            "the optical axes are nearly parallel (spread {:.1}°, under {MIN_AXIS_SPREAD_DEGREES}°): \
             a forward-facing capture, whose axes converge nowhere",
            spread.max(0.0).sqrt().asin().to_degrees()
        ));
    }
    let focus = solve3(&a_sum, b_sum).ok_or("the axes' normal equations are singular")?;
    if focus.iter().any(|v| !v.is_finite()) {
        return Err("the axes' meeting point is not finite".into());
    }
    let mut depths = Vec::with_capacity(cams.len());
    let mut radii = Vec::with_capacity(cams.len());
    for (i, cam) in cams.iter().enumerate() {
        let d = cam.to_camera(focus)[2];
        if d.is_nan() || d <= 0.0 {
            return Err(format!(
                "the axes meet behind camera {i} (depth {d:.3}): the cameras do not look at a common subject"
            ));
        }
        let half = [
            cam.cx / cam.fx,
            (cam.width as f64 - cam.cx) / cam.fx,
            cam.cy / cam.fy,
            (cam.height as f64 - cam.cy) / cam.fy,
        ]
        .into_iter()
        .fold(f64::INFINITY, f64::min)
        .max(0.0)
        .atan();
        depths.push(d);
        radii.push(d * half.sin());
    }
    radii.sort_by(f64::total_cmp);
    let radius = radii[radii.len() / 2];
    let dmin = depths.iter().copied().fold(f64::INFINITY, f64::min);
    let dmax = depths.iter().copied().fold(0.0, f64::max);
    let near = dmin - radius;
    let far = dmax + radius;
    if !(near > 0.0 && far > near && far.is_finite()) {
        return Err(format!("the estimate {near:.3}–{far:.3} is unusable"));
    }
    Ok(CameraBounds {
        near,
        far,
        focus,
        radius,
        focus_depths: (dmin, dmax),
    })
}

/// Near/far from sparse points, per view as COLMAP's `poses_bounds` are made: the depths of
/// the points each view observes, `near = 0.8 ×` their 0.5th percentile and `far = 1.2 ×` their
/// 99.5th (the import's rule for a whole scene, applied per view); the scene's bounds are the
/// smallest near and the largest far.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PointBounds {
    /// Per view (`None` for a view that observes no point in front of it).
    pub per_view: Vec<Option<(f64, f64)>>,
    /// Smallest near over the views.
    pub near: f64,
    /// Largest far over the views.
    pub far: f64,
}

/// Near/far from the depths of point observations: `0.8 ×` the 0.5th percentile and `1.2 ×`
/// the 99.5th (sorts `depths`); `None` when there are none. The import's rule for a scene with
/// points, and [`from_points`]'s per view.
pub fn depth_range(depths: &mut [f64]) -> Option<(f64, f64)> {
    if depths.is_empty() {
        return None;
    }
    depths.sort_by(f64::total_cmp);
    let q = |f: f64| depths[((depths.len() - 1) as f64 * f).round() as usize];
    Some((0.8 * q(0.005), 1.2 * q(0.995)))
}

/// Bounds from the points' tracks (see [`PointBounds`]); `None` when no view observes a point.
pub fn from_points(cams: &[Camera], cloud: &PointCloud) -> Option<PointBounds> {
    let mut depths: Vec<Vec<f64>> = vec![Vec::new(); cams.len()];
    for i in 0..cloud.len() {
        let p = cloud.positions[i].map(f64::from);
        for &v in cloud.track(i) {
            if let Some(cam) = cams.get(v as usize) {
                let z = cam.to_camera(p)[2];
                if z > 0.0 {
                    depths[v as usize].push(z);
                }
            }
        }
    }
    let per_view: Vec<Option<(f64, f64)>> = depths.iter_mut().map(|d| depth_range(d)).collect();
    let near = per_view
        .iter()
        .flatten()
        .map(|b| b.0)
        .fold(f64::INFINITY, f64::min);
    let far = per_view.iter().flatten().map(|b| b.1).fold(0.0, f64::max);
    (near.is_finite() && far > near).then_some(PointBounds {
        per_view,
        near,
        far,
    })
}

/// Smallest eigenvalue of a symmetric 3×3 matrix (trigonometric closed form).
fn symmetric_min_eigenvalue(m: &[[f64; 3]; 3]) -> f64 {
    let p1 = m[0][1].powi(2) + m[0][2].powi(2) + m[1][2].powi(2);
    let q = (m[0][0] + m[1][1] + m[2][2]) / 3.0;
    if p1 == 0.0 {
        return m[0][0].min(m[1][1]).min(m[2][2]);
    }
    let p2 = (m[0][0] - q).powi(2) + (m[1][1] - q).powi(2) + (m[2][2] - q).powi(2) + 2.0 * p1;
    let p = (p2 / 6.0).sqrt();
    let b: [[f64; 3]; 3] = std::array::from_fn(|r| {
        std::array::from_fn(|k| (m[r][k] - if r == k { q } else { 0.0 }) / p)
    });
    let r = (linalg::det3(&b) / 2.0).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    // Eigenvalues q + 2p·cos(φ + 2πk/3); the smallest is k = 1.
    q + 2.0 * p * (phi + 2.0 * std::f64::consts::PI / 3.0).cos()
}

/// Solves `m x = b` by Cramer's rule (`None` when `m` is singular).
pub(crate) fn solve3(m: &[[f64; 3]; 3], b: Vec3) -> Option<Vec3> {
    let det = linalg::det3(m);
    if det.abs() < 1e-300 || !det.is_finite() {
        return None;
    }
    Some(std::array::from_fn(|c| {
        let mut mc = *m;
        for r in 0..3 {
            mc[r][c] = b[r];
        }
        linalg::det3(&mc) / det
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera at `centre` looking at `target` (OpenCV axes, world y down).
    fn look_at(centre: Vec3, target: Vec3, w: u32, h: u32, focal: f64) -> Camera {
        let f = linalg::normalize(linalg::sub(target, centre));
        let down = [0.0, 1.0, 0.0];
        let right = linalg::normalize(linalg::cross(down, f));
        let down = linalg::cross(f, right);
        let r = [right, down, f];
        let t = linalg::scale(linalg::mat3_vec(&r, centre), -1.0);
        Camera {
            width: w,
            height: h,
            fx: focal,
            fy: focal,
            cx: w as f64 / 2.0,
            cy: h as f64 / 2.0,
            world_to_camera: linalg::mat4_from_rt(&r, t),
        }
    }

    #[test]
    fn inward_ring_converges_on_its_subject() {
        let subject = [0.2, -0.1, 0.3];
        // DTU-like: an arc of ±40° at distance 2–2.4, all looking at the subject.
        let cams: Vec<Camera> = (0..9)
            .map(|i| {
                let az = (-40.0 + 10.0 * i as f64).to_radians();
                let dist = 2.0 + 0.05 * i as f64;
                let c = [
                    subject[0] + dist * az.sin(),
                    subject[1] - 0.5,
                    subject[2] - dist * az.cos(),
                ];
                look_at(c, subject, 400, 300, 400.0)
            })
            .collect();
        let b = from_cameras(&cams).unwrap();
        for (f, s) in b.focus.iter().zip(subject) {
            assert!((f - s).abs() < 1e-9, "{b:?}");
        }
        // Half field of view: atan(150/400) ⇒ sin = 0.351; depths 2.06–2.46.
        let (dmin, dmax) = b.focus_depths;
        assert!(dmin > 2.0 && dmax < 2.5, "{b:?}");
        assert!((b.radius / 2.25 - 0.351).abs() < 0.03, "{b:?}");
        assert!(b.near < dmin && b.near > 0.5 * dmin, "{b:?}");
        assert!(b.far > dmax && b.far < 1.5 * dmax, "{b:?}");
    }

    #[test]
    fn forward_facing_and_diverging_captures_are_refused() {
        // Parallel axes (LLFF-like grid of positions, one direction).
        let cams: Vec<Camera> = (0..6)
            .map(|i| {
                let c = [0.1 * (i % 3) as f64, 0.1 * (i / 3) as f64, 0.0];
                look_at(c, [c[0], c[1], 5.0], 400, 300, 400.0)
            })
            .collect();
        let e = from_cameras(&cams).unwrap_err();
        assert!(e.contains("nearly parallel"), "{e}");
        // Cameras looking outwards from a common centre: the axes meet behind them.
        let cams: Vec<Camera> = (0..8)
            .map(|i| {
                let az = (45.0 * i as f64).to_radians();
                let c = [az.sin(), 0.0, az.cos()];
                look_at(c, [3.0 * c[0], 0.0, 3.0 * c[2]], 400, 300, 400.0)
            })
            .collect();
        let e = from_cameras(&cams).unwrap_err();
        assert!(e.contains("behind camera"), "{e}");
        assert!(from_cameras(&cams[..1]).is_err());
    }

    #[test]
    fn point_bounds_are_per_view_depth_quantiles() {
        let cams = [
            look_at([0.0, 0.0, -2.0], [0.0, 0.0, 0.0], 100, 100, 100.0),
            look_at([0.0, 0.0, -4.0], [0.0, 0.0, 0.0], 100, 100, 100.0),
            look_at([0.0, 0.0, -3.0], [0.0, 0.0, 0.0], 100, 100, 100.0),
        ];
        // Points at z = −0.5 … 0.5 seen by views 0 and 1; view 2 sees none.
        let mut cloud = PointCloud {
            track_offsets: vec![0],
            ..PointCloud::default()
        };
        for k in 0..=10 {
            cloud.positions.push([0.0, 0.0, -0.5 + 0.1 * k as f32]);
            cloud.colors.push([0.5; 3]);
            cloud.errors.push(0.0);
            cloud.track_views.extend([0, 1]);
            cloud.track_offsets.push(cloud.track_views.len() as u32);
        }
        let b = from_points(&cams, &cloud).unwrap();
        let (n0, f0) = b.per_view[0].unwrap();
        assert!(
            (n0 - 0.8 * 1.5).abs() < 1e-6 && (f0 - 1.2 * 2.5).abs() < 1e-6,
            "{b:?}"
        );
        let (n1, f1) = b.per_view[1].unwrap();
        assert!(
            (n1 - 0.8 * 3.5).abs() < 1e-6 && (f1 - 1.2 * 4.5).abs() < 1e-6,
            "{b:?}"
        );
        assert_eq!(b.per_view[2], None);
        assert_eq!((b.near, b.far), (n0, f1));
        assert!(from_points(&cams, &PointCloud::default()).is_none());
    }

    #[test]
    fn min_eigenvalue_matches_a_known_spectrum() {
        // R diag(0.5, 2, 3) Rᵀ for a rotation R.
        let r = linalg::axis_angle(linalg::normalize([1.0, 2.0, 0.5]), 0.7);
        let d = [0.5, 2.0, 3.0];
        let m: [[f64; 3]; 3] = std::array::from_fn(|i| {
            std::array::from_fn(|j| (0..3).map(|k| r[i][k] * d[k] * r[j][k]).sum())
        });
        assert!((symmetric_min_eigenvalue(&m) - 0.5).abs() < 1e-12);
        let x = solve3(&m, [1.0, -2.0, 0.25]).unwrap();
        let y = linalg::mat3_vec(&m, x);
        assert!((y[0] - 1.0).abs() < 1e-12 && (y[1] + 2.0).abs() < 1e-12);
    }
}
