//! `augsplat run --executor slurm` on a real one-node Slurm cluster on localhost, brought up
//! by `tests/slurm/localhost.sh` (which installs the Debian packages when missing) and stopped
//! by pid at the end. Skips with a message outside CI when no cluster can be started; fails
//! under `CI=true`.
//!
//! One test function, so the cluster is started once and stopped after every check:
//! - the tiny demo as a γ sweep through Slurm gives exactly the keys and output manifests of a
//!   local run; the shared ensemble is submitted once, as one array, and the sweep points'
//!   nodes as one array each;
//! - `scancel` of a running node's job: the driver reports it, the store holds no entry for
//!   it, a rerun completes it;
//! - `scontrol requeue` of a training job: the requeued job resumes from its checkpoint and
//!   stores the bytes of an uninterrupted run;
//! - `augsplat status` names the Slurm job of a running node.

use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_augsplat");

/// The cluster; stopped (by the pids in its folder) when dropped.
struct Cluster {
    dir: tempfile::TempDir,
    conf: String,
    script: PathBuf,
}

impl Cluster {
    fn start() -> Option<Cluster> {
        let script = augsplat_testkit::workspace_root().join("tests/slurm/localhost.sh");
        let dir = tempfile::Builder::new()
            .prefix("augsplat-slurm-")
            .tempdir()
            .unwrap();
        let out = Command::new("bash")
            .arg(&script)
            .arg("start")
            .arg(dir.path())
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        let conf = stdout
            .lines()
            .rev()
            .find_map(|l| l.strip_prefix("export SLURM_CONF="))
            .map(|s| s.trim().trim_matches('\'').trim_matches('"').to_string());
        match (out.status.success(), conf) {
            (true, Some(conf)) => Some(Cluster { dir, conf, script }),
            _ => {
                let _ = Command::new("bash")
                    .arg(&script)
                    .arg("stop")
                    .arg(dir.path())
                    .output();
                augsplat_testkit::skip(
                    "slurm_cli",
                    &format!(
                        "no Slurm cluster could be started on localhost ({}):\n{}{}",
                        script.display(),
                        stdout,
                        String::from_utf8_lossy(&out.stderr)
                    ),
                );
                None
            }
        }
    }

    /// A command with this cluster's `SLURM_CONF`.
    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    fn text(&self, program: &str, args: &[&str]) -> String {
        let o = self.command(program).args(args).output().unwrap();
        String::from_utf8_lossy(&o.stdout).into_owned()
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new("bash")
            .arg(&self.script)
            .arg("stop")
            .arg(self.dir.path())
            .output();
    }
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// `augsplat run FILE --cache CACHE` with `sets` and `extra`, through Slurm when `slurm`.
fn run_cmd(
    cluster: &Cluster,
    file: &Path,
    cache: &Path,
    slurm: bool,
    sets: &[&str],
    extra: &[&str],
) -> Command {
    let mut c = cluster.command(BIN);
    c.arg("run").arg(file).arg("--cache").arg(cache).arg("-q");
    if slurm {
        c.args(["--executor", "slurm"]);
    }
    for s in sets {
        c.arg("--set").arg(s);
    }
    c.args(extra);
    c
}

/// Per node of a run's summary: (key, output name → manifest) from the store.
fn keys_and_manifests(cache: &Path, summary: &Path) -> BTreeMap<String, (String, Value)> {
    let s: Value = serde_json::from_slice(&std::fs::read(summary).unwrap()).unwrap();
    let store = augsplat_graph::Store::open(cache).unwrap();
    s["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            let key = n["key"].as_str().unwrap().to_string();
            let entry = store
                .action(&augsplat_graph::store::unhex(&key).unwrap())
                .unwrap()
                .unwrap_or_else(|| panic!("no entry for {}", n["name"]));
            (
                n["name"].as_str().unwrap().to_string(),
                (key, serde_json::to_value(&entry.outputs).unwrap()),
            )
        })
        .collect()
}

/// Every submission of the latest Slurm run on `cache`: the keys of each `.keys` file.
fn submissions(cache: &Path) -> Vec<Vec<String>> {
    let root = cache.join("runs/slurm");
    let mut runs: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .collect();
    runs.sort();
    let run = runs.last().expect("a Slurm run folder");
    let mut files: Vec<PathBuf> = std::fs::read_dir(run)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "keys"))
        .collect();
    files.sort();
    files
        .iter()
        .map(|f| {
            std::fs::read_to_string(f)
                .unwrap()
                .lines()
                .map(|l| l.split_whitespace().next().unwrap().to_string())
                .collect()
        })
        .collect()
}

/// Waits until `f` holds, polling.
fn wait_until(what: &str, limit: Duration, mut f: impl FnMut() -> bool) {
    let t = Instant::now();
    while !f() {
        assert!(t.elapsed() < limit, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The Slurm job id of the run's running job whose script names `node`.
fn running_job_of(cluster: &Cluster, cache: &Path, node: &str) -> Option<String> {
    let st: Value = serde_json::from_slice(
        &Command::new(BIN)
            .args(["status", "--json", "--cache"])
            .arg(cache)
            .output()
            .ok()?
            .stdout,
    )
    .ok()?;
    let n = st["nodes"]
        .as_array()?
        .iter()
        .find(|n| n["name"] == node && n["state"] == "running")?;
    let place = n["place"].as_str()?;
    let id = place
        .strip_prefix("Slurm job ")?
        .split_whitespace()
        .next()?;
    // Confirm with squeue that the job runs.
    cluster
        .text("squeue", &["--noheader", "--array", "--format=%i %T"])
        .lines()
        .any(|l| l.trim() == format!("{id} RUNNING"))
        .then(|| id.to_string())
}

fn spawn_quiet(mut c: Command) -> Child {
    c.stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

#[test]
fn slurm_executor_on_a_localhost_cluster() {
    let Some(cluster) = Cluster::start() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let tiny = augsplat_testkit::tiny::pipeline();

    // 1. The tiny demo as a γ sweep: Slurm against local, key for key.
    let sweep = tmp.path().join("sweep.ron");
    std::fs::write(
        &sweep,
        format!(
            "(extends: {:?}, sweep: Grid({{ \"params.gamma\": [0.5, 1.5] }}))",
            tiny.display().to_string()
        ),
    )
    .unwrap();
    let (s_cache, l_cache) = (tmp.path().join("slurm"), tmp.path().join("local"));
    let (s_sum, l_sum) = (tmp.path().join("s.json"), tmp.path().join("l.json"));
    let t = Instant::now();
    let o = run_cmd(
        &cluster,
        &sweep,
        &s_cache,
        true,
        &[],
        &["--summary-json", s_sum.to_str().unwrap()],
    )
    .output()
    .unwrap();
    let slurm_secs = t.elapsed().as_secs_f64();
    assert!(o.status.success(), "{}", text(&o));
    let t = Instant::now();
    let o = run_cmd(
        &cluster,
        &sweep,
        &l_cache,
        false,
        &[],
        &["--summary-json", l_sum.to_str().unwrap()],
    )
    .output()
    .unwrap();
    let local_secs = t.elapsed().as_secs_f64();
    assert!(o.status.success(), "{}", text(&o));
    eprintln!("tiny γ sweep: Slurm {slurm_secs:.1} s, local {local_secs:.1} s");
    let (s, l) = (
        keys_and_manifests(&s_cache, &s_sum),
        keys_and_manifests(&l_cache, &l_sum),
    );
    assert_eq!(
        s, l,
        "keys and output manifests differ between Slurm and local"
    );
    let subs = submissions(&s_cache);
    let all: Vec<&String> = subs.iter().flatten().collect();
    let mut unique = all.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(
        all.len(),
        unique.len(),
        "a key was submitted twice: {subs:?}"
    );
    let key_of = |name: &str| s[name].0.clone();
    let fields: Vec<String> = s
        .keys()
        .filter(|n| n.starts_with("field"))
        .map(|n| key_of(n))
        .collect();
    assert!(fields.len() >= 2, "{:?}", s.keys());
    let field_sub: Vec<&Vec<String>> = subs
        .iter()
        .filter(|k| k.iter().any(|k| fields.contains(k)))
        .collect();
    assert_eq!(
        field_sub.len(),
        1,
        "the ensemble is one submission: {subs:?}"
    );
    assert_eq!(
        field_sub[0].len(),
        fields.len(),
        "one array task per member"
    );
    let aggregates: Vec<String> = s
        .keys()
        .filter(|n| n.starts_with("aggregate"))
        .map(|n| key_of(n))
        .collect();
    assert_eq!(aggregates.len(), 2, "one aggregate per γ: {:?}", s.keys());
    assert!(
        subs.iter().any(|k| {
            let mut k = k.clone();
            k.sort();
            let mut a = aggregates.clone();
            a.sort();
            k == a
        }),
        "the sweep points' aggregates are one array: {subs:?}"
    );

    // 2. scancel of a running node's job.
    let mark = tmp.path().join("mark");
    let slow = tmp.path().join("slow.ron");
    std::fs::write(
        &slow,
        format!(
            r#"(nodes: {{
    "a": (kind: "Command", args: (program: "sh", args: ["-c", "echo data > $AUGSPLAT_OUT_OUT/x"])),
    "slow": (kind: "Command",
        args: (program: "sh", inputs: ["src"],
               args: ["-c", "if [ ! -f {m} ]; then touch {m}; sleep 120; fi; cat {{in:src}}/x > {{out:out}}/x"]),
        inputs: {{ "src": "a" }}),
}})"#,
            m = mark.display()
        ),
    )
    .unwrap();
    let c_cache = tmp.path().join("cancel");
    let child = spawn_quiet(run_cmd(&cluster, &slow, &c_cache, true, &[], &[]));
    let mut job = None;
    wait_until(
        "the slow node's job to run",
        Duration::from_secs(120),
        || {
            job = running_job_of(&cluster, &c_cache, "slow");
            job.is_some() && mark.exists()
        },
    );
    let job = job.unwrap();
    // `augsplat status` names the job while it runs.
    let st = Command::new(BIN)
        .args(["status", "--cache"])
        .arg(&c_cache)
        .output()
        .unwrap();
    let st = String::from_utf8_lossy(&st.stdout).into_owned();
    assert!(
        st.lines()
            .any(|l| l.starts_with("slow") && l.contains(&format!("Slurm job {job}"))),
        "{st}"
    );
    assert!(cluster
        .command("scancel")
        .arg(&job)
        .status()
        .unwrap()
        .success());
    let o = child.wait_with_output().unwrap();
    let report = text(&o);
    assert!(!o.status.success(), "{report}");
    assert!(
        report.contains(&format!("Slurm job {job} ended CANCELLED")),
        "the driver reports the cancellation: {report}"
    );
    let store = augsplat_graph::Store::open(&c_cache).unwrap();
    let actions: usize = std::fs::read_dir(c_cache.join("actions"))
        .unwrap()
        .flatten()
        .map(|d| std::fs::read_dir(d.path()).unwrap().count())
        .sum();
    assert_eq!(actions, 1, "only `a` has an entry");
    drop(store);
    let o = run_cmd(&cluster, &slow, &c_cache, true, &[], &[])
        .output()
        .unwrap();
    assert!(o.status.success(), "the rerun completes it: {}", text(&o));

    // 3. scontrol requeue of a training job: it resumes from its checkpoint.
    let sets = ["params.gs_steps=1200", "params.eval_every=300"];
    let train = ["--target", "baseline", "--checkpoint-every", "100"];
    let whole = tmp.path().join("whole");
    let w_sum = tmp.path().join("w.json");
    let mut args = train.to_vec();
    args.extend(["--summary-json", w_sum.to_str().unwrap()]);
    let o = run_cmd(&cluster, &tiny, &whole, false, &sets, &args)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let r_cache = tmp.path().join("requeue");
    let r_sum = tmp.path().join("r.json");
    let mut args = train.to_vec();
    args.extend(["--summary-json", r_sum.to_str().unwrap(), "--requeue"]);
    let child = spawn_quiet(run_cmd(&cluster, &tiny, &r_cache, true, &sets, &args));
    let mut job = None;
    wait_until(
        "a checkpoint of the training job",
        Duration::from_secs(180),
        || {
            let ck = std::fs::read_dir(r_cache.join("checkpoints"))
                .into_iter()
                .flatten()
                .flatten()
                .any(|e| e.path().join("state.ckpt").is_file());
            if ck {
                job = running_job_of(&cluster, &r_cache, "baseline");
            }
            ck && job.is_some()
        },
    );
    let job = job.unwrap();
    assert!(cluster
        .command("scontrol")
        .args(["requeue", &job])
        .status()
        .unwrap()
        .success());
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let restarts = cluster.text("scontrol", &["show", "job", &job]);
    let (a, b) = (
        keys_and_manifests(&r_cache, &r_sum),
        keys_and_manifests(&whole, &w_sum),
    );
    assert_eq!(
        a["baseline"], b["baseline"],
        "the requeued training stored the uninterrupted run's bytes"
    );
    let store = augsplat_graph::Store::open(&r_cache).unwrap();
    let entry = store
        .action(&augsplat_graph::store::unhex(&a["baseline"].0).unwrap())
        .unwrap()
        .unwrap();
    let log = std::fs::read_to_string(store.blob(entry.log.as_ref().unwrap()).unwrap()).unwrap();
    assert!(
        log.contains("resumed from the checkpoint at step"),
        "the requeued job resumed ({restarts}):\n{log}"
    );
}
