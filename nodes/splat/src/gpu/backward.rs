//! Host side of the GPU backward pass, so far its second stage: the projection and colour
//! backward (`project/project_vjp.wgsl`) from per-Gaussian screen-space gradients. The first
//! stage (per-tile pair sums of the compositing backward) and the training loop on the GPU
//! are not written yet.

use super::forward::{camera_words, GpuScene};
use super::{f32_words, GpuContext, GpuError};
use crate::render::RenderSettings;
use crate::tiles::TileGrid;
use augsplat_core::Camera;

/// f32 values per Gaussian of the screen-space gradient: dL/d(mean2d x, y; conic a, b, c;
/// opacity; colour r, g, b; depth) — the CPU's pair-sum layout.
pub const SCREEN_GRAD_STRIDE: usize = 10;
/// f32 values per Gaussian of [`ParamGradsGpu::params`]: dL/d(mean 3, log-scale 3, raw
/// quaternion 4, opacity logit 1).
pub const PARAM_GRAD_STRIDE: usize = 11;

/// Gradients of the raw parameters from [`project_vjp_gpu`].
#[derive(Clone, Debug, PartialEq)]
pub struct ParamGradsGpu {
    /// [`PARAM_GRAD_STRIDE`] values per Gaussian.
    pub params: Vec<f32>,
    /// dL/d(SH coefficients), the layout of `Gaussians::sh` (zero above the active degree).
    pub sh: Vec<f32>,
}

/// The projection and colour backward on the GPU: given each Gaussian's screen-space
/// gradient (`screen`, [`SCREEN_GRAD_STRIDE`] values per Gaussian), the gradients of its raw
/// parameters, the SH view direction's dependence on the mean included — the WGSL twin of
/// the CPU backward's per-Gaussian stage. Gaussians whose projection fails get zeros.
pub fn project_vjp_gpu(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    screen: &[f32],
) -> Result<ParamGradsGpu, GpuError> {
    let n = scene.len();
    if screen.len() != n * SCREEN_GRAD_STRIDE {
        return Err(GpuError::Invalid(format!(
            "{} screen-space gradient values for {n} Gaussians (need {SCREEN_GRAD_STRIDE} each)",
            screen.len()
        )));
    }
    cam.validate()
        .map_err(|e| GpuError::Invalid(format!("camera: {e}")))?;
    let grid = TileGrid::new(cam.width, cam.height);
    let k = scene.coeffs as usize;
    ctx.scoped(|| {
        let camera = ctx.uniform("camera", &camera_words(scene, cam, s, grid));
        let upstream =
            ctx.storage_init("screen-space gradients", &f32_words(screen.iter().copied()))?;
        let grads = ctx.storage("parameter gradients", 4 * (PARAM_GRAD_STRIDE * n) as u64)?;
        let sh = ctx.storage("SH gradients", 4 * (3 * k * n) as u64)?;
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        ctx.dispatch(
            &mut enc,
            &ctx.kernels.project_vjp,
            &[
                (0, &camera),
                (1, &scene.means),
                (2, &scene.scales),
                (3, &scene.quats),
                (4, &scene.logits),
                (5, &scene.sh),
                (6, &upstream),
                (7, &grads),
                (8, &sh),
            ],
            ctx.groups((n as u32).div_ceil(256)),
        );
        ctx.submit(enc)?;
        let to_f32 = |w: Vec<u32>| w.into_iter().map(f32::from_bits).collect();
        Ok(ParamGradsGpu {
            params: to_f32(ctx.read_words(&grads, PARAM_GRAD_STRIDE * n)?),
            sh: to_f32(ctx.read_words(&sh, 3 * k * n)?),
        })
    })
}
