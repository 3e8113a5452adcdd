//! Per-Gaussian projection (gsplat "classic" EWA splatting, docs/design.md, *Projection*) and its analytic
//! vector–Jacobian product, both in f64 and on eight Gaussians at once (the `lanes` module:
//! one AVX-512 register per quantity, or portable lanes with the same bits). Branches are
//! lane masks; the single-Gaussian [`project`] and [`project_vjp`] run the same code.
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
use crate::lanes::{self, c, Lanes, Mask, LANES, P8};
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

/// ln(f64::MAX): the largest argument whose `exp` is finite.
const LN_F64_MAX: f64 = 709.782712893384;

/// Rotation matrix of a unit quaternion (w, x, y, z).
#[inline]
pub fn quat_rot(q: [f64; 4]) -> M3 {
    let l = quat_rot_lanes(q.map(P8::splat));
    l.map(|row| row.map(|v| v.0[0]))
}

/// Logistic sigmoid (as the projection computes it).
#[inline]
pub fn sigmoid(x: f64) -> f64 {
    lanes::sigmoid(P8::splat(x)).0[0]
}

/// Per-lane projection status: the first check that fails decides (in the order of the
/// module documentation).
#[derive(Clone, Copy, Default)]
pub(crate) struct Status {
    /// Lanes already decided.
    decided: Mask,
    /// Lanes found invalid.
    pub invalid: Mask,
    /// Lanes culled.
    pub culled: Mask,
}

impl Status {
    #[inline(always)]
    fn invalid_where(&mut self, m: Mask) {
        let new = m & !self.decided;
        self.invalid |= new;
        self.decided |= new;
    }
    #[inline(always)]
    fn culled_where(&mut self, m: Mask) {
        let new = m & !self.decided;
        self.culled |= new;
        self.decided |= new;
    }
    /// Lanes that passed every check so far.
    #[inline(always)]
    pub fn visible(&self) -> Mask {
        !self.decided
    }
}

/// Eight Gaussians' raw parameters (or gradients with respect to them), one per lane.
#[derive(Clone, Copy)]
pub(crate) struct ParamLanes<L> {
    pub mean: [L; 3],
    pub log_scale: [L; 3],
    pub quat: [L; 4],
    pub logit: L,
    /// The factor on the opacity ([`crate::RenderSettings::opacity_scale`]; 1 without one).
    /// Not a parameter: gradient lanes leave it at 1.
    pub opacity_scale: L,
}

impl<L: Lanes> ParamLanes<L> {
    /// Gaussians `idx[l]` of the parameter arrays, with their opacity factors when `scales`
    /// holds one per Gaussian (else 1).
    #[inline(always)]
    pub fn gather(
        means: &[[f32; 3]],
        log_scales: &[[f32; 3]],
        quats: &[[f32; 4]],
        logits: &[f32],
        scales: Option<&[f32]>,
        idx: &[usize; LANES],
    ) -> Self {
        let mut m = [[0.0; LANES]; 3];
        let mut ls = [[0.0; LANES]; 3];
        let mut q = [[0.0; LANES]; 4];
        let mut o = [0.0; LANES];
        let mut f = [1.0; LANES];
        let scales = scales.filter(|s| s.len() == logits.len());
        for l in 0..LANES {
            let i = idx[l];
            for k in 0..3 {
                m[k][l] = means[i][k] as f64;
                ls[k][l] = log_scales[i][k] as f64;
            }
            for k in 0..4 {
                q[k][l] = quats[i][k] as f64;
            }
            o[l] = logits[i] as f64;
            if let Some(s) = scales {
                f[l] = s[i] as f64;
            }
        }
        ParamLanes {
            mean: [
                L::from_array(m[0]),
                L::from_array(m[1]),
                L::from_array(m[2]),
            ],
            log_scale: [
                L::from_array(ls[0]),
                L::from_array(ls[1]),
                L::from_array(ls[2]),
            ],
            quat: [
                L::from_array(q[0]),
                L::from_array(q[1]),
                L::from_array(q[2]),
                L::from_array(q[3]),
            ],
            logit: L::from_array(o),
            opacity_scale: L::from_array(f),
        }
    }
}

impl ParamLanes<P8> {
    /// One Gaussian in every lane.
    fn one(mean: [f32; 3], log_scale: [f32; 3], quat: [f32; 4], logit: f32) -> Self {
        ParamLanes::gather(&[mean], &[log_scale], &[quat], &[logit], None, &[0; LANES])
    }
}

type M3L<L> = [[L; 3]; 3];

struct Inter<L> {
    status: Status,
    s: [L; 3],
    qn: [L; 4],
    qnorm: L,
    /// A = W·R (camera-frame axes of the Gaussian).
    a: M3L<L>,
    /// M' = A·diag(s): camera-frame covariance Σ_c = M' M'ᵀ.
    mp: M3L<L>,
    pc: [L; 3],
    /// Jacobian entries J00, J02, J11, J12 (J01 = J10 = 0).
    jac: [L; 4],
    /// Lanes whose t_x/z (t_y/z) is clamped, and the clamp values.
    clamped: [Mask; 2],
    limit: [L; 2],
    /// T = J M' (2×3): Σ2d_raw = T Tᵀ.
    tm: [[L; 3]; 2],
    x_raw: [L; 3],
    det_blur: L,
    conic: [L; 3],
    ratio: L,
    /// sigmoid(logit).
    sigmoid: L,
    /// The opacity factor ([`ParamLanes::opacity_scale`]).
    opacity_scale: L,
    /// sigmoid(logit) × the opacity factor, before the antialiasing compensation.
    opacity_base: L,
}

#[inline(always)]
fn all_finite<L: Lanes>(v: &[L]) -> Mask {
    // A loop, not a fold with a closure (see `lanes::to_arrays`).
    let mut m = lanes::ALL;
    for x in v {
        m &= x.is_finite();
    }
    m
}

/// The clamp of the projection Jacobian's x/z or y/z to `[−neg, pos]`: (clamped lanes, the
/// limit hit, the clamped value). A NaN ratio is in neither clamp (as the comparisons say).
#[inline(always)]
fn clamp_ratio<L: Lanes>(t: L, pos: f64, neg: f64) -> (Mask, L, L) {
    let hi = t.gt(c(pos));
    let lo = t.lt(c(-neg));
    let limit = L::select(hi, c(pos), c(-neg));
    (hi | lo, limit, L::select(hi | lo, limit, t))
}

/// The shared forward intermediates of eight Gaussians (every lane is computed; the status
/// says which are meaningful).
#[inline(always)]
fn intermediates<L: Lanes>(cam: &CameraModel, gl: &ParamLanes<L>, near: f64) -> Inter<L> {
    let mut status = Status::default();
    let finite = all_finite(&gl.mean)
        & all_finite(&gl.log_scale)
        & all_finite(&gl.quat)
        & gl.logit.is_finite();
    status.invalid_where(!finite);
    let mu = gl.mean;
    let mut pc = [c::<L>(0.0); 3];
    for i in 0..3 {
        pc[i] = (mu[0] * cam.r[i][0] + mu[1] * cam.r[i][1] + mu[2] * cam.r[i][2]) + cam.t[i];
    }
    let q = gl.quat;
    let n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    status.invalid_where(!(n2.ge(c(MIN_QUAT_NORM2)) & n2.is_finite()));
    // exp(x) is finite exactly when x ≤ ln(f64::MAX) (no f32 lies between that bound and
    // its f64 rounding).
    let lim = c::<L>(LN_F64_MAX);
    let ls = gl.log_scale;
    status.invalid_where(!(ls[0].le(lim) & ls[1].le(lim) & ls[2].le(lim)));
    status.culled_where(!pc[2].ge(c(near)));
    let s = [lanes::exp(ls[0]), lanes::exp(ls[1]), lanes::exp(ls[2])];
    let qnorm = n2.sqrt();
    let inv = c::<L>(1.0) / qnorm;
    let qn = [q[0] * inv, q[1] * inv, q[2] * inv, q[3] * inv];
    let rot = quat_rot_lanes(qn);
    let w = &cam.r;
    let mut a = [[c::<L>(0.0); 3]; 3];
    let mut mp = [[c::<L>(0.0); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            a[i][j] = rot[0][j] * w[i][0] + rot[1][j] * w[i][1] + rot[2][j] * w[i][2];
            mp[i][j] = a[i][j] * s[j];
        }
    }
    let (x, y, z) = (pc[0], pc[1], pc[2]);
    let (u, v) = (x / z, y / z);
    let (clamped_x, limit_x, txz) = clamp_ratio(u, cam.lim_x_pos, cam.lim_x_neg);
    let (clamped_y, limit_y, tyz) = clamp_ratio(v, cam.lim_y_pos, cam.lim_y_neg);
    let jac = [
        c::<L>(cam.fx) / z,
        txz * -cam.fx / z,
        c::<L>(cam.fy) / z,
        tyz * -cam.fy / z,
    ];
    let mut tm = [[c::<L>(0.0); 3]; 2];
    for k in 0..3 {
        tm[0][k] = jac[0] * mp[0][k] + jac[1] * mp[2][k];
        tm[1][k] = jac[2] * mp[1][k] + jac[3] * mp[2][k];
    }
    let x_raw = [
        dot3(&tm[0], &tm[0]),
        dot3(&tm[0], &tm[1]),
        dot3(&tm[1], &tm[1]),
    ];
    status.invalid_where(!all_finite(&x_raw));
    let det_raw = x_raw[0] * x_raw[2] - x_raw[1] * x_raw[1];
    let (p, q2, r) = (x_raw[0] + EPS2D, x_raw[1], x_raw[2] + EPS2D);
    let det_blur = p * r - q2 * q2;
    status.culled_where(!det_blur.gt(c(0.0)));
    let inv_det = c::<L>(1.0) / det_blur;
    let conic = [r * inv_det, -q2 * inv_det, p * inv_det];
    let ratio = det_raw * inv_det;
    let sigmoid = lanes::sigmoid(gl.logit);
    Inter {
        status,
        s,
        qn,
        qnorm,
        a,
        mp,
        pc,
        jac,
        clamped: [clamped_x, clamped_y],
        limit: [limit_x, limit_y],
        tm,
        x_raw,
        det_blur,
        conic,
        ratio,
        sigmoid,
        opacity_scale: gl.opacity_scale,
        // × 1 without a factor: the same bits as the sigmoid alone.
        opacity_base: sigmoid * gl.opacity_scale,
    }
}

/// `p · q` lane-wise, summed left to right.
#[inline(always)]
fn dot3<L: Lanes>(p: &[L; 3], q: &[L; 3]) -> L {
    p[0] * q[0] + p[1] * q[1] + p[2] * q[2]
}

/// [`quat_rot`] lane-wise.
#[inline(always)]
fn quat_rot_lanes<L: Lanes>(q: [L; 4]) -> M3L<L> {
    let [w, x, y, z] = q;
    let one = c::<L>(1.0);
    [
        [
            one - (y * y + z * z) * 2.0,
            (x * y - w * z) * 2.0,
            (x * z + w * y) * 2.0,
        ],
        [
            (x * y + w * z) * 2.0,
            one - (x * x + z * z) * 2.0,
            (y * z - w * x) * 2.0,
        ],
        [
            (x * z - w * y) * 2.0,
            (y * z + w * x) * 2.0,
            one - (x * x + y * y) * 2.0,
        ],
    ]
}

#[inline(always)]
fn compensation<L: Lanes>(ratio: L) -> L {
    ratio.max(c(MIN_COMPENSATION_RATIO)).sqrt()
}

/// The projections of eight Gaussians: a lane's values are meaningful where
/// `status.visible()` has its bit.
#[derive(Clone, Copy)]
pub(crate) struct ProjectedLanes<L> {
    pub status: Status,
    pub mean2d: [L; 2],
    pub conic: [L; 3],
    pub opacity: L,
    pub depth: L,
    /// Bounding-box half extents (integral values).
    pub radius: [L; 2],
    /// ln(opacity / ALPHA_THRESHOLD), which also bounds the splat's support.
    pub log_alpha_ratio: L,
}

impl<L: Lanes> ProjectedLanes<L> {
    /// The lanes' outcomes.
    #[inline(always)]
    pub fn unpack(&self) -> [Outcome; LANES] {
        let m = [self.mean2d[0].to_array(), self.mean2d[1].to_array()];
        let k = [
            self.conic[0].to_array(),
            self.conic[1].to_array(),
            self.conic[2].to_array(),
        ];
        let o = self.opacity.to_array();
        let d = self.depth.to_array();
        let r = [self.radius[0].to_array(), self.radius[1].to_array()];
        let vis = self.status.visible();
        std::array::from_fn(|l| {
            if (vis >> l) & 1 == 1 {
                Outcome::Visible(Projected {
                    mean2d: [m[0][l], m[1][l]],
                    conic: [k[0][l], k[1][l], k[2][l]],
                    opacity: o[l],
                    depth: d[l],
                    radius: [r[0][l] as i32, r[1][l] as i32],
                })
            } else if (self.status.invalid >> l) & 1 == 1 {
                Outcome::Invalid
            } else {
                Outcome::Culled
            }
        })
    }
}

/// Projects eight Gaussians (see [`project`]).
#[inline(always)]
pub(crate) fn project_lanes<L: Lanes>(
    cam: &CameraModel,
    gl: &ParamLanes<L>,
    antialiased: bool,
    near: f64,
) -> ProjectedLanes<L> {
    let it = intermediates(cam, gl, near);
    let mut status = it.status;
    let mut opacity = it.opacity_base;
    if antialiased {
        opacity = opacity * compensation(it.ratio);
    }
    let thr = ALPHA_THRESHOLD as f64;
    status.culled_where(!opacity.ge(c(thr)));
    let log_alpha_ratio = lanes::ln(opacity / thr);
    // NaN (culled lanes) is first, so it gives MAX_EXTEND.
    let extend = (log_alpha_ratio * 2.0).sqrt().min(c(MAX_EXTEND));
    let rx = (extend * (it.x_raw[0] + EPS2D).sqrt()).ceil();
    let ry = (extend * (it.x_raw[2] + EPS2D).sqrt()).ceil();
    let zero = c::<L>(0.0);
    status.culled_where(rx.le(zero) & ry.le(zero));
    let (x, y, z) = (it.pc[0], it.pc[1], it.pc[2]);
    let mean2d = [x * cam.fx / z + cam.cx, y * cam.fy / z + cam.cy];
    status.invalid_where(!(mean2d[0].is_finite() & mean2d[1].is_finite()));
    let outside = (mean2d[0] + rx).le(zero)
        | (mean2d[0] - rx).ge(c(cam.width as f64))
        | (mean2d[1] + ry).le(zero)
        | (mean2d[1] - ry).ge(c(cam.height as f64));
    status.culled_where(outside);
    ProjectedLanes {
        status,
        mean2d,
        conic: it.conic,
        opacity,
        depth: z,
        radius: [rx, ry],
        log_alpha_ratio,
    }
}

/// ln(opacity / ALPHA_THRESHOLD), computed as [`project_lanes`] computes it.
#[cfg(test)]
pub(crate) fn log_alpha_ratio(opacity: f64) -> f64 {
    lanes::ln(P8::splat(opacity / ALPHA_THRESHOLD as f64)).0[0]
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
    let gl = ParamLanes::one(mean, log_scale, quat, logit);
    let [first, ..] = project_lanes(cam, &gl, antialiased, near).unpack();
    first
}

/// Gradients with respect to the projection outputs of eight Gaussians.
#[derive(Clone, Copy)]
pub(crate) struct ProjectedGradLanes<L> {
    pub mean2d: [L; 2],
    pub conic: [L; 3],
    pub opacity: L,
    pub depth: L,
}

impl<L: Lanes> ProjectedGradLanes<L> {
    /// From per-lane rows in the order mean2d x, y, conic a, b, c, opacity, depth.
    #[inline(always)]
    pub fn from_rows(r: [[f64; LANES]; 7]) -> Self {
        ProjectedGradLanes {
            mean2d: [L::from_array(r[0]), L::from_array(r[1])],
            conic: [
                L::from_array(r[2]),
                L::from_array(r[3]),
                L::from_array(r[4]),
            ],
            opacity: L::from_array(r[5]),
            depth: L::from_array(r[6]),
        }
    }
}

impl<L: Lanes> ParamLanes<L> {
    /// The lanes unpacked (as gradients).
    #[inline(always)]
    pub fn unpack(&self) -> [ParamGrad; LANES] {
        let m = lanes::to_arrays(self.mean);
        let s = lanes::to_arrays(self.log_scale);
        let q = lanes::to_arrays(self.quat);
        let o = self.logit.to_array();
        std::array::from_fn(|l| ParamGrad {
            mean: [m[0][l], m[1][l], m[2][l]],
            log_scale: [s[0][l], s[1][l], s[2][l]],
            quat: [q[0][l], q[1][l], q[2][l], q[3][l]],
            logit: o[l],
        })
    }
}

/// Backward of [`project_lanes`]; lanes whose forward intermediates are invalid or culled
/// get zeros (the callers only ask for visible Gaussians).
#[inline(always)]
pub(crate) fn project_vjp_lanes<L: Lanes>(
    cam: &CameraModel,
    gl: &ParamLanes<L>,
    antialiased: bool,
    near: f64,
    g: &ProjectedGradLanes<L>,
) -> ParamLanes<L> {
    let it = intermediates(cam, gl, near);
    let [a, b, cc] = it.conic;
    let k = [[a, b], [b, cc]];
    // Full-matrix gradient of the conic (b sits in both off-diagonal entries).
    let gk = [
        [g.conic[0], g.conic[1] * 0.5],
        [g.conic[1] * 0.5, g.conic[2]],
    ];
    // G_X = −K G_K K.
    let mut kg = [[c::<L>(0.0); 2]; 2];
    for i in 0..2 {
        for j in 0..2 {
            kg[i][j] = k[i][0] * gk[0][j] + k[i][1] * gk[1][j];
        }
    }
    let mut gx = [[c::<L>(0.0); 2]; 2];
    for i in 0..2 {
        for j in 0..2 {
            gx[i][j] = -(kg[i][0] * k[0][j] + kg[i][1] * k[1][j]);
        }
    }
    let mut g_obase = g.opacity;
    if antialiased {
        let comp = compensation(it.ratio);
        g_obase = g.opacity * comp;
        let g_comp = g.opacity * it.opacity_base;
        let g_ratio = g_comp / (comp * 2.0);
        let xr = it.x_raw;
        // d(det_raw/det_blur)/dX = adj(X)ᵀ/det_blur − ratio·K where the ratio is not
        // clamped.
        let live = it.ratio.gt(c(MIN_COMPENSATION_RATIO));
        let adj = [[xr[2], -xr[1]], [-xr[1], xr[0]]];
        for i in 0..2 {
            for j in 0..2 {
                let with = gx[i][j] + g_ratio * (adj[i][j] / it.det_blur - it.ratio * k[i][j]);
                gx[i][j] = L::select(live, with, gx[i][j]);
            }
        }
    }
    // Σ2d_raw = T Tᵀ, T = J M' ⇒ G_T = 2 G T (G symmetric); G_J = G_T M'ᵀ; G_M' = Jᵀ G_T.
    let tm = &it.tm;
    let mut gt = [[c::<L>(0.0); 3]; 2];
    for k in 0..3 {
        gt[0][k] = (gx[0][0] * tm[0][k] + gx[0][1] * tm[1][k]) * 2.0;
        gt[1][k] = (gx[1][0] * tm[0][k] + gx[1][1] * tm[1][k]) * 2.0;
    }
    let mp = &it.mp;
    let dot = |p: &[L; 3], q: &[L; 3]| p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
    let g_j00 = dot(&gt[0], &mp[0]);
    let g_j02 = dot(&gt[0], &mp[2]);
    let g_j11 = dot(&gt[1], &mp[1]);
    let g_j12 = dot(&gt[1], &mp[2]);
    let [j00, j02, j11, j12] = it.jac;
    let mut g_mp = [[c::<L>(0.0); 3]; 3];
    for k in 0..3 {
        g_mp[0][k] = j00 * gt[0][k];
        g_mp[1][k] = j11 * gt[1][k];
        g_mp[2][k] = j02 * gt[0][k] + j12 * gt[1][k];
    }
    let (x, y, z) = (it.pc[0], it.pc[1], it.pc[2]);
    let (fx, fy) = (cam.fx, cam.fy);
    let (z2, z3) = (z * z, z * z * z);
    // mean2d
    let mut g_pc = [
        g.mean2d[0] * fx / z,
        g.mean2d[1] * fy / z,
        -((g.mean2d[0] * fx * x + g.mean2d[1] * fy * y) / z2),
    ];
    // J00 = fx/z, J11 = fy/z
    g_pc[2] = g_pc[2] - (g_j00 * fx / z2 + g_j11 * fy / z2);
    // J02 = −fx·t_x/z² with t_x = x, or −fx·L/z when clamped (so the x path is cut).
    let free_x = g_pc[0] - g_j02 * fx / z2;
    let free_z = g_pc[2] + g_j02 * 2.0 * fx * x / z3;
    let clamped_z = g_pc[2] + g_j02 * fx * it.limit[0] / z2;
    g_pc[0] = L::select(it.clamped[0], g_pc[0], free_x);
    g_pc[2] = L::select(it.clamped[0], clamped_z, free_z);
    let free_y = g_pc[1] - g_j12 * fy / z2;
    let free_z = g_pc[2] + g_j12 * 2.0 * fy * y / z3;
    let clamped_z = g_pc[2] + g_j12 * fy * it.limit[1] / z2;
    g_pc[1] = L::select(it.clamped[1], g_pc[1], free_y);
    g_pc[2] = L::select(it.clamped[1], clamped_z, free_z);
    g_pc[2] = g_pc[2] + g.depth;
    let w = &cam.r;
    let mut g_mean = [c::<L>(0.0); 3];
    for i in 0..3 {
        g_mean[i] = g_pc[0] * w[0][i] + g_pc[1] * w[1][i] + g_pc[2] * w[2][i];
    }
    // M' = A diag(s): G_A = G_M' diag(s), G_s = colsum(A ∘ G_M'); A = W R ⇒ G_R = Wᵀ G_A.
    let mut g_a = [[c::<L>(0.0); 3]; 3];
    let mut g_ls = [c::<L>(0.0); 3];
    for r in 0..3 {
        for col in 0..3 {
            g_a[r][col] = g_mp[r][col] * it.s[col];
            g_ls[col] = g_ls[col] + g_mp[r][col] * it.a[r][col];
        }
    }
    for jj in 0..3 {
        g_ls[jj] = g_ls[jj] * it.s[jj];
    }
    let mut gr = [[c::<L>(0.0); 3]; 3];
    for r in 0..3 {
        for col in 0..3 {
            gr[r][col] = g_a[0][col] * w[0][r] + g_a[1][col] * w[1][r] + g_a[2][col] * w[2][r];
        }
    }
    let [qw, qx, qy, qz] = it.qn;
    let gqn = [
        (-qz * gr[0][1] + qy * gr[0][2] + qz * gr[1][0] - qx * gr[1][2] - qy * gr[2][0]
            + qx * gr[2][1])
            * 2.0,
        (qy * gr[0][1] + qz * gr[0][2] + qy * gr[1][0] - qx * gr[1][1] * 2.0 - qw * gr[1][2]
            + qz * gr[2][0]
            + qw * gr[2][1]
            - qx * gr[2][2] * 2.0)
            * 2.0,
        (-(qy * gr[0][0] * 2.0) + qx * gr[0][1] + qw * gr[0][2] + qx * gr[1][0] + qz * gr[1][2]
            - qw * gr[2][0]
            + qz * gr[2][1]
            - qy * gr[2][2] * 2.0)
            * 2.0,
        (-(qz * gr[0][0] * 2.0) - qw * gr[0][1] + qx * gr[0][2] + qw * gr[1][0]
            - qz * gr[1][1] * 2.0
            + qy * gr[1][2]
            + qx * gr[2][0]
            + qy * gr[2][1])
            * 2.0,
    ];
    let dotq = gqn[0] * qw + gqn[1] * qx + gqn[2] * qy + gqn[3] * qz;
    let g_quat = [
        (gqn[0] - qw * dotq) / it.qnorm,
        (gqn[1] - qx * dotq) / it.qnorm,
        (gqn[2] - qy * dotq) / it.qnorm,
        (gqn[3] - qz * dotq) / it.qnorm,
    ];
    let o = it.sigmoid;
    // × 1 without a factor: the same bits as before it existed.
    let logit = g_obase * it.opacity_scale * o * (c::<L>(1.0) - o);
    // Lanes whose intermediates failed give zeros.
    let ok = it.status.visible();
    let zero = c::<L>(0.0);
    let keep = |v: L| L::select(ok, v, zero);
    ParamLanes {
        mean: [keep(g_mean[0]), keep(g_mean[1]), keep(g_mean[2])],
        log_scale: [keep(g_ls[0]), keep(g_ls[1]), keep(g_ls[2])],
        quat: [
            keep(g_quat[0]),
            keep(g_quat[1]),
            keep(g_quat[2]),
            keep(g_quat[3]),
        ],
        logit: keep(logit),
        opacity_scale: c::<L>(1.0),
    }
}

/// Backward of [`project`] for a visible Gaussian: dL/d(raw parameters) from dL/d(outputs).
/// Returns zeros for a Gaussian whose projection fails before its conic (invalid, behind
/// the near plane, degenerate).
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
    let gl = ParamLanes::one(mean, log_scale, quat, logit);
    let row = |v: f64| [v; LANES];
    let g = ProjectedGradLanes::<P8>::from_rows([
        row(g.mean2d[0]),
        row(g.mean2d[1]),
        row(g.conic[0]),
        row(g.conic[1]),
        row(g.conic[2]),
        row(g.opacity),
        row(g.depth),
    ]);
    let [first, ..] = project_vjp_lanes(cam, &gl, antialiased, near, &g).unpack();
    first
}

pub mod gpu;
#[cfg(test)]
mod tests;
