//! The wall-time section of the report: bars per stage, run time against error with the
//! Pareto front, and error against training time, from the seconds the evaluations carry.

use crate::evalset::{EvalDir, MetricKey};
use crate::html::escape;
use crate::svg::{self, Chart, LabeledPoint};
use std::fmt::Write as _;

/// Whether any evaluation carries a wall time (training or evaluation).
pub(super) fn any_times(evals: &[EvalDir]) -> bool {
    evals
        .iter()
        .any(|e| e.metrics.train_seconds.is_some() || e.metrics.eval_seconds.is_some())
}

/// What the report says about wall time when no evaluation carries it.
pub const TIMES_ELSEWHERE: &str = "Wall times are not in this report, so that it is the same byte for byte on every run: `augsplat status` (and `augsplat run --summary-json`) lists the seconds each node took as the store recorded them. `record_wall_time: true` on OptimizeSplats and Evaluate writes them into their outputs instead, and this section then plots them.";

/// The wall-time section: bars per stage, run time vs error and error vs training time, and a
/// Markdown table, from the seconds the evaluations carry (`record_wall_time: true`); when none
/// does, only a note saying where the times are.
pub(super) fn time_section(evals: &[EvalDir], labels: &[String], md: &mut String) -> String {
    let mut out = String::from("<h2 id=\"time\">Wall time</h2>");
    if !any_times(evals) {
        // The store records each node's seconds beside its outputs, never in them: a report
        // holding them would differ from run to run. So the page says where to read them.
        out.push_str("<p class=\"note\">");
        // `code` spans of the Markdown become <code> elements.
        for (i, part) in TIMES_ELSEWHERE.split('`').enumerate() {
            if i % 2 == 1 {
                let _ = write!(out, "<code>{}</code>", escape(part));
            } else {
                out.push_str(&escape(part));
            }
        }
        out.push_str("</p>");
        let _ = write!(md, "## Wall time\n\n{TIMES_ELSEWHERE}\n\n");
        md.push_str("Plots, images and synthetic views: see `index.html`.\n");
        return out;
    }
    out.push_str("<div class=\"plots\">");
    let train: Vec<f64> = evals
        .iter()
        .map(|e| e.metrics.train_seconds.unwrap_or(f64::NAN))
        .collect();
    let eval: Vec<f64> = evals
        .iter()
        .map(|e| e.metrics.eval_seconds.unwrap_or(f64::NAN))
        .collect();
    out.push_str(&svg::bar_chart(
        &Chart::new("Wall time per stage", "seconds", ""),
        labels,
        &[
            ("training".into(), train.clone()),
            ("evaluation".into(), eval.clone()),
        ],
    ));
    // Run time vs error: average error when every run has it, PSNR otherwise.
    let use_avg = evals
        .iter()
        .all(|e| e.metrics.mean.avg_error.is_some_and(f64::is_finite));
    let (key, ylabel) = if use_avg {
        (MetricKey::AvgError, "average error (lower is better)")
    } else {
        (MetricKey::Psnr, "PSNR dB (higher is better)")
    };
    let points: Vec<LabeledPoint> = evals
        .iter()
        .zip(labels)
        .enumerate()
        .filter_map(|(i, (e, l))| {
            Some(LabeledPoint {
                label: l.clone(),
                group: i,
                x: e.metrics.train_seconds?,
                y: e.metrics.mean.get(key)?,
            })
        })
        .collect();
    out.push_str(&svg::scatter_chart(
        &Chart::new(
            "Run time vs error (Pareto front dashed)",
            "training seconds",
            ylabel,
        ),
        &points,
        labels,
        use_avg,
    ));
    // Along each training curve: error vs seconds.
    let series = super::curve_series(evals, labels, key, |p| p.seconds);
    out.push_str(&svg::line_chart(
        &Chart::new(
            "Error vs training time (curves)",
            "training seconds",
            ylabel,
        ),
        &series,
    ));
    out.push_str("</div>");
    md.push_str("## Wall time\n\n| Method | training s | evaluation s |\n|---|---:|---:|\n");
    let seconds = |v: f64| {
        if v.is_finite() {
            format!("{v:.1}")
        } else {
            "—".to_string()
        }
    };
    for ((l, t), ev) in labels.iter().zip(&train).zip(&eval) {
        let _ = writeln!(
            md,
            "| {} | {} | {} |",
            l.replace('|', "\\|"),
            seconds(*t),
            seconds(*ev)
        );
    }
    md.push_str("\nPlots, images and synthetic views: see `index.html`.\n");
    out
}
