//! The node kinds of this crate: thin adapters from typed args and folders to the library.
//!
//! | kind | inputs | outputs |
//! |---|---|---|
//! | `ImportScene` | `source` (COLMAP / transforms.json / LLFF folder) | `scene` |
//! | `SyntheticScene` | — | `scene` (plus `exact_depth/`) |
//! | `SplitScene` | `scene` | `train`, `test` |
//! | `TriangulatePoints` | `scene` | `scene` (with `points3D` from its photos) |
//! | `SparseDepth` | `scene`, optional `dense` (folder of per-view depth maps) | `scene` |
//! | `ExportScene` | `scene` | `export` |

use crate::depth::{self, DepthMap};
use crate::error::SceneError;
use crate::export::{export_scene, ExportFormat};
use crate::import::{check_scene, copy_scene, import_scene, ImportOptions, NormalizeMode};
use crate::source::{load_colmap, load_llff, load_transforms, RawScene};
use crate::split::{split_indices, subset};
use crate::synthetic::{generate, SyntheticParams};
use crate::triangulate::matching::MatchRules;
use crate::triangulate::solve::SolveRules;
use crate::triangulate::{triangulate_scene, TriangulateOptions};
use augsplat_core::Scene;
use augsplat_graph::{InputDecl, Node, NodeError, Registry, RunContext, Threads};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Component, Path, PathBuf};

/// Registers every node kind of this crate.
pub fn register(registry: &mut Registry) {
    registry
        .register::<ImportScene>()
        .register::<SyntheticScene>()
        .register::<SplitScene>()
        .register::<SparseDepth>()
        .register::<TriangulatePoints>()
        .register::<ExportScene>();
}

/// Source formats of [`ImportScene`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum SourceFormat {
    /// Detect: `model` if given, else `transforms.json`, else `poses_bounds.npy`, else a COLMAP
    /// model in `sparse/0`, `sparse`, `sparse_txt`, `colmap/sparse/0` or the folder itself.
    #[default]
    Auto,
    /// A COLMAP sparse model (binary or text) with an images folder.
    Colmap,
    /// A nerfstudio / instant-ngp transforms.json.
    Transforms,
    /// LLFF `poses_bounds.npy` with `images_N`.
    Llff,
}

/// Args of [`ImportScene`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ImportSceneArgs {
    /// The source format.
    pub format: SourceFormat,
    /// Images folder relative to the source (default: `images` for COLMAP, `images_<llff_factor>`
    /// for LLFF; transforms.json paths are relative to the JSON file).
    pub images: Option<String>,
    /// The COLMAP model folder or the transforms JSON file, relative to the source (default:
    /// detected, see [`SourceFormat::Auto`]).
    pub model: Option<String>,
    /// LLFF images folder factor: 8 reads `images_8` (1 reads `images`).
    pub llff_factor: u32,
    /// Integer downscale (area averaging) applied after undistortion.
    pub downscale: u32,
    /// Undistort distorted cameras to their pinhole part (see `intrinsics`).
    pub undistort: bool,
    /// The normalisation policy.
    pub normalize: NormalizeMode,
    /// Import a COLMAP model or transforms.json whose registered views lack their image file,
    /// leaving those views out (listed on the terminal and in the log). Off by default: a
    /// missing photo is an error. (Not serialised when off, so keys of earlier runs stand.)
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub allow_missing_images: bool,
    /// Choose the downscale from the photos: the smallest factor (at least `downscale`) that
    /// brings the longest side of every view to at most this many pixels, so one pipeline fits
    /// any capture (`pipelines/capture.ron` uses 512). `None`: `downscale` alone. (Not
    /// serialised when `None`, so keys of earlier runs stand.)
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_side: Option<u32>,
}

impl Default for ImportSceneArgs {
    fn default() -> Self {
        ImportSceneArgs {
            format: SourceFormat::Auto,
            images: None,
            model: None,
            llff_factor: 8,
            downscale: 1,
            undistort: true,
            normalize: NormalizeMode::Cameras,
            allow_missing_images: false,
            max_side: None,
        }
    }
}

/// The downscale factor for views whose longest side is `longest` pixels: the smallest factor
/// of at least `downscale` that brings it to at most `max_side` (capped at 64).
pub fn auto_downscale(longest: u32, downscale: u32, max_side: Option<u32>) -> u32 {
    match max_side {
        None => downscale,
        Some(m) => downscale.max(longest.div_ceil(m.max(1))).min(64),
    }
}

/// A path argument relative to the source folder: no absolute paths, no `..`.
fn relative(arg: &str, value: &str) -> Result<PathBuf, String> {
    let p = Path::new(value);
    if p.is_absolute()
        || p.components()
            .any(|c| matches!(c, Component::ParentDir | Component::Prefix(_)))
    {
        return Err(format!(
            "{arg} = {value:?} must be a path inside the source folder (relative, without `..`)"
        ));
    }
    Ok(p.to_path_buf())
}

/// `path` relative to the source folder, for descriptions that must not depend on where the
/// source lives (the scene's bytes must be the same for the same source content).
fn rel(source: &Path, path: &Path) -> String {
    match path.strip_prefix(source) {
        Ok(r) if r.as_os_str().is_empty() => ".".into(),
        Ok(r) => r.display().to_string(),
        Err(_) => path.display().to_string(),
    }
}

/// Reads a source folder into a raw scene according to `args`. The scene's `source` text
/// names the format and the model/images paths relative to the source folder.
pub fn read_source(source: &Path, args: &ImportSceneArgs) -> Result<RawScene, SceneError> {
    if !source.is_dir() {
        return Err(SceneError::missing(source, "source folder"));
    }
    let model = args
        .model
        .as_deref()
        .map(|m| relative("model", m).map(|p| source.join(p)))
        .transpose()
        .map_err(SceneError::Invalid)?;
    let images = args
        .images
        .as_deref()
        .map(|m| relative("images", m).map(|p| source.join(p)))
        .transpose()
        .map_err(SceneError::Invalid)?;
    let colmap_candidates = ["sparse/0", "sparse", "sparse_txt", "colmap/sparse/0", "."];
    let format = match args.format {
        SourceFormat::Auto => match &model {
            Some(m) if m.extension().is_some_and(|e| e == "json") => SourceFormat::Transforms,
            Some(_) => SourceFormat::Colmap,
            None if source.join("transforms.json").is_file() => SourceFormat::Transforms,
            None if source.join("poses_bounds.npy").is_file() => SourceFormat::Llff,
            None if colmap_candidates
                .iter()
                .any(|c| crate::colmap::is_model_dir(&source.join(c))) =>
            {
                SourceFormat::Colmap
            }
            None => {
                return Err(SceneError::format(
                    source,
                    "cannot tell the format: no transforms.json, no poses_bounds.npy, and no COLMAP \
                     model (cameras.bin/.txt) in sparse/0, sparse, sparse_txt, colmap/sparse/0 or the \
                     folder itself; set `format` and `model`",
                ))
            }
        },
        f => f,
    };
    match format {
        SourceFormat::Colmap => {
            let model_dir = match model {
                Some(m) => m,
                None => colmap_candidates
                    .iter()
                    .map(|c| source.join(c))
                    .find(|d| crate::colmap::is_model_dir(d))
                    .ok_or_else(|| SceneError::missing(&source.join("sparse/0"), "COLMAP model"))?,
            };
            let images = images.unwrap_or_else(|| source.join("images"));
            let mut raw = load_colmap(&model_dir, &images)?;
            raw.source = format!(
                "COLMAP model {} with images {}",
                rel(source, &model_dir),
                rel(source, &images)
            );
            Ok(raw)
        }
        SourceFormat::Transforms => {
            let file = model.unwrap_or_else(|| source.join("transforms.json"));
            let mut raw = load_transforms(&file)?;
            raw.source = format!("transforms.json {}", rel(source, &file));
            Ok(raw)
        }
        SourceFormat::Llff => {
            let (images, note) = match images {
                Some(i) => (i, None),
                None => crate::source::choose_llff_images(source, args.llff_factor)?,
            };
            let mut raw = load_llff(source, &images)?;
            raw.warnings.extend(note);
            raw.source = format!("LLFF poses_bounds.npy with images {}", rel(source, &images));
            Ok(raw)
        }
        SourceFormat::Auto => unreachable!("resolved above"),
    }
}

/// `ImportScene`: a COLMAP, transforms.json or LLFF source → a normalised scene.
pub struct ImportScene;

impl Node for ImportScene {
    const KIND: &'static str = "ImportScene";
    const VERSION: u32 = 4;
    type Args = ImportSceneArgs;

    fn inputs(_: &Self::Args) -> Vec<InputDecl> {
        vec![InputDecl::one("source")]
    }
    fn outputs(_: &Self::Args) -> Vec<String> {
        vec!["scene".into()]
    }
    fn threads(_: &Self::Args) -> Threads {
        Threads::All
    }
    fn validate(a: &Self::Args) -> Result<(), String> {
        if a.downscale == 0 || a.downscale > 64 {
            return Err(format!("downscale = {} must be within 1..=64", a.downscale));
        }
        if a.max_side.is_some_and(|m| m < 16) {
            return Err(format!(
                "max_side = {} must be at least 16 pixels (or None)",
                a.max_side.unwrap_or(0)
            ));
        }
        if let Some(m) = &a.model {
            relative("model", m)?;
        }
        if let Some(m) = &a.images {
            relative("images", m)?;
        }
        Ok(())
    }
    fn run(a: &Self::Args, ctx: &mut RunContext) -> Result<(), NodeError> {
        Self::validate(a).map_err(NodeError::new)?;
        let source = ctx.input("source")?.to_path_buf();
        let out = ctx.output("scene")?.to_path_buf();
        let raw = read_source(&source, a)?;
        if !raw.missing_images.is_empty() {
            let list: Vec<String> = raw.missing_images.iter().map(|p| rel(&source, p)).collect();
            if !a.allow_missing_images {
                return Err(NodeError::new(format!(
                    "{} registered view(s) of {} have no image file: {}. Restore the photos, or set \
                     `allow_missing_images: true` to import without those views",
                    list.len(),
                    raw.source,
                    list.join(", ")
                )));
            }
            // On the terminal as well as in the log: a smaller scene changes every result.
            eprintln!(
                "warning: ImportScene: skipping {} registered view(s) without an image file: {}",
                list.len(),
                list.join(", ")
            );
        }
        let longest = raw
            .views
            .iter()
            .map(|v| v.intrinsics.width.max(v.intrinsics.height))
            .max()
            .unwrap_or(1);
        let downscale = auto_downscale(longest, a.downscale, a.max_side);
        if downscale != a.downscale {
            ctx.log(format!(
                "downscale {downscale}: the longest side, {longest} px, to at most {} px",
                a.max_side.unwrap_or(0)
            ));
        }
        let opts = ImportOptions {
            downscale,
            undistort: a.undistort,
            normalize: a.normalize,
        };
        let log = |s: &str| ctx.log(s);
        let scene = import_scene(&raw, &opts, &out, &log)?;
        ctx.log(format!(
            "imported {} views ({}), {} points",
            scene.views.len(),
            raw.source,
            raw.points.positions.len()
        ));
        Ok(())
    }
}

/// `SyntheticScene`: the generated default scene (no inputs).
pub struct SyntheticScene;

impl Node for SyntheticScene {
    const KIND: &'static str = "SyntheticScene";
    const VERSION: u32 = 2;
    type Args = SyntheticParams;

    fn inputs(_: &Self::Args) -> Vec<InputDecl> {
        Vec::new()
    }
    fn outputs(_: &Self::Args) -> Vec<String> {
        vec!["scene".into()]
    }
    fn threads(_: &Self::Args) -> Threads {
        Threads::All
    }
    fn validate(a: &Self::Args) -> Result<(), String> {
        a.validate()
    }
    fn run(a: &Self::Args, ctx: &mut RunContext) -> Result<(), NodeError> {
        let out = ctx.output("scene")?.to_path_buf();
        let scene = generate(a, &out)?;
        ctx.log(format!("generated {} views", scene.views.len()));
        Ok(())
    }
}

/// Args of [`SplitScene`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SplitSceneArgs {
    /// Views to sample before the holdout (`None` keeps all; more than available keeps all).
    pub count: Option<u32>,
    /// Every n-th sampled view (in name order, starting with the first) is a test view.
    pub holdout_every: u32,
    /// Seed of the sampling.
    pub seed: u64,
}

impl Default for SplitSceneArgs {
    fn default() -> Self {
        SplitSceneArgs {
            count: Some(30),
            holdout_every: 8,
            seed: 42,
        }
    }
}

/// `SplitScene`: the paper's sparse-view split into `train` and `test` scenes.
pub struct SplitScene;

impl Node for SplitScene {
    const KIND: &'static str = "SplitScene";
    const VERSION: u32 = 2;
    type Args = SplitSceneArgs;

    fn inputs(_: &Self::Args) -> Vec<InputDecl> {
        vec![InputDecl::one("scene")]
    }
    fn outputs(_: &Self::Args) -> Vec<String> {
        vec!["train".into(), "test".into()]
    }
    fn validate(a: &Self::Args) -> Result<(), String> {
        if a.holdout_every < 2 {
            return Err(format!(
                "holdout_every = {} must be at least 2",
                a.holdout_every
            ));
        }
        if a.count == Some(0) {
            return Err("count must be at least 1 (or None for all views)".into());
        }
        Ok(())
    }
    fn run(a: &Self::Args, ctx: &mut RunContext) -> Result<(), NodeError> {
        let src = ctx.input("scene")?.to_path_buf();
        let scene = Scene::load(&src)?;
        let cloud = scene.load_points(&src)?;
        check_scene(&scene, &cloud, &src)?;
        let split = split_indices(scene.views.len(), a.count, a.holdout_every, a.seed)?;
        if let Some(k) = a.count {
            if (k as usize) > scene.views.len() {
                ctx.log(format!(
                    "warning: count {k} exceeds the {} views available; keeping all",
                    scene.views.len()
                ));
            }
        }
        let (train, train_pts) = subset(&scene, &cloud, &split.train, 2);
        let (test, test_pts) = subset(&scene, &cloud, &split.test, 0);
        copy_scene(&train, &train_pts, &src, ctx.output("train")?)?;
        copy_scene(&test, &test_pts, &src, ctx.output("test")?)?;
        ctx.log(format!(
            "split: {} train, {} test views; {} of {} points kept (seen by ≥ 2 train views)",
            train.views.len(),
            test.views.len(),
            train_pts.len(),
            cloud.len()
        ));
        Ok(())
    }
}

/// Args of [`SparseDepth`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SparseDepthArgs {
    /// Points need at least this many views in their track.
    pub min_track: u32,
    /// σ of the weight exp(−(e/σ)²) in pixels (`None`: the mean error of the points used).
    pub sigma_px: Option<f64>,
    /// Depth per unit of a 16-bit dense depth PNG (source units).
    pub dense_png_scale: f64,
    /// Weight given to dense depth.
    pub dense_weight: f32,
}

impl Default for SparseDepthArgs {
    fn default() -> Self {
        SparseDepthArgs {
            min_track: 2,
            sigma_px: None,
            dense_png_scale: 0.001,
            dense_weight: 1.0,
        }
    }
}

/// `SparseDepth`: per-view depth (Z) and confidence (W) EXRs from the SfM points, or from
/// dense maps in the optional `dense` input where a view has one.
pub struct SparseDepth;

impl Node for SparseDepth {
    const KIND: &'static str = "SparseDepth";
    const VERSION: u32 = 2;
    type Args = SparseDepthArgs;

    fn inputs(_: &Self::Args) -> Vec<InputDecl> {
        vec![InputDecl::one("scene"), InputDecl::optional("dense")]
    }
    fn outputs(_: &Self::Args) -> Vec<String> {
        vec!["scene".into()]
    }
    fn validate(a: &Self::Args) -> Result<(), String> {
        if let Some(s) = a.sigma_px {
            if !(s > 0.0 && s.is_finite()) {
                return Err(format!("sigma_px = {s} must be positive"));
            }
        }
        if !(a.dense_png_scale > 0.0 && a.dense_png_scale.is_finite()) {
            return Err(format!(
                "dense_png_scale = {} must be positive",
                a.dense_png_scale
            ));
        }
        if !(0.0..=1.0).contains(&a.dense_weight) {
            return Err(format!(
                "dense_weight = {} must be within [0, 1]",
                a.dense_weight
            ));
        }
        Ok(())
    }
    fn run(a: &Self::Args, ctx: &mut RunContext) -> Result<(), NodeError> {
        Self::validate(a).map_err(NodeError::new)?;
        let src = ctx.input("scene")?.to_path_buf();
        let dense = ctx.optional_input("dense").map(Path::to_path_buf);
        let out = ctx.output("scene")?.to_path_buf();
        let mut scene = Scene::load(&src)?;
        let cloud = scene.load_points(&src)?;
        check_scene(&scene, &cloud, &src)?;
        let min_track = a.min_track.max(1) as usize;
        let sigma = depth::weight_sigma(&cloud, min_track, a.sigma_px);
        let ddir = out.join("depth");
        std::fs::create_dir_all(&ddir).map_err(|e| SceneError::io(&ddir, e))?;
        let results: Vec<Result<(bool, usize), SceneError>> = (0..scene.views.len())
            .into_par_iter()
            .map(|i| {
                let d = match &dense {
                    Some(dir) => {
                        depth::dense_depth(&scene, i, dir, a.dense_png_scale, a.dense_weight)?
                    }
                    None => None,
                };
                let used_dense = d.is_some();
                let DepthMap { z, w } =
                    d.unwrap_or_else(|| depth::sparse_depth(&scene, &cloud, i, min_track, sigma));
                let v = &scene.views[i];
                let path = ddir.join(format!("{}.exr", v.name));
                augsplat_core::image::write_exr(
                    &path,
                    v.camera.width,
                    v.camera.height,
                    &[("Z", &z), ("W", &w)],
                )?;
                Ok((used_dense, z.iter().filter(|&&x| x > 0.0).count()))
            })
            .collect();
        let (mut n_dense, mut n_px) = (0, 0);
        for r in results {
            let (d, n) = r?;
            n_dense += d as usize;
            n_px += n;
        }
        for v in &mut scene.views {
            v.depth = Some(format!("depth/{}.exr", v.name));
        }
        copy_scene(&scene, &cloud, &src, &out)?;
        ctx.log(format!(
            "depth for {} views ({n_dense} dense), {n_px} pixels with depth, σ = {sigma:.4} px",
            scene.views.len()
        ));
        Ok(())
    }
}

/// When [`TriangulatePoints`] triangulates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum TriangulateWhen {
    /// Only when the scene has no points (else the folder passes through unchanged).
    #[default]
    Missing,
    /// Always, replacing any points the scene has.
    Always,
    /// Never: the folder passes through unchanged, and Gaussians without points start at
    /// random in the frusta.
    Never,
}

/// Args of [`TriangulatePoints`] (see [`crate::triangulate`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TriangulatePointsArgs {
    /// When to triangulate.
    pub when: TriangulateWhen,
    /// Keypoints per view at most.
    pub max_features: u32,
    /// Views each view is matched with (nearest centres among those looking the same way).
    pub neighbours: u32,
    /// Largest angle between two matched views' optical axes, degrees.
    pub max_axis_angle_deg: f64,
    /// Largest distance of a match from its epipolar line, pixels.
    pub epipolar_px: f64,
    /// Largest Hamming distance of a match (of 256 bits).
    pub max_hamming: u32,
    /// Ratio test: the best distance below this multiple of the second best.
    pub ratio: f64,
    /// Largest reprojection error of an observation kept, pixels.
    pub max_reprojection_px: f64,
    /// Fewest views a point keeps.
    pub min_track: u32,
    /// Smallest angle between a point's rays, degrees.
    pub min_angle_deg: f64,
    /// Neighbours of the isolation test (isolated points never set the bounds).
    pub outlier_neighbours: u32,
    /// Isolation: mean neighbour distance above this multiple of the median.
    pub outlier_ratio: f64,
    /// Drop isolated points (off: they are often a capture's sparse background, which the
    /// Gaussians need).
    pub drop_isolated: bool,
    /// Seed of BRIEF's test pairs.
    pub seed: u64,
    /// Fewer points than this is reported as a failed triangulation (terminal, log, record).
    pub min_points: u32,
}

impl Default for TriangulatePointsArgs {
    fn default() -> Self {
        let o = TriangulateOptions::default();
        TriangulatePointsArgs {
            when: TriangulateWhen::Missing,
            max_features: o.max_features as u32,
            neighbours: o.neighbours as u32,
            max_axis_angle_deg: o.max_axis_angle_deg,
            epipolar_px: o.matching.epipolar_px,
            max_hamming: o.matching.max_hamming,
            ratio: o.matching.ratio,
            max_reprojection_px: o.solve.max_reprojection_px,
            min_track: o.solve.min_track as u32,
            min_angle_deg: o.solve.min_angle_deg,
            outlier_neighbours: o.outlier_neighbours as u32,
            outlier_ratio: o.outlier_ratio,
            drop_isolated: o.drop_isolated,
            seed: o.seed,
            min_points: 1000,
        }
    }
}

impl TriangulatePointsArgs {
    /// The library's options.
    pub fn options(&self) -> TriangulateOptions {
        TriangulateOptions {
            max_features: self.max_features as usize,
            neighbours: self.neighbours as usize,
            max_axis_angle_deg: self.max_axis_angle_deg,
            matching: MatchRules {
                epipolar_px: self.epipolar_px,
                max_hamming: self.max_hamming,
                ratio: self.ratio,
            },
            solve: SolveRules {
                max_reprojection_px: self.max_reprojection_px,
                min_track: self.min_track as usize,
                min_angle_deg: self.min_angle_deg,
            },
            outlier_neighbours: self.outlier_neighbours as usize,
            outlier_ratio: self.outlier_ratio,
            drop_isolated: self.drop_isolated,
            seed: self.seed,
        }
    }
}

/// `TriangulatePoints`: sparse points from the photos and known poses of a scene without
/// them (COLMAP's `point_triangulator`), with near/far from the points; `triangulation.json`
/// beside them says what was found at each stage.
pub struct TriangulatePoints;

impl Node for TriangulatePoints {
    const KIND: &'static str = "TriangulatePoints";
    const VERSION: u32 = 1;
    type Args = TriangulatePointsArgs;

    fn inputs(_: &Self::Args) -> Vec<InputDecl> {
        vec![InputDecl::one("scene")]
    }
    fn outputs(_: &Self::Args) -> Vec<String> {
        vec!["scene".into()]
    }
    fn threads(_: &Self::Args) -> Threads {
        Threads::All
    }
    fn validate(a: &Self::Args) -> Result<(), String> {
        let positive = [
            ("max_axis_angle_deg", a.max_axis_angle_deg),
            ("epipolar_px", a.epipolar_px),
            ("max_reprojection_px", a.max_reprojection_px),
            ("outlier_ratio", a.outlier_ratio),
        ];
        for (name, v) in positive {
            if !(v > 0.0 && v.is_finite()) {
                return Err(format!("{name} = {v} must be positive"));
            }
        }
        if !(a.ratio > 0.0 && a.ratio <= 1.0) {
            return Err(format!("ratio = {} must be within (0, 1]", a.ratio));
        }
        if !(a.min_angle_deg >= 0.0 && a.min_angle_deg < 90.0) {
            return Err(format!(
                "min_angle_deg = {} must be within [0, 90)",
                a.min_angle_deg
            ));
        }
        if a.max_features < 16 || a.neighbours == 0 || a.min_track < 2 || a.max_hamming > 256 {
            return Err(format!(
                "max_features ≥ 16, neighbours ≥ 1, min_track ≥ 2 and max_hamming ≤ 256 are needed                  (got {}, {}, {}, {})",
                a.max_features, a.neighbours, a.min_track, a.max_hamming
            ));
        }
        Ok(())
    }
    fn run(a: &Self::Args, ctx: &mut RunContext) -> Result<(), NodeError> {
        let src = ctx.input("scene")?.to_path_buf();
        let out = ctx.output("scene")?.to_path_buf();
        let scene = Scene::load(&src)?;
        let pass = match a.when {
            TriangulateWhen::Never => Some("when: Never"),
            TriangulateWhen::Missing if scene.has_points => Some("the scene has points"),
            _ => None,
        };
        if let Some(why) = pass {
            crate::triangulate::copy_tree(&src, &out)?;
            ctx.log(format!("passed through unchanged ({why})"));
            return Ok(());
        }
        let started = std::time::Instant::now();
        let record = triangulate_scene(&src, &out, &a.options(), a.min_points as usize)?;
        ctx.log(format!(
            "{} in {:.2} s; near/far {:.4}–{:.4} (before {:.4}–{:.4})",
            record.report.summary(),
            started.elapsed().as_secs_f64(),
            record
                .bounds
                .as_ref()
                .map_or(record.bounds_before.0, |b| b.near),
            record
                .bounds
                .as_ref()
                .map_or(record.bounds_before.1, |b| b.far),
            record.bounds_before.0,
            record.bounds_before.1
        ));
        if let Some(w) = &record.warning {
            let msg = format!("warning: TriangulatePoints: {w}");
            // On the terminal as well as in the log: the run will start from poor points.
            eprintln!("{msg}");
            ctx.log(msg);
        }
        Ok(())
    }
}

/// Args of [`ExportScene`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExportSceneArgs {
    /// The format to write.
    pub format: ExportFormat,
}

/// `ExportScene`: a scene → COLMAP text or transforms.json (original frame).
pub struct ExportScene;

impl Node for ExportScene {
    const KIND: &'static str = "ExportScene";
    const VERSION: u32 = 3;
    type Args = ExportSceneArgs;

    fn inputs(_: &Self::Args) -> Vec<InputDecl> {
        vec![InputDecl::one("scene")]
    }
    fn outputs(_: &Self::Args) -> Vec<String> {
        vec!["export".into()]
    }
    fn run(a: &Self::Args, ctx: &mut RunContext) -> Result<(), NodeError> {
        let src = ctx.input("scene")?.to_path_buf();
        export_scene(&src, ctx.output("export")?, a.format)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::auto_downscale;

    #[test]
    fn auto_downscale_brings_the_longest_side_within_the_bound() {
        assert_eq!(auto_downscale(4032, 1, None), 1);
        assert_eq!(auto_downscale(4032, 2, None), 2);
        assert_eq!(auto_downscale(504, 1, Some(512)), 1);
        assert_eq!(auto_downscale(800, 1, Some(512)), 2);
        assert_eq!(auto_downscale(4032, 1, Some(512)), 8);
        assert_eq!(auto_downscale(4033, 1, Some(512)), 8);
        assert_eq!(auto_downscale(4097, 1, Some(512)), 9);
        assert_eq!(
            auto_downscale(800, 4, Some(512)),
            4,
            "never below `downscale`"
        );
        assert_eq!(auto_downscale(100_000, 1, Some(16)), 64, "capped");
    }
}
