//! One track → one point: the rays' midpoint (least squares over all rays), refined by
//! Gauss–Newton on the reprojection error, with the geometric checks of COLMAP's
//! triangulator: every observation in front of its camera and within the reprojection
//! bound (the worst is dropped and the point re-solved until all are), enough views left,
//! and a large enough angle between the rays.

use crate::bounds::solve3;
use augsplat_core::linalg::{self, Vec3};
use augsplat_core::Camera;

/// The checks a point must pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveRules {
    /// Largest reprojection error of any observation kept, pixels.
    pub max_reprojection_px: f64,
    /// Fewest observations a point keeps.
    pub min_track: usize,
    /// Smallest largest angle between two of the point's rays, degrees.
    pub min_angle_deg: f64,
}

/// Why a track gave no point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rejection {
    /// Fewer than `min_track` observations left after the reprojection and depth checks.
    TooFewViews,
    /// The rays are too nearly parallel.
    SmallAngle,
}

/// A triangulated point.
#[derive(Clone, Debug, PartialEq)]
pub struct Solved {
    /// Position.
    pub position: Vec3,
    /// Indices (into the observations given) of the observations kept.
    pub kept: Vec<usize>,
    /// Mean reprojection error over the kept observations, pixels.
    pub mean_error: f64,
}

/// Whether a camera-space depth is not in front of the camera (NaN included).
fn behind(z: f64) -> bool {
    z.is_nan() || z <= 0.0
}

/// Midpoint of the rays through the observations: minimises `Σ ‖(I − d dᵀ)(x − c)‖²`.
fn midpoint(rays: &[(Vec3, Vec3)]) -> Option<Vec3> {
    let mut a = [[0f64; 3]; 3];
    let mut b = [0f64; 3];
    for (c, d) in rays {
        for r in 0..3 {
            for k in 0..3 {
                let m = if r == k { 1.0 } else { 0.0 } - d[r] * d[k];
                a[r][k] += m;
                b[r] += m * c[k];
            }
        }
    }
    solve3(&a, b).filter(|x| x.iter().all(|v| v.is_finite()))
}

/// Reprojection residual (pixels) and its Jacobian with respect to the point, or `None`
/// when the point is not in front of the camera.
fn residual(cam: &Camera, x: Vec3, uv: (f64, f64)) -> Option<([f64; 2], [Vec3; 2])> {
    let (r, t) = linalg::rt_from_mat4(&cam.world_to_camera);
    let p = linalg::add(linalg::mat3_vec(&r, x), t);
    if behind(p[2]) {
        return None;
    }
    let iz = 1.0 / p[2];
    let res = [
        cam.fx * p[0] * iz + cam.cx - uv.0,
        cam.fy * p[1] * iz + cam.cy - uv.1,
    ];
    let ju: Vec3 = std::array::from_fn(|k| cam.fx * (r[0][k] - p[0] * iz * r[2][k]) * iz);
    let jv: Vec3 = std::array::from_fn(|k| cam.fy * (r[1][k] - p[1] * iz * r[2][k]) * iz);
    Some((res, [ju, jv]))
}

/// A few Gauss–Newton steps on the reprojection error (stops when a step would put the point
/// behind a camera).
fn refine(cams: &[&Camera], obs: &[(f64, f64)], mut x: Vec3) -> Vec3 {
    for _ in 0..5 {
        let mut a = [[0f64; 3]; 3];
        let mut g = [0f64; 3];
        for (cam, uv) in cams.iter().zip(obs) {
            let Some((res, jac)) = residual(cam, x, *uv) else {
                return x;
            };
            for (rv, j) in res.iter().zip(&jac) {
                for r in 0..3 {
                    g[r] -= j[r] * rv;
                    for k in 0..3 {
                        a[r][k] += j[r] * j[k];
                    }
                }
            }
        }
        let Some(step) = solve3(&a, g) else {
            return x;
        };
        let next = linalg::add(x, step);
        if !next.iter().all(|v| v.is_finite()) || cams.iter().any(|c| behind(c.to_camera(next)[2]))
        {
            return x;
        }
        x = next;
    }
    x
}

/// Triangulates one track: `cams[i]` observed the point at `obs[i]` (continuous pixels).
pub fn solve_track(
    cams: &[&Camera],
    obs: &[(f64, f64)],
    rules: &SolveRules,
) -> Result<Solved, Rejection> {
    let mut kept: Vec<usize> = (0..obs.len()).collect();
    loop {
        if kept.len() < rules.min_track.max(2) {
            return Err(Rejection::TooFewViews);
        }
        let kc: Vec<&Camera> = kept.iter().map(|&i| cams[i]).collect();
        let ko: Vec<(f64, f64)> = kept.iter().map(|&i| obs[i]).collect();
        let rays: Vec<(Vec3, Vec3)> = kc
            .iter()
            .zip(&ko)
            .map(|(c, uv)| c.ray(uv.0, uv.1))
            .collect();
        let Some(x0) = midpoint(&rays) else {
            return Err(Rejection::SmallAngle);
        };
        // Observations behind their camera at the midpoint go first, then the worst
        // reprojection error above the bound, one at a time.
        if let Some(behind) = kc.iter().position(|c| behind(c.to_camera(x0)[2])) {
            kept.remove(behind);
            continue;
        }
        let x = refine(&kc, &ko, x0);
        let errors: Vec<f64> = kc
            .iter()
            .zip(&ko)
            .map(|(c, uv)| match residual(c, x, *uv) {
                Some((r, _)) => r[0].hypot(r[1]),
                None => f64::INFINITY,
            })
            .collect();
        let (worst, err) = errors
            .iter()
            .copied()
            .enumerate()
            .fold((0, -1.0), |m, (i, e)| if e > m.1 { (i, e) } else { m });
        if err.is_nan() || err > rules.max_reprojection_px {
            kept.remove(worst);
            continue;
        }
        let mut widest = 0f64;
        for i in 0..kc.len() {
            let di = linalg::normalize(linalg::sub(x, kc[i].center()));
            for cj in &kc[i + 1..] {
                let dj = linalg::normalize(linalg::sub(x, cj.center()));
                widest = widest.max(linalg::dot(di, dj).clamp(-1.0, 1.0).acos());
            }
        }
        if widest.to_degrees() < rules.min_angle_deg {
            return Err(Rejection::SmallAngle);
        }
        let mean_error = errors.iter().sum::<f64>() / errors.len() as f64;
        return Ok(Solved {
            position: x,
            kept,
            mean_error,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn look_at(centre: Vec3, target: Vec3) -> Camera {
        let f = linalg::normalize(linalg::sub(target, centre));
        let right = linalg::normalize(linalg::cross([0.0, 1.0, 0.0], f));
        let down = linalg::cross(f, right);
        let r = [right, down, f];
        let t = linalg::scale(linalg::mat3_vec(&r, centre), -1.0);
        Camera {
            width: 400,
            height: 300,
            fx: 350.0,
            fy: 360.0,
            cx: 201.0,
            cy: 149.0,
            world_to_camera: linalg::mat4_from_rt(&r, t),
        }
    }

    const RULES: SolveRules = SolveRules {
        max_reprojection_px: 2.0,
        min_track: 2,
        min_angle_deg: 1.5,
    };

    #[test]
    fn noisy_observations_give_the_point_and_an_outlier_is_dropped() {
        let p = [0.1, -0.2, 0.3];
        let cams: Vec<Camera> = (0..4)
            .map(|i| look_at([-0.6 + 0.4 * i as f64, 0.1, -2.5], [0.0, 0.0, 0.0]))
            .collect();
        let refs: Vec<&Camera> = cams.iter().collect();
        let noise = [(0.3, -0.2), (-0.25, 0.1), (0.1, 0.3), (-0.2, -0.3)];
        let mut obs: Vec<(f64, f64)> = cams
            .iter()
            .zip(noise)
            .map(|(c, n)| {
                let (u, v, _) = c.project(p);
                (u + n.0, v + n.1)
            })
            .collect();
        let s = solve_track(&refs, &obs, &RULES).unwrap();
        assert_eq!(s.kept, vec![0, 1, 2, 3]);
        assert!(linalg::norm(linalg::sub(s.position, p)) < 0.01, "{s:?}");
        assert!(s.mean_error < 0.5, "{s:?}");
        // A wrong match 15 px off is dropped; the others still give the point.
        obs[2].0 += 15.0;
        let s = solve_track(&refs, &obs, &RULES).unwrap();
        assert_eq!(s.kept, vec![0, 1, 3]);
        assert!(linalg::norm(linalg::sub(s.position, p)) < 0.01, "{s:?}");
        // With three views required and two agreeing, there is no point.
        obs[3].1 -= 20.0;
        let strict = SolveRules {
            min_track: 3,
            ..RULES
        };
        assert_eq!(
            solve_track(&refs, &obs, &strict),
            Err(Rejection::TooFewViews)
        );
    }

    #[test]
    fn nearly_parallel_rays_are_refused() {
        let p = [0.0, 0.0, 0.0];
        // Two cameras 1 mm apart at 2.5 units: 0.02° between the rays.
        let cams = [look_at([0.0, 0.0, -2.5], p), look_at([0.001, 0.0, -2.5], p)];
        let refs: Vec<&Camera> = cams.iter().collect();
        let obs: Vec<(f64, f64)> = cams
            .iter()
            .map(|c| {
                let (u, v, _) = c.project(p);
                (u, v)
            })
            .collect();
        assert_eq!(solve_track(&refs, &obs, &RULES), Err(Rejection::SmallAngle));
    }
}
