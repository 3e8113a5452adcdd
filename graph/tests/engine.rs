//! Engine behaviour with toy node kinds that record every execution: caching and early
//! cutoff, keys, sweeps and repeats, failures, targets, parallelism, `why`, GC, several
//! processes on one store. Each test owns its recorder (through its `Env`), so the tests run
//! in parallel.

mod common;

use augsplat_graph::{Engine, RunOptions};
use common::env::{statuses, Env, CHAIN};
use common::registry;

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
    let dry = env.engine.gc(true, false).unwrap();
    assert_eq!(dry.actions_removed, 4);
    assert_eq!(dry.actions_kept, 4);
    let again = env.engine.gc(true, false).unwrap();
    assert_eq!(again.actions_removed, 4, "a dry run removes nothing");
    let rep = env.engine.gc(false, false).unwrap();
    assert_eq!(rep.actions_removed, 4);
    assert!(rep.blobs_removed > 0);
    assert_eq!(env.read(&plan, &report, "len", "out"), "19");
    env.run(&f, &[]);
    assert!(env.take().is_empty(), "the latest run survives gc");
    // While a run holds the store, gc refuses.
    let _held = env.engine.store().lock_shared().unwrap();
    assert!(env.engine.gc(false, false).is_err());
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
