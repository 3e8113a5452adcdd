//! Isolated points: a wrong match seen by two views triangulates to a consistent but wrong
//! place (a silhouette T-junction, a repeated texture along the epipolar line) that no
//! reprojection check can catch, and lands away from the surfaces the other points sample.
//! A point whose mean distance to its `k` nearest neighbours exceeds `ratio ×` the median of
//! that distance over the cloud is dropped (statistical outlier removal, as in PCL and Open3D,
//! with a median instead of mean + σ so the outliers do not set their own bar).

use augsplat_core::linalg::Vec3;
use rayon::prelude::*;
use std::collections::HashMap;

/// Rings of cells searched around a point. A cell is about the cloud's typical spacing, so a
/// point without `k` neighbours within this many cells is isolated at any sensible ratio; the
/// bound keeps far background points from searching the whole space.
const SEARCH_RINGS: i64 = 8;

/// A uniform grid over points for neighbour queries.
pub struct Grid<'a> {
    points: &'a [Vec3],
    cell: f64,
    cells: HashMap<[i64; 3], Vec<u32>>,
}

impl<'a> Grid<'a> {
    /// The grid of `points` with cubic cells of side `cell`.
    pub fn new(points: &'a [Vec3], cell: f64) -> Self {
        let mut cells: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for (i, p) in points.iter().enumerate() {
            cells.entry(Self::key(p, cell)).or_default().push(i as u32);
        }
        Grid {
            points,
            cell,
            cells,
        }
    }

    fn key(p: &Vec3, cell: f64) -> [i64; 3] {
        p.map(|x| (x / cell).floor() as i64)
    }

    /// Distances from `p` to its `k` nearest points (ascending; point `skip` left out), fewer
    /// when fewer lie within eight cells.
    pub fn nearest(&self, p: Vec3, k: usize, skip: Option<usize>) -> Vec<f64> {
        let c = Self::key(&p, self.cell);
        let mut best: Vec<f64> = Vec::with_capacity(k + 1);
        for r in 0..=SEARCH_RINGS {
            if best.len() == k && (r - 1) as f64 * self.cell > best[k - 1] {
                break;
            }
            for dx in -r..=r {
                for dy in -r..=r {
                    for dz in -r..=r {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != r {
                            continue;
                        }
                        let Some(list) = self.cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) else {
                            continue;
                        };
                        for &j in list {
                            if Some(j as usize) == skip {
                                continue;
                            }
                            let q = self.points[j as usize];
                            let d = ((p[0] - q[0]).powi(2)
                                + (p[1] - q[1]).powi(2)
                                + (p[2] - q[2]).powi(2))
                            .sqrt();
                            let at = best.partition_point(|&b| b <= d);
                            if at < k {
                                best.insert(at, d);
                                best.truncate(k);
                            }
                        }
                    }
                }
            }
        }
        best
    }

    /// Mean distance from point `i` to its `k` nearest other points; infinite when fewer than
    /// `k` lie within [`SEARCH_RINGS`] cells.
    fn mean_knn(&self, i: usize, k: usize) -> f64 {
        let best = self.nearest(self.points[i], k, Some(i));
        if best.len() < k {
            return f64::INFINITY;
        }
        best.iter().sum::<f64>() / best.len() as f64
    }
}

/// Which points are isolated (see the module docs). Clouds of at most `k` points keep all.
pub fn isolated(points: &[Vec3], k: usize, ratio: f64) -> Vec<bool> {
    if points.len() <= k || k == 0 {
        return vec![false; points.len()];
    }
    // Cell size: the bounding box of the central 90 % of the points, divided so that a
    // typical cell holds a few points.
    let mut diag2 = 0.0;
    for a in 0..3 {
        let mut v: Vec<f64> = points.iter().map(|p| p[a]).collect();
        v.sort_by(f64::total_cmp);
        let q = |f: f64| v[((v.len() - 1) as f64 * f) as usize];
        diag2 += (q(0.95) - q(0.05)).powi(2);
    }
    let cell = (diag2.sqrt() / (points.len() as f64).cbrt()).max(1e-12);
    let grid = Grid::new(points, cell);
    let dist: Vec<f64> = (0..points.len())
        .into_par_iter()
        .map(|i| grid.mean_knn(i, k))
        .collect();
    let mut sorted = dist.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    dist.iter()
        .map(|&d| d.is_nan() || d > ratio * median)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stray_point_off_a_sampled_plane_is_isolated() {
        let mut pts: Vec<Vec3> = (0..400)
            .map(|i| [(i % 20) as f64 * 0.05, (i / 20) as f64 * 0.05, 1.0])
            .collect();
        pts.push([0.5, 0.5, 1.6]);
        pts.push([0.52, 0.5, 1.0]);
        let out = isolated(&pts, 6, 3.0);
        assert!(out[400], "the stray point");
        assert!(!out[401], "a point on the plane between samples");
        assert_eq!(out.iter().filter(|&&o| o).count(), 1);
        assert_eq!(isolated(&pts[..5], 6, 3.0), vec![false; 5]);
    }
}
