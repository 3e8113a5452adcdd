//! Proving what the store holds.
//!
//! - [`Store::action_state`]: an action entry is *present* only when it parses and every
//!   output it names has its manifest, its folder, every file and every blob; an entry that
//!   exists but lacks any of these is *broken* (reported by `plan`, recomputed by `run` with a
//!   warning), never "cached".
//! - [`Store::check_output`]: before a node reads a stored output, the output folder must hold
//!   exactly the files and folders its manifest lists (an extra, missing or special file is
//!   damage) and each file is hashed with blake3 against the manifest: bit rot that keeps a
//!   file's size, modification time and inode is found before a node computes on it.
//! - [`Store::verify`]: `augsplat verify` re-hashes every blob against its name and every
//!   output folder against its manifest, and names each damaged action entry by node, key and
//!   file. An entry whose recorded inputs ([`ActionEntry::inputs`]) include a damaged output,
//!   or an output of a damaged or tainted entry, is *tainted*: it computed on bytes that are
//!   not what its key names. With `repair` it removes the damaged and tainted entries (with
//!   their descendants), damaged manifests, output folders and blobs (a blob whose content
//!   does not match its name is not a good blob) so the next run recomputes them. It never
//!   removes a blob whose content matches its name, and never opens a special file.

use crate::error::EngineError;
use crate::store::{
    hash_file, hex, list_dir, remove_tree, unhex, ActionEntry, Hash, Manifest, ManifestEntry, Store,
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

/// The inode of a file (0 where unknown): a file that shares a good blob's inode is that blob.
fn inode(meta: &fs::Metadata) -> u64 {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        meta.ino()
    }
    #[cfg(not(unix))]
    {
        let _ = meta;
        0
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

impl Store {
    fn manifest_path(&self, m: &Hash) -> PathBuf {
        self.root()
            .join("manifests")
            .join(format!("{}.json", hex(m)))
    }

    /// Reads manifest `m` and checks that its content hashes to its name.
    pub fn read_manifest(&self, m: &Hash) -> Result<Manifest, String> {
        let p = self.manifest_path(m);
        let bytes =
            read_plain(&p).map_err(|e| format!("manifest {} is unreadable ({e})", p.display()))?;
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
        let bytes = match read_plain(&p) {
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

    /// Checks the stored output `m` against its manifest before a node reads it: the folder
    /// holds exactly the manifest's files and folders, and every file hashes to its manifest
    /// hash (in parallel on the current rayon pool).
    pub fn check_output(&self, m: &Hash) -> Result<(), String> {
        let manifest = self.read_manifest(m)?;
        let dir = self.output_dir(m);
        match folder_damage(&manifest, &dir) {
            None => Ok(()),
            Some((path, detail)) => Err(format!("{}: {detail}", path.display())),
        }
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
                let meta = fs::symlink_metadata(p);
                let size = meta.as_ref().map(|m| m.len()).unwrap_or(0);
                let h = match meta {
                    // Never open a FIFO, socket, device or link: reading one may block.
                    Ok(m) if !m.file_type().is_file() => {
                        Err("not a plain file (a link, FIFO, socket or device)".to_string())
                    }
                    _ => hash_file(p).map_err(|e| e.to_string()),
                };
                (p.clone(), name, h, size)
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
                        good_blob_inodes.insert(name, inode(&meta));
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
        let mut sound: Vec<(PathBuf, String, ActionEntry)> = Vec::new();
        for sub in list_dir(&self.root().join("actions")) {
            for ap in list_dir(&sub) {
                rep.actions += 1;
                let key = ap
                    .file_stem()
                    .map(|s| s.to_string_lossy().to_string())
                    .unwrap_or_default();
                let entry = match read_plain(&ap).map_err(|e| e.to_string()).and_then(|b| {
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
                } else {
                    sound.push((ap, key, entry));
                }
            }
        }

        // 3b. Taint: an entry that read a damaged output, or an output that only damaged or
        // tainted entries produced, computed on bytes its key does not name; so did every
        // entry downstream of it.
        for (ap, key, entry, detail) in tainted_entries(&sound, &bad_manifests) {
            rep.broken_actions.push(Problem {
                path: ap.clone(),
                node: Some(entry.name.clone()),
                key: Some(key.clone()),
                detail,
            });
            bad_actions.push(ap.clone());
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
                // A verified-at stamp that older versions kept beside the manifest.
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

    /// The first damage of manifest `h`'s output folder: a missing or damaged blob, a missing,
    /// extra or special file, a wrong size, or (for a file that is not the blob itself) a
    /// wrong hash.
    fn manifest_damage(
        &self,
        h: &Hash,
        m: &Manifest,
        bad_blobs: &BTreeSet<String>,
        good_blob_inodes: &BTreeMap<String, u64>,
    ) -> Option<(PathBuf, String)> {
        for e in m.entries.iter().filter(|e| !e.hash.is_empty()) {
            let blob = self.blob_path(&e.hash);
            if bad_blobs.contains(&e.hash) {
                return Some((blob, format!("blob of {} is damaged", e.path)));
            }
            if !blob.is_file() {
                return Some((blob, format!("blob of {} is missing", e.path)));
            }
        }
        let dir = self.output_dir(h);
        if !dir.is_dir() {
            // No folder: nothing hands it to a node (an entry naming it is broken).
            return None;
        }
        // A file that is the blob itself (same inode) was hashed with the blobs.
        folder_damage_with(m, &dir, |e, meta| {
            good_blob_inodes.get(&e.hash) == Some(&inode(meta))
        })
    }

    /// Sets aside stored output `m` (its folder, and every blob of it whose content does not
    /// match its name) after a pre-run check found it damaged, so that its entry is broken and
    /// the next run recomputes it. Returns whether the folder was set aside.
    pub(crate) fn set_aside_damaged_output(&self, m: &Hash) -> bool {
        if let Ok(manifest) = self.read_manifest(m) {
            for e in manifest.entries.iter().filter(|e| !e.hash.is_empty()) {
                let blob = self.blob_path(&e.hash);
                let good = fs::symlink_metadata(&blob)
                    .map(|x| x.is_file())
                    .unwrap_or(false)
                    && hash_file(&blob).ok().as_deref() == Some(e.hash.as_str());
                if !good {
                    remove_tree(&blob);
                }
            }
        }
        let dir = self.output_dir(m);
        let aside = self
            .root()
            .join("tmp")
            .join(format!("damaged-{}", crate::store::unique_suffix()));
        if fs::rename(&dir, &aside).is_ok() {
            remove_tree(&aside);
            true
        } else {
            false
        }
    }
}

/// Reads a file that must be a plain file (never opens a FIFO, socket or device, which could
/// block forever).
pub(crate) fn read_plain(p: &Path) -> std::io::Result<Vec<u8>> {
    let meta = fs::symlink_metadata(p)?;
    if !meta.file_type().is_file() {
        return Err(std::io::Error::other(
            "not a plain file (a link, FIFO, socket or device)",
        ));
    }
    fs::read(p)
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

/// The sound entries that are tainted, with why: an entry whose recorded inputs include a
/// damaged manifest, or a manifest that only tainted entries produced; repeated until nothing
/// changes, so descendants follow. (An entry that is broken for another reason, a missing
/// log say, taints nothing: what its dependants read was checked when they read it.)
#[allow(clippy::type_complexity)]
fn tainted_entries<'a>(
    sound: &'a [(PathBuf, String, ActionEntry)],
    bad_manifests: &BTreeMap<String, String>,
) -> Vec<(&'a PathBuf, &'a String, &'a ActionEntry, String)> {
    // Manifest -> the keys of the entries that produced it.
    let mut producers: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for (_, key, e) in sound {
        for m in e.outputs.values() {
            producers.entry(m.as_str()).or_default().push(key.as_str());
        }
    }
    let mut bad: BTreeSet<&str> = BTreeSet::new();
    let mut out = Vec::new();
    let mut tainted: BTreeSet<usize> = BTreeSet::new();
    loop {
        let mut changed = false;
        for (i, (ap, key, e)) in sound.iter().enumerate() {
            if tainted.contains(&i) {
                continue;
            }
            let why = e.inputs.iter().find_map(|(slot, ms)| {
                ms.iter().find_map(|m| {
                    if let Some(d) = bad_manifests.get(m) {
                        return Some(format!(
                            "tainted: it read input `{slot}` from a damaged output ({d})"
                        ));
                    }
                    let prods = producers.get(m.as_str())?;
                    let all_bad = prods.iter().all(|k| bad.contains(*k));
                    (all_bad && !prods.is_empty()).then(|| {
                        format!(
                            "tainted: it read input `{slot}` from an output of the tainted \
                             entry {}…",
                            &prods[0][..prods[0].len().min(16)]
                        )
                    })
                })
            });
            if let Some(why) = why {
                tainted.insert(i);
                bad.insert(key.as_str());
                out.push((ap, key, e, why));
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    out
}
