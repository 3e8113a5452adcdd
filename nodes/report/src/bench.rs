//! Run time against error (`augsplat bench`): per configuration of a grid and per method, the
//! compute seconds of every node the method's evaluation needs and its held-out error; per
//! method the Pareto front (no configuration both cheaper and better) and its knee; written as
//! a Markdown table, a JSON record and an HTML page with one scatter plot per method.
//!
//! [`sweep`] writes the pipeline the bench runs (the grid as its sweep), [`cost`] attributes
//! the run's compute seconds and held-out errors to each configuration and method, and
//! [`BenchTable`] holds the result and writes its files.

pub mod cost;
pub mod sweep;

use crate::error::ReportError;
use crate::svg::{self, escape, Chart, LabeledPoint};
use augsplat_core::bench_record;
pub use augsplat_core::bench_record::civil_date;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One (configuration, method) measurement.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BenchPoint {
    /// The configuration (`steps=100,members=3`).
    pub config: String,
    /// The method's label (`3DGS`, `Dual`, `Ensemble median`).
    pub method: String,
    /// Compute seconds of every node the method's evaluation needs, upstream included, each
    /// as its cache record says (shared nodes count in every configuration that needs them).
    pub seconds: f64,
    /// Held-out error at the evaluated checkpoint: the average error when LPIPS weights were
    /// connected, else the MSE (see [`BenchTable::error_name`]).
    pub error: f64,
    /// Held-out PSNR, dB.
    pub psnr: f64,
    /// Nodes counted in `seconds`.
    pub nodes: usize,
    /// What skipping saved, estimated from the training's own step times (see [`Savings`]).
    #[serde(default, skip_serializing_if = "Savings::is_empty")]
    pub saved: Savings,
}

/// Seconds a method's training did not spend because it skipped work, estimated from the
/// step times its node measured (its cache record's `measures`), not included in
/// [`BenchPoint::seconds`]. Each is `None` when the skip did not happen.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Savings {
    /// The early stop: the steps not run × the mean time of the kind of step (with or
    /// without synthetic views) the run ended on. Evaluations it would have run are not
    /// counted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub early_stop: Option<f64>,
    /// Dual's synthetic branch switching off (`off_below`): the steps run after the switch ×
    /// (mean step time with synthetic views − mean step time without).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub branch_off: Option<f64>,
}

impl Savings {
    /// Whether nothing was skipped (serde's `skip_serializing_if`).
    pub fn is_empty(&self) -> bool {
        self.early_stop.is_none() && self.branch_off.is_none()
    }

    /// From a training node's measures (`steps_requested`, `steps_run`, `synthetic_steps`,
    /// `synthetic_step_seconds`, `real_only_steps`, `real_only_step_seconds`, optional
    /// `synthetic_off_step` and `last_step_synthetic`); empty when they are missing.
    pub fn from_measures(m: &std::collections::BTreeMap<String, f64>) -> Savings {
        let get = |k: &str| m.get(k).copied();
        let (Some(req), Some(run), Some(ns), Some(ts), Some(nr), Some(tr)) = (
            get("steps_requested"),
            get("steps_run"),
            get("synthetic_steps"),
            get("synthetic_step_seconds"),
            get("real_only_steps"),
            get("real_only_step_seconds"),
        ) else {
            return Savings::default();
        };
        let mean = |t: f64, n: f64| (n > 0.0).then(|| t / n);
        let (synth, real) = (mean(ts, ns), mean(tr, nr));
        let early_stop = (run < req)
            .then(|| {
                let rate = if get("last_step_synthetic") == Some(1.0) {
                    synth
                } else {
                    real.or(synth)
                };
                rate.map(|r| (req - run) * r)
            })
            .flatten();
        let branch_off = get("synthetic_off_step").and_then(|off| {
            let (s, r) = (synth?, real?);
            Some(((run - off).max(0.0) * (s - r)).max(0.0))
        });
        Savings {
            early_stop,
            branch_off,
        }
    }

    /// `early stop 12.3 s; branch off 4.50 s`, or empty.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if let Some(s) = self.early_stop {
            parts.push(format!("early stop {} s", seconds(s)));
        }
        if let Some(s) = self.branch_off {
            parts.push(format!("branch off {} s", seconds(s)));
        }
        parts.join("; ")
    }
}

/// Where and when the bench ran.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Machine {
    /// CPU model name.
    pub cpu: String,
    /// Logical cores.
    pub cores: usize,
    /// Vector instruction sets found (`avx2`, `fma`, `avx512f`, `neon`).
    pub isa: Vec<String>,
    /// UTC date (`YYYY-MM-DD`).
    pub date: String,
}

impl Machine {
    /// `CPU (N cores, avx2+fma)`.
    pub fn describe(&self) -> String {
        let isa = if self.isa.is_empty() {
            String::new()
        } else {
            format!(", {}", self.isa.join("+"))
        };
        format!("{} ({} cores{isa})", self.cpu, self.cores)
    }

    /// This machine, now (the CPU model, cores and date of [`bench_record`]).
    pub fn this() -> Machine {
        let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let flags: Vec<&str> = info
            .lines()
            .find(|l| l.starts_with("flags") || l.starts_with("Features"))
            .and_then(|l| l.split_once(':'))
            .map(|(_, v)| v.split_whitespace().collect())
            .unwrap_or_default();
        let isa = ["avx2", "fma", "avx512f", "neon", "asimd"]
            .iter()
            .filter(|f| flags.contains(f))
            .map(|f| f.to_string())
            .collect();
        Machine {
            cpu: bench_record::cpu_model(),
            cores: bench_record::cores(),
            isa,
            date: bench_record::today(),
        }
    }
}

/// Seconds to three significant digits or whole seconds.
fn seconds(s: f64) -> String {
    if s < 10.0 {
        format!("{s:.2}")
    } else if s < 100.0 {
        format!("{s:.1}")
    } else {
        format!("{s:.0}")
    }
}

/// A whole bench.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BenchTable {
    /// The pipeline benched.
    pub pipeline: String,
    /// The grid, as given (`field.steps=[100,200]`).
    pub grid: Vec<String>,
    /// `average error` or `MSE`.
    pub error_name: String,
    /// The machine and date.
    pub machine: Machine,
    /// Every measurement, in configuration order, then method order.
    pub points: Vec<BenchPoint>,
    /// Evaluations a scene gate skipped: (configuration, evaluation node, compute seconds of
    /// what it needed, the gate included). They have no error, so no point.
    #[serde(default)]
    pub gated: Vec<(String, String, f64)>,
}

/// One method's Pareto front (indices into [`BenchTable::points`], by rising cost) and its
/// knee.
#[derive(Clone, Debug, PartialEq)]
pub struct Front {
    /// The method.
    pub method: String,
    /// The optimal points.
    pub front: Vec<usize>,
    /// The knee (an element of `front`).
    pub knee: Option<usize>,
}

/// The knee of a front given as (cost, error) points by rising cost: the point farthest below
/// the straight line from the cheapest to the most accurate point, both axes scaled to the
/// front's range (a front of one or two points: its most accurate point).
pub fn knee(front: &[(f64, f64)]) -> Option<usize> {
    let n = front.len();
    if n == 0 {
        return None;
    }
    if n <= 2 {
        return Some(n - 1);
    }
    let (x0, y0) = front[0];
    let (x1, y1) = front[n - 1];
    let (sx, sy) = (
        (x1 - x0).max(f64::MIN_POSITIVE),
        (y0 - y1).max(f64::MIN_POSITIVE),
    );
    let mut best = (n - 1, 0.0);
    for (i, &(x, y)) in front.iter().enumerate() {
        let u = (x - x0) / sx; // 0 → 1
        let v = (y0 - y) / sy; // 0 → 1: error reduction
        let gain = v - u; // above the diagonal: more reduction than cost
        if gain > best.1 {
            best = (i, gain);
        }
    }
    Some(best.0)
}

impl BenchTable {
    /// The methods, in first-seen order.
    pub fn methods(&self) -> Vec<String> {
        let mut m: Vec<String> = Vec::new();
        for p in &self.points {
            if !m.contains(&p.method) {
                m.push(p.method.clone());
            }
        }
        m
    }

    /// Per method, its Pareto front over the configurations and the knee.
    pub fn fronts(&self) -> Vec<Front> {
        self.methods()
            .into_iter()
            .map(|method| {
                let idx: Vec<usize> = (0..self.points.len())
                    .filter(|&i| self.points[i].method == method)
                    .collect();
                let xy: Vec<(f64, f64)> = idx
                    .iter()
                    .map(|&i| (self.points[i].seconds, self.points[i].error))
                    .collect();
                let front: Vec<usize> = svg::pareto_front(&xy).iter().map(|&k| idx[k]).collect();
                let fxy: Vec<(f64, f64)> = front
                    .iter()
                    .map(|&i| (self.points[i].seconds, self.points[i].error))
                    .collect();
                let knee = knee(&fxy).map(|k| front[k]);
                Front {
                    method,
                    front,
                    knee,
                }
            })
            .collect()
    }

    /// The table's column names.
    fn header(&self) -> Vec<String> {
        [
            "method",
            "configuration",
            "seconds",
            &self.error_name,
            "PSNR",
            "nodes",
            "saved (est.)",
            "front",
        ]
        .map(String::from)
        .to_vec()
    }

    /// The table's rows, method by method: seconds, error and PSNR per configuration, with
    /// the front (`*`) and the knee (`* knee`) marked.
    fn rows(&self) -> Vec<Vec<String>> {
        let mut rows = Vec::new();
        for f in self.fronts() {
            for (i, p) in self.points.iter().enumerate() {
                if p.method != f.method {
                    continue;
                }
                let mark = if f.knee == Some(i) {
                    "* knee"
                } else if f.front.contains(&i) {
                    "*"
                } else {
                    ""
                };
                rows.push(vec![
                    p.method.clone(),
                    p.config.clone(),
                    seconds(p.seconds),
                    format!("{:.4}", p.error),
                    format!("{:.2}", p.psnr),
                    p.nodes.to_string(),
                    p.saved.describe(),
                    mark.to_string(),
                ]);
            }
        }
        rows
    }

    /// The Markdown table (one row per method and configuration) after a paragraph naming
    /// the pipeline, the grid, the machine and the definitions.
    pub fn markdown(&self) -> String {
        let mut out = format!(
            "Bench of `{}` over {} — {}, {}.\n\nCost: compute seconds of every node a method's evaluation needs, from the cache records. Error: held-out {} at the evaluated checkpoint. Saved (est.): seconds the training skipped — an early stop's steps not run, Dual's steps after its synthetic branch switched off — at the run's own mean step times, not part of the cost. `*`: on the method's Pareto front; `knee`: the front's knee.\n\n",
            self.pipeline,
            self.grid.iter().map(|g| format!("`{g}`")).collect::<Vec<_>>().join(", "),
            self.machine.describe(),
            self.machine.date,
            self.error_name
        );
        let line = |cells: &[String]| format!("| {} |\n", cells.join(" | "));
        out.push_str(&line(&self.header()));
        out.push_str("|---|---|---:|---:|---:|---:|---|---|\n");
        for r in self.rows() {
            out.push_str(&line(&r));
        }
        if !self.gated.is_empty() {
            out.push_str("\nSkipped by the scene gate (no error to measure; cost of what ran for it, the gate included):\n\n");
            for (config, node, secs) in &self.gated {
                out.push_str(&format!("- `{config}`: `{node}` ({})\n", seconds(*secs)));
            }
        }
        out
    }

    /// Writes `bench.md` ([`BenchTable::markdown`]), `bench.html` ([`BenchTable::html`]) and
    /// `bench.json` (the table itself) into `out`, and returns the Markdown.
    pub fn write_files(&self, out: &Path) -> Result<String, ReportError> {
        let write = |name: &str, text: String| {
            let p = out.join(name);
            std::fs::write(&p, text)
                .map_err(|e| ReportError::Message(format!("writing {}: {e}", p.display())))
        };
        let md = self.markdown();
        write("bench.md", md.clone())?;
        write("bench.html", self.html())?;
        let json =
            serde_json::to_string_pretty(self).map_err(|e| ReportError::Message(e.to_string()))?;
        write("bench.json", json)?;
        Ok(md)
    }

    /// A self-contained HTML page: the table and one scatter plot (seconds against error,
    /// front dashed) per method.
    pub fn html(&self) -> String {
        let mut charts = String::new();
        for (g, method) in self.methods().iter().enumerate() {
            let pts: Vec<LabeledPoint> = self
                .points
                .iter()
                .filter(|p| &p.method == method)
                .map(|p| LabeledPoint {
                    label: p.config.clone(),
                    group: g,
                    x: p.seconds,
                    y: p.error,
                })
                .collect();
            let chart = Chart::new(method, "compute seconds", &self.error_name);
            charts.push_str(&svg::scatter_chart(
                &chart,
                &pts,
                std::slice::from_ref(method),
                true,
            ));
        }
        let cells = |tag: &str, r: &[String]| {
            let c: String = r
                .iter()
                .map(|c| format!("<{tag}>{}</{tag}>", escape(c)))
                .collect();
            format!("<tr>{c}</tr>\n")
        };
        let mut table = cells("th", &self.header());
        for r in self.rows() {
            table.push_str(&cells("td", &r));
        }
        format!(
            "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>augsplat bench: {p}</title>\n<style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 8px;text-align:right}}svg{{margin:1em 1em 0 0}}</style></head><body>\n<h1>Run time against error: {p}</h1>\n<p>{machine}, {date}. Grid: {grid}. Cost: compute seconds of every node a method's evaluation needs (cache records). Error: held-out {err}.</p>\n<div>{charts}</div>\n<table>\n{table}</table>\n</body></html>\n",
            p = escape(&self.pipeline),
            machine = escape(&self.machine.describe()),
            date = self.machine.date,
            grid = escape(&self.grid.join(", ")),
            err = escape(&self.error_name),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn measures(pairs: &[(&str, f64)]) -> std::collections::BTreeMap<String, f64> {
        pairs.iter().map(|&(k, v)| (k.to_string(), v)).collect()
    }

    #[test]
    fn savings_come_from_the_measured_step_times() {
        // Dual: 100 synthetic steps at 0.5 s, then 300 real-only at 0.1 s, off after step 100.
        let m = measures(&[
            ("steps_requested", 400.0),
            ("steps_run", 400.0),
            ("synthetic_steps", 100.0),
            ("synthetic_step_seconds", 50.0),
            ("real_only_steps", 300.0),
            ("real_only_step_seconds", 30.0),
            ("synthetic_off_step", 100.0),
        ]);
        let s = Savings::from_measures(&m);
        assert_eq!(s.early_stop, None);
        assert!((s.branch_off.unwrap() - 300.0 * 0.4).abs() < 1e-9, "{s:?}");
        // The same, stopped early at step 250 (last step real-only): 150 steps × 0.1 s.
        let mut m2 = m.clone();
        m2.insert("steps_run".into(), 250.0);
        m2.insert("real_only_steps".into(), 150.0);
        m2.insert("real_only_step_seconds".into(), 15.0);
        let s = Savings::from_measures(&m2);
        assert!((s.early_stop.unwrap() - 15.0).abs() < 1e-9, "{s:?}");
        assert!((s.branch_off.unwrap() - 150.0 * 0.4).abs() < 1e-9, "{s:?}");
        // Stopped while still rendering synthetic views: at the synthetic rate.
        let mut m3 = m2.clone();
        m3.remove("synthetic_off_step");
        m3.insert("last_step_synthetic".into(), 1.0);
        let s = Savings::from_measures(&m3);
        assert!((s.early_stop.unwrap() - 150.0 * 0.5).abs() < 1e-9, "{s:?}");
        assert_eq!(s.branch_off, None);
        // No measures (an older cache record): nothing claimed.
        assert!(Savings::from_measures(&measures(&[])).is_empty());
        assert_eq!(s.describe(), "early stop 75.0 s");
    }

    fn table(points: &[(&str, &str, f64, f64)]) -> BenchTable {
        BenchTable {
            pipeline: "p.ron".into(),
            grid: vec!["a=[1,2]".into()],
            error_name: "MSE".into(),
            machine: Machine {
                cpu: "cpu".into(),
                cores: 2,
                isa: vec!["avx2".into()],
                date: "2026-11-25".into(),
            },
            points: points
                .iter()
                .map(|&(c, m, s, e)| BenchPoint {
                    config: c.into(),
                    method: m.into(),
                    seconds: s,
                    error: e,
                    psnr: 20.0,
                    nodes: 3,
                    saved: Savings::default(),
                })
                .collect(),
            gated: Vec::new(),
        }
    }

    #[test]
    fn fronts_and_knees_on_a_constructed_set() {
        // Method A: (10, 0.5) (20, 0.2) (40, 0.15) (30, 0.3) dominated by (20, 0.2);
        // (15, 0.5) dominated by (10, 0.5).
        let t = table(&[
            ("c1", "A", 10.0, 0.5),
            ("c2", "A", 20.0, 0.2),
            ("c3", "A", 30.0, 0.3),
            ("c4", "A", 40.0, 0.15),
            ("c5", "A", 15.0, 0.5),
            ("c1", "B", 5.0, 1.0),
            ("c2", "B", 5.0, 0.9),
        ]);
        let f = t.fronts();
        assert_eq!(f[0].method, "A");
        assert_eq!(f[0].front, vec![0, 1, 3]);
        assert_eq!(f[0].knee, Some(1), "most of the gain for half the cost");
        assert_eq!(f[1].front, vec![6], "equal cost: the lower error only");
        assert_eq!(f[1].knee, Some(6));
        let md = t.markdown();
        assert!(
            md.contains("| A | c2 | 20.0 | 0.2000 | 20.00 | 3 |  | * knee |"),
            "{md}"
        );
        assert!(
            md.contains("| A | c3 | 30.0 | 0.3000 | 20.00 | 3 |  |  |"),
            "{md}"
        );
        assert!(md.contains("| B | c2 | 5.00 | 0.9000 |"), "{md}");
        let html = t.html();
        assert_eq!(html.matches("<svg").count(), 2);
        assert!(html.contains("class=\"pareto\""));
        assert!(
            html.contains("<td>c2</td><td>20.0</td><td>0.2000</td>"),
            "{html}"
        );
        assert_eq!(html.matches("<td>* knee</td>").count(), 2);
    }

    #[test]
    fn the_files_hold_the_markdown_the_page_and_the_table() {
        let dir = tempfile::tempdir().unwrap();
        let t = table(&[("c1", "A", 10.0, 0.5), ("c2", "A", 20.0, 0.2)]);
        let md = t.write_files(dir.path()).unwrap();
        assert_eq!(md, t.markdown());
        let read = |f: &str| std::fs::read_to_string(dir.path().join(f)).unwrap();
        assert_eq!(read("bench.md"), md);
        assert_eq!(read("bench.html"), t.html());
        let back: BenchTable = serde_json::from_str(&read("bench.json")).unwrap();
        assert_eq!(back, t);
        let e = t.write_files(&dir.path().join("absent")).unwrap_err();
        assert!(e.to_string().starts_with("writing "), "{e}");
    }

    #[test]
    fn knee_of_short_fronts_and_dates() {
        assert_eq!(knee(&[]), None);
        assert_eq!(knee(&[(1.0, 2.0)]), Some(0));
        assert_eq!(knee(&[(1.0, 2.0), (2.0, 1.0)]), Some(1));
        // A straight line has no point above the diagonal: the most accurate one.
        assert_eq!(knee(&[(0.0, 2.0), (1.0, 1.0), (2.0, 0.0)]), Some(2));
        assert_eq!(civil_date(0), "1970-01-01");
        assert_eq!(civil_date(20_417), "2025-11-25");
        assert_eq!(civil_date(11_016), "2000-02-29");
    }
}
