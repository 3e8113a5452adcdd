//! Pipeline documents: reading a `.ron` file, `extends` merging, `--set` overrides, `Param`
//! substitution and sweep expansion. Everything here works on [`Value`] trees that keep the
//! origin of every value; typing against node kinds happens in [`crate::resolve`].
//!
//! Merge rules for `extends: "base.ron"` (the child is the file that says `extends`; with a
//! list, `extends: ["a.ron", "b.ron"]`, b is merged onto a by the same rules, then the child):
//! - `params`: merged by name; the child's value wins.
//! - `nodes`: merged by node name. A node only in one file is kept. A node in both is merged
//!   field by field: `kind`, `repeat` and `gate` are replaced; `inputs` are merged by input name (the
//!   child's reference wins); `args` are merged recursively: struct fields and map entries are
//!   merged, every other value (numbers, strings, lists, enum variants) is replaced whole. If the
//!   child gives a different `kind`, the child's node replaces the base's entirely. Writing
//!   `"name": Remove` in the child deletes the base's node.
//! - `sweep`: the child's replaces the base's; `sweep: None` removes it.
//! - Relative paths (`Path("..")`, nested `extends`) resolve against the file that wrote them.

use crate::error::Diagnostic;
use crate::syntax::{self, Origin, Value, ValueKind};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The top-level fields a pipeline document may have.
pub const TOP_FIELDS: &[&str] = &["extends", "params", "nodes", "sweep", "resources"];
/// The fields a node may have.
pub const NODE_FIELDS: &[&str] = &["kind", "args", "inputs", "repeat", "gate"];

/// How deep a chain of `extends` may go (a file that extends a file that extends ...).
pub const MAX_EXTENDS_DEPTH: usize = 64;

/// Reads a pipeline file and everything it extends, merged. Each file is read and merged once
/// (a file named twice, or by two bases, is reused), and the chain is at most
/// [`MAX_EXTENDS_DEPTH`] files deep.
pub fn load_document(path: &Path) -> Result<Value, Diagnostic> {
    let mut chain = Vec::new();
    let mut loaded = std::collections::HashMap::new();
    load_rec(path, &mut chain, &mut loaded)
}

fn load_rec(
    path: &Path,
    chain: &mut Vec<PathBuf>,
    loaded: &mut std::collections::HashMap<PathBuf, Value>,
) -> Result<Value, Diagnostic> {
    let canon = std::fs::canonicalize(path)
        .map_err(|e| Diagnostic::bare(format!("cannot open pipeline {}: {e}", path.display())))?;
    if let Some(doc) = loaded.get(&canon) {
        return Ok(doc.clone());
    }
    if chain.len() >= MAX_EXTENDS_DEPTH {
        let names: Vec<String> = chain.iter().map(|p| p.display().to_string()).collect();
        return Err(Diagnostic::bare(format!(
            "`extends` goes more than {MAX_EXTENDS_DEPTH} files deep: {} -> ... -> {} -> {}",
            names[..3.min(names.len())].join(" -> "),
            names[names.len().saturating_sub(2)..].join(" -> "),
            canon.display()
        ))
        .hint("a pipeline extends a few bases; flatten the chain"));
    }
    if chain.contains(&canon) {
        let names: Vec<String> = chain.iter().map(|p| p.display().to_string()).collect();
        return Err(Diagnostic::bare(format!(
            "`extends` loops: {} -> {}",
            names.join(" -> "),
            canon.display()
        ))
        .hint("remove one of the `extends` lines"));
    }
    let text = std::fs::read_to_string(&canon)
        .map_err(|e| Diagnostic::bare(format!("cannot read pipeline {}: {e}", canon.display())))?;
    let file: Arc<Path> = Arc::from(canon.as_path());
    let doc = syntax::parse(&text, Some(file), None)?;
    check_shape(&doc)?;
    chain.push(canon.clone());
    let result = match doc.field("extends") {
        None => Ok(strip_extends(doc)),
        Some(ext) => {
            // One file, or a list merged left to right (later files win), then this one.
            let items: Vec<&Value> = match &ext.kind {
                ValueKind::List(items) if !items.is_empty() => items.iter().collect(),
                _ => vec![ext],
            };
            let mut base: Option<Value> = None;
            for item in items {
                let rel = item.as_str().ok_or_else(|| {
                    Diagnostic::at(
                        &item.origin,
                        format!(
                            "`extends` must be a string path or a list of them, found {}",
                            item.describe()
                        ),
                    )
                })?;
                let base_path = item.origin.base_dir().join(rel);
                if !base_path.exists() {
                    return Err(Diagnostic::at(
                        &item.origin,
                        format!(
                            "`extends` names {}, which does not exist",
                            base_path.display()
                        ),
                    )
                    .hint("the path is relative to the file that writes it"));
                }
                let doc_i = load_rec(&base_path, chain, loaded)?;
                base = Some(match base {
                    None => doc_i,
                    Some(b) => merge_documents(b, doc_i),
                });
            }
            let base = base.expect("at least one base");
            Ok(merge_documents(base, strip_extends(doc)))
        }
    };
    chain.pop();
    if let Ok(doc) = &result {
        loaded.insert(canon, doc.clone());
    }
    result
}

fn strip_extends(mut doc: Value) -> Value {
    if let ValueKind::Struct(_, fields) = &mut doc.kind {
        fields.retain(|(n, _)| n != "extends");
    }
    doc
}

/// Checks the document's top-level shape: a struct with known fields, `nodes` a map of structs.
pub fn check_shape(doc: &Value) -> Result<(), Diagnostic> {
    let fields = doc.fields().ok_or_else(|| {
        Diagnostic::at(
            &doc.origin,
            format!(
                "a pipeline must be a struct `( nodes: {{ .. }} )`, found {}",
                doc.describe()
            ),
        )
    })?;
    for (name, v) in fields {
        if !TOP_FIELDS.contains(&name.as_str()) {
            return Err(
                Diagnostic::at(&v.origin, format!("unknown pipeline field `{name}`")).hint(
                    format!("a pipeline has the fields {}", TOP_FIELDS.join(", ")),
                ),
            );
        }
    }
    if let Some(nodes) = doc.field("nodes") {
        let ValueKind::Map(entries) = &nodes.kind else {
            return Err(Diagnostic::at(
                &nodes.origin,
                format!(
                    "`nodes` must be a map {{ \"name\": (kind: ..) }}, found {}",
                    nodes.describe()
                ),
            ));
        };
        for (k, v) in entries {
            let Some(name) = k.as_str() else {
                return Err(Diagnostic::at(&k.origin, "node names must be strings")
                    .hint("write `\"name\": (kind: \"Kind\")`"));
            };
            if name.is_empty()
                || !name
                    .chars()
                    .all(|c| c.is_alphanumeric() || c == '_' || c == '-')
            {
                return Err(Diagnostic::at(
                    &k.origin,
                    format!("node name `{name}` may only hold letters, digits, `_` and `-`"),
                ));
            }
            if matches!(&v.kind, ValueKind::Ident(i) if i == "Remove") {
                continue;
            }
            let nf = v.fields().ok_or_else(|| {
                Diagnostic::at(
                    &v.origin,
                    format!(
                        "node `{name}` must be a struct `(kind: \"..\", args: (..), inputs: {{..}})`, found {}",
                        v.describe()
                    ),
                )
            })?;
            for (f, fv) in nf {
                if !NODE_FIELDS.contains(&f.as_str()) {
                    return Err(Diagnostic::at(
                        &fv.origin,
                        format!("unknown field `{f}` in node `{name}`"),
                    )
                    .hint(format!("a node has the fields {}", NODE_FIELDS.join(", "))));
                }
            }
        }
    }
    Ok(())
}

fn key_text(v: &Value) -> String {
    match &v.kind {
        ValueKind::Str(s) => s.clone(),
        _ => v.to_ron(),
    }
}

/// Deep merge: struct fields and map entries merge recursively; anything else is replaced.
pub fn merge_values(base: Value, child: Value) -> Value {
    match (base.kind, child.kind) {
        (ValueKind::Struct(bn, mut bf), ValueKind::Struct(cn, cf)) if bn == cn || cn.is_none() => {
            for (name, cv) in cf {
                if let Some(pos) = bf.iter().position(|(n, _)| *n == name) {
                    let bv = bf.remove(pos).1;
                    bf.insert(pos, (name, merge_values(bv, cv)));
                } else {
                    bf.push((name, cv));
                }
            }
            Value {
                kind: ValueKind::Struct(bn, bf),
                origin: child.origin,
            }
        }
        (ValueKind::Unit, ValueKind::Struct(cn, cf)) => Value {
            kind: ValueKind::Struct(cn, cf),
            origin: child.origin,
        },
        (ValueKind::Struct(bn, bf), ValueKind::Unit) => Value {
            kind: ValueKind::Struct(bn, bf),
            origin: base.origin,
        },
        (ValueKind::Map(mut be), ValueKind::Map(ce)) => {
            for (k, cv) in ce {
                let kt = key_text(&k);
                if let Some(pos) = be.iter().position(|(bk, _)| key_text(bk) == kt) {
                    let (bk, bv) = be.remove(pos);
                    be.insert(pos, (bk, merge_values(bv, cv)));
                } else {
                    be.push((k, cv));
                }
            }
            Value {
                kind: ValueKind::Map(be),
                origin: child.origin,
            }
        }
        (_, ck) => Value {
            kind: ck,
            origin: child.origin,
        },
    }
}

fn merge_documents(base: Value, child: Value) -> Value {
    // Node-level rules first: a different kind replaces the node, `Remove` deletes it.
    let mut base = base;
    let mut child = child;
    if let (Some(bn), Some(cn)) = (field_mut(&mut base, "nodes"), child_nodes(&child)) {
        if let ValueKind::Map(bentries) = &mut bn.kind {
            for (k, cv) in cn {
                let kt = key_text(&k);
                let Some(pos) = bentries.iter().position(|(bk, _)| key_text(bk) == kt) else {
                    continue;
                };
                let remove = matches!(&cv.kind, ValueKind::Ident(i) if i == "Remove");
                let kind_changed = match (bentries[pos].1.field("kind"), cv.field("kind")) {
                    (Some(a), Some(b)) => a.as_str() != b.as_str(),
                    _ => false,
                };
                if remove || kind_changed {
                    bentries.remove(pos);
                }
            }
        }
    }
    // Drop `Remove` markers from the child before merging.
    if let Some(cn) = field_mut(&mut child, "nodes") {
        if let ValueKind::Map(entries) = &mut cn.kind {
            entries.retain(|(_, v)| !matches!(&v.kind, ValueKind::Ident(i) if i == "Remove"));
        }
    }
    // `sweep` is replaced, never merged.
    if child.field("sweep").is_some() {
        if let ValueKind::Struct(_, f) = &mut base.kind {
            f.retain(|(n, _)| n != "sweep");
        }
    }
    // `args` inside a node: merge; `inputs`: merge by name; `kind`/`repeat`: replaced (default).
    merge_values(base, child)
}

fn child_nodes(doc: &Value) -> Option<Vec<(Value, Value)>> {
    match &doc.field("nodes")?.kind {
        ValueKind::Map(e) => Some(e.clone()),
        _ => None,
    }
}

fn field_mut<'a>(v: &'a mut Value, name: &str) -> Option<&'a mut Value> {
    match &mut v.kind {
        ValueKind::Struct(_, f) => f.iter_mut().find(|(n, _)| n == name).map(|(_, v)| v),
        _ => None,
    }
}

fn map_entry_mut<'a>(v: &'a mut Value, key: &str) -> Option<&'a mut Value> {
    match &mut v.kind {
        ValueKind::Map(e) => e
            .iter_mut()
            .find(|(k, _)| key_text(k) == key)
            .map(|(_, v)| v),
        _ => None,
    }
}

/// Names of the document's nodes, in file order.
pub fn node_names(doc: &Value) -> Vec<String> {
    match doc.field("nodes").map(|n| &n.kind) {
        Some(ValueKind::Map(e)) => e.iter().map(|(k, _)| key_text(k)).collect(),
        _ => Vec::new(),
    }
}

/// Parses a `--set PATH=VALUE` argument into the path and a value whose origin is the override.
pub fn parse_set(text: &str) -> Result<(String, Value), Diagnostic> {
    let Some((path, value)) = text.split_once('=') else {
        return Err(Diagnostic::bare(format!("--set `{text}` has no `=`"))
            .hint("write --set NODE.ARG=VALUE, e.g. --set train.steps=300"));
    };
    let origin = Origin::Set(Arc::from(text));
    let v = syntax::parse(value, None, Some(origin.clone())).map_err(|e| {
        Diagnostic::at(
            &origin,
            format!("the value `{value}` is not RON: {}", e.message),
        )
        .hint("strings need quotes: --set node.name='\"text\"'")
    })?;
    Ok((path.trim().to_string(), v))
}

/// Sets `path` (`NODE.ARG[.SUB..]` or `params.NAME`) to `value` in the document, as if the file
/// said so. Missing struct fields are created.
pub fn apply_set(doc: &mut Value, path: &str, value: Value) -> Result<(), Diagnostic> {
    let origin = value.origin.clone();
    let parts: Vec<&str> = path.split('.').collect();
    if parts.len() < 2 || parts.iter().any(|p| p.is_empty()) {
        return Err(Diagnostic::at(
            &origin,
            format!("`{path}` is not a path of the form NODE.ARG or params.NAME"),
        ));
    }
    if parts[0] == "params" {
        let params = ensure_field(doc, "params", || ValueKind::Map(Vec::new()), &origin);
        if !matches!(params.kind, ValueKind::Map(_)) {
            return Err(Diagnostic::at(&params.origin, "`params` must be a map"));
        }
        let name = parts[1];
        let known: Vec<String> = match &params.kind {
            ValueKind::Map(e) => e
                .iter()
                .filter_map(|(k, _)| k.as_str().map(str::to_string))
                .collect(),
            _ => Vec::new(),
        };
        let Some(slot) = map_entry_mut(params, name) else {
            // A param no file declares is used by no node: setting it would change nothing
            // the user can see, so it is a typo.
            let close: Vec<&str> = known
                .iter()
                .map(String::as_str)
                .filter(|k| crate::resolve::refs::similar(k, name))
                .collect();
            let hint = if !close.is_empty() {
                format!("did you mean `params.{}`?", close.join("` or `params."))
            } else if known.is_empty() {
                "this pipeline declares no params".to_string()
            } else {
                format!("params: {}", known.join(", "))
            };
            return Err(
                Diagnostic::at(&origin, format!("there is no param `{name}` (`{path}`)"))
                    .hint(hint),
            );
        };
        return set_in(slot, &parts[2..], value, path);
    }
    let names = node_names(doc);
    let node_name = parts[0];
    let Some(node) = field_mut(doc, "nodes").and_then(|nodes| map_entry_mut(nodes, node_name))
    else {
        return Err(
            Diagnostic::at(&origin, format!("there is no node `{node_name}`"))
                .hint(format!("nodes: {}", names.join(", "))),
        );
    };
    let args = ensure_field(
        node,
        "args",
        || ValueKind::Struct(None, Vec::new()),
        &origin,
    );
    set_in(args, &parts[1..], value, path)
}

fn ensure_field<'a>(
    v: &'a mut Value,
    name: &str,
    make: impl FnOnce() -> ValueKind,
    origin: &Origin,
) -> &'a mut Value {
    if matches!(v.kind, ValueKind::Unit) {
        v.kind = ValueKind::Struct(None, Vec::new());
    }
    let ValueKind::Struct(_, fields) = &mut v.kind else {
        // Callers only pass structs (checked by `check_shape`).
        panic!("ensure_field on a non-struct");
    };
    if let Some(pos) = fields.iter().position(|(n, _)| n == name) {
        &mut fields[pos].1
    } else {
        fields.push((name.to_string(), Value::new(make(), origin.clone())));
        &mut fields.last_mut().expect("just pushed").1
    }
}

fn set_in(slot: &mut Value, rest: &[&str], value: Value, full: &str) -> Result<(), Diagnostic> {
    if rest.is_empty() {
        *slot = value;
        return Ok(());
    }
    let origin = value.origin.clone();
    if matches!(slot.kind, ValueKind::Unit) {
        slot.kind = ValueKind::Struct(None, Vec::new());
    }
    match &mut slot.kind {
        ValueKind::Struct(_, fields) => {
            let pos = match fields.iter().position(|(n, _)| n == rest[0]) {
                Some(p) => p,
                None => {
                    fields.push((rest[0].to_string(), Value::new(ValueKind::Unit, origin)));
                    fields.len() - 1
                }
            };
            set_in(&mut fields[pos].1, &rest[1..], value, full)
        }
        ValueKind::Map(entries) => {
            let pos = match entries.iter().position(|(k, _)| key_text(k) == rest[0]) {
                Some(p) => p,
                None => {
                    entries.push((
                        Value::new(ValueKind::Str(rest[0].into()), origin.clone()),
                        Value::new(ValueKind::Unit, origin),
                    ));
                    entries.len() - 1
                }
            };
            set_in(&mut entries[pos].1, &rest[1..], value, full)
        }
        _ => Err(Diagnostic::at(
            &origin,
            format!(
                "`{full}`: `{}` is {}, which has no fields",
                rest[0],
                slot.describe()
            ),
        )
        .hint(format!("it was set at {}", slot.origin))),
    }
}

/// One point of a sweep: its label and the assignments that make it.
#[derive(Clone, Debug)]
pub struct SweepPoint {
    /// Readable label, e.g. `gamma=0.5,steps=100` (empty without a sweep).
    pub label: String,
    /// Per axis: (path, value), values carry a [`Origin::Sweep`] origin.
    pub assignments: Vec<(String, Value)>,
}

/// The sweep axes of a document: (path, short label, values) and whether it is a grid.
#[derive(Clone, Debug)]
pub struct Sweep {
    /// `true` for `Grid`, `false` for `Zip`.
    pub grid: bool,
    /// (path, short name, values).
    pub axes: Vec<(String, String, Vec<Value>)>,
}

/// Reads the document's `sweep`, if any.
pub fn sweep_of(doc: &Value) -> Result<Option<Sweep>, Diagnostic> {
    let Some(s) = doc.field("sweep") else {
        return Ok(None);
    };
    if matches!(&s.kind, ValueKind::Ident(i) if i == "None") {
        return Ok(None);
    }
    let bad = || {
        Diagnostic::at(
            &s.origin,
            format!(
                "`sweep` must be Grid({{\"node.arg\": [v1, v2]}}) or Zip({{..}}), found {}",
                s.describe()
            ),
        )
    };
    let ValueKind::Tuple(Some(name), items) = &s.kind else {
        return Err(bad());
    };
    let grid = match name.as_str() {
        "Grid" => true,
        "Zip" => false,
        _ => {
            return Err(bad().hint(
                "the sweep kinds are Grid (every combination) and Zip (values taken in step)",
            ))
        }
    };
    let [m] = items.as_slice() else {
        return Err(bad());
    };
    let ValueKind::Map(entries) = &m.kind else {
        return Err(bad());
    };
    let mut axes = Vec::new();
    for (k, v) in entries {
        let Some(path) = k.as_str() else {
            return Err(Diagnostic::at(
                &k.origin,
                "sweep paths must be strings like \"node.arg\"",
            ));
        };
        let ValueKind::List(values) = &v.kind else {
            return Err(Diagnostic::at(
                &v.origin,
                format!("sweep axis `{path}` must be a list of values"),
            ));
        };
        if values.is_empty() {
            return Err(Diagnostic::at(
                &v.origin,
                format!("sweep axis `{path}` has no values"),
            ));
        }
        axes.push((path.to_string(), String::new(), values.clone()));
    }
    if axes.is_empty() {
        return Err(Diagnostic::at(&m.origin, "the sweep has no axes"));
    }
    if !grid {
        let n = axes[0].2.len();
        if let Some((p, _, v)) = axes.iter().find(|a| a.2.len() != n) {
            return Err(Diagnostic::at(
                &s.origin,
                format!(
                    "Zip axes must have equal lengths: `{}` has {n} values, `{p}` has {}",
                    axes[0].0,
                    v.len()
                ),
            )
            .hint("use Grid for every combination"));
        }
    }
    // Short names: the last path component, unless two axes share it.
    let lasts: Vec<String> = axes
        .iter()
        .map(|a| a.0.rsplit('.').next().unwrap_or(&a.0).to_string())
        .collect();
    for (i, a) in axes.iter_mut().enumerate() {
        a.1 = if lasts.iter().filter(|l| **l == lasts[i]).count() > 1 {
            a.0.clone()
        } else {
            lasts[i].clone()
        };
    }
    Ok(Some(Sweep { grid, axes }))
}

/// Expands a sweep into its points (one empty point without a sweep). Grid points vary the last
/// axis fastest.
pub fn sweep_points(sweep: Option<&Sweep>) -> Vec<Vec<usize>> {
    let Some(s) = sweep else {
        return vec![Vec::new()];
    };
    if !s.grid {
        return (0..s.axes[0].2.len())
            .map(|i| vec![i; s.axes.len()])
            .collect();
    }
    let mut points = vec![Vec::new()];
    for (_, _, values) in &s.axes {
        let mut next = Vec::new();
        for p in &points {
            for i in 0..values.len() {
                let mut q = p.clone();
                q.push(i);
                next.push(q);
            }
        }
        points = next;
    }
    points
}

/// The assignments and label of point `coords` of `sweep`.
pub fn point(sweep: Option<&Sweep>, coords: &[usize]) -> SweepPoint {
    let Some(s) = sweep else {
        return SweepPoint {
            label: String::new(),
            assignments: Vec::new(),
        };
    };
    let mut labels = Vec::new();
    let mut assignments = Vec::new();
    for ((path, short, values), &i) in s.axes.iter().zip(coords) {
        let text = format!("{short}={}", values[i].to_ron());
        let origin = Origin::Sweep(Arc::from(format!(
            "{path}={} (sweep at {})",
            values[i].to_ron(),
            values[i].origin
        )));
        assignments.push((path.clone(), values[i].clone().with_origin_deep(&origin)));
        labels.push(text);
    }
    SweepPoint {
        label: labels.join(","),
        assignments,
    }
}

/// The params that `doc` declares but no node uses through `Param("name")` (name and where it
/// is declared): setting them changes nothing, which `plan` and `run` warn about.
pub fn unused_params(doc: &Value) -> Vec<(String, crate::syntax::Origin)> {
    fn used(v: &Value, out: &mut BTreeSet<String>) {
        match &v.kind {
            ValueKind::Tuple(Some(n), items) if n == "Param" => {
                if let [x] = items.as_slice() {
                    if let Some(name) = x.as_str() {
                        out.insert(name.to_string());
                    }
                }
            }
            ValueKind::List(items) | ValueKind::Tuple(_, items) => {
                items.iter().for_each(|i| used(i, out))
            }
            ValueKind::Map(entries) => entries.iter().for_each(|(k, v)| {
                used(k, out);
                used(v, out)
            }),
            ValueKind::Struct(_, fields) => fields.iter().for_each(|(_, v)| used(v, out)),
            _ => {}
        }
    }
    let mut names = BTreeSet::new();
    if let Some(nodes) = doc.field("nodes") {
        used(nodes, &mut names);
    }
    let Some(ValueKind::Map(entries)) = doc.field("params").map(|p| &p.kind) else {
        return Vec::new();
    };
    entries
        .iter()
        .filter_map(|(k, _)| {
            let name = k.as_str()?;
            (!names.contains(name)).then(|| (name.to_string(), k.origin.clone()))
        })
        .collect()
}

/// Replaces every `Param("name")` inside `v` by the parameter's value.
pub fn substitute_params(v: &mut Value, params: &[(String, Value)]) -> Result<(), Diagnostic> {
    if let ValueKind::Tuple(Some(n), items) = &v.kind {
        if n == "Param" {
            let name = match items.as_slice() {
                [x] => x.as_str().map(str::to_string),
                _ => None,
            };
            let Some(name) = name else {
                return Err(Diagnostic::at(&v.origin, "write `Param(\"name\")`"));
            };
            let Some((_, val)) = params.iter().find(|(k, _)| *k == name) else {
                let known: Vec<&str> = params.iter().map(|(k, _)| k.as_str()).collect();
                return Err(
                    Diagnostic::at(&v.origin, format!("unknown parameter `{name}`")).hint(
                        if known.is_empty() {
                            "declare it under `params: { .. }`".to_string()
                        } else {
                            format!("params: {}", known.join(", "))
                        },
                    ),
                );
            };
            *v = val.clone();
            return Ok(());
        }
    }
    match &mut v.kind {
        ValueKind::List(items) | ValueKind::Tuple(_, items) => items
            .iter_mut()
            .try_for_each(|i| substitute_params(i, params)),
        ValueKind::Map(entries) => entries
            .iter_mut()
            .try_for_each(|(_, v)| substitute_params(v, params)),
        ValueKind::Struct(_, fields) => fields
            .iter_mut()
            .try_for_each(|(_, v)| substitute_params(v, params)),
        _ => Ok(()),
    }
}

/// The document's params as (name, value), after substitution among themselves is not allowed.
pub fn params_of(doc: &Value) -> Result<Vec<(String, Value)>, Diagnostic> {
    let Some(p) = doc.field("params") else {
        return Ok(Vec::new());
    };
    let ValueKind::Map(entries) = &p.kind else {
        return Err(Diagnostic::at(
            &p.origin,
            format!(
                "`params` must be a map {{ \"name\": value }}, found {}",
                p.describe()
            ),
        ));
    };
    let mut out = Vec::new();
    for (k, v) in entries {
        let Some(name) = k.as_str() else {
            return Err(Diagnostic::at(&k.origin, "parameter names must be strings"));
        };
        out.push((name.to_string(), v.clone()));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Value {
        syntax::parse(s, None, None).unwrap()
    }

    #[test]
    fn merge_rules() {
        let base = parse(
            r#"(params: {"a": 1, "b": 2}, nodes: {"x": (kind: "K", args: (p: 1, q: (r: 1, s: 2)), inputs: {"i": "y"}), "z": (kind: "Z")}, sweep: Grid({"x.p": [1, 2]}))"#,
        );
        let child = parse(
            r#"(params: {"b": 3}, nodes: {"x": (args: (q: (s: 5), l: [1])), "z": Remove, "w": (kind: "W")}, sweep: None)"#,
        );
        let m = merge_documents(base, child);
        assert_eq!(
            m.to_ron(),
            r#"(params: {"a": 1, "b": 3}, nodes: {"x": (kind: "K", args: (p: 1, q: (r: 1, s: 5), l: [1]), inputs: {"i": "y"}), "w": (kind: "W")}, sweep: None)"#
        );
        let base = parse(r#"(nodes: {"x": (kind: "K", args: (p: 1))})"#);
        let child = parse(r#"(nodes: {"x": (kind: "L", args: (q: 2))})"#);
        assert_eq!(
            merge_documents(base, child).to_ron(),
            r#"(nodes: {"x": (kind: "L", args: (q: 2))})"#
        );
    }

    #[test]
    fn set_paths() {
        let mut d = parse(r#"(nodes: {"x": (kind: "K")}, params: {"m": 1})"#);
        let (p, v) = parse_set("x.a.b=[1, 2]").unwrap();
        apply_set(&mut d, &p, v).unwrap();
        let (p, v) = parse_set("params.m=3").unwrap();
        apply_set(&mut d, &p, v).unwrap();
        assert_eq!(
            d.to_ron(),
            r#"(nodes: {"x": (kind: "K", args: (a: (b: [1, 2])))}, params: {"m": 3})"#
        );
        // An undeclared param is a typo, not a new param.
        let (p, v) = parse_set("params.n=3").unwrap();
        let e = apply_set(&mut d, &p, v).unwrap_err();
        assert!(e.message.contains("no param `n`"), "{e:?}");
        let (p, v) = parse_set("nope.a=1").unwrap();
        assert!(apply_set(&mut d, &p, v)
            .unwrap_err()
            .message
            .contains("no node"));
    }

    #[test]
    fn grid_and_zip() {
        let d = parse(r#"(sweep: Grid({"a.x": [1, 2], "b.x": [3, 4, 5]}))"#);
        let s = sweep_of(&d).unwrap().unwrap();
        let pts = sweep_points(Some(&s));
        assert_eq!(pts.len(), 6);
        assert_eq!(point(Some(&s), &pts[1]).label, "a.x=1,b.x=4");
        let d = parse(r#"(sweep: Zip({"a.x": [1, 2], "b.y": [3, 4]}))"#);
        let s = sweep_of(&d).unwrap().unwrap();
        assert_eq!(point(Some(&s), &sweep_points(Some(&s))[1]).label, "x=2,y=4");
        let d = parse(r#"(sweep: Zip({"a.x": [1, 2], "b.y": [3]}))"#);
        assert!(sweep_of(&d).is_err());
    }
}
