//! The large-Gaussian prune's extent: gsplat's camera-spread scene scale, or the content's
//! own extent (`densify.prune_extent: Content`) for captures whose content reaches far past
//! the cameras (LLFF).

use augsplat_core::Camera;
use augsplat_splat::adam::Adam;
use augsplat_splat::densify::{Densifier, DensifyArgs, Extents, PruneExtent};
use augsplat_splat::train::{
    content_extent, scene_scale, RealImages, RealLoss, RealView, TrainArgs, Trainer,
};
use augsplat_splat::Gaussians;

/// A 4×3 camera at `centre` looking along +z (identity rotation).
fn camera_at(centre: [f64; 3]) -> Camera {
    Camera {
        width: 4,
        height: 3,
        fx: 4.0,
        fy: 4.0,
        cx: 2.0,
        cy: 1.5,
        world_to_camera: [
            [1.0, 0.0, 0.0, -centre[0]],
            [0.0, 1.0, 0.0, -centre[1]],
            [0.0, 0.0, 1.0, -centre[2]],
            [0.0, 0.0, 0.0, 1.0],
        ],
    }
}

/// Four cameras on a square of half-side 0.5 around the origin, as a forward-facing rig.
fn rig() -> Vec<Camera> {
    [[-0.5, -0.5], [0.5, -0.5], [-0.5, 0.5], [0.5, 0.5]]
        .iter()
        .map(|&[x, y]| camera_at([x, y, 0.0]))
        .collect()
}

/// Opaque Gaussians at `means`, with the largest scale `scales[i]`.
fn gaussians(means: &[[f32; 3]], scales: &[f32]) -> Gaussians {
    let mut g = Gaussians::empty(0);
    for (m, &s) in means.iter().zip(scales) {
        g.means.push(*m);
        g.log_scales.push([s.ln(), (0.5 * s).ln(), (0.25 * s).ln()]);
        g.quats.push([1.0, 0.0, 0.0, 0.0]);
        g.opacity_logits.push(2.0);
        g.sh.extend([0.1, 0.2, 0.3]);
    }
    g
}

#[test]
fn the_content_extent_is_the_90th_percentile_distance_and_ignores_far_outliers() {
    let cams = rig();
    let refs: Vec<&Camera> = cams.iter().collect();
    // Points straight ahead at depths 1..=100: the 0-based 89th smallest distance is 90.
    let mut means: Vec<[f32; 3]> = (1..=100).map(|k| [0.0, 0.0, k as f32]).collect();
    let e = content_extent(&refs, &means).unwrap();
    assert!((e - 1.1 * 90.0).abs() < 1e-9, "{e}");
    // The five farthest points thrown a million units away move nothing.
    for m in means.iter_mut().skip(95) {
        m[2] = 1e6;
    }
    assert_eq!(content_extent(&refs, &means), Some(e));
    // The camera rule for the same rig: 1.1 × √0.5.
    let s = scene_scale(&refs);
    assert!((s - 1.1 * 0.5f64.sqrt()).abs() < 1e-12);
    assert!(e > 100.0 * s);
    // Nothing to measure.
    assert_eq!(content_extent(&refs, &[]), None);
    assert_eq!(content_extent(&[], &means), None);
    assert_eq!(content_extent(&refs, &[[0.0, 0.0, 0.0]]), None);
}

fn real_views(cams: &[Camera]) -> RealImages {
    RealImages {
        views: cams
            .iter()
            .enumerate()
            .map(|(i, c)| RealView {
                name: format!("v{i}"),
                camera: c.clone(),
                image: vec![0.5; (c.width * c.height * 3) as usize],
            })
            .collect(),
        loss: RealLoss::default(),
    }
}

fn args(extent: PruneExtent) -> TrainArgs {
    TrainArgs {
        steps: 10,
        sh_degree: 0,
        densify: DensifyArgs {
            prune_extent: extent,
            ..Default::default()
        },
        ..Default::default()
    }
}

#[test]
fn the_trainer_prunes_against_the_content_only_when_asked_and_never_below_the_cameras() {
    // Forward-facing: the content at depths 10–40, far past the cameras' spread.
    let cams = rig();
    let refs: Vec<&Camera> = cams.iter().collect();
    let ss = scene_scale(&refs);
    let real = real_views(&cams);
    let means: Vec<[f32; 3]> = (0..31).map(|k| [0.0, 0.0, 10.0 + k as f32]).collect();
    let g = gaussians(&means, &vec![0.1; means.len()]);
    let expected = content_extent(&refs, &means).unwrap();
    assert!(expected > 10.0 * ss);
    let t = Trainer::new(args(PruneExtent::Content), g.clone(), ss, &real, None);
    assert_eq!(t.prune_extent(), expected);
    assert_eq!(t.scene_scale(), ss);
    let t = Trainer::new(args(PruneExtent::Cameras), g, ss, &real, None);
    assert_eq!(t.prune_extent(), ss);

    // Around an object: cameras on a ring of radius 4, content within radius 1 of the centre.
    let ring: Vec<Camera> = (0..8)
        .map(|k| {
            let a = k as f64 * std::f64::consts::FRAC_PI_4;
            camera_at([4.0 * a.cos(), 4.0 * a.sin(), 0.0])
        })
        .collect();
    let refs: Vec<&Camera> = ring.iter().collect();
    let ss = scene_scale(&refs);
    let real = real_views(&ring);
    let means: Vec<[f32; 3]> = (0..20)
        .map(|k| {
            let a = k as f32 * 0.3;
            [a.cos(), a.sin(), 0.05 * k as f32 - 0.5]
        })
        .collect();
    let g = gaussians(&means, &vec![0.1; means.len()]);
    assert!(content_extent(&refs, &means).unwrap() < ss);
    let t = Trainer::new(args(PruneExtent::Content), g, ss, &real, None);
    assert_eq!(t.prune_extent(), ss, "never below the camera rule");
}

#[test]
fn the_prune_uses_its_own_extent_and_growth_keeps_the_scene_scale() {
    let a = DensifyArgs {
        start: 0,
        every: 100,
        reset_every: 100,
        scale_with_steps: false,
        grad_threshold: 1e-3,
        ..Default::default()
    };
    let sched = a.scaled(1000);
    // Scales 0.05, 0.5 and 5 against prune_scale3d 0.1: the camera extent 1 prunes the
    // last two, a content extent of 10 only the last.
    let means = [[0.0, 0.0, 5.0], [0.0, 0.0, 10.0], [0.0, 0.0, 30.0]];
    let run = |extents: Extents| {
        let mut g = gaussians(&means, &[0.05, 0.5, 5.0]);
        let mut adam = Adam::new(g.len(), g.coeffs());
        let mut d = Densifier::new(g.len());
        // The first one is due to grow (its statistic is over the threshold): split when its
        // largest scale is above grow_scale3d × the scene extent (0.01 × 1), cloned otherwise.
        d.grad2d[0] = 1.0;
        d.count[0] = 1;
        let r = d.step_post_update(
            200,
            &sched,
            &a,
            &mut g,
            &mut adam,
            extents,
            7,
            &mut |_| unreachable!(),
        );
        (r, g)
    };
    let (r, g) = run(Extents::uniform(1.0));
    assert_eq!((r.split, r.cloned, r.pruned), (1, 0, 2));
    assert!(g.log_scales.iter().all(|s| s[0].exp() < 0.05));
    let (r, g) = run(Extents {
        scene: 1.0,
        prune: 10.0,
    });
    assert_eq!((r.split, r.cloned, r.pruned), (1, 0, 1));
    let largest: Vec<f32> = g.log_scales.iter().map(|s| s[0].exp()).collect();
    assert_eq!(largest.len(), 3);
    let kept = largest.iter().filter(|&&s| (s - 0.5).abs() < 1e-5).count();
    assert_eq!(kept, 1, "the 0.5 Gaussian survives: {largest:?}");
    // With a scene extent of 10 the same Gaussian is small enough to be cloned instead.
    let (r, _) = run(Extents {
        scene: 10.0,
        prune: 10.0,
    });
    assert_eq!((r.split, r.cloned, r.pruned), (0, 1, 1));
}

#[test]
fn the_default_extent_stays_out_of_the_key() {
    let default = serde_json::to_value(DensifyArgs::default()).unwrap();
    assert!(default.get("prune_extent").is_none(), "{default}");
    let content = serde_json::to_value(DensifyArgs {
        prune_extent: PruneExtent::Content,
        ..Default::default()
    })
    .unwrap();
    assert_eq!(content["prune_extent"], "Content");
    let back: DensifyArgs = serde_json::from_value(content).unwrap();
    assert_eq!(back.prune_extent, PruneExtent::Content);
}
