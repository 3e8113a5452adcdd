//! Host side of the GPU losses (`loss/loss.wgsl`): the photometric loss (L2 or L1, plus SSIM
//! with valid padding) and the weighted L2 of [`crate::loss`], recorded into a caller's
//! command encoder on GPU buffers so that a training step can keep its images on the GPU.
//!
//! The kernels write `scale · dL/dpred` (they do not add to it) and leave one f32 partial
//! sum per 256-value block, summed by a fixed tree; [`LossSums::value`] adds the partials in
//! index order in f64. No atomics: the same inputs on one adapter give the same bytes.

use crate::gpu::{f32_words, GpuBuffer, GpuContext, GpuError};
use crate::loss::{gaussian_window, PixelLoss, WeightNorm, SSIM_C1, SSIM_C2, SSIM_WINDOW};

/// Values per block of the loss kernels (their workgroup size): one partial sum each.
pub(crate) const BLOCK: u64 = 256;
/// Rows and columns the SSIM window reaches past its first one.
const HALO: u32 = SSIM_WINDOW as u32 - 1;

/// Which loss a view uses on the GPU.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GpuLoss {
    /// The real-image loss `(1 − λ)·P + λ·(1 − SSIM)` of [`crate::loss::photometric`]; the
    /// SSIM term is left out (as on the CPU) when λ = 0 or the image is smaller than the
    /// 11-pixel window in either dimension.
    Photometric {
        /// The pixel-wise term P.
        kind: PixelLoss,
        /// λ, the weight of the SSIM term.
        ssim_lambda: f32,
    },
    /// The confidence-weighted L2 of [`crate::loss::weighted_l2`]:
    /// `Σ_p w_p Σ_c (pred − target)² / denominator`, with weights that are not finite or not
    /// positive counted as 0; a denominator that is not positive and finite gives loss 0 and
    /// a zero gradient. [`GpuLoss::weighted_l2`] makes the denominator of a [`WeightNorm`].
    WeightedL2 {
        /// `3 · Σ w` ([`WeightNorm::WeightSum`]) or `3 · pixels` ([`WeightNorm::PixelCount`]).
        denominator: f64,
    },
}

impl GpuLoss {
    /// The weighted L2 normalised by `norm` for the per-pixel `weights`: the denominator is
    /// [`crate::loss::weighted_l2_denominator`], the very number the CPU's weighted L2 divides
    /// by.
    pub fn weighted_l2(norm: WeightNorm, weights: &[f32]) -> GpuLoss {
        GpuLoss::WeightedL2 {
            denominator: crate::loss::weighted_l2_denominator(weights, norm),
        }
    }
}

/// The loss kernels' constants, from the Rust side: the block of the partial sums and
/// SSIM's window (after the renderer's prelude, `augsplat_render::gpu::prelude`).
pub(crate) fn prelude() -> String {
    use augsplat_render::gpu::prelude::constant_u32;
    let window = crate::loss::SSIM_WINDOW as u64;
    constant_u32("LOSS_BLOCK", BLOCK)
        + &constant_u32("SSIM_WINDOW", window)
        + &constant_u32("SSIM_HALO", window - 1)
}

/// The compiled loss kernels (`loss/loss.wgsl`).
pub(crate) struct LossKernels {
    /// [`u8_values`], for targets held as bytes.
    u8_values: wgpu::Buffer,
    pixel: wgpu::ComputePipeline,
    weighted: wgpu::ComputePipeline,
    h_moments: wgpu::ComputePipeline,
    v_ssim: wgpu::ComputePipeline,
    v_adjoint: wgpu::ComputePipeline,
    ssim_grad: wgpu::ComputePipeline,
}

impl LossKernels {
    pub(crate) fn new(m: crate::gpu::ModuleSetup<'_>) -> LossKernels {
        let [pixel, weighted, h_moments, v_ssim, v_adjoint, ssim_grad] = crate::gpu::pipelines_with(
            m,
            "loss.wgsl",
            &prelude(),
            include_str!("loss.wgsl"),
            [
                "pixel",
                "weighted",
                "h_moments",
                "v_ssim",
                "v_adjoint",
                "ssim_grad",
            ],
        );
        let u8_values = m.0.create_buffer(&wgpu::BufferDescriptor {
            label: Some("byte values"),
            size: 4 * 256,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: true,
        });
        // Mapping at creation fails only on a lost device, whose every later call fails.
        if let Ok(mut view) = u8_values.slice(..).get_mapped_range_mut() {
            view.copy_from_slice(&crate::gpu::words_to_bytes(&f32_words(u8_values_table())));
        }
        u8_values.unmap();
        LossKernels {
            u8_values,
            pixel,
            weighted,
            h_moments,
            v_ssim,
            v_adjoint,
            ssim_grad,
        }
    }
}

/// The value of each byte of a decoded 8-bit photo (`k / 255` in f32, as the image decoder
/// gives it): a target whose every value is one of these is kept on the GPU as bytes.
pub fn u8_values_table() -> [f32; 256] {
    std::array::from_fn(|k| k as f32 / 255.0)
}

/// `values` as bytes (four per word, little end first) when every value is exactly one of
/// [`u8_values_table`]'s, else `None`.
pub fn pack_u8(values: &[f32]) -> Option<Vec<u32>> {
    let table = u8_values_table();
    let mut words = vec![0u32; values.len().div_ceil(4)];
    for (i, &v) in values.iter().enumerate() {
        let k = (v * 255.0).round();
        if !(0.0..=255.0).contains(&k) || table[k as usize].to_bits() != v.to_bits() {
            return None;
        }
        words[i / 4] |= (k as u32) << (8 * (i % 4));
    }
    Some(words)
}

/// A target image on the GPU: f32 values, or bytes ([`pack_u8`]).
#[derive(Clone, Copy)]
pub(crate) struct TargetBuffer<'a> {
    /// The values.
    pub(crate) buf: &'a wgpu::Buffer,
    /// Whether they are bytes.
    pub(crate) bytes: bool,
}

/// One term's per-block partial sums on the GPU.
struct Partials {
    buf: GpuBuffer,
    blocks: usize,
    /// What the sum is divided by (values, map values or the weighted L2's denominator).
    divisor: f64,
}

impl Partials {
    fn new(ctx: &GpuContext, what: &str, values: u64, divisor: f64) -> Result<Self, GpuError> {
        let blocks = values.div_ceil(BLOCK);
        Ok(Partials {
            buf: ctx.storage(what, 4 * blocks)?,
            blocks: blocks as usize,
            divisor,
        })
    }

    /// The mean of the partials `words` (read back from `buf`), added in index order, in f64.
    fn mean_of(&self, words: &[u32]) -> f64 {
        let sum: f64 = words.iter().map(|&w| f64::from(f32::from_bits(w))).sum();
        sum / self.divisor
    }
}

/// The partial sums of one recorded loss; read them after the encoder has been submitted.
pub(crate) struct LossSums {
    /// The pixel term (or the weighted L2); `None` where it is 0 by definition.
    pixel: Option<Partials>,
    /// The SSIM map; `None` where the SSIM term is left out.
    ssim: Option<Partials>,
    /// The factor of the pixel term in the loss (`1 − λ`, or 1 for the weighted L2).
    pixel_weight: f64,
}

impl LossSums {
    /// The sums of an empty image: loss 0.
    fn zero(pixel_weight: f64) -> LossSums {
        LossSums {
            pixel: None,
            ssim: None,
            pixel_weight,
        }
    }

    /// The loss value, the same quantity as the CPU function returns (the first of
    /// [`crate::loss::photometric`]'s three).
    pub(crate) fn value(&self, ctx: &GpuContext) -> Result<f64, GpuError> {
        Ok(self.terms(ctx)?.0)
    }

    /// `(loss, pixel term, mean SSIM)` as [`crate::loss::photometric`] returns them (SSIM 1
    /// where the term is left out); for the weighted L2, `(loss, loss, 1)`.
    pub(crate) fn terms(&self, ctx: &GpuContext) -> Result<(f64, f64, f64), GpuError> {
        let enc = ctx.encoder();
        let words = ctx.read_after(enc, &self.parts())?;
        Ok(self.terms_from(&words))
    }

    /// The partial-sum buffers to read back, for [`GpuContext::read_after`]: (buffer, first
    /// word, words).
    pub(crate) fn parts(&self) -> Vec<(&wgpu::Buffer, u64, usize)> {
        [&self.pixel, &self.ssim]
            .into_iter()
            .flatten()
            .map(|p| (&*p.buf, 0, p.blocks))
            .collect()
    }

    /// [`LossSums::terms`] from the words of [`LossSums::parts`], in that order.
    pub(crate) fn terms_from(&self, words: &[Vec<u32>]) -> (f64, f64, f64) {
        let mut words = words.iter();
        let mut next = |p: &Partials| p.mean_of(words.next().map_or(&[][..], |w| &w[..]));
        let pixel = self.pixel.as_ref().map_or(0.0, &mut next);
        match self.ssim.as_ref().map(&mut next) {
            Some(ssim) => {
                let lam = 1.0 - self.pixel_weight;
                (self.pixel_weight * pixel + lam * (1.0 - ssim), pixel, ssim)
            }
            None => (self.pixel_weight * pixel, pixel, 1.0),
        }
    }
}

/// Checks that `buf` holds at least `words` f32 words.
fn check_size(buf: &wgpu::Buffer, words: u64, what: &str) -> Result<(), GpuError> {
    if buf.size() < 4 * words {
        return Err(GpuError::Invalid(format!(
            "loss: the {what} buffer has {} bytes, the image needs {}",
            buf.size(),
            4 * words
        )));
    }
    Ok(())
}

/// The uniform of `loss.wgsl`: sizes, stride, mode, gradient factors, stabilisers, window.
#[allow(clippy::too_many_arguments)]
fn params(
    width: u32,
    height: u32,
    stride: u32,
    mode: u32,
    k: f32,
    gs: f32,
    bytes: bool,
) -> Vec<u32> {
    let mut w = vec![width, height, stride, mode];
    w.extend(f32_words([k, gs, SSIM_C1 as f32, SSIM_C2 as f32]));
    w.extend(f32_words(gaussian_window().map(|v| v as f32)));
    w.push(0);
    w.extend([u32::from(bytes), 0, 0, 0]);
    w
}

/// The image buffers and size of one recorded loss.
struct Images<'a> {
    pred: &'a wgpu::Buffer,
    stride: u32,
    target: TargetBuffer<'a>,
    d_rgb: &'a wgpu::Buffer,
    width: u32,
    height: u32,
}

impl Images<'_> {
    /// Interleaved values, `3·W·H`.
    fn values(&self) -> u64 {
        3 * u64::from(self.width) * u64::from(self.height)
    }
    /// The words of `loss.wgsl`'s uniform with this size and stride.
    fn params(&self, mode: u32, k: f32, gs: f32) -> Vec<u32> {
        params(
            self.width,
            self.height,
            self.stride,
            mode,
            k,
            gs,
            self.target.bytes,
        )
    }
}

/// Records the loss of `pred` (`pred_stride` f32 words per pixel, colour in the first three:
/// the forward's image buffer, or a plain rgb buffer with stride 3) against `target`
/// (`H·W·3` f32) and, for [`GpuLoss::WeightedL2`], `weights` (`H·W` f32; ignored otherwise):
/// writes `scale · dL/dpred` into `d_rgb` (`H·W·3` f32, overwritten) and returns the partial
/// sums that give the loss value once `enc` has been submitted. The factors follow the CPU
/// functions' arithmetic in f32, so the gradient matches theirs (added into zeros) to
/// rounding.
#[allow(clippy::too_many_arguments)]
pub(crate) fn record_loss(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    pred: &wgpu::Buffer,
    pred_stride: u32,
    target: TargetBuffer<'_>,
    weights: Option<&wgpu::Buffer>,
    width: u32,
    height: u32,
    loss: GpuLoss,
    scale: f32,
    d_rgb: &wgpu::Buffer,
) -> Result<LossSums, GpuError> {
    let pixels = u64::from(width) * u64::from(height);
    // The kernels index the five moment planes (< 15 words per pixel) in u32.
    if 15 * pixels > u64::from(u32::MAX) {
        return Err(GpuError::Invalid(format!(
            "loss: a {width}×{height} image is too large for the loss kernels"
        )));
    }
    if pred_stride < 3 {
        return Err(GpuError::Invalid(format!(
            "loss: a prediction stride of {pred_stride} words per pixel (need at least 3)"
        )));
    }
    check_size(pred, u64::from(pred_stride) * pixels, "prediction")?;
    let target_words = if target.bytes {
        (3 * pixels).div_ceil(4)
    } else {
        3 * pixels
    };
    check_size(target.buf, target_words, "target")?;
    check_size(d_rgb, 3 * pixels, "gradient")?;
    let im = Images {
        pred,
        stride: pred_stride,
        target,
        d_rgb,
        width,
        height,
    };
    match loss {
        GpuLoss::WeightedL2 { denominator } => {
            let w = weights.ok_or_else(|| {
                GpuError::Invalid("loss: the weighted L2 needs a weight buffer".into())
            })?;
            check_size(w, pixels, "weight")?;
            record_weighted(ctx, enc, &im, w, denominator, scale)
        }
        GpuLoss::Photometric { kind, ssim_lambda } => {
            record_photometric(ctx, enc, &im, kind, ssim_lambda, scale)
        }
    }
}

/// The weighted L2 (`weighted`).
fn record_weighted(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    im: &Images<'_>,
    weights: &wgpu::Buffer,
    denominator: f64,
    scale: f32,
) -> Result<LossSums, GpuError> {
    let n = im.values();
    let live = denominator > 0.0 && denominator.is_finite();
    if n == 0 {
        return Ok(LossSums::zero(1.0));
    }
    // The CPU's factor (loss/mod.rs `weighted_l2`); mode 1 writes a zero gradient.
    let g = (2.0 * scale as f64 / denominator) as f32;
    let uni = ctx.uniform("weighted L2 params", &im.params(u32::from(!live), g, 0.0));
    let kr = ctx.kernels_of(LossKernels::new)?;
    let sums = Partials::new(ctx, "weighted L2 sums", n, denominator)?;
    ctx.dispatch(
        enc,
        &kr.weighted,
        &[
            (0, &uni),
            (1, im.pred),
            (2, im.target.buf),
            (3, weights),
            (9, &kr.u8_values),
            (6, im.d_rgb),
            (7, &sums.buf),
        ],
        groups(ctx, n),
    );
    Ok(LossSums {
        pixel: live.then_some(sums),
        ssim: None,
        pixel_weight: 1.0,
    })
}

/// The photometric loss: `pixel` alone, or the four SSIM passes (see `loss.wgsl`).
fn record_photometric(
    ctx: &GpuContext,
    enc: &mut augsplat_render::gpu::Encoder,
    im: &Images<'_>,
    kind: PixelLoss,
    ssim_lambda: f32,
    scale: f32,
) -> Result<LossSums, GpuError> {
    let n = im.values();
    let pixel_weight = 1.0 - f64::from(ssim_lambda);
    if n == 0 {
        return Ok(LossSums::zero(pixel_weight));
    }
    // The CPU's factors, in its order of f32 operations (loss/mod.rs `photometric`).
    let pix_scale = scale * (1.0 - ssim_lambda);
    let (mode, k) = match kind {
        PixelLoss::L2 => (0, 2.0 * pix_scale / n as f32),
        PixelLoss::L1 => (1, pix_scale / n as f32),
    };
    let kr = ctx.kernels_of(LossKernels::new)?;
    let pix = Partials::new(ctx, "pixel-term sums", n, n as f64)?;
    let (width, height) = (im.width, im.height);
    let window = SSIM_WINDOW as u32;
    if ssim_lambda == 0.0 || width < window || height < window {
        let uni = ctx.uniform("pixel loss params", &im.params(mode, k, 0.0));
        ctx.dispatch(
            enc,
            &kr.pixel,
            &[
                (0, &uni),
                (1, im.pred),
                (2, im.target.buf),
                (6, im.d_rgb),
                (9, &kr.u8_values),
                (7, &pix.buf),
            ],
            groups(ctx, n),
        );
        return Ok(LossSums {
            pixel: Some(pix),
            ssim: None,
            pixel_weight,
        });
    }
    let m = 3 * u64::from(width - HALO);
    let plane = u64::from(height) * m;
    let count = u64::from(height - HALO) * m;
    let gs = ((-scale * ssim_lambda) as f64 / count as f64) as f32;
    let uni = ctx.uniform("photometric loss params", &im.params(mode, k, gs));
    let moments = ctx.storage("SSIM moments", 4 * 5 * plane)?;
    let part = ctx.storage("SSIM partials", 4 * 3 * count)?;
    let ssim = Partials::new(ctx, "SSIM sums", count, count as f64)?;
    ctx.dispatch(
        enc,
        &kr.h_moments,
        &[
            (0, &uni),
            (1, im.pred),
            (2, im.target.buf),
            (4, &moments),
            (9, &kr.u8_values),
        ],
        groups(ctx, plane),
    );
    ctx.dispatch(
        enc,
        &kr.v_ssim,
        &[(0, &uni), (4, &moments), (5, &part), (7, &ssim.buf)],
        groups(ctx, count),
    );
    ctx.dispatch(
        enc,
        &kr.v_adjoint,
        &[(0, &uni), (4, &moments), (5, &part)],
        groups(ctx, plane),
    );
    ctx.dispatch(
        enc,
        &kr.ssim_grad,
        &[
            (0, &uni),
            (1, im.pred),
            (2, im.target.buf),
            (4, &moments),
            (6, im.d_rgb),
            (9, &kr.u8_values),
            (7, &pix.buf),
        ],
        groups(ctx, n),
    );
    Ok(LossSums {
        pixel: Some(pix),
        ssim: Some(ssim),
        pixel_weight,
    })
}

/// Workgroups for one thread per value.
fn groups(ctx: &GpuContext, values: u64) -> [u32; 2] {
    ctx.groups(values.div_ceil(BLOCK) as u32)
}

/// The loss of `pred_rgb` against `target` (both `H·W·3`, interleaved) on the GPU, with
/// `weights` (`H·W`) for [`GpuLoss::WeightedL2`]: uploads, runs the kernels and reads back
/// `(loss value, scale · dL/dpred)` — the value [`crate::loss::photometric`] (first of its
/// three) or [`crate::loss::weighted_l2`] returns and the gradient they add into a zero
/// buffer, to f32 rounding. For tests and tools; a GPU training step keeps its buffers on
/// the GPU instead. Deterministic: the same inputs give the same bytes on one adapter.
#[allow(clippy::too_many_arguments)]
pub fn loss_gpu(
    ctx: &GpuContext,
    pred_rgb: &[f32],
    target: &[f32],
    weights: Option<&[f32]>,
    width: u32,
    height: u32,
    loss: GpuLoss,
    scale: f32,
) -> Result<(f64, Vec<f32>), GpuError> {
    let pixels = width as usize * height as usize;
    for (what, len, need) in [
        ("prediction", pred_rgb.len(), 3 * pixels),
        ("target", target.len(), 3 * pixels),
        ("weight", weights.map_or(pixels, <[f32]>::len), pixels),
    ] {
        if len != need {
            return Err(GpuError::Invalid(format!(
                "loss: {len} {what} values for a {width}×{height} image (need {need})"
            )));
        }
    }
    if pixels == 0 {
        return Ok((0.0, Vec::new()));
    }
    ctx.scoped(|| {
        let pred = ctx.storage_init("prediction", &f32_words(pred_rgb.iter().copied()))?;
        let tgt = ctx.storage_init("target", &f32_words(target.iter().copied()))?;
        let w = match weights {
            Some(w) => Some(ctx.storage_init("weights", &f32_words(w.iter().copied()))?),
            None => None,
        };
        let d_rgb = ctx.storage("colour gradients", 4 * 3 * pixels as u64)?;
        let mut enc = ctx.encoder();
        let sums = record_loss(
            ctx,
            &mut enc,
            &pred,
            3,
            TargetBuffer {
                buf: &tgt,
                bytes: false,
            },
            w.as_deref(),
            width,
            height,
            loss,
            scale,
            &d_rgb,
        )?;
        ctx.submit(enc)?;
        let grad = ctx
            .read_words(&d_rgb, 3 * pixels)?
            .into_iter()
            .map(f32::from_bits)
            .collect();
        Ok((sums.value(ctx)?, grad))
    })
}

#[cfg(test)]
mod tests {
    use augsplat_render::gpu::prelude::{declared_constants, prelude_names};

    /// The trainer's kernels, by file name.
    const SOURCES: &[(&str, &str)] = &[
        ("loss.wgsl", include_str!("loss.wgsl")),
        ("adam.wgsl", include_str!("../adam/adam.wgsl")),
        ("accumulate.wgsl", include_str!("../train/accumulate.wgsl")),
        ("densify.wgsl", include_str!("../densify/densify.wgsl")),
        (
            "keep_visible.wgsl",
            include_str!("../densify/keep_visible.wgsl"),
        ),
    ];

    #[test]
    fn no_trainer_kernel_declares_a_generated_constant_again() {
        let own = super::prelude();
        let generated: Vec<String> = prelude_names()
            .into_iter()
            .map(String::from)
            .chain(declared_constants(&own))
            .collect();
        for (file, src) in SOURCES {
            for name in declared_constants(src) {
                assert!(
                    !generated.contains(&name),
                    "{file} declares {name}, which is generated from the Rust constant"
                );
            }
            assert!(!src.contains("fn finite("), "{file} defines finite() again");
        }
        assert!(own.contains("const SSIM_WINDOW: u32 = 11u;"), "{own}");
        assert!(own.contains("const SSIM_HALO: u32 = 10u;"), "{own}");
        assert!(own.contains("const LOSS_BLOCK: u32 = 256u;"), "{own}");
    }
}
