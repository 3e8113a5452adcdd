//! `augsplat run`: run a pipeline (every run is a resume). Also holds the options the engine
//! subcommands (`plan`, `why`, `expand`, `gc`) share.

use super::CmdResult;
use augsplat_graph::exec::{slurm::SlurmOptions, ExecutorKind};
use augsplat_graph::{default_cache_dir, Engine, Plan, Registry, RunOptions};
use std::io::IsTerminal;
use std::path::PathBuf;

/// Arguments of `augsplat run`.
#[derive(clap::Args)]
pub struct Args {
    /// Pipeline, overrides, store.
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Build only these nodes (and what they need). A node name matches all its instances;
    /// `field[2]` or `aggregate@gamma=0.5` match one. Repeatable.
    #[arg(long = "target", value_name = "NODE")]
    pub targets: Vec<String>,
    /// Cores to use in total (default: all).
    #[arg(long, short = 'j')]
    pub jobs: Option<usize>,
    /// Write `{"nodes":[{"name","kind","key","status","seconds"}..]}` to this file.
    #[arg(long, value_name = "PATH")]
    pub summary_json: Option<PathBuf>,
    /// Pin this run's results under NAME (kept by `gc` until `cache/pins/NAME.json` is deleted).
    #[arg(long, value_name = "NAME")]
    pub pin: Option<String>,
    /// Copy the run's results into `DIR/<instance>/<output>/` (writable copies, replacing
    /// earlier ones): the outputs of the `--target` nodes, or without targets of the nodes
    /// nothing else consumes (e.g. the report of each sweep point).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// No progress bars and no final table.
    #[arg(long, short = 'q')]
    pub quiet: bool,
    /// Print each node's log lines on stderr as they arrive, as `[node 12.3 s] line` (the
    /// trainers log their evaluations and refinements): for long runs whose stderr goes to a
    /// file. Works with `--quiet`.
    #[arg(long)]
    pub log: bool,
    /// Where nodes run: `local` (this process) or `slurm` (one `sbatch` job per ready node,
    /// one job array per repeat or sweep; the store must be on a filesystem the compute nodes
    /// share). Resources come from the pipeline's `resources:` block.
    #[arg(long, value_name = "local|slurm", default_value = "local")]
    pub executor: String,
    /// An option for every `sbatch` call, e.g. `--slurm-opt=--partition=gpu`. Repeatable.
    #[arg(long = "slurm-opt", value_name = "OPT", allow_hyphen_values = true)]
    pub slurm_opts: Vec<String>,
    /// Submit Slurm jobs with `--requeue`: a preempted job is requeued and resumes from its
    /// node's last checkpoint.
    #[arg(long)]
    pub requeue: bool,
    /// Long nodes (field and splat training) save a checkpoint every N of their steps, which
    /// an interrupted run resumes from (0: never). Not part of any key.
    #[arg(long, value_name = "N", default_value_t = augsplat_graph::exec::DEFAULT_CHECKPOINT_EVERY)]
    pub checkpoint_every: u64,
}

/// Runs `augsplat run`.
pub fn run(args: Args, registry: &Registry) -> CmdResult {
    let (engine, plan) = args.pipeline.load_creating(registry)?;
    let mut opts = RunOptions {
        targets: args.targets.clone(),
        progress: !args.quiet && std::io::stderr().is_terminal(),
        checkpoint_every: args.checkpoint_every,
        echo_log: args.log,
        ..Default::default()
    };
    opts.executor = match args.executor.as_str() {
        "local" => {
            if !args.slurm_opts.is_empty() || args.requeue {
                return Err("--slurm-opt and --requeue need --executor slurm".into());
            }
            ExecutorKind::Local
        }
        "slurm" => ExecutorKind::Slurm(slurm_options(&args, engine.store().root())?),
        other => {
            return Err(format!(
                "--executor {other}: unknown executor (use `local` or `slurm`)"
            ))
        }
    };
    if let Some(j) = args.jobs {
        if j == 0 {
            return Err("--jobs must be at least 1".into());
        }
        opts.jobs = j;
    }
    let report = engine.run(&plan, &opts).map_err(|e| e.to_string())?;
    if let Some(path) = &args.summary_json {
        let text = serde_json::to_string_pretty(&report.summary_json(&plan)).expect("json");
        std::fs::write(path, text).map_err(|e| format!("writing {}: {e}", path.display()))?;
    }
    if let Some(name) = &args.pin {
        let keys: Vec<String> = report
            .results
            .iter()
            .flatten()
            .filter_map(|r| r.key.as_ref().map(augsplat_graph::store::hex))
            .collect();
        engine.store().pin(name, &keys).map_err(|e| e.to_string())?;
    }
    let results = report.final_outputs(&plan, engine.store(), &args.targets);
    if !args.quiet {
        print!("{}", report.table(&plan));
    }
    if let Some(dir) = &args.out {
        for (inst, output, from) in &results {
            let to = out_path(dir, inst, output);
            // Never hand a user a damaged result: the copy is checked like a node's input.
            if let Some(m) = engine.store().output_of_folder(from) {
                engine.store().check_output(&m).map_err(|damage| {
                    format!(
                        "not copying {inst}.{output} to {}: its stored output is damaged \
                         ({damage}); run `augsplat verify --repair`, then run again to \
                         recompute it",
                        to.display()
                    )
                })?;
            }
            copy_output(from, &to)
                .map_err(|e| format!("copying {} to {}: {e}", from.display(), to.display()))?;
        }
    }
    if !args.quiet && !results.is_empty() {
        println!("results:");
        for (inst, output, from) in &results {
            let shown = match &args.out {
                Some(dir) => out_path(dir, inst, output),
                None => from.clone(),
            };
            println!("  {inst}.{output}  {}", shown.display());
        }
    }
    let failures = report.failures(&plan);
    if failures.is_empty() {
        Ok(())
    } else {
        let mut msg = format!(
            "{} node(s) failed; nothing was stored for them:",
            failures.len()
        );
        for (_, m) in failures {
            msg.push_str("\n  ");
            msg.push_str(&m.replace('\n', "\n  "));
        }
        Err(msg)
    }
}

/// The Slurm executor's options: its worker is this very program's hidden `compute-node`
/// subcommand, with the same pipeline, overrides and (absolute) store.
fn slurm_options(args: &Args, store_root: &std::path::Path) -> Result<SlurmOptions, String> {
    let exe = std::env::current_exe().map_err(|e| format!("locating augsplat itself: {e}"))?;
    let file = std::fs::canonicalize(&args.pipeline.file)
        .map_err(|e| format!("{}: {e}", args.pipeline.file.display()))?;
    let mut worker = vec![
        exe.display().to_string(),
        "compute-node".into(),
        "--cache".into(),
        store_root.display().to_string(),
        "--checkpoint-every".into(),
        args.checkpoint_every.to_string(),
    ];
    for s in &args.pipeline.sets {
        worker.push(format!("--set={s}"));
    }
    worker.push(file.display().to_string());
    Ok(SlurmOptions {
        worker,
        sbatch_opts: args.slurm_opts.clone(),
        requeue: args.requeue,
        ..Default::default()
    })
}

/// Pipeline file, overrides and store location.
#[derive(clap::Args, Clone, Debug)]
pub struct PipelineArgs {
    /// The pipeline file (.ron).
    pub file: PathBuf,
    /// Override a value as if the file said so: `NODE.ARG[.SUB]=RON_VALUE` or `params.NAME=RON_VALUE`
    /// (strings need quotes: --set 'node.name="text"'). Repeatable.
    #[arg(long = "set", value_name = "PATH=VALUE")]
    pub sets: Vec<String>,
    /// The store (default: $AUGSPLAT_CACHE, else ./cache).
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
}

impl PipelineArgs {
    /// Opens the store, creating it when the path holds none (only `run` and `bench` do), and
    /// resolves the pipeline.
    pub fn load_creating(&self, registry: &Registry) -> Result<(Engine, Plan), String> {
        self.resolve(open_engine(registry, self.cache.clone())?)
    }

    /// Opens the existing store (a path that holds none is an error, never a new empty store)
    /// and resolves the pipeline.
    pub fn load(&self, registry: &Registry) -> Result<(Engine, Plan), String> {
        self.resolve(open_existing_engine(registry, self.cache.clone())?)
    }

    /// Resolves the pipeline against the existing store, or, where the path holds no store,
    /// against a scratch store that is removed afterwards (`expand` needs a store only to
    /// hash external inputs). The scratch store's folder comes back with the plan.
    pub fn load_anywhere(
        &self,
        registry: &Registry,
    ) -> Result<(Engine, Plan, Option<ScratchStore>), String> {
        match open_existing_engine(registry, self.cache.clone()) {
            Ok(engine) => self.resolve(engine).map(|(e, p)| (e, p, None)),
            Err(_) => {
                let scratch = ScratchStore::new()?;
                let engine =
                    Engine::new(registry.clone(), &scratch.0).map_err(|e| e.to_string())?;
                self.resolve(engine).map(|(e, p)| (e, p, Some(scratch)))
            }
        }
    }

    fn resolve(&self, engine: Engine) -> Result<(Engine, Plan), String> {
        let plan = engine
            .load(&self.file, &self.sets)
            .map_err(|e| e.to_string())?;
        for w in &plan.warnings {
            eprintln!("warning: {w}");
        }
        Ok((engine, plan))
    }
}

/// A temporary store under the system's temporary folder, removed when dropped.
pub struct ScratchStore(PathBuf);

impl ScratchStore {
    fn new() -> Result<ScratchStore, String> {
        let p = std::env::temp_dir().join(format!(
            "augsplat-scratch-store-{}-{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_nanos())
                .unwrap_or(0)
        ));
        Ok(ScratchStore(p))
    }
}

impl Drop for ScratchStore {
    fn drop(&mut self) {
        augsplat_graph::store::remove_tree(&self.0);
    }
}

/// Opens the store at `cache` (or the default), creating it if the path holds none.
pub fn open_engine(registry: &Registry, cache: Option<PathBuf>) -> Result<Engine, String> {
    let cache = cache.unwrap_or_else(default_cache_dir);
    Engine::new(registry.clone(), cache).map_err(|e| e.to_string())
}

/// Opens the existing store at `cache` (or the default); a path that holds no store is an
/// error naming it.
pub fn open_existing_engine(registry: &Registry, cache: Option<PathBuf>) -> Result<Engine, String> {
    let cache = cache.unwrap_or_else(default_cache_dir);
    Engine::open_existing(registry.clone(), cache).map_err(|e| e.to_string())
}

/// Where `--out DIR` puts output `output` of instance `inst`: `DIR/<inst>/<output>/`, each name
/// made a safe folder name (a swept string may hold `/` or `..`), so nothing lands outside DIR.
fn out_path(dir: &std::path::Path, inst: &str, output: &str) -> PathBuf {
    use augsplat_graph::key::safe_folder_name;
    dir.join(safe_folder_name(inst))
        .join(safe_folder_name(output))
}

/// Copies the output folder `from` (read-only files in the store) to `to` as ordinary
/// writable files, replacing whatever `to` held.
fn copy_output(from: &std::path::Path, to: &std::path::Path) -> std::io::Result<()> {
    if to.exists() {
        std::fs::remove_dir_all(to)?;
    }
    std::fs::create_dir_all(to)?;
    for entry in std::fs::read_dir(from)? {
        let entry = entry?;
        let (src, dst) = (entry.path(), to.join(entry.file_name()));
        if entry.file_type()?.is_dir() {
            copy_output(&src, &dst)?;
        } else {
            std::fs::copy(&src, &dst)?;
            #[cfg(unix)]
            {
                use std::os::unix::fs::PermissionsExt;
                std::fs::set_permissions(&dst, std::fs::Permissions::from_mode(0o644))?;
            }
            #[cfg(not(unix))]
            {
                let mut perm = std::fs::metadata(&dst)?.permissions();
                #[allow(clippy::permissions_set_readonly_false)]
                perm.set_readonly(false);
                std::fs::set_permissions(&dst, perm)?;
            }
        }
    }
    Ok(())
}
