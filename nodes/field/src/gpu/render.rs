//! Rendering a field on the GPU: forward only, many views per pass. Rays march through the
//! occupancy grid (empty cells give no samples), the density network runs on every marched
//! sample, each ray composites up to the sample after which its transmittance falls below the
//! cut-off, and only the samples before it whose weight reaches
//! [`RENDER_MIN_COLOR_WEIGHT`] are compacted (prefix sum) and go through the colour network —
//! the CPU renderer's maths ([`crate::render::render_camera`]), including its opacity and
//! depth sums over the kept samples.
//!
//! A pass holds up to [`SAMPLE_BUDGET`] samples: the rays of consecutive views are batched
//! until their samples would pass it. Each pass waits twice: for its sample count and for its
//! pixels.

use super::*;
use crate::render::{RenderStats, RenderedImage};
use augsplat_core::Camera;

/// Rays of the first pass of a render (later passes are sized from the samples per ray seen).
const FIRST_PASS_RAYS: usize = 1 << 14;

/// Most rays in one pass.
const MAX_PASS_RAYS: usize = 1 << 18;

/// A field's state on the GPU, ready to render.
pub struct GpuFieldRef<'a> {
    /// The architecture.
    pub field: &'a Field,
    /// All parameters.
    pub params: &'a wgpu::Buffer,
    /// Occupancy flags (u32 per cell).
    pub occupied: &'a wgpu::Buffer,
    /// The mean appearance embedding (see [`mean_embedding_buffer`]).
    pub mean_emb: &'a wgpu::Buffer,
}

/// What one ray rendered.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RayPixel {
    /// Colour over the background.
    pub rgb: [f32; 3],
    /// Opacity.
    pub acc: f32,
    /// `Σ w t` (divide by the opacity for the expected distance).
    pub depth: f32,
    /// Marching steps.
    pub steps: u32,
    /// Samples in occupied cells.
    pub marched: u32,
    /// Samples through the density network (segments up to the transmittance cut-off).
    pub density: u32,
    /// Samples through the colour network.
    pub color: u32,
}

impl RayPixel {
    /// The ray's counters.
    pub fn stats(&self) -> RenderStats {
        RenderStats {
            steps: u64::from(self.steps),
            marched: u64::from(self.marched),
            density: u64::from(self.density),
            color: u64::from(self.color),
        }
    }
}

/// Renders ray records (`field.wgsl`) in passes; returns each ray's pixel.
pub fn render_rays_gpu(
    ctx: &GpuContext,
    model: &GpuFieldRef<'_>,
    rays: &[[f32; RAY_FLOATS]],
) -> Result<Vec<RayPixel>, GpuError> {
    let mut out = Vec::with_capacity(rays.len());
    let mut batch = FIRST_PASS_RAYS;
    let mut at = 0;
    while at < rays.len() {
        let end = (at + batch).min(rays.len());
        match render_pass(ctx, model, &rays[at..end])? {
            Some(pixels) => {
                // Size the next pass from this one's samples per ray.
                let marched: u64 = pixels.iter().map(|p| u64::from(p.marched)).sum();
                let per_ray = (marched as f64 / (end - at) as f64).max(1.0);
                batch = ((sample_budget(ctx, model.field) as f64 / per_ray * 0.9) as usize)
                    .clamp(64, MAX_PASS_RAYS);
                out.extend(pixels);
                at = end;
            }
            None => batch = (end - at).div_ceil(2),
        }
    }
    Ok(out)
}

/// Evaluates the density network segment by segment (16, 32, 64, then 128 samples of every
/// ray still going, as [`crate::field::Field`]'s renderer does) until each ray's transmittance
/// falls below the cut-off or its samples run out: one wait per round, for the round's sample
/// count. Records nothing more after `enc` (which it submits). Returns the network's output for
/// every evaluated sample (`1 + GEO_FEAT_DIM` rows of the pass's stride) and the rays' state
/// (`field.wgsl`'s `ray_state`).
fn record_densities_until_termination(
    ctx: &GpuContext,
    model: &GpuFieldRef<'_>,
    marched: &Marched,
    n_rays: u32,
    mut enc: augsplat_render::gpu::Encoder,
) -> Result<(GpuBuffer, GpuBuffer), GpuError> {
    let field = model.field;
    let k = kernels(ctx)?;
    let ld = marched.ld;
    let dout = ctx.storage(
        "density outputs",
        4 * (1 + GEO_FEAT_DIM as u64) * u64::from(ld),
    )?;
    let state = ctx.storage("ray march state", 16 * u64::from(n_rays.max(1)))?;
    let counts = ctx.storage("segment offsets", 4 * (u64::from(n_rays) + 1))?;
    let [px, py, pz] = marched.points.buffers();
    for round in 0u32.. {
        let settings = PassSettings {
            n_rays,
            ld,
            n: marched.n,
            mode: 16 << round.min(3),
            first: round,
            ..Default::default()
        };
        let u = ctx.uniform("field params", &field_words(field, settings));
        ctx.dispatch(
            &mut enc,
            &k.seg_count,
            &[(0, &u), (3, &marched.starts), (23, &state), (24, &counts)],
            ctx.groups(n_rays.div_ceil(256)),
        );
        ctx.record_scan(&mut enc, &counts, n_rays + 1)?;
        let m = ctx.read_after(enc, &[(&counts, u64::from(n_rays), 1)])?[0][0];
        enc = ctx.encoder();
        if m == 0 {
            break;
        }
        let ldm = batch_stride(m);
        let column = |what: &str| ctx.storage(what, 4 * u64::from(ldm));
        let (idx, gx, gy, gz) = (
            column("segment samples")?,
            column("segment x")?,
            column("segment y")?,
            column("segment z")?,
        );
        ctx.dispatch(
            &mut enc,
            &k.seg_gather,
            &[
                (0, &u),
                (4, px),
                (5, py),
                (6, pz),
                (23, &state),
                (24, &counts),
                (25, &idx),
                (28, &gx),
                (29, &gy),
                (30, &gz),
            ],
            ctx.groups(n_rays.div_ceil(256)),
        );
        let points = GpuPoints::from_buffers(gx, gy, gz, m as usize, ldm as usize)?;
        let dens = record_density(ctx, &mut enc, field, model.params, &points, ldm, m)?;
        let scatter = PassSettings {
            ld,
            n: m,
            first: ldm,
            ..Default::default()
        };
        let u2 = ctx.uniform("field params", &field_words(field, scatter));
        ctx.dispatch(
            &mut enc,
            &k.seg_scatter,
            &[(0, &u2), (25, &idx), (26, dens.out()), (27, &dout)],
            ctx.groups(m.div_ceil(256)),
        );
        ctx.dispatch(
            &mut enc,
            &k.seg_advance,
            &[
                (0, &u),
                (3, &marched.starts),
                (7, &marched.samp),
                (23, &state),
                (24, &counts),
                (27, &dout),
            ],
            ctx.groups(n_rays.div_ceil(256)),
        );
    }
    ctx.defer(enc)?;
    Ok((dout, state))
}

/// One pass over `rays`; `None` when their samples pass the budget (and there is more than
/// one ray to split).
fn render_pass(
    ctx: &GpuContext,
    model: &GpuFieldRef<'_>,
    rays: &[[f32; RAY_FLOATS]],
) -> Result<Option<Vec<RayPixel>>, GpuError> {
    let field = model.field;
    let k = kernels(ctx)?;
    let n_rays = rays.len() as u32;
    let Counted {
        rays: rays_buf,
        starts,
        n,
        ..
    } = count_samples(ctx, field, rays, model.occupied, &[])?;
    let budget = sample_budget(ctx, field);
    if n > budget && n_rays > 1 {
        return Ok(None);
    }
    let mut enc = ctx.encoder();
    let batch = RayBatch {
        rays: &rays_buf,
        occupied: model.occupied,
        n_rays,
    };
    let marched = record_write(ctx, &mut enc, field, batch, starts, n)?;
    let ld = marched.ld;
    let (dout, ray_state) = record_densities_until_termination(ctx, model, &marched, n_rays, enc)?;
    let mut enc = ctx.encoder();
    let wg = ctx.storage("sample weights", 8 * u64::from(ld))?;
    let flags = ctx.storage("live samples", 4 * (u64::from(n) + 1))?;
    let ray_out = ctx.storage(
        "field ray outputs",
        4 * (RAY_OUT_FLOATS as u64) * u64::from(n_rays),
    )?;
    let u = ctx.uniform(
        "field params",
        &field_words(
            field,
            PassSettings {
                n_rays,
                ld,
                n,
                min_color_w: RENDER_MIN_COLOR_WEIGHT,
                ..Default::default()
            },
        ),
    );
    ctx.dispatch(
        &mut enc,
        &k.ray_render,
        &[
            (0, &u),
            (3, &marched.starts),
            (7, &marched.samp),
            (9, &dout),
            (16, &wg),
            (19, &ray_out),
            (20, &flags),
            (23, &ray_state),
        ],
        ctx.groups(n_rays.div_ceil(256)),
    );
    ctx.record_scan(&mut enc, &flags, n + 1)?;
    let alive = ctx.storage("live sample indices", 4 * u64::from(n.max(1)))?;
    let alive_count = ctx.storage("live sample count", 16)?;
    ctx.dispatch(
        &mut enc,
        &k.compact,
        &[(0, &u), (12, &alive), (13, &alive_count), (20, &flags)],
        ctx.groups((n + 1).div_ceil(256)),
    );
    let color = record_color(
        ctx,
        &mut enc,
        field,
        model.params,
        &rays_buf,
        &marched,
        &dout,
        model.mean_emb,
        Some((&alive, &alive_count)),
    )?;
    let cout = &color.acts[color.acts.len() - 1];
    ctx.dispatch(
        &mut enc,
        &k.ray_composite,
        &[
            (0, &u),
            (1, &rays_buf),
            (3, &marched.starts),
            (15, cout),
            (16, &wg),
            (19, &ray_out),
            (20, &flags),
        ],
        ctx.groups(n_rays.div_ceil(256)),
    );
    let words = ctx.read_after(
        enc,
        &[
            (&ray_out, 0, RAY_OUT_FLOATS * rays.len()),
            (&marched.steps, 0, rays.len()),
        ],
    )?;
    ctx.reclaim();
    let f = |w: u32| f32::from_bits(w);
    let pixels = words[0]
        .chunks_exact(RAY_OUT_FLOATS)
        .zip(&words[1])
        .map(|(o, &steps)| RayPixel {
            rgb: [f(o[0]), f(o[1]), f(o[2])],
            acc: f(o[3]),
            depth: f(o[4]),
            steps,
            marched: o[10],
            density: o[11],
            color: o[8],
        })
        .collect();
    Ok(Some(pixels))
}

/// Renders cameras as [`crate::render::render_camera`] does (every pixel, mean embedding,
/// jitter ½), batching the rays of consecutive views into shared passes.
pub fn render_views_gpu(
    ctx: &GpuContext,
    model: &GpuFieldRef<'_>,
    cams: &[Camera],
    background: [f32; 3],
) -> Result<Vec<RenderedImage>, GpuError> {
    let mut images = Vec::with_capacity(cams.len());
    let mut first = 0;
    while first < cams.len() {
        // Views whose rays fit one batch of ray records (at least one view).
        let mut end = first + 1;
        let mut rays_in = cams[first].width as usize * cams[first].height as usize;
        while end < cams.len() {
            let more = cams[end].width as usize * cams[end].height as usize;
            if rays_in + more > MAX_PASS_RAYS {
                break;
            }
            rays_in += more;
            end += 1;
        }
        let mut rays = Vec::with_capacity(rays_in);
        let mut cosines = Vec::with_capacity(rays_in);
        for cam in &cams[first..end] {
            let (recs, cos) = camera_rays(cam, background);
            rays.extend(recs);
            cosines.extend(cos);
        }
        let pixels = render_rays_gpu(ctx, model, &rays)?;
        let mut at = 0;
        for cam in &cams[first..end] {
            let n = cam.width as usize * cam.height as usize;
            let mut img = RenderedImage {
                width: cam.width,
                height: cam.height,
                rgb: Vec::with_capacity(3 * n),
                depth: Vec::with_capacity(n),
                acc: Vec::with_capacity(n),
                stats: RenderStats::default(),
            };
            for (px, cos) in pixels[at..at + n].iter().zip(&cosines[at..at + n]) {
                img.rgb.extend_from_slice(&px.rgb);
                img.depth.push(if px.acc > 1e-6 {
                    px.depth / px.acc * cos
                } else {
                    0.0
                });
                img.acc.push(px.acc);
                img.stats.add(&px.stats());
            }
            images.push(img);
            at += n;
        }
        first = end;
    }
    Ok(images)
}

/// Uploads a trained field (parameters and occupancy) and renders `cams` on the GPU.
pub fn render_cameras_gpu(
    ctx: &GpuContext,
    field: &Field,
    params: &[f32],
    occupancy: &crate::occupancy::OccupancyGrid,
    cams: &[Camera],
    background: [f32; 3],
) -> Result<Vec<RenderedImage>, GpuError> {
    ctx.scoped(|| {
        let p = ctx.storage_init("field parameters", &f32_words(params.iter().copied()))?;
        let occ = ctx.storage_init("occupancy", &occupancy_words(occupancy))?;
        let mean = mean_embedding_buffer(ctx, field, params)?;
        let model = GpuFieldRef {
            field,
            params: &p,
            occupied: &occ,
            mean_emb: &mean,
        };
        let images = render_views_gpu(ctx, &model, cams, background)?;
        ctx.reclaim();
        Ok(images)
    })
}

/// The ray records of every pixel of `cam` (row-major), as the CPU renderer casts them, and
/// each ray's cosine to the optical axis (for depth along the axis).
pub fn camera_rays(cam: &Camera, background: [f32; 3]) -> (Vec<[f32; RAY_FLOATS]>, Vec<f32>) {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let fwd = cam.forward();
    (0..w * h)
        .map(|p| {
            let (o, d) = cam.pixel_ray((p / w) as u32, (p % w) as u32);
            let ray = RayInput {
                origin: o.map(|x| x as f32),
                dir: d.map(|x| x as f32),
                image: NO_IMAGE,
                background,
            };
            let cos = (d[0] * fwd[0] + d[1] * fwd[1] + d[2] * fwd[2]) as f32;
            (ray_record(&ray, [0.0; 3], (0.0, 0.0), 0.5), cos)
        })
        .unzip()
}
