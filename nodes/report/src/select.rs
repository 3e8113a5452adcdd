//! Checkpoint selection from a training curve, as AugSplat reports results.
//!
//! The paper evaluates every 100 steps and reports (a) for each method the checkpoint with the
//! lowest *average error* `(MSE · sqrt(1 − SSIM) · LPIPS)^(1/3)` and (b) every method at the
//! *baseline's* best step. This module implements both over [`TrainingCurve`]s.
//!
//! Rules (documented because they decide reported numbers):
//! - **Criterion**: average error (lower is better) when every evaluation point of the curve
//!   carries a finite average error; otherwise PSNR (higher is better), and the selection says
//!   so in its note (LPIPS weights were unavailable during training).
//! - Points whose criterion value is not finite are skipped.
//! - **Tie-break**: among points with exactly equal criterion values, the *earliest* step wins
//!   (the cheaper model; with early stopping in mind).
//! - **Baseline-step lookup**: the point at exactly the baseline's best step when the curve has
//!   it; otherwise the latest point *before* that step (the checkpoint that existed then), and
//!   the result records that the match was not exact; `None` when the curve has no point at or
//!   before the step.

use augsplat_core::artifacts::{CurvePoint, TrainingCurve};
use serde::{Deserialize, Serialize};

/// What a best step was chosen by: the splat library's checkpoint criterion (one owner).
pub use augsplat_splat::fit::Criterion;

/// The best evaluation point of a curve.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BestStep {
    /// The chosen step.
    pub step: u64,
    /// What it was chosen by.
    pub criterion: Criterion,
    /// Why the fallback criterion was used, if it was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// The curve's evaluation at that step.
    pub point: CurvePoint,
}

/// A method's evaluation at the baseline's best step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AtBaselineStep {
    /// The baseline's label (from its curve).
    pub baseline_label: String,
    /// The baseline's best step and how it was chosen.
    pub baseline_best: BestStep,
    /// The step of this method's curve that was used.
    pub step: u64,
    /// Whether `step` equals the baseline's best step.
    pub exact: bool,
    /// This method's evaluation at `step`.
    pub point: CurvePoint,
}

/// The criterion a curve supports: average error when every point has a finite one.
pub fn criterion_for(curve: &TrainingCurve) -> Criterion {
    let all_avg = !curve.points.is_empty()
        && curve
            .points
            .iter()
            .all(|p| p.avg_error.is_some_and(f64::is_finite));
    if all_avg {
        Criterion::AvgError
    } else {
        Criterion::Psnr
    }
}

/// The best point of a curve by [`criterion_for`] (see the module rules), or `None` when no
/// point has a finite criterion value.
pub fn best_step(curve: &TrainingCurve) -> Option<BestStep> {
    let criterion = criterion_for(curve);
    // Score: lower is better.
    let score = |p: &CurvePoint| -> Option<f64> {
        let v = match criterion {
            Criterion::AvgError => p.avg_error?,
            Criterion::Psnr => -p.psnr,
        };
        v.is_finite().then_some(v)
    };
    let mut best: Option<(&CurvePoint, f64)> = None;
    for p in &curve.points {
        let Some(s) = score(p) else { continue };
        best = match best {
            None => Some((p, s)),
            Some((bp, bs)) => {
                if s < bs || (s == bs && p.step < bp.step) {
                    Some((p, s))
                } else {
                    Some((bp, bs))
                }
            }
        };
    }
    let (point, _) = best?;
    let note = match criterion {
        Criterion::AvgError => None,
        Criterion::Psnr => {
            let missing = curve
                .points
                .iter()
                .filter(|p| !p.avg_error.is_some_and(f64::is_finite))
                .count();
            Some(format!(
                "average error unavailable at {missing} of {} evaluations (no LPIPS weights during training): best step chosen by PSNR",
                curve.points.len()
            ))
        }
    };
    Some(BestStep {
        step: point.step,
        criterion,
        note,
        point: point.clone(),
    })
}

/// The point of `curve` at `step`: exact when present, otherwise the latest point before it
/// (`exact = false`); `None` when the curve has no point at or before `step`.
pub fn point_at_step(curve: &TrainingCurve, step: u64) -> Option<(CurvePoint, bool)> {
    if let Some(p) = curve.points.iter().find(|p| p.step == step) {
        return Some((p.clone(), true));
    }
    curve
        .points
        .iter()
        .filter(|p| p.step < step)
        .max_by_key(|p| p.step)
        .map(|p| (p.clone(), false))
}

/// This method's evaluation at the baseline's best step (the paper's second comparison), or
/// `None` when the baseline has no best step or this curve nothing at or before it.
pub fn at_baseline_step(curve: &TrainingCurve, baseline: &TrainingCurve) -> Option<AtBaselineStep> {
    let baseline_best = best_step(baseline)?;
    let (point, exact) = point_at_step(curve, baseline_best.step)?;
    Some(AtBaselineStep {
        baseline_label: baseline.label.clone(),
        step: point.step,
        exact,
        point,
        baseline_best,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pt(step: u64, psnr: f64, avg: Option<f64>) -> CurvePoint {
        CurvePoint {
            step,
            psnr,
            ssim: 0.5,
            lpips: avg.map(|_| 0.3),
            mse: 0.01,
            avg_error: avg,
            ..Default::default()
        }
    }

    fn curve(points: Vec<CurvePoint>) -> TrainingCurve {
        TrainingCurve {
            label: "m".into(),
            points,
        }
    }

    #[test]
    fn best_by_avg_error_not_by_psnr() {
        // Step 200 has the best PSNR, step 300 the lowest average error: the paper's rule
        // picks 300.
        let c = curve(vec![
            pt(100, 15.0, Some(0.30)),
            pt(200, 19.0, Some(0.25)),
            pt(300, 18.0, Some(0.20)),
            pt(400, 17.0, Some(0.22)),
        ]);
        let b = best_step(&c).unwrap();
        assert_eq!(b.step, 300);
        assert_eq!(b.criterion, Criterion::AvgError);
        assert!(b.note.is_none());
    }

    #[test]
    fn ties_pick_the_earliest_step() {
        let c = curve(vec![
            pt(100, 15.0, Some(0.3)),
            pt(200, 15.0, Some(0.2)),
            pt(300, 15.0, Some(0.2)),
        ]);
        assert_eq!(best_step(&c).unwrap().step, 200);
        // Same with the PSNR fallback, and regardless of point order in the file.
        let c = curve(vec![
            pt(300, 18.0, None),
            pt(100, 18.0, None),
            pt(200, 17.0, None),
        ]);
        assert_eq!(best_step(&c).unwrap().step, 100);
    }

    #[test]
    fn psnr_fallback_when_lpips_missing_anywhere() {
        let c = curve(vec![
            pt(100, 15.0, Some(0.1)),
            pt(200, 19.0, None),
            pt(300, 18.0, Some(0.2)),
        ]);
        let b = best_step(&c).unwrap();
        assert_eq!(b.step, 200);
        assert_eq!(b.criterion, Criterion::Psnr);
        let note = b.note.unwrap();
        assert!(note.contains("1 of 3"), "{note}");
        assert!(note.contains("PSNR"), "{note}");
    }

    #[test]
    fn non_finite_points_are_skipped_and_empty_curves_have_no_best() {
        let c = curve(vec![
            pt(100, f64::NAN, None),
            pt(200, 16.0, None),
            pt(300, f64::INFINITY, None),
        ]);
        assert_eq!(best_step(&c).unwrap().step, 200);
        assert!(best_step(&curve(vec![])).is_none());
        assert!(best_step(&curve(vec![pt(1, f64::NAN, None)])).is_none());
        let c = curve(vec![
            pt(100, 15.0, Some(f64::NAN)),
            pt(200, 14.0, Some(0.5)),
        ]);
        // A NaN average error makes the curve fall back to PSNR.
        assert_eq!(best_step(&c).unwrap().criterion, Criterion::Psnr);
        assert_eq!(best_step(&c).unwrap().step, 100);
    }

    #[test]
    fn baseline_step_lookup_golden() {
        let baseline = TrainingCurve {
            label: "3DGS".into(),
            points: vec![
                pt(100, 15.0, Some(0.30)),
                pt(200, 16.0, Some(0.21)),
                pt(300, 16.5, Some(0.22)),
            ],
        };
        let method = curve(vec![
            pt(100, 15.5, Some(0.28)),
            pt(200, 16.4, Some(0.20)),
            pt(300, 17.0, Some(0.18)),
        ]);
        let at = at_baseline_step(&method, &baseline).unwrap();
        assert_eq!(at.baseline_label, "3DGS");
        assert_eq!(at.baseline_best.step, 200);
        assert_eq!(at.step, 200);
        assert!(at.exact);
        assert_eq!(at.point.psnr, 16.4);
        // Coarser evaluation grid: the latest point before the baseline's step.
        let coarse = curve(vec![pt(150, 15.9, Some(0.25)), pt(250, 16.9, Some(0.19))]);
        let at = at_baseline_step(&coarse, &baseline).unwrap();
        assert_eq!((at.step, at.exact), (150, false));
        // Nothing at or before the step.
        let late = curve(vec![pt(250, 16.9, Some(0.19))]);
        assert!(at_baseline_step(&late, &baseline).is_none());
        assert!(point_at_step(&late, 250).unwrap().1);
    }
}
