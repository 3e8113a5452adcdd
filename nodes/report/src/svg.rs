//! A small SVG plotting module: line charts, labelled scatter plots with a Pareto front, and
//! horizontal stacked bar charts. Output is a self-contained `<svg>` element (no scripts, no
//! external fonts or styles), deterministic for the same input, suitable for inlining in HTML.
//!
//! Non-finite data points are skipped; a chart without finite data shows "no data".

use std::fmt::Write as _;

/// Series colours (Tableau 10), used in order.
pub const PALETTE: [&str; 10] = [
    "#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7",
    "#9c755f", "#bab0ac",
];

/// The colour of series `i`.
pub fn color(i: usize) -> &'static str {
    PALETTE[i % PALETTE.len()]
}

/// Frame and labels of a chart.
#[derive(Clone, Debug)]
pub struct Chart {
    /// Title above the plot area.
    pub title: String,
    /// Label under the x axis.
    pub x_label: String,
    /// Label beside the y axis.
    pub y_label: String,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

impl Chart {
    /// A chart of the default size (480 × 300).
    pub fn new(title: &str, x_label: &str, y_label: &str) -> Chart {
        Chart {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            width: 480,
            height: 300,
        }
    }
}

/// A named sequence of (x, y) points.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// The points, drawn in order.
    pub points: Vec<(f64, f64)>,
}

/// A labelled point of a scatter plot.
#[derive(Clone, Debug, PartialEq)]
pub struct LabeledPoint {
    /// Text beside the marker.
    pub label: String,
    /// Colour group (index into [`PALETTE`]).
    pub group: usize,
    /// x value.
    pub x: f64,
    /// y value.
    pub y: f64,
}

/// Escapes text for XML/HTML content and attribute values.
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for ch in s.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c if (c as u32) < 0x20 && c != '\n' && c != '\t' => {}
            c => out.push(c),
        }
    }
    out
}

/// "Nice" tick values (1, 2, 5 × 10^k steps) covering `[lo, hi]` with at most about
/// `max_ticks` ticks. Returns (ticks, step). A degenerate or non-finite range gives one tick.
pub fn nice_ticks(lo: f64, hi: f64, max_ticks: usize) -> (Vec<f64>, f64) {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo || max_ticks < 2 {
        let v = if lo.is_finite() { lo } else { 0.0 };
        return (vec![v], 1.0);
    }
    let raw = (hi - lo) / (max_ticks - 1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let norm = raw / mag;
    let step = mag
        * if norm <= 1.0 {
            1.0
        } else if norm <= 2.0 {
            2.0
        } else if norm <= 5.0 {
            5.0
        } else {
            10.0
        };
    let first = (lo / step).ceil();
    let last = (hi / step).floor();
    let mut ticks = Vec::new();
    let mut k = first;
    while k <= last + 1e-9 && ticks.len() < 100 {
        let v = k * step;
        ticks.push(if v.abs() < step * 1e-9 { 0.0 } else { v });
        k += 1.0;
    }
    (ticks, step)
}

/// Formats a tick value with as many decimals as the step needs.
pub fn format_tick(v: f64, step: f64) -> String {
    let decimals = if step >= 1.0 || step <= 0.0 || !step.is_finite() {
        0
    } else {
        (-step.log10().floor()) as usize
    };
    let decimals = decimals.min(8);
    if v.abs() >= 1e6 || (v != 0.0 && v.abs() < 1e-4) {
        return format!("{v:.2e}");
    }
    format!("{v:.decimals$}")
}

/// Range of finite values, padded by 5 % (a single value gets ±5 % or ±1).
fn padded_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if lo > hi {
        return None;
    }
    if hi == lo {
        let d = if lo == 0.0 { 1.0 } else { lo.abs() * 0.05 };
        return Some((lo - d, hi + d));
    }
    let pad = (hi - lo) * 0.05;
    Some((lo - pad, hi + pad))
}

/// Geometry of the plot area and the data-to-pixel maps.
struct Frame {
    left: f64,
    top: f64,
    right: f64,
    bottom: f64,
    x: (f64, f64),
    y: (f64, f64),
}

impl Frame {
    fn new(chart: &Chart, x: (f64, f64), y: (f64, f64), right_margin: f64) -> Frame {
        Frame {
            left: 62.0,
            top: 34.0,
            right: chart.width as f64 - right_margin,
            bottom: chart.height as f64 - 46.0,
            x,
            y,
        }
    }
    fn px(&self, v: f64) -> f64 {
        self.left + (v - self.x.0) / (self.x.1 - self.x.0) * (self.right - self.left)
    }
    fn py(&self, v: f64) -> f64 {
        self.bottom - (v - self.y.0) / (self.y.1 - self.y.0) * (self.bottom - self.top)
    }
}

fn open_svg(out: &mut String, chart: &Chart, class: &str) {
    let _ = write!(
        out,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" class=\"plot {class}\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" role=\"img\" font-family=\"sans-serif\" font-size=\"11\">",
        w = chart.width,
        h = chart.height
    );
    let _ = write!(out, "<title>{}</title>", escape(&chart.title));
    let _ = write!(
        out,
        "<rect x=\"0\" y=\"0\" width=\"{}\" height=\"{}\" fill=\"#ffffff\"/>",
        chart.width, chart.height
    );
    let _ = write!(
        out,
        "<text x=\"{}\" y=\"18\" text-anchor=\"middle\" font-size=\"13\" font-weight=\"bold\">{}</text>",
        chart.width as f64 / 2.0,
        escape(&chart.title)
    );
}

fn no_data(out: &mut String, chart: &Chart) {
    let _ = write!(
        out,
        "<text class=\"no-data\" x=\"{}\" y=\"{}\" text-anchor=\"middle\" fill=\"#888\">no data</text></svg>",
        chart.width as f64 / 2.0,
        chart.height as f64 / 2.0
    );
}

fn axes(out: &mut String, chart: &Chart, f: &Frame) {
    let (xt, xs) = nice_ticks(f.x.0, f.x.1, 6);
    let (yt, ys) = nice_ticks(f.y.0, f.y.1, 6);
    out.push_str("<g class=\"grid\" stroke=\"#e4e4e4\" stroke-width=\"1\">");
    for &t in &yt {
        let y = f.py(t);
        let _ = write!(
            out,
            "<line x1=\"{:.1}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\"/>",
            f.left, f.right
        );
    }
    for &t in &xt {
        let x = f.px(t);
        let _ = write!(
            out,
            "<line x1=\"{x:.1}\" y1=\"{:.1}\" x2=\"{x:.1}\" y2=\"{:.1}\"/>",
            f.top, f.bottom
        );
    }
    out.push_str("</g>");
    let _ = write!(
        out,
        "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"none\" stroke=\"#444\"/>",
        f.left,
        f.top,
        f.right - f.left,
        f.bottom - f.top
    );
    out.push_str("<g class=\"ticks\" fill=\"#333\">");
    for &t in &xt {
        let _ = write!(
            out,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
            f.px(t),
            f.bottom + 14.0,
            format_tick(t, xs)
        );
    }
    for &t in &yt {
        let _ = write!(
            out,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>",
            f.left - 5.0,
            f.py(t) + 4.0,
            format_tick(t, ys)
        );
    }
    out.push_str("</g>");
    let _ = write!(
        out,
        "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
        (f.left + f.right) / 2.0,
        chart.height as f64 - 12.0,
        escape(&chart.x_label)
    );
    let cy = (f.top + f.bottom) / 2.0;
    let _ = write!(
        out,
        "<text x=\"14\" y=\"{cy:.1}\" text-anchor=\"middle\" transform=\"rotate(-90 14 {cy:.1})\">{}</text>",
        escape(&chart.y_label)
    );
}

fn legend(out: &mut String, f: &Frame, labels: &[(usize, &str)]) {
    out.push_str("<g class=\"legend\">");
    for (row, (color_index, label)) in labels.iter().enumerate() {
        let y = f.top + 8.0 + row as f64 * 15.0;
        let x = f.right + 8.0;
        let _ = write!(
            out,
            "<rect x=\"{x:.1}\" y=\"{:.1}\" width=\"12\" height=\"3\" fill=\"{}\"/><text x=\"{:.1}\" y=\"{:.1}\">{}</text>",
            y - 2.0,
            color(*color_index),
            x + 16.0,
            y + 2.0,
            escape(label)
        );
    }
    out.push_str("</g>");
}

/// Legend width for these labels (approximate text metrics).
fn legend_width(labels: &[&str]) -> f64 {
    let longest = labels.iter().map(|l| l.chars().count()).max().unwrap_or(0);
    (longest as f64 * 6.5 + 30.0).clamp(40.0, 200.0)
}

/// A line chart: one polyline (with point markers) per series, a legend on the right.
pub fn line_chart(chart: &Chart, series: &[Series]) -> String {
    let mut out = String::new();
    open_svg(&mut out, chart, "line-chart");
    let finite = |&(x, y): &(f64, f64)| x.is_finite() && y.is_finite();
    let xs = padded_range(
        series
            .iter()
            .flat_map(|s| s.points.iter().filter(|p| finite(p)).map(|p| p.0)),
    );
    let ys = padded_range(
        series
            .iter()
            .flat_map(|s| s.points.iter().filter(|p| finite(p)).map(|p| p.1)),
    );
    let (Some(xr), Some(yr)) = (xs, ys) else {
        no_data(&mut out, chart);
        return out;
    };
    let labels: Vec<&str> = series.iter().map(|s| s.label.as_str()).collect();
    let f = Frame::new(chart, xr, yr, legend_width(&labels) + 10.0);
    axes(&mut out, chart, &f);
    for (i, s) in series.iter().enumerate() {
        let pts: Vec<(f64, f64)> = s.points.iter().copied().filter(finite).collect();
        if pts.is_empty() {
            continue;
        }
        let _ = write!(
            out,
            "<g class=\"series\" data-label=\"{}\" stroke=\"{c}\" fill=\"{c}\">",
            escape(&s.label),
            c = color(i)
        );
        let mut d = String::new();
        for (k, (x, y)) in pts.iter().enumerate() {
            let _ = write!(
                d,
                "{}{:.1},{:.1}",
                if k == 0 { "M" } else { " L" },
                f.px(*x),
                f.py(*y)
            );
        }
        let _ = write!(out, "<path d=\"{d}\" fill=\"none\" stroke-width=\"1.8\"/>");
        for (x, y) in &pts {
            let _ = write!(
                out,
                "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"2.2\" stroke=\"none\"/>",
                f.px(*x),
                f.py(*y)
            );
        }
        out.push_str("</g>");
    }
    let entries: Vec<(usize, &str)> = labels.iter().copied().enumerate().collect();
    legend(&mut out, &f, &entries);
    out.push_str("</svg>");
    out
}

/// Indices of the Pareto-optimal points when both x and y are minimised (for y maximised,
/// negate it). Ties in x keep the lower y; sorted by x. Non-finite points are never optimal.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len())
        .filter(|&i| points[i].0.is_finite() && points[i].1.is_finite())
        .collect();
    order.sort_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[a].1.total_cmp(&points[b].1))
            .then(a.cmp(&b))
    });
    let mut front = Vec::new();
    let mut best_y = f64::INFINITY;
    for i in order {
        if points[i].1 < best_y {
            best_y = points[i].1;
            front.push(i);
        }
    }
    front
}

/// A scatter plot of labelled points with the Pareto front drawn as a dashed step line
/// (x minimised; y minimised when `minimize_y`, else maximised). Legend: one entry per group
/// name in `groups`.
pub fn scatter_chart(
    chart: &Chart,
    points: &[LabeledPoint],
    groups: &[String],
    minimize_y: bool,
) -> String {
    let mut out = String::new();
    open_svg(&mut out, chart, "scatter-chart");
    let ok: Vec<&LabeledPoint> = points
        .iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite())
        .collect();
    let (Some(xr), Some(yr)) = (
        padded_range(ok.iter().map(|p| p.x)),
        padded_range(ok.iter().map(|p| p.y)),
    ) else {
        no_data(&mut out, chart);
        return out;
    };
    let labels: Vec<&str> = groups.iter().map(String::as_str).collect();
    let f = Frame::new(chart, xr, yr, legend_width(&labels) + 10.0);
    axes(&mut out, chart, &f);
    let sign = if minimize_y { 1.0 } else { -1.0 };
    let xy: Vec<(f64, f64)> = ok.iter().map(|p| (p.x, sign * p.y)).collect();
    let front = pareto_front(&xy);
    if !front.is_empty() {
        let mut d = String::new();
        for (k, &i) in front.iter().enumerate() {
            let (x, y) = (f.px(ok[i].x), f.py(ok[i].y));
            if k == 0 {
                let _ = write!(d, "M{x:.1},{y:.1}");
            } else {
                let prev_y = f.py(ok[front[k - 1]].y);
                let _ = write!(d, " L{x:.1},{prev_y:.1} L{x:.1},{y:.1}");
            }
        }
        let _ = write!(
            out,
            "<path class=\"pareto\" d=\"{d}\" fill=\"none\" stroke=\"#888\" stroke-dasharray=\"4 3\"/>"
        );
    }
    out.push_str("<g class=\"points\">");
    for (i, p) in ok.iter().enumerate() {
        let on_front = front.contains(&i);
        let _ = write!(
            out,
            "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"{}\" fill=\"{}\" stroke=\"#222\" stroke-width=\"{}\"><title>{}</title></circle><text x=\"{:.1}\" y=\"{:.1}\" font-size=\"10\" fill=\"#333\">{}</text>",
            f.px(p.x),
            f.py(p.y),
            if on_front { 5 } else { 4 },
            color(p.group),
            if on_front { "1.5" } else { "0.5" },
            escape(&p.label),
            f.px(p.x) + 6.0,
            f.py(p.y) - 5.0,
            escape(&p.label)
        );
    }
    out.push_str("</g>");
    let entries: Vec<(usize, &str)> = labels.iter().copied().enumerate().collect();
    legend(&mut out, &f, &entries);
    out.push_str("</svg>");
    out
}

/// A horizontal stacked bar chart: one bar per category, one segment per stack (values ≥ 0;
/// negative or non-finite values count as 0). `stacks` = (segment name, value per category).
pub fn bar_chart(chart: &Chart, categories: &[String], stacks: &[(String, Vec<f64>)]) -> String {
    let mut out = String::new();
    let bar_h = 18.0;
    let height = (categories.len() as f64 * (bar_h + 8.0) + 90.0).max(chart.height as f64);
    let chart = Chart {
        height: height as u32,
        ..chart.clone()
    };
    open_svg(&mut out, &chart, "bar-chart");
    let val = |s: usize, c: usize| -> f64 {
        stacks[s]
            .1
            .get(c)
            .copied()
            .filter(|v| v.is_finite() && *v > 0.0)
            .unwrap_or(0.0)
    };
    let totals: Vec<f64> = (0..categories.len())
        .map(|c| (0..stacks.len()).map(|s| val(s, c)).sum())
        .collect();
    let max = totals.iter().copied().fold(0.0, f64::max);
    if categories.is_empty() || max <= 0.0 {
        no_data(&mut out, &chart);
        return out;
    }
    let names: Vec<&str> = stacks.iter().map(|s| s.0.as_str()).collect();
    let label_w = categories
        .iter()
        .map(|c| c.chars().count())
        .max()
        .unwrap_or(0) as f64
        * 6.5
        + 10.0;
    let mut f = Frame::new(
        &chart,
        (0.0, max * 1.05),
        (0.0, 1.0),
        legend_width(&names) + 10.0,
    );
    f.left = label_w.clamp(62.0, 220.0);
    let (xt, xs) = nice_ticks(0.0, max * 1.05, 6);
    out.push_str("<g class=\"grid\" stroke=\"#e4e4e4\">");
    for &t in &xt {
        let _ = write!(
            out,
            "<line x1=\"{x:.1}\" y1=\"{:.1}\" x2=\"{x:.1}\" y2=\"{:.1}\"/>",
            f.top,
            f.bottom,
            x = f.px(t)
        );
    }
    out.push_str("</g><g class=\"ticks\" fill=\"#333\">");
    for &t in &xt {
        let _ = write!(
            out,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
            f.px(t),
            f.bottom + 14.0,
            format_tick(t, xs)
        );
    }
    out.push_str("</g>");
    let _ = write!(
        out,
        "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
        (f.left + f.right) / 2.0,
        chart.height as f64 - 12.0,
        escape(&chart.x_label)
    );
    for (c, cat) in categories.iter().enumerate() {
        let y = f.top + 6.0 + c as f64 * (bar_h + 8.0);
        let _ = write!(
            out,
            "<g class=\"bar\" data-label=\"{}\"><text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>",
            escape(cat),
            f.left - 5.0,
            y + bar_h / 2.0 + 4.0,
            escape(cat)
        );
        let mut x0 = 0.0;
        for (s, (stack_name, _)) in stacks.iter().enumerate() {
            let v = val(s, c);
            if v <= 0.0 {
                continue;
            }
            let _ = write!(
                out,
                "<rect x=\"{:.1}\" y=\"{y:.1}\" width=\"{:.1}\" height=\"{bar_h}\" fill=\"{}\"><title>{}: {}: {:.2}</title></rect>",
                f.px(x0),
                f.px(x0 + v) - f.px(x0),
                color(s),
                escape(cat),
                escape(stack_name),
                v
            );
            x0 += v;
        }
        let _ = write!(
            out,
            "<text x=\"{:.1}\" y=\"{:.1}\" font-size=\"10\">{:.1}</text></g>",
            f.px(x0) + 4.0,
            y + bar_h / 2.0 + 4.0,
            totals[c]
        );
    }
    let entries: Vec<(usize, &str)> = names.iter().copied().enumerate().collect();
    legend(&mut out, &f, &entries);
    out.push_str("</svg>");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_ticks_golden() {
        assert_eq!(
            nice_ticks(0.0, 10.0, 6).0,
            vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]
        );
        let (t, s) = nice_ticks(0.12, 0.57, 6);
        assert_eq!(s, 0.1);
        assert_eq!(t.len(), 4);
        assert!((t[0] - 0.2).abs() < 1e-12 && (t[3] - 0.5).abs() < 1e-12);
        assert_eq!(nice_ticks(3.0, 3.0, 6).0, vec![3.0]);
        assert_eq!(nice_ticks(f64::NAN, 1.0, 6).0, vec![0.0]);
        assert_eq!(format_tick(0.30000000000000004, 0.1), "0.3");
        assert_eq!(format_tick(1500.0, 500.0), "1500");
    }

    #[test]
    fn pareto_front_golden() {
        // (time, error): 0 dominates 3; 1 and 2 trade off; 4 is NaN.
        let pts = [
            (1.0, 0.5),
            (2.0, 0.3),
            (4.0, 0.2),
            (3.0, 0.6),
            (f64::NAN, 0.0),
        ];
        assert_eq!(pareto_front(&pts), vec![0, 1, 2]);
        assert_eq!(pareto_front(&[]), Vec::<usize>::new());
        // Equal x: only the lower y is optimal.
        assert_eq!(pareto_front(&[(1.0, 0.5), (1.0, 0.4)]), vec![1]);
    }

    #[test]
    fn line_chart_draws_one_path_per_series_and_escapes() {
        let s = vec![
            Series {
                label: "3DGS <base>".into(),
                points: vec![(100.0, 15.0), (200.0, 16.0), (300.0, f64::NAN)],
            },
            Series {
                label: "Dual".into(),
                points: vec![(100.0, 15.5), (200.0, 16.8)],
            },
        ];
        let svg = line_chart(&Chart::new("PSNR", "step", "dB"), &s);
        assert!(svg.starts_with("<svg") && svg.ends_with("</svg>"));
        assert_eq!(svg.matches("class=\"series\"").count(), 2);
        assert_eq!(svg.matches("<path").count(), 2);
        assert_eq!(
            svg.matches("<circle").count(),
            4,
            "the NaN point is skipped"
        );
        assert!(svg.contains("3DGS &lt;base&gt;"));
        assert!(!svg.contains("NaN"));
        let empty = line_chart(&Chart::new("x", "", ""), &[]);
        assert!(empty.contains("no data"));
    }

    #[test]
    fn scatter_and_bars_render() {
        let pts = vec![
            LabeledPoint {
                label: "a".into(),
                group: 0,
                x: 10.0,
                y: 0.2,
            },
            LabeledPoint {
                label: "b".into(),
                group: 1,
                x: 20.0,
                y: 0.1,
            },
            LabeledPoint {
                label: "c".into(),
                group: 1,
                x: 30.0,
                y: 0.3,
            },
        ];
        let svg = scatter_chart(
            &Chart::new("t", "s", "e"),
            &pts,
            &["g0".into(), "g1".into()],
            true,
        );
        assert_eq!(svg.matches("<circle").count(), 3);
        assert!(svg.contains("class=\"pareto\""));
        let svg = bar_chart(
            &Chart::new("t", "seconds", ""),
            &["m1".into(), "m2".into()],
            &[
                ("train".into(), vec![5.0, 7.0]),
                ("eval".into(), vec![1.0, f64::NAN]),
            ],
        );
        assert_eq!(svg.matches("class=\"bar\"").count(), 2);
        assert_eq!(
            svg.matches("<rect").count(),
            1 + 3 + 2,
            "background, segments, legend"
        );
        assert!(bar_chart(&Chart::new("t", "", ""), &[], &[]).contains("no data"));
    }
}
