//! The report's image sections: ground truth beside each method with zoomed crops where the
//! first method errs most, and the synthetic views beside their confidence maps.

use super::ReportOptions;
use crate::evalset::EvalDir;
use crate::html::{self, escape};
use crate::ReportError;
use augsplat_core::artifacts::{self, SyntheticSet};
use augsplat_core::{image, ImageF32};
use std::fmt::Write as _;
use std::path::Path;

/// Draws a 2-pixel red rectangle outline (in place) to show where a crop was taken.
fn outline(img: &mut ImageF32, x0: u32, y0: u32, w: u32, h: u32) {
    if img.channels < 3 || img.width == 0 || img.height == 0 {
        return;
    }
    let x1 = (x0 + w).min(img.width) - 1;
    let y1 = (y0 + h).min(img.height) - 1;
    let mut paint = |x: u32, y: u32| {
        if x < img.width && y < img.height {
            img.set(x, y, 0, 1.0);
            img.set(x, y, 1, 0.1);
            img.set(x, y, 2, 0.1);
        }
    };
    for t in 0..2 {
        for x in x0..=x1 {
            paint(x, y0 + t);
            paint(x, y1.saturating_sub(t));
        }
        for y in y0..=y1 {
            paint(x0 + t, y);
            paint(x1.saturating_sub(t), y);
        }
    }
}

fn figure(uri: &str, caption: &str, width: u32, class: &str) -> String {
    format!(
        "<figure><img class=\"{class}\" src=\"{uri}\" width=\"{width}\" alt=\"{c}\"><figcaption>{c}</figcaption></figure>",
        c = escape(caption)
    )
}

pub(super) fn image_section(
    opts: &ReportOptions,
    evals: &[EvalDir],
    labels: &[String],
) -> Result<String, ReportError> {
    let mut out = String::from("<h2 id=\"images\">Ground truth vs methods</h2>");
    let first = &evals[0];
    let views: Vec<&str> = first
        .metrics
        .views
        .iter()
        .map(|v| v.name.as_str())
        .filter(|n| first.gt_path(n).is_file())
        .take(opts.max_views)
        .collect();
    if views.is_empty() {
        out.push_str(
            "<p class=\"note\">No ground-truth images in the first evaluation folder.</p>",
        );
        return Ok(out);
    }
    let _ = write!(
        out,
        "<p class=\"note\">Crops (red boxes) are placed where {} differs most from the ground truth; zoomed with nearest-neighbour sampling.</p>",
        escape(&labels[0])
    );
    for name in views {
        let gt = image::read_rgb(&first.gt_path(name))?;
        let mut renders: Vec<Option<ImageF32>> = Vec::with_capacity(evals.len());
        for e in evals {
            let p = e.render_path(name);
            renders.push(if p.is_file() {
                let img = image::read_rgb(&p)?;
                (img.width == gt.width && img.height == gt.height).then_some(img)
            } else {
                None
            });
        }
        let win = (gt.width.min(gt.height) / 4).max(1);
        let (cx, cy) = match &renders[0] {
            Some(r) => html::worst_window(&gt, r, win),
            None => ((gt.width - win) / 2, (gt.height - win) / 2),
        };
        let zoom = (opts.crop_size / win).max(1);
        // Small images are shown enlarged by an integer factor (pixelated), large ones
        // downscaled to fit.
        let (shown_w, full_class) = if gt.width < opts.image_width {
            (
                gt.width * (opts.image_width / gt.width.max(1)).max(1),
                "full px",
            )
        } else {
            (gt.width.min(opts.image_width), "full")
        };
        let factor = gt.width.div_ceil(opts.image_width.max(1)).max(1);
        let mut full_row = String::from("<div class=\"row\">");
        let mut crop_row = String::from("<div class=\"row\">");
        let mut panels: Vec<(String, Option<&ImageF32>)> = vec![("ground truth".into(), Some(&gt))];
        for (r, l) in renders.iter().zip(labels) {
            panels.push((l.clone(), r.as_ref()));
        }
        for (caption, img) in panels {
            match img {
                Some(img) => {
                    let mut small = html::fit_width(img, opts.image_width);
                    outline(
                        &mut small,
                        cx / factor,
                        cy / factor,
                        win.div_ceil(factor),
                        win.div_ceil(factor),
                    );
                    full_row.push_str(&figure(
                        &html::png_data_uri(&small)?,
                        &caption,
                        shown_w,
                        full_class,
                    ));
                    let c = html::upscale_nearest(&html::crop(img, cx, cy, win, win), zoom);
                    crop_row.push_str(&figure(
                        &html::png_data_uri(&c)?,
                        &format!("{caption} (crop)"),
                        c.width,
                        "px crop",
                    ));
                }
                None => {
                    let _ = write!(full_row, "<figure><figcaption>{}: render missing or of another size</figcaption></figure>", escape(&caption));
                }
            }
        }
        let _ = write!(
            out,
            "<h3>{}</h3>{full_row}</div>{crop_row}</div>",
            escape(name)
        );
    }
    Ok(out)
}

pub(super) fn synthetic_section(opts: &ReportOptions, dir: &Path) -> Result<String, ReportError> {
    let set: SyntheticSet = artifacts::read_json(&dir.join(artifacts::files::SYNTHETIC))?;
    let mut out = String::from("<h2 id=\"synthetic\">Synthetic views and confidence</h2>");
    let n = set.views.len();
    let _ = write!(
        out,
        "<p class=\"note\">{n} synthetic views (ensemble median targets); confidence w = (1 − V<sub>norm</sub>)<sup>γ</sup> shown from 0 (dark purple) to 1 (yellow).</p>"
    );
    let k = opts.max_synthetic.min(n);
    for i in 0..k {
        // Evenly spaced picks, deterministic.
        let v = &set.views[if k <= 1 { 0 } else { i * (n - 1) / (k - 1) }];
        let px = v.read(dir)?;
        let (target, w) = (px.target, px.weight.as_slice());
        let conf = html::confidence_colormap(w, target.width, target.height);
        let mean = if w.is_empty() {
            0.0
        } else {
            v.weight_sum / w.len() as f64
        };
        let zoom = (opts.image_width / target.width.max(1)).clamp(1, 8);
        let show_w = target.width * zoom;
        let _ = write!(
            out,
            "<div class=\"row\">{}{}</div>",
            figure(
                &html::png_data_uri(&target)?,
                &format!("{} target", v.name),
                show_w,
                "px"
            ),
            figure(
                &html::png_data_uri(&conf)?,
                &format!("{} confidence (mean {mean:.2})", v.name),
                show_w,
                "px"
            ),
        );
    }
    Ok(out)
}
