//! Host side of the GPU forward pass: uploads, the kernel sequence, read-back.

use crate::constants::{JACOBIAN_CLAMP_MARGIN, TILE};
use crate::gpu::{f32_words, GpuBuffer, GpuContext, GpuError};
use crate::render::{Cutoff, RenderSettings, RenderStats};
use crate::tiles::TileGrid;
use crate::Gaussians;
use augsplat_core::Camera;

/// f32 words per splat record (`project.wgsl`).
pub const SPLAT_STRIDE: u64 = 12;
/// f32 words per pixel of the image buffer (`forward.wgsl`): r, g, b, alpha, depth, T, the
/// bits of the last contributor's position.
pub const IMAGE_STRIDE: usize = 7;
/// Gaussians per projection workgroup.
const GROUP: u32 = 256;
/// The pair count (`counts[gaussians]`, [`ForwardState::pair_count_at`]) a forward pass
/// leaves when one of its tiles holds more pairs than [`tile_pair_cap`] allows: no pass has
/// that many pairs. [`ForwardState::check_count`] turns it into an error.
pub const TILES_PAST_LOOP_CAP: u32 = u32::MAX;

/// The most (tile, Gaussian) pairs one tile may hold on `adapter`, 0 where nothing caps it:
/// where a driver caps an invocation's loop iterations
/// ([`crate::gpu::AdapterSummary::loop_cap`]), the compositor and its backward run one
/// iteration a pair of a tile and a few a batch of 256, so a tile may hold 15/16 of the cap.
pub fn tile_pair_cap(adapter: &crate::gpu::AdapterSummary) -> u32 {
    adapter.loop_cap().map_or(0, |cap| cap / 16 * 15)
}

/// The error of a forward pass one of whose tiles passed [`tile_pair_cap`]: its pixels would
/// have been cut short.
pub fn past_loop_cap_error(adapter: &crate::gpu::AdapterSummary) -> GpuError {
    GpuError::Invalid(format!(
        "a tile of this view holds more than {} (tile, Gaussian) pairs, more than {} lets a \
         shader run through (it ends an invocation's loops after {} iterations): render with \
         backend: Cpu, or on a hardware GPU",
        tile_pair_cap(adapter),
        adapter.name,
        adapter.loop_cap().unwrap_or(0)
    ))
}

/// One GPU render: the image planes of [`crate::RenderOutput`] and its counters.
#[derive(Clone, Debug, PartialEq)]
pub struct GpuFrame {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Colour, `height·width·3` interleaved, background composited.
    pub rgb: Vec<f32>,
    /// Accumulated alpha `1 − T`.
    pub alpha: Vec<f32>,
    /// Expected depth normalised by alpha (0 where alpha < 1e-6).
    pub depth: Vec<f32>,
    /// Final transmittance T per pixel.
    pub transmittance: Vec<f32>,
    /// Per pixel, the 1-based position in its tile's list of the last Gaussian composited
    /// (0: none).
    pub last: Vec<u32>,
    /// Counters, as the CPU renderer counts them.
    pub stats: RenderStats,
}

/// A set of Gaussians uploaded to the GPU once, to render from many cameras.
pub struct GpuScene {
    /// Number of Gaussians.
    pub n: u32,
    /// SH coefficients per channel.
    pub coeffs: u32,
    /// The stored SH degree.
    pub sh_degree: u32,
    /// Means, 3 f32 per Gaussian.
    pub means: GpuBuffer,
    /// Log-scales, 3 f32 per Gaussian.
    pub scales: GpuBuffer,
    /// Raw quaternions, 4 f32 per Gaussian.
    pub quats: GpuBuffer,
    /// Opacity logits, 1 f32 per Gaussian.
    pub logits: GpuBuffer,
    /// SH coefficients, `3·coeffs` f32 per Gaussian.
    pub sh: GpuBuffer,
}

impl GpuScene {
    /// Uploads `g` (checked for consistent array sizes and the adapter's buffer limits).
    pub fn upload(ctx: &GpuContext, g: &Gaussians) -> Result<GpuScene, GpuError> {
        let n = g.len();
        let k = g.coeffs();
        if g.log_scales.len() != n || g.quats.len() != n || g.opacity_logits.len() != n {
            return Err(GpuError::Invalid(format!(
                "inconsistent Gaussian arrays: {n} means, {} scales, {} quaternions, {} opacities",
                g.log_scales.len(),
                g.quats.len(),
                g.opacity_logits.len()
            )));
        }
        if g.sh.len() != n * k * 3 {
            return Err(GpuError::Invalid(format!(
                "{} SH values for {n} Gaussians of degree {}",
                g.sh.len(),
                g.sh_degree
            )));
        }
        let n32 = u32::try_from(n)
            .ok()
            .filter(|&v| v < u32::MAX / 16)
            .ok_or_else(|| {
                GpuError::Invalid(format!("{n} Gaussians are too many for one render"))
            })?;
        ctx.scoped(|| {
            Ok(GpuScene {
                n: n32,
                coeffs: k as u32,
                sh_degree: g.sh_degree,
                means: ctx
                    .storage_items_init("means", &f32_words(g.means.iter().flatten().copied()))?,
                scales: ctx.storage_items_init(
                    "log-scales",
                    &f32_words(g.log_scales.iter().flatten().copied()),
                )?,
                quats: ctx.storage_items_init(
                    "quaternions",
                    &f32_words(g.quats.iter().flatten().copied()),
                )?,
                logits: ctx.storage_items_init(
                    "opacity logits",
                    &f32_words(g.opacity_logits.iter().copied()),
                )?,
                sh: ctx.storage_items_init("SH coefficients", &f32_words(g.sh.iter().copied()))?,
            })
        })
    }
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.n as usize
    }
    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
}

/// The word of [`camera_words`] that holds the number of Gaussians (`cam.counts.x`).
pub const CAMERA_COUNT_WORD: usize = 28;

/// The camera uniform of `project.wgsl`.
pub fn camera_words(g: &GpuScene, cam: &Camera, s: &RenderSettings, grid: TileGrid) -> Vec<u32> {
    let (r, t) = augsplat_core::linalg::rt_from_mat4(&cam.world_to_camera);
    let centre = cam.center();
    let (wd, ht) = (f64::from(cam.width), f64::from(cam.height));
    let tan_x = 0.5 * wd / cam.fx;
    let tan_y = 0.5 * ht / cam.fy;
    let f = |v: f64| (v as f32).to_bits();
    let mut w = Vec::with_capacity(36);
    for i in 0..3 {
        w.extend([f(r[i][0]), f(r[i][1]), f(r[i][2]), f(t[i])]);
    }
    w.extend([f(cam.fx), f(cam.fy), f(cam.cx), f(cam.cy)]);
    w.extend([
        f((wd - cam.cx) / cam.fx + JACOBIAN_CLAMP_MARGIN * tan_x),
        f(cam.cx / cam.fx + JACOBIAN_CLAMP_MARGIN * tan_x),
        f((ht - cam.cy) / cam.fy + JACOBIAN_CLAMP_MARGIN * tan_y),
        f(cam.cy / cam.fy + JACOBIAN_CLAMP_MARGIN * tan_y),
    ]);
    w.extend([f(centre[0]), f(centre[1]), f(centre[2]), s.near.to_bits()]);
    w.extend([cam.width, cam.height, grid.tiles_x, grid.tiles_y]);
    w.extend([
        g.n,
        g.coeffs,
        s.sh_degree.min(g.sh_degree),
        u32::from(s.antialiased),
    ]);
    w.extend([s.max_alpha.to_bits(), 0, 0, 0]);
    w
}

/// Renders `g` from `cam` on the GPU: the same projection, binning and compositing as
/// [`crate::render()`], in f32 (the tests hold images to the CPU's within 1e-4; they agree to
/// about 5e-7). Uploads `g` first; to render one set from many cameras, upload it once with
/// [`GpuScene::upload`] and call [`render_scene`].
pub fn render_gpu(
    ctx: &GpuContext,
    g: &Gaussians,
    cam: &Camera,
    s: &RenderSettings,
) -> Result<GpuFrame, GpuError> {
    let scene = GpuScene::upload(ctx, g)?;
    render_scene(ctx, &scene, cam, s)
}

/// Renders an uploaded set from `cam` (see [`render_gpu`]).
pub fn render_scene(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
) -> Result<GpuFrame, GpuError> {
    render_scene_with_cutoff(ctx, scene, cam, s, Cutoff::Hard)
}

/// [`render_scene`] with a choice of alpha cutoff; `Cutoff::Smooth` exists only for the
/// finite-difference tests (as [`crate::render_with_cutoff`]).
#[doc(hidden)]
pub fn render_scene_with_cutoff(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    cutoff: Cutoff,
) -> Result<GpuFrame, GpuError> {
    render_whole(ctx, scene, cam, s, cutoff, None)
}

/// [`render_scene`] with a pixel mask, as [`crate::render_masked`]: pixels whose mask value is
/// 0 are neither composited nor back-propagated (background, alpha 0, depth 0); a mask of
/// the wrong length is ignored (all ones).
pub fn render_scene_masked(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    mask: Option<&[u8]>,
) -> Result<GpuFrame, GpuError> {
    render_whole(ctx, scene, cam, s, Cutoff::Hard, mask)
}

/// A pixel mask as the rasteriser reads it (one word per pixel), when `mask` holds one value
/// for each of `pixels` pixels (otherwise none: a mask of the wrong length is ignored, as on
/// the CPU).
pub fn upload_mask(
    ctx: &GpuContext,
    pixels: usize,
    mask: Option<&[u8]>,
) -> Result<Option<GpuBuffer>, GpuError> {
    match mask.filter(|m| m.len() == pixels) {
        Some(m) => {
            let words: Vec<u32> = m.iter().map(|&v| u32::from(v != 0)).collect();
            Ok(Some(ctx.storage_init("pixel mask", &words)?))
        }
        None => Ok(None),
    }
}

/// A whole render: the forward pass, the read-back, and a reclaim of its buffers.
fn render_whole(
    ctx: &GpuContext,
    scene: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    cutoff: Cutoff,
    mask: Option<&[u8]>,
) -> Result<GpuFrame, GpuError> {
    let grid = tile_grid(cam)?;
    let frame = ctx.scoped(|| {
        let mask = upload_mask(ctx, cam.width as usize * cam.height as usize, mask)?;
        render_inner(ctx, scene, cam, s, grid, cutoff, mask.as_deref())
    });
    // Every encoder of the render was submitted: its buffers are free for the next one.
    ctx.reclaim();
    frame
}

/// The tile grid of a valid camera, within the kernels' rectangle encoding (65535 tiles per
/// axis); the one check every GPU entry point makes on its camera.
pub fn tile_grid(cam: &Camera) -> Result<TileGrid, GpuError> {
    cam.validate()
        .map_err(|e| GpuError::Invalid(format!("camera: {e}")))?;
    let grid = TileGrid::new(cam.width, cam.height);
    if grid.tiles_x > 0xffff || grid.tiles_y > 0xffff {
        return Err(GpuError::Invalid(format!(
            "{}×{} tiles exceed the rectangle encoding (65535 per axis)",
            grid.tiles_x, grid.tiles_y
        )));
    }
    Ok(grid)
}

/// The buffers of one forward pass that the backward pass reads again.
pub struct ForwardState {
    /// Number of Gaussians.
    pub gaussians: u32,
    /// Number of (tile, Gaussian) pair slots: the pairs, or more when the pass was sized
    /// ahead of its count ([`forward_pass_in`]).
    pub pairs: u32,
    /// The forward kernels' parameters (with `pairs`).
    pub params: GpuBuffer,
    /// Per Gaussian: tile rectangle, tile count, status.
    pub rects: GpuBuffer,
    /// Rank → Gaussian.
    pub order: GpuBuffer,
    /// Per rank: the offset of its pairs (exclusive scan of tile counts).
    pub counts: GpuBuffer,
    /// Per emit position: the pair's rank.
    pub pair_rank: GpuBuffer,
    /// Emit positions in (tile, rank) order.
    pub sorted: GpuBuffer,
    /// Per tile: [start, end) in `sorted`.
    pub ranges: GpuBuffer,
    /// Screen-space splats by Gaussian.
    pub splats: GpuBuffer,
    /// The image (`IMAGE_STRIDE` words per pixel).
    pub image: GpuBuffer,
    /// Per pixel: last contributor, composited pairs.
    pub info: GpuBuffer,
}

impl ForwardState {
    /// Where the pass's pair count sits on the device (`counts[gaussians]`): read it after the
    /// pass, in a read-back the caller makes anyway, and compare with [`Self::pairs`].
    pub fn pair_count_at(&self) -> (&wgpu::Buffer, u64) {
        (&self.counts, u64::from(self.gaussians))
    }

    /// Whether a pass sized ahead had more pairs (`count`, read at
    /// [`Self::pair_count_at`]) than slots: its image and lists are then wrong.
    pub fn overflowed_in(&self, count: u32) -> bool {
        count > self.pairs
    }

    /// [`past_loop_cap_error`] when `count` (read at [`Self::pair_count_at`]) says one of the
    /// pass's tiles passed the adapter's loop cap ([`TILES_PAST_LOOP_CAP`]).
    pub fn check_count(&self, ctx: &GpuContext, count: u32) -> Result<(), GpuError> {
        if count == TILES_PAST_LOOP_CAP {
            return Err(past_loop_cap_error(ctx.adapter()));
        }
        Ok(())
    }
}

/// Where [`record_projection`] writes, per Gaussian: its splat ([`SPLAT_STRIDE`] words:
/// mean2d, conic, opacity, colour, depth), its tile rectangle (4 words: packed x and y
/// ranges, tile count, status — 0 visible, 1 culled, 2 invalid) and its depth sort key.
#[derive(Clone, Copy)]
pub struct Projection<'a> {
    /// [`SPLAT_STRIDE`] f32 words per Gaussian.
    pub splats: &'a wgpu::Buffer,
    /// 4 u32 words per Gaussian.
    pub rects: &'a wgpu::Buffer,
    /// 1 u32 word per Gaussian (0xffffffff when culled).
    pub keys: &'a wgpu::Buffer,
}

/// Records the projection (`project.wgsl`) of every Gaussian of `g` with the opacity logits
/// `logits` (the scene's own, or another array of one logit per Gaussian) from the camera
/// `camera_w` ([`camera_words`]), in as few dispatches as the binding limit allows.
pub fn record_projection(
    ctx: &GpuContext,
    enc: &mut crate::gpu::Encoder,
    g: &GpuScene,
    logits: &wgpu::Buffer,
    camera_w: &[u32],
    out: Projection<'_>,
) -> Result<(), GpuError> {
    ctx.dispatch_items(
        enc,
        &ctx.kernels.project.project,
        (camera_w, CAMERA_COUNT_WORD),
        &[
            (1, &g.means, 3),
            (2, &g.scales, 3),
            (3, &g.quats, 4),
            (4, logits, 1),
            (5, &g.sh, 3 * u64::from(g.coeffs)),
            (6, out.splats, SPLAT_STRIDE),
            (7, out.rects, 4),
            (8, out.keys, 1),
        ],
        g.n,
        1,
    )
}

/// Runs the forward kernels and keeps their buffers (one wait, for the number of pairs).
#[allow(clippy::too_many_arguments)]
pub fn forward_pass(
    ctx: &GpuContext,
    g: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    grid: TileGrid,
    cutoff: Cutoff,
    mask: Option<&wgpu::Buffer>,
) -> Result<ForwardState, GpuError> {
    forward_pass_in(ctx, g, cam, s, grid, cutoff, mask, None)
}

/// [`forward_pass`] with `slots` (tile, Gaussian) pair slots when given, so that nothing
/// waits: the pass is recorded and kept for the next submission ([`GpuContext::defer`]). When the pairs exceed the slots
/// (`counts[gaussians]` > `slots`, see [`ForwardState::overflowed_in`]) the pass is wrong and
/// must be discarded; otherwise its bytes are those of [`forward_pass`] (unused slots sort
/// first and belong to no tile). With `None`, the pairs are counted first (one wait) and the
/// slots are exactly the pairs.
#[allow(clippy::too_many_arguments)]
pub fn forward_pass_in(
    ctx: &GpuContext,
    g: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    grid: TileGrid,
    cutoff: Cutoff,
    mask: Option<&wgpu::Buffer>,
    slots: Option<u32>,
) -> Result<ForwardState, GpuError> {
    if s.opacity_scale.is_some() {
        return Err(GpuError::Invalid(
            "per-Gaussian opacity factors (DropGaussian) are rendered on the CPU only: use the CPU backend".into(),
        ));
    }
    let n = g.n;
    let nn = u64::from(n);
    let kr = &ctx.kernels;
    let camera_w = camera_words(g, cam, s, grid);
    let splats = ctx.storage_split("splats", nn, SPLAT_STRIDE, 2)?;
    let meta = ctx.storage("tile rectangles", 16 * nn)?;
    let keys = ctx.storage("depth keys", 4 * nn)?;
    // Written by the sort's first pass (the indices need no upload).
    let vals = ctx.storage_overwritten("Gaussian order", 4 * nn)?;
    let keys2 = ctx.storage("depth keys (scratch)", 4 * nn)?;
    let vals2 = ctx.storage("Gaussian order (scratch)", 4 * nn)?;
    let counts = ctx.storage("tile counts", 4 * (nn + 1))?;

    // Project, sort by (depth, index), count each rank's tiles and scan them.
    let mut enc = ctx.encoder();
    record_projection(
        ctx,
        &mut enc,
        g,
        &g.logits,
        &camera_w,
        Projection {
            splats: &splats,
            rects: &meta,
            keys: &keys,
        },
    )?;
    let (_, sorted_order) =
        ctx.record_sort_indices(&mut enc, &keys, &vals, (&keys2, &vals2), n, 32)?;
    let order_in_vals = std::ptr::eq(sorted_order, &*vals);
    let order = if order_in_vals { vals } else { vals2 };
    let pixels = u64::from(cam.width) * u64::from(cam.height);
    let fwd_params = |pairs: u32| {
        let mut w = vec![
            n,
            pairs,
            grid.tiles_x,
            grid.tiles_y,
            cam.width,
            cam.height,
            crate::forward::effective_max_alpha(s).to_bits(),
            u32::from(cutoff == Cutoff::Smooth),
        ];
        w.extend(f32_words(s.background));
        w.push(0);
        // Where the splats and the backward's screen-space gradients switch to their second
        // binding, and its pair slots to their second, third and fourth.
        w.extend(ctx.split_points(nn, SPLAT_STRIDE, 2));
        w.extend(ctx.split_points(nn, crate::backward::gpu::SCREEN_GRAD_STRIDE as u64, 2));
        w.extend([u32::from(mask.is_some()), tile_pair_cap(ctx.adapter())]);
        w.extend(ctx.split_points(u64::from(pairs), crate::backward::gpu::PAIR_STRIDE, 4));
        w.push(0);
        w
    };
    let params0 = ctx.uniform("forward params", &fwd_params(0));
    ctx.dispatch(
        &mut enc,
        &kr.forward.gather_counts,
        &[(0, &params0), (1, &meta), (2, &order), (3, &counts)],
        ctx.groups(n.div_ceil(GROUP)),
    );
    ctx.record_scan(&mut enc, &counts, n + 1)?;
    // The number of (tile, Gaussian) pairs: the exclusive sum at n (counts[n] was zero).
    let (pairs, mut enc) = match slots {
        Some(slots) => (slots, enc),
        None => (
            ctx.read_after(enc, &[(&counts, u64::from(n), 1)])?[0][0],
            ctx.encoder(),
        ),
    };

    // Emit the pairs in rank order, sort them by tile (stable: ranks stay ascending), find
    // each tile's range and composite.
    let np = u64::from(pairs);
    let tile_keys = ctx.storage("pair tiles", 4 * np)?;
    let pair_vals = ctx.storage("pair emit positions", 4 * np)?;
    let pair_rank = ctx.storage("pair ranks", 4 * np)?;
    let tile_keys2 = ctx.storage("pair tiles (scratch)", 4 * np)?;
    let pair_vals2 = ctx.storage("pair emit positions (scratch)", 4 * np)?;
    let ranges = ctx.storage("tile ranges", 8 * grid.len() as u64)?;
    let image = ctx.storage("image", 4 * IMAGE_STRIDE as u64 * pixels)?;
    let info = ctx.storage("pixel info", 8 * pixels)?;
    let params = ctx.uniform("forward params", &fwd_params(pairs));
    ctx.dispatch(
        &mut enc,
        &kr.forward.emit_pairs,
        &[
            (0, &params),
            (1, &meta),
            (2, &order),
            (3, &counts),
            (4, &tile_keys),
            (5, &pair_vals),
            (10, &pair_rank),
        ],
        ctx.groups(n.div_ceil(GROUP)),
    );
    // Keys run to tiles (a tile's key is its index + 1, 0 an unused slot).
    let tile_bits = u32::BITS - (grid.len() as u32).leading_zeros();
    let (sorted_tiles, sorted_pairs) = ctx.record_sort(
        &mut enc,
        &tile_keys,
        &pair_vals,
        (&tile_keys2, &pair_vals2),
        pairs,
        tile_bits,
    )?;
    enc.clear_buffer(&ranges, 0, None);
    ctx.dispatch(
        &mut enc,
        &kr.forward.tile_ranges,
        &[(0, &params), (4, sorted_tiles), (6, &ranges)],
        ctx.groups(pairs.div_ceil(GROUP)),
    );
    let splat_ranges = ctx.split_ranges(&splats, nn, SPLAT_STRIDE, 2);
    let no_mask;
    let mask = match mask {
        Some(m) => m,
        None => {
            no_mask = ctx.storage("no pixel mask", 16)?;
            &*no_mask
        }
    };
    ctx.dispatch_mixed(
        &mut enc,
        &kr.forward.rasterize,
        &[
            (0, &params),
            (2, &order),
            (3, &counts),
            (5, sorted_pairs),
            (6, &ranges),
            (8, &image),
            (9, &info),
            (10, &pair_rank),
            (12, mask),
        ],
        [7, 11].into_iter().zip(splat_ranges).collect(),
        [grid.tiles_x, grid.tiles_y],
    );
    // The image stays on the GPU until a caller reads it (after its own work, one wait). A
    // pass sized ahead waits for the next submission with the caller's work on it.
    match slots {
        Some(_) => ctx.defer(enc)?,
        None => ctx.submit_no_wait(enc)?,
    }
    let sorted_in_first = std::ptr::eq(sorted_pairs, &*pair_vals);
    let sorted = if sorted_in_first {
        pair_vals
    } else {
        pair_vals2
    };
    Ok(ForwardState {
        gaussians: n,
        pairs,
        params,
        rects: meta,
        order,
        counts,
        pair_rank,
        sorted,
        ranges,
        splats,
        image,
        info,
    })
}

#[allow(clippy::too_many_arguments)]
fn render_inner(
    ctx: &GpuContext,
    g: &GpuScene,
    cam: &Camera,
    s: &RenderSettings,
    grid: TileGrid,
    cutoff: Cutoff,
    mask: Option<&wgpu::Buffer>,
) -> Result<GpuFrame, GpuError> {
    let n = g.n;
    let st = forward_pass(ctx, g, cam, s, grid, cutoff, mask)?;
    let (image, info, meta) = (&st.image, &st.info, &st.rects);
    let pixels = u64::from(cam.width) * u64::from(cam.height);
    // Read back.
    let px = pixels as usize;
    let (count_buf, count_at) = st.pair_count_at();
    let mut words = ctx.read_after(
        ctx.encoder(),
        &[
            (count_buf, count_at, 1),
            (image, 0, IMAGE_STRIDE * px),
            (info, 0, 2 * px),
            (meta, 0, 4 * n as usize),
        ],
    )?;
    st.check_count(ctx, words[0][0])?;
    let status = words.pop().unwrap_or_default();
    let inf = words.pop().unwrap_or_default();
    let img = words.pop().unwrap_or_default();
    let mut frame = GpuFrame {
        width: cam.width,
        height: cam.height,
        rgb: Vec::with_capacity(3 * px),
        alpha: Vec::with_capacity(px),
        depth: Vec::with_capacity(px),
        transmittance: Vec::with_capacity(px),
        last: Vec::with_capacity(px),
        stats: RenderStats::default(),
    };
    for p in img.chunks_exact(IMAGE_STRIDE) {
        frame.rgb.extend(p[..3].iter().map(|w| f32::from_bits(*w)));
        frame.alpha.push(f32::from_bits(p[3]));
        frame.depth.push(f32::from_bits(p[4]));
        frame.transmittance.push(f32::from_bits(p[5]));
    }
    for p in inf.chunks_exact(2) {
        frame.last.push(p[0]);
        frame.stats.pairs += u64::from(p[1]);
    }
    for m in status.chunks_exact(4) {
        match m[3] {
            0 => frame.stats.visible += 1,
            1 => frame.stats.culled += 1,
            _ => frame.stats.invalid += 1,
        }
    }
    debug_assert_eq!(TILE, 16);
    Ok(frame)
}

/// The compiled forward kernels (`forward.wgsl`): tile binning and compositing.
pub(crate) struct Kernels {
    gather_counts: wgpu::ComputePipeline,
    emit_pairs: wgpu::ComputePipeline,
    tile_ranges: wgpu::ComputePipeline,
    rasterize: wgpu::ComputePipeline,
}

impl Kernels {
    pub(crate) fn new(m: crate::gpu::ModuleSetup<'_>) -> Kernels {
        let [gather_counts, emit_pairs, tile_ranges, rasterize] = crate::gpu::pipelines(
            m,
            "forward.wgsl",
            include_str!("forward.wgsl"),
            ["gather_counts", "emit_pairs", "tile_ranges", "rasterize"],
        );
        Kernels {
            gather_counts,
            emit_pairs,
            tile_ranges,
            rasterize,
        }
    }
}
