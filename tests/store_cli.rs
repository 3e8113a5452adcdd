//! The store through the `augsplat` binary: a mistyped `--cache` is never taken for an empty
//! store, and `run --out` never hands the user a damaged result.

use std::path::Path;
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_augsplat");

fn augsplat(dir: &Path, args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .env_remove("AUGSPLAT_CACHE")
        .output()
        .unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

const PIPELINE: &str = r#"(nodes: { "hello": (kind: "Command", args: (program: "sh", args: ["-c", "echo hello > {out:out}/greeting.txt"])) })"#;

#[test]
fn commands_other_than_run_refuse_a_path_that_holds_no_store() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("p.ron");
    std::fs::write(&p, PIPELINE).unwrap();
    let ps = p.to_str().unwrap();
    for args in [
        vec!["verify", "--cache", "cahce"],
        vec!["status", "--cache", "cahce"],
        vec!["gc", "--cache", "cahce"],
        vec!["plan", ps, "--cache", "cahce"],
        vec!["why", ps, "hello", "--cache", "cahce"],
    ] {
        let out = augsplat(dir.path(), &args);
        assert!(!out.status.success(), "{args:?} succeeded: {}", text(&out));
        assert!(
            text(&out).contains("holds no augsplat store"),
            "{args:?}: {}",
            text(&out)
        );
        assert!(
            !dir.path().join("cahce").exists(),
            "{args:?} created a store"
        );
    }
    // `expand` needs no store; `run` creates one.
    let out = augsplat(dir.path(), &["expand", ps, "--cache", "cahce"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(!dir.path().join("cahce").exists());
    let out = augsplat(dir.path(), &["run", ps, "--cache", "store"]);
    assert!(out.status.success(), "{}", text(&out));
    let out = augsplat(dir.path(), &["verify", "--cache", "store"]);
    assert!(out.status.success(), "{}", text(&out));
}

#[test]
fn run_out_never_copies_a_damaged_cached_output() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("p.ron");
    std::fs::write(&p, PIPELINE).unwrap();
    let ps = p.to_str().unwrap();
    let out = augsplat(dir.path(), &["run", ps, "--cache", "store"]);
    assert!(out.status.success(), "{}", text(&out));
    // Damage the stored file in place (same size).
    let outputs = dir.path().join("store/outputs");
    let folder = std::fs::read_dir(&outputs)
        .unwrap()
        .next()
        .unwrap()
        .unwrap();
    let f = folder.path().join("greeting.txt");
    let mut perm = std::fs::metadata(&f).unwrap().permissions();
    #[allow(clippy::permissions_set_readonly_false)]
    perm.set_readonly(false);
    std::fs::set_permissions(&f, perm).unwrap();
    std::fs::write(&f, b"HELLO\n").unwrap();

    let out = augsplat(
        dir.path(),
        &["run", ps, "--cache", "store", "--out", "results"],
    );
    assert!(
        !out.status.success(),
        "copied a damaged output: {}",
        text(&out)
    );
    assert!(text(&out).contains("damaged"), "{}", text(&out));
    assert!(!dir.path().join("results/hello/out/greeting.txt").exists());
}

#[test]
fn run_out_writes_only_below_its_folder_whatever_a_swept_value_holds() {
    let dir = tempfile::tempdir().unwrap();
    let marker = format!("augsplat_escape_{}", std::process::id());
    let escape = format!("{}{marker}", "/..".repeat(40));
    let p = dir.path().join("p.ron");
    std::fs::write(
        &p,
        format!(
            r#"(nodes: {{ "n": (kind: "Command", args: (program: "sh", args: ["-c", "echo hi > {{out:out}}/x"])) }},
               sweep: Grid({{ "n.args": [["-c", "echo a > {{out:out}}/x", "{escape}"], ["-c", "echo b > {{out:out}}/x", "{escape}/"]] }}))"#
        ),
    )
    .unwrap();
    let out = augsplat(
        dir.path(),
        &[
            "run",
            p.to_str().unwrap(),
            "--cache",
            "store",
            "--out",
            "res",
        ],
    );
    assert!(out.status.success(), "{}", text(&out));
    let escaped: Vec<_> = std::fs::read_dir("/")
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with(&marker))
        .collect();
    for e in &escaped {
        let _ = std::fs::remove_dir_all(e.path());
    }
    assert!(escaped.is_empty(), "wrote outside --out: {escaped:?}");
    let mut names: Vec<String> = std::fs::read_dir(dir.path().join("res"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    names.sort();
    assert_eq!(
        names.len(),
        2,
        "two points, two distinct folders: {names:?}"
    );
    for n in &names {
        assert!(!n.contains('/') && !n.contains(".."), "{n}");
        let x = dir.path().join("res").join(n).join("out/x");
        assert!(x.is_file(), "{}", x.display());
    }
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        3,
        "only p.ron, store/ and res/ in the folder"
    );
}

#[test]
fn a_run_waiting_on_another_drivers_claim_says_whom_it_waits_for() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("p.ron");
    std::fs::write(&p, PIPELINE).unwrap();
    let ps = p.to_str().unwrap();
    let summary = dir.path().join("s.json");
    let out = augsplat(
        dir.path(),
        &[
            "run",
            ps,
            "--cache",
            "store",
            "--summary-json",
            summary.to_str().unwrap(),
        ],
    );
    assert!(out.status.success(), "{}", text(&out));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
    let key = v["nodes"][0]["key"].as_str().unwrap().to_string();
    // Its entry goes, and another driver (on another host) claims the key.
    let store = dir.path().join("store");
    std::fs::remove_file(
        store
            .join("actions")
            .join(&key[..2])
            .join(format!("{key}.json")),
    )
    .unwrap();
    let claim = store.join("locks").join(format!("{key}.claim"));
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs();
    std::fs::write(
        &claim,
        format!(
            r#"{{"host":"another-host","pid":4242,"start_ticks":0,"slurm_job":null,"since_unix":{now},"token":"t"}}"#
        ),
    )
    .unwrap();
    let child = Command::new(BIN)
        .args(["run", ps, "--cache", "store"])
        .current_dir(dir.path())
        .env("AUGSPLAT_CLAIM_STALE_SECS", "600")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // `status` shows the node waiting for that driver.
    let t = std::time::Instant::now();
    let status = loop {
        let s = augsplat(dir.path(), &["status", "--cache", "store"]);
        let s = text(&s);
        if s.contains("waiting") && s.contains("another-host") {
            break s;
        }
        assert!(
            t.elapsed().as_secs() < 30,
            "status never showed the wait:\n{s}"
        );
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    assert!(status.contains("pid 4242 on another-host"), "{status}");
    // The other driver goes away without a result: the run computes it itself.
    std::fs::remove_file(&claim).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("waiting: `hello` is being computed by pid 4242 on another-host"),
        "{err}"
    );
    let s = text(&augsplat(dir.path(), &["status", "--cache", "store"]));
    assert!(!s.contains("another-host"), "{s}");
}

#[test]
fn status_all_lists_the_last_runs_newest_first() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("p.ron");
    std::fs::write(&p, PIPELINE).unwrap();
    let q = dir.path().join("q.ron");
    std::fs::write(&q, PIPELINE.replace("hello", "bye")).unwrap();
    for f in [&p, &q] {
        let out = augsplat(
            dir.path(),
            &["run", f.to_str().unwrap(), "--cache", "store", "-q"],
        );
        assert!(out.status.success(), "{}", text(&out));
        // Run ids hold the start second: keep the runs' order unambiguous.
        std::thread::sleep(std::time::Duration::from_millis(1100));
    }
    let latest = text(&augsplat(dir.path(), &["status", "--cache", "store"]));
    assert!(
        latest.contains("q.ron") && !latest.contains("p.ron"),
        "{latest}"
    );
    let out = augsplat(dir.path(), &["status", "--all", "--cache", "store"]);
    assert!(out.status.success(), "{}", text(&out));
    let t = String::from_utf8_lossy(&out.stdout).to_string();
    let lines: Vec<&str> = t.lines().collect();
    assert_eq!(lines.len(), 2, "{t}");
    assert!(
        lines[0].contains("q.ron") && lines[0].contains("finished"),
        "{t}"
    );
    assert!(
        lines[1].contains("p.ron") && lines[1].contains("1 ran"),
        "{t}"
    );
}
