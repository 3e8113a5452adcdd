//! Float images and their file formats.
//!
//! [`ImageF32`] is interleaved (pixel-major, channels innermost), values in [0, 1] for colour.
//! Readers: PNG/JPEG (8 or 16 bit, grey/RGB/RGBA → RGB), EXR (named channels), NPY (float32
//! H×W×C or H×W). Writers: PNG (8-bit, rounded, clamped), EXR (float32 named channels),
//! NPY (float32). Colour values are stored as encoded in the file (no linearisation).

use crate::CoreError;
use std::fs::File;
use std::path::Path;

/// An interleaved float image.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageF32 {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Channels per pixel.
    pub channels: u32,
    /// `height × width × channels` values, row-major, channels innermost.
    pub data: Vec<f32>,
}

impl ImageF32 {
    /// A zero-filled image.
    pub fn new(width: u32, height: u32, channels: u32) -> Self {
        ImageF32 {
            width,
            height,
            channels,
            data: vec![0.0; (width * height * channels) as usize],
        }
    }
    /// Wraps existing data; panics if the length does not match (a programming error).
    pub fn from_vec(width: u32, height: u32, channels: u32, data: Vec<f32>) -> Self {
        assert_eq!(
            data.len(),
            (width * height * channels) as usize,
            "ImageF32::from_vec size mismatch"
        );
        ImageF32 {
            width,
            height,
            channels,
            data,
        }
    }
    /// An image whose value at (x, y, channel) is `f(x, y, channel)`.
    pub fn from_fn(
        width: u32,
        height: u32,
        channels: u32,
        f: impl Fn(u32, u32, u32) -> f32,
    ) -> Self {
        let mut data = Vec::with_capacity((width * height * channels) as usize);
        for y in 0..height {
            for x in 0..width {
                for c in 0..channels {
                    data.push(f(x, y, c));
                }
            }
        }
        ImageF32::from_vec(width, height, channels, data)
    }
    /// Number of pixels.
    pub fn pixels(&self) -> usize {
        (self.width * self.height) as usize
    }
    /// Value at column x, row y, channel c.
    pub fn get(&self, x: u32, y: u32, c: u32) -> f32 {
        self.data[((y * self.width + x) * self.channels + c) as usize]
    }
    /// Sets the value at column x, row y, channel c.
    pub fn set(&mut self, x: u32, y: u32, c: u32, v: f32) {
        self.data[((y * self.width + x) * self.channels + c) as usize] = v;
    }
    /// One channel as a planar vector.
    pub fn channel(&self, c: u32) -> Vec<f32> {
        self.data
            .iter()
            .skip(c as usize)
            .step_by(self.channels as usize)
            .copied()
            .collect()
    }
    /// Area-average downscale by an integer factor (partial edge blocks are averaged over the
    /// pixels they hold). Pixel centres stay consistent with [`crate::Camera::resized`] when the
    /// size divides exactly.
    pub fn downscale(&self, factor: u32) -> ImageF32 {
        if factor <= 1 {
            return self.clone();
        }
        let w = self.width.div_ceil(factor);
        let h = self.height.div_ceil(factor);
        let c = self.channels as usize;
        let mut out = ImageF32::new(w, h, self.channels);
        for oy in 0..h {
            for ox in 0..w {
                let mut acc = [0f64; 8];
                let mut n = 0f64;
                for y in oy * factor..((oy + 1) * factor).min(self.height) {
                    for x in ox * factor..((ox + 1) * factor).min(self.width) {
                        let base = ((y * self.width + x) as usize) * c;
                        for k in 0..c.min(8) {
                            acc[k] += self.data[base + k] as f64;
                        }
                        n += 1.0;
                    }
                }
                let base = ((oy * w + ox) as usize) * c;
                for k in 0..c.min(8) {
                    out.data[base + k] = (acc[k] / n) as f32;
                }
            }
        }
        out
    }
}

/// Reads a colour image as 3-channel RGB: PNG/JPEG (any bit depth; grey is replicated, alpha
/// dropped), EXR (channels R, G, B) or NPY (float32 H×W×3).
pub fn read_rgb(path: &Path) -> Result<ImageF32, CoreError> {
    let ext = extension(path);
    match ext.as_str() {
        "exr" => {
            let exr = read_exr(path)?;
            let get = |n: &str| {
                exr.channel(n).ok_or_else(|| {
                    CoreError::format(
                        path,
                        format!("EXR has no channel {n} (has {:?})", exr.names()),
                    )
                })
            };
            let (r, g, b) = (get("R")?, get("G")?, get("B")?);
            let mut data = Vec::with_capacity(r.len() * 3);
            for i in 0..r.len() {
                data.extend_from_slice(&[r[i], g[i], b[i]]);
            }
            Ok(ImageF32::from_vec(exr.width, exr.height, 3, data))
        }
        "npy" => {
            let img = read_npy(path)?;
            if img.channels != 3 {
                return Err(CoreError::format(
                    path,
                    format!("expected H×W×3, found {} channels", img.channels),
                ));
            }
            Ok(img)
        }
        _ => {
            check_complete(path)?;
            let reader = ::image::ImageReader::open(path)
                .map_err(|e| CoreError::io(path, e))?
                .with_guessed_format()
                .map_err(|e| CoreError::io(path, e))?;
            let dynimg = reader
                .decode()
                .map_err(|e| CoreError::format(path, format!("not a readable image: {e}")))?;
            let rgb = dynimg.to_rgb32f();
            let (w, h) = rgb.dimensions();
            Ok(ImageF32::from_vec(w, h, 3, rgb.into_raw()))
        }
    }
}

/// Refuses a PNG or JPEG file that ends before its end marker (a PNG's `IEND` chunk, a JPEG's
/// EOI marker `FF D9`): decoders fill the missing rows with grey instead of failing, which
/// would silently train on a broken photo. Other formats pass (their decoders report
/// truncation themselves).
fn check_complete(path: &Path) -> Result<(), CoreError> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = File::open(path).map_err(|e| CoreError::io(path, e))?;
    let len = f.metadata().map_err(|e| CoreError::io(path, e))?.len();
    let mut head = [0u8; 8];
    let got = f.read(&mut head).map_err(|e| CoreError::io(path, e))?;
    let head = &head[..got];
    let tail_len = len.min(4096);
    f.seek(SeekFrom::Start(len - tail_len))
        .map_err(|e| CoreError::io(path, e))?;
    let mut tail = vec![0u8; tail_len as usize];
    f.read_exact(&mut tail)
        .map_err(|e| CoreError::io(path, e))?;
    let truncated = |what: &str| {
        Err(CoreError::format(
            path,
            format!("the file is truncated: it ends ({len} bytes) before the {what}"),
        ))
    };
    if head.starts_with(&[0x89, b'P', b'N', b'G']) {
        // The IEND chunk: length 0, "IEND", CRC; only trailing garbage may follow it.
        if !tail.windows(4).any(|w| w == b"IEND") {
            return truncated("PNG's IEND chunk");
        }
    } else if head.starts_with(&[0xff, 0xd8]) {
        if !tail.windows(2).any(|w| w == [0xff, 0xd9]) {
            return truncated("JPEG end-of-image marker (FF D9)");
        }
        // An end marker proves nothing by itself (one appended to a cut file looks the same):
        // walk the compressed data and count its blocks.
        let bytes = std::fs::read(path).map_err(|e| CoreError::io(path, e))?;
        crate::jpeg_check::check_scans_complete(&bytes).map_err(|why| {
            CoreError::format(path, format!("the JPEG is truncated or damaged: {why}"))
        })?;
    }
    Ok(())
}

/// Image width and height from the file header, without decoding the pixels.
pub fn image_size(path: &Path) -> Result<(u32, u32), CoreError> {
    ::image::ImageReader::open(path)
        .map_err(|e| CoreError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| CoreError::io(path, e))?
        .into_dimensions()
        .map_err(|e| CoreError::format(path, format!("not a readable image: {e}")))
}

/// Writes an 8-bit PNG (1, 3 or 4 channels); values are clamped to [0, 1] and rounded.
pub fn write_png(path: &Path, img: &ImageF32) -> Result<(), CoreError> {
    let bytes: Vec<u8> = img.data.iter().map(|&v| to_u8(v)).collect();
    let color = match img.channels {
        1 => ::image::ExtendedColorType::L8,
        3 => ::image::ExtendedColorType::Rgb8,
        4 => ::image::ExtendedColorType::Rgba8,
        c => {
            return Err(CoreError::format(
                path,
                format!("cannot write a {c}-channel PNG"),
            ))
        }
    };
    ::image::save_buffer_with_format(
        path,
        &bytes,
        img.width,
        img.height,
        color,
        ::image::ImageFormat::Png,
    )
    .map_err(|e| CoreError::format(path, format!("cannot write PNG: {e}")))
}

/// Quantises a [0, 1] value to 8 bits (clamped, round-half-up; NaN → 0).
pub fn to_u8(v: f32) -> u8 {
    if v.is_nan() {
        0
    } else {
        (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
    }
}

/// A decoded EXR: planar float channels by name.
#[derive(Clone, Debug)]
pub struct ExrImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// (name, row-major samples) in file order.
    pub channels: Vec<(String, Vec<f32>)>,
}

impl ExrImage {
    /// The samples of the channel called `name`.
    pub fn channel(&self, name: &str) -> Option<&[f32]> {
        self.channels
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }
    /// Channel names.
    pub fn names(&self) -> Vec<&str> {
        self.channels.iter().map(|(n, _)| n.as_str()).collect()
    }
}

/// Writes float32 planar channels to an uncompressed... (ZIP-compressed, lossless) EXR.
pub fn write_exr(
    path: &Path,
    width: u32,
    height: u32,
    channels: &[(&str, &[f32])],
) -> Result<(), CoreError> {
    use exr::prelude::*;
    let n = (width * height) as usize;
    if channels.is_empty() {
        return Err(CoreError::format(path, "an EXR needs at least one channel"));
    }
    let mut list: Vec<AnyChannel<FlatSamples>> = Vec::with_capacity(channels.len());
    for (name, data) in channels {
        if data.len() != n {
            return Err(CoreError::format(
                path,
                format!("channel {name} has {} samples, expected {n}", data.len()),
            ));
        }
        list.push(AnyChannel::new(*name, FlatSamples::F32(data.to_vec())));
    }
    let layer = Layer::new(
        (width as usize, height as usize),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(list.into_iter().collect()),
    );
    Image::from_layer(layer)
        .write()
        .to_file(path)
        .map_err(|e| CoreError::format(path, format!("cannot write EXR: {e}")))
}

/// Reads every channel of the first layer of an EXR as float32.
pub fn read_exr(path: &Path) -> Result<ExrImage, CoreError> {
    use exr::prelude::*;
    if !path.exists() {
        return Err(CoreError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "file not found"),
        ));
    }
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| CoreError::format(path, format!("not a readable EXR: {e}")))?;
    let layer = image.layer_data;
    let size = layer.size;
    let channels = layer
        .channel_data
        .list
        .iter()
        .map(|ch| {
            let data: Vec<f32> = ch.sample_data.values_as_f32().collect();
            (ch.name.to_string(), data)
        })
        .collect();
    Ok(ExrImage {
        width: size.0 as u32,
        height: size.1 as u32,
        channels,
    })
}

/// Writes float32 NPY with shape H×W×C (or H×W for one channel).
pub fn write_npy(path: &Path, img: &ImageF32) -> Result<(), CoreError> {
    let shape = if img.channels == 1 {
        format!("({}, {})", img.height, img.width)
    } else {
        format!("({}, {}, {})", img.height, img.width, img.channels)
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    let total = 10 + header.len() + 1;
    let pad = (64 - total % 64) % 64;
    header.push_str(&" ".repeat(pad));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + img.data.len() * 4);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in &img.data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, out).map_err(|e| CoreError::io(path, e))
}

/// Reads a float32 or float64 little-endian NPY of shape H×W×C or H×W into an image.
pub fn read_npy(path: &Path) -> Result<ImageF32, CoreError> {
    let (shape, values) = read_npy_array(path)?;
    let (h, w, c) = match shape.as_slice() {
        [h, w] => (*h, *w, 1),
        [h, w, c] => (*h, *w, *c),
        s => {
            return Err(CoreError::format(
                path,
                format!("expected a 2-D or 3-D array, found shape {s:?}"),
            ))
        }
    };
    Ok(ImageF32::from_vec(
        w as u32,
        h as u32,
        c as u32,
        values.into_iter().map(|v| v as f32).collect(),
    ))
}

/// Reads a C-order little-endian NPY array of `<f4` or `<f8` values: (shape, values as f64).
pub fn read_npy_array(path: &Path) -> Result<(Vec<usize>, Vec<f64>), CoreError> {
    let bytes = std::fs::read(path).map_err(|e| CoreError::io(path, e))?;
    let bad = |m: &str| CoreError::format(path, format!("not a supported NPY file: {m}"));
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(bad("missing magic"));
    }
    let (hlen, hstart) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err(bad("truncated header"));
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => return Err(bad(&format!("version {v}"))),
    };
    let header = std::str::from_utf8(
        bytes
            .get(hstart..hstart + hlen)
            .ok_or_else(|| bad("truncated header"))?,
    )
    .map_err(|_| bad("header is not text"))?;
    let descr = if header.contains("'<f4'") {
        4
    } else if header.contains("'<f8'") {
        8
    } else {
        return Err(bad("dtype must be little-endian float32 or float64"));
    };
    if header.contains("'fortran_order': True") {
        return Err(bad("Fortran order is not supported"));
    }
    let open = header.find("'shape': (").ok_or_else(|| bad("no shape"))? + "'shape': (".len();
    let close = header[open..].find(')').ok_or_else(|| bad("no shape"))? + open;
    let shape: Vec<usize> = header[open..close]
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>().map_err(|_| bad("shape is not integers")))
        .collect::<Result<_, _>>()?;
    let count: usize = shape.iter().product();
    let data = &bytes[hstart + hlen..];
    if data.len() < count * descr {
        return Err(bad(&format!(
            "{} data bytes, need {}",
            data.len(),
            count * descr
        )));
    }
    let values = if descr == 4 {
        data.chunks_exact(4)
            .take(count)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64)
            .collect()
    } else {
        data.chunks_exact(8)
            .take(count)
            .map(|b| f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
            .collect()
    };
    Ok((shape, values))
}

fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: u32, h: u32, c: u32) -> ImageF32 {
        let data = (0..w * h * c).map(|i| (i % 251) as f32 / 250.0).collect();
        ImageF32::from_vec(w, h, c, data)
    }

    #[test]
    fn png_npy_exr_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let img = ramp(7, 5, 3);
        let p = dir.path().join("a.png");
        write_png(&p, &img).unwrap();
        let back = read_rgb(&p).unwrap();
        assert_eq!((back.width, back.height), (7, 5));
        for (a, b) in img.data.iter().zip(&back.data) {
            assert!((a - b).abs() <= 0.5 / 255.0 + 1e-6);
        }
        let n = dir.path().join("a.npy");
        write_npy(&n, &img).unwrap();
        assert_eq!(read_rgb(&n).unwrap(), img);
        let e = dir.path().join("a.exr");
        let (r, g, b) = (img.channel(0), img.channel(1), img.channel(2));
        write_exr(&e, 7, 5, &[("R", &r), ("G", &g), ("B", &b)]).unwrap();
        assert_eq!(read_rgb(&e).unwrap(), img);
    }

    #[test]
    fn bad_files_name_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.png");
        std::fs::write(&p, b"not an image").unwrap();
        let err = read_rgb(&p).unwrap_err().to_string();
        assert!(err.contains("x.png"), "{err}");
    }

    #[test]
    fn truncated_png_and_jpeg_are_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let img = ramp(64, 48, 3);
        let png = dir.path().join("a.png");
        write_png(&png, &img).unwrap();
        let rgb8: Vec<u8> = img.data.iter().map(|&v| to_u8(v)).collect();
        let mut jpeg = Vec::new();
        ::image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
            .encode(&rgb8, 64, 48, ::image::ExtendedColorType::Rgb8)
            .unwrap();
        let jpg = dir.path().join("a.jpg");
        std::fs::write(&jpg, &jpeg).unwrap();
        for p in [&png, &jpg] {
            let whole = read_rgb(p).unwrap();
            assert_eq!((whole.width, whole.height), (64, 48));
            let bytes = std::fs::read(p).unwrap();
            let cut = dir
                .path()
                .join(format!("cut.{}", p.extension().unwrap().to_string_lossy()));
            std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
            let err = read_rgb(&cut).unwrap_err().to_string();
            assert!(err.contains("cut.") && err.contains("truncated"), "{err}");
        }
    }

    #[test]
    fn a_truncated_jpeg_with_an_end_marker_appended_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        for (w, h) in [(96, 64), (61, 37)] {
            let img = ramp(w, h, 3);
            let rgb8: Vec<u8> = img.data.iter().map(|&v| to_u8(v)).collect();
            let mut jpeg = Vec::new();
            ::image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
                .encode(&rgb8, w, h, ::image::ExtendedColorType::Rgb8)
                .unwrap();
            let whole = dir.path().join("whole.jpg");
            std::fs::write(&whole, &jpeg).unwrap();
            assert_eq!(read_rgb(&whole).map(|i| i.width).ok(), Some(w));
            // Cut at 60 %, then append the end-of-image marker by hand.
            let mut cut = jpeg[..jpeg.len() * 6 / 10].to_vec();
            cut.extend_from_slice(&[0xff, 0xd9]);
            let p = dir.path().join("mended.jpg");
            std::fs::write(&p, &cut).unwrap();
            let err = match read_rgb(&p) {
                Ok(_) => panic!("a cut {w}×{h} JPEG with an end marker was read"),
                Err(e) => e.to_string(),
            };
            assert!(
                err.contains("mended.jpg") && err.contains("cut short"),
                "{err}"
            );
        }
    }

    #[test]
    fn downscale_averages_blocks() {
        let img = ImageF32::from_vec(2, 2, 1, vec![0.0, 1.0, 1.0, 0.0]);
        assert_eq!(img.downscale(2).data, vec![0.5]);
    }
}
