//! DropGaussian (Park, Ryu and Kim, CVPR 2025), the strongest simple sparse-view baseline: every
//! training render drops each Gaussian with probability `p` and scales the survivors' opacity
//! by 1/(1 − p), so the rendered image keeps its expected opacity while each Gaussian is
//! pushed to explain the views on its own. `p` rises linearly over the run, from 0 at the
//! first step to `max_rate` at the last (the authors' code: 0.2 · iteration / 10,000 over its
//! 10,000 iterations). Evaluations render every Gaussian, unscaled.
//!
//! The factors go to the renderer as [`crate::RenderSettings::opacity_scale`]: the opacity
//! after the sigmoid is multiplied (a survivor's may pass 1; the per-pixel clamp then
//! decides, as in the authors' rasteriser), and the gradient of a logit carries the factor. A
//! dropped Gaussian (factor 0) is culled in that render: no gradient, no densification
//! statistic. The draw is a pure function of the seed, the step and the render's place in
//! the step, so a run is reproducible and a resumed run draws the same.

use augsplat_core::Rng;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// DropGaussian's settings (an `OptimizeSplats` option; absent = off).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DropGaussian {
    /// The drop rate reached at the last step (the authors': 0.2).
    pub max_rate: f64,
}

impl Default for DropGaussian {
    fn default() -> Self {
        DropGaussian { max_rate: 0.2 }
    }
}

impl DropGaussian {
    /// Checks the range: `max_rate` in [0, 1).
    pub fn validate(&self) -> Result<(), String> {
        if !(0.0..1.0).contains(&self.max_rate) {
            return Err(format!(
                "drop_gaussians.max_rate = {} must be in [0, 1)",
                self.max_rate
            ));
        }
        Ok(())
    }

    /// The drop rate at 0-based step `step` of `steps`: `max_rate · step / steps`.
    pub fn rate(&self, step: u64, steps: u64) -> f64 {
        self.max_rate * step as f64 / steps.max(1) as f64
    }

    /// The opacity factors of `n` Gaussians for the `render`-th render of step `step`: 0 with
    /// probability `rate`, else 1/(1 − rate); `None` at rate 0 (nothing dropped, nothing
    /// scaled: the render of the run without DropGaussian).
    pub fn factors(
        &self,
        seed: u64,
        step: u64,
        steps: u64,
        render: u64,
        n: usize,
    ) -> Option<Arc<[f32]>> {
        let p = self.rate(step, steps);
        if p <= 0.0 {
            return None;
        }
        let keep = (1.0 / (1.0 - p)) as f32;
        let mut rng = Rng::stream(seed ^ 0xD509_6A55, step.wrapping_mul(1 << 16) ^ render);
        Some(
            (0..n)
                .map(|_| if rng.next_f64() < p { 0.0 } else { keep })
                .collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rate_rises_linearly_and_the_draw_keeps_the_expected_opacity() {
        let d = DropGaussian::default();
        assert_eq!(d.rate(0, 1000), 0.0);
        assert!((d.rate(500, 1000) - 0.1).abs() < 1e-15);
        assert!((d.rate(1000, 1000) - 0.2).abs() < 1e-15);
        assert!(
            d.factors(1, 0, 1000, 0, 10).is_none(),
            "step 0 drops nothing"
        );
        let n = 200_000;
        let f = d.factors(1, 999, 1000, 0, n).unwrap();
        let p = d.rate(999, 1000);
        let dropped = f.iter().filter(|&&x| x == 0.0).count() as f64 / n as f64;
        assert!((dropped - p).abs() < 0.005, "dropped {dropped}, rate {p}");
        assert!(f.iter().all(|&x| x == 0.0 || x == (1.0 / (1.0 - p)) as f32));
        // The expected factor is 1: the image keeps its expected opacity.
        let mean = f.iter().map(|&x| f64::from(x)).sum::<f64>() / n as f64;
        assert!((mean - 1.0).abs() < 0.01, "mean factor {mean}");
        // A pure function of (seed, step, render); each changes the draw.
        assert_eq!(f, d.factors(1, 999, 1000, 0, n).unwrap());
        assert_ne!(f, d.factors(2, 999, 1000, 0, n).unwrap());
        assert_ne!(f, d.factors(1, 998, 1000, 0, n).unwrap());
        assert_ne!(f, d.factors(1, 999, 1000, 1, n).unwrap());
        assert!(DropGaussian { max_rate: 1.0 }.validate().is_err());
        assert!(DropGaussian { max_rate: -0.1 }.validate().is_err());
        assert!(d.validate().is_ok());
    }
}
