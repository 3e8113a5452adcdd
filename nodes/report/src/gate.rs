//! The `Gate` node: decides, from training views only, whether a scene is worth the radiance
//! field ensemble and Staged/Dual AugSplat, and writes the decision the engine's gates read
//! (`gate.json`, see `augsplat_graph::gate`).
//!
//! Its inputs are evaluations of cheap rehearsals run on a split *of the training views*
//! (`pipelines/gate.ron` builds them: a short 3DGS baseline, a short Dual AugSplat fed by one
//! short field, and that field's renders), measured on training views that the rehearsals did
//! not train on. No held-out view reaches any of them, so the decision cannot leak the test
//! set. The rule: run when the rehearsed method (or, with `criterion: Prior`, the field
//! itself) has an error at least `margin` (relative) below the rehearsed baseline's.

use crate::ensemble::EnsembleMetrics;
use crate::evalset::{EvalDir, Metrics};
use augsplat_core::artifacts;
use augsplat_graph::{InputDecl, Node, NodeError, RunContext};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;

/// Which rehearsal the decision compares with the baseline's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum GateCriterion {
    /// The rehearsed method (Dual AugSplat with one short field) against the baseline: does
    /// the method help on this scene?
    #[default]
    Method,
    /// The field's own renders against the baseline: does the prior beat sparse-view 3DGS?
    Prior,
}

/// Args of [`GateNode`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GateArgs {
    /// What is compared with the baseline.
    pub criterion: GateCriterion,
    /// Relative error reduction required to run (0.01: the compared error must be at least
    /// 1 % below the baseline's).
    pub margin: f64,
    /// `Some(true)` / `Some(false)`: decide so whatever the evidence (it is still measured
    /// and reported); `None`: decide from the evidence.
    pub force: Option<bool>,
}

impl Default for GateArgs {
    fn default() -> Self {
        GateArgs {
            criterion: GateCriterion::Method,
            margin: 0.01,
            force: None,
        }
    }
}

/// The gate's evidence (`evidence/gate_evidence.json`): the decision with the measured reason,
/// the numbers behind it. The engine reads only [`GateReport::decision`] (`decision/gate.json`),
/// whose reason holds no measured number: a rehearsal that moves but decides the same leaves
/// every gated node's key unchanged.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GateReport {
    /// Whether the gated nodes run.
    pub run: bool,
    /// Why, in one sentence.
    pub reason: String,
    /// The criterion used.
    pub criterion: GateCriterion,
    /// Which error was compared: `avg_error` when every rehearsal has LPIPS, else `mse`.
    pub metric: String,
    /// The required relative reduction.
    pub margin: f64,
    /// Whether `force` decided.
    pub forced: bool,
    /// What the evidence alone says (equal to `run` unless forced).
    pub evidence_run: bool,
    /// The rehearsed baseline's error and metrics.
    pub baseline: GateEvidence,
    /// The rehearsed method's, when connected.
    pub method: Option<GateEvidence>,
    /// The field's (median of the rehearsal's members), when connected.
    pub prior: Option<GateEvidence>,
    /// The training views the rehearsals were measured on (none is a held-out view).
    pub views: Vec<String>,
}

/// One rehearsal's numbers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GateEvidence {
    /// Its label.
    pub label: String,
    /// The compared error.
    pub error: f64,
    /// Relative change against the baseline's error (negative: lower error).
    pub relative: f64,
    /// Its mean metrics.
    pub metrics: Metrics,
}

/// `Gate`: inputs `baseline` (an `Evaluate` output of the rehearsed 3DGS baseline), optional
/// `method` (an `Evaluate` output of the rehearsed method) and optional `prior` (an
/// `EvaluateEnsemble` output of the rehearsal's field renders); outputs `decision` (`gate.json`,
/// what the engine reads: connect `gate: "gate.decision"` on the nodes it decides for) and
/// `evidence` (`gate_evidence.json`, [`GateReport`], and `gate.md`; connect it to the report's
/// `gate` input).
pub struct GateNode;

/// File names of the outputs.
pub mod files {
    /// `decision`: what the engine reads (`augsplat_graph::gate::GATE_FILE`).
    pub const DECISION: &str = augsplat_graph::gate::GATE_FILE;
    /// `evidence`: the decision with its numbers ([`super::GateReport`]), read by the report.
    pub const EVIDENCE: &str = "gate_evidence.json";
    /// `evidence`: the same in words.
    pub const MARKDOWN: &str = "gate.md";
}

/// The error compared: average error when both have it, else MSE.
fn error_of(m: &Metrics, use_avg: bool) -> f64 {
    if use_avg {
        m.avg_error.unwrap_or(f64::NAN)
    } else {
        m.mse
    }
}

/// Decides from the rehearsals' mean metrics (pure: the node's adapter reads the folders).
pub fn decide(
    args: &GateArgs,
    baseline: (&str, &Metrics),
    method: Option<(&str, &Metrics)>,
    prior: Option<(&str, &Metrics)>,
    views: Vec<String>,
) -> Result<GateReport, String> {
    let compared = match args.criterion {
        GateCriterion::Method => method.ok_or(
            "criterion Method needs the `method` input (an evaluation of the rehearsed method)",
        )?,
        GateCriterion::Prior => prior.ok_or(
            "criterion Prior needs the `prior` input (an ensemble evaluation of the rehearsal's field)",
        )?,
    };
    let all = [Some(baseline), method, prior];
    let use_avg = all.iter().flatten().all(|(_, m)| m.avg_error.is_some());
    let metric = if use_avg { "avg_error" } else { "mse" };
    let base_err = error_of(baseline.1, use_avg);
    let evidence = |(label, m): (&str, &Metrics)| {
        let e = error_of(m, use_avg);
        GateEvidence {
            label: label.to_string(),
            error: e,
            relative: e / base_err - 1.0,
            metrics: m.clone(),
        }
    };
    let c = evidence(compared);
    if !(c.error.is_finite() && base_err.is_finite() && base_err > 0.0) {
        return Err(format!(
            "the rehearsals' errors are not usable ({metric}: baseline {base_err}, {} {})",
            c.label, c.error
        ));
    }
    let what = match args.criterion {
        GateCriterion::Method => "the rehearsed method",
        GateCriterion::Prior => "the rehearsed prior",
    };
    let helps = c.relative <= -args.margin;
    let measured = format!(
        "{what} ({}) has {metric} {:.4} against the baseline's {:.4} ({:+.1} %, needed ≤ {:+.1} %) on {} training view(s) left out of the rehearsals",
        c.label,
        c.error,
        base_err,
        100.0 * c.relative,
        -100.0 * args.margin,
        views.len()
    );
    let (run, reason) = match args.force {
        Some(true) => (true, format!("forced to run by the pipeline; {measured}")),
        Some(false) => (false, format!("forced to skip by the pipeline; {measured}")),
        None if helps => (true, format!("worth it: {measured}")),
        None => (
            false,
            format!("skipped by the gate, the prior is not worth its cost here: {measured}"),
        ),
    };
    Ok(GateReport {
        run,
        reason,
        criterion: args.criterion,
        metric: metric.into(),
        margin: args.margin,
        forced: args.force.is_some(),
        evidence_run: helps,
        baseline: evidence(baseline),
        method: method.map(evidence),
        prior: prior.map(evidence),
        views,
    })
}

impl GateReport {
    /// What the engine reads: `run` and a reason without measured numbers, the same for every
    /// "run" (forced or measured), so that gated nodes keep their keys while the decision
    /// stands.
    pub fn decision(&self, args: &GateArgs) -> augsplat_graph::gate::GateDecision {
        let what = match self.criterion {
            GateCriterion::Method => "method",
            GateCriterion::Prior => "prior",
        };
        let reason = if self.run {
            "the scene gate says run".to_string()
        } else if self.forced {
            "forced to skip by the pipeline's scene gate".to_string()
        } else {
            format!(
                "skipped by the scene gate: the rehearsed {what} did not lower the error by {} % \
                 on training views held out of the rehearsal (evidence in the report)",
                100.0 * args.margin
            )
        };
        augsplat_graph::gate::GateDecision {
            run: self.run,
            reason,
        }
    }

    /// The decision and its evidence as Markdown (a heading, a sentence and a table).
    pub fn to_markdown(&self) -> String {
        let mut md = format!(
            "## Gate: {}\n\n{}\n\n| rehearsal | {} | vs baseline | PSNR | SSIM |\n|---|---:|---:|---:|---:|\n",
            if self.run { "run" } else { "skip" },
            self.reason,
            self.metric
        );
        let rows = [
            Some(&self.baseline),
            self.method.as_ref(),
            self.prior.as_ref(),
        ];
        for e in rows.into_iter().flatten() {
            let _ = writeln!(
                md,
                "| {} | {:.4} | {:+.1} % | {:.2} | {:.3} |",
                e.label,
                e.error,
                100.0 * e.relative,
                e.metrics.psnr,
                e.metrics.ssim
            );
        }
        let _ = writeln!(
            md,
            "\nMeasured on the training views {} (rehearsals trained without them; no held-out view is read).",
            self.views.join(", ")
        );
        md
    }
}

impl Node for GateNode {
    const KIND: &'static str = "Gate";
    const VERSION: u32 = 2;
    type Args = GateArgs;

    fn inputs(_: &GateArgs) -> Vec<InputDecl> {
        vec![
            InputDecl::one("baseline"),
            InputDecl::optional("method"),
            InputDecl::optional("prior"),
        ]
    }
    fn outputs(_: &GateArgs) -> Vec<String> {
        vec!["decision".into(), "evidence".into()]
    }
    fn validate(a: &GateArgs) -> Result<(), String> {
        if !(0.0..1.0).contains(&a.margin) {
            return Err(format!("margin {} must be within [0, 1)", a.margin));
        }
        Ok(())
    }
    fn run(args: &GateArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let baseline = EvalDir::load(ctx.input("baseline")?)?;
        let method = match ctx.optional_input("method") {
            Some(d) => Some(EvalDir::load(d)?),
            None => None,
        };
        let prior: Option<EnsembleMetrics> = match ctx.optional_input("prior") {
            Some(d) => Some(artifacts::read_json(
                &d.join(crate::evalset::files::METRICS),
            )?),
            None => None,
        };
        let views = baseline
            .metrics
            .views
            .iter()
            .map(|v| v.name.clone())
            .collect();
        let report = decide(
            args,
            (&baseline.metrics.label, &baseline.metrics.mean),
            method
                .as_ref()
                .map(|m| (m.metrics.label.as_str(), &m.metrics.mean)),
            prior
                .as_ref()
                .map(|p| ("field (rehearsal)", &p.median.mean)),
            views,
        )
        .map_err(NodeError::new)?;
        ctx.log(&report.reason);
        let decision = ctx.output("decision")?;
        artifacts::write_json(&decision.join(files::DECISION), &report.decision(args))?;
        let evidence = ctx.output("evidence")?;
        artifacts::write_json(&evidence.join(files::EVIDENCE), &report)?;
        std::fs::write(evidence.join(files::MARKDOWN), report.to_markdown())?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(mse: f64, avg: Option<f64>) -> Metrics {
        Metrics {
            psnr: -10.0 * mse.log10(),
            ssim: 0.5,
            mse,
            lpips: avg.map(|_| 0.3),
            avg_error: avg,
        }
    }

    #[test]
    fn runs_only_when_the_compared_rehearsal_beats_the_baseline_by_the_margin() {
        let args = GateArgs::default();
        let views = vec!["a".to_string(), "b".to_string()];
        let b = m(0.010, Some(0.100));
        // 2 % lower: runs.
        let r = decide(
            &args,
            ("3DGS", &b),
            Some(("Dual", &m(0.02, Some(0.098)))),
            None,
            views.clone(),
        )
        .unwrap();
        assert!(r.run, "{}", r.reason);
        assert_eq!(r.metric, "avg_error");
        assert!((r.method.as_ref().unwrap().relative + 0.02).abs() < 1e-12);
        // 0.5 % lower: below the 1 % margin, skipped.
        let r = decide(
            &args,
            ("3DGS", &b),
            Some(("Dual", &m(0.02, Some(0.0995)))),
            None,
            views.clone(),
        )
        .unwrap();
        assert!(!r.run);
        assert!(r.reason.contains("skipped by the gate"), "{}", r.reason);
        // Without LPIPS anywhere the MSE decides.
        let r = decide(
            &args,
            ("3DGS", &m(0.010, None)),
            Some(("Dual", &m(0.009, Some(0.5)))),
            None,
            views.clone(),
        )
        .unwrap();
        assert_eq!(r.metric, "mse");
        assert!(r.run);
        // The prior criterion reads the prior, and needs it.
        let p = GateArgs {
            criterion: GateCriterion::Prior,
            ..GateArgs::default()
        };
        let e = decide(&p, ("3DGS", &b), Some(("Dual", &b)), None, views.clone()).unwrap_err();
        assert!(e.contains("prior"), "{e}");
        let r = decide(
            &p,
            ("3DGS", &b),
            None,
            Some(("field", &m(0.02, Some(0.2)))),
            views.clone(),
        )
        .unwrap();
        assert!(!r.run);
        // Forcing decides, and still reports the evidence.
        let f = GateArgs {
            force: Some(true),
            ..GateArgs::default()
        };
        let r = decide(
            &f,
            ("3DGS", &b),
            Some(("Dual", &m(0.02, Some(0.2)))),
            None,
            views.clone(),
        )
        .unwrap();
        assert!(r.run && r.forced && r.reason.contains("forced"));
        assert!(!r.evidence_run, "the evidence alone says skip");
        assert_eq!(r.decision(&f).reason, "the scene gate says run");
        let md = r.to_markdown();
        assert!(md.contains("| Dual | 0.2000 | +100.0 % |"), "{md}");
        // Unusable errors are an error, not a decision.
        let e = decide(
            &args,
            ("3DGS", &m(0.0, None)),
            Some(("Dual", &b)),
            None,
            views,
        )
        .unwrap_err();
        assert!(e.contains("not usable"), "{e}");
    }
}
