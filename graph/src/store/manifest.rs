//! Output manifests: the listing of one output folder, whose hash names the output's content,
//! and the check of a folder against its manifest (exactly its files, each file's blake3).

use super::hash::{hash_file, Hash};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

/// One entry of a manifest: a file (with size and blob hash) or a folder.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, Eq)]
pub struct ManifestEntry {
    /// Path relative to the output folder, `/`-separated; folders end with `/`.
    pub path: String,
    /// File size in bytes (0 for folders).
    pub size: u64,
    /// Blob hash (hex) of a file; empty for folders.
    pub hash: String,
}

/// The listing of one output folder, sorted by path. Its hash identifies the output's content.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, Eq, Default)]
pub struct Manifest {
    /// Entries sorted by path.
    pub entries: Vec<ManifestEntry>,
}

impl Manifest {
    /// The canonical bytes (compact JSON) and their hash.
    pub fn hash(&self) -> Hash {
        *blake3::hash(&serde_json::to_vec(self).expect("manifest serialises")).as_bytes()
    }
}

/// Every file, folder and special file below `dir` (links not followed), by `/`-separated
/// path relative to it (folders end with `/`), with its metadata.
fn list_tree(dir: &Path) -> Result<Vec<(String, PathBuf, fs::Metadata)>, String> {
    let mut out = Vec::new();
    let mut stack = vec![(dir.to_path_buf(), String::new())];
    while let Some((d, prefix)) = stack.pop() {
        let rd = fs::read_dir(&d).map_err(|e| format!("{} cannot be listed ({e})", d.display()))?;
        for e in rd {
            let e = e.map_err(|e| format!("{} cannot be listed ({e})", d.display()))?;
            let p = e.path();
            let meta = fs::symlink_metadata(&p)
                .map_err(|e| format!("{} unreadable ({e})", p.display()))?;
            let name = e.file_name().to_string_lossy().to_string();
            if meta.is_dir() {
                stack.push((p.clone(), format!("{prefix}{name}/")));
                out.push((format!("{prefix}{name}/"), p, meta));
            } else {
                out.push((format!("{prefix}{name}"), p, meta));
            }
        }
    }
    out.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(out)
}

/// The first damage of output folder `dir` against `manifest`, hashing every file (see
/// [`folder_damage_with`]).
pub(crate) fn folder_damage(manifest: &Manifest, dir: &Path) -> Option<(PathBuf, String)> {
    folder_damage_with(manifest, dir, |_, _| false)
}

/// The first damage of output folder `dir` against `manifest`: anything in the folder that
/// the manifest does not list, a link, FIFO, socket or device file (never opened), a listed
/// file or folder that is missing, a wrong size, or a file whose blake3 differs (files for
/// which `skip_hash` says so are not hashed; the others are hashed in parallel).
pub(crate) fn folder_damage_with(
    manifest: &Manifest,
    dir: &Path,
    skip_hash: impl Fn(&ManifestEntry, &fs::Metadata) -> bool + Sync,
) -> Option<(PathBuf, String)> {
    let listed = match list_tree(dir) {
        Ok(l) => l,
        Err(e) => return Some((dir.to_path_buf(), e)),
    };
    let expected: BTreeMap<&str, &ManifestEntry> = manifest
        .entries
        .iter()
        .map(|e| (e.path.as_str(), e))
        .collect();
    let mut present: BTreeMap<&str, &fs::Metadata> = BTreeMap::new();
    for (rel, p, meta) in &listed {
        let ft = meta.file_type();
        if !ft.is_file() && !ft.is_dir() {
            return Some((
                p.clone(),
                "is not a plain file or folder (a link, FIFO, socket or device); an output \
                 folder holds exactly its manifest's files"
                    .into(),
            ));
        }
        if !expected.contains_key(rel.as_str()) {
            return Some((
                p.clone(),
                "is not in the output's manifest: an output folder holds exactly its \
                 manifest's files"
                    .into(),
            ));
        }
        present.insert(rel.as_str(), meta);
    }
    let mut to_hash: Vec<(&ManifestEntry, PathBuf)> = Vec::new();
    for e in &manifest.entries {
        let p = dir.join(&e.path);
        let Some(meta) = present.get(e.path.as_str()) else {
            return Some((p, "is missing".into()));
        };
        if e.path.ends_with('/') {
            continue;
        }
        if !meta.is_file() {
            return Some((p, "is a folder; its manifest lists a file".into()));
        }
        if meta.len() != e.size {
            return Some((
                p,
                format!("holds {} bytes; the manifest says {}", meta.len(), e.size),
            ));
        }
        if !skip_hash(e, meta) {
            to_hash.push((e, p));
        }
    }
    to_hash
        .par_iter()
        .map(|(e, p)| match hash_file(p) {
            Ok(x) if x == e.hash => None,
            Ok(x) => Some((
                p.clone(),
                format!("content hashes to {x}, the manifest says {}", e.hash),
            )),
            Err(err) => Some((p.clone(), format!("unreadable: {err}"))),
        })
        .find_first(|r| r.is_some())
        .flatten()
}
