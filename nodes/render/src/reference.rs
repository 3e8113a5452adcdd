//! An independent, untiled f64 reference renderer for tests.
//!
//! It follows docs/design.md (*Compositing*) literally — every pixel visits every non-culled Gaussian in
//! (depth, index) order — with its own f64 parameter set ([`RefGaussians`]) so that tests
//! can take central finite differences of any parameter. It shares no code with the fast
//! path except the constants (rotation from `augsplat_core::linalg`, matrices written out,
//! its own SH polynomials).
//!
//! With `smooth = true` the hard 1/255 alpha cutoff is replaced by the C¹ smoothstep
//! α·s((α − 1/255)/(1/255)), s(x) = 3x² − 2x³ on [0, 1] — the same rule as
//! [`crate::render::Cutoff::Smooth`].

// Negated comparisons are deliberate: they also reject NaN. Index loops read best in
// small fixed-size numeric code.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use crate::constants::{
    ALPHA_THRESHOLD, C0, C1, C2, C3, EPS2D, JACOBIAN_CLAMP_MARGIN, MAX_EXTEND,
    MIN_COMPENSATION_RATIO, TRANSMITTANCE_THRESHOLD,
};
use crate::gaussians::Gaussians;
use crate::render::RenderSettings;
use augsplat_core::linalg::{quat_to_mat3, Mat3};
use augsplat_core::Camera;

/// Gaussians with f64 parameters (same meaning and layout as [`Gaussians`]).
#[derive(Clone, Debug, PartialEq)]
pub struct RefGaussians {
    /// Centres.
    pub means: Vec<[f64; 3]>,
    /// Log scales.
    pub log_scales: Vec<[f64; 3]>,
    /// Raw quaternions (w, x, y, z).
    pub quats: Vec<[f64; 4]>,
    /// Opacity logits.
    pub logits: Vec<f64>,
    /// SH coefficients `[(i·K + k)·3 + c]`.
    pub sh: Vec<f64>,
    /// Stored SH degree.
    pub degree: u32,
}

impl From<&Gaussians> for RefGaussians {
    fn from(g: &Gaussians) -> Self {
        let f3 = |v: &[f32; 3]| [v[0] as f64, v[1] as f64, v[2] as f64];
        RefGaussians {
            means: g.means.iter().map(f3).collect(),
            log_scales: g.log_scales.iter().map(f3).collect(),
            quats: g
                .quats
                .iter()
                .map(|q| [q[0] as f64, q[1] as f64, q[2] as f64, q[3] as f64])
                .collect(),
            logits: g.opacity_logits.iter().map(|v| *v as f64).collect(),
            sh: g.sh.iter().map(|v| *v as f64).collect(),
            degree: g.sh_degree,
        }
    }
}

/// A reference image.
#[derive(Clone, Debug, PartialEq)]
pub struct RefImage {
    /// `H·W·3` colour (background composited).
    pub rgb: Vec<f64>,
    /// `H·W` accumulated alpha.
    pub alpha: Vec<f64>,
    /// `H·W` expected depth normalised by alpha (0 where alpha < 1e-6).
    pub depth: Vec<f64>,
    /// Number of non-culled Gaussians.
    pub visible: usize,
}

struct Splat {
    mean2d: [f64; 2],
    conic: [[f64; 2]; 2],
    opacity: f64,
    color: [f64; 3],
    depth: f64,
    index: usize,
}

fn sh_poly(degree: u32, d: [f64; 3]) -> Vec<f64> {
    let (x, y, z) = (d[0], d[1], d[2]);
    let mut v = vec![C0];
    if degree >= 1 {
        v.extend([-C1 * y, C1 * z, -C1 * x]);
    }
    if degree >= 2 {
        v.extend([
            C2[0] * x * y,
            C2[1] * y * z,
            C2[2] * (2.0 * z * z - x * x - y * y),
            C2[3] * x * z,
            C2[4] * (x * x - y * y),
        ]);
    }
    if degree >= 3 {
        v.extend([
            C3[0] * y * (3.0 * x * x - y * y),
            C3[1] * x * y * z,
            C3[2] * y * (4.0 * z * z - x * x - y * y),
            C3[3] * z * (2.0 * z * z - 3.0 * x * x - 3.0 * y * y),
            C3[4] * x * (4.0 * z * z - x * x - y * y),
            C3[5] * z * (x * x - y * y),
            C3[6] * x * (x * x - 3.0 * y * y),
        ]);
    }
    v
}

fn matmul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut c = [[0.0; 3]; 3];
    for (i, row) in c.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn transpose(a: &Mat3) -> Mat3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[j][i] = a[i][j];
        }
    }
    c
}

fn project_one(
    g: &RefGaussians,
    i: usize,
    cam: &Camera,
    s: &RenderSettings,
    degree: u32,
) -> Option<Splat> {
    let w2c = cam.world_to_camera;
    let rw: Mat3 = [
        [w2c[0][0], w2c[0][1], w2c[0][2]],
        [w2c[1][0], w2c[1][1], w2c[1][2]],
        [w2c[2][0], w2c[2][1], w2c[2][2]],
    ];
    let m = g.means[i];
    let p: Vec<f64> = (0..3)
        .map(|r| rw[r][0] * m[0] + rw[r][1] * m[1] + rw[r][2] * m[2] + w2c[r][3])
        .collect();
    let (x, y, z) = (p[0], p[1], p[2]);
    if !(z >= s.near as f64) {
        return None;
    }
    let q = g.quats[i];
    if q.iter().map(|v| v * v).sum::<f64>() < 1e-24 {
        return None;
    }
    let rot = quat_to_mat3(q);
    let sc = g.log_scales[i].map(f64::exp);
    let sdiag: Mat3 = [[sc[0], 0.0, 0.0], [0.0, sc[1], 0.0], [0.0, 0.0, sc[2]]];
    let rs = matmul(&rot, &sdiag);
    let cov = matmul(&rs, &transpose(&rs));
    let cov_c = matmul(&matmul(&rw, &cov), &transpose(&rw));
    let (w, h) = (cam.width as f64, cam.height as f64);
    let lim = |c: f64, f: f64, size: f64, v: f64| {
        let margin = JACOBIAN_CLAMP_MARGIN * 0.5 * size / f;
        v.clamp(-(c / f) - margin, (size - c) / f + margin)
    };
    let tx = z * lim(cam.cx, cam.fx, w, x / z);
    let ty = z * lim(cam.cy, cam.fy, h, y / z);
    let jac = [
        [cam.fx / z, 0.0, -cam.fx * tx / (z * z)],
        [0.0, cam.fy / z, -cam.fy * ty / (z * z)],
    ];
    let mut c2 = [[0.0f64; 2]; 2];
    for a in 0..2 {
        for b in 0..2 {
            let mut acc = 0.0;
            for k in 0..3 {
                for l in 0..3 {
                    acc += jac[a][k] * cov_c[k][l] * jac[b][l];
                }
            }
            c2[a][b] = acc;
        }
    }
    let det0 = c2[0][0] * c2[1][1] - c2[0][1] * c2[1][0];
    c2[0][0] += EPS2D;
    c2[1][1] += EPS2D;
    let det = c2[0][0] * c2[1][1] - c2[0][1] * c2[1][0];
    if !(det > 0.0) {
        return None;
    }
    let conic = [
        [c2[1][1] / det, -c2[0][1] / det],
        [-c2[1][0] / det, c2[0][0] / det],
    ];
    let mut opacity = 1.0 / (1.0 + (-g.logits[i]).exp());
    if let Some(f) = s
        .opacity_scale
        .as_deref()
        .filter(|f| f.len() == g.logits.len())
    {
        opacity *= f64::from(f[i]);
    }
    if s.antialiased {
        opacity *= (det0 / det).max(MIN_COMPENSATION_RATIO).sqrt();
    }
    if opacity < ALPHA_THRESHOLD as f64 {
        return None;
    }
    let mean2d = [cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy];
    let extend = (2.0 * (opacity * 255.0).ln()).sqrt().min(MAX_EXTEND);
    let (rx, ry) = (
        (extend * c2[0][0].sqrt()).ceil(),
        (extend * c2[1][1].sqrt()).ceil(),
    );
    if mean2d[0] + rx <= 0.0 || mean2d[0] - rx >= w || mean2d[1] + ry <= 0.0 || mean2d[1] - ry >= h
    {
        return None;
    }
    let c = cam.center();
    let v = [m[0] - c[0], m[1] - c[1], m[2] - c[2]];
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let dir = [v[0] / n, v[1] / n, v[2] / n];
    let basis = sh_poly(degree, dir);
    let kk = (g.degree as usize + 1).pow(2);
    let mut color = [0.0; 3];
    for (ch, col) in color.iter_mut().enumerate() {
        let mut acc = 0.5;
        for (k, y) in basis.iter().enumerate() {
            acc += g.sh[(i * kk + k) * 3 + ch] * y;
        }
        *col = acc.max(0.0);
    }
    Some(Splat {
        mean2d,
        conic,
        opacity,
        color,
        depth: z,
        index: i,
    })
}

/// Renders `g` pixel by pixel in f64. Invalid parameters are the caller's concern (the
/// reference is only used on valid scenes).
pub fn render_reference(
    g: &RefGaussians,
    cam: &Camera,
    s: &RenderSettings,
    smooth: bool,
) -> RefImage {
    let degree = s.sh_degree.min(g.degree).min(3);
    let mut splats: Vec<Splat> = (0..g.means.len())
        .filter_map(|i| project_one(g, i, cam, s, degree))
        .collect();
    splats.sort_by(|a, b| {
        (a.depth as f32)
            .total_cmp(&(b.depth as f32))
            .then(a.index.cmp(&b.index))
    });
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut img = RefImage {
        rgb: vec![0.0; w * h * 3],
        alpha: vec![0.0; w * h],
        depth: vec![0.0; w * h],
        visible: splats.len(),
    };
    let max_alpha = s.max_alpha as f64;
    let thr = ALPHA_THRESHOLD as f64;
    for py in 0..h {
        for px in 0..w {
            let (u, v) = (px as f64 + 0.5, py as f64 + 0.5);
            let mut t = 1.0f64;
            let mut col = [0.0f64; 3];
            let mut dsum = 0.0;
            for sp in &splats {
                let d = [sp.mean2d[0] - u, sp.mean2d[1] - v];
                let sigma = 0.5
                    * (d[0] * (sp.conic[0][0] * d[0] + sp.conic[0][1] * d[1])
                        + d[1] * (sp.conic[1][0] * d[0] + sp.conic[1][1] * d[1]));
                if sigma < 0.0 {
                    continue;
                }
                let mut alpha = (sp.opacity * (-sigma).exp()).min(max_alpha);
                if smooth {
                    if alpha <= thr {
                        continue;
                    }
                    let x = ((alpha - thr) / thr).min(1.0);
                    alpha *= x * x * (3.0 - 2.0 * x);
                } else if alpha < thr {
                    continue;
                }
                if t * (1.0 - alpha) <= TRANSMITTANCE_THRESHOLD as f64 {
                    break;
                }
                for ch in 0..3 {
                    col[ch] += sp.color[ch] * alpha * t;
                }
                dsum += sp.depth * alpha * t;
                t *= 1.0 - alpha;
            }
            let p = py * w + px;
            for ch in 0..3 {
                img.rgb[p * 3 + ch] = col[ch] + t * s.background[ch] as f64;
            }
            img.alpha[p] = 1.0 - t;
            img.depth[p] = if 1.0 - t >= 1e-6 {
                dsum / (1.0 - t)
            } else {
                0.0
            };
        }
    }
    img
}
