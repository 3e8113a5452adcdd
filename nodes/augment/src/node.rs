//! The node adapters: typed args in, artifact folders out.

use crate::aggregate::AggregateParams;
use crate::ensemble::aggregate_ensemble;
pub use crate::ensemble::{AggregateReport, AggregateViewStats};
use crate::poses::{candidate_pool, proximity_report, synthesize_poses, PoseParams};
use augsplat_core::artifacts::{self, files, PoseSet};
#[cfg(doc)]
use augsplat_core::artifacts::{RenderSet, SyntheticSet};
use augsplat_core::{Camera, Scene};
use augsplat_graph::{InputDecl, Node, NodeError, RunContext, Threads};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

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
    const VERSION: u32 = 2;
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
    const VERSION: u32 = 2;
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
        let camera = v.camera.downscaled(downscale);
        views.push(augsplat_core::artifacts::PoseView {
            name: v.name.clone(),
            camera,
            origin: format!("scene:{}", v.name),
        });
    }
    Ok(PoseSet { views })
}

/// `AggregateEnsemble`: input `members` (a list of [`RenderSet`] folders, one per ensemble
/// member, EXR channels R, G, B, D, A) → output `synthetic` (a [`SyntheticSet`]:
/// `targets/<name>.exr` (R, G, B), `weights/<name>.exr` (W), `previews/<name>_target.png`,
/// `previews/<name>_weight.png`, and `aggregate_report.json`). See [`crate::aggregate`].
pub struct AggregateEnsemble;

impl Node for AggregateEnsemble {
    const KIND: &'static str = "AggregateEnsemble";
    const VERSION: u32 = 2;
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
        let dirs: Vec<PathBuf> = ctx.input_list("members")?.to_vec();
        let out = ctx.output("synthetic")?.to_path_buf();
        let ctx_ref: &RunContext = ctx;
        let (set, report) = aggregate_ensemble(&dirs, args, &out, &|done, total| {
            ctx_ref.progress(done, total, "aggregating views")
        })?;
        let stats = &report.views;
        let degenerate = stats.iter().filter(|s| s.degenerate).count();
        let mean_w = if stats.is_empty() {
            0.0
        } else {
            stats.iter().map(|s| s.mean_weight).sum::<f64>() / stats.len() as f64
        };
        ctx.log(format!(
            "aggregated {} views over {} members: mean weight {:.4}, {} degenerate (P_hi ≤ P_lo → weight 1 where V ≤ P_lo)",
            set.views.len(),
            report.members,
            mean_w,
            degenerate
        ));
        artifacts::write_json(&out.join(files::SYNTHETIC), &set)?;
        artifacts::write_json(&out.join(AGGREGATE_REPORT), &report)?;
        Ok(())
    }
}
