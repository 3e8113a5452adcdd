//! What a run reports: the per-computation results as a summary, a table and the final
//! outputs, and the records a run leaves in the store (`runs/latest` for `why` and GC,
//! `runs/records` for every run).

use super::{CompResult, RunReport, Status};
use crate::error::EngineError;
use crate::resolve::{Plan, Source};
use crate::store::{hex, hostname, now_unix, Hash, Store};
use std::collections::BTreeMap;
use std::path::PathBuf;

impl RunReport {
    /// Whether every needed computation ran or was cached.
    pub fn success(&self) -> bool {
        self.results
            .iter()
            .flatten()
            .all(|r| matches!(r.status, Status::Ran | Status::Cached))
    }
    /// The failures: (instance name, message).
    pub fn failures(&self, plan: &Plan) -> Vec<(String, String)> {
        self.results
            .iter()
            .enumerate()
            .filter_map(|(c, r)| match r.as_ref().map(|r| &r.status) {
                Some(Status::Failed(m)) => {
                    Some((plan.comps[c].display_name(plan).to_string(), m.clone()))
                }
                _ => None,
            })
            .collect()
    }
    /// The folder of output `output` of the instance named `instance`, if it ran or was cached.
    pub fn output_dir(
        &self,
        plan: &Plan,
        store: &Store,
        instance: &str,
        output: &str,
    ) -> Option<PathBuf> {
        let inst = plan.instances.iter().find(|i| i.name == instance)?;
        let r = self.results[inst.comp].as_ref()?;
        r.outputs.get(output).map(|m| store.output_dir(m))
    }
    /// The results a run was for: the outputs of the instances matching `targets`, or, without
    /// targets, of the instances nothing else in the run consumes (the pipeline's sinks, e.g.
    /// each sweep point's report). One entry per (instance, output) that ran or was cached:
    /// (instance name, output name, its folder in the store), in pipeline order.
    pub fn final_outputs(
        &self,
        plan: &Plan,
        store: &Store,
        targets: &[String],
    ) -> Vec<(String, String, PathBuf)> {
        let n = plan.comps.len();
        let wanted: Vec<bool> = if targets.is_empty() {
            let mut consumed = vec![false; n];
            for (c, comp) in plan.comps.iter().enumerate() {
                if self.results.get(c).is_none_or(|r| r.is_none()) {
                    continue;
                }
                for slot in &comp.inputs {
                    for (src, _) in &slot.sources {
                        if let Source::Node { comp: up, .. } = src {
                            consumed[*up] = true;
                        }
                    }
                }
            }
            (0..n).map(|c| !consumed[c]).collect()
        } else {
            let mut w = vec![false; n];
            for t in targets {
                for i in plan.match_target(t) {
                    w[plan.instances[i].comp] = true;
                }
            }
            w
        };
        let mut out = Vec::new();
        for inst in &plan.instances {
            if !wanted[inst.comp] {
                continue;
            }
            let Some(r) = self.results.get(inst.comp).and_then(|r| r.as_ref()) else {
                continue;
            };
            if !matches!(r.status, Status::Ran | Status::Cached) {
                continue;
            }
            for (name, m) in &r.outputs {
                out.push((inst.name.clone(), name.clone(), store.output_dir(m)));
            }
        }
        out
    }
    /// `{"nodes":[{"name","kind","key","status","seconds"}..]}`: one entry per needed instance;
    /// `status` is `ran`, `cached` or `failed` (a node not run because an input failed is
    /// `failed` too); failed entries add `"error"` with the reason, gated ones (see
    /// [`crate::gate`]) `"gated"` with the gate's reason.
    pub fn summary_json(&self, plan: &Plan) -> serde_json::Value {
        let mut nodes = Vec::new();
        for inst in &plan.instances {
            let Some(r) = &self.results[inst.comp] else {
                continue;
            };
            // The summary's vocabulary is ran | cached | failed: a computation that did not
            // run because an input failed is reported as failed, with the reason.
            let (status, error) = match &r.status {
                Status::Failed(msg) => ("failed", Some(msg.clone())),
                Status::Skipped => ("failed", Some("not run: an input failed".to_string())),
                other => (other.as_str(), None),
            };
            let mut entry = serde_json::json!({
                "name": inst.name,
                "kind": plan.comps[inst.comp].node.kind(),
                "key": r.key.as_ref().map(hex).unwrap_or_default(),
                "status": status,
                "seconds": r.seconds,
            });
            if let Some(e) = error {
                entry["error"] = serde_json::Value::String(e);
            }
            if let Some(g) = &r.gated {
                entry["gated"] = serde_json::Value::String(g.clone());
            }
            nodes.push(entry);
        }
        serde_json::json!({ "nodes": nodes })
    }
    /// A text table: node, kind, cached/ran, seconds this run, seconds when computed (the
    /// cache record's for cached nodes), and the totals.
    pub fn table(&self, plan: &Plan) -> String {
        let mut rows = vec![(
            "node".to_string(),
            "kind".to_string(),
            "status".to_string(),
            "seconds".to_string(),
            "computed s".to_string(),
        )];
        for inst in &plan.instances {
            let Some(r) = &self.results[inst.comp] else {
                continue;
            };
            let status = if r.waited && r.status == Status::Cached {
                "cached (waited)".into()
            } else {
                r.status.as_str().to_string()
            };
            let status = match (&r.gated, r.status == Status::Cached) {
                (Some(_), true) => "gated (cached)".to_string(),
                (Some(_), false) => "gated".to_string(),
                (None, _) => status,
            };
            let computed = match r.status {
                Status::Ran | Status::Cached => format!("{:.2}", r.computed_seconds),
                _ => "—".to_string(),
            };
            rows.push((
                inst.name.clone(),
                plan.comps[inst.comp].node.kind().to_string(),
                status,
                format!("{:.2}", r.seconds),
                computed,
            ));
        }
        let w0 = rows.iter().map(|r| r.0.chars().count()).max().unwrap_or(0);
        let w1 = rows.iter().map(|r| r.1.len()).max().unwrap_or(0);
        let w2 = rows.iter().map(|r| r.2.len()).max().unwrap_or(0);
        let mut s = String::new();
        for (a, b, c, d, e) in rows {
            s.push_str(&format!("{a:w0$}  {b:w1$}  {c:w2$}  {d:>8}  {e:>10}\n"));
        }
        let (mut ran, mut cached, mut failed, mut gated) = (0, 0, 0, 0);
        for r in self.results.iter().flatten() {
            match r.status {
                Status::Ran | Status::Cached if r.gated.is_some() => gated += 1,
                Status::Ran => ran += 1,
                Status::Cached => cached += 1,
                _ => failed += 1,
            }
        }
        let gated = if gated > 0 {
            format!("{gated} gated, ")
        } else {
            String::new()
        };
        // Computations shared by several instances count once.
        let computed: f64 = self
            .results
            .iter()
            .flatten()
            .filter(|r| matches!(r.status, Status::Ran | Status::Cached))
            .map(|r| r.computed_seconds)
            .sum();
        s.push_str(&format!(
            "{ran} ran, {gated}{cached} cached, {failed} failed or skipped, {:.2} s \
             (sum of the needed nodes' compute times: {computed:.2} s)\n",
            self.seconds
        ));
        s
    }
}

/// A flattened view of typed args: leaf path -> JSON value (objects are walked, everything
/// else is a leaf).
pub fn flatten_args(v: &serde_json::Value) -> BTreeMap<String, serde_json::Value> {
    fn walk(v: &serde_json::Value, prefix: &str, out: &mut BTreeMap<String, serde_json::Value>) {
        match v {
            serde_json::Value::Object(m) if !m.is_empty() => {
                for (k, x) in m {
                    let p = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    walk(x, &p, out);
                }
            }
            _ => {
                out.insert(prefix.to_string(), v.clone());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(v, "", &mut out);
    out
}

/// The origin of arg `path` in a computation's written args, or `default` when not written.
pub fn arg_origin(plan: &Plan, c: usize, path: &str) -> String {
    let mut cur = &plan.comps[c].args_value;
    for seg in path.split('.').filter(|s| !s.is_empty()) {
        let next = match &cur.kind {
            crate::syntax::ValueKind::Struct(_, f) => {
                f.iter().find(|(n, _)| n == seg).map(|(_, v)| v)
            }
            crate::syntax::ValueKind::Map(e) => e
                .iter()
                .find(|(k, _)| k.as_str() == Some(seg))
                .map(|(_, v)| v),
            _ => None,
        };
        match next {
            Some(n) => cur = n,
            None => {
                return if std::ptr::eq(cur, &plan.comps[c].args_value) {
                    "default".into()
                } else {
                    cur.origin.to_string()
                }
            }
        }
    }
    cur.origin.to_string()
}

/// The per-instance record of a computation (kept in `runs/latest` for `why` and GC).
pub fn instance_record(
    plan: &Plan,
    c: usize,
    key: &Hash,
    results: &[Option<CompResult>],
    status: &str,
) -> serde_json::Value {
    let comp = &plan.comps[c];
    let flat = flatten_args(&comp.args_json);
    let origins: BTreeMap<String, String> = flat
        .keys()
        .map(|k| (k.clone(), arg_origin(plan, c, k)))
        .collect();
    let inputs: BTreeMap<String, Vec<serde_json::Value>> = comp
        .inputs
        .iter()
        .map(|slot| {
            let v = slot
                .sources
                .iter()
                .map(|(s, shown)| {
                    let m = match s {
                        Source::External { hash, .. } => Some(hex(hash)),
                        Source::Node { comp: up, output } => results[*up]
                            .as_ref()
                            .and_then(|r| r.outputs.get(output))
                            .map(hex),
                    };
                    match s {
                        // The links it went through, so `why` can say which one moved.
                        Source::External { path, .. } => serde_json::json!({
                            "from": shown,
                            "manifest": m,
                            "links": crate::store::links_within(path),
                        }),
                        Source::Node { .. } => serde_json::json!({ "from": shown, "manifest": m }),
                    }
                })
                .collect();
            (slot.name.clone(), v)
        })
        .collect();
    serde_json::json!({
        "key": hex(key),
        "kind": comp.node.kind(),
        "version": comp.node.version(),
        "salt": comp.salt,
        "args": comp.args_json,
        "origins": origins,
        "inputs": inputs,
        "status": status,
    })
}

/// Writes the run's records: each successful instance's record replaces its previous one in
/// `runs/latest`, and the run's summary goes to `runs/records`.
pub(super) fn write_records(
    plan: &Plan,
    store: &Store,
    report: &RunReport,
) -> Result<(), EngineError> {
    let mut latest = store
        .read_latest(&plan.id)
        .unwrap_or_else(|| serde_json::json!({}));
    if !latest.get("instances").is_some_and(|v| v.is_object()) {
        latest = serde_json::json!({ "instances": {} });
    }
    let insts = latest["instances"].as_object_mut().expect("made an object");
    // Instances no longer in the pipeline stop being roots.
    insts.retain(|name, _| plan.instances.iter().any(|i| i.name == *name));
    for inst in &plan.instances {
        let Some(r) = &report.results[inst.comp] else {
            continue;
        };
        // Only successful results replace the previous record: `why` compares against the
        // last good run, and GC keeps it.
        if let (Some(key), Status::Ran | Status::Cached) = (&r.key, &r.status) {
            insts.insert(
                inst.name.clone(),
                instance_record(plan, inst.comp, key, &report.results, r.status.as_str()),
            );
        }
    }
    latest["pipeline"] = serde_json::json!(plan.file.display().to_string());
    latest["time_unix"] = serde_json::json!(now_unix());
    store.write_latest(&plan.id, &latest)?;
    let mut summary = report.summary_json(plan);
    summary["pipeline"] = serde_json::json!(plan.file.display().to_string());
    summary["time_unix"] = serde_json::json!(now_unix());
    summary["host"] = serde_json::json!(hostname());
    store.write_record(&summary)?;
    Ok(())
}
