//! The identity of a computation: its **key** (what the cache is addressed by) and its
//! **structural id** (what the resolver deduplicates by).
//!
//! # The key
//!
//! [`compute_key`] is a blake3 hash of, in this order, each field prefixed by its length as a
//! little-endian `u64`:
//!
//! 1. the domain tag `augsplat-key`;
//! 2. [`STORE_FORMAT`] (little-endian `u32`);
//! 3. the kind's name and its `VERSION` (little-endian `u32`);
//! 4. the canonical typed args: compact JSON of the fully-defaulted args struct, fields in
//!    declaration order (see [`DynNode::canonical_args`]);
//! 5. the salt: `[0]` when absent, `[1] ‖ index` (little-endian `u64`) for a repeat instance of
//!    a kind without a numeric `seed` arg;
//! 6. the number of input slots, then per slot (sorted by name): its name, its number of
//!    sources, and the manifest hash of each source in written order — the content hash of
//!    the upstream output folder, or of the external file or folder.
//!
//! Nothing else goes in. In particular a key **never** depends on:
//!
//! - wall time, timestamps, the host, the process id or the user;
//! - the thread count: `--jobs`, the kind's `threads()`, the rayon pool size;
//! - any path: the pipeline file, the cache folder, where an external input lives (only its
//!   content), scratch folders;
//! - names: the node's or instance's name, sweep labels, the written reference
//!   (`"field[0].weights"` vs `"field"`), the pipeline's id;
//! - how the args were written: comments, whitespace, field order, a default written out or
//!   left implicit, a value set by `--set`, a sweep or `Param(..)` rather than by hand;
//! - the upstream computations themselves (their kinds, args or keys): only the content of
//!   the outputs they produced, so a rerun that produces identical bytes leaves its dependents
//!   cached (early cutoff);
//! - resources of any kind (memory, disk, an accelerator) or the order in which nodes ran.
//!
//! A node's context seed is derived *from* its key (its first eight bytes), never the reverse.
//!
//! # The structural id
//!
//! [`structural_id`] identifies a computation *before* anything runs: the same kind, version,
//! canonical args and salt as the key, but the inputs are described by where they come from
//! (the upstream computation's structural id and output name, or an external input's content
//! hash) instead of by the content of upstream outputs. Two instances with the same structural
//! id — within one pipeline or across sweep points — are one computation. It is never stored:
//! it only has to be stable within one resolution.
//!
//! [`pipeline_id`] names a pipeline's run records; it is not part of any key.

use crate::registry::DynNode;
use crate::resolve::{Comp, InputSlot, Source};
use crate::store::{Hash, STORE_FORMAT};
use std::path::Path;

/// The key of a computation given the manifest hash of each of its input sources (same order
/// as `comp.inputs[..].sources`). See the module docs for exactly what goes in, and
/// docs/design.md, *Engine semantics*.
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

/// The structural id of a computation of kind `node` with canonical args `canonical`, salt
/// `salt` and resolved `inputs`, whose [`Source::Node`] sources index `comps` (upstream
/// computations, already interned). See the module docs.
pub fn structural_id(
    node: &dyn DynNode,
    canonical: &[u8],
    salt: Option<u64>,
    inputs: &[InputSlot],
    comps: &[Comp],
) -> Hash {
    let mut h = blake3::Hasher::new();
    h.update(b"augsplat-sid");
    h.update(node.kind().as_bytes());
    h.update(&node.version().to_le_bytes());
    h.update(&(canonical.len() as u64).to_le_bytes());
    h.update(canonical);
    h.update(&salt.map_or([0xff; 8], u64::to_le_bytes));
    for slot in inputs {
        h.update(&(slot.name.len() as u64).to_le_bytes());
        h.update(slot.name.as_bytes());
        h.update(&(slot.sources.len() as u64).to_le_bytes());
        for (s, _) in &slot.sources {
            match s {
                Source::Node { comp, output } => {
                    h.update(b"N");
                    h.update(&comps[*comp].sid);
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
    *h.finalize().as_bytes()
}

/// A stable id for a pipeline file (hash of its absolute path). It names the pipeline's run
/// records (`runs/latest/<id>.json`) and is never part of a key.
pub fn pipeline_id(file: &Path) -> String {
    let abs = std::fs::canonicalize(file).unwrap_or_else(|_| file.to_path_buf());
    blake3::hash(abs.to_string_lossy().as_bytes()).to_hex()[..32].to_string()
}

/// `name` (an instance or output name, which may hold a sweep value) as one safe folder name:
/// path separators, control characters and `..` become `_`, a leading `.` gets a `_` before
/// it, and when anything changed a short hash of the original keeps distinct names distinct.
/// `run --out` writes only below its folder whatever a swept string holds.
pub fn safe_folder_name(name: &str) -> String {
    let mut s: String = name
        .chars()
        .map(|c| {
            if c == '/' || c == '\\' || c.is_control() {
                '_'
            } else {
                c
            }
        })
        .collect();
    while s.contains("..") {
        s = s.replace("..", "__");
    }
    if s.is_empty() || s.starts_with('.') {
        s.insert(0, '_');
    }
    if s != name {
        s.push('-');
        s.push_str(&blake3::hash(name.as_bytes()).to_hex()[..8]);
    }
    s
}
