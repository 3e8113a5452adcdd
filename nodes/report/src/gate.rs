//! The `Gate` node: decides, from training views only, whether a scene is worth the radiance
//! field ensemble and Staged/Dual AugSplat, and writes the decision the engine's gates read
//! (`gate.json`, see `augsplat_graph::gate`).
//!
//! Its inputs are evaluations of cheap rehearsals run on a split *of the training views*
//! (`pipelines/gate.ron` builds them: a short 3DGS baseline, a short Dual AugSplat fed by one
//! short field, and that field's renders), measured on training views that the rehearsals did
//! not train on. No held-out view reaches any of them, so the decision cannot leak the test
//! set. The rule: run when the rehearsed method (or, with `criterion: Prior`, the field
//! itself) has an error at least `margin` (relative) below the rehearsed baseline's. With
//! `criterion: Choose` the gate rehearses both methods and picks one: the one with the lower
//! error when that error is at least `margin` below the baseline's, neither otherwise; its
//! `staged` and `dual` outputs then decide for each method and `decision` for what both
//! need (the ensemble).

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
    /// The rehearsed Staged (`staged` input) and Dual (`method` input) against the baseline:
    /// the one with the lower error runs when it is at least `margin` below the baseline's
    /// (Staged on a tie), neither otherwise.
    Choose,
}

/// The methods a [`GateCriterion::Choose`] gate picks from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum GatedMethod {
    /// Staged AugSplat.
    Staged,
    /// Dual AugSplat.
    Dual,
}

impl GatedMethod {
    /// The output that decides for this method.
    pub fn output(self) -> &'static str {
        match self {
            GatedMethod::Staged => "staged",
            GatedMethod::Dual => "dual",
        }
    }
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
    /// The rehearsed method's (Dual with `criterion: Choose`), when connected.
    pub method: Option<GateEvidence>,
    /// The rehearsed Staged's, when connected.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub staged: Option<GateEvidence>,
    /// The method a [`GateCriterion::Choose`] gate picked from the evidence (`None`: neither,
    /// or another criterion).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chosen: Option<GatedMethod>,
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

/// The rehearsals' labels and mean metrics, as the gate's inputs give them.
#[derive(Clone, Copy, Debug)]
pub struct Rehearsals<'a> {
    /// The rehearsed 3DGS baseline.
    pub baseline: (&'a str, &'a Metrics),
    /// The rehearsed method (Dual), when connected.
    pub method: Option<(&'a str, &'a Metrics)>,
    /// The rehearsed Staged, when connected.
    pub staged: Option<(&'a str, &'a Metrics)>,
    /// The rehearsal's field (median of its members), when connected.
    pub prior: Option<(&'a str, &'a Metrics)>,
}

/// Decides from the rehearsals' mean metrics (pure: the node's adapter reads the folders).
pub fn decide(
    args: &GateArgs,
    r: &Rehearsals<'_>,
    views: Vec<String>,
) -> Result<GateReport, String> {
    let all = [Some(r.baseline), r.method, r.staged, r.prior];
    let use_avg = all.iter().flatten().all(|(_, m)| m.avg_error.is_some());
    let metric = if use_avg { "avg_error" } else { "mse" };
    let base_err = error_of(r.baseline.1, use_avg);
    let evidence = |(label, m): (&str, &Metrics)| {
        let e = error_of(m, use_avg);
        GateEvidence {
            label: label.to_string(),
            error: e,
            relative: e / base_err - 1.0,
            metrics: m.clone(),
        }
    };
    let (compared, candidate) = compared(args.criterion, r, |x| error_of(x.1, use_avg))?;
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
        GateCriterion::Choose => "the better rehearsed method",
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
        baseline: evidence(r.baseline),
        method: r.method.map(evidence),
        staged: r.staged.map(evidence),
        prior: r.prior.map(evidence),
        chosen: candidate.filter(|_| helps),
        views,
    })
}

/// The rehearsal `criterion` compares with the baseline (for `Choose`, the one of Staged and
/// Dual with the lower `error`, Staged on a tie) and, for `Choose`, which method that is.
fn compared<'a>(
    criterion: GateCriterion,
    r: &Rehearsals<'a>,
    error: impl Fn((&'a str, &'a Metrics)) -> f64,
) -> Result<((&'a str, &'a Metrics), Option<GatedMethod>), String> {
    const NEEDS_METHOD: &str =
        "criterion Method needs the `method` input (an evaluation of the rehearsed method)";
    match criterion {
        GateCriterion::Method => Ok((r.method.ok_or(NEEDS_METHOD)?, None)),
        GateCriterion::Prior => Ok((
            r.prior.ok_or(
                "criterion Prior needs the `prior` input (an ensemble evaluation of the rehearsal's field)",
            )?,
            None,
        )),
        GateCriterion::Choose => {
            let (Some(staged), Some(dual)) = (r.staged, r.method) else {
                return Err("criterion Choose needs the `staged` and `method` inputs (evaluations of the rehearsed Staged and Dual)".into());
            };
            // NaN never wins: the comparison is false and Staged is kept only if Dual's is NaN.
            if error(dual) < error(staged) || error(staged).is_nan() {
                Ok((dual, Some(GatedMethod::Dual)))
            } else {
                Ok((staged, Some(GatedMethod::Staged)))
            }
        }
    }
}

impl GateReport {
    /// What the engine reads: `run` and a reason without measured numbers, the same for every
    /// "run" (forced or measured), so that gated nodes keep their keys while the decision
    /// stands.
    pub fn decision(&self, args: &GateArgs) -> augsplat_graph::gate::GateDecision {
        let what = match self.criterion {
            GateCriterion::Method => "method",
            GateCriterion::Prior => "prior",
            GateCriterion::Choose => "methods",
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

    /// What the engine reads for one method of a [`GateCriterion::Choose`] gate: run when the
    /// gate was forced to run, or when the evidence chose this method. The reason holds no
    /// measured number (see [`GateReport::decision`]).
    pub fn method_decision(
        &self,
        args: &GateArgs,
        method: GatedMethod,
    ) -> augsplat_graph::gate::GateDecision {
        let run = match args.force {
            Some(force) => force,
            None => self.chosen == Some(method),
        };
        let reason = if run {
            "the scene gate says run".to_string()
        } else if self.forced {
            "forced to skip by the pipeline's scene gate".to_string()
        } else if let Some(other) = self.chosen {
            format!(
                "skipped by the scene gate: the other rehearsed method ({other:?}) lowered the error more on training views held out of the rehearsal (evidence in the report)"
            )
        } else {
            format!(
                "skipped by the scene gate: neither rehearsed method lowered the error by {} % on training views held out of the rehearsal (evidence in the report)",
                100.0 * args.margin
            )
        };
        augsplat_graph::gate::GateDecision { run, reason }
    }

    /// The decision in a word or two: `run`, `run Staged`, `run Dual` or `skip`.
    pub fn verdict(&self) -> String {
        match (self.run, self.chosen) {
            (true, Some(m)) if !self.forced => format!("run {m:?}"),
            (true, _) => "run".to_string(),
            (false, _) => "skip".to_string(),
        }
    }

    /// The rehearsals' evidence in table order: baseline, Staged, the method, the prior.
    pub fn rows(&self) -> impl Iterator<Item = &GateEvidence> {
        [
            Some(&self.baseline),
            self.staged.as_ref(),
            self.method.as_ref(),
            self.prior.as_ref(),
        ]
        .into_iter()
        .flatten()
    }

    /// The decision and its evidence as Markdown (a heading, a sentence and a table).
    pub fn to_markdown(&self) -> String {
        let mut md = format!(
            "## Gate: {}\n\n{}\n\n| rehearsal | {} | vs baseline | PSNR | SSIM |\n|---|---:|---:|---:|---:|\n",
            self.verdict(),
            self.reason,
            self.metric
        );
        for e in self.rows() {
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
            InputDecl::optional("staged"),
            InputDecl::optional("prior"),
        ]
    }
    fn outputs(a: &GateArgs) -> Vec<String> {
        let mut out = vec!["decision".to_string()];
        if a.criterion == GateCriterion::Choose {
            out.extend([GatedMethod::Staged, GatedMethod::Dual].map(|m| m.output().to_string()));
        }
        out.push("evidence".into());
        out
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
        let staged = match ctx.optional_input("staged") {
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
        fn labelled(e: &EvalDir) -> (&str, &Metrics) {
            (e.metrics.label.as_str(), &e.metrics.mean)
        }
        let rehearsals = Rehearsals {
            baseline: labelled(&baseline),
            method: method.as_ref().map(labelled),
            staged: staged.as_ref().map(labelled),
            prior: prior
                .as_ref()
                .map(|p| ("field (rehearsal)", &p.median.mean)),
        };
        let report = decide(args, &rehearsals, views).map_err(NodeError::new)?;
        ctx.log(&report.reason);
        if args.criterion == GateCriterion::Choose {
            for m in [GatedMethod::Staged, GatedMethod::Dual] {
                let out = ctx.output(m.output())?;
                artifacts::write_json(
                    &out.join(files::DECISION),
                    &report.method_decision(args, m),
                )?;
            }
        }
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

    fn reh<'a>(
        baseline: (&'a str, &'a Metrics),
        method: Option<(&'a str, &'a Metrics)>,
        prior: Option<(&'a str, &'a Metrics)>,
    ) -> Rehearsals<'a> {
        Rehearsals {
            baseline,
            method,
            staged: None,
            prior,
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
            &reh(("3DGS", &b), Some(("Dual", &m(0.02, Some(0.098)))), None),
            views.clone(),
        )
        .unwrap();
        assert!(r.run, "{}", r.reason);
        assert_eq!(r.metric, "avg_error");
        assert!((r.method.as_ref().unwrap().relative + 0.02).abs() < 1e-12);
        // 0.5 % lower: below the 1 % margin, skipped.
        let r = decide(
            &args,
            &reh(("3DGS", &b), Some(("Dual", &m(0.02, Some(0.0995)))), None),
            views.clone(),
        )
        .unwrap();
        assert!(!r.run);
        assert!(r.reason.contains("skipped by the gate"), "{}", r.reason);
        // Without LPIPS anywhere the MSE decides.
        let r = decide(
            &args,
            &reh(
                ("3DGS", &m(0.010, None)),
                Some(("Dual", &m(0.009, Some(0.5)))),
                None,
            ),
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
        let e = decide(
            &p,
            &reh(("3DGS", &b), Some(("Dual", &b)), None),
            views.clone(),
        )
        .unwrap_err();
        assert!(e.contains("prior"), "{e}");
        let r = decide(
            &p,
            &reh(("3DGS", &b), None, Some(("field", &m(0.02, Some(0.2))))),
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
            &reh(("3DGS", &b), Some(("Dual", &m(0.02, Some(0.2)))), None),
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
            &reh(("3DGS", &m(0.0, None)), Some(("Dual", &b)), None),
            views,
        )
        .unwrap_err();
        assert!(e.contains("not usable"), "{e}");
    }

    #[test]
    fn choose_runs_the_better_rehearsed_method_or_neither() {
        let args = GateArgs {
            criterion: GateCriterion::Choose,
            ..GateArgs::default()
        };
        let views = vec!["a".to_string()];
        let b = m(0.010, Some(0.100));
        let choose = |staged: f64, dual: f64, args: &GateArgs| {
            let (s, d) = (m(0.01, Some(staged)), m(0.01, Some(dual)));
            let r = Rehearsals {
                baseline: ("3DGS", &b),
                method: Some(("Dual", &d)),
                staged: Some(("Staged", &s)),
                prior: None,
            };
            let report = decide(args, &r, views.clone()).unwrap();
            let runs = [GatedMethod::Staged, GatedMethod::Dual]
                .map(|x| report.method_decision(args, x).run);
            (report, runs)
        };
        // Staged 5 % lower, Dual 2 % lower: Staged alone runs (and the ensemble).
        let (r, runs) = choose(0.095, 0.098, &args);
        assert_eq!(r.chosen, Some(GatedMethod::Staged));
        assert!(r.run && r.reason.contains("(Staged)"), "{}", r.reason);
        assert_eq!(runs, [true, false]);
        let why = r.method_decision(&args, GatedMethod::Dual).reason;
        assert!(why.contains("other rehearsed method (Staged)"), "{why}");
        assert!(r.to_markdown().starts_with("## Gate: run Staged"));
        // Dual lower: Dual alone.
        let (r, runs) = choose(0.099, 0.090, &args);
        assert_eq!(r.chosen, Some(GatedMethod::Dual));
        assert_eq!(runs, [false, true]);
        // The better one is within the margin: neither, and no ensemble.
        let (r, runs) = choose(0.0995, 0.0999, &args);
        assert_eq!(r.chosen, None);
        assert!(!r.run);
        assert_eq!(runs, [false, false]);
        let why = r.method_decision(&args, GatedMethod::Staged).reason;
        assert!(why.contains("neither rehearsed method"), "{why}");
        // A run-run decision holds no number: the same bytes whichever method won.
        let (r1, _) = choose(0.095, 0.098, &args);
        let (r2, _) = choose(0.080, 0.098, &args);
        assert_eq!(
            r1.method_decision(&args, GatedMethod::Staged),
            r2.method_decision(&args, GatedMethod::Staged)
        );
        assert_eq!(r1.decision(&args), r2.decision(&args));
        // Forced open, both run whatever the evidence (the validation runs measure both).
        let forced = GateArgs {
            force: Some(true),
            ..args.clone()
        };
        let (r, runs) = choose(0.0995, 0.0999, &forced);
        assert!(r.run && !r.evidence_run);
        assert_eq!(runs, [true, true]);
        // Both inputs are needed.
        let r = Rehearsals {
            baseline: ("3DGS", &b),
            method: Some(("Dual", &b)),
            staged: None,
            prior: None,
        };
        let e = decide(&args, &r, views.clone()).unwrap_err();
        assert!(e.contains("`staged` and `method`"), "{e}");
        // The outputs a Choose gate has.
        assert_eq!(
            GateNode::outputs(&args),
            ["decision", "staged", "dual", "evidence"]
        );
        assert_eq!(
            GateNode::outputs(&GateArgs::default()),
            ["decision", "evidence"]
        );
    }
}
