//! The library face of the engine: load a pipeline, run it, explain it, collect garbage.
//!
//! ```no_run
//! use augsplat_graph::{Engine, Registry, RunOptions};
//! let engine = Engine::new(Registry::with_engine_kinds(), "cache").unwrap();
//! let plan = engine.load("pipelines/demo.ron".as_ref(), &["train.steps=100".into()]).unwrap();
//! let report = engine.run(&plan, &RunOptions::default()).unwrap();
//! assert!(report.success());
//! ```

use crate::error::{EngineError, PipelineError};
use crate::exec::{execute, RunOptions, RunReport};
use crate::registry::Registry;
use crate::resolve::{load_plan, Plan};
use crate::store::gc::GcReport;
use crate::store::verify::VerifyReport;
use crate::store::Store;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The store location: `$AUGSPLAT_CACHE`, else `./cache`.
pub fn default_cache_dir() -> PathBuf {
    std::env::var_os("AUGSPLAT_CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("cache"))
}

/// A registry of node kinds and a store.
pub struct Engine {
    registry: Registry,
    store: Store,
}

impl Engine {
    /// An engine over the store at `cache` (created if missing).
    pub fn new(registry: Registry, cache: impl Into<PathBuf>) -> Result<Engine, EngineError> {
        Ok(Engine {
            registry,
            store: Store::open(cache)?,
        })
    }
    /// An engine over the existing store at `cache`: creates nothing, and a path that holds
    /// no store is [`EngineError::NoStore`] (every command but `run` opens its store so).
    pub fn open_existing(
        registry: Registry,
        cache: impl Into<PathBuf>,
    ) -> Result<Engine, EngineError> {
        Ok(Engine {
            registry,
            store: Store::open_existing(cache)?,
        })
    }
    /// The registry.
    pub fn registry(&self) -> &Registry {
        &self.registry
    }
    /// The store.
    pub fn store(&self) -> &Store {
        &self.store
    }
    /// Loads and resolves a pipeline with `--set` style overrides (`NODE.ARG=RON`).
    pub fn load(&self, file: &Path, sets: &[String]) -> Result<Plan, PipelineError> {
        load_plan(&self.registry, &self.store, file, sets)
    }
    /// Runs a plan (finished nodes are found in the store).
    pub fn run(&self, plan: &Plan, opts: &RunOptions) -> Result<RunReport, EngineError> {
        execute(plan, &self.store, opts)
    }
    /// The text of `augsplat plan`.
    pub fn plan_text(&self, plan: &Plan, targets: &[String]) -> Result<String, EngineError> {
        crate::explain::plan_text(plan, &self.store, targets)
    }
    /// The text of `augsplat why`.
    pub fn why_text(&self, plan: &Plan, node: &str) -> Result<String, EngineError> {
        crate::explain::why_text(plan, &self.store, node)
    }
    /// Garbage collection (see [`Store::gc`]).
    pub fn gc(&self, dry_run: bool, repair: bool) -> Result<GcReport, EngineError> {
        self.store.gc(dry_run, repair)
    }
    /// Verification of the whole store (see [`Store::verify`]).
    pub fn verify(&self, repair: bool) -> Result<VerifyReport, EngineError> {
        self.store.verify(repair)
    }
}

/// The text of `augsplat expand`: each sweep point's fully resolved pipeline (extends merged,
/// overrides and params applied), with its node instances and structural ids.
pub fn expand_text(plan: &Plan) -> String {
    let mut s = String::new();
    for p in &plan.points {
        if !p.label.is_empty() {
            let _ = writeln!(s, "// sweep point {}", p.label);
        }
        let _ = writeln!(s, "{}", p.document.to_ron_pretty(0));
        let _ = writeln!(s, "// instances:");
        for &i in &p.instances {
            let inst = &plan.instances[i];
            let comp = &plan.comps[inst.comp];
            let _ = writeln!(
                s,
                "//   {} ({}) args {}",
                inst.name,
                comp.node.kind(),
                comp.args_json
            );
        }
        s.push('\n');
    }
    s
}

/// Loads and runs a pipeline in one call; returns the plan and the report.
pub fn run_pipeline(
    registry: Registry,
    file: &Path,
    sets: &[String],
    cache: &Path,
    opts: &RunOptions,
) -> Result<(Plan, RunReport), EngineError> {
    let engine = Engine::new(registry, cache)?;
    let plan = engine.load(file, sets)?;
    let report = engine.run(&plan, opts)?;
    Ok((plan, report))
}
