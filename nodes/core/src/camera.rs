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
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::{axis_angle, mat4_from_rt};

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
        let small = cam.resized(32, 24);
        let (u2, v2, _) = small.project(p);
        assert!((u2 - u / 2.0).abs() < 1e-9 && (v2 - v / 2.0).abs() < 1e-9);
    }
}
