//! The local executor: runs the needed computations of a [`Plan`] in dependency order,
//! independent ones in parallel within a thread budget, each inside a rayon pool of its own
//! budget; finds finished ones in the store by key (every run is a resume); claims keys so two
//! processes never compute one twice; promotes outputs atomically.

use crate::error::EngineError;
use crate::node::{ProgressSink, RunContext, Threads};
use crate::resolve::{compute_key, Plan, Source};
use crate::store::{
    hex, hostname, now_unix, remove_tree, unhex, ActionEntry, Hash, Store, STORE_FORMAT,
};
use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::collections::{BTreeMap, VecDeque};
use std::path::PathBuf;
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

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

impl RunReport {
    /// Whether every needed computation ran or was cached.
    pub fn success(&self) -> bool {
        self.results
            .iter()
            .flatten()
            .all(|r| matches!(r.status, Status::Ran | Status::Cached))
    }
    /// The failures: (instance name, message).
    pub fn failures(&self, plan: &Plan) -> Vec<(String, String)> {
        self.results
            .iter()
            .enumerate()
            .filter_map(|(c, r)| match r.as_ref().map(|r| &r.status) {
                Some(Status::Failed(m)) => {
                    Some((plan.comps[c].display_name(plan).to_string(), m.clone()))
                }
                _ => None,
            })
            .collect()
    }
    /// The folder of output `output` of the instance named `instance`, if it ran or was cached.
    pub fn output_dir(
        &self,
        plan: &Plan,
        store: &Store,
        instance: &str,
        output: &str,
    ) -> Option<PathBuf> {
        let inst = plan.instances.iter().find(|i| i.name == instance)?;
        let r = self.results[inst.comp].as_ref()?;
        r.outputs.get(output).map(|m| store.output_dir(m))
    }
    /// The results a run was for: the outputs of the instances matching `targets`, or, without
    /// targets, of the instances nothing else in the run consumes (the pipeline's sinks, e.g.
    /// each sweep point's report). One entry per (instance, output) that ran or was cached:
    /// (instance name, output name, its folder in the store), in pipeline order.
    pub fn final_outputs(
        &self,
        plan: &Plan,
        store: &Store,
        targets: &[String],
    ) -> Vec<(String, String, PathBuf)> {
        let n = plan.comps.len();
        let wanted: Vec<bool> = if targets.is_empty() {
            let mut consumed = vec![false; n];
            for (c, comp) in plan.comps.iter().enumerate() {
                if self.results.get(c).is_none_or(|r| r.is_none()) {
                    continue;
                }
                for slot in &comp.inputs {
                    for (src, _) in &slot.sources {
                        if let Source::Node { comp: up, .. } = src {
                            consumed[*up] = true;
                        }
                    }
                }
            }
            (0..n).map(|c| !consumed[c]).collect()
        } else {
            let mut w = vec![false; n];
            for t in targets {
                for i in plan.match_target(t) {
                    w[plan.instances[i].comp] = true;
                }
            }
            w
        };
        let mut out = Vec::new();
        for inst in &plan.instances {
            if !wanted[inst.comp] {
                continue;
            }
            let Some(r) = self.results.get(inst.comp).and_then(|r| r.as_ref()) else {
                continue;
            };
            if !matches!(r.status, Status::Ran | Status::Cached) {
                continue;
            }
            for (name, m) in &r.outputs {
                out.push((inst.name.clone(), name.clone(), store.output_dir(m)));
            }
        }
        out
    }
    /// `{"nodes":[{"name","kind","key","status","seconds"}..]}`: one entry per needed instance;
    /// `status` is `ran`, `cached` or `failed` (a node not run because an input failed is
    /// `failed` too); failed entries add `"error"` with the reason.
    pub fn summary_json(&self, plan: &Plan) -> serde_json::Value {
        let mut nodes = Vec::new();
        for inst in &plan.instances {
            let Some(r) = &self.results[inst.comp] else {
                continue;
            };
            // The summary's vocabulary is ran | cached | failed: a computation that did not
            // run because an input failed is reported as failed, with the reason.
            let (status, error) = match &r.status {
                Status::Failed(msg) => ("failed", Some(msg.clone())),
                Status::Skipped => ("failed", Some("not run: an input failed".to_string())),
                other => (other.as_str(), None),
            };
            let mut entry = serde_json::json!({
                "name": inst.name,
                "kind": plan.comps[inst.comp].node.kind(),
                "key": r.key.as_ref().map(hex).unwrap_or_default(),
                "status": status,
                "seconds": r.seconds,
            });
            if let Some(e) = error {
                entry["error"] = serde_json::Value::String(e);
            }
            nodes.push(entry);
        }
        serde_json::json!({ "nodes": nodes })
    }
    /// A text table: node, kind, cached/ran, seconds this run, seconds when computed (the
    /// cache record's for cached nodes), and the totals.
    pub fn table(&self, plan: &Plan) -> String {
        let mut rows = vec![(
            "node".to_string(),
            "kind".to_string(),
            "status".to_string(),
            "seconds".to_string(),
            "computed s".to_string(),
        )];
        for inst in &plan.instances {
            let Some(r) = &self.results[inst.comp] else {
                continue;
            };
            let status = if r.waited && r.status == Status::Cached {
                "cached (waited)".into()
            } else {
                r.status.as_str().to_string()
            };
            let computed = match r.status {
                Status::Ran | Status::Cached => format!("{:.2}", r.computed_seconds),
                _ => "—".to_string(),
            };
            rows.push((
                inst.name.clone(),
                plan.comps[inst.comp].node.kind().to_string(),
                status,
                format!("{:.2}", r.seconds),
                computed,
            ));
        }
        let w0 = rows.iter().map(|r| r.0.chars().count()).max().unwrap_or(0);
        let w1 = rows.iter().map(|r| r.1.len()).max().unwrap_or(0);
        let w2 = rows.iter().map(|r| r.2.len()).max().unwrap_or(0);
        let mut s = String::new();
        for (a, b, c, d, e) in rows {
            s.push_str(&format!("{a:w0$}  {b:w1$}  {c:w2$}  {d:>8}  {e:>10}\n"));
        }
        let (mut ran, mut cached, mut failed) = (0, 0, 0);
        for r in self.results.iter().flatten() {
            match r.status {
                Status::Ran => ran += 1,
                Status::Cached => cached += 1,
                _ => failed += 1,
            }
        }
        // Computations shared by several instances count once.
        let computed: f64 = self
            .results
            .iter()
            .flatten()
            .filter(|r| matches!(r.status, Status::Ran | Status::Cached))
            .map(|r| r.computed_seconds)
            .sum();
        s.push_str(&format!(
            "{ran} ran, {cached} cached, {failed} failed or skipped, {:.2} s \
             (sum of the needed nodes' compute times: {computed:.2} s)\n",
            self.seconds
        ));
        s
    }
}

/// Collects a running node's log and drives its progress bar.
struct NodeSink {
    lines: Mutex<Vec<String>>,
    bar: Option<ProgressBar>,
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
        if let Ok(mut l) = self.lines.lock() {
            l.push(line.to_string());
        }
        if let Some(b) = &self.bar {
            b.set_message(line.chars().take(60).collect::<String>());
        }
    }
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

enum Msg {
    Done(usize, CompResult),
}

/// Runs the plan. Returns a report even when nodes fail (check [`RunReport::success`]); errors
/// are reserved for the store itself failing.
pub fn execute(plan: &Plan, store: &Store, opts: &RunOptions) -> Result<RunReport, EngineError> {
    let t0 = Instant::now();
    let _shared = store.lock_shared()?;
    let need = plan.needed(&opts.targets)?;
    let n = plan.comps.len();
    let jobs = opts.jobs.max(1);
    let mut results: Vec<Option<CompResult>> = vec![None; n];
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
    let mut ready: VecDeque<usize> = (0..n).filter(|&c| need[c] && waiting[c] == 0).collect();
    let total = need.iter().filter(|x| **x).count() as u64;
    let multi = MultiProgress::with_draw_target(if opts.progress {
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
    let (tx, rx) = mpsc::channel::<Msg>();
    let mut free = jobs;
    let mut running = 0usize;
    let mut running_need: BTreeMap<usize, usize> = BTreeMap::new();

    std::thread::scope(|scope| -> Result<(), EngineError> {
        loop {
            // Start what fits.
            let mut i = 0;
            while i < ready.len() {
                let c = ready[i];
                let comp = &plan.comps[c];
                // Inputs' folders and manifests.
                let mut ms = Vec::new();
                let mut folders = Vec::new();
                for slot in &comp.inputs {
                    let mut v = Vec::new();
                    let mut f = Vec::new();
                    for (s, _) in &slot.sources {
                        match s {
                            Source::External { path, hash } => {
                                v.push(*hash);
                                f.push(path.clone());
                            }
                            Source::Node { comp: up, output } => {
                                let m = results[*up].as_ref().and_then(|r| r.outputs.get(output)).copied().ok_or_else(|| {
                                    EngineError::Other(format!("internal: output `{output}` of an upstream node is missing"))
                                })?;
                                v.push(m);
                                f.push(store.output_dir(&m));
                            }
                        }
                    }
                    ms.push(v);
                    folders.push((slot.name.clone(), f));
                }
                let key = compute_key(comp, &ms);
                if let Some(entry) = store.action(&key)? {
                    ready.remove(i);
                    let outputs = outputs_of(&entry)?;
                    finish(
                        c,
                        CompResult {
                            status: Status::Cached,
                            key: Some(key),
                            seconds: 0.0,
                            computed_seconds: entry.seconds,
                            outputs,
                            waited: false,
                        },
                        &mut results,
                        &dependents,
                        &mut waiting,
                        &mut ready,
                        &need,
                    );
                    overall.inc(1);
                    i = 0;
                    continue;
                }
                let want = match comp.threads {
                    Threads::One => 1,
                    Threads::All => jobs,
                    Threads::Exactly(k) => k.clamp(1, jobs),
                };
                if want > free {
                    if comp.threads == Threads::All {
                        break; // reserve the machine for it: start nothing after it
                    }
                    i += 1;
                    continue;
                }
                ready.remove(i);
                free -= want;
                running += 1;
                running_need.insert(c, want);
                let bar = if opts.progress {
                    let b = multi.add(ProgressBar::new_spinner());
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
                } else {
                    None
                };
                let tx = tx.clone();
                let name = comp.display_name(plan).to_string();
                scope.spawn(move || {
                    let r = run_one(plan, c, &name, key, folders, store, want, bar.clone());
                    if let Some(b) = bar {
                        b.finish_and_clear();
                    }
                    let _ = tx.send(Msg::Done(c, r));
                });
            }
            if running == 0 {
                break;
            }
            let Ok(Msg::Done(c, r)) = rx.recv() else {
                break;
            };
            running -= 1;
            free += running_need.remove(&c).unwrap_or(0);
            overall.inc(1);
            if let Status::Failed(m) = &r.status {
                let _ = multi.println(format!(
                    "failed: {} — {}",
                    plan.comps[c].display_name(plan),
                    m.lines().next().unwrap_or("")
                ));
            }
            finish(
                c,
                r,
                &mut results,
                &dependents,
                &mut waiting,
                &mut ready,
                &need,
            );
        }
        Ok(())
    })?;
    overall.finish_and_clear();
    // Whatever was needed and never reached: skipped (an ancestor failed).
    for c in 0..n {
        if need[c] && results[c].is_none() {
            results[c] = Some(CompResult {
                status: Status::Skipped,
                key: None,
                seconds: 0.0,
                computed_seconds: 0.0,
                outputs: BTreeMap::new(),
                waited: false,
            });
        }
    }
    let report = RunReport {
        results,
        seconds: t0.elapsed().as_secs_f64(),
    };
    write_records(plan, store, &report)?;
    Ok(report)
}

fn outputs_of(entry: &ActionEntry) -> Result<BTreeMap<String, Hash>, EngineError> {
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

fn finish(
    c: usize,
    r: CompResult,
    results: &mut [Option<CompResult>],
    dependents: &[Vec<usize>],
    waiting: &mut [usize],
    ready: &mut VecDeque<usize>,
    need: &[bool],
) {
    let ok = matches!(r.status, Status::Ran | Status::Cached);
    results[c] = Some(r);
    if ok {
        for &d in &dependents[c] {
            waiting[d] -= 1;
            if waiting[d] == 0 && need[d] {
                // Keep the ready queue in plan order (stable, deterministic scheduling).
                let pos = ready.iter().position(|&x| x > d).unwrap_or(ready.len());
                ready.insert(pos, d);
            }
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn run_one(
    plan: &Plan,
    c: usize,
    name: &str,
    key: Hash,
    inputs: Vec<(String, Vec<PathBuf>)>,
    store: &Store,
    threads: usize,
    bar: Option<ProgressBar>,
) -> CompResult {
    let comp = &plan.comps[c];
    let fail = |m: String, secs: f64| CompResult {
        status: Status::Failed(m),
        key: Some(key),
        seconds: secs,
        computed_seconds: secs,
        outputs: BTreeMap::new(),
        waited: false,
    };
    let claim = match store.claim(&key) {
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
                    outputs,
                    waited: claim.waited,
                },
                Err(e) => fail(e.to_string(), 0.0),
            }
        }
        Ok(None) => {}
        Err(e) => return fail(e.to_string(), 0.0),
    }
    let scratch = match store.new_scratch(&key) {
        Ok(s) => s,
        Err(e) => return fail(e.to_string(), 0.0),
    };
    let result = run_in_scratch(plan, c, name, key, inputs, store, threads, bar, &scratch);
    remove_tree(&scratch);
    drop(claim);
    match result {
        Ok(r) => r,
        Err((m, secs)) => {
            let _ = comp;
            fail(m, secs)
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn run_in_scratch(
    plan: &Plan,
    c: usize,
    name: &str,
    key: Hash,
    inputs: Vec<(String, Vec<PathBuf>)>,
    store: &Store,
    threads: usize,
    bar: Option<ProgressBar>,
    scratch: &std::path::Path,
) -> Result<CompResult, (String, f64)> {
    let comp = &plan.comps[c];
    let mut outputs = Vec::new();
    for o in &comp.outputs {
        let p = scratch.join("out").join(o);
        std::fs::create_dir_all(&p).map_err(|e| (format!("creating {}: {e}", p.display()), 0.0))?;
        outputs.push((o.clone(), p));
    }
    let work = scratch.join("work");
    std::fs::create_dir_all(&work)
        .map_err(|e| (format!("creating {}: {e}", work.display()), 0.0))?;
    let sink = Arc::new(NodeSink {
        lines: Mutex::new(Vec::new()),
        bar,
    });
    let seed = u64::from_le_bytes(key[..8].try_into().expect("8 bytes"));
    let mut ctx = RunContext {
        inputs,
        outputs: outputs.clone(),
        scratch: work,
        seed,
        threads,
        sink: sink.clone(),
        node_name: name.to_string(),
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| (format!("building a thread pool: {e}"), 0.0))?;
    let t = Instant::now();
    let res = pool.install(|| {
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            comp.node.run(&comp.args, &mut ctx)
        }))
    });
    let secs = t.elapsed().as_secs_f64();
    let log_text = sink.lines.lock().map(|l| l.join("\n")).unwrap_or_default();
    let tail = |log: &str| -> String {
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
    };
    let err = match res {
        Ok(Ok(())) => None,
        Ok(Err(e)) => Some(e.message().to_string()),
        Err(p) => Some(format!(
            "panicked: {}",
            p.downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "(no message)".into())
        )),
    };
    if let Some(m) = err {
        let msg = format!(
            "node `{name}` ({}) failed: {m}{}",
            comp.node.kind(),
            tail(&log_text)
        );
        let _ = store.write_atomic(
            &store
                .root()
                .join("runs")
                .join(format!("failed-{}.log", hex(&key))),
            format!("{msg}\n\n{log_text}\n").as_bytes(),
        );
        return Err((msg, secs));
    }
    let mut manifests = BTreeMap::new();
    for (o, p) in &outputs {
        if !p.is_dir() {
            return Err((
                format!(
                    "node `{name}` ({}) removed its output folder `{o}`",
                    comp.node.kind()
                ),
                secs,
            ));
        }
        let m = pool
            .install(|| store.promote(p))
            .map_err(|e| (format!("storing output `{o}` of `{name}`: {e}"), secs))?;
        manifests.insert(o.clone(), m);
    }
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
    };
    store
        .write_action(&key, &entry)
        .map_err(|e| (e.to_string(), secs))?;
    Ok(CompResult {
        status: Status::Ran,
        key: Some(key),
        seconds: secs,
        computed_seconds: secs,
        outputs: manifests,
        waited: false,
    })
}

/// A flattened view of typed args: leaf path -> JSON value (objects are walked, everything
/// else is a leaf).
pub fn flatten_args(v: &serde_json::Value) -> BTreeMap<String, serde_json::Value> {
    fn walk(v: &serde_json::Value, prefix: &str, out: &mut BTreeMap<String, serde_json::Value>) {
        match v {
            serde_json::Value::Object(m) if !m.is_empty() => {
                for (k, x) in m {
                    let p = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    walk(x, &p, out);
                }
            }
            _ => {
                out.insert(prefix.to_string(), v.clone());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(v, "", &mut out);
    out
}

/// The origin of arg `path` in a computation's written args, or `default` when not written.
pub fn arg_origin(plan: &Plan, c: usize, path: &str) -> String {
    let mut cur = &plan.comps[c].args_value;
    for seg in path.split('.').filter(|s| !s.is_empty()) {
        let next = match &cur.kind {
            crate::syntax::ValueKind::Struct(_, f) => {
                f.iter().find(|(n, _)| n == seg).map(|(_, v)| v)
            }
            crate::syntax::ValueKind::Map(e) => e
                .iter()
                .find(|(k, _)| k.as_str() == Some(seg))
                .map(|(_, v)| v),
            _ => None,
        };
        match next {
            Some(n) => cur = n,
            None => {
                return if std::ptr::eq(cur, &plan.comps[c].args_value) {
                    "default".into()
                } else {
                    cur.origin.to_string()
                }
            }
        }
    }
    cur.origin.to_string()
}

/// The per-instance record of a computation (kept in `runs/latest` for `why` and GC).
pub fn instance_record(
    plan: &Plan,
    c: usize,
    key: &Hash,
    results: &[Option<CompResult>],
    status: &str,
) -> serde_json::Value {
    let comp = &plan.comps[c];
    let flat = flatten_args(&comp.args_json);
    let origins: BTreeMap<String, String> = flat
        .keys()
        .map(|k| (k.clone(), arg_origin(plan, c, k)))
        .collect();
    let inputs: BTreeMap<String, Vec<serde_json::Value>> = comp
        .inputs
        .iter()
        .map(|slot| {
            let v = slot
                .sources
                .iter()
                .map(|(s, shown)| {
                    let m = match s {
                        Source::External { hash, .. } => Some(hex(hash)),
                        Source::Node { comp: up, output } => results[*up]
                            .as_ref()
                            .and_then(|r| r.outputs.get(output))
                            .map(hex),
                    };
                    serde_json::json!({ "from": shown, "manifest": m })
                })
                .collect();
            (slot.name.clone(), v)
        })
        .collect();
    serde_json::json!({
        "key": hex(key),
        "kind": comp.node.kind(),
        "version": comp.node.version(),
        "salt": comp.salt,
        "args": comp.args_json,
        "origins": origins,
        "inputs": inputs,
        "status": status,
    })
}

fn write_records(plan: &Plan, store: &Store, report: &RunReport) -> Result<(), EngineError> {
    let mut latest = store
        .read_latest(&plan.id)
        .unwrap_or_else(|| serde_json::json!({}));
    if !latest.get("instances").is_some_and(|v| v.is_object()) {
        latest = serde_json::json!({ "instances": {} });
    }
    let insts = latest["instances"].as_object_mut().expect("made an object");
    // Instances no longer in the pipeline stop being roots.
    insts.retain(|name, _| plan.instances.iter().any(|i| i.name == *name));
    for inst in &plan.instances {
        let Some(r) = &report.results[inst.comp] else {
            continue;
        };
        // Only successful results replace the previous record: `why` compares against the
        // last good run, and GC keeps it.
        if let (Some(key), Status::Ran | Status::Cached) = (&r.key, &r.status) {
            insts.insert(
                inst.name.clone(),
                instance_record(plan, inst.comp, key, &report.results, r.status.as_str()),
            );
        }
    }
    latest["pipeline"] = serde_json::json!(plan.file.display().to_string());
    latest["time_unix"] = serde_json::json!(now_unix());
    store.write_latest(&plan.id, &latest)?;
    let mut summary = report.summary_json(plan);
    summary["pipeline"] = serde_json::json!(plan.file.display().to_string());
    summary["time_unix"] = serde_json::json!(now_unix());
    summary["host"] = serde_json::json!(hostname());
    store.write_record(&summary)?;
    Ok(())
}
