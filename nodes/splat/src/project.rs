//! Per-Gaussian projection (gsplat "classic" EWA splatting, DESIGN.md §4) and its analytic
//! vector–Jacobian product, both in f64 (the per-Gaussian cost is small next to compositing).
//!
//! Forward: scale = exp(log_scale), R = R(q/|q|), Σ = R S Sᵀ Rᵀ; p_c = W μ + t; Σ_c = W Σ Wᵀ;
//! J = [[fx/z, 0, −fx·t_x/z²], [0, fy/z, −fy·t_y/z²]] with t_x/z clamped to
//! [−cx/fx − 0.3·tan(fovx/2), (width − cx)/fx + 0.3·tan(fovx/2)] (same for y);
//! Σ2d = J Σ_c Jᵀ + 0.3·I; conic = Σ2d⁻¹; mean2d = (fx·x/z + cx, fy·y/z + cy) (unclamped);
//! opacity = sigmoid(logit) [× sqrt(max(0.005², det Σ2d_raw / det Σ2d)) when antialiased];
//! radius = ceil(min(3.33, sqrt(2 ln(255·opacity))) · sqrt(Σ2d_ii)) per axis.
//!
//! Culling (counted as *culled*): z < near, det Σ2d ≤ 0, opacity < 1/255, zero radius, or the
//! bounding box entirely outside the image. *Invalid*: any non-finite parameter, a quaternion
//! of (near) zero norm, or a non-finite covariance.
//!
//! In the clamped branch of the Jacobian the x (or y) gradient is zero and the z gradient is
//! the exact derivative of the clamped expression (−fx·L/z ⇒ fx·L/z²), so finite differences
//! agree everywhere away from the clamp boundary.

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use crate::constants::{
    ALPHA_THRESHOLD, EPS2D, JACOBIAN_CLAMP_MARGIN, MAX_EXTEND, MIN_COMPENSATION_RATIO,
    MIN_QUAT_NORM2,
};
use augsplat_core::Camera;

type M3 = [[f64; 3]; 3];

/// A camera prepared for projection.
#[derive(Clone, Debug)]
pub struct CameraModel {
    /// World-to-camera rotation.
    pub r: M3,
    /// World-to-camera translation.
    pub t: [f64; 3],
    /// Focal length x, pixels.
    pub fx: f64,
    /// Focal length y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Camera centre, world frame (for SH view directions).
    pub center: [f64; 3],
    lim_x_pos: f64,
    lim_x_neg: f64,
    lim_y_pos: f64,
    lim_y_neg: f64,
}

impl CameraModel {
    /// Prepares `cam`.
    pub fn new(cam: &Camera) -> Self {
        let w = cam.world_to_camera;
        let r = [
            [w[0][0], w[0][1], w[0][2]],
            [w[1][0], w[1][1], w[1][2]],
            [w[2][0], w[2][1], w[2][2]],
        ];
        let t = [w[0][3], w[1][3], w[2][3]];
        let mut center = [0.0; 3];
        for i in 0..3 {
            center[i] = -(r[0][i] * t[0] + r[1][i] * t[1] + r[2][i] * t[2]);
        }
        let (wd, ht) = (cam.width as f64, cam.height as f64);
        let tan_x = 0.5 * wd / cam.fx;
        let tan_y = 0.5 * ht / cam.fy;
        CameraModel {
            r,
            t,
            fx: cam.fx,
            fy: cam.fy,
            cx: cam.cx,
            cy: cam.cy,
            width: cam.width,
            height: cam.height,
            center,
            lim_x_pos: (wd - cam.cx) / cam.fx + JACOBIAN_CLAMP_MARGIN * tan_x,
            lim_x_neg: cam.cx / cam.fx + JACOBIAN_CLAMP_MARGIN * tan_x,
            lim_y_pos: (ht - cam.cy) / cam.fy + JACOBIAN_CLAMP_MARGIN * tan_y,
            lim_y_neg: cam.cy / cam.fy + JACOBIAN_CLAMP_MARGIN * tan_y,
        }
    }
}

/// A projected (visible) Gaussian.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projected {
    /// Centre in pixels.
    pub mean2d: [f64; 2],
    /// Conic (a, b, c) = upper triangle of Σ2d⁻¹.
    pub conic: [f64; 3],
    /// Opacity after activation (and antialiasing compensation).
    pub opacity: f64,
    /// Camera-space depth z.
    pub depth: f64,
    /// Bounding-box half extents in pixels (x, y).
    pub radius: [i32; 2],
}

/// The projection of one Gaussian.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outcome {
    /// Reaches the image.
    Visible(Projected),
    /// Valid but culled.
    Culled,
    /// Non-finite or degenerate parameters.
    Invalid,
}

/// Gradients with respect to the projection's outputs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ProjectedGrad {
    /// dL/d(mean2d).
    pub mean2d: [f64; 2],
    /// dL/d(conic a, b, c).
    pub conic: [f64; 3],
    /// dL/d(opacity after compensation).
    pub opacity: f64,
    /// dL/d(depth z).
    pub depth: f64,
}

/// Gradients with respect to one Gaussian's raw geometric parameters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ParamGrad {
    /// dL/d(mean).
    pub mean: [f64; 3],
    /// dL/d(log scale).
    pub log_scale: [f64; 3],
    /// dL/d(raw quaternion).
    pub quat: [f64; 4],
    /// dL/d(opacity logit).
    pub logit: f64,
}

struct Inter {
    s: [f64; 3],
    qn: [f64; 4],
    qnorm: f64,
    /// A = W·R (camera-frame axes of the Gaussian).
    a: M3,
    /// M' = A·diag(s): camera-frame covariance Σ_c = M' M'ᵀ.
    mp: M3,
    pc: [f64; 3],
    /// Jacobian entries J00, J02, J11, J12 (J01 = J10 = 0).
    jac: [f64; 4],
    clamp: [Option<f64>; 2],
    /// T = J M' (2×3): Σ2d_raw = T Tᵀ.
    tm: [[f64; 3]; 2],
    x_raw: [f64; 3],
    det_blur: f64,
    conic: [f64; 3],
    ratio: f64,
    opacity_base: f64,
}

#[inline(always)]
fn finite(v: &[f32]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Rotation matrix of a unit quaternion (w, x, y, z).
#[inline]
pub fn quat_rot(q: [f64; 4]) -> M3 {
    let [w, x, y, z] = q;
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// Logistic sigmoid.
#[inline]
pub fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// ln(f64::MAX): the largest argument whose `exp` is finite.
const LN_F64_MAX: f64 = 709.782712893384;

#[inline(always)]
fn intermediates(
    cam: &CameraModel,
    mean: [f32; 3],
    log_scale: [f32; 3],
    quat: [f32; 4],
    logit: f32,
    near: f64,
) -> Result<Inter, Outcome> {
    if !(finite(&mean) && finite(&log_scale) && finite(&quat) && logit.is_finite()) {
        return Err(Outcome::Invalid);
    }
    let mu = [mean[0] as f64, mean[1] as f64, mean[2] as f64];
    let mut pc = cam.t;
    for i in 0..3 {
        pc[i] += cam.r[i][0] * mu[0] + cam.r[i][1] * mu[1] + cam.r[i][2] * mu[2];
    }
    let q = [
        quat[0] as f64,
        quat[1] as f64,
        quat[2] as f64,
        quat[3] as f64,
    ];
    let n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    if !(n2 >= MIN_QUAT_NORM2) || !n2.is_finite() {
        return Err(Outcome::Invalid);
    }
    // exp(x) is finite exactly when x ≤ ln(f64::MAX) (no f32 lies between that bound and
    // its f64 rounding), so the scales are checked before, and computed after, the near-plane
    // test: Gaussians behind the camera cost no exponentials.
    if !log_scale.iter().all(|&l| l as f64 <= LN_F64_MAX) {
        return Err(Outcome::Invalid);
    }
    if !(pc[2] >= near) {
        return Err(Outcome::Culled);
    }
    let s = [
        (log_scale[0] as f64).exp(),
        (log_scale[1] as f64).exp(),
        (log_scale[2] as f64).exp(),
    ];
    let qnorm = n2.sqrt();
    let inv = 1.0 / qnorm;
    let qn = [q[0] * inv, q[1] * inv, q[2] * inv, q[3] * inv];
    let rot = quat_rot(qn);
    let w = &cam.r;
    let mut a = [[0.0; 3]; 3];
    let mut mp = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            a[i][j] = w[i][0] * rot[0][j] + w[i][1] * rot[1][j] + w[i][2] * rot[2][j];
            mp[i][j] = a[i][j] * s[j];
        }
    }
    let (x, y, z) = (pc[0], pc[1], pc[2]);
    let (u, v) = (x / z, y / z);
    let clamp_x = if u > cam.lim_x_pos {
        Some(cam.lim_x_pos)
    } else if u < -cam.lim_x_neg {
        Some(-cam.lim_x_neg)
    } else {
        None
    };
    let clamp_y = if v > cam.lim_y_pos {
        Some(cam.lim_y_pos)
    } else if v < -cam.lim_y_neg {
        Some(-cam.lim_y_neg)
    } else {
        None
    };
    let txz = clamp_x.unwrap_or(u);
    let tyz = clamp_y.unwrap_or(v);
    let jac = [cam.fx / z, -cam.fx * txz / z, cam.fy / z, -cam.fy * tyz / z];
    let mut tm = [[0.0; 3]; 2];
    for k in 0..3 {
        tm[0][k] = jac[0] * mp[0][k] + jac[1] * mp[2][k];
        tm[1][k] = jac[2] * mp[1][k] + jac[3] * mp[2][k];
    }
    let dot = |p: &[f64; 3], q: &[f64; 3]| p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
    let x_raw = [
        dot(&tm[0], &tm[0]),
        dot(&tm[0], &tm[1]),
        dot(&tm[1], &tm[1]),
    ];
    if !x_raw.iter().all(|v| v.is_finite()) {
        return Err(Outcome::Invalid);
    }
    let det_raw = x_raw[0] * x_raw[2] - x_raw[1] * x_raw[1];
    let (p, q2, r) = (x_raw[0] + EPS2D, x_raw[1], x_raw[2] + EPS2D);
    let det_blur = p * r - q2 * q2;
    if !(det_blur > 0.0) {
        return Err(Outcome::Culled);
    }
    let inv_det = 1.0 / det_blur;
    let conic = [r * inv_det, -q2 * inv_det, p * inv_det];
    let ratio = det_raw * inv_det;
    Ok(Inter {
        s,
        qn,
        qnorm,
        a,
        mp,
        pc,
        jac,
        clamp: [clamp_x, clamp_y],
        tm,
        x_raw,
        det_blur,
        conic,
        ratio,
        opacity_base: sigmoid(logit as f64),
    })
}

fn compensation(ratio: f64) -> f64 {
    ratio.max(MIN_COMPENSATION_RATIO).sqrt()
}

/// Projects one Gaussian.
#[inline]
pub fn project(
    cam: &CameraModel,
    mean: [f32; 3],
    log_scale: [f32; 3],
    quat: [f32; 4],
    logit: f32,
    antialiased: bool,
    near: f64,
) -> Outcome {
    let it = match intermediates(cam, mean, log_scale, quat, logit, near) {
        Ok(it) => it,
        Err(o) => return o,
    };
    let mut opacity = it.opacity_base;
    if antialiased {
        opacity *= compensation(it.ratio);
    }
    if !(opacity >= ALPHA_THRESHOLD as f64) {
        return Outcome::Culled;
    }
    let extend = MAX_EXTEND.min((2.0 * (opacity / ALPHA_THRESHOLD as f64).ln()).sqrt());
    let rx = (extend * (it.x_raw[0] + EPS2D).sqrt()).ceil();
    let ry = (extend * (it.x_raw[2] + EPS2D).sqrt()).ceil();
    if rx <= 0.0 && ry <= 0.0 {
        return Outcome::Culled;
    }
    let (x, y, z) = (it.pc[0], it.pc[1], it.pc[2]);
    let mean2d = [cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy];
    if !(mean2d[0].is_finite() && mean2d[1].is_finite()) {
        return Outcome::Invalid;
    }
    if mean2d[0] + rx <= 0.0
        || mean2d[0] - rx >= cam.width as f64
        || mean2d[1] + ry <= 0.0
        || mean2d[1] - ry >= cam.height as f64
    {
        return Outcome::Culled;
    }
    Outcome::Visible(Projected {
        mean2d,
        conic: it.conic,
        opacity,
        depth: z,
        radius: [rx as i32, ry as i32],
    })
}

/// Backward of [`project`] for a visible Gaussian: dL/d(raw parameters) from dL/d(outputs).
/// Returns zeros for a Gaussian that is not visible.
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn project_vjp(
    cam: &CameraModel,
    mean: [f32; 3],
    log_scale: [f32; 3],
    quat: [f32; 4],
    logit: f32,
    antialiased: bool,
    near: f64,
    g: &ProjectedGrad,
) -> ParamGrad {
    let it = match intermediates(cam, mean, log_scale, quat, logit, near) {
        Ok(it) => it,
        Err(_) => return ParamGrad::default(),
    };
    let [a, b, c] = it.conic;
    let k = [[a, b], [b, c]];
    // Full-matrix gradient of the conic (b sits in both off-diagonal entries).
    let gk = [
        [g.conic[0], 0.5 * g.conic[1]],
        [0.5 * g.conic[1], g.conic[2]],
    ];
    // G_X = −K G_K K.
    let mut kg = [[0.0; 2]; 2];
    for i in 0..2 {
        for j in 0..2 {
            kg[i][j] = k[i][0] * gk[0][j] + k[i][1] * gk[1][j];
        }
    }
    let mut gx = [[0.0; 2]; 2];
    for i in 0..2 {
        for j in 0..2 {
            gx[i][j] = -(kg[i][0] * k[0][j] + kg[i][1] * k[1][j]);
        }
    }
    let mut g_obase = g.opacity;
    if antialiased {
        let comp = compensation(it.ratio);
        g_obase = g.opacity * comp;
        if it.ratio > MIN_COMPENSATION_RATIO {
            let g_comp = g.opacity * it.opacity_base;
            let g_ratio = g_comp / (2.0 * comp);
            let xr = it.x_raw;
            // d(det_raw/det_blur)/dX = adj(X)ᵀ/det_blur − ratio·K.
            let adj = [[xr[2], -xr[1]], [-xr[1], xr[0]]];
            for i in 0..2 {
                for j in 0..2 {
                    gx[i][j] += g_ratio * (adj[i][j] / it.det_blur - it.ratio * k[i][j]);
                }
            }
        }
    }
    // Σ2d_raw = T Tᵀ, T = J M' ⇒ G_T = 2 G T (G symmetric); G_J = G_T M'ᵀ; G_M' = Jᵀ G_T.
    let tm = &it.tm;
    let mut gt = [[0.0; 3]; 2];
    for k in 0..3 {
        gt[0][k] = 2.0 * (gx[0][0] * tm[0][k] + gx[0][1] * tm[1][k]);
        gt[1][k] = 2.0 * (gx[1][0] * tm[0][k] + gx[1][1] * tm[1][k]);
    }
    let mp = &it.mp;
    let dot = |p: &[f64; 3], q: &[f64; 3]| p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
    let g_j00 = dot(&gt[0], &mp[0]);
    let g_j02 = dot(&gt[0], &mp[2]);
    let g_j11 = dot(&gt[1], &mp[1]);
    let g_j12 = dot(&gt[1], &mp[2]);
    let [j00, j02, j11, j12] = it.jac;
    let mut g_mp = [[0.0; 3]; 3];
    for k in 0..3 {
        g_mp[0][k] = j00 * gt[0][k];
        g_mp[1][k] = j11 * gt[1][k];
        g_mp[2][k] = j02 * gt[0][k] + j12 * gt[1][k];
    }
    let (x, y, z) = (it.pc[0], it.pc[1], it.pc[2]);
    let (fx, fy) = (cam.fx, cam.fy);
    let (z2, z3) = (z * z, z * z * z);
    let mut g_pc = [0.0; 3];
    // mean2d
    g_pc[0] += g.mean2d[0] * fx / z;
    g_pc[1] += g.mean2d[1] * fy / z;
    g_pc[2] -= (g.mean2d[0] * fx * x + g.mean2d[1] * fy * y) / z2;
    // J00 = fx/z, J11 = fy/z
    g_pc[2] -= g_j00 * fx / z2 + g_j11 * fy / z2;
    // J02 = −fx·tx/z²
    match it.clamp[0] {
        None => {
            g_pc[0] -= g_j02 * fx / z2;
            g_pc[2] += g_j02 * 2.0 * fx * x / z3;
        }
        Some(l) => g_pc[2] += g_j02 * fx * l / z2,
    }
    match it.clamp[1] {
        None => {
            g_pc[1] -= g_j12 * fy / z2;
            g_pc[2] += g_j12 * 2.0 * fy * y / z3;
        }
        Some(l) => g_pc[2] += g_j12 * fy * l / z2,
    }
    g_pc[2] += g.depth;
    let w = &cam.r;
    let mut g_mean = [0.0; 3];
    for i in 0..3 {
        g_mean[i] = w[0][i] * g_pc[0] + w[1][i] * g_pc[1] + w[2][i] * g_pc[2];
    }
    // M' = A diag(s): G_A = G_M' diag(s), G_s = colsum(A ∘ G_M'); A = W R ⇒ G_R = Wᵀ G_A.
    let mut g_a = [[0.0; 3]; 3];
    let mut g_ls = [0.0; 3];
    for r in 0..3 {
        for col in 0..3 {
            g_a[r][col] = g_mp[r][col] * it.s[col];
            g_ls[col] += g_mp[r][col] * it.a[r][col];
        }
    }
    for jj in 0..3 {
        g_ls[jj] *= it.s[jj];
    }
    let mut g_rot = [[0.0; 3]; 3];
    for r in 0..3 {
        for col in 0..3 {
            g_rot[r][col] = w[0][r] * g_a[0][col] + w[1][r] * g_a[1][col] + w[2][r] * g_a[2][col];
        }
    }
    let [qw, qx, qy, qz] = it.qn;
    let gr = g_rot;
    let gqn = [
        2.0 * (-qz * gr[0][1] + qy * gr[0][2] + qz * gr[1][0] - qx * gr[1][2] - qy * gr[2][0]
            + qx * gr[2][1]),
        2.0 * (qy * gr[0][1] + qz * gr[0][2] + qy * gr[1][0] - 2.0 * qx * gr[1][1] - qw * gr[1][2]
            + qz * gr[2][0]
            + qw * gr[2][1]
            - 2.0 * qx * gr[2][2]),
        2.0 * (-2.0 * qy * gr[0][0]
            + qx * gr[0][1]
            + qw * gr[0][2]
            + qx * gr[1][0]
            + qz * gr[1][2]
            - qw * gr[2][0]
            + qz * gr[2][1]
            - 2.0 * qy * gr[2][2]),
        2.0 * (-2.0 * qz * gr[0][0] - qw * gr[0][1] + qx * gr[0][2] + qw * gr[1][0]
            - 2.0 * qz * gr[1][1]
            + qy * gr[1][2]
            + qx * gr[2][0]
            + qy * gr[2][1]),
    ];
    let dotq = gqn[0] * qw + gqn[1] * qx + gqn[2] * qy + gqn[3] * qz;
    let g_quat = [
        (gqn[0] - qw * dotq) / it.qnorm,
        (gqn[1] - qx * dotq) / it.qnorm,
        (gqn[2] - qy * dotq) / it.qnorm,
        (gqn[3] - qz * dotq) / it.qnorm,
    ];
    let o = it.opacity_base;
    ParamGrad {
        mean: g_mean,
        log_scale: g_ls,
        quat: g_quat,
        logit: g_obase * o * (1.0 - o),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scale_bound_is_exactly_where_exp_overflows() {
        assert!(LN_F64_MAX.exp().is_finite());
        // The f32 values on either side of the bound.
        let below = 709.782_65_f32;
        let above = f32::from_bits(below.to_bits() + 1);
        assert!((below as f64) <= LN_F64_MAX && (above as f64) > LN_F64_MAX);
        assert!((below as f64).exp().is_finite());
        assert!((above as f64).exp().is_infinite());
        // Behind the camera the one is culled and the other invalid, as when the
        // exponentials were taken before the near-plane test; in front both overflow the
        // covariance (invalid).
        let cam = augsplat_core::Camera {
            width: 32,
            height: 24,
            fx: 30.0,
            fy: 30.0,
            cx: 16.0,
            cy: 12.0,
            world_to_camera: augsplat_core::linalg::mat4_from_rt(
                &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                [0.0, 0.0, 0.0],
            ),
        };
        let cm = CameraModel::new(&cam);
        let q = [1.0, 0.0, 0.0, 0.0];
        let go =
            |z: f32, ls: f32| project(&cm, [0.0, 0.0, z], [ls, -3.0, -3.0], q, 2.0, false, 0.01);
        assert!(matches!(go(2.0, below), Outcome::Invalid));
        assert!(matches!(go(2.0, above), Outcome::Invalid));
        assert!(matches!(go(-2.0, below), Outcome::Culled));
        assert!(matches!(go(-2.0, above), Outcome::Invalid));
    }
}
