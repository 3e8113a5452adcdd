//! The sparse-view split (the paper's protocol): sample K views with a seed, then hold out
//! every n-th of them (in name order) as the test set.
//!
//! - K views are drawn by a Fisher–Yates shuffle of the view indices with [`Rng::new(seed)`]
//!   and kept in name order; `count: None`, or K ≥ the number of views, keeps every view.
//! - Among the kept views, position i (0-based, name order) is a test view when
//!   `i % holdout_every == 0` (mip-NeRF 360 / gsplat convention: 30 → 26 train + 4 test).
//! - The train scene keeps a point only when at least 2 train views observe it, and its track
//!   is remapped to train-view indices; the test scene carries no points (nothing a test view
//!   sees can reach the initialisation).
//!
//! [`Rng::new(seed)`]: augsplat_core::Rng::new

use crate::error::{Result, SceneError};
use augsplat_core::{PointCloud, Rng, Scene};

/// Which views of a scene go to train and test (indices into the scene's views, ascending).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Split {
    /// Train view indices.
    pub train: Vec<usize>,
    /// Test view indices.
    pub test: Vec<usize>,
}

/// Chooses the split of `n` views.
pub fn split_indices(n: usize, count: Option<u32>, holdout_every: u32, seed: u64) -> Result<Split> {
    if holdout_every < 2 {
        return Err(SceneError::Invalid(format!(
            "holdout_every must be at least 2 (found {holdout_every})"
        )));
    }
    let mut chosen: Vec<usize> = (0..n).collect();
    if let Some(k) = count {
        if k == 0 {
            return Err(SceneError::Invalid(
                "count must be at least 1 (or None for all views)".into(),
            ));
        }
        if (k as usize) < n {
            let mut rng = Rng::new(seed);
            rng.shuffle(&mut chosen);
            chosen.truncate(k as usize);
            chosen.sort_unstable();
        }
    }
    let (mut train, mut test) = (Vec::new(), Vec::new());
    for (i, &v) in chosen.iter().enumerate() {
        if i % holdout_every as usize == 0 {
            test.push(v);
        } else {
            train.push(v);
        }
    }
    if train.is_empty() {
        return Err(SceneError::Invalid(format!(
            "the split leaves no training view ({} views chosen, every {holdout_every}th held out)",
            chosen.len()
        )));
    }
    Ok(Split { train, test })
}

/// The sub-scene of `views` (indices into `scene.views`), with the points that at least
/// `min_views` of those views observe, tracks remapped. `min_views == 0` drops all points.
pub fn subset(
    scene: &Scene,
    cloud: &PointCloud,
    views: &[usize],
    min_views: usize,
) -> (Scene, PointCloud) {
    let mut remap = vec![u32::MAX; scene.views.len()];
    for (new, &old) in views.iter().enumerate() {
        remap[old] = new as u32;
    }
    let mut out = PointCloud::default();
    if min_views > 0 {
        out.track_offsets.push(0);
        let mut track = Vec::new();
        for i in 0..cloud.len() {
            track.clear();
            track.extend(
                cloud
                    .track(i)
                    .iter()
                    .filter_map(|&t| remap.get(t as usize).copied().filter(|&r| r != u32::MAX)),
            );
            if track.len() >= min_views {
                out.positions.push(cloud.positions[i]);
                out.colors.push(cloud.colors[i]);
                out.errors.push(cloud.errors[i]);
                out.track_views.extend_from_slice(&track);
                out.track_offsets.push(out.track_views.len() as u32);
            }
        }
    }
    let sub = Scene {
        source: scene.source.clone(),
        views: views.iter().map(|&i| scene.views[i].clone()).collect(),
        near: scene.near,
        far: scene.far,
        normalization: scene.normalization.clone(),
        has_points: !out.is_empty(),
    };
    (sub, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_protocol_sizes_and_reproducibility() {
        let s = split_indices(117, Some(30), 8, 42).unwrap();
        assert_eq!((s.train.len(), s.test.len()), (26, 4));
        assert_eq!(s, split_indices(117, Some(30), 8, 42).unwrap());
        assert_ne!(s, split_indices(117, Some(30), 8, 43).unwrap());
        for t in &s.test {
            assert!(!s.train.contains(t));
        }
        let all = split_indices(25, Some(30), 8, 42).unwrap();
        assert_eq!((all.train.len(), all.test.len()), (21, 4));
        assert_eq!(all.test, vec![0, 8, 16, 24]);
        assert!(split_indices(10, Some(0), 8, 1).is_err());
        assert!(split_indices(10, None, 1, 1).is_err());
        assert!(split_indices(1, None, 8, 1).is_err());
    }
}
