//! Shared helpers of the training tests: a generated scene split into train/test folders.
#![allow(dead_code)]

use augsplat_core::Scene;
use augsplat_scene::split;
use augsplat_scene::synthetic::{self, SyntheticParams};
use std::path::{Path, PathBuf};

/// Generates the procedural scene (`views` views of `w×h`) under `root/full` and writes
/// `root/train` (every view but each 8th) and `root/test` (each 8th view, from 0).
pub fn make_scene(root: &Path, w: u32, h: u32, views: u32, points: u32) -> (PathBuf, PathBuf) {
    let full = root.join("full");
    let params = SyntheticParams {
        width: w,
        height: h,
        views,
        points,
        supersample: 2,
        ..Default::default()
    };
    let scene = synthetic::generate(&params, &full).expect("generate scene");
    let cloud = scene.load_points(&full).expect("points");
    let n = scene.views.len();
    let train: Vec<usize> = (0..n).filter(|i| i % 8 != 0).collect();
    let test: Vec<usize> = (0..n).filter(|i| i % 8 == 0).collect();
    let mut out = Vec::new();
    for (name, ids) in [("train", train), ("test", test)] {
        let dir = root.join(name);
        std::fs::create_dir_all(dir.join("images")).unwrap();
        let (sub, pts) = split::subset(&scene, &cloud, &ids, 1);
        for v in &sub.views {
            std::fs::copy(full.join(&v.image), dir.join(&v.image)).unwrap();
        }
        let sub = Scene {
            has_points: !pts.is_empty(),
            ..sub
        };
        sub.save(&dir).unwrap();
        if !pts.is_empty() {
            pts.save(&dir.join(augsplat_core::scene::POINTS_FILE))
                .unwrap();
        }
        out.push(dir);
    }
    (out[0].clone(), out[1].clone())
}

/// The views of a scene folder, with their photos, as the trainer's real supervision.
pub fn load_views(dir: &Path) -> Vec<augsplat_splat::train::RealView> {
    let scene = Scene::load(dir).unwrap();
    (0..scene.views.len())
        .map(|i| augsplat_splat::train::RealView {
            name: scene.views[i].name.clone(),
            camera: scene.views[i].camera.clone(),
            image: scene.load_image(dir, i).unwrap().data,
        })
        .collect()
}

/// The training folder's views as real supervision (default loss), the test folder's views,
/// and the training cameras' scene scale.
pub fn real_case(
    train: &Path,
    test: &Path,
) -> (
    augsplat_splat::train::RealImages,
    Vec<augsplat_splat::train::RealView>,
    f64,
) {
    let views = load_views(train);
    let cams: Vec<_> = views.iter().map(|v| &v.camera).collect();
    let scale = augsplat_splat::train::scene_scale(&cams);
    let real = augsplat_splat::train::RealImages {
        views,
        loss: Default::default(),
    };
    (real, load_views(test), scale)
}

/// The scene folder's points as Gaussians of SH degree `degree` (scene scale `sscale`).
pub fn initial(dir: &Path, degree: u32, sscale: f64) -> augsplat_splat::Gaussians {
    let scene = Scene::load(dir).unwrap();
    let cloud = scene.load_points(dir).unwrap();
    augsplat_splat::init::from_points(&cloud, degree, &Default::default(), sscale, 1)
}

/// The bits of every parameter of `g` (means, log-scales, quaternions, opacity logits, SH), for
/// comparing two runs byte for byte.
pub fn param_bits(g: &augsplat_splat::Gaussians) -> Vec<u32> {
    g.means
        .as_flattened()
        .iter()
        .chain(g.log_scales.as_flattened())
        .chain(g.quats.as_flattened())
        .chain(&g.opacity_logits)
        .chain(&g.sh)
        .map(|v| v.to_bits())
        .collect()
}
