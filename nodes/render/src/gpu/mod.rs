//! The GPU backend (wgpu + WGSL; Vulkan, Metal, DX12 or GL, whichever the machine has):
//! the same splatting maths as the CPU kernels, in f32, deterministic.
//!
//! This module holds what every kernel family shares: the context (adapter, device, limits,
//! error scopes, a buffer pool: `gpu/pool.rs`, encoders whose dispatches share a compute
//! pass: `gpu/encoder.rs`, encoders and small uploads kept and submitted together:
//! `gpu/submit.rs`), the buffer layout past one binding
//! (`gpu/chunk.rs`), the WGSL prelude
//! generated from the Rust constants (`gpu/prelude.rs`), and the radix sort and prefix sum
//! (`gpu/sort.rs`, `sort.wgsl`, `scan.wgsl`). Each kernel family keeps its GPU half beside
//! its CPU half: `forward/gpu.rs` + `forward.wgsl`, `backward/gpu.rs` + `backward.wgsl`,
//! `project/gpu.rs` + `project.wgsl`/`project_vjp.wgsl`. Other crates compile their own
//! kernels on the same context ([`GpuContext::kernels_of`]): the trainer's losses, Adam and
//! training state (`augsplat-splat`'s `loss/gpu.rs`, `adam/gpu.rs`, `train/gpu.rs`).
//!
//! - [`GpuContext`]: the adapter and device (limits raised to what the adapter reports), with
//!   the adapter's name, driver and backend for the outputs' metadata; asking for a GPU where
//!   there is none is a [`GpuError::NoAdapter`] that says what was found. Buffers may exceed
//!   one storage binding (`gpu/chunk.rs`): per-Gaussian arrays that kernels touch only at
//!   their own Gaussian (parameters, SH, gradients, moments) run in chunks; the splats, the
//!   screen-space gradients and the backward's pair slots are bound as two to four ranges;
//!   the rest (tile lists, images) must fit one binding. Past that a [`GpuError::TooLarge`]
//!   names the buffer;
//! - [`backward_gpu`]: gradients of a loss on the colour — the compositing backward walks
//!   each tile back to front and sums every (tile, Gaussian) pair's 256 pixels in a fixed
//!   order into the pair's own slot (each of the tile's 16 columns top to bottom, then the
//!   16 column sums left to right: two barriers per pair), each Gaussian's slots are summed
//!   in tile order (`backward/backward.wgsl`), and [`project_vjp_gpu`]
//!   (`project/project_vjp.wgsl`) turns them into gradients of the raw parameters;
//! - [`render_gpu`]: the forward pass — projection and SH colour (`project/project.wgsl`), a
//!   stable radix sort of the visible Gaussians by depth (`gpu/sort.wgsl`, `gpu/scan.wgsl`),
//!   tile binning in (tile, depth, index) order by a second stable sort on the tile, and
//!   per-tile front-to-back compositing in shared-memory batches (`forward/forward.wgsl`).
//!
//! Determinism: every reduction runs in a fixed order — prefix sums by blocks in shared
//! memory, radix sort ranks by counting, compositing in list order — and no float atomics
//! (no atomics at all) are used, so the same inputs on the same adapter give the same bytes.
//! The one exception is `backward_gpu_atomic`, a float-atomic variant of the compositing
//! backward that exists only to measure what this determinism costs
//! (`examples/gpu_determinism_cost.rs`); it is built only with the `determinism-cost`
//! feature.

mod chunk;
mod encoder;
mod pool;
pub mod prelude;
pub mod sort;
mod submit;
mod ticket;

#[cfg(feature = "determinism-cost")]
pub use crate::backward::gpu::backward_gpu_atomic;
pub use crate::backward::gpu::{
    backward_gpu, backward_gpu_timed, backward_gpu_with_cutoff, project_vjp_gpu, BackwardStage,
    ParamGradsGpu, PARAM_GRAD_STRIDE, SCREEN_GRAD_STRIDE,
};
pub use crate::forward::gpu::{
    forward_pass_in, past_loop_cap_error, render_gpu, render_scene, render_scene_masked,
    render_scene_with_cutoff, tile_pair_cap, upload_mask, GpuFrame, GpuScene, TILES_PAST_LOOP_CAP,
};

pub use encoder::{Encoder, RecordingStats};
use pool::Contents;
pub use pool::{GpuBuffer, PoolStats, DEFAULT_IDLE_BYTES};
pub use submit::BATCHED_UPLOAD_BYTES;
pub use ticket::ReadTicket;

/// What can go wrong on the GPU.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter was found (or none of the kind asked for).
    #[error("the GPU backend was asked for, but no GPU adapter was found ({found}); install a Vulkan driver (on Linux without a GPU, Mesa's lavapipe: `apt-get install mesa-vulkan-drivers`) or use the CPU backend")]
    NoAdapter {
        /// What the search found, in words.
        found: String,
    },
    /// `WGPU_ADAPTER_NAME` names no adapter on this machine.
    #[error("WGPU_ADAPTER_NAME={wanted:?} matches no GPU adapter (adapters here: {found}); set it to part of one of these names, or unset it")]
    NoNamedAdapter {
        /// The variable's value.
        wanted: String,
        /// The adapters found, in words.
        found: String,
    },
    /// The device could not be created, was lost, or reported an error.
    #[error("GPU device error on {adapter}: {message}")]
    Device {
        /// The adapter.
        adapter: String,
        /// What went wrong.
        message: String,
    },
    /// The work needs a buffer larger than the adapter allows.
    #[error("{what} needs {bytes} bytes; {adapter} allows {limit} for it")]
    TooLarge {
        /// Which buffer, and how it is bound ("one binding", "two bindings", "one buffer").
        what: String,
        /// Its size.
        bytes: u64,
        /// The adapter's limit for such a buffer.
        limit: u64,
        /// The adapter.
        adapter: String,
    },
    /// The inputs are inconsistent.
    #[error("{0}")]
    Invalid(String),
}

/// The adapter a result was computed on: name, driver and backend (for outputs' metadata).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct AdapterSummary {
    /// The adapter's name (e.g. "NVIDIA H100 80GB HBM3", "llvmpipe (LLVM 15.0.6, 256 bits)").
    pub name: String,
    /// The driver's name and version information.
    pub driver: String,
    /// The graphics API (Vulkan, Metal, Dx12, Gl).
    pub backend: String,
    /// Discrete, integrated, virtual GPU or CPU.
    pub device_type: String,
}

impl AdapterSummary {
    /// The most loop iterations one shader invocation runs on this adapter, all its loops
    /// together, where the driver caps them: Mesa's llvmpipe (lavapipe) ends an invocation's
    /// loops after 65,535 (`LP_MAX_TGSI_LOOP_ITERATIONS` in gallivm), silently. `None`: no
    /// known cap (hardware GPUs). Work whose loops would pass it is an error instead: a tile
    /// of more pairs than [`tile_pair_cap`], a field step of too many rays.
    pub fn loop_cap(&self) -> Option<u32> {
        self.name.contains("llvmpipe").then_some(65_535)
    }
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} ({}, {}, {})",
            self.name, self.backend, self.driver, self.device_type
        )
    }
}

/// A GPU device with the compiled kernels.
pub struct GpuContext {
    /// The device (for recording and submitting work).
    pub device: wgpu::Device,
    /// The device's queue.
    pub queue: wgpu::Queue,
    adapter: AdapterSummary,
    limits: wgpu::Limits,
    /// The largest storage binding in bytes (see [`GpuContext::with_binding_limit`]).
    binding_limit: u64,
    pub(crate) kernels: Kernels,
    /// Why the device was lost, once it was (set by wgpu's device-lost callback).
    lost: std::sync::Arc<std::sync::Mutex<Option<String>>>,
    /// The fault tests' option: the device is destroyed when this many training steps have
    /// begun on it (see [`GpuContext::lose_device_after`]).
    lose_after_steps: Option<u64>,
    /// Training steps begun on this context.
    steps_begun: std::sync::atomic::AtomicU64,
    /// Whether kernels read their parameters from storage buffers (see
    /// [`prelude::shader_module`]).
    params_as_storage: bool,
    /// Kernels other crates compile on this context ([`GpuContext::kernels_of`]), by type.
    extensions: std::sync::Mutex<KernelCache>,
    /// Buffers that were dropped, for reuse (`gpu/pool.rs`).
    pool: std::sync::Arc<pool::Pool>,
    /// Times the host has waited for the device ([`GpuContext::host_waits`]).
    waits: std::sync::atomic::AtomicU64,
    /// Of those, the waits for the latest submission ([`GpuContext::draining_waits`]).
    draining_waits: std::sync::atomic::AtomicU64,
    /// Nanoseconds the host has spent in those waits ([`GpuContext::host_wait_seconds`]).
    wait_nanos: std::sync::atomic::AtomicU64,
    /// Encoders kept for the next submission (`gpu/submit.rs`).
    pending: std::sync::Mutex<submit::Pending>,
    /// Submissions made ([`GpuContext::submissions`]).
    submissions: std::sync::atomic::AtomicU64,
    /// Dispatches, passes and uploads recorded ([`GpuContext::recording_stats`]).
    recording: encoder::RecordingCounters,
    /// The first error in making a submission's uploads (`gpu/submit.rs`), reported by
    /// [`GpuContext::check_lost`] from then on.
    upload_error: std::sync::Mutex<Option<String>>,
}

/// Compiled kernel sets by type.
type KernelCache =
    std::collections::HashMap<std::any::TypeId, std::sync::Arc<dyn std::any::Any + Send + Sync>>;

/// The compiled compute pipelines, by kernel family (each family's `gpu.rs` builds its own
/// from the WGSL beside it).
pub(crate) struct Kernels {
    pub(crate) project: crate::project::gpu::Kernels,
    pub(crate) sort: sort::Kernels,
    pub(crate) forward: crate::forward::gpu::Kernels,
    pub(crate) backward: crate::backward::gpu::Kernels,
}

/// The adapter wgpu prefers (high-performance first), or an error naming what was found.
fn default_adapter(instance: &wgpu::Instance) -> Result<wgpu::Adapter, GpuError> {
    pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        force_fallback_adapter: false,
        compatible_surface: None,
        apply_limit_buckets: false,
    }))
    .map_err(|e| {
        let all = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
        let found = if all.is_empty() {
            format!("no adapter on any backend: {e}")
        } else {
            all.iter()
                .map(|a| {
                    let i = a.get_info();
                    format!("{} ({:?}) unusable", i.name, i.backend)
                })
                .collect::<Vec<_>>()
                .join(", ")
        };
        GpuError::NoAdapter { found }
    })
}

/// The first adapter (in wgpu's order, on the backends `WGPU_BACKEND` allows) whose name
/// contains `wanted`, case-insensitively.
fn named_adapter(instance: &wgpu::Instance, wanted: &str) -> Result<wgpu::Adapter, GpuError> {
    let all = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
    let needle = wanted.trim().to_lowercase();
    let names: Vec<String> = all
        .iter()
        .map(|a| {
            let i = a.get_info();
            format!("{} ({:?})", i.name, i.backend)
        })
        .collect();
    all.into_iter()
        .find(|a| a.get_info().name.to_lowercase().contains(&needle))
        .ok_or_else(|| GpuError::NoNamedAdapter {
            wanted: wanted.to_string(),
            found: if names.is_empty() {
                "none".into()
            } else {
                names.join(", ")
            },
        })
}

impl GpuContext {
    /// Opens the first adapter wgpu finds (high-performance preferred; `WGPU_BACKEND` narrows
    /// the backends, and `WGPU_ADAPTER_NAME` picks the first adapter whose name contains its
    /// value, case-insensitively — one that matches none is an error listing the adapters,
    /// never a fall-back), with the adapter's own limits, and compiles the kernels.
    pub fn new() -> Result<GpuContext, GpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = match std::env::var("WGPU_ADAPTER_NAME")
            .ok()
            .filter(|v| !v.trim().is_empty())
        {
            Some(wanted) => named_adapter(&instance, &wanted)?,
            None => default_adapter(&instance)?,
        };
        let info = adapter.get_info();
        let summary = AdapterSummary {
            name: info.name.clone(),
            driver: format!("{} {}", info.driver, info.driver_info)
                .trim()
                .to_string(),
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
        };
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("augsplat"),
            required_features: wgpu::Features::empty(),
            required_limits: limits.clone(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
        }))
        .map_err(|e| GpuError::Device {
            adapter: summary.to_string(),
            message: format!("cannot open the device: {e}"),
        })?;
        let lost = std::sync::Arc::new(std::sync::Mutex::new(None));
        let lost_in_callback = lost.clone();
        device.set_device_lost_callback(move |reason, message| {
            if let Ok(mut l) = lost_in_callback.lock() {
                *l = Some(if message.is_empty() {
                    format!("{reason:?}")
                } else {
                    format!("{reason:?}: {message}")
                });
            }
        });
        // Compiling the kernels reports shader errors through an error scope, not a panic.
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        // Software adapters read the kernels' parameters from storage buffers: lavapipe
        // (Mesa 22) recompiles a compute shader at every dispatch whose uniform values it can
        // inline into branches and loop bounds, and never frees the copies (about 380 kB per
        // render). Real GPUs keep uniform buffers.
        let params_as_storage = info.device_type == wgpu::DeviceType::Cpu;
        let kernels = Kernels::new(&device, params_as_storage);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Device {
                adapter: summary.to_string(),
                message: format!("the kernels do not compile: {e}"),
            });
        }
        let binding_limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        Ok(GpuContext {
            device,
            queue,
            adapter: summary,
            binding_limit,
            limits,
            kernels,
            lost,
            // The fault tests reach a node in a child process through the environment; never
            // set in real runs.
            lose_after_steps: std::env::var("AUGSPLAT_TEST_LOSE_GPU_AFTER")
                .ok()
                .and_then(|v| v.parse().ok()),
            steps_begun: Default::default(),
            params_as_storage,
            extensions: Default::default(),
            pool: Default::default(),
            waits: Default::default(),
            draining_waits: Default::default(),
            wait_nanos: Default::default(),
            pending: Default::default(),
            submissions: Default::default(),
            recording: Default::default(),
            upload_error: Default::default(),
        })
    }

    /// The kernel set `K` on this context, compiled by `compile` at its first use and shared
    /// after that: how other kernel families (the trainer's losses and Adam, a radiance
    /// field's kernels) run on the same device, limits, error scopes and buffers as the
    /// renderer. A kernel that does not compile is a [`GpuError::Device`].
    pub fn kernels_of<K: std::any::Any + Send + Sync>(
        &self,
        compile: impl FnOnce(ModuleSetup<'_>) -> K,
    ) -> Result<std::sync::Arc<K>, GpuError> {
        let id = std::any::TypeId::of::<K>();
        let mut cache = self
            .extensions
            .lock()
            .map_err(|_| self.device_error("a kernel cache was poisoned".into()))?;
        if let Some(k) = cache.get(&id) {
            return std::sync::Arc::clone(k)
                .downcast::<K>()
                .map_err(|_| self.device_error("a kernel cache holds the wrong type".into()));
        }
        let k = std::sync::Arc::new(
            self.scoped(|| Ok(compile((&self.device, self.params_as_storage))))?,
        );
        cache.insert(id, k.clone());
        Ok(k)
    }

    /// A test-only option: the device is destroyed, as a driver reset would, when `steps`
    /// training steps have begun on this context (the step numbered `steps`, from 0, then
    /// fails with the device's message). `AUGSPLAT_TEST_LOSE_GPU_AFTER=N` sets it for the
    /// contexts [`GpuContext::new`] opens, so that the fault tests reach a node in a child
    /// process.
    #[doc(hidden)]
    pub fn lose_device_after(mut self, steps: u64) -> GpuContext {
        self.lose_after_steps = Some(steps);
        self
    }

    /// Counts a training step beginning on this context (for
    /// [`GpuContext::lose_device_after`]).
    pub fn count_training_step(&self) {
        let begun = self
            .steps_begun
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        if self.lose_after_steps == Some(begun) {
            self.destroy_device();
        }
    }

    /// The adapter this context runs on.
    pub fn adapter(&self) -> &AdapterSummary {
        &self.adapter
    }

    /// Destroys the device, as a driver reset or an unplugged GPU would: every later call on
    /// this context fails with a [`GpuError::Device`]. Only for the fault tests.
    #[doc(hidden)]
    pub fn destroy_device(&self) {
        self.device.destroy();
    }

    /// The device's limits (the adapter's own, which the context asks for in full).
    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// The largest storage binding in bytes: the adapter's, or less (see
    /// [`GpuContext::with_binding_limit`]). A kernel that binds a buffer whole needs it within.
    pub fn binding_limit(&self) -> u64 {
        self.binding_limit
    }

    /// A storage buffer of `bytes` bytes (at least 16), checked against the adapter's limits.
    /// It reads as zeros; it comes from the context's buffer pool when the pool holds one of
    /// its size.
    pub fn storage(&self, what: &str, bytes: u64) -> Result<GpuBuffer, GpuError> {
        self.storage_within(what, bytes, self.binding_limit)
    }

    /// A storage buffer of `bytes` bytes (at least 16), checked against `limit`, reading as
    /// zeros.
    pub fn storage_within(
        &self,
        what: &str,
        bytes: u64,
        limit: u64,
    ) -> Result<GpuBuffer, GpuError> {
        self.storage_shaped(what, bytes, limit, Contents::Zeroed)
    }

    /// A storage buffer of `bytes` bytes (at least 16) whose contents are left as they are: a
    /// buffer from the pool is not cleared. Only for a caller whose kernels write every word
    /// they later read before reading it.
    pub(crate) fn storage_overwritten(
        &self,
        what: &str,
        bytes: u64,
    ) -> Result<GpuBuffer, GpuError> {
        self.storage_shaped(what, bytes, self.binding_limit, Contents::Overwritten)
    }

    /// A storage buffer of `bytes` bytes rounded up as [`GpuContext::storage`] rounds,
    /// checked against `limit`.
    fn storage_shaped(
        &self,
        what: &str,
        bytes: u64,
        limit: u64,
        contents: Contents,
    ) -> Result<GpuBuffer, GpuError> {
        // At least one 16-byte element: kernels read some buffers as arrays of vec4, and an
        // empty set (no Gaussians, no pairs) still binds them.
        let bytes = bytes.max(16).next_multiple_of(4);
        if bytes > limit {
            let how = if limit < self.limits.max_buffer_size {
                "one binding"
            } else {
                "one buffer"
            };
            return Err(GpuError::TooLarge {
                what: format!("{what} ({how})"),
                bytes,
                limit,
                adapter: self.adapter.to_string(),
            });
        }
        Ok(self.pooled(
            what,
            bytes,
            wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            contents,
        ))
    }

    /// A storage buffer holding `data` (f32 or u32 words), checked against `limit`; past
    /// `data` (a buffer is at least 16 bytes) it reads as zeros.
    pub(crate) fn storage_init_within(
        &self,
        what: &str,
        data: &[u32],
        limit: u64,
    ) -> Result<GpuBuffer, GpuError> {
        let bytes = 4 * data.len() as u64;
        let buf = self.storage_shaped(what, bytes, limit, Contents::Overwritten)?;
        // Written whole, zeros past `data` up to a buffer's 16-byte minimum: an upload never
        // lands on a buffer whose clear is still kept (`gpu/submit.rs`).
        let mut words = data.to_vec();
        words.resize(words.len().max(4), 0);
        self.upload(&buf, &words_to_bytes(&words));
        Ok(buf)
    }

    /// A storage buffer holding `data` (f32 or u32 words).
    pub fn storage_init(&self, what: &str, data: &[u32]) -> Result<GpuBuffer, GpuError> {
        self.storage_init_within(what, data, self.binding_limit)
    }

    /// A uniform buffer holding `words` (zeros after them up to a multiple of 16 bytes).
    pub fn uniform(&self, what: &str, words: &[u32]) -> GpuBuffer {
        // Uploaded before the next submission rather than mapped at creation: on a lost device
        // a mapped creation panics inside wgpu, a failed upload is an error
        // (`GpuContext::check_lost`).
        let mut bytes = words_to_bytes(words);
        bytes.resize(
            (bytes.len() as u64).max(16).next_multiple_of(16) as usize,
            0,
        );
        // Also STORAGE: software adapters bind parameters as storage (`prelude::shader_module`).
        let usage = wgpu::BufferUsages::UNIFORM
            | wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST;
        let buf = self.pooled(what, bytes.len() as u64, usage, Contents::Overwritten);
        self.upload(&buf, &bytes);
        buf
    }

    /// Workgroups for `blocks` blocks: (x, y) with x ≤ the per-dimension limit.
    pub fn groups(&self, blocks: u32) -> [u32; 2] {
        let max = self.limits.max_compute_workgroups_per_dimension.max(1);
        if blocks <= max {
            [blocks.max(1), 1]
        } else {
            [max, blocks.div_ceil(max)]
        }
    }

    /// Submits `enc` and waits for the device; reports validation errors, out-of-memory and
    /// device loss as [`GpuError::Device`].
    pub fn submit(&self, enc: crate::gpu::Encoder) -> Result<(), GpuError> {
        self.submit_kept(Some(enc.finish()));
        self.wait()
    }

    /// Submits what is kept ([`GpuContext::defer`]) and `enc` without waiting for them: for
    /// work whose results stay on the GPU. The queue runs submissions in order, so the next read-back ([`GpuContext::read_after`])
    /// sees its effects; errors surface there or in the enclosing [`GpuContext::scoped`].
    pub fn submit_no_wait(&self, enc: crate::gpu::Encoder) -> Result<(), GpuError> {
        self.submit_kept(Some(enc.finish()));
        let _ = self.device.poll(wgpu::PollType::Poll);
        self.check_lost()
    }

    /// Submits what is kept ([`GpuContext::defer`]) and waits until everything submitted so
    /// far has run.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.submit_kept(None);
        self.count_wait(true);
        let started = std::time::Instant::now();
        let polled = self.device.poll(wgpu::PollType::wait_indefinitely());
        self.add_wait_time(started);
        polled.map_err(|e| self.device_error(format!("waiting for the GPU: {e}")))?;
        self.check_lost()
    }

    /// How many times the host has waited for the device on this context (a submission
    /// waited for, a read-back): what a step costs in round trips, for the tests and
    /// benchmarks that count them.
    pub fn host_waits(&self) -> u64 {
        self.waits.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// How many of [`GpuContext::host_waits`] waited for the latest submission: the device
    /// had nothing queued behind the awaited work, so it sat idle from the end of that work
    /// until the host submitted again. A wait for an earlier submission
    /// ([`ReadTicket::wait`] while later work is queued) leaves the device busy.
    pub fn draining_waits(&self) -> u64 {
        self.draining_waits
            .load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Counts a wait (`draining`: for the latest submission).
    pub(crate) fn count_wait(&self, draining: bool) {
        self.waits
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        if draining {
            self.draining_waits
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
    }

    /// The seconds the host has spent waiting for the device on this context: a step's wall
    /// time less its waits is what the host spent recording and submitting it (the time in
    /// which a GPU that finished its work sits idle).
    pub fn host_wait_seconds(&self) -> f64 {
        self.wait_nanos.load(std::sync::atomic::Ordering::Relaxed) as f64 * 1e-9
    }

    pub(crate) fn add_wait_time(&self, started: std::time::Instant) {
        let nanos = u64::try_from(started.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.wait_nanos
            .fetch_add(nanos, std::sync::atomic::Ordering::Relaxed);
    }

    /// A [`GpuError::Device`] if the device was lost (a driver reset, a removed GPU), or if a
    /// submission's gathered uploads could not be made (`gpu/submit.rs`).
    pub fn check_lost(&self) -> Result<(), GpuError> {
        let lost = self.lost.lock().ok().and_then(|l| l.clone());
        if let Some(why) = lost {
            return Err(self.device_error(format!("the GPU device was lost ({why})")));
        }
        match self.upload_error.lock().ok().and_then(|e| e.clone()) {
            Some(why) => Err(self.device_error(why)),
            None => Ok(()),
        }
    }

    /// Keeps an error of a submission's uploads for [`GpuContext::check_lost`] (the first
    /// one: the data behind every later one is missing too).
    pub(crate) fn note_upload_error(&self, message: String) {
        if let Ok(mut e) = self.upload_error.lock() {
            e.get_or_insert(message);
        }
    }

    /// A [`GpuError::Device`] on this context's adapter.
    pub fn device_error(&self, message: String) -> GpuError {
        GpuError::Device {
            adapter: self.adapter.to_string(),
            message,
        }
    }

    /// Copies `words` u32 words of `buf` back to the host.
    pub fn read_words(&self, buf: &wgpu::Buffer, words: usize) -> Result<Vec<u32>, GpuError> {
        if words == 0 {
            return Ok(Vec::new());
        }
        let enc = self.encoder();
        let mut parts = self.read_after(enc, &[(buf, 0, words)])?;
        Ok(parts.pop().unwrap_or_default())
    }

    /// Appends to `enc` a copy of each part (buffer, first word, words) into one staging
    /// buffer, submits it after what is kept ([`GpuContext::defer`]), waits once and returns
    /// each part's words: one round trip for several small read-backs
    /// ([`GpuContext::read_later`] and its wait).
    pub fn read_after(
        &self,
        enc: crate::gpu::Encoder,
        parts: &[(&wgpu::Buffer, u64, usize)],
    ) -> Result<Vec<Vec<u32>>, GpuError> {
        self.read_later(enc, parts)?.wait(self)
    }

    /// Runs `f` inside an error scope: validation errors and out-of-memory become
    /// [`GpuError::Device`] instead of a panic in wgpu's default handler.
    pub fn scoped<T>(&self, f: impl FnOnce() -> Result<T, GpuError>) -> Result<T, GpuError> {
        self.check_lost()?;
        let oom_scope = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation_scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = f();
        let validation = pollster::block_on(validation_scope.pop());
        let oom = pollster::block_on(oom_scope.pop());
        if oom.is_none() && validation.is_none() {
            let _ = self.device.poll(wgpu::PollType::Poll);
            self.check_lost()?;
            return out;
        }
        // A lost or destroyed device shows up as errors on whatever was recorded: let the
        // queue drain (wgpu reports the loss once it is empty) and name the cause.
        let _ = self.device.poll(wgpu::PollType::wait_indefinitely());
        self.check_lost()?;
        if let Some(e) = oom {
            return Err(self.device_error(format!("out of GPU memory: {}", error_chain(&e))));
        }
        if let Some(e) = validation {
            return Err(self.device_error(format!("validation error: {}", error_chain(&e))));
        }
        out
    }
}

/// `e` and its sources, joined by ": " (wgpu's top-level message alone can be as bare as
/// "Validation Error").
fn error_chain(e: &wgpu::Error) -> String {
    let mut text = e.to_string();
    let mut source = std::error::Error::source(e);
    while let Some(s) = source {
        let line = s.to_string();
        if !text.contains(&line) {
            text.push_str(": ");
            text.push_str(&line);
        }
        source = s.source();
    }
    text
}

impl Kernels {
    fn new(device: &wgpu::Device, params_as_storage: bool) -> Kernels {
        let m = (device, params_as_storage);
        Kernels {
            project: crate::project::gpu::Kernels::new(m),
            sort: sort::Kernels::new(m),
            forward: crate::forward::gpu::Kernels::new(m),
            backward: crate::backward::gpu::Kernels::new(m),
        }
    }
}

/// What a family's kernels are compiled with: the device, and whether parameters are bound
/// as storage (see [`prelude::shader_module`]).
pub type ModuleSetup<'a> = (&'a wgpu::Device, bool);

/// Compiles `src` (with the prelude) and its entry points `entries`, in order.
pub fn pipelines<const K: usize>(
    setup: ModuleSetup<'_>,
    label: &str,
    src: &str,
    entries: [&str; K],
) -> [wgpu::ComputePipeline; K] {
    pipelines_with(setup, label, "", src, entries)
}

/// [`pipelines`] with the family's own generated declarations `extra` after the prelude.
pub fn pipelines_with<const K: usize>(
    (device, params_as_storage): ModuleSetup<'_>,
    label: &str,
    extra: &str,
    src: &str,
    entries: [&str; K],
) -> [wgpu::ComputePipeline; K] {
    let module = prelude::shader_module(device, label, extra, src, params_as_storage);
    entries.map(|entry| {
        device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: None,
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        })
    })
}

/// Little-endian bytes of `words`.
pub fn words_to_bytes(words: &[u32]) -> Vec<u8> {
    words.iter().flat_map(|w| w.to_le_bytes()).collect()
}

/// The bits of f32 values, for buffers.
pub fn f32_words(v: impl IntoIterator<Item = f32>) -> Vec<u32> {
    v.into_iter().map(f32::to_bits).collect()
}
