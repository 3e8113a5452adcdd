//! Benchmark: import + undistort + 30-view split of the bonsai capture (800×533, 25
//! registered views of colmap30) through the node kinds, as a pipeline would run them.
//!
//! `cargo run --release -p augsplat-scene --example bench_import -- [THREADS] [REPEATS]
//! [--json PATH]` (data from `<workspace>/../shared/data`, or `$AUGSPLAT_DATA`). Prints the
//! best time of each stage over the repeats; `--json` also writes the total as a `BenchRecord`
//! (`docs/figures/`).

use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_graph::{Node, RunContext};
use augsplat_scene::node::{
    ImportScene, ImportSceneArgs, SourceFormat, SplitScene, SplitSceneArgs,
};
use std::path::{Path, PathBuf};
use std::time::Instant;

fn run<N: Node>(args: &N::Args, inputs: &[(&str, &Path)], root: &Path, threads: usize) -> f64 {
    let outputs = N::outputs(args);
    let names: Vec<&str> = outputs.iter().map(String::as_str).collect();
    let inputs = inputs
        .iter()
        .map(|(n, p)| (n.to_string(), vec![p.to_path_buf()]))
        .collect();
    let mut ctx = RunContext::standalone(inputs, &names, root, 0, threads).expect("context");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool");
    let t = Instant::now();
    if let Err(e) = pool.install(|| N::run(args, &mut ctx)) {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
    t.elapsed().as_secs_f64()
}

fn main() {
    let (a, json) = bench_record::args_and_json();
    let threads: usize = a.first().and_then(|s| s.parse().ok()).unwrap_or(2);
    let repeats: usize = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(3);
    let data = std::env::var_os("AUGSPLAT_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    let src = data.join("bonsai");
    if !src.is_dir() {
        eprintln!("{} is absent", src.display());
        std::process::exit(2);
    }
    let import = ImportSceneArgs {
        format: SourceFormat::Colmap,
        model: Some("colmap30/sparse/0".into()),
        images: Some("images".into()),
        ..Default::default()
    };
    let split = SplitSceneArgs::default();
    let (mut best_i, mut best_s) = (f64::INFINITY, f64::INFINITY);
    for _ in 0..repeats {
        let tmp =
            std::env::temp_dir().join(format!("augsplat_bench_import_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&tmp);
        let ti = run::<ImportScene>(&import, &[("source", &src)], &tmp.join("import"), threads);
        let scene = tmp.join("import/scene");
        let ts = run::<SplitScene>(&split, &[("scene", &scene)], &tmp.join("split"), threads);
        best_i = best_i.min(ti);
        best_s = best_s.min(ts);
        let _ = std::fs::remove_dir_all(&tmp);
    }
    println!(
        "bonsai colmap30 (25 views, 800×533, OPENCV → PINHOLE), {threads} threads, best of {repeats}: \
         import+undistort {best_i:.3} s, split {best_s:.3} s, total {:.3} s",
        best_i + best_s
    );
    let record = BenchRecord::now(
        format!("import, undistortion and split of bonsai colmap30 (25 views, 800×533), {threads} threads"),
        bench_record::example_command("augsplat-scene", "bench_import", &a),
        format!(
            "{:.3} s: import+undistort {best_i:.3} s, split {best_s:.3} s (best of {repeats})",
            best_i + best_s
        ),
        best_i + best_s,
        "s",
    );
    record.write_or_exit(json.as_deref());
}
