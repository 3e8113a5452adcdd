//! HTML and Markdown building blocks: escaping, base64 PNG data URIs, image crops and
//! colour maps, and metric tables with the best value per column marked.

use crate::evalset::MetricKey;
use crate::ReportError;
use augsplat_core::ImageF32;
use std::fmt::Write as _;

pub use crate::svg::escape;

/// Standard base64 (RFC 4648, with padding).
pub fn base64(bytes: &[u8]) -> String {
    const TABLE: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = ((b[0] as u32) << 16) | ((b[1] as u32) << 8) | b[2] as u32;
        out.push(TABLE[(n >> 18) as usize & 63] as char);
        out.push(TABLE[(n >> 12) as usize & 63] as char);
        out.push(if chunk.len() > 1 {
            TABLE[(n >> 6) as usize & 63] as char
        } else {
            '='
        });
        out.push(if chunk.len() > 2 {
            TABLE[n as usize & 63] as char
        } else {
            '='
        });
    }
    out
}

/// Encodes a 1-, 3- or 4-channel float image (values clamped to [0, 1]) as 8-bit PNG bytes.
pub fn png_bytes(img: &ImageF32) -> Result<Vec<u8>, ReportError> {
    use ::image::ImageEncoder;
    let color = match img.channels {
        1 => ::image::ExtendedColorType::L8,
        3 => ::image::ExtendedColorType::Rgb8,
        4 => ::image::ExtendedColorType::Rgba8,
        c => {
            return Err(ReportError::Message(format!(
                "cannot encode a {c}-channel image as PNG"
            )))
        }
    };
    let bytes: Vec<u8> = img
        .data
        .iter()
        .map(|&v| augsplat_core::image::to_u8(v))
        .collect();
    let mut out = Vec::new();
    ::image::codecs::png::PngEncoder::new(&mut out)
        .write_image(&bytes, img.width, img.height, color)
        .map_err(|e| ReportError::Message(format!("cannot encode PNG: {e}")))?;
    Ok(out)
}

/// A `data:image/png;base64,…` URI of the image.
pub fn png_data_uri(img: &ImageF32) -> Result<String, ReportError> {
    Ok(format!(
        "data:image/png;base64,{}",
        base64(&png_bytes(img)?)
    ))
}

/// Downscales (area average, integer factor) so that the width is at most `max_width`.
pub fn fit_width(img: &ImageF32, max_width: u32) -> ImageF32 {
    if img.width <= max_width || max_width == 0 {
        return img.clone();
    }
    img.downscale(img.width.div_ceil(max_width))
}

/// The `w × h` window at column `x`, row `y` (clipped to the image).
pub fn crop(img: &ImageF32, x: u32, y: u32, w: u32, h: u32) -> ImageF32 {
    let x = x.min(img.width.saturating_sub(1));
    let y = y.min(img.height.saturating_sub(1));
    let w = w.min(img.width - x).max(1);
    let h = h.min(img.height - y).max(1);
    let c = img.channels as usize;
    let mut data = Vec::with_capacity((w * h) as usize * c);
    for row in y..y + h {
        let start = ((row * img.width + x) as usize) * c;
        data.extend_from_slice(&img.data[start..start + w as usize * c]);
    }
    ImageF32::from_vec(w, h, img.channels, data)
}

/// Nearest-neighbour upscale by an integer factor (keeps pixels visible in zoomed crops).
pub fn upscale_nearest(img: &ImageF32, factor: u32) -> ImageF32 {
    let f = factor.max(1);
    let (w, h, c) = (img.width * f, img.height * f, img.channels as usize);
    let mut data = Vec::with_capacity((w * h) as usize * c);
    for y in 0..h {
        for x in 0..w {
            let s = (((y / f) * img.width + x / f) as usize) * c;
            data.extend_from_slice(&img.data[s..s + c]);
        }
    }
    ImageF32::from_vec(w, h, img.channels, data)
}

/// The top-left corner of the `win × win` window (on a grid of `win/2` strides) with the
/// largest mean absolute difference between `a` and `b` (same size, any channels). Ties pick
/// the first window in row-major order. Used to place zoomed crops where a method errs most.
pub fn worst_window(a: &ImageF32, b: &ImageF32, win: u32) -> (u32, u32) {
    if a.width != b.width || a.height != b.height || a.channels != b.channels {
        return (0, 0);
    }
    let (w, h) = (a.width as usize, a.height as usize);
    let c = a.channels as usize;
    let win = (win as usize).clamp(1, w.min(h).max(1));
    // Integral image of the per-pixel error (f64, exact enough for any size here).
    let mut integral = vec![0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0f64;
        for x in 0..w {
            let base = (y * w + x) * c;
            let mut e = 0f64;
            for k in 0..c {
                let d = (a.data[base + k] - b.data[base + k]) as f64;
                if d.is_finite() {
                    e += d.abs();
                }
            }
            row += e;
            integral[(y + 1) * (w + 1) + x + 1] = integral[y * (w + 1) + x + 1] + row;
        }
    }
    let stride = (win / 2).max(1);
    let mut best = (0usize, 0usize, f64::NEG_INFINITY);
    let mut y = 0;
    while y + win <= h {
        let mut x = 0;
        while x + win <= w {
            let s = integral[(y + win) * (w + 1) + x + win]
                - integral[y * (w + 1) + x + win]
                - integral[(y + win) * (w + 1) + x]
                + integral[y * (w + 1) + x];
            if s > best.2 {
                best = (x, y, s);
            }
            x += stride;
        }
        y += stride;
    }
    (best.0 as u32, best.1 as u32)
}

/// A colour map for confidence in [0, 1] (dark purple → teal → yellow, viridis-like by
/// linear interpolation between five anchors); non-finite values map to black.
pub fn confidence_colormap(values: &[f32], width: u32, height: u32) -> ImageF32 {
    const ANCHORS: [[f32; 3]; 5] = [
        [0.267, 0.005, 0.329],
        [0.229, 0.322, 0.546],
        [0.128, 0.567, 0.551],
        [0.369, 0.789, 0.383],
        [0.993, 0.906, 0.144],
    ];
    let mut data = Vec::with_capacity(values.len() * 3);
    for &v in values {
        if !v.is_finite() {
            data.extend_from_slice(&[0.0, 0.0, 0.0]);
            continue;
        }
        let t = v.clamp(0.0, 1.0) * 4.0;
        let i = (t.floor() as usize).min(3);
        let f = t - i as f32;
        for (lo, hi) in ANCHORS[i].iter().zip(&ANCHORS[i + 1]) {
            data.push(lo * (1.0 - f) + hi * f);
        }
    }
    ImageF32::from_vec(width, height, 3, data)
}

/// A row of a [`MetricTable`].
#[derive(Clone, Debug, PartialEq)]
pub struct MetricRow {
    /// Method label.
    pub label: String,
    /// Extra text shown after the label (e.g. `step 300`), may be empty.
    pub detail: String,
    /// One value per column (`None`: unavailable).
    pub values: Vec<Option<f64>>,
}

/// A table of methods × metrics, like the paper's Table 1.
///
/// The best value of each column is marked (bold, CSS class `best`) when at least two rows have
/// a comparable value in that column. Values are compared *as shown* (rounded to the table's
/// decimals), so every row that shows the best value is marked (ties are all marked). NaN
/// never counts; +∞ PSNR (identical images) is a valid best.
#[derive(Clone, Debug, PartialEq)]
pub struct MetricTable {
    /// Caption.
    pub caption: String,
    /// The metric of each column.
    pub columns: Vec<MetricKey>,
    /// The rows.
    pub rows: Vec<MetricRow>,
}

/// Which entries of one column are best: the maximum (or minimum) of the non-NaN values, all
/// ties marked; nothing is marked when fewer than two values are comparable.
pub fn best_marks(values: &[Option<f64>], higher_is_better: bool) -> Vec<bool> {
    let ok: Vec<f64> = values
        .iter()
        .flatten()
        .copied()
        .filter(|v| !v.is_nan())
        .collect();
    if ok.len() < 2 {
        return vec![false; values.len()];
    }
    let best = if higher_is_better {
        ok.iter().copied().fold(f64::NEG_INFINITY, f64::max)
    } else {
        ok.iter().copied().fold(f64::INFINITY, f64::min)
    };
    values.iter().map(|v| *v == Some(best)).collect()
}

impl MetricTable {
    /// Marks per cell (`[row][column]`).
    pub fn marks(&self) -> Vec<Vec<bool>> {
        let mut marks = vec![vec![false; self.columns.len()]; self.rows.len()];
        for (c, key) in self.columns.iter().enumerate() {
            let col: Vec<Option<f64>> = self
                .rows
                .iter()
                .map(|r| {
                    r.values
                        .get(c)
                        .copied()
                        .flatten()
                        .map(|v| key.round_shown(v))
                })
                .collect();
            for (r, m) in best_marks(&col, key.higher_is_better())
                .into_iter()
                .enumerate()
            {
                marks[r][c] = m;
            }
        }
        marks
    }

    fn header_text(key: MetricKey) -> String {
        format!(
            "{} {}",
            key.title(),
            if key.higher_is_better() { "↑" } else { "↓" }
        )
    }

    /// The table as an HTML `<table class="metrics">`.
    pub fn to_html(&self) -> String {
        let marks = self.marks();
        let mut out = String::from("<table class=\"metrics\">");
        let _ = write!(
            out,
            "<caption>{}</caption><thead><tr><th>Method</th>",
            escape(&self.caption)
        );
        for key in &self.columns {
            let _ = write!(out, "<th>{}</th>", escape(&Self::header_text(*key)));
        }
        out.push_str("</tr></thead><tbody>");
        for (r, row) in self.rows.iter().enumerate() {
            let _ = write!(out, "<tr><th scope=\"row\">{}", escape(&row.label));
            if !row.detail.is_empty() {
                let _ = write!(
                    out,
                    " <span class=\"detail\">{}</span>",
                    escape(&row.detail)
                );
            }
            out.push_str("</th>");
            for (c, key) in self.columns.iter().enumerate() {
                let text = match row.values.get(c).copied().flatten() {
                    Some(v) => key.format(v),
                    None => "—".into(),
                };
                if marks[r][c] {
                    let _ = write!(
                        out,
                        "<td class=\"best\"><strong>{}</strong></td>",
                        escape(&text)
                    );
                } else {
                    let _ = write!(out, "<td>{}</td>", escape(&text));
                }
            }
            out.push_str("</tr>");
        }
        out.push_str("</tbody></table>");
        out
    }

    /// The table in Markdown (best values in bold).
    pub fn to_markdown(&self) -> String {
        let marks = self.marks();
        let md = |s: &str| s.replace('|', "\\|");
        let mut out = format!("**{}**\n\n| Method |", md(&self.caption));
        for key in &self.columns {
            let _ = write!(out, " {} |", Self::header_text(*key));
        }
        out.push_str("\n|---|");
        for _ in &self.columns {
            out.push_str("---:|");
        }
        out.push('\n');
        for (r, row) in self.rows.iter().enumerate() {
            let label = if row.detail.is_empty() {
                md(&row.label)
            } else {
                format!("{} ({})", md(&row.label), md(&row.detail))
            };
            let _ = write!(out, "| {label} |");
            for (c, key) in self.columns.iter().enumerate() {
                let text = match row.values.get(c).copied().flatten() {
                    Some(v) => key.format(v),
                    None => "—".into(),
                };
                if marks[r][c] {
                    let _ = write!(out, " **{text}** |");
                } else {
                    let _ = write!(out, " {text} |");
                }
            }
            out.push('\n');
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_rfc4648_vectors() {
        for (input, want) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(input.as_bytes()), want);
        }
    }

    #[test]
    fn png_bytes_decode_back() {
        let img = ImageF32::from_vec(2, 1, 3, vec![0.0, 0.5, 1.0, 1.0, 0.25, 0.0]);
        let bytes = png_bytes(&img).unwrap();
        let back = ::image::load_from_memory(&bytes).unwrap().to_rgb8();
        assert_eq!(back.as_raw(), &vec![0, 128, 255, 255, 64, 0]);
        assert!(png_bytes(&ImageF32::new(1, 1, 2)).is_err());
    }

    #[test]
    fn table_marks_best_per_column_golden() {
        // Paper Table 1 averages: 3DGS 17.88/0.622/0.625/0.192, Staged 18.39/0.630/0.632/0.183,
        // Dual 18.37/0.630/0.631/0.184. Best: PSNR Staged; SSIM tie Staged+Dual; LPIPS 3DGS
        // (lower); avg error Staged.
        let t = MetricTable {
            caption: "mip-NeRF 360".into(),
            columns: MetricKey::TABLE.to_vec(),
            rows: vec![
                MetricRow {
                    label: "3DGS".into(),
                    detail: String::new(),
                    values: vec![Some(17.88), Some(0.622), Some(0.625), Some(0.192)],
                },
                MetricRow {
                    label: "Staged".into(),
                    detail: String::new(),
                    values: vec![Some(18.39), Some(0.630), Some(0.632), Some(0.183)],
                },
                MetricRow {
                    label: "Dual".into(),
                    detail: "step 300".into(),
                    values: vec![Some(18.37), Some(0.630), Some(0.631), Some(0.184)],
                },
            ],
        };
        assert_eq!(
            t.marks(),
            vec![
                vec![false, false, true, false],
                vec![true, true, false, true],
                vec![false, true, false, false],
            ]
        );
        let html = t.to_html();
        assert_eq!(html.matches("class=\"best\"").count(), 5);
        assert!(html.contains("<td class=\"best\"><strong>18.39</strong></td>"));
        assert!(html.contains("<td>17.88</td>"));
        assert!(html.contains("PSNR ↑") && html.contains("LPIPS ↓"));
        let md = t.to_markdown();
        assert!(
            md.contains("| Staged | **18.39** | **0.630** | 0.632 | **0.183** |"),
            "{md}"
        );
        assert!(
            md.contains("| Dual (step 300) | 18.37 | **0.630** | 0.631 | 0.184 |"),
            "{md}"
        );
    }

    #[test]
    fn ties_at_the_shown_precision_are_all_marked() {
        let t = MetricTable {
            caption: String::new(),
            columns: vec![MetricKey::Ssim, MetricKey::Psnr],
            rows: vec![
                MetricRow {
                    label: "a".into(),
                    detail: String::new(),
                    values: vec![Some(0.0381), Some(6.381)],
                },
                MetricRow {
                    label: "b".into(),
                    detail: String::new(),
                    values: vec![Some(0.0379), Some(6.389)],
                },
                MetricRow {
                    label: "c".into(),
                    detail: String::new(),
                    values: vec![Some(0.0374), None],
                },
            ],
        };
        // SSIM 0.038 / 0.038 / 0.037: a and b tie as shown; PSNR 6.38 vs 6.39: b alone.
        assert_eq!(
            t.marks(),
            vec![vec![true, false], vec![true, true], vec![false, false]]
        );
    }

    #[test]
    fn marks_skip_missing_nan_and_single_values() {
        assert_eq!(
            best_marks(&[Some(1.0), None, Some(f64::NAN)], true),
            vec![false; 3]
        );
        assert_eq!(
            best_marks(&[Some(1.0), None, Some(2.0)], false),
            vec![true, false, false]
        );
        assert_eq!(
            best_marks(&[Some(f64::INFINITY), Some(30.0)], true),
            vec![true, false]
        );
    }

    #[test]
    fn crops_and_windows() {
        let mut a = ImageF32::new(8, 8, 1);
        let b = ImageF32::new(8, 8, 1);
        a.set(6, 5, 0, 1.0);
        let (x, y) = worst_window(&a, &b, 4);
        assert!(x <= 6 && 6 < x + 4 && y <= 5 && 5 < y + 4, "({x},{y})");
        let c = crop(&a, x, y, 4, 4);
        assert_eq!((c.width, c.height), (4, 4));
        assert_eq!(c.get(6 - x, 5 - y, 0), 1.0);
        let up = upscale_nearest(&c, 3);
        assert_eq!((up.width, up.height), (12, 12));
        assert_eq!(up.get((6 - x) * 3 + 2, (5 - y) * 3, 0), 1.0);
        // Crops past the border are clipped, never panic.
        let edge = crop(&a, 7, 7, 4, 4);
        assert_eq!((edge.width, edge.height), (1, 1));
        assert_eq!(fit_width(&ImageF32::new(800, 10, 3), 400).width, 400);
        let cm = confidence_colormap(&[0.0, 1.0, f32::NAN], 3, 1);
        assert_eq!(cm.get(2, 0, 0), 0.0);
        assert!(cm.get(1, 0, 0) > 0.9);
    }
}
