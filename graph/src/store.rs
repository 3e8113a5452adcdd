//! The store: content-addressed blobs, output manifests, the action cache, claims, run records
//! and garbage collection.
//!
//! Layout under the store root (default `./cache`):
//! ```text
//! store.lock                 runs hold it shared, `gc` exclusive
//! blobs/ab/<hash>            file contents by blake3 (read-only)
//! manifests/<hash>.json      an output folder's listing: path, size, blob hash per file
//! outputs/<hash>/            the folder itself (hard links to blobs), read-only, given to dependents
//! actions/ab/<key>.json      action cache: key -> output manifests + run metadata (time, host, seed, log)
//! locks/<key>.lock           claims: a process computing a key holds an OS lock on its file
//! tmp/                       scratch folders and half-written files (never read as results)
//! runs/latest/<id>.json      the latest run of each pipeline (GC roots, `why`)
//! runs/records/<t>-<pid>.json every run's summary
//! pins/<name>.json           pinned results (GC roots)
//! extcache/<id>.json         hashes of external input files by path + size + mtime
//! ```
//! An action entry is written last, by atomic rename, after its outputs are complete: a killed
//! or failed run leaves only scratch files and unreferenced blobs, never an entry.

use crate::error::{io, EngineError};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::fs::{self, File};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A blake3 hash.
pub type Hash = [u8; 32];

/// Store format version; part of every key.
pub const STORE_FORMAT: u32 = 1;

/// Lower-case hex of a hash.
pub fn hex(h: &Hash) -> String {
    let mut s = String::with_capacity(64);
    for b in h {
        s.push_str(&format!("{b:02x}"));
    }
    s
}

/// Parses 64 hex digits.
pub fn unhex(s: &str) -> Option<Hash> {
    if s.len() != 64 {
        return None;
    }
    let mut h = [0u8; 32];
    for (i, b) in h.iter_mut().enumerate() {
        *b = u8::from_str_radix(s.get(2 * i..2 * i + 2)?, 16).ok()?;
    }
    Some(h)
}

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

pub use crate::claim::Claim;

/// What `gc` removed or would remove.
#[derive(Clone, Debug, Default)]
pub struct GcReport {
    /// Number of root keys kept (latest runs + pins).
    pub roots: usize,
    /// Root files read.
    pub root_files: Vec<String>,
    /// Action entries kept / removed.
    pub actions_kept: usize,
    /// Removed action entries.
    pub actions_removed: usize,
    /// Output folders (manifests) kept.
    pub outputs_kept: usize,
    /// Removed output folders.
    pub outputs_removed: usize,
    /// Blobs kept.
    pub blobs_kept: usize,
    /// Removed blobs.
    pub blobs_removed: usize,
    /// Bytes of removed blobs.
    pub bytes_removed: u64,
    /// Scratch folders, stale claim files and half-written files removed.
    pub scratch_removed: usize,
    /// Checkpoint folders removed: their key has its entry, or no root and no run's status
    /// names it (no pipeline will resume it).
    pub checkpoints_removed: usize,
    /// Kept entries that are broken (an output, manifest, file or blob is missing): the next
    /// run recomputes them. Each names the node, key and what is missing.
    pub broken: Vec<String>,
    /// Unreadable kept entries and manifests dropped by `repair`.
    pub repaired: Vec<String>,
}

/// A store on disk.
#[derive(Clone, Debug)]
pub struct Store {
    root: PathBuf,
}

static COUNTER: AtomicU64 = AtomicU64::new(0);

pub(crate) fn unique_suffix() -> String {
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    format!("{}-{n}-{t:x}", std::process::id())
}

/// Seconds since the Unix epoch.
pub fn now_unix() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

/// This machine's host name.
pub fn hostname() -> String {
    fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| fs::read_to_string("/etc/hostname"))
        .map(|s| s.trim().to_string())
        .or_else(|_| std::env::var("HOSTNAME"))
        .unwrap_or_else(|_| "unknown".into())
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
            crate::verify::EntryState::Present(e) => Some(e),
            _ => None,
        })
    }

    /// Claims `key`: returns at once if no other process computes it, else waits until that
    /// process finishes, dies or stops renewing its claim (see [`crate::claim`]: claim files,
    /// not OS locks, so that a store on NFS or Lustre works).
    pub fn claim(&self, key: &Hash) -> Result<Claim, EngineError> {
        self.claim_reporting(key, &|_| {})
    }

    /// [`Store::claim`], calling `on_wait` with the holder whenever it starts waiting for a
    /// new one, and with `None` once it holds the claim after waiting.
    pub fn claim_reporting(
        &self,
        key: &Hash,
        on_wait: &dyn Fn(Option<&crate::claim::ClaimHolder>),
    ) -> Result<Claim, EngineError> {
        crate::claim::acquire_reporting(
            &self.claim_path(key),
            &crate::claim::ClaimPolicy::default(),
            on_wait,
        )
    }

    /// The claim file of `key`.
    pub fn claim_path(&self, key: &Hash) -> PathBuf {
        crate::claim::claim_path(&self.root.join("locks"), &hex(key))
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
        if dest.is_dir() && crate::verify::folder_damage(&manifest, &dest).is_none() {
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

/// Collects every `key` string and `keys` list of a run record or pin (the GC roots).
pub(crate) fn collect_keys(v: &serde_json::Value, out: &mut BTreeSet<String>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                match (k.as_str(), x) {
                    ("key", serde_json::Value::String(s)) if s.len() == 64 => {
                        out.insert(s.clone());
                    }
                    ("keys", serde_json::Value::Array(a)) => {
                        out.extend(a.iter().filter_map(|s| s.as_str()).map(str::to_string));
                    }
                    _ => collect_keys(x, out),
                }
            }
        }
        serde_json::Value::Array(a) => a.iter().for_each(|x| collect_keys(x, out)),
        _ => {}
    }
}

/// The entries of a folder, sorted (none if it cannot be read).
pub(crate) fn list_dir(p: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = fs::read_dir(p)
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    v.sort();
    v
}

/// A file's modification time in nanoseconds since the epoch (−1 when unknown): with its size
/// and inode, what the external inputs' hash cache compares.
pub(crate) fn mtime_ns(meta: &fs::Metadata) -> i128 {
    meta.modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map(|d| d.as_nanos() as i128)
        .unwrap_or(-1)
}

/// The hash cache of one external input: relative path -> (size, mtime ns, inode, hash).
type ExtCache = BTreeMap<String, (u64, i128, u64, String)>;

/// The manifest of external input `abs` (a file or a folder, links followed), hashing each
/// file with `hash(rel, path)`.
fn external_manifest(
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

fn cached_hash(
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

/// Hashes a file with blake3 (memory-mapped and multi-threaded on the current rayon pool for
/// large files). Returns hex.
pub fn hash_file(path: &Path) -> Result<String, EngineError> {
    let mut h = blake3::Hasher::new();
    let len = fs::metadata(path).map_err(io("reading", path))?.len();
    if len >= 1 << 20 {
        h.update_mmap_rayon(path).map_err(io("hashing", path))?;
    } else {
        h.update_reader(File::open(path).map_err(io("opening", path))?)
            .map_err(io("hashing", path))?;
    }
    Ok(h.finalize().to_hex().to_string())
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

/// Sets or clears the write bits of a file or folder (best effort).
pub(crate) fn set_readonly(p: &Path, ro: bool) {
    if let Ok(m) = fs::metadata(p) {
        let mut perm = m.permissions();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = perm.mode();
            perm.set_mode(if ro { mode & !0o222 } else { mode | 0o200 });
        }
        #[cfg(not(unix))]
        perm.set_readonly(ro);
        let _ = fs::set_permissions(p, perm);
    }
}

/// The number of hard links to a file (1 where unknown).
pub(crate) fn link_count(p: &Path) -> u64 {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        fs::symlink_metadata(p).map(|m| m.nlink()).unwrap_or(1)
    }
    #[cfg(not(unix))]
    {
        let _ = p;
        1
    }
}

fn set_tree_readonly(p: &Path) {
    if let Ok(rd) = fs::read_dir(p) {
        for e in rd.flatten() {
            if e.file_type().map(|t| t.is_dir()).unwrap_or(false) {
                set_tree_readonly(&e.path());
            }
        }
    }
    set_readonly(p, true);
}

/// Removes a file or folder tree, making read-only folders writable first. Errors are ignored
/// (a later `gc` retries).
pub fn remove_tree(p: &Path) {
    fn unlock(p: &Path) {
        set_readonly(p, false);
        if let Ok(rd) = fs::read_dir(p) {
            for e in rd.flatten() {
                if e.file_type().map(|t| t.is_dir()).unwrap_or(false) {
                    unlock(&e.path());
                }
            }
        }
    }
    if p.is_dir() {
        unlock(p);
        let _ = fs::remove_dir_all(p);
    } else {
        let _ = fs::remove_file(p);
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
