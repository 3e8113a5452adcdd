//! The engine through the `augsplat` binary: crash safety (SIGKILL mid-node), two concurrent
//! runs on one store, error reporting, failing nodes, summaries, plan/why/expand/gc.
//! Uses the engine's `Command` kind with `sh`, so no 3-D node is involved.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_augsplat");

struct Env {
    dir: tempfile::TempDir,
}

impl Env {
    fn new() -> Env {
        Env {
            dir: tempfile::tempdir().unwrap(),
        }
    }
    fn path(&self, p: &str) -> PathBuf {
        self.dir.path().join(p)
    }
    fn write(&self, name: &str, text: &str) -> PathBuf {
        let p = self.path(name);
        std::fs::write(&p, text).unwrap();
        p
    }
    fn cmd(&self, args: &[&str]) -> Command {
        let mut c = Command::new(BIN);
        c.args(args)
            .current_dir(self.dir.path())
            .env("AUGSPLAT_CACHE", self.path("cache"));
        c
    }
    fn run(&self, args: &[&str]) -> Output {
        self.cmd(args).output().unwrap()
    }
    /// Lines of the execution log the pipeline's commands append to.
    fn log(&self) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_to_string(self.path("log.txt"))
            .unwrap_or_default()
            .lines()
            .map(str::to_string)
            .collect();
        v.sort();
        v
    }
    fn actions(&self) -> usize {
        let mut n = 0;
        for sub in std::fs::read_dir(self.path("cache/actions"))
            .into_iter()
            .flatten()
            .flatten()
        {
            n += std::fs::read_dir(sub.path()).into_iter().flatten().count();
        }
        n
    }
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// A three-node chain whose middle node sleeps (only on its first attempt when `once`).
fn chain(env: &Env, sleep: &str) -> PathBuf {
    let log = env.path("log.txt");
    let log = log.display();
    env.write(
        "p.ron",
        &format!(
            r#"(
    nodes: {{
        "a": (kind: "Command", args: (program: "sh", args: ["-c", "echo a >> {log}; echo data > $AUGSPLAT_OUT_OUT/x"])),
        "slow": (kind: "Command",
            args: (program: "sh", inputs: ["src"],
                   args: ["-c", "echo slow >> {log}; cat {{in:src}}/x > {{out:out}}/x; {sleep}; echo more >> {{out:out}}/x"]),
            inputs: {{ "src": "a" }}),
        "c": (kind: "Command",
            args: (program: "sh", inputs: ["src"], args: ["-c", "echo c >> {log}; cp {{in:src}}/x {{out:out}}/x"]),
            inputs: {{ "src": "slow" }}),
    }},
)"#
        ),
    )
}

fn wait_for(env: &Env, line: &str, limit: Duration) {
    let t = Instant::now();
    while !env.log().iter().any(|l| l == line) {
        assert!(
            t.elapsed() < limit,
            "timed out waiting for `{line}` in the log"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn read_output(env: &Env, summary: &Path, node: &str) -> String {
    let s: serde_json::Value = serde_json::from_slice(&std::fs::read(summary).unwrap()).unwrap();
    let key = s["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == node)
        .unwrap()["key"]
        .as_str()
        .unwrap()
        .to_string();
    let entry: serde_json::Value = serde_json::from_slice(
        &std::fs::read(env.path(&format!("cache/actions/{}/{key}.json", &key[..2]))).unwrap(),
    )
    .unwrap();
    let m = entry["outputs"]["out"].as_str().unwrap();
    std::fs::read_to_string(env.path(&format!("cache/outputs/{m}/x"))).unwrap()
}

#[test]
fn sigkill_in_the_middle_of_a_node_then_a_clean_rerun() {
    let env = Env::new();
    // The middle node sleeps only on its first attempt (marker file outside the key).
    let mark = env.path("mark");
    let f = chain(
        &env,
        &format!(
            "if [ ! -f {0} ]; then touch {0}; sleep 30; fi",
            mark.display()
        ),
    );
    let mut child = env
        .cmd(&["run", f.to_str().unwrap(), "-q"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    wait_for(&env, "slow", Duration::from_secs(60));
    std::thread::sleep(Duration::from_millis(200));
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    assert_eq!(
        env.actions(),
        1,
        "only the finished node `a` may have an entry"
    );
    // Scratch of the killed node exists but is not a result.
    let out = env.run(&["plan", f.to_str().unwrap()]);
    let t = text(&out);
    assert!(
        t.contains("a     Command  cached") && t.contains("slow  Command  will run"),
        "{t}"
    );
    let summary = env.path("s.json");
    let out = env.run(&[
        "run",
        f.to_str().unwrap(),
        "--summary-json",
        summary.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(
        env.log(),
        ["a", "c", "slow", "slow"],
        "the killed node reruns once, `a` stays cached"
    );
    assert_eq!(read_output(&env, &summary, "c"), "data\nmore\n");
    let out = env.run(&["run", f.to_str().unwrap()]);
    assert!(out.status.success());
    assert_eq!(env.log().len(), 4, "third run computes nothing");
    // gc clears the killed run's scratch folder.
    let out = env.run(&["gc"]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(std::fs::read_dir(env.path("cache/tmp")).unwrap().count(), 0);
}

#[test]
fn two_concurrent_runs_compute_each_node_once() {
    let env = Env::new();
    let f = chain(&env, "sleep 1");
    let s1 = env.path("s1.json");
    let s2 = env.path("s2.json");
    let c1 = env
        .cmd(&[
            "run",
            f.to_str().unwrap(),
            "--summary-json",
            s1.to_str().unwrap(),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let c2 = env
        .cmd(&[
            "run",
            f.to_str().unwrap(),
            "--summary-json",
            s2.to_str().unwrap(),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let o1 = c1.wait_with_output().unwrap();
    let o2 = c2.wait_with_output().unwrap();
    assert!(o1.status.success(), "{}", text(&o1));
    assert!(o2.status.success(), "{}", text(&o2));
    assert_eq!(env.log(), ["a", "c", "slow"], "each node computed once");
    let ran = |p: &Path| -> Vec<String> {
        let s: serde_json::Value = serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap();
        s["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|n| n["status"] == "ran")
            .map(|n| n["name"].as_str().unwrap().to_string())
            .collect()
    };
    let mut all = ran(&s1);
    all.extend(ran(&s2));
    all.sort();
    assert_eq!(all, ["a", "c", "slow"]);
    assert_eq!(read_output(&env, &s1, "c"), read_output(&env, &s2, "c"));
}

#[test]
fn summary_json_and_table() {
    let env = Env::new();
    let f = chain(&env, "true");
    let s = env.path("s.json");
    let out = env.run(&[
        "run",
        f.to_str().unwrap(),
        "--summary-json",
        s.to_str().unwrap(),
        "-j",
        "2",
    ]);
    assert!(out.status.success(), "{}", text(&out));
    let t = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        t.contains("node") && t.contains("slow  Command  ran"),
        "{t}"
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&s).unwrap()).unwrap();
    let nodes = v["nodes"].as_array().unwrap();
    assert_eq!(nodes.len(), 3);
    for n in nodes {
        assert_eq!(n.as_object().unwrap().len(), 5);
        assert_eq!(n["kind"], "Command");
        assert_eq!(n["status"], "ran");
        assert_eq!(n["key"].as_str().unwrap().len(), 64);
        assert!(n["seconds"].as_f64().unwrap() >= 0.0);
    }
    let out = env.run(&[
        "run",
        f.to_str().unwrap(),
        "--summary-json",
        s.to_str().unwrap(),
    ]);
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&s).unwrap()).unwrap();
    assert!(v["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .all(|n| n["status"] == "cached"));
}

#[test]
fn pipeline_errors_exit_nonzero_with_location_and_run_nothing() {
    let env = Env::new();
    let cases = [
        ("syntax.ron", "(nodes: {\n  \"a\": (kind: \"Command\" args: ()),\n})", ":2:25", "syntax error"),
        ("kind.ron", "(nodes: {\n  \"a\": (kind: \"Comand\"),\n})", ":2:15", "did you mean Command"),
        ("arg.ron", "(nodes: {\n  \"a\": (kind: \"Command\", args: (program: \"true\", progam: \"x\")),\n})", ":2:58", "progam"),
        ("type.ron", "(nodes: {\n  \"a\": (kind: \"Command\", args: (program: 5)),\n})", ":2:42", "program"),
        ("dangling.ron", "(nodes: {\n  \"a\": (kind: \"Command\", args: (program: \"true\", inputs: [\"x\"]), inputs: {\"x\": \"b\"}),\n})", ":2:80", "not a node"),
        (
            "cycle.ron",
            "(nodes: {\n  \"a\": (kind: \"Command\", args: (program: \"true\", inputs: [\"x\"]), inputs: {\"x\": \"b\"}),\n  \"b\": (kind: \"Command\", args: (program: \"true\", inputs: [\"x\"]), inputs: {\"x\": \"a\"}),\n})",
            "cycle.ron:",
            "cycle",
        ),
    ];
    for (name, src, loc, what) in cases {
        let f = env.write(name, src);
        let out = env.run(&["run", f.to_str().unwrap()]);
        let t = text(&out);
        assert!(!out.status.success(), "{name}: {t}");
        assert!(
            t.contains(&format!("{name}{loc}")) || (loc.ends_with(':') && t.contains(loc)),
            "{name}: expected {loc} in {t}"
        );
        assert!(
            t.contains(what) && t.contains("hint") || name == "type.ron",
            "{name}: {t}"
        );
    }
    let f = env.write(
        "ok.ron",
        "(nodes: {\"a\": (kind: \"Command\", args: (program: \"true\"))})",
    );
    let out = env.run(&["run", f.to_str().unwrap(), "--set", "a.program=("]);
    assert!(
        !out.status.success() && text(&out).contains("--set a.program=("),
        "{}",
        text(&out)
    );
    assert_eq!(env.actions(), 0, "nothing ran");
}

#[test]
fn failing_node_reports_its_log_and_stores_nothing() {
    let env = Env::new();
    let log = env.path("log.txt");
    let f = env.write(
        "f.ron",
        &format!(
            r#"(nodes: {{
            "a": (kind: "Command", args: (program: "sh", args: ["-c", "echo a >> {0}"])),
            "bad": (kind: "Command", args: (program: "sh", inputs: ["x"], args: ["-c", "echo bad >> {0}; echo partial > {{out:out}}/x; echo oh-no >&2; exit 7"]), inputs: {{"x": "a"}}),
        }})"#,
            log.display()
        ),
    );
    let out = env.run(&["run", f.to_str().unwrap()]);
    let t = text(&out);
    assert!(!out.status.success());
    assert!(
        t.contains("`bad` (Command) failed") && t.contains("exit status: 7") && t.contains("oh-no"),
        "{t}"
    );
    assert_eq!(env.actions(), 1, "only `a` is stored");
    let out = env.run(&["run", f.to_str().unwrap()]);
    assert!(!out.status.success());
    assert_eq!(env.log(), ["a", "bad", "bad"], "`a` stays cached");
}

#[test]
fn plan_why_expand_gc_commands() {
    let env = Env::new();
    let f = env.write(
        "p.ron",
        r#"(
    params: { "n": 2 },
    nodes: {
        "gen": (kind: "Command", repeat: Param("n"), args: (program: "sh", args: ["-c", "echo {seed} > {out:out}/s"])),
        "all": (kind: "Command", args: (program: "sh", list_inputs: ["m"], args: ["-c", "cat $AUGSPLAT_IN_M/s > {out:out}/x 2>/dev/null || true"]), inputs: { "m": "gen[*]" }),
    },
    sweep: Grid({ "all.version": [1, 2] }),
)"#,
    );
    let fs = f.to_str().unwrap();
    let t = text(&env.run(&["expand", fs]));
    assert!(
        t.contains("// sweep point version=1") && t.contains("gen[1]"),
        "{t}"
    );
    // Before the first run there is no store: `plan` says so (a mistyped --cache looks the
    // same) and creates none.
    let out = env.run(&["plan", fs]);
    assert!(!out.status.success());
    assert!(
        text(&out).contains("holds no augsplat store"),
        "{}",
        text(&out)
    );
    assert!(!env.path("cache").exists());
    let out = env.run(&["run", fs, "--target", "gen"]);
    assert!(out.status.success(), "{}", text(&out));
    let t = text(&env.run(&["plan", fs]));
    assert!(
        t.contains("version=1: 1 new, 2 cached") && t.contains("version=2: 1 new, 2 cached"),
        "{t}"
    );
    let out = env.run(&["run", fs]);
    assert!(out.status.success(), "{}", text(&out));
    let t = text(&env.run(&["plan", fs, "--set", "params.n=3"]));
    assert!(
        t.contains("gen[2]") && t.contains("version=1: 2 new, 2 cached"),
        "{t}"
    );
    let t = text(&env.run(&["why", fs, "all@version=2", "--set", "params.n=3"]));
    assert!(t.contains("input `m` now comes from"), "{t}");
    let out = env.run(&["why", fs, "nope"]);
    assert!(!out.status.success() && text(&out).contains("no node `nope`"));
    let t = text(&env.run(&["gc", "--dry-run"]));
    assert!(t.contains("would remove: 0 actions"), "{t}");
}

/// `run` lists the results (the sinks, or the targets) and `--out DIR` copies them into
/// DIR/<instance>/<output>/ as writable files, replacing earlier copies, cached or not.
#[test]
fn run_lists_its_results_and_out_copies_them() {
    let env = Env::new();
    let f = chain(&env, "true");
    let out = env.run(&["run", f.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out));
    let t = String::from_utf8_lossy(&out.stdout).to_string();
    // Only the sink `c` is a result; its folder is in the store.
    let line = t
        .lines()
        .find(|l| l.trim_start().starts_with("c.out"))
        .unwrap_or_else(|| panic!("no result line in:\n{t}"));
    let path = PathBuf::from(line.split_whitespace().nth(1).unwrap());
    assert!(path.starts_with(env.path("cache/outputs")), "{line}");
    assert_eq!(
        std::fs::read_to_string(path.join("x")).unwrap(),
        "data\nmore\n"
    );
    assert!(
        !t.lines().any(|l| l.trim_start().starts_with("slow.out")),
        "{t}"
    );
    // Cached now; --out copies the same bytes, writable, and a second copy replaces the first.
    let dir = env.path("results");
    std::fs::create_dir_all(dir.join("c/out")).unwrap();
    std::fs::write(dir.join("c/out/stale"), "old").unwrap();
    for _ in 0..2 {
        let out = env.run(&["run", f.to_str().unwrap(), "--out", dir.to_str().unwrap()]);
        assert!(out.status.success(), "{}", text(&out));
        let x = dir.join("c/out/x");
        assert_eq!(std::fs::read_to_string(&x).unwrap(), "data\nmore\n");
        assert!(!std::fs::metadata(&x).unwrap().permissions().readonly());
        assert!(!dir.join("c/out/stale").exists());
        assert!(String::from_utf8_lossy(&out.stdout)
            .contains(&format!("{}", x.parent().unwrap().display())));
    }
    // With a target, that node's outputs are the results.
    let out = env.run(&[
        "run",
        f.to_str().unwrap(),
        "--target",
        "slow",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(
        std::fs::read_to_string(dir.join("slow/out/x")).unwrap(),
        "data\nmore\n"
    );
    // Writing the copy is safe: the store's file is untouched.
    std::fs::write(dir.join("slow/out/x"), "edited").unwrap();
    assert_eq!(
        std::fs::read_to_string(path.join("x")).unwrap(),
        "data\nmore\n"
    );
}

/// `verify` on a sound store exits 0; after a blob is damaged it names the node, the blob and
/// the repair command and exits 1; `verify --repair` removes the damage and the next run
/// recomputes it.
#[test]
fn verify_names_damage_exits_nonzero_and_repair_lets_run_recompute() {
    let env = Env::new();
    let f = chain(&env, "true");
    let fs_ = f.to_str().unwrap();
    let out = env.run(&["run", fs_]);
    assert!(out.status.success(), "{}", text(&out));
    let out = env.run(&["verify"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("the store is sound"), "{}", text(&out));
    // Damage the blob of `a`'s output ("data\n"): one flipped bit, same size.
    let p = std::fs::read_dir(env.path("cache/blobs"))
        .unwrap()
        .flatten()
        .flat_map(|d| std::fs::read_dir(d.path()).unwrap().flatten())
        .map(|e| e.path())
        .find(|p| std::fs::read(p).unwrap() == b"data\n")
        .expect("the blob of `a`'s output");
    let blob = p.file_name().unwrap().to_string_lossy().to_string();
    let mut perm = std::fs::metadata(&p).unwrap().permissions();
    #[allow(clippy::permissions_set_readonly_false)]
    perm.set_readonly(false);
    std::fs::set_permissions(&p, perm).unwrap();
    std::fs::write(&p, b"dbta\n").unwrap();
    let out = env.run(&["verify"]);
    let t = text(&out);
    assert!(!out.status.success(), "{t}");
    assert!(t.contains("node `a`") && t.contains(&blob), "{t}");
    assert!(t.contains("verify --repair"), "{t}");
    let out = env.run(&["verify", "--repair"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("removed:"), "{}", text(&out));
    assert!(env.run(&["verify"]).status.success());
    let out = env.run(&["run", fs_]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        std::fs::read(&p).unwrap() == b"data\n",
        "the blob is whole again"
    );
}

/// A `Command` whose program writes to its input works on a copy: the node fails, the stored
/// blob and the user's external file are unchanged, and the store stays sound.
#[test]
fn a_command_that_writes_to_its_inputs_fails_and_changes_nothing() {
    let env = Env::new();
    let ext = env.write("user.txt", "mine\n");
    let f = env.write(
        "p.ron",
        r#"(
    nodes: {
        "a": (kind: "Command", args: (program: "sh", args: ["-c", "echo data > $AUGSPLAT_OUT_OUT/x"])),
        "evil": (kind: "Command",
            args: (program: "sh", inputs: ["src", "user"],
                   args: ["-c", "chmod -R u+w {in:src} {in:user}; echo more >> {in:src}/x; echo more >> {in:user}; echo ok > {out:out}/y"]),
            inputs: { "src": "a", "user": Path("user.txt") }),
    },
)"#,
    );
    let out = env.run(&["run", f.to_str().unwrap()]);
    let t = text(&out);
    assert!(!out.status.success(), "{t}");
    assert!(t.contains("changed its input"), "{t}");
    assert_eq!(std::fs::read_to_string(&ext).unwrap(), "mine\n");
    let blob = std::fs::read_dir(env.path("cache/blobs"))
        .unwrap()
        .flatten()
        .flat_map(|d| std::fs::read_dir(d.path()).unwrap().flatten())
        .any(|e| std::fs::read(e.path()).unwrap() == b"data\n");
    assert!(blob, "the stored blob still holds `data`");
    let v = env.run(&["verify"]);
    assert!(v.status.success(), "{}", text(&v));
}

/// A claim whose holder stopped renewing it (a frozen driver: SIGSTOP) is taken over after
/// the stale bound by a second driver, which computes the node and finishes.
#[cfg(target_os = "linux")]
#[test]
fn a_claim_whose_holder_stopped_renewing_is_taken_over() {
    let env = Env::new();
    let f = chain(&env, "sleep 1");
    let mut frozen = env
        .cmd(&["run", f.to_str().unwrap(), "-q"])
        .env("AUGSPLAT_CLAIM_STALE_SECS", "2")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    wait_for(&env, "slow", Duration::from_secs(60));
    let pid = frozen.id().to_string();
    assert!(Command::new("kill")
        .args(["-STOP", &pid])
        .status()
        .unwrap()
        .success());
    let t = Instant::now();
    let out = env
        .cmd(&["run", f.to_str().unwrap()])
        .env("AUGSPLAT_CLAIM_STALE_SECS", "2")
        .output()
        .unwrap();
    let took = t.elapsed();
    frozen.kill().unwrap();
    frozen.wait().unwrap();
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        took >= Duration::from_millis(1500),
        "{took:?}: it waited for the bound"
    );
    assert_eq!(
        env.log(),
        ["a", "c", "slow", "slow"],
        "the stale node ran again"
    );
}

#[test]
fn log_prints_node_log_lines_as_they_arrive() {
    let env = Env::new();
    let f = env.write(
        "l.ron",
        r#"(nodes: {
            "talk": (kind: "Command", args: (program: "sh", args: ["-c", "echo first-line; echo second-line >&2"])),
        })"#,
    );
    let out = env.run(&["run", f.to_str().unwrap(), "-q", "--log"]);
    assert!(out.status.success(), "{}", text(&out));
    let err = String::from_utf8_lossy(&out.stderr);
    // Each line carries the node's name and its elapsed seconds: `[talk 0.0 s] first-line`.
    for line in ["first-line", "second-line"] {
        assert!(
            err.lines()
                .any(|l| l.starts_with("[talk ") && l.contains(" s] ") && l.ends_with(line)),
            "{err}"
        );
    }
    // Without `--log` (and cached now, with a changed node so it runs again) nothing is echoed.
    let g = env.write(
        "m.ron",
        r#"(nodes: {
            "talk": (kind: "Command", args: (program: "sh", args: ["-c", "echo third-line"])),
        })"#,
    );
    let out = env.run(&["run", g.to_str().unwrap(), "-q"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(!text(&out).contains("third-line"), "{}", text(&out));
}
