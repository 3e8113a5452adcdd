//! The public rendering entry points: [`render`], [`render_masked`] and [`backward`].
//!
//! The pipeline (gsplat "classic" 3DGS, docs/design.md, *Compositing*): per-Gaussian projection
//! ([`crate::project`]) → tile binning with one depth sort ([`crate::tiles`]) → per-tile
//! front-to-back compositing (`crate::forward`); the backward pass (`crate::backward`)
//! recomputes each tile back to front from the per-pixel last-contributor index and final
//! transmittance kept in [`RenderOutput`].

use crate::constants::{MAX_ALPHA, NEAR};
use crate::gaussians::Gaussians;
use augsplat_core::Camera;

/// Options of one render.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderSettings {
    /// Active SH degree; clamped to the Gaussians' stored degree.
    pub sh_degree: u32,
    /// Colour composited behind the Gaussians (`C + T·background`).
    pub background: [f32; 3],
    /// Upper clamp of the per-pixel alpha (0.99 by default).
    pub max_alpha: f32,
    /// Multiply opacities by the antialiasing compensation sqrt(det Σ2d / det(Σ2d + eps2d·I)).
    pub antialiased: bool,
    /// Near-plane depth; Gaussians with camera-space z below it are culled.
    pub near: f32,
    /// A factor on each Gaussian's opacity (after the sigmoid, before the antialiasing
    /// compensation and the per-pixel clamp), one per Gaussian: DropGaussian's 0 for a dropped
    /// Gaussian and 1/(1 − p) for a survivor, which may lift an opacity above 1. `None`: 1
    /// for every Gaussian. A slice of the wrong length is ignored (treated as all ones). The
    /// CPU renderer only: the GPU backend refuses it.
    pub opacity_scale: Option<std::sync::Arc<[f32]>>,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            sh_degree: 3,
            background: [0.0; 3],
            max_alpha: MAX_ALPHA,
            antialiased: false,
            near: NEAR,
            opacity_scale: None,
        }
    }
}

/// Counters of one render.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RenderStats {
    /// Gaussians that reach at least one tile.
    pub visible: usize,
    /// Valid Gaussians culled (near plane, off-screen, opacity below 1/255, degenerate 2D covariance).
    pub culled: usize,
    /// Gaussians with NaN/Inf parameters, a zero quaternion or a non-finite covariance.
    pub invalid: usize,
    /// Composited (Gaussian, pixel) pairs: alpha evaluated and at least 1/255.
    pub pairs: u64,
}

/// How the 1/255 alpha cutoff is applied.
#[doc(hidden)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Cutoff {
    /// gsplat's hard step: alpha below 1/255 is skipped.
    #[default]
    Hard,
    /// Test-only C¹ smoothstep: alpha' = alpha·s((alpha − 1/255)/(1/255)), s = 3x² − 2x³ on
    /// [0, 1]; differentiable everywhere so finite differences are meaningful.
    Smooth,
}

/// The result of a render, with the state the backward pass needs.
#[derive(Clone, Debug)]
pub struct RenderOutput {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Colour, `height·width·3` interleaved, background composited.
    pub rgb: Vec<f32>,
    /// Accumulated alpha `1 − T`, `height·width`.
    pub alpha: Vec<f32>,
    /// Expected depth *normalised by alpha*: Σ z_i α_i T_i / (1 − T), camera-space z; 0 where
    /// alpha < 1e-6. `height·width`.
    pub depth: Vec<f32>,
    /// Counters.
    pub stats: RenderStats,
    pub(crate) state: crate::forward::RasterState,
}

/// Per-Gaussian gradients of a loss.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Gradients {
    /// dL/d(means).
    pub means: Vec<[f32; 3]>,
    /// dL/d(log scales).
    pub log_scales: Vec<[f32; 3]>,
    /// dL/d(raw, unnormalised quaternions).
    pub quats: Vec<[f32; 4]>,
    /// dL/d(opacity logits).
    pub opacity_logits: Vec<f32>,
    /// dL/d(SH coefficients), same layout and degree as `Gaussians::sh` (zero above the active degree).
    pub sh: Vec<f32>,
    /// dL/d(mean2d) summed over this view's pixels, in NDC-normalised units: the pixel-space
    /// gradient × (width/2, height/2), as gsplat's densification statistic. Signed (the
    /// caller takes the norm).
    pub means2d_abs: Vec<[f32; 2]>,
    /// Whether the Gaussian was visible (radius > 0) in this view.
    pub visible: Vec<bool>,
}

/// Renders `g` from `cam`.
pub fn render(g: &Gaussians, cam: &Camera, s: &RenderSettings) -> RenderOutput {
    render_masked(g, cam, s, None)
}

/// Renders `g` from `cam`; pixels whose mask value is 0 are neither composited nor
/// back-propagated (output = background, alpha 0, depth 0) and tiles whose mask is all zero
/// are skipped entirely. `mask`, when given, holds `height·width` values; a mask of the
/// wrong length is ignored (treated as all ones) rather than panicking.
pub fn render_masked(
    g: &Gaussians,
    cam: &Camera,
    s: &RenderSettings,
    mask: Option<&[u8]>,
) -> RenderOutput {
    render_with_cutoff(g, cam, s, mask, Cutoff::Hard)
}

/// [`render_masked`] with a choice of alpha cutoff; `Cutoff::Smooth` exists only for the
/// finite-difference tests.
#[doc(hidden)]
pub fn render_with_cutoff(
    g: &Gaussians,
    cam: &Camera,
    s: &RenderSettings,
    mask: Option<&[u8]>,
    cutoff: Cutoff,
) -> RenderOutput {
    crate::forward::render_impl(g, cam, s, mask, cutoff)
}

/// Gradients of a loss given dL/d(rgb) (`H·W·3`), optional dL/d(alpha) (`H·W`) and
/// dL/d(depth) (`H·W`, of the alpha-normalised depth). `out` must be the result of rendering
/// the same `g` from the same `cam`; the compositing settings (background, max_alpha,
/// antialiasing, near, SH degree) are taken from `out`, so `s` only documents intent.
/// Slices of the wrong length, and non-finite upstream values, are treated as zero.
pub fn backward(
    g: &Gaussians,
    cam: &Camera,
    s: &RenderSettings,
    out: &RenderOutput,
    d_rgb: &[f32],
    d_alpha: Option<&[f32]>,
    d_depth: Option<&[f32]>,
) -> Gradients {
    crate::backward::backward_impl(g, cam, s, out, d_rgb, d_alpha, d_depth)
}

/// Adds the gradients of a loss given dL/d(rgb) to a running sum `acc` (e.g. the gradients
/// of a training step's earlier renders), without allocating per-render buffers. The result
/// equals adding [`backward`]'s output value by value for the Gaussians this render composites
/// (bit for bit, up to the sign of zero sums); their `acc.visible` is set. The SH values above the render's degree and
/// every Gaussian the render does not composite are left untouched. Nothing is added when
/// `acc`'s sizes do not match `g`. The densification statistic is not produced (use
/// [`backward`] for renders that feed it).
pub fn backward_add(
    g: &Gaussians,
    cam: &Camera,
    out: &RenderOutput,
    d_rgb: &[f32],
    acc: &mut crate::backward::ParamGrads,
) {
    crate::backward::backward_add_impl(g, cam, out, d_rgb, acc)
}
