//! What a training run is asked to do: [`TrainArgs`] and its parts.

use crate::adam::LearningRates;
use crate::densify::DensifyArgs;
use crate::init::InitArgs;
use crate::loss::PixelLoss;
use crate::schedule::Schedule;
use crate::RenderSettings;
use serde::{Deserialize, Serialize};

/// Real-image loss parameters: `(1 − λ)·P + λ·(1 − SSIM)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RealLoss {
    /// λ, the SSIM share.
    pub ssim_lambda: f64,
    /// The pixel term P.
    pub kind: PixelLoss,
}

impl Default for RealLoss {
    fn default() -> Self {
        RealLoss {
            ssim_lambda: 0.2,
            kind: PixelLoss::L2,
        }
    }
}

/// Synthetic-supervision parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SyntheticArgs {
    /// Normalise the weighted L2 by the weight sum (else by the pixel count), see
    /// [`crate::loss::weighted_l2`].
    pub normalize_by_weight_sum: bool,
    /// Pixels whose weight is below this are neither rendered nor back-propagated (0 = render
    /// everything; tiles with no such pixel are skipped by the rasteriser).
    pub skip_below: f64,
    /// Also accumulate the densification statistic from synthetic renders.
    pub densify_from_synthetic: bool,
    /// Gather the densification statistic from each render's gradient divided by that
    /// render's loss weight (Dual's `1 − λ` for the real view, `λ / B` for a synthetic one),
    /// so a real view densifies at the baseline's rate while the synthetic branch is on.
    /// `false` (the paper's, as a gsplat trainer would do it): the statistic sees the
    /// weighted gradient. Left out of the key when `false`.
    #[serde(skip_serializing_if = "is_false")]
    pub unweighted_stats: bool,
}

fn is_false(b: &bool) -> bool {
    !*b
}

impl SyntheticArgs {
    /// The factor on a render's densification statistic when its loss was scaled by
    /// `scale`: 1 / `scale` with [`SyntheticArgs::unweighted_stats`], else 1.
    pub fn stat_factor(&self, scale: f64) -> f32 {
        if self.unweighted_stats && scale > 0.0 {
            (1.0 / scale) as f32
        } else {
            1.0
        }
    }
}

impl Default for SyntheticArgs {
    fn default() -> Self {
        SyntheticArgs {
            normalize_by_weight_sum: true,
            skip_below: 0.0,
            densify_from_synthetic: false,
            unweighted_stats: false,
        }
    }
}

/// The `OptimizeSplats` arguments (also the trainer's configuration).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainArgs {
    /// Optimisation steps.
    pub steps: u64,
    /// Evaluate the held-out views every this many steps (and after the last step).
    pub eval_every: u64,
    /// Maximum SH degree (storage and final active degree).
    pub sh_degree: u32,
    /// Active SH degree increases by one every this many steps (gsplat: 1000).
    pub sh_increase_every: u64,
    /// Background colour.
    pub background: [f32; 3],
    /// Per-pixel alpha clamp.
    pub max_alpha: f32,
    /// Antialiased rasterisation (mip-splatting compensation).
    pub antialiased: bool,
    /// Learning rates.
    pub learning_rates: LearningRates,
    /// Densification.
    pub densify: DensifyArgs,
    /// Initialisation.
    pub init: InitArgs,
    /// Real-image loss.
    pub real_loss: RealLoss,
    /// Supervision schedule.
    pub schedule: Schedule,
    /// Synthetic supervision options.
    pub synthetic: SyntheticArgs,
    /// Stop when the selection metric (average error, or PSNR without LPIPS) has not improved
    /// for this many evaluations.
    pub early_stop_patience: Option<u32>,
    /// Scene scale override (None: 1.1 × the largest distance of a training camera from the
    /// cameras' mean, as gsplat).
    pub scene_scale: Option<f64>,
    /// LPIPS backbone when the `lpips` input is connected: "alex" (AugSplat) or "vgg".
    pub lpips_net: String,
    /// Seed of every random choice.
    pub seed: u64,
    /// Method name for reports (empty: the schedule's name).
    pub label: String,
    /// Write wall-clock seconds into `curve.json` (off by default: with it the output bytes
    /// differ between runs; the node log always has the times).
    pub record_wall_time: bool,
    /// Where each view's render and backward pass run: `Cpu` (default) or `Gpu` (wgpu; the
    /// loss, Adam, densification and the held-out evaluations stay on the CPU). Left out of
    /// the serialised args when `Cpu`, so CPU keys did not change when it was added.
    #[serde(skip_serializing_if = "crate::Backend::is_cpu")]
    pub backend: crate::Backend,
    /// Which Gaussians each Adam step updates: `Dense` (all of them, gsplat
    /// `simple_trainer`'s default, and ours) or `Selective` (the visible ones). Left out of
    /// the serialised args when `Dense`.
    #[serde(skip_serializing_if = "crate::adam::AdamUpdates::is_dense")]
    pub adam: crate::adam::AdamUpdates,
    /// DropGaussian ([`crate::dropout`]): `Some((max_rate: 0.2))` drops Gaussians at random in
    /// every training render, at a rate rising to `max_rate`. CPU backend only. Left out of
    /// the serialised args when `None` (off), so no key of a run without it moved.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drop_gaussians: Option<crate::dropout::DropGaussian>,
}

impl Default for TrainArgs {
    fn default() -> Self {
        TrainArgs {
            steps: 3000,
            eval_every: 100,
            sh_degree: 3,
            sh_increase_every: 1000,
            background: [0.0; 3],
            max_alpha: crate::constants::MAX_ALPHA,
            antialiased: false,
            learning_rates: LearningRates::default(),
            densify: DensifyArgs::default(),
            init: InitArgs::default(),
            real_loss: RealLoss::default(),
            schedule: Schedule::Baseline,
            synthetic: SyntheticArgs::default(),
            early_stop_patience: None,
            scene_scale: None,
            lpips_net: "alex".into(),
            seed: 0,
            label: String::new(),
            record_wall_time: false,
            backend: crate::Backend::Cpu,
            adam: crate::adam::AdamUpdates::Dense,
            drop_gaussians: None,
        }
    }
}

impl TrainArgs {
    /// Checks every range.
    pub fn validate(&self) -> Result<(), String> {
        if self.sh_degree > 3 {
            return Err(format!("sh_degree = {} must be 0..=3", self.sh_degree));
        }
        if self.sh_increase_every == 0 {
            return Err("sh_increase_every must be ≥ 1".into());
        }
        if self.eval_every == 0 {
            return Err("eval_every must be ≥ 1".into());
        }
        if !(self.max_alpha > 0.0 && self.max_alpha <= 1.0) {
            return Err(format!("max_alpha = {} must be in (0, 1]", self.max_alpha));
        }
        if self.background.iter().any(|v| !v.is_finite()) {
            return Err("background must be finite".into());
        }
        if !(0.0..=1.0).contains(&self.real_loss.ssim_lambda) {
            return Err(format!(
                "real_loss.ssim_lambda = {} must be in [0, 1]",
                self.real_loss.ssim_lambda
            ));
        }
        if let Some(d) = &self.drop_gaussians {
            d.validate()?;
            if self.backend == crate::Backend::Gpu {
                return Err("drop_gaussians needs per-Gaussian opacity factors, which the GPU backend does not have yet: use backend: Cpu, or drop_gaussians: None".into());
            }
        }
        if !(self.synthetic.skip_below.is_finite() && self.synthetic.skip_below >= 0.0) {
            return Err(format!(
                "synthetic.skip_below = {} must be finite and ≥ 0",
                self.synthetic.skip_below
            ));
        }
        if let Some(s) = self.scene_scale {
            if !(s.is_finite() && s > 0.0) {
                return Err(format!("scene_scale = {s} must be positive"));
            }
        }
        if !matches!(
            self.lpips_net.to_ascii_lowercase().as_str(),
            "alex" | "alexnet" | "vgg" | "vgg16"
        ) {
            return Err(format!(
                "lpips_net = {:?} must be \"alex\" or \"vgg\"",
                self.lpips_net
            ));
        }
        self.learning_rates.validate()?;
        self.densify.validate()?;
        self.init.validate()?;
        self.schedule.validate()
    }
    /// The method's name for reports: `label`, or the schedule's name when it is empty.
    pub fn method_label(&self) -> String {
        if self.label.is_empty() {
            self.schedule.name().to_string()
        } else {
            self.label.clone()
        }
    }
    /// The active SH degree at 0-based step `step`.
    pub fn active_sh_degree(&self, step: u64) -> u32 {
        ((step / self.sh_increase_every.max(1)).min(self.sh_degree as u64)) as u32
    }
    /// Render settings at step `step`.
    pub fn render_settings(&self, step: u64) -> RenderSettings {
        RenderSettings {
            sh_degree: self.active_sh_degree(step),
            background: self.background,
            max_alpha: self.max_alpha,
            antialiased: self.antialiased,
            ..RenderSettings::default()
        }
    }
}
