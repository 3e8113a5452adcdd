//! The custom augmentation in Python (`examples/custom_augment_python/ensemble_mean.py`, run by
//! the engine's `Command` kind): `pipelines/custom_augment_python.ron` at the tiny sizes trains
//! Dual AugSplat on the script's synthetic set and reaches the report; that set is the
//! members' mean the Rust `EnsembleMean` computes (recomputed here from the member EXRs) and
//! passes `SyntheticView::read`'s checks; and the script refuses malformed members with a
//! non-zero exit and an error naming the file.
//!
//! They need `python3` with numpy on `PATH`: without it they are skipped outside CI and fail
//! under `CI=true`.

use augsplat_core::artifacts::{self, files, RenderSet, RenderedView, SyntheticSet};
use augsplat_core::{image, Camera};
use augsplat_graph::store::unhex;
use augsplat_graph::Store;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Whether `python3` with numpy runs; if not, reports the skip (a failure under CI).
fn python_with_numpy(test: &str) -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import numpy"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        augsplat_testkit::skip(
            test,
            "python3 with numpy is not installed (apt-get install -y python3-numpy)",
        );
    }
    ok
}

fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Runs the script directly: `python3 ensemble_mean.py --power P --out OUT MEMBER…`.
fn run_script(power: &str, out: &Path, members: &[PathBuf]) -> Output {
    Command::new("python3")
        .arg(root().join("examples/custom_augment_python/ensemble_mean.py"))
        .args(["--power", power, "--out"])
        .arg(out)
        .args(members)
        .output()
        .expect("runs python3")
}

/// Reads plane `name` of an EXR.
fn plane(exr: &image::ExrImage, path: &Path, name: &str) -> Vec<f32> {
    exr.channel(name)
        .unwrap_or_else(|| panic!("{}: no channel {name}", path.display()))
        .to_vec()
}

/// Checks the synthetic set in `dir` against the Rust `EnsembleMean`'s prior on the members'
/// render folders: per view the mean of R, G, B summed in member order in f32, and the weight
/// clamp(mean A, 0, 1)^power; to 1e-6, through `SyntheticView::read` (the contract's checks).
fn check_is_the_ensemble_mean(dir: &Path, members: &[PathBuf], power: f32) {
    let set: SyntheticSet = artifacts::read_json(&dir.join(files::SYNTHETIC)).unwrap();
    let renders: Vec<RenderSet> = members
        .iter()
        .map(|m| artifacts::read_json(&m.join(files::RENDERS)).unwrap())
        .collect();
    assert_eq!(set.views.len(), renders[0].views.len());
    let k = members.len() as f32;
    for (vi, view) in set.views.iter().enumerate() {
        let rendered = &renders[0].views[vi];
        assert_eq!(view.name, rendered.name);
        assert_eq!(view.camera, rendered.camera);
        let stem = artifacts::file_stem(&view.name);
        assert_eq!(view.target, format!("targets/{stem}.exr"));
        assert_eq!(view.weight, format!("weights/{stem}.exr"));
        let n = (view.camera.width * view.camera.height) as usize;
        let (mut rgb, mut alpha) = (vec![0.0f32; 3 * n], vec![0.0f32; n]);
        for (m, r) in members.iter().zip(&renders) {
            let path = m.join(&r.views[vi].file);
            let exr = image::read_exr(&path).unwrap();
            for (c, ch) in ["R", "G", "B"].into_iter().enumerate() {
                for (s, v) in rgb[c * n..(c + 1) * n]
                    .iter_mut()
                    .zip(plane(&exr, &path, ch))
                {
                    *s += v;
                }
            }
            for (s, v) in alpha.iter_mut().zip(plane(&exr, &path, "A")) {
                *s += v;
            }
        }
        let px = view.read(dir).unwrap();
        for p in 0..n {
            for c in 0..3 {
                let (got, want) = (px.target.data[3 * p + c], rgb[c * n + p] / k);
                assert!((got - want).abs() <= 1e-6, "{}: {got} vs {want}", view.name);
            }
            let want = (alpha[p] / k).clamp(0.0, 1.0).powf(power);
            let got = px.weight[p];
            assert!((got - want).abs() <= 1e-6, "{}: {got} vs {want}", view.name);
        }
        let sum: f64 = px.weight.iter().map(|&w| w as f64).sum();
        assert!((view.weight_sum - sum).abs() <= 1e-9, "{}", view.name);
    }
}

/// The folder of output `output` of the instance `name` in a run summary, through the store's
/// action entry.
fn output_dir(store: &Store, nodes: &[Value], name: &str, output: &str) -> PathBuf {
    let node = nodes
        .iter()
        .find(|n| n["name"] == name)
        .unwrap_or_else(|| panic!("no instance {name} in the summary"));
    let key = unhex(node["key"].as_str().unwrap()).expect("a hex key");
    let action = store.action(&key).unwrap().expect("an action entry");
    store.output_dir(&unhex(&action.outputs[output]).expect("a hex manifest"))
}

#[test]
fn the_python_prior_trains_dual_augsplat_and_is_the_ensemble_mean() {
    if !python_with_numpy("the_python_prior_trains_dual_augsplat_and_is_the_ensemble_mean") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (cache, summary) = (tmp.path().join("store"), tmp.path().join("summary.json"));
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_augsplat"));
    cmd.arg("run")
        .arg(root().join("pipelines/custom_augment_python.ron"))
        .arg("--cache")
        .arg(&cache)
        .arg("--summary-json")
        .arg(&summary)
        .arg("-q");
    for s in augsplat_testkit::tiny::SETS {
        cmd.arg("--set").arg(s);
    }
    let out = cmd.output().unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let s: Value = serde_json::from_slice(&std::fs::read(&summary).unwrap()).unwrap();
    let nodes = s["nodes"].as_array().unwrap();
    for name in ["mean_py", "dual_mean_py", "eval_dual_mean_py", "report"] {
        let node = nodes.iter().find(|n| n["name"] == name);
        let status = node.unwrap_or_else(|| panic!("no node {name}"))["status"].as_str();
        assert_eq!(status, Some("ran"), "{name}");
    }
    let store = Store::open(&cache).unwrap();
    let report = output_dir(&store, nodes, "report", "report");
    let md = std::fs::read_to_string(report.join("summary.md")).unwrap();
    assert!(md.contains("Dual (Python mean prior)"), "{md}");
    // The script's set is the Rust node's mean of the same members (`render[*]`, in order).
    let mut members: Vec<(usize, PathBuf)> = nodes
        .iter()
        .filter_map(|n| {
            let name = n["name"].as_str()?;
            let i = name
                .strip_prefix("render[")?
                .strip_suffix(']')?
                .parse()
                .ok()?;
            Some((i, output_dir(&store, nodes, name, "renders")))
        })
        .collect();
    members.sort();
    assert!(members.len() >= 2, "{members:?}");
    let members: Vec<PathBuf> = members.into_iter().map(|(_, d)| d).collect();
    let synthetic = output_dir(&store, nodes, "mean_py", "synthetic");
    check_is_the_ensemble_mean(&synthetic, &members, 1.0);
}

/// Writes a member's render folder: views `a view/1` and `b` at 37×35 (three ZIP blocks, the
/// last partial), smooth enough that ZIP compresses them, with opacities outside [0, 1].
fn write_member(dir: &Path, seed: f32) {
    let (w, h) = (37u32, 35u32);
    let mut views = Vec::new();
    for (i, name) in ["a view/1", "b"].into_iter().enumerate() {
        let f = |c: usize| -> Vec<f32> {
            (0..w * h)
                .map(|p| {
                    let (x, y) = ((p % w) as f32, (p / w) as f32);
                    (0.1 * x + 0.07 * y + seed + c as f32 + i as f32).sin() * 0.8 + 0.4
                })
                .collect()
        };
        let file = format!("view_{i}.exr");
        let (r, g, b, d, a) = (f(0), f(1), f(2), f(3), f(4));
        let channels = [("R", &r[..]), ("G", &g), ("B", &b), ("D", &d), ("A", &a)];
        image::write_exr(&dir.join(&file), w, h, &channels).unwrap();
        let mut m = [[0.0; 4]; 4];
        for (j, row) in m.iter_mut().enumerate() {
            row[j] = 1.0;
        }
        let camera = Camera {
            width: w,
            height: h,
            fx: 30.0,
            fy: 30.0,
            cx: 18.5,
            cy: 17.5,
            world_to_camera: m,
        };
        views.push(RenderedView {
            name: name.into(),
            camera,
            file,
        });
    }
    artifacts::write_json(&dir.join(files::RENDERS), &RenderSet { views }).unwrap();
}

#[test]
fn the_script_writes_the_mean_and_names_the_file_it_cannot_use() {
    if !python_with_numpy("the_script_writes_the_mean_and_names_the_file_it_cannot_use") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let members: Vec<PathBuf> = (0..3).map(|k| tmp.path().join(format!("m{k}"))).collect();
    for (k, m) in members.iter().enumerate() {
        std::fs::create_dir_all(m).unwrap();
        write_member(m, k as f32 * 0.9);
    }
    let out = run_script("2", &tmp.path().join("synthetic"), &members);
    assert!(out.status.success(), "{}", text(&out));
    check_is_the_ensemble_mean(&tmp.path().join("synthetic"), &members, 2.0);

    // Each case breaks member 1 of a fresh copy; the error names the file.
    let broken = |case: &str, edit: &dyn Fn(&Path) -> PathBuf, says: &str| {
        let dir = tmp.path().join(case);
        let copies: Vec<PathBuf> = (0..3).map(|k| dir.join(format!("m{k}"))).collect();
        for (m, c) in members.iter().zip(&copies) {
            augsplat_testkit::copy_dir(m, c);
        }
        let file = edit(&copies[1]);
        let out = run_script("1", &dir.join("synthetic"), &copies);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{case}: {}", text(&out));
        assert!(
            err.contains(&file.display().to_string()) && err.contains(says),
            "{case}: expected the file {} and `{says}` in:\n{err}",
            file.display()
        );
    };
    broken(
        "missing_file",
        &|m| {
            std::fs::remove_file(m.join("view_1.exr")).unwrap();
            m.join("view_1.exr")
        },
        "No such file",
    );
    broken(
        "image_of_another_size",
        &|m| {
            let p = m.join("view_1.exr");
            let v = vec![0.5f32; 36 * 35];
            let channels = [("R", &v[..]), ("G", &v), ("B", &v), ("A", &v)];
            image::write_exr(&p, 36, 35, &channels).unwrap();
            p
        },
        "image is 36×35, its camera says 37×35",
    );
    broken(
        "view_of_another_size",
        &|m| {
            let p = m.join(files::RENDERS);
            let mut set: RenderSet = artifacts::read_json(&p).unwrap();
            set.views[1].camera.width = 40;
            artifacts::write_json(&p, &set).unwrap();
            p
        },
        "view `b` (40×35) does not match member 0 view `b` (37×35)",
    );
    broken(
        "unsupported_compression",
        &|m| {
            // Patch the compression attribute (ZIP) to PIZ, which the script does not read.
            let p = m.join("view_0.exr");
            let mut bytes = std::fs::read(&p).unwrap();
            let tag = b"compression\0compression\0\x01\0\0\0";
            let at = bytes.windows(tag.len()).position(|w| w == tag).unwrap();
            bytes[at + tag.len()] = 4;
            std::fs::write(&p, bytes).unwrap();
            p
        },
        "compression PIZ is not supported",
    );
}
