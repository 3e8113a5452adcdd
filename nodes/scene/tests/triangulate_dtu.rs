//! Triangulation on dtu_scan24 with its SfM points set aside: the points found from the photos
//! and the calibrated poses against the shipped COLMAP points, on the training views that
//! `pipelines/capture.ron` draws (30 views, every 8th held out, at most 512 px).

mod common;

use augsplat_core::{PointCloud, Scene};
use augsplat_scene::import::{import_scene, ImportOptions};
use augsplat_scene::node::{read_source, ImportSceneArgs};
use augsplat_scene::split::{split_indices, subset};
use augsplat_scene::triangulate::outliers::Grid;
use augsplat_scene::triangulate::{triangulate, TriangulateOptions, Triangulated};
use common::data_dir;

/// Distance from each point of `a` to its nearest point of `b` (infinite beyond the grid's
/// search, eight cells of `cell`).
fn nearest_distances(a: &PointCloud, b: &PointCloud, cell: f64) -> Vec<f64> {
    let to: Vec<[f64; 3]> = b.positions.iter().map(|p| p.map(f64::from)).collect();
    let grid = Grid::new(&to, cell);
    a.positions
        .iter()
        .map(|p| {
            grid.nearest(p.map(f64::from), 1, None)
                .first()
                .copied()
                .unwrap_or(f64::INFINITY)
        })
        .collect()
}

#[test]
fn dtu_triangulated_points_agree_with_its_sfm_points() {
    let Some(d) = data_dir("dtu_triangulated_points_agree_with_its_sfm_points") else {
        return;
    };
    let raw = read_source(&d.join("dtu_scan24"), &ImportSceneArgs::default()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let opts = ImportOptions {
        downscale: 2,
        ..Default::default()
    };
    import_scene(&raw, &opts, dir.path(), &|_| {}).unwrap();
    let scene = Scene::load(dir.path()).unwrap();
    let sfm_all = scene.load_points(dir.path()).unwrap();
    let split = split_indices(scene.views.len(), Some(30), 8, 42).unwrap();
    let (train, sfm) = subset(&scene, &sfm_all, &split.train, 2);
    let cams: Vec<_> = train.views.iter().map(|v| v.camera.clone()).collect();
    let names: Vec<_> = train.views.iter().map(|v| v.name.clone()).collect();
    let index: Vec<usize> = split.train.clone();
    let images: Vec<_> = index
        .iter()
        .map(|&i| scene.load_image(dir.path(), i).unwrap())
        .collect();
    let t0 = std::time::Instant::now();
    let topts = TriangulateOptions::default();
    let Triangulated { cloud, report, .. } = triangulate(&cams, &images, &names, &topts).unwrap();
    eprintln!(
        "{} in {:.2} s",
        report.summary(),
        t0.elapsed().as_secs_f64()
    );
    // The scene's extent: the diagonal of the box holding the central 98 % of the SfM points
    // along each axis (the model keeps some far background points).
    let extent = {
        let mut d2 = 0.0;
        for a in 0..3 {
            let mut v: Vec<f64> = sfm.positions.iter().map(|p| p[a] as f64).collect();
            v.sort_by(f64::total_cmp);
            let q = |f: f64| v[((v.len() - 1) as f64 * f) as usize];
            d2 += (q(0.99) - q(0.01)).powi(2);
        }
        f64::sqrt(d2)
    };
    let mut dist = nearest_distances(&cloud, &sfm, extent / 100.0);
    dist.sort_by(f64::total_cmp);
    let median = dist[dist.len() / 2];
    eprintln!(
        "{} triangulated, {} SfM points; extent {extent:.4}; nearest SfM point: median {:.5} \
         ({:.3} % of the extent), 90 % {:.5}",
        cloud.len(),
        sfm.len(),
        median,
        100.0 * median / extent,
        dist[dist.len() * 9 / 10]
    );
    // Measured: 12,585 points, median 0.71 % of the extent (0.00634 of 0.8884). The defaults
    // were chosen on this scene's training views.
    assert!(cloud.len() >= 5000, "{}", report.summary());
    assert!(
        median < 0.01 * extent,
        "median {median} against extent {extent}"
    );
}
