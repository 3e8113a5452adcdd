//! Listing and hashing folders into manifests: a node's outputs (links refused) and external
//! inputs (links followed; each file's hash cached by path, size, mtime and inode).

use super::files::{list_dir, mtime_ns};
use super::hash::hash_file;
use super::manifest::{Manifest, ManifestEntry};
use crate::error::{io, EngineError};
use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

/// The hash cache of one external input: relative path -> (size, mtime ns, inode, hash).
pub(super) type ExtCache = BTreeMap<String, (u64, i128, u64, String)>;

/// The manifest of external input `abs` (a file or a folder, links followed), hashing each
/// file with `hash(rel, path)`.
pub(super) fn external_manifest(
    abs: &Path,
    mut hash: impl FnMut(&str, &Path) -> Result<String, EngineError>,
) -> Result<Manifest, EngineError> {
    let meta = fs::metadata(abs).map_err(io("reading input", abs))?;
    if !meta.is_file() && !meta.is_dir() {
        return Err(special_file_error(abs, &meta.file_type()));
    }
    if meta.is_file() {
        let h = hash("", abs)?;
        Ok(Manifest {
            entries: vec![ManifestEntry {
                path: String::new(),
                size: meta.len(),
                hash: h,
            }],
        })
    } else {
        scan_tree(abs, Links::Follow, |rel, p, _| hash(rel, p))
    }
}

/// The hash of external input file `path` (at `rel` in its input), from `old` when its size,
/// mtime and inode are unchanged, else hashed afresh; recorded in `new` either way.
pub(super) fn cached_hash(
    old: &ExtCache,
    new: &mut ExtCache,
    rel: &str,
    path: &Path,
    meta: &fs::Metadata,
) -> Result<String, EngineError> {
    let mtime = mtime_ns(meta);
    #[cfg(unix)]
    let ino = {
        use std::os::unix::fs::MetadataExt;
        meta.ino()
    };
    #[cfg(not(unix))]
    let ino = 0u64;
    let h = match old.get(rel) {
        Some((s, m, i, h)) if *s == meta.len() && *m == mtime && *i == ino && mtime >= 0 => {
            h.clone()
        }
        _ => hash_file(path)?,
    };
    new.insert(rel.to_string(), (meta.len(), mtime, ino, h.clone()));
    Ok(h)
}

/// The symbolic links met below external input `abs` (its own path first, when it is one):
/// each link's path relative to `abs` (empty for `abs` itself) and its target as written.
/// `why` compares them between runs to say which link now points elsewhere.
pub fn links_within(abs: &Path) -> BTreeMap<String, String> {
    fn walk(dir: &Path, prefix: &str, depth: usize, out: &mut BTreeMap<String, String>) {
        if depth > 64 {
            return;
        }
        for p in list_dir(dir) {
            let name = p
                .file_name()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_default();
            let rel = format!("{prefix}{name}");
            let Ok(meta) = fs::symlink_metadata(&p) else {
                continue;
            };
            if meta.file_type().is_symlink() {
                if let Ok(t) = fs::read_link(&p) {
                    out.insert(rel.clone(), t.display().to_string());
                }
            }
            if fs::metadata(&p).map(|m| m.is_dir()).unwrap_or(false) {
                walk(&p, &format!("{rel}/"), depth + 1, out);
            }
        }
    }
    let mut out = BTreeMap::new();
    if let Ok(t) = fs::read_link(abs) {
        out.insert(String::new(), t.display().to_string());
    }
    if fs::metadata(abs).map(|m| m.is_dir()).unwrap_or(false) {
        walk(abs, "", 0, &mut out);
    }
    out
}

/// The error for a FIFO, socket or device file where a plain file or folder must be (reading
/// one would block forever or never end).
fn special_file_error(p: &Path, ft: &fs::FileType) -> EngineError {
    #[cfg(unix)]
    let what = {
        use std::os::unix::fs::FileTypeExt;
        if ft.is_fifo() {
            "a FIFO (named pipe)"
        } else if ft.is_socket() {
            "a socket"
        } else if ft.is_block_device() || ft.is_char_device() {
            "a device file"
        } else {
            "not a plain file"
        }
    };
    #[cfg(not(unix))]
    let what = {
        let _ = ft;
        "not a plain file"
    };
    EngineError::Other(format!(
        "{} is {what}; pipeline inputs and node outputs must hold plain files and folders",
        p.display()
    ))
}

/// How [`scan_tree`] treats symbolic links.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Links {
    /// Refused: a node's output holds plain files and folders only.
    Refuse,
    /// Followed to the file or folder they point to (external inputs, as make, Bazel and
    /// Snakemake do); a link that leads back into a folder it lies in is a cycle and refused,
    /// as is a dangling one.
    Follow,
}

/// Lists a folder recursively (sorted, `/`-separated, folders end with `/`), hashing each file
/// with `hash(rel, path, size)`. Symbolic links are refused (see [`scan_tree`] to follow them).
pub fn scan_folder(
    root: &Path,
    hash: impl FnMut(&str, &Path, u64) -> Result<String, EngineError>,
) -> Result<Manifest, EngineError> {
    scan_tree(root, Links::Refuse, hash)
}

/// [`scan_folder`] with a choice of how symbolic links are treated. FIFOs, sockets and device
/// files are refused either way and never opened.
pub fn scan_tree(
    root: &Path,
    links: Links,
    mut hash: impl FnMut(&str, &Path, u64) -> Result<String, EngineError>,
) -> Result<Manifest, EngineError> {
    let mut entries = Vec::new();
    // Canonical paths of the folders from the root down to the one being listed: a link to
    // any of them is a cycle.
    let mut ancestors: Vec<PathBuf> = Vec::new();
    scan_dir(root, "", links, &mut ancestors, &mut hash, &mut entries)?;
    entries.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(Manifest { entries })
}

/// How deep [`scan_tree`] descends (a guard against link chains that never repeat a folder).
const MAX_SCAN_DEPTH: usize = 256;

/// Lists folder `dir` (at `prefix` in the tree) into `entries`, descending into its folders
/// (see [`scan_tree`]); `ancestors` holds the canonical folders above it.
fn scan_dir(
    dir: &Path,
    prefix: &str,
    links: Links,
    ancestors: &mut Vec<PathBuf>,
    hash: &mut impl FnMut(&str, &Path, u64) -> Result<String, EngineError>,
    entries: &mut Vec<ManifestEntry>,
) -> Result<(), EngineError> {
    if ancestors.len() >= MAX_SCAN_DEPTH {
        return Err(EngineError::Other(format!(
            "{} lies more than {MAX_SCAN_DEPTH} folders deep; refusing to descend further",
            dir.display()
        )));
    }
    let canonical = fs::canonicalize(dir).map_err(io("reading", dir))?;
    ancestors.push(canonical);
    let mut items: Vec<_> = fs::read_dir(dir)
        .map_err(io("listing", dir))?
        .map(|e| e.map_err(io("listing", dir)))
        .collect::<Result<_, _>>()?;
    items.sort_by_key(|e| e.file_name());
    for e in items {
        let name = e.file_name().to_string_lossy().to_string();
        let p = e.path();
        let mut ft = e.file_type().map_err(io("reading", &p))?;
        let rel = format!("{prefix}{name}");
        if ft.is_symlink() {
            if links == Links::Refuse {
                return Err(EngineError::Other(format!(
                    "{} is a symbolic link; a node's outputs must hold plain files",
                    p.display()
                )));
            }
            let meta = fs::metadata(&p).map_err(|e| {
                EngineError::Other(format!(
                    "{} is a symbolic link whose target cannot be read ({e})",
                    p.display()
                ))
            })?;
            ft = meta.file_type();
            if ft.is_dir() {
                let target = fs::canonicalize(&p).map_err(io("reading", &p))?;
                if ancestors.contains(&target) {
                    return Err(EngineError::Other(format!(
                        "{} is a symbolic link to {}, a folder it lies in: a cycle",
                        p.display(),
                        target.display()
                    )));
                }
            }
        }
        if !ft.is_dir() && !ft.is_file() {
            return Err(special_file_error(&p, &ft));
        } else if ft.is_dir() {
            entries.push(ManifestEntry {
                path: format!("{rel}/"),
                size: 0,
                hash: String::new(),
            });
            scan_dir(&p, &format!("{rel}/"), links, ancestors, hash, entries)?;
        } else {
            let size = fs::metadata(&p).map_err(io("reading", &p))?.len();
            let h = hash(&rel, &p, size)?;
            entries.push(ManifestEntry {
                path: rel,
                size,
                hash: h,
            });
        }
    }
    ancestors.pop();
    Ok(())
}
