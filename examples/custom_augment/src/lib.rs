//! An example custom augmentation node in its own crate: `EnsembleMean` turns the radiance-field
//! ensemble's renders into a synthetic set (the public contract of `augsplat_core::artifacts`,
//! synthetic-set format version 1) that `OptimizeSplats` reads in place of
//! `AggregateEnsemble`'s.
//!
//! Its prior is deliberately simpler than AugSplat's: the target is the per-pixel **mean** of
//! the members' colours (not the median), and the confidence is **variance-free** — the
//! members' mean opacity (channel A of their renders) raised to `power`, so pixels the fields
//! leave empty get no weight, however much the members agree there.
//!
//! `pipelines/custom_augment_rust.ron` trains Dual AugSplat on it beside the demo's methods:
//!
//! ```text
//! cargo run --release -p augsplat-custom-augment -- run pipelines/custom_augment_rust.ron
//! ```

use augsplat_augment::ensemble::read_members;
use augsplat_core::artifacts::{self, files, SyntheticSet, SyntheticView};
use augsplat_core::{image, Camera};
use augsplat_graph::{InputDecl, Node, NodeError, Registry, RunContext, Threads};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Args of [`EnsembleMean`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EnsembleMeanArgs {
    /// The confidence is the members' mean opacity to this power (≥ 0; 0 = weight 1
    /// everywhere).
    pub power: f32,
}

impl Default for EnsembleMeanArgs {
    fn default() -> Self {
        EnsembleMeanArgs { power: 1.0 }
    }
}

/// The mean colour and the mean opacity of one view over the members, planar (`R…, G…, B…`)
/// and `H·W`; the members' planes are summed in member order, so the result does not depend on
/// the thread count.
pub fn mean_view(members: &[(Vec<f32>, Vec<f32>)], power: f32) -> (Vec<f32>, Vec<f32>) {
    let k = members.len().max(1) as f32;
    let n = members.first().map_or(0, |m| m.1.len());
    let mut rgb = vec![0.0f32; 3 * n];
    let mut alpha = vec![0.0f32; n];
    for (c, a) in members {
        for (s, v) in rgb.iter_mut().zip(c) {
            *s += v;
        }
        for (s, v) in alpha.iter_mut().zip(a) {
            *s += v;
        }
    }
    rgb.iter_mut().for_each(|v| *v /= k);
    let weight = alpha
        .iter()
        .map(|a| (a / k).clamp(0.0, 1.0).powf(power))
        .collect();
    (rgb, weight)
}

/// Reads a member's render of one view: planar RGB and the opacity channel A.
fn read_render(path: &Path, cam: &Camera) -> Result<(Vec<f32>, Vec<f32>), NodeError> {
    let exr = image::read_exr(path)?;
    if (exr.width, exr.height) != (cam.width, cam.height) {
        return Err(NodeError::new(format!(
            "{}: image is {}×{}, its camera says {}×{}",
            path.display(),
            exr.width,
            exr.height,
            cam.width,
            cam.height
        )));
    }
    let plane = |ch: &str| {
        exr.channel(ch).map(<[f32]>::to_vec).ok_or_else(|| {
            NodeError::new(format!(
                "{}: no channel {ch} (has {:?})",
                path.display(),
                exr.names()
            ))
        })
    };
    let mut rgb = plane("R")?;
    rgb.extend(plane("G")?);
    rgb.extend(plane("B")?);
    Ok((rgb, plane("A")?))
}

/// `EnsembleMean`: `members` (the ensemble's render sets) → `synthetic` (a synthetic set).
pub struct EnsembleMean;

impl Node for EnsembleMean {
    const KIND: &'static str = "EnsembleMean";
    const VERSION: u32 = 1;
    type Args = EnsembleMeanArgs;
    fn inputs(_: &EnsembleMeanArgs) -> Vec<InputDecl> {
        vec![InputDecl::many("members")]
    }
    fn outputs(_: &EnsembleMeanArgs) -> Vec<String> {
        vec!["synthetic".into()]
    }
    fn threads(_: &EnsembleMeanArgs) -> Threads {
        Threads::All
    }
    fn validate(args: &EnsembleMeanArgs) -> Result<(), String> {
        if !(args.power.is_finite() && args.power >= 0.0) {
            return Err(format!("power = {} must be finite and ≥ 0", args.power));
        }
        Ok(())
    }
    fn run(args: &EnsembleMeanArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let dirs: Vec<PathBuf> = ctx.input_list("members")?.to_vec();
        let out = ctx.output("synthetic")?.to_path_buf();
        let sets = read_members(&dirs)?;
        SyntheticSet::create_folders(&out)?;
        let views = sets[0]
            .views
            .par_iter()
            .enumerate()
            .map(|(vi, view)| {
                let members = sets
                    .iter()
                    .zip(&dirs)
                    .map(|(s, d)| read_render(&d.join(&s.views[vi].file), &view.camera))
                    .collect::<Result<Vec<_>, _>>()?;
                let (target, weight) = mean_view(&members, args.power);
                Ok(SyntheticView::write(
                    &out,
                    &view.name,
                    &view.camera,
                    &target,
                    &weight,
                )?)
            })
            .collect::<Result<Vec<_>, NodeError>>()?;
        ctx.log(format!(
            "ensemble mean of {} members over {} views (confidence: mean opacity^{})",
            dirs.len(),
            views.len(),
            args.power
        ));
        artifacts::write_json(&out.join(files::SYNTHETIC), &SyntheticSet { views })?;
        Ok(())
    }
}

/// Registers [`EnsembleMean`].
pub fn register(registry: &mut Registry) {
    registry.register::<EnsembleMean>();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_of_two_members_and_opacity_confidence() {
        let a = (vec![0.2, 0.4, 0.0, 1.0, 0.5, 0.5], vec![1.0, 0.0]);
        let b = (vec![0.4, 0.0, 1.0, 0.0, 0.5, 0.1], vec![0.5, 0.0]);
        let (rgb, w) = mean_view(&[a.clone(), b.clone()], 1.0);
        let want = [0.3, 0.2, 0.5, 0.5, 0.5, 0.3];
        for (x, y) in rgb.iter().zip(want) {
            assert!((x - y).abs() < 1e-6, "{rgb:?}");
        }
        assert_eq!(w, vec![0.75, 0.0]);
        let (_, w2) = mean_view(&[a, b], 2.0);
        assert_eq!(w2, vec![0.5625, 0.0]);
    }
}
