//! The `Report` node over three evaluations and a synthetic set: the page is well-formed,
//! self-contained and shows the tables, plots and images; the same inputs give the same bytes;
//! headless Chromium loads it without errors (skipped when `chromium` is not installed).

mod common;

use augsplat_graph::{Node, RunContext};
use augsplat_report::node::{files, ReportArgs};
use augsplat_report::ReportNode;
use common::*;
use std::path::{Path, PathBuf};
use std::time::Duration;

const VOID: [&str; 6] = ["meta", "img", "br", "hr", "input", "link"];

/// Checks that tags nest properly (void elements and `/>` self-closing aside), attribute
/// values are quoted, and that no raw `<` or `&` appears outside markup or entities.
fn check_well_formed(html: &str) -> Result<(), String> {
    let body = html
        .strip_prefix("<!DOCTYPE html>\n")
        .ok_or("missing doctype")?;
    let bytes = body.as_bytes();
    let mut stack: Vec<String> = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'<' => {
                let end = body[i..]
                    .find('>')
                    .ok_or(format!("unclosed tag at byte {i}"))?
                    + i;
                let tag = &body[i + 1..end];
                if tag.matches('"').count() % 2 != 0 {
                    return Err(format!(
                        "unbalanced quotes in <{}>",
                        &tag[..tag.len().min(60)]
                    ));
                }
                if let Some(name) = tag.strip_prefix('/') {
                    let top = stack.pop().ok_or(format!("</{name}> closes nothing"))?;
                    if top != name {
                        return Err(format!("</{name}> closes <{top}>"));
                    }
                } else {
                    let name: String = tag
                        .chars()
                        .take_while(|c| c.is_ascii_alphanumeric())
                        .collect();
                    if name.is_empty() {
                        return Err(format!("bad tag <{}>", &tag[..tag.len().min(40)]));
                    }
                    if !tag.ends_with('/') && !VOID.contains(&name.as_str()) {
                        stack.push(name);
                    }
                }
                i = end + 1;
            }
            b'&' => {
                let semi = body[i..].find(';').ok_or(format!("bare & at byte {i}"))?;
                let ent = &body[i + 1..i + semi];
                if semi > 8 || !ent.chars().all(|c| c.is_ascii_alphanumeric() || c == '#') {
                    return Err(format!("bare & at byte {i}"));
                }
                i += semi + 1;
            }
            b'>' => return Err(format!("stray > at byte {i}")),
            _ => i += 1,
        }
    }
    if !stack.is_empty() {
        return Err(format!("unclosed elements: {stack:?}"));
    }
    Ok(())
}

fn build(root: &Path, title: &str) -> PathBuf {
    let evals = make_evals(&root.join("fixtures"));
    let syn = root.join("synthetic");
    make_synthetic(&syn, 5);
    let out = root.join("out");
    let mut ctx = RunContext::standalone(
        vec![("evals".into(), evals), ("synthetic".into(), vec![syn])],
        &["report"],
        &out,
        0,
        1,
    )
    .unwrap();
    let args = ReportArgs {
        title: title.into(),
        ..Default::default()
    };
    ReportNode::run(&args, &mut ctx).unwrap();
    out.join("report")
}

#[test]
fn page_is_well_formed_self_contained_and_complete() {
    let dir = tempfile::tempdir().unwrap();
    let report = build(dir.path(), "Bonsai <sparse> & friends");
    let html = std::fs::read_to_string(report.join(files::INDEX)).unwrap();
    check_well_formed(&html).unwrap();
    assert!(html.contains("<title>Bonsai &lt;sparse&gt; &amp; friends</title>"));
    // Self-contained: no scripts, no external resources.
    assert!(!html.contains("<script"));
    for bad in ["src=\"http", "href=\"http", "src=\"/", "url("] {
        assert!(!html.contains(bad), "external reference {bad}");
    }
    // Tables: evaluated checkpoint, best step, at the baseline's step; best cells marked.
    assert_eq!(
        html.matches("<table class=\"metrics\">").count(),
        4,
        "3 result tables + per-view"
    );
    assert!(
        html.contains("All methods at the baseline&#39;s best step (3DGS, step 400)"),
        "baseline caption"
    );
    assert!(html.matches("class=\"best\"").count() >= 4);
    // Plots: 4 curves + wall time + scatter + error-vs-time.
    assert_eq!(html.matches("<svg").count(), 7);
    assert_eq!(html.matches("class=\"series\"").count(), 4 * 3 + 3);
    assert!(html.contains("class=\"pareto\""));
    // Images: 3 views × (GT + 3 methods) full + crops, and 4 synthetic views × 2.
    let pngs = html.matches("src=\"data:image/png;base64,").count();
    assert_eq!(pngs, 3 * 4 * 2 + 4 * 2);
    assert!(html.contains("syn000 confidence") && html.contains("syn004 target"));
    let md = std::fs::read_to_string(report.join(files::SUMMARY)).unwrap();
    assert!(md.starts_with("# Bonsai <sparse> & friends\n"));
    assert!(md.contains("| Method | PSNR ↑ | SSIM ↑ | LPIPS ↓ | Avg. error ↓ |"));
    assert!(md.contains("| 3DGS (best @ step 400) |"), "{md}");
    assert!(md.contains("## Wall time"));
    // Times that were not recorded show as a dash, never as NaN.
    assert!(!md.contains("NaN"), "{md}");
}

#[test]
fn golden_best_marks_in_the_built_tables() {
    // The fixture's evaluations use noise amplitudes 0.08 (3DGS), 0.05 (Staged), 0.06 (Dual):
    // Staged must win PSNR, SSIM and (with weights) LPIPS of the evaluated checkpoint.
    let dir = tempfile::tempdir().unwrap();
    let evals: Vec<_> = make_evals(dir.path())
        .iter()
        .map(|p| augsplat_report::evalset::EvalDir::load(p).unwrap())
        .collect();
    let labels = augsplat_report::compare::display_labels(&evals);
    let tables = augsplat_report::report::results_tables(&evals, &labels);
    let marks = tables[0].marks();
    assert_eq!(
        marks[1][0..2],
        [true, true],
        "Staged best PSNR/SSIM: {marks:?}"
    );
    assert!(!marks[0][0] && !marks[2][0]);
    if lpips_dir().is_some() {
        assert_eq!(
            marks[1][2..4],
            [true, true],
            "Staged best LPIPS/avg error: {marks:?}"
        );
    }
    // Curve tables: the fixture curves go flat from step 400 (3DGS) and 500 (Staged); ties
    // pick the earliest step. Dual keeps improving to its last step, 600.
    assert_eq!(tables[1].rows[0].detail, "step 400 (by average error)");
    assert_eq!(tables[1].rows[1].detail, "step 500 (by average error)");
    assert_eq!(tables[1].rows[2].detail, "step 600 (by average error)");
    // Baseline table: the baseline at its own best step, the others at step 400.
    assert_eq!(tables[2].rows.len(), 3);
    assert_eq!(tables[2].rows[0].detail, "baseline, step 400");
    assert_eq!(tables[2].rows[1].detail, "step 400");
    assert_eq!(tables[2].rows[2].detail, "step 400");
}

#[test]
fn same_inputs_give_the_same_page_apart_from_measured_times() {
    let dir = tempfile::tempdir().unwrap();
    let evals = make_evals(&dir.path().join("f"));
    let run = |name: &str| {
        let out = dir.path().join(name);
        let mut ctx = RunContext::standalone(
            vec![("evals".into(), evals.clone())],
            &["report"],
            &out,
            0,
            1,
        )
        .unwrap();
        ReportNode::run(&ReportArgs::default(), &mut ctx).unwrap();
        std::fs::read(out.join("report").join(files::INDEX)).unwrap()
    };
    assert_eq!(run("a"), run("b"));
}

/// Without recorded wall times (the default: outputs stay byte-identical) the report has no
/// table of dashes and no empty time plots, only a note saying where the store's times are.
#[test]
fn unrecorded_wall_times_leave_a_note_not_a_table() {
    let dir = tempfile::tempdir().unwrap();
    let evals: Vec<_> = make_evals(dir.path())
        .iter()
        .map(|p| {
            let mut e = augsplat_report::evalset::EvalDir::load(p).unwrap();
            e.metrics.train_seconds = None;
            e.metrics.eval_seconds = None;
            e.metrics.notes.push(
                "training wall time not recorded (OptimizeSplats `record_wall_time: true` \
                 records it)"
                    .into(),
            );
            if let Some(c) = &mut e.curve {
                c.points.iter_mut().for_each(|p| p.seconds = 0.0);
            }
            e
        })
        .collect();
    let opts = augsplat_report::report::ReportOptions {
        viewer: false,
        ..Default::default()
    };
    let built = augsplat_report::report::build_report(&opts, &evals, None).unwrap();
    let note = augsplat_report::report::TIMES_ELSEWHERE;
    assert!(built
        .markdown
        .contains(&format!("## Wall time\n\n{note}\n")));
    assert!(!built.markdown.contains("training s"), "{}", built.markdown);
    // Said once, not once per method.
    assert_eq!(built.markdown.matches("record_wall_time").count(), 1);
    assert!(built.html.contains("<code>augsplat status</code>"));
    assert!(!built.html.contains("Wall time per stage"));
    // The four training curves only.
    assert_eq!(built.html.matches("<svg").count(), 4);
    check_well_formed(&built.html).unwrap();
}

#[test]
fn report_errors_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let mut ctx = RunContext::standalone(
        vec![("evals".into(), vec![dir.path().to_path_buf()])],
        &["report"],
        &dir.path().join("o"),
        0,
        1,
    )
    .unwrap();
    let err = ReportNode::run(&ReportArgs::default(), &mut ctx)
        .unwrap_err()
        .to_string();
    assert!(err.contains("not an evaluation folder"), "{err}");
    let mut ctx = RunContext::standalone(
        vec![("evals".into(), vec![])],
        &["report"],
        &dir.path().join("o2"),
        0,
        1,
    )
    .unwrap();
    let err = ReportNode::run(&ReportArgs::default(), &mut ctx)
        .unwrap_err()
        .to_string();
    assert!(err.contains("at least one evaluation"), "{err}");
}

#[test]
fn renders_in_headless_chromium() {
    let Some(exe) = augsplat_testkit::browser::chromium("the report page's browser check") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let report = build(dir.path(), "AugSplat fixture report");
    let index = report.join(files::INDEX);
    let url = format!("file://{}", index.display());
    // The screenshot is kept for CI artefacts under the tests' temp dir.
    let keep = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("report_chromium");
    std::fs::create_dir_all(&keep).unwrap();
    let shot = keep.join("shot.png");
    let _ = std::fs::remove_file(&shot);
    std::fs::copy(&index, keep.join("index.html")).unwrap();

    let mut cmd = augsplat_testkit::browser::headless(&exe, &dir.path().join("profile1"));
    cmd.arg("--dump-dom").arg(&url);
    let (dom, log) = augsplat_testkit::browser::run_limited(cmd, Duration::from_secs(120));
    assert!(
        dom.contains("<table class=\"metrics\">"),
        "DOM lacks the table; stderr:\n{log}"
    );
    assert!(dom.matches("<svg").count() >= 7, "DOM lacks the plots");
    assert!(dom.contains("AugSplat fixture report"));
    for bad in [
        "Uncaught",
        "ERR_FILE_NOT_FOUND",
        "Failed to load resource",
        "CONSOLE",
    ] {
        assert!(!log.contains(bad), "chromium reported `{bad}`:\n{log}");
    }

    let mut cmd = augsplat_testkit::browser::headless(&exe, &dir.path().join("profile2"));
    cmd.arg(format!("--screenshot={}", shot.display()))
        .arg("--window-size=1280,2000")
        .arg("--hide-scrollbars")
        .arg(&url);
    let (_, log) = augsplat_testkit::browser::run_limited(cmd, Duration::from_secs(120));
    let img = image::open(&shot)
        .unwrap_or_else(|e| panic!("no screenshot at {} ({e}); stderr:\n{log}", shot.display()));
    assert_eq!((img.width(), img.height()), (1280, 2000));
    // Not blank: the page has text, tables and coloured plots.
    let rgb = img.to_rgb8();
    let distinct: std::collections::BTreeSet<[u8; 3]> = rgb.pixels().map(|p| p.0).collect();
    assert!(
        distinct.len() > 50,
        "screenshot looks blank ({} colours)",
        distinct.len()
    );
    eprintln!("screenshot: {}", shot.display());
}
