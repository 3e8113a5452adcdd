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
//!
//! [`load_plan`] resolves each sweep point's document with `point`'s steps (substitute params
//! → type nodes → resolve inputs → check cycles → intern), then names the instances across
//! points and orders them for display. What identifies a computation (its structural id) and
//! what addresses its outputs (its key) live in [`crate::key`].

mod point;
pub(crate) mod refs;
mod resources;

pub use crate::key::{compute_key, pipeline_id};
pub use resources::Resources;

use crate::error::{Diagnostic, PipelineError};
use crate::node::Threads;
use crate::registry::{ArgsBox, DynNode, Registry};
use crate::spec;
use crate::store::{Hash, Store};
use crate::syntax::{Value, ValueKind};
use point::Builder;
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
    /// Structural id: kind, version, args, salt and the structural ids of its inputs (see
    /// [`crate::key::structural_id`]).
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
    /// Things that load but are probably not what the user meant (a declared param that no
    /// node uses), each with its location; `plan` and `run` print them.
    pub warnings: Vec<String>,
    /// The `resources:` block: Slurm resources by node name or kind (never part of a key).
    pub resources: BTreeMap<String, Resources>,
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
    /// Computation `c` and every computation it needs (transitively), in plan order.
    pub fn closure(&self, c: usize) -> Vec<usize> {
        let mut need = vec![false; self.comps.len()];
        need[c] = true;
        for i in (0..=c).rev() {
            if need[i] {
                for slot in &self.comps[i].inputs {
                    for (s, _) in &slot.sources {
                        if let Source::Node { comp, .. } = s {
                            need[*comp] = true;
                        }
                    }
                }
            }
        }
        (0..self.comps.len()).filter(|&i| need[i]).collect()
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
    // Params inherited through `extends` are the base file's business: warn about those the
    // pipeline file itself declares or a `--set` gives.
    let own_file = std::fs::canonicalize(file).unwrap_or_else(|_| file.to_path_buf());
    let warnings: Vec<String> = spec::unused_params(&doc)
        .into_iter()
        .filter(|(_, origin)| match origin {
            crate::syntax::Origin::File { path, .. } => {
                std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf()) == own_file
            }
            _ => true,
        })
        .map(|(name, origin)| {
            format!("{origin}: param `{name}` is declared but no node uses it (`Param(\"{name}\")`); setting it changes nothing")
        })
        .collect();
    let sweep = spec::sweep_of(&doc)?;
    let resources = resources::parse(&doc)?;
    if let ValueKind::Struct(_, f) = &mut doc.kind {
        f.retain(|(n, _)| n != "sweep" && n != "resources");
    }
    let coords = spec::sweep_points(sweep.as_ref());
    let mut b = Builder::new(registry, store);
    let mut per_point: Vec<Vec<(String, String, usize)>> = Vec::new();
    let mut points = Vec::new();
    for c in &coords {
        let pt = spec::point(sweep.as_ref(), c);
        let (names, document) = resolve_sweep_point(&mut b, &doc, &pt)?;
        per_point.push(names);
        points.push(PointInfo {
            label: pt.label,
            instances: Vec::new(),
            document,
        });
    }
    let mut comps = b.comps;
    let instances = name_instances(&mut comps, &mut points, &per_point, sweep.as_ref(), &coords);
    let instances = order_by_depth(&mut comps, &mut points, instances);
    Ok(Plan {
        file: file.to_path_buf(),
        id: pipeline_id(file),
        comps,
        instances,
        points,
        warnings,
        resources,
    })
}

/// Resolves sweep point `pt` of `doc`: applies its assignments and resolves the resulting
/// document (messages name the point). Returns (instance name, node name, comp) per instance
/// and the point's resolved document.
#[allow(clippy::type_complexity)]
fn resolve_sweep_point(
    b: &mut Builder<'_>,
    doc: &Value,
    pt: &spec::SweepPoint,
) -> Result<(Vec<(String, String, usize)>, Value), PipelineError> {
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
    Ok((names, pdoc))
}

/// Names the instances across sweep points: a node that is the same computation at every
/// point keeps its name; one that varies gets `@` + the sweep axes it depends on. Fills
/// `comps[..].instances` and `points[..].instances`; instances come in first-seen order.
fn name_instances(
    comps: &mut [Comp],
    points: &mut [PointInfo],
    per_point: &[Vec<(String, String, usize)>],
    sweep: Option<&spec::Sweep>,
    coords: &[Vec<usize>],
) -> Vec<Instance> {
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
    for (name, base) in &order {
        let comps_at = &table[name];
        let relevant = relevant_axes(sweep, coords, comps_at);
        let label_of = |p: usize| -> String {
            let s = sweep.expect("relevant axes imply a sweep");
            relevant
                .iter()
                .map(|&a| format!("{}={}", s.axes[a].1, s.axes[a].2[coords[p][a]].to_ron()))
                .collect::<Vec<_>>()
                .join(",")
        };
        for (p, c) in comps_at.iter().enumerate() {
            let Some(c) = *c else { continue };
            let full = if relevant.is_empty() {
                name.clone()
            } else {
                format!("{name}@{}", label_of(p))
            };
            let idx = *inst_index.entry(full.clone()).or_insert_with(|| {
                instances.push(Instance {
                    name: full.clone(),
                    base: base.clone(),
                    comp: c,
                    points: Vec::new(),
                });
                comps[c].instances.push(instances.len() - 1);
                instances.len() - 1
            });
            instances[idx].points.push(p);
            points[p].instances.push(idx);
        }
    }
    instances
}

/// The sweep axes (indices) a node's name must show, given its computation at each point
/// (`comps_at`, `None` where the point lacks it): none when it is one computation at every
/// point; on a grid, the axes along which it changes; every axis for a zip, or when those
/// axes' values do not determine the computation.
fn relevant_axes(
    sweep: Option<&spec::Sweep>,
    coords: &[Vec<usize>],
    comps_at: &[Option<usize>],
) -> Vec<usize> {
    let first = comps_at.iter().flatten().next().copied();
    let all_same = comps_at.iter().flatten().all(|c| Some(*c) == first);
    let s = match sweep {
        Some(s) if !all_same => s,
        _ => return Vec::new(),
    };
    let mut rel = Vec::new();
    if s.grid {
        for a in 0..s.axes.len() {
            let differs = (0..coords.len()).any(|p| {
                (0..coords.len()).any(|q| {
                    (0..s.axes.len()).all(|k| (k == a) != (coords[p][k] == coords[q][k]))
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
    // Check the label determines the computation; else use every axis.
    let label_of = |p: usize| -> String {
        rel.iter()
            .map(|&a| format!("{}={}", s.axes[a].1, s.axes[a].2[coords[p][a]].to_ron()))
            .collect::<Vec<_>>()
            .join(",")
    };
    let mut seen: HashMap<String, usize> = HashMap::new();
    let ambiguous = (0..coords.len()).any(|p| match comps_at[p] {
        Some(c) => *seen.entry(label_of(p)).or_insert(c) != c,
        None => false,
    });
    if ambiguous {
        rel = (0..s.axes.len()).collect();
    }
    rel
}

/// Lists instances by dependency depth, then first-seen order, so tables read top-down;
/// renumbers the instance indices held by `comps` and `points` to match.
fn order_by_depth(
    comps: &mut [Comp],
    points: &mut [PointInfo],
    instances: Vec<Instance>,
) -> Vec<Instance> {
    let mut depth = vec![0usize; comps.len()];
    for c in 0..comps.len() {
        for slot in &comps[c].inputs {
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
    for c in comps.iter_mut() {
        for i in &mut c.instances {
            *i = new_index[*i];
        }
        c.instances.sort_unstable();
    }
    for p in points.iter_mut() {
        for i in &mut p.instances {
            *i = new_index[*i];
        }
    }
    perm.into_iter().map(|i| instances[i].clone()).collect()
}
