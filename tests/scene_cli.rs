//! The scene stage through the `augsplat` binary: `inspect` (text and JSON) on the real
//! captures, and failing imports in a pipeline run (exit non-zero, message names the file,
//! nothing stored). Real-data tests skip with a message when ../shared/data is absent.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_augsplat");

fn data() -> Option<PathBuf> {
    augsplat_testkit::data::shared_data("scene CLI", "")
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn inspect(args: &[&str]) -> Output {
    Command::new(BIN)
        .arg("inspect")
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn inspect_bonsai_reports_colmaps_reprojection_error() {
    let Some(d) = data() else { return };
    for model in [
        "bonsai/colmap30/sparse/0",
        "bonsai/colmap30/sparse_txt",
        "bonsai/colmap30",
    ] {
        let p = d.join(model);
        let out = inspect(&[p.to_str().unwrap(), "--json"]);
        assert!(out.status.success(), "{}", text(&out));
        let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let e = j["mean_reprojection_error"].as_f64().unwrap();
        // COLMAP's model_analyzer printed 0.326190 px.
        assert!((e - 0.326190).abs() < 0.01, "{model}: {e}");
        assert_eq!(j["registered_images"], 25);
        assert_eq!(j["points"], 6478);
        assert_eq!(j["observations"], 22916);
        assert_eq!(j["cameras"], 1);
        let i = &j["intrinsics"][0];
        assert_eq!(
            (
                i["model"].as_str().unwrap(),
                i["width"].as_u64().unwrap(),
                i["height"].as_u64().unwrap()
            ),
            ("OPENCV", 800, 533)
        );
    }
    let out = inspect(&[d.join("bonsai/colmap30/sparse/0").to_str().unwrap()]);
    let t = text(&out);
    assert!(
        out.status.success() && t.contains("0.326190 px") && t.contains("registered images:  25"),
        "{t}"
    );
    let out = inspect(&[d.join("fern").to_str().unwrap(), "--json"]);
    assert!(out.status.success(), "{}", text(&out));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["format"], "LLFF");
    assert_eq!(j["registered_images"], 20);
    assert!(j["near_far"][0].as_f64().unwrap() > 0.0);
}

#[test]
fn inspect_errors_name_the_path_and_exit_non_zero() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("no_such_scene");
    let out = inspect(&[missing.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(text(&out).contains("no_such_scene"), "{}", text(&out));
    // A truncated binary model.
    let m = tmp.path().join("model");
    std::fs::create_dir_all(&m).unwrap();
    std::fs::write(m.join("cameras.bin"), [1u8, 0, 0, 0, 0, 0, 0, 0, 1, 0]).unwrap();
    let out = inspect(&[m.to_str().unwrap()]);
    assert!(!out.status.success());
    let t = text(&out);
    assert!(t.contains("cameras.bin") && t.contains("truncated"), "{t}");
    // A folder with nothing recognisable.
    let out = inspect(&[tmp.path().to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(text(&out).contains("no supported scene"), "{}", text(&out));
}

fn action_entries(cache: &Path) -> usize {
    let mut n = 0;
    for sub in std::fs::read_dir(cache.join("actions"))
        .into_iter()
        .flatten()
        .flatten()
    {
        n += std::fs::read_dir(sub.path()).into_iter().flatten().count();
    }
    n
}

#[test]
fn failing_import_in_a_pipeline_stores_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    // A generated scene exported to COLMAP text is a valid source; then break it.
    let src = tmp.path().join("src");
    std::fs::create_dir_all(&src).unwrap();
    let pipeline = tmp.path().join("p.ron");
    std::fs::write(
        &pipeline,
        r#"(
    nodes: {
        "syn": (kind: "SyntheticScene", args: (width: 32, height: 24, views: 4, points: 50, supersample: 1)),
        "export": (kind: "ExportScene", args: (format: ColmapText), inputs: { "scene": "syn" }),
        "scene": (kind: "ImportScene", inputs: { "source": Path("src") }),
    },
)"#,
    )
    .unwrap();
    let cache = tmp.path().join("cache");
    let run = |target: &str| {
        Command::new(BIN)
            .args(["run", pipeline.to_str().unwrap(), "-q", "--target", target])
            .env("AUGSPLAT_CACHE", &cache)
            .current_dir(tmp.path())
            .output()
            .unwrap()
    };
    // An empty source folder: the format cannot be detected.
    let out = run("scene");
    assert!(!out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("src"), "{}", text(&out));
    assert_eq!(
        action_entries(&cache),
        0,
        "a failed import must leave no cache entry"
    );
    // Build the export, copy it in as the source, and corrupt one image.
    let out = run("export");
    assert!(out.status.success(), "{}", text(&out));
    let before = action_entries(&cache);
    assert_eq!(before, 2);
    let outputs = cache.join("outputs");
    let export = std::fs::read_dir(&outputs)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.join("sparse/0/cameras.txt").is_file())
        .expect("the export folder in the store");
    augsplat_testkit::copy_dir(&export, &src);
    std::fs::write(src.join("images/view_002.png"), b"not an image").unwrap();
    let out = run("scene");
    assert!(!out.status.success());
    let t = text(&out);
    assert!(
        t.contains("view_002.png") && t.contains("not a readable image"),
        "{t}"
    );
    assert_eq!(
        action_entries(&cache),
        before,
        "a failed import must leave no cache entry"
    );
    // Repaired, it imports.
    std::fs::copy(
        export.join("images/view_002.png"),
        src.join("images/view_002.png"),
    )
    .unwrap();
    let out = run("scene");
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(action_entries(&cache), before + 1);
}
