//! `plan` and `why`: what will run, and exactly what changed since a node's previous run.

use crate::error::EngineError;
use crate::exec::{arg_origin, flatten_args, plan_keys, PlannedKeys};
use crate::resolve::{Plan, Source};
use crate::store::EntryState;
use crate::store::{hex, Store};
use std::collections::BTreeSet;
use std::fmt::Write as _;

/// What `plan` expects for one computation.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Expect {
    /// Its key is in the store.
    Cached,
    /// Its key is known and not in the store.
    WillRun,
    /// An input will be recomputed first; it runs unless early cutoff finds identical inputs.
    AfterUpstream,
    /// Its key has an entry in the store that cannot be used (missing or unreadable outputs):
    /// it will be recomputed.
    Broken(String),
}

impl Expect {
    /// Short text.
    pub fn as_str(&self) -> String {
        match self {
            Expect::Cached => "cached".into(),
            Expect::WillRun => "will run".into(),
            Expect::AfterUpstream => "will run (inputs recomputed first)".into(),
            Expect::Broken(reason) => format!("broken, will run again: {reason}"),
        }
    }
}

/// Per computation, what will happen (`None` when not needed for the targets).
pub fn expectations(
    plan: &Plan,
    store: &Store,
    targets: &[String],
) -> Result<Vec<Option<Expect>>, EngineError> {
    let need = plan.needed(targets)?;
    let keys = plan_keys(plan, store)?;
    keys.iter()
        .enumerate()
        .map(|(c, k)| {
            let e = match k {
                Some((_, Some(_))) => Expect::Cached,
                Some((key, None)) => match store.action_state(key)? {
                    EntryState::Broken { reason, .. } => Expect::Broken(reason),
                    _ => Expect::WillRun,
                },
                None => Expect::AfterUpstream,
            };
            Ok(need[c].then_some(e))
        })
        .collect()
}

/// The text of `augsplat plan`: per node, cached or will run; per sweep point, new vs cached.
pub fn plan_text(plan: &Plan, store: &Store, targets: &[String]) -> Result<String, EngineError> {
    let ex = expectations(plan, store, targets)?;
    let mut s = String::new();
    let w = plan
        .instances
        .iter()
        .map(|i| i.name.chars().count())
        .max()
        .unwrap_or(4)
        .max(4);
    let wk = plan
        .comps
        .iter()
        .map(|c| c.node.kind().len())
        .max()
        .unwrap_or(4)
        .max(4);
    let _ = writeln!(s, "{:w$}  {:wk$}  status", "node", "kind");
    for inst in &plan.instances {
        let Some(e) = &ex[inst.comp] else { continue };
        let _ = writeln!(
            s,
            "{:w$}  {:wk$}  {}",
            inst.name,
            plan.comps[inst.comp].node.kind(),
            e.as_str()
        );
    }
    let unique_new = ex
        .iter()
        .flatten()
        .filter(|e| **e != Expect::Cached)
        .count();
    let unique_cached = ex
        .iter()
        .flatten()
        .filter(|e| **e == Expect::Cached)
        .count();
    if plan.points.len() > 1 {
        let _ = writeln!(s, "\nsweep points ({}):", plan.points.len());
        for p in &plan.points {
            let comps: BTreeSet<usize> = p
                .instances
                .iter()
                .map(|&i| plan.instances[i].comp)
                .filter(|&c| ex[c].is_some())
                .collect();
            let cached = comps
                .iter()
                .filter(|&&c| ex[c] == Some(Expect::Cached))
                .count();
            let _ = writeln!(
                s,
                "  {}: {} new, {} cached",
                p.label,
                comps.len() - cached,
                cached
            );
        }
    }
    let _ = writeln!(
        s,
        "\n{unique_new} to run, {unique_cached} cached ({} unique computations)",
        unique_new + unique_cached
    );
    Ok(s)
}

/// The text of `augsplat why NODE`: for each matching instance, what changed against the
/// previous run of that instance recorded for this pipeline.
pub fn why_text(plan: &Plan, store: &Store, node: &str) -> Result<String, EngineError> {
    let matches = plan.match_target(node);
    if matches.is_empty() {
        let names: BTreeSet<&str> = plan.instances.iter().map(|i| i.base.as_str()).collect();
        return Err(EngineError::Other(format!(
            "no node `{node}` in {}\n  hint: nodes: {}",
            plan.file.display(),
            names.into_iter().collect::<Vec<_>>().join(", ")
        )));
    }
    let keys = plan_keys(plan, store)?;
    let record = store.read_latest(&plan.id);
    let mut out = String::new();
    let mut seen = BTreeSet::new();
    for i in matches {
        explain(plan, &keys, record.as_ref(), i, 0, &mut seen, &mut out);
    }
    Ok(out)
}

fn show(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Null => "(absent)".into(),
        v => v.to_string(),
    }
}

#[allow(clippy::too_many_arguments)]
fn explain(
    plan: &Plan,
    keys: &PlannedKeys,
    record: Option<&serde_json::Value>,
    inst: usize,
    depth: usize,
    seen: &mut BTreeSet<usize>,
    out: &mut String,
) {
    let pad = "  ".repeat(depth);
    let name = &plan.instances[inst].name;
    let c = plan.instances[inst].comp;
    let comp = &plan.comps[c];
    if !seen.insert(inst) {
        let _ = writeln!(out, "{pad}`{name}`: see above");
        return;
    }
    if let Some((k, Some(entry))) = &keys[c] {
        let _ = writeln!(
            out,
            "{pad}`{name}` ({}) is cached: key {} was computed by `{}` on {} in {:.2} s; nothing to rerun",
            comp.node.kind(),
            &hex(k)[..16],
            entry.name,
            entry.host,
            entry.seconds
        );
        return;
    }
    let prev = record
        .and_then(|r| r.get("instances"))
        .and_then(|i| i.get(name));
    let Some(prev) = prev else {
        let _ = writeln!(
            out,
            "{pad}`{name}` ({}) will run: no previous successful run of it is recorded for {}",
            comp.node.kind(),
            plan.file.display()
        );
        return;
    };
    let _ = writeln!(
        out,
        "{pad}`{name}` ({}) will run because:",
        comp.node.kind()
    );
    let before = out.len();
    if prev["kind"].as_str() != Some(comp.node.kind()) {
        let _ = writeln!(
            out,
            "{pad}  kind changed: {} -> {}",
            show(&prev["kind"]),
            comp.node.kind()
        );
    } else if prev["version"].as_u64() != Some(comp.node.version() as u64) {
        let _ = writeln!(
            out,
            "{pad}  the kind's VERSION changed: {} -> {} (its code changed)",
            show(&prev["version"]),
            comp.node.version()
        );
    }
    if prev["salt"].as_u64() != comp.salt {
        let _ = writeln!(
            out,
            "{pad}  repeat index in the key changed: {} -> {:?}",
            show(&prev["salt"]),
            comp.salt
        );
    }
    let old = flatten_args(&prev["args"]);
    let new = flatten_args(&comp.args_json);
    let paths: BTreeSet<&String> = old.keys().chain(new.keys()).collect();
    for p in paths {
        let (o, n) = (
            old.get(p).cloned().unwrap_or_default(),
            new.get(p).cloned().unwrap_or_default(),
        );
        if o != n {
            let was = prev["origins"]
                .get(p.as_str())
                .and_then(|x| x.as_str())
                .unwrap_or("?");
            let _ = writeln!(
                out,
                "{pad}  arg `{p}`: {} -> {}  (set at {}; was set at {was})",
                show(&o),
                show(&n),
                arg_origin(plan, c, p)
            );
        }
    }
    for slot in &comp.inputs {
        let old_list = prev["inputs"]
            .get(&slot.name)
            .and_then(|v| v.as_array())
            .cloned()
            .unwrap_or_default();
        let old_from: Vec<&str> = old_list
            .iter()
            .map(|x| x["from"].as_str().unwrap_or("?"))
            .collect();
        let new_from: Vec<&str> = slot
            .sources
            .iter()
            .map(|(_, shown)| shown.as_str())
            .collect();
        if old_from != new_from {
            let _ = writeln!(
                out,
                "{pad}  input `{}` now comes from [{}] (was [{}])",
                slot.name,
                new_from.join(", "),
                old_from.join(", ")
            );
            continue;
        }
        for (j, (s, shown)) in slot.sources.iter().enumerate() {
            let old_m = old_list
                .get(j)
                .and_then(|x| x["manifest"].as_str())
                .unwrap_or("");
            match s {
                Source::External { hash, path } => {
                    if hex(hash) != old_m {
                        let _ = writeln!(
                            out,
                            "{pad}  input `{}`: the content of {} changed (manifest {} -> {})",
                            slot.name,
                            path.display(),
                            short(old_m),
                            &hex(hash)[..16]
                        );
                        let old_links = old_list.get(j).map(|x| &x["links"]);
                        for line in moved_links(path, old_links) {
                            let _ = writeln!(out, "{pad}    {line}");
                        }
                    }
                }
                Source::Node { comp: up, output } => match &keys[*up] {
                    Some((_, Some(entry))) => {
                        let m = entry.outputs.get(output).map(String::as_str).unwrap_or("");
                        if m != old_m {
                            let _ = writeln!(
                                out,
                                "{pad}  input `{}` from `{shown}` has new content (manifest {} -> {})",
                                slot.name,
                                short(old_m),
                                short(m)
                            );
                        }
                    }
                    _ => {
                        let _ = writeln!(
                            out,
                            "{pad}  input `{}` comes from `{shown}`, which will run first:",
                            slot.name
                        );
                        let up_inst = plan.comps[*up]
                            .instances
                            .iter()
                            .copied()
                            .find(|&i| shown.starts_with(&plan.instances[i].name))
                            .or(plan.comps[*up].instances.first().copied());
                        if let Some(ui) = up_inst {
                            explain(plan, keys, record, ui, depth + 2, seen, out);
                        }
                    }
                },
            }
        }
    }
    if out.len() == before {
        let same_key =
            keys[c].as_ref().map(|(k, _)| hex(k)) == prev["key"].as_str().map(str::to_string);
        let _ = writeln!(
            out,
            "{pad}  nothing changed since its previous run{}, but that result is no longer in the store (removed by gc, or the store is new)",
            if same_key { " (same key)" } else { "" }
        );
    }
}

/// The symbolic links below external input `path` whose target differs from the previous
/// run's record `old` (a map of relative path to target), in words.
fn moved_links(path: &std::path::Path, old: Option<&serde_json::Value>) -> Vec<String> {
    let now = crate::store::links_within(path);
    let was: std::collections::BTreeMap<String, String> = old
        .and_then(|v| serde_json::from_value(v.clone()).ok())
        .unwrap_or_default();
    let name = |rel: &str| {
        if rel.is_empty() {
            path.display().to_string()
        } else {
            path.join(rel).display().to_string()
        }
    };
    let mut lines = Vec::new();
    for (rel, target) in &now {
        match was.get(rel) {
            Some(t) if t != target => lines.push(format!(
                "the link {} now points to {target} (was {t})",
                name(rel)
            )),
            None => lines.push(format!("{} is now a link to {target}", name(rel))),
            _ => {}
        }
    }
    for (rel, t) in &was {
        if !now.contains_key(rel) {
            lines.push(format!("{} is no longer a link (was to {t})", name(rel)));
        }
    }
    lines
}

fn short(h: &str) -> &str {
    if h.is_empty() {
        "(none)"
    } else {
        &h[..h.len().min(16)]
    }
}
