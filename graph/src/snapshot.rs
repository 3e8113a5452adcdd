//! Snapshots of a node's input folders (each file's size and modification time), taken before
//! the node runs and compared after, so a node, or a program it ran, that changed what it read
//! fails: inputs are read-only. Used by the executor and by the `Command` kind.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Per input name, every file and folder below each of its paths with its size and
/// modification time (a stat per file: cheap beside any node).
pub(crate) type InputSnapshot = BTreeMap<String, BTreeMap<PathBuf, (u64, i128)>>;

/// Every file and folder below each input's paths, with its size and modification time.
pub(crate) fn input_snapshot(inputs: &[(String, Vec<PathBuf>)]) -> InputSnapshot {
    fn walk(p: &Path, out: &mut BTreeMap<PathBuf, (u64, i128)>) {
        let Ok(meta) = std::fs::symlink_metadata(p) else {
            return;
        };
        let mtime = crate::store::mtime_ns(&meta);
        out.insert(
            p.to_path_buf(),
            (if meta.is_dir() { 0 } else { meta.len() }, mtime),
        );
        if meta.is_dir() {
            if let Ok(rd) = std::fs::read_dir(p) {
                for e in rd.flatten() {
                    walk(&e.path(), out);
                }
            }
        }
    }
    inputs
        .iter()
        .map(|(name, paths)| {
            let mut files = BTreeMap::new();
            for p in paths {
                walk(p, &mut files);
            }
            (name.clone(), files)
        })
        .collect()
}

/// The first difference between two snapshots, in words (`None` when the inputs are as they
/// were).
pub(crate) fn changed_input(before: &InputSnapshot, after: &InputSnapshot) -> Option<String> {
    for (name, b) in before {
        let Some(a) = after.get(name) else {
            return Some(format!("`{name}` was disconnected"));
        };
        for (p, st) in b {
            match a.get(p) {
                None => return Some(format!("`{name}`: {} was removed", p.display())),
                Some(x) if x != st => {
                    return Some(format!("`{name}`: {} was modified", p.display()))
                }
                _ => {}
            }
        }
        if let Some(p) = a.keys().find(|p| !b.contains_key(*p)) {
            return Some(format!("`{name}`: {} was added", p.display()));
        }
    }
    None
}
