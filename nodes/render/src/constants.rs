//! Every magic number of the rasteriser in one place (gsplat `Common.h` style).

/// Gaussians whose per-pixel alpha is below this are skipped (and culled if their opacity is).
pub const ALPHA_THRESHOLD: f32 = 1.0 / 255.0;
/// Default upper clamp of the per-pixel alpha (gsplat ≥ 1.6 and Inria; 0.999 in gsplat 1.5.x).
pub const MAX_ALPHA: f32 = 0.99;
/// Compositing stops *before* a Gaussian that would bring the transmittance to or below this.
pub const TRANSMITTANCE_THRESHOLD: f32 = 1e-4;
/// Screen-space blur added to the diagonal of the projected covariance, pixels².
pub const EPS2D: f64 = 0.3;
/// Gaussians whose camera-space depth is below this are culled.
pub const NEAR: f32 = 0.01;
/// Tile edge in pixels.
pub const TILE: u32 = 16;
/// Pixels per tile.
pub const TILE_PIXELS: usize = (TILE * TILE) as usize;
/// The clamp of the Jacobian's x/z, y/z extends this fraction of tan(fov/2) past the image.
pub const JACOBIAN_CLAMP_MARGIN: f64 = 0.3;
/// The opacity-aware radius never extends past this many standard deviations.
pub const MAX_EXTEND: f64 = 3.33;
/// Lower clamp of the antialiasing compensation ratio det(Σ2d)/det(Σ2d + eps2d·I).
pub const MIN_COMPENSATION_RATIO: f64 = 0.005 * 0.005;
/// Squared quaternion norms below this are degenerate (the Gaussian is invalid).
pub const MIN_QUAT_NORM2: f64 = 1e-24;
/// Accumulated alpha below which the normalised expected depth is reported as 0.
pub const DEPTH_ALPHA_EPS: f32 = 1e-6;

/// SH degree-0 constant.
pub const C0: f64 = 0.282_094_791_773_878_14;
/// SH degree-1 constant.
pub const C1: f64 = 0.488_602_511_902_919_9;
/// SH degree-2 constants.
pub const C2: [f64; 5] = [
    1.092_548_430_592_079_2,
    -1.092_548_430_592_079_2,
    0.315_391_565_252_520_05,
    -1.092_548_430_592_079_2,
    0.546_274_215_296_039_6,
];
/// SH degree-3 constants.
pub const C3: [f64; 7] = [
    -0.590_043_589_926_643_5,
    2.890_611_442_640_554,
    -0.457_045_799_464_465_8,
    0.373_176_332_590_115_4,
    -0.457_045_799_464_465_8,
    1.445_305_721_320_277,
    -0.590_043_589_926_643_5,
];
