//! Running a [`Plan`]: the needed computations in dependency order, independent ones in
//! parallel, each found in the store by key when it is there (every run is a resume); claims
//! keep two processes from computing one key twice, and outputs are promoted atomically.
//!
//! [`execute`] hands the run to one driver loop (`driver.rs`) over an executor, which only
//! starts jobs and reports what became of them: `local.rs` runs each on a worker thread within
//! a thread budget, each inside a rayon pool of its own budget; [`slurm`] submits each as a
//! Slurm job. `schedule.rs` is the driver's scheduler (what waits, what is ready, what fits);
//! `run.rs` runs one computation; `report.rs` turns the results into summaries and the store's
//! run records; [`status`] writes the run's live status file.

mod driver;
mod local;
mod report;
mod run;
mod schedule;
pub mod slurm;
pub mod status;

pub use report::{arg_origin, flatten_args, instance_record};

use crate::error::EngineError;
use crate::key::compute_key;
use crate::resolve::{Plan, Source};
use crate::store::{unhex, ActionEntry, Hash, Store};
use driver::drive;
use local::Local;
use slurm::Slurm;
use std::collections::BTreeMap;
use std::time::Instant;

/// How to run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Thread budget of the executor (cores). Default: all available.
    pub jobs: usize,
    /// Instances or node names to build (with their ancestors); empty = everything.
    pub targets: Vec<String>,
    /// Draw progress bars on stderr (only when it is a terminal).
    pub progress: bool,
    /// Long nodes save a checkpoint every this many of their steps (0: never); a rerun of
    /// an interrupted computation resumes from it. Not part of any key.
    pub checkpoint_every: u64,
    /// Echo each running node's log lines to stderr as they arrive, prefixed with the node's
    /// name and its elapsed seconds (for long runs under `nohup`, Slurm or a CI log, where no
    /// progress bar is drawn). The log is stored with the node's result either way.
    pub echo_log: bool,
    /// Where computations run.
    pub executor: ExecutorKind,
}

/// Where a run's computations run.
#[derive(Clone, Debug, Default)]
pub enum ExecutorKind {
    /// In this process, on worker threads (the default).
    #[default]
    Local,
    /// Each as a Slurm job (see [`slurm`]).
    Slurm(slurm::SlurmOptions),
}

/// The default checkpoint cadence, in a node's steps.
pub const DEFAULT_CHECKPOINT_EVERY: u64 = 1000;

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            jobs: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1),
            targets: Vec::new(),
            progress: false,
            checkpoint_every: DEFAULT_CHECKPOINT_EVERY,
            echo_log: false,
            executor: ExecutorKind::Local,
        }
    }
}

/// What happened to a computation.
#[derive(Clone, Debug, PartialEq)]
pub enum Status {
    /// It ran and its outputs were stored.
    Ran,
    /// Its key was in the store.
    Cached,
    /// It (or its promotion) failed; the message says why.
    Failed(String),
    /// An input failed, so it did not run.
    Skipped,
}

impl Status {
    /// `ran`, `cached`, `failed` or `skipped`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Status::Ran => "ran",
            Status::Cached => "cached",
            Status::Failed(_) => "failed",
            Status::Skipped => "skipped",
        }
    }
}

/// The result of one computation.
#[derive(Clone, Debug)]
pub struct CompResult {
    /// What happened.
    pub status: Status,
    /// Its key (unknown when skipped).
    pub key: Option<Hash>,
    /// Seconds it ran (0 when cached).
    pub seconds: f64,
    /// Seconds the computation took when it ran: this run's for `Ran`, the cache entry's
    /// record for `Cached` (so a resumed run still shows what each stage costs).
    pub computed_seconds: f64,
    /// Output name -> manifest hash.
    pub outputs: BTreeMap<String, Hash>,
    /// Whether it waited for another process computing the same key.
    pub waited: bool,
    /// When a gate ended it without running (see [`crate::gate`]), the gate's reason; its
    /// outputs hold only the marker.
    pub gated: Option<String>,
}

/// The result of a run.
pub struct RunReport {
    /// Per computation (`None`: not needed for the targets).
    pub results: Vec<Option<CompResult>>,
    /// Wall-clock seconds of the whole run.
    pub seconds: f64,
}

/// Per computation: its key when computable before running (every input external or cached),
/// with its action entry when the key is in the store.
pub type PlannedKeys = Vec<Option<(Hash, Option<ActionEntry>)>>;

/// Keys computable without running anything: for each computation whose inputs are all
/// external or cached, its key and (if present) its action entry.
pub fn plan_keys(plan: &Plan, store: &Store) -> Result<PlannedKeys, EngineError> {
    let mut out: PlannedKeys = Vec::with_capacity(plan.comps.len());
    for comp in &plan.comps {
        let mut ms = Vec::with_capacity(comp.inputs.len());
        let mut known = true;
        'slots: for slot in &comp.inputs {
            let mut v = Vec::with_capacity(slot.sources.len());
            for (s, _) in &slot.sources {
                match s {
                    Source::External { hash, .. } => v.push(*hash),
                    Source::Node { comp: up, output } => match &out[*up] {
                        Some((_, Some(entry))) => {
                            match entry.outputs.get(output).and_then(|m| unhex(m)) {
                                Some(m) => v.push(m),
                                None => {
                                    known = false;
                                    break 'slots;
                                }
                            }
                        }
                        _ => {
                            known = false;
                            break 'slots;
                        }
                    },
                }
            }
            ms.push(v);
        }
        if !known {
            out.push(None);
            continue;
        }
        let key = compute_key(comp, &ms);
        out.push(Some((key, store.action(&key)?)));
    }
    Ok(out)
}

/// Runs the plan. Returns a report even when nodes fail (check [`RunReport::success`]); errors
/// are reserved for the store itself failing (and, with Slurm, for `sbatch` being absent).
pub fn execute(plan: &Plan, store: &Store, opts: &RunOptions) -> Result<RunReport, EngineError> {
    let t0 = Instant::now();
    let _shared = store.lock_shared()?;
    let need = plan.needed(&opts.targets)?;
    let executor = match opts.executor {
        ExecutorKind::Local => "local",
        ExecutorKind::Slurm(_) => "slurm",
    };
    let mut status = status::StatusWriter::new(store, plan.file.display().to_string(), executor);
    let results = match &opts.executor {
        ExecutorKind::Local => std::thread::scope(|scope| {
            let mut local = Local::new(scope, plan, store);
            drive(plan, store, opts, need, &mut local, &mut status)
        })?,
        ExecutorKind::Slurm(s) => {
            let mut slurm = Slurm::new(plan, store, opts, s, status.run_id())?;
            drive(plan, store, opts, need, &mut slurm, &mut status)?
        }
    };
    let report = RunReport {
        results,
        seconds: t0.elapsed().as_secs_f64(),
    };
    report::write_records(plan, store, &report)?;
    Ok(report)
}

/// Computes the one computation of `plan` whose key is `key_hex` (its inputs must be in the
/// store), as a Slurm job's worker does: claims it, finds it cached or runs it with `threads`
/// threads, stores its outputs and entry.
pub fn compute_by_key(
    plan: &Plan,
    store: &Store,
    key_hex: &str,
    threads: usize,
    checkpoint_every: u64,
) -> Result<CompResult, EngineError> {
    let _shared = store.lock_shared()?;
    let want =
        unhex(key_hex).ok_or_else(|| EngineError::Other(format!("`{key_hex}` is not a key")))?;
    let keys = plan_keys(plan, store)?;
    let c = keys
        .iter()
        .position(|k| k.as_ref().is_some_and(|(k, _)| *k == want))
        .ok_or_else(|| {
            EngineError::Other(format!(
                "no computation of {} has the key {key_hex} with its inputs in the store {} \
                 (the pipeline or an input changed since the job was submitted, or an input's \
                 entry is not visible on this machine yet)",
                plan.file.display(),
                store.root().display()
            ))
        })?;
    let (folders, hashes) = input_folders(plan, store, &keys, c)?;
    let job = run::Job {
        comp: c,
        name: plan.comps[c].display_name(plan).to_string(),
        key: want,
        inputs: folders,
        input_hashes: hashes,
        threads: threads.max(1),
        bar: None,
        checkpoint_every,
        echo_log: false,
    };
    let name = plan.comps[c].display_name(plan).to_string();
    Ok(job.run(plan, store, &|h| {
        if let Some(h) = h {
            eprintln!("{}", schedule::waiting_line(&name, h))
        }
    }))
}

/// Computation `c`'s input folders and their content hashes (per slot, in the same order),
/// from its upstream computations' entries in `keys`.
#[allow(clippy::type_complexity)]
fn input_folders(
    plan: &Plan,
    store: &Store,
    keys: &PlannedKeys,
    c: usize,
) -> Result<(Vec<(String, Vec<std::path::PathBuf>)>, Vec<Vec<Hash>>), EngineError> {
    let mut out = Vec::new();
    let mut hashes = Vec::new();
    for slot in &plan.comps[c].inputs {
        let mut f = Vec::new();
        let mut h = Vec::new();
        for (s, _) in &slot.sources {
            match s {
                Source::External { path, hash } => {
                    f.push(path.clone());
                    h.push(*hash);
                }
                Source::Node { comp: up, output } => {
                    let m = keys[*up]
                        .as_ref()
                        .and_then(|(_, e)| e.as_ref())
                        .and_then(|e| e.outputs.get(output))
                        .and_then(|m| unhex(m))
                        .ok_or_else(|| {
                            EngineError::Other(format!(
                                "output `{output}` of an upstream node is not in the store"
                            ))
                        })?;
                    f.push(store.output_dir(&m));
                    h.push(m);
                }
            }
        }
        out.push((slot.name.clone(), f));
        hashes.push(h);
    }
    Ok((out, hashes))
}
