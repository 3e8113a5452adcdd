//! augsplat's pipeline engine. It knows nothing about 3D.
//!
//! - [`node`]: the node API ([`Node`], [`RunContext`]).
//! - [`registry`]: kinds by name and the type-erased adapter.

pub mod node;
pub mod registry;

pub use node::{InputDecl, Node, NodeError, ProgressSink, RunContext, Threads};
pub use registry::{ArgsBox, ArgsError, DynNode, Registry};
