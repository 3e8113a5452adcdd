//! Tiled front-to-back compositing.

use crate::gaussians::Gaussians;
use crate::render::{Cutoff, RenderOutput, RenderSettings};
use augsplat_core::Camera;

/// State kept from the forward pass for the backward pass.
#[derive(Clone, Debug, Default)]
pub(crate) struct RasterState {}

pub(crate) fn render_impl(
    _g: &Gaussians,
    _cam: &Camera,
    _s: &RenderSettings,
    _mask: Option<&[u8]>,
    _cutoff: Cutoff,
) -> RenderOutput {
    todo!("forward lands in the next commit")
}
