//! A capture whose `images/` is a symbolic link to another disk (the usual way to point a tool
//! at data stored elsewhere) imports, and pointing the link at other photos reruns the import,
//! with `why` naming the link.

#![cfg(unix)]

use std::path::Path;
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_augsplat");

fn augsplat(dir: &Path, args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .env("AUGSPLAT_CACHE", dir.join("cache"))
        .current_dir(dir)
        .output()
        .unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// The status of node `name` in a `--summary-json` file.
fn status_of(summary: &Path, name: &str) -> String {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(summary).unwrap()).unwrap();
    v["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == name)
        .unwrap()["status"]
        .as_str()
        .unwrap()
        .to_string()
}

#[test]
fn a_capture_with_linked_images_imports_and_a_moved_link_reruns_the_import() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    // A generated 6-view COLMAP export.
    std::fs::write(
        dir.join("export.ron"),
        r#"(nodes: {
        "syn": (kind: "SyntheticScene", args: (width: 32, height: 24, views: 6, points: 200, supersample: 1)),
        "export": (kind: "ExportScene", args: (format: ColmapText), inputs: { "scene": "syn" }),
    })"#,
    )
    .unwrap();
    let out = augsplat(dir, &["run", "export.ron", "-q", "--out", "exported"]);
    assert!(out.status.success(), "{}", text(&out));
    augsplat_testkit::copy_dir(&dir.join("exported/export/export"), &dir.join("src"));

    // Its photos live on "another disk"; the capture links to them.
    std::fs::rename(dir.join("src/images"), dir.join("disk1")).unwrap();
    augsplat_testkit::copy_dir(&dir.join("disk1"), &dir.join("disk2"));
    let mut photos: Vec<_> = std::fs::read_dir(dir.join("disk2"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .collect();
    photos.sort();
    // One photo differs on the second disk (another valid photo of the same size).
    std::fs::copy(&photos[1], &photos[0]).unwrap();
    std::os::unix::fs::symlink(dir.join("disk1"), dir.join("src/images")).unwrap();

    std::fs::write(
        dir.join("import.ron"),
        r#"(nodes: { "scene": (kind: "ImportScene", args: (format: Auto), inputs: { "source": Path("src") }) })"#,
    )
    .unwrap();
    let summary = dir.join("s.json");
    let s = summary.to_str().unwrap();
    let out = augsplat(dir, &["run", "import.ron", "-q", "--summary-json", s]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(status_of(&summary, "scene"), "ran");
    let out = augsplat(dir, &["run", "import.ron", "-q", "--summary-json", s]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(status_of(&summary, "scene"), "cached");

    std::fs::remove_file(dir.join("src/images")).unwrap();
    std::os::unix::fs::symlink(dir.join("disk2"), dir.join("src/images")).unwrap();
    let why = augsplat(dir, &["why", "import.ron", "scene"]);
    assert!(why.status.success(), "{}", text(&why));
    assert!(
        text(&why).contains("now points to") && text(&why).contains("disk2"),
        "{}",
        text(&why)
    );
    let out = augsplat(dir, &["run", "import.ron", "-q", "--summary-json", s]);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(status_of(&summary, "scene"), "ran");
}
