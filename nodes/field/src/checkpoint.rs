//! Checkpoints of field training: the parameters, the occupancy grid, Adam's moments, the
//! curve so far and the loop's counters, bit for bit (see
//! [`train_resumable`](crate::train::train_resumable)).

use crate::occupancy::OccupancyGrid;
use crate::train::{Adam, TrainState};

/// Checkpoints of a [`train_resumable`](crate::train::train_resumable) run (the `TrainField` node's engine checkpoints).
pub struct FieldCheckpoints<'a> {
    /// Save every this many steps (0: never).
    pub every: u64,
    /// A checkpoint an interrupted run of the same options and views saved.
    pub resume: Option<Vec<u8>>,
    /// Stores one checkpoint (replacing the previous one).
    pub save: &'a mut dyn FnMut(Vec<u8>) -> Result<(), String>,
    /// Receives a line for the log (resumed, saved, a refused checkpoint).
    pub log: &'a mut dyn FnMut(String),
}

/// The loop's state beside the parameters: what a checkpoint holds.
pub(crate) struct FieldLoop {
    pub(crate) step: u32,
    pub(crate) adam: Adam,
    pub(crate) curve: augsplat_core::artifacts::TrainingCurve,
    pub(crate) consecutive_bad: u32,
    pub(crate) loss_acc: (f64, u32),
}

/// A checkpoint of a run of `steps` steps: the step count it was made for and the step it
/// reached come first, so a checkpoint of another run is refused before anything is used.
pub(crate) fn write_field_checkpoint(state: &TrainState, l: &FieldLoop, steps: u32) -> Vec<u8> {
    use augsplat_core::state::{write_curve, StateWriter};
    let mut w = StateWriter::new();
    w.tag("field-train-2");
    w.u32(steps);
    w.u32(l.step);
    w.f32s(&state.params);
    w.u32(state.occupancy.res);
    w.f32s(&state.occupancy.ema);
    w.bytes(&state.occupancy.occupied);
    w.u32(state.skipped_steps);
    w.u64(state.nonfinite_values);
    w.f32s(&l.adam.m);
    w.f32s(&l.adam.v);
    w.u32(l.adam.t);
    write_curve(&mut w, &l.curve);
    w.u32(l.consecutive_bad);
    w.f64(l.loss_acc.0);
    w.u32(l.loss_acc.1);
    w.finish()
}

pub(crate) fn read_field_checkpoint(
    bytes: &[u8],
    n_params: usize,
    res: u32,
    steps: u32,
) -> Result<(TrainState, FieldLoop), augsplat_core::state::StateError> {
    use augsplat_core::state::{read_curve, StateError, StateReader};
    let mut r = StateReader::new(bytes);
    r.tag("field-train-2")?;
    let made_for = r.u32()?;
    let step = r.u32()?;
    if made_for != steps || step > steps {
        return Err(StateError(format!(
            "it was made at step {step} of a {made_for}-step run, and this run has {steps} steps"
        )));
    }
    let params = r.f32s()?;
    let occ_res = r.u32()?;
    let ema = r.f32s()?;
    let occupied = r.bytes()?;
    let skipped_steps = r.u32()?;
    let nonfinite_values = r.u64()?;
    let m = r.f32s()?;
    let v = r.f32s()?;
    let t = r.u32()?;
    let curve = read_curve(&mut r)?;
    let consecutive_bad = r.u32()?;
    let loss_acc = (r.f64()?, r.u32()?);
    r.end()?;
    let cells = (res as usize).pow(3);
    if params.len() != n_params
        || m.len() != n_params
        || v.len() != n_params
        || occ_res != res
        || ema.len() != cells
        || occupied.len() != cells
    {
        return Err(StateError(
            "the checkpoint is for another field layout".into(),
        ));
    }
    Ok((
        TrainState {
            params,
            occupancy: OccupancyGrid { res, ema, occupied },
            skipped_steps,
            nonfinite_values,
        },
        FieldLoop {
            step,
            adam: Adam { m, v, t },
            curve,
            consecutive_bad,
            loss_acc,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use augsplat_core::state::StateWriter;

    /// The header of a checkpoint: its format tag, the run's step count and the step reached.
    fn header(tag: &str, made_for: u32, step: u32) -> Vec<u8> {
        let mut w = StateWriter::new();
        w.tag(tag);
        w.u32(made_for);
        w.u32(step);
        w.finish()
    }

    #[test]
    fn another_runs_step_count_or_an_older_format_is_refused() {
        let err = |bytes: &[u8]| match read_field_checkpoint(bytes, 4, 2, 1000) {
            Ok(_) => panic!("a foreign checkpoint was read"),
            Err(e) => e.to_string(),
        };
        // A step-1,800 checkpoint of an 1,800-step run, in a 1,000-step run.
        let e = err(&header("field-train-2", 1800, 1800));
        assert!(e.contains("1800") && e.contains("1000"), "{e}");
        // Made for 2,000 steps, stopped at 500: within this run's steps, still another run.
        let e = err(&header("field-train-2", 2000, 500));
        assert!(e.contains("2000-step"), "{e}");
        // A past step for the right count (a damaged header).
        let e = err(&header("field-train-2", 1000, 1200));
        assert!(e.contains("1200"), "{e}");
        // The earlier format, which did not record the step count.
        let e = err(&header("field-train", 1000, 500));
        assert!(e.contains("field-train-2"), "{e}");
    }
}
