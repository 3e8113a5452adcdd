//! The local executor: runs the needed computations of a [`Plan`] in dependency order,
//! independent ones in parallel within a thread budget, each inside a rayon pool of its own
//! budget; finds finished ones in the store by key (every run is a resume); claims keys so two
//! processes never compute one twice; promotes outputs atomically.
//!
//! [`execute`] is a short loop over a scheduler (`schedule.rs`: `Scheduler::start_ready` starts
//! what is ready and fits, `Scheduler::on_message` takes one finished computation); `run.rs`
//! runs one computation on a worker thread; `report.rs` turns the results into summaries and
//! the store's run records.

mod report;
mod run;
mod schedule;

pub use report::{arg_origin, flatten_args, instance_record};
pub(crate) use run::{changed_input, input_snapshot};

use crate::error::EngineError;
use crate::key::compute_key;
use crate::resolve::{Plan, Source};
use crate::store::{unhex, ActionEntry, Hash, Store};
use schedule::{Msg, Scheduler};
use std::collections::BTreeMap;
use std::sync::mpsc;
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
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            jobs: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1),
            targets: Vec::new(),
            progress: false,
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
/// are reserved for the store itself failing.
pub fn execute(plan: &Plan, store: &Store, opts: &RunOptions) -> Result<RunReport, EngineError> {
    let t0 = Instant::now();
    let _shared = store.lock_shared()?;
    let need = plan.needed(&opts.targets)?;
    let mut sched = Scheduler::new(plan, store, need, opts.jobs.max(1), opts.progress);
    let (tx, rx) = mpsc::channel::<Msg>();
    std::thread::scope(|scope| -> Result<(), EngineError> {
        loop {
            sched.start_ready(|job| {
                let tx = tx.clone();
                scope.spawn(move || {
                    let c = job.comp;
                    let _ = tx.send(Msg::Done(c, job.run(plan, store)));
                });
            })?;
            if sched.idle() {
                break;
            }
            let Ok(msg) = rx.recv() else {
                break;
            };
            sched.on_message(msg);
        }
        Ok(())
    })?;
    let report = RunReport {
        results: sched.into_results(),
        seconds: t0.elapsed().as_secs_f64(),
    };
    report::write_records(plan, store, &report)?;
    Ok(report)
}
