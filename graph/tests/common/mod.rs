//! Toy node kinds for the engine's tests, and a [`Recorder`] that each test owns: the
//! registry from [`registry`] wraps every toy kind so that its runs are recorded in that
//! test's recorder only, and tests can run in parallel without seeing each other's runs.
#![allow(dead_code)]

pub mod env;

use augsplat_graph::{
    ArgsBox, ArgsError, DynNode, InputDecl, Node, NodeError, Registry, RunContext, Threads,
};
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

/// What the toy nodes of one test did: which nodes ran, how many ran at once, and whether a
/// `Threads::All` node ever ran beside another.
#[derive(Default)]
pub struct Recorder {
    /// Every execution's node name since the last `take`.
    record: Mutex<Vec<String>>,
    /// Nodes (other than `Threads::All` ones) running now.
    active: AtomicUsize,
    /// The most nodes seen running at once.
    max_active: AtomicUsize,
    /// `Threads::All` nodes running now.
    heavy_running: AtomicUsize,
    /// Times a node started while a `Threads::All` node ran, or a `Threads::All` node started
    /// while others ran.
    violations: AtomicUsize,
}

impl Recorder {
    /// A fresh recorder to share with a registry.
    pub fn new() -> Arc<Recorder> {
        Arc::new(Recorder::default())
    }
    /// The names recorded since the last `take`, sorted.
    pub fn take(&self) -> Vec<String> {
        let mut v = std::mem::take(&mut *self.record.lock().unwrap());
        v.sort();
        v
    }
    /// The most nodes seen running at once.
    pub fn max_active(&self) -> usize {
        self.max_active.load(Ordering::SeqCst)
    }
    /// Forgets the most nodes seen running at once.
    pub fn reset_max_active(&self) {
        self.max_active.store(0, Ordering::SeqCst);
    }
    /// Times a `Threads::All` node ran beside another.
    pub fn violations(&self) -> usize {
        self.violations.load(Ordering::SeqCst)
    }
    /// Runs `f` as node `name`: records it and counts it as running meanwhile.
    fn running<T>(&self, name: &str, heavy: bool, f: impl FnOnce() -> T) -> T {
        self.record.lock().unwrap().push(name.to_string());
        if heavy {
            self.heavy_running.fetch_add(1, Ordering::SeqCst);
            if self.active.load(Ordering::SeqCst) > 0 {
                self.violations.fetch_add(1, Ordering::SeqCst);
            }
            let r = f();
            self.heavy_running.fetch_sub(1, Ordering::SeqCst);
            r
        } else {
            let now = self.active.fetch_add(1, Ordering::SeqCst) + 1;
            self.max_active.fetch_max(now, Ordering::SeqCst);
            if self.heavy_running.load(Ordering::SeqCst) > 0 {
                self.violations.fetch_add(1, Ordering::SeqCst);
            }
            let r = f();
            self.active.fetch_sub(1, Ordering::SeqCst);
            r
        }
    }
}

/// A toy kind whose runs go to a recorder; everything else (and so every key) is the kind's.
struct Recorded {
    inner: Arc<dyn DynNode>,
    rec: Arc<Recorder>,
}

impl DynNode for Recorded {
    fn kind(&self) -> &'static str {
        self.inner.kind()
    }
    fn version(&self) -> u32 {
        self.inner.version()
    }
    fn parse_args(&self, ron_text: &str) -> Result<ArgsBox, ArgsError> {
        self.inner.parse_args(ron_text)
    }
    fn canonical_args(&self, args: &ArgsBox) -> Vec<u8> {
        self.inner.canonical_args(args)
    }
    fn args_json(&self, args: &ArgsBox) -> serde_json::Value {
        self.inner.args_json(args)
    }
    fn default_args_json(&self) -> serde_json::Value {
        self.inner.default_args_json()
    }
    fn inputs(&self, args: &ArgsBox) -> Vec<InputDecl> {
        self.inner.inputs(args)
    }
    fn outputs(&self, args: &ArgsBox) -> Vec<String> {
        self.inner.outputs(args)
    }
    fn threads(&self, args: &ArgsBox) -> Threads {
        self.inner.threads(args)
    }
    fn validate(&self, args: &ArgsBox) -> Result<(), String> {
        self.inner.validate(args)
    }
    fn run(&self, args: &ArgsBox, ctx: &mut RunContext) -> Result<(), NodeError> {
        let heavy = self.inner.threads(args) == Threads::All;
        let name = ctx.node_name().to_string();
        self.rec.running(&name, heavy, || self.inner.run(args, ctx))
    }
}

fn sleep(ms: u64) {
    std::thread::sleep(std::time::Duration::from_millis(ms));
}

#[derive(Clone, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SourceArgs {
    pub value: String,
    pub count: u32,
    pub sleep_ms: u64,
    pub nested: Nested,
}

#[derive(Clone, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Nested {
    pub alpha: f64,
    pub tags: Vec<String>,
}

impl Default for Nested {
    fn default() -> Self {
        Nested {
            alpha: 0.5,
            tags: Vec::new(),
        }
    }
}

/// Writes `value` (repeated `count` times, at least once) to `out/value.txt`.
pub struct Source;
impl Node for Source {
    const KIND: &'static str = "Source";
    const VERSION: u32 = 1;
    type Args = SourceArgs;
    fn inputs(_: &SourceArgs) -> Vec<InputDecl> {
        Vec::new()
    }
    fn outputs(_: &SourceArgs) -> Vec<String> {
        vec!["out".into()]
    }
    fn run(args: &SourceArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        sleep(args.sleep_ms);
        let text = args.value.repeat(args.count.max(1) as usize);
        std::fs::write(
            ctx.output("out")?.join("value.txt"),
            format!("{text}|{}", args.nested.alpha),
        )?;
        Ok(())
    }
}

#[derive(Clone, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AppendArgs {
    pub suffix: String,
    pub sleep_ms: u64,
}

/// Reads `a/value.txt`, appends `suffix`; two outputs: `out` and `len`.
pub struct Append;
impl Node for Append {
    const KIND: &'static str = "Append";
    const VERSION: u32 = 1;
    type Args = AppendArgs;
    fn inputs(_: &AppendArgs) -> Vec<InputDecl> {
        vec![InputDecl::one("a")]
    }
    fn outputs(_: &AppendArgs) -> Vec<String> {
        vec!["out".into(), "len".into()]
    }
    fn run(args: &AppendArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        sleep(args.sleep_ms);
        let v = std::fs::read_to_string(ctx.input("a")?.join("value.txt"))?;
        let s = format!("{v}{}", args.suffix);
        std::fs::write(ctx.output("out")?.join("value.txt"), &s)?;
        std::fs::write(ctx.output("len")?.join("value.txt"), s.len().to_string())?;
        Ok(())
    }
}

#[derive(Clone, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LenArgs {}

/// Writes the length of `a/value.txt` (so different inputs can give identical outputs).
pub struct Len;
impl Node for Len {
    const KIND: &'static str = "Len";
    const VERSION: u32 = 1;
    type Args = LenArgs;
    fn inputs(_: &LenArgs) -> Vec<InputDecl> {
        vec![InputDecl::one("a")]
    }
    fn outputs(_: &LenArgs) -> Vec<String> {
        vec!["out".into()]
    }
    fn run(_: &LenArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let v = std::fs::read_to_string(ctx.input("a")?.join("value.txt"))?;
        std::fs::write(ctx.output("out")?.join("value.txt"), v.len().to_string())?;
        Ok(())
    }
}

#[derive(Clone, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ConcatArgs {
    pub sep: String,
}

/// Concatenates every folder of list input `items`.
pub struct Concat;
impl Node for Concat {
    const KIND: &'static str = "Concat";
    const VERSION: u32 = 1;
    type Args = ConcatArgs;
    fn inputs(_: &ConcatArgs) -> Vec<InputDecl> {
        vec![InputDecl::many("items"), InputDecl::optional("extra")]
    }
    fn outputs(_: &ConcatArgs) -> Vec<String> {
        vec!["out".into()]
    }
    fn run(args: &ConcatArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let mut parts = Vec::new();
        for p in ctx.input_list("items")? {
            parts.push(std::fs::read_to_string(p.join("value.txt"))?);
        }
        std::fs::write(ctx.output("out")?.join("value.txt"), parts.join(&args.sep))?;
        Ok(())
    }
}

#[derive(Clone, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DecideArgs {
    /// Whether the decision says run.
    pub run: bool,
    /// Write something that is not a decision.
    pub garbled: bool,
}

/// Writes a gate decision (`gate.json`) into output `decision`.
pub struct Decide;
impl Node for Decide {
    const KIND: &'static str = "Decide";
    const VERSION: u32 = 1;
    type Args = DecideArgs;
    fn inputs(_: &DecideArgs) -> Vec<InputDecl> {
        vec![InputDecl::optional("a")]
    }
    fn outputs(_: &DecideArgs) -> Vec<String> {
        vec!["decision".into()]
    }
    fn run(args: &DecideArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let text = if args.garbled {
            "{\"run\": 1}".to_string()
        } else {
            format!(
                "{{\"run\": {}, \"reason\": \"toy decision {}\", \"evidence\": 7}}",
                args.run, args.run
            )
        };
        std::fs::write(ctx.output("decision")?.join("gate.json"), text)?;
        Ok(())
    }
}

/// Lists its `items`, writing `gated(REASON)` for a gated one (it accepts them).
pub struct Collect;
impl Node for Collect {
    const KIND: &'static str = "Collect";
    const VERSION: u32 = 1;
    type Args = ConcatArgs;
    fn inputs(_: &ConcatArgs) -> Vec<InputDecl> {
        vec![InputDecl::many("items").accepting_gated()]
    }
    fn outputs(_: &ConcatArgs) -> Vec<String> {
        vec!["out".into()]
    }
    fn run(args: &ConcatArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let mut parts = Vec::new();
        for p in ctx.input_list("items")? {
            match augsplat_graph::gate::gated_reason(p) {
                Some(r) => parts.push(format!("gated({r})")),
                None => parts.push(std::fs::read_to_string(p.join("value.txt"))?),
            }
        }
        std::fs::write(ctx.output("out")?.join("value.txt"), parts.join(&args.sep))?;
        Ok(())
    }
}

#[derive(Clone, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SeededArgs {
    pub seed: u64,
}

/// Writes its arg seed and its context seed.
pub struct Seeded;
impl Node for Seeded {
    const KIND: &'static str = "Seeded";
    const VERSION: u32 = 1;
    type Args = SeededArgs;
    fn inputs(_: &SeededArgs) -> Vec<InputDecl> {
        vec![InputDecl::optional("a")]
    }
    fn outputs(_: &SeededArgs) -> Vec<String> {
        vec!["out".into()]
    }
    fn run(args: &SeededArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        std::fs::write(
            ctx.output("out")?.join("value.txt"),
            format!("{} {}", args.seed, ctx.seed()),
        )?;
        Ok(())
    }
}

#[derive(Clone, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FailArgs {
    pub fail: bool,
    pub panic: bool,
}

/// Fails (after logging and writing a partial output) when `fail`; panics when `panic`.
pub struct Fail;
impl Node for Fail {
    const KIND: &'static str = "Fail";
    const VERSION: u32 = 1;
    type Args = FailArgs;
    fn inputs(_: &FailArgs) -> Vec<InputDecl> {
        vec![InputDecl::optional("a")]
    }
    fn outputs(_: &FailArgs) -> Vec<String> {
        vec!["out".into()]
    }
    fn validate(args: &FailArgs) -> Result<(), String> {
        if args.fail && args.panic {
            return Err("`fail` and `panic` cannot both be set".into());
        }
        Ok(())
    }
    fn run(args: &FailArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        std::fs::write(ctx.output("out")?.join("value.txt"), "partial")?;
        ctx.log("about to decide");
        if args.panic {
            panic!("toy panic");
        }
        if args.fail {
            return Err(NodeError::new("toy failure"));
        }
        Ok(())
    }
}

#[derive(Clone, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HeavyArgs {
    pub sleep_ms: u64,
}

/// A node that asks for every core; records the rayon pool size it got.
pub struct Heavy;
impl Node for Heavy {
    const KIND: &'static str = "Heavy";
    const VERSION: u32 = 1;
    type Args = HeavyArgs;
    fn inputs(_: &HeavyArgs) -> Vec<InputDecl> {
        Vec::new()
    }
    fn outputs(_: &HeavyArgs) -> Vec<String> {
        vec!["out".into()]
    }
    fn threads(_: &HeavyArgs) -> Threads {
        Threads::All
    }
    fn run(args: &HeavyArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        sleep(args.sleep_ms);
        let pool = rayon::current_num_threads();
        std::fs::write(
            ctx.output("out")?.join("value.txt"),
            format!("{} {}", ctx.threads(), pool),
        )?;
        Ok(())
    }
}

/// Every toy kind, recording into `rec`, plus the engine's own kinds.
pub fn registry(rec: Arc<Recorder>) -> Registry {
    let mut toys = Registry::new();
    toys.register::<Source>()
        .register::<Append>()
        .register::<Len>()
        .register::<Concat>();
    toys.register::<Seeded>()
        .register::<Fail>()
        .register::<Heavy>();
    toys.register::<Decide>().register::<Collect>();
    let mut r = Registry::with_engine_kinds();
    for name in toys.names() {
        let inner = toys.get(name).expect("listed").clone();
        r.register_dyn(Arc::new(Recorded {
            inner,
            rec: rec.clone(),
        }));
    }
    r
}
