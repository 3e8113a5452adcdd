//! COLMAP's binary form: `cameras.bin`, `images.bin`, `points3D.bin`.

use super::{check_point, make_camera, make_image, ColmapModel, ColmapPoint};
use crate::error::{Result, SceneError};
use crate::intrinsics::ModelKind;
use std::path::{Path, PathBuf};

impl ColmapModel {
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
}

fn write_bytes(path: &Path, b: &[u8]) -> Result<()> {
    std::fs::write(path, b).map_err(|e| SceneError::io(path, e))
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
