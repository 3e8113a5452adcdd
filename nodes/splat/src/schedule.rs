//! How real and synthetic supervision are mixed over a training run: the [`Schedule`]
//! (baseline 3DGS, AugSplat's Staged and Dual) and the [`StepPlan`] it gives each step. Pure
//! functions of the step, checked against their closed forms by the tests.

use serde::{Deserialize, Serialize};

fn d_warmup() -> u64 {
    300
}
fn d_batch() -> usize {
    20
}
fn d_true() -> bool {
    true
}
fn d_w_nerf0() -> f64 {
    2.0
}
fn d_w_real() -> f64 {
    1.0
}
fn d_quarter() -> f64 {
    300.0
}
fn d_off_below() -> Option<f64> {
    Some(0.1)
}

/// How real and synthetic supervision are mixed over the run. Omitted variant fields take
/// the paper's defaults (Staged 300 / 20 / reset; Dual 2.0 / 1.0 / 300 / Some(0.1) / 20).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum Schedule {
    /// Real images only (3DGS).
    #[default]
    Baseline,
    /// Synthetic-only for exactly `warmup_steps` steps, then real only. At the switch, when
    /// `reset_at_switch`, opacities are clamped to at most 0.1 and the optimiser state is
    /// cleared (a fresh Adam), as the authors' code.
    Staged {
        /// Steps of synthetic-only supervision.
        #[serde(default = "d_warmup")]
        warmup_steps: u64,
        /// Synthetic views per step.
        #[serde(default = "d_batch")]
        synthetic_batch: usize,
        /// Reset opacities and optimiser state at the switch.
        #[serde(default = "d_true")]
        reset_at_switch: bool,
    },
    /// Both every step: `λ_nerf(t) = w̃/(w̃ + w_real)`, `w̃ = w_nerf0 · 4^(−t/D)`, the real
    /// weight `w_real/(w̃ + w_real)`. The synthetic branch is off once `w̃ < off_below`
    /// (authors' code: 0.1; `None` = never). `quarter_decay` D = 0 means the synthetic branch
    /// is off from step 0 (the limit of an infinitely fast decay), never NaN.
    Dual {
        /// w_nerf0.
        #[serde(default = "d_w_nerf0")]
        w_nerf0: f64,
        /// w_real.
        #[serde(default = "d_w_real")]
        w_real: f64,
        /// D, steps over which the synthetic weight quarters.
        #[serde(default = "d_quarter")]
        quarter_decay: f64,
        /// Switch the synthetic branch off when its raw weight drops below this.
        #[serde(default = "d_off_below")]
        off_below: Option<f64>,
        /// Synthetic views per step.
        #[serde(default = "d_batch")]
        synthetic_batch: usize,
        /// Ours, not the paper's: at the first step with the synthetic branch off, clamp
        /// opacities to at most 0.1 and clear the optimiser state, as Staged does at its
        /// switch (Gaussians that only the prior's views asked for then fade unless the real
        /// views keep them). Left out of the key when `false`.
        #[serde(default, skip_serializing_if = "is_false")]
        reset_at_off: bool,
    },
}

fn is_false(b: &bool) -> bool {
    !*b
}

/// What one step does, as decided by the [`Schedule`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepPlan {
    /// Weight of the real loss (0 = no real render this step).
    pub real_weight: f64,
    /// Weight of the synthetic loss (0 = no synthetic render this step).
    pub synthetic_weight: f64,
    /// Synthetic views rendered this step.
    pub synthetic_batch: usize,
    /// The first real-only step after synthetic ones (Staged's switch, Dual's switch-off);
    /// a reset asked for happens before it.
    pub switch: bool,
}

/// Dual's raw synthetic weight `w̃ = w_nerf0 · 4^(−t/D)`; 0 for D = 0 (see [`Schedule::Dual`]).
pub fn dual_raw_weight(w_nerf0: f64, quarter_decay: f64, step: u64) -> f64 {
    if quarter_decay <= 0.0 {
        return 0.0;
    }
    w_nerf0 * 4f64.powf(-(step as f64) / quarter_decay)
}

/// Dual's `λ_nerf(t) = w̃/(w̃ + w_real)` (without the `off_below` switch).
pub fn dual_lambda(w_nerf0: f64, w_real: f64, quarter_decay: f64, step: u64) -> f64 {
    let w = dual_raw_weight(w_nerf0, quarter_decay, step);
    if w + w_real <= 0.0 {
        return 0.0;
    }
    w / (w + w_real)
}

impl Schedule {
    /// Short name for reports: "3DGS", "Staged", "Dual".
    pub fn name(&self) -> &'static str {
        match self {
            Schedule::Baseline => "3DGS",
            Schedule::Staged { .. } => "Staged",
            Schedule::Dual { .. } => "Dual",
        }
    }
    /// Whether the schedule needs a synthetic source.
    pub fn needs_synthetic(&self) -> bool {
        !matches!(self, Schedule::Baseline)
    }
    /// Checks ranges.
    pub fn validate(&self) -> Result<(), String> {
        match *self {
            Schedule::Baseline => Ok(()),
            Schedule::Staged {
                synthetic_batch, ..
            } => {
                if synthetic_batch == 0 {
                    return Err("schedule Staged: synthetic_batch must be ≥ 1".into());
                }
                Ok(())
            }
            Schedule::Dual {
                w_nerf0,
                w_real,
                quarter_decay,
                off_below,
                synthetic_batch,
                ..
            } => {
                for (n, v) in [
                    ("w_nerf0", w_nerf0),
                    ("w_real", w_real),
                    ("quarter_decay", quarter_decay),
                ] {
                    if !v.is_finite() || v < 0.0 {
                        return Err(format!("schedule Dual: {n} = {v} must be finite and ≥ 0"));
                    }
                }
                if w_real <= 0.0 {
                    return Err("schedule Dual: w_real must be > 0".into());
                }
                if let Some(o) = off_below {
                    if !o.is_finite() || o < 0.0 {
                        return Err(format!(
                            "schedule Dual: off_below = {o} must be finite and ≥ 0"
                        ));
                    }
                }
                if synthetic_batch == 0 {
                    return Err("schedule Dual: synthetic_batch must be ≥ 1".into());
                }
                Ok(())
            }
        }
    }
    /// The plan of 0-based step `step`. Pure: tests check it against the closed forms.
    pub fn plan(&self, step: u64) -> StepPlan {
        let real_only = StepPlan {
            real_weight: 1.0,
            synthetic_weight: 0.0,
            synthetic_batch: 0,
            switch: false,
        };
        match *self {
            Schedule::Baseline => real_only,
            Schedule::Staged {
                warmup_steps,
                synthetic_batch,
                ..
            } => {
                if step < warmup_steps {
                    StepPlan {
                        real_weight: 0.0,
                        synthetic_weight: 1.0,
                        synthetic_batch,
                        switch: false,
                    }
                } else {
                    StepPlan {
                        switch: step == warmup_steps && warmup_steps > 0,
                        ..real_only
                    }
                }
            }
            Schedule::Dual {
                w_nerf0,
                w_real,
                quarter_decay,
                off_below,
                synthetic_batch,
                ..
            } => {
                let off_at = |t: u64| {
                    let raw = dual_raw_weight(w_nerf0, quarter_decay, t);
                    raw <= 0.0 || off_below.is_some_and(|o| raw < o)
                };
                let raw = dual_raw_weight(w_nerf0, quarter_decay, step);
                if off_at(step) {
                    return StepPlan {
                        switch: step > 0 && !off_at(step - 1),
                        ..real_only
                    };
                }
                let lam = raw / (raw + w_real);
                StepPlan {
                    real_weight: 1.0 - lam,
                    synthetic_weight: lam,
                    synthetic_batch,
                    switch: false,
                }
            }
        }
    }
}
