//! Occupancy grid over contracted space (`[−2, 2]³`, cubic cells) for empty-space skipping:
//! an EMA of `σ · step` per cell, refreshed every few steps after a warm-up; a cell is occupied
//! when its EMA exceeds `min(mean EMA, threshold)` (nerfacc's rule).

use crate::constants::{CONTRACTED_RADIUS, OCCUPANCY_DECAY, OCCUPANCY_THRESHOLD};

/// The grid.
#[derive(Clone, Debug, PartialEq)]
pub struct OccupancyGrid {
    /// Cells per axis.
    pub res: u32,
    /// EMA of `σ · step` per cell (x fastest).
    pub ema: Vec<f32>,
    /// Occupancy flag per cell (1 = occupied).
    pub occupied: Vec<u8>,
}

impl OccupancyGrid {
    /// A grid with every cell occupied (before the first update).
    pub fn full(res: u32) -> OccupancyGrid {
        let n = (res as usize).pow(3);
        OccupancyGrid {
            res,
            ema: vec![0.0; n],
            occupied: vec![1; n],
        }
    }
    /// Number of cells.
    pub fn len(&self) -> usize {
        self.occupied.len()
    }
    /// Whether the grid has no cells.
    pub fn is_empty(&self) -> bool {
        self.occupied.is_empty()
    }
    /// The cell holding contracted point `c`.
    #[inline]
    pub fn cell(&self, c: [f32; 3]) -> usize {
        let r = self.res as f32;
        let mut idx = [0usize; 3];
        for a in 0..3 {
            let u = (c[a] + CONTRACTED_RADIUS) / (2.0 * CONTRACTED_RADIUS) * r;
            // `u.max(0.0) as usize` equals `u.floor().max(0.0) as usize` for every `u`
            // (truncation is floor on non-negative values; negatives and NaN give 0, large
            // values saturate) without a libm `floorf` call (no SSE4.1 `roundss` in the
            // baseline target).
            idx[a] = (u.max(0.0) as usize).min(self.res as usize - 1);
        }
        let res = self.res as usize;
        idx[0] + idx[1] * res + idx[2] * res * res
    }
    /// Whether contracted point `c` lies in an occupied cell.
    #[inline]
    pub fn is_occupied(&self, c: [f32; 3]) -> bool {
        self.occupied[self.cell(c)] != 0
    }
    /// Lower corner and edge of cell `i` in contracted space.
    pub fn cell_box(&self, i: usize) -> ([f32; 3], f32) {
        let res = self.res as usize;
        let edge = 2.0 * CONTRACTED_RADIUS / self.res as f32;
        let ijk = [i % res, (i / res) % res, i / (res * res)];
        (ijk.map(|v| v as f32 * edge - CONTRACTED_RADIUS), edge)
    }
    /// Folds new per-cell values into the EMA (`ema = max(ema·decay, value)`) and recomputes
    /// the flags. Non-finite values count as occupied-by-zero (ignored).
    pub fn update(&mut self, values: &[f32]) {
        let mut sum = 0f64;
        for (e, &v) in self.ema.iter_mut().zip(values) {
            let v = if v.is_finite() { v.max(0.0) } else { 0.0 };
            *e = (*e * OCCUPANCY_DECAY).max(v);
            sum += *e as f64;
        }
        let mean = (sum / self.ema.len().max(1) as f64) as f32;
        let thr = mean.min(OCCUPANCY_THRESHOLD);
        for (o, &e) in self.occupied.iter_mut().zip(&self.ema) {
            *o = (e > thr) as u8;
        }
    }
    /// Fraction of occupied cells.
    pub fn occupied_fraction(&self) -> f64 {
        self.occupied.iter().map(|&o| o as u64).sum::<u64>() as f64 / self.len().max(1) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`OccupancyGrid::cell`] (truncating cast) gives the cell of the former
    /// `floor().max(0.0)` formula for ordinary, boundary and non-finite coordinates.
    #[test]
    fn cell_matches_floor_formula() {
        let grid = OccupancyGrid::full(64);
        let r = grid.res as f32;
        let old = |c: [f32; 3]| {
            let mut idx = [0usize; 3];
            for a in 0..3 {
                let u = (c[a] + CONTRACTED_RADIUS) / (2.0 * CONTRACTED_RADIUS) * r;
                idx[a] = (u.floor().max(0.0) as usize).min(grid.res as usize - 1);
            }
            let res = grid.res as usize;
            idx[0] + idx[1] * res + idx[2] * res * res
        };
        let mut vals: Vec<f32> = vec![
            0.0,
            -0.0,
            CONTRACTED_RADIUS,
            -CONTRACTED_RADIUS,
            -CONTRACTED_RADIUS - 1e-7,
            -CONTRACTED_RADIUS - 0.01,
            CONTRACTED_RADIUS + 0.5,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            f32::MIN,
            1e-30,
            -1e-30,
        ];
        let mut rng = augsplat_core::Rng::new(3);
        for _ in 0..3000 {
            vals.push(rng.uniform(-2.5, 2.5) as f32);
        }
        for (k, &v) in vals.iter().enumerate() {
            let w = vals[(k * 7 + 3) % vals.len()];
            let c = [v, w, -v];
            assert_eq!(grid.cell(c), old(c), "{c:?}");
        }
    }
}
