//! Camera models with lens distortion, and undistortion of points and images.
//!
//! Supported models (COLMAP names): `SIMPLE_PINHOLE` (f, cx, cy), `PINHOLE` (fx, fy, cx, cy),
//! `SIMPLE_RADIAL` (f, cx, cy, k), `RADIAL` (f, cx, cy, k1, k2) and `OPENCV` (fx, fy, cx, cy,
//! k1, k2, p1, p2). transforms.json files may also give `k3`, `k4` (radial terms in r⁶ and r⁸,
//! as nerfstudio reads them). All are one [`Intrinsics`] with a [`Distortion`]:
//!
//! ```text
//! r² = x² + y²,   d = 1 + k1 r² + k2 r⁴ + k3 r⁶ + k4 r⁸
//! x_d = x·d + 2 p1 x y + p2 (r² + 2x²)
//! y_d = y·d + p1 (r² + 2y²) + 2 p2 x y
//! u = fx·x_d + cx,  v = fy·y_d + cy       (pixel centres at +0.5, as COLMAP and augsplat)
//! ```
//!
//! **Undistortion of images** is by inverse mapping: every pixel centre of the output (pinhole)
//! image is taken to normalised coordinates, distorted, mapped into the source image and
//! sampled bilinearly. **Crop policy**: the output keeps the source's size and its pinhole
//! part (fx, fy, cx, cy) — what COLMAP's undistorter produced for the bonsai captures; output
//! pixels whose source position falls outside the source image take the nearest edge pixel
//! (clamped sampling), so there are no black borders (for barrel distortion, k1 < 0, every
//! output pixel lands inside the source anyway).

use crate::error::{Result, SceneError};
use augsplat_core::{Camera, ImageF32};
use rayon::prelude::*;
use std::path::Path;

/// Lens distortion coefficients (OpenCV / nerfstudio convention). All zero means pinhole.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Distortion {
    /// Radial coefficient of r².
    pub k1: f64,
    /// Radial coefficient of r⁴.
    pub k2: f64,
    /// Radial coefficient of r⁶.
    pub k3: f64,
    /// Radial coefficient of r⁸.
    pub k4: f64,
    /// Tangential coefficient p1.
    pub p1: f64,
    /// Tangential coefficient p2.
    pub p2: f64,
}

impl Distortion {
    /// Whether every coefficient is zero.
    pub fn is_zero(&self) -> bool {
        [self.k1, self.k2, self.k3, self.k4, self.p1, self.p2]
            .iter()
            .all(|&v| v == 0.0)
    }

    /// Distorts normalised image coordinates.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let d = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * (self.k3 + r2 * self.k4)));
        (
            x * d + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * d + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Distortion and its Jacobian ∂(x_d, y_d)/∂(x, y) as [[dxx, dxy], [dyx, dyy]].
    fn distort_jacobian(&self, x: f64, y: f64) -> ((f64, f64), [[f64; 2]; 2]) {
        let r2 = x * x + y * y;
        let d = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * (self.k3 + r2 * self.k4)));
        // dd/d(r²)
        let dd = self.k1 + r2 * (2.0 * self.k2 + r2 * (3.0 * self.k3 + r2 * 4.0 * self.k4));
        let (ddx, ddy) = (dd * 2.0 * x, dd * 2.0 * y);
        let xd = x * d + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * d + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        let j = [
            [
                d + x * ddx + 2.0 * self.p1 * y + self.p2 * 6.0 * x,
                x * ddy + 2.0 * self.p1 * x + self.p2 * 2.0 * y,
            ],
            [
                y * ddx + self.p1 * 2.0 * x + 2.0 * self.p2 * y,
                d + y * ddy + self.p1 * 6.0 * y + 2.0 * self.p2 * x,
            ],
        ];
        ((xd, yd), j)
    }

    /// Inverts [`Distortion::distort`] by Newton's method (started at the distorted point).
    /// Returns `None` when the iteration does not converge (far outside the model's range).
    pub fn undistort(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        if self.is_zero() {
            return Some((xd, yd));
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..50 {
            let ((fx, fy), j) = self.distort_jacobian(x, y);
            let (rx, ry) = (fx - xd, fy - yd);
            if rx.abs() < 1e-15 && ry.abs() < 1e-15 {
                return Some((x, y));
            }
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if !det.is_finite() || det.abs() < 1e-12 {
                return None;
            }
            let dx = (j[1][1] * rx - j[0][1] * ry) / det;
            let dy = (-j[1][0] * rx + j[0][0] * ry) / det;
            x -= dx;
            y -= dy;
            if !(x.is_finite() && y.is_finite()) {
                return None;
            }
            if dx.abs() < 1e-14 && dy.abs() < 1e-14 {
                return Some((x, y));
            }
        }
        let ((fx, fy), _) = self.distort_jacobian(x, y);
        ((fx - xd).abs() < 1e-9 && (fy - yd).abs() < 1e-9).then_some((x, y))
    }
}

/// A camera model as a COLMAP camera or a transforms.json frame describes it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelKind {
    /// f, cx, cy.
    SimplePinhole,
    /// fx, fy, cx, cy.
    Pinhole,
    /// f, cx, cy, k.
    SimpleRadial,
    /// f, cx, cy, k1, k2.
    Radial,
    /// fx, fy, cx, cy, k1, k2, p1, p2 (and k3, k4 from transforms.json).
    OpenCv,
}

impl ModelKind {
    /// COLMAP's model name.
    pub fn colmap_name(self) -> &'static str {
        match self {
            ModelKind::SimplePinhole => "SIMPLE_PINHOLE",
            ModelKind::Pinhole => "PINHOLE",
            ModelKind::SimpleRadial => "SIMPLE_RADIAL",
            ModelKind::Radial => "RADIAL",
            ModelKind::OpenCv => "OPENCV",
        }
    }
    /// COLMAP's numeric model id (as in cameras.bin).
    pub fn colmap_id(self) -> i32 {
        match self {
            ModelKind::SimplePinhole => 0,
            ModelKind::Pinhole => 1,
            ModelKind::SimpleRadial => 2,
            ModelKind::Radial => 3,
            ModelKind::OpenCv => 4,
        }
    }
    /// The model with COLMAP id `id`, if supported.
    pub fn from_colmap_id(id: i32) -> Option<ModelKind> {
        Some(match id {
            0 => ModelKind::SimplePinhole,
            1 => ModelKind::Pinhole,
            2 => ModelKind::SimpleRadial,
            3 => ModelKind::Radial,
            4 => ModelKind::OpenCv,
            _ => return None,
        })
    }
    /// The model called `name` (COLMAP spelling), if supported.
    pub fn from_colmap_name(name: &str) -> Option<ModelKind> {
        Some(match name {
            "SIMPLE_PINHOLE" => ModelKind::SimplePinhole,
            "PINHOLE" => ModelKind::Pinhole,
            "SIMPLE_RADIAL" => ModelKind::SimpleRadial,
            "RADIAL" => ModelKind::Radial,
            "OPENCV" => ModelKind::OpenCv,
            _ => return None,
        })
    }
    /// Number of parameters COLMAP stores for the model.
    pub fn param_count(self) -> usize {
        match self {
            ModelKind::SimplePinhole => 3,
            ModelKind::Pinhole => 4,
            ModelKind::SimpleRadial => 4,
            ModelKind::Radial => 5,
            ModelKind::OpenCv => 8,
        }
    }
}

/// Intrinsics with distortion, at a given image size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    /// The model the parameters came from.
    pub kind: ModelKind,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length x, pixels.
    pub fx: f64,
    /// Focal length y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Distortion (zero for the pinhole models).
    pub distortion: Distortion,
}

impl Intrinsics {
    /// Builds intrinsics from COLMAP's parameter list for `kind`. `params` must hold exactly
    /// [`ModelKind::param_count`] values (the caller reports the entry on error).
    pub fn from_colmap(
        kind: ModelKind,
        width: u32,
        height: u32,
        params: &[f64],
    ) -> std::result::Result<Intrinsics, String> {
        if params.len() != kind.param_count() {
            return Err(format!(
                "model {} needs {} parameters, found {}",
                kind.colmap_name(),
                kind.param_count(),
                params.len()
            ));
        }
        if let Some(bad) = params.iter().find(|v| !v.is_finite()) {
            return Err(format!("parameter {bad} is not finite"));
        }
        let p = params;
        let mut d = Distortion::default();
        let (fx, fy, cx, cy) = match kind {
            ModelKind::SimplePinhole => (p[0], p[0], p[1], p[2]),
            ModelKind::Pinhole => (p[0], p[1], p[2], p[3]),
            ModelKind::SimpleRadial => {
                d.k1 = p[3];
                (p[0], p[0], p[1], p[2])
            }
            ModelKind::Radial => {
                d.k1 = p[3];
                d.k2 = p[4];
                (p[0], p[0], p[1], p[2])
            }
            ModelKind::OpenCv => {
                d.k1 = p[4];
                d.k2 = p[5];
                d.p1 = p[6];
                d.p2 = p[7];
                (p[0], p[1], p[2], p[3])
            }
        };
        let intr = Intrinsics {
            kind,
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion: d,
        };
        intr.check()?;
        Ok(intr)
    }

    /// COLMAP's parameter list for this camera's model.
    pub fn colmap_params(&self) -> Vec<f64> {
        let d = &self.distortion;
        match self.kind {
            ModelKind::SimplePinhole => vec![self.fx, self.cx, self.cy],
            ModelKind::Pinhole => vec![self.fx, self.fy, self.cx, self.cy],
            ModelKind::SimpleRadial => vec![self.fx, self.cx, self.cy, d.k1],
            ModelKind::Radial => vec![self.fx, self.cx, self.cy, d.k1, d.k2],
            ModelKind::OpenCv => vec![self.fx, self.fy, self.cx, self.cy, d.k1, d.k2, d.p1, d.p2],
        }
    }

    /// Checks sizes and focal lengths.
    pub fn check(&self) -> std::result::Result<(), String> {
        if self.width == 0 || self.height == 0 {
            return Err(format!(
                "image size {}×{} is empty",
                self.width, self.height
            ));
        }
        let all = [
            self.fx,
            self.fy,
            self.cx,
            self.cy,
            self.distortion.k1,
            self.distortion.k2,
            self.distortion.k3,
            self.distortion.k4,
            self.distortion.p1,
            self.distortion.p2,
        ];
        if all.iter().any(|v| !v.is_finite()) {
            return Err("intrinsics contain a non-finite value".into());
        }
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(format!(
                "focal lengths must be positive (fx {}, fy {})",
                self.fx, self.fy
            ));
        }
        Ok(())
    }

    /// Whether the camera has lens distortion.
    pub fn is_distorted(&self) -> bool {
        !self.distortion.is_zero()
    }

    /// Projects a point given in camera coordinates (z forward) to pixels, with distortion.
    /// `None` when the point is at or behind the camera.
    pub fn project_camera_point(&self, p: [f64; 3]) -> Option<(f64, f64)> {
        if p[2] <= 0.0 {
            return None;
        }
        let (xd, yd) = self.distortion.distort(p[0] / p[2], p[1] / p[2]);
        Some((self.fx * xd + self.cx, self.fy * yd + self.cy))
    }

    /// Maps a pixel position of the distorted image to the undistorted (pinhole) image of
    /// [`undistort_image`]. `None` where Newton's method fails.
    pub fn undistort_pixel(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let (x, y) = self
            .distortion
            .undistort((u - self.cx) / self.fx, (v - self.cy) / self.fy)?;
        Some((self.fx * x + self.cx, self.fy * y + self.cy))
    }

    /// The pinhole camera of the undistorted image (same size, same fx, fy, cx, cy), with the
    /// given pose.
    pub fn pinhole_camera(&self, world_to_camera: augsplat_core::linalg::Mat4) -> Camera {
        Camera {
            width: self.width,
            height: self.height,
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            world_to_camera,
        }
    }
}

/// A precomputed inverse map for one camera: for each output pixel, the source pixel block
/// and bilinear weights (source positions clamped to the image, so edge pixels repeat).
#[derive(Clone, Debug)]
pub struct UndistortMap {
    width: u32,
    height: u32,
    /// Index of the top-left source pixel of each output pixel's 2×2 block.
    base: Vec<u32>,
    /// Step to the right neighbour (0 at the right edge, else 1) and to the lower neighbour
    /// (0 at the bottom edge, else the width), in pixels.
    step: Vec<(u8, u32)>,
    /// Bilinear weights along x and y.
    weight: Vec<(f32, f32)>,
}

impl UndistortMap {
    /// Builds the map of `intr` (forward distortion of every output pixel centre; rows in
    /// parallel, deterministic).
    pub fn new(intr: &Intrinsics) -> UndistortMap {
        let (w, h) = (intr.width as usize, intr.height as usize);
        let mut base = vec![0u32; w * h];
        let mut step = vec![(0u8, 0u32); w * h];
        let mut weight = vec![(0f32, 0f32); w * h];
        base.par_chunks_mut(w)
            .zip(step.par_chunks_mut(w))
            .zip(weight.par_chunks_mut(w))
            .enumerate()
            .for_each(|(i, ((rb, rs), rw))| {
                let y = (i as f64 + 0.5 - intr.cy) / intr.fy;
                for j in 0..w {
                    let x = (j as f64 + 0.5 - intr.cx) / intr.fx;
                    let (xd, yd) = intr.distortion.distort(x, y);
                    // Continuous source position in index space (pixel centres at integers),
                    // clamped to the image.
                    let sx = intr.fx * xd + intr.cx - 0.5;
                    let sy = intr.fy * yd + intr.cy - 0.5;
                    let sx = if sx.is_finite() {
                        sx.clamp(0.0, (w - 1) as f64)
                    } else {
                        0.0
                    };
                    let sy = if sy.is_finite() {
                        sy.clamp(0.0, (h - 1) as f64)
                    } else {
                        0.0
                    };
                    let x0 = (sx.floor() as usize).min(w - 1);
                    let y0 = (sy.floor() as usize).min(h - 1);
                    rb[j] = (y0 * w + x0) as u32;
                    rs[j] = ((x0 + 1 < w) as u8, if y0 + 1 < h { w as u32 } else { 0 });
                    rw[j] = ((sx - x0 as f64) as f32, (sy - y0 as f64) as f32);
                }
            });
        UndistortMap {
            width: intr.width,
            height: intr.height,
            base,
            step,
            weight,
        }
    }

    /// Applies the map to an image of the camera's size (bilinear, clamped at the edges).
    pub fn apply(&self, src: &ImageF32, path: &Path) -> Result<ImageF32> {
        if src.width != self.width || src.height != self.height {
            return Err(SceneError::format(
                path,
                format!(
                    "image is {}×{} but its camera says {}×{}",
                    src.width, src.height, self.width, self.height
                ),
            ));
        }
        let (w, c) = (src.width as usize, src.channels as usize);
        let mut out = ImageF32::new(src.width, src.height, src.channels);
        let data = &src.data;
        out.data
            .par_chunks_mut(w * c)
            .enumerate()
            .for_each(|(i, row)| {
                let r = i * w..(i + 1) * w;
                for (((px, &b), &(dx, dy)), &(fx, fy)) in row
                    .chunks_exact_mut(c)
                    .zip(&self.base[r.clone()])
                    .zip(&self.step[r.clone()])
                    .zip(&self.weight[r])
                {
                    let a = b as usize * c;
                    let bb = a + dx as usize * c;
                    let d = a + dy as usize * c;
                    let e = d + dx as usize * c;
                    for k in 0..c {
                        let top = data[a + k] + (data[bb + k] - data[a + k]) * fx;
                        let bot = data[d + k] + (data[e + k] - data[d + k]) * fx;
                        px[k] = top + (bot - top) * fy;
                    }
                }
            });
        Ok(out)
    }
}

/// Undistorts an image of camera `intr` to its pinhole camera (see the module docs for the
/// method and crop policy). `path` names the image in errors.
pub fn undistort_image(intr: &Intrinsics, src: &ImageF32, path: &Path) -> Result<ImageF32> {
    UndistortMap::new(intr).apply(src, path)
}

/// Downscales an image by an integer factor by area averaging. Rows and columns beyond the
/// last full block are cropped first, so the pixel-centre convention holds exactly: output
/// pixel j covers input pixels [j·f, (j+1)·f), and `u_out = u_in / f`.
pub fn downscale_image(img: &ImageF32, factor: u32) -> ImageF32 {
    if factor <= 1 {
        return img.clone();
    }
    let (w, h) = (img.width / factor, img.height / factor);
    let c = img.channels as usize;
    let mut out = ImageF32::new(w, h, img.channels);
    let src_w = img.width as usize;
    let f = factor as usize;
    let inv = 1.0 / (f * f) as f64;
    out.data
        .par_chunks_mut((w as usize * c).max(1))
        .enumerate()
        .for_each(|(oy, row)| {
            let mut acc = vec![0f64; c];
            for ox in 0..w as usize {
                acc.iter_mut().for_each(|a| *a = 0.0);
                for y in oy * f..(oy + 1) * f {
                    let base = (y * src_w + ox * f) * c;
                    for px in img.data[base..base + f * c].chunks_exact(c) {
                        for k in 0..c {
                            acc[k] += px[k] as f64;
                        }
                    }
                }
                for k in 0..c {
                    row[ox * c + k] = (acc[k] * inv) as f32;
                }
            }
        });
    out
}

/// The camera of [`downscale_image`]: size floor(W/f) × floor(H/f), focal lengths and
/// principal point divided by f.
pub fn downscale_camera(cam: &Camera, factor: u32) -> Camera {
    if factor <= 1 {
        return cam.clone();
    }
    let f = factor as f64;
    Camera {
        width: cam.width / factor,
        height: cam.height / factor,
        fx: cam.fx / f,
        fy: cam.fy / f,
        cx: cam.cx / f,
        cy: cam.cy / f,
        world_to_camera: cam.world_to_camera,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opencv() -> Intrinsics {
        Intrinsics::from_colmap(
            ModelKind::OpenCv,
            200,
            150,
            &[180.0, 178.0, 101.0, 74.5, -0.0846, 0.1563, 0.00347, 0.0039],
        )
        .unwrap()
    }

    #[test]
    fn undistort_inverts_distort() {
        let models = [
            Distortion {
                k1: -0.0846,
                k2: 0.1563,
                p1: 0.00347,
                p2: 0.0039,
                ..Default::default()
            },
            Distortion {
                k1: 0.12,
                ..Default::default()
            },
            Distortion {
                k1: -0.2,
                k2: 0.05,
                k3: -0.01,
                k4: 0.002,
                p1: -0.001,
                p2: 0.002,
            },
        ];
        for d in models {
            for i in -10..=10 {
                for j in -10..=10 {
                    let (x, y) = (i as f64 * 0.06, j as f64 * 0.045);
                    let (xd, yd) = d.distort(x, y);
                    let (xu, yu) = d.undistort(xd, yd).expect("converges");
                    assert!(
                        (xu - x).abs() < 1e-10 && (yu - y).abs() < 1e-10,
                        "{d:?} {x} {y}"
                    );
                }
            }
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let d = Distortion {
            k1: -0.2,
            k2: 0.05,
            k3: -0.01,
            k4: 0.002,
            p1: -0.001,
            p2: 0.002,
        };
        let (x, y) = (0.31, -0.22);
        let (_, j) = d.distort_jacobian(x, y);
        let h = 1e-6;
        let (a, b) = (d.distort(x + h, y), d.distort(x - h, y));
        let (c, e) = (d.distort(x, y + h), d.distort(x, y - h));
        let num = [
            [(a.0 - b.0) / (2.0 * h), (c.0 - e.0) / (2.0 * h)],
            [(a.1 - b.1) / (2.0 * h), (c.1 - e.1) / (2.0 * h)],
        ];
        for r in 0..2 {
            for s in 0..2 {
                assert!((j[r][s] - num[r][s]).abs() < 1e-8, "{r}{s}");
            }
        }
    }

    #[test]
    fn colmap_params_round_trip_and_reject_bad_values() {
        let i = opencv();
        assert_eq!(i.colmap_params().len(), 8);
        let back =
            Intrinsics::from_colmap(ModelKind::OpenCv, 200, 150, &i.colmap_params()).unwrap();
        assert_eq!(back, i);
        assert!(Intrinsics::from_colmap(ModelKind::Pinhole, 10, 10, &[1.0, 2.0]).is_err());
        assert!(
            Intrinsics::from_colmap(ModelKind::Pinhole, 10, 10, &[f64::NAN, 1.0, 1.0, 1.0])
                .is_err()
        );
        assert!(
            Intrinsics::from_colmap(ModelKind::Pinhole, 10, 10, &[-1.0, 1.0, 1.0, 1.0]).is_err()
        );
        for id in 0..5 {
            let k = ModelKind::from_colmap_id(id).unwrap();
            assert_eq!(ModelKind::from_colmap_name(k.colmap_name()), Some(k));
        }
        assert_eq!(ModelKind::from_colmap_id(5), None);
    }

    /// A smooth test pattern as a function of undistorted pixel position.
    fn pattern(u: f64, v: f64) -> f32 {
        (0.5 + 0.4 * (u * 0.07).sin() * (v * 0.05).cos()) as f32
    }

    #[test]
    fn undistorting_a_synthetic_distorted_image_recovers_the_pattern() {
        let intr = opencv();
        // Build the distorted image: distorted pixel centre → undistorted position → pattern.
        let (w, h) = (intr.width, intr.height);
        let mut src = ImageF32::new(w, h, 1);
        for i in 0..h {
            for j in 0..w {
                let (u, v) = intr
                    .undistort_pixel(j as f64 + 0.5, i as f64 + 0.5)
                    .unwrap();
                src.set(j, i, 0, pattern(u, v));
            }
        }
        let out = undistort_image(&intr, &src, Path::new("test.png")).unwrap();
        let mut max_err = 0f32;
        for i in 5..h - 5 {
            for j in 5..w - 5 {
                let e = (out.get(j, i, 0) - pattern(j as f64 + 0.5, i as f64 + 0.5)).abs();
                max_err = max_err.max(e);
            }
        }
        // Bilinear interpolation of a pattern with ~0.07 rad/px: error ≲ (0.07²/8)·0.4.
        assert!(max_err < 5e-3, "max error {max_err}");
        // Wrong size is a clear error naming the file.
        let bad = ImageF32::new(10, 10, 1);
        let err = undistort_image(&intr, &bad, Path::new("x/img.png")).unwrap_err();
        assert!(err.to_string().contains("x/img.png"), "{err}");
    }

    #[test]
    fn undistortion_is_thread_count_independent() {
        let intr = opencv();
        let mut src = ImageF32::new(intr.width, intr.height, 3);
        for (k, v) in src.data.iter_mut().enumerate() {
            *v = ((k * 7919) % 1000) as f32 / 1000.0;
        }
        let run = |n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
                .install(|| undistort_image(&intr, &src, Path::new("a")).unwrap())
        };
        assert_eq!(run(1).data, run(2).data);
    }

    #[test]
    fn downscale_keeps_pixel_centres() {
        // A linear ramp in u: averaging a block gives the ramp at the block centre.
        let (w, h) = (9, 7);
        let mut img = ImageF32::new(w, h, 1);
        for i in 0..h {
            for j in 0..w {
                img.set(j, i, 0, (j as f32 + 0.5) * 0.1);
            }
        }
        let small = downscale_image(&img, 2);
        assert_eq!((small.width, small.height), (4, 3));
        for j in 0..4 {
            // u_out = u_in / 2 ⇒ the value at output centre j + 0.5 is 0.1·2·(j + 0.5).
            let want = 0.1 * 2.0 * (j as f32 + 0.5);
            assert!((small.get(j, 1, 0) - want).abs() < 1e-6);
        }
        let cam = Camera {
            width: 9,
            height: 7,
            fx: 10.0,
            fy: 11.0,
            cx: 4.5,
            cy: 3.5,
            world_to_camera: augsplat_core::linalg::mat4_from_rt(
                &augsplat_core::linalg::IDENTITY3,
                [0.0; 3],
            ),
        };
        let c2 = downscale_camera(&cam, 2);
        assert_eq!((c2.width, c2.height), (4, 3));
        let (u, v, _) = cam.project([0.3, -0.2, 2.0]);
        let (u2, v2, _) = c2.project([0.3, -0.2, 2.0]);
        assert!((u2 - u / 2.0).abs() < 1e-12 && (v2 - v / 2.0).abs() < 1e-12);
    }
}
