//! Reading, writing and checking COLMAP models.

use super::*;

pub(crate) fn tiny_model() -> ColmapModel {
    let mut m = ColmapModel::default();
    m.cameras.insert(
        1,
        ColmapCamera {
            id: 1,
            intrinsics: Intrinsics::from_colmap(
                ModelKind::OpenCv,
                64,
                48,
                &[60.0, 61.0, 32.0, 24.5, -0.05, 0.01, 0.001, -0.002],
            )
            .unwrap(),
        },
    );
    m.cameras.insert(
        2,
        ColmapCamera {
            id: 2,
            intrinsics: Intrinsics::from_colmap(
                ModelKind::SimpleRadial,
                64,
                48,
                &[55.0, 32.0, 24.0, 0.02],
            )
            .unwrap(),
        },
    );
    let q = linalg::mat3_to_quat(&linalg::axis_angle([0.1, 1.0, 0.2], 0.3));
    let pts = [[0.1, 0.2, 3.0], [-0.4, 0.1, 2.5]];
    for (id, cam, t) in [(3u32, 1u32, [0.0, 0.0, 0.0]), (7, 2, [0.3, -0.1, 0.2])] {
        let img = ColmapImage {
            id,
            qvec: q,
            tvec: t,
            camera_id: cam,
            name: format!("img{id}.png"),
            points2d: vec![],
        };
        m.images.insert(id, img);
    }
    // Keypoints: exact projections plus a known offset of 0.5 px in x for image 7.
    for (pi, p) in pts.iter().enumerate() {
        for id in [3u32, 7] {
            let img = &m.images[&id];
            let cam = &m.cameras[&img.camera_id].intrinsics;
            let (u, v) = cam
                .project_camera_point(transform(&img.world_to_camera(), *p))
                .unwrap();
            let off = if id == 7 { 0.5 } else { 0.0 };
            m.images
                .get_mut(&id)
                .unwrap()
                .points2d
                .push(([u + off, v], pi as i64 + 10));
        }
    }
    for (pi, p) in pts.iter().enumerate() {
        m.points.push(ColmapPoint {
            id: pi as u64 + 10,
            xyz: *p,
            rgb: [10, 20, 30],
            error: 0.25,
            track: vec![(3, pi as u32), (7, pi as u32)],
        });
    }
    m
}

#[test]
fn text_and_binary_round_trip() {
    let m = tiny_model();
    let dir = tempfile::tempdir().unwrap();
    m.save_text(dir.path()).unwrap();
    let t = ColmapModel::load(dir.path()).unwrap();
    assert_eq!(t, m);
    let bdir = tempfile::tempdir().unwrap();
    m.save_binary(bdir.path()).unwrap();
    let b = ColmapModel::load(bdir.path()).unwrap();
    assert_eq!(b, m);
}

#[test]
fn reprojection_error_matches_known_offsets() {
    let m = tiny_model();
    // Each point: image 3 exact, image 7 off by 0.5 px ⇒ per-point mean 0.25 ⇒ mean 0.25.
    let (e, np, no) = m.mean_reprojection_error().unwrap();
    assert!((e - 0.25).abs() < 1e-9, "{e}");
    assert_eq!((np, no), (2, 4));
}

#[test]
fn empty_points_line_and_name_with_spaces() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("cameras.txt"),
        "# c\n1 PINHOLE 10 8 9 9 5 4\n",
    )
    .unwrap();
    std::fs::write(
        dir.path().join("images.txt"),
        "# i\n1 1 0 0 0 0 0 0 1 my image.png\n\n2 1 0 0 0 1 0 0 1 b.png\n",
    )
    .unwrap();
    std::fs::write(dir.path().join("points3D.txt"), "").unwrap();
    let m = ColmapModel::load(dir.path()).unwrap();
    assert_eq!(m.images.len(), 2);
    assert_eq!(m.images[&1].name, "my image.png");
    assert!(m.images[&2].points2d.is_empty());
}

#[test]
fn bad_models_name_file_and_entry() {
    let m = tiny_model();
    // Truncated binary.
    let dir = tempfile::tempdir().unwrap();
    m.save_binary(dir.path()).unwrap();
    let p = dir.path().join("images.bin");
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() - 30]).unwrap();
    let e = ColmapModel::load(dir.path()).unwrap_err().to_string();
    assert!(
        e.contains("images.bin") && e.contains("truncated") && e.contains("img7.png"),
        "{e}"
    );
    // Unknown model in text.
    let dir = tempfile::tempdir().unwrap();
    m.save_text(dir.path()).unwrap();
    let p = dir.path().join("cameras.txt");
    let t = std::fs::read_to_string(&p)
        .unwrap()
        .replace("SIMPLE_RADIAL", "FISHEYE_X");
    std::fs::write(&p, t).unwrap();
    let e = ColmapModel::load(dir.path()).unwrap_err().to_string();
    assert!(
        e.contains("cameras.txt") && e.contains("camera 2") && e.contains("FISHEYE_X"),
        "{e}"
    );
    // NaN in a pose.
    let dir = tempfile::tempdir().unwrap();
    let mut bad = m.clone();
    bad.images.get_mut(&7).unwrap().tvec[1] = f64::NAN;
    bad.save_text(dir.path()).unwrap();
    let e = ColmapModel::load(dir.path()).unwrap_err().to_string();
    assert!(
        e.contains("images.txt") && e.contains("image 7") && e.contains("non-finite"),
        "{e}"
    );
    // Missing folder.
    let e = ColmapModel::load(Path::new("/nonexistent/sparse/0"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/sparse/0"), "{e}");
}
