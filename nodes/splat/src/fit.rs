//! Training policy: a whole training run from loaded inputs to the kept checkpoints, as the
//! `OptimizeSplats` node runs it — and as benches and library users can run it without a
//! graph.
//!
//! - Inputs: [`crate::inputs`] loads them from folders ([`crate::inputs::TrainingInputs`]) and
//!   chooses the initial Gaussians ([`crate::inputs::initial_state`]).
//! - [`fit`]: steps the [`Trainer`]; evaluates the held-out views every `eval_every` steps and
//!   after the last step ([`evaluate`], the metrics of `augsplat_metrics::measure`); keeps the
//!   best checkpoint — the lowest average error when an LPIPS model is given, else the highest
//!   PSNR ([`Criterion`]); stops early after `early_stop_patience` evaluations without
//!   improvement. With `steps = 0` the initialisation itself is evaluated and kept.
//! - [`Fitted::best_record`]: the `best.json` record of the kept checkpoint.
//!
//! Wall-clock seconds enter the curve only with `record_wall_time`, so that a run's outputs
//! are byte-identical for identical arguments and inputs.

use crate::train::{
    evaluate, EvalError, Evaluation, RealImages, RealView, Supervision, SyntheticImages, TrainArgs,
    Trainer,
};
use crate::Gaussians;
use augsplat_core::artifacts::{self, CurvePoint, TrainingCurve};
use augsplat_graph::NodeError;
use augsplat_metrics::lpips::Lpips;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// How a checkpoint is chosen: by [`fit`] for the model it keeps, and by the evaluation's
/// best-step rule (serialised as `avg_error` / `psnr`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Criterion {
    /// The lowest held-out average error (the paper's rule; needs an LPIPS model).
    AvgError,
    /// The highest held-out PSNR (the fallback when the average error is unavailable).
    Psnr,
}

impl Criterion {
    /// `avg_error` or `psnr`, as `best.json` names it.
    pub fn name(self) -> &'static str {
        match self {
            Criterion::AvgError => "avg_error",
            Criterion::Psnr => "psnr",
        }
    }
    /// "average error" or "PSNR", for reports.
    pub fn describe(self) -> &'static str {
        match self {
            Criterion::AvgError => "average error",
            Criterion::Psnr => "PSNR",
        }
    }
    /// Whether evaluation `p` is better than the kept `best` (strictly; a missing average
    /// error counts as infinite).
    pub fn better(self, p: &CurvePoint, best: &CurvePoint) -> bool {
        match self {
            Criterion::AvgError => {
                p.avg_error.unwrap_or(f64::INFINITY) < best.avg_error.unwrap_or(f64::INFINITY)
            }
            Criterion::Psnr => p.psnr > best.psnr,
        }
    }
}

/// What [`fit`] reports while it runs.
#[derive(Clone, Debug, PartialEq)]
pub enum FitEvent {
    /// A line for the log (densification, evaluations, an early stop).
    Log(String),
    /// `done` of `total` steps are done.
    Progress {
        /// Steps done.
        done: u64,
        /// Steps requested.
        total: u64,
        /// In words.
        message: String,
    },
}

/// The outcome of [`fit`].
#[derive(Clone, Debug)]
pub struct Fitted {
    /// The Gaussians after the last step run.
    pub last: Gaussians,
    /// The kept checkpoint.
    pub best: Gaussians,
    /// The kept checkpoint's evaluation.
    pub best_point: CurvePoint,
    /// Every evaluation, in step order.
    pub curve: TrainingCurve,
    /// How the checkpoint was chosen.
    pub criterion: Criterion,
    /// Steps actually run (fewer than requested after an early stop).
    pub steps_run: u64,
    /// Whether training stopped early.
    pub early_stopped: bool,
    /// Scene scale used by the learning rates and densification.
    pub scene_scale: f64,
    /// Wall-clock seconds of the run.
    pub seconds: f64,
    /// What this process timed of the steps it ran, for the node's cache record (never an
    /// output: wall-clock figures would break the outputs' byte identity).
    pub timing: StepTiming,
}

/// Wall-clock seconds of the training steps one process ran, split by whether a step rendered
/// synthetic views, and where Dual's synthetic branch switched off. `augsplat bench` turns
/// them into the seconds the switch-off saved: the steps after it, each at the difference of
/// the two kinds' mean step times.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepTiming {
    /// Steps requested.
    pub steps_requested: u64,
    /// Steps timed that rendered synthetic views (with or without real ones).
    pub synthetic_steps: u64,
    /// Their seconds.
    pub synthetic_seconds: f64,
    /// Steps timed on real views alone.
    pub real_only_steps: u64,
    /// Their seconds.
    pub real_only_seconds: f64,
    /// Dual only: the steps done when its synthetic branch switched off (`off_below`) for the
    /// rest of the run, as this process saw it.
    pub synthetic_off_step: Option<u64>,
    /// Whether the last step timed rendered synthetic views.
    pub last_step_synthetic: bool,
}

impl StepTiming {
    /// Counts step `rep` that took `seconds`: real-only or with synthetic views, and for Dual
    /// (`dual`) the step its synthetic branch went off (`had_synthetic` remembers whether a
    /// synthetic step came before).
    pub fn record(
        &mut self,
        rep: &crate::train::StepReport,
        seconds: f64,
        dual: bool,
        had_synthetic: &mut bool,
    ) {
        self.last_step_synthetic = rep.synthetic_loss.is_some();
        if rep.synthetic_loss.is_some() {
            self.synthetic_steps += 1;
            self.synthetic_seconds += seconds;
            *had_synthetic = true;
            self.synthetic_off_step = None;
        } else {
            self.real_only_steps += 1;
            self.real_only_seconds += seconds;
            if dual && *had_synthetic && self.synthetic_off_step.is_none() {
                self.synthetic_off_step = Some(rep.step);
            }
        }
    }

    /// `(name, value)` pairs for [`augsplat_graph::RunContext::measure`].
    pub fn measures(&self, steps_run: u64) -> Vec<(&'static str, f64)> {
        let mut m = vec![
            ("steps_requested", self.steps_requested as f64),
            ("steps_run", steps_run as f64),
            ("synthetic_steps", self.synthetic_steps as f64),
            ("synthetic_step_seconds", self.synthetic_seconds),
            ("real_only_steps", self.real_only_steps as f64),
            ("real_only_step_seconds", self.real_only_seconds),
        ];
        if let Some(s) = self.synthetic_off_step {
            m.push(("synthetic_off_step", s as f64));
        }
        m.push((
            "last_step_synthetic",
            if self.last_step_synthetic { 1.0 } else { 0.0 },
        ));
        m
    }
}

/// `best.json`: the selected checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BestRecord {
    /// Method label.
    pub label: String,
    /// "avg_error" (lowest) or "psnr" (highest).
    pub criterion: String,
    /// Steps done at the checkpoint.
    pub step: u64,
    /// The evaluation there.
    pub point: CurvePoint,
    /// Steps actually run (less than requested after an early stop).
    pub steps_run: u64,
    /// Whether training stopped early.
    pub early_stopped: bool,
    /// Scene scale used by the learning rates and densification.
    pub scene_scale: f64,
}

impl Fitted {
    /// The `best.json` record of the kept checkpoint.
    pub fn best_record(&self) -> BestRecord {
        BestRecord {
            label: self.curve.label.clone(),
            criterion: self.criterion.name().into(),
            step: self.best_point.step,
            point: self.best_point.clone(),
            steps_run: self.steps_run,
            early_stopped: self.early_stopped,
            scene_scale: self.scene_scale,
        }
    }
}

fn point(step: u64, e: &Evaluation, primitives: usize, seconds: f64, loss: f64) -> CurvePoint {
    CurvePoint {
        step,
        psnr: e.psnr,
        ssim: e.ssim,
        lpips: e.lpips,
        mse: e.mse,
        avg_error: e.avg_error,
        primitives: primitives as u64,
        seconds,
        loss,
    }
}

/// Checkpoints of a [`fit`] run (the engine's `RunContext::save_checkpoint` /
/// `load_checkpoint` for the `OptimizeSplats` node).
pub struct FitCheckpoints<'a> {
    /// Save every this many steps (0: never).
    pub every: u64,
    /// A checkpoint an interrupted run of the same arguments and inputs saved, to continue
    /// from.
    pub resume: Option<Vec<u8>>,
    /// Stores one checkpoint (replacing the previous one).
    pub save: &'a mut dyn FnMut(Vec<u8>) -> Result<(), String>,
}

/// The training loop's own state beside the [`Trainer`]'s.
struct LoopState {
    curve: TrainingCurve,
    best: Option<(CurvePoint, Gaussians)>,
    since_best: u32,
    loss_acc: f64,
    loss_n: u64,
}

/// A checkpoint of a run of `steps` steps: the step count it was made for and the step it
/// reached come first, so a checkpoint of another run is refused before anything is restored.
fn write_checkpoint(trainer: &mut Trainer<'_>, st: &LoopState, steps: u64) -> Vec<u8> {
    use augsplat_core::state::StateWriter;
    let mut w = StateWriter::new();
    w.tag("fit-2");
    w.u64(steps);
    w.u64(trainer.steps_done());
    augsplat_core::state::write_curve(&mut w, &st.curve);
    w.u64(st.since_best as u64);
    w.f64(st.loss_acc);
    w.u64(st.loss_n);
    w.bool(st.best.is_some());
    if let Some((p, g)) = &st.best {
        augsplat_core::state::write_point(&mut w, p);
        g.write_state(&mut w);
    }
    trainer.write_state(&mut w);
    w.finish()
}

fn read_checkpoint(
    bytes: &[u8],
    trainer: &mut Trainer<'_>,
    steps: u64,
) -> Result<LoopState, augsplat_core::state::StateError> {
    use augsplat_core::state::{read_curve, read_point, StateError, StateReader};
    let mut r = StateReader::new(bytes);
    r.tag("fit-2")?;
    let made_for = r.u64()?;
    let reached = r.u64()?;
    if made_for != steps || reached > steps {
        return Err(StateError(format!(
            "it was made at step {reached} of a {made_for}-step run, and this run has {steps} \
             steps"
        )));
    }
    let curve = read_curve(&mut r)?;
    let since_best = r.u64()? as u32;
    let loss_acc = r.f64()?;
    let loss_n = r.u64()?;
    let best = if r.bool()? {
        let p = read_point(&mut r)?;
        Some((p, Gaussians::read_state(&mut r)?))
    } else {
        None
    };
    trainer.restore_state(&mut r)?;
    r.end()?;
    Ok(LoopState {
        curve,
        best,
        since_best,
        loss_acc,
        loss_n,
    })
}

/// Trains from `g0` on `real` (and `synthetic`, as the schedule of `args` mixes them) for
/// `args.steps` steps, evaluating on `test` (with `lpips` when given) every `args.eval_every`
/// steps and after the last one, keeping the best checkpoint and stopping early per
/// `args.early_stop_patience` (see the module documentation), on `device` (the host
/// evaluates). `on_event` receives the log lines and
/// progress. The curve's label is [`TrainArgs::method_label`]. With `checkpoints`, the whole
/// state is saved every `every` steps and a given checkpoint is continued from: the result is
/// the same, bit for bit, as a run that never stopped.
#[allow(clippy::too_many_arguments)]
pub fn fit(
    args: &TrainArgs,
    g0: Gaussians,
    scene_scale: f64,
    real: &RealImages,
    synthetic: Option<&SyntheticImages>,
    test: &[RealView],
    lpips: Option<&Lpips>,
    device: &crate::Device,
    checkpoints: Option<FitCheckpoints<'_>>,
    on_event: &mut dyn FnMut(FitEvent),
) -> Result<Fitted, EvalError> {
    let a = args;
    let label = a.method_label();
    let criterion = if lpips.is_some() {
        Criterion::AvgError
    } else {
        Criterion::Psnr
    };
    let mut trainer = Trainer::new(
        a.clone(),
        g0,
        scene_scale,
        real,
        synthetic.map(|s| s as &dyn Supervision),
    );
    for line in densify_notes(a, &trainer) {
        on_event(FitEvent::Log(line));
    }
    trainer.on_device(device);
    let mut st = LoopState {
        curve: TrainingCurve {
            label: label.clone(),
            points: Vec::new(),
        },
        best: None,
        since_best: 0,
        loss_acc: 0.0,
        loss_n: 0,
    };
    let (every, mut save) = match checkpoints {
        Some(c) => {
            if let Some(bytes) = c.resume {
                if let Some(resumed) = resume(&bytes, &mut trainer, a.steps, on_event) {
                    st = resumed;
                }
            }
            (c.every, Some(c.save))
        }
        None => (0, None),
    };
    let mut early = false;
    let t0 = std::time::Instant::now();
    let mut timing = StepTiming {
        steps_requested: a.steps,
        ..StepTiming::default()
    };
    let mut had_synthetic = false;
    // Only Dual switches a branch off to save time; Staged's switch is its method.
    let dual = matches!(a.schedule, crate::train::Schedule::Dual { .. });
    // The seconds of each step recorded and not yet reported, oldest first: on a GPU a
    // step's report comes back while the device runs the next one (`Trainer::advance`).
    let mut seconds = std::collections::VecDeque::new();
    while trainer.steps_done() < a.steps {
        let ts = std::time::Instant::now();
        let mut reports = trainer.advance();
        let done = trainer.steps_done();
        let eval_due = done.is_multiple_of(a.eval_every) || done == a.steps;
        let save_due = save.is_some() && every > 0 && done.is_multiple_of(every) && done < a.steps;
        if eval_due || save_due {
            // The curve's mean loss and a checkpoint count every step up to this one.
            reports.extend(trainer.finish_steps());
        }
        seconds.push_back(ts.elapsed().as_secs_f64());
        for rep in reports {
            let took = seconds.pop_front().unwrap_or_default();
            timing.record(&rep, took, dual, &mut had_synthetic);
            st.loss_acc += rep.loss;
            st.loss_n += 1;
            if let Some(line) = refine_line(rep.step + 1, &rep) {
                on_event(FitEvent::Log(line));
            }
        }
        if eval_due {
            let eval = Evaluating {
                args: a,
                test,
                lpips,
                criterion,
                started: t0,
            };
            if eval.run(&mut trainer, &mut st, on_event)? {
                early = true;
                break;
            }
        }
        if let Some(save) = save.as_mut().filter(|_| save_due) {
            let line = match save(write_checkpoint(&mut trainer, &st, a.steps)) {
                Ok(()) => format!("checkpoint at step {done}"),
                Err(e) => format!("warning: could not save the checkpoint at step {done}: {e}"),
            };
            on_event(FitEvent::Log(line));
        }
        on_event(FitEvent::Progress {
            done,
            total: a.steps,
            message: format!("{label} step {done}/{}", a.steps),
        });
    }
    let steps_run = trainer.steps_done();
    let LoopState {
        mut curve, best, ..
    } = st;
    let (best_point, best) = match best {
        Some(b) => b,
        None => {
            // steps = 0: evaluate the initialisation.
            let e = evaluate(trainer.gaussians(), test, &a.render_settings(0), lpips)?;
            let p = point(0, &e, trainer.primitives(), 0.0, 0.0);
            curve.points.push(p.clone());
            (p, trainer.gaussians().clone())
        }
    };
    Ok(Fitted {
        last: trainer.into_gaussians(),
        best,
        best_point,
        curve,
        criterion,
        steps_run,
        early_stopped: early,
        scene_scale,
        seconds: t0.elapsed().as_secs_f64(),
        timing,
    })
}

/// Writes a run's model folder `out`: `final.ply` (the last step's Gaussians), `best.ply`
/// (the kept checkpoint), `curve.json`, `best.json` ([`BestRecord`]) and, when a GPU computed
/// the renders and gradients, `device.json` (its adapter).
pub fn write_model(
    out: &Path,
    fitted: &Fitted,
    adapter: Option<&crate::gpu::AdapterSummary>,
) -> Result<(), NodeError> {
    crate::write_ply(&out.join("final.ply"), &fitted.last)?;
    crate::write_ply(&out.join("best.ply"), &fitted.best)?;
    artifacts::write_json(&out.join(artifacts::files::CURVE), &fitted.curve)?;
    artifacts::write_json(&out.join("best.json"), &fitted.best_record())?;
    if let Some(d) = adapter {
        artifacts::write_json(&out.join("device.json"), d)?;
    }
    Ok(())
}

/// Continues from the checkpoint `bytes` when it fits this run (a log line says so), or
/// leaves the trainer as it was and says why it starts afresh.
fn resume(
    bytes: &[u8],
    trainer: &mut Trainer<'_>,
    steps: u64,
    on_event: &mut dyn FnMut(FitEvent),
) -> Option<LoopState> {
    // The trainer's own state as it starts: a checkpoint refused after its trainer part was
    // read must not leave the trainer half-restored.
    let pristine = {
        let mut w = augsplat_core::state::StateWriter::new();
        trainer.write_state(&mut w);
        w.finish()
    };
    match read_checkpoint(bytes, trainer, steps) {
        Ok(s) => {
            on_event(FitEvent::Log(format!(
                "resumed from the checkpoint at step {}",
                trainer.steps_done()
            )));
            Some(s)
        }
        Err(e) => {
            // Its own state, written a moment ago: reading it back cannot fail.
            trainer
                .restore_state(&mut augsplat_core::state::StateReader::new(&pristine))
                .expect("a trainer reads back the state it wrote");
            on_event(FitEvent::Log(format!(
                "cannot continue from the saved checkpoint ({e}); starting afresh"
            )));
            None
        }
    }
}

/// The log line of a step that densified, pruned or reset opacities (`done` steps done).
fn refine_line(done: u64, rep: &crate::train::StepReport) -> Option<String> {
    let r = &rep.refine;
    (r.cloned + r.split + r.pruned > 0 || r.reset).then(|| {
        format!(
            "step {done}: cloned {}, split {}, pruned {}{} → {} Gaussians",
            r.cloned,
            r.split,
            r.pruned,
            if r.reset { ", opacity reset" } else { "" },
            rep.gaussians
        )
    })
}

/// One held-out evaluation during a run, and what it decides.
struct Evaluating<'a> {
    args: &'a TrainArgs,
    test: &'a [RealView],
    lpips: Option<&'a Lpips>,
    criterion: Criterion,
    started: std::time::Instant,
}

impl Evaluating<'_> {
    /// Evaluates the trainer's Gaussians, adds the point to the curve, keeps them when they
    /// are the best so far, and returns whether the patience ran out (stop early).
    fn run(
        &self,
        trainer: &mut Trainer<'_>,
        st: &mut LoopState,
        on_event: &mut dyn FnMut(FitEvent),
    ) -> Result<bool, EvalError> {
        let (a, done) = (self.args, trainer.steps_done());
        let (test, lpips, criterion) = (self.test, self.lpips, self.criterion);
        let settings = a.render_settings(done);
        let e = trainer.evaluate(test, &settings, lpips)?;
        let secs = self.started.elapsed().as_secs_f64();
        let p = point(
            done,
            &e,
            trainer.primitives(),
            if a.record_wall_time { secs } else { 0.0 },
            st.loss_acc / st.loss_n.max(1) as f64,
        );
        st.loss_acc = 0.0;
        st.loss_n = 0;
        on_event(FitEvent::Log(format!(
            "step {done}: PSNR {:.3} SSIM {:.4}{} loss {:.5} Gaussians {} ({secs:.1} s)",
            p.psnr,
            p.ssim,
            p.lpips.map_or(String::new(), |l| format!(" LPIPS {l:.4}")),
            p.loss,
            p.primitives
        )));
        let better = match &st.best {
            None => true,
            Some((b, _)) => criterion.better(&p, b),
        };
        if better {
            st.best = Some((p.clone(), trainer.gaussians().clone()));
            st.since_best = 0;
        } else {
            st.since_best += 1;
        }
        st.curve.points.push(p);
        if let Some(pat) = a.early_stop_patience {
            if st.since_best >= pat && done < a.steps {
                on_event(FitEvent::Log(format!(
                    "early stop at step {done}: no improvement in {pat} evaluations"
                )));
                return Ok(true);
            }
        }
        Ok(false)
    }
}

/// What a run's densification settings mean here, for the log: the content's extent when the
/// large-Gaussian prune measures against it, and a note when a short run never reaches the
/// opacity reset its non-default settings concern.
fn densify_notes(a: &TrainArgs, trainer: &Trainer<'_>) -> Vec<String> {
    let mut lines = Vec::new();
    if a.densify.prune_extent == crate::densify::PruneExtent::Content {
        lines.push(format!(
            "large-Gaussian prune against the content's extent {:.4} ({:.2} × the scene scale)",
            trainer.prune_extent(),
            trainer.prune_extent() / trainer.scene_scale()
        ));
    }
    let sched = a.densify.scaled(a.steps);
    let defaults = crate::densify::DensifyArgs::default();
    if a.densify.enabled
        && !sched.reaches_reset()
        && (a.densify.reset != defaults.reset || a.densify.prune_extent != defaults.prune_extent)
    {
        lines.push(sched.short_run_note(a.steps));
    }
    lines
}
