//! The `OptimizeSplats` node kind and the family's `register`.
//!
//! Inputs: `train` (scene folder), `test` (scene folder of held-out views), optional
//! `synthetic` (a `SyntheticSet` folder; required by the Staged and Dual schedules), optional
//! `lpips` (a folder holding `lpips_{alex,vgg}_v0.1.safetensors`, or the file itself).
//! Output `model`: `final.ply`, `best.ply`, `curve.json` ([`TrainingCurve`](augsplat_core::artifacts::TrainingCurve)) and `best.json`
//! ([`BestRecord`]).
//!
//! The best checkpoint is chosen by the lowest held-out average error when LPIPS weights are
//! connected, else by the highest PSNR (`best.json` says which). Wall-clock seconds are
//! logged, and written into `curve.json` only with `record_wall_time` (default off), because
//! outputs must be byte-identical for identical args and inputs.

pub use crate::fit::BestRecord;
use crate::fit::{self, FitEvent};
use crate::inputs::{self, InputDirs, TrainingInputs};
use crate::train::TrainArgs;
use crate::Device;
use augsplat_graph::{InputDecl, Node, NodeError, Registry, RunContext, Threads};

/// Registers the splatting family's node kinds.
pub fn register(registry: &mut Registry) {
    registry.register::<OptimizeSplats>();
}

/// The Gaussian optimisation node (baseline 3DGS, Staged and Dual AugSplat schedules): an
/// adapter over [`crate::inputs`] and [`crate::fit`].
pub struct OptimizeSplats;

impl Node for OptimizeSplats {
    const KIND: &'static str = "OptimizeSplats";
    const VERSION: u32 = 7;
    type Args = TrainArgs;

    fn inputs(_args: &TrainArgs) -> Vec<InputDecl> {
        vec![
            InputDecl::one("train"),
            InputDecl::one("test"),
            InputDecl::optional("synthetic"),
            InputDecl::optional("lpips"),
            InputDecl::optional("init_depth"),
        ]
    }
    fn outputs(_args: &TrainArgs) -> Vec<String> {
        vec!["model".into()]
    }
    fn threads(_args: &TrainArgs) -> Threads {
        Threads::All
    }
    fn validate(args: &TrainArgs) -> Result<(), String> {
        args.validate()
    }

    fn run(a: &TrainArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let dirs = InputDirs {
            train: ctx.input("train")?,
            test: ctx.input("test")?,
            synthetic: ctx.optional_input("synthetic"),
            lpips: ctx.optional_input("lpips"),
            init_depth: ctx.optional_input("init_depth"),
        };
        let inputs = TrainingInputs::load(a, &dirs, &mut |line| ctx.log(line))?;
        let (sscale, start) = inputs::initial_state(a, &inputs.real, &dirs)?;
        if let Some(note) = &start.note {
            ctx.log(note);
            if let Some(warning) = start.terminal_warning() {
                // On the terminal too: such a start can silently ruin the run.
                eprintln!("warning: {}: {warning}", ctx.node_name());
            }
        }
        ctx.log(inputs.summary(a, start.gaussians.len(), sscale));
        let device =
            Device::open(a.backend).map_err(|e| NodeError::new(format!("backend: Gpu: {e}")))?;
        if let Some(adapter) = device.adapter() {
            ctx.log(format!(
                "rendering and back-propagating on the GPU: {adapter}"
            ));
        }
        let mut save = |bytes: Vec<u8>| {
            ctx.save_checkpoint(&bytes)
                .map_err(|e| e.message().to_string())
        };
        let checkpoints = ctx.checkpoint_every().map(|every| fit::FitCheckpoints {
            every,
            resume: ctx.load_checkpoint(),
            save: &mut save,
        });
        let fitted = fit::fit(
            a,
            start.gaussians,
            sscale,
            &inputs.real,
            inputs.synthetic.as_ref(),
            &inputs.test,
            inputs.lpips.as_ref(),
            &device,
            checkpoints,
            &mut |e| report(ctx, e),
        )?;
        for (name, value) in fitted.timing.measures(fitted.steps_run) {
            ctx.measure(name, value);
        }
        fit::write_model(ctx.output("model")?, &fitted, device.adapter())?;
        ctx.log(format!(
            "done: {} steps in {:.1} s",
            fitted.steps_run, fitted.seconds
        ));
        Ok(())
    }
}

/// A training event in the node's log or progress.
fn report(ctx: &RunContext, e: FitEvent) {
    match e {
        FitEvent::Log(line) => ctx.log(line),
        FitEvent::Progress {
            done,
            total,
            message,
        } => ctx.progress(done, total, &message),
    }
}
