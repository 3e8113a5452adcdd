//! The registry of node kinds, and the type-erased adapter the engine works with.

use crate::node::{InputDecl, Node, NodeError, RunContext, Threads};
use std::any::Any;
use std::collections::BTreeMap;
use std::sync::Arc;

/// Typed args after parsing, type-erased.
pub type ArgsBox = Arc<dyn Any + Send + Sync>;

/// An error turning RON text into a kind's typed args.
#[derive(Debug, Clone, PartialEq)]
pub struct ArgsError {
    /// The dotted path of the offending field inside `args` (empty for the whole value).
    pub path: String,
    /// What is wrong.
    pub message: String,
}

/// The object-safe face of a node kind, as the engine uses it.
pub trait DynNode: Send + Sync {
    /// Kind name.
    fn kind(&self) -> &'static str;
    /// Kind version.
    fn version(&self) -> u32;
    /// Parses RON text of the args (a struct or map; `()`/empty means all defaults).
    fn parse_args(&self, ron_text: &str) -> Result<ArgsBox, ArgsError>;
    /// The canonical encoding of typed args: compact JSON of the fully-defaulted struct, fields
    /// in declaration order. Formatting, comments, field order and default-vs-explicit never
    /// change it.
    fn canonical_args(&self, args: &ArgsBox) -> Vec<u8>;
    /// Typed args as a JSON value (for `why`, `expand` and run records).
    fn args_json(&self, args: &ArgsBox) -> serde_json::Value;
    /// The kind's default args as a JSON value.
    fn default_args_json(&self) -> serde_json::Value;
    /// Declared inputs.
    fn inputs(&self, args: &ArgsBox) -> Vec<InputDecl>;
    /// Declared outputs.
    fn outputs(&self, args: &ArgsBox) -> Vec<String>;
    /// Wanted threads.
    fn threads(&self, args: &ArgsBox) -> Threads;
    /// Semantic validation.
    fn validate(&self, args: &ArgsBox) -> Result<(), String>;
    /// Runs the node.
    fn run(&self, args: &ArgsBox, ctx: &mut RunContext) -> Result<(), NodeError>;
}

struct Adapter<N: Node>(std::marker::PhantomData<fn() -> N>);

impl<N: Node> Adapter<N> {
    fn typed(args: &ArgsBox) -> &N::Args {
        args.downcast_ref::<N::Args>()
            .expect("args were parsed by the same kind")
    }
}

impl<N: Node> DynNode for Adapter<N> {
    fn kind(&self) -> &'static str {
        N::KIND
    }
    fn version(&self) -> u32 {
        N::VERSION
    }
    fn parse_args(&self, ron_text: &str) -> Result<ArgsBox, ArgsError> {
        let trimmed = ron_text.trim();
        let args: N::Args = if trimmed.is_empty() || trimmed == "()" || trimmed == "{}" {
            N::Args::default()
        } else {
            // `implicit_some`: an `Option` field may be written `steps: 100` as well as `Some(100)`.
            let opts = ron::Options::default()
                .with_default_extension(ron::extensions::Extensions::IMPLICIT_SOME);
            let mut de = ron::Deserializer::from_str_with_options(trimmed, &opts).map_err(|e| {
                ArgsError {
                    path: String::new(),
                    message: e.to_string(),
                }
            })?;
            let value: N::Args =
                serde_path_to_error::deserialize(&mut de).map_err(|e| ArgsError {
                    path: e
                        .path()
                        .to_string()
                        .trim_start_matches('.')
                        .replace('?', "")
                        .to_string(),
                    message: e.inner().to_string(),
                })?;
            de.end().map_err(|e| ArgsError {
                path: String::new(),
                message: e.to_string(),
            })?;
            value
        };
        Ok(Arc::new(args))
    }
    fn canonical_args(&self, args: &ArgsBox) -> Vec<u8> {
        serde_json::to_vec(Self::typed(args)).expect("typed args serialise")
    }
    fn args_json(&self, args: &ArgsBox) -> serde_json::Value {
        serde_json::to_value(Self::typed(args)).expect("typed args serialise")
    }
    fn default_args_json(&self) -> serde_json::Value {
        serde_json::to_value(N::Args::default()).expect("typed args serialise")
    }
    fn inputs(&self, args: &ArgsBox) -> Vec<InputDecl> {
        N::inputs(Self::typed(args))
    }
    fn outputs(&self, args: &ArgsBox) -> Vec<String> {
        N::outputs(Self::typed(args))
    }
    fn threads(&self, args: &ArgsBox) -> Threads {
        N::threads(Self::typed(args))
    }
    fn validate(&self, args: &ArgsBox) -> Result<(), String> {
        N::validate(Self::typed(args))
    }
    fn run(&self, args: &ArgsBox, ctx: &mut RunContext) -> Result<(), NodeError> {
        N::run(Self::typed(args), ctx)
    }
}

/// Where a named installed resource lives on this machine (model weights a user downloads
/// once, say), for the `Installed("name")` input reference: `locate` returns its file or
/// folder, or `None` when it is not installed; `hint` tells a user how to install it.
#[derive(Clone)]
pub struct InstalledResource {
    /// Finds the resource; `None` when it is not installed.
    pub locate: Arc<dyn Fn() -> Option<std::path::PathBuf> + Send + Sync>,
    /// How to install it, in words (shown when a required input names a missing one).
    pub hint: String,
}

/// Node kinds by name, and the installed resources pipelines may name.
#[derive(Clone, Default)]
pub struct Registry {
    kinds: BTreeMap<&'static str, Arc<dyn DynNode>>,
    resources: BTreeMap<String, InstalledResource>,
}

impl Registry {
    /// An empty registry.
    pub fn new() -> Self {
        Registry::default()
    }
    /// A registry holding the engine's own kinds (`Command`).
    pub fn with_engine_kinds() -> Self {
        let mut r = Registry::default();
        r.register::<crate::command::Command>();
        r
    }
    /// Registers kind `N` under `N::KIND` (a later registration of the same name replaces it).
    pub fn register<N: Node>(&mut self) -> &mut Self {
        self.kinds
            .insert(N::KIND, Arc::new(Adapter::<N>(std::marker::PhantomData)));
        self
    }
    /// Registers an already type-erased kind under its [`DynNode::kind`] (a later
    /// registration of the same name replaces it): e.g. a wrapper that instruments another
    /// kind. The wrapper must answer `kind`, `version` and `canonical_args` exactly as the
    /// kind it wraps does, or it changes keys.
    pub fn register_dyn(&mut self, node: Arc<dyn DynNode>) -> &mut Self {
        self.kinds.insert(node.kind(), node);
        self
    }
    /// The kind called `name`.
    pub fn get(&self, name: &str) -> Option<&Arc<dyn DynNode>> {
        self.kinds.get(name)
    }
    /// All registered kind names, sorted.
    pub fn names(&self) -> Vec<&'static str> {
        self.kinds.keys().copied().collect()
    }
    /// Registers installed resource `name` (a later registration of the same name replaces
    /// it). Pipelines connect it with `Installed("name")`; it is content-hashed like a
    /// `Path(..)`, so installing or changing it changes the keys of the nodes that read it.
    pub fn register_resource(
        &mut self,
        name: &str,
        locate: impl Fn() -> Option<std::path::PathBuf> + Send + Sync + 'static,
        hint: &str,
    ) -> &mut Self {
        self.resources.insert(
            name.to_string(),
            InstalledResource {
                locate: Arc::new(locate),
                hint: hint.to_string(),
            },
        );
        self
    }
    /// The installed resource called `name`.
    pub fn resource(&self, name: &str) -> Option<&InstalledResource> {
        self.resources.get(name)
    }
    /// All registered resource names, sorted.
    pub fn resource_names(&self) -> Vec<&str> {
        self.resources.keys().map(String::as_str).collect()
    }
}
