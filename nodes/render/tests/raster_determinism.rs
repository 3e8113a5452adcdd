//! Render and backward are bit-identical with 1 and 2 threads.
#![allow(clippy::needless_range_loop)]

mod raster_common;

use augsplat_render::{backward, render, Gradients, RenderOutput, RenderSettings};
use raster_common::*;

fn run(threads: usize) -> (RenderOutput, Gradients) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let cam = camera(150, 110);
        let g = random_scene(42, 9000, 3, &cam, (-3.0, 6.0));
        let s = RenderSettings {
            background: [0.1, 0.2, 0.3],
            ..Default::default()
        };
        let out = render(&g, &cam, &s);
        let n = out.rgb.len();
        let d: Vec<f32> = (0..n)
            .map(|i| ((i * 7919) % 13) as f32 * 0.01 - 0.06)
            .collect();
        let da: Vec<f32> = (0..n / 3).map(|i| ((i * 31) % 5) as f32 * 0.01).collect();
        let gr = backward(&g, &cam, &s, &out, &d, Some(&da), Some(&da));
        (out, gr)
    })
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn one_and_two_threads_give_identical_bits() {
    let (o1, g1) = run(1);
    let (o2, g2) = run(2);
    assert!(o1.stats.visible > 1000 && o1.stats.pairs > 0);
    assert_eq!(bits(&o1.rgb), bits(&o2.rgb));
    assert_eq!(bits(&o1.alpha), bits(&o2.alpha));
    assert_eq!(bits(&o1.depth), bits(&o2.depth));
    assert_eq!(o1.stats, o2.stats);
    let flat = |g: &Gradients| {
        let mut v: Vec<u32> = Vec::new();
        v.extend(g.means.iter().flatten().map(|x| x.to_bits()));
        v.extend(g.log_scales.iter().flatten().map(|x| x.to_bits()));
        v.extend(g.quats.iter().flatten().map(|x| x.to_bits()));
        v.extend(g.opacity_logits.iter().map(|x| x.to_bits()));
        v.extend(g.sh.iter().map(|x| x.to_bits()));
        v.extend(g.means2d_abs.iter().flatten().map(|x| x.to_bits()));
        v
    };
    assert_eq!(flat(&g1), flat(&g2));
    assert_eq!(g1.visible, g2.visible);
    assert!(g1.means.iter().flatten().any(|v| *v != 0.0));
}
