//! The local executor: each job runs on a worker thread of this process, spawned in the
//! run's thread scope; a worker sends back its result, and whom it waits for while another
//! process holds its key's claim. The thread budget is the scheduler's.

use super::driver::Executor;
use super::run::Job;
use super::schedule::Msg;
use crate::error::EngineError;
use crate::resolve::Plan;
use crate::store::claim::ClaimHolder;
use crate::store::{hostname, Store};
use std::sync::mpsc::{self, Receiver, Sender};
use std::thread::Scope;

/// Worker threads in a thread scope (see the module documentation).
pub(super) struct Local<'scope, 'env> {
    scope: &'scope Scope<'scope, 'env>,
    plan: &'env Plan,
    store: &'env Store,
    /// Cloned into each worker.
    tx: Sender<Msg>,
    rx: Receiver<Msg>,
    /// Where every job runs: `pid N on HOST`.
    here: String,
}

impl<'scope, 'env> Local<'scope, 'env> {
    /// Workers spawned in `scope`, computing computations of `plan` into `store`.
    pub(super) fn new(
        scope: &'scope Scope<'scope, 'env>,
        plan: &'env Plan,
        store: &'env Store,
    ) -> Self {
        let (tx, rx) = mpsc::channel();
        Local {
            scope,
            plan,
            store,
            tx,
            rx,
            here: format!("pid {} on {}", std::process::id(), hostname()),
        }
    }
}

impl Executor for Local<'_, '_> {
    fn unbounded(&self) -> bool {
        false
    }

    fn eager_status(&self) -> bool {
        true
    }

    /// Spawns one worker per job; every job starts.
    fn submit(&mut self, jobs: Vec<Job>) -> Vec<Msg> {
        for job in jobs {
            let (plan, store, tx) = (self.plan, self.store, self.tx.clone());
            self.scope.spawn(move || {
                let c = job.comp;
                let waiting = tx.clone();
                let on_wait = move |h: Option<&ClaimHolder>| {
                    let _ = waiting.send(Msg::Waiting(c, h.cloned()));
                };
                let _ = tx.send(Msg::Done(c, job.run(plan, store, &on_wait)));
            });
        }
        Vec::new()
    }

    /// Waits for the next message of any worker: one per step.
    fn poll(&mut self) -> Result<Vec<Msg>, EngineError> {
        // `self.tx` lives as long as `self`: the channel never closes while a worker runs.
        self.rx
            .recv()
            .map(|msg| vec![msg])
            .map_err(|_| EngineError::Other("internal: the local executor's channel closed".into()))
    }

    fn place(&self, _c: usize) -> Option<(String, bool)> {
        Some((self.here.clone(), false))
    }
}
