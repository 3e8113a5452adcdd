//! Limits with messages: `extends` lists that repeat a file load each file once (they used to
//! load exponentially), and a chain of `extends` deeper than the limit is an error naming it.

mod common;

use common::env::Env;
use std::time::{Duration, Instant};

/// Writes `base.ron` and files `f{n-1}.ron` … `f0.ron`, each extending the next `times` times
/// (the last extends `base.ron`); returns the path of `f0.ron`.
fn chain(env: &Env, n: usize, times: usize) -> std::path::PathBuf {
    env.write(
        "base.ron",
        r#"(nodes: { "src": (kind: "Source", args: (value: "ab", count: 2)) })"#,
    );
    for i in 0..n {
        let next = if i + 1 == n {
            "base.ron".to_string()
        } else {
            format!("f{}.ron", i + 1)
        };
        let list = vec![format!("{next:?}"); times].join(", ");
        env.write(&format!("f{i}.ron"), &format!("(extends: [{list}])"));
    }
    env.dir.path().join("f0.ron")
}

#[test]
fn extends_lists_that_repeat_a_file_load_it_once() {
    let env = Env::new();
    let f = chain(&env, 20, 2);
    let t = Instant::now();
    let plan = env.engine.load(&f, &[]).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        t.elapsed() < Duration::from_secs(5),
        "2^20 loads: {:?}",
        t.elapsed()
    );
    assert_eq!(plan.instances.len(), 1);
}

#[test]
fn an_extends_chain_deeper_than_the_limit_is_an_error_naming_it() {
    let env = Env::new();
    let f = chain(&env, 100, 1);
    let err = match env.engine.load(&f, &[]) {
        Ok(_) => panic!("a 100-deep chain loads"),
        Err(e) => e.to_string(),
    };
    assert!(err.contains("more than 64 files deep"), "{err}");
    assert!(err.contains("f0.ron"), "{err}");
    // Within the limit it loads.
    let env = Env::new();
    let f = chain(&env, 60, 1);
    assert!(env.engine.load(&f, &[]).is_ok());
}
