//! Analytic backward pass.

use crate::gaussians::Gaussians;
use crate::render::{Gradients, RenderOutput, RenderSettings};
use augsplat_core::Camera;

pub(crate) fn backward_impl(
    _g: &Gaussians,
    _cam: &Camera,
    _s: &RenderSettings,
    _out: &RenderOutput,
    _d_rgb: &[f32],
    _d_alpha: Option<&[f32]>,
    _d_depth: Option<&[f32]>,
) -> Gradients {
    todo!("backward lands in a later commit")
}
