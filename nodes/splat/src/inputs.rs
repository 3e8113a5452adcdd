//! The training node's inputs as the trainer takes them, read from folders: the training and
//! held-out views ([`load_real_views`]), the synthetic set ([`load_synthetic`], an
//! `AggregateEnsemble` output read through
//! [`SyntheticView::read`](augsplat_core::artifacts::SyntheticView::read)), the LPIPS model
//! ([`load_lpips`]), the check of the schedule's needs ([`check_supervision`]), all four
//! together ([`TrainingInputs::load`]), and the start: the scene scale and the initial
//! Gaussians from the scene's points, the prior's depth or the bounds ([`initial_state`]).

use crate::init::{self, InitView};
use crate::loss::WeightNorm;
use crate::train::{
    scene_scale, RealImages, RealView, SynthView, SyntheticArgs, SyntheticImages, TrainArgs,
};
use augsplat_core::artifacts::{self, SyntheticSet};
use augsplat_core::Scene;
use augsplat_graph::NodeError;
use augsplat_metrics::lpips::{self, Backbone, Lpips};
use std::path::Path;

/// The folders a training run reads.
#[derive(Clone, Copy, Debug)]
pub struct InputDirs<'a> {
    /// The training scene.
    pub train: &'a Path,
    /// The held-out scene.
    pub test: &'a Path,
    /// The synthetic set, when connected.
    pub synthetic: Option<&'a Path>,
    /// The LPIPS weights (a folder or the file), when connected.
    pub lpips: Option<&'a Path>,
    /// A radiance field's renders at the training views (depth and alpha), when connected.
    pub init_depth: Option<&'a Path>,
}

/// Everything a training run supervises and evaluates with.
pub struct TrainingInputs {
    /// The training views and their loss.
    pub real: RealImages,
    /// The held-out views.
    pub test: Vec<RealView>,
    /// The synthetic supervision, when connected.
    pub synthetic: Option<SyntheticImages>,
    /// The LPIPS model, when connected and the held-out views are large enough for it.
    pub lpips: Option<Lpips>,
}

impl TrainingInputs {
    /// Loads the inputs of `dirs` for `args`; `log` receives what the run should know (a
    /// synthetic set with zero weight everywhere, held-out views too small for LPIPS).
    pub fn load(
        args: &TrainArgs,
        dirs: &InputDirs<'_>,
        log: &mut dyn FnMut(String),
    ) -> Result<TrainingInputs, NodeError> {
        let real = RealImages {
            views: load_real_views(dirs.train, "train")?,
            loss: args.real_loss.clone(),
        };
        if real.views.is_empty() {
            return Err(NodeError::new("input `train`: the scene has no views"));
        }
        let test = load_real_views(dirs.test, "test")?;
        let synthetic = match dirs.synthetic {
            Some(d) => Some(load_synthetic(d, &args.synthetic)?),
            None => None,
        };
        if let Some(warning) = check_supervision(args, synthetic.as_ref())? {
            log(warning);
        }
        let lpips = match dirs.lpips {
            Some(d) => Some(load_lpips(d, &args.lpips_net)?),
            None => None,
        };
        // Held-out views too small for the backbone have no LPIPS: as without weights, the
        // best checkpoint is chosen by PSNR.
        let lpips = match (lpips, test.first()) {
            (Some(m), Some(v)) if !m.accepts(v.camera.width as usize, v.camera.height as usize) => {
                log(format!(
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
        Ok(TrainingInputs {
            real,
            test,
            synthetic,
            lpips,
        })
    }

    /// One line for the log: the method, the views of each kind, the initial Gaussians and
    /// the scene scale.
    pub fn summary(&self, args: &TrainArgs, initial: usize, scene_scale: f64) -> String {
        format!(
            "{}: {} train views, {} test views, {} synthetic views, {initial} initial Gaussians, scene scale {scene_scale:.4}",
            args.method_label(),
            self.real.views.len(),
            self.test.len(),
            self.synthetic.as_ref().map_or(0, |s| s.views.len()),
        )
    }
}

/// The scene scale (`args.scene_scale`, else [`scene_scale`] of the training cameras) and the
/// initial Gaussians of [`init::initial_gaussians`]: from the training scene's points, else
/// from the prior's depth at the training views (read only then), else random.
pub fn initial_state(
    args: &TrainArgs,
    real: &RealImages,
    dirs: &InputDirs<'_>,
) -> Result<(f64, init::Initial), NodeError> {
    let cams: Vec<&augsplat_core::Camera> = real.views.iter().map(|v| &v.camera).collect();
    let sscale = args.scene_scale.unwrap_or_else(|| scene_scale(&cams));
    let scene = Scene::load(dirs.train)?;
    let cloud = scene.load_points(dirs.train)?;
    let views: Vec<InitView<'_>> = real.views.iter().map(RealView::init_view).collect();
    // The prior's depth at the training views, read only when it can matter.
    let prior_maps = match dirs.init_depth {
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
    let start = init::initial_gaussians(
        &cloud,
        &scene,
        &views,
        &prior,
        args.sh_degree,
        &args.init,
        sscale,
        args.seed,
    );
    Ok((sscale, start))
}

/// Loads the views of the scene folder `dir` as training or held-out images, checking each
/// camera and that each image has its camera's size. `what` names the input in errors.
pub fn load_real_views(dir: &Path, what: &str) -> Result<Vec<RealView>, NodeError> {
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

/// Loads a synthetic set's folder (`synthetic.json` and each view's target and weights) as
/// synthetic supervision with the options `opts` (skip threshold, normalisation).
pub fn load_synthetic(dir: &Path, opts: &SyntheticArgs) -> Result<SyntheticImages, NodeError> {
    let set: SyntheticSet = artifacts::read_json(&dir.join(artifacts::files::SYNTHETIC))
        .map_err(|e| NodeError::from(e).context("input `synthetic`"))?;
    let mut views = Vec::with_capacity(set.views.len());
    for v in &set.views {
        v.camera
            .validate()
            .map_err(|m| NodeError::new(format!("input `synthetic`: view {}: {m}", v.name)))?;
        let px = v
            .read(dir)
            .map_err(|e| NodeError::from(e).context("input `synthetic`"))?;
        views.push(SynthView::new(
            v.name.clone(),
            v.camera.clone(),
            px.target.data,
            px.weight,
            opts.skip_below,
        ));
    }
    Ok(SyntheticImages {
        views,
        norm: if opts.normalize_by_weight_sum {
            WeightNorm::WeightSum
        } else {
            WeightNorm::PixelCount
        },
    })
}

/// Loads the LPIPS model of backbone `net` ("alex" or "vgg") from `dir`, a folder holding
/// `lpips_{alex,vgg}_v0.1.safetensors` or the weights file itself.
pub fn load_lpips(dir: &Path, net: &str) -> Result<Lpips, NodeError> {
    let backbone: Backbone = net.parse().map_err(NodeError::new)?;
    let path = lpips::find_weights(Some(dir), backbone).ok_or_else(|| {
        NodeError::new(format!(
            "input `lpips`: {} holds no {}",
            dir.display(),
            backbone.file_name()
        ))
    })?;
    Ok(Lpips::load(&path)?)
}

/// Checks that the schedule of `args` has the synthetic supervision it needs: an error when
/// it needs some and none is given, a warning (returned) when every synthetic view has zero
/// weight.
pub fn check_supervision(
    args: &TrainArgs,
    synthetic: Option<&SyntheticImages>,
) -> Result<Option<String>, NodeError> {
    if !args.schedule.needs_synthetic() {
        return Ok(None);
    }
    match synthetic {
        None => Err(NodeError::new(format!(
            "schedule {} needs the `synthetic` input (an AggregateEnsemble output)",
            args.schedule.name()
        ))),
        Some(s) if s.views.iter().all(|v| v.weight_sum <= 0.0) => Ok(Some(
            "warning: every synthetic view has zero weight; synthetic supervision does nothing"
                .into(),
        )),
        _ => Ok(None),
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
