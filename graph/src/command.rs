//! The engine's own `Command` node kind: runs an external program on declared input folders
//! and output folders. No shell is involved: `program` is started with the `args` list.
//!
//! In `args` and `env` values, `{in:NAME}` is an input's folder (a list input given as a whole
//! argument expands to one argument per folder; inside a longer string its folders are joined
//! with `:`), `{out:NAME}` an output folder, `{scratch}` a temporary folder, `{seed}` and
//! `{threads}` the node's seed and thread budget. The same values are in the environment:
//! `AUGSPLAT_IN_<NAME>`, `AUGSPLAT_OUT_<NAME>` (upper-case), `AUGSPLAT_SCRATCH`,
//! `AUGSPLAT_SEED`, `AUGSPLAT_THREADS`. The program's stdout and stderr go to the node's log;
//! a non-zero exit fails the node, showing the log's last lines. The program runs in the
//! scratch folder. To make a script's content part of the key, pass it as an input:
//! `inputs: { "script": Path("augment.py") }` with `args: ["{in:script}", ..]`.
//!
//! Inputs are handed over as copies (cloned extents where the filesystem can): `{in:NAME}` is
//! a copy of the stored folder or the external file, so nothing the program does — as root
//! too — reaches a stored blob or the user's files. A program that changes its copy fails the
//! node all the same: inputs are read-only by contract.

use crate::node::{InputDecl, Node, NodeError, RunContext, Threads};
use crate::snapshot::{changed_input, input_snapshot};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::Stdio;

/// Args of [`Command`].
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct CommandArgs {
    /// The program (a name looked up on `PATH`, or a path).
    pub program: String,
    /// Its arguments, with placeholders.
    pub args: Vec<String>,
    /// Names of single-folder inputs.
    pub inputs: Vec<String>,
    /// Names of list inputs (one or more folders).
    pub list_inputs: Vec<String>,
    /// Names of optional single-folder inputs.
    pub optional_inputs: Vec<String>,
    /// Output folder names (default: one output, `out`).
    pub outputs: Vec<String>,
    /// Extra environment variables (values may hold placeholders).
    pub env: BTreeMap<String, String>,
    /// Cores the program uses: 0 = every core of the executor's budget.
    pub threads: usize,
    /// Bump to force a rerun when the program changed (it is part of the key).
    pub version: u32,
}

impl Default for CommandArgs {
    fn default() -> Self {
        CommandArgs {
            program: String::new(),
            args: Vec::new(),
            inputs: Vec::new(),
            list_inputs: Vec::new(),
            optional_inputs: Vec::new(),
            outputs: vec!["out".into()],
            env: BTreeMap::new(),
            threads: 1,
            version: 0,
        }
    }
}

/// Runs an external program (see the module docs).
pub struct Command;

fn valid_name(n: &str) -> bool {
    !n.is_empty() && n.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
}

fn placeholders(s: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = s;
    while let Some(a) = rest.find('{') {
        match rest[a..].find('}') {
            Some(b) => {
                out.push(&rest[a + 1..a + b]);
                rest = &rest[a + b + 1..];
            }
            None => break,
        }
    }
    out
}

impl Node for Command {
    const KIND: &'static str = "Command";
    const VERSION: u32 = 1;
    type Args = CommandArgs;

    fn inputs(args: &CommandArgs) -> Vec<InputDecl> {
        let mut v: Vec<InputDecl> = args.inputs.iter().map(|n| InputDecl::one(n)).collect();
        v.extend(args.list_inputs.iter().map(|n| InputDecl::many(n)));
        v.extend(args.optional_inputs.iter().map(|n| InputDecl::optional(n)));
        v
    }
    fn outputs(args: &CommandArgs) -> Vec<String> {
        args.outputs.clone()
    }
    fn threads(args: &CommandArgs) -> Threads {
        match args.threads {
            0 => Threads::All,
            1 => Threads::One,
            n => Threads::Exactly(n),
        }
    }
    fn validate(args: &CommandArgs) -> Result<(), String> {
        if args.program.is_empty() {
            return Err("`program` is empty".into());
        }
        let ins: Vec<&String> = args
            .inputs
            .iter()
            .chain(&args.list_inputs)
            .chain(&args.optional_inputs)
            .collect();
        for (i, n) in ins.iter().enumerate() {
            if !valid_name(n) {
                return Err(format!(
                    "input name `{n}` may only hold ASCII letters, digits and `_`"
                ));
            }
            if ins[..i].contains(n) {
                return Err(format!("input `{n}` is declared twice"));
            }
        }
        if args.outputs.is_empty() {
            return Err("`outputs` is empty: a Command needs at least one output folder".into());
        }
        for (i, n) in args.outputs.iter().enumerate() {
            if !valid_name(n) || args.outputs[..i].contains(n) {
                return Err(format!("output name `{n}` is invalid or repeated"));
            }
        }
        for s in args.args.iter().chain(args.env.values()) {
            for p in placeholders(s) {
                let ok = match p.split_once(':') {
                    Some(("in", n)) => ins.iter().any(|x| *x == n),
                    Some(("out", n)) => args.outputs.iter().any(|x| x == n),
                    None => matches!(p, "scratch" | "seed" | "threads"),
                    _ => false,
                };
                if !ok {
                    return Err(format!(
                        "placeholder `{{{p}}}` in `{s}` names nothing declared (use {{in:NAME}}, {{out:NAME}}, {{scratch}}, {{seed}}, {{threads}})"
                    ));
                }
            }
        }
        Ok(())
    }
    fn run(args: &CommandArgs, ctx: &mut RunContext) -> Result<(), NodeError> {
        let (copies, mut vars) = copy_inputs(args, ctx)?;
        let before = input_snapshot(&copies);
        for n in &args.outputs {
            vars.push((
                format!("out:{n}"),
                vec![ctx.output(n)?.display().to_string()],
            ));
        }
        vars.push(("scratch".into(), vec![ctx.scratch().display().to_string()]));
        vars.push(("seed".into(), vec![ctx.seed().to_string()]));
        vars.push(("threads".into(), vec![ctx.threads().to_string()]));
        let (cmd, argv) = program_command(args, &vars, ctx.scratch());
        ctx.log(format!("$ {} {}", args.program, argv.join(" ")));
        let status = run_logging(cmd, &args.program, ctx)?;
        if !status.success() {
            return Err(NodeError::new(format!(
                "`{}` exited with {status}",
                args.program
            )));
        }
        if let Some(change) = changed_input(&before, &input_snapshot(&copies)) {
            return Err(NodeError::new(format!(
                "`{}` changed its input {change} (a copy: the original is untouched); inputs \
                 are read-only, write to an output folder instead",
                args.program
            )));
        }
        Ok(())
    }
}

/// Placeholder values by name (`in:NAME`, `out:NAME`, `scratch`, `seed`, `threads`): one
/// value per folder of a list input, one otherwise.
type Vars = Vec<(String, Vec<String>)>;

/// The copies of each input's folders, by input name.
type Copies = Vec<(String, Vec<PathBuf>)>;

/// Copies every input the node got (reflinks where the filesystem has them), so that nothing
/// the program does — as root too — reaches a stored blob or a user's file. Returns the
/// copies by input name, and the `in:NAME` placeholder values that name them.
fn copy_inputs(args: &CommandArgs, ctx: &RunContext) -> Result<(Copies, Vars), NodeError> {
    let copies_root = ctx
        .scratch()
        .parent()
        .unwrap_or(ctx.scratch())
        .join("inputs");
    let mut copies: Copies = Vec::new();
    let mut vars: Vars = Vec::new();
    let mut add_input = |n: &str, paths: Vec<PathBuf>| -> Result<(), NodeError> {
        let mut v = Vec::new();
        let mut mine = Vec::new();
        for (i, p) in paths.iter().enumerate() {
            let dest = copies_root.join(n).join(i.to_string());
            let copy = copy_input(p, &dest).map_err(|e| {
                NodeError::new(format!("copying input `{n}` ({}): {e}", p.display()))
            })?;
            v.push(copy.display().to_string());
            mine.push(copy);
        }
        vars.push((format!("in:{n}"), v));
        copies.push((n.to_string(), mine));
        Ok(())
    };
    for n in args.inputs.iter().chain(&args.list_inputs) {
        add_input(n, ctx.input_list(n)?.to_vec())?;
    }
    for n in &args.optional_inputs {
        add_input(
            n,
            ctx.optional_input(n)
                .map(|p| p.to_path_buf())
                .into_iter()
                .collect(),
        )?;
    }
    Ok((copies, vars))
}

/// The program's command, run in `scratch`: its arguments with placeholders replaced (a
/// placeholder alone in an argument gives one argument per value, else values are joined
/// with `:`), `AUGSPLAT_*` variables for every placeholder, the user's `env`, and (on Linux)
/// death with the engine. Returns it with the arguments, for the log.
fn program_command(
    args: &CommandArgs,
    vars: &Vars,
    scratch: &Path,
) -> (std::process::Command, Vec<String>) {
    let subst = |s: &str| -> String {
        let mut out = s.to_string();
        for (k, v) in vars {
            out = out.replace(&format!("{{{k}}}"), &v.join(":"));
        }
        out
    };
    let mut argv = Vec::new();
    for a in &args.args {
        match vars.iter().find(|(k, _)| a == &format!("{{{k}}}")) {
            Some((_, v)) => argv.extend(v.iter().cloned()),
            None => argv.push(subst(a)),
        }
    }
    let mut cmd = std::process::Command::new(&args.program);
    cmd.args(&argv)
        .current_dir(scratch)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    for (k, v) in vars {
        let name = match k.split_once(':') {
            Some((dir, n)) => format!("AUGSPLAT_{}_{}", dir.to_uppercase(), n.to_uppercase()),
            None => format!("AUGSPLAT_{}", k.to_uppercase()),
        };
        cmd.env(name, v.join(":"));
    }
    for (k, v) in &args.env {
        cmd.env(k, subst(v));
    }
    // If the engine process dies (even by SIGKILL), the program dies with it instead of
    // running on as an orphan.
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        // SAFETY: only calls the async-signal-safe prctl between fork and exec.
        unsafe {
            cmd.pre_exec(|| {
                libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
                Ok(())
            });
        }
    }
    (cmd, argv)
}

/// Starts `cmd` and sends each line of its stdout and stderr to the node's log as it comes;
/// returns how it exited.
fn run_logging(
    mut cmd: std::process::Command,
    program: &str,
    ctx: &mut RunContext,
) -> Result<std::process::ExitStatus, NodeError> {
    let mut child = cmd
        .spawn()
        .map_err(|e| NodeError::new(format!("cannot start `{program}`: {e} (is it on PATH?)")))?;
    let stdout = child.stdout.take().expect("piped");
    let stderr = child.stderr.take().expect("piped");
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let tx2 = tx.clone();
    let t1 = std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let t2 = std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx2.send(line);
        }
    });
    for line in rx {
        ctx.log(line);
    }
    let _ = t1.join();
    let _ = t2.join();
    child
        .wait()
        .map_err(|e| NodeError::new(format!("waiting for `{program}`: {e}")))
}

/// Copies a file or a folder tree from `from` to `to` (files by `fs::copy`, which clones
/// extents where the filesystem can). Copies of read-only blobs stay read-only: a node that
/// rewrites a copied file removes it first.
pub fn copy_tree(from: &Path, to: &Path) -> std::io::Result<()> {
    if from.is_dir() {
        std::fs::create_dir_all(to)?;
        for e in std::fs::read_dir(from)? {
            let e = e?;
            copy_tree(&e.path(), &to.join(e.file_name()))?;
        }
    } else {
        std::fs::copy(from, to)?;
    }
    Ok(())
}

/// Copies an input file or folder to `dest/<its name>` ([`copy_tree`]) and returns the copy's
/// path.
fn copy_input(src: &Path, dest: &Path) -> std::io::Result<PathBuf> {
    std::fs::create_dir_all(dest)?;
    let name = src
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_else(|| "input".into());
    let to = dest.join(name);
    copy_tree(src, &to)?;
    Ok(to)
}
