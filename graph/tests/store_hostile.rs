//! The store under hostile conditions: bit rot that keeps a file's size, modification time and
//! inode, damaged folders and manifests that `run` must heal, stray files and special files in
//! the store, programs that hard-link a user's file into their output, checkpoints placed in
//! another computation's folder, orphaned checkpoints, mistyped store paths, and inputs reached
//! through symbolic links.

mod common;

use augsplat_graph::store::{hex, Store};
use augsplat_graph::{EngineError, RunContext};
use common::env::{statuses, Env, CHAIN};
use std::fs;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Makes `p` writable.
fn writable(p: &Path) {
    let mut perm = fs::metadata(p).unwrap().permissions();
    #[allow(clippy::permissions_set_readonly_false)]
    perm.set_readonly(false);
    fs::set_permissions(p, perm).unwrap();
}

/// Flips one bit of `p` in place and puts its modification time back: same inode, size and
/// mtime, as bit rot on a disk looks.
fn rot(p: &Path) {
    let mtime = fs::metadata(p).unwrap().modified().unwrap();
    writable(p);
    let mut bytes = fs::read(p).unwrap();
    bytes[0] ^= 0x10;
    fs::write(p, bytes).unwrap();
    fs::File::options()
        .write(true)
        .open(p)
        .unwrap()
        .set_modified(mtime)
        .unwrap();
}

/// The chain run once on a fresh store; returns the environment, the pipeline file and the
/// output folder of each of its instances' `out`.
fn chain() -> (Env, PathBuf, Vec<(String, PathBuf)>) {
    let env = Env::new();
    let f = env.write("p.ron", CHAIN);
    let (plan, report) = env.run(&f, &[]);
    assert!(report.success());
    env.take();
    let outs = ["src", "app", "len", "other"]
        .iter()
        .map(|n| {
            let d = report
                .output_dir(&plan, env.engine.store(), n, "out")
                .unwrap();
            (n.to_string(), d)
        })
        .collect();
    (env, f, outs)
}

fn out_of<'a>(outs: &'a [(String, PathBuf)], name: &str) -> &'a Path {
    &outs.iter().find(|(n, _)| n == name).unwrap().1
}

#[test]
fn bit_rot_taints_every_entry_that_read_it_and_repair_removes_them_with_descendants() {
    let (env, f, outs) = chain();
    let store = env.engine.store();
    rot(&out_of(&outs, "src").join("value.txt"));

    let v = store.verify(false).unwrap();
    assert!(!v.clean());
    let tainted: Vec<&str> = v
        .broken_actions
        .iter()
        .filter(|p| p.detail.starts_with("tainted"))
        .filter_map(|p| p.node.as_deref())
        .collect();
    // `app` and `other` read `src`'s damaged output; `len` read `app`'s.
    for n in ["app", "other", "len"] {
        assert!(
            tainted.contains(&n),
            "{n} is tainted: {:?}",
            v.broken_actions
        );
    }
    assert!(v
        .broken_actions
        .iter()
        .any(|p| p.node.as_deref() == Some("src") && !p.detail.starts_with("tainted")));

    let r = store.verify(true).unwrap();
    assert!(r.removed.len() >= 4, "{:?}", r.removed);
    assert!(store.verify(false).unwrap().clean());
    let (plan, report) = env.run(&f, &[]);
    assert!(report.success());
    assert_eq!(env.take(), ["app", "len", "other", "src"]);
    assert_eq!(env.read(&plan, &report, "app", "out"), "abab|0.5!");
}

#[test]
fn run_heals_a_damaged_manifest_file_it_recomputes() {
    let (env, f, outs) = chain();
    let store = env.engine.store();
    let m = store.output_of_folder(out_of(&outs, "src")).unwrap();
    let mpath = store
        .root()
        .join("manifests")
        .join(format!("{}.json", hex(&m)));
    writable(&mpath);
    fs::write(&mpath, b"{\"entries\":[]}").unwrap();

    let (plan, report) = env.run(&f, &[]);
    assert!(report.success(), "{}", report.summary_json(&plan));
    assert_eq!(env.take(), ["src"], "only the broken entry is recomputed");
    assert!(
        store.read_manifest(&m).is_ok(),
        "the manifest was rewritten"
    );
    assert!(store.verify(false).unwrap().clean());
    let (plan, report) = env.run(&f, &[]);
    assert!(statuses(&plan, &report).iter().all(|(_, s)| s == "cached"));
}

#[test]
fn run_heals_a_damaged_output_folder_it_recomputes() {
    let (env, f, outs) = chain();
    let store = env.engine.store();
    let dir = out_of(&outs, "app");
    writable(dir);
    fs::remove_file(dir.join("value.txt")).unwrap();

    let (plan, report) = env.run(&f, &[]);
    assert!(report.success(), "{}", report.summary_json(&plan));
    assert_eq!(env.take(), ["app"]);
    assert_eq!(env.read(&plan, &report, "app", "out"), "abab|0.5!");
    assert!(store.verify(false).unwrap().clean());
}

#[test]
fn an_extra_file_in_a_stored_output_is_damage_for_verify_and_the_input_check() {
    let (env, _, outs) = chain();
    let store = env.engine.store();
    let dir = out_of(&outs, "src");
    writable(dir);
    fs::write(dir.join("stray.txt"), b"not in the manifest").unwrap();

    let v = store.verify(false).unwrap();
    assert!(
        v.damage
            .iter()
            .any(|p| p.path.ends_with("stray.txt") && p.detail.contains("manifest")),
        "{:?}",
        v.damage
    );
    let m = store.output_of_folder(dir).unwrap();
    let err = store.check_output(&m).unwrap_err();
    assert!(err.contains("stray.txt"), "{err}");

    // A node that must read it refuses, and the next run recomputes the damaged output.
    let f2 = env.write("p.ron", &CHAIN.replace(r#"suffix: "!""#, r#"suffix: "+""#));
    let (_, report) = env.run(&f2, &[]);
    assert!(!report.success());
    assert!(env.take().is_empty());
    let (plan, report) = env.run(&f2, &[]);
    assert!(report.success());
    assert_eq!(env.read(&plan, &report, "app", "out"), "abab|0.5+");
}

#[cfg(unix)]
fn mkfifo(p: &Path) {
    let ok = std::process::Command::new("mkfifo")
        .arg(p)
        .status()
        .unwrap()
        .success();
    assert!(ok, "mkfifo {}", p.display());
}

/// Runs `f` on another thread and fails the test if it takes longer than `secs`.
fn within<T: Send + 'static>(secs: u64, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(Duration::from_secs(secs))
        .expect("it hung (a special file was opened?)")
}

#[cfg(unix)]
#[test]
fn a_fifo_in_blobs_or_in_an_output_is_reported_never_opened() {
    let (env, _, outs) = chain();
    let store = env.engine.store().clone();
    let fifo = store
        .root()
        .join("blobs/ab")
        .join(format!("ab{}", "0".repeat(62)));
    fs::create_dir_all(fifo.parent().unwrap()).unwrap();
    mkfifo(&fifo);
    let dir = out_of(&outs, "src").to_path_buf();
    writable(&dir);
    mkfifo(&dir.join("pipe"));

    let v = {
        let store = store.clone();
        within(30, move || store.verify(false).unwrap())
    };
    assert!(
        v.damage
            .iter()
            .any(|p| p.path == fifo && p.detail.contains("not a plain file")),
        "{:?}",
        v.damage
    );
    assert!(
        v.damage.iter().any(|p| p.path.ends_with("pipe")),
        "{:?}",
        v.damage
    );
    let m = store.output_of_folder(&dir).unwrap();
    let err = within(30, move || store.check_output(&m).unwrap_err());
    assert!(err.contains("pipe"), "{err}");
}

#[cfg(unix)]
#[test]
fn a_program_that_hard_links_a_users_file_leaves_that_file_alone() {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let env = Env::new();
    let user = env.dir.path().join("notes.txt");
    fs::write(&user, b"first draft\n").unwrap();
    let f = env.write(
        "p.ron",
        &format!(
            r#"(nodes: {{ "grab": (kind: "Command", args: (program: "ln", args: ["{}", "{{out:out}}/notes.txt"])) }})"#,
            user.display()
        ),
    );
    let (plan, report) = env.run(&f, &[]);
    assert!(report.success(), "{}", report.summary_json(&plan));
    let meta = fs::metadata(&user).unwrap();
    assert_eq!(meta.nlink(), 1, "the user's file is not tied to the store");
    assert_ne!(
        meta.permissions().mode() & 0o200,
        0,
        "the user's file is still writable"
    );
    fs::write(&user, b"second draft\n").unwrap();
    let out = report
        .output_dir(&plan, env.engine.store(), "grab", "out")
        .unwrap();
    assert_eq!(
        fs::read_to_string(out.join("notes.txt")).unwrap(),
        "first draft\n"
    );
    assert!(env.engine.store().verify(false).unwrap().clean());
}

#[test]
fn a_checkpoint_made_for_another_key_is_ignored() {
    let dir = tempfile::tempdir().unwrap();
    let ctx = |ckpt: &str| {
        RunContext::standalone(vec![], &["out"], &dir.path().join("o"), 0, 1)
            .unwrap()
            .with_checkpoints(dir.path().join(ckpt), 1)
    };
    let a = ctx("a");
    a.save_checkpoint(b"state of a").unwrap();
    assert_eq!(a.load_checkpoint().as_deref(), Some(&b"state of a"[..]));
    // Another computation's checkpoint moved into this one's folder.
    fs::create_dir_all(dir.path().join("b")).unwrap();
    fs::copy(
        dir.path().join("a/state.ckpt"),
        dir.path().join("b/state.ckpt"),
    )
    .unwrap();
    assert_eq!(ctx("b").load_checkpoint(), None);
}

/// `gc` on the test's store, retried while it reports the store busy: a child process that
/// another test of this binary forks inherits this test's lock descriptors until it execs,
/// and under load that window can overlap the call (no run of this test uses the store then).
fn gc_when_free(env: &Env) -> augsplat_graph::GcReport {
    for _ in 0..100 {
        match env.engine.gc(false, false) {
            Err(augsplat_graph::EngineError::Busy(_)) => {
                std::thread::sleep(std::time::Duration::from_millis(20))
            }
            other => return other.unwrap(),
        }
    }
    panic!("the store stayed busy for 2 s")
}

#[test]
fn gc_removes_checkpoints_that_no_pipeline_will_resume() {
    let (env, _, _) = chain();
    let store = env.engine.store();
    let orphan = store.root().join("checkpoints").join("11".repeat(32));
    let resumable = store.root().join("checkpoints").join("22".repeat(32));
    for d in [&orphan, &resumable] {
        fs::create_dir_all(d).unwrap();
        fs::write(d.join("state.ckpt"), b"x").unwrap();
    }
    // A run that was interrupted while computing the second key names it in its status.
    fs::write(
        store.root().join("runs/status/interrupted.json"),
        format!(
            r#"{{"nodes": [{{"name": "n", "key": "{}"}}]}}"#,
            "22".repeat(32)
        ),
    )
    .unwrap();
    let rep = gc_when_free(&env);
    assert_eq!(rep.checkpoints_removed, 1);
    assert!(!orphan.exists());
    assert!(resumable.exists());
}

#[test]
fn only_opening_to_run_creates_a_store() {
    let dir = tempfile::tempdir().unwrap();
    let typo = dir.path().join("cahce");
    match Store::open_existing(&typo) {
        Err(EngineError::NoStore(p)) => assert_eq!(p, typo),
        other => panic!("expected NoStore, got {other:?}"),
    }
    assert!(!typo.exists(), "nothing was created");
    Store::open(&typo).unwrap();
    assert!(Store::open_existing(&typo).is_ok());
}

#[cfg(unix)]
#[test]
fn inputs_are_followed_through_links_and_a_moved_link_reruns_and_is_explained() {
    use std::os::unix::fs::symlink;
    let env = Env::new();
    let root = env.dir.path();
    for (d, text) in [("disk1", "one\n"), ("disk2", "two\n")] {
        fs::create_dir_all(root.join(d)).unwrap();
        fs::write(root.join(d).join("a.txt"), text).unwrap();
    }
    fs::create_dir_all(root.join("capture")).unwrap();
    symlink(root.join("disk1"), root.join("capture/images")).unwrap();
    let f = env.write(
        "p.ron",
        r#"(nodes: { "read": (kind: "Command", args: (program: "sh", inputs: ["c"], args: ["-c", "cat {in:c}/images/a.txt > {out:out}/a.txt"]), inputs: { "c": Path("capture") }) })"#,
    );
    let (plan, report) = env.run(&f, &[]);
    assert!(report.success(), "{}", report.summary_json(&plan));
    let out = report
        .output_dir(&plan, env.engine.store(), "read", "out")
        .unwrap();
    assert_eq!(fs::read_to_string(out.join("a.txt")).unwrap(), "one\n");

    // The link now points at another disk: the key changes, the node reruns, `why` says so.
    fs::remove_file(root.join("capture/images")).unwrap();
    symlink(root.join("disk2"), root.join("capture/images")).unwrap();
    let plan2 = env.engine.load(&f, &[]).unwrap();
    let why = env.engine.why_text(&plan2, "read").unwrap();
    assert!(why.contains("now points to"), "{why}");
    assert!(why.contains("disk2"), "{why}");
    let (plan2, report2) = env.run(&f, &[]);
    assert!(report2.success());
    let out2 = report2
        .output_dir(&plan2, env.engine.store(), "read", "out")
        .unwrap();
    assert_eq!(fs::read_to_string(out2.join("a.txt")).unwrap(), "two\n");

    // A link back into a folder it lies in is a cycle: refused with a message.
    symlink(root.join("capture"), root.join("capture/loop")).unwrap();
    let err = match env.engine.load(&f, &[]) {
        Ok(_) => panic!("a cycle of links loads"),
        Err(e) => e.to_string(),
    };
    assert!(err.contains("cycle"), "{err}");
}

#[test]
fn an_external_input_changed_after_loading_is_refused_before_the_node_runs() {
    let env = Env::new();
    let data = env.dir.path().join("data.txt");
    fs::write(&data, b"before\n").unwrap();
    let f = env.write(
        "p.ron",
        r#"(nodes: { "read": (kind: "Command", args: (program: "sh", inputs: ["d"], args: ["-c", "cat {in:d} > {out:out}/x"]), inputs: { "d": Path("data.txt") }) })"#,
    );
    let plan = env.engine.load(&f, &[]).unwrap();
    // The content changes between loading (the key) and running (what the node would read).
    fs::write(&data, b"after!\n").unwrap();
    let report = env.engine.run(&plan, &Default::default()).unwrap();
    assert!(!report.success());
    let s = report.summary_json(&plan).to_string();
    assert!(s.contains("changed after the pipeline was loaded"), "{s}");
    assert_eq!(
        env.engine.store().verify(false).unwrap().actions,
        0,
        "nothing was stored under the old key"
    );
}
