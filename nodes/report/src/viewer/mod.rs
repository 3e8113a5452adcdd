//! The interactive 3-D viewer: a self-contained WebGL2 splat renderer (no CDN, no server)
//! that the `Report` page embeds and `augsplat view` writes as a page of its own.
//!
//! - [`pack`](mod@pack): the models, quantised to 24 bytes per Gaussian (degree-0 colour);
//! - `viewer.js`: decoding, a back-to-front sort per frame, the splat shaders (the CPU
//!   rasteriser's projection, cutoffs and clamps, in f32), orbit / pan / zoom / fly controls,
//!   camera frusta (training blue, held-out orange; click one to jump to it), synchronised
//!   side-by-side panes (one per model, and the ground truth at held-out cameras).
//!
//! The page needs WebGL2 (every current browser; headless Chromium's software rasteriser
//! too). Frames are drawn on demand, after an interaction, not continuously.

pub mod pack;

use crate::html::escape;
use augsplat_core::Camera;
pub use pack::{pack, PackedModel, BYTES_PER_GAUSSIAN};
use serde_json::json;

/// The viewer's script.
const SCRIPT: &str = include_str!("viewer.js");

/// The viewer's style (scoped to `.viewer`).
const STYLE: &str = ".viewer{margin:12px 0}.viewer-bar{display:flex;flex-wrap:wrap;gap:12px;align-items:center;font-size:.9em;margin-bottom:6px}\
.viewer-help{color:#666}.viewer-status{color:#333;font-weight:bold}\
.viewer-panes{display:flex;flex-wrap:wrap;gap:8px}.viewer-pane{flex:1 1 0;min-width:220px;max-width:100%}\
.viewer-pane canvas,.viewer-pane img{width:100%;height:auto;display:block;background:#000;outline:none}\
.viewer-label{font-size:.85em;color:#444;margin:2px 0}.viewer-gt-note{color:#777;font-size:.85em;padding:24px 8px;border:1px dashed #bbb}";

/// Default cap on the Gaussians of one pane (24 MB of payload).
pub const DEFAULT_MAX_GAUSSIANS: usize = 1_000_000;

/// One pane: a labelled model.
#[derive(Clone, Debug)]
pub struct ViewerModel {
    /// The pane's title (the method).
    pub label: String,
    /// The quantised model.
    pub packed: PackedModel,
}

/// A camera drawn as a frustum and offered as a viewpoint.
#[derive(Clone, Debug)]
pub struct ViewerCamera {
    /// The view's name.
    pub name: String,
    /// Held out (drawn orange, has a ground-truth pane) or training (blue).
    pub held_out: bool,
    /// The camera.
    pub camera: Camera,
    /// The ground truth at this camera, as a `data:` URI, if any.
    pub ground_truth: Option<String>,
}

/// The viewer's data as JSON, safe to embed in a `<script>` element.
fn data_json(models: &[ViewerModel], cameras: &[ViewerCamera], background: [f32; 3]) -> String {
    let models: Vec<_> = models
        .iter()
        .map(|m| {
            json!({
                "label": m.label,
                "count": m.packed.count,
                "total": m.packed.total,
                "bounds": m.packed.bounds,
                "payload": crate::html::base64(&m.packed.payload),
            })
        })
        .collect();
    let cameras: Vec<_> = cameras
        .iter()
        .map(|c| {
            let (r, t) = augsplat_core::linalg::rt_from_mat4(&c.camera.world_to_camera);
            json!({
                "name": c.name,
                "held_out": c.held_out,
                "width": c.camera.width,
                "height": c.camera.height,
                "fx": c.camera.fx,
                "fy": c.camera.fy,
                "cx": c.camera.cx,
                "cy": c.camera.cy,
                "R": r.iter().flatten().collect::<Vec<_>>(),
                "t": t,
                "gt": c.ground_truth,
            })
        })
        .collect();
    let v = json!({
        "version": 1,
        "background": background,
        "models": models,
        "cameras": cameras,
    });
    // `</` would end the script element and `<!--` could open a comment state: inside JSON
    // (only in strings), `<` can always be written `\u003c`.
    v.to_string().replace('<', "\\u003c")
}

/// The viewer as an HTML fragment (a `<section>` with its style, data and script).
pub fn viewer_section(
    models: &[ViewerModel],
    cameras: &[ViewerCamera],
    background: [f32; 3],
) -> String {
    format!(
        "<section class=\"viewer\" id=\"augsplat-viewer\"><style>{STYLE}</style>\
<div class=\"viewer-bar\"><label>camera <select class=\"viewer-camera\"></select></label>\
<label><input type=\"checkbox\" class=\"viewer-frusta\" checked> frusta</label>\
<span class=\"viewer-help\">drag: orbit · shift- or right-drag: pan · wheel: zoom · click a canvas, then W A S D Q E: fly · click a frustum: jump to its camera</span>\
<span class=\"viewer-status\"></span></div><div class=\"viewer-panes\"></div>\
<script type=\"application/json\" id=\"augsplat-viewer-data\">{data}</script><script>{SCRIPT}</script></section>",
        data = data_json(models, cameras, background),
    )
}

/// A whole page holding only the viewer (what `augsplat view` writes).
pub fn viewer_page(
    title: &str,
    models: &[ViewerModel],
    cameras: &[ViewerCamera],
    background: [f32; 3],
) -> String {
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\
<style>body{{font-family:system-ui,sans-serif;margin:16px;color:#222}}h1{{font-size:1.3em}}</style></head>\
<body><h1>{t}</h1>{section}</body></html>\n",
        t = escape(title),
        section = viewer_section(models, cameras, background),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_cannot_close_the_script_element() {
        let cam = ViewerCamera {
            name: "</script><script>alert(1)</script><!--".into(),
            held_out: true,
            camera: augsplat_core::Camera {
                width: 4,
                height: 3,
                fx: 4.0,
                fy: 4.0,
                cx: 2.0,
                cy: 1.5,
                world_to_camera: augsplat_core::linalg::mat4_from_rt(
                    &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                    [0.0; 3],
                ),
            },
            ground_truth: None,
        };
        let html = viewer_section(&[], &[cam], [0.0; 3]);
        assert_eq!(html.matches("</script>").count(), 2, "{html}");
        assert!(!html.contains("<!--"));
        let start = html.find("augsplat-viewer-data\">").unwrap() + 22;
        let end = start + html[start..].find("</script>").unwrap();
        let v: serde_json::Value = serde_json::from_str(&html[start..end]).unwrap();
        assert_eq!(
            v["cameras"][0]["name"],
            "</script><script>alert(1)</script><!--"
        );
        assert_eq!(v["cameras"][0]["R"].as_array().unwrap().len(), 9);
    }
}
