//! augsplat's pipeline engine. It knows nothing about 3D.
//!
//! - [`node`]: the node API ([`Node`], [`RunContext`]).
//! - [`registry`]: kinds by name and the type-erased adapter.
//! - [`syntax`]: a RON reader that keeps positions; [`spec`]: `extends`, `--set`, params, sweeps.
//! - [`resolve`]: typing against the registry, repeats, references, cycles, dedup → [`Plan`].
//! - [`key`]: what identifies a computation (structural id) and addresses its outputs (key).
//! - [`store`]: blobs, manifests, action cache, records; [`store::claim`]: claims on keys that
//!   hold on shared filesystems; [`store::verify`] and [`store::gc`]: `verify` and `gc`.
//! - [`exec`]: one driver loop over the local and Slurm executors; [`explain`]: `plan` and `why`;
//!   [`engine`]: the library API.
//! - [`command`]: the `Command` node kind (external programs); [`gate`]: nodes that end at
//!   once when another node's decision says so.
//!
//! See `graph/README.md` for the pipeline syntax and the engine's semantics.

pub mod command;
pub mod engine;
pub mod error;
pub mod exec;
pub mod explain;
pub mod gate;
pub mod key;
pub mod node;
pub mod registry;
pub mod resolve;
mod snapshot;
pub mod spec;
pub mod store;
pub mod syntax;

pub use engine::{default_cache_dir, expand_text, run_pipeline, Engine};
pub use error::{Diagnostic, EngineError, PipelineError};
pub use exec::{RunOptions, RunReport, Status};
pub use node::{InputDecl, Node, NodeError, NullSink, ProgressSink, RunContext, Threads};
pub use registry::{ArgsBox, ArgsError, DynNode, InstalledResource, Registry};
pub use resolve::Plan;
pub use store::gc::GcReport;
pub use store::verify::{Problem, VerifyReport};
pub use store::{EntryState, Store};
