//! The generated scene: determinism, geometry, cameras and points.

use super::world::soft_checker;
use super::*;

fn small() -> SyntheticParams {
    SyntheticParams {
        width: 32,
        height: 24,
        views: 6,
        points: 200,
        supersample: 2,
        ..Default::default()
    }
}

#[test]
fn checker_is_bounded_and_continuous() {
    let mut prev = soft_checker(-3.0, 0.3, 0.08);
    for k in 1..6000 {
        let x = -3.0 + k as f64 * 0.001;
        let c = soft_checker(x, 0.3, 0.08);
        assert!((0.0..=1.0).contains(&c));
        assert!((c - prev).abs() < 0.02, "jump at {x}: {prev} → {c}");
        prev = c;
    }
}

#[test]
fn forward_layout_looks_one_way_and_orbit_surrounds() {
    let f = design_cameras(&SyntheticParams {
        layout: Layout::Forward,
        views: 9,
        ..Default::default()
    });
    let d0 = f[0].forward();
    for c in &f {
        assert!((linalg::dot(c.forward(), d0) - 1.0).abs() < 1e-12);
    }
    let o = design_cameras(&SyntheticParams::default());
    // Orbit cameras look at the target (0, 0, 0.3) from all sides.
    let mut sum = [0.0; 3];
    for c in &o {
        let to = linalg::normalize(linalg::sub([0.0, 0.0, 0.3], c.center()));
        assert!(linalg::dot(to, c.forward()) > 1.0 - 1e-12);
        sum = linalg::add(sum, c.forward());
    }
    assert!(linalg::norm([sum[0], sum[1], 0.0]) < 1e-9);
}

#[test]
fn exact_depth_matches_independent_ray_sphere_geometry() {
    // The pixel-centre depth at the image centre of a camera looking at the big sphere's
    // centre equals (distance − radius) along the axis (the centre ray is the optical axis
    // up to half a pixel).
    let world = World::new(0.0);
    let s = &world.spheres[0];
    let c = [s.c[0] + 2.0, s.c[1] - 0.5, s.c[2] + 0.4];
    let w2c = look_along(c, linalg::sub(s.c, c));
    let cam = Camera {
        width: 33,
        height: 33,
        fx: 40.0,
        fy: 40.0,
        cx: 16.5,
        cy: 16.5,
        world_to_camera: w2c,
    };
    let (_, depth) = render_view(&world, &cam, 1);
    let want = linalg::norm(linalg::sub(s.c, c)) - s.r;
    assert!(
        (depth[16 * 33 + 16] as f64 - want).abs() < 1e-5,
        "{} vs {want}",
        depth[16 * 33 + 16]
    );
}

#[test]
fn generated_scene_is_consistent_and_deterministic() {
    let p = small();
    let a = tempfile::tempdir().unwrap();
    let b = tempfile::tempdir().unwrap();
    let sa = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| generate(&p, a.path()).unwrap());
    let sb = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(|| generate(&p, b.path()).unwrap());
    assert_eq!(sa, sb);
    for f in [
        "scene.json",
        "points.safetensors",
        "images/view_003.png",
        "exact_depth/view_003.exr",
    ] {
        assert_eq!(
            std::fs::read(a.path().join(f)).unwrap(),
            std::fs::read(b.path().join(f)).unwrap(),
            "{f}"
        );
    }
    let cloud = sa.load_points(a.path()).unwrap();
    assert_eq!(cloud.len(), 200);
    // Normalised: mean camera centre at the origin, farthest camera at distance 1.
    let far = sa
        .views
        .iter()
        .map(|v| linalg::norm(v.camera.center()))
        .fold(0.0, f64::max);
    assert!((far - 1.0).abs() < 1e-9);
    // Noise-free points lie exactly at the exact depth of the pixel they project to
    // (within the depth change across a pixel), in every view of their track.
    let p0 = SyntheticParams {
        point_noise: 0.0,
        ..small()
    };
    let c = tempfile::tempdir().unwrap();
    let s0 = generate(&p0, c.path()).unwrap();
    let cl = s0.load_points(c.path()).unwrap();
    let mut close = 0;
    let mut total = 0;
    for i in 0..cl.len() {
        assert!(cl.track(i).len() >= 2);
        assert_eq!(cl.errors[i], 0.0);
        let t = cl.track(i)[0] as usize;
        let v = &s0.views[t];
        let exr =
            augsplat_core::image::read_exr(&c.path().join(format!("exact_depth/{}.exr", v.name)))
                .unwrap();
        let z = exr.channel("Z").unwrap();
        let q = cl.positions[i];
        let (u, vv, d) = v.camera.project([q[0] as f64, q[1] as f64, q[2] as f64]);
        let k = vv as usize * v.camera.width as usize + u as usize;
        total += 1;
        if ((z[k] as f64 - d) / d).abs() < 0.05 {
            close += 1;
        }
    }
    assert!(close as f64 > 0.9 * total as f64, "{close}/{total}");
}
