//! The Slurm executor: this process keeps the graph and submits each ready computation as a
//! Slurm job — the ready instances of one node (the members of a `repeat`, the points of a
//! sweep) as one job array — whose worker computes exactly that key into the shared store.
//!
//! - **Submission.** Only computations whose inputs are in the store become ready (the
//!   scheduler's rule), so nothing is submitted early, and nothing downstream of a failure is
//!   submitted at all. Each submission writes `runs/slurm/<run>/<n>.keys` (one `KEY THREADS`
//!   line per array task) and `<n>.sh`, and calls `sbatch --parsable` with the run's job name
//!   `augsplat-<run>`, the node's [`Resources`](crate::resolve::Resources) (from the
//!   pipeline's `resources:` block, never part of a key) and the user's pass-through options.
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

use super::schedule::Scheduler;
use super::status::StatusWriter;
use super::{CompResult, RunOptions, Status};
use crate::error::EngineError;
use crate::node::Threads;
use crate::resolve::Plan;
use crate::store::{hex, Store};
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
    key: crate::store::Hash,
    /// Its spinner, when bars are drawn (cleared when it ends).
    bar: Option<indicatif::ProgressBar>,
}

/// `squeue`'s view of the run's jobs: job id → (state, node list).
type Listing = BTreeMap<String, (String, String)>;

/// Runs the needed computations of `plan` as Slurm jobs (see the module documentation).
pub(super) fn run(
    plan: &Plan,
    store: &Store,
    opts: &RunOptions,
    slurm: &SlurmOptions,
    need: Vec<bool>,
    status: &mut StatusWriter<'_>,
) -> Result<Vec<Option<CompResult>>, EngineError> {
    if slurm.worker.is_empty() {
        return Err(EngineError::Other(
            "the Slurm executor needs a worker command".into(),
        ));
    }
    // Every ready computation is submitted at once: the cluster does the scheduling, and the
    // thread budget (`--jobs`) only sizes each job.
    let mut sched = Scheduler::new(plan, store, need, opts.jobs.max(1), opts.progress);
    sched.checkpoint_every = opts.checkpoint_every;
    sched.unbounded = true;
    let run_dir = store
        .root()
        .join("runs")
        .join("slurm")
        .join(status.run_id());
    std::fs::create_dir_all(&run_dir).map_err(crate::error::io("creating", &run_dir))?;
    let job_name = format!("augsplat-{}", status.run_id());
    let accounting = accounting_enabled();
    let mut submitted: BTreeMap<usize, Submitted> = BTreeMap::new();
    let mut n_submissions = 0usize;
    let mut pause = Duration::from_millis(500);
    loop {
        let mut ready = Vec::new();
        sched.start_ready(|job| ready.push(job))?;
        // One submission per node name (array for several instances), in plan order.
        let mut groups: BTreeMap<String, Vec<super::run::Job>> = BTreeMap::new();
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
        let mut changed = !order.is_empty();
        // Slurm's default `MaxArraySize` is 1001: larger groups go as several arrays.
        let batches: Vec<Vec<super::run::Job>> = order
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
            .collect();
        for jobs in batches {
            let id = n_submissions;
            n_submissions += 1;
            match submit(plan, slurm, opts, &run_dir, &job_name, id, &jobs) {
                Ok(ids) => {
                    for (job, (jid, out_file)) in jobs.iter().zip(ids) {
                        submitted.insert(
                            job.comp,
                            Submitted {
                                job: jid,
                                out_file,
                                state: "PENDING".into(),
                                node: String::new(),
                                ended_at: None,
                                key: job.key,
                                bar: job.bar.clone(),
                            },
                        );
                    }
                }
                Err(m) => {
                    for job in &jobs {
                        if let Some(b) = &job.bar {
                            b.finish_and_clear();
                        }
                        sched.on_message(super::schedule::Msg::Done(
                            job.comp,
                            failed(job.key, m.clone()),
                        ));
                    }
                }
            }
        }
        let place = |c: usize| {
            submitted.get(&c).map(|s| {
                let queued = s.state == "PENDING" || s.state == "REQUEUED";
                let at = if s.node.is_empty() || queued {
                    format!(" ({})", s.state)
                } else {
                    format!(" on {}", s.node)
                };
                (format!("Slurm job {}{at}", s.job), queued)
            })
        };
        status.update(sched.node_states(&place), changed);
        if sched.idle() {
            break;
        }
        std::thread::sleep(pause);
        let listing = match squeue(&job_name) {
            Ok(l) => l,
            Err(m) => {
                eprintln!("warning: {m}; polling again");
                pause = (pause.mul_f64(1.6)).min(slurm.poll_max);
                continue;
            }
        };
        let gone: Vec<String> = submitted
            .values()
            .filter(|s| !listing.contains_key(&s.job))
            .map(|s| s.job.clone())
            .collect();
        let final_states = if accounting && !gone.is_empty() {
            sacct_states(&gone)
        } else {
            BTreeMap::new()
        };
        let mut done = Vec::new();
        for (&c, s) in submitted.iter_mut() {
            let seen = listing
                .get(&s.job)
                .map(|(st, node)| (st.clone(), node.clone()))
                .or_else(|| {
                    final_states
                        .get(&s.job)
                        .map(|st| (st.clone(), String::new()))
                });
            if let Some((st, node)) = &seen {
                if *st != s.state || (!node.is_empty() && *node != s.node) {
                    changed = true;
                }
                s.state = st.clone();
                if !node.is_empty() {
                    s.node = node.clone();
                }
                if let Some(b) = &s.bar {
                    b.set_message(format!("Slurm job {} {st}", s.job));
                }
                if LIVE_STATES.contains(&st.as_str()) {
                    s.ended_at = None;
                    continue;
                }
            }
            // Ended (or no longer listed): the store says whether it succeeded.
            if let Some(entry) = store.action(&s.key)? {
                let outputs = super::run::outputs_of(&entry)?;
                done.push((
                    c,
                    CompResult {
                        status: Status::Ran,
                        key: Some(s.key),
                        seconds: entry.seconds,
                        computed_seconds: entry.seconds,
                        gated: super::run::gated_outputs(store, &outputs),
                        outputs,
                        waited: false,
                    },
                ));
                continue;
            }
            let ended = *s.ended_at.get_or_insert_with(Instant::now);
            // A job that Slurm says failed is not waited for long; one that completed (or
            // vanished) may still be on its way through the shared filesystem.
            let completed = seen.as_ref().is_none_or(|(st, _)| st == "COMPLETED");
            let bound = if completed {
                slurm.visibility_wait
            } else {
                slurm.visibility_wait.min(Duration::from_secs(5))
            };
            if ended.elapsed() >= bound {
                crate::store::claim::break_claim_of_job(&store.claim_path(&s.key), &s.job);
                let state = seen.map(|(st, _)| st).unwrap_or_else(|| "ended".into());
                done.push((c, failed(s.key, job_failure(store, s, &state))));
            }
        }
        for (c, r) in done {
            if let Some(b) = submitted.remove(&c).and_then(|s| s.bar) {
                b.finish_and_clear();
            }
            changed = true;
            sched.on_message(super::schedule::Msg::Done(c, r));
        }
        pause = if changed {
            Duration::from_millis(500)
        } else {
            (pause.mul_f64(1.6)).min(slurm.poll_max)
        };
    }
    let results = sched.into_results();
    status.finish(super::status::states_of_results(plan, &results));
    Ok(results)
}

fn failed(key: crate::store::Hash, m: String) -> CompResult {
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

/// Submits `jobs` (one node's ready computations) as one job, or one array; returns each one's
/// job id and output file, or why `sbatch` refused.
fn submit(
    plan: &Plan,
    slurm: &SlurmOptions,
    opts: &RunOptions,
    run_dir: &Path,
    job_name: &str,
    id: usize,
    jobs: &[super::run::Job],
) -> Result<Vec<(String, PathBuf)>, String> {
    let first = &plan.comps[jobs[0].comp];
    let res = plan.resources_of(jobs[0].comp).cloned().unwrap_or_default();
    let cpus = res.cpus.map(|c| c as usize).unwrap_or(match first.threads {
        Threads::One => 1,
        Threads::Exactly(k) => k,
        Threads::All => opts.jobs.max(1),
    });
    let keys_file = run_dir.join(format!("{id}.keys"));
    let lines: String = jobs
        .iter()
        .map(|j| format!("{} {cpus}\n", hex(&j.key)))
        .collect();
    std::fs::write(&keys_file, lines)
        .map_err(|e| format!("writing {}: {e}", keys_file.display()))?;
    let mut cmd_line: Vec<String> = slurm.worker.iter().map(|a| sh_quote(a)).collect();
    cmd_line.push("--keys-file".into());
    cmd_line.push(sh_quote(&keys_file.display().to_string()));
    cmd_line.push("--index".into());
    cmd_line.push("\"${SLURM_ARRAY_TASK_ID:-0}\"".into());
    let script = run_dir.join(format!("{id}.sh"));
    let text = format!(
        "#!/bin/sh\n# augsplat: {} ({}), {} computation(s)\nexec {}\n",
        first.display_name(plan),
        first.node.kind(),
        jobs.len(),
        cmd_line.join(" ")
    );
    std::fs::write(&script, text).map_err(|e| format!("writing {}: {e}", script.display()))?;
    let array = jobs.len() > 1;
    let out_pattern = run_dir.join(if array {
        format!("{id}_%a.out")
    } else {
        format!("{id}.out")
    });
    let mut args: Vec<String> = vec![
        "--parsable".into(),
        format!("--job-name={job_name}"),
        format!("--output={}", out_pattern.display()),
        format!("--cpus-per-task={cpus}"),
        "--ntasks=1".into(),
        // A requeued job appends to its output instead of truncating the first attempt's.
        "--open-mode=append".into(),
        if slurm.requeue {
            "--requeue".into()
        } else {
            "--no-requeue".into()
        },
    ];
    if array {
        args.push(format!("--array=0-{}", jobs.len() - 1));
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
    args.extend(slurm.sbatch_opts.iter().cloned());
    args.push(script.display().to_string());
    let out = Command::new("sbatch")
        .args(&args)
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
    let jid = text
        .trim()
        .split(';')
        .next()
        .filter(|s| !s.is_empty() && s.chars().all(|c| c.is_ascii_digit()))
        .ok_or_else(|| format!("sbatch printed no job id: {text:?}"))?
        .to_string();
    Ok((0..jobs.len())
        .map(|i| {
            if array {
                (format!("{jid}_{i}"), run_dir.join(format!("{id}_{i}.out")))
            } else {
                (jid.clone(), run_dir.join(format!("{id}.out")))
            }
        })
        .collect())
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
