//! Engine behaviour with toy node kinds that record every execution. Each test owns its
//! recorder (through its `Env`), so the tests run in parallel.

mod common;

use augsplat_graph::{Engine, RunOptions};
use common::{registry, Recorder};
use std::path::{Path, PathBuf};
use std::sync::Arc;

struct Env {
    dir: tempfile::TempDir,
    engine: Engine,
    /// What this test's toy nodes did.
    rec: Arc<Recorder>,
}

impl Env {
    fn new() -> Env {
        let dir = tempfile::tempdir().unwrap();
        let rec = Recorder::new();
        let engine = Engine::new(registry(rec.clone()), dir.path().join("cache")).unwrap();
        Env { dir, engine, rec }
    }
    /// The nodes run since the last `take`, sorted.
    fn take(&self) -> Vec<String> {
        self.rec.take()
    }
    fn write(&self, name: &str, text: &str) -> PathBuf {
        let p = self.dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    }
    fn run(&self, file: &Path, sets: &[&str]) -> (augsplat_graph::Plan, augsplat_graph::RunReport) {
        self.run_opts(
            file,
            sets,
            &RunOptions {
                jobs: 2,
                ..Default::default()
            },
        )
    }
    fn run_opts(
        &self,
        file: &Path,
        sets: &[&str],
        opts: &RunOptions,
    ) -> (augsplat_graph::Plan, augsplat_graph::RunReport) {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let plan = self
            .engine
            .load(file, &sets)
            .unwrap_or_else(|e| panic!("{e}"));
        let report = self.engine.run(&plan, opts).unwrap();
        (plan, report)
    }
    fn keys(&self, file: &Path, sets: &[&str]) -> Vec<(String, String)> {
        let (plan, report) = self.run(file, sets);
        let s = report.summary_json(&plan);
        s["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| {
                (
                    n["name"].as_str().unwrap().to_string(),
                    n["key"].as_str().unwrap().to_string(),
                )
            })
            .collect()
    }
    fn read(
        &self,
        plan: &augsplat_graph::Plan,
        report: &augsplat_graph::RunReport,
        inst: &str,
        out: &str,
    ) -> String {
        let d = report
            .output_dir(plan, self.engine.store(), inst, out)
            .unwrap_or_else(|| panic!("no output {inst}.{out}"));
        std::fs::read_to_string(d.join("value.txt")).unwrap()
    }
}

const CHAIN: &str = r#"// a small chain with a fan-out
(
    nodes: {
        "src": (kind: "Source", args: (value: "ab", count: 2)),
        "app": (kind: "Append", args: (suffix: "!"), inputs: { "a": "src" }),
        "len": (kind: "Len", inputs: { "a": "app.out" }),
        "other": (kind: "Append", args: (suffix: "?"), inputs: { "a": "src.out" }),
    },
)
"#;

fn statuses(
    plan: &augsplat_graph::Plan,
    report: &augsplat_graph::RunReport,
) -> Vec<(String, String)> {
    let s = report.summary_json(plan);
    let mut v: Vec<(String, String)> = s["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            (
                n["name"].as_str().unwrap().into(),
                n["status"].as_str().unwrap().into(),
            )
        })
        .collect();
    v.sort();
    v
}

#[test]
fn first_run_runs_all_second_none_and_arg_change_reruns_descendants() {
    let env = Env::new();
    let f = env.write("p.ron", CHAIN);
    let (plan, report) = env.run(&f, &[]);
    assert!(report.success());
    assert_eq!(env.take(), ["app", "len", "other", "src"]);
    assert_eq!(env.read(&plan, &report, "app", "out"), "abab|0.5!");
    assert_eq!(env.read(&plan, &report, "len", "out"), "9");
    let first: Vec<f64> = report.results.iter().flatten().map(|r| r.seconds).collect();
    let (plan, report) = env.run(&f, &[]);
    assert!(env.take().is_empty(), "second run must run nothing");
    assert!(statuses(&plan, &report).iter().all(|(_, s)| s == "cached"));
    // A cached node takes no time in this run and reports, for the table, its compute time
    // recorded by the run that computed it.
    let second: Vec<(f64, f64)> = report
        .results
        .iter()
        .flatten()
        .map(|r| (r.seconds, r.computed_seconds))
        .collect();
    assert_eq!(first.len(), second.len());
    for (a, (b, b_computed)) in first.iter().zip(&second) {
        assert!(*a > 0.0);
        assert_eq!(*b, 0.0);
        assert_eq!(b_computed, a);
    }
    let table = report.table(&plan);
    assert!(table.contains("computed s"), "{table}");
    assert!(table.contains("compute times"), "{table}");
    // Change `app`'s suffix: app and len rerun, src and other stay cached.
    let f2 = env.write("p.ron", &CHAIN.replace(r#"suffix: "!""#, r#"suffix: "%""#));
    let (plan, report) = env.run(&f2, &[]);
    assert_eq!(env.take(), ["app", "len"]);
    let expect: Vec<(String, String)> = [
        ("app", "ran"),
        ("len", "ran"),
        ("other", "cached"),
        ("src", "cached"),
    ]
    .iter()
    .map(|(a, b)| (a.to_string(), b.to_string()))
    .collect();
    assert_eq!(statuses(&plan, &report), expect);
    // Changing the source reruns everything downstream of it.
    let f3 = env.write("p.ron", &CHAIN.replace("count: 2", "count: 3"));
    env.run(&f3, &[]);
    assert_eq!(env.take(), ["app", "len", "other", "src"]);
}

#[test]
fn early_cutoff_stops_the_cascade() {
    let env = Env::new();
    let text = r#"(nodes: {
        "src": (kind: "Source", args: (value: "abc")),
        "len": (kind: "Len", inputs: { "a": "src" }),
        "down": (kind: "Append", args: (suffix: "x"), inputs: { "a": "len" }),
    })"#;
    let f = env.write("p.ron", text);
    env.run(&f, &[]);
    assert_eq!(env.take(), ["down", "len", "src"]);
    // Same length, different bytes: src and len rerun, len's output is byte-identical, so
    // `down` stays cached.
    let f = env.write("p.ron", &text.replace("\"abc\"", "\"xyz\""));
    let (plan, report) = env.run(&f, &[]);
    assert_eq!(env.take(), ["len", "src"]);
    let st = statuses(&plan, &report);
    assert!(st.contains(&("down".into(), "cached".into())), "{st:?}");
}

#[test]
fn formatting_only_edits_change_no_key() {
    let env = Env::new();
    let a = env.write("a.ron", r#"(nodes: {"src": (kind: "Source", args: (value: "v", count: 2)), "app": (kind: "Append", args: (suffix: "s"), inputs: {"a": "src.out"})})"#);
    let b = env.write(
        "b.ron",
        r#"
// comments, whitespace, field order, explicit defaults, different reference spelling
(
    nodes: {
        "app": (
            inputs: { "a": "src" },   /* one output: `.out` may be omitted */
            args: ( sleep_ms: 0, suffix: "s" ),
            kind: "Append",
        ),
        "src": (
            kind: "Source",
            args: (
                count: 2,
                nested: (alpha: 0.5, tags: []),   // the defaults, written out
                value: "v",
            ),
        ),
    },
)"#,
    );
    let mut ka = env.keys(&a, &[]);
    let mut kb = env.keys(&b, &[]);
    ka.sort();
    kb.sort();
    assert_eq!(ka, kb);
    assert_eq!(
        env.take(),
        ["app", "src"],
        "the second file must run nothing new"
    );
}

#[test]
fn set_behaves_like_editing_the_file() {
    let env = Env::new();
    let f = env.write("p.ron", CHAIN);
    env.run(&f, &[]);
    env.take();
    let set = env.keys(&f, &["app.suffix=\"%\"", "src.nested.alpha=0.25"]);
    assert_eq!(env.take(), ["app", "len", "other", "src"]);
    let edited = env.write(
        "q.ron",
        &CHAIN
            .replace(r#"suffix: "!""#, r#"suffix: "%""#)
            .replace("count: 2", "count: 2, nested: (alpha: 0.25)"),
    );
    let ed = env.keys(&edited, &[]);
    assert!(
        env.take().is_empty(),
        "the edited file must find everything cached"
    );
    assert_eq!(set, ed);
}

#[test]
fn sweep_runs_shared_upstream_once_with_readable_names() {
    let env = Env::new();
    let f = env.write(
        "s.ron",
        r#"(
        nodes: {
            "src": (kind: "Source", args: (value: "v", sleep_ms: 20)),
            "app": (kind: "Append", inputs: { "a": "src" }),
        },
        sweep: Grid({ "app.suffix": ["a", "b", "c", "d"] }),
    )"#,
    );
    let (plan, report) = env.run(&f, &[]);
    let rec = env.take();
    assert_eq!(rec.iter().filter(|n| *n == "src").count(), 1, "{rec:?}");
    assert_eq!(rec.len(), 5);
    let names: Vec<String> = statuses(&plan, &report)
        .into_iter()
        .map(|(n, _)| n)
        .collect();
    assert_eq!(
        names,
        [
            "app@suffix=\"a\"",
            "app@suffix=\"b\"",
            "app@suffix=\"c\"",
            "app@suffix=\"d\"",
            "src"
        ]
    );
    assert_eq!(
        env.read(&plan, &report, "app@suffix=\"c\"", "out"),
        "v|0.5c"
    );
    // Zip over two axes, one upstream, one downstream: the upstream varies too.
    let f = env.write(
        "z.ron",
        r#"(
        nodes: {
            "src": (kind: "Source", args: (value: "v")),
            "app": (kind: "Append", inputs: { "a": "src" }),
        },
        sweep: Zip({ "app.suffix": ["a", "b"], "src.count": [2, 3] }),
    )"#,
    );
    let (plan, report) = env.run(&f, &[]);
    assert_eq!(
        env.take(),
        [
            "app@suffix=\"a\",count=2",
            "app@suffix=\"b\",count=3",
            "src@suffix=\"a\",count=2",
            "src@suffix=\"b\",count=3"
        ]
    );
    assert_eq!(
        env.read(&plan, &report, "app@suffix=\"b\",count=3", "out"),
        "vvv|0.5b"
    );
    // Plan shows new vs cached per point.
    let f = env.write(
        "s.ron",
        &std::fs::read_to_string(env.dir.path().join("s.ron"))
            .unwrap()
            .replace(r#""d"]"#, r#""d", "e"]"#),
    );
    let plan = env.engine.load(&f, &[]).unwrap();
    let text = env.engine.plan_text(&plan, &[]).unwrap();
    assert!(text.contains("suffix=\"e\": 1 new, 1 cached"), "{text}");
    assert!(text.contains("suffix=\"a\": 0 new, 2 cached"), "{text}");
}

#[test]
fn repeat_growing_runs_one_new_instance_with_its_own_seed() {
    let env = Env::new();
    let text = r#"(
        params: { "members": 5 },
        nodes: {
            "src": (kind: "Source", args: (value: "v")),
            "member": (kind: "Seeded", repeat: Param("members"), args: (seed: 10), inputs: { "a": "src" }),
            "tag": (kind: "Append", repeat: Param("members"), args: (suffix: "t"), inputs: { "a": "member[i]" }),
            "all": (kind: "Concat", args: (sep: ","), inputs: { "items": "tag[*].out" }),
            "two": (kind: "Concat", inputs: { "items": ["tag[0].out", "tag[4].out"] }),
        },
    )"#;
    let f = env.write("r.ron", text);
    let (plan, report) = env.run(&f, &[]);
    assert_eq!(env.take().len(), 1 + 5 + 5 + 2);
    let all = env.read(&plan, &report, "all", "out");
    let parts: Vec<&str> = all.split(',').collect();
    assert_eq!(parts.len(), 5);
    for (i, p) in parts.iter().enumerate() {
        assert!(
            p.starts_with(&format!("{} ", 10 + i)),
            "instance {i} must get seed 10 + {i}: {p}"
        );
    }
    let (plan, report) = env.run(&f, &["params.members=6"]);
    assert_eq!(env.take(), ["all", "member[5]", "tag[5]"]);
    assert_eq!(env.read(&plan, &report, "all", "out").split(',').count(), 6);
    // Kinds without a seed arg get the index in their key: distinct context seeds.
    let f = env.write("q.ron", r#"(nodes: {"x": (kind: "Fail", repeat: 3)})"#);
    let (plan, report) = env.run(&f, &[]);
    let keys: std::collections::BTreeSet<String> = report.summary_json(&plan)["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n["key"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(keys.len(), 3);
}

fn load_err(env: &Env, name: &str, text: &str) -> String {
    let f = env.write(name, text);
    match env.engine.load(&f, &[]) {
        Ok(_) => panic!("{name} should not load"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn errors_have_locations_and_hints_and_run_nothing() {
    let env = Env::new();
    let dir = env.dir.path().canonicalize().unwrap();
    let at = |f: &str, l: u32, c: u32| format!("{}:{l}:{c}", dir.join(f).display());
    let e = load_err(
        &env,
        "syntax.ron",
        "(nodes: {\n  \"a\": (kind: \"Source\" args: ()),\n})",
    );
    assert!(
        e.contains(&at("syntax.ron", 2, 24)) && e.contains("syntax error"),
        "{e}"
    );
    let e = load_err(
        &env,
        "kind.ron",
        "(nodes: {\n  \"a\": (kind: \"Sorce\"),\n})",
    );
    assert!(
        e.contains(&at("kind.ron", 2, 15))
            && e.contains("unknown node kind `Sorce`")
            && e.contains("did you mean Source"),
        "{e}"
    );
    let e = load_err(
        &env,
        "arg.ron",
        "(nodes: {\n  \"a\": (kind: \"Source\", args: (value: \"x\",\n     cuont: 3)),\n})",
    );
    assert!(
        e.contains(&at("arg.ron", 3, 13)) && e.contains("cuont") && e.contains("hint"),
        "{e}"
    );
    let e = load_err(
        &env,
        "type.ron",
        "(nodes: {\n  \"a\": (kind: \"Source\", args: (nested: (alpha: \"high\"))),\n})",
    );
    assert!(
        e.contains(&at("type.ron", 2, 48))
            && e.contains("nested.alpha")
            && e.contains("defaults to 0.5"),
        "{e}"
    );
    let e = load_err(
        &env,
        "dangling.ron",
        "(nodes: {\n  \"a\": (kind: \"Len\", inputs: {\"a\": \"scr.out\"}),\n  \"src\": (kind: \"Source\"),\n})",
    );
    assert!(
        e.contains(&at("dangling.ron", 2, 36))
            && e.contains("`scr`")
            && e.contains("did you mean `src`"),
        "{e}"
    );
    let e = load_err(
        &env,
        "output.ron",
        "(nodes: {\n  \"a\": (kind: \"Len\", inputs: {\"a\": \"b\"}),\n  \"b\": (kind: \"Append\", inputs: {\"a\": \"a\"}),\n})",
    );
    assert!(e.contains("has 2 outputs") && e.contains("out, len"), "{e}");
    let e = load_err(
        &env,
        "cycle.ron",
        "(nodes: {\n  \"a\": (kind: \"Len\", inputs: {\"a\": \"b.out\"}),\n  \"b\": (kind: \"Append\", inputs: {\"a\": \"a\"}),\n})",
    );
    assert!(
        e.contains("cycle") && e.contains("a -> b -> a") || e.contains("b -> a -> b"),
        "{e}"
    );
    assert!(
        e.contains(&dir.join("cycle.ron").display().to_string()),
        "{e}"
    );
    let e = load_err(
        &env,
        "missing.ron",
        "(nodes: {\n  \"a\": (kind: \"Len\"),\n})",
    );
    assert!(
        e.contains(&at("missing.ron", 2, 3)) && e.contains("needs input `a`"),
        "{e}"
    );
    let e = load_err(
        &env,
        "validate.ron",
        "(nodes: {\n  \"a\": (kind: \"Fail\", args: (fail: true, panic: true)),\n})",
    );
    assert!(
        e.contains(&at("validate.ron", 2, 29)) && e.contains("cannot both"),
        "{e}"
    );
    let f = env.write(
        "v2.ron",
        "(nodes: {\"a\": (kind: \"Fail\", args: (fail: true))})",
    );
    let e = env
        .engine
        .load(&f, &["a.panic=true".into()])
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("cannot both") && e.contains("values here come from --set a.panic=true"),
        "{e}"
    );
    let e = load_err(
        &env,
        "empty.ron",
        "(nodes: {\"s\": (kind: \"Seeded\", repeat: 0), \"c\": (kind: \"Concat\", inputs: {\"items\": \"s[*]\"})})",
    );
    assert!(e.contains("gets no folder"), "{e}");
    let e = load_err(&env, "top.ron", "(nodez: {})");
    assert!(
        e.contains(&at("top.ron", 1, 9)) && e.contains("unknown pipeline field"),
        "{e}"
    );
    let e = load_err(
        &env,
        "param.ron",
        "(nodes: {\"a\": (kind: \"Seeded\", repeat: Param(\"n\"))})",
    );
    assert!(e.contains("unknown parameter `n`"), "{e}");
    let f = env.write("ok.ron", CHAIN);
    let e = env
        .engine
        .load(&f, &["app.suffix=oops(".into()])
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("--set app.suffix=oops("), "{e}");
    let e = env
        .engine
        .load(&f, &["app.suffix=3".into()])
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("--set app.suffix=3") && e.contains("suffix"),
        "{e}"
    );
    assert!(env.take().is_empty(), "nothing may run");
}

#[test]
fn failing_node_stores_nothing_and_keeps_ancestors() {
    let env = Env::new();
    let text = r#"(nodes: {
        "src": (kind: "Source", args: (value: "v")),
        "bad": (kind: "Fail", args: (fail: true), inputs: { "a": "src" }),
        "after": (kind: "Len", inputs: { "a": "bad" }),
        "side": (kind: "Len", inputs: { "a": "src" }),
    })"#;
    let f = env.write("f.ron", text);
    let (plan, report) = env.run(&f, &[]);
    assert!(!report.success());
    assert_eq!(env.take(), ["bad", "side", "src"]);
    let st = statuses(&plan, &report);
    let expect: Vec<(String, String)> = [
        ("after", "failed"),
        ("bad", "failed"),
        ("side", "ran"),
        ("src", "ran"),
    ]
    .iter()
    .map(|(a, b)| (a.to_string(), b.to_string()))
    .collect();
    assert_eq!(st, expect);
    let summary = report.summary_json(&plan);
    let error_of = |name: &str| {
        summary["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|n| n["name"] == name)
            .map(|n| n["error"].as_str().unwrap_or("").to_string())
            .unwrap()
    };
    assert!(error_of("bad").contains("toy failure"));
    assert!(error_of("after").contains("an input failed"));
    assert_eq!(error_of("side"), "");
    let fails = report.failures(&plan);
    assert!(
        fails[0].1.contains("toy failure") && fails[0].1.contains("about to decide"),
        "{fails:?}"
    );
    let bad = plan
        .instances
        .iter()
        .find(|i| i.name == "bad")
        .unwrap()
        .comp;
    let key = report.results[bad].as_ref().unwrap().key.unwrap();
    assert!(
        env.engine.store().action(&key).unwrap().is_none(),
        "no cache entry for a failed node"
    );
    // Rerun: ancestors cached, the failing node runs again (and fails again).
    let (_, report) = env.run(&f, &[]);
    assert_eq!(env.take(), ["bad"]);
    assert!(!report.success());
    // A panic is a failure too.
    let f = env.write(
        "p.ron",
        r#"(nodes: {"bad": (kind: "Fail", args: (panic: true))})"#,
    );
    let (plan, report) = env.run(&f, &[]);
    assert!(report.failures(&plan)[0].1.contains("toy panic"));
}

#[test]
fn targets_run_only_what_is_needed() {
    let env = Env::new();
    let f = env.write("p.ron", CHAIN);
    let (plan, report) = env.run_opts(
        &f,
        &[],
        &RunOptions {
            jobs: 2,
            targets: vec!["app".into()],
            ..Default::default()
        },
    );
    assert_eq!(env.take(), ["app", "src"]);
    assert_eq!(statuses(&plan, &report).len(), 2);
    let sets: Vec<String> = Vec::new();
    let plan = env.engine.load(&f, &sets).unwrap();
    assert!(env
        .engine
        .run(
            &plan,
            &RunOptions {
                targets: vec!["nope".into()],
                ..Default::default()
            }
        )
        .is_err());
}

#[test]
fn independent_nodes_run_in_parallel_and_heavy_nodes_run_alone() {
    let env = Env::new();
    let f = env.write(
        "p.ron",
        r#"(nodes: {
        "a": (kind: "Source", args: (value: "a", sleep_ms: 300)),
        "b": (kind: "Source", args: (value: "b", sleep_ms: 300)),
        "c": (kind: "Source", args: (value: "c", sleep_ms: 300)),
        "h": (kind: "Heavy", args: (sleep_ms: 200)),
        "d": (kind: "Source", args: (value: "d", sleep_ms: 300)),
    })"#,
    );
    let (plan, report) = env.run_opts(
        &f,
        &[],
        &RunOptions {
            jobs: 3,
            ..Default::default()
        },
    );
    assert_eq!(env.take().len(), 5);
    assert_eq!(env.rec.max_active(), 3);
    assert_eq!(
        env.rec.violations(),
        0,
        "a Threads::All node ran beside another"
    );
    assert_eq!(
        env.read(&plan, &report, "h", "out"),
        "3 3",
        "the heavy node gets a rayon pool of the whole budget"
    );
    let f = env.write(
        "q.ron",
        r#"(nodes: {"a": (kind: "Source", args: (value: "a", sleep_ms: 100)), "b": (kind: "Source", args: (value: "b", sleep_ms: 100))})"#,
    );
    env.rec.reset_max_active();
    env.run_opts(
        &f,
        &[],
        &RunOptions {
            jobs: 1,
            ..Default::default()
        },
    );
    assert_eq!(env.rec.max_active(), 1);
}

#[test]
fn extends_merges_and_paths_resolve_against_their_file() {
    let env = Env::new();
    std::fs::create_dir_all(env.dir.path().join("base/data")).unwrap();
    std::fs::write(env.dir.path().join("base/data/value.txt"), "external").unwrap();
    env.write(
        "base/base.ron",
        r#"(
        params: { "n": 2 },
        nodes: {
            "ext": (kind: "Len", inputs: { "a": Path("data") }),
            "src": (kind: "Source", args: (value: "v", nested: (alpha: 1.0, tags: ["x"]))),
            "app": (kind: "Append", args: (suffix: "base"), inputs: { "a": "src" }),
            "gone": (kind: "Source"),
        },
    )"#,
    );
    let f = env.write(
        "child.ron",
        r#"(
        extends: "base/base.ron",
        nodes: {
            "src": (args: (nested: (alpha: 2.0))),
            "app": (inputs: { "a": "ext" }),
            "gone": Remove,
        },
    )"#,
    );
    let (plan, report) = env.run(&f, &[]);
    assert_eq!(env.take(), ["app", "ext", "src"]);
    assert_eq!(env.read(&plan, &report, "ext", "out"), "8");
    assert_eq!(env.read(&plan, &report, "app", "out"), "8base");
    assert_eq!(env.read(&plan, &report, "src", "out"), "v|2");
    let src = plan
        .instances
        .iter()
        .find(|i| i.name == "src")
        .unwrap()
        .comp;
    assert_eq!(
        plan.comps[src].args_json["nested"]["tags"],
        serde_json::json!(["x"]),
        "nested struct fields merge"
    );
    let text = augsplat_graph::expand_text(&plan);
    assert!(
        text.contains("alpha: 2.0") && !text.contains("gone"),
        "{text}"
    );
    // Editing the external file reruns its reader; `why` says so.
    std::fs::write(env.dir.path().join("base/data/value.txt"), "external!").unwrap();
    let plan = env.engine.load(&f, &[]).unwrap();
    let why = env.engine.why_text(&plan, "ext").unwrap();
    assert!(
        why.contains("the content of") && why.contains("changed"),
        "{why}"
    );
    env.run(&f, &[]);
    assert_eq!(env.take(), ["app", "ext"]);
}

#[test]
fn why_names_the_changed_arg_with_its_location_or_override() {
    let env = Env::new();
    let f = env.write("p.ron", CHAIN);
    env.run(&f, &[]);
    env.take();
    let plan = env.engine.load(&f, &[]).unwrap();
    assert!(env
        .engine
        .why_text(&plan, "len")
        .unwrap()
        .contains("is cached"));
    let f = env.write("p.ron", &CHAIN.replace(r#"suffix: "!""#, r#"suffix: "%""#));
    let plan = env.engine.load(&f, &[]).unwrap();
    let why = env.engine.why_text(&plan, "len").unwrap();
    let file = f.canonicalize().unwrap();
    assert!(
        why.contains("input `a` comes from `app.out`, which will run first"),
        "{why}"
    );
    assert!(why.contains(r#"arg `suffix`: "!" -> "%""#), "{why}");
    assert!(why.contains(&format!("{}:5:48", file.display())), "{why}");
    let plan = env.engine.load(&f, &["src.count=5".into()]).unwrap();
    let why = env.engine.why_text(&plan, "src").unwrap();
    assert!(
        why.contains("arg `count`: 2 -> 5") && why.contains("--set src.count=5"),
        "{why}"
    );
    // A never-run node.
    let f = env.write(
        "p.ron",
        &CHAIN
            .replace("\"other\"", "\"fresh\"")
            .replace("\"?\"", "\"??\""),
    );
    let plan = env.engine.load(&f, &[]).unwrap();
    assert!(env
        .engine
        .why_text(&plan, "fresh")
        .unwrap()
        .contains("no previous successful run"));
}

#[test]
fn gc_keeps_latest_runs_and_pins() {
    let env = Env::new();
    let f = env.write("p.ron", CHAIN);
    env.run(&f, &[]);
    let f = env.write("p.ron", &CHAIN.replace("count: 2", "count: 7"));
    let (plan, report) = env.run(&f, &[]);
    env.take();
    let dry = env.engine.gc(true).unwrap();
    assert_eq!(dry.actions_removed, 4);
    assert_eq!(dry.actions_kept, 4);
    let again = env.engine.gc(true).unwrap();
    assert_eq!(again.actions_removed, 4, "a dry run removes nothing");
    let rep = env.engine.gc(false).unwrap();
    assert_eq!(rep.actions_removed, 4);
    assert!(rep.blobs_removed > 0);
    assert_eq!(env.read(&plan, &report, "len", "out"), "19");
    env.run(&f, &[]);
    assert!(env.take().is_empty(), "the latest run survives gc");
    // While a run holds the store, gc refuses.
    let _held = env.engine.store().lock_shared().unwrap();
    assert!(env.engine.gc(false).is_err());
}

#[test]
fn two_engines_on_one_store_compute_each_node_once() {
    let env = Env::new();
    let f = env.write(
        "p.ron",
        r#"(nodes: {
        "a": (kind: "Source", args: (value: "a", sleep_ms: 300)),
        "b": (kind: "Append", args: (suffix: "b", sleep_ms: 100), inputs: { "a": "a" }),
        "c": (kind: "Len", inputs: { "a": "b.out" }),
    })"#,
    );
    let cache = env.dir.path().join("cache");
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| {
                let e = Engine::new(registry(env.rec.clone()), &cache).unwrap();
                let plan = e.load(&f, &[]).unwrap();
                let r = e
                    .run(
                        &plan,
                        &RunOptions {
                            jobs: 1,
                            ..Default::default()
                        },
                    )
                    .unwrap();
                assert!(r.success());
            });
        }
    });
    assert_eq!(env.take(), ["a", "b", "c"]);
}

#[test]
fn keys_and_outputs_do_not_depend_on_thread_budget() {
    let env1 = Env::new();
    let env2 = Env::new();
    let text = r#"(nodes: {"s": (kind: "Seeded", repeat: 3, args: (seed: 1)), "c": (kind: "Concat", inputs: {"items": "s[*]"})})"#;
    let f1 = env1.write("p.ron", text);
    let f2 = env2.write("p.ron", text);
    let (p1, r1) = env1.run_opts(
        &f1,
        &[],
        &RunOptions {
            jobs: 1,
            ..Default::default()
        },
    );
    let (p2, r2) = env2.run_opts(
        &f2,
        &[],
        &RunOptions {
            jobs: 2,
            ..Default::default()
        },
    );
    assert_eq!(
        r1.summary_json(&p1)["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| n["key"].clone())
            .collect::<Vec<_>>(),
        r2.summary_json(&p2)["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| n["key"].clone())
            .collect::<Vec<_>>()
    );
    assert_eq!(
        env1.read(&p1, &r1, "c", "out"),
        env2.read(&p2, &r2, "c", "out")
    );
    let s = r1.summary_json(&p1);
    for n in s["nodes"].as_array().unwrap() {
        let o = n.as_object().unwrap();
        assert_eq!(
            o.keys().cloned().collect::<Vec<_>>(),
            ["key", "kind", "name", "seconds", "status"]
        );
    }
}

#[test]
fn command_kind_runs_a_program_without_a_shell() {
    let env = Env::new();
    let f = env.write(
        "c.ron",
        r#"(nodes: {
        "src": (kind: "Source", args: (value: "hello")),
        "cmd": (kind: "Command", args: (
            program: "cp",
            args: ["{in:data}/value.txt", "{out:out}/copied.txt"],
            inputs: ["data"],
        ), inputs: { "data": "src" }),
        "bad": (kind: "Command", args: (program: "sh", args: ["-c", "echo to-stdout; echo to-stderr >&2; exit 3"])),
        "env": (kind: "Command", args: (program: "sh", args: ["-c", "echo $AUGSPLAT_SEED > $AUGSPLAT_OUT_OUT/seed.txt"])),
    })"#,
    );
    let (plan, report) = env.run(&f, &[]);
    let d = report
        .output_dir(&plan, env.engine.store(), "cmd", "out")
        .unwrap();
    assert_eq!(
        std::fs::read_to_string(d.join("copied.txt")).unwrap(),
        "hello|0.5"
    );
    let fails = report.failures(&plan);
    assert_eq!(fails.len(), 1);
    assert!(
        fails[0].1.contains("exit status: 3")
            && fails[0].1.contains("to-stdout")
            && fails[0].1.contains("to-stderr"),
        "{fails:?}"
    );
    let d = report
        .output_dir(&plan, env.engine.store(), "env", "out")
        .unwrap();
    assert!(std::fs::read_to_string(d.join("seed.txt"))
        .unwrap()
        .trim()
        .parse::<u64>()
        .is_ok());
    let e = load_err(
        &env,
        "bad.ron",
        r#"(nodes: {"x": (kind: "Command", args: (program: "true", args: ["{in:nope}"]))})"#,
    );
    assert!(e.contains("{in:nope}"), "{e}");
}
