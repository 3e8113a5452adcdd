//! The node adapters: typed args in, artifact folders out.

use crate::aggregate::{aggregate_view, AggregateParams, Workspace};
use crate::poses::{candidate_pool, proximity_report, synthesize_poses, PoseParams};
use augsplat_core::artifacts::{self, files, PoseSet, RenderSet, SyntheticSet, SyntheticView};
use augsplat_core::{image, Camera, ImageF32, Scene};
use augsplat_graph::{InputDecl, Node, NodeError, RunContext, Threads};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// File name of the pose proximity report written beside `poses.json`.
pub const POSES_REPORT: &str = "poses_report.json";
/// File name of the per-view aggregation statistics written beside `synthetic.json`.
pub const AGGREGATE_REPORT: &str = "aggregate_report.json";

/// `SynthesizePoses`: input `train` (a scene folder) → output `poses` (`poses.json`, a
/// [`PoseSet`], plus `poses_report.json`, a [`crate::poses::PosesReport`]).
/// See [`crate::poses`] for the method.
pub struct SynthesizePoses;

impl Node for SynthesizePoses {
    const KIND: &'static str = "SynthesizePoses";
    const VERSION: u32 = 1;
    type Args = PoseParams;

    fn inputs(_: &PoseParams) -> Vec<InputDecl> {
        vec![InputDecl::one("train")]
    }
    fn outputs(_: &PoseParams) -> Vec<String> {
        vec!["poses".into()]
    }
    fn threads(_: &PoseParams) -> Threads {
        Threads::One
    }
    fn validate(args: &PoseParams) -> Result<(), String> {
        args.validate()
    }
    fn run(args: &PoseParams, ctx: &mut RunContext) -> Result<(), NodeError> {
        let train = ctx.input("train")?;
        let scene = Scene::load(train)?;
        let views: Vec<(String, Camera)> = scene
            .views
            .iter()
            .map(|v| (v.name.clone(), v.camera.clone()))
            .collect();
        let pool = candidate_pool(&views, args)
            .map_err(|e| NodeError::new(e.to_string()).context(train.display()))?;
        let poses = synthesize_poses(&views, args)
            .map_err(|e| NodeError::new(e.to_string()).context(train.display()))?;
        let pool_jitter = pool
            .iter()
            .filter(|c| c.origin.starts_with("jitter:"))
            .count();
        let report = proximity_report(
            &views,
            (pool_jitter, pool.len() - pool_jitter),
            args.count,
            &poses,
        );
        if poses.len() < args.count {
            ctx.log(format!(
                "warning: the pool holds only {} candidates; using all of them instead of {}",
                pool.len(),
                args.count
            ));
        }
        ctx.log(format!(
            "{} poses ({} jittered, {} interpolated) from {} training views; median NN distance {:.4}; \
             distance to nearest training camera / NN distance: min {:.3} median {:.3} max {:.3}; \
             view angle to it (deg): min {:.2} median {:.2} max {:.2}",
            report.drawn,
            report.drawn_jitter,
            report.drawn_interpolated,
            report.training_views,
            report.median_nn_distance,
            report.nearest_distance_rel.min,
            report.nearest_distance_rel.median,
            report.nearest_distance_rel.max,
            report.nearest_view_angle_deg.min,
            report.nearest_view_angle_deg.median,
            report.nearest_view_angle_deg.max,
        ));
        let out = ctx.output("poses")?;
        artifacts::write_json(&out.join(files::POSES), &PoseSet { views: poses })?;
        artifacts::write_json(&out.join(POSES_REPORT), &report)?;
        Ok(())
    }
}

/// Args of [`ScenePoses`].
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScenePosesArgs {
    /// Integer downscale of the cameras (1 = the scene's image resolution).
    pub downscale: u32,
}

impl Default for ScenePosesArgs {
    fn default() -> Self {
        ScenePosesArgs { downscale: 1 }
    }
}

/// `ScenePoses`: input `scene` (a scene folder) → output `poses` (`poses.json`, a
/// [`PoseSet`] with one pose per view: the view's name and camera, at 1/`downscale` of its
/// resolution, origin `scene:<name>`). It lets a field ensemble be rendered at real views —
/// e.g. the held-out ones, to measure each member and the ensemble median (`EvaluateEnsemble`).
pub struct ScenePoses;

impl Node for ScenePoses {
    const KIND: &'static str = "ScenePoses";
    const VERSION: u32 = 1;
    type Args = ScenePosesArgs;

    fn inputs(_: &ScenePosesArgs) -> Vec<InputDecl> {
        vec![InputDecl::one("scene")]
    }
    fn outputs(_: &ScenePosesArgs) -> Vec<String> {
        vec!["poses".into()]
    }
    fn threads(_: &ScenePosesArgs) -> Threads {
        Threads::One
    }
    fn validate(args: &ScenePosesArgs) -> Result<(), String> {
        if args.downscale == 0 {
            return Err("downscale must be ≥ 1".into());
        }
        Ok(())
    }
    fn run(args: &ScenePosesArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let dir = ctx.input("scene")?.to_path_buf();
        let poses = scene_poses(&dir, args.downscale)?;
        let out = ctx.output("poses")?;
        artifacts::write_json(&out.join(files::POSES), &poses)?;
        Ok(())
    }
}

/// The poses of every view of the scene folder `dir`, cameras at 1/`downscale` (rounded up).
/// Errors name the scene file and the view whose camera is invalid.
pub fn scene_poses(dir: &Path, downscale: u32) -> Result<PoseSet, NodeError> {
    let scene = Scene::load(dir)?;
    if scene.views.is_empty() {
        return Err(NodeError::new(format!(
            "{}: the scene has no views",
            dir.join(augsplat_core::scene::SCENE_FILE).display()
        )));
    }
    let downscale = downscale.max(1);
    let mut views = Vec::with_capacity(scene.views.len());
    for v in &scene.views {
        v.camera.validate().map_err(|e| {
            NodeError::new(format!(
                "{}: view {:?}: {e}",
                dir.join(augsplat_core::scene::SCENE_FILE).display(),
                v.name
            ))
        })?;
        let camera = if downscale > 1 {
            v.camera.resized(
                v.camera.width.div_ceil(downscale),
                v.camera.height.div_ceil(downscale),
            )
        } else {
            v.camera.clone()
        };
        views.push(augsplat_core::artifacts::PoseView {
            name: v.name.clone(),
            camera,
            origin: format!("scene:{}", v.name),
        });
    }
    Ok(PoseSet { views })
}

/// Per-view statistics of an aggregation (`aggregate_report.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AggregateViewStats {
    /// The view's name.
    pub name: String,
    /// Lower normalisation percentile of the (blurred) variance.
    pub p_lo: f64,
    /// Upper normalisation percentile.
    pub p_hi: f64,
    /// Mean (blurred) variance.
    pub mean_variance: f64,
    /// Mean weight.
    pub mean_weight: f64,
    /// Whether the normalisation was degenerate (P_hi ≤ P_lo; see [`crate::aggregate`]).
    pub degenerate: bool,
}

/// The aggregation report.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AggregateReport {
    /// Ensemble members aggregated.
    pub members: usize,
    /// The args used.
    pub params: AggregateParams,
    /// Per view.
    pub views: Vec<AggregateViewStats>,
}

/// `AggregateEnsemble`: input `members` (a list of [`RenderSet`] folders, one per ensemble
/// member, EXR channels R, G, B, D, A) → output `synthetic` (a [`SyntheticSet`]:
/// `targets/<name>.exr` (R, G, B), `weights/<name>.exr` (W), `previews/<name>_target.png`,
/// `previews/<name>_weight.png`, and `aggregate_report.json`). See [`crate::aggregate`].
pub struct AggregateEnsemble;

/// A file-name-safe version of a view name.
fn file_stem(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Reads the R, G, B planes of a render EXR into one planar buffer, checking its size and
/// that every value is finite.
fn read_planar_rgb(path: &Path, cam: &Camera) -> Result<Vec<f32>, NodeError> {
    let exr = image::read_exr(path)?;
    if exr.width != cam.width || exr.height != cam.height {
        return Err(NodeError::new(format!(
            "{}: image is {}×{}, its camera says {}×{}",
            path.display(),
            exr.width,
            exr.height,
            cam.width,
            cam.height
        )));
    }
    let n = (cam.width * cam.height) as usize;
    let mut out = Vec::with_capacity(3 * n);
    for ch in ["R", "G", "B"] {
        let plane = exr.channel(ch).ok_or_else(|| {
            NodeError::new(format!(
                "{}: no channel {ch} (has {:?})",
                path.display(),
                exr.names()
            ))
        })?;
        if let Some(i) = plane.iter().position(|v| !v.is_finite()) {
            return Err(NodeError::new(format!(
                "{}: channel {ch} holds a non-finite value ({}) at pixel ({}, {})",
                path.display(),
                plane[i],
                i % cam.width as usize,
                i / cam.width as usize
            )));
        }
        out.extend_from_slice(plane);
    }
    Ok(out)
}

impl Node for AggregateEnsemble {
    const KIND: &'static str = "AggregateEnsemble";
    const VERSION: u32 = 1;
    type Args = AggregateParams;

    fn inputs(_: &AggregateParams) -> Vec<InputDecl> {
        vec![InputDecl::many("members")]
    }
    fn outputs(_: &AggregateParams) -> Vec<String> {
        vec!["synthetic".into()]
    }
    fn threads(_: &AggregateParams) -> Threads {
        Threads::All
    }
    fn validate(args: &AggregateParams) -> Result<(), String> {
        args.validate()
    }
    fn run(args: &AggregateParams, ctx: &mut RunContext) -> Result<(), NodeError> {
        args.validate().map_err(NodeError::new)?;
        let dirs: Vec<PathBuf> = ctx.input_list("members")?.to_vec();
        if dirs.is_empty() {
            return Err(NodeError::new("input `members` lists no render sets"));
        }
        let sets: Vec<RenderSet> = dirs
            .iter()
            .map(|d| artifacts::read_json::<RenderSet>(&d.join(files::RENDERS)))
            .collect::<Result<_, _>>()?;
        // Every member must render the same views with the same cameras' image sizes.
        let first = &sets[0];
        for (k, s) in sets.iter().enumerate().skip(1) {
            if s.views.len() != first.views.len() {
                return Err(NodeError::new(format!(
                    "member {k} ({}) has {} views, member 0 ({}) has {}",
                    dirs[k].display(),
                    s.views.len(),
                    dirs[0].display(),
                    first.views.len()
                )));
            }
            for (a, b) in first.views.iter().zip(&s.views) {
                if a.name != b.name
                    || a.camera.width != b.camera.width
                    || a.camera.height != b.camera.height
                {
                    return Err(NodeError::new(format!(
                        "member {k} ({}) view `{}` ({}×{}) does not match member 0 view `{}` ({}×{})",
                        dirs[k].display(),
                        b.name,
                        b.camera.width,
                        b.camera.height,
                        a.name,
                        a.camera.width,
                        a.camera.height
                    )));
                }
            }
        }
        let out = ctx.output("synthetic")?.to_path_buf();
        for sub in ["targets", "weights", "previews"] {
            std::fs::create_dir_all(out.join(sub))
                .map_err(|e| NodeError::from(e).context(out.join(sub).display()))?;
        }
        let total = first.views.len() as u64;
        let done = AtomicU64::new(0);
        let ctx_ref: &RunContext = ctx;
        let results: Vec<(SyntheticView, AggregateViewStats)> = first
            .views
            .par_iter()
            .enumerate()
            .map_init(Workspace::default, |ws, (vi, view)| {
                let cam = &view.camera;
                let members: Vec<Vec<f32>> = sets
                    .iter()
                    .zip(&dirs)
                    .map(|(s, d)| read_planar_rgb(&d.join(&s.views[vi].file), cam))
                    .collect::<Result<_, _>>()?;
                let refs: Vec<&[f32]> = members.iter().map(|v| v.as_slice()).collect();
                let (w, h) = (cam.width as usize, cam.height as usize);
                let agg = aggregate_view(&refs, w, h, args, ws);
                let n = w * h;
                let stem = file_stem(&view.name);
                let target_rel = format!("targets/{stem}.exr");
                let weight_rel = format!("weights/{stem}.exr");
                let (r, g, b) = (
                    &agg.target[..n],
                    &agg.target[n..2 * n],
                    &agg.target[2 * n..],
                );
                image::write_exr(
                    &out.join(&target_rel),
                    cam.width,
                    cam.height,
                    &[("R", r), ("G", g), ("B", b)],
                )?;
                image::write_exr(
                    &out.join(&weight_rel),
                    cam.width,
                    cam.height,
                    &[("W", &agg.weight)],
                )?;
                let mut rgb = Vec::with_capacity(3 * n);
                for p in 0..n {
                    rgb.extend_from_slice(&[r[p], g[p], b[p]]);
                }
                image::write_png(
                    &out.join(format!("previews/{stem}_target.png")),
                    &ImageF32::from_vec(cam.width, cam.height, 3, rgb),
                )?;
                image::write_png(
                    &out.join(format!("previews/{stem}_weight.png")),
                    &ImageF32::from_vec(cam.width, cam.height, 1, agg.weight.clone()),
                )?;
                let weight_sum: f64 = agg.weight.iter().map(|&x| x as f64).sum();
                let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                ctx_ref.progress(d, total, "aggregating views");
                Ok((
                    SyntheticView {
                        name: view.name.clone(),
                        camera: cam.clone(),
                        target: target_rel,
                        weight: weight_rel,
                        weight_sum,
                    },
                    AggregateViewStats {
                        name: view.name.clone(),
                        p_lo: agg.p_lo,
                        p_hi: agg.p_hi,
                        mean_variance: agg.mean_variance,
                        mean_weight: if n > 0 { weight_sum / n as f64 } else { 0.0 },
                        degenerate: agg.degenerate,
                    },
                ))
            })
            .collect::<Result<_, NodeError>>()?;
        let (views, stats): (Vec<_>, Vec<_>) = results.into_iter().unzip();
        let degenerate = stats.iter().filter(|s| s.degenerate).count();
        let mean_w = if stats.is_empty() {
            0.0
        } else {
            stats.iter().map(|s| s.mean_weight).sum::<f64>() / stats.len() as f64
        };
        ctx.log(format!(
            "aggregated {} views over {} members: mean weight {:.4}, {} degenerate (P_hi ≤ P_lo → weight 1 where V ≤ P_lo)",
            views.len(),
            sets.len(),
            mean_w,
            degenerate
        ));
        artifacts::write_json(&out.join(files::SYNTHETIC), &SyntheticSet { views })?;
        artifacts::write_json(
            &out.join(AGGREGATE_REPORT),
            &AggregateReport {
                members: sets.len(),
                params: args.clone(),
                views: stats,
            },
        )?;
        Ok(())
    }
}
