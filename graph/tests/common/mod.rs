//! Toy node kinds that record every execution, for the engine's tests.
#![allow(dead_code)]

use augsplat_graph::{InputDecl, Node, NodeError, Registry, RunContext, Threads};
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// Every execution: (node name, kind).
pub static RECORD: Mutex<Vec<String>> = Mutex::new(Vec::new());
/// Serialises tests (they share RECORD).
pub static SERIAL: Mutex<()> = Mutex::new(());
static ACTIVE: AtomicUsize = AtomicUsize::new(0);
/// The most nodes seen running at once.
pub static MAX_ACTIVE: AtomicUsize = AtomicUsize::new(0);
/// Set while a Threads::All node runs; other nodes record a violation if they see it.
pub static HEAVY_RUNNING: AtomicUsize = AtomicUsize::new(0);
pub static VIOLATIONS: AtomicUsize = AtomicUsize::new(0);

pub fn lock() -> std::sync::MutexGuard<'static, ()> {
    let g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    RECORD.lock().unwrap().clear();
    MAX_ACTIVE.store(0, Ordering::SeqCst);
    VIOLATIONS.store(0, Ordering::SeqCst);
    g
}

/// The names recorded since the last `take`, sorted.
pub fn take() -> Vec<String> {
    let mut v = std::mem::take(&mut *RECORD.lock().unwrap());
    v.sort();
    v
}

fn record(ctx: &RunContext) {
    RECORD.lock().unwrap().push(ctx.node_name().to_string());
}

fn enter(ms: u64) {
    let now = ACTIVE.fetch_add(1, Ordering::SeqCst) + 1;
    MAX_ACTIVE.fetch_max(now, Ordering::SeqCst);
    if HEAVY_RUNNING.load(Ordering::SeqCst) > 0 {
        VIOLATIONS.fetch_add(1, Ordering::SeqCst);
    }
    std::thread::sleep(std::time::Duration::from_millis(ms));
    ACTIVE.fetch_sub(1, Ordering::SeqCst);
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
        record(ctx);
        enter(args.sleep_ms);
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
        record(ctx);
        enter(args.sleep_ms);
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
        record(ctx);
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
        record(ctx);
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
        record(ctx);
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
        record(ctx);
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
        record(ctx);
        HEAVY_RUNNING.fetch_add(1, Ordering::SeqCst);
        if ACTIVE.load(Ordering::SeqCst) > 0 {
            VIOLATIONS.fetch_add(1, Ordering::SeqCst);
        }
        std::thread::sleep(std::time::Duration::from_millis(args.sleep_ms));
        HEAVY_RUNNING.fetch_sub(1, Ordering::SeqCst);
        let pool = rayon::current_num_threads();
        std::fs::write(
            ctx.output("out")?.join("value.txt"),
            format!("{} {}", ctx.threads(), pool),
        )?;
        Ok(())
    }
}

/// Every toy kind plus the engine's own.
pub fn registry() -> Registry {
    let mut r = Registry::with_engine_kinds();
    r.register::<Source>()
        .register::<Append>()
        .register::<Len>()
        .register::<Concat>();
    r.register::<Seeded>()
        .register::<Fail>()
        .register::<Heavy>();
    r
}
