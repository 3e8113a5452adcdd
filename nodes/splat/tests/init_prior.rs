//! Initialisation from the radiance-field prior's depth: points land on the photo's rays at
//! the prior's depth (D / A), only where the prior is opaque, at any render scale; the policy
//! prefers SfM points, then the prior, then random points.

use augsplat_core::{PointCloud, Scene};
use augsplat_splat::init::{from_prior_depth, initial_gaussians, InitArgs, InitView, PriorDepth};

#[test]
fn points_lie_at_the_priors_depth_where_it_is_opaque() {
    // World points at Z = 0 lie 2 in front of this camera.
    let cam = augsplat_testkit::cameras::facing(32, 24, 2.0);
    let image = vec![0.25f32; 32 * 24 * 3];
    let views = [InitView {
        camera: &cam,
        image: &image,
    }];
    // The prior at 1/4 scale: a plane 2 in front (D = z · A) on the left half, empty on the
    // right half (A = 0).
    let (w, h) = (8u32, 6u32);
    let mut depth = vec![0.0f32; (w * h) as usize];
    let mut alpha = vec![0.0f32; (w * h) as usize];
    for y in 0..h {
        for x in 0..w / 2 {
            let i = (y * w + x) as usize;
            alpha[i] = 0.8;
            depth[i] = 2.0 * 0.8;
        }
    }
    let prior = [PriorDepth {
        view: 0,
        width: w,
        height: h,
        depth: &depth,
        alpha: &alpha,
    }];
    let args = InitArgs {
        random_points: 500,
        ..InitArgs::default()
    };
    let g = from_prior_depth(&views, &prior, 0, &args, 1.0, 7);
    assert_eq!(g.len(), 500);
    for m in &g.means {
        assert!(m[2].abs() < 1e-5, "on the plane Z = 0: {m:?}");
        // Left half of the image: x < 0 in camera space (principal point at the centre).
        assert!(m[0] <= 1e-6, "only where the prior is opaque: {m:?}");
    }
    // The colour comes from the photo.
    let dc = (0.25 - 0.5) / augsplat_splat::constants::C0;
    assert!((g.sh[0] as f64 - dc).abs() < 1e-5);
    // Deterministic.
    let again = from_prior_depth(&views, &prior, 0, &args, 1.0, 7);
    assert_eq!(g.means, again.means);

    // The policy: no points + a prior → the prior; a transparent prior → random points.
    let scene = Scene {
        source: "test".into(),
        views: Vec::new(),
        near: 1.0,
        far: 3.0,
        normalization: Default::default(),
        has_points: false,
    };
    let init = initial_gaussians(
        &PointCloud::default(),
        &scene,
        &views,
        &prior,
        0,
        &args,
        1.0,
        7,
    );
    assert!(init.note.unwrap().contains("back-projected"));
    let empty = vec![0.0f32; (w * h) as usize];
    let transparent = [PriorDepth {
        alpha: &empty,
        ..prior[0]
    }];
    let init = initial_gaussians(
        &PointCloud::default(),
        &scene,
        &views,
        &transparent,
        0,
        &args,
        1.0,
        7,
    );
    assert!(init
        .note
        .unwrap()
        .contains("random Gaussians on training rays"));
    assert!(!init.warn);
    // No points, no prior, unusable bounds: the cube, loudly.
    let bad = Scene {
        near: f64::NAN,
        ..scene.clone()
    };
    let init = initial_gaussians(&PointCloud::default(), &bad, &views, &[], 0, &args, 1.0, 7);
    assert!(init.warn);
}
