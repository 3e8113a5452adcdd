//! The triangulation on the generated scene (whose exact depth is known) and on bad input.

use super::*;
use crate::synthetic::{generate, SyntheticParams};
use augsplat_core::Scene;

fn generated(
    dir: &std::path::Path,
    views: u32,
) -> (Scene, Vec<Camera>, Vec<ImageF32>, Vec<String>) {
    let scene = generate(
        &SyntheticParams {
            width: 320,
            height: 240,
            views,
            points: 0,
            supersample: 2,
            ..Default::default()
        },
        dir,
    )
    .unwrap();
    let cams = scene.views.iter().map(|v| v.camera.clone()).collect();
    let images = (0..scene.views.len())
        .map(|i| scene.load_image(dir, i).unwrap())
        .collect();
    let names = scene.views.iter().map(|v| v.name.clone()).collect();
    (scene, cams, images, names)
}

/// Relative difference between each point's depth and the ray-traced depth at its projection,
/// in every view of its track.
fn depth_errors(dir: &std::path::Path, scene: &Scene, cloud: &PointCloud) -> Vec<f64> {
    let depths: Vec<Vec<f32>> = scene
        .views
        .iter()
        .map(|v| {
            let exr =
                augsplat_core::image::read_exr(&dir.join(format!("exact_depth/{}.exr", v.name)))
                    .unwrap();
            exr.channel("Z").unwrap().to_vec()
        })
        .collect();
    let mut errs = Vec::new();
    for i in 0..cloud.len() {
        let p = cloud.positions[i].map(|x| x as f64);
        for &v in cloud.track(i) {
            let cam = &scene.views[v as usize].camera;
            let e = crate::synthetic::surface_error(&depths[v as usize], cam, p)
                .expect("a point projects into the views of its track");
            errs.push(e);
        }
    }
    errs.sort_by(f64::total_cmp);
    errs
}

#[test]
fn points_of_the_generated_scene_lie_on_its_surfaces() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, cams, images, names) = generated(dir.path(), 30);
    let topts = TriangulateOptions::default();
    let Triangulated { cloud, report, .. } = triangulate(&cams, &images, &names, &topts).unwrap();
    eprintln!("{}", report.summary());
    // Measured: 2,339 points, relative depth error median 0.35 %, 75th percentile 2.3 %.
    assert!(report.points >= 1000, "{}", report.summary());
    assert_eq!(cloud.len(), report.points);
    assert!(report.mean_error_px < 1.0, "{}", report.summary());
    let errs = depth_errors(dir.path(), &scene, &cloud);
    let q = |f: f64| errs[((errs.len() - 1) as f64 * f) as usize];
    eprintln!(
        "depth error: median {:.4}, 75 % {:.4}, 90 % {:.4}, 99 % {:.4}",
        q(0.5),
        q(0.75),
        q(0.9),
        q(0.99)
    );
    assert!(q(0.5) < 0.005, "median relative depth error {}", q(0.5));
    assert!(
        q(0.75) < 0.05,
        "75th percentile relative depth error {}",
        q(0.75)
    );
    // Colours are the photos' (in [0, 1]), tracks name real views.
    for (i, c) in cloud.colors.iter().enumerate() {
        assert!(c.iter().all(|v| (0.0..=1.0).contains(v)));
        assert!(cloud.track(i).len() >= 2);
        assert!(cloud.track(i).iter().all(|&v| (v as usize) < cams.len()));
    }
    // The same bytes on one thread.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let one = pool
        .install(|| triangulate(&cams, &images, &names, &TriangulateOptions::default()))
        .unwrap();
    assert_eq!(one.cloud, cloud);
    // The isolation filter (off by default: it also drops a capture's sparse background,
    // which the Gaussians need) removes most wrong two-view points. Measured: 1,886 points,
    // 90th percentile 5.1 %.
    let filtered = TriangulateOptions {
        drop_isolated: true,
        ..TriangulateOptions::default()
    };
    let Triangulated { cloud, report, .. } =
        triangulate(&cams, &images, &names, &filtered).unwrap();
    assert!(
        report.rejected_isolated > 0 && cloud.len() >= 1000,
        "{}",
        report.summary()
    );
    let errs = depth_errors(dir.path(), &scene, &cloud);
    let q = |f: f64| errs[((errs.len() - 1) as f64 * f) as usize];
    assert!(
        q(0.9) < 0.08,
        "90th percentile relative depth error {}",
        q(0.9)
    );
}

#[test]
fn bad_captures_get_clear_errors_or_an_explained_empty_cloud() {
    let dir = tempfile::tempdir().unwrap();
    let (_, cams, images, names) = generated(dir.path(), 4);
    let opts = TriangulateOptions::default();
    // One view.
    let e = triangulate(&cams[..1], &images[..1], &names[..1], &opts).unwrap_err();
    assert!(e.to_string().contains("at least two views"), "{e}");
    // An image of another size than its camera.
    let mut small = images.clone();
    small[2] = small[2].downscale(2);
    let e = triangulate(&cams, &small, &names, &opts).unwrap_err();
    assert!(
        e.to_string().contains("view_002") && e.to_string().contains("160×120"),
        "{e}"
    );
    // Every camera at one point (a panorama, or poses gone wrong).
    let mut same = cams.clone();
    for c in &mut same {
        let r = c.rotation();
        c.world_to_camera = linalg::mat4_from_rt(&r, [0.0, 0.0, 0.0]);
    }
    let e = triangulate(&same, &images, &names, &opts).unwrap_err();
    assert!(e.to_string().contains("at one point"), "{e}");
    // Views with no overlap: each looks away from the others (axes > 60° apart): no pairs,
    // no points, and the report says why.
    let mut apart = cams.clone();
    for (i, c) in apart.iter_mut().enumerate() {
        let r = linalg::axis_angle([0.0, 1.0, 0.0], i as f64 * std::f64::consts::FRAC_PI_2);
        c.world_to_camera = linalg::mat4_from_rt(&r, [0.0, 0.0, -(i as f64) - 1.0]);
    }
    let Triangulated { cloud, report, .. } = triangulate(&apart, &images, &names, &opts).unwrap();
    assert!(cloud.is_empty());
    assert_eq!((report.pairs, report.points), (0, 0), "{report:?}");
    assert!(report.keypoints > 0);
}
