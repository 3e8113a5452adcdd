//! PLY export → import → render is bit-identical; the layout is Inria's; bad files fail
//! with a clear error.
#![allow(clippy::needless_range_loop)]

mod raster_common;

use augsplat_core::FileError;
use augsplat_render::{read_ply, render, write_ply, RenderSettings, SplatError};
use raster_common::*;
use std::io::Write;

#[test]
fn roundtrip_is_bit_identical_for_every_degree() {
    let dir = tempfile::tempdir().unwrap();
    let cam = camera(64, 48);
    for degree in 0..=3 {
        let g = random_scene(degree as u64, 500, degree, &cam, (-3.0, 5.0));
        let path = dir.path().join(format!("d{degree}.ply"));
        write_ply(&path, &g).unwrap();
        let back = read_ply(&path).unwrap();
        assert_eq!(back, g);
        let s = RenderSettings::default();
        let a = render(&g, &cam, &s);
        let b = render(&back, &cam, &s);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a.rgb), bits(&b.rgb));
        assert_eq!(bits(&a.alpha), bits(&b.alpha));
    }
}

#[test]
fn layout_is_inria_channel_major() {
    let dir = tempfile::tempdir().unwrap();
    let cam = camera(8, 8);
    let mut g = random_scene(1, 2, 3, &cam, (0.0, 1.0));
    // Coefficient k = 2 of channel c = 1 of Gaussian 1 must be f_rest_{1·15 + 1} = f_rest_16.
    let k = 16;
    g.sh[(k + 2) * 3 + 1] = 123.5;
    let path = dir.path().join("g.ply");
    write_ply(&path, &g).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    let props: Vec<&str> = header
        .lines()
        .filter_map(|l| l.strip_prefix("property float "))
        .collect();
    assert_eq!(props.len(), 62);
    assert_eq!(
        &props[..9],
        &["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    );
    assert_eq!(props[9], "f_rest_0");
    assert_eq!(
        &props[54..],
        &["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    );
    let col = props.iter().position(|p| *p == "f_rest_16").unwrap();
    let off = end + 4 * (62 + col);
    let v = f32::from_le_bytes(bytes[off..off + 4].try_into().unwrap());
    assert_eq!(v, 123.5);
    let op = end + 4 * (62 + 54);
    assert_eq!(
        f32::from_le_bytes(bytes[op..op + 4].try_into().unwrap()),
        g.opacity_logits[1]
    );
}

#[test]
fn bad_files_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let cam = camera(8, 8);
    let g = random_scene(1, 3, 1, &cam, (0.0, 1.0));
    let path = dir.path().join("g.ply");
    write_ply(&path, &g).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let write = |name: &str, b: &[u8]| {
        let p = dir.path().join(name);
        std::fs::File::create(&p).unwrap().write_all(b).unwrap();
        p
    };
    let truncated = write("t.ply", &bytes[..bytes.len() - 5]);
    let e = read_ply(&truncated).unwrap_err();
    assert!(
        matches!(e, SplatError::File(FileError::Format { .. }))
            && e.to_string().contains("ends at vertex 2"),
        "{e}"
    );
    let ascii = String::from_utf8_lossy(&bytes).replace("binary_little_endian", "ascii");
    let e = read_ply(&write("a.ply", ascii.as_bytes())).unwrap_err();
    assert!(e.to_string().contains("ascii"), "{e}");
    let noop = String::from_utf8_lossy(&bytes).replacen(
        "property float opacity",
        "property float opac",
        1,
    );
    let e = read_ply(&write("o.ply", noop.as_bytes())).unwrap_err();
    assert!(
        e.to_string().contains("missing vertex property `opacity`"),
        "{e}"
    );
    // A header that claims a billion vertices is refused before anything is allocated.
    let huge = String::from_utf8_lossy(&bytes).replacen(
        "element vertex 3",
        "element vertex 1000000000",
        1,
    );
    let t = std::time::Instant::now();
    let e = read_ply(&write("h.ply", huge.as_bytes())).unwrap_err();
    assert!(e.to_string().contains("of 1000000000"), "{e}");
    assert!(t.elapsed() < std::time::Duration::from_secs(1));
    let e = read_ply(&write("n.ply", b"hello")).unwrap_err();
    assert!(e.to_string().contains("not a PLY"), "{e}");
    let e = read_ply(&dir.path().join("absent.ply")).unwrap_err();
    assert!(matches!(e, SplatError::File(FileError::Io { .. })));
}
