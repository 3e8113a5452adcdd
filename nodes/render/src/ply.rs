//! Inria-layout PLY export and import (docs/design.md, *Gaussians and PLY*): binary little-endian float32 vertex
//! properties `x y z nx ny nz f_dc_0..2 f_rest_* opacity scale_0..2 rot_0..3`, raw
//! (pre-activation) values. `f_rest` is channel-major: coefficient k ≥ 1 of channel c is
//! `f_rest_{c·(K−1)+(k−1)}` with K = (degree + 1)². The reader accepts the properties in any
//! order (extra float properties are ignored) and infers the SH degree from the number of
//! `f_rest_*` properties.

use crate::error::SplatError;
use crate::gaussians::{sh_coeffs, Gaussians};
use augsplat_core::FileError;
use std::io::Seek;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::Path;

/// Writes `g` as a binary little-endian float32 PLY in the Inria layout.
pub fn write_ply(path: &Path, g: &Gaussians) -> Result<(), SplatError> {
    let io = |source| SplatError::File(FileError::io(path, source));
    let n = g.len();
    let k = g.coeffs();
    if g.log_scales.len() != n
        || g.quats.len() != n
        || g.opacity_logits.len() != n
        || g.sh.len() != n * k * 3
    {
        return Err(SplatError::Invalid(format!(
            "cannot write {}: inconsistent Gaussian arrays ({} means, {} scales, {} quats, {} opacities, {} SH values for degree {})",
            path.display(),
            n,
            g.log_scales.len(),
            g.quats.len(),
            g.opacity_logits.len(),
            g.sh.len(),
            g.sh_degree
        )));
    }
    let file = std::fs::File::create(path).map_err(io)?;
    let mut w = BufWriter::new(file);
    let mut header = String::new();
    header.push_str("ply\nformat binary_little_endian 1.0\n");
    header.push_str(&format!("element vertex {n}\n"));
    for name in [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ] {
        header.push_str(&format!("property float {name}\n"));
    }
    for j in 0..3 * (k - 1) {
        header.push_str(&format!("property float f_rest_{j}\n"));
    }
    for name in [
        "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
    ] {
        header.push_str(&format!("property float {name}\n"));
    }
    header.push_str("end_header\n");
    w.write_all(header.as_bytes()).map_err(io)?;
    let mut row: Vec<f32> = Vec::with_capacity(17 + 3 * k);
    let mut bytes: Vec<u8> = Vec::with_capacity(4 * (17 + 3 * k));
    for i in 0..n {
        row.clear();
        row.extend_from_slice(&g.means[i]);
        row.extend_from_slice(&[0.0; 3]);
        let sh = g.sh_of(i);
        row.extend_from_slice(&sh[0..3]);
        for c in 0..3 {
            for kk in 1..k {
                row.push(sh[kk * 3 + c]);
            }
        }
        row.push(g.opacity_logits[i]);
        row.extend_from_slice(&g.log_scales[i]);
        row.extend_from_slice(&g.quats[i]);
        bytes.clear();
        for v in &row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        w.write_all(&bytes).map_err(io)?;
    }
    w.flush().map_err(io)?;
    Ok(())
}

/// Reads an Inria-layout PLY (binary little-endian, float32 vertex properties).
pub fn read_ply(path: &Path) -> Result<Gaussians, SplatError> {
    let io = |source| SplatError::File(FileError::io(path, source));
    let bad = |message: String| SplatError::File(FileError::format(path, message));
    let file = std::fs::File::open(path).map_err(io)?;
    let mut r = BufReader::new(file);
    let mut line = String::new();
    let read_line =
        |r: &mut BufReader<std::fs::File>, line: &mut String| -> Result<bool, SplatError> {
            line.clear();
            let got = r.read_line(line).map_err(io)?;
            Ok(got > 0)
        };
    if !read_line(&mut r, &mut line)? || line.trim_end() != "ply" {
        return Err(bad("not a PLY file (missing the `ply` magic line)".into()));
    }
    let mut count: Option<usize> = None;
    let mut props: Vec<String> = Vec::new();
    let mut in_vertex = false;
    loop {
        if !read_line(&mut r, &mut line)? {
            return Err(bad("header ends before `end_header`".into()));
        }
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            ["end_header"] => break,
            ["format", fmt, _] => {
                if *fmt != "binary_little_endian" {
                    return Err(bad(format!(
                        "format `{fmt}` is not supported (only binary_little_endian, as the Inria layout uses)"
                    )));
                }
            }
            ["comment", ..] | ["obj_info", ..] | [] => {}
            ["element", name, n] => {
                if count.is_some() {
                    return Err(bad(format!(
                        "element `{name}` after `vertex` is not supported (Inria splat files hold only vertices)"
                    )));
                }
                if *name != "vertex" {
                    return Err(bad(format!(
                        "element `{name}` before `vertex` is not supported"
                    )));
                }
                count = Some(
                    n.parse()
                        .map_err(|_| bad(format!("bad vertex count `{n}`")))?,
                );
                in_vertex = true;
            }
            ["property", ty, name] => {
                if !in_vertex {
                    return Err(bad(format!("property `{name}` outside the vertex element")));
                }
                if *ty != "float" && *ty != "float32" {
                    return Err(bad(format!(
                        "property `{name}` has type `{ty}`; only float32 properties are supported"
                    )));
                }
                props.push(name.to_string());
            }
            _ => return Err(bad(format!("unexpected header line `{}`", line.trim_end()))),
        }
    }
    let n = count.ok_or_else(|| bad("no `element vertex` in the header".into()))?;
    let find = |name: &str| {
        props
            .iter()
            .position(|p| p == name)
            .ok_or_else(|| bad(format!("missing vertex property `{name}`")))
    };
    let pos = [find("x")?, find("y")?, find("z")?];
    let dc = [find("f_dc_0")?, find("f_dc_1")?, find("f_dc_2")?];
    let op = find("opacity")?;
    let sc = [find("scale_0")?, find("scale_1")?, find("scale_2")?];
    let rot = [
        find("rot_0")?,
        find("rot_1")?,
        find("rot_2")?,
        find("rot_3")?,
    ];
    let n_rest = props.iter().filter(|p| p.starts_with("f_rest_")).count();
    let degree = (0..=3u32)
        .find(|d| 3 * (sh_coeffs(*d) - 1) == n_rest)
        .ok_or_else(|| {
            bad(format!(
                "{n_rest} f_rest properties do not match an SH degree 0–3 (expected 0, 9, 24 or 45)"
            ))
        })?;
    let k = sh_coeffs(degree);
    let mut rest = Vec::with_capacity(n_rest);
    for j in 0..n_rest {
        rest.push(find(&format!("f_rest_{j}"))?);
    }
    let stride = props.len();
    // A header may claim more vertices than the file holds: never allocate for more than the
    // bytes after the header can carry.
    let file_len = r.get_ref().metadata().map_err(io)?.len();
    let header_len = r.stream_position().map_err(io)?;
    let body_vertices = (file_len.saturating_sub(header_len) / (stride as u64 * 4).max(1)) as usize;
    if n > body_vertices {
        return Err(bad(format!(
            "file ends at vertex {body_vertices} of {n} (the header claims {n} vertices of {} bytes; the file holds {} bytes after the header)",
            stride * 4,
            file_len.saturating_sub(header_len)
        )));
    }
    let mut g = Gaussians::empty(degree);
    g.means.reserve(n);
    g.sh.reserve(n * k * 3);
    let mut buf = vec![0u8; stride * 4];
    let mut row = vec![0f32; stride];
    for i in 0..n {
        r.read_exact(&mut buf).map_err(|e| {
            if e.kind() == std::io::ErrorKind::UnexpectedEof {
                bad(format!("file ends at vertex {i} of {n}"))
            } else {
                io(e)
            }
        })?;
        for (j, v) in row.iter_mut().enumerate() {
            *v = f32::from_le_bytes([buf[4 * j], buf[4 * j + 1], buf[4 * j + 2], buf[4 * j + 3]]);
        }
        g.means.push([row[pos[0]], row[pos[1]], row[pos[2]]]);
        g.log_scales.push([row[sc[0]], row[sc[1]], row[sc[2]]]);
        g.quats
            .push([row[rot[0]], row[rot[1]], row[rot[2]], row[rot[3]]]);
        g.opacity_logits.push(row[op]);
        g.sh.extend_from_slice(&[row[dc[0]], row[dc[1]], row[dc[2]]]);
        for kk in 1..k {
            for c in 0..3 {
                g.sh.push(row[rest[c * (k - 1) + (kk - 1)]]);
            }
        }
    }
    Ok(g)
}
