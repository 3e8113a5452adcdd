//! One driver loop for every executor.
//!
//! The driver owns the graph: which computations wait, which are ready, which are cached and
//! which were skipped because an input failed (the [`Scheduler`]). An [`Executor`] only runs
//! what it is given and says what finished: [`Executor::submit`] starts ready jobs,
//! [`Executor::poll`] waits for news of the started ones. [`drive`] repeats five named steps
//! until nothing runs:
//!
//! 1. [`pick_ready`]: the ready computations, in plan order (those whose key is in the store
//!    finish at once as cached, and their dependents may become ready in the same walk);
//! 2. submit them to the executor (one it cannot start comes back failed, and is settled);
//! 3. [`report`]: every needed node's state to the run's status file;
//! 4. poll the executor;
//! 5. [`settle`]: record each finished computation's result (its dependents become ready, or
//!    are skipped when it failed) and note which ones wait for another process's claim.

use super::run::Job;
use super::schedule::{Msg, Scheduler};
use super::status::{states_of_results, StatusWriter};
use super::{CompResult, RunOptions};
use crate::error::EngineError;
use crate::resolve::Plan;
use crate::store::Store;

/// Where a run's computations run: an executor starts the jobs it is given and reports what
/// became of them; everything else is the driver's.
pub(super) trait Executor {
    /// Whether every ready computation is started at once, whatever the thread budget (a
    /// cluster schedules its own jobs; the budget only sizes each one). Else only what fits
    /// the budget starts.
    fn unbounded(&self) -> bool;

    /// Whether the status file is written after every step (each step is one start or finish,
    /// cheap beside any node); else it is written when something was submitted, and otherwise
    /// at most once a second.
    fn eager_status(&self) -> bool;

    /// Starts `jobs` (ready computations, in plan order). Returns what the driver settles at
    /// once: the results of the jobs that could not be started.
    fn submit(&mut self, jobs: Vec<Job>) -> Vec<Msg>;

    /// Waits for news of the started jobs: the results of finished ones, and claim waits.
    /// May return nothing (nothing changed). Errors only when the store fails.
    fn poll(&mut self) -> Result<Vec<Msg>, EngineError>;

    /// Where started computation `c` runs (for the status file), and whether it is still
    /// queued there.
    fn place(&self, c: usize) -> Option<(String, bool)>;
}

/// Runs the needed computations of `plan` (those `need` marks) on `exec` (see the module
/// documentation); returns every needed computation's result, and marks the status file
/// finished.
pub(super) fn drive(
    plan: &Plan,
    store: &Store,
    opts: &RunOptions,
    need: Vec<bool>,
    exec: &mut impl Executor,
    status: &mut StatusWriter<'_>,
) -> Result<Vec<Option<CompResult>>, EngineError> {
    let mut sched = scheduler(plan, store, opts, need, exec.unbounded());
    loop {
        let ready = pick_ready(&mut sched)?;
        let submitted = !ready.is_empty();
        let refused = exec.submit(ready);
        settle(&mut sched, refused);
        report(status, &sched, exec, submitted || exec.eager_status());
        if sched.idle() {
            break;
        }
        let news = exec.poll()?;
        settle(&mut sched, news);
    }
    let results = sched.into_results();
    status.finish(states_of_results(plan, &results));
    Ok(results)
}

/// The run's scheduler, set up from its options and the executor's budget rule.
fn scheduler<'a>(
    plan: &'a Plan,
    store: &'a Store,
    opts: &RunOptions,
    need: Vec<bool>,
    unbounded: bool,
) -> Scheduler<'a> {
    let mut sched = Scheduler::new(plan, store, need, opts.jobs.max(1), opts.progress);
    sched.checkpoint_every = opts.checkpoint_every;
    sched.echo_log = opts.echo_log;
    sched.unbounded = unbounded;
    sched
}

/// Step 1: the computations that are ready and fit, as jobs (cached ones finish on the way).
fn pick_ready(sched: &mut Scheduler<'_>) -> Result<Vec<Job>, EngineError> {
    let mut ready = Vec::new();
    sched.start_ready(|job| ready.push(job))?;
    Ok(ready)
}

/// Step 3: every needed node's state, where the executor runs it, to the status file
/// (written now when `force`, else at most once a second).
fn report(status: &mut StatusWriter<'_>, sched: &Scheduler<'_>, exec: &impl Executor, force: bool) {
    status.update(sched.node_states(&|c| exec.place(c)), force);
}

/// Step 5: hands each message (a finished computation, a claim wait) to the scheduler.
fn settle(sched: &mut Scheduler<'_>, msgs: Vec<Msg>) {
    for msg in msgs {
        sched.on_message(msg);
    }
}
