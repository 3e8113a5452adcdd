//! The `OptimizeSplats` node kind and the family's `register`.
//!
//! Inputs: `train` (scene folder), `test` (scene folder of held-out views), optional
//! `synthetic` (a `SyntheticSet` folder; required by the Staged and Dual schedules), optional
//! `lpips` (a folder holding `lpips_{alex,vgg}_v0.1.safetensors`, or the file itself).
//! Output `model`: `final.ply`, `best.ply`, `curve.json` ([`TrainingCurve`](augsplat_core::artifacts::TrainingCurve)) and `best.json`
//! ([`BestRecord`]).
//!
//! The best checkpoint is chosen by the lowest held-out average error when LPIPS weights are
//! connected, else by the highest PSNR (`best.json` says which). Wall-clock seconds are
//! logged, and written into `curve.json` only with `record_wall_time` (default off), because
//! outputs must be byte-identical for identical args and inputs.

pub use crate::fit::BestRecord;
use crate::fit::{self, FitEvent};
use crate::init::{self, InitView};
use crate::train::{scene_scale, RealImages, RealView, TrainArgs};
use augsplat_core::artifacts;
use augsplat_core::Scene;
use augsplat_graph::{InputDecl, Node, NodeError, Registry, RunContext, Threads};

/// Registers the splatting family's node kinds.
pub fn register(registry: &mut Registry) {
    registry.register::<OptimizeSplats>();
}

/// The Gaussian optimisation node (baseline 3DGS, Staged and Dual AugSplat schedules): an
/// adapter over [`crate::fit`] and [`init::initial_gaussians`].
pub struct OptimizeSplats;

impl Node for OptimizeSplats {
    const KIND: &'static str = "OptimizeSplats";
    // 2: FMA rasteriser kernels, the fused loss and Frusta random initialisation change the
    // outputs. 3: the curve's average error is the mean of per-view average errors (as
    // `Evaluate`), which can change the best checkpoint. 4: the projection's own exp/ln
    // (eight Gaussians per vector) change renders in the last bits. 5: the kernels' base-2
    // exponential (σ in bits, a degree-5 polynomial) changes renders in the last bits.
    // 6: Adam updates every Gaussian by default (`adam: Dense`, gsplat's default), where
    // version 5 and earlier updated only the visible ones (now `adam: Selective`).
    // 7: with `backend: Gpu` the loss and Adam run on the GPU (CPU outputs unchanged).
    const VERSION: u32 = 7;
    type Args = TrainArgs;

    fn inputs(_args: &TrainArgs) -> Vec<InputDecl> {
        vec![
            InputDecl::one("train"),
            InputDecl::one("test"),
            InputDecl::optional("synthetic"),
            InputDecl::optional("lpips"),
            InputDecl::optional("init_depth"),
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

    fn run(a: &TrainArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        a.validate().map_err(NodeError::new)?;
        let train_dir = ctx.input("train")?.to_path_buf();
        let real = RealImages {
            views: fit::load_real_views(&train_dir, "train")?,
            loss: a.real_loss.clone(),
        };
        if real.views.is_empty() {
            return Err(NodeError::new("input `train`: the scene has no views"));
        }
        let test = fit::load_real_views(ctx.input("test")?, "test")?;
        let synth = match ctx.optional_input("synthetic") {
            Some(d) => Some(fit::load_synthetic(d, &a.synthetic)?),
            None => None,
        };
        if let Some(warning) = fit::check_supervision(a, synth.as_ref())? {
            ctx.log(warning);
        }
        let lpips = match ctx.optional_input("lpips") {
            Some(d) => Some(fit::load_lpips(d, &a.lpips_net)?),
            None => None,
        };
        // Held-out views too small for the backbone have no LPIPS: as without weights, the
        // best checkpoint is chosen by PSNR.
        let lpips = match (lpips, test.first()) {
            (Some(m), Some(v)) if !m.accepts(v.camera.width as usize, v.camera.height as usize) => {
                ctx.log(format!(
                    "the held-out views ({}×{}) are too small for LPIPS-{}: LPIPS and the \
                     average error are unavailable; the best checkpoint is chosen by PSNR",
                    v.camera.width,
                    v.camera.height,
                    m.backbone()
                ));
                None
            }
            (m, _) => m,
        };
        let cams: Vec<&augsplat_core::Camera> = real.views.iter().map(|v| &v.camera).collect();
        let sscale = a.scene_scale.unwrap_or_else(|| scene_scale(&cams));
        let scene = Scene::load(&train_dir)?;
        let cloud = scene.load_points(&train_dir)?;
        let views: Vec<InitView<'_>> = real.views.iter().map(RealView::init_view).collect();
        // The prior's depth at the training views, read only when it can matter.
        let prior_maps = match ctx.optional_input("init_depth") {
            Some(d) if cloud.is_empty() => read_prior_depth(d, &real.views)?,
            _ => Vec::new(),
        };
        let prior: Vec<init::PriorDepth<'_>> = prior_maps
            .iter()
            .map(|(view, img)| init::PriorDepth {
                view: *view,
                width: img.width,
                height: img.height,
                depth: img.channel("D").unwrap_or(&[]),
                alpha: img.channel("A").unwrap_or(&[]),
            })
            .collect();
        let init = init::initial_gaussians(
            &cloud,
            &scene,
            &views,
            &prior,
            a.sh_degree,
            &a.init,
            sscale,
            a.seed,
        );
        if let Some(note) = &init.note {
            ctx.log(note);
            if init.warn {
                // On the terminal too: such a start can silently ruin the run.
                eprintln!(
                    "warning: {}: {note}; connect `init_depth` (a radiance field's renders at the \
                     training views) or give the scene SfM points or near/far bounds",
                    ctx.node_name()
                );
            }
        }
        ctx.log(format!(
            "{}: {} train views, {} test views, {} synthetic views, {} initial Gaussians, scene scale {sscale:.4}",
            a.method_label(),
            real.views.len(),
            test.len(),
            synth.as_ref().map_or(0, |s| s.views.len()),
            init.gaussians.len()
        ));
        let device = crate::Device::open(a.backend)
            .map_err(|e| NodeError::new(format!("backend: Gpu: {e}")))?;
        if let Some(adapter) = device.adapter() {
            ctx.log(format!(
                "rendering and back-propagating on the GPU: {adapter}"
            ));
        }
        let ctx_ref: &RunContext = ctx;
        let mut save = |bytes: Vec<u8>| {
            ctx_ref
                .save_checkpoint(&bytes)
                .map_err(|e| e.message().to_string())
        };
        let checkpoints = ctx_ref.checkpoint_every().map(|every| fit::FitCheckpoints {
            every,
            resume: ctx_ref.load_checkpoint(),
            save: &mut save,
        });
        let fitted = fit::fit(
            a,
            init.gaussians,
            sscale,
            &real,
            synth.as_ref(),
            &test,
            lpips.as_ref(),
            &device,
            checkpoints,
            &mut |e| match e {
                FitEvent::Log(line) => ctx_ref.log(line),
                FitEvent::Progress {
                    done,
                    total,
                    message,
                } => ctx_ref.progress(done, total, &message),
            },
        )?;
        let out = ctx.output("model")?.to_path_buf();
        for (name, value) in fitted.timing.measures(fitted.steps_run) {
            ctx.measure(name, value);
        }
        crate::write_ply(&out.join("final.ply"), &fitted.last)?;
        crate::write_ply(&out.join("best.ply"), &fitted.best)?;
        artifacts::write_json(&out.join(artifacts::files::CURVE), &fitted.curve)?;
        artifacts::write_json(&out.join("best.json"), &fitted.best_record())?;
        if let Some(d) = device.adapter() {
            // The adapter that computed the renders and gradients.
            artifacts::write_json(&out.join("device.json"), d)?;
        }
        ctx.log(format!(
            "done: {} steps in {:.1} s",
            fitted.steps_run, fitted.seconds
        ));
        Ok(())
    }
}

/// The prior's depth maps (`RenderField` output at the training views, e.g. through
/// `ScenePoses` of the training scene): per training view found by name, its index and EXR.
fn read_prior_depth(
    dir: &std::path::Path,
    views: &[RealView],
) -> Result<Vec<(usize, augsplat_core::image::ExrImage)>, NodeError> {
    let set: augsplat_core::artifacts::RenderSet =
        augsplat_core::artifacts::read_json(&dir.join("renders.json"))
            .map_err(|e| NodeError::from(e).context("input `init_depth`"))?;
    let mut out = Vec::new();
    for r in &set.views {
        let Some(i) = views.iter().position(|v| v.name == r.name) else {
            continue;
        };
        let img = augsplat_core::image::read_exr(&dir.join(&r.file))
            .map_err(|e| NodeError::from(e).context("input `init_depth`"))?;
        if img.channel("D").is_none() || img.channel("A").is_none() {
            return Err(NodeError::new(format!(
                "input `init_depth`: {} has no D and A channels (connect a RenderField output)",
                dir.join(&r.file).display()
            )));
        }
        out.push((i, img));
    }
    if out.is_empty() {
        return Err(NodeError::new(format!(
            "input `init_depth` ({}): none of its {} render(s) is a training view (render the \
             training scene's poses: ScenePoses of the `train` scene)",
            dir.display(),
            set.views.len()
        )));
    }
    Ok(out)
}
