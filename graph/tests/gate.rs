//! Gates (`gate: "node.output"`): a node whose gate says no ends at once, its dependents are
//! gated with it unless they accept gated inputs, independent nodes run as usual, the
//! decision is part of the key, and a bad decision fails the node with the file named.

mod common;

use common::env::{statuses, Env};

const GATED: &str = r#"(
    params: { "go": false },
    nodes: {
        "decide": (kind: "Decide", args: (run: Param("go"))),
        "src": (kind: "Source", args: (value: "ab")),
        "costly": (kind: "Append", args: (suffix: "!"), gate: "decide.decision", inputs: { "a": "src" }),
        "after": (kind: "Len", inputs: { "a": "costly.out" }),
        "free": (kind: "Append", args: (suffix: "?"), inputs: { "a": "src" }),
        "table": (kind: "Collect", args: (sep: ","), inputs: { "items": ["free.out", "after.out"] }),
    },
)"#;

#[test]
fn a_gate_that_says_no_ends_its_branch_and_the_report_sees_it() {
    let env = Env::new();
    let f = env.write("p.ron", GATED);
    let (plan, report) = env.run(&f, &[]);
    assert!(report.success());
    // Neither the gated node nor its dependent ran their code.
    assert_eq!(env.take(), ["decide", "free", "src", "table"]);
    let summary = report.summary_json(&plan);
    let mut gated: Vec<&str> = summary["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|n| n["gated"].is_string())
        .map(|n| n["name"].as_str().unwrap())
        .collect();
    gated.sort();
    assert_eq!(gated, ["after", "costly"]);
    for n in summary["nodes"].as_array().unwrap() {
        if n["gated"].is_string() {
            assert_eq!(n["gated"], "toy decision false");
        }
    }
    assert_eq!(
        env.read(&plan, &report, "table", "out"),
        "ab|0.5?,gated(toy decision false)"
    );
    let table = report.table(&plan);
    assert!(
        table
            .lines()
            .any(|l| l.starts_with("costly") && l.contains("gated")),
        "{table}"
    );
    // A gated output holds only the marker.
    let dir = report
        .output_dir(&plan, env.engine.store(), "costly", "out")
        .unwrap();
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, [augsplat_graph::gate::GATED_MARKER]);

    // A rerun finds everything cached, still marked gated.
    let (plan, report) = env.run(&f, &[]);
    assert!(env.take().is_empty());
    assert!(statuses(&plan, &report).iter().all(|(_, s)| s == "cached"));
    assert!(report.table(&plan).contains("gated (cached)"));

    // The decision is part of the key: flipping it runs the branch, and the report again.
    let (plan, report) = env.run(&f, &["params.go=true"]);
    assert!(report.success());
    assert_eq!(env.take(), ["after", "costly", "decide", "table"]);
    assert_eq!(env.read(&plan, &report, "table", "out"), "ab|0.5?,7");
    assert!(report.results.iter().flatten().all(|r| r.gated.is_none()));
}

#[test]
fn an_unreadable_decision_fails_the_gated_node_and_stores_nothing_for_it() {
    let env = Env::new();
    let f = env.write(
        "p.ron",
        &GATED.replace(
            r#"args: (run: Param("go"))"#,
            r#"args: (run: Param("go"), garbled: true)"#,
        ),
    );
    let (plan, report) = env.run(&f, &[]);
    assert!(!report.success());
    let s = report.summary_json(&plan);
    let costly = s["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == "costly")
        .unwrap()
        .clone();
    assert_eq!(costly["status"], "failed");
    let err = costly["error"].as_str().unwrap();
    assert!(
        err.contains("gate.json") && err.contains("not a gate decision"),
        "{err}"
    );
    assert!(report
        .output_dir(&plan, env.engine.store(), "costly", "out")
        .is_none());
}

#[test]
fn a_gate_must_name_one_existing_output() {
    let env = Env::new();
    let e = common::env::load_err(
        &env,
        "p.ron",
        &GATED.replace(r#"gate: "decide.decision""#, r#"gate: "decidr.decision""#),
    );
    assert!(e.contains("decidr") && e.contains("decide"), "{e}");
}

#[test]
fn a_gate_mixes_into_a_pipeline_through_a_list_of_extends() {
    let env = Env::new();
    env.write(
        "base.ron",
        r#"(nodes: {
            "src": (kind: "Source", args: (value: "ab")),
            "costly": (kind: "Append", args: (suffix: "!"), inputs: { "a": "src" }),
        })"#,
    );
    // A fragment: adds the decision and gates a node it does not define.
    env.write(
        "gate.ron",
        r#"(nodes: {
            "decide": (kind: "Decide", args: (run: false)),
            "costly": (gate: "decide.decision", args: (suffix: "?")),
        })"#,
    );
    let f = env.write(
        "p.ron",
        r#"(extends: ["base.ron", "gate.ron"], nodes: { "costly": (args: (suffix: "%")) })"#,
    );
    let (plan, report) = env.run(&f, &[]);
    assert!(report.success());
    assert_eq!(env.take(), ["decide", "src"]);
    let text = augsplat_graph::expand_text(&plan);
    assert!(text.contains(r#"suffix: "%""#), "{text}");
    assert!(report.results.iter().flatten().any(|r| r.gated.is_some()));
    let e = common::env::load_err(&env, "q.ron", r#"(extends: ["base.ron", 3])"#);
    assert!(e.contains("list of them"), "{e}");
}
