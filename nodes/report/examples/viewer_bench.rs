//! Frame time of the 3-D viewer in headless Chromium (software WebGL unless the machine has a
//! GPU Chromium uses): for each count, a random cloud (`Gaussians::random_cloud`, the scene of
//! `train_step_bench`: a box 4 units in front of the camera, footprints of a few pixels) is
//! written as a viewer page with one camera, and the page orbits it for `frames` frames, each
//! a depth sort, a draw and a one-pixel read back (the median after the first frame).
//!
//! ```text
//! cargo run --release -p augsplat-report --example viewer_bench -- [W H frames count...] [--json PATH]
//! ```
//! Defaults: 800 533 20 100000 1000000. Prints one JSON line per count and the page size;
//! the pages stay in `target/tmp/viewer_bench/` (open one to look, or to profile). `--json`
//! also writes the frame times as a `BenchRecord` (`docs/figures/`), its value the last
//! count's median.

use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_report::viewer::{self, ViewerCamera, ViewerModel};
use augsplat_splat::Gaussians;
use std::time::Duration;

fn main() {
    let (args, json) = bench_record::args_and_json();
    let num = |i: usize, d: usize| -> usize {
        args.get(i).map_or(d, |s| {
            s.parse()
                .unwrap_or_else(|_| panic!("argument {} `{s}` is not a number", i + 1))
        })
    };
    let (w, h, frames) = (num(0, 800) as u32, num(1, 533) as u32, num(2, 20));
    let counts: Vec<usize> = if args.len() > 3 {
        (3..args.len()).map(|i| num(i, 0)).collect()
    } else {
        vec![100_000, 1_000_000]
    };
    let Some(exe) = augsplat_testkit::browser::chromium("viewer_bench") else {
        return;
    };
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/tmp/viewer_bench");
    std::fs::create_dir_all(&dir).expect("create target/tmp/viewer_bench");
    let camera = augsplat_testkit::cameras::square_pixels(
        w,
        h,
        [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 4.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    );
    // Per count: (Gaussians, median frame ms, median sort ms).
    let mut medians: Vec<(usize, f64, f64)> = Vec::new();
    for n in counts {
        let g = Gaussians::random_cloud(n, 4.0 / camera.fx, 7);
        let packed = viewer::pack(&g, n);
        let page = viewer::viewer_page(
            "viewer bench",
            &[ViewerModel {
                label: format!("{n} random Gaussians"),
                packed,
            }],
            &[ViewerCamera {
                name: "bench".into(),
                held_out: false,
                camera: camera.clone(),
                ground_truth: None,
            }],
            [0.0; 3],
        );
        let file = dir.join(format!("bench{n}.html"));
        std::fs::write(&file, &page).expect("write the page");
        let mut cmd = augsplat_testkit::browser::headless(&exe, &dir.join(format!("profile{n}")));
        cmd.arg("--dump-dom")
            .arg(format!("file://{}#bench={frames}", file.display()));
        let (dom, log) = augsplat_testkit::browser::run_limited(cmd, Duration::from_secs(600));
        let Some(result) = augsplat_testkit::browser::text_in_dom(&dom, "viewer-bench") else {
            panic!("no bench result for {n} Gaussians; stderr:\n{log}");
        };
        println!(
            "{result} page {:.1} MB",
            std::fs::metadata(&file).map_or(0, |m| m.len()) as f64 / 1e6
        );
        let v: serde_json::Value =
            serde_json::from_str(&result).unwrap_or_else(|e| panic!("{result}: {e}"));
        let ms = |k: &str| v[k].as_f64().unwrap_or(f64::NAN);
        medians.push((n, ms("median_ms"), ms("median_sort_ms")));
    }
    let Some(&(_, last, _)) = medians.last() else {
        return;
    };
    let figure: Vec<String> = medians
        .iter()
        .map(|(n, f, s)| format!("{n} Gaussians {f:.1} ms (sort {s:.1} ms)"))
        .collect();
    let record = BenchRecord::now(
        format!("3-D viewer frame in headless Chromium, {w}×{h}"),
        bench_record::example_command("augsplat-report", "viewer_bench", &args),
        format!("median frame of {frames}: {}", figure.join(", ")),
        last,
        "ms",
    );
    record.write_or_exit(json.as_deref());
}
