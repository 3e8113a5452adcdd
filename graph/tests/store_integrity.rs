//! The store proves what it holds: a flipped bit is found by `verify` and refused as a node's
//! input, a missing blob makes an entry broken (reported by `plan`, recomputed by `run`), and
//! `gc` never removes anything when it cannot read a kept entry.

mod common;

use common::env::{statuses, Env, CHAIN};
use std::fs;
use std::path::{Path, PathBuf};

/// Makes `p` writable and flips one bit of its first byte in place (same inode, same size),
/// as disk corruption or a stray write through a hard link would.
fn flip_bit(p: &Path) {
    let mut perm = fs::metadata(p).unwrap().permissions();
    #[allow(clippy::permissions_set_readonly_false)]
    perm.set_readonly(false);
    fs::set_permissions(p, perm).unwrap();
    let mut bytes = fs::read(p).unwrap();
    bytes[0] ^= 0x04;
    fs::write(p, bytes).unwrap();
}

/// Every file below `dir`, sorted.
fn files_below(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in fs::read_dir(&d).unwrap().flatten() {
            if e.file_type().unwrap().is_dir() {
                stack.push(e.path());
            } else {
                out.push(e.path());
            }
        }
    }
    out.sort();
    out
}

/// The toy chain run once on a fresh store (its recorder emptied).
fn chain_run() -> (
    Env,
    PathBuf,
    augsplat_graph::Plan,
    augsplat_graph::RunReport,
) {
    let env = Env::new();
    let f = env.write("p.ron", CHAIN);
    let (plan, report) = env.run(&f, &[]);
    assert!(report.success());
    env.take();
    (env, f, plan, report)
}

#[test]
fn a_flipped_bit_is_named_by_verify_refused_as_input_and_repaired() {
    let (env, _, plan, report) = chain_run();
    let store = env.engine.store();
    assert!(store.verify(false).unwrap().clean());
    let src_out = report.output_dir(&plan, store, "src", "out").unwrap();
    // The stored value is a hard link to its blob: flipping the file flips the blob.
    flip_bit(&src_out.join("value.txt"));

    let v = store.verify(false).unwrap();
    assert!(!v.clean());
    assert!(
        v.damage
            .iter()
            .any(|p| p.detail.contains("not to its name")),
        "the blob is named: {:?}",
        v.damage
    );
    let broken = v
        .broken_actions
        .iter()
        .find(|p| p.node.as_deref() == Some("src"))
        .unwrap_or_else(|| panic!("src's entry is named: {:?}", v.broken_actions));
    assert_eq!(broken.key.as_ref().unwrap().len(), 64);

    // A dependent that must run refuses the damaged input, naming it; the damaged output is
    // set aside, so the next run recomputes it and the store heals without `verify`.
    let f2 = env.write("p.ron", &CHAIN.replace(r#"suffix: "!""#, r#"suffix: "%""#));
    let (plan2, report2) = env.run(&f2, &[]);
    assert!(!report2.success());
    assert!(
        env.take().is_empty(),
        "no node computed on the damaged input"
    );
    let s = report2.summary_json(&plan2).to_string();
    assert!(s.contains("damaged store entry"), "{s}");
    assert!(s.contains("run again to recompute it"), "{s}");

    let (plan3, report3) = env.run(&f2, &[]);
    assert!(report3.success());
    assert!(env.take().contains(&"src".to_string()));
    assert_eq!(env.read(&plan3, &report3, "app", "out"), "abab|0.5%");
    // What `src`'s damage tainted (the entries that read it before) `verify --repair` removes.
    store.verify(true).unwrap();
    assert!(
        store.verify(false).unwrap().clean(),
        "repaired store is sound"
    );

    let clean = Env::new();
    let fc = clean.write("p.ron", &CHAIN.replace(r#"suffix: "!""#, r#"suffix: "%""#));
    assert_eq!(clean.keys(&fc, &[]), env.keys(&f2, &[]));
}

#[test]
fn a_deleted_blob_is_broken_in_plan_and_recomputed_by_run() {
    let (env, f, plan, report) = chain_run();
    let store = env.engine.store();
    // Remove the blob of `app`'s output `out` (its content is `app`'s alone; the hard-linked
    // output folder keeps a copy, but the store no longer holds the blob).
    let app_out = report.output_dir(&plan, store, "app", "out").unwrap();
    let m = store.output_of_folder(&app_out).unwrap();
    let manifest = store.read_manifest(&m).unwrap();
    for e in manifest.entries.iter().filter(|e| !e.hash.is_empty()) {
        let blob = store.root().join("blobs").join(&e.hash[..2]).join(&e.hash);
        fs::remove_file(blob).unwrap();
    }
    let text = env
        .engine
        .plan_text(&env.engine.load(&f, &[]).unwrap(), &[])
        .unwrap();
    let line = text.lines().find(|l| l.starts_with("app")).unwrap();
    assert!(line.contains("broken"), "{text}");
    assert!(line.contains("missing"), "{text}");
    let gc = env.engine.gc(true, false).unwrap();
    assert!(
        gc.broken.iter().any(|b| b.contains("`app`")),
        "{:?}",
        gc.broken
    );
    assert!(!store.verify(false).unwrap().clean());

    let (plan2, report2) = env.run(&f, &[]);
    assert!(report2.success());
    // `app` is recomputed; `len` reads identical bytes again, so it stays cached.
    assert_eq!(env.take(), ["app"]);
    let st = statuses(&plan2, &report2);
    assert!(
        st.contains(&("app".to_string(), "ran".to_string())),
        "{st:?}"
    );
    assert!(
        st.contains(&("len".to_string(), "cached".to_string())),
        "{st:?}"
    );
    assert!(
        store.verify(false).unwrap().clean(),
        "the rerun healed the store"
    );
}

#[test]
fn gc_stops_on_an_unreadable_kept_manifest_and_removes_nothing() {
    let (env, _, plan, report) = chain_run();
    // Something gc would remove: the previous outputs of `app` after an edit.
    let f2 = env.write("p.ron", &CHAIN.replace(r#"suffix: "!""#, r#"suffix: "%""#));
    assert!(env.run(&f2, &[]).1.success());
    let store = env.engine.store();
    let src_out = report.output_dir(&plan, store, "src", "out").unwrap();
    let m = store.output_of_folder(&src_out).unwrap();
    let mpath = store
        .root()
        .join("manifests")
        .join(format!("{}.json", augsplat_graph::store::hex(&m)));
    fs::write(&mpath, b"{ not json").unwrap();
    let before = files_below(store.root());
    let err = env.engine.gc(false, false).unwrap_err().to_string();
    assert!(err.contains(&mpath.display().to_string()), "{err}");
    assert!(err.contains("nothing was removed"), "{err}");
    assert_eq!(files_below(store.root()), before, "gc removed something");

    // With --repair the unreadable manifest is dropped first, then gc proceeds; the next run
    // recomputes `src`.
    let rep = env.engine.gc(false, true).unwrap();
    assert!(
        rep.repaired.iter().any(|p| p.contains("manifests")),
        "{:?}",
        rep.repaired
    );
    assert!(rep.actions_removed > 0);
    env.take();
    assert!(env.run(&f2, &[]).1.success());
    assert!(env.take().contains(&"src".to_string()));
}

#[test]
fn input_checks_hash_every_file_and_see_bit_rot_that_keeps_size_mtime_and_inode() {
    let (env, _, plan, report) = chain_run();
    let store = env.engine.store();
    let out = report.output_dir(&plan, store, "src", "out").unwrap();
    let m = store.output_of_folder(&out).unwrap();
    store.check_output(&m).unwrap();
    store.check_output(&m).unwrap();
    // Bit rot: same inode, same size, and the modification time put back.
    let f = out.join("value.txt");
    let mtime = fs::metadata(&f).unwrap().modified().unwrap();
    flip_bit(&f);
    fs::File::options()
        .write(true)
        .open(&f)
        .unwrap()
        .set_modified(mtime)
        .unwrap();
    assert_eq!(fs::metadata(&f).unwrap().modified().unwrap(), mtime);
    let err = store.check_output(&m).unwrap_err();
    assert!(err.contains("content hashes to"), "{err}");
}

/// A node kind that appends to its input file (what a buggy node or script might do).
struct Vandal;
impl augsplat_graph::Node for Vandal {
    const KIND: &'static str = "Vandal";
    const VERSION: u32 = 1;
    type Args = ();
    fn inputs(_: &()) -> Vec<augsplat_graph::InputDecl> {
        vec![augsplat_graph::InputDecl::one("a")]
    }
    fn outputs(_: &()) -> Vec<String> {
        vec!["out".into()]
    }
    fn run(_: &(), ctx: &mut augsplat_graph::RunContext) -> Result<(), augsplat_graph::NodeError> {
        let p = ctx.input("a")?.join("value.txt");
        let mut perm = fs::metadata(&p)?.permissions();
        #[allow(clippy::permissions_set_readonly_false)]
        perm.set_readonly(false);
        fs::set_permissions(&p, perm)?;
        use std::io::Write;
        fs::OpenOptions::new()
            .append(true)
            .open(&p)?
            .write_all(b"!")?;
        Ok(())
    }
}

/// Runs pipeline `text` with the `Vandal` kind registered, in a fresh store; returns the
/// engine (for its store) and the run's summary, which must report a failure.
fn run_vandal(dir: &std::path::Path, text: &str) -> (augsplat_graph::Engine, String) {
    let mut reg = common::registry(common::Recorder::new());
    reg.register::<Vandal>();
    let engine = augsplat_graph::Engine::new(reg, dir.join("cache")).unwrap();
    let f = dir.join("p.ron");
    fs::write(&f, text).unwrap();
    let plan = engine.load(&f, &[]).unwrap();
    let report = engine
        .run(&plan, &augsplat_graph::RunOptions::default())
        .unwrap();
    assert!(!report.success());
    let s = report.summary_json(&plan).to_string();
    (engine, s)
}

#[test]
fn a_node_that_writes_to_its_input_fails_and_nothing_is_cached() {
    let dir = tempfile::tempdir().unwrap();
    let (engine, s) = run_vandal(
        dir.path(),
        r#"(nodes: {
            "src": (kind: "Source", args: (value: "ab", count: 1)),
            "bad": (kind: "Vandal", inputs: { "a": "src" }),
        })"#,
    );
    assert!(
        s.contains("changed its input `a`") && s.contains("value.txt"),
        "{s}"
    );
    assert!(s.contains("verify --repair"), "{s}");
    // No entry for `bad`; `verify` sees the damage the node did to `src`'s stored output.
    let v = engine.store().verify(false).unwrap();
    assert!(
        v.broken_actions
            .iter()
            .any(|p| p.node.as_deref() == Some("src")),
        "{v:?}"
    );
    assert_eq!(v.actions, 1, "only `src` has an entry");
}

#[test]
fn a_gated_node_that_writes_to_its_input_fails_too() {
    // The gate's hidden slot must not hide the input check.
    let dir = tempfile::tempdir().unwrap();
    let (_, s) = run_vandal(
        dir.path(),
        r#"(nodes: {
            "decide": (kind: "Decide", args: (run: true)),
            "src": (kind: "Source", args: (value: "ab", count: 1)),
            "bad": (kind: "Vandal", gate: "decide.decision", inputs: { "a": "src" }),
        })"#,
    );
    assert!(s.contains("changed its input `a`"), "{s}");
}
