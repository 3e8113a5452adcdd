//! Every importer (COLMAP, transforms.json, LLFF) decodes each photo in full: a JPEG cut at
//! 60 % with an end-of-image marker (FF D9) appended by hand, and a PNG cut short, are refused
//! with an error naming the file, while the untouched files import.

mod common;

use augsplat_scene::export::ExportFormat;
use augsplat_scene::node::{ExportScene, ExportSceneArgs, ImportScene, ImportSceneArgs};
use common::{run_node, small_synthetic};
use std::path::{Path, PathBuf};

/// Encodes the image at `png` as a quality-90 JPEG `jpg`.
fn encode_jpeg(png: &Path, jpg: &Path) {
    let img = augsplat_core::image::read_rgb(png).unwrap();
    let rgb8: Vec<u8> = img
        .data
        .iter()
        .map(|&v| augsplat_core::image::to_u8(v))
        .collect();
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 90)
        .encode(&rgb8, img.width, img.height, image::ExtendedColorType::Rgb8)
        .unwrap();
    std::fs::write(jpg, bytes).unwrap();
}

/// Cuts `path` to 60 % of its bytes; with `mend`, appends the JPEG end marker FF D9.
fn cut(path: &Path, mend: bool) {
    let bytes = std::fs::read(path).unwrap();
    let mut out = bytes[..bytes.len() * 6 / 10].to_vec();
    if mend {
        out.extend_from_slice(&[0xff, 0xd9]);
    }
    std::fs::write(path, out).unwrap();
}

/// Replaces `from` by `to` in the text file `path`.
fn edit(path: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains(from), "{} lacks {from}", path.display());
    std::fs::write(path, text.replace(from, to)).unwrap();
}

fn import(src: &Path, args: &ImportSceneArgs, root: &Path) -> Result<(), String> {
    run_node::<ImportScene>(args, &[("source", src)], root, 1).map_err(|e| e.message().to_string())
}

fn sorted_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    files
}

/// Exports a generated scene as `format` into `dir`, with its first photo re-encoded as a JPEG
/// (the model refers to it by its new name). Returns the source folder and the JPEG's and the
/// second photo's (a PNG) file names.
fn source_with_a_jpeg(tmp: &Path, name: &str, format: ExportFormat) -> (PathBuf, String, String) {
    let syn = small_synthetic(&tmp.join(name), 3);
    let root = tmp.join(name).join("e");
    run_node::<ExportScene>(&ExportSceneArgs { format }, &[("scene", &syn)], &root, 1).unwrap();
    let src = root.join("export");
    let images = sorted_files(&src.join("images"));
    let png = images[0].clone();
    let stem = png.file_stem().unwrap().to_string_lossy().into_owned();
    let jpg = png.with_extension("jpg");
    encode_jpeg(&png, &jpg);
    std::fs::remove_file(&png).unwrap();
    let model = match format {
        ExportFormat::Transforms => src.join("transforms.json"),
        _ => src.join("sparse/0/images.txt"),
    };
    edit(&model, &format!("{stem}.png"), &format!("{stem}.jpg"));
    let second = images[1]
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    (src, format!("{stem}.jpg"), second)
}

/// A copy of `src` in `dst` with `file` under `images/` cut (`mend`: FF D9 appended).
fn with_cut(src: &Path, dst: &Path, file: &str, mend: bool) -> PathBuf {
    augsplat_testkit::copy_dir(src, dst);
    cut(&dst.join("images").join(file), mend);
    dst.to_path_buf()
}

fn assert_refused(src: &Path, args: &ImportSceneArgs, root: &Path, file: &str, what: &str) {
    let e = match import(src, args, root) {
        Ok(()) => panic!("{what}: the import read a cut {file}"),
        Err(e) => e,
    };
    assert!(
        e.contains(file) && (e.contains("truncated") || e.contains("cut short")),
        "{what}: {e}"
    );
}

#[test]
fn colmap_and_transforms_refuse_cut_jpegs_and_pngs() {
    let tmp = tempfile::tempdir().unwrap();
    for (format, name) in [
        (ExportFormat::ColmapText, "colmap"),
        (ExportFormat::Transforms, "transforms"),
    ] {
        let (src, jpg, png) = source_with_a_jpeg(tmp.path(), name, format);
        let args = ImportSceneArgs::default();
        let out = tmp.path().join(name).join("whole");
        import(&src, &args, &out).unwrap_or_else(|e| panic!("{name}: {e}"));
        let n = augsplat_core::Scene::load(&out.join("scene"))
            .unwrap()
            .views
            .len();
        assert_eq!(n, 3, "{name}");

        let mended = with_cut(&src, &tmp.path().join(name).join("mended"), &jpg, true);
        let root = tmp.path().join(name).join("o1");
        assert_refused(&mended, &args, &root, &jpg, name);

        let cut_png = with_cut(&src, &tmp.path().join(name).join("cutpng"), &png, false);
        let root = tmp.path().join(name).join("o2");
        assert_refused(&cut_png, &args, &root, &png, name);
    }
}

/// An LLFF `poses_bounds.npy` for `n` views of `w`×`h` pixels looking down +z from z = −3.
fn write_poses_bounds(path: &Path, n: usize, w: u32, h: u32) {
    let mut data = Vec::with_capacity(n * 17);
    for i in 0..n {
        // Row-major 3×5 [down | right | back | t | hwf]: the OpenCV rotation is the identity.
        let (h, w, f) = (h as f32, w as f32, w as f32);
        data.extend_from_slice(&[0.0, 1.0, 0.0, 0.2 * i as f32, h]);
        data.extend_from_slice(&[1.0, 0.0, 0.0, 0.0, w]);
        data.extend_from_slice(&[0.0, 0.0, -1.0, -3.0, f]);
        data.extend_from_slice(&[1.0, 10.0]);
    }
    let img = augsplat_core::ImageF32::from_vec(17, n as u32, 1, data);
    augsplat_core::image::write_npy(path, &img).unwrap();
}

/// Checks an LLFF source whose photos (`images/`) are `files`: it imports whole, and is
/// refused with `files[1]` cut (JPEGs with FF D9 appended).
fn check_llff(tmp: &Path, files: &[PathBuf], what: &str) {
    let src = tmp.join(what).join("src");
    let images = src.join("images");
    std::fs::create_dir_all(&images).unwrap();
    for f in files {
        std::fs::copy(f, images.join(f.file_name().unwrap())).unwrap();
    }
    let (w, h) = augsplat_core::image::image_size(&files[0]).unwrap();
    write_poses_bounds(&src.join("poses_bounds.npy"), files.len(), w, h);
    let args = ImportSceneArgs {
        llff_factor: 1,
        ..Default::default()
    };
    import(&src, &args, &tmp.join(what).join("whole")).unwrap_or_else(|e| panic!("{what}: {e}"));
    let name = files[1].file_name().unwrap().to_string_lossy().into_owned();
    let jpeg = name.to_lowercase().ends_with(".jpg");
    let bad = with_cut(&src, &tmp.join(what).join("cut"), &name, jpeg);
    assert_refused(&bad, &args, &tmp.join(what).join("o"), &name, what);
}

#[test]
fn llff_refuses_a_cut_jpeg_or_png() {
    let tmp = tempfile::tempdir().unwrap();
    let syn = small_synthetic(tmp.path(), 3);
    let pngs = sorted_files(&syn.join("images"));
    let jpgs_dir = tmp.path().join("jpgs");
    std::fs::create_dir_all(&jpgs_dir).unwrap();
    let jpgs: Vec<PathBuf> = pngs
        .iter()
        .map(|p| {
            let j = jpgs_dir.join(p.with_extension("jpg").file_name().unwrap());
            encode_jpeg(p, &j);
            j
        })
        .collect();
    check_llff(tmp.path(), &jpgs, "llff-jpeg");
    check_llff(tmp.path(), &pngs, "llff-png");
}

/// Real camera JPEGs (bonsai's photos): two import whole; cut at 60 % with FF D9 appended,
/// one is refused. Skips with a message where the shared data folder is absent.
#[test]
fn llff_refuses_a_cut_real_photo() {
    let Some(data) = common::data_dir("llff_refuses_a_cut_real_photo") else {
        return;
    };
    let dir = data.join("bonsai/images");
    if !dir.is_dir() {
        augsplat_testkit::skip("llff_refuses_a_cut_real_photo", "no bonsai/images");
        return;
    }
    let files: Vec<PathBuf> = sorted_files(&dir).into_iter().take(2).collect();
    let tmp = tempfile::tempdir().unwrap();
    check_llff(tmp.path(), &files, "bonsai");
}
