//! Running one computation: claim its key, look in the store again, run the node in a scratch
//! folder inside a rayon pool of its thread budget, promote its outputs, and write its action
//! entry last (by atomic rename), so a node that fails, panics or is killed leaves no entry.

use super::{CompResult, Status};
use crate::error::EngineError;
use crate::node::{NodeError, ProgressSink, RunContext};
use crate::resolve::{Comp, Plan};
use crate::snapshot::{changed_input, input_snapshot, InputSnapshot};
use crate::store::{
    hex, hostname, now_unix, remove_tree, unhex, ActionEntry, Hash, Store, STORE_FORMAT,
};
use indicatif::ProgressBar;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Collects a running node's log and drives its progress bar.
struct NodeSink {
    lines: Mutex<Vec<String>>,
    bar: Option<ProgressBar>,
    /// With `--log`: the node's name and start, to echo each line to stderr.
    echo: Option<(String, Instant)>,
}

impl ProgressSink for NodeSink {
    fn progress(&self, done: u64, total: u64, message: &str) {
        if let Some(b) = &self.bar {
            b.set_length(total);
            b.set_position(done);
            if !message.is_empty() {
                b.set_message(message.to_string());
            }
        }
    }
    fn log(&self, line: &str) {
        if let Some((name, start)) = &self.echo {
            let line = format!("[{name} {:.1} s] {line}", start.elapsed().as_secs_f64());
            match &self.bar {
                Some(b) => b.println(line),
                None => eprintln!("{line}"),
            }
        }
        if let Ok(mut l) = self.lines.lock() {
            l.push(line.to_string());
        }
        if let Some(b) = &self.bar {
            b.set_message(line.chars().take(60).collect::<String>());
        }
    }
}

/// The output manifests named by a cache entry.
pub(super) fn outputs_of(entry: &ActionEntry) -> Result<BTreeMap<String, Hash>, EngineError> {
    entry
        .outputs
        .iter()
        .map(|(k, v)| {
            unhex(v).map(|h| (k.clone(), h)).ok_or_else(|| {
                EngineError::Other(format!("action {} has a bad manifest hash", entry.key))
            })
        })
        .collect()
}

/// A computation ready to run: everything a worker thread needs.
pub(super) struct Job {
    /// Index into [`Plan::comps`].
    pub(super) comp: usize,
    /// Its display name (the first instance's).
    pub(super) name: String,
    /// Its key.
    pub(super) key: Hash,
    /// Its input folders, per input name.
    pub(super) inputs: Vec<(String, Vec<PathBuf>)>,
    /// The content hash of each input folder (output manifest or external input hash), in
    /// the order of `inputs`: what its key was computed with, checked before the node runs
    /// and recorded in its entry.
    pub(super) input_hashes: Vec<Vec<Hash>>,
    /// Its thread budget (the size of its rayon pool).
    pub(super) threads: usize,
    /// Its progress bar, when bars are drawn.
    pub(super) bar: Option<ProgressBar>,
    /// Checkpoint every this many steps (0: never).
    pub(super) checkpoint_every: u64,
    /// Echo the node's log lines to stderr as they arrive.
    pub(super) echo_log: bool,
}

impl Job {
    /// Runs the computation (on a worker thread) and clears its progress bar.
    pub(super) fn run(
        self,
        plan: &Plan,
        store: &Store,
        on_wait: &dyn Fn(Option<&crate::store::claim::ClaimHolder>),
    ) -> CompResult {
        let bar = self.bar.clone();
        let r = run_one(plan, store, self, on_wait);
        if let Some(b) = bar {
            b.finish_and_clear();
        }
        r
    }
}

/// The reason a stored computation was gated (its outputs hold the marker), if it was.
pub(super) fn gated_outputs(store: &Store, outputs: &BTreeMap<String, Hash>) -> Option<String> {
    outputs
        .values()
        .next()
        .and_then(|m| crate::gate::gated_reason(&store.output_dir(m)))
}

/// Claims the job's key, finds it cached if another process finished it meanwhile, and
/// otherwise runs it in a fresh scratch folder (removed afterwards).
fn run_one(
    plan: &Plan,
    store: &Store,
    job: Job,
    on_wait: &dyn Fn(Option<&crate::store::claim::ClaimHolder>),
) -> CompResult {
    let key = job.key;
    let fail = |m: String, secs: f64| CompResult {
        status: Status::Failed(m),
        key: Some(key),
        seconds: secs,
        computed_seconds: secs,
        outputs: BTreeMap::new(),
        waited: false,
        gated: None,
    };
    let claim = match store.claim_reporting(&key, on_wait) {
        Ok(c) => c,
        Err(e) => return fail(e.to_string(), 0.0),
    };
    // Another process may have finished it while we waited for the claim.
    match store.action(&key) {
        Ok(Some(entry)) => {
            return match outputs_of(&entry) {
                Ok(outputs) => CompResult {
                    status: Status::Cached,
                    key: Some(key),
                    seconds: 0.0,
                    computed_seconds: entry.seconds,
                    gated: gated_outputs(store, &outputs),
                    outputs,
                    waited: claim.waited,
                },
                Err(e) => fail(e.to_string(), 0.0),
            }
        }
        Ok(None) => {}
        Err(e) => return fail(e.to_string(), 0.0),
    }
    let checked = Instant::now();
    if let Err(m) = check_inputs(store, &job) {
        return fail(m, 0.0);
    }
    let check_seconds = checked.elapsed().as_secs_f64();
    let scratch = match store.new_scratch(&key) {
        Ok(s) => s,
        Err(e) => return fail(e.to_string(), 0.0),
    };
    let result = run_in_scratch(plan, store, job, &scratch, check_seconds);
    remove_tree(&scratch);
    drop(claim);
    match result {
        Ok(r) => r,
        Err((m, secs)) => fail(m, secs),
    }
}

/// Hashes everything the job reads and checks it against what its key was computed with: a
/// stored output against its manifest (exactly its files, each file's blake3), an external
/// input against its content hash. A damaged stored output is set aside, so that the next run
/// finds its entry broken and recomputes it; the node fails before it runs, naming the file.
fn check_inputs(store: &Store, job: &Job) -> Result<(), String> {
    for ((name, folders), hashes) in job.inputs.iter().zip(&job.input_hashes) {
        for (folder, hash) in folders.iter().zip(hashes) {
            if let Some(m) = store.output_of_folder(folder) {
                store.check_output(&m).map_err(|damage| {
                    let healed = store.set_aside_damaged_output(&m);
                    format!(
                        "input `{name}` comes from a damaged store entry ({}): {damage}. {}",
                        folder.display(),
                        if healed {
                            "The damaged output was set aside: run again to recompute it"
                        } else {
                            "Run `augsplat verify --repair` to remove the damaged entries, \
                             then run again to recompute them"
                        }
                    )
                })?;
            } else {
                store.check_external(folder, hash).map_err(|m| {
                    format!("input `{name}`: {m}; run again to use its new content")
                })?;
            }
        }
    }
    Ok(())
}

/// Runs the job's node in `scratch` and stores its outputs and action entry. On failure:
/// the message and the seconds the node ran (its log goes to `runs/failed-<key>.log`).
///
/// Steps: make the scratch folders; set up the node's context (its inputs without the gate's
/// slot, a snapshot of them); run the node, or write the gated marker; fail if it failed or
/// changed an input; promote its outputs; write its action entry last.
fn run_in_scratch(
    plan: &Plan,
    store: &Store,
    job: Job,
    scratch: &Path,
    check_seconds: f64,
) -> Result<CompResult, (String, f64)> {
    let Job {
        comp: c,
        name,
        key,
        inputs,
        input_hashes,
        threads,
        bar,
        checkpoint_every,
        echo_log,
    } = job;
    let name = name.as_str();
    let comp = &plan.comps[c];
    let (outputs, work) = scratch_folders(comp, scratch)?;
    let sink = Arc::new(NodeSink {
        lines: Mutex::new(Vec::new()),
        bar,
        echo: echo_log.then(|| (name.to_string(), Instant::now())),
    });
    let seed = u64::from_le_bytes(key[..8].try_into().expect("8 bytes"));
    // A gate that says no, or a gated input the node does not accept: the node ends at once
    // with the marker in each output folder (see `crate::gate`). The node never sees the
    // gate's slot.
    let gated = crate::gate::skip_reason(&comp.node.inputs(&comp.args), &inputs)
        .map_err(|m| (format!("node `{name}` ({}): {m}", comp.node.kind()), 0.0))?;
    let consumed: BTreeMap<String, Vec<String>> = inputs
        .iter()
        .zip(&input_hashes)
        .map(|((n, _), hs)| (n.clone(), hs.iter().map(hex).collect()))
        .collect();
    let mut inputs = inputs;
    inputs.retain(|(n, _)| n != crate::gate::GATE_SLOT);
    // What the node's inputs look like now; a node that changes them fails (below).
    let before = input_snapshot(&inputs);
    let mut ctx = RunContext {
        inputs,
        outputs: outputs.clone(),
        scratch: work,
        seed,
        threads,
        sink: sink.clone(),
        node_name: name.to_string(),
        checkpoints: Some(crate::node::Checkpoints {
            dir: store.checkpoint_dir(&key),
            every: checkpoint_every,
            key,
        }),
        measures: BTreeMap::new(),
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| (format!("building a thread pool: {e}"), 0.0))?;
    let t = Instant::now();
    let res = run_node(comp, &mut ctx, &pool, &outputs, gated.as_deref());
    let secs = t.elapsed().as_secs_f64();
    let log_text = sink.lines.lock().map(|l| l.join("\n")).unwrap_or_default();
    check_run(
        store,
        comp,
        name,
        &key,
        res,
        &log_text,
        &before,
        &ctx.inputs,
    )
    .map_err(|m| (m, secs))?;
    let manifests = promote_outputs(store, &pool, comp, name, &outputs).map_err(|m| (m, secs))?;
    let log = if log_text.is_empty() {
        None
    } else {
        store.put_blob(log_text.as_bytes()).ok()
    };
    let entry = ActionEntry {
        format: STORE_FORMAT,
        key: hex(&key),
        kind: comp.node.kind().to_string(),
        version: comp.node.version(),
        name: name.to_string(),
        outputs: manifests.iter().map(|(k, v)| (k.clone(), hex(v))).collect(),
        seconds: secs,
        time_unix: now_unix(),
        host: hostname(),
        pid: std::process::id(),
        seed,
        threads,
        log,
        measures: std::mem::take(&mut ctx.measures),
        inputs: consumed,
        check_seconds,
    };
    store
        .write_action(&key, &entry)
        .map_err(|e| (e.to_string(), secs))?;
    // The outputs are stored: an interrupted run's checkpoints are no longer needed.
    remove_tree(&store.checkpoint_dir(&key));
    Ok(CompResult {
        status: Status::Ran,
        key: Some(key),
        seconds: secs,
        computed_seconds: secs,
        outputs: manifests,
        waited: false,
        gated,
    })
}

/// Each output's folder, by output name, in the node's order.
type OutputFolders = Vec<(String, PathBuf)>;

/// One output folder per output of `comp` under `scratch/out/`, and the node's own scratch
/// folder `scratch/work`.
fn scratch_folders(comp: &Comp, scratch: &Path) -> Result<(OutputFolders, PathBuf), (String, f64)> {
    let mut outputs = Vec::new();
    for o in &comp.outputs {
        let p = scratch.join("out").join(o);
        std::fs::create_dir_all(&p).map_err(|e| (format!("creating {}: {e}", p.display()), 0.0))?;
        outputs.push((o.clone(), p));
    }
    let work = scratch.join("work");
    std::fs::create_dir_all(&work)
        .map_err(|e| (format!("creating {}: {e}", work.display()), 0.0))?;
    Ok((outputs, work))
}

/// Runs the node in `pool` (a panic is caught), or, when a gate ended it (`gated`: why),
/// writes the gated marker into each output folder instead.
fn run_node(
    comp: &Comp,
    ctx: &mut RunContext,
    pool: &rayon::ThreadPool,
    outputs: &[(String, PathBuf)],
    gated: Option<&str>,
) -> std::thread::Result<Result<(), NodeError>> {
    match gated {
        Some(reason) => {
            ctx.log(format!("gated: {reason}"));
            Ok(outputs
                .iter()
                .try_for_each(|(_, p)| crate::gate::write_marker(p, reason))
                .map_err(|e| NodeError::new(format!("writing the gated marker: {e}"))))
        }
        None => pool.install(|| {
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                comp.node.run(&comp.args, ctx)
            }))
        }),
    }
}

/// Whether the node's run may be stored: it did not fail (else its log goes to
/// `runs/failed-<key>.log`, and the message ends with the log's last lines) and it left its
/// inputs as they were (`before`).
#[allow(clippy::too_many_arguments)]
fn check_run(
    store: &Store,
    comp: &Comp,
    name: &str,
    key: &Hash,
    res: std::thread::Result<Result<(), NodeError>>,
    log_text: &str,
    before: &InputSnapshot,
    inputs: &[(String, Vec<PathBuf>)],
) -> Result<(), String> {
    if let Some(m) = failure_of(res) {
        let msg = format!(
            "node `{name}` ({}) failed: {m}{}",
            comp.node.kind(),
            log_tail(log_text)
        );
        let _ = store.write_atomic(
            &store
                .root()
                .join("runs")
                .join(format!("failed-{}.log", hex(key))),
            format!("{msg}\n\n{log_text}\n").as_bytes(),
        );
        return Err(msg);
    }
    if let Some(change) = changed_input(before, &input_snapshot(inputs)) {
        return Err(format!(
            "node `{name}` ({}) changed its input {change}; inputs are read-only (write to an \
             output folder instead). If the input came from the store, run `augsplat verify \
             --repair` before the next run",
            comp.node.kind()
        ));
    }
    Ok(())
}

/// Promotes each output folder into the store (in `pool`); returns the manifests by output
/// name. A node that removed an output folder fails.
fn promote_outputs(
    store: &Store,
    pool: &rayon::ThreadPool,
    comp: &Comp,
    name: &str,
    outputs: &[(String, PathBuf)],
) -> Result<BTreeMap<String, Hash>, String> {
    let mut manifests = BTreeMap::new();
    for (o, p) in outputs {
        if !p.is_dir() {
            return Err(format!(
                "node `{name}` ({}) removed its output folder `{o}`",
                comp.node.kind()
            ));
        }
        let m = pool
            .install(|| store.promote(p))
            .map_err(|e| format!("storing output `{o}` of `{name}`: {e}"))?;
        manifests.insert(o.clone(), m);
    }
    Ok(manifests)
}

/// Why a node's run failed (its error, or its panic's message), or `None` when it succeeded.
fn failure_of(res: std::thread::Result<Result<(), NodeError>>) -> Option<String> {
    match res {
        Ok(Ok(())) => None,
        Ok(Err(e)) => Some(e.message().to_string()),
        Err(p) => Some(format!(
            "panicked: {}",
            p.downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "(no message)".into())
        )),
    }
}

/// The last 20 lines of a node's log, formatted to follow a failure message (empty when the
/// log is).
fn log_tail(log: &str) -> String {
    let lines: Vec<&str> = log.lines().collect();
    let start = lines.len().saturating_sub(20);
    if lines.is_empty() {
        String::new()
    } else {
        format!(
            "\n  last lines of its log:\n    {}",
            lines[start..].join("\n    ")
        )
    }
}
