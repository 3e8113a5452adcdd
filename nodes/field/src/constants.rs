//! Every magic number of the radiance field in one place (defaults of the node args live in
//! [`crate::node`]; these are fixed properties of the method).

/// Rays stop contributing once transmittance falls below this (instant-ngp, nerfacc).
pub const TRANSMITTANCE_THRESHOLD: f32 = 1e-4;
/// Occupancy threshold on the EMA of `σ · step` per cell (nerfacc's `occ_thre`).
pub const OCCUPANCY_THRESHOLD: f32 = 0.01;
/// EMA decay of the occupancy grid.
pub const OCCUPANCY_DECAY: f32 = 0.95;
/// The occupancy grid is refreshed every this many steps after its warm-up.
pub const OCCUPANCY_UPDATE_EVERY: u32 = 16;
/// Truncated exponential: the argument is clamped to this before `exp` (forward and backward).
pub const TRUNC_EXP_MAX: f32 = 15.0;
/// Lower clamp of the truncated exponential's argument (keeps densities representable).
pub const TRUNC_EXP_MIN: f32 = -15.0;
/// Primes of the instant-ngp spatial hash (x, y, z).
pub const HASH_PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];
/// Initial hash-table entries are uniform in ±this (instant-ngp).
pub const GRID_INIT_RANGE: f32 = 1e-4;
/// Radius of the contracted ball (mip-NeRF 360).
pub const CONTRACTED_RADIUS: f32 = 2.0;
/// Adam β1.
pub const ADAM_BETA1: f32 = 0.9;
/// Adam β2 (instant-ngp / nerfacto use 0.99 for hash grids).
pub const ADAM_BETA2: f32 = 0.99;
/// Adam ε (nerfacto uses 1e-15 for the grid; larger values slow the sparse grid updates).
pub const ADAM_EPS: f32 = 1e-15;
/// ε inside the DS-NeRF log: `−log(w + ε)`.
pub const DEPTH_LOG_EPS: f32 = 1e-5;
/// Training stops with an error after this many consecutive steps whose gradient was not finite.
pub const MAX_CONSECUTIVE_BAD_STEPS: u32 = 20;
/// Hard cap on marching iterations per ray (guards against degenerate bounds).
pub const MAX_MARCH_ITERATIONS: u32 = 4096;
/// Geometry feature width passed from the density MLP to the colour MLP (nerfacto).
pub const GEO_FEAT_DIM: usize = 15;
/// Number of SH components of the view direction (degree 4 ⇒ 16, nerfacto).
pub const SH_COMPONENTS: usize = 16;
/// When rendering, samples with weight below this skip the colour network (their colour
/// could change the pixel by at most this much each).
pub const RENDER_MIN_COLOR_WEIGHT: f32 = 1e-5;
