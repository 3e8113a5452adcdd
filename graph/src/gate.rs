//! Gates: a node may read another node's decision and end at once when it says no.
//!
//! A node written with `gate: "decide.decision"` gets that output as a hidden input slot
//! ([`GATE_SLOT`]), so the decision is part of its key like any input. Before the node runs,
//! the engine reads [`GATE_FILE`] from that folder — `{ "run": bool, "reason": "..." }`, other
//! fields are the gate's evidence and are ignored here. When `run` is false the node's `run`
//! is never called: each of its output folders holds only [`GATED_MARKER`] with the reason,
//! and that is stored as the computation's result (so a rerun finds it cached, and a changed
//! decision changes the key).
//!
//! A gated output propagates: a node that reads one through an input that does not accept
//! gated folders ([`crate::InputDecl::accepting_gated`]) is gated too, with the same reason,
//! without running. A node that accepts them (a report, say) runs and sees the marker through
//! [`gated_reason`]. The graph stays static: every node has an entry, and the run's table
//! says `gated` for the ones that ended this way.

use crate::node::InputDecl;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The name of the hidden input slot that carries a node's gate.
pub const GATE_SLOT: &str = "@gate";
/// The file a gate's output folder holds.
pub const GATE_FILE: &str = "gate.json";
/// The file each output folder of a gated computation holds (and nothing else).
pub const GATED_MARKER: &str = ".augsplat-gated.json";

/// The part of [`GATE_FILE`] the engine reads.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GateDecision {
    /// Whether the gated nodes run.
    pub run: bool,
    /// Why, in a sentence (shown in tables and reports).
    pub reason: String,
}

/// What [`GATED_MARKER`] holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct GatedMarker {
    gated: String,
}

/// Reads a gate's decision from its output folder.
pub fn read_decision(folder: &Path) -> Result<GateDecision, String> {
    let p = folder.join(GATE_FILE);
    let text = std::fs::read_to_string(&p).map_err(|e| {
        format!(
            "the gate's folder has no readable {GATE_FILE} ({}: {e}); a `gate:` must name an \
             output that holds a decision {{ \"run\": true|false, \"reason\": \"...\" }}",
            p.display()
        )
    })?;
    serde_json::from_str(&text).map_err(|e| {
        format!(
            "{}: not a gate decision ({e}); expected {{ \"run\": true|false, \"reason\": \"...\" }}",
            p.display()
        )
    })
}

/// The reason an output folder was gated, when it was (it holds [`GATED_MARKER`]).
pub fn gated_reason(folder: &Path) -> Option<String> {
    let text = std::fs::read_to_string(folder.join(GATED_MARKER)).ok()?;
    match serde_json::from_str::<GatedMarker>(&text) {
        Ok(m) => Some(m.gated),
        Err(_) => Some("skipped by a gate".into()),
    }
}

/// Writes the marker of a gated output into `folder`.
pub fn write_marker(folder: &Path, reason: &str) -> std::io::Result<()> {
    let text = serde_json::to_string_pretty(&GatedMarker {
        gated: reason.to_string(),
    })
    .map_err(std::io::Error::other)?;
    std::fs::write(folder.join(GATED_MARKER), text + "\n")
}

/// Why a computation with these declared inputs and these input folders must not run: its
/// gate says no, or an input that does not accept gated folders reads one. `Ok(None)`: run it.
/// An unreadable decision is an error (the node fails with it).
pub(crate) fn skip_reason(
    decls: &[InputDecl],
    inputs: &[(String, Vec<PathBuf>)],
) -> Result<Option<String>, String> {
    for (name, folders) in inputs {
        if name == GATE_SLOT {
            for f in folders {
                let d = read_decision(f)?;
                if !d.run {
                    return Ok(Some(d.reason));
                }
            }
            continue;
        }
        let accepts = decls.iter().any(|d| &d.name == name && d.accepts_gated);
        if accepts {
            continue;
        }
        if let Some(r) = folders.iter().find_map(|f| gated_reason(f)) {
            return Ok(Some(r));
        }
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_no_gates_and_a_gated_input_propagates_unless_accepted() {
        let t = tempfile::tempdir().unwrap();
        let gate = t.path().join("gate");
        std::fs::create_dir_all(&gate).unwrap();
        std::fs::write(
            gate.join(GATE_FILE),
            r#"{"run": false, "reason": "the prior loses", "evidence": [1, 2]}"#,
        )
        .unwrap();
        let inputs = vec![(GATE_SLOT.to_string(), vec![gate.clone()])];
        assert_eq!(
            skip_reason(&[], &inputs).unwrap().as_deref(),
            Some("the prior loses")
        );

        let gated = t.path().join("gated");
        std::fs::create_dir_all(&gated).unwrap();
        write_marker(&gated, "the prior loses").unwrap();
        assert_eq!(gated_reason(&gated).as_deref(), Some("the prior loses"));
        let inputs = vec![("x".to_string(), vec![t.path().to_path_buf(), gated.clone()])];
        let plain = [InputDecl::many("x")];
        assert_eq!(
            skip_reason(&plain, &inputs).unwrap().as_deref(),
            Some("the prior loses")
        );
        let accepting = [InputDecl::many("x").accepting_gated()];
        assert_eq!(skip_reason(&accepting, &inputs).unwrap(), None);

        std::fs::write(gate.join(GATE_FILE), r#"{"run": true, "reason": "ok"}"#).unwrap();
        let inputs = vec![(GATE_SLOT.to_string(), vec![gate.clone()])];
        assert_eq!(skip_reason(&[], &inputs).unwrap(), None);
    }

    #[test]
    fn an_unreadable_decision_names_the_file() {
        let t = tempfile::tempdir().unwrap();
        let inputs = vec![(GATE_SLOT.to_string(), vec![t.path().to_path_buf()])];
        let e = skip_reason(&[], &inputs).unwrap_err();
        assert!(e.contains(GATE_FILE), "{e}");
        std::fs::write(t.path().join(GATE_FILE), r#"{"run": "yes"}"#).unwrap();
        let e = skip_reason(&[], &inputs).unwrap_err();
        assert!(e.contains("not a gate decision"), "{e}");
    }
}
