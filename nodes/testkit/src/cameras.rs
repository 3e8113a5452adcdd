//! Test cameras: a square-pixel pinhole facing +Z, and cameras on a ring looking at the origin.

use augsplat_core::linalg::mat4_from_rt;
use augsplat_core::{linalg, Camera};

/// A `w`×`h` camera with focal length `w`, the principal point at the centre, identity
/// rotation and translation `(0, 0, z)` (world points at Z = 0 lie `z` in front of it).
pub fn facing(w: u32, h: u32, z: f64) -> Camera {
    square_pixels(
        w,
        h,
        [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, z],
            [0.0, 0.0, 0.0, 1.0],
        ],
    )
}

/// A `w`×`h` camera with focal length `w` (square pixels), the principal point at the centre,
/// and pose `world_to_camera`.
pub fn square_pixels(w: u32, h: u32, world_to_camera: [[f64; 4]; 4]) -> Camera {
    Camera {
        width: w,
        height: h,
        fx: w as f64,
        fy: w as f64,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
        world_to_camera,
    }
}

/// A `w`×`h` camera (focal length `w`, centred principal point) at `eye`, looking at the
/// origin with image-down roughly along world −Y (OpenCV axes).
pub fn looking_at_origin(eye: [f64; 3], w: u32, h: u32) -> Camera {
    let f = linalg::normalize(linalg::scale(eye, -1.0));
    let x = linalg::normalize(linalg::cross([0.0, -1.0, 0.0], f));
    let y = linalg::cross(f, x);
    let r = [x, y, f];
    square_pixels(
        w,
        h,
        mat4_from_rt(&r, linalg::scale(linalg::mat3_vec(&r, eye), -1.0)),
    )
}

/// Camera `i` of `n` on a horizontal ring of radius `radius` at height `y`, looking at the
/// origin (see [`looking_at_origin`]).
pub fn ring(i: usize, n: usize, radius: f64, y: f64, w: u32, h: u32) -> Camera {
    let a = i as f64 / n as f64 * std::f64::consts::TAU;
    looking_at_origin([radius * a.cos(), y, radius * a.sin()], w, h)
}
