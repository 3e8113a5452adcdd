//! Benchmark of the triangulation (run by hand, not a test):
//!
//! ```text
//! cargo run --release -p augsplat-scene --example bench_triangulate [-- VIEWS [THREADS] [--json PATH]]
//! ```
//!
//! Imports `../shared/data/dtu_scan24` at 400×300 (capture.ron's `max_side: 512`), sets its SfM
//! points aside, and triangulates the first `VIEWS` views (default 30) with the default
//! options on `THREADS` threads (default: all), three times; prints the stage counts, the
//! median time, and one JSON line (`{"bench": "triangulate", ...}`); `--json PATH` writes the
//! median as a `BenchRecord` for `docs/figures/`.

use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_scene::import::{import_scene, ImportOptions};
use augsplat_scene::node::{read_source, ImportSceneArgs};
use augsplat_scene::triangulate::{triangulate, TriangulateOptions};
use std::time::Instant;

fn main() {
    let (all, json) = bench_record::args_and_json();
    let mut args = all.iter();
    let views: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(30);
    let threads: usize = args
        .next()
        .and_then(|a| a.parse().ok())
        .unwrap_or_else(rayon::current_num_threads);
    let src = augsplat_testkit::data::shared_data_dir().join("dtu_scan24");
    let raw = read_source(&src, &ImportSceneArgs::default()).expect("dtu_scan24 in ../shared/data");
    let dir = tempfile::tempdir().expect("temporary folder");
    let opts = ImportOptions {
        downscale: 2,
        ..Default::default()
    };
    import_scene(&raw, &opts, dir.path(), &|_| {}).expect("import");
    let scene = augsplat_core::Scene::load(dir.path()).expect("scene");
    let n = views.min(scene.views.len());
    let cams: Vec<_> = scene.views[..n].iter().map(|v| v.camera.clone()).collect();
    let names: Vec<_> = scene.views[..n].iter().map(|v| v.name.clone()).collect();
    let images: Vec<_> = (0..n)
        .map(|i| scene.load_image(dir.path(), i).expect("image"))
        .collect();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool");
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..3 {
        let t = Instant::now();
        let r = pool
            .install(|| triangulate(&cams, &images, &names, &TriangulateOptions::default()))
            .expect("triangulation");
        times.push(t.elapsed().as_secs_f64());
        last = Some(r);
    }
    times.sort_by(f64::total_cmp);
    let r = last.expect("three runs");
    println!("{}", r.report.summary());
    println!(
        "{n} views at {}×{}, {threads} threads: median {:.2} s (of {:.2} / {:.2} / {:.2})",
        cams[0].width, cams[0].height, times[1], times[0], times[1], times[2]
    );
    println!(
        "{{\"bench\": \"triangulate\", \"scene\": \"dtu_scan24\", \"views\": {n}, \"width\": {}, \
         \"threads\": {threads}, \"seconds\": {:.3}, \"points\": {}}}",
        cams[0].width, times[1], r.report.points
    );
    let record = BenchRecord::now(
        format!(
            "triangulation of dtu_scan24 without its SfM points, {n} views at {}×{}, {threads} threads",
            cams[0].width, cams[0].height
        ),
        bench_record::example_command("augsplat-scene", "bench_triangulate", &all),
        format!(
            "median {:.2} s of 3 runs ({:.2} / {:.2} / {:.2}), {} points",
            times[1], times[0], times[1], times[2], r.report.points
        ),
        times[1],
        "s",
    );
    record.write_or_exit(json.as_deref());
}
