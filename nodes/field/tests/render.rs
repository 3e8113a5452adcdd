//! Rendering with density evaluation stopped at early termination matches the full evaluation.

mod common;

use augsplat_core::Rng;
use augsplat_field::field::{ChunkState, Field, FieldConfig, RayInput};
use augsplat_field::hashgrid::HashGridConfig;
use augsplat_field::occupancy::OccupancyGrid;

fn field() -> Field {
    Field::new(FieldConfig {
        grid: HashGridConfig {
            levels: 4,
            features_per_level: 2,
            log2_table_size: 10,
            base_resolution: 4,
            max_resolution: 40,
        },
        hidden_width: 16,
        appearance_dim: 2,
        n_images: 2,
        center: [0.0; 3],
        radius: 1.0,
        near: 0.1,
        far: 6.0,
        march_steps: 64,
        occupancy_resolution: 8,
    })
    .unwrap()
}

/// Seeded parameters with the hash table drawn uniform in ±1 when `table_seed` is given (a
/// textured density) and the density network's output bias set to `bias` (positive: a mix
/// of opaque and semi-transparent regions along the rays; very negative: transparent).
fn params_with_density_bias(f: &Field, seed: u64, table_seed: Option<u64>, bias: f32) -> Vec<f32> {
    let mut params = f.init_params(seed);
    if let Some(t) = table_seed {
        let mut rng = Rng::new(t);
        for p in params[..f.density_offset].iter_mut() {
            *p = rng.uniform(-1.0, 1.0) as f32;
        }
    }
    let l0 = f.density.layers[0];
    let bias0 = f.density_offset + l0.params() + f.density.layers[1].inp * f.density.layers[1].out;
    params[bias0] = bias;
    params
}

#[test]
fn stopping_at_termination_keeps_colour_weights_and_cut() {
    let f = field();
    let params = params_with_density_bias(&f, 3, Some(8), 1.5);
    let occ = OccupancyGrid::full(8);
    let rays: Vec<RayInput> = (0..40)
        .map(|r| {
            let a = r as f64 * 0.37;
            let d = augsplat_core::linalg::normalize([0.4 * a.cos(), 0.4 * a.sin(), 1.0]);
            RayInput {
                origin: [0.05 * r as f32 - 1.0, 0.2, -2.5],
                dir: d.map(|v| v as f32),
                image: u32::MAX,
                background: [0.9, 0.5, 0.1],
            }
        })
        .collect();
    let mean = f.mean_embedding(&params);
    let run = |stop: bool| {
        let mut st = ChunkState::default();
        st.min_color_weight = 1e-5;
        st.stop_at_termination = stop;
        f.forward_chunk(
            &params,
            &occ,
            &rays,
            &|r| (r as f32 * 0.13) % 1.0,
            &mean,
            &mut st,
        );
        st
    };
    let full = run(false);
    let stop = run(true);
    assert!(
        stop.n() < full.n() / 2,
        "termination should drop most samples ({} of {})",
        stop.n(),
        full.n()
    );
    let mut terminated = 0;
    for r in 0..rays.len() {
        let (fa, fb) = (full.ray_start[r], full.ray_start[r + 1]);
        let (sa, sb) = (stop.ray_start[r], stop.ray_start[r + 1]);
        // Every kept sample has the same weight; the cut is the same.
        assert_eq!(&full.w[fa..fa + (sb - sa)], &stop.w[sa..sb], "ray {r}");
        assert_eq!(full.n_color[r], stop.n_color[r], "ray {r}");
        terminated += (sb - sa < fb - fa) as usize;
        let (o, p) = (full.out[r], stop.out[r]);
        for k in 0..3 {
            assert!(
                (o.rgb[k] - p.rgb[k]).abs() <= 1e-4,
                "ray {r}: {o:?} vs {p:?}"
            );
        }
        assert!((o.acc - p.acc).abs() <= 1e-4, "ray {r}");
        assert!((o.depth - p.depth).abs() <= 1e-4 * 6.0, "ray {r}");
    }
    assert!(terminated > 10, "only {terminated} rays terminated early");
}

/// `render_camera` gives the same bits for any parallel chunk size (its inner passes of
/// `RENDER_PASS_RAYS` rays included) and counts what it evaluated consistently: every marched
/// sample, fewer through the density network once rays terminate, fewer still with a colour.
#[test]
fn render_camera_is_independent_of_chunking_and_counts_samples() {
    use augsplat_field::train::{render_camera, RENDER_PASS_RAYS};
    let f = field();
    let params = params_with_density_bias(&f, 5, Some(9), 1.5);
    let occ = OccupancyGrid::full(8);
    let cam = common::look_at([0.3, -0.2, -2.5], 23, 17);
    let reference = render_camera(&f, &params, &occ, &cam, [0.2, 0.4, 0.6], 1);
    for chunk in [RENDER_PASS_RAYS - 1, RENDER_PASS_RAYS + 3, 256, 10_000] {
        let img = render_camera(&f, &params, &occ, &cam, [0.2, 0.4, 0.6], chunk);
        assert_eq!(img, reference, "chunk of {chunk} rays");
    }
    let s = reference.stats;
    let rays = 23 * 17;
    assert!(s.steps >= s.marched && s.marched >= rays, "{s:?}");
    assert!(s.density < s.marched, "no ray stopped early: {s:?}");
    assert!(s.color <= s.density && s.color > 0, "{s:?}");
}

/// A transparent field (no ray reaches the termination threshold): the render path, which
/// then hands its segment outputs over without compaction, gives exactly the full
/// evaluation's bits.
#[test]
fn render_without_termination_equals_the_full_evaluation() {
    let f = field();
    let params = params_with_density_bias(&f, 4, None, -4.0);
    let occ = OccupancyGrid::full(8);
    let rays: Vec<RayInput> = (0..24)
        .map(|r| RayInput {
            origin: [0.04 * r as f32 - 0.5, -0.1, -2.5],
            dir: augsplat_core::linalg::normalize([0.05 * (r % 5) as f64, 0.1, 1.0])
                .map(|v| v as f32),
            image: u32::MAX,
            background: [0.3, 0.6, 0.9],
        })
        .collect();
    let mean = f.mean_embedding(&params);
    let run = |stop: bool| {
        let mut st = ChunkState::default();
        st.min_color_weight = 1e-5;
        st.stop_at_termination = stop;
        f.forward_chunk(&params, &occ, &rays, &|_| 0.25, &mean, &mut st);
        st
    };
    let (full, stop) = (run(false), run(true));
    assert!(full.n() > 24 * 20, "{} samples", full.n());
    assert_eq!(
        stop.n(),
        full.n(),
        "a ray terminated: the test needs a thinner field"
    );
    assert_eq!(stop.out, full.out);
    assert_eq!(stop.w, full.w);
    assert!(stop.out.iter().all(|o| o.acc < 0.9 && o.acc > 0.0));
}
