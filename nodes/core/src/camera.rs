//! The pinhole camera every stage shares: OpenCV axes (x right, y down, z forward),
//! world-to-camera `p_c = R p_w + t`, pixel (i, j) centred at (j + 0.5, i + 0.5).

use crate::linalg::{self, Mat3, Mat4, Vec3};
use serde::{Deserialize, Serialize};

/// A pinhole camera with its pose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels (image left edge is 0).
    pub cx: f64,
    /// Principal point y, pixels (image top edge is 0).
    pub cy: f64,
    /// World-to-camera rigid transform, row-major, OpenCV axes.
    pub world_to_camera: Mat4,
}

impl Camera {
    /// Rotation part of world-to-camera.
    pub fn rotation(&self) -> Mat3 {
        linalg::rt_from_mat4(&self.world_to_camera).0
    }
    /// Translation part of world-to-camera.
    pub fn translation(&self) -> Vec3 {
        linalg::rt_from_mat4(&self.world_to_camera).1
    }
    /// Camera-to-world transform.
    pub fn camera_to_world(&self) -> Mat4 {
        linalg::rigid_inverse(&self.world_to_camera)
    }
    /// Camera centre in world coordinates: −Rᵀt.
    pub fn center(&self) -> Vec3 {
        let (r, t) = linalg::rt_from_mat4(&self.world_to_camera);
        linalg::scale(linalg::mat3_vec(&linalg::transpose3(&r), t), -1.0)
    }
    /// Viewing direction (camera +z) in world coordinates.
    pub fn forward(&self) -> Vec3 {
        let r = self.rotation();
        [r[2][0], r[2][1], r[2][2]]
    }
    /// World point to camera coordinates.
    pub fn to_camera(&self, p: Vec3) -> Vec3 {
        let (r, t) = linalg::rt_from_mat4(&self.world_to_camera);
        linalg::add(linalg::mat3_vec(&r, p), t)
    }
    /// Projects a world point: (u, v, z) with u, v in pixels (continuous; pixel centres at +0.5)
    /// and z the depth along the optical axis. u, v are meaningless when z ≤ 0.
    pub fn project(&self, p: Vec3) -> (f64, f64, f64) {
        let c = self.to_camera(p);
        (
            self.fx * c[0] / c[2] + self.cx,
            self.fy * c[1] / c[2] + self.cy,
            c[2],
        )
    }
    /// Ray through continuous pixel position (u, v): origin and unit direction in world space.
    pub fn ray(&self, u: f64, v: f64) -> (Vec3, Vec3) {
        let d_cam = [(u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0];
        let r = self.rotation();
        let d = linalg::mat3_vec(&linalg::transpose3(&r), d_cam);
        (self.center(), linalg::normalize(d))
    }
    /// Ray through the centre of pixel (row i, column j).
    pub fn pixel_ray(&self, i: u32, j: u32) -> (Vec3, Vec3) {
        self.ray(j as f64 + 0.5, i as f64 + 0.5)
    }
    /// The same camera for an image resized to `width × height`: focal lengths and principal
    /// point scale by the size ratio, which keeps the pixel-centre convention exact.
    pub fn resized(&self, width: u32, height: u32) -> Camera {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Camera {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            world_to_camera: self.world_to_camera,
        }
    }
    /// The same camera for its image downscaled by an integer `factor` (each side rounded
    /// up, as image downscaling does); `factor ≤ 1` is the camera itself.
    pub fn downscaled(&self, factor: u32) -> Camera {
        if factor > 1 {
            self.resized(self.width.div_ceil(factor), self.height.div_ceil(factor))
        } else {
            self.clone()
        }
    }
    /// Horizontal and vertical field of view, radians.
    pub fn fov(&self) -> (f64, f64) {
        (
            2.0 * (self.width as f64 / (2.0 * self.fx)).atan(),
            2.0 * (self.height as f64 / (2.0 * self.fy)).atan(),
        )
    }
    /// Checks that every number is finite and the intrinsics are positive.
    pub fn validate(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 {
            return Err(format!(
                "image size {}×{} is empty",
                self.width, self.height
            ));
        }
        if self.width > Camera::MAX_SIDE || self.height > Camera::MAX_SIDE {
            return Err(format!(
                "image size {}×{} exceeds the largest supported side, {} pixels",
                self.width,
                self.height,
                Camera::MAX_SIDE
            ));
        }
        for (name, v) in [
            ("fx", self.fx),
            ("fy", self.fy),
            ("cx", self.cx),
            ("cy", self.cy),
        ] {
            if !v.is_finite() {
                return Err(format!("{name} = {v} is not finite"));
            }
        }
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(format!(
                "focal lengths must be positive (fx {}, fy {})",
                self.fx, self.fy
            ));
        }
        if self
            .world_to_camera
            .iter()
            .flatten()
            .any(|v| !v.is_finite())
        {
            return Err("pose contains a non-finite value".into());
        }
        self.check_rotation()
    }

    /// The largest image side a camera may have (a 16384×16384 image is 3 GiB in f32 RGB);
    /// larger sizes are errors rather than allocation failures.
    pub const MAX_SIDE: u32 = 16384;

    /// How far from orthonormal a rotation may be (each entry of R·Rᵀ − I) and still be a
    /// rotation.
    pub const ROTATION_TOLERANCE: f64 = 1e-4;

    /// Checks that the pose is rigid: the rotation block orthonormal to
    /// [`Camera::ROTATION_TOLERANCE`] with determinant +1, and the last row `[0, 0, 0, 1]`. The
    /// message shows the offending matrix.
    pub fn check_rotation(&self) -> Result<(), String> {
        let m = &self.world_to_camera;
        let show = || {
            let rows: Vec<String> = m
                .iter()
                .map(|r| format!("[{}, {}, {}, {}]", r[0], r[1], r[2], r[3]))
                .collect();
            format!("[{}]", rows.join(", "))
        };
        if m[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(format!(
                "world_to_camera's last row must be [0, 0, 0, 1]; the matrix is {}",
                show()
            ));
        }
        let r = self.rotation();
        let mut worst = 0.0f64;
        for i in 0..3 {
            for j in 0..3 {
                let dot: f64 = (0..3).map(|k| r[i][k] * r[j][k]).sum();
                let want = if i == j { 1.0 } else { 0.0 };
                worst = worst.max((dot - want).abs());
            }
        }
        let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
            - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
        if worst > Camera::ROTATION_TOLERANCE || det <= 0.0 {
            return Err(format!(
                "the rotation of world_to_camera is not a rotation (R·Rᵀ is off the identity by {worst:.3e}, det {det:.6}; allowed: {:e} and +1); the matrix is {}",
                Camera::ROTATION_TOLERANCE,
                show()
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::{axis_angle, mat4_from_rt};

    #[test]
    fn validate_rejects_non_rigid_poses_and_huge_images() {
        let good = Camera {
            width: 64,
            height: 48,
            fx: 50.0,
            fy: 50.0,
            cx: 32.0,
            cy: 24.0,
            world_to_camera: mat4_from_rt(&axis_angle([0.3, -0.5, 0.8], 0.7), [0.1, 0.2, 3.0]),
        };
        assert!(good.validate().is_ok());
        // A scaled rotation, a singular one, a reflection, a projective last row.
        let mut scaled = good.clone();
        for r in scaled.world_to_camera.iter_mut().take(3) {
            for v in r.iter_mut().take(3) {
                *v *= 1.01;
            }
        }
        let e = scaled.validate().unwrap_err();
        assert!(
            e.contains("not a rotation") && e.contains("the matrix is [["),
            "{e}"
        );
        let mut singular = good.clone();
        singular.world_to_camera[2] = [0.0, 0.0, 0.0, 3.0];
        assert!(singular.validate().unwrap_err().contains("not a rotation"));
        let mut mirror = good.clone();
        for v in mirror.world_to_camera[0].iter_mut().take(3) {
            *v = -*v;
        }
        assert!(mirror.validate().unwrap_err().contains("det -1"));
        let mut projective = good.clone();
        projective.world_to_camera[3] = [0.0, 0.0, 0.1, 1.0];
        assert!(projective.validate().unwrap_err().contains("last row"));
        // Within the tolerance (rounded files) is fine.
        let mut rounded = good.clone();
        rounded.world_to_camera[0][0] += 2e-5;
        assert!(rounded.validate().is_ok());
        let huge = Camera {
            width: 100_000,
            height: 100_000,
            ..good
        };
        assert!(huge
            .validate()
            .unwrap_err()
            .contains("largest supported side"));
    }

    #[test]
    fn ray_and_projection_agree() {
        let cam = Camera {
            width: 64,
            height: 48,
            fx: 50.0,
            fy: 52.0,
            cx: 31.0,
            cy: 25.0,
            world_to_camera: mat4_from_rt(&axis_angle([0.2, 1.0, 0.1], 0.8), [0.3, -0.2, 2.0]),
        };
        let (o, d) = cam.pixel_ray(10, 20);
        let p = linalg::add(o, linalg::scale(d, 3.7));
        let (u, v, z) = cam.project(p);
        assert!(z > 0.0);
        assert!((u - 20.5).abs() < 1e-9 && (v - 10.5).abs() < 1e-9);
        // Integer downscaling rounds each side up; a factor of 1 keeps the camera.
        assert_eq!(cam.downscaled(1), cam);
        let third = cam.downscaled(3);
        assert_eq!(
            (third.width, third.height),
            (cam.width.div_ceil(3), cam.height.div_ceil(3))
        );
        assert_eq!(third, cam.resized(third.width, third.height));
        let small = cam.resized(32, 24);
        let (u2, v2, _) = small.project(p);
        assert!((u2 - u / 2.0).abs() < 1e-9 && (v2 - v / 2.0).abs() < 1e-9);
    }
}
