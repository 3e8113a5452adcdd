//! The `OptimizeSplats` node kind and the family's `register`.
//!
//! Inputs: `train` (scene folder), `test` (scene folder of held-out views), optional
//! `synthetic` (a `SyntheticSet` folder; required by the Staged and Dual schedules), optional
//! `lpips` (a folder holding `lpips_{alex,vgg}_v0.1.safetensors`, or the file itself).
//! Output `model`: `final.ply`, `best.ply`, `curve.json` ([`TrainingCurve`]) and `best.json`
//! ([`BestRecord`]).
//!
//! The best checkpoint is chosen by the lowest held-out average error when LPIPS weights are
//! connected, else by the highest PSNR (`best.json` says which). Wall-clock seconds are
//! logged, and written into `curve.json` only with `record_wall_time` (default off), because
//! outputs must be byte-identical for identical args and inputs.

use crate::init;
use crate::loss::WeightNorm;
use crate::train::{
    evaluate, scene_scale, Evaluation, RealImages, RealView, Supervision, SynthView,
    SyntheticImages, TrainArgs, Trainer,
};
use crate::Gaussians;
use augsplat_core::artifacts::{self, CurvePoint, SyntheticSet, TrainingCurve};
use augsplat_core::{image, Scene};
use augsplat_graph::{InputDecl, Node, NodeError, Registry, RunContext, Threads};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Registers the splatting family's node kinds.
pub fn register(registry: &mut Registry) {
    registry.register::<OptimizeSplats>();
}

/// The Gaussian optimisation node (baseline 3DGS, Staged and Dual AugSplat schedules).
pub struct OptimizeSplats;

/// `best.json`: the selected checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BestRecord {
    /// Method label.
    pub label: String,
    /// "avg_error" (lowest) or "psnr" (highest).
    pub criterion: String,
    /// Steps done at the checkpoint.
    pub step: u64,
    /// The evaluation there.
    pub point: CurvePoint,
    /// Steps actually run (less than requested after an early stop).
    pub steps_run: u64,
    /// Whether training stopped early.
    pub early_stopped: bool,
    /// Scene scale used by the learning rates and densification.
    pub scene_scale: f64,
}

fn load_real(dir: &Path, what: &str) -> Result<Vec<RealView>, NodeError> {
    let scene =
        Scene::load(dir).map_err(|e| NodeError::from(e).context(format!("input `{what}`")))?;
    let mut out = Vec::with_capacity(scene.views.len());
    for (i, v) in scene.views.iter().enumerate() {
        v.camera
            .validate()
            .map_err(|m| NodeError::new(format!("input `{what}`: view {}: {m}", v.name)))?;
        let img = scene
            .load_image(dir, i)
            .map_err(|e| NodeError::from(e).context(format!("input `{what}`")))?;
        if (img.width, img.height) != (v.camera.width, v.camera.height) {
            return Err(NodeError::new(format!(
                "input `{what}`: image {} is {}×{} but its camera is {}×{}",
                dir.join(&v.image).display(),
                img.width,
                img.height,
                v.camera.width,
                v.camera.height
            )));
        }
        out.push(RealView {
            name: v.name.clone(),
            camera: v.camera.clone(),
            image: img.data,
        });
    }
    Ok(out)
}

fn load_synthetic(dir: &Path, args: &TrainArgs) -> Result<Vec<SynthView>, NodeError> {
    let set: SyntheticSet = artifacts::read_json(&dir.join(artifacts::files::SYNTHETIC))
        .map_err(|e| NodeError::from(e).context("input `synthetic`"))?;
    let mut out = Vec::with_capacity(set.views.len());
    for v in &set.views {
        v.camera
            .validate()
            .map_err(|m| NodeError::new(format!("input `synthetic`: view {}: {m}", v.name)))?;
        let tpath = dir.join(&v.target);
        let target = image::read_rgb(&tpath).map_err(NodeError::from)?;
        let wpath = dir.join(&v.weight);
        let exr = image::read_exr(&wpath).map_err(NodeError::from)?;
        let weight = exr
            .channel("W")
            .ok_or_else(|| {
                NodeError::new(format!("{}: weight EXR has no channel W", wpath.display()))
            })?
            .to_vec();
        let (w, h) = (v.camera.width, v.camera.height);
        if (target.width, target.height) != (w, h) || weight.len() != (w * h) as usize {
            return Err(NodeError::new(format!(
                "input `synthetic`: view {}: target {}×{} / weight {} values do not match the camera {}×{}",
                v.name,
                target.width,
                target.height,
                weight.len(),
                w,
                h
            )));
        }
        out.push(SynthView::new(
            v.name.clone(),
            v.camera.clone(),
            target.data,
            weight,
            args.synthetic.skip_below,
        ));
    }
    Ok(out)
}

fn point(step: u64, e: &Evaluation, g: &Gaussians, seconds: f64, loss: f64) -> CurvePoint {
    CurvePoint {
        step,
        psnr: e.psnr,
        ssim: e.ssim,
        lpips: e.lpips,
        mse: e.mse,
        avg_error: e.avg_error,
        primitives: g.len() as u64,
        seconds,
        loss,
    }
}

impl Node for OptimizeSplats {
    const KIND: &'static str = "OptimizeSplats";
    // 2: FMA rasteriser kernels, the fused loss and Frusta random initialisation change the
    // outputs. 3: the curve's average error is the mean of per-view average errors (as
    // `Evaluate`), which can change the best checkpoint. 4: the projection's own exp/ln
    // (eight Gaussians per vector) change renders in the last bits. 5: the kernels' base-2
    // exponential (σ in bits, a degree-5 polynomial) changes renders in the last bits.
    const VERSION: u32 = 5;
    type Args = TrainArgs;

    fn inputs(_args: &TrainArgs) -> Vec<InputDecl> {
        vec![
            InputDecl::one("train"),
            InputDecl::one("test"),
            InputDecl::optional("synthetic"),
            InputDecl::optional("lpips"),
        ]
    }
    fn outputs(_args: &TrainArgs) -> Vec<String> {
        vec!["model".into()]
    }
    fn threads(_args: &TrainArgs) -> Threads {
        Threads::All
    }
    fn validate(args: &TrainArgs) -> Result<(), String> {
        args.validate()
    }

    fn run(args: &TrainArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let a = args;
        a.validate().map_err(NodeError::new)?;
        let train_dir = ctx.input("train")?.to_path_buf();
        let test_dir = ctx.input("test")?.to_path_buf();
        let real = RealImages {
            views: load_real(&train_dir, "train")?,
            loss: a.real_loss.clone(),
        };
        if real.views.is_empty() {
            return Err(NodeError::new("input `train`: the scene has no views"));
        }
        let test = load_real(&test_dir, "test")?;
        let synth = match ctx.optional_input("synthetic") {
            Some(d) => Some(SyntheticImages {
                views: load_synthetic(d, a)?,
                norm: if a.synthetic.normalize_by_weight_sum {
                    WeightNorm::WeightSum
                } else {
                    WeightNorm::PixelCount
                },
            }),
            None => None,
        };
        if a.schedule.needs_synthetic() {
            match &synth {
                None => {
                    return Err(NodeError::new(format!(
                        "schedule {} needs the `synthetic` input (an AggregateEnsemble output)",
                        a.schedule.name()
                    )))
                }
                Some(s) if s.views.iter().all(|v| v.weight_sum <= 0.0) => {
                    ctx.log("warning: every synthetic view has zero weight; synthetic supervision does nothing");
                }
                _ => {}
            }
        }
        let lpips = match ctx.optional_input("lpips") {
            Some(d) => {
                let backbone: augsplat_metrics::lpips::Backbone =
                    a.lpips_net.parse().map_err(NodeError::new)?;
                let path =
                    augsplat_metrics::lpips::find_weights(Some(d), backbone).ok_or_else(|| {
                        NodeError::new(format!(
                            "input `lpips`: {} holds no {}",
                            d.display(),
                            backbone.file_name()
                        ))
                    })?;
                Some(augsplat_metrics::lpips::Lpips::load(&path).map_err(NodeError::from)?)
            }
            None => None,
        };
        let cams: Vec<&augsplat_core::Camera> = real.views.iter().map(|v| &v.camera).collect();
        let sscale = a.scene_scale.unwrap_or_else(|| scene_scale(&cams));
        let scene = Scene::load(&train_dir).map_err(NodeError::from)?;
        let cloud = scene.load_points(&train_dir).map_err(NodeError::from)?;
        let g0 = if cloud.is_empty() {
            let cs: Vec<[f64; 3]> = cams.iter().map(|c| c.center()).collect();
            let center =
                std::array::from_fn(|k| cs.iter().map(|c| c[k]).sum::<f64>() / cs.len() as f64);
            let bounds_ok = scene.near.is_finite()
                && scene.far.is_finite()
                && scene.near > 0.0
                && scene.far > scene.near;
            match a.init.random_in {
                init::RandomInit::Frusta if bounds_ok => {
                    ctx.log(format!(
                        "no sparse points: {} random Gaussians on training rays, depth {:.3}–{:.3} (uniform in disparity)",
                        a.init.random_points, scene.near, scene.far
                    ));
                    let views: Vec<init::InitView<'_>> = real
                        .views
                        .iter()
                        .map(|v| init::InitView {
                            camera: &v.camera,
                            image: &v.image,
                        })
                        .collect();
                    init::random_in_frusta(
                        &views,
                        scene.near,
                        scene.far,
                        a.sh_degree,
                        &a.init,
                        sscale,
                        a.seed,
                    )
                }
                mode => {
                    ctx.log(format!(
                        "no sparse points: {} random Gaussians in a cube of half-side {} scene scales{}",
                        a.init.random_points,
                        a.init.random_extent,
                        if mode == init::RandomInit::Frusta {
                            format!(" (the scene's bounds {}–{} are unusable for Frusta)", scene.near, scene.far)
                        } else {
                            String::new()
                        }
                    ));
                    init::random(center, a.sh_degree, &a.init, sscale, a.seed)
                }
            }
        } else {
            init::from_points(&cloud, a.sh_degree, &a.init, sscale, a.seed)
        };
        let label = if a.label.is_empty() {
            a.schedule.name().to_string()
        } else {
            a.label.clone()
        };
        ctx.log(format!(
            "{label}: {} train views, {} test views, {} synthetic views, {} initial Gaussians, scene scale {sscale:.4}",
            real.views.len(),
            test.len(),
            synth.as_ref().map_or(0, |s| s.views.len()),
            g0.len()
        ));
        let by_avg = lpips.is_some();
        let mut trainer = Trainer::new(
            a.clone(),
            g0,
            sscale,
            &real,
            synth.as_ref().map(|s| s as &dyn Supervision),
        );
        let mut curve = TrainingCurve {
            label: label.clone(),
            points: Vec::new(),
        };
        let mut best: Option<(CurvePoint, Gaussians)> = None;
        let mut since_best = 0u32;
        let mut early = false;
        let t0 = std::time::Instant::now();
        let mut loss_acc = 0.0;
        let mut loss_n = 0u64;
        while trainer.steps_done() < a.steps {
            let rep = trainer.step();
            loss_acc += rep.loss;
            loss_n += 1;
            let done = trainer.steps_done();
            if rep.refine.cloned + rep.refine.split + rep.refine.pruned > 0 || rep.refine.reset {
                ctx.log(format!(
                    "step {done}: cloned {}, split {}, pruned {}{} → {} Gaussians",
                    rep.refine.cloned,
                    rep.refine.split,
                    rep.refine.pruned,
                    if rep.refine.reset {
                        ", opacity reset"
                    } else {
                        ""
                    },
                    rep.gaussians
                ));
            }
            if done.is_multiple_of(a.eval_every) || done == a.steps {
                let settings = a.render_settings(done);
                let e = evaluate(trainer.gaussians(), &test, &settings, lpips.as_ref())
                    .map_err(NodeError::from)?;
                let secs = t0.elapsed().as_secs_f64();
                let p = point(
                    done,
                    &e,
                    trainer.gaussians(),
                    if args.record_wall_time { secs } else { 0.0 },
                    loss_acc / loss_n.max(1) as f64,
                );
                loss_acc = 0.0;
                loss_n = 0;
                ctx.log(format!(
                    "step {done}: PSNR {:.3} SSIM {:.4}{} loss {:.5} Gaussians {} ({secs:.1} s)",
                    p.psnr,
                    p.ssim,
                    p.lpips.map_or(String::new(), |l| format!(" LPIPS {l:.4}")),
                    p.loss,
                    p.primitives
                ));
                let better = match &best {
                    None => true,
                    Some((b, _)) => {
                        if by_avg {
                            p.avg_error.unwrap_or(f64::INFINITY)
                                < b.avg_error.unwrap_or(f64::INFINITY)
                        } else {
                            p.psnr > b.psnr
                        }
                    }
                };
                if better {
                    best = Some((p.clone(), trainer.gaussians().clone()));
                    since_best = 0;
                } else {
                    since_best += 1;
                }
                curve.points.push(p);
                if let Some(pat) = a.early_stop_patience {
                    if since_best >= pat && done < a.steps {
                        ctx.log(format!(
                            "early stop at step {done}: no improvement in {pat} evaluations"
                        ));
                        early = true;
                        break;
                    }
                }
            }
            ctx.progress(done, a.steps, &format!("{label} step {done}/{}", a.steps));
        }
        let out = ctx.output("model")?.to_path_buf();
        let steps_run = trainer.steps_done();
        let (best_point, best_g) = match best {
            Some(b) => b,
            None => {
                // steps = 0: evaluate the initialisation.
                let e = evaluate(
                    trainer.gaussians(),
                    &test,
                    &a.render_settings(0),
                    lpips.as_ref(),
                )
                .map_err(NodeError::from)?;
                let p = point(0, &e, trainer.gaussians(), 0.0, 0.0);
                curve.points.push(p.clone());
                (p, trainer.gaussians().clone())
            }
        };
        crate::write_ply(&out.join("final.ply"), trainer.gaussians()).map_err(NodeError::from)?;
        crate::write_ply(&out.join("best.ply"), &best_g).map_err(NodeError::from)?;
        artifacts::write_json(&out.join(artifacts::files::CURVE), &curve)
            .map_err(NodeError::from)?;
        let rec = BestRecord {
            label,
            criterion: if by_avg {
                "avg_error".into()
            } else {
                "psnr".into()
            },
            step: best_point.step,
            point: best_point,
            steps_run,
            early_stopped: early,
            scene_scale: sscale,
        };
        artifacts::write_json(&out.join("best.json"), &rec).map_err(NodeError::from)?;
        ctx.log(format!(
            "done: {steps_run} steps in {:.1} s",
            t0.elapsed().as_secs_f64()
        ));
        Ok(())
    }
}
