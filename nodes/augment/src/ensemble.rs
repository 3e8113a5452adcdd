//! Aggregating an ensemble's renders into synthetic supervision: the library side of the
//! `AggregateEnsemble` node. [`aggregate_ensemble`] reads the members' render sets, checks that
//! they are one ensemble ([`RenderSet::check_compatible`]), aggregates every view with
//! [`aggregate_view`] (in parallel, one [`Workspace`] per thread) and writes each view with
//! [`SyntheticView::write`], the owner of the synthetic view's files.

use crate::aggregate::{aggregate_view, AggregateParams, Workspace};
use augsplat_core::artifacts::{self, files, RenderSet, SyntheticSet, SyntheticView};
use augsplat_core::{image, Camera};
use augsplat_graph::NodeError;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

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

/// Reads the render set (`renders.json`) of each member folder and checks that they render
/// the same views at the same sizes.
pub fn read_members(dirs: &[PathBuf]) -> Result<Vec<RenderSet>, NodeError> {
    if dirs.is_empty() {
        return Err(NodeError::new("input `members` lists no render sets"));
    }
    let sets: Vec<RenderSet> = dirs
        .iter()
        .map(|d| artifacts::read_json::<RenderSet>(&d.join(files::RENDERS)))
        .collect::<Result<_, _>>()?;
    let paths: Vec<&Path> = dirs.iter().map(PathBuf::as_path).collect();
    RenderSet::check_compatible(&sets, &paths).map_err(NodeError::new)?;
    Ok(sets)
}

/// Aggregates the ensemble whose members' render folders are `dirs` into the synthetic set's
/// folder `out`: every view's target and weight files (see [`SyntheticView::write`]), in
/// parallel; `progress(done, total)` after each view. Returns the set's index and the
/// per-view statistics, in view order; writing them (`synthetic.json`,
/// `aggregate_report.json`) is left to the caller.
pub fn aggregate_ensemble(
    dirs: &[PathBuf],
    args: &AggregateParams,
    out: &Path,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<(SyntheticSet, AggregateReport), NodeError> {
    let sets = read_members(dirs)?;
    let first = &sets[0];
    SyntheticSet::create_folders(out)?;
    let total = first.views.len() as u64;
    let done = AtomicU64::new(0);
    let results: Vec<(SyntheticView, AggregateViewStats)> = first
        .views
        .par_iter()
        .enumerate()
        .map_init(Workspace::default, |ws, (vi, view)| {
            let cam = &view.camera;
            let members: Vec<Vec<f32>> = sets
                .iter()
                .zip(dirs)
                .map(|(s, d)| read_planar_rgb(&d.join(&s.views[vi].file), cam))
                .collect::<Result<_, _>>()?;
            let refs: Vec<&[f32]> = members.iter().map(|v| v.as_slice()).collect();
            let (w, h) = (cam.width as usize, cam.height as usize);
            let agg = aggregate_view(&refs, w, h, args, ws);
            let n = w * h;
            let sv = SyntheticView::write(out, &view.name, cam, &agg.target, &agg.weight)?;
            let weight_sum = sv.weight_sum;
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(d, total);
            Ok((
                sv,
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
    let report = AggregateReport {
        members: sets.len(),
        params: args.clone(),
        views: stats,
    };
    Ok((SyntheticSet { views }, report))
}
