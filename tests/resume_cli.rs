//! Long nodes survive kills: `OptimizeSplats` killed (SIGKILL) mid-training on the tiny demo
//! resumes from its last checkpoint and stores exactly the bytes of an uninterrupted run;
//! `augsplat status` shows the interrupted run, then the finished one.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_augsplat");

fn cmd(cache: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(BIN);
    c.arg("run")
        .arg(augsplat_testkit::tiny::pipeline())
        .arg("--cache")
        .arg(cache)
        .args(["--target", "baseline", "-q", "--checkpoint-every", "100"])
        .args([
            "--set",
            "params.gs_steps=1200",
            "--set",
            "params.eval_every=300",
        ])
        .args(extra);
    c
}

/// The stored `model` folder and log of `baseline`, from a run's summary.
fn model_and_log(cache: &Path, summary: &Path) -> (PathBuf, String) {
    let s: Value = serde_json::from_slice(&std::fs::read(summary).unwrap()).unwrap();
    let node = s["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == "baseline")
        .unwrap()
        .clone();
    let store = augsplat_graph::Store::open(cache).unwrap();
    let key = augsplat_graph::store::unhex(node["key"].as_str().unwrap()).unwrap();
    let entry = store.action(&key).unwrap().expect("an entry");
    let log = entry
        .log
        .as_ref()
        .and_then(|h| store.blob(h))
        .map(|p| std::fs::read_to_string(p).unwrap())
        .unwrap_or_default();
    let dir = store.output_dir(&augsplat_graph::store::unhex(&entry.outputs["model"]).unwrap());
    (dir, log)
}

fn status(cache: &Path) -> String {
    let o = Command::new(BIN)
        .args(["status", "--cache"])
        .arg(cache)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn training_killed_mid_run_resumes_from_its_checkpoint_with_the_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    // The uninterrupted run.
    let whole = tmp.path().join("whole");
    let s_whole = tmp.path().join("whole.json");
    let o = cmd(&whole, &["--summary-json", s_whole.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let st = status(&whole);
    assert!(st.contains("finished") && st.contains("baseline"), "{st}");
    assert!(
        std::fs::read_dir(whole.join("checkpoints"))
            .unwrap()
            .count()
            == 0,
        "checkpoints are removed once the entry is stored"
    );

    // Killed once its second checkpoint is on disk.
    let cache = tmp.path().join("killed");
    let mut child = cmd(&cache, &[])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t = Instant::now();
    let ckpt = loop {
        let found = std::fs::read_dir(cache.join("checkpoints"))
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path().join("state.ckpt"))
            .find(|p| p.is_file());
        if let Some(p) = found {
            // Wait for a later checkpoint than the first, to kill between two of them.
            let first = std::fs::metadata(&p).unwrap().modified().unwrap();
            while std::fs::metadata(&p).unwrap().modified().unwrap() == first {
                assert!(
                    t.elapsed() < Duration::from_secs(120),
                    "no second checkpoint"
                );
                std::thread::sleep(Duration::from_millis(5));
            }
            break p;
        }
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before a checkpoint was seen"
        );
        assert!(
            t.elapsed() < Duration::from_secs(120),
            "no checkpoint appeared"
        );
        std::thread::sleep(Duration::from_millis(5));
    };
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    assert!(ckpt.is_file(), "the checkpoint outlives the killed run");
    let st = status(&cache);
    assert!(st.contains("interrupted"), "{st}");
    assert!(
        st.lines()
            .any(|l| l.starts_with("baseline") && l.contains("running")),
        "{st}"
    );

    // The rerun continues from the checkpoint.
    let s_again = tmp.path().join("again.json");
    let o = cmd(&cache, &["--summary-json", s_again.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (a, log) = model_and_log(&cache, &s_again);
    let resumed_at: u64 = log
        .lines()
        .find_map(|l| l.strip_prefix("resumed from the checkpoint at step "))
        .unwrap_or_else(|| panic!("the rerun did not resume:\n{log}"))
        .trim()
        .parse()
        .unwrap();
    assert!(
        (200..1200).contains(&resumed_at) && resumed_at.is_multiple_of(100),
        "{resumed_at}"
    );
    let (b, _) = model_and_log(&whole, &s_whole);
    for f in ["final.ply", "best.ply", "curve.json", "best.json"] {
        assert!(
            std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
            "{f} differs from the uninterrupted run's (resumed at step {resumed_at})"
        );
    }
    assert!(
        !ckpt.exists(),
        "the checkpoint is removed once the entry is stored"
    );
    let st = status(&cache);
    assert!(st.contains("finished"), "{st}");
}
