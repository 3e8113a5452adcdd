//! augsplat-report: how results are judged and shown.
//!
//! - [`select`]: best checkpoint of a training curve (lowest average error, PSNR fallback) and
//!   the lookup of every method at the baseline's best step, as AugSplat reports;
//! - [`evalset`]: the `eval` folder layout (`metrics.json`, `metrics.csv`, renders, ground truth,
//!   curve) shared by the `Evaluate` node, the `Report` node and `augsplat compare`;
//! - [`svg`]: a small deterministic SVG plotting module (line, scatter + Pareto front, bars);
//! - [`html`]: HTML helpers (escaping, base64 PNG data URIs, tables with the best value per
//!   column marked);
//! - [`evaluate`]: the `Evaluate` node (render held-out views, per-view/mean metrics);
//! - [`ensemble`]: the `EvaluateEnsemble` node (each radiance-field member and their per-pixel
//!   median on the held-out views);
//! - [`report`], [`node`]: the report builder and the `Report` node;
//! - [`gate`]: the `Gate` node (is a scene worth the ensemble and Staged/Dual? decided from
//!   training views only);
//! - [`compare`]: metric deltas across runs (ablation points);
//! - [`viewer`]: the interactive WebGL2 splat viewer of the report and `augsplat view`.

pub mod bench;
pub mod compare;
pub mod ensemble;
pub mod error;
pub mod evalset;
pub mod evaluate;
pub mod gate;
pub mod html;
pub mod node;
pub mod report;
pub mod select;
pub mod svg;
pub mod viewer;

pub use ensemble::EvaluateEnsembleNode;
pub use error::ReportError;
pub use evaluate::EvaluateNode;
pub use gate::GateNode;
/// The `Report` node's module under its former name (`augsplat_report::report_node::…` paths
/// still resolve); the module is [`node`], as in every node family.
pub use node as report_node;
pub use node::ReportNode;

/// Registers this family's node kinds (`Report`; `Evaluate`; `EvaluateEnsemble`; `Gate`) and the
/// installed resource `lpips` (pipelines connect it with `Installed("lpips")`).
pub fn register(registry: &mut augsplat_graph::Registry) {
    registry.register::<EvaluateNode>();
    registry.register::<EvaluateEnsembleNode>();
    registry.register::<ReportNode>();
    registry.register::<GateNode>();
    registry.register_resource("lpips", installed_lpips, evaluate::LPIPS_INSTALL_HINT);
}

/// Where LPIPS weights are installed: the file or folder `AUGSPLAT_LPIPS_WEIGHTS` names, else
/// the default folder when it holds a weight file, else the folder of the weights that ship with
/// the project (LPIPS-alex in float16, [`augsplat_metrics::lpips::bundled_dir`]).
/// `augsplat weights status` shows which.
pub fn installed_lpips() -> Option<std::path::PathBuf> {
    use augsplat_metrics::lpips::{bundled_dir, default_dir, Backbone, WEIGHTS_ENV};
    let holds_weights = |d: &std::path::Path| {
        [Backbone::Alex, Backbone::Vgg]
            .iter()
            .any(|b| d.join(b.file_name()).is_file())
    };
    if let Some(v) = std::env::var_os(WEIGHTS_ENV).filter(|v| !v.is_empty()) {
        let p = std::path::PathBuf::from(v);
        if p.exists() {
            return Some(p);
        }
    }
    default_dir()
        .filter(|d| holds_weights(d))
        .or_else(|| Some(bundled_dir()).filter(|d| holds_weights(d)))
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_former_module_name_still_resolves() {
        let _: fn() -> crate::report_node::ReportArgs = crate::node::ReportArgs::default;
        assert_eq!(crate::report_node::files::INDEX, crate::node::files::INDEX);
    }
}
