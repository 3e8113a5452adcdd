//! A run's live status, for `augsplat status`: the executor rewrites
//! `runs/status/<run id>.json` (atomically, at most once a second and at the end) with every
//! needed node's state — waiting, ready, queued, running (where), ran, cached, failed (why),
//! skipped — and points `runs/status/latest` at it.

use crate::error::EngineError;
use crate::store::{hostname, now_unix, Store};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// One node's state in a run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NodeState {
    /// Display name (the first instance's).
    pub name: String,
    /// Node kind.
    pub kind: String,
    /// Its key (hex), once known.
    pub key: Option<String>,
    /// `waiting` (for inputs), `ready` (for cores), `queued` (submitted, pending), `running`,
    /// `ran`, `cached`, `failed` or `skipped`.
    pub state: String,
    /// Where it runs: `pid 12 on host`, or `Slurm job 34 on node7`.
    pub place: Option<String>,
    /// Seconds it ran (`ran`), or its cache entry's seconds (`cached`).
    pub seconds: Option<f64>,
    /// Why it failed (with the tail of its log).
    pub message: Option<String>,
}

/// `runs/status/<run id>.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunStatus {
    /// `<unix time>-<pid>` of the driver.
    pub run_id: String,
    /// The pipeline file.
    pub pipeline: String,
    /// `local` or `slurm`.
    pub executor: String,
    /// The driver's host.
    pub host: String,
    /// The driver's process id.
    pub pid: u32,
    /// When the run started (Unix seconds).
    pub started_unix: u64,
    /// When this file was written.
    pub updated_unix: u64,
    /// Whether the run has ended.
    pub finished: bool,
    /// Every needed node, in plan order.
    pub nodes: Vec<NodeState>,
}

/// Writes a run's status file as it changes.
pub(super) struct StatusWriter<'a> {
    store: &'a Store,
    status: RunStatus,
    path: PathBuf,
    last: Option<Instant>,
}

impl<'a> StatusWriter<'a> {
    pub(super) fn new(store: &'a Store, pipeline: String, executor: &str) -> Self {
        let pid = std::process::id();
        let started = now_unix();
        let run_id = format!("{started}-{pid}");
        let path = store
            .root()
            .join("runs")
            .join("status")
            .join(format!("{run_id}.json"));
        StatusWriter {
            store,
            status: RunStatus {
                run_id,
                pipeline,
                executor: executor.into(),
                host: hostname(),
                pid,
                started_unix: started,
                updated_unix: started,
                finished: false,
                nodes: Vec::new(),
            },
            path,
            last: None,
        }
    }

    /// The run's id (names its Slurm jobs).
    pub(super) fn run_id(&self) -> &str {
        &self.status.run_id
    }

    /// Records `nodes`; writes the file when `force` or a second has passed since the last
    /// write. A failure to write is reported once on stderr and never fails the run.
    pub(super) fn update(&mut self, nodes: Vec<NodeState>, force: bool) {
        self.status.nodes = nodes;
        if !force
            && self
                .last
                .is_some_and(|t| t.elapsed() < Duration::from_secs(1))
        {
            return;
        }
        let first = self.last.is_none();
        self.last = Some(Instant::now());
        if let Err(e) = self.write(first) {
            if first {
                eprintln!("warning: cannot write the run's status file: {e}");
            }
        }
    }

    /// Marks the run finished and writes the file.
    pub(super) fn finish(&mut self, nodes: Vec<NodeState>) {
        self.status.finished = true;
        self.update(nodes, true);
    }

    fn write(&mut self, first: bool) -> Result<(), EngineError> {
        self.status.updated_unix = now_unix();
        let text = serde_json::to_vec_pretty(&self.status).expect("status serialises");
        self.store.write_atomic(&self.path, &text)?;
        if first {
            let latest = self.path.with_file_name("latest");
            self.store
                .write_atomic(&latest, self.status.run_id.as_bytes())?;
            prune_statuses(self.store, KEPT_STATUSES);
        }
        Ok(())
    }
}

/// How many runs' status files a store keeps (`augsplat status --all` lists them).
pub const KEPT_STATUSES: usize = 20;

/// The status files of `store`'s runs, newest first (by start time, then run id).
fn status_files(store: &Store) -> Vec<(u64, String, PathBuf)> {
    let dir = store.root().join("runs").join("status");
    let mut v: Vec<(u64, String, PathBuf)> = crate::store::list_dir(&dir)
        .into_iter()
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .filter_map(|p| {
            let id = p.file_stem()?.to_string_lossy().to_string();
            let started = id.split('-').next()?.parse().ok()?;
            Some((started, id, p))
        })
        .collect();
    v.sort_by(|a, b| (b.0, &b.1).cmp(&(a.0, &a.1)));
    v
}

/// Removes all but the newest `keep` status files.
fn prune_statuses(store: &Store, keep: usize) {
    for (_, _, p) in status_files(store).into_iter().skip(keep) {
        let _ = std::fs::remove_file(p);
    }
}

/// The status of every run the store keeps ([`KEPT_STATUSES`] at most), newest first; a file
/// that cannot be read is skipped.
pub fn recent_statuses(store: &Store) -> Vec<RunStatus> {
    status_files(store)
        .into_iter()
        .filter_map(|(_, _, p)| {
            let bytes = crate::store::read_plain(&p).ok()?;
            serde_json::from_slice(&bytes).ok()
        })
        .collect()
}

/// The status of the latest run on `store` (the one `runs/status/latest` names), if any.
pub fn latest_status(store: &Store) -> Result<Option<RunStatus>, EngineError> {
    let dir = store.root().join("runs").join("status");
    let Ok(id) = std::fs::read_to_string(dir.join("latest")) else {
        return Ok(None);
    };
    let path = dir.join(format!("{}.json", id.trim()));
    let bytes = std::fs::read(&path).map_err(crate::error::io("reading", &path))?;
    serde_json::from_slice(&bytes)
        .map(Some)
        .map_err(|e| EngineError::Other(format!("{}: {e}", path.display())))
}

/// Every needed computation's final state, from a run's results.
pub(super) fn states_of_results(
    plan: &crate::resolve::Plan,
    results: &[Option<super::CompResult>],
) -> Vec<NodeState> {
    use super::Status;
    results
        .iter()
        .enumerate()
        .filter_map(|(c, r)| {
            let r = r.as_ref()?;
            let comp = &plan.comps[c];
            Some(NodeState {
                name: comp.display_name(plan).to_string(),
                kind: comp.node.kind().to_string(),
                key: r.key.as_ref().map(crate::store::hex),
                state: r.status.as_str().into(),
                place: None,
                seconds: matches!(r.status, Status::Ran | Status::Cached)
                    .then_some(r.computed_seconds),
                message: match &r.status {
                    Status::Failed(m) => Some(m.clone()),
                    _ => r.gated.as_ref().map(|g| format!("gated: {g}")),
                },
            })
        })
        .collect()
}
