//! COLMAP's text form: `cameras.txt`, `images.txt`, `points3D.txt`.

use super::{check_point, make_camera, make_image, ColmapModel, ColmapPoint};
use crate::error::{Result, SceneError};
use crate::intrinsics::ModelKind;
use std::fmt::Write as _;
use std::path::Path;

impl ColmapModel {
    /// Reads `cameras.txt`, `images.txt`, `points3D.txt`.
    pub fn load_text(dir: &Path) -> Result<ColmapModel> {
        let mut model = ColmapModel::default();
        // cameras.txt
        let path = dir.join("cameras.txt");
        let text = read_text(&path)?;
        for (ln, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let at = |m: String| SceneError::format(&path, format!("line {}: {m}", ln + 1));
            let tok: Vec<&str> = line.split_whitespace().collect();
            if tok.len() < 4 {
                return Err(at(format!(
                    "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS…, found `{line}`"
                )));
            }
            let id: i64 = parse(tok[0]).map_err(&at)?;
            let kind = ModelKind::from_colmap_name(tok[1]).ok_or_else(|| {
                at(format!(
                    "camera {id}: unknown or unsupported camera model `{}` \
                     (supported: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV)",
                    tok[1]
                ))
            })?;
            let width: u64 = parse(tok[2]).map_err(&at)?;
            let height: u64 = parse(tok[3]).map_err(&at)?;
            let params = tok[4..]
                .iter()
                .map(|t| parse::<f64>(t))
                .collect::<std::result::Result<Vec<_>, _>>()
                .map_err(&at)?;
            let cam = make_camera(&path, id, kind, width, height, &params)
                .map_err(|e| at(strip_path(e, &path)))?;
            model.cameras.insert(cam.id, cam);
        }
        // images.txt: two lines per image (the second may be empty).
        let path = dir.join("images.txt");
        let text = read_text(&path)?;
        let lines: Vec<&str> = text.lines().collect();
        let mut i = 0;
        while i < lines.len() {
            let line = lines[i].trim();
            let ln = i + 1;
            i += 1;
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let at = |m: String| SceneError::format(&path, format!("line {ln}: {m}"));
            let tok: Vec<&str> = line.split_whitespace().collect();
            if tok.len() < 10 {
                return Err(at(format!(
                    "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, found `{line}`"
                )));
            }
            let id: i64 = parse(tok[0]).map_err(&at)?;
            let mut v = [0.0; 7];
            for (k, t) in tok[1..8].iter().enumerate() {
                v[k] = parse(t).map_err(&at)?;
            }
            let camera_id: i64 = parse(tok[8]).map_err(&at)?;
            let name = tok[9..].join(" ");
            let mut points2d = Vec::new();
            if i < lines.len() && !lines[i].trim_start().starts_with('#') {
                let pl = lines[i];
                let pln = i + 1;
                i += 1;
                let pt: Vec<&str> = pl.split_whitespace().collect();
                if !pt.len().is_multiple_of(3) {
                    return Err(SceneError::format(
                        &path,
                        format!("line {pln}: image {id} ({name}): POINTS2D has {} values, not a multiple of 3", pt.len()),
                    ));
                }
                let atp = |m: String| {
                    SceneError::format(&path, format!("line {pln}: image {id} ({name}): {m}"))
                };
                points2d.reserve(pt.len() / 3);
                for c in pt.chunks_exact(3) {
                    let x: f64 = parse(c[0]).map_err(&atp)?;
                    let y: f64 = parse(c[1]).map_err(&atp)?;
                    let pid: i64 = parse(c[2]).map_err(&atp)?;
                    points2d.push(([x, y], pid));
                }
            }
            let img = make_image(
                &path,
                id,
                [v[0], v[1], v[2], v[3]],
                [v[4], v[5], v[6]],
                camera_id,
                name,
                points2d,
            )
            .map_err(|e| at(strip_path(e, &path)))?;
            model.images.insert(img.id, img);
        }
        // points3D.txt
        let path = dir.join("points3D.txt");
        let text = read_text(&path)?;
        for (ln, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let at = |m: String| SceneError::format(&path, format!("line {}: {m}", ln + 1));
            let tok: Vec<&str> = line.split_whitespace().collect();
            if tok.len() < 8 || !(tok.len() - 8).is_multiple_of(2) {
                return Err(at(
                    "expected POINT3D_ID X Y Z R G B ERROR followed by (IMAGE_ID, POINT2D_IDX) pairs".into(),
                ));
            }
            let id: u64 = parse(tok[0]).map_err(&at)?;
            let xyz = [
                parse(tok[1]).map_err(&at)?,
                parse(tok[2]).map_err(&at)?,
                parse(tok[3]).map_err(&at)?,
            ];
            let rgb = [
                parse(tok[4]).map_err(&at)?,
                parse(tok[5]).map_err(&at)?,
                parse(tok[6]).map_err(&at)?,
            ];
            let error: f64 = parse(tok[7]).map_err(&at)?;
            let track = tok[8..]
                .chunks_exact(2)
                .map(|c| Ok((parse(c[0])?, parse(c[1])?)))
                .collect::<std::result::Result<Vec<(u32, u32)>, String>>()
                .map_err(&at)?;
            check_point(&path, id, xyz).map_err(|e| at(strip_path(e, &path)))?;
            model.points.push(ColmapPoint {
                id,
                xyz,
                rgb,
                error,
                track,
            });
        }
        Ok(model)
    }

    /// Writes the model as COLMAP text files into `dir` (which must exist).
    pub fn save_text(&self, dir: &Path) -> Result<()> {
        let mut s = String::new();
        s.push_str("# Camera list with one line of data per camera:\n");
        s.push_str("#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
        let _ = writeln!(s, "# Number of cameras: {}", self.cameras.len());
        for cam in self.cameras.values() {
            let i = &cam.intrinsics;
            let _ = write!(
                s,
                "{} {} {} {}",
                cam.id,
                i.kind.colmap_name(),
                i.width,
                i.height
            );
            for p in i.colmap_params() {
                let _ = write!(s, " {p:?}");
            }
            s.push('\n');
        }
        write_text(&dir.join("cameras.txt"), &s)?;

        let mut s = String::new();
        s.push_str("# Image list with two lines of data per image:\n");
        s.push_str("#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n");
        s.push_str("#   POINTS2D[] as (X, Y, POINT3D_ID)\n");
        let _ = writeln!(s, "# Number of images: {}", self.images.len());
        for img in self.images.values() {
            let q = img.qvec;
            let t = img.tvec;
            let _ = writeln!(
                s,
                "{} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {} {}",
                img.id, q[0], q[1], q[2], q[3], t[0], t[1], t[2], img.camera_id, img.name
            );
            let mut first = true;
            for (xy, pid) in &img.points2d {
                if !first {
                    s.push(' ');
                }
                first = false;
                let _ = write!(s, "{:?} {:?} {}", xy[0], xy[1], pid);
            }
            s.push('\n');
        }
        write_text(&dir.join("images.txt"), &s)?;

        let mut s = String::new();
        s.push_str("# 3D point list with one line of data per point:\n");
        s.push_str("#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n");
        let _ = writeln!(s, "# Number of points: {}", self.points.len());
        for p in &self.points {
            let _ = write!(
                s,
                "{} {:?} {:?} {:?} {} {} {} {:?}",
                p.id, p.xyz[0], p.xyz[1], p.xyz[2], p.rgb[0], p.rgb[1], p.rgb[2], p.error
            );
            for (iid, idx) in &p.track {
                let _ = write!(s, " {iid} {idx}");
            }
            s.push('\n');
        }
        write_text(&dir.join("points3D.txt"), &s)
    }
}

/// Removes a leading "<path>: " from an error's text (to re-wrap it with a line number).
fn strip_path(e: SceneError, path: &Path) -> String {
    let s = e.to_string();
    let prefix = format!("{}: ", path.display());
    s.strip_prefix(&prefix).map(str::to_string).unwrap_or(s)
}

fn parse<T: std::str::FromStr>(t: &str) -> std::result::Result<T, String> {
    t.parse::<T>()
        .map_err(|_| format!("cannot parse `{t}` as {}", std::any::type_name::<T>()))
}

fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| SceneError::io(path, e))
}

fn write_text(path: &Path, s: &str) -> Result<()> {
    std::fs::write(path, s).map_err(|e| SceneError::io(path, e))
}
