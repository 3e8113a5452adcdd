//! `augsplat verify`: proving what the store holds.
//!
//! [`Store::verify`] re-hashes every blob against its name and every output folder against its
//! manifest, and names each damaged action entry by node, key and file. An entry whose
//! recorded inputs ([`ActionEntry::inputs`]) include a damaged output, or an output of a
//! damaged or tainted entry, is *tainted*: it computed on bytes that are not what its key
//! names. With `repair` it removes the damaged and tainted entries (with their descendants),
//! damaged manifests, output folders and blobs (a blob whose content does not match its name
//! is not a good blob) so the next run recomputes them. It never removes a blob whose content
//! matches its name, and never opens a special file.
//!
//! It runs in phases, each a function: check the blobs, check the manifests (with their
//! folders), check the entries, follow the taint, repair. The cheap checks every run makes
//! live with the store itself ([`Store::action_state`], [`Store::check_output`]).

use super::files::{file_name, file_stem, inode, list_dir, read_plain, remove_tree, unique_suffix};
use super::hash::{hash_file, unhex, Hash};
use super::manifest::{folder_damage_with, Manifest};
use super::{ActionEntry, Store};
use crate::error::EngineError;
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::fs::{self, File};
use std::path::{Path, PathBuf};
use std::time::Instant;

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

/// What the blob phase found: the blobs whose content does not match their name, and the
/// inode of each good one (a file of an output folder that shares it is that blob).
#[derive(Default)]
struct BlobCheck {
    bad: BTreeSet<String>,
    good_inodes: BTreeMap<String, u64>,
}

/// A sound action entry: its path, its key (hex) and its content.
type SoundEntry = (PathBuf, String, ActionEntry);

impl Store {
    /// Re-hashes every blob and output file and checks every manifest and action entry (see
    /// the module documentation). With `repair`, removes what is damaged so that the next run
    /// recomputes it; the store must not be in use by a run (the exclusive lock is taken).
    pub fn verify(&self, repair: bool) -> Result<VerifyReport, EngineError> {
        let t0 = Instant::now();
        let _lock = self.verify_lock(repair)?;
        let mut rep = VerifyReport::default();
        let blobs = self.check_blobs(&mut rep);
        let bad_manifests = self.check_manifests(&mut rep, &blobs);
        let (mut bad_actions, sound) = self.check_entries(&mut rep, &blobs.bad, &bad_manifests);
        bad_actions.extend(check_taint(&mut rep, &sound, &bad_manifests));
        if repair {
            self.repair_damage(&mut rep, &bad_actions, &bad_manifests, &blobs.bad);
        }
        rep.seconds = t0.elapsed().as_secs_f64();
        Ok(rep)
    }

    /// The store lock `verify` holds: exclusive with `repair` (refused while a run holds the
    /// store), else shared.
    fn verify_lock(&self, repair: bool) -> Result<File, EngineError> {
        if !repair {
            return self.lock_shared();
        }
        self.try_lock_exclusive()?.ok_or_else(|| {
            EngineError::Busy(format!(
                "a run is using the store {}; `verify --repair` removes entries and waits for no run: retry when it has finished",
                self.root().display()
            ))
        })
    }

    /// Phase 1: every blob against its name; each damaged or unreadable one is reported.
    fn check_blobs(&self, rep: &mut VerifyReport) -> BlobCheck {
        let mut found = BlobCheck::default();
        for (p, name, h, size) in self.hash_blobs() {
            rep.blobs += 1;
            rep.bytes += size;
            let detail = match h {
                Ok(h) if h == name => {
                    if let Ok(meta) = fs::metadata(&p) {
                        found.good_inodes.insert(name, inode(&meta));
                    }
                    continue;
                }
                Ok(h) => format!("blob content hashes to {h}, not to its name"),
                Err(e) => format!("blob unreadable: {e}"),
            };
            rep.damage.push(Problem {
                path: p,
                node: None,
                key: None,
                detail,
            });
            found.bad.insert(name);
        }
        found
    }

    /// Every blob's path, name, content hash (or why it cannot be hashed) and size, hashed in
    /// parallel.
    fn hash_blobs(&self) -> Vec<(PathBuf, String, Result<String, String>, u64)> {
        let blobs: Vec<PathBuf> = list_dir(&self.root().join("blobs"))
            .iter()
            .flat_map(|d| list_dir(d))
            .collect();
        blobs
            .par_iter()
            .map(|p| {
                let meta = fs::symlink_metadata(p);
                let size = meta.as_ref().map(|m| m.len()).unwrap_or(0);
                let h = match meta {
                    // Never open a FIFO, socket, device or link: reading one may block.
                    Ok(m) if !m.file_type().is_file() => {
                        Err("not a plain file (a link, FIFO, socket or device)".to_string())
                    }
                    _ => hash_file(p).map_err(|e| e.to_string()),
                };
                (p.clone(), file_name(p), h, size)
            })
            .collect()
    }

    /// Phase 2: every manifest, and its output folder's files. Returns the damaged manifests
    /// (hex) with what is wrong with each, each one reported.
    fn check_manifests(
        &self,
        rep: &mut VerifyReport,
        blobs: &BlobCheck,
    ) -> BTreeMap<String, String> {
        let mut bad = BTreeMap::new();
        for mp in list_dir(&self.root().join("manifests")) {
            rep.manifests += 1;
            let stem = file_stem(&mp);
            let Some(h) = unhex(&stem) else {
                continue;
            };
            let problem = match self.read_manifest(&h) {
                Err(reason) => Some((mp.clone(), reason)),
                Ok(m) => self.manifest_damage(&h, &m, &blobs.bad, &blobs.good_inodes),
            };
            if let Some((path, detail)) = problem {
                rep.damage.push(Problem {
                    path,
                    node: None,
                    key: None,
                    detail: detail.clone(),
                });
                bad.insert(stem, detail);
            }
        }
        bad
    }

    /// Phase 3: every action entry. Returns the paths of the broken ones (each reported) and
    /// the sound ones.
    fn check_entries(
        &self,
        rep: &mut VerifyReport,
        bad_blobs: &BTreeSet<String>,
        bad_manifests: &BTreeMap<String, String>,
    ) -> (Vec<PathBuf>, Vec<SoundEntry>) {
        let mut bad = Vec::new();
        let mut sound = Vec::new();
        let subs = list_dir(&self.root().join("actions"));
        for ap in subs.iter().flat_map(|d| list_dir(d)) {
            rep.actions += 1;
            let key = file_stem(&ap);
            let (problem, node) = match read_entry(&ap) {
                Err(e) => ((ap.clone(), format!("action entry unreadable ({e})")), None),
                Ok(entry) => match self.entry_damage(&ap, &entry, bad_blobs, bad_manifests) {
                    Some(problem) => (problem, Some(entry.name)),
                    None => {
                        sound.push((ap, key, entry));
                        continue;
                    }
                },
            };
            let (path, detail) = problem;
            rep.broken_actions.push(Problem {
                path,
                node,
                key: Some(key),
                detail,
            });
            bad.push(ap);
        }
        (bad, sound)
    }

    /// What breaks a readable entry, if anything, with the file concerned: an output whose
    /// manifest is damaged, a missing manifest, folder, file or blob, or a damaged or missing
    /// log blob.
    fn entry_damage(
        &self,
        ap: &Path,
        entry: &ActionEntry,
        bad_blobs: &BTreeSet<String>,
        bad_manifests: &BTreeMap<String, String>,
    ) -> Option<(PathBuf, String)> {
        for (out, m) in &entry.outputs {
            if let Some(d) = bad_manifests.get(m) {
                return Some((
                    self.root().join("manifests").join(format!("{m}.json")),
                    format!("output `{out}` is damaged: {d}"),
                ));
            }
        }
        if let Some(reason) = self.entry_problem(entry) {
            return Some((ap.to_path_buf(), reason));
        }
        let log = entry.log.as_ref()?;
        (bad_blobs.contains(log) || self.blob(log).is_none()).then(|| {
            (
                ap.to_path_buf(),
                format!("its log blob {log} is damaged or missing"),
            )
        })
    }

    /// Phase 4, with `repair`: removes the damaged and tainted entries, the damaged manifests
    /// with their output folders, and the damaged blobs; good blobs stay.
    fn repair_damage(
        &self,
        rep: &mut VerifyReport,
        bad_actions: &[PathBuf],
        bad_manifests: &BTreeMap<String, String>,
        bad_blobs: &BTreeSet<String>,
    ) {
        for ap in bad_actions {
            if fs::remove_file(ap).is_ok() {
                rep.removed.push(self.relative(ap));
            }
        }
        for stem in bad_manifests.keys() {
            let dir = self.root().join("outputs").join(stem);
            if dir.exists() {
                remove_tree(&dir);
                rep.removed.push(self.relative(&dir));
            }
            let mp = self.root().join("manifests").join(format!("{stem}.json"));
            if fs::remove_file(&mp).is_ok() {
                rep.removed.push(self.relative(&mp));
            }
            // A verified-at stamp that older versions kept beside the manifest.
            let _ = fs::remove_file(self.root().join("verified").join(format!("{stem}.json")));
        }
        for name in bad_blobs {
            let p = self.blob_path(name);
            remove_tree(&p);
            if !p.exists() {
                rep.removed.push(self.relative(&p));
            }
        }
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
            .join(format!("damaged-{}", unique_suffix()));
        if fs::rename(&dir, &aside).is_ok() {
            remove_tree(&aside);
            true
        } else {
            false
        }
    }
}

/// An action entry file, read (never opening a special file) and parsed.
fn read_entry(ap: &Path) -> Result<ActionEntry, String> {
    let bytes = read_plain(ap).map_err(|e| e.to_string())?;
    serde_json::from_slice::<ActionEntry>(&bytes).map_err(|e| e.to_string())
}

/// Phase 3b: taint. An entry that read a damaged output, or an output that only damaged or
/// tainted entries produced, computed on bytes its key does not name; so did every entry
/// downstream of it. Returns the tainted entries' paths, each one reported.
fn check_taint(
    rep: &mut VerifyReport,
    sound: &[SoundEntry],
    bad_manifests: &BTreeMap<String, String>,
) -> Vec<PathBuf> {
    let mut bad = Vec::new();
    for (ap, key, entry, detail) in tainted_entries(sound, bad_manifests) {
        rep.broken_actions.push(Problem {
            path: ap.clone(),
            node: Some(entry.name.clone()),
            key: Some(key.clone()),
            detail,
        });
        bad.push(ap.clone());
    }
    bad
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
