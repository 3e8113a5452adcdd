//! The node API: what a node kind is, and what it gets when it runs.
//!
//! A node kind is a Rust type implementing [`Node`]: typed serde args, a `VERSION`, declared
//! named inputs and outputs, and a `run` function. The engine resolves its inputs to read-only
//! folders, gives it one scratch folder per declared output, and promotes those folders into
//! the store only when `run` returns `Ok`.

use serde::{de::DeserializeOwned, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// How many cores a node wants while it runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Threads {
    /// A light node: one core; the executor may run others beside it.
    One,
    /// A heavy node: every core of the executor's budget; nothing else runs beside it.
    All,
    /// A fixed number of cores (capped at the executor's budget).
    Exactly(usize),
}

/// One declared input of a node kind.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct InputDecl {
    /// The input's name, as written under `inputs:` in a pipeline.
    pub name: String,
    /// Whether the pipeline may omit it.
    pub optional: bool,
    /// Whether it takes a list of references (e.g. every member of an ensemble).
    pub many: bool,
    /// Whether the node runs when this input is a gated output (see [`crate::gate`]) and
    /// handles it itself; otherwise such an input gates the node too.
    pub accepts_gated: bool,
}

impl InputDecl {
    /// A required single input.
    pub fn one(name: &str) -> Self {
        InputDecl {
            name: name.into(),
            optional: false,
            many: false,
            accepts_gated: false,
        }
    }
    /// An optional single input.
    pub fn optional(name: &str) -> Self {
        InputDecl {
            name: name.into(),
            optional: true,
            many: false,
            accepts_gated: false,
        }
    }
    /// A required list input (one or more references).
    pub fn many(name: &str) -> Self {
        InputDecl {
            name: name.into(),
            optional: false,
            many: true,
            accepts_gated: false,
        }
    }
    /// The same input, read even when it is a gated output: the node runs and finds the
    /// marker with [`crate::gate::gated_reason`] (a report that says a method was skipped).
    pub fn accepting_gated(mut self) -> Self {
        self.accepts_gated = true;
        self
    }
}

/// An error raised by a node's `run`. Holds a readable message (with the chain of causes);
/// the engine shows it, keeps it in the node's log and stores nothing for the node.
#[derive(Debug)]
pub struct NodeError {
    message: String,
}

impl NodeError {
    /// An error with this message.
    pub fn new(message: impl Into<String>) -> Self {
        NodeError {
            message: message.into(),
        }
    }
    /// The message.
    pub fn message(&self) -> &str {
        &self.message
    }
    /// Prefixes the message with context ("while reading X: ...").
    pub fn context(self, ctx: impl std::fmt::Display) -> Self {
        NodeError {
            message: format!("{ctx}: {}", self.message),
        }
    }
}

impl std::fmt::Display for NodeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl<E: std::error::Error> From<E> for NodeError {
    fn from(e: E) -> Self {
        let mut message = e.to_string();
        let mut src = e.source();
        while let Some(s) = src {
            let part = s.to_string();
            if !message.contains(&part) {
                message.push_str(": ");
                message.push_str(&part);
            }
            src = s.source();
        }
        NodeError { message }
    }
}

/// Receives progress and log lines from a running node. The executor provides one; tests can
/// use [`NullSink`].
pub trait ProgressSink: Send + Sync {
    /// `done` of `total` units finished, with a short message.
    fn progress(&self, done: u64, total: u64, message: &str);
    /// A log line (kept in the node's log in the store).
    fn log(&self, line: &str);
}

/// A sink that drops everything.
pub struct NullSink;

impl ProgressSink for NullSink {
    fn progress(&self, _: u64, _: u64, _: &str) {}
    fn log(&self, _: &str) {}
}

/// What a running node gets: its inputs, its output folders, a seed, a thread budget and a
/// progress sink.
pub struct RunContext {
    /// Resolved inputs by name: each a list of read-only folders (one for single inputs).
    pub(crate) inputs: Vec<(String, Vec<PathBuf>)>,
    /// Output folders by name, already created, empty.
    pub(crate) outputs: Vec<(String, PathBuf)>,
    /// A folder for temporary files that are not outputs.
    pub(crate) scratch: PathBuf,
    pub(crate) seed: u64,
    pub(crate) threads: usize,
    pub(crate) sink: Arc<dyn ProgressSink>,
    pub(crate) node_name: String,
    /// Where checkpoints go and how often (steps), when the engine keeps them.
    pub(crate) checkpoints: Option<Checkpoints>,
    /// What the node measured about its run (see [`RunContext::measure`]).
    pub(crate) measures: BTreeMap<String, f64>,
}

/// A node run's checkpoint folder and cadence (see [`RunContext::save_checkpoint`]).
#[derive(Clone, Debug)]
pub struct Checkpoints {
    /// The folder, tied to the computation's key; it outlives a killed run.
    pub dir: PathBuf,
    /// Save every this many steps (0: never).
    pub every: u64,
    /// The computation's key: written into each checkpoint, and a checkpoint made for another
    /// key is ignored on load.
    pub key: [u8; 32],
}

/// The file a checkpoint is saved in, inside [`Checkpoints::dir`].
const CHECKPOINT_FILE: &str = "state.ckpt";
/// The first bytes of a checkpoint file: magic, then the key it was made for, then the
/// blake3 of the state, then the state.
const CHECKPOINT_MAGIC: &[u8; 8] = b"AUGCKPT2";
/// Where a checkpoint's state begins.
const CHECKPOINT_HEADER: usize = 8 + 32 + 32;

impl RunContext {
    /// Builds a context by hand, for running a node outside the engine (tests, benchmarks).
    /// Output folders are created under `outputs_root/<name>`.
    pub fn standalone(
        inputs: Vec<(String, Vec<PathBuf>)>,
        output_names: &[&str],
        outputs_root: &Path,
        seed: u64,
        threads: usize,
    ) -> std::io::Result<RunContext> {
        let mut outputs = Vec::new();
        for name in output_names {
            let p = outputs_root.join(name);
            std::fs::create_dir_all(&p)?;
            outputs.push((name.to_string(), p));
        }
        let scratch = outputs_root.join(".scratch");
        std::fs::create_dir_all(&scratch)?;
        Ok(RunContext {
            inputs,
            outputs,
            scratch,
            seed,
            threads: threads.max(1),
            sink: Arc::new(NullSink),
            node_name: "standalone".into(),
            checkpoints: None,
            measures: BTreeMap::new(),
        })
    }

    /// Keeps checkpoints in `dir` every `every` steps (a standalone context keeps none). The
    /// checkpoints are tied to `dir` (its path stands in for the key the engine would give).
    pub fn with_checkpoints(mut self, dir: PathBuf, every: u64) -> Self {
        let key = *blake3::hash(dir.to_string_lossy().as_bytes()).as_bytes();
        self.checkpoints = Some(Checkpoints { dir, every, key });
        self
    }

    /// How often a long node should save its state, in its own steps (`None`: checkpoints are
    /// off). The cadence is not part of any key: it changes when a node saves, never what it
    /// computes.
    pub fn checkpoint_every(&self) -> Option<u64> {
        self.checkpoints
            .as_ref()
            .map(|c| c.every)
            .filter(|&e| e > 0)
    }

    /// Saves a checkpoint: `bytes` replace the previous one atomically (written beside it,
    /// then renamed), with a checksum. A node saves its whole state, enough to continue as if
    /// it had never stopped; the engine keeps the folder while the key has no entry and
    /// removes it once the outputs are stored. Does nothing when checkpoints are off.
    pub fn save_checkpoint(&self, bytes: &[u8]) -> Result<(), NodeError> {
        let Some(c) = &self.checkpoints else {
            return Ok(());
        };
        let err = |what: &str, p: &Path, e: std::io::Error| {
            NodeError::new(format!("{what} checkpoint {}: {e}", p.display()))
        };
        std::fs::create_dir_all(&c.dir).map_err(|e| err("creating", &c.dir, e))?;
        let tmp = c
            .dir
            .join(format!(".{CHECKPOINT_FILE}.{}", std::process::id()));
        let mut data = Vec::with_capacity(bytes.len() + CHECKPOINT_HEADER);
        data.extend_from_slice(CHECKPOINT_MAGIC);
        data.extend_from_slice(&c.key);
        data.extend_from_slice(blake3::hash(bytes).as_bytes());
        data.extend_from_slice(bytes);
        {
            use std::io::Write;
            let mut f = std::fs::File::create(&tmp).map_err(|e| err("writing", &tmp, e))?;
            f.write_all(&data).map_err(|e| err("writing", &tmp, e))?;
            // On disk before it replaces the previous checkpoint.
            f.sync_all().map_err(|e| err("writing", &tmp, e))?;
        }
        let dest = c.dir.join(CHECKPOINT_FILE);
        std::fs::rename(&tmp, &dest).map_err(|e| err("renaming", &dest, e))
    }

    /// The latest checkpoint saved by an earlier, interrupted run of this computation, if any.
    /// One that is damaged, made by an older format, or made for another computation (another
    /// key: other args, inputs or seed) is reported in the log and ignored: the node starts
    /// afresh.
    pub fn load_checkpoint(&self) -> Option<Vec<u8>> {
        let c = self.checkpoints.as_ref()?;
        let p = c.dir.join(CHECKPOINT_FILE);
        let data = std::fs::read(&p).ok()?;
        let h = CHECKPOINT_HEADER;
        let problem = if data.len() < h || &data[..8] != CHECKPOINT_MAGIC {
            Some("is damaged or from an older format".to_string())
        } else if data[8..40] != c.key {
            Some(format!(
                "was made for another computation (key {}…, this one is {}…)",
                crate::store::hex(&data[8..40].try_into().expect("32 bytes"))
                    .get(..16)
                    .unwrap_or(""),
                crate::store::hex(&c.key).get(..16).unwrap_or("")
            ))
        } else if blake3::hash(&data[h..]).as_bytes() != &data[40..h] {
            Some("is damaged".to_string())
        } else {
            None
        };
        match problem {
            None => Some(data[h..].to_vec()),
            Some(why) => {
                self.log(format!(
                    "ignoring the checkpoint {}: it {why} (starting afresh)",
                    p.display()
                ));
                None
            }
        }
    }

    /// The folder of single input `name`.
    pub fn input(&self, name: &str) -> Result<&Path, NodeError> {
        match self.inputs.iter().find(|(n, _)| n == name) {
            Some((_, paths)) if paths.len() == 1 => Ok(&paths[0]),
            Some((_, paths)) => Err(NodeError::new(format!(
                "input `{name}` has {} folders, expected one",
                paths.len()
            ))),
            None => Err(NodeError::new(format!("input `{name}` was not connected"))),
        }
    }
    /// The folder of an optional single input, if connected.
    pub fn optional_input(&self, name: &str) -> Option<&Path> {
        self.inputs
            .iter()
            .find(|(n, _)| n == name)
            .and_then(|(_, p)| p.first().map(|p| p.as_path()))
    }
    /// The folders of list input `name`, in the order the pipeline lists them.
    pub fn input_list(&self, name: &str) -> Result<&[PathBuf], NodeError> {
        self.inputs
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, p)| p.as_slice())
            .ok_or_else(|| NodeError::new(format!("input `{name}` was not connected")))
    }
    /// The (empty, existing) folder to write output `name` into.
    pub fn output(&self, name: &str) -> Result<&Path, NodeError> {
        self.outputs
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, p)| p.as_path())
            .ok_or_else(|| NodeError::new(format!("output `{name}` is not declared")))
    }
    /// A scratch folder for temporary files (discarded after the run).
    pub fn scratch(&self) -> &Path {
        &self.scratch
    }
    /// A seed derived from the node's key: stable for the same args and inputs. Nodes with a
    /// `seed` arg should mix it in (or use it alone) so users control the stream.
    pub fn seed(&self) -> u64 {
        self.seed
    }
    /// The number of threads this node may use. The engine runs `run` inside a rayon pool of
    /// this size, so plain rayon calls respect it.
    pub fn threads(&self) -> usize {
        self.threads
    }
    /// The node's instance name in the pipeline.
    pub fn node_name(&self) -> &str {
        &self.node_name
    }
    /// Reports progress: `done` of `total` units.
    pub fn progress(&self, done: u64, total: u64, message: &str) {
        self.sink.progress(done, total, message);
    }
    /// Writes a line to the node's log.
    pub fn log(&self, line: impl AsRef<str>) {
        self.sink.log(line.as_ref());
    }
    /// Records a measurement of this run (seconds of a phase, a count) under `name`; the
    /// engine keeps it in the computation's cache record (`measures`), not in an output, so
    /// wall-clock figures never reach a key. A later value for the same name replaces it.
    pub fn measure(&mut self, name: impl Into<String>, value: f64) {
        self.measures.insert(name.into(), value);
    }
    /// The measurements recorded so far.
    pub fn measures(&self) -> &BTreeMap<String, f64> {
        &self.measures
    }
}

/// A node kind. Implement this for a unit struct and register it with
/// [`crate::Registry::register`].
///
/// Contract: for the same args and the same input bytes, `run` writes the same output bytes,
/// whatever the thread count (this is what makes early cutoff work).
pub trait Node: Send + Sync + 'static {
    /// The kind name used in pipelines (`kind: "OptimizeSplats"`).
    const KIND: &'static str;
    /// Bump when the outputs change for the same args and inputs; it is part of every key.
    const VERSION: u32;
    /// Typed args. Use `#[serde(default, deny_unknown_fields)]` on the struct so omitted fields
    /// take their defaults and typos are errors. Maps must be ordered (BTreeMap).
    type Args: Serialize + DeserializeOwned + Default + Clone + Send + Sync + 'static;

    /// The declared inputs (may depend on the args).
    fn inputs(args: &Self::Args) -> Vec<InputDecl>;
    /// The declared output names (may depend on the args). Each becomes a folder.
    fn outputs(args: &Self::Args) -> Vec<String>;
    /// How many cores the node wants. Default: one.
    fn threads(_args: &Self::Args) -> Threads {
        Threads::One
    }
    /// Checks args beyond their types (ranges, consistency). Errors are reported against the
    /// pipeline file before anything runs. Default: accept.
    fn validate(_args: &Self::Args) -> Result<(), String> {
        Ok(())
    }
    /// Does the work: reads `ctx.input(..)` folders, writes into `ctx.output(..)` folders.
    fn run(args: &Self::Args, ctx: &mut RunContext) -> Result<(), NodeError>;
}
