//! The pipeline file as a language: diagnostics, `extends` and external paths, and the
//! engine's `Command` kind. Each test owns its recorder (through its `Env`).

mod common;

use common::env::{load_err, Env, CHAIN};

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

/// Typos an ablation would silently run: a `--set` or a sweep of an undeclared param, the same
/// key twice in a map, a huge `repeat`; each is an error with its location and, where a close
/// name exists, "did you mean". A declared param that no node uses is a warning.
#[test]
fn typos_in_params_and_maps_are_errors_with_locations() {
    let env = Env::new();
    let text = r#"(
    params: { "suffix": "!", "count": 2 },
    nodes: {
        "src": (kind: "Source", args: (value: "ab", count: Param("count"))),
        "app": (kind: "Append", args: (suffix: Param("suffix")), inputs: { "a": "src" }),
    },
)"#;
    let f = env.write("p.ron", text);
    let e = env
        .engine
        .load(&f, &["params.sufix=\"?\"".to_string()])
        .err()
        .expect("an undeclared param is an error")
        .to_string();
    assert!(e.contains("--set params.sufix"), "{e}");
    assert!(e.contains("there is no param `sufix`"), "{e}");
    assert!(e.contains("did you mean `params.suffix`?"), "{e}");
    assert!(env
        .engine
        .load(&f, &["params.suffix=\"?\"".to_string()])
        .is_ok());

    let e = load_err(
        &env,
        "sweep.ron",
        &text.replace("\n)", "\n    sweep: Grid({ \"params.cuont\": [1, 2] }),\n)"),
    );
    assert!(e.contains("there is no param `cuont`"), "{e}");
    assert!(e.contains("did you mean `params.count`?"), "{e}");

    let e = load_err(
        &env,
        "dup_node.ron",
        &text.replace(
            "\"app\": (kind",
            "\"src\": (kind: \"Source\", args: (value: \"x\")),\n        \"app\": (kind",
        ),
    );
    assert!(e.contains("dup_node.ron:5:9"), "{e}");
    assert!(e.contains("key \"src\" is written twice"), "{e}");
    assert!(e.contains("first at"), "{e}");

    let e = load_err(
        &env,
        "dup_param.ron",
        &text.replace("\"count\": 2 }", "\"count\": 2, \"suffix\": \"?\" }"),
    );
    assert!(e.contains("dup_param.ron:2:"), "{e}");
    assert!(e.contains("key \"suffix\" is written twice"), "{e}");

    let e = load_err(
        &env,
        "huge.ron",
        r#"(nodes: { "src": (kind: "Source", repeat: 1000000000, args: (value: "a")) })"#,
    );
    assert!(e.contains("huge.ron:1:"), "{e}");
    assert!(e.contains("at most 10000"), "{e}");

    let f = env.write(
        "unused.ron",
        &text.replace("\"count\": 2 }", "\"count\": 2, \"gamma\": 1.5 }"),
    );
    let plan = env.engine.load(&f, &[]).unwrap();
    assert_eq!(plan.warnings.len(), 1, "{:?}", plan.warnings);
    assert!(
        plan.warnings[0].contains("unused.ron:2:"),
        "{:?}",
        plan.warnings
    );
    assert!(
        plan.warnings[0].contains("param `gamma`"),
        "{:?}",
        plan.warnings
    );
    assert!(env
        .engine
        .load(&env.write("p.ron", text), &[])
        .unwrap()
        .warnings
        .is_empty());
}

/// A FIFO inside an input folder is an error naming it, at once (reading it would block).
#[cfg(unix)]
#[test]
fn a_fifo_in_an_input_folder_is_an_error_not_a_hang() {
    let env = Env::new();
    let data = env.dir.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    std::fs::write(data.join("a.txt"), "x").unwrap();
    let fifo = data.join("pipe");
    let ok = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(ok.success());
    let f = env.write(
        "p.ron",
        r#"(nodes: { "ext": (kind: "Len", inputs: { "a": Path("data") }) })"#,
    );
    let t = std::time::Instant::now();
    let e = match env.engine.load(&f, &[]) {
        Ok(_) => panic!("a FIFO input must not load"),
        Err(e) => e.to_string(),
    };
    assert!(t.elapsed() < std::time::Duration::from_secs(1));
    assert!(e.contains("pipe") && e.contains("FIFO"), "{e}");
}
