//! Tests of the backward tile kernels: every instruction-set tier against the portable twin.

use super::tile::{tree_sum16, BwdTile};
use super::*;
use crate::forward::tests::random_tile_splats;
use augsplat_core::simd::for_each_isa;

fn tile_state(seed: u64, n: u32) -> BwdTile {
    let mut rng = augsplat_core::Rng::new(seed);
    let mut tile = BwdTile::default();
    for ly in 0..16 {
        let row = &mut tile.rows[ly];
        for l in 0..16 {
            row.last[l] = rng.below(n as u64 + 1) as u32;
            row.t[l] = rng.uniform(1e-4, 1.0) as f32;
            for ch in 0..3 {
                row.gc[ch][l] = rng.uniform(-1.0, 1.0) as f32;
            }
            row.gs[l] = rng.uniform(-0.1, 0.1) as f32;
            row.r[l] = rng.uniform(-1.0, 1.0) as f32;
        }
        tile.row_last[ly] = row.last.iter().copied().max().unwrap();
    }
    tile
}

fn run(isa: Isa, smooth: bool, splats: &[Splat2D], list: &[u32]) -> Vec<u32> {
    let mut tile = tile_state(9, list.len() as u32);
    let mut out = vec![[f32::NAN; 10]; list.len()];
    let mut emit = |k: usize, v: PairGrad| out[k] = v;
    if smooth {
        backward_tile_dispatch::<true>(isa, splats, list, 0, 0, &mut tile, 0.99, &mut emit);
    } else {
        backward_tile_dispatch::<false>(isa, splats, list, 0, 0, &mut tile, 0.99, &mut emit);
    }
    assert!(
        out.iter().flatten().all(|v| v.is_finite()),
        "every entry is emitted"
    );
    let mut v: Vec<u32> = out.iter().flatten().map(|x| x.to_bits()).collect();
    for row in &tile.rows {
        v.extend(row.t.iter().map(|x| x.to_bits()));
        v.extend(row.r.iter().map(|x| x.to_bits()));
    }
    v
}

#[test]
fn vector_variants_are_bit_identical_to_the_portable_kernel() {
    let splats = random_tile_splats(5, 200);
    let list: Vec<u32> = (0..200).collect();
    for smooth in [false, true] {
        let runs = for_each_isa("backward tile kernel", |isa| {
            run(isa, smooth, &splats, &list)
        });
        let a = &runs[0].1;
        assert!(a.iter().filter(|v| **v != 0).count() > 500);
        for (isa, b) in &runs[1..] {
            assert_eq!(a, b, "{isa:?} smooth {smooth}");
        }
    }
}

#[test]
fn tree_sum_matches_plain_sum_closely() {
    let v: [f32; 16] = std::array::from_fn(|i| (i as f32 * 0.37).sin());
    let plain: f64 = v.iter().map(|x| *x as f64).sum();
    assert!((tree_sum16(&v) as f64 - plain).abs() < 1e-6);
}
