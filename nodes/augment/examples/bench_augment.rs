//! Benchmarks of the augmentation kernels and nodes (run by hand, not a test):
//!
//! ```text
//! cargo run --release -p augsplat-augment --example bench_augment [-- --json PATH]
//! ```
//!
//! Measures, at the paper's sizes (200 synthetic views at 1/8 of 800×533 → 100×67, M = 5):
//! the aggregation kernel (no blur and 9×9 blur) on 1 and 2 threads, the whole
//! `AggregateEnsemble` node with EXR reading and writing, and pose synthesis for 26 cameras
//! (with the size of the candidate pool, which is what rendering every candidate would cost
//! instead of only the drawn poses). `--json PATH` also writes the node's time on 2 threads as
//! a `BenchRecord` (`docs/figures/`).

use augsplat_augment::aggregate::{aggregate_view, AggregateParams, Workspace};
use augsplat_augment::poses::{candidate_pool, synthesize_poses, PoseParams};
use augsplat_augment::AggregateEnsemble;
use augsplat_core::artifacts::{self, files, RenderSet, RenderedView};
use augsplat_core::bench_record::{self, BenchRecord};
use augsplat_core::{image, Camera, Rng};
use augsplat_graph::{Node, RunContext};
use rayon::prelude::*;
use std::time::Instant;

fn camera(i: usize, n: usize, w: u32, h: u32) -> Camera {
    let a = i as f64 / n as f64 * std::f64::consts::TAU;
    let eye = [3.0 * a.cos(), 0.1 * (i as f64).sin(), 3.0 * a.sin()];
    augsplat_testkit::cameras::looking_at_origin(eye, w, h)
}

fn time<T>(label: &str, reps: usize, mut f: impl FnMut() -> T) -> f64 {
    let _ = f();
    let t = Instant::now();
    for _ in 0..reps {
        std::hint::black_box(f());
    }
    let s = t.elapsed().as_secs_f64() / reps as f64;
    println!("{label:<58} {:>10.3} ms", s * 1e3);
    s
}

fn main() {
    let (args, json) = bench_record::args_and_json();
    let (views, m, w, h) = (200usize, 5usize, 100usize, 67usize);
    let n = w * h;
    let mut rng = Rng::new(1);
    let members: Vec<Vec<Vec<f32>>> = (0..views)
        .map(|_| {
            (0..m)
                .map(|_| (0..3 * n).map(|_| rng.next_f32()).collect())
                .collect()
        })
        .collect();
    println!("aggregation: {views} views of {w}×{h}, M = {m}");
    // Seconds of the kernel on 2 threads, without and with the blur, and of the node.
    let mut kernel2 = [0.0; 2];
    let mut node2 = 0.0;
    for (b, blur) in [None, Some(9)].into_iter().enumerate() {
        let params = AggregateParams {
            blur,
            ..AggregateParams::default()
        };
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let label = format!("kernel, blur {blur:?}, {threads} thread(s), all views");
            let s = time(&label, 3, || {
                pool.install(|| {
                    members
                        .par_iter()
                        .map_init(Workspace::default, |ws, mv| {
                            let refs: Vec<&[f32]> = mv.iter().map(|v| v.as_slice()).collect();
                            aggregate_view(&refs, w, h, &params, ws).weight[0]
                        })
                        .sum::<f32>()
                })
            });
            println!("{:<58} {:>10.1} Mpx/s", "", (views * n) as f64 / s / 1e6);
            if threads == 2 {
                kernel2[b] = s;
            }
        }
    }

    // The node with file I/O.
    let tmp = std::env::temp_dir().join(format!("augsplat-bench-augment-{}", std::process::id()));
    let dirs: Vec<_> = (0..m)
        .map(|k| {
            let dir = tmp.join(format!("member{k}"));
            std::fs::create_dir_all(&dir).unwrap();
            let mut set = RenderSet::default();
            for (v, mv) in members.iter().enumerate() {
                let file = format!("view_{v:04}.exr");
                let p = &mv[k];
                let ones = vec![1f32; n];
                image::write_exr(
                    &dir.join(&file),
                    w as u32,
                    h as u32,
                    &[
                        ("R", &p[..n]),
                        ("G", &p[n..2 * n]),
                        ("B", &p[2 * n..]),
                        ("D", &ones),
                        ("A", &ones),
                    ],
                )
                .unwrap();
                set.views.push(RenderedView {
                    name: format!("syn{v:04}"),
                    camera: camera(v, views, w as u32, h as u32),
                    file,
                });
            }
            artifacts::write_json(&dir.join(files::RENDERS), &set).unwrap();
            dir
        })
        .collect();
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut i = 0;
        let s = time(
            &format!("AggregateEnsemble node (EXR in/out, PNG previews), {threads} thr"),
            2,
            || {
                i += 1;
                let root = tmp.join(format!("out{threads}_{i}"));
                let mut ctx = RunContext::standalone(
                    vec![("members".into(), dirs.clone())],
                    &["synthetic"],
                    &root,
                    0,
                    threads,
                )
                .unwrap();
                pool.install(|| AggregateEnsemble::run(&AggregateParams::default(), &mut ctx))
                    .unwrap();
            },
        );
        if threads == 2 {
            node2 = s;
        }
    }
    let _ = std::fs::remove_dir_all(&tmp);

    // Pose synthesis at the paper's protocol (26 training views at 800×533).
    let train: Vec<(String, Camera)> = (0..26)
        .map(|i| (format!("v{i}"), camera(i, 26, 800, 533)))
        .collect();
    let params = PoseParams::default();
    let pool = candidate_pool(&train, &params).unwrap();
    let poses = time("SynthesizePoses kernel, 26 cameras, 200 drawn", 20, || {
        synthesize_poses(&train, &params).unwrap().len()
    });
    println!(
        "candidate pool {} poses, drawn {}: rendering only the drawn poses renders {:.1}% of the pool",
        pool.len(),
        params.count,
        100.0 * params.count as f64 / pool.len() as f64
    );
    let record = BenchRecord::now(
        format!("AggregateEnsemble, {views} views of {w}×{h}, M = {m}, 2 threads"),
        bench_record::example_command("augsplat-augment", "bench_augment", &args),
        format!(
            "node (EXR in/out, PNG previews) {:.0} ms; kernel {:.0} ms, with 9×9 blur {:.0} ms; pose synthesis (26 cameras) {:.1} ms",
            node2 * 1e3,
            kernel2[0] * 1e3,
            kernel2[1] * 1e3,
            poses * 1e3
        ),
        node2 * 1e3,
        "ms",
    );
    record.write_or_exit(json.as_deref());
}
