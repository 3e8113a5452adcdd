//! The `Report` node: a self-contained HTML page and a Markdown summary over several
//! evaluations (see [`crate::report`]).

use crate::evalset::EvalDir;
use crate::gate::GateReport;
use crate::report::{build_report, ReportOptions};
use augsplat_graph::gate::gated_reason;
use augsplat_graph::{InputDecl, Node, NodeError, RunContext};
use serde::{Deserialize, Serialize};

/// Args of [`ReportNode`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReportArgs {
    /// Page title.
    pub title: String,
    /// Number of test views shown side by side with zoomed crops.
    pub max_views: usize,
    /// Number of synthetic views shown with their confidence maps.
    pub max_synthetic: usize,
    /// Display width of full images, pixels.
    pub image_width: u32,
    /// Embed the interactive 3-D viewer of the evaluated models.
    pub viewer: bool,
    /// Cap on the Gaussians per viewer pane (the most opaque are kept; 24 bytes each).
    pub viewer_max_gaussians: usize,
}

impl Default for ReportArgs {
    fn default() -> Self {
        let o = ReportOptions::default();
        ReportArgs {
            title: o.title,
            max_views: o.max_views,
            max_synthetic: o.max_synthetic,
            image_width: o.image_width,
            viewer: o.viewer,
            viewer_max_gaussians: o.viewer_max_gaussians,
        }
    }
}

/// `Report`: inputs `evals` (a list of `Evaluate` outputs, in display order; the first one
/// places the zoomed crops), optional `synthetic` (a synthetic set for example views with
/// confidence maps), optional `train` (the training scene, whose cameras the 3-D viewer
/// draws) and optional `gate` (a `Gate`'s `evidence` output, shown with the decision);
/// evaluations and a synthetic set that a gate skipped are listed as skipped. Output `report`
/// with `index.html` (self-contained: no external files, the one script is the viewer's) and
/// `summary.md`.
pub struct ReportNode;

/// File names of the `report` output.
pub mod files {
    /// The HTML page.
    pub const INDEX: &str = "index.html";
    /// The Markdown summary.
    pub const SUMMARY: &str = "summary.md";
}

impl Node for ReportNode {
    const KIND: &'static str = "Report";
    const VERSION: u32 = 7;
    type Args = ReportArgs;

    fn inputs(_args: &ReportArgs) -> Vec<InputDecl> {
        vec![
            // A gate may skip methods (and the ensemble): the report still runs and says so.
            InputDecl::many("evals").accepting_gated(),
            InputDecl::optional("synthetic").accepting_gated(),
            InputDecl::optional("train"),
            InputDecl::optional("gate"),
        ]
    }
    fn outputs(_args: &ReportArgs) -> Vec<String> {
        vec!["report".into()]
    }
    fn validate(args: &ReportArgs) -> Result<(), String> {
        if args.image_width < 16 || args.image_width > 4096 {
            return Err(format!(
                "image_width {} must be within 16..=4096",
                args.image_width
            ));
        }
        if args.viewer_max_gaussians == 0 {
            return Err("viewer_max_gaussians must be at least 1 (use viewer: false to leave the viewer out)".into());
        }
        Ok(())
    }
    fn run(args: &ReportArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let mut evals = Vec::new();
        let mut gated_evals = Vec::new();
        for dir in ctx.input_list("evals")? {
            match gated_reason(dir) {
                Some(reason) => gated_evals.push(reason),
                None => evals.push(EvalDir::load(dir)?),
            }
        }
        let gate = match ctx.optional_input("gate") {
            Some(d) => Some(augsplat_core::artifacts::read_json::<GateReport>(
                &d.join(crate::gate::files::EVIDENCE),
            )?),
            None => None,
        };
        let opts = ReportOptions {
            title: args.title.clone(),
            max_views: args.max_views,
            max_synthetic: args.max_synthetic,
            image_width: args.image_width,
            viewer: args.viewer,
            viewer_max_gaussians: args.viewer_max_gaussians,
            train_scene: ctx.optional_input("train").map(|p| p.to_path_buf()),
            gate,
            gated_evals,
            ..ReportOptions::default()
        };
        let synthetic = ctx
            .optional_input("synthetic")
            .filter(|p| gated_reason(p).is_none())
            .map(|p| p.to_path_buf());
        let built = build_report(&opts, &evals, synthetic.as_deref())?;
        let out = ctx.output("report")?;
        let index = out.join(files::INDEX);
        std::fs::write(&index, built.html)
            .map_err(|e| NodeError::from(e).context(index.display()))?;
        let summary = out.join(files::SUMMARY);
        std::fs::write(&summary, built.markdown)
            .map_err(|e| NodeError::from(e).context(summary.display()))?;
        ctx.log(format!(
            "report over {} evaluation(s) written to {}",
            evals.len(),
            index.display()
        ));
        Ok(())
    }
}
