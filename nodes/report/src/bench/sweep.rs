//! The pipeline `augsplat bench` runs: the benched pipeline extended with its grid as the
//! sweep, so that the normal engine runs every configuration (upstream shared by several
//! configurations computed once, everything cached).

use crate::error::ReportError;
use std::path::Path;

/// The text of the sweep file (`OUT/bench.ron`) for pipeline `file` over `grid`, each axis
/// written `PATH=[V, ..]` (`NODE.ARG` or `params.NAME`, RON values); the grid is every
/// combination. A malformed axis is an error quoting it.
pub fn sweep_file(file: &Path, grid: &[String]) -> Result<String, ReportError> {
    let mut axes = Vec::new();
    for g in grid {
        let (path, values) = g
            .split_once('=')
            .ok_or_else(|| ReportError::Message(format!("--grid {g}: write PATH=[V, ..]")))?;
        let (path, values) = (path.trim(), values.trim());
        if path.is_empty() || !values.starts_with('[') || !values.ends_with(']') {
            return Err(ReportError::Message(format!(
                "--grid {g}: write PATH=[V, ..], e.g. 'field.steps=[100, 200]'"
            )));
        }
        axes.push(format!("{path:?}: {values}"));
    }
    Ok(format!(
        "// Written by `augsplat bench`: {} with the grid as its sweep.\n(\n    extends: {:?},\n    sweep: Grid({{ {} }}),\n)\n",
        file.display(),
        file.display().to_string(),
        axes.join(", ")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(axes: &[&str]) -> Vec<String> {
        axes.iter().map(|a| a.to_string()).collect()
    }

    #[test]
    fn the_grid_becomes_the_sweep_of_a_file_extending_the_pipeline() {
        let text = sweep_file(
            Path::new("/p/demo.ron"),
            &grid(&["field.steps=[100, 200]", " params.gs_steps = [10,20] "]),
        )
        .unwrap();
        assert_eq!(
            text,
            "// Written by `augsplat bench`: /p/demo.ron with the grid as its sweep.\n(\n    extends: \"/p/demo.ron\",\n    sweep: Grid({ \"field.steps\": [100, 200], \"params.gs_steps\": [10,20] }),\n)\n"
        );
    }

    #[test]
    fn a_malformed_axis_is_an_error_quoting_it() {
        let e = sweep_file(Path::new("p.ron"), &grid(&["field.steps"])).unwrap_err();
        assert_eq!(e.to_string(), "--grid field.steps: write PATH=[V, ..]");
        for bad in ["field.steps=100", "=[1]", "a=[1"] {
            let e = sweep_file(Path::new("p.ron"), &grid(&[bad])).unwrap_err();
            assert_eq!(
                e.to_string(),
                format!("--grid {bad}: write PATH=[V, ..], e.g. 'field.steps=[100, 200]'")
            );
        }
    }
}
