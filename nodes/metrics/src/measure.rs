//! The held-out metrics of one render against its ground truth, and their mean over views: the
//! one definition that the training curve (`augsplat_splat::train::evaluate`) and the
//! `Evaluate` node both use, so a curve point and an evaluation of the same model agree.
//!
//! PSNR convention: the PSNR of an exact render (MSE 0) is `f64::INFINITY`, as
//! [`crate::psnr_from_mse`] gives it — no cap. A mean over views that include an exact render
//! is therefore infinite too; the artifacts that store PSNRs write it as the string `inf`
//! (`augsplat_core::artifacts::nonfinite`).

use crate::lpips::Lpips;
use crate::MetricsError;
use augsplat_core::ImageF32;

/// The metrics of one image pair, or their mean over views (see [`mean`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Measurement {
    /// PSNR, dB, for data range 1 (`f64::INFINITY` for an exact render).
    pub psnr: f64,
    /// SSIM, torchmetrics convention ([`crate::ssim()`]).
    pub ssim: f64,
    /// Mean squared error over pixels and channels.
    pub mse: f64,
    /// LPIPS distance, when a model was given.
    pub lpips: Option<f64>,
    /// Average error `(MSE · sqrt(1 − SSIM) · LPIPS)^(1/3)` ([`crate::average_error`]), when
    /// a model was given.
    pub avg_error: Option<f64>,
}

/// Measures `render` against `gt` (same size, values in [0, 1]; callers clamp renders first,
/// as gsplat's evaluation does): MSE, SSIM, PSNR from the MSE, and LPIPS and the average error
/// when `lpips` is given and the images are large enough for it ([`Lpips::accepts`]; smaller
/// ones have no LPIPS, as without weights — never a made-up number).
pub fn measure(
    render: &ImageF32,
    gt: &ImageF32,
    lpips: Option<&Lpips>,
) -> Result<Measurement, MetricsError> {
    let mse = crate::mse(render, gt)?;
    let ssim = crate::ssim(render, gt)?;
    let lp = match lpips {
        Some(m) if m.accepts(gt.width as usize, gt.height as usize) => {
            Some(m.distance(render, gt)?)
        }
        _ => None,
    };
    Ok(Measurement {
        psnr: crate::psnr_from_mse(mse),
        ssim,
        mse,
        lpips: lp,
        avg_error: lp.map(|l| crate::average_error(mse, ssim, l)),
    })
}

/// The mean of each metric over `items` (`None` when there are none); LPIPS and the average
/// error only when every item has them. Each mean is the sum in item order, starting from
/// 0.0, divided by the count — PSNR is the mean of per-view PSNRs, as gsplat and AugSplat
/// report it.
pub fn mean(items: &[Measurement]) -> Option<Measurement> {
    if items.is_empty() {
        return None;
    }
    let n = items.len() as f64;
    let sum = |f: &dyn Fn(&Measurement) -> f64| {
        let mut s = 0.0;
        for m in items {
            s += f(m);
        }
        s / n
    };
    let sum_opt = |f: &dyn Fn(&Measurement) -> Option<f64>| -> Option<f64> {
        let mut s = 0.0;
        for m in items {
            s += f(m)?;
        }
        Some(s / n)
    };
    Some(Measurement {
        psnr: sum(&|m| m.psnr),
        ssim: sum(&|m| m.ssim),
        mse: sum(&|m| m.mse),
        lpips: sum_opt(&|m| m.lpips),
        avg_error: sum_opt(&|m| m.avg_error),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: u32, h: u32, f: impl Fn(u32, u32, u32) -> f32) -> ImageF32 {
        ImageF32::from_fn(w, h, 3, f)
    }

    #[test]
    fn exact_render_has_infinite_psnr() {
        let a = img(16, 12, |x, y, c| ((x * 7 + y * 3 + c) % 11) as f32 / 10.0);
        let m = measure(&a, &a, None).unwrap();
        assert_eq!(m.psnr, f64::INFINITY);
        assert_eq!(m.mse, 0.0);
        assert!((m.ssim - 1.0).abs() < 1e-9, "{}", m.ssim);
        assert_eq!((m.lpips, m.avg_error), (None, None));
        // The mean over views that include an exact render is infinite too (no cap).
        let b = img(16, 12, |x, y, c| ((x * 7 + y * 3 + c) % 11) as f32 / 12.0);
        let other = measure(&b, &a, None).unwrap();
        assert!(other.psnr.is_finite());
        assert_eq!(mean(&[other, m]).unwrap().psnr, f64::INFINITY);
    }

    #[test]
    fn measure_matches_the_metric_functions() {
        let a = img(16, 12, |x, y, c| ((x * 5 + y + c) % 9) as f32 / 8.0);
        let b = img(16, 12, |x, y, c| ((x + y * 3 + 2 * c) % 7) as f32 / 6.0);
        let m = measure(&a, &b, None).unwrap();
        assert_eq!(m.mse, crate::mse(&a, &b).unwrap());
        assert_eq!(m.psnr, crate::psnr(&a, &b).unwrap());
        assert_eq!(m.ssim, crate::ssim(&a, &b).unwrap());
    }

    #[test]
    fn mean_is_the_ordered_sum_over_the_count() {
        let v = |p: f64, l: Option<f64>| Measurement {
            psnr: p,
            ssim: p / 100.0,
            mse: p / 1000.0,
            lpips: l,
            avg_error: l.map(|x| x / 2.0),
        };
        let items = [
            v(20.0, Some(0.25)),
            v(30.1, Some(0.5)),
            v(25.7, Some(0.125)),
        ];
        let m = mean(&items).unwrap();
        assert_eq!(m.psnr, (0.0 + 20.0 + 30.1 + 25.7) / 3.0);
        assert_eq!(m.lpips, Some((0.0 + 0.25 + 0.5 + 0.125) / 3.0));
        let partial = [v(20.0, Some(0.25)), v(30.0, None)];
        assert_eq!(mean(&partial).unwrap().lpips, None);
        assert_eq!(mean(&partial).unwrap().avg_error, None);
        assert!(mean(&[]).is_none());
    }
}
