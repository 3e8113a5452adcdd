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
    rot: M3,
    m: M3,
    pc: [f64; 3],
    cov_c: M3,
    jac: [[f64; 3]; 2],
    clamp: [Option<f64>; 2],
    x_raw: [f64; 3],
    det_blur: f64,
    conic: [f64; 3],
    ratio: f64,
    opacity_base: f64,
}

fn finite(v: &[f32]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn mul3(a: &M3, b: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    c
}

fn tr3(a: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = a[j][i];
        }
    }
    c
}

/// Rotation matrix of a unit quaternion (w, x, y, z).
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
pub fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

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
    let s = [
        (log_scale[0] as f64).exp(),
        (log_scale[1] as f64).exp(),
        (log_scale[2] as f64).exp(),
    ];
    if !s.iter().all(|v| v.is_finite()) {
        return Err(Outcome::Invalid);
    }
    let q = [
        quat[0] as f64,
        quat[1] as f64,
        quat[2] as f64,
        quat[3] as f64,
    ];
    let n2 = q.iter().map(|v| v * v).sum::<f64>();
    if !(n2 >= MIN_QUAT_NORM2) || !n2.is_finite() {
        return Err(Outcome::Invalid);
    }
    let qnorm = n2.sqrt();
    let qn = [q[0] / qnorm, q[1] / qnorm, q[2] / qnorm, q[3] / qnorm];
    let mu = [mean[0] as f64, mean[1] as f64, mean[2] as f64];
    let mut pc = cam.t;
    for i in 0..3 {
        pc[i] += cam.r[i][0] * mu[0] + cam.r[i][1] * mu[1] + cam.r[i][2] * mu[2];
    }
    if !(pc[2] >= near) {
        return Err(Outcome::Culled);
    }
    let rot = quat_rot(qn);
    let mut m = rot;
    for row in m.iter_mut() {
        for j in 0..3 {
            row[j] *= s[j];
        }
    }
    let cov = mul3(&m, &tr3(&m));
    let cov_c = mul3(&mul3(&cam.r, &cov), &tr3(&cam.r));
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
    let jac = [
        [cam.fx / z, 0.0, -cam.fx * txz / z],
        [0.0, cam.fy / z, -cam.fy * tyz / z],
    ];
    // T = J Σ_c, Σ2d = T Jᵀ.
    let mut tm = [[0.0; 3]; 2];
    for i in 0..2 {
        for k in 0..3 {
            tm[i][k] = jac[i][0] * cov_c[0][k] + jac[i][1] * cov_c[1][k] + jac[i][2] * cov_c[2][k];
        }
    }
    let dotj =
        |i: usize, j: usize| tm[i][0] * jac[j][0] + tm[i][1] * jac[j][1] + tm[i][2] * jac[j][2];
    let x_raw = [dotj(0, 0), 0.5 * (dotj(0, 1) + dotj(1, 0)), dotj(1, 1)];
    if !x_raw.iter().all(|v| v.is_finite()) {
        return Err(Outcome::Invalid);
    }
    let det_raw = x_raw[0] * x_raw[2] - x_raw[1] * x_raw[1];
    let (p, q2, r) = (x_raw[0] + EPS2D, x_raw[1], x_raw[2] + EPS2D);
    let det_blur = p * r - q2 * q2;
    if !(det_blur > 0.0) {
        return Err(Outcome::Culled);
    }
    let conic = [r / det_blur, -q2 / det_blur, p / det_blur];
    let ratio = det_raw / det_blur;
    Ok(Inter {
        s,
        qn,
        qnorm,
        rot,
        m,
        pc,
        cov_c,
        jac,
        clamp: [clamp_x, clamp_y],
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
    // Σ2d_raw = J Σ_c Jᵀ ⇒ G_Σc = Jᵀ G J, G_J = 2 G J Σ_c.
    let j = it.jac;
    let mut gj_tmp = [[0.0; 3]; 2]; // G J
    for r in 0..2 {
        for col in 0..3 {
            gj_tmp[r][col] = gx[r][0] * j[0][col] + gx[r][1] * j[1][col];
        }
    }
    let mut g_covc = [[0.0; 3]; 3];
    for r in 0..3 {
        for col in 0..3 {
            g_covc[r][col] = j[0][r] * gj_tmp[0][col] + j[1][r] * gj_tmp[1][col];
        }
    }
    let mut g_j = [[0.0; 3]; 2];
    for r in 0..2 {
        for col in 0..3 {
            let mut acc = 0.0;
            for kk in 0..3 {
                acc += gj_tmp[r][kk] * it.cov_c[kk][col];
            }
            g_j[r][col] = 2.0 * acc;
        }
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
    g_pc[2] -= g_j[0][0] * fx / z2 + g_j[1][1] * fy / z2;
    // J02 = −fx·tx/z²
    match it.clamp[0] {
        None => {
            g_pc[0] -= g_j[0][2] * fx / z2;
            g_pc[2] += g_j[0][2] * 2.0 * fx * x / z3;
        }
        Some(l) => g_pc[2] += g_j[0][2] * fx * l / z2,
    }
    match it.clamp[1] {
        None => {
            g_pc[1] -= g_j[1][2] * fy / z2;
            g_pc[2] += g_j[1][2] * 2.0 * fy * y / z3;
        }
        Some(l) => g_pc[2] += g_j[1][2] * fy * l / z2,
    }
    g_pc[2] += g.depth;
    let w = &cam.r;
    let mut g_mean = [0.0; 3];
    for i in 0..3 {
        g_mean[i] = w[0][i] * g_pc[0] + w[1][i] * g_pc[1] + w[2][i] * g_pc[2];
    }
    // G_Σ = Wᵀ G_Σc W
    let g_cov = mul3(&mul3(&tr3(w), &g_covc), w);
    // Σ = M Mᵀ ⇒ G_M = (G_Σ + G_Σᵀ) M
    let mut gsym = g_cov;
    for r in 0..3 {
        for col in 0..3 {
            gsym[r][col] = g_cov[r][col] + g_cov[col][r];
        }
    }
    let g_m = mul3(&gsym, &it.m);
    let mut g_rot = [[0.0; 3]; 3];
    let mut g_ls = [0.0; 3];
    for r in 0..3 {
        for col in 0..3 {
            g_rot[r][col] = g_m[r][col] * it.s[col];
            g_ls[col] += g_m[r][col] * it.rot[r][col];
        }
    }
    for jj in 0..3 {
        g_ls[jj] *= it.s[jj];
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
