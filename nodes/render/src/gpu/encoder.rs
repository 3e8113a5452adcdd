//! Recording: an [`Encoder`] keeps one compute pass open across the dispatches recorded into
//! it, so that a step's many small kernels cost the host one pass instead of one each.
//!
//! wgpu encodes every compute pass into its own command buffer with its own resource
//! tracking when the encoder is finished; a pass per dispatch cost this project's training
//! step most of its recording time (`examples/gpu_dispatch_cost.rs` measures it). Within one
//! pass wgpu still makes each dispatch see the writes of the dispatches before it (every
//! dispatch is its own usage scope, with the barriers between them that a pass per dispatch
//! had), so keeping the pass open changes when work is encoded, never what it computes.
//!
//! Any other command (a copy, a clear) needs the pass ended first: the encoder ends it when
//! it is borrowed mutably as a [`wgpu::CommandEncoder`] (`DerefMut`), so code that records a
//! copy between dispatches reads as before, and the next dispatch opens a new pass.

use super::GpuContext;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

/// What a context has recorded since it opened: what a step costs the host in passes and
/// uploads, for the tests and benchmarks that count them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RecordingStats {
    /// Dispatches recorded ([`GpuContext::dispatch`], [`GpuContext::dispatch_entries`]).
    pub dispatches: u64,
    /// Compute passes those dispatches began: one per run of dispatches with nothing else
    /// recorded between them in one [`Encoder`].
    pub passes: u64,
    /// Uploads gathered into a submission's batch (parameter blocks, short arrays).
    pub gathered_uploads: u64,
    /// Queue writes made: one per submission with gathered uploads, one per large upload.
    pub queue_writes: u64,
}

/// The counters behind [`RecordingStats`].
#[derive(Default)]
pub(crate) struct RecordingCounters {
    dispatches: AtomicU64,
    passes: AtomicU64,
    gathered_uploads: AtomicU64,
    queue_writes: AtomicU64,
}

impl RecordingCounters {
    /// Counts an upload: gathered into a batch, or a queue write of its own.
    pub(crate) fn count_upload(&self, gathered: bool) {
        if gathered {
            self.gathered_uploads.fetch_add(1, Relaxed);
        } else {
            self.queue_writes.fetch_add(1, Relaxed);
        }
    }
}

/// A command encoder whose dispatches share one compute pass (see the module notes).
pub struct Encoder {
    /// The open pass, ended before anything else is recorded (and dropped before `enc`).
    pass: Option<wgpu::ComputePass<'static>>,
    /// The encoder, locked by wgpu while `pass` is open.
    enc: wgpu::CommandEncoder,
}

impl Encoder {
    /// Whether a compute pass is open (the next dispatch continues it).
    pub fn in_pass(&self) -> bool {
        self.pass.is_some()
    }

    /// The open compute pass, begun if none is.
    pub fn pass(&mut self) -> &mut wgpu::ComputePass<'static> {
        self.pass.get_or_insert_with(|| {
            self.enc
                .begin_compute_pass(&wgpu::ComputePassDescriptor::default())
                .forget_lifetime()
        })
    }

    /// Ends the open pass and finishes the encoder.
    pub fn finish(self) -> wgpu::CommandBuffer {
        let Encoder { pass, enc } = self;
        drop(pass);
        enc.finish()
    }
}

impl std::ops::Deref for Encoder {
    type Target = wgpu::CommandEncoder;

    fn deref(&self) -> &wgpu::CommandEncoder {
        &self.enc
    }
}

impl std::ops::DerefMut for Encoder {
    /// Ends the open pass: every command an encoder records needs it ended.
    fn deref_mut(&mut self) -> &mut wgpu::CommandEncoder {
        self.pass = None;
        &mut self.enc
    }
}

impl GpuContext {
    /// A new [`Encoder`] on this context's device.
    pub fn encoder(&self) -> Encoder {
        Encoder {
            pass: None,
            enc: self.device.create_command_encoder(&Default::default()),
        }
    }

    /// What this context has recorded since it opened (dispatches, passes, uploads).
    pub fn recording_stats(&self) -> RecordingStats {
        let c = &self.recording;
        RecordingStats {
            dispatches: c.dispatches.load(Relaxed),
            passes: c.passes.load(Relaxed),
            gathered_uploads: c.gathered_uploads.load(Relaxed),
            queue_writes: c.queue_writes.load(Relaxed),
        }
    }

    /// Records one dispatch of `pipeline` over `groups` workgroups (spread over two
    /// dimensions past the per-dimension limit) with `buffers` at bindings 0, 1, ….
    pub fn dispatch(
        &self,
        enc: &mut Encoder,
        pipeline: &wgpu::ComputePipeline,
        bindings: &[(u32, &wgpu::Buffer)],
        groups: [u32; 2],
    ) {
        let entries: Vec<wgpu::BindGroupEntry<'_>> = bindings
            .iter()
            .map(|(b, buf)| wgpu::BindGroupEntry {
                binding: *b,
                resource: buf.as_entire_binding(),
            })
            .collect();
        self.dispatch_entries(enc, pipeline, &entries, groups);
    }

    /// [`GpuContext::dispatch`] with ready bind-group entries (whole buffers or ranges).
    pub fn dispatch_entries(
        &self,
        enc: &mut Encoder,
        pipeline: &wgpu::ComputePipeline,
        entries: &[wgpu::BindGroupEntry<'_>],
        groups: [u32; 2],
    ) {
        let layout = pipeline.get_bind_group_layout(0);
        let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &layout,
            entries,
        });
        self.recording.dispatches.fetch_add(1, Relaxed);
        if !enc.in_pass() {
            self.recording.passes.fetch_add(1, Relaxed);
        }
        let pass = enc.pass();
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(groups[0], groups[1], 1);
    }
}
