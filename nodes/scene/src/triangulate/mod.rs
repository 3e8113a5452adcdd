//! Sparse points from photos with known poses — what COLMAP's `point_triangulator` does for a
//! model without points — so a capture without SfM points starts from its surfaces.
//!
//! 1. [`features`]: FAST-9 corners with BRIEF descriptors (`imageproc`) per view.
//! 2. [`matching`]: each view is matched with its nearest views that look the same way;
//!    candidates are restricted to the epipolar band the known poses give, then the ratio
//!    test and a mutual check.
//! 3. [`tracks`]: matches joined into multi-view tracks; contradictory tracks dropped.
//! 4. [`solve`]: each track triangulated (ray midpoint, Gauss–Newton on the reprojection
//!    error), observations beyond the reprojection bound or behind a camera dropped, and the
//!    point kept when enough views remain and the rays meet at a large enough angle.
//!
//! 5. [`outliers`]: points far from every other point (wrong two-view matches, or a sparse
//!    background) found; they are kept (dropped only on request) but never set the bounds.
//!
//! Colours are the mean of the photos at the kept observations. Every stage runs in parallel
//! over views, pairs or tracks and collects in order, so the cloud is the same bytes for any
//! thread count.

pub mod features;
pub mod matching;
pub mod outliers;
pub mod solve;
pub mod tracks;

use crate::error::{Result, SceneError};
use augsplat_core::linalg;
use augsplat_core::scene::POINTS_FILE;
use augsplat_core::{Camera, ImageF32, PointCloud, Scene};
use matching::{match_pair, select_pairs, MatchRules};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use solve::{solve_track, Rejection, SolveRules};
use std::path::Path;

/// Settings of [`triangulate`].
#[derive(Clone, Debug, PartialEq)]
pub struct TriangulateOptions {
    /// Keypoints per view at most.
    pub max_features: usize,
    /// Views each view is matched with.
    pub neighbours: usize,
    /// Largest angle between two views' optical axes for them to be matched, degrees.
    pub max_axis_angle_deg: f64,
    /// Matching thresholds.
    pub matching: MatchRules,
    /// Point checks.
    pub solve: SolveRules,
    /// Neighbours of the isolation test. Isolated points never set the bounds; they are
    /// dropped from the cloud only with `drop_isolated`.
    pub outlier_neighbours: usize,
    /// A point is isolated when its mean neighbour distance exceeds this multiple of the
    /// cloud's median.
    pub outlier_ratio: f64,
    /// Drop isolated points (off by default: they are often a capture's sparse background,
    /// whose points the Gaussians need).
    pub drop_isolated: bool,
    /// Seed of BRIEF's test pairs.
    pub seed: u64,
}

impl Default for TriangulateOptions {
    fn default() -> Self {
        TriangulateOptions {
            max_features: 16000,
            neighbours: 6,
            max_axis_angle_deg: 60.0,
            matching: MatchRules {
                epipolar_px: 2.0,
                max_hamming: 64,
                ratio: 0.85,
            },
            solve: SolveRules {
                max_reprojection_px: 2.0,
                min_track: 2,
                min_angle_deg: 1.5,
            },
            outlier_neighbours: 6,
            outlier_ratio: 3.0,
            drop_isolated: false,
            seed: 0,
        }
    }
}

/// What the triangulation found, stage by stage (written beside the points as
/// `triangulation.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TriangulationReport {
    /// Views used.
    pub views: usize,
    /// Keypoints over all views.
    pub keypoints: usize,
    /// Fewest keypoints of one view.
    pub keypoints_min: usize,
    /// Views whose corners needed a FAST threshold below the first (low contrast).
    pub low_contrast_views: usize,
    /// View pairs matched.
    pub pairs: usize,
    /// Mutual matches over all pairs.
    pub matches: usize,
    /// Tracks of two or more observations.
    pub tracks: usize,
    /// Matches refused for joining two keypoints of one view into one track.
    pub conflicting_matches: usize,
    /// Tracks left with fewer views than required (after the reprojection and depth checks).
    pub rejected_few_views: usize,
    /// Tracks whose rays meet at too small an angle.
    pub rejected_small_angle: usize,
    /// Points found isolated (dropped only with `drop_isolated`; never used for the bounds).
    pub isolated: usize,
    /// Isolated points dropped.
    pub rejected_isolated: usize,
    /// Points kept.
    pub points: usize,
    /// Mean number of views per point.
    pub mean_track: f64,
    /// Mean reprojection error of the points, pixels.
    pub mean_error_px: f64,
}

impl TriangulationReport {
    /// One line of what was tried and found.
    pub fn summary(&self) -> String {
        format!(
            "{} points from {} views: {} keypoints (fewest in a view {}, {} low-contrast views), \
             {} view pairs, {} matches ({} refused as conflicting), {} tracks; rejected {} with too few \
             views, {} with too small an angle; {} isolated ({} dropped); {:.2} views per point, mean reprojection error \
             {:.3} px",
            self.points,
            self.views,
            self.keypoints,
            self.keypoints_min,
            self.low_contrast_views,
            self.pairs,
            self.matches,
            self.conflicting_matches,
            self.tracks,
            self.rejected_few_views,
            self.rejected_small_angle,
            self.isolated,
            self.rejected_isolated,
            self.mean_track,
            self.mean_error_px
        )
    }
}

/// The result of [`triangulate`].
#[derive(Clone, Debug, PartialEq)]
pub struct Triangulated {
    /// The points with their colours, mean reprojection errors and tracks.
    pub cloud: PointCloud,
    /// The stages' counts.
    pub report: TriangulationReport,
    /// Per point of the cloud: whether it is isolated (kept, but not used for the bounds).
    pub isolated: Vec<bool>,
}

/// Checks the inputs: at least two views, images the size their cameras say, cameras not all
/// at one point.
fn check_inputs(cams: &[Camera], images: &[ImageF32], names: &[String]) -> Result<()> {
    if cams.len() < 2 {
        return Err(SceneError::Invalid(format!(
            "triangulation needs at least two views; the scene has {}",
            cams.len()
        )));
    }
    for ((cam, img), name) in cams.iter().zip(images).zip(names) {
        if (img.width, img.height) != (cam.width, cam.height) {
            return Err(SceneError::Invalid(format!(
                "view {name}: the image is {}×{} but its camera says {}×{}",
                img.width, img.height, cam.width, cam.height
            )));
        }
    }
    let centres: Vec<_> = cams.iter().map(Camera::center).collect();
    let spread = centres
        .iter()
        .map(|c| linalg::norm(linalg::sub(*c, centres[0])))
        .fold(0.0, f64::max);
    let depth = cams
        .iter()
        .map(|c| linalg::norm(c.center()))
        .fold(0.0, f64::max)
        .max(1.0);
    if spread.is_nan() || spread <= 1e-9 * depth {
        return Err(SceneError::Invalid(format!(
            "all {} cameras are at one point ({:.4}, {:.4}, {:.4}): with no baseline between \
             the views nothing can be triangulated (a panorama or wrong poses?)",
            cams.len(),
            centres[0][0],
            centres[0][1],
            centres[0][2]
        )));
    }
    Ok(())
}

/// Triangulates sparse points from `images` taken by `cams` (`names` name the views in
/// errors). Errors: fewer than two views, an image whose size differs from its camera's, all
/// cameras at one point. A capture where nothing matches gives an empty cloud and a report
/// that says why.
pub fn triangulate(
    cams: &[Camera],
    images: &[ImageF32],
    names: &[String],
    opts: &TriangulateOptions,
) -> Result<Triangulated> {
    check_inputs(cams, images, names)?;
    let pairs_tests = features::test_pairs(opts.seed);
    let min_features = (opts.max_features / 4).max(1);
    let keypoints: Vec<features::Keypoints> = images
        .par_iter()
        .map(|img| features::detect(img, opts.max_features, min_features, &pairs_tests))
        .collect();
    let view_pairs = select_pairs(cams, opts.neighbours, opts.max_axis_angle_deg);
    let matches: Vec<((usize, usize), Vec<matching::Match>)> = view_pairs
        .par_iter()
        .map(|&(a, b)| {
            let m = match_pair(
                &cams[a],
                &cams[b],
                &keypoints[a],
                &keypoints[b],
                &opts.matching,
            );
            ((a, b), m)
        })
        .collect();
    let counts: Vec<usize> = keypoints.iter().map(features::Keypoints::len).collect();
    let joined = tracks::join(&counts, &matches);
    let solved: Vec<std::result::Result<(solve::Solved, Vec<u32>), Rejection>> = joined
        .tracks
        .par_iter()
        .map(|t| {
            let cs: Vec<&Camera> = t.iter().map(|&(v, _)| &cams[v as usize]).collect();
            let obs: Vec<(f64, f64)> = t
                .iter()
                .map(|&(v, k)| {
                    let kp = &keypoints[v as usize];
                    (kp.u[k as usize], kp.v[k as usize])
                })
                .collect();
            solve_track(&cs, &obs, &opts.solve).map(|s| {
                let views = s.kept.iter().map(|&i| t[i].0).collect();
                (s, views)
            })
        })
        .collect();
    let mut report = TriangulationReport {
        views: cams.len(),
        keypoints: counts.iter().sum(),
        keypoints_min: counts.iter().copied().min().unwrap_or(0),
        low_contrast_views: keypoints
            .iter()
            .filter(|k| k.threshold < features::FAST_THRESHOLDS[0])
            .count(),
        pairs: view_pairs.len(),
        matches: matches.iter().map(|(_, m)| m.len()).sum(),
        tracks: joined.tracks.len(),
        conflicting_matches: joined.conflicting_matches,
        ..TriangulationReport::default()
    };
    let positions: Vec<linalg::Vec3> = solved
        .iter()
        .filter_map(|r| r.as_ref().ok().map(|(s, _)| s.position))
        .collect();
    let flags = outliers::isolated(&positions, opts.outlier_neighbours, opts.outlier_ratio);
    report.isolated = flags.iter().filter(|&&f| f).count();
    let mut flags = flags.into_iter();
    let mut isolated = Vec::new();
    let mut cloud = PointCloud::default();
    cloud.track_offsets.push(0);
    let (mut sum_track, mut sum_err) = (0usize, 0f64);
    for (r, t) in solved.iter().zip(&joined.tracks) {
        match r {
            Err(Rejection::TooFewViews) => report.rejected_few_views += 1,
            Err(Rejection::SmallAngle) => report.rejected_small_angle += 1,
            Ok((s, views)) => {
                let iso = flags.next() == Some(true);
                if iso && opts.drop_isolated {
                    report.rejected_isolated += 1;
                    continue;
                }
                isolated.push(iso);
                let mut rgb = [0f64; 3];
                for &i in &s.kept {
                    let (v, k) = t[i];
                    let img = &images[v as usize];
                    let kp = &keypoints[v as usize];
                    let (x, y) = (kp.u[k as usize] as u32, kp.v[k as usize] as u32);
                    for (c, sum) in rgb.iter_mut().enumerate() {
                        *sum += img.get(x, y, c.min(img.channels as usize - 1) as u32) as f64;
                    }
                }
                let n = s.kept.len() as f64;
                cloud.positions.push(s.position.map(|x| x as f32));
                cloud.colors.push(rgb.map(|c| (c / n) as f32));
                cloud.errors.push(s.mean_error as f32);
                cloud.track_views.extend_from_slice(views);
                cloud.track_offsets.push(cloud.track_views.len() as u32);
                sum_track += views.len();
                sum_err += s.mean_error;
            }
        }
    }
    report.points = cloud.len();
    if report.points > 0 {
        report.mean_track = sum_track as f64 / report.points as f64;
        report.mean_error_px = sum_err / report.points as f64;
    }
    Ok(Triangulated {
        cloud,
        report,
        isolated,
    })
}

#[cfg(test)]
mod tests;

/// The record written beside the triangulated points.
pub const RECORD_FILE: &str = "triangulation.json";

/// What [`triangulate_scene`] did, as written to [`RECORD_FILE`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TriangulationRecord {
    /// The stages' counts.
    pub report: TriangulationReport,
    /// The scene's near/far before (from the import: the cameras' axes, LLFF bounds or the
    /// defaults).
    pub bounds_before: (f64, f64),
    /// Near/far from the triangulated points (per view and for the scene), when any.
    pub bounds: Option<crate::bounds::PointBounds>,
    /// Set when the cloud is too small to start from (fewer than the node's `min_points`).
    pub warning: Option<String>,
}

/// Copies a scene folder (the engine's [`augsplat_graph::command::copy_tree`]).
pub fn copy_tree(from: &Path, to: &Path) -> Result<()> {
    augsplat_graph::command::copy_tree(from, to).map_err(|e| SceneError::io(from, e))
}

/// Triangulates the scene folder `src` into `out`: the folder copied, its points replaced by
/// the triangulated ones, its near/far taken from them, and [`RECORD_FILE`] beside. A cloud of
/// fewer than `min_points` points is kept but carries a warning (also in the record); with no
/// points at all the scene stays without points and keeps its bounds.
pub fn triangulate_scene(
    src: &Path,
    out: &Path,
    opts: &TriangulateOptions,
    min_points: usize,
) -> Result<TriangulationRecord> {
    let mut scene = Scene::load(src)?;
    let cams: Vec<Camera> = scene.views.iter().map(|v| v.camera.clone()).collect();
    let names: Vec<String> = scene.views.iter().map(|v| v.name.clone()).collect();
    let images: Vec<ImageF32> = (0..scene.views.len())
        .into_par_iter()
        .map(|i| scene.load_image(src, i).map_err(SceneError::from))
        .collect::<Result<_>>()?;
    let Triangulated {
        cloud,
        report,
        isolated,
    } = triangulate(&cams, &images, &names, opts)?;
    copy_tree(src, out)?;
    // The copies of the files rewritten below may be read-only (store blobs): removed first.
    let points_file = out.join(POINTS_FILE);
    for f in [
        points_file.clone(),
        out.join(augsplat_core::scene::SCENE_FILE),
    ] {
        if f.exists() {
            std::fs::remove_file(&f).map_err(|e| SceneError::io(&f, e))?;
        }
    }
    let bounds_before = (scene.near, scene.far);
    // Bounds from the points that are not isolated: a few wrong two-view points far behind
    // the scene would otherwise set the far bound.
    let mut dense = PointCloud {
        track_offsets: vec![0],
        ..PointCloud::default()
    };
    for i in (0..cloud.len()).filter(|&i| !isolated[i]) {
        dense.positions.push(cloud.positions[i]);
        dense.track_views.extend_from_slice(cloud.track(i));
        dense.track_offsets.push(dense.track_views.len() as u32);
    }
    let bounds = crate::bounds::from_points(&cams, &dense);
    if let Some(b) = &bounds {
        scene.near = b.near;
        scene.far = b.far;
    }
    scene.has_points = !cloud.is_empty();
    if scene.has_points {
        cloud.save(&points_file)?;
    }
    scene.save(out)?;
    let warning = (report.points < min_points).then(|| {
        format!(
            "triangulation found only {} points (fewer than {min_points}): {}. The Gaussians \
             will start mostly from random positions between the bounds; check that the views \
             overlap and the poses are right, or import a model with SfM points",
            report.points,
            report.summary()
        )
    });
    let record = TriangulationRecord {
        report,
        bounds_before,
        bounds,
        warning,
    };
    augsplat_core::artifacts::write_json(&out.join(RECORD_FILE), &record)?;
    Ok(record)
}
