//! The Slurm executor: this process keeps the graph and submits each ready computation as a
//! Slurm job — the ready instances of one node (the members of a `repeat`, the points of a
//! sweep) as one job array — whose worker computes exactly that key into the shared store.
//!
//! - **Submission.** Only computations whose inputs are in the store become ready (the
//!   scheduler's rule), so nothing is submitted early, and nothing downstream of a failure is
//!   submitted at all. Each submission writes `runs/slurm/<run>/<n>.keys` (one `KEY THREADS`
//!   line per array task) and `<n>.sh`, and calls `sbatch --parsable` with the run's job name
//!   `augsplat-<run>`, the node's [`Resources`] (from the pipeline's `resources:` block,
//!   never part of a key) and the user's pass-through options.
//! - **Polling.** One `squeue --name=augsplat-<run>` call per poll for all the run's jobs, with
//!   exponential back-off (0.5 s growing to [`SlurmOptions::poll_max`], back to 0.5 s when
//!   something changes). `sacct` is asked only when the cluster keeps accounting, and only about
//!   jobs `squeue` no longer lists.
//! - **Success is the store's word.** A job has succeeded when its key's action entry (written
//!   last, atomically) is visible. A job that ended without one is waited for within
//!   [`SlurmOptions::visibility_wait`] (a shared filesystem may show it late), then reported
//!   failed with its Slurm state, its output file's tail and the node's log; its claim is
//!   broken so a rerun does not wait for it.
//! - **Preemption.** A requeued job (`scontrol requeue`, or preemption with `--requeue`) stays
//!   in `squeue` and is simply waited for; its rerun resumes from the node's checkpoint.
//!
//! The executor is three short steps under the run's driver loop, which keeps the graph:
//! `submit` groups the ready jobs into one submission per node and calls `sbatch`; `poll`
//! lists the run's jobs; `settle` asks the store about each job that ended (`outcome`).

use super::driver::Executor;
use super::run::{gated_outputs, outputs_of, Job};
use super::schedule::Msg;
use super::{CompResult, RunOptions, Status};
use crate::error::EngineError;
use crate::node::Threads;
use crate::resolve::{Plan, Resources};
use crate::store::claim::break_claim_of_job;
use crate::store::{hex, Hash, Store};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// How to run on Slurm.
#[derive(Clone, Debug)]
pub struct SlurmOptions {
    /// The worker's command line (program, then arguments); each job appends
    /// `--keys-file FILE --index N` and runs it on a compute node, where it computes line `N`'s
    /// key into the store. The CLI passes its own hidden subcommand.
    pub worker: Vec<String>,
    /// Options given to every `sbatch` (e.g. `--partition=gpu`), after the resources'.
    pub sbatch_opts: Vec<String>,
    /// Submit with `--requeue` (a preempted job is requeued and resumes from its checkpoint);
    /// else `--no-requeue`.
    pub requeue: bool,
    /// The longest pause between two polls.
    pub poll_max: Duration,
    /// How long a job that ended is waited for to show its entry in the store.
    pub visibility_wait: Duration,
}

impl Default for SlurmOptions {
    fn default() -> Self {
        SlurmOptions {
            worker: Vec::new(),
            sbatch_opts: Vec::new(),
            requeue: false,
            poll_max: Duration::from_secs(30),
            visibility_wait: Duration::from_secs(120),
        }
    }
}

/// Slurm job states in which a job may still produce its entry.
const LIVE_STATES: &[&str] = &[
    "PENDING",
    "CONFIGURING",
    "RUNNING",
    "COMPLETING",
    "SUSPENDED",
    "REQUEUED",
    "REQUEUE_FED",
    "REQUEUE_HOLD",
    "RESIZING",
    "SIGNALING",
    "STAGE_OUT",
    "STOPPED",
    "RESV_DEL_HOLD",
];

/// The most tasks in one job array.
const MAX_ARRAY: usize = 1000;

/// One submitted computation.
struct Submitted {
    /// The Slurm job id (`123`, or `123_4` for an array task).
    job: String,
    /// Its `.out` file.
    out_file: PathBuf,
    /// Last state seen, and the node.
    state: String,
    node: String,
    /// When it was first seen ended without an entry.
    ended_at: Option<Instant>,
    /// The key.
    key: Hash,
    /// Its spinner, when bars are drawn (cleared when it ends).
    bar: Option<indicatif::ProgressBar>,
}

impl Submitted {
    /// Job `job`, just submitted as Slurm job `jid` writing to `out_file`.
    fn new(job: Job, jid: String, out_file: PathBuf) -> Self {
        Submitted {
            job: jid,
            out_file,
            state: "PENDING".into(),
            node: String::new(),
            ended_at: None,
            key: job.key,
            bar: job.bar,
        }
    }

    /// Records what `squeue` or `sacct` says of the job (its state, and its node when named);
    /// returns whether that changed, and whether the job may still produce its entry.
    fn observe(&mut self, seen: Option<&(String, String)>) -> (bool, bool) {
        let Some((st, node)) = seen else {
            return (false, false);
        };
        let changed = *st != self.state || (!node.is_empty() && *node != self.node);
        self.state = st.clone();
        if !node.is_empty() {
            self.node = node.clone();
        }
        if let Some(b) = &self.bar {
            b.set_message(format!("Slurm job {} {st}", self.job));
        }
        let live = LIVE_STATES.contains(&st.as_str());
        if live {
            self.ended_at = None;
        }
        (changed, live)
    }

    /// Where it runs, for the status file, and whether it is still queued.
    fn place(&self) -> (String, bool) {
        let queued = self.state == "PENDING" || self.state == "REQUEUED";
        let at = if self.node.is_empty() || queued {
            format!(" ({})", self.state)
        } else {
            format!(" on {}", self.node)
        };
        (format!("Slurm job {}{at}", self.job), queued)
    }
}

/// `squeue`'s view of the run's jobs: job id → (state, node list).
type Listing = BTreeMap<String, (String, String)>;

/// The pause after a poll that found something changed.
const SHORT_PAUSE: Duration = Duration::from_millis(500);

/// The Slurm executor over one run (see the module documentation).
pub(super) struct Slurm<'a> {
    plan: &'a Plan,
    store: &'a Store,
    slurm: &'a SlurmOptions,
    /// The run's thread budget (`--jobs`): the cores of a job whose node uses all it is given.
    jobs: usize,
    /// `runs/slurm/<run>/`: each submission's keys file, script and output files.
    run_dir: PathBuf,
    /// `augsplat-<run>`: the name of every job of the run.
    job_name: String,
    /// Whether the cluster keeps accounting (so `sacct` can answer).
    accounting: bool,
    /// The submitted computations that have not settled, by computation.
    submitted: BTreeMap<usize, Submitted>,
    /// Submissions so far (each one's files are numbered).
    submissions: usize,
    /// The pause before the next poll: [`SHORT_PAUSE`], growing while nothing changes.
    pause: Duration,
    /// Whether something changed in this step (a submission, a job's state or node, a job
    /// settled): the next pause is short again.
    changed: bool,
}

impl<'a> Slurm<'a> {
    /// The executor of run `run_id`: checks that there is a worker command and makes the
    /// run's folder.
    pub(super) fn new(
        plan: &'a Plan,
        store: &'a Store,
        opts: &RunOptions,
        slurm: &'a SlurmOptions,
        run_id: &str,
    ) -> Result<Self, EngineError> {
        if slurm.worker.is_empty() {
            return Err(EngineError::Other(
                "the Slurm executor needs a worker command".into(),
            ));
        }
        let run_dir = store.root().join("runs").join("slurm").join(run_id);
        std::fs::create_dir_all(&run_dir).map_err(crate::error::io("creating", &run_dir))?;
        Ok(Slurm {
            plan,
            store,
            slurm,
            jobs: opts.jobs.max(1),
            run_dir,
            job_name: format!("augsplat-{run_id}"),
            accounting: accounting_enabled(),
            submitted: BTreeMap::new(),
            submissions: 0,
            pause: SHORT_PAUSE,
            changed: false,
        })
    }

    /// Settles each submitted job that is no longer live, given `squeue`'s `listing` and the
    /// final states `sacct` knows (see [`outcome`]); returns their results.
    fn settle(
        &mut self,
        listing: &Listing,
        finals: &BTreeMap<String, String>,
    ) -> Result<Vec<Msg>, EngineError> {
        let mut done = Vec::new();
        for (&c, s) in self.submitted.iter_mut() {
            let seen = listing
                .get(&s.job)
                .cloned()
                .or_else(|| finals.get(&s.job).map(|st| (st.clone(), String::new())));
            let (changed, live) = s.observe(seen.as_ref());
            self.changed |= changed;
            if live {
                continue;
            }
            if let Some(r) = outcome(self.store, self.slurm, s, seen)? {
                done.push((c, r));
            }
        }
        let mut msgs = Vec::new();
        for (c, r) in done {
            if let Some(b) = self.submitted.remove(&c).and_then(|s| s.bar) {
                b.finish_and_clear();
            }
            self.changed = true;
            msgs.push(Msg::Done(c, r));
        }
        Ok(msgs)
    }

    /// The pause after this one when nothing changed: 1.6 times as long, up to
    /// [`SlurmOptions::poll_max`].
    fn longer_pause(&self) -> Duration {
        self.pause.mul_f64(1.6).min(self.slurm.poll_max)
    }

    /// The final states of the submitted jobs that `listing` no longer shows, when the
    /// cluster keeps accounting (one `sacct` call).
    fn final_states(&self, listing: &Listing) -> BTreeMap<String, String> {
        let gone: Vec<String> = self
            .submitted
            .values()
            .filter(|s| !listing.contains_key(&s.job))
            .map(|s| s.job.clone())
            .collect();
        if self.accounting && !gone.is_empty() {
            sacct_states(&gone)
        } else {
            BTreeMap::new()
        }
    }

    /// Submits `jobs` (one node's ready computations) as one job, or one array; returns each
    /// one's job id and output file, or why `sbatch` refused.
    fn sbatch(&self, id: usize, jobs: &[Job]) -> Result<Vec<(String, PathBuf)>, String> {
        let res = self
            .plan
            .resources_of(jobs[0].comp)
            .cloned()
            .unwrap_or_default();
        let cpus = match (res.cpus, self.plan.comps[jobs[0].comp].threads) {
            (Some(c), _) => c as usize,
            (None, Threads::One) => 1,
            (None, Threads::Exactly(k)) => k,
            (None, Threads::All) => self.jobs,
        };
        let script = self.write_job_files(id, jobs, cpus)?;
        let array = jobs.len() > 1;
        let args = self.sbatch_args(id, jobs.len(), cpus, &res, &script);
        let jid = run_sbatch(&args)?;
        Ok((0..jobs.len())
            .map(|i| {
                if array {
                    (
                        format!("{jid}_{i}"),
                        self.run_dir.join(format!("{id}_{i}.out")),
                    )
                } else {
                    (jid.clone(), self.run_dir.join(format!("{id}.out")))
                }
            })
            .collect())
    }

    /// Writes submission `id`'s keys file (one `KEY THREADS` line per array task) and its
    /// script, which runs the worker on the task's line; returns the script's path.
    fn write_job_files(&self, id: usize, jobs: &[Job], cpus: usize) -> Result<PathBuf, String> {
        let first = &self.plan.comps[jobs[0].comp];
        let keys_file = self.run_dir.join(format!("{id}.keys"));
        let lines: String = jobs
            .iter()
            .map(|j| format!("{} {cpus}\n", hex(&j.key)))
            .collect();
        std::fs::write(&keys_file, lines)
            .map_err(|e| format!("writing {}: {e}", keys_file.display()))?;
        let mut cmd_line: Vec<String> = self.slurm.worker.iter().map(|a| sh_quote(a)).collect();
        cmd_line.push("--keys-file".into());
        cmd_line.push(sh_quote(&keys_file.display().to_string()));
        cmd_line.push("--index".into());
        cmd_line.push("\"${SLURM_ARRAY_TASK_ID:-0}\"".into());
        let script = self.run_dir.join(format!("{id}.sh"));
        let text = format!(
            "#!/bin/sh\n# augsplat: {} ({}), {} computation(s)\nexec {}\n",
            first.display_name(self.plan),
            first.node.kind(),
            jobs.len(),
            cmd_line.join(" ")
        );
        std::fs::write(&script, text).map_err(|e| format!("writing {}: {e}", script.display()))?;
        Ok(script)
    }

    /// The `sbatch` arguments of submission `id` of `tasks` computations: the run's job name,
    /// the output file, the cores, requeueing, the array, the node's resources, the user's
    /// options, then the script.
    fn sbatch_args(
        &self,
        id: usize,
        tasks: usize,
        cpus: usize,
        res: &Resources,
        script: &Path,
    ) -> Vec<String> {
        let array = tasks > 1;
        let out_pattern = self.run_dir.join(if array {
            format!("{id}_%a.out")
        } else {
            format!("{id}.out")
        });
        let mut args: Vec<String> = vec![
            "--parsable".into(),
            format!("--job-name={}", self.job_name),
            format!("--output={}", out_pattern.display()),
            format!("--cpus-per-task={cpus}"),
            "--ntasks=1".into(),
            // A requeued job appends to its output instead of truncating the first attempt's.
            "--open-mode=append".into(),
            if self.slurm.requeue {
                "--requeue".into()
            } else {
                "--no-requeue".into()
            },
        ];
        if array {
            args.push(format!("--array=0-{}", tasks - 1));
        }
        if let Some(m) = &res.mem {
            args.push(format!("--mem={m}"));
        }
        if let Some(t) = &res.time {
            args.push(format!("--time={t}"));
        }
        if let Some(g) = res.gpus {
            args.push(format!("--gpus={g}"));
        }
        if let Some(p) = &res.partition {
            args.push(format!("--partition={p}"));
        }
        args.extend(res.sbatch.iter().cloned());
        args.extend(self.slurm.sbatch_opts.iter().cloned());
        args.push(script.display().to_string());
        args
    }
}

impl Executor for Slurm<'_> {
    fn unbounded(&self) -> bool {
        true
    }

    fn eager_status(&self) -> bool {
        false
    }

    /// One submission per node (an array of its ready instances), in plan order; a refused
    /// submission fails its jobs at once.
    fn submit(&mut self, jobs: Vec<Job>) -> Vec<Msg> {
        self.changed = !jobs.is_empty();
        let mut refused = Vec::new();
        for batch in batches(self.plan, jobs) {
            let id = self.submissions;
            self.submissions += 1;
            match self.sbatch(id, &batch) {
                Ok(ids) => {
                    for (job, (jid, out_file)) in batch.into_iter().zip(ids) {
                        self.submitted
                            .insert(job.comp, Submitted::new(job, jid, out_file));
                    }
                }
                Err(m) => {
                    for job in batch {
                        if let Some(b) = &job.bar {
                            b.finish_and_clear();
                        }
                        refused.push(Msg::Done(job.comp, failed(job.key, m.clone())));
                    }
                }
            }
        }
        refused
    }

    /// Sleeps the current pause, lists the run's jobs (one `squeue` call; `sacct` for those it
    /// no longer lists) and settles those that ended; the pause is short again after a
    /// change, else grows. A failed `squeue` is a warning, and the next poll waits longer.
    fn poll(&mut self) -> Result<Vec<Msg>, EngineError> {
        std::thread::sleep(self.pause);
        let listing = match squeue(&self.job_name) {
            Ok(l) => l,
            Err(m) => {
                eprintln!("warning: {m}; polling again");
                self.pause = self.longer_pause();
                return Ok(Vec::new());
            }
        };
        let finals = self.final_states(&listing);
        let done = self.settle(&listing, &finals)?;
        self.pause = if self.changed {
            SHORT_PAUSE
        } else {
            self.longer_pause()
        };
        Ok(done)
    }

    fn place(&self, c: usize) -> Option<(String, bool)> {
        self.submitted.get(&c).map(Submitted::place)
    }
}

/// The ready jobs as submissions: one per node (by its name and kind), in order of first
/// appearance; Slurm's default `MaxArraySize` is 1001, so a larger node goes as several
/// arrays of at most [`MAX_ARRAY`].
fn batches(plan: &Plan, ready: Vec<Job>) -> Vec<Vec<Job>> {
    let mut groups: BTreeMap<String, Vec<Job>> = BTreeMap::new();
    let mut order = Vec::new();
    for job in ready {
        let comp = &plan.comps[job.comp];
        let base = comp
            .instances
            .first()
            .map(|&i| plan.instances[i].base.clone())
            .unwrap_or_default();
        let g = format!("{base}/{}", comp.node.kind());
        if !groups.contains_key(&g) {
            order.push(g.clone());
        }
        groups.entry(g).or_default().push(job);
    }
    order
        .iter()
        .flat_map(|g| {
            let mut jobs = groups.remove(g).unwrap_or_default();
            let mut out = Vec::new();
            while jobs.len() > MAX_ARRAY {
                let rest = jobs.split_off(MAX_ARRAY);
                out.push(std::mem::replace(&mut jobs, rest));
            }
            out.push(jobs);
            out
        })
        .collect()
}

/// What became of submitted job `s`, which Slurm no longer lists as live (`seen`: its last
/// state, if Slurm still knows it). Success is the store's word: its key's entry is visible.
/// Without one it is waited for (a shared filesystem may show the entry late: up to
/// [`SlurmOptions::visibility_wait`] after a job that completed or vanished, 5 s at most after
/// one that Slurm says failed), then it fails with its state, its output's tail and the
/// node's log, and its claim is broken so that a rerun does not wait for it. `None`: still
/// waited for.
fn outcome(
    store: &Store,
    slurm: &SlurmOptions,
    s: &mut Submitted,
    seen: Option<(String, String)>,
) -> Result<Option<CompResult>, EngineError> {
    if let Some(entry) = store.action(&s.key)? {
        let outputs = outputs_of(&entry)?;
        return Ok(Some(CompResult {
            status: Status::Ran,
            key: Some(s.key),
            seconds: entry.seconds,
            computed_seconds: entry.seconds,
            gated: gated_outputs(store, &outputs),
            outputs,
            waited: false,
        }));
    }
    let ended = *s.ended_at.get_or_insert_with(Instant::now);
    let completed = seen.as_ref().is_none_or(|(st, _)| st == "COMPLETED");
    let bound = if completed {
        slurm.visibility_wait
    } else {
        slurm.visibility_wait.min(Duration::from_secs(5))
    };
    if ended.elapsed() < bound {
        return Ok(None);
    }
    break_claim_of_job(&store.claim_path(&s.key), &s.job);
    let state = seen.map(|(st, _)| st).unwrap_or_else(|| "ended".into());
    Ok(Some(failed(s.key, job_failure(store, s, &state))))
}

/// The result of a job that failed with message `m`.
fn failed(key: Hash, m: String) -> CompResult {
    CompResult {
        status: Status::Failed(m),
        key: Some(key),
        seconds: 0.0,
        computed_seconds: 0.0,
        outputs: BTreeMap::new(),
        waited: false,
        gated: None,
    }
}

/// Why a job that ended without an entry failed: its state, the tail of its output file and
/// the node's failure log when it wrote one.
fn job_failure(store: &Store, s: &Submitted, state: &str) -> String {
    let mut m = format!(
        "Slurm job {} ended {state} without storing its result",
        s.job
    );
    let failed_log = store
        .root()
        .join("runs")
        .join(format!("failed-{}.log", hex(&s.key)));
    if let Ok(t) = std::fs::read_to_string(&failed_log) {
        m.push_str(&format!(": {}", t.lines().next().unwrap_or("")));
    }
    if let Ok(t) = std::fs::read_to_string(&s.out_file) {
        let lines: Vec<&str> = t.lines().collect();
        let tail = &lines[lines.len().saturating_sub(15)..];
        if !tail.is_empty() {
            m.push_str(&format!(
                "\n  last lines of {}:\n    {}",
                s.out_file.display(),
                tail.join("\n    ")
            ));
        }
    }
    m
}

/// Quotes `s` for a POSIX shell.
fn sh_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

/// Runs `sbatch` with `args`; returns the job id it printed, or why it refused.
fn run_sbatch(args: &[String]) -> Result<String, String> {
    let out = Command::new("sbatch")
        .args(args)
        .output()
        .map_err(|e| format!("running sbatch: {e} (is Slurm installed here?)"))?;
    if !out.status.success() {
        return Err(format!(
            "sbatch {} refused the job: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    // `--parsable` prints `JOBID` or `JOBID;CLUSTER`.
    let text = String::from_utf8_lossy(&out.stdout);
    text.trim()
        .split(';')
        .next()
        .filter(|s| !s.is_empty() && s.chars().all(|c| c.is_ascii_digit()))
        .map(str::to_string)
        .ok_or_else(|| format!("sbatch printed no job id: {text:?}"))
}

/// One `squeue` call for all the run's jobs (array tasks one per line).
fn squeue(job_name: &str) -> Result<Listing, String> {
    let out = Command::new("squeue")
        .args([
            "--noheader",
            "--array",
            "--states=all",
            &format!("--name={job_name}"),
            "--format=%i|%T|%N",
        ])
        .output()
        .map_err(|e| format!("running squeue: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "squeue failed: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    Ok(parse_squeue(&String::from_utf8_lossy(&out.stdout)))
}

/// Parses `squeue --format=%i|%T|%N` lines.
fn parse_squeue(text: &str) -> Listing {
    text.lines()
        .filter_map(|l| {
            let mut p = l.trim().split('|');
            let id = p.next()?.trim();
            let st = p.next()?.trim();
            let node = p.next().unwrap_or("").trim();
            (!id.is_empty()).then(|| (id.to_string(), (st.to_string(), node.to_string())))
        })
        .collect()
}

/// Whether the cluster keeps job accounting (so `sacct` can answer).
fn accounting_enabled() -> bool {
    let Ok(out) = Command::new("scontrol").args(["show", "config"]).output() else {
        return false;
    };
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .find(|l| l.trim_start().starts_with("AccountingStorageType"))
        .is_some_and(|l| !l.contains("accounting_storage/none"))
}

/// The final states `sacct` knows for `jobs` (one call).
fn sacct_states(jobs: &[String]) -> BTreeMap<String, String> {
    let Ok(out) = Command::new("sacct")
        .args([
            "--noheader",
            "--parsable2",
            "--format=JobID,State",
            &format!("--jobs={}", jobs.join(",")),
        ])
        .output()
    else {
        return BTreeMap::new();
    };
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let (id, st) = l.split_once('|')?;
            // "CANCELLED by 0" → "CANCELLED".
            let st = st.split_whitespace().next()?;
            Some((id.to_string(), st.to_string()))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn squeue_lines_parse() {
        let l = parse_squeue("12_0|RUNNING|n1\n12_1|PENDING|\n13|COMPLETED|n2\n\n");
        assert_eq!(l["12_0"], ("RUNNING".into(), "n1".into()));
        assert_eq!(l["12_1"], ("PENDING".into(), String::new()));
        assert_eq!(l["13"].0, "COMPLETED");
        assert_eq!(l.len(), 3);
    }

    #[test]
    fn shell_quoting_survives_quotes() {
        assert_eq!(sh_quote("a b"), "'a b'");
        assert_eq!(sh_quote("it's"), "'it'\\''s'");
    }
}
