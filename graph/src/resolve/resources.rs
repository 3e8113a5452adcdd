//! The pipeline's `resources:` block: what a node's jobs ask of a cluster, by node name or
//! kind, read by the Slurm executor. Never part of a key: where a node runs never changes
//! what it computes.

use super::Plan;
use crate::error::{Diagnostic, PipelineError};
use crate::syntax::Value;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// What a node's jobs ask of a cluster (the Slurm executor turns each field into an `sbatch`
/// option): a value of the pipeline's `resources:` block, keyed by a node's name in the
/// pipeline or by its kind (the name wins), or `default`. Not part of any key: where a node
/// runs never changes what it computes.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Resources {
    /// `--cpus-per-task` (default: 1 for a one-thread node, else the run's `--jobs`).
    pub cpus: Option<u32>,
    /// `--mem`, e.g. "8G".
    pub mem: Option<String>,
    /// `--time`, e.g. "02:00:00".
    pub time: Option<String>,
    /// `--gpus` (for nodes with `backend: Gpu`).
    pub gpus: Option<u32>,
    /// `--partition`.
    pub partition: Option<String>,
    /// More `sbatch` options, verbatim (e.g. `["--constraint=a100"]`).
    pub sbatch: Vec<String>,
}

/// The document's `resources:` block, typed.
pub(super) fn parse(doc: &Value) -> Result<BTreeMap<String, Resources>, PipelineError> {
    let Some(v) = doc.field("resources") else {
        return Ok(BTreeMap::new());
    };
    // `cpus: 2` as well as `cpus: Some(2)`, as in node args.
    let opts =
        ron::Options::default().with_default_extension(ron::extensions::Extensions::IMPLICIT_SOME);
    opts.from_str(&v.to_ron()).map_err(|e| {
        Diagnostic::at(&v.origin, format!("`resources`: {e}"))
            .hint(
                "write `resources: { \"OptimizeSplats\": (cpus: 8, mem: \"16G\", time: \"04:00:00\", gpus: 1) }` \
                 (keys: node names, kinds or `default`; fields: cpus, mem, time, gpus, partition, sbatch)",
            )
            .into()
    })
}

impl Plan {
    /// The resources of computation `c`: its node name's entry, else its kind's, else `default`.
    pub fn resources_of(&self, c: usize) -> Option<&Resources> {
        let comp = &self.comps[c];
        let base = comp.instances.first().map(|&i| &self.instances[i].base);
        base.and_then(|b| self.resources.get(b))
            .or_else(|| self.resources.get(comp.node.kind()))
            .or_else(|| self.resources.get("default"))
    }
}
