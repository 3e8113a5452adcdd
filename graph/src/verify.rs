//! Proving what the store holds.
//!
//! - [`Store::action_state`]: an action entry is *present* only when it parses and every
//!   output it names has its manifest, its folder, every file and every blob; an entry that
//!   exists but lacks any of these is *broken* (reported by `plan`, recomputed by `run` with a
//!   warning), never "cached".
//! - [`Store::check_output`]: before a node reads a stored output, each of its files is
//!   checked against the output's manifest (size, and the blake3 hash unless the file's size,
//!   modification time and inode equal a *verified-at stamp* written by an earlier check, so a
//!   steady-state rerun hashes nothing).
//! - [`Store::verify`]: `augsplat verify` re-hashes every blob against its name and every
//!   output folder against its manifest, and names each damaged action entry by node, key and
//!   file; with `repair` it removes the damaged entries, manifests, output folders and blobs
//!   (a blob whose content does not match its name is not a good blob) so the next run
//!   recomputes them. It never removes a blob whose content matches its name.

use crate::error::EngineError;
use crate::store::{
    hash_file, hex, list_dir, mtime_ns, remove_tree, unhex, ActionEntry, Hash, Manifest, Store,
};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What the store holds for one key.
#[derive(Clone, Debug)]
pub enum EntryState {
    /// No action entry.
    Absent,
    /// A complete entry: every output's manifest, folder, files and blobs are there.
    Present(ActionEntry),
    /// An entry exists but cannot be used; the key must be recomputed.
    Broken {
        /// The instance that computed it (empty when the entry itself is unreadable).
        name: String,
        /// What is missing or unreadable, naming the file.
        reason: String,
    },
}

/// One damaged or missing thing found by [`Store::verify`].
#[derive(Clone, Debug)]
pub struct Problem {
    /// The file or folder concerned.
    pub path: PathBuf,
    /// The node instance whose entry is affected, when known.
    pub node: Option<String>,
    /// The action key (hex) whose entry is affected, when known.
    pub key: Option<String>,
    /// What is wrong.
    pub detail: String,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.node, &self.key) {
            (Some(n), Some(k)) => write!(f, "node `{n}` (key {}…): ", &k[..k.len().min(16)])?,
            (None, Some(k)) => write!(f, "key {}…: ", &k[..k.len().min(16)])?,
            _ => {}
        }
        write!(f, "{}: {}", self.path.display(), self.detail)
    }
}

/// The result of [`Store::verify`].
#[derive(Clone, Debug, Default)]
pub struct VerifyReport {
    /// Blobs re-hashed.
    pub blobs: usize,
    /// Their bytes.
    pub bytes: u64,
    /// Manifests checked.
    pub manifests: usize,
    /// Action entries checked.
    pub actions: usize,
    /// Damaged blobs, manifests and output files (each once).
    pub damage: Vec<Problem>,
    /// Action entries that cannot be used (damaged or missing outputs, unreadable entries).
    pub broken_actions: Vec<Problem>,
    /// What `repair` removed (store-relative paths).
    pub removed: Vec<String>,
    /// Wall seconds.
    pub seconds: f64,
}

impl VerifyReport {
    /// Whether the store held nothing damaged or broken.
    pub fn clean(&self) -> bool {
        self.damage.is_empty() && self.broken_actions.is_empty()
    }
}

/// Size, modification time (ns) and inode of a file: the verified-at stamp of one file.
type FileStamp = (u64, i128, u64);

fn file_stamp(meta: &fs::Metadata) -> FileStamp {
    let mtime = mtime_ns(meta);
    #[cfg(unix)]
    let ino = {
        use std::os::unix::fs::MetadataExt;
        meta.ino()
    };
    #[cfg(not(unix))]
    let ino = 0;
    (meta.len(), mtime, ino)
}

impl Store {
    fn manifest_path(&self, m: &Hash) -> PathBuf {
        self.root()
            .join("manifests")
            .join(format!("{}.json", hex(m)))
    }

    fn stamp_path(&self, m: &Hash) -> PathBuf {
        self.root()
            .join("verified")
            .join(format!("{}.json", hex(m)))
    }

    /// Reads manifest `m` and checks that its content hashes to its name.
    pub fn read_manifest(&self, m: &Hash) -> Result<Manifest, String> {
        let p = self.manifest_path(m);
        let bytes =
            fs::read(&p).map_err(|e| format!("manifest {} is unreadable ({e})", p.display()))?;
        let manifest: Manifest = serde_json::from_slice(&bytes)
            .map_err(|e| format!("manifest {} does not parse ({e})", p.display()))?;
        if manifest.hash() != *m {
            return Err(format!(
                "manifest {} does not match its name (its content hashes to {})",
                p.display(),
                hex(&manifest.hash())
            ));
        }
        Ok(manifest)
    }

    /// The state of `key`'s action entry (cheap: reads the entry and its manifests and checks
    /// that every file and blob exists; hashes nothing).
    pub fn action_state(&self, key: &Hash) -> Result<EntryState, EngineError> {
        let p = self.action_path(key);
        let bytes = match fs::read(&p) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(EntryState::Absent),
            Err(e) => {
                return Err(EngineError::Io {
                    what: "reading",
                    path: p,
                    source: e,
                })
            }
        };
        let entry: ActionEntry = match serde_json::from_slice(&bytes) {
            Ok(e) => e,
            Err(e) => {
                return Ok(EntryState::Broken {
                    name: String::new(),
                    reason: format!("action entry {} does not parse ({e})", p.display()),
                })
            }
        };
        Ok(match self.entry_problem(&entry) {
            None => EntryState::Present(entry),
            Some(reason) => EntryState::Broken {
                name: entry.name.clone(),
                reason,
            },
        })
    }

    /// What makes `entry` unusable, if anything (missing manifest, folder, file or blob).
    pub(crate) fn entry_problem(&self, entry: &ActionEntry) -> Option<String> {
        for (out, m) in &entry.outputs {
            let Some(h) = unhex(m) else {
                return Some(format!("output `{out}` names a bad manifest hash {m:?}"));
            };
            let dir = self.output_dir(&h);
            if !dir.is_dir() {
                return Some(format!(
                    "output `{out}`: folder {} is missing",
                    dir.display()
                ));
            }
            let manifest = match self.read_manifest(&h) {
                Ok(m) => m,
                Err(reason) => return Some(format!("output `{out}`: {reason}")),
            };
            for e in manifest.entries.iter().filter(|e| !e.hash.is_empty()) {
                let f = dir.join(&e.path);
                if !f.is_file() {
                    return Some(format!("output `{out}`: file {} is missing", f.display()));
                }
                if !self.blob_path(&e.hash).is_file() {
                    return Some(format!(
                        "output `{out}`: blob {} (of {}) is missing",
                        e.hash, e.path
                    ));
                }
            }
        }
        None
    }

    /// Checks the stored output `m` against its manifest before a node reads it: every file
    /// present with its size, and its blake3 hash unless a verified-at stamp (size, mtime,
    /// inode) from an earlier check still matches. On success the stamp is refreshed.
    pub fn check_output(&self, m: &Hash) -> Result<(), String> {
        let manifest = self.read_manifest(m)?;
        let dir = self.output_dir(m);
        let stamp_path = self.stamp_path(m);
        let old: BTreeMap<String, FileStamp> = fs::read(&stamp_path)
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok())
            .unwrap_or_default();
        let files: Vec<_> = manifest
            .entries
            .iter()
            .filter(|e| !e.path.ends_with('/'))
            .collect();
        let checked: Vec<Result<(String, FileStamp, bool), String>> = files
            .par_iter()
            .map(|e| {
                let p = dir.join(&e.path);
                let meta = fs::metadata(&p).map_err(|_| format!("{} is missing", p.display()))?;
                if meta.len() != e.size {
                    return Err(format!(
                        "{} holds {} bytes; its manifest says {}",
                        p.display(),
                        meta.len(),
                        e.size
                    ));
                }
                let stamp = file_stamp(&meta);
                if old.get(&e.path) == Some(&stamp) && stamp.1 >= 0 {
                    return Ok((e.path.clone(), stamp, false));
                }
                let h = hash_file(&p).map_err(|x| x.to_string())?;
                if h != e.hash {
                    return Err(format!(
                        "{} does not match its manifest (blake3 {h}, expected {})",
                        p.display(),
                        e.hash
                    ));
                }
                Ok((e.path.clone(), stamp, true))
            })
            .collect();
        let mut new = BTreeMap::new();
        let mut hashed = false;
        for r in checked {
            let (path, stamp, h) = r?;
            hashed |= h;
            new.insert(path, stamp);
        }
        if hashed || new.len() != old.len() {
            // A stamp that cannot be written only costs a re-hash next time.
            let _ = self.write_atomic(
                &stamp_path,
                &serde_json::to_vec(&new).expect("stamp serialises"),
            );
        }
        Ok(())
    }

    /// The manifest hash of `folder` when it is a stored output folder (`outputs/<hash>`).
    pub fn output_of_folder(&self, folder: &Path) -> Option<Hash> {
        if folder.parent()? != self.root().join("outputs") {
            return None;
        }
        unhex(&folder.file_name()?.to_string_lossy())
    }

    /// Re-hashes every blob and output file and checks every manifest and action entry (see
    /// the module documentation). With `repair`, removes what is damaged so that the next run
    /// recomputes it; the store must not be in use by a run (the exclusive lock is taken).
    pub fn verify(&self, repair: bool) -> Result<VerifyReport, EngineError> {
        let t0 = Instant::now();
        let _lock = if repair {
            match self.try_lock_exclusive()? {
                Some(l) => l,
                None => {
                    return Err(EngineError::Busy(format!(
                        "a run is using the store {}; `verify --repair` removes entries and waits for no run: retry when it has finished",
                        self.root().display()
                    )))
                }
            }
        } else {
            self.lock_shared()?
        };
        let mut rep = VerifyReport::default();
        let rel = |p: &Path| {
            p.strip_prefix(self.root())
                .unwrap_or(p)
                .display()
                .to_string()
        };

        // 1. Every blob against its name.
        let blobs: Vec<PathBuf> = list_dir(&self.root().join("blobs"))
            .iter()
            .flat_map(|d| list_dir(d))
            .collect();
        let hashed: Vec<(PathBuf, String, Result<String, String>, u64)> = blobs
            .par_iter()
            .map(|p| {
                let name = p
                    .file_name()
                    .map(|s| s.to_string_lossy().to_string())
                    .unwrap_or_default();
                let size = fs::metadata(p).map(|m| m.len()).unwrap_or(0);
                (
                    p.clone(),
                    name,
                    hash_file(p).map_err(|e| e.to_string()),
                    size,
                )
            })
            .collect();
        let mut bad_blobs: BTreeSet<String> = BTreeSet::new();
        let mut good_blob_inodes: BTreeMap<String, u64> = BTreeMap::new();
        for (p, name, h, size) in hashed {
            rep.blobs += 1;
            rep.bytes += size;
            match h {
                Ok(h) if h == name => {
                    if let Ok(meta) = fs::metadata(&p) {
                        good_blob_inodes.insert(name, file_stamp(&meta).2);
                    }
                }
                Ok(h) => {
                    rep.damage.push(Problem {
                        path: p.clone(),
                        node: None,
                        key: None,
                        detail: format!("blob content hashes to {h}, not to its name"),
                    });
                    bad_blobs.insert(name);
                }
                Err(e) => {
                    rep.damage.push(Problem {
                        path: p.clone(),
                        node: None,
                        key: None,
                        detail: format!("blob unreadable: {e}"),
                    });
                    bad_blobs.insert(name);
                }
            }
        }

        // 2. Every manifest, and its output folder's files.
        let mut bad_manifests: BTreeMap<String, String> = BTreeMap::new();
        for mp in list_dir(&self.root().join("manifests")) {
            rep.manifests += 1;
            let stem = mp
                .file_stem()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_default();
            let Some(h) = unhex(&stem) else {
                continue;
            };
            let problem = match self.read_manifest(&h) {
                Err(reason) => Some((mp.clone(), reason)),
                Ok(m) => self.manifest_damage(&h, &m, &bad_blobs, &good_blob_inodes),
            };
            if let Some((path, detail)) = problem {
                rep.damage.push(Problem {
                    path,
                    node: None,
                    key: None,
                    detail: detail.clone(),
                });
                bad_manifests.insert(stem, detail);
            }
        }

        // 3. Every action entry.
        let mut bad_actions: Vec<PathBuf> = Vec::new();
        for sub in list_dir(&self.root().join("actions")) {
            for ap in list_dir(&sub) {
                rep.actions += 1;
                let key = ap
                    .file_stem()
                    .map(|s| s.to_string_lossy().to_string())
                    .unwrap_or_default();
                let entry = match fs::read(&ap).map_err(|e| e.to_string()).and_then(|b| {
                    serde_json::from_slice::<ActionEntry>(&b).map_err(|e| e.to_string())
                }) {
                    Ok(e) => e,
                    Err(e) => {
                        rep.broken_actions.push(Problem {
                            path: ap.clone(),
                            node: None,
                            key: Some(key),
                            detail: format!("action entry unreadable ({e})"),
                        });
                        bad_actions.push(ap);
                        continue;
                    }
                };
                let mut why: Option<(PathBuf, String)> = None;
                for (out, m) in &entry.outputs {
                    if let Some(d) = bad_manifests.get(m) {
                        why = Some((
                            self.root().join("manifests").join(format!("{m}.json")),
                            format!("output `{out}` is damaged: {d}"),
                        ));
                        break;
                    }
                }
                if why.is_none() {
                    if let Some(reason) = self.entry_problem(&entry) {
                        why = Some((ap.clone(), reason));
                    }
                }
                if why.is_none() {
                    if let Some(log) = &entry.log {
                        if bad_blobs.contains(log) || self.blob(log).is_none() {
                            why = Some((
                                ap.clone(),
                                format!("its log blob {log} is damaged or missing"),
                            ));
                        }
                    }
                }
                if let Some((path, detail)) = why {
                    rep.broken_actions.push(Problem {
                        path,
                        node: Some(entry.name.clone()),
                        key: Some(key),
                        detail,
                    });
                    bad_actions.push(ap);
                }
            }
        }

        // 4. Repair: damaged entries, manifests, folders and blobs go; good blobs stay.
        if repair {
            for ap in &bad_actions {
                if fs::remove_file(ap).is_ok() {
                    rep.removed.push(rel(ap));
                }
            }
            for stem in bad_manifests.keys() {
                let dir = self.root().join("outputs").join(stem);
                if dir.exists() {
                    remove_tree(&dir);
                    rep.removed.push(rel(&dir));
                }
                let mp = self.root().join("manifests").join(format!("{stem}.json"));
                if fs::remove_file(&mp).is_ok() {
                    rep.removed.push(rel(&mp));
                }
                let _ = fs::remove_file(self.root().join("verified").join(format!("{stem}.json")));
            }
            for name in &bad_blobs {
                let p = self.blob_path(name);
                remove_tree(&p);
                if !p.exists() {
                    rep.removed.push(rel(&p));
                }
            }
        }
        rep.seconds = t0.elapsed().as_secs_f64();
        Ok(rep)
    }

    /// The first damage of manifest `h`'s output folder: a missing or damaged blob, a missing
    /// file, a wrong size, or (for a file that is not the blob itself) a wrong hash.
    fn manifest_damage(
        &self,
        h: &Hash,
        m: &Manifest,
        bad_blobs: &BTreeSet<String>,
        good_blob_inodes: &BTreeMap<String, u64>,
    ) -> Option<(PathBuf, String)> {
        let dir = self.output_dir(h);
        for e in m.entries.iter().filter(|e| !e.hash.is_empty()) {
            let blob = self.blob_path(&e.hash);
            if bad_blobs.contains(&e.hash) {
                return Some((blob, format!("blob of {} is damaged", e.path)));
            }
            if !blob.is_file() {
                return Some((blob, format!("blob of {} is missing", e.path)));
            }
            if !dir.is_dir() {
                // No folder: nothing hands it to a node (an entry naming it is broken).
                continue;
            }
            let f = dir.join(&e.path);
            let Ok(meta) = fs::metadata(&f) else {
                return Some((f, "file is missing".into()));
            };
            if meta.len() != e.size {
                return Some((
                    f,
                    format!("holds {} bytes; the manifest says {}", meta.len(), e.size),
                ));
            }
            if good_blob_inodes.get(&e.hash) == Some(&file_stamp(&meta).2) {
                continue; // the blob itself, hashed above
            }
            match hash_file(&f) {
                Ok(x) if x == e.hash => {}
                Ok(x) => {
                    return Some((
                        f,
                        format!("content hashes to {x}, the manifest says {}", e.hash),
                    ))
                }
                Err(err) => return Some((f, format!("unreadable: {err}"))),
            }
        }
        None
    }
}
