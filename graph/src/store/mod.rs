//! The store: content-addressed blobs, output manifests, the action cache, claims, run records
//! and garbage collection.
//!
//! Layout under the store root (default `./cache`):
//! ```text
//! store.lock                 runs hold it shared, `gc` and `verify --repair` exclusive
//! blobs/ab/<hash>            file contents by blake3 (read-only)
//! manifests/<hash>.json      an output folder's listing: path, size, blob hash per file
//! outputs/<hash>/            the folder itself (hard links to blobs), read-only, given to dependents
//! actions/ab/<key>.json      action cache: key -> output manifests + run metadata (time, host, seed, log)
//! locks/<key>.claim          claims: the process computing a key (see [`claim`])
//! checkpoints/<key>/         an interrupted node run's checkpoints, resumed by the next run
//! tmp/                       scratch folders and half-written files (never read as results)
//! runs/latest/<id>.json      the latest run of each pipeline (GC roots, `why`)
//! runs/records/<t>-<pid>.json every run's summary
//! runs/status/<run>.json     each recent run's live status (`augsplat status`)
//! pins/<name>.json           pinned results (GC roots)
//! extcache/<id>.json         hashes of external input files by path + size + mtime
//! ```
//! An action entry is written last, by atomic rename, after its outputs are complete: a killed
//! or failed run leaves only scratch files and unreferenced blobs, never an entry.
//!
//!
//! What a run trusts, checked cheaply on every read:
//! - [`Store::action_state`]: an action entry is *present* only when it parses and every
//!   output it names has its manifest, its folder, every file and every blob; an entry that
//!   exists but lacks any of these is *broken* (reported by `plan`, recomputed by `run` with a
//!   warning), never "cached".
//! - [`Store::check_output`]: before a node reads a stored output, the output folder must hold
//!   exactly the files and folders its manifest lists (an extra, missing or special file is
//!   damage) and each file is hashed with blake3 against the manifest: bit rot that keeps a
//!   file's size, modification time and inode is found before a node computes on it.
//!
//! This module holds [`Store`] itself: opening, locks, paths, blobs, promotion, the action
//! cache and entry states. Beside it: [`claim`] (claims on keys), [`verify`] (`augsplat
//! verify`), [`gc`] (garbage collection), and the leaves they all share, which import nothing
//! from the others: hashes, manifests, folder scans and filesystem helpers.

pub mod claim;
mod files;
pub mod gc;
mod hash;
mod manifest;
mod scan;
pub mod verify;

pub use claim::Claim;
pub use files::{hostname, now_unix, remove_tree};
pub(crate) use files::{list_dir, mtime_ns, read_plain};
pub use hash::{hash_file, hex, unhex, Hash};
use manifest::folder_damage;
pub use manifest::{Manifest, ManifestEntry};
pub use scan::{links_within, scan_folder, scan_tree, Links};

use crate::error::{io, EngineError};
use files::{link_count, set_readonly, set_tree_readonly, unique_suffix};
use scan::{cached_hash, external_manifest, ExtCache};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fs::{self, File};
use std::path::{Path, PathBuf};

/// Store format version; part of every key.
pub const STORE_FORMAT: u32 = 1;

/// An action cache entry: what a key produced and how.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ActionEntry {
    /// Store format.
    pub format: u32,
    /// The key (hex).
    pub key: String,
    /// Node kind.
    pub kind: String,
    /// Kind version.
    pub version: u32,
    /// The instance name that computed it.
    pub name: String,
    /// Output name -> manifest hash (hex).
    pub outputs: BTreeMap<String, String>,
    /// Seconds the node ran.
    pub seconds: f64,
    /// Unix time the entry was written.
    pub time_unix: u64,
    /// Host that computed it.
    pub host: String,
    /// Process id that computed it.
    pub pid: u32,
    /// The seed given to the node.
    pub seed: u64,
    /// Threads given to the node.
    pub threads: usize,
    /// Blob hash (hex) of the node's log, if it logged anything.
    pub log: Option<String>,
    /// What the node measured about its own run ([`crate::RunContext::measure`]): seconds
    /// of its phases, counts. Kept here, never in an output or a key, so a benchmark can read
    /// them without breaking the outputs' byte identity.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub measures: BTreeMap<String, f64>,
    /// What the node read: per input name, the content hash (hex) of each folder, checked by
    /// hashing just before the node ran (an output manifest, or an external input's hash).
    /// `verify` follows these records: an entry that read a damaged output, or an output of
    /// a damaged or tainted entry, is tainted. Empty in entries written before it existed.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub inputs: BTreeMap<String, Vec<String>>,
    /// Wall seconds the pre-run check spent hashing those inputs (not part of `seconds`).
    #[serde(default)]
    pub check_seconds: f64,
}

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

/// A store on disk.
#[derive(Clone, Debug)]
pub struct Store {
    root: PathBuf,
}

impl Store {
    /// Opens (creating if needed) the store at `root`.
    pub fn open(root: impl Into<PathBuf>) -> Result<Store, EngineError> {
        let root = root.into();
        for d in [
            "blobs",
            "manifests",
            "outputs",
            "actions",
            "locks",
            "checkpoints",
            "tmp",
            "runs/latest",
            "runs/records",
            "runs/status",
            "pins",
            "extcache",
        ] {
            let p = root.join(d);
            fs::create_dir_all(&p).map_err(io("creating store folder", &p))?;
        }
        // Absolute, so folders handed to nodes (and external programs run elsewhere) resolve.
        let root = fs::canonicalize(&root).map_err(io("opening store", &root))?;
        Ok(Store { root })
    }
    /// Opens the existing store at `root`; unlike [`Store::open`] it creates nothing, and a
    /// path that holds no store is an error ([`EngineError::NoStore`]): a mistyped `--cache`
    /// must not pass for an empty store.
    pub fn open_existing(root: impl Into<PathBuf>) -> Result<Store, EngineError> {
        let root = root.into();
        let is_store = ["blobs", "manifests", "outputs", "actions"]
            .iter()
            .all(|d| root.join(d).is_dir());
        if !is_store {
            return Err(EngineError::NoStore(root));
        }
        Store::open(root)
    }
    /// The store root.
    pub fn root(&self) -> &Path {
        &self.root
    }
    /// `p` relative to the store root, as text (as reports name what they removed).
    pub(crate) fn relative(&self, p: &Path) -> String {
        p.strip_prefix(&self.root)
            .unwrap_or(p)
            .display()
            .to_string()
    }

    fn lock_file(&self) -> Result<File, EngineError> {
        let p = self.root.join("store.lock");
        fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&p)
            .map_err(io("opening", &p))
    }
    /// Takes the store lock shared (held by every run for its whole duration; `gc` waits for it).
    pub fn lock_shared(&self) -> Result<File, EngineError> {
        let f = self.lock_file()?;
        f.lock_shared()
            .map_err(io("locking", &self.root.join("store.lock")))?;
        Ok(f)
    }
    /// Tries to take the store lock exclusively (for `gc`); `None` if a run holds it.
    pub fn try_lock_exclusive(&self) -> Result<Option<File>, EngineError> {
        let f = self.lock_file()?;
        match f.try_lock() {
            Ok(()) => Ok(Some(f)),
            Err(fs::TryLockError::WouldBlock) => Ok(None),
            Err(fs::TryLockError::Error(e)) => Err(EngineError::Io {
                what: "locking",
                path: self.root.join("store.lock"),
                source: e,
            }),
        }
    }

    pub(crate) fn action_path(&self, key: &Hash) -> PathBuf {
        let h = hex(key);
        self.root
            .join("actions")
            .join(&h[..2])
            .join(format!("{h}.json"))
    }
    /// The materialised, read-only folder of an output manifest.
    pub fn output_dir(&self, manifest: &Hash) -> PathBuf {
        self.root.join("outputs").join(hex(manifest))
    }
    pub(crate) fn blob_path(&self, h: &str) -> PathBuf {
        self.root.join("blobs").join(&h[..2]).join(h)
    }
    /// The path of a blob (e.g. a node log).
    pub fn blob(&self, h: &str) -> Option<PathBuf> {
        (h.len() == 64)
            .then(|| self.blob_path(h))
            .filter(|p| p.exists())
    }

    /// The action entry of `key`, if present and complete (see [`Store::action_state`]: a
    /// broken entry counts as absent).
    pub fn action(&self, key: &Hash) -> Result<Option<ActionEntry>, EngineError> {
        Ok(match self.action_state(key)? {
            EntryState::Present(e) => Some(e),
            _ => None,
        })
    }

    /// Claims `key`: returns at once if no other process computes it, else waits until that
    /// process finishes, dies or stops renewing its claim (see [`claim`]: claim files,
    /// not OS locks, so that a store on NFS or Lustre works).
    pub fn claim(&self, key: &Hash) -> Result<Claim, EngineError> {
        self.claim_reporting(key, &|_| {})
    }

    /// [`Store::claim`], calling `on_wait` with the holder whenever it starts waiting for a
    /// new one, and with `None` once it holds the claim after waiting.
    pub fn claim_reporting(
        &self,
        key: &Hash,
        on_wait: &dyn Fn(Option<&claim::ClaimHolder>),
    ) -> Result<Claim, EngineError> {
        claim::acquire_reporting(
            &self.claim_path(key),
            &claim::ClaimPolicy::default(),
            on_wait,
        )
    }

    /// The claim file of `key`.
    pub fn claim_path(&self, key: &Hash) -> PathBuf {
        claim::claim_path(&self.root.join("locks"), &hex(key))
    }

    /// The folder a node run of `key` keeps its checkpoints in: it outlives a killed run, so
    /// the next run of the same key resumes from it, and is removed when the key's entry is
    /// written.
    pub fn checkpoint_dir(&self, key: &Hash) -> PathBuf {
        self.root.join("checkpoints").join(hex(key))
    }

    /// A fresh scratch folder for one node run.
    pub fn new_scratch(&self, key: &Hash) -> Result<PathBuf, EngineError> {
        let p = self
            .root
            .join("tmp")
            .join(format!("run-{}-{}", &hex(key)[..16], unique_suffix()));
        fs::create_dir_all(&p).map_err(io("creating scratch folder", &p))?;
        Ok(p)
    }

    /// Writes `bytes` to `dest` atomically (temporary file in the store, then rename).
    pub fn write_atomic(&self, dest: &Path, bytes: &[u8]) -> Result<(), EngineError> {
        let tmp = self.root.join("tmp").join(format!("w-{}", unique_suffix()));
        fs::write(&tmp, bytes).map_err(io("writing", &tmp))?;
        if let Some(parent) = dest.parent() {
            fs::create_dir_all(parent).map_err(io("creating", parent))?;
        }
        fs::rename(&tmp, dest).map_err(io("renaming into place", dest))
    }

    /// Stores bytes as a blob; returns its hash (hex).
    pub fn put_blob(&self, bytes: &[u8]) -> Result<String, EngineError> {
        let h = blake3::hash(bytes).to_hex().to_string();
        let p = self.blob_path(&h);
        if !p.exists() {
            self.write_atomic(&p, bytes)?;
            set_readonly(&p, true);
        }
        Ok(h)
    }

    /// Moves a finished output folder into the store: every file becomes a blob (hard-linked
    /// back in place), the manifest is written, and the folder is renamed to `outputs/<hash>`.
    /// Returns the manifest hash.
    ///
    /// It heals what it finds damaged: an existing blob whose content does not match its name
    /// is replaced by the new file, a manifest file that does not match its name is rewritten,
    /// and an existing output folder that does not hold exactly its manifest's files is
    /// replaced (by atomic rename) with the new one. A file with more than one hard link (a
    /// program that linked a user's file into its output) is copied, never moved, so the
    /// user's file is neither turned read-only nor tied to the store.
    pub fn promote(&self, folder: &Path) -> Result<Hash, EngineError> {
        let manifest = scan_folder(folder, |_rel, path, _size| hash_file(path))?;
        for e in manifest.entries.iter().filter(|e| !e.path.ends_with('/')) {
            let src = folder.join(&e.path);
            self.store_blob(&src, &e.hash)?;
        }
        let mh = manifest.hash();
        let mpath = self
            .root
            .join("manifests")
            .join(format!("{}.json", hex(&mh)));
        if self.read_manifest(&mh).is_err() {
            self.write_atomic(
                &mpath,
                &serde_json::to_vec(&manifest).expect("manifest serialises"),
            )?;
        }
        let dest = self.output_dir(&mh);
        if dest.is_dir() && folder_damage(&manifest, &dest).is_none() {
            // Same content already materialised (by us or another process).
            remove_tree(folder);
            return Ok(mh);
        }
        if dest.is_dir() {
            // A damaged folder: set it aside (one rename), put the new one in its place.
            let aside = self
                .root
                .join("tmp")
                .join(format!("damaged-{}", unique_suffix()));
            match fs::rename(&dest, &aside) {
                Ok(()) => remove_tree(&aside),
                Err(e) if dest.is_dir() => {
                    return Err(EngineError::Io {
                        what: "setting aside the damaged output folder",
                        path: dest,
                        source: e,
                    })
                }
                Err(_) => {} // another process moved it first
            }
        }
        match fs::rename(folder, &dest) {
            Ok(()) => set_tree_readonly(&dest),
            Err(_) if dest.is_dir() => remove_tree(folder),
            Err(e) => {
                return Err(EngineError::Io {
                    what: "promoting output to",
                    path: dest,
                    source: e,
                })
            }
        }
        Ok(mh)
    }

    /// Makes `src` (a file of a folder being promoted, hashing to `hash`) a hard link to its
    /// blob, creating or healing the blob from it.
    fn store_blob(&self, src: &Path, hash: &str) -> Result<(), EngineError> {
        let blob = self.blob_path(hash);
        if let Some(parent) = blob.parent() {
            fs::create_dir_all(parent).map_err(io("creating", parent))?;
        }
        let good_blob = fs::symlink_metadata(&blob)
            .map(|m| m.is_file())
            .unwrap_or(false)
            && hash_file(&blob).ok().as_deref() == Some(hash);
        if !good_blob {
            if fs::symlink_metadata(&blob).is_ok() {
                // Damaged (or not a plain file): replaced below by a good copy.
                set_readonly(&blob, false);
                remove_tree(&blob);
            }
            if link_count(src) > 1 {
                // Another name shares this file's inode (a user's file): copy its bytes.
                let tmp = self.root.join("tmp").join(format!("b-{}", unique_suffix()));
                fs::copy(src, &tmp).map_err(io("copying into the store", src))?;
                set_readonly(&tmp, true);
                fs::rename(&tmp, &blob).map_err(io("moving into the store", &tmp))?;
            } else {
                set_readonly(src, true);
                fs::rename(src, &blob).map_err(io("moving into the store", src))?;
            }
        }
        if fs::symlink_metadata(src).is_ok() {
            // Unlinking a name never changes the inode's other names or permissions.
            fs::remove_file(src).map_err(io("removing", src))?;
        }
        if fs::hard_link(&blob, src).is_err() {
            fs::copy(&blob, src).map_err(io("copying blob to", src))?;
            set_readonly(src, true);
        }
        Ok(())
    }

    /// Writes an action entry (the commit point of a node run).
    pub fn write_action(&self, key: &Hash, entry: &ActionEntry) -> Result<(), EngineError> {
        let bytes = serde_json::to_vec_pretty(entry).expect("entry serialises");
        self.write_atomic(&self.action_path(key), &bytes)
    }

    /// The content hash of an external file or folder (same scheme as output manifests),
    /// following symbolic links to what they point to; cached by path + size + mtime + inode
    /// under `extcache/` (the pre-run check hashes again without the cache, see
    /// [`Store::check_external`]).
    pub fn hash_external(&self, path: &Path) -> Result<Hash, EngineError> {
        let abs = fs::canonicalize(path).map_err(io("reading input", path))?;
        let id = blake3::hash(abs.to_string_lossy().as_bytes()).to_hex();
        let cpath = self
            .root
            .join("extcache")
            .join(format!("{}.json", &id[..32]));
        let old: ExtCache = fs::read(&cpath)
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok())
            .unwrap_or_default();
        let mut new: ExtCache = BTreeMap::new();
        let manifest = external_manifest(&abs, |rel, p| {
            let m = fs::metadata(p).map_err(io("reading input", p))?;
            cached_hash(&old, &mut new, rel, p, &m)
        })?;
        if old != new {
            let _ = self.write_atomic(&cpath, &serde_json::to_vec(&new).expect("cache serialises"));
        }
        Ok(manifest.hash())
    }

    /// Hashes external input `path` afresh (no cache) and checks it against `expected`, the
    /// hash its key was computed with: what a node is about to read is what its key names.
    pub fn check_external(&self, path: &Path, expected: &Hash) -> Result<(), String> {
        let m = external_manifest(path, |_, p| hash_file(p)).map_err(|e| e.to_string())?;
        if m.hash() == *expected {
            Ok(())
        } else {
            Err(format!(
                "{} changed after the pipeline was loaded (its content now hashes to {}, the \
                 key was computed for {})",
                path.display(),
                &hex(&m.hash())[..16],
                &hex(expected)[..16]
            ))
        }
    }

    /// Writes the record of the latest run of pipeline `id`.
    pub fn write_latest(&self, id: &str, record: &serde_json::Value) -> Result<(), EngineError> {
        let p = self.root.join("runs/latest").join(format!("{id}.json"));
        self.write_atomic(&p, &serde_json::to_vec_pretty(record).expect("json"))
    }
    /// Reads the record of the latest run of pipeline `id`.
    pub fn read_latest(&self, id: &str) -> Option<serde_json::Value> {
        let p = self.root.join("runs/latest").join(format!("{id}.json"));
        fs::read(p)
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok())
    }
    /// Appends a run record (the run's summary) to `runs/records`.
    pub fn write_record(&self, record: &serde_json::Value) -> Result<PathBuf, EngineError> {
        let p =
            self.root
                .join("runs/records")
                .join(format!("{}-{}.json", now_unix(), unique_suffix()));
        self.write_atomic(&p, &serde_json::to_vec_pretty(record).expect("json"))?;
        Ok(p)
    }
    /// Pins a set of keys under `name` (a GC root until unpinned by deleting `pins/<name>.json`).
    pub fn pin(&self, name: &str, keys: &[String]) -> Result<(), EngineError> {
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_alphanumeric() || "-_.".contains(c))
        {
            return Err(EngineError::Other(format!(
                "pin name `{name}` may only hold letters, digits, `-`, `_` and `.`"
            )));
        }
        let p = self.root.join("pins").join(format!("{name}.json"));
        self.write_atomic(
            &p,
            &serde_json::to_vec_pretty(&serde_json::json!({ "keys": keys })).expect("json"),
        )
    }
}

/// Entry states and the checks of what a node is about to read (see the module
/// documentation).
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
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn promote_dedups_and_manifests_are_content_only() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path().join("s")).unwrap();
        let make = |name: &str| {
            let f = dir.path().join(name);
            fs::create_dir_all(f.join("sub")).unwrap();
            fs::write(f.join("a.txt"), b"hello").unwrap();
            fs::write(f.join("sub/b.bin"), [1u8, 2, 3]).unwrap();
            f
        };
        let m1 = store.promote(&make("o1")).unwrap();
        let m2 = store.promote(&make("o2")).unwrap();
        assert_eq!(m1, m2);
        let out = store.output_dir(&m1);
        assert_eq!(fs::read(out.join("a.txt")).unwrap(), b"hello");
        assert_eq!(fs::read(out.join("sub/b.bin")).unwrap(), [1, 2, 3]);
        assert!(!dir.path().join("o2").exists());
        // Same content outside the store hashes the same.
        let ext = make("o3");
        assert_eq!(store.hash_external(&ext).unwrap(), m1);
        fs::write(ext.join("a.txt"), b"hellO").unwrap();
        assert_ne!(store.hash_external(&ext).unwrap(), m1);
        assert_eq!(unhex(&hex(&m1)), Some(m1));
    }
}
