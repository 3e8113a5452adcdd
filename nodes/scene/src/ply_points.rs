//! Sparse points kept in a PLY file beside a capture — nerfstudio's `ns-process-data` writes
//! its COLMAP points as `sparse_pc.ply` and names it in `transforms.json` (`ply_file_path`),
//! in the transforms' own frame — and their tracks.
//!
//! **Reading:** `ascii 1.0` and `binary_little_endian 1.0`; the `vertex` element's `x y z`
//! (float or double) and, when present, `red green blue` (uchar, or float in [0, 1]); other
//! vertex properties of any scalar type are skipped; elements after `vertex` are ignored.
//!
//! **Tracks:** a PLY stores no observations, but the split and `SparseDepth` need to know which
//! views see a point. A point is taken as seen by a view when it projects inside the image in
//! front of the camera and is not hidden: within [`OCCLUSION_TOLERANCE`] of the nearest point's
//! depth in its cell (the points themselves as a coarse depth buffer, so a surface's front
//! hides its back). Cells are sized to the points: about [`POINTS_PER_CELL`] of the points
//! inside the image per cell, so a sparse cloud's gaps do not let hidden points through.

use crate::error::{Result, SceneError};
use crate::source::{Observation, RawView};
use augsplat_core::linalg::Vec3;
use std::io::Write;
use std::path::Path;

/// Points per depth-buffer cell of the visibility test, on average over the image.
pub const POINTS_PER_CELL: f64 = 4.0;
/// A point is visible when its depth is at most `1 +` this times the cell's nearest depth.
pub const OCCLUSION_TOLERANCE: f64 = 0.05;

/// Points read from a PLY file: positions and colours in [0, 1] (grey 0.5 when the file has
/// none).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlyPoints {
    /// Positions in the file's frame.
    pub positions: Vec<Vec3>,
    /// RGB colours in [0, 1].
    pub colors: Vec<[f32; 3]>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
    fn read_le(self, b: &[u8]) -> f64 {
        match self {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(b[..8].try_into().unwrap_or([0; 8])),
        }
    }
}

/// Reads the points of a PLY file (see the module docs).
pub fn read_points_ply(path: &Path) -> Result<PlyPoints> {
    let bytes = std::fs::read(path).map_err(|e| SceneError::io(path, e))?;
    let bad = |m: String| SceneError::format(path, m);
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .ok_or_else(|| bad("not a PLY file: no `end_header` line".into()))?;
    let header =
        std::str::from_utf8(&bytes[..end]).map_err(|_| bad("the header is not text".into()))?;
    let body = &bytes[end + 11..];
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err(bad("not a PLY file: it does not start with `ply`".into()));
    }
    let mut binary = None;
    let mut count = None;
    let mut props: Vec<(String, Scalar)> = Vec::new();
    let mut in_vertex = false;
    let mut before_vertex = false;
    for (no, line) in lines.enumerate() {
        let words: Vec<&str> = line.split_whitespace().collect();
        let at = |m: &str| bad(format!("header line {}: {m}: `{line}`", no + 2));
        match words.as_slice() {
            ["format", "ascii", _] => binary = Some(false),
            ["format", "binary_little_endian", _] => binary = Some(true),
            ["format", f, _] => {
                return Err(at(&format!(
                    "format {f} is not supported (ascii or binary_little_endian)"
                )))
            }
            ["element", "vertex", n] => {
                count = Some(n.parse::<usize>().map_err(|_| at("bad vertex count"))?);
                in_vertex = true;
            }
            ["element", ..] => {
                if count.is_none() {
                    before_vertex = true;
                }
                in_vertex = false;
            }
            ["property", "list", ..] if in_vertex => {
                return Err(at("list properties on vertices are not supported"))
            }
            ["property", ty, name] if in_vertex => {
                let s = Scalar::parse(ty).ok_or_else(|| at("unknown property type"))?;
                props.push((name.to_string(), s));
            }
            _ => {}
        }
    }
    let binary = binary.ok_or_else(|| bad("no `format` line".into()))?;
    let n = count.ok_or_else(|| bad("no `element vertex`".into()))?;
    if before_vertex {
        return Err(bad(
            "an element comes before `vertex`; only files whose first element is `vertex` are read"
                .into(),
        ));
    }
    let find = |name: &str| props.iter().position(|(p, _)| p == name);
    let (xi, yi, zi) = match (find("x"), find("y"), find("z")) {
        (Some(x), Some(y), Some(z)) => (x, y, z),
        _ => return Err(bad("the vertices have no x, y, z".into())),
    };
    let rgb = match (find("red"), find("green"), find("blue")) {
        (Some(r), Some(g), Some(b)) => Some([r, g, b]),
        _ => None,
    };
    let mut values = vec![0f64; props.len()];
    let mut out = PlyPoints::default();
    let mut text = if binary {
        None
    } else {
        Some(
            std::str::from_utf8(body)
                .map_err(|_| bad("the ASCII body is not text".into()))?
                .lines(),
        )
    };
    let stride: usize = props.iter().map(|(_, s)| s.size()).sum();
    for i in 0..n {
        match &mut text {
            None => {
                let rec = body
                    .get(i * stride..(i + 1) * stride)
                    .ok_or_else(|| bad(format!("the file ends at vertex {i} of {n}")))?;
                let mut o = 0;
                for (v, (_, s)) in values.iter_mut().zip(&props) {
                    *v = s.read_le(&rec[o..]);
                    o += s.size();
                }
            }
            Some(lines) => {
                let line = lines
                    .next()
                    .ok_or_else(|| bad(format!("the file ends at vertex {i} of {n}")))?;
                let mut words = line.split_whitespace();
                for v in values.iter_mut() {
                    *v = words
                        .next()
                        .and_then(|w| w.parse::<f64>().ok())
                        .ok_or_else(|| bad(format!("vertex {i}: `{line}` has too few numbers")))?;
                }
            }
        }
        let p = [values[xi], values[yi], values[zi]];
        if !p.iter().all(|v| v.is_finite()) {
            return Err(bad(format!("vertex {i}: position {p:?} is not finite")));
        }
        out.positions.push(p);
        out.colors.push(match rgb {
            None => [0.5; 3],
            Some(idx) => idx.map(|k| {
                let v = values[k];
                let v = if props[k].1 == Scalar::F32 || props[k].1 == Scalar::F64 {
                    v
                } else {
                    v / 255.0
                };
                v.clamp(0.0, 1.0) as f32
            }),
        });
    }
    Ok(out)
}

/// Writes points as an ASCII PLY (`x y z` float, `red green blue` uchar), as nerfstudio does.
pub fn write_points_ply(path: &Path, positions: &[Vec3], colors: &[[f32; 3]]) -> Result<()> {
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property uint8 red\nproperty uint8 green\nproperty uint8 blue\nend_header\n",
        positions.len()
    );
    for (p, c) in positions.iter().zip(colors) {
        let c = c.map(augsplat_core::image::to_u8);
        s.push_str(&format!(
            "{} {} {} {} {} {}\n",
            p[0] as f32, p[1] as f32, p[2] as f32, c[0], c[1], c[2]
        ));
    }
    let mut f = std::fs::File::create(path).map_err(|e| SceneError::io(path, e))?;
    f.write_all(s.as_bytes())
        .map_err(|e| SceneError::io(path, e))
}

/// Tracks of points without observations, from visibility in `views` (see the module docs).
pub fn tracks_by_visibility(views: &[RawView], positions: &[Vec3]) -> Vec<Vec<Observation>> {
    let mut tracks = vec![Vec::new(); positions.len()];
    for (vi, v) in views.iter().enumerate() {
        let cam = v.intrinsics.pinhole_camera(v.world_to_camera);
        let (w, h) = (cam.width as f64, cam.height as f64);
        let uvz: Vec<Option<(f64, f64, f64)>> = positions
            .iter()
            .map(|&p| {
                let (u, y, z) = cam.project(p);
                (z > 0.0 && u >= 0.0 && y >= 0.0 && u < w && y < h).then_some((u, y, z))
            })
            .collect();
        let inside = uvz.iter().flatten().count().max(1) as f64;
        let cell_px = (w * h * POINTS_PER_CELL / inside).sqrt().max(1.0);
        let (cw, ch) = ((w / cell_px).ceil() as usize, (h / cell_px).ceil() as usize);
        let mut nearest = vec![f64::INFINITY; cw * ch];
        let projected: Vec<Option<(usize, f64)>> = uvz
            .iter()
            .map(|o| o.map(|(u, y, z)| ((y / cell_px) as usize * cw + (u / cell_px) as usize, z)))
            .collect();
        for &(cell, z) in projected.iter().flatten() {
            nearest[cell] = nearest[cell].min(z);
        }
        for (t, pr) in tracks.iter_mut().zip(&projected) {
            if let Some((cell, z)) = *pr {
                if z <= nearest[cell] * (1.0 + OCCLUSION_TOLERANCE) {
                    t.push(Observation {
                        view: vi,
                        keypoint: None,
                    });
                }
            }
        }
    }
    tracks
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_and_binary_files_read_the_same_points() {
        let dir = tempfile::tempdir().unwrap();
        let pts = vec![[0.5, -1.25, 3.0], [1e-3, 2.0, -4.5]];
        let cols = vec![[1.0, 0.0, 0.5], [0.2, 0.4, 0.6]];
        let a = dir.path().join("a.ply");
        write_points_ply(&a, &pts, &cols).unwrap();
        let read = read_points_ply(&a).unwrap();
        assert_eq!(read.positions, pts);
        for (c, e) in read.colors.iter().zip(&cols) {
            for k in 0..3 {
                assert!((c[k] - e[k]).abs() <= 0.5 / 255.0 + 1e-6, "{c:?} {e:?}");
            }
        }
        // Binary little-endian with doubles, an extra property and no colours.
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty double x\n\
property double y\nproperty double z\nproperty float nx\nend_header\n"
            .to_vec();
        for p in &pts {
            for v in p {
                b.extend(v.to_le_bytes());
            }
            b.extend(1f32.to_le_bytes());
        }
        let bp = dir.path().join("b.ply");
        std::fs::write(&bp, &b).unwrap();
        let read = read_points_ply(&bp).unwrap();
        assert_eq!(read.positions, pts);
        assert_eq!(read.colors, vec![[0.5; 3]; 2]);
        // Cut short: a clear error naming the file.
        std::fs::write(&bp, &b[..b.len() - 3]).unwrap();
        let e = read_points_ply(&bp).unwrap_err().to_string();
        assert!(e.contains("b.ply") && e.contains("ends at vertex 1"), "{e}");
        std::fs::write(
            &bp,
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n",
        )
        .unwrap();
        let e = read_points_ply(&bp).unwrap_err().to_string();
        assert!(e.contains("no x, y, z"), "{e}");
    }
}
