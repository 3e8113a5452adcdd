//! Garbage collection: keeps every action reachable from a root (the latest run of each
//! pipeline, every pin) with its outputs, blobs and log; removes the rest, all scratch files
//! and stale claims.
//!
//! It never trusts what it cannot read: everything is read first and nothing is removed until
//! every kept entry and kept manifest has been read. An unreadable one stops `gc` with an
//! error naming it (its blobs could not be proved unreferenced); with `repair` such an entry
//! or manifest is dropped first (its key is then recomputed by the next run). `gc` refuses
//! while a run holds the store.
//!
//! [`Store::gc`] runs in phases, each a function: read the roots; mark the entries and the
//! manifests to keep (the read phase); drop what cannot be read (with `repair`); then sweep
//! entries and output folders, checkpoints, blobs and scratch files (the remove phase).

use super::files::{file_name, file_stem, list_dir, read_plain, remove_tree, set_readonly};
use super::hash::unhex;
use super::{ActionEntry, Manifest, Store};
use crate::error::EngineError;
use std::collections::BTreeSet;
use std::fs;
use std::path::PathBuf;

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

/// What the read phase decided, before anything is removed.
#[derive(Default)]
struct Marks {
    /// Entry files that no root keeps.
    drop_actions: Vec<PathBuf>,
    /// The manifests (hex) that kept entries name.
    keep_manifests: BTreeSet<String>,
    /// Manifest files that no kept entry names.
    drop_manifests: Vec<PathBuf>,
    /// The blobs (hex) that kept entries and manifests name.
    keep_blobs: BTreeSet<String>,
    /// Kept entries and manifests that cannot be read.
    unreadable: Vec<PathBuf>,
}

impl Store {
    /// Garbage collection (see the module documentation). With `dry_run`, removes nothing
    /// and reports what it would remove.
    pub fn gc(&self, dry_run: bool, repair: bool) -> Result<GcReport, EngineError> {
        let Some(lock) = self.try_lock_exclusive()? else {
            return Err(EngineError::Busy(format!(
                "a run is using the store {}; gc never removes what a running job uses: retry when it has finished",
                self.root().display()
            )));
        };
        let mut rep = GcReport::default();
        let roots = self.gc_roots(&mut rep)?;
        // Read phase: decide everything before removing anything.
        let mut marks = Marks::default();
        self.mark_entries(&mut rep, &roots, &mut marks);
        self.mark_manifests(&mut rep, &mut marks);
        if !marks.unreadable.is_empty() {
            self.drop_unreadable(&mut rep, &marks.unreadable, dry_run, repair)?;
            if !dry_run {
                drop(lock);
                return self.gc_after_repair(rep.repaired);
            }
        }
        // Remove phase.
        self.sweep_entries(&mut rep, &marks, dry_run);
        self.sweep_checkpoints(&mut rep, &roots, dry_run);
        self.sweep_blobs(&mut rep, &marks.keep_blobs, dry_run);
        self.sweep_scratch(&mut rep, dry_run);
        drop(lock);
        Ok(rep)
    }

    /// The root keys: every key the latest runs and the pins name. A root file that cannot be
    /// read stops `gc` (what it keeps is unknown).
    fn gc_roots(&self, rep: &mut GcReport) -> Result<BTreeSet<String>, EngineError> {
        let mut keep_keys: BTreeSet<String> = BTreeSet::new();
        for dir in ["runs/latest", "pins"] {
            for f in list_dir(&self.root().join(dir)) {
                let v = read_plain(&f)
                    .ok()
                    .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok());
                let Some(v) = v else {
                    return Err(EngineError::Other(format!(
                        "gc: the root file {} cannot be read, so what it keeps is unknown; nothing was removed (fix or remove that file, then run gc again)",
                        f.display()
                    )));
                };
                collect_keys(&v, &mut keep_keys);
                rep.root_files.push(self.relative(&f));
            }
        }
        rep.roots = keep_keys.len();
        Ok(keep_keys)
    }

    /// Read phase, entries: an entry no root names is dropped; a kept one keeps its
    /// manifests and its log (and is reported broken when an output is incomplete).
    fn mark_entries(&self, rep: &mut GcReport, roots: &BTreeSet<String>, marks: &mut Marks) {
        for sub in list_dir(&self.root().join("actions")) {
            for f in list_dir(&sub) {
                let key = file_stem(&f);
                if !roots.contains(&key) {
                    marks.drop_actions.push(f);
                    continue;
                }
                let Some(entry) = read_plain(&f)
                    .ok()
                    .and_then(|b| serde_json::from_slice::<ActionEntry>(&b).ok())
                else {
                    marks.unreadable.push(f);
                    continue;
                };
                // The entry is already parsed: check its outputs without reading it again.
                if let Some(reason) = self.entry_problem(&entry) {
                    rep.broken.push(format!(
                        "node `{}` (key {}…): {reason}",
                        entry.name,
                        &key[..key.len().min(16)]
                    ));
                }
                marks.keep_manifests.extend(entry.outputs.values().cloned());
                marks.keep_blobs.extend(entry.log.clone());
                rep.actions_kept += 1;
            }
        }
    }

    /// Read phase, manifests: one no kept entry names is dropped; a kept one keeps its blobs.
    fn mark_manifests(&self, rep: &mut GcReport, marks: &mut Marks) {
        for f in list_dir(&self.root().join("manifests")) {
            if !marks.keep_manifests.contains(&file_stem(&f)) {
                marks.drop_manifests.push(f);
                continue;
            }
            match read_plain(&f)
                .ok()
                .and_then(|b| serde_json::from_slice::<Manifest>(&b).ok())
            {
                Some(m) => {
                    marks.keep_blobs.extend(
                        m.entries
                            .into_iter()
                            .filter(|e| !e.hash.is_empty())
                            .map(|e| e.hash),
                    );
                    rep.outputs_kept += 1;
                }
                None => marks.unreadable.push(f),
            }
        }
    }

    /// Kept entries and manifests that cannot be read: an error without `repair`; with it,
    /// each is dropped (a manifest with its output folder) unless `dry_run`, and reported.
    fn drop_unreadable(
        &self,
        rep: &mut GcReport,
        unreadable: &[PathBuf],
        dry_run: bool,
        repair: bool,
    ) -> Result<(), EngineError> {
        if !repair {
            let names: Vec<String> = unreadable.iter().map(|p| p.display().to_string()).collect();
            return Err(EngineError::Other(format!(
                "gc: cannot read {} kept by a root: {}. Their blobs cannot be proved unreferenced, so nothing was removed. `augsplat gc --repair` drops them first (their nodes are recomputed by the next run); `augsplat verify` checks the whole store",
                if names.len() == 1 { "this entry" } else { "these entries" },
                names.join(", ")
            )));
        }
        // Drop each unreadable kept file, and every kept entry that names an unreadable
        // manifest; the collection then starts again (their blobs are no longer kept).
        for p in unreadable {
            if !dry_run {
                set_readonly(p, false);
                let _ = fs::remove_file(p);
                if p.parent()
                    .map(|d| d.ends_with("manifests"))
                    .unwrap_or(false)
                {
                    remove_tree(&self.root().join("outputs").join(file_stem(p)));
                }
            }
            rep.repaired.push(self.relative(p));
        }
        Ok(())
    }

    /// Remove phase, entries and outputs: the dropped entries, the dropped manifests with
    /// their output folders, and output folders whose manifest file is missing (an
    /// interrupted promotion).
    fn sweep_entries(&self, rep: &mut GcReport, marks: &Marks, dry_run: bool) {
        let root = self.root();
        for f in &marks.drop_actions {
            rep.actions_removed += 1;
            if !dry_run {
                let _ = fs::remove_file(f);
            }
        }
        for f in &marks.drop_manifests {
            rep.outputs_removed += 1;
            if !dry_run {
                remove_tree(&root.join("outputs").join(file_stem(f)));
                let _ = fs::remove_file(f);
                // A verified-at stamp that older versions kept beside the manifest.
                let _ =
                    fs::remove_file(root.join("verified").join(format!("{}.json", file_stem(f))));
            }
        }
        for d in list_dir(&root.join("outputs")) {
            let name = file_name(&d);
            if !marks.keep_manifests.contains(&name)
                && !root.join("manifests").join(format!("{name}.json")).exists()
            {
                rep.scratch_removed += 1;
                if !dry_run {
                    remove_tree(&d);
                }
            }
        }
    }

    /// Remove phase, checkpoints: those of a key that has its entry, or that no root and no
    /// run's status names (no pipeline will resume it): the interrupted run they belong to is
    /// gone.
    fn sweep_checkpoints(&self, rep: &mut GcReport, roots: &BTreeSet<String>, dry_run: bool) {
        let mut resumable = roots.clone();
        for f in list_dir(&self.root().join("runs/status")) {
            if let Some(v) = read_plain(&f)
                .ok()
                .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            {
                collect_keys(&v, &mut resumable);
            }
        }
        for d in list_dir(&self.root().join("checkpoints")) {
            let key = file_name(&d);
            let has_entry = unhex(&key)
                .map(|k| self.action_path(&k).exists())
                .unwrap_or(false);
            if has_entry || !resumable.contains(&key) {
                rep.checkpoints_removed += 1;
                if !dry_run {
                    remove_tree(&d);
                }
            }
        }
    }

    /// Remove phase, blobs: every blob that no kept entry or manifest names.
    fn sweep_blobs(&self, rep: &mut GcReport, keep_blobs: &BTreeSet<String>, dry_run: bool) {
        for sub in list_dir(&self.root().join("blobs")) {
            for f in list_dir(&sub) {
                if keep_blobs.contains(&file_name(&f)) {
                    rep.blobs_kept += 1;
                    continue;
                }
                rep.blobs_removed += 1;
                rep.bytes_removed += fs::metadata(&f).map(|m| m.len()).unwrap_or(0);
                if !dry_run {
                    set_readonly(&f, false);
                    let _ = fs::remove_file(&f);
                }
            }
        }
    }

    /// Remove phase, scratch: every scratch folder, half-written file and claim file (no run
    /// holds the store, so none is live).
    fn sweep_scratch(&self, rep: &mut GcReport, dry_run: bool) {
        for dir in ["tmp", "locks"] {
            for f in list_dir(&self.root().join(dir)) {
                rep.scratch_removed += 1;
                if !dry_run {
                    remove_tree(&f);
                }
            }
        }
    }

    /// The collection that follows a repair (the exclusive lock is released and taken again).
    fn gc_after_repair(&self, repaired: Vec<String>) -> Result<GcReport, EngineError> {
        let mut rep = self.gc(false, false)?;
        rep.repaired = repaired;
        Ok(rep)
    }
}
