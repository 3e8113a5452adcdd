//! The scheduler of one run: which needed computations wait on which, which are ready, which
//! run, and how much of the thread budget is free.
//!
//! The driver loop (`driver.rs`) alternates two steps of it until nothing runs:
//! [`Scheduler::start_ready`] walks the ready queue in plan order, finishing at once each
//! computation whose key is in the store and handing over each one whose thread budget fits (a
//! `Threads::All` computation that does not fit reserves the machine: nothing after it
//! starts); [`Scheduler::on_message`] takes a finished computation's result, frees its threads
//! and readies its dependents. A failed computation's dependents never become ready;
//! [`Scheduler::into_results`] marks them skipped.

use super::run::{outputs_of, Job};
use super::{CompResult, Status};
use crate::error::EngineError;
use crate::key::compute_key;
use crate::node::Threads;
use crate::resolve::{Plan, Source};
use crate::store::EntryState;
use crate::store::{hex, Hash, Store};
use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::PathBuf;
use std::time::Duration;

/// What a worker thread sends back.
pub(super) enum Msg {
    /// Computation `.0` finished with result `.1`.
    Done(usize, CompResult),
    /// Computation `.0` waits for another process, `.1`, that holds its key's claim (`None`:
    /// it no longer waits).
    Waiting(usize, Option<crate::store::claim::ClaimHolder>),
}

/// The line a run prints when a node waits for another process computing the same key.
pub(super) fn waiting_line(name: &str, h: &crate::store::claim::ClaimHolder) -> String {
    format!(
        "waiting: `{name}` is being computed by {}, which claimed it {} s ago; its result \
         will be used when it finishes (a claim whose holder died is taken over)",
        h.describe(),
        crate::store::now_unix().saturating_sub(h.since_unix)
    )
}

/// The overall progress bar and, when drawn, one spinner per running computation.
struct Progress {
    multi: MultiProgress,
    overall: ProgressBar,
    /// Whether bars are drawn (per-node spinners are made only then).
    show: bool,
}

impl Progress {
    fn new(show: bool, total: u64) -> Self {
        let multi = MultiProgress::with_draw_target(if show {
            ProgressDrawTarget::stderr()
        } else {
            ProgressDrawTarget::hidden()
        });
        let overall = multi.add(ProgressBar::new(total));
        overall.set_style(
            ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} nodes {msg}")
                .expect("template")
                .progress_chars("=> "),
        );
        Progress {
            multi,
            overall,
            show,
        }
    }

    /// A spinner for computation `c` about to start, when bars are drawn.
    fn node_bar(&self, plan: &Plan, c: usize) -> Option<ProgressBar> {
        if !self.show {
            return None;
        }
        let comp = &plan.comps[c];
        let b = self.multi.add(ProgressBar::new_spinner());
        b.set_style(
            ProgressStyle::with_template("  {spinner} {prefix} [{elapsed}] {wide_msg}")
                .expect("template"),
        );
        b.set_prefix(format!(
            "{} ({})",
            comp.display_name(plan),
            comp.node.kind()
        ));
        b.enable_steady_tick(Duration::from_millis(200));
        Some(b)
    }
}

/// The state of one run's scheduling (see the module docs).
pub(super) struct Scheduler<'a> {
    plan: &'a Plan,
    store: &'a Store,
    /// Which computations the targets need.
    need: Vec<bool>,
    /// The executor's thread budget.
    jobs: usize,
    /// Threads not held by running computations.
    free: usize,
    /// Per computation, its result once finished.
    results: Vec<Option<CompResult>>,
    /// Per computation, the needed computations that read one of its outputs.
    dependents: Vec<Vec<usize>>,
    /// Per computation, how many of its upstream computations have not finished well.
    waiting: Vec<usize>,
    /// Needed computations whose inputs are all available, in plan order.
    ready: VecDeque<usize>,
    /// Running computations and the threads each holds.
    running: BTreeMap<usize, usize>,
    /// Running computations' keys.
    running_keys: BTreeMap<usize, Hash>,
    progress: Progress,
    /// Computations whose broken cache entry was already reported.
    warned_broken: BTreeSet<usize>,
    /// Running computations that wait for another process's claim on their key: whom.
    waiting_for: BTreeMap<usize, crate::store::claim::ClaimHolder>,
    /// The checkpoint cadence handed to each job.
    pub(super) checkpoint_every: u64,
    /// Whether each job echoes its log lines to stderr.
    pub(super) echo_log: bool,
    /// Start every ready computation, whatever the thread budget (the Slurm executor: the
    /// cluster schedules; the budget only sizes each job).
    pub(super) unbounded: bool,
}

impl<'a> Scheduler<'a> {
    /// A scheduler for the computations of `plan` that `need` marks, with `jobs` threads;
    /// draws progress bars on stderr when `show_progress`.
    pub(super) fn new(
        plan: &'a Plan,
        store: &'a Store,
        need: Vec<bool>,
        jobs: usize,
        show_progress: bool,
    ) -> Self {
        let n = plan.comps.len();
        let mut dependents: Vec<Vec<usize>> = vec![Vec::new(); n];
        let mut waiting = vec![0usize; n];
        for (c, comp) in plan.comps.iter().enumerate() {
            if !need[c] {
                continue;
            }
            let mut ups: Vec<usize> = comp
                .inputs
                .iter()
                .flat_map(|s| s.sources.iter())
                .filter_map(|(s, _)| match s {
                    Source::Node { comp, .. } => Some(*comp),
                    _ => None,
                })
                .collect();
            ups.sort_unstable();
            ups.dedup();
            waiting[c] = ups.len();
            for u in ups {
                dependents[u].push(c);
            }
        }
        let ready: VecDeque<usize> = (0..n).filter(|&c| need[c] && waiting[c] == 0).collect();
        let total = need.iter().filter(|x| **x).count() as u64;
        Scheduler {
            plan,
            store,
            need,
            jobs,
            free: jobs,
            results: vec![None; n],
            dependents,
            waiting,
            ready,
            running: BTreeMap::new(),
            running_keys: BTreeMap::new(),
            progress: Progress::new(show_progress, total),
            warned_broken: BTreeSet::new(),
            waiting_for: BTreeMap::new(),
            checkpoint_every: super::DEFAULT_CHECKPOINT_EVERY,
            echo_log: false,
            unbounded: false,
        }
    }

    /// Whether nothing is running (so no message will come).
    pub(super) fn idle(&self) -> bool {
        self.running.is_empty()
    }

    /// Walks the ready queue in plan order: a computation whose key is in the store finishes
    /// as cached (and the walk restarts, its dependents may now be ready); one whose thread
    /// budget fits is handed to `spawn` as a [`Job`]; a `Threads::All` one that does not fit
    /// stops the walk. Errors only when the store fails.
    pub(super) fn start_ready(&mut self, mut spawn: impl FnMut(Job)) -> Result<(), EngineError> {
        let mut i = 0;
        while i < self.ready.len() {
            let c = self.ready[i];
            let (manifests, folders) = self.inputs_of(c)?;
            let key = compute_key(&self.plan.comps[c], &manifests);
            let state = self.store.action_state(&key)?;
            if let EntryState::Broken { reason, .. } = &state {
                if self.warned_broken.insert(c) {
                    let name = self.plan.comps[c].display_name(self.plan);
                    self.progress.multi.suspend(|| {
                        eprintln!(
                            "warning: `{name}`: its cached result (key {}…) is broken: {reason}; recomputing it",
                            &hex(&key)[..16]
                        )
                    });
                }
            }
            if let EntryState::Present(entry) = state {
                self.ready.remove(i);
                let outputs = outputs_of(&entry)?;
                self.finish(
                    c,
                    CompResult {
                        status: Status::Cached,
                        key: Some(key),
                        seconds: 0.0,
                        computed_seconds: entry.seconds,
                        gated: super::run::gated_outputs(self.store, &outputs),
                        outputs,
                        waited: false,
                    },
                );
                self.progress.overall.inc(1);
                i = 0;
                continue;
            }
            let threads = self.plan.comps[c].threads;
            let want = match threads {
                Threads::One => 1,
                Threads::All => self.jobs,
                Threads::Exactly(k) => k.clamp(1, self.jobs),
            };
            if want > self.free && !self.unbounded {
                if threads == Threads::All {
                    break; // reserve the machine for it: start nothing after it
                }
                i += 1;
                continue;
            }
            self.ready.remove(i);
            if !self.unbounded {
                self.free -= want;
            }
            self.running.insert(c, want);
            self.running_keys.insert(c, key);
            spawn(Job {
                comp: c,
                bar: self.progress.node_bar(self.plan, c),
                name: self.plan.comps[c].display_name(self.plan).to_string(),
                key,
                inputs: folders,
                input_hashes: manifests,
                threads: want,
                checkpoint_every: self.checkpoint_every,
                echo_log: self.echo_log,
            });
        }
        Ok(())
    }

    /// Takes a worker's message: frees the computation's threads, reports a failure, records
    /// the result and readies the dependents.
    pub(super) fn on_message(&mut self, msg: Msg) {
        let (c, r) = match msg {
            Msg::Done(c, r) => (c, r),
            Msg::Waiting(c, None) => {
                self.waiting_for.remove(&c);
                return;
            }
            Msg::Waiting(c, Some(holder)) => {
                let name = self.plan.comps[c].display_name(self.plan);
                let line = waiting_line(name, &holder);
                let _ = self.progress.multi.println(&line);
                if self.progress.multi.is_hidden() {
                    eprintln!("{line}");
                }
                self.waiting_for.insert(c, holder);
                return;
            }
        };
        self.waiting_for.remove(&c);
        let held = self.running.remove(&c).unwrap_or(0);
        if !self.unbounded {
            self.free += held;
        }
        self.running_keys.remove(&c);
        self.progress.overall.inc(1);
        if let Status::Failed(m) = &r.status {
            let _ = self.progress.multi.println(format!(
                "failed: {} — {}",
                self.plan.comps[c].display_name(self.plan),
                m.lines().next().unwrap_or("")
            ));
        }
        self.finish(c, r);
    }

    /// Clears the bars and returns every needed computation's result; one never reached (an
    /// ancestor failed) is [`Status::Skipped`].
    pub(super) fn into_results(self) -> Vec<Option<CompResult>> {
        self.progress.overall.finish_and_clear();
        let mut results = self.results;
        for (c, r) in results.iter_mut().enumerate() {
            if self.need[c] && r.is_none() {
                *r = Some(CompResult {
                    status: Status::Skipped,
                    key: None,
                    seconds: 0.0,
                    computed_seconds: 0.0,
                    outputs: BTreeMap::new(),
                    waited: false,
                    gated: None,
                });
            }
        }
        results
    }

    /// Every needed computation's state for the status file; `place` says where a running
    /// (or submitted) one is and whether it is still queued there.
    pub(super) fn node_states(
        &self,
        place: &dyn Fn(usize) -> Option<(String, bool)>,
    ) -> Vec<super::status::NodeState> {
        let mut out = Vec::new();
        for (c, comp) in self.plan.comps.iter().enumerate() {
            if !self.need[c] {
                continue;
            }
            let mut st = super::status::NodeState {
                name: comp.display_name(self.plan).to_string(),
                kind: comp.node.kind().to_string(),
                key: None,
                state: "waiting".into(),
                place: None,
                seconds: None,
                message: None,
            };
            if let Some(r) = &self.results[c] {
                st.key = r.key.as_ref().map(hex);
                st.state = r.status.as_str().into();
                match &r.status {
                    Status::Ran | Status::Cached => {
                        st.seconds = Some(r.computed_seconds);
                        st.message = r.gated.as_ref().map(|g| format!("gated: {g}"));
                    }
                    Status::Failed(m) => st.message = Some(m.clone()),
                    Status::Skipped => {}
                }
            } else if let Some(h) = self.waiting_for.get(&c) {
                st.state = "waiting".into();
                st.key = self.running_keys.get(&c).map(hex);
                st.message = Some(format!(
                    "for {}, which computes the same key (claimed at Unix time {})",
                    h.describe(),
                    h.since_unix
                ));
            } else if self.running.contains_key(&c) {
                st.state = "running".into();
                st.key = self.running_keys.get(&c).map(hex);
                if let Some((p, queued)) = place(c) {
                    if queued {
                        st.state = "queued".into();
                    }
                    st.place = Some(p);
                }
            } else if self.ready.contains(&c) {
                st.state = "ready".into();
            }
            out.push(st);
        }
        out
    }

    /// Computation `c`'s input manifests (for its key) and folders (for its node), per slot.
    #[allow(clippy::type_complexity)]
    fn inputs_of(
        &self,
        c: usize,
    ) -> Result<(Vec<Vec<Hash>>, Vec<(String, Vec<PathBuf>)>), EngineError> {
        let mut ms = Vec::new();
        let mut folders = Vec::new();
        for slot in &self.plan.comps[c].inputs {
            let mut v = Vec::new();
            let mut f = Vec::new();
            for (s, _) in &slot.sources {
                match s {
                    Source::External { path, hash } => {
                        v.push(*hash);
                        f.push(path.clone());
                    }
                    Source::Node { comp: up, output } => {
                        let m = self.results[*up]
                            .as_ref()
                            .and_then(|r| r.outputs.get(output))
                            .copied()
                            .ok_or_else(|| {
                                EngineError::Other(format!(
                                    "internal: output `{output}` of an upstream node is missing"
                                ))
                            })?;
                        v.push(m);
                        f.push(self.store.output_dir(&m));
                    }
                }
            }
            ms.push(v);
            folders.push((slot.name.clone(), f));
        }
        Ok((ms, folders))
    }

    /// Records computation `c`'s result; when it ran or was cached, its dependents wait on
    /// one fewer input, and those that wait on none join the ready queue in plan order.
    fn finish(&mut self, c: usize, r: CompResult) {
        let ok = matches!(r.status, Status::Ran | Status::Cached);
        self.results[c] = Some(r);
        if ok {
            for &d in &self.dependents[c] {
                self.waiting[d] -= 1;
                if self.waiting[d] == 0 && self.need[d] {
                    // Keep the ready queue in plan order (stable, deterministic scheduling).
                    let pos = self
                        .ready
                        .iter()
                        .position(|&x| x > d)
                        .unwrap_or(self.ready.len());
                    self.ready.insert(pos, d);
                }
            }
        }
    }
}
