//! Host side of the GPU backward pass: the compositing backward (`backward/backward.wgsl`:
//! per-tile pair sums — each pair's 256 pixels summed column by column, then the 16 columns,
//! in a fixed order — then per-Gaussian sums in tile order) and the projection and colour
//! backward (`project/project_vjp.wgsl`); `record_backward` and `record_vjp` are the same
//! steps recorded into a caller's encoder, for the training step on the GPU (`augsplat-splat`'s `train/gpu.rs`).
//! `backward_gpu_atomic` (hidden) swaps the ordered pair sums for float atomics, only to
//! measure what determinism costs.

use crate::forward::gpu::{
    camera_words, forward_pass, ForwardState, GpuScene, CAMERA_COUNT_WORD, SPLAT_STRIDE,
};
use crate::gpu::{f32_words, GpuBuffer, GpuContext, GpuError};
use crate::render::{Cutoff, RenderSettings};
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
    /// From [`backward_gpu`]: dL/d(mean2d) in NDC-normalised units (the pixel-space gradient
    /// × (width/2, height/2)), the densification statistic of [`crate::Gradients`]; empty
    /// from [`project_vjp_gpu`].
    pub means2d: Vec<[f32; 2]>,
    /// From [`backward_gpu`]: whether each Gaussian reached a tile; empty from
    /// [`project_vjp_gpu`].
    pub visible: Vec<bool>,
}

impl ParamGradsGpu {
    /// The gradients in the CPU backward's layout ([`crate::Gradients`]).
    pub fn into_gradients(self) -> crate::Gradients {
        const K: usize = PARAM_GRAD_STRIDE;
        let p = &self.params;
        let n = p.len() / K;
        crate::Gradients {
            means: (0..n)
                .map(|j| [p[j * K], p[j * K + 1], p[j * K + 2]])
                .collect(),
            log_scales: (0..n)
                .map(|j| [p[j * K + 3], p[j * K + 4], p[j * K + 5]])
                .collect(),
            quats: (0..n)
                .map(|j| [p[j * K + 6], p[j * K + 7], p[j * K + 8], p[j * K + 9]])
                .collect(),
            opacity_logits: (0..n).map(|j| p[j * K + 10]).collect(),
            sh: self.sh,
            means2d_abs: self.means2d,
            visible: self.visible,
        }
    }
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
    crate::forward::gpu::tile_grid(cam)?;
    ctx.scoped(|| {
        let upstream =
            ctx.storage_init("screen-space gradients", &f32_words(screen.iter().copied()))?;
        vjp_inner(ctx, scene, cam, s, &upstream)
    })
}

/// Runs `project_vjp.wgsl` on the screen-space gradients in `upstream` and reads the
/// parameter gradients back.
fn vjp_inner(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    upstream: &wgpu::Buffer,
) -> Result<ParamGradsGpu, GpuError> {
    let n = scene.len();
    let k = scene.coeffs as usize;
    let grads = ctx.storage_items("parameter gradients", 4 * (PARAM_GRAD_STRIDE * n) as u64)?;
    let sh = ctx.storage_items("SH gradients", 4 * (3 * k * n) as u64)?;
    let mut enc = ctx.encoder();
    record_vjp(ctx, &mut enc, scene, cam, s, upstream, (&grads, &sh))?;
    ctx.submit(enc)?;
    let to_f32 = |w: Vec<u32>| w.into_iter().map(f32::from_bits).collect();
    Ok(ParamGradsGpu {
        params: to_f32(ctx.read_words(&grads, PARAM_GRAD_STRIDE * n)?),
        sh: to_f32(ctx.read_words(&sh, 3 * k * n)?),
        means2d: Vec::new(),
        visible: Vec::new(),
    })
}

/// Records `project_vjp.wgsl`: the screen-space gradients in `upstream` become the raw
/// parameters' gradients in `out` (`PARAM_GRAD_STRIDE` values per Gaussian, then the SH
/// gradients in the parameters' layout).
pub fn record_vjp(
    ctx: &GpuContext,
    enc: &mut crate::gpu::Encoder,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    upstream: &wgpu::Buffer,
    out: (&wgpu::Buffer, &wgpu::Buffer),
) -> Result<(), GpuError> {
    let grid = TileGrid::new(cam.width, cam.height);
    let k3 = 3 * u64::from(scene.coeffs);
    ctx.dispatch_items(
        enc,
        &ctx.kernels.project.project_vjp,
        (&camera_words(scene, cam, s, grid), CAMERA_COUNT_WORD),
        &[
            (1, &scene.means, 3),
            (2, &scene.scales, 3),
            (3, &scene.quats, 4),
            (4, &scene.logits, 1),
            (5, &scene.sh, k3),
            (6, upstream, SCREEN_GRAD_STRIDE as u64),
            (7, out.0, PARAM_GRAD_STRIDE as u64),
            (8, out.1, k3),
        ],
        scene.n,
        1,
    )
}

/// Records the compositing backward of one forward pass: `d_rgb` (dL/d(rgb), `H·W·3`) becomes
/// each Gaussian's screen-space gradient in `screen` ([`SCREEN_GRAD_STRIDE`] values per
/// Gaussian) — per-tile pair sums into `pair_grads` (`PAIR_STRIDE` values per pair, see
/// [`pair_buffer`]), then each Gaussian's pairs summed in tile order.
#[allow(clippy::too_many_arguments)]
pub fn record_backward(
    ctx: &GpuContext,
    enc: &mut crate::gpu::Encoder,
    st: &ForwardState,
    grid: TileGrid,
    d_rgb: &wgpu::Buffer,
    screen: &wgpu::Buffer,
    n: u32,
    pair_grads: &wgpu::Buffer,
) {
    let kr = &ctx.kernels;
    let (walk, splats) = walk_bindings(ctx, st, d_rgb);
    let mut ranged = splats;
    ranged.extend(pair_ranges(ctx, st, pair_grads));
    ctx.dispatch_mixed(
        enc,
        &kr.backward.rasterize_backward,
        &walk,
        ranged,
        [grid.tiles_x, grid.tiles_y],
    );
    let mut ranged = splat_ranges(ctx, st);
    ranged.extend(pair_ranges(ctx, st, pair_grads));
    ranged.extend(screen_ranges(ctx, st, screen));
    ctx.dispatch_mixed(
        enc,
        &kr.backward.gaussian_sums,
        &[
            (0, &st.params),
            (1, &st.rects),
            (2, &st.order),
            (3, &st.counts),
        ],
        ranged,
        ctx.groups(n.div_ceil(256)),
    );
}

/// The pair slots' four bindings ([`PAIR_BINDINGS`]) of the backward kernels.
fn pair_ranges<'a>(
    ctx: &GpuContext,
    st: &ForwardState,
    pair_grads: &'a wgpu::Buffer,
) -> Vec<(u32, wgpu::BindingResource<'a>)> {
    let pairs = u64::from(st.pairs);
    let r = ctx.split_ranges(pair_grads, pairs, PAIR_STRIDE, PAIR_BINDINGS.len());
    PAIR_BINDINGS.into_iter().zip(r).collect()
}

/// The screen-space gradients' two bindings (11 and 14) of the backward kernels.
fn screen_ranges<'a>(
    ctx: &GpuContext,
    st: &ForwardState,
    screen: &'a wgpu::Buffer,
) -> Vec<(u32, wgpu::BindingResource<'a>)> {
    let n = u64::from(st.gaussians);
    let r = ctx.split_ranges(screen, n, SCREEN_GRAD_STRIDE as u64, 2);
    [11, 14].into_iter().zip(r).collect()
}

/// The splats' two bindings (7 and 12) of the backward kernels.
fn splat_ranges<'a>(
    ctx: &GpuContext,
    st: &'a ForwardState,
) -> Vec<(u32, wgpu::BindingResource<'a>)> {
    let r = ctx.split_ranges(&st.splats, u64::from(st.gaussians), SPLAT_STRIDE, 2);
    [7, 12].into_iter().zip(r).collect()
}

/// The bindings both compositing backward kernels (`rasterize_backward` and its atomic
/// variant) read: the forward pass's lists and image and `d_rgb` at binding 9, whole; the
/// splats' two ranges.
#[allow(clippy::type_complexity)]
fn walk_bindings<'a>(
    ctx: &GpuContext,
    st: &'a ForwardState,
    d_rgb: &'a wgpu::Buffer,
) -> (
    Vec<(u32, &'a wgpu::Buffer)>,
    Vec<(u32, wgpu::BindingResource<'a>)>,
) {
    let whole = vec![
        (0, &*st.params),
        (2, &*st.order),
        (4, &*st.pair_rank),
        (5, &*st.sorted),
        (6, &*st.ranges),
        (8, &*st.image),
        (9, d_rgb),
    ];
    (whole, splat_ranges(ctx, st))
}

/// The pair buffer [`record_backward`] sums into, sized for a forward pass's pairs.
pub fn pair_buffer(ctx: &GpuContext, st: &ForwardState) -> Result<GpuBuffer, GpuError> {
    ctx.storage_split(
        "pair gradients",
        u64::from(st.pairs),
        PAIR_STRIDE,
        PAIR_BINDINGS.len(),
    )
}

/// The gradients of a loss on the colour image, on the GPU: renders `scene` from `cam` (the
/// forward kernels), walks every tile back to front for the pair sums, sums each Gaussian's
/// pairs in a fixed order and runs the projection and colour backward — the WGSL twin of
/// [`crate::backward()`] with `d_alpha` and `d_depth` absent. `d_rgb` holds dL/d(rgb),
/// `height·width·3` values. Deterministic: the same inputs give the same bytes on one
/// adapter (no atomics).
pub fn backward_gpu(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    d_rgb: &[f32],
) -> Result<ParamGradsGpu, GpuError> {
    backward_gpu_with_cutoff(ctx, scene, cam, s, d_rgb, Cutoff::Hard)
}

/// [`backward_gpu`] with a choice of alpha cutoff; `Cutoff::Smooth` exists only for the
/// finite-difference tests.
#[doc(hidden)]
pub fn backward_gpu_with_cutoff(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    d_rgb: &[f32],
    cutoff: Cutoff,
) -> Result<ParamGradsGpu, GpuError> {
    backward_whole(ctx, scene, cam, s, d_rgb, cutoff, Reduction::Ordered).map(|(g, _)| g)
}

/// [`backward_inner`] and a reclaim of its buffers (every encoder it recorded was submitted).
fn backward_whole(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    d_rgb: &[f32],
    cutoff: Cutoff,
    reduction: Reduction,
) -> Result<(ParamGradsGpu, BackwardStage), GpuError> {
    let out = backward_inner(ctx, scene, cam, s, d_rgb, cutoff, reduction);
    ctx.reclaim();
    out
}

/// [`backward_gpu`] with the per-Gaussian sums done by float atomics instead of ordered pair
/// slots (`backward/backward_atomic.wgsl`): each tile adds its share of a Gaussian's
/// screen-space gradient straight into the Gaussian's slot by a compare-exchange loop on the
/// bits, so there is no pair buffer and no second pass. It exists only to measure what the
/// determinism of [`backward_gpu`] costs (`examples/gpu_determinism_cost.rs`); nothing else
/// uses it. Not bit-reproducible by design on real GPUs: the order in which tiles add into a
/// Gaussian's slot depends on scheduling, so the gradients agree with [`backward_gpu`]'s only
/// up to f32 rounding, and two runs may differ in the last bits.
#[cfg(feature = "determinism-cost")]
#[doc(hidden)]
pub fn backward_gpu_atomic(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    d_rgb: &[f32],
) -> Result<ParamGradsGpu, GpuError> {
    backward_inner(ctx, scene, cam, s, d_rgb, Cutoff::Hard, Reduction::Atomic).map(|(g, _)| g)
}

/// What one [`backward_gpu_timed`] run spent in the stage where the two reductions differ.
#[doc(hidden)]
#[derive(Clone, Copy, Debug)]
pub struct BackwardStage {
    /// Number of (tile, Gaussian) pairs of the forward pass.
    pub pairs: u32,
    /// Wall time of the compositing backward's submission, from recording to the device's
    /// completion: `rasterize_backward` + `gaussian_sums` (deterministic), or the buffer
    /// clear + `rasterize_backward_atomic` (atomic). The forward pass before it and the
    /// projection backward and read-backs after it are the same for both and left out.
    pub kernels: std::time::Duration,
}

/// [`backward_gpu`] (`atomic` false) or [`backward_gpu_atomic`] (`atomic` true), with the
/// pair count and the time of the stage where they differ; for the determinism-cost example.
/// The atomic variant is built only with the `determinism-cost` feature (an error without).
#[doc(hidden)]
pub fn backward_gpu_timed(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    d_rgb: &[f32],
    atomic: bool,
) -> Result<(ParamGradsGpu, BackwardStage), GpuError> {
    let reduction = match atomic {
        false => Reduction::Ordered,
        #[cfg(feature = "determinism-cost")]
        true => Reduction::Atomic,
        #[cfg(not(feature = "determinism-cost"))]
        true => {
            return Err(GpuError::Invalid(
                "the float-atomic backward is built only with the `determinism-cost` feature"
                    .into(),
            ))
        }
    };
    backward_whole(ctx, scene, cam, s, d_rgb, Cutoff::Hard, reduction)
}

/// How the compositing backward sums each Gaussian's per-tile shares.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Reduction {
    /// Into the pairs' own slots, then per Gaussian in tile order (`backward.wgsl`).
    Ordered,
    /// Straight into the Gaussian's slot by float atomic adds (`backward_atomic.wgsl`).
    #[cfg(feature = "determinism-cost")]
    Atomic,
}

/// The forward kernels, the compositing backward with `reduction`, the projection backward
/// and the read-backs; with the pair count and the compositing backward's wall time.
fn backward_inner(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    d_rgb: &[f32],
    cutoff: Cutoff,
    reduction: Reduction,
) -> Result<(ParamGradsGpu, BackwardStage), GpuError> {
    let grid = crate::forward::gpu::tile_grid(cam)?;
    let pixels = cam.width as usize * cam.height as usize;
    if d_rgb.len() != 3 * pixels {
        return Err(GpuError::Invalid(format!(
            "{} colour gradient values for a {}×{} image (need {})",
            d_rgb.len(),
            cam.width,
            cam.height,
            3 * pixels
        )));
    }
    ctx.scoped(|| {
        let st = forward_pass(ctx, scene, cam, s, grid, cutoff, None)?;
        let (count_buf, count_at) = st.pair_count_at();
        let count = ctx.read_after(ctx.encoder(), &[(count_buf, count_at, 1)])?[0][0];
        st.check_count(ctx, count)?;
        let n = scene.len() as u64;
        let g_rgb = ctx.storage_init("colour gradients", &f32_words(d_rgb.iter().copied()))?;
        let screen =
            ctx.storage_split("screen-space gradients", n, SCREEN_GRAD_STRIDE as u64, 2)?;
        // Allocated before the clock starts: the timed stage is the kernels alone.
        let pair_grads = match reduction {
            Reduction::Ordered => Some(pair_buffer(ctx, &st)?),
            #[cfg(feature = "determinism-cost")]
            Reduction::Atomic => None,
        };
        // The forward's work done before the clock starts.
        ctx.wait()?;
        let started = std::time::Instant::now();
        let mut enc = ctx.encoder();
        if let Some(pair_grads) = &pair_grads {
            record_backward(
                ctx, &mut enc, &st, grid, &g_rgb, &screen, n as u32, pair_grads,
            );
        } else {
            #[cfg(feature = "determinism-cost")]
            {
                enc.clear_buffer(&screen, 0, None);
                let (walk, mut ranged) = walk_bindings(ctx, &st, &g_rgb);
                ranged.extend(screen_ranges(ctx, &st, &screen));
                ctx.dispatch_mixed(
                    &mut enc,
                    &ctx.kernels.backward.rasterize_backward_atomic,
                    &walk,
                    ranged,
                    [grid.tiles_x, grid.tiles_y],
                );
            }
        }
        ctx.submit(enc)?;
        let stage = BackwardStage {
            pairs: st.pairs,
            kernels: started.elapsed(),
        };
        let mut out = vjp_inner(ctx, scene, cam, s, &screen)?;
        let nn = n as usize;
        let sg = ctx.read_words(&screen, SCREEN_GRAD_STRIDE * nn)?;
        let (hw, hh) = (0.5 * cam.width as f32, 0.5 * cam.height as f32);
        out.means2d = sg
            .chunks_exact(SCREEN_GRAD_STRIDE)
            .map(|c| [f32::from_bits(c[0]) * hw, f32::from_bits(c[1]) * hh])
            .collect();
        out.visible = ctx
            .read_words(&st.rects, 4 * nn)?
            .chunks_exact(4)
            .map(|m| m[2] > 0)
            .collect();
        Ok((out, stage))
    })
}

/// f32 values per pair slot of `backward.wgsl`.
pub const PAIR_STRIDE: u64 = 10;

/// The bindings of the pair slots' four ranges in `backward.wgsl` (a 5M-Gaussian 1080p
/// step has about 10M pairs: 400 MB of slots).
const PAIR_BINDINGS: [u32; 4] = [10, 13, 15, 16];

/// The compiled backward kernels (`backward.wgsl`; with the `determinism-cost` feature also
/// the float-atomic variant that measures what the fixed order costs).
pub(crate) struct Kernels {
    rasterize_backward: wgpu::ComputePipeline,
    gaussian_sums: wgpu::ComputePipeline,
    #[cfg(feature = "determinism-cost")]
    rasterize_backward_atomic: wgpu::ComputePipeline,
}

impl Kernels {
    pub(crate) fn new(m: crate::gpu::ModuleSetup<'_>) -> Kernels {
        let [rasterize_backward, gaussian_sums] = crate::gpu::pipelines(
            m,
            "backward.wgsl",
            include_str!("backward.wgsl"),
            ["rasterize_backward", "gaussian_sums"],
        );
        #[cfg(feature = "determinism-cost")]
        let [rasterize_backward_atomic] = crate::gpu::pipelines(
            m,
            "backward_atomic.wgsl",
            include_str!("backward_atomic.wgsl"),
            ["rasterize_backward_atomic"],
        );
        Kernels {
            rasterize_backward,
            gaussian_sums,
            #[cfg(feature = "determinism-cost")]
            rasterize_backward_atomic,
        }
    }
}
