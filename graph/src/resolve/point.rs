//! Resolving one sweep point's document into computations, in five steps:
//!
//! 1. [`substitute_params`]: `Param("name")` → its value in every node body;
//! 2. [`Builder::type_nodes`]: each node's kind, `repeat` and typed args, one [`Local`] per
//!    instance;
//! 3. [`Builder::resolve_inputs`]: each instance's input references → sources;
//! 4. [`check_cycles`]: the inputs must form a DAG; gives a topological order;
//! 5. [`Builder::intern`]: upstream first, each instance becomes a [`Comp`], shared with every
//!    earlier instance (of this point or another) that has the same structural id.
//!
//! Each step reports every problem it finds at once; a step with errors stops the point.

use super::{Comp, InputSlot, Source};
use crate::error::{Diagnostic, PipelineError};
use crate::key;
use crate::node::InputDecl;
use crate::registry::{ArgsBox, DynNode, Registry};
use crate::spec;
use crate::store::{Hash, Store};
use crate::syntax::{Origin, Value, ValueKind};
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::Arc;

/// Resolves points against a registry, accumulating the unique computations of all points.
pub(super) struct Builder<'a> {
    pub(super) registry: &'a Registry,
    pub(super) store: &'a Store,
    /// Unique computations so far, upstream first.
    pub(super) comps: Vec<Comp>,
    /// Structural id -> index into `comps`.
    by_sid: HashMap<Hash, usize>,
    /// Content hashes of external inputs already hashed, by absolute path.
    pub(super) ext_cache: HashMap<PathBuf, Hash>,
    /// `Installed(..)` references to resources that are not installed, so far (each leaves
    /// an optional input unconnected).
    pub(super) uninstalled: usize,
}

/// A node instance within one point, before deduplication.
pub(super) struct Local {
    pub(super) name: String,
    pub(super) base: String,
    pub(super) index: Option<usize>,
    pub(super) node: Arc<dyn DynNode>,
    args: ArgsBox,
    args_value: Value,
    salt: Option<u64>,
    pub(super) outputs: Vec<String>,
    decls: Vec<InputDecl>,
    inputs_value: Option<Value>,
    /// The node's `gate:` reference, if any (see [`crate::gate`]).
    gate_value: Option<Value>,
    node_origin: Origin,
}

/// An input slot within one point: name and (source, written reference) pairs.
pub(super) type LSlot = (String, Vec<(LSource, String)>);

/// Where an input comes from within one point.
pub(super) enum LSource {
    /// Output `.1` of local instance `.0`.
    Local(usize, String),
    /// An external file or folder (absolute path) and its content hash.
    External(PathBuf, Hash),
}

/// Per node name: its instances (indices into the locals) and whether it has `repeat`.
pub(super) type ByNode = BTreeMap<String, (Vec<usize>, bool)>;

/// Step 1: substitutes params in every node body and writes the substituted nodes back into
/// `doc` (so `expand` shows the values). Returns the `nodes` entries (name, body).
fn substitute_params(doc: &mut Value) -> Result<Vec<(Value, Value)>, PipelineError> {
    let params = spec::params_of(doc)?;
    let mut nodes: Vec<(Value, Value)> = match doc.field("nodes").map(|n| &n.kind) {
        Some(ValueKind::Map(e)) => e.clone(),
        _ => {
            return Err(Diagnostic::at(&doc.origin, "the pipeline has no `nodes`")
                .hint("write `( nodes: { \"name\": (kind: \"Kind\", args: (..)) } )`")
                .into())
        }
    };
    let mut errors = Vec::new();
    for (_, v) in nodes.iter_mut() {
        if let Err(d) = spec::substitute_params(v, &params) {
            errors.push(d);
        }
    }
    if let Some(ValueKind::Map(e)) = doc_nodes_mut(doc) {
        *e = nodes.clone();
    }
    if !errors.is_empty() {
        return Err(PipelineError(errors));
    }
    Ok(nodes)
}

impl<'a> Builder<'a> {
    /// A builder with no computations yet.
    pub(super) fn new(registry: &'a Registry, store: &'a Store) -> Self {
        Builder {
            registry,
            store,
            comps: Vec::new(),
            by_sid: HashMap::new(),
            ext_cache: HashMap::new(),
            uninstalled: 0,
        }
    }
}

impl Builder<'_> {
    /// Resolves one point's document; returns (instance name, node name, comp) per instance.
    pub(super) fn resolve_point(
        &mut self,
        doc: &mut Value,
    ) -> Result<Vec<(String, String, usize)>, PipelineError> {
        let nodes = substitute_params(doc)?;
        let all_names: Vec<String> = nodes
            .iter()
            .filter_map(|(k, _)| k.as_str().map(str::to_string))
            .collect();
        let (locals, by_node) = self.type_nodes(&nodes)?;
        let edges = self.resolve_inputs(&locals, &by_node, &all_names)?;
        let order = check_cycles(&locals, &edges)?;
        let global = self.intern(&locals, &edges, &order);
        Ok(locals
            .iter()
            .zip(global)
            .map(|(l, g)| (l.name.clone(), l.base.clone(), g))
            .collect())
    }

    /// Step 2: types every node (kind, `repeat`, args) and expands its repeat instances.
    /// Returns the instances in file order and, per node name, its instances.
    fn type_nodes(&self, nodes: &[(Value, Value)]) -> Result<(Vec<Local>, ByNode), PipelineError> {
        let mut errors = Vec::new();
        let mut locals: Vec<Local> = Vec::new();
        let mut by_node: ByNode = BTreeMap::new();
        for (k, v) in nodes {
            let name = k.as_str().unwrap_or_default().to_string();
            if let Some(ids) = self.type_node(&name, k, v, &mut locals, &mut errors) {
                by_node.insert(name, ids);
            }
        }
        if !errors.is_empty() {
            return Err(PipelineError(errors));
        }
        Ok((locals, by_node))
    }

    /// Types node `name` (written at `k`, body `v`) and appends its instances to `locals`.
    /// Returns its instances and whether it repeats, or `None` when its kind, `repeat` or
    /// `args` is unusable (the problem is in `errors`). An instance whose args do not type
    /// stops the node's instances there (the problem is in `errors`).
    fn type_node(
        &self,
        name: &str,
        k: &Value,
        v: &Value,
        locals: &mut Vec<Local>,
        errors: &mut Vec<Diagnostic>,
    ) -> Option<(Vec<usize>, bool)> {
        let header = self
            .node_kind(name, v)
            .and_then(|(node, kind_name)| Ok((node, kind_name, node_repeat(v)?, node_args(v)?)));
        let (node, kind_name, repeat, args_v) = match header {
            Ok(h) => h,
            Err(d) => {
                errors.push(d);
                return None;
            }
        };
        let defaults = node.default_args_json();
        let has_seed = defaults.get("seed").is_some_and(|s| s.is_u64());
        let mut ids = Vec::new();
        for i in 0..repeat.unwrap_or(1) {
            let (a, salt) = match repeat {
                Some(_) => instance_args(&*node, &args_v, i, has_seed),
                None => (args_v.clone(), None),
            };
            let typed = match typed_args(&*node, name, kind_name, &a, &defaults) {
                Ok(t) => t,
                Err(d) => {
                    errors.push(d);
                    break;
                }
            };
            let inst_name = if repeat.is_some() {
                format!("{name}[{i}]")
            } else {
                name.to_string()
            };
            locals.push(Local {
                name: inst_name,
                base: name.to_string(),
                index: repeat.map(|_| i),
                outputs: node.outputs(&typed),
                decls: node.inputs(&typed),
                node: node.clone(),
                args: typed,
                args_value: a,
                salt,
                inputs_value: v.field("inputs").cloned(),
                gate_value: v.field("gate").cloned(),
                node_origin: k.origin.clone(),
            });
            ids.push(locals.len() - 1);
        }
        Some((ids, repeat.is_some()))
    }

    /// The registered kind that node `name` (body `v`) names, and the kind's name.
    fn node_kind<'v>(
        &self,
        name: &str,
        v: &'v Value,
    ) -> Result<(Arc<dyn DynNode>, &'v str), Diagnostic> {
        let Some(kind_v) = v.field("kind") else {
            return Err(
                Diagnostic::at(&v.origin, format!("node `{name}` has no `kind`"))
                    .hint("write `kind: \"KindName\"`"),
            );
        };
        let Some(kind_name) = kind_v.as_str() else {
            return Err(Diagnostic::at(&kind_v.origin, "`kind` must be a string"));
        };
        let Some(node) = self.registry.get(kind_name).cloned() else {
            let names = self.registry.names();
            let close: Vec<&str> = names
                .iter()
                .copied()
                .filter(|n| super::refs::similar(n, kind_name))
                .collect();
            let hint = if close.is_empty() {
                format!("registered kinds: {}", names.join(", "))
            } else {
                format!(
                    "did you mean {}? (registered kinds: {})",
                    close.join(" or "),
                    names.join(", ")
                )
            };
            return Err(
                Diagnostic::at(&kind_v.origin, format!("unknown node kind `{kind_name}`"))
                    .hint(hint),
            );
        };
        Ok((node, kind_name))
    }

    /// Step 3: resolves every instance's input references. Returns, per instance, its input
    /// slots sorted by name.
    fn resolve_inputs(
        &mut self,
        locals: &[Local],
        by_node: &ByNode,
        all_names: &[String],
    ) -> Result<Vec<Vec<LSlot>>, PipelineError> {
        let mut errors = Vec::new();
        let edges = locals
            .iter()
            .map(|l| self.resolve_slots(l, by_node, locals, all_names, &mut errors))
            .collect();
        if !errors.is_empty() {
            return Err(PipelineError(errors));
        }
        Ok(edges)
    }

    /// The input slots of instance `l`, sorted by name; problems (an `inputs` that is not a
    /// map, unknown inputs, bad references, wrong counts, missing inputs) go to `errors`.
    fn resolve_slots(
        &mut self,
        l: &Local,
        by_node: &ByNode,
        locals: &[Local],
        all_names: &[String],
        errors: &mut Vec<Diagnostic>,
    ) -> Vec<LSlot> {
        let mut slots: Vec<LSlot> = Vec::new();
        let entries: Vec<(Value, Value)> = match l.inputs_value.as_ref().map(|v| &v.kind) {
            None | Some(ValueKind::Unit) => Vec::new(),
            Some(ValueKind::Map(e)) => e.clone(),
            Some(_) => {
                let v = l.inputs_value.as_ref().expect("matched Some");
                errors.push(Diagnostic::at(
                    &v.origin,
                    format!(
                        "`inputs` of `{}` must be a map {{ \"input\": \"node.output\" }}",
                        l.base
                    ),
                ));
                return slots;
            }
        };
        let declared: Vec<&str> = l.decls.iter().map(|d| d.name.as_str()).collect();
        for (k, v) in &entries {
            let Some(iname) = k.as_str() else {
                errors.push(Diagnostic::at(&k.origin, "input names must be strings"));
                continue;
            };
            let Some(decl) = l.decls.iter().find(|d| d.name == iname) else {
                errors.push(
                    Diagnostic::at(
                        &k.origin,
                        format!(
                            "node `{}` ({}) has no input `{iname}`",
                            l.base,
                            l.node.kind()
                        ),
                    )
                    .hint(if declared.is_empty() {
                        "this kind takes no inputs".to_string()
                    } else {
                        format!("its inputs: {}", declared.join(", "))
                    }),
                );
                continue;
            };
            let items: Vec<&Value> = match &v.kind {
                ValueKind::List(items) => items.iter().collect(),
                _ => vec![v],
            };
            let errors_before = errors.len();
            let uninstalled_before = self.uninstalled;
            let mut sources = Vec::new();
            for item in items {
                match self.resolve_ref(l, item, decl, by_node, locals, all_names) {
                    Ok(mut s) => sources.append(&mut s),
                    Err(d) => errors.push(d),
                }
            }
            // An optional input whose only references name resources that are not installed
            // stays unconnected, as if it were not written.
            if sources.is_empty()
                && self.uninstalled > uninstalled_before
                && errors.len() == errors_before
            {
                continue;
            }
            if !decl.many
                && sources.len() != 1
                && !errors.iter().any(|e| e.origin.as_ref() == Some(&v.origin))
            {
                errors.push(Diagnostic::at(
                    &v.origin,
                    format!(
                        "input `{iname}` of `{}` takes one reference, found {}",
                        l.name,
                        sources.len()
                    ),
                ));
            }
            if decl.many && sources.is_empty() && errors.len() == errors_before {
                errors.push(
                    Diagnostic::at(
                        &v.origin,
                        format!("list input `{iname}` of `{}` gets no folder", l.name),
                    )
                    .hint("a list input needs at least one reference (is a `repeat` 0?)"),
                );
            }
            slots.push((iname.to_string(), sources));
        }
        if let Some(g) = &l.gate_value {
            // The gate is a hidden input slot: its decision is part of the key.
            let decl = InputDecl::one(crate::gate::GATE_SLOT);
            match self.resolve_ref(l, g, &decl, by_node, locals, all_names) {
                Ok(s) if s.len() == 1 => slots.push((crate::gate::GATE_SLOT.to_string(), s)),
                Ok(s) => errors.push(
                    Diagnostic::at(
                        &g.origin,
                        format!(
                            "`gate` of `{}` takes one reference, found {}",
                            l.name,
                            s.len()
                        ),
                    )
                    .hint("write `gate: \"node.output\"` naming one decision"),
                ),
                Err(d) => errors.push(d),
            }
        }
        for d in &l.decls {
            if !d.optional && !slots.iter().any(|(n, _)| *n == d.name) {
                errors.push(
                    Diagnostic::at(
                        &l.node_origin,
                        format!(
                            "node `{}` ({}) needs input `{}`",
                            l.base,
                            l.node.kind(),
                            d.name
                        ),
                    )
                    .hint(format!(
                        "add `inputs: {{ \"{}\": \"other_node.output\" }}`",
                        d.name
                    )),
                );
            }
        }
        slots.sort_by(|a, b| a.0.cmp(&b.0));
        slots
    }

    /// Step 5: in topological `order`, turns each instance into a computation (its inputs now
    /// naming computations), sharing the existing one with the same structural id. Returns
    /// each instance's index into `self.comps`.
    fn intern(&mut self, locals: &[Local], edges: &[Vec<LSlot>], order: &[usize]) -> Vec<usize> {
        let mut global = vec![usize::MAX; locals.len()];
        for &li in order {
            let l = &locals[li];
            let inputs = comp_inputs(&edges[li], &global);
            let canonical = l.node.canonical_args(&l.args);
            let sid = key::structural_id(&*l.node, &canonical, l.salt, &inputs, &self.comps);
            let gi = match self.by_sid.get(&sid) {
                Some(&gi) => gi,
                None => {
                    self.comps.push(Comp {
                        node: l.node.clone(),
                        args_json: l.node.args_json(&l.args),
                        args: l.args.clone(),
                        canonical,
                        salt: l.salt,
                        inputs,
                        outputs: l.outputs.clone(),
                        threads: l.node.threads(&l.args),
                        sid,
                        args_value: l.args_value.clone(),
                        instances: Vec::new(),
                    });
                    self.by_sid.insert(sid, self.comps.len() - 1);
                    self.comps.len() - 1
                }
            };
            global[li] = gi;
        }
        global
    }
}

/// The largest `repeat` a node may have: each instance is a computation with its own key,
/// entry and output folders, so more would be a typo rather than an ensemble.
pub const MAX_REPEAT: usize = 10_000;

/// Node body `v`'s `repeat`: `None` without one.
fn node_repeat(v: &Value) -> Result<Option<usize>, Diagnostic> {
    match v.field("repeat") {
        None => Ok(None),
        Some(r) => match &r.kind {
            ValueKind::Num(n) if n.parse::<usize>().is_ok_and(|k| k > MAX_REPEAT) => {
                Err(Diagnostic::at(
                    &r.origin,
                    format!(
                        "`repeat` is {n}; at most {MAX_REPEAT} instances of a node are allowed"
                    ),
                ))
            }
            ValueKind::Num(n) if n.parse::<usize>().is_ok() => {
                Ok(Some(n.parse::<usize>().expect("checked")))
            }
            _ => Err(Diagnostic::at(
                &r.origin,
                format!(
                    "`repeat` must be a non-negative integer, found {}",
                    r.describe()
                ),
            )),
        },
    }
}

/// Node body `v`'s `args` as written (unit when absent); must be a struct.
fn node_args(v: &Value) -> Result<Value, Diagnostic> {
    let args_v = v
        .field("args")
        .cloned()
        .unwrap_or_else(|| Value::new(ValueKind::Unit, v.origin.clone()));
    if args_v.fields().is_none() {
        return Err(Diagnostic::at(
            &args_v.origin,
            format!(
                "`args` must be a struct `(name: value, ..)`, found {}",
                args_v.describe()
            ),
        ));
    }
    Ok(args_v)
}

/// The written args of repeat instance `i` and its salt: with a numeric `seed` arg
/// (`has_seed`), instance `i` gets `seed + i` (an engine-set value) and no salt; otherwise the
/// args are unchanged and the salt is `i`.
fn instance_args(
    node: &dyn DynNode,
    args_v: &Value,
    i: usize,
    has_seed: bool,
) -> (Value, Option<u64>) {
    let mut a = args_v.clone();
    if !has_seed {
        return (a, Some(i as u64));
    }
    let base = match node.parse_args(&a.to_ron()) {
        Ok(t) => node
            .args_json(&t)
            .get("seed")
            .and_then(|s| s.as_u64())
            .unwrap_or(0),
        Err(_) => 0,
    };
    let origin = Origin::Engine(Arc::from(format!("repeat instance {i}: seed {base} + {i}")));
    if let ValueKind::Unit = a.kind {
        a.kind = ValueKind::Struct(None, Vec::new());
    }
    if let ValueKind::Struct(_, f) = &mut a.kind {
        let v = Value::new(
            ValueKind::Num(base.wrapping_add(i as u64).to_string()),
            origin,
        );
        match f.iter_mut().find(|(n, _)| n == "seed") {
            Some(slot) => slot.1 = v,
            None => f.push(("seed".into(), v)),
        }
    }
    (a, None)
}

/// Parses and validates written args `a` of node `name` (kind `kind_name`, default args
/// `defaults`); a diagnostic points at the offending field when it is written.
fn typed_args(
    node: &dyn DynNode,
    name: &str,
    kind_name: &str,
    a: &Value,
    defaults: &serde_json::Value,
) -> Result<ArgsBox, Diagnostic> {
    let typed = match node.parse_args(&a.to_ron()) {
        Ok(t) => t,
        Err(e) => {
            let at = locate(a, &e.path, &e.message);
            let d = Diagnostic::at(
                &at.origin,
                format!(
                    "invalid args for node `{name}` ({kind_name}){}: {}",
                    if e.path.is_empty() {
                        String::new()
                    } else {
                        format!(" at `{}`", e.path)
                    },
                    e.message
                ),
            );
            let fields: Vec<String> = defaults
                .as_object()
                .map(|o| o.keys().cloned().collect())
                .unwrap_or_default();
            return Err(
                match default_at(defaults, &e.path).filter(|_| !e.path.is_empty()) {
                    Some(dv) => d.hint(format!("`{}` defaults to {dv}", e.path)),
                    None => d.hint(format!("{kind_name} args: {}", fields.join(", "))),
                },
            );
        }
    };
    if let Err(msg) = node.validate(&typed) {
        let mut d = Diagnostic::at(
            &a.origin,
            format!("invalid args for node `{name}` ({kind_name}): {msg}"),
        );
        let overrides = overrides_in(a);
        if !overrides.is_empty() {
            d = d.hint(format!("values here come from {}", overrides.join(", ")));
        }
        return Err(d);
    }
    Ok(typed)
}

/// Step 4: the instances' inputs must not form a cycle. Returns the instances (indices into
/// `locals`) in a topological order, upstream first; a cycle is reported with its chain, at
/// the `inputs` of one of its nodes.
fn check_cycles(locals: &[Local], edges: &[Vec<LSlot>]) -> Result<Vec<usize>, PipelineError> {
    let mut g = petgraph::graph::DiGraph::<usize, ()>::new();
    let ids: Vec<_> = (0..locals.len()).map(|i| g.add_node(i)).collect();
    for (i, slots) in edges.iter().enumerate() {
        for (_, srcs) in slots {
            for (s, _) in srcs {
                if let LSource::Local(j, _) = s {
                    g.add_edge(ids[*j], ids[i], ());
                }
            }
        }
    }
    match petgraph::algo::toposort(&g, None) {
        Ok(o) => Ok(o.into_iter().map(|nid| g[nid]).collect()),
        Err(_) => {
            let sccs = petgraph::algo::tarjan_scc(&g);
            let cyc = sccs
                .into_iter()
                .find(|c| c.len() > 1 || g.contains_edge(c[0], c[0]))
                .unwrap_or_default();
            let mut names: Vec<&str> = cyc.iter().map(|n| locals[g[*n]].name.as_str()).collect();
            names.reverse();
            let first = cyc.last().map(|n| g[*n]).unwrap_or(0);
            let origin = locals[first]
                .inputs_value
                .as_ref()
                .map(|v| v.origin.clone())
                .unwrap_or(locals[first].node_origin.clone());
            let mut chain = names.join(" -> ");
            chain.push_str(&format!(" -> {}", names.first().unwrap_or(&"?")));
            Err(
                Diagnostic::at(&origin, format!("the inputs form a cycle: {chain}"))
                    .hint("a node cannot depend on its own output; break the cycle by removing one input")
                    .into(),
            )
        }
    }
}

/// An instance's slots with local sources replaced by computations (`global`: instance index
/// -> computation index, filled for every upstream instance).
fn comp_inputs(slots: &[LSlot], global: &[usize]) -> Vec<InputSlot> {
    slots
        .iter()
        .map(|(name, srcs)| InputSlot {
            name: name.clone(),
            sources: srcs
                .iter()
                .map(|(s, shown)| {
                    let src = match s {
                        LSource::Local(j, out) => Source::Node {
                            comp: global[*j],
                            output: out.clone(),
                        },
                        LSource::External(p, h) => Source::External {
                            path: p.clone(),
                            hash: *h,
                        },
                    };
                    (src, shown.clone())
                })
                .collect(),
        })
        .collect()
}

/// Finds the value at an `ArgsError` path inside the written args, for its origin.
fn locate<'v>(args: &'v Value, path: &str, message: &str) -> &'v Value {
    let mut cur = args;
    let segs: Vec<String> = path
        .replace('[', ".[")
        .split('.')
        .filter(|s| !s.is_empty())
        .map(str::to_string)
        .collect();
    for seg in &segs {
        let next = if let Some(idx) = seg.strip_prefix('[').and_then(|s| s.strip_suffix(']')) {
            match (&cur.kind, idx.parse::<usize>()) {
                (ValueKind::List(items) | ValueKind::Tuple(_, items), Ok(i)) => items.get(i),
                _ => None,
            }
        } else {
            match &cur.kind {
                ValueKind::Struct(_, f) => f.iter().find(|(n, _)| n == seg).map(|(_, v)| v),
                ValueKind::Map(e) => e
                    .iter()
                    .find(|(k, _)| k.as_str() == Some(seg) || k.to_ron() == *seg)
                    .map(|(_, v)| v),
                ValueKind::Tuple(Some(n), items) if n == seg && items.len() == 1 => items.first(),
                _ => None,
            }
        };
        match next {
            Some(n) => cur = n,
            None => break,
        }
    }
    // Unknown-field errors name the field in backticks: point at it if it is written here.
    for tok in message.split('`').skip(1).step_by(2) {
        if let ValueKind::Struct(_, f) = &cur.kind {
            if let Some((_, v)) = f.iter().find(|(n, _)| n == tok) {
                return v;
            }
        }
    }
    cur
}

/// The default value at dotted `path` inside a kind's default args.
fn default_at<'j>(json: &'j serde_json::Value, path: &str) -> Option<&'j serde_json::Value> {
    let mut cur = json;
    for seg in path.split('.').filter(|s| !s.is_empty()) {
        cur = cur.get(seg)?;
    }
    Some(cur)
}

/// The `--set` / sweep / engine origins of values inside `v` (for messages about whole args).
fn overrides_in(v: &Value) -> Vec<String> {
    fn walk(v: &Value, out: &mut Vec<String>) {
        if !matches!(v.origin, Origin::File { .. }) {
            let s = v.origin.to_string();
            if !out.contains(&s) {
                out.push(s);
            }
        }
        match &v.kind {
            ValueKind::List(items) | ValueKind::Tuple(_, items) => {
                items.iter().for_each(|i| walk(i, out))
            }
            ValueKind::Map(e) => e.iter().for_each(|(_, x)| walk(x, out)),
            ValueKind::Struct(_, f) => f.iter().for_each(|(_, x)| walk(x, out)),
            _ => {}
        }
    }
    let mut out = Vec::new();
    walk(v, &mut out);
    out
}

/// The `nodes` map of a pipeline document, for writing substituted nodes back.
fn doc_nodes_mut(doc: &mut Value) -> Option<&mut ValueKind> {
    match &mut doc.kind {
        ValueKind::Struct(_, f) => f
            .iter_mut()
            .find(|(n, _)| n == "nodes")
            .map(|(_, v)| &mut v.kind),
        _ => None,
    }
}
