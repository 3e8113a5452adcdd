//! Input references: parsing `"node[i].output"`-style strings, `Path(..)` and
//! `Installed(..)`, and resolving them against one point's instances.

use super::point::{Builder, ByNode, LSource, Local};
use crate::error::Diagnostic;
use crate::node::InputDecl;
use crate::store::Hash;
use crate::syntax::{Origin, Value, ValueKind};
use std::path::Path;

/// A parsed reference string: node name, index and output.
struct RefSpec {
    node: String,
    index: RefIndex,
    output: Option<String>,
}

/// Which instances of a repeated node a reference takes.
enum RefIndex {
    None,
    Same,
    All,
    Fixed(usize),
}

/// Parses `node`, `node.output`, `node[i]`, `node[*].output`, `node[3].output`.
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

impl Builder<'_> {
    /// The content hash of external input `path` (cached per path within this resolution).
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

    /// The source of `Path("..")` reference `item` (with tuple `items`): the file or folder,
    /// relative to the file that wrote it, must exist; it is content-hashed.
    fn external_ref(
        &mut self,
        item: &Value,
        items: &[Value],
    ) -> Result<Vec<(LSource, String)>, Diagnostic> {
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
        Ok(vec![(
            LSource::External(abs.clone(), h),
            format!("Path({:?})", abs.display().to_string()),
        )])
    }

    /// The source of `Installed("name")` reference `item` (with tuple `items`): the file or
    /// folder where the registry's resource `name` is installed, content-hashed as a
    /// `Path(..)`. A resource that is not installed leaves an optional input unconnected (no
    /// source) and fails a required one with the resource's install hint.
    fn installed_ref(
        &mut self,
        item: &Value,
        items: &[Value],
        decl: &InputDecl,
    ) -> Result<Vec<(LSource, String)>, Diagnostic> {
        let Some(name) = items
            .first()
            .and_then(|v| v.as_str())
            .filter(|_| items.len() == 1)
        else {
            return Err(Diagnostic::at(&item.origin, "write `Installed(\"name\")`"));
        };
        let Some(res) = self.registry.resource(name) else {
            let known = self.registry.resource_names();
            return Err(Diagnostic::at(
                &item.origin,
                format!("no installed resource is called `{name}`"),
            )
            .hint(if known.is_empty() {
                "this build registers none".to_string()
            } else {
                format!("known: {}", known.join(", "))
            }));
        };
        match (res.locate)().filter(|p| p.exists()) {
            Some(p) => {
                let abs = std::fs::canonicalize(&p).unwrap_or(p);
                let h = self.ext_hash(&abs, &item.origin)?;
                Ok(vec![(
                    LSource::External(abs.clone(), h),
                    format!("Installed({name:?}) = {}", abs.display()),
                )])
            }
            None if decl.optional => {
                self.uninstalled += 1;
                Ok(Vec::new())
            }
            None => Err(Diagnostic::at(
                &item.origin,
                format!(
                    "`{name}` is not installed, and input `{}` needs it",
                    decl.name
                ),
            )
            .hint(res.hint.clone())),
        }
    }

    /// Resolves one written reference `item` of input `decl` of instance `l` to its sources
    /// with their written form (`field[0].weights`, `Path(..)`).
    pub(super) fn resolve_ref(
        &mut self,
        l: &Local,
        item: &Value,
        decl: &InputDecl,
        by_node: &ByNode,
        locals: &[Local],
        all_names: &[String],
    ) -> Result<Vec<(LSource, String)>, Diagnostic> {
        if let ValueKind::Tuple(Some(t), items) = &item.kind {
            if t == "Path" {
                return self.external_ref(item, items);
            }
            if t == "Installed" {
                return self.installed_ref(item, items, decl);
            }
        }
        let Some(text) = item.as_str() else {
            return Err(Diagnostic::at(
                &item.origin,
                format!(
                    "an input reference must be a string \"node.output\", Path(\"..\") or Installed(\"..\"), found {}",
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
        let picked = pick_instances(&r, ids, *repeated, l, decl, item)?;
        let mut out = Vec::new();
        for j in picked {
            let t = &locals[j];
            let output = pick_output(&r, t, item)?;
            out.push((
                LSource::Local(j, output.clone()),
                format!("{}.{output}", t.name),
            ));
        }
        Ok(out)
    }
}

/// The instances (indices into the locals) that reference `r` takes from node `r.node`
/// (instances `ids`, `repeated` when it has `repeat`), for input `decl` of instance `l`.
fn pick_instances(
    r: &RefSpec,
    ids: &[usize],
    repeated: bool,
    l: &Local,
    decl: &InputDecl,
    item: &Value,
) -> Result<Vec<usize>, Diagnostic> {
    let picked: Vec<usize> = match (&r.index, repeated) {
        (RefIndex::None, false) => ids.to_vec(),
        (RefIndex::None, true) if decl.many => ids.to_vec(),
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
            ids.to_vec()
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
    Ok(picked)
}

/// The output of instance `t` that reference `r` names (its only output when `r` names none).
fn pick_output(r: &RefSpec, t: &Local, item: &Value) -> Result<String, Diagnostic> {
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
    Ok(output)
}

/// Whether two names are close (case-insensitive equal, one contains the other, or edit distance ≤ 2).
pub(crate) fn similar(a: &str, b: &str) -> bool {
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
