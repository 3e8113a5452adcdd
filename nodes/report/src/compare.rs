//! Metric deltas across runs (ablation points): what `augsplat compare` prints.
//!
//! Each run is an eval folder ([`crate::evalset::EvalDir`]). One run is the reference (the first
//! by default); every run's metrics are shown with their difference to the reference
//! (`run − reference`, so positive is better for PSNR/SSIM and negative for the others).

use crate::evalset::{nonfinite, EvalDir, MetricKey, Metrics};
use crate::ReportError;
use serde_json::{json, Value};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Which numbers of a run are compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Source {
    /// The evaluated checkpoint's mean metrics at full resolution (`metrics.json` `mean`).
    #[default]
    Eval,
    /// The training curve's best step (lowest average error; PSNR fallback).
    Best,
    /// The training curve at the baseline's best step (runs evaluated with a baseline).
    Baseline,
}

impl Source {
    /// Parses `eval`, `best` or `baseline`.
    pub fn parse(s: &str) -> Result<Source, ReportError> {
        match s {
            "eval" => Ok(Source::Eval),
            "best" => Ok(Source::Best),
            "baseline" => Ok(Source::Baseline),
            other => Err(ReportError::Message(format!(
                "unknown metric source `{other}` (expected eval, best or baseline)"
            ))),
        }
    }
    /// The name accepted by [`Source::parse`].
    pub fn name(self) -> &'static str {
        match self {
            Source::Eval => "eval",
            Source::Best => "best",
            Source::Baseline => "baseline",
        }
    }
}

/// One run in a comparison.
#[derive(Clone, Debug, PartialEq)]
pub struct ComparedRun {
    /// Display label (the method label, with the folder name when labels repeat).
    pub label: String,
    /// The eval folder.
    pub path: PathBuf,
    /// The step the numbers belong to, when known.
    pub step: Option<u64>,
    /// Value per metric of [`Comparison::metrics`] (`None`: unavailable).
    pub values: Vec<Option<f64>>,
    /// `value − reference value` per metric (`None` when either is unavailable).
    pub deltas: Vec<Option<f64>>,
    /// Training seconds, when known.
    pub train_seconds: Option<f64>,
}

/// A comparison of several runs against a reference run.
#[derive(Clone, Debug, PartialEq)]
pub struct Comparison {
    /// Where the numbers come from.
    pub source: Source,
    /// The compared metrics, in column order.
    pub metrics: Vec<MetricKey>,
    /// Index of the reference run in `runs`.
    pub reference: usize,
    /// The runs, in the order given.
    pub runs: Vec<ComparedRun>,
}

fn numbers(run: &EvalDir, source: Source) -> Result<(Metrics, Option<u64>), ReportError> {
    let m = &run.metrics;
    match source {
        Source::Eval => Ok((m.mean.clone(), m.checkpoint_step)),
        Source::Best => m
            .best
            .as_ref()
            .map(|b| (Metrics::from_curve_point(&b.point), Some(b.step)))
            .ok_or_else(|| {
                ReportError::invalid(
                    &run.dir,
                    "has no best step (the model had no training curve)",
                )
            }),
        Source::Baseline => m
            .at_baseline
            .as_ref()
            .map(|b| (Metrics::from_curve_point(&b.point), Some(b.step)))
            .ok_or_else(|| {
                ReportError::invalid(
                    &run.dir,
                    "has no evaluation at a baseline's step (run Evaluate with a `baseline` input)",
                )
            }),
    }
}

/// Compares `runs` against `runs[reference]`.
pub fn compare(
    runs: &[EvalDir],
    reference: usize,
    source: Source,
) -> Result<Comparison, ReportError> {
    if runs.is_empty() {
        return Err(ReportError::Message(
            "nothing to compare: no runs given".into(),
        ));
    }
    if reference >= runs.len() {
        return Err(ReportError::Message(format!(
            "reference run {reference} out of range (there are {} runs)",
            runs.len()
        )));
    }
    let metrics = MetricKey::ALL.to_vec();
    let mut rows = Vec::with_capacity(runs.len());
    for run in runs {
        let (m, step) = numbers(run, source)?;
        let values: Vec<Option<f64>> = metrics.iter().map(|&k| m.get(k)).collect();
        rows.push((run, values, step));
    }
    let labels = display_labels(runs);
    let ref_values = rows[reference].1.clone();
    let runs = rows
        .into_iter()
        .zip(labels)
        .map(|((run, values, step), label)| {
            let deltas = values
                .iter()
                .zip(&ref_values)
                .map(|(v, r)| Some((*v)? - (*r)?))
                .collect();
            ComparedRun {
                label,
                path: run.dir.clone(),
                step,
                values,
                deltas,
                train_seconds: run.metrics.train_seconds,
            }
        })
        .collect();
    Ok(Comparison {
        source,
        metrics,
        reference,
        runs,
    })
}

/// Labels for display: the method label, plus, where labels repeat (or are empty), the
/// shortest trailing part of the folder path that tells the repeats apart — the folder name,
/// or e.g. `eval_dual@gamma=0.5/eval` for the `run --out` layout `<instance>/<output>`.
pub fn display_labels(runs: &[EvalDir]) -> Vec<String> {
    runs.iter()
        .map(|r| {
            let label = &r.metrics.label;
            let same: Vec<&EvalDir> = runs.iter().filter(|o| &o.metrics.label == label).collect();
            if same.len() == 1 && !label.is_empty() {
                return label.clone();
            }
            let dir = distinguishing_suffix(&r.dir, &same);
            if label.is_empty() {
                dir
            } else {
                format!("{label} [{dir}]")
            }
        })
        .collect()
}

/// The last `k` components of `path`, for the smallest `k` that no other folder of `group`
/// shares (the whole path when none does).
fn distinguishing_suffix(path: &std::path::Path, group: &[&EvalDir]) -> String {
    let parts = |p: &std::path::Path| -> Vec<String> {
        p.components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect()
    };
    let mine = parts(path);
    let others: Vec<Vec<String>> = group
        .iter()
        .filter(|o| o.dir != path)
        .map(|o| parts(&o.dir))
        .collect();
    let tail = |v: &[String], k: usize| v[v.len().saturating_sub(k)..].join("/");
    for k in 1..=mine.len() {
        let t = tail(&mine, k);
        if others.iter().all(|o| tail(o, k) != t) {
            return t;
        }
    }
    path.display().to_string()
}

fn signed(key: MetricKey, d: f64) -> String {
    if d.is_nan() {
        return "nan".into();
    }
    let s = key.format(d);
    if d > 0.0 || (d == 0.0 && d.is_sign_positive()) {
        format!("+{s}")
    } else {
        s
    }
}

impl Comparison {
    /// A plain-text table: one row per run, each metric as `value (Δ)`; the reference row is
    /// marked with `*`, and deltas that improve on the reference with `▲`, worsen with `▼`.
    pub fn to_text(&self) -> String {
        let mut header = vec!["run".to_string(), "step".to_string()];
        for k in &self.metrics {
            header.push(format!(
                "{} {}",
                k.title(),
                if k.higher_is_better() { "↑" } else { "↓" }
            ));
        }
        header.push("train s".into());
        let mut table = vec![header];
        for (i, run) in self.runs.iter().enumerate() {
            let mut row = vec![
                format!(
                    "{}{}",
                    if i == self.reference { "* " } else { "  " },
                    run.label
                ),
                run.step
                    .map(|s| s.to_string())
                    .unwrap_or_else(|| "—".into()),
            ];
            for (c, key) in self.metrics.iter().enumerate() {
                let cell = match (run.values[c], run.deltas[c]) {
                    (None, _) => "—".to_string(),
                    (Some(v), _) if i == self.reference => key.format(v),
                    (Some(v), None) => key.format(v),
                    (Some(v), Some(d)) => {
                        let arrow = if d == 0.0 || d.is_nan() {
                            " "
                        } else if (d > 0.0) == key.higher_is_better() {
                            "▲"
                        } else {
                            "▼"
                        };
                        format!("{} ({}{arrow})", key.format(v), signed(*key, d))
                    }
                };
                row.push(cell);
            }
            row.push(
                run.train_seconds
                    .map(|s| format!("{s:.1}"))
                    .unwrap_or_else(|| "—".into()),
            );
            table.push(row);
        }
        let cols = table[0].len();
        let widths: Vec<usize> = (0..cols)
            .map(|c| {
                table
                    .iter()
                    .map(|r| r[c].chars().count())
                    .max()
                    .unwrap_or(0)
            })
            .collect();
        let mut out = format!(
            "metrics: {} (Δ = run − reference; * = reference)\n",
            match self.source {
                Source::Eval => "evaluated checkpoint, mean over test views",
                Source::Best => "training curve at each run's best step",
                Source::Baseline => "training curve at the baseline's best step",
            }
        );
        for row in &table {
            let mut line = String::new();
            for (c, cell) in row.iter().enumerate() {
                let pad = widths[c] - cell.chars().count();
                if c == 0 {
                    let _ = write!(line, "{cell}{}", " ".repeat(pad));
                } else {
                    let _ = write!(line, "  {}{cell}", " ".repeat(pad));
                }
            }
            out.push_str(line.trim_end());
            out.push('\n');
        }
        out
    }

    /// The comparison as JSON: `{source, reference, runs: [{label, path, step, train_seconds,
    /// metrics: {psnr: {value, delta}, …}}]}`; non-finite numbers as strings (`"inf"`).
    pub fn to_json(&self) -> Value {
        let num = |v: Option<f64>| match v {
            None => Value::Null,
            Some(v) if v.is_finite() => json!(v),
            Some(v) => Value::String(nonfinite::format_value(v)),
        };
        let runs: Vec<Value> = self
            .runs
            .iter()
            .map(|r| {
                let mut metrics = serde_json::Map::new();
                for (c, key) in self.metrics.iter().enumerate() {
                    metrics.insert(
                        key.key().into(),
                        json!({"value": num(r.values[c]), "delta": num(r.deltas[c])}),
                    );
                }
                json!({
                    "label": r.label,
                    "path": r.path.display().to_string(),
                    "step": r.step,
                    "train_seconds": num(r.train_seconds),
                    "metrics": Value::Object(metrics),
                })
            })
            .collect();
        json!({
            "source": self.source.name(),
            "reference": self.runs[self.reference].label,
            "runs": runs,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evalset::{EvalMetrics, FORMAT_VERSION};

    fn run(label: &str, dir: &str, psnr: f64, lpips: Option<f64>) -> EvalDir {
        EvalDir {
            dir: PathBuf::from(dir),
            metrics: EvalMetrics {
                format: FORMAT_VERSION,
                label: label.into(),
                checkpoint: "best".into(),
                checkpoint_step: Some(300),
                train_psnr: None,
                lpips_net: Some("alex".into()),
                mean: Metrics {
                    psnr,
                    ssim: 0.6,
                    mse: 0.01,
                    lpips,
                    avg_error: lpips.map(|l| l / 2.0),
                },
                views: vec![],
                best: None,
                at_baseline: None,
                train_seconds: Some(12.0),
                primitives: None,
                eval_seconds: Some(1.0),
                device: None,
                notes: vec![],
            },
            curve: None,
        }
    }

    #[test]
    fn repeated_labels_show_the_shortest_distinguishing_path() {
        let runs = vec![
            run("3DGS", "out/eval_baseline/eval", 17.0, None),
            run("Dual", "out/eval_dual@gamma=0.5/eval", 18.0, None),
            run("Dual", "out/eval_dual@gamma=1.0/eval", 18.1, None),
            run("Staged", "x/a", 18.2, None),
            run("Staged", "y/b", 18.3, None),
            run("", "z/anon", 18.4, None),
        ];
        assert_eq!(
            display_labels(&runs),
            [
                "3DGS",
                "Dual [eval_dual@gamma=0.5/eval]",
                "Dual [eval_dual@gamma=1.0/eval]",
                "Staged [a]",
                "Staged [b]",
                "anon",
            ]
        );
    }

    #[test]
    fn deltas_against_the_reference_golden() {
        let runs = vec![
            run("3DGS", "a", 17.88, Some(0.625)),
            run("Dual", "b", 18.37, Some(0.631)),
            run("Dual", "c", 18.00, None),
        ];
        let c = compare(&runs, 0, Source::Eval).unwrap();
        assert_eq!(c.runs[1].label, "Dual [b]");
        assert_eq!(c.runs[0].label, "3DGS");
        let psnr = c
            .metrics
            .iter()
            .position(|k| *k == MetricKey::Psnr)
            .unwrap();
        let lp = c
            .metrics
            .iter()
            .position(|k| *k == MetricKey::Lpips)
            .unwrap();
        assert!((c.runs[1].deltas[psnr].unwrap() - 0.49).abs() < 1e-9);
        assert!((c.runs[1].deltas[lp].unwrap() - 0.006).abs() < 1e-9);
        assert_eq!(c.runs[2].deltas[lp], None);
        assert_eq!(c.runs[0].deltas[psnr], Some(0.0));
        let text = c.to_text();
        assert!(text.contains("* 3DGS"), "{text}");
        assert!(text.contains("18.37 (+0.49▲)"), "{text}");
        assert!(text.contains("0.631 (+0.006▼)"), "{text}");
        let j = c.to_json();
        assert_eq!(j["reference"], "3DGS");
        assert_eq!(j["runs"][1]["metrics"]["psnr"]["value"], 18.37);
        assert!(j["runs"][2]["metrics"]["lpips"]["value"].is_null());
    }

    #[test]
    fn infinite_psnr_and_bad_arguments() {
        let runs = vec![
            run("a", "a", 20.0, None),
            run("b", "b", f64::INFINITY, None),
        ];
        let c = compare(&runs, 0, Source::Eval).unwrap();
        assert_eq!(c.to_json()["runs"][1]["metrics"]["psnr"]["delta"], "inf");
        assert!(compare(&runs, 5, Source::Eval).is_err());
        assert!(compare(&[], 0, Source::Eval).is_err());
        let err = compare(&runs, 0, Source::Baseline).unwrap_err().to_string();
        assert!(err.contains("baseline"), "{err}");
        assert!(Source::parse("nope").is_err());
    }
}
