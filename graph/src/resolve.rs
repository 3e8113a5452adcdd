//! From a pipeline document to a [`Plan`]: typed args through the registry, `repeat`
//! instances, input references, cycle checks, sweep points, and deduplication of identical
//! computations across instances and sweep points (by a structural id).
//!
//! Input references: `"node.output"`, `"node"` (when the node has one output), `"node[i].out"`
//! (the same repeat index as the referring node), `"node[3].out"`, `"node[*].out"` (every instance,
//! for list inputs), a list of such strings, or `Path("file-or-folder")` for an external input
//! (relative to the file that writes it; content-hashed).
//!
//! Repeats: `repeat: N` (or `Param("name")`) makes instances `node[0]..node[N-1]`. If the kind's
//! args have a numeric `seed` field, instance `i` gets `seed + i`; otherwise the instance index
//! becomes part of the key (so each instance's `ctx.seed()` differs). Either way instance `i`'s
//! key does not depend on `N`.

use crate::error::{Diagnostic, PipelineError};
use crate::node::{InputDecl, Threads};
use crate::registry::{ArgsBox, DynNode, Registry};
use crate::spec;
use crate::store::{Hash, Store, STORE_FORMAT};
use crate::syntax::{Origin, Value, ValueKind};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Where an input's folder comes from.
#[derive(Clone, Debug)]
pub enum Source {
    /// Output `output` of computation `comp`.
    Node {
        /// Index into [`Plan::comps`].
        comp: usize,
        /// The output name.
        output: String,
    },
    /// An external file or folder and its content hash.
    External {
        /// Absolute path.
        path: PathBuf,
        /// Content hash (same scheme as output manifests).
        hash: Hash,
    },
}

/// One input slot of a computation: its name and its sources (one, or a list).
#[derive(Clone, Debug)]
pub struct InputSlot {
    /// Input name.
    pub name: String,
    /// Sources with their written reference (`field[0].weights`, `Path(..)`).
    pub sources: Vec<(Source, String)>,
}

/// A unique computation: a kind with typed args and resolved inputs. Instances with the same
/// structural id (in one pipeline or across sweep points) share one computation.
pub struct Comp {
    /// The kind.
    pub node: Arc<dyn DynNode>,
    /// Typed args.
    pub args: ArgsBox,
    /// Typed args as JSON (defaults filled in).
    pub args_json: serde_json::Value,
    /// Canonical encoding of the typed args.
    pub canonical: Vec<u8>,
    /// The repeat index, when it is part of the key (kinds without a `seed` arg).
    pub salt: Option<u64>,
    /// Inputs, sorted by name.
    pub inputs: Vec<InputSlot>,
    /// Output names.
    pub outputs: Vec<String>,
    /// Wanted threads.
    pub threads: Threads,
    /// Structural id: kind, version, args, salt and the structural ids of its inputs.
    pub sid: Hash,
    /// The args as written (after overrides), with origins.
    pub args_value: Value,
    /// Instances that are this computation (indices into [`Plan::instances`]).
    pub instances: Vec<usize>,
}

impl Comp {
    /// The first instance name, for display.
    pub fn display_name<'a>(&self, plan: &'a Plan) -> &'a str {
        self.instances
            .first()
            .map(|&i| plan.instances[i].name.as_str())
            .unwrap_or("?")
    }
}

/// A named node instance (`field[2]`, `aggregate@gamma=0.5`).
#[derive(Clone, Debug)]
pub struct Instance {
    /// Full instance name.
    pub name: String,
    /// The node's name in the pipeline file.
    pub base: String,
    /// Its computation.
    pub comp: usize,
    /// The sweep points it belongs to.
    pub points: Vec<usize>,
}

/// A sweep point.
#[derive(Clone, Debug)]
pub struct PointInfo {
    /// Label (`gamma=0.5`), empty without a sweep.
    pub label: String,
    /// Instances of this point.
    pub instances: Vec<usize>,
    /// The resolved document of this point (for `expand`).
    pub document: Value,
}

/// A resolved pipeline: unique computations in topological order, instance names, sweep points.
pub struct Plan {
    /// The pipeline file.
    pub file: PathBuf,
    /// A stable id of the pipeline (from its absolute path), naming its run records.
    pub id: String,
    /// Computations; every input of `comps[i]` refers to a lower index.
    pub comps: Vec<Comp>,
    /// Instances.
    pub instances: Vec<Instance>,
    /// Sweep points (one without a sweep).
    pub points: Vec<PointInfo>,
}

impl Plan {
    /// Instances matching a target: full name, node name, or the name before `@`.
    pub fn match_target(&self, target: &str) -> Vec<usize> {
        (0..self.instances.len())
            .filter(|&i| {
                let inst = &self.instances[i];
                inst.name == target
                    || inst.base == target
                    || inst.name.split('@').next() == Some(target)
            })
            .collect()
    }
    /// Computations needed for `targets` (all when empty), as a mask.
    pub fn needed(&self, targets: &[String]) -> Result<Vec<bool>, PipelineError> {
        let mut need = vec![targets.is_empty(); self.comps.len()];
        for t in targets {
            let m = self.match_target(t);
            if m.is_empty() {
                let names: Vec<&str> = self
                    .instances
                    .iter()
                    .map(|i| i.base.as_str())
                    .collect::<std::collections::BTreeSet<_>>()
                    .into_iter()
                    .collect();
                return Err(Diagnostic::bare(format!("--target `{t}` matches no node"))
                    .hint(format!("nodes: {}", names.join(", ")))
                    .into());
            }
            for i in m {
                need[self.instances[i].comp] = true;
            }
        }
        for c in (0..self.comps.len()).rev() {
            if need[c] {
                for slot in &self.comps[c].inputs {
                    for (s, _) in &slot.sources {
                        if let Source::Node { comp, .. } = s {
                            need[*comp] = true;
                        }
                    }
                }
            }
        }
        Ok(need)
    }
}

/// The key of a computation given the manifest hash of each of its input sources (same order
/// as `comp.inputs[..].sources`): DESIGN.md §3.
pub fn compute_key(comp: &Comp, input_manifests: &[Vec<Hash>]) -> Hash {
    let mut h = blake3::Hasher::new();
    let mut put = |b: &[u8]| {
        h.update(&(b.len() as u64).to_le_bytes());
        h.update(b);
    };
    put(b"augsplat-key");
    put(&STORE_FORMAT.to_le_bytes());
    put(comp.node.kind().as_bytes());
    put(&comp.node.version().to_le_bytes());
    put(&comp.canonical);
    match comp.salt {
        Some(s) => put(&[&[1u8][..], &s.to_le_bytes()].concat()),
        None => put(&[0u8]),
    }
    put(&(comp.inputs.len() as u64).to_le_bytes());
    for (slot, ms) in comp.inputs.iter().zip(input_manifests) {
        put(slot.name.as_bytes());
        put(&(ms.len() as u64).to_le_bytes());
        for m in ms {
            put(m);
        }
    }
    *h.finalize().as_bytes()
}

/// A stable id for a pipeline file (hash of its absolute path).
pub fn pipeline_id(file: &Path) -> String {
    let abs = std::fs::canonicalize(file).unwrap_or_else(|_| file.to_path_buf());
    blake3::hash(abs.to_string_lossy().as_bytes()).to_hex()[..32].to_string()
}

/// Loads `file`, applies `--set` overrides, expands sweeps and resolves everything against the
/// registry. Hashes external inputs through `store` (cached by path + size + mtime).
pub fn load_plan(
    registry: &Registry,
    store: &Store,
    file: &Path,
    sets: &[String],
) -> Result<Plan, PipelineError> {
    let mut doc = spec::load_document(file)?;
    for s in sets {
        let (path, value) = spec::parse_set(s)?;
        spec::apply_set(&mut doc, &path, value)?;
    }
    let sweep = spec::sweep_of(&doc)?;
    if let ValueKind::Struct(_, f) = &mut doc.kind {
        f.retain(|(n, _)| n != "sweep");
    }
    let coords = spec::sweep_points(sweep.as_ref());
    let mut b = Builder {
        registry,
        store,
        comps: Vec::new(),
        by_sid: HashMap::new(),
        ext_cache: HashMap::new(),
    };
    // Per point: (base instance name -> comp), and the point's document.
    let mut per_point: Vec<Vec<(String, String, usize)>> = Vec::new();
    let mut docs = Vec::new();
    for c in &coords {
        let pt = spec::point(sweep.as_ref(), c);
        let mut pdoc = doc.clone();
        for (path, value) in &pt.assignments {
            spec::apply_set(&mut pdoc, path, value.clone()).map_err(|d| {
                let label = if pt.label.is_empty() {
                    String::new()
                } else {
                    format!(" (sweep point {})", pt.label)
                };
                Diagnostic {
                    message: format!("{}{label}", d.message),
                    ..d
                }
            })?;
        }
        let names = b.resolve_point(&mut pdoc).map_err(|mut e| {
            if !pt.label.is_empty() {
                for d in &mut e.0 {
                    d.message = format!("{} (sweep point {})", d.message, pt.label);
                }
            }
            e
        })?;
        per_point.push(names);
        docs.push(pdoc);
    }
    // Instance names: a node that is the same computation at every point keeps its name; one
    // that varies gets `@` + the sweep axes it depends on.
    let mut order: Vec<(String, String)> = Vec::new();
    let mut table: BTreeMap<String, Vec<Option<usize>>> = BTreeMap::new();
    for (p, names) in per_point.iter().enumerate() {
        for (name, base, comp) in names {
            if !table.contains_key(name) {
                order.push((name.clone(), base.clone()));
                table.insert(name.clone(), vec![None; coords.len()]);
            }
            table.get_mut(name).expect("inserted")[p] = Some(*comp);
        }
    }
    let mut instances: Vec<Instance> = Vec::new();
    let mut inst_index: HashMap<String, usize> = HashMap::new();
    let mut points: Vec<PointInfo> = coords
        .iter()
        .zip(docs)
        .map(|(c, d)| PointInfo {
            label: spec::point(sweep.as_ref(), c).label,
            instances: Vec::new(),
            document: d,
        })
        .collect();
    for (name, base) in &order {
        let comps_at = &table[name];
        let first = comps_at.iter().flatten().next().copied();
        let all_same = comps_at.iter().flatten().all(|c| Some(*c) == first);
        let relevant: Vec<usize> = match &sweep {
            Some(s) if !all_same => {
                let mut rel = Vec::new();
                if s.grid {
                    for a in 0..s.axes.len() {
                        let differs = (0..coords.len()).any(|p| {
                            (0..coords.len()).any(|q| {
                                (0..s.axes.len())
                                    .all(|k| (k == a) != (coords[p][k] == coords[q][k]))
                                    && comps_at[p].is_some()
                                    && comps_at[q].is_some()
                                    && comps_at[p] != comps_at[q]
                            })
                        });
                        if differs {
                            rel.push(a);
                        }
                    }
                }
                if rel.is_empty() {
                    rel = (0..s.axes.len()).collect();
                }
                rel
            }
            _ => Vec::new(),
        };
        // Check the label determines the computation; else use every axis.
        let label_of = |p: usize, rel: &[usize]| -> String {
            let s = sweep.as_ref().expect("relevant axes imply a sweep");
            rel.iter()
                .map(|&a| format!("{}={}", s.axes[a].1, s.axes[a].2[coords[p][a]].to_ron()))
                .collect::<Vec<_>>()
                .join(",")
        };
        let mut relevant = relevant;
        if !relevant.is_empty() {
            let mut seen: HashMap<String, usize> = HashMap::new();
            let ambiguous = (0..coords.len()).any(|p| match comps_at[p] {
                Some(c) => *seen.entry(label_of(p, &relevant)).or_insert(c) != c,
                None => false,
            });
            if ambiguous {
                relevant = (0..sweep.as_ref().map_or(0, |s| s.axes.len())).collect();
            }
        }
        for (p, c) in comps_at.iter().enumerate() {
            let Some(c) = *c else { continue };
            let full = if relevant.is_empty() {
                name.clone()
            } else {
                format!("{name}@{}", label_of(p, &relevant))
            };
            let idx = *inst_index.entry(full.clone()).or_insert_with(|| {
                instances.push(Instance {
                    name: full.clone(),
                    base: base.clone(),
                    comp: c,
                    points: Vec::new(),
                });
                b.comps[c].instances.push(instances.len() - 1);
                instances.len() - 1
            });
            instances[idx].points.push(p);
            points[p].instances.push(idx);
        }
    }
    // List instances by dependency depth, then file order, so tables read top-down.
    let mut depth = vec![0usize; b.comps.len()];
    for c in 0..b.comps.len() {
        for slot in &b.comps[c].inputs {
            for (src, _) in &slot.sources {
                if let Source::Node { comp, .. } = src {
                    depth[c] = depth[c].max(depth[*comp] + 1);
                }
            }
        }
    }
    let mut perm: Vec<usize> = (0..instances.len()).collect();
    perm.sort_by_key(|&i| (depth[instances[i].comp], i));
    let mut new_index = vec![0; instances.len()];
    for (new, &old) in perm.iter().enumerate() {
        new_index[old] = new;
    }
    let mut comps = b.comps;
    for c in &mut comps {
        for i in &mut c.instances {
            *i = new_index[*i];
        }
        c.instances.sort_unstable();
    }
    for p in &mut points {
        for i in &mut p.instances {
            *i = new_index[*i];
        }
    }
    let instances = perm.into_iter().map(|i| instances[i].clone()).collect();
    Ok(Plan {
        file: file.to_path_buf(),
        id: pipeline_id(file),
        comps,
        instances,
        points,
    })
}

struct Builder<'a> {
    registry: &'a Registry,
    store: &'a Store,
    comps: Vec<Comp>,
    by_sid: HashMap<Hash, usize>,
    ext_cache: HashMap<PathBuf, Hash>,
}

/// A node instance within one point, before deduplication.
struct Local {
    name: String,
    base: String,
    index: Option<usize>,
    node: Arc<dyn DynNode>,
    args: ArgsBox,
    args_value: Value,
    salt: Option<u64>,
    outputs: Vec<String>,
    decls: Vec<InputDecl>,
    inputs_value: Option<Value>,
    node_origin: Origin,
}

/// An input slot within one point: name and (source, written reference) pairs.
type LSlot = (String, Vec<(LSource, String)>);

enum LSource {
    Local(usize, String),
    External(PathBuf, Hash),
}

struct RefSpec {
    node: String,
    index: RefIndex,
    output: Option<String>,
}

enum RefIndex {
    None,
    Same,
    All,
    Fixed(usize),
}

fn parse_ref(s: &str) -> Option<RefSpec> {
    let (head, output) = match s.find(['.']) {
        Some(dot) if !s[..dot].contains('[') || s[..dot].contains(']') => {
            (&s[..dot], Some(s[dot + 1..].to_string()))
        }
        _ => match s.find("].") {
            Some(p) => (&s[..=p], Some(s[p + 2..].to_string())),
            None => (s, None),
        },
    };
    let (node, index) = match head.find('[') {
        Some(b) => {
            let inner = head[b + 1..].strip_suffix(']')?;
            let idx = match inner {
                "i" => RefIndex::Same,
                "*" => RefIndex::All,
                n => RefIndex::Fixed(n.parse().ok()?),
            };
            (&head[..b], idx)
        }
        None => (head, RefIndex::None),
    };
    if node.is_empty() || output.as_deref() == Some("") {
        return None;
    }
    Some(RefSpec {
        node: node.to_string(),
        index,
        output,
    })
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

fn default_at<'j>(json: &'j serde_json::Value, path: &str) -> Option<&'j serde_json::Value> {
    let mut cur = json;
    for seg in path.split('.').filter(|s| !s.is_empty()) {
        cur = cur.get(seg)?;
    }
    Some(cur)
}

impl Builder<'_> {
    fn ext_hash(&mut self, path: &Path, origin: &Origin) -> Result<Hash, Diagnostic> {
        if let Some(h) = self.ext_cache.get(path) {
            return Ok(*h);
        }
        let h = self
            .store
            .hash_external(path)
            .map_err(|e| Diagnostic::at(origin, format!("cannot hash external input: {e}")))?;
        self.ext_cache.insert(path.to_path_buf(), h);
        Ok(h)
    }

    /// Resolves one point's document; returns (instance name, node name, comp) per instance.
    fn resolve_point(
        &mut self,
        doc: &mut Value,
    ) -> Result<Vec<(String, String, usize)>, PipelineError> {
        let params = spec::params_of(doc)?;
        let mut errors = Vec::new();
        let mut locals: Vec<Local> = Vec::new();
        let mut by_node: BTreeMap<String, (Vec<usize>, bool)> = BTreeMap::new();
        let nodes: Vec<(Value, Value)> = match doc.field("nodes").map(|n| &n.kind) {
            Some(ValueKind::Map(e)) => e.clone(),
            _ => {
                return Err(Diagnostic::at(&doc.origin, "the pipeline has no `nodes`")
                    .hint("write `( nodes: { \"name\": (kind: \"Kind\", args: (..)) } )`")
                    .into())
            }
        };
        let all_names: Vec<String> = nodes
            .iter()
            .filter_map(|(k, _)| k.as_str().map(str::to_string))
            .collect();
        // Substitute params everywhere in node bodies (so `expand` shows the values).
        let mut nodes = nodes;
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
        for (k, v) in &nodes {
            let name = k.as_str().unwrap_or_default().to_string();
            let Some(kind_v) = v.field("kind") else {
                errors.push(
                    Diagnostic::at(&v.origin, format!("node `{name}` has no `kind`"))
                        .hint("write `kind: \"KindName\"`"),
                );
                continue;
            };
            let Some(kind_name) = kind_v.as_str() else {
                errors.push(Diagnostic::at(&kind_v.origin, "`kind` must be a string"));
                continue;
            };
            let Some(node) = self.registry.get(kind_name).cloned() else {
                let names = self.registry.names();
                let close: Vec<&str> = names
                    .iter()
                    .copied()
                    .filter(|n| similar(n, kind_name))
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
                errors.push(
                    Diagnostic::at(&kind_v.origin, format!("unknown node kind `{kind_name}`"))
                        .hint(hint),
                );
                continue;
            };
            let repeat = match v.field("repeat") {
                None => None,
                Some(r) => match &r.kind {
                    ValueKind::Num(n) if n.parse::<usize>().is_ok() => {
                        Some(n.parse::<usize>().expect("checked"))
                    }
                    _ => {
                        errors.push(Diagnostic::at(
                            &r.origin,
                            format!(
                                "`repeat` must be a non-negative integer, found {}",
                                r.describe()
                            ),
                        ));
                        continue;
                    }
                },
            };
            let args_v = v
                .field("args")
                .cloned()
                .unwrap_or_else(|| Value::new(ValueKind::Unit, v.origin.clone()));
            if args_v.fields().is_none() {
                errors.push(Diagnostic::at(
                    &args_v.origin,
                    format!(
                        "`args` must be a struct `(name: value, ..)`, found {}",
                        args_v.describe()
                    ),
                ));
                continue;
            }
            let defaults = node.default_args_json();
            let has_seed = defaults.get("seed").is_some_and(|s| s.is_u64());
            let count = repeat.unwrap_or(1);
            let mut ids = Vec::new();
            for i in 0..count {
                let mut a = args_v.clone();
                let mut salt = None;
                if repeat.is_some() {
                    if has_seed {
                        // Instance i gets seed + i.
                        let base = match node.parse_args(&a.to_ron()) {
                            Ok(t) => node
                                .args_json(&t)
                                .get("seed")
                                .and_then(|s| s.as_u64())
                                .unwrap_or(0),
                            Err(_) => 0,
                        };
                        let origin = Origin::Engine(Arc::from(format!(
                            "repeat instance {i}: seed {base} + {i}"
                        )));
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
                    } else {
                        salt = Some(i as u64);
                    }
                }
                let typed = match node.parse_args(&a.to_ron()) {
                    Ok(t) => t,
                    Err(e) => {
                        let at = locate(&a, &e.path, &e.message);
                        let mut d = Diagnostic::at(
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
                        d = match default_at(&defaults, &e.path).filter(|_| !e.path.is_empty()) {
                            Some(dv) => d.hint(format!("`{}` defaults to {dv}", e.path)),
                            None => d.hint(format!("{kind_name} args: {}", fields.join(", "))),
                        };
                        errors.push(d);
                        break;
                    }
                };
                if let Err(msg) = node.validate(&typed) {
                    let mut d = Diagnostic::at(
                        &a.origin,
                        format!("invalid args for node `{name}` ({kind_name}): {msg}"),
                    );
                    let overrides = overrides_in(&a);
                    if !overrides.is_empty() {
                        d = d.hint(format!("values here come from {}", overrides.join(", ")));
                    }
                    errors.push(d);
                    break;
                }
                let inst_name = if repeat.is_some() {
                    format!("{name}[{i}]")
                } else {
                    name.clone()
                };
                locals.push(Local {
                    name: inst_name,
                    base: name.clone(),
                    index: repeat.map(|_| i),
                    outputs: node.outputs(&typed),
                    decls: node.inputs(&typed),
                    node: node.clone(),
                    args: typed,
                    args_value: a,
                    salt,
                    inputs_value: v.field("inputs").cloned(),
                    node_origin: k.origin.clone(),
                });
                ids.push(locals.len() - 1);
            }
            by_node.insert(name, (ids, repeat.is_some()));
        }
        if !errors.is_empty() {
            return Err(PipelineError(errors));
        }
        // Inputs.
        let mut edges: Vec<Vec<LSlot>> = Vec::new();
        for l in &locals {
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
                    edges.push(slots);
                    continue;
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
                let mut sources = Vec::new();
                for item in items {
                    match self.resolve_ref(l, item, decl, &by_node, &locals, &all_names) {
                        Ok(mut s) => sources.append(&mut s),
                        Err(d) => errors.push(d),
                    }
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
            edges.push(slots);
        }
        if !errors.is_empty() {
            return Err(PipelineError(errors));
        }
        // Cycles and topological order.
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
        let order = match petgraph::algo::toposort(&g, None) {
            Ok(o) => o,
            Err(_) => {
                let sccs = petgraph::algo::tarjan_scc(&g);
                let cyc = sccs
                    .into_iter()
                    .find(|c| c.len() > 1 || g.contains_edge(c[0], c[0]))
                    .unwrap_or_default();
                let mut names: Vec<&str> =
                    cyc.iter().map(|n| locals[g[*n]].name.as_str()).collect();
                names.reverse();
                let first = cyc.last().map(|n| g[*n]).unwrap_or(0);
                let origin = locals[first]
                    .inputs_value
                    .as_ref()
                    .map(|v| v.origin.clone())
                    .unwrap_or(locals[first].node_origin.clone());
                let mut chain = names.join(" -> ");
                chain.push_str(&format!(" -> {}", names.first().unwrap_or(&"?")));
                return Err(Diagnostic::at(&origin, format!("the inputs form a cycle: {chain}"))
                    .hint("a node cannot depend on its own output; break the cycle by removing one input")
                    .into());
            }
        };
        // Structural ids and global comps, upstream first.
        let mut global = vec![usize::MAX; locals.len()];
        for nid in order {
            let li = g[nid];
            let l = &locals[li];
            let inputs: Vec<InputSlot> = edges[li]
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
                .collect();
            let canonical = l.node.canonical_args(&l.args);
            let mut h = blake3::Hasher::new();
            h.update(b"augsplat-sid");
            h.update(l.node.kind().as_bytes());
            h.update(&l.node.version().to_le_bytes());
            h.update(&(canonical.len() as u64).to_le_bytes());
            h.update(&canonical);
            h.update(&l.salt.map_or([0xff; 8], u64::to_le_bytes));
            for slot in &inputs {
                h.update(&(slot.name.len() as u64).to_le_bytes());
                h.update(slot.name.as_bytes());
                h.update(&(slot.sources.len() as u64).to_le_bytes());
                for (s, _) in &slot.sources {
                    match s {
                        Source::Node { comp, output } => {
                            h.update(b"N");
                            h.update(&self.comps[*comp].sid);
                            h.update(&(output.len() as u64).to_le_bytes());
                            h.update(output.as_bytes());
                        }
                        Source::External { hash, .. } => {
                            h.update(b"E");
                            h.update(hash);
                        }
                    }
                }
            }
            let sid = *h.finalize().as_bytes();
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
        Ok(locals
            .iter()
            .enumerate()
            .map(|(i, l)| (l.name.clone(), l.base.clone(), global[i]))
            .collect())
    }

    #[allow(clippy::too_many_arguments)]
    fn resolve_ref(
        &mut self,
        l: &Local,
        item: &Value,
        decl: &InputDecl,
        by_node: &BTreeMap<String, (Vec<usize>, bool)>,
        locals: &[Local],
        all_names: &[String],
    ) -> Result<Vec<(LSource, String)>, Diagnostic> {
        if let ValueKind::Tuple(Some(t), items) = &item.kind {
            if t == "Path" {
                let Some(rel) = items
                    .first()
                    .and_then(|v| v.as_str())
                    .filter(|_| items.len() == 1)
                else {
                    return Err(Diagnostic::at(
                        &item.origin,
                        "write `Path(\"relative/or/absolute/path\")`",
                    ));
                };
                let p = item.origin.base_dir().join(rel);
                if !p.exists() {
                    return Err(Diagnostic::at(
                        &item.origin,
                        format!("external input {} does not exist", p.display()),
                    )
                    .hint("paths are relative to the pipeline file that writes them"));
                }
                let abs = std::fs::canonicalize(&p).unwrap_or(p);
                let h = self.ext_hash(&abs, &item.origin)?;
                return Ok(vec![(
                    LSource::External(abs.clone(), h),
                    format!("Path({:?})", abs.display().to_string()),
                )]);
            }
        }
        let Some(text) = item.as_str() else {
            return Err(Diagnostic::at(
                &item.origin,
                format!(
                    "an input reference must be a string \"node.output\" or Path(\"..\"), found {}",
                    item.describe()
                ),
            ));
        };
        let Some(r) = parse_ref(text) else {
            return Err(Diagnostic::at(&item.origin, format!("`{text}` is not a reference"))
                .hint("write \"node.output\", \"node\", \"node[i].output\", \"node[*].output\" or \"node[2].output\""));
        };
        let Some((ids, repeated)) = by_node.get(&r.node) else {
            let close: Vec<&str> = all_names
                .iter()
                .map(|s| s.as_str())
                .filter(|n| similar(n, &r.node))
                .collect();
            let hint = if close.is_empty() {
                format!("nodes: {}", all_names.join(", "))
            } else {
                format!("did you mean `{}`?", close.join("` or `"))
            };
            return Err(Diagnostic::at(
                &item.origin,
                format!(
                    "input `{}` of `{}` refers to `{}`, which is not a node",
                    decl.name, l.base, r.node
                ),
            )
            .hint(hint));
        };
        let picked: Vec<usize> = match (&r.index, repeated) {
            (RefIndex::None, false) => ids.clone(),
            (RefIndex::None, true) if decl.many => ids.clone(),
            (RefIndex::None, true) => {
                return Err(Diagnostic::at(
                    &item.origin,
                    format!("`{}` has {} instances; say which", r.node, ids.len()),
                )
                .hint(format!(
                "write `{0}[i]` for the same index, `{0}[0]` for one, or `{0}[*]` for a list input",
                r.node
            )))
            }
            (RefIndex::All, _) => {
                if !decl.many {
                    return Err(Diagnostic::at(
                        &item.origin,
                        format!(
                            "input `{}` takes one folder, but `{}[*]` is a list",
                            decl.name, r.node
                        ),
                    )
                    .hint("use `[i]` or a fixed index, or connect a list input"));
                }
                ids.clone()
            }
            (RefIndex::Same, _) => {
                let Some(i) = l.index else {
                    return Err(Diagnostic::at(
                        &item.origin,
                        format!("`{}[i]` needs `{}` to have `repeat`", r.node, l.base),
                    )
                    .hint("use a fixed index such as `[0]`"));
                };
                if !repeated {
                    return Err(Diagnostic::at(
                        &item.origin,
                        format!(
                            "`{}` has no `repeat`; write `{}` without an index",
                            r.node, r.node
                        ),
                    ));
                }
                match ids.get(i) {
                    Some(&x) => vec![x],
                    None => {
                        return Err(Diagnostic::at(
                            &item.origin,
                            format!(
                                "`{}[i]` with i = {i}: `{}` has only {} instances",
                                r.node,
                                r.node,
                                ids.len()
                            ),
                        )
                        .hint("give both nodes the same `repeat`"))
                    }
                }
            }
            (RefIndex::Fixed(k), _) => match (repeated, ids.get(*k)) {
                (true, Some(&x)) => vec![x],
                _ => {
                    return Err(Diagnostic::at(
                        &item.origin,
                        format!(
                            "`{}[{k}]`: `{}` has {} instance(s)",
                            r.node,
                            r.node,
                            ids.len()
                        ),
                    ))
                }
            },
        };
        let mut out = Vec::new();
        for j in picked {
            let t = &locals[j];
            let output = match &r.output {
                Some(o) if t.outputs.contains(o) => o.clone(),
                Some(o) => {
                    return Err(Diagnostic::at(
                        &item.origin,
                        format!("`{}` ({}) has no output `{o}`", r.node, t.node.kind()),
                    )
                    .hint(format!("its outputs: {}", t.outputs.join(", "))))
                }
                None if t.outputs.len() == 1 => t.outputs[0].clone(),
                None => {
                    return Err(Diagnostic::at(
                        &item.origin,
                        format!(
                            "`{}` ({}) has {} outputs; say which",
                            r.node,
                            t.node.kind(),
                            t.outputs.len()
                        ),
                    )
                    .hint(format!(
                        "write `{}.OUTPUT` with OUTPUT one of {}",
                        r.node,
                        t.outputs.join(", ")
                    )))
                }
            };
            out.push((
                LSource::Local(j, output.clone()),
                format!("{}.{output}", t.name),
            ));
        }
        Ok(out)
    }
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

fn doc_nodes_mut(doc: &mut Value) -> Option<&mut ValueKind> {
    match &mut doc.kind {
        ValueKind::Struct(_, f) => f
            .iter_mut()
            .find(|(n, _)| n == "nodes")
            .map(|(_, v)| &mut v.kind),
        _ => None,
    }
}

/// Whether two names are close (case-insensitive equal, one contains the other, or edit distance ≤ 2).
fn similar(a: &str, b: &str) -> bool {
    let (a, b) = (a.to_lowercase(), b.to_lowercase());
    if a == b || (b.len() >= 3 && a.contains(&b)) || (a.len() >= 3 && b.contains(&a)) {
        return true;
    }
    let (a, b): (Vec<char>, Vec<char>) = (a.chars().collect(), b.chars().collect());
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for i in 1..=a.len() {
        let mut cur = vec![i; b.len() + 1];
        for j in 1..=b.len() {
            cur[j] = (prev[j] + 1)
                .min(cur[j - 1] + 1)
                .min(prev[j - 1] + usize::from(a[i - 1] != b[j - 1]));
        }
        prev = cur;
    }
    prev[b.len()] <= 2
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refs() {
        let r = parse_ref("field[i].weights").unwrap();
        assert_eq!(
            (r.node.as_str(), r.output.as_deref()),
            ("field", Some("weights"))
        );
        assert!(matches!(r.index, RefIndex::Same));
        let r = parse_ref("render[*].renders").unwrap();
        assert!(matches!(r.index, RefIndex::All));
        let r = parse_ref("scene").unwrap();
        assert!(r.output.is_none() && matches!(r.index, RefIndex::None));
        assert!(matches!(
            parse_ref("a[3]").unwrap().index,
            RefIndex::Fixed(3)
        ));
        assert!(parse_ref("a[x].b").is_none());
        assert!(parse_ref("a.").is_none());
        assert!(similar("TrainField", "TrainFeild"));
        assert!(!similar("Alpha", "Omega"));
    }
}
