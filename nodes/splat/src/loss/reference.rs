//! Plain f64 references (direct per-window sums, no separability) for the tests.

use super::*;

/// Mean SSIM over the valid map, computed per window in f64.
pub fn ssim(pred: &[f64], target: &[f64], width: usize, height: usize) -> f64 {
    if width < SSIM_WINDOW || height < SSIM_WINDOW {
        return 1.0;
    }
    let w1 = gaussian_window();
    let (ow, oh) = (width - SSIM_WINDOW + 1, height - SSIM_WINDOW + 1);
    let mut total = 0.0;
    for ch in 0..3 {
        for oy in 0..oh {
            for ox in 0..ow {
                let (mut mx, mut my, mut exx, mut eyy, mut exy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for ky in 0..SSIM_WINDOW {
                    for kx in 0..SSIM_WINDOW {
                        let w = w1[ky] * w1[kx];
                        let i = ((oy + ky) * width + ox + kx) * 3 + ch;
                        let (x, y) = (pred[i], target[i]);
                        mx += w * x;
                        my += w * y;
                        exx += w * x * x;
                        eyy += w * y * y;
                        exy += w * x * y;
                    }
                }
                let vx = exx - mx * mx;
                let vy = eyy - my * my;
                let cxy = exy - mx * my;
                total += (2.0 * mx * my + SSIM_C1) * (2.0 * cxy + SSIM_C2)
                    / ((mx * mx + my * my + SSIM_C1) * (vx + vy + SSIM_C2));
            }
        }
    }
    total / (ow * oh * 3) as f64
}

/// Weighted L2 in f64 with the same normalisation rules as [`super::weighted_l2`].
pub fn weighted_l2(pred: &[f64], target: &[f64], weights: &[f64], norm: WeightNorm) -> f64 {
    let mut s = 0.0;
    let mut ws = 0.0;
    for (p, &w) in weights.iter().enumerate() {
        let w = if w.is_finite() && w > 0.0 { w } else { 0.0 };
        ws += w;
        for ch in 0..3 {
            let d = pred[p * 3 + ch] - target[p * 3 + ch];
            s += w * d * d;
        }
    }
    let denom = match norm {
        WeightNorm::WeightSum => 3.0 * ws,
        WeightNorm::PixelCount => 3.0 * weights.len() as f64,
    };
    if denom <= 0.0 {
        0.0
    } else {
        s / denom
    }
}
