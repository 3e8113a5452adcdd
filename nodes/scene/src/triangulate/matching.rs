//! Which views are matched, and matching under the known epipolar geometry.
//!
//! **Pairs:** views whose optical axes differ by at most `max_axis_angle` and whose centres
//! are apart; of those, each view is paired with its `neighbours` nearest by centre distance
//! (the union of both directions, sorted).
//!
//! **Matches:** the poses are known, so the fundamental matrix of a pair is too. A keypoint of
//! view `a` is compared only with the keypoints of view `b` within `epipolar_px` of its
//! epipolar line; the nearest descriptor (Hamming) is kept when it is within `max_hamming`
//! and clearly better than the second (`ratio`), and when the same test from `b` back to `a`
//! picks the same pair (mutual).

use super::features::{hamming, Keypoints};
use augsplat_core::linalg::{self, Mat3, Vec3};
use augsplat_core::Camera;

/// One match: keypoint indices in the pair's first and second view, and the Hamming distance
/// of their descriptors.
pub type Match = (u32, u32, u32);

/// The pairs to match (see the module docs), as `(a, b)` with `a < b`, sorted.
pub fn select_pairs(
    cams: &[Camera],
    neighbours: usize,
    max_axis_angle_deg: f64,
) -> Vec<(usize, usize)> {
    let n = cams.len();
    let cos_max = max_axis_angle_deg.to_radians().cos();
    let fwd: Vec<Vec3> = cams
        .iter()
        .map(|c| linalg::normalize(c.forward()))
        .collect();
    let ctr: Vec<Vec3> = cams.iter().map(Camera::center).collect();
    let scale = ctr
        .iter()
        .flat_map(|a| ctr.iter().map(move |b| linalg::norm(linalg::sub(*a, *b))))
        .fold(0.0, f64::max);
    let mut pairs = Vec::new();
    for i in 0..n {
        let mut cands: Vec<(f64, usize)> = (0..n)
            .filter(|&j| j != i)
            .filter(|&j| linalg::dot(fwd[i], fwd[j]) >= cos_max)
            .map(|j| (linalg::norm(linalg::sub(ctr[i], ctr[j])), j))
            .filter(|&(d, _)| d > 1e-9 * scale.max(1e-300))
            .collect();
        cands.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for &(_, j) in cands.iter().take(neighbours) {
            pairs.push((i.min(j), i.max(j)));
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// Thresholds of [`match_pair`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MatchRules {
    /// Largest distance of a keypoint from the epipolar line, pixels.
    pub epipolar_px: f64,
    /// Largest Hamming distance of a match (of 256 bits).
    pub max_hamming: u32,
    /// The best distance must be below `ratio ×` the second best.
    pub ratio: f64,
}

/// The fundamental matrix mapping a pixel of `a` (homogeneous, continuous coordinates) to its
/// epipolar line in `b`: `F = K_b⁻ᵀ [t]ₓ R K_a⁻¹` with `R, t` the pose of `b` relative to `a`.
pub fn fundamental(a: &Camera, b: &Camera) -> Mat3 {
    let (ra, ta) = linalg::rt_from_mat4(&a.world_to_camera);
    let (rb, tb) = linalg::rt_from_mat4(&b.world_to_camera);
    let r = linalg::mat3_mul(&rb, &linalg::transpose3(&ra));
    let t = linalg::sub(tb, linalg::mat3_vec(&r, ta));
    let tx = [[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]];
    let e = linalg::mat3_mul(&tx, &r);
    let ka_inv = [
        [1.0 / a.fx, 0.0, -a.cx / a.fx],
        [0.0, 1.0 / a.fy, -a.cy / a.fy],
        [0.0, 0.0, 1.0],
    ];
    let kb_inv_t = [
        [1.0 / b.fx, 0.0, 0.0],
        [0.0, 1.0 / b.fy, 0.0],
        [-b.cx / b.fx, -b.cy / b.fy, 1.0],
    ];
    linalg::mat3_mul(&linalg::mat3_mul(&kb_inv_t, &e), &ka_inv)
}

/// For every keypoint of `from`, the best keypoint of `to` near its epipolar line under `f`
/// that passes the rules and its distance (`u32::MAX` when none does).
fn best_along_lines(
    f: &Mat3,
    from: &Keypoints,
    to: &Keypoints,
    rules: &MatchRules,
) -> Vec<(u32, u32)> {
    let mut best = vec![(u32::MAX, u32::MAX); from.len()];
    for (i, slot) in best.iter_mut().enumerate() {
        let x = [from.u[i], from.v[i], 1.0];
        let l = linalg::mat3_vec(f, x);
        let norm = (l[0] * l[0] + l[1] * l[1]).sqrt();
        if norm.is_nan() || norm <= 0.0 {
            continue;
        }
        let band = rules.epipolar_px * norm;
        let (mut d1, mut d2, mut j1) = (u32::MAX, u32::MAX, u32::MAX);
        let di = &from.descriptors[i];
        for j in 0..to.len() {
            let s = l[0] * to.u[j] + l[1] * to.v[j] + l[2];
            if s.abs() > band {
                continue;
            }
            let d = hamming(di, &to.descriptors[j]);
            if d < d1 {
                (d2, d1, j1) = (d1, d, j as u32);
            } else if d < d2 {
                d2 = d;
            }
        }
        if d1 <= rules.max_hamming && (d2 == u32::MAX || (d1 as f64) < rules.ratio * d2 as f64) {
            *slot = (j1, d1);
        }
    }
    best
}

/// Mutual matches of views `a` and `b` (see the module docs), in order of `a`'s keypoints.
pub fn match_pair(
    cam_a: &Camera,
    cam_b: &Camera,
    ka: &Keypoints,
    kb: &Keypoints,
    rules: &MatchRules,
) -> Vec<Match> {
    let f = fundamental(cam_a, cam_b);
    let ab = best_along_lines(&f, ka, kb, rules);
    let ba = best_along_lines(&linalg::transpose3(&f), kb, ka, rules);
    ab.iter()
        .enumerate()
        .filter(|&(i, &(j, _))| j != u32::MAX && ba[j as usize].0 == i as u32)
        .map(|(i, &(j, d))| (i as u32, j, d))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera_at(centre: Vec3, yaw: f64) -> Camera {
        let r = linalg::axis_angle([0.0, 1.0, 0.0], yaw);
        let t = linalg::scale(linalg::mat3_vec(&r, centre), -1.0);
        Camera {
            width: 200,
            height: 100,
            fx: 150.0,
            fy: 140.0,
            cx: 100.0,
            cy: 50.0,
            world_to_camera: linalg::mat4_from_rt(&r, t),
        }
    }

    #[test]
    fn a_point_lies_on_its_epipolar_line() {
        let a = camera_at([0.0, 0.0, 0.0], 0.0);
        let b = camera_at([0.4, -0.1, 0.05], -0.2);
        let f = fundamental(&a, &b);
        for p in [[0.1, 0.2, 3.0], [-0.5, 0.1, 2.0], [0.3, -0.2, 5.0]] {
            let (ua, va, _) = a.project(p);
            let (ub, vb, _) = b.project(p);
            let l = linalg::mat3_vec(&f, [ua, va, 1.0]);
            let dist = (l[0] * ub + l[1] * vb + l[2]) / (l[0] * l[0] + l[1] * l[1]).sqrt();
            assert!(dist.abs() < 1e-9, "{dist}");
        }
    }

    #[test]
    fn pairs_are_nearest_views_that_look_alike() {
        let mut cams: Vec<Camera> = (0..5)
            .map(|i| camera_at([0.25 * i as f64, 0.0, 0.0], 0.0))
            .collect();
        // A view looking the other way pairs with none; one at the same centre neither.
        cams.push(camera_at([0.0, 0.0, 0.0], std::f64::consts::PI));
        cams.push(camera_at([0.0, 0.0, 0.0], 0.0));
        let pairs = select_pairs(&cams, 1, 60.0);
        assert_eq!(pairs, vec![(0, 1), (1, 2), (1, 6), (2, 3), (3, 4)]);
    }
}
