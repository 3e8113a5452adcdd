//! COLMAP sparse models: reading the binary (`cameras.bin`, `images.bin`, `points3D.bin`) and
//! text (`*.txt`) forms, writing the text form, and COLMAP's mean reprojection error.
//!
//! COLMAP stores world-to-camera poses as a unit quaternion (qw, qx, qy, qz) and a translation,
//! OpenCV camera axes, pixel centres at +0.5 — the same conventions as augsplat's [`Camera`].
//!
//! [`Camera`]: augsplat_core::Camera

use crate::error::{Result, SceneError};
use crate::intrinsics::{Intrinsics, ModelKind};
use augsplat_core::linalg::{self, Mat4};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One COLMAP camera (intrinsics shared by images).
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// Camera id.
    pub id: u32,
    /// Model, size and parameters.
    pub intrinsics: Intrinsics,
}

/// One registered image.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// Image id.
    pub id: u32,
    /// World-to-camera rotation as (qw, qx, qy, qz).
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    /// The camera it uses.
    pub camera_id: u32,
    /// File name relative to the images folder.
    pub name: String,
    /// 2D keypoints (x, y in pixels) and the 3D point each belongs to (-1 for none).
    pub points2d: Vec<([f64; 2], i64)>,
}

impl ColmapImage {
    /// The world-to-camera 4×4 transform.
    pub fn world_to_camera(&self) -> Mat4 {
        linalg::mat4_from_rt(&linalg::quat_to_mat3(self.qvec), self.tvec)
    }
}

/// One 3D point with its track.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    /// Point id.
    pub id: u64,
    /// Position (model frame).
    pub xyz: [f64; 3],
    /// Colour.
    pub rgb: [u8; 3],
    /// Mean reprojection error COLMAP stored, pixels.
    pub error: f64,
    /// Observations: (image id, index into that image's `points2d`).
    pub track: Vec<(u32, u32)>,
}

/// A whole sparse model.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColmapModel {
    /// Cameras by id.
    pub cameras: BTreeMap<u32, ColmapCamera>,
    /// Registered images by id.
    pub images: BTreeMap<u32, ColmapImage>,
    /// Points, sorted by id by [`ColmapModel::load`] (file order from the format readers).
    pub points: Vec<ColmapPoint>,
}

/// Whether `dir` holds a COLMAP model (binary or text).
pub fn is_model_dir(dir: &Path) -> bool {
    dir.join("cameras.bin").is_file() || dir.join("cameras.txt").is_file()
}

impl ColmapModel {
    /// Reads a model folder: binary if `cameras.bin` exists, else text.
    pub fn load(dir: &Path) -> Result<ColmapModel> {
        if !dir.is_dir() {
            return Err(SceneError::missing(dir, "COLMAP model folder"));
        }
        let model = if dir.join("cameras.bin").is_file() {
            ColmapModel::load_binary(dir)?
        } else if dir.join("cameras.txt").is_file() {
            ColmapModel::load_text(dir)?
        } else {
            return Err(SceneError::missing(
                &dir.join("cameras.bin"),
                "COLMAP cameras file (cameras.bin or cameras.txt)",
            ));
        };
        model.check_references(dir)?;
        let mut model = model;
        model.points.sort_by_key(|p| p.id);
        Ok(model)
    }

    /// Reads `cameras.bin`, `images.bin`, `points3D.bin`.
    pub fn load_binary(dir: &Path) -> Result<ColmapModel> {
        let mut model = ColmapModel::default();
        // cameras.bin
        let path = dir.join("cameras.bin");
        let mut r = BinReader::open(&path)?;
        let n = r.u64("number of cameras")?;
        for k in 0..n {
            let what = format!("camera entry {k}");
            let id = r.i32(&what)?;
            let model_id = r.i32(&what)?;
            let width = r.u64(&what)?;
            let height = r.u64(&what)?;
            let kind = ModelKind::from_colmap_id(model_id).ok_or_else(|| {
                SceneError::format(
                    &path,
                    format!(
                        "camera {id}: unknown or unsupported camera model id {model_id} \
                         (supported: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV)"
                    ),
                )
            })?;
            let mut params = Vec::with_capacity(kind.param_count());
            for _ in 0..kind.param_count() {
                params.push(r.f64(&what)?);
            }
            let cam = make_camera(&path, id as i64, kind, width, height, &params)?;
            model.cameras.insert(cam.id, cam);
        }
        r.finish()?;
        // images.bin
        let path = dir.join("images.bin");
        let mut r = BinReader::open(&path)?;
        let n = r.u64("number of images")?;
        for k in 0..n {
            let what = format!("image entry {k}");
            let id = r.i32(&what)?;
            let mut qvec = [0.0; 4];
            for q in &mut qvec {
                *q = r.f64(&what)?;
            }
            let mut tvec = [0.0; 3];
            for t in &mut tvec {
                *t = r.f64(&what)?;
            }
            let camera_id = r.i32(&what)?;
            let name = r.cstring(&what)?;
            let what = format!("image entry {k} (id {id}, {name})");
            let np = r.u64(&what)?;
            if np > r.remaining() as u64 / 24 {
                return Err(r.truncated(&what));
            }
            let mut points2d = Vec::with_capacity(np as usize);
            for _ in 0..np {
                let x = r.f64(&what)?;
                let y = r.f64(&what)?;
                let pid = r.i64(&what)?;
                points2d.push(([x, y], pid));
            }
            let img = make_image(
                &path,
                id as i64,
                qvec,
                tvec,
                camera_id as i64,
                name,
                points2d,
            )?;
            model.images.insert(img.id, img);
        }
        r.finish()?;
        // points3D.bin
        let path = dir.join("points3D.bin");
        let mut r = BinReader::open(&path)?;
        let n = r.u64("number of points")?;
        for k in 0..n {
            let what = format!("point entry {k}");
            let id = r.u64(&what)?;
            let mut xyz = [0.0; 3];
            for v in &mut xyz {
                *v = r.f64(&what)?;
            }
            let rgb = [r.u8(&what)?, r.u8(&what)?, r.u8(&what)?];
            let error = r.f64(&what)?;
            let what = format!("point entry {k} (id {id})");
            let nt = r.u64(&what)?;
            if nt > r.remaining() as u64 / 8 {
                return Err(r.truncated(&what));
            }
            let mut track = Vec::with_capacity(nt as usize);
            for _ in 0..nt {
                let img = r.i32(&what)?;
                let idx = r.i32(&what)?;
                if img < 0 || idx < 0 {
                    return Err(SceneError::format(
                        &path,
                        format!("point {id}: negative track entry ({img}, {idx})"),
                    ));
                }
                track.push((img as u32, idx as u32));
            }
            check_point(&path, id, xyz)?;
            model.points.push(ColmapPoint {
                id,
                xyz,
                rgb,
                error,
                track,
            });
        }
        r.finish()?;
        Ok(model)
    }

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

    /// Checks that images name existing cameras and tracks name existing images/keypoints.
    fn check_references(&self, dir: &Path) -> Result<()> {
        for img in self.images.values() {
            if !self.cameras.contains_key(&img.camera_id) {
                return Err(SceneError::format(
                    dir.join("images"),
                    format!(
                        "image {} ({}) uses camera {}, which the model does not have",
                        img.id, img.name, img.camera_id
                    ),
                ));
            }
        }
        for p in &self.points {
            for &(iid, idx) in &p.track {
                let ok = self.images.get(&iid).is_some_and(|img| {
                    (idx as usize) < img.points2d.len() || img.points2d.is_empty()
                });
                if !ok {
                    return Err(SceneError::format(
                        dir.join("points3D"),
                        format!("point {}: track names image {iid} keypoint {idx}, which does not exist", p.id),
                    ));
                }
            }
        }
        Ok(())
    }

    /// COLMAP's mean reprojection error: for each point with at least one observation whose
    /// keypoint is known, the mean distance (pixels) between its projection (with distortion)
    /// and the keypoint; then the mean over those points. Returns (error, number of points,
    /// number of observations), or `None` when no observation has a keypoint.
    pub fn mean_reprojection_error(&self) -> Option<(f64, usize, usize)> {
        let mut sum = 0.0;
        let mut npts = 0usize;
        let mut nobs = 0usize;
        for p in &self.points {
            let mut s = 0.0;
            let mut n = 0usize;
            for &(iid, idx) in &p.track {
                let Some(img) = self.images.get(&iid) else {
                    continue;
                };
                let Some(&(xy, _)) = img.points2d.get(idx as usize) else {
                    continue;
                };
                let cam = &self.cameras[&img.camera_id].intrinsics;
                let w2c = img.world_to_camera();
                let pc = transform(&w2c, p.xyz);
                let Some((u, v)) = cam.project_camera_point(pc) else {
                    continue;
                };
                s += ((u - xy[0]).powi(2) + (v - xy[1]).powi(2)).sqrt();
                n += 1;
            }
            if n > 0 {
                sum += s / n as f64;
                npts += 1;
                nobs += n;
            }
        }
        (npts > 0).then(|| (sum / npts as f64, npts, nobs))
    }

    /// Writes the model as COLMAP binary files into `dir` (which must exist).
    pub fn save_binary(&self, dir: &Path) -> Result<()> {
        let m = self;
        let mut b = Vec::new();
        b.extend((m.cameras.len() as u64).to_le_bytes());
        for c in m.cameras.values() {
            b.extend((c.id as i32).to_le_bytes());
            b.extend(c.intrinsics.kind.colmap_id().to_le_bytes());
            b.extend((c.intrinsics.width as u64).to_le_bytes());
            b.extend((c.intrinsics.height as u64).to_le_bytes());
            for p in c.intrinsics.colmap_params() {
                b.extend(p.to_le_bytes());
            }
        }
        write_bytes(&dir.join("cameras.bin"), &b)?;
        let mut b = Vec::new();
        b.extend((m.images.len() as u64).to_le_bytes());
        for i in m.images.values() {
            b.extend((i.id as i32).to_le_bytes());
            for v in i.qvec.iter().chain(&i.tvec) {
                b.extend(v.to_le_bytes());
            }
            b.extend((i.camera_id as i32).to_le_bytes());
            b.extend(i.name.as_bytes());
            b.push(0);
            b.extend((i.points2d.len() as u64).to_le_bytes());
            for (xy, pid) in &i.points2d {
                b.extend(xy[0].to_le_bytes());
                b.extend(xy[1].to_le_bytes());
                b.extend(pid.to_le_bytes());
            }
        }
        write_bytes(&dir.join("images.bin"), &b)?;
        let mut b = Vec::new();
        b.extend((m.points.len() as u64).to_le_bytes());
        for p in &m.points {
            b.extend(p.id.to_le_bytes());
            for v in p.xyz {
                b.extend(v.to_le_bytes());
            }
            b.extend(p.rgb);
            b.extend(p.error.to_le_bytes());
            b.extend((p.track.len() as u64).to_le_bytes());
            for (i, k) in &p.track {
                b.extend((*i as i32).to_le_bytes());
                b.extend((*k as i32).to_le_bytes());
            }
        }
        write_bytes(&dir.join("points3D.bin"), &b)
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

/// Applies a rigid 4×4 transform to a point.
pub(crate) fn transform(m: &Mat4, p: [f64; 3]) -> [f64; 3] {
    let (r, t) = linalg::rt_from_mat4(m);
    linalg::add(linalg::mat3_vec(&r, p), t)
}

fn make_camera(
    path: &Path,
    id: i64,
    kind: ModelKind,
    width: u64,
    height: u64,
    params: &[f64],
) -> Result<ColmapCamera> {
    let bad = |m: String| SceneError::format(path, format!("camera {id}: {m}"));
    let id = u32::try_from(id).map_err(|_| bad("id out of range".into()))?;
    let (w, h) = (
        u32::try_from(width).map_err(|_| bad(format!("width {width} out of range")))?,
        u32::try_from(height).map_err(|_| bad(format!("height {height} out of range")))?,
    );
    let intrinsics = Intrinsics::from_colmap(kind, w, h, params).map_err(bad)?;
    Ok(ColmapCamera { id, intrinsics })
}

fn make_image(
    path: &Path,
    id: i64,
    qvec: [f64; 4],
    tvec: [f64; 3],
    camera_id: i64,
    name: String,
    points2d: Vec<([f64; 2], i64)>,
) -> Result<ColmapImage> {
    let bad = |m: String| SceneError::format(path, format!("image {id} ({name}): {m}"));
    let uid = u32::try_from(id).map_err(|_| bad("id out of range".into()))?;
    let cid =
        u32::try_from(camera_id).map_err(|_| bad(format!("camera id {camera_id} out of range")))?;
    if qvec.iter().chain(&tvec).any(|v| !v.is_finite()) {
        return Err(bad(format!(
            "pose contains a non-finite value (q {qvec:?}, t {tvec:?})"
        )));
    }
    let qn = qvec.iter().map(|v| v * v).sum::<f64>().sqrt();
    if qn.is_nan() || qn <= 1e-6 {
        return Err(bad("rotation quaternion is zero".into()));
    }
    if name.is_empty() {
        return Err(bad("empty image name".into()));
    }
    if points2d
        .iter()
        .any(|(xy, _)| !xy[0].is_finite() || !xy[1].is_finite())
    {
        return Err(bad("a keypoint position is not finite".into()));
    }
    Ok(ColmapImage {
        id: uid,
        qvec,
        tvec,
        camera_id: cid,
        name,
        points2d,
    })
}

fn check_point(path: &Path, id: u64, xyz: [f64; 3]) -> Result<()> {
    if xyz.iter().any(|v| !v.is_finite()) {
        return Err(SceneError::format(
            path,
            format!("point {id}: position {xyz:?} is not finite"),
        ));
    }
    Ok(())
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

fn write_bytes(path: &Path, b: &[u8]) -> Result<()> {
    std::fs::write(path, b).map_err(|e| SceneError::io(path, e))
}

fn write_text(path: &Path, s: &str) -> Result<()> {
    std::fs::write(path, s).map_err(|e| SceneError::io(path, e))
}

/// A little-endian cursor over a binary model file that reports truncation with the entry.
struct BinReader {
    path: PathBuf,
    bytes: Vec<u8>,
    pos: usize,
}

impl BinReader {
    fn open(path: &Path) -> Result<BinReader> {
        let bytes = std::fs::read(path).map_err(|e| SceneError::io(path, e))?;
        Ok(BinReader {
            path: path.to_path_buf(),
            bytes,
            pos: 0,
        })
    }
    fn remaining(&self) -> usize {
        self.bytes.len() - self.pos
    }
    fn truncated(&self, what: &str) -> SceneError {
        SceneError::format(
            &self.path,
            format!(
                "truncated binary model: ran out of data at byte {} of {} while reading {what}",
                self.pos,
                self.bytes.len()
            ),
        )
    }
    fn take<const N: usize>(&mut self, what: &str) -> Result<[u8; N]> {
        let s = self
            .bytes
            .get(self.pos..self.pos + N)
            .ok_or_else(|| self.truncated(what))?;
        self.pos += N;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }
    fn u8(&mut self, what: &str) -> Result<u8> {
        Ok(self.take::<1>(what)?[0])
    }
    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(what)?))
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(what)?))
    }
    fn i64(&mut self, what: &str) -> Result<i64> {
        Ok(i64::from_le_bytes(self.take(what)?))
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(what)?))
    }
    fn cstring(&mut self, what: &str) -> Result<String> {
        let rest = &self.bytes[self.pos..];
        let end = rest
            .iter()
            .position(|&b| b == 0)
            .ok_or_else(|| self.truncated(what))?;
        let s = String::from_utf8_lossy(&rest[..end]).into_owned();
        self.pos += end + 1;
        Ok(s)
    }
    fn finish(&self) -> Result<()> {
        if self.pos != self.bytes.len() {
            return Err(SceneError::format(
                &self.path,
                format!(
                    "{} unexpected bytes after the last entry",
                    self.bytes.len() - self.pos
                ),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
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
}
