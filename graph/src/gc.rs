//! Garbage collection: keeps every action reachable from a root (the latest run of each
//! pipeline, every pin) with its outputs, blobs and log; removes the rest, all scratch files
//! and stale claims.
//!
//! It never trusts what it cannot read: everything is read first and nothing is removed until
//! every kept entry and kept manifest has been read. An unreadable one stops `gc` with an
//! error naming it (its blobs could not be proved unreferenced); with `repair` such an entry
//! or manifest is dropped first (its key is then recomputed by the next run). `gc` refuses
//! while a run holds the store.

use crate::error::EngineError;
use crate::store::{
    collect_keys, list_dir, remove_tree, set_readonly, ActionEntry, GcReport, Manifest, Store,
};
use std::collections::BTreeSet;
use std::fs;
use std::path::{Path, PathBuf};

fn stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default()
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
        let root = self.root();
        let rel = |p: &Path| p.strip_prefix(root).unwrap_or(p).display().to_string();
        let mut rep = GcReport::default();
        let mut keep_keys: BTreeSet<String> = BTreeSet::new();
        for dir in ["runs/latest", "pins"] {
            for f in list_dir(&root.join(dir)) {
                let v = crate::verify::read_plain(&f)
                    .ok()
                    .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok());
                let Some(v) = v else {
                    return Err(EngineError::Other(format!(
                        "gc: the root file {} cannot be read, so what it keeps is unknown; nothing was removed (fix or remove that file, then run gc again)",
                        f.display()
                    )));
                };
                collect_keys(&v, &mut keep_keys);
                rep.root_files.push(rel(&f));
            }
        }
        rep.roots = keep_keys.len();

        // Read phase: decide everything before removing anything.
        let mut drop_actions: Vec<PathBuf> = Vec::new();
        let mut keep_manifests: BTreeSet<String> = BTreeSet::new();
        let mut keep_blobs: BTreeSet<String> = BTreeSet::new();
        let mut unreadable: Vec<PathBuf> = Vec::new();
        for sub in list_dir(&root.join("actions")) {
            for f in list_dir(&sub) {
                let key = stem(&f);
                if !keep_keys.contains(&key) {
                    drop_actions.push(f);
                    continue;
                }
                match crate::verify::read_plain(&f)
                    .ok()
                    .and_then(|b| serde_json::from_slice::<ActionEntry>(&b).ok())
                {
                    Some(entry) => {
                        // The entry is already parsed: check its outputs without reading it
                        // again.
                        if let Some(reason) = self.entry_problem(&entry) {
                            rep.broken.push(format!(
                                "node `{}` (key {}…): {reason}",
                                entry.name,
                                &key[..key.len().min(16)]
                            ));
                        }
                        keep_manifests.extend(entry.outputs.values().cloned());
                        keep_blobs.extend(entry.log.clone());
                        rep.actions_kept += 1;
                    }
                    None => unreadable.push(f),
                }
            }
        }
        let mut drop_manifests: Vec<PathBuf> = Vec::new();
        for f in list_dir(&root.join("manifests")) {
            let name = stem(&f);
            if !keep_manifests.contains(&name) {
                drop_manifests.push(f);
                continue;
            }
            match crate::verify::read_plain(&f)
                .ok()
                .and_then(|b| serde_json::from_slice::<Manifest>(&b).ok())
            {
                Some(m) => {
                    keep_blobs.extend(
                        m.entries
                            .into_iter()
                            .filter(|e| !e.hash.is_empty())
                            .map(|e| e.hash),
                    );
                    rep.outputs_kept += 1;
                }
                None => unreadable.push(f),
            }
        }
        if !unreadable.is_empty() {
            let names: Vec<String> = unreadable.iter().map(|p| p.display().to_string()).collect();
            if !repair {
                return Err(EngineError::Other(format!(
                    "gc: cannot read {} kept by a root: {}. Their blobs cannot be proved unreferenced, so nothing was removed. `augsplat gc --repair` drops them first (their nodes are recomputed by the next run); `augsplat verify` checks the whole store",
                    if names.len() == 1 { "this entry" } else { "these entries" },
                    names.join(", ")
                )));
            }
            // Repair: drop each unreadable kept file, and every kept entry that names an
            // unreadable manifest; then collect again (their blobs are no longer kept).
            for p in &unreadable {
                if !dry_run {
                    set_readonly(p, false);
                    let _ = fs::remove_file(p);
                    if p.parent()
                        .map(|d| d.ends_with("manifests"))
                        .unwrap_or(false)
                    {
                        remove_tree(&root.join("outputs").join(stem(p)));
                    }
                }
                rep.repaired.push(rel(p));
            }
            if !dry_run {
                drop(lock);
                return self.gc_after_repair(rep.repaired);
            }
        }

        // Remove phase.
        for f in &drop_actions {
            rep.actions_removed += 1;
            if !dry_run {
                let _ = fs::remove_file(f);
            }
        }
        for f in &drop_manifests {
            rep.outputs_removed += 1;
            if !dry_run {
                remove_tree(&root.join("outputs").join(stem(f)));
                let _ = fs::remove_file(f);
                // A verified-at stamp that older versions kept beside the manifest.
                let _ = fs::remove_file(root.join("verified").join(format!("{}.json", stem(f))));
            }
        }
        // Output folders whose manifest file is missing (interrupted promotion) go too.
        for d in list_dir(&root.join("outputs")) {
            let name = d
                .file_name()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_default();
            if !keep_manifests.contains(&name)
                && !root.join("manifests").join(format!("{name}.json")).exists()
            {
                rep.scratch_removed += 1;
                if !dry_run {
                    remove_tree(&d);
                }
            }
        }
        // Checkpoints of a key that has its entry, or that no root and no run's status names
        // (no pipeline will resume it): the interrupted run they belong to is gone.
        let mut resumable = keep_keys.clone();
        for f in list_dir(&root.join("runs/status")) {
            if let Some(v) = crate::verify::read_plain(&f)
                .ok()
                .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            {
                collect_keys(&v, &mut resumable);
            }
        }
        for d in list_dir(&root.join("checkpoints")) {
            let key = d
                .file_name()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_default();
            let has_entry = crate::store::unhex(&key)
                .map(|k| self.action_path(&k).exists())
                .unwrap_or(false);
            if has_entry || !resumable.contains(&key) {
                rep.checkpoints_removed += 1;
                if !dry_run {
                    remove_tree(&d);
                }
            }
        }
        for sub in list_dir(&root.join("blobs")) {
            for f in list_dir(&sub) {
                let name = f
                    .file_name()
                    .map(|s| s.to_string_lossy().to_string())
                    .unwrap_or_default();
                if keep_blobs.contains(&name) {
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
        for dir in ["tmp", "locks"] {
            for f in list_dir(&root.join(dir)) {
                rep.scratch_removed += 1;
                if !dry_run {
                    remove_tree(&f);
                }
            }
        }
        drop(lock);
        Ok(rep)
    }

    /// The collection that follows a repair (the exclusive lock is released and taken again).
    fn gc_after_repair(&self, repaired: Vec<String>) -> Result<GcReport, EngineError> {
        let mut rep = self.gc(false, false)?;
        rep.repaired = repaired;
        Ok(rep)
    }
}
