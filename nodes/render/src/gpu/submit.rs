//! Submissions: work recorded for the queue waits on the context until something needs it
//! run, so that many small encoders (a step's views, its clears and its optimiser update) go
//! to the device in one submission instead of one each, each paying the host's latency.
//!
//! - [`GpuContext::defer`] finishes an encoder and keeps it, in order, without submitting;
//! - [`GpuContext::submit`], [`GpuContext::submit_no_wait`], a read-back
//!   ([`GpuContext::read_after`]), [`GpuContext::wait`] and [`GpuContext::flush`] submit
//!   everything kept, then their own work, in one `queue.submit`;
//! - a pooled buffer handed out again zeroed is cleared in an encoder that runs in the next
//!   submission before any kept work (after the gathered uploads below): it is idle, so no
//!   kept work uses it, and what it is recorded into comes later (`gpu/pool.rs`);
//! - small uploads (a kernel's parameter block, a short array: [`GpuContext::uniform`],
//!   [`GpuContext::storage_init`] up to [`BATCHED_UPLOAD_BYTES`]) wait with them too: their
//!   bytes are gathered on the host and go up in one queue write per submission, copied to
//!   their buffers at its start. A queue write costs wgpu a staging buffer of its own, which
//!   was most of the time a step took to record.
//!
//! Order is unchanged: the queue runs the kept encoders in the order they were recorded, so
//! deferring changes when work starts, never what it computes. Two rules keep it so. An
//! upload (batched, or a large one's own `queue.write_buffer`) lands before the next
//! submission's encoders, so it may target only a buffer that no kept encoder uses and that
//! is not cleared by the next submission: a fresh or reused buffer that its writer overwrites
//! whole (`GpuContext::storage_init`, `GpuContext::uniform`). And the pool reclaims dropped
//! buffers only when nothing is kept ([`GpuContext::reclaim`]): a kept encoder or upload may
//! still use them.

use super::pool::Contents;
use super::{Encoder, GpuBuffer, GpuContext, GpuError};

/// The largest upload gathered into a submission's batch (64 KiB); a larger one goes up in a
/// queue write of its own, whose staging buffer its size amortises.
pub const BATCHED_UPLOAD_BYTES: usize = 64 << 10;

/// The most bytes gathered for one submission (16 MiB); uploads past it go up in queue
/// writes of their own.
const MAX_BATCH_BYTES: usize = 16 << 20;

/// The smallest staging buffer a submission's uploads go up in (sizes round up to a power of
/// two from here, so the pool hands the same few shapes out again).
const MIN_STAGING_BYTES: u64 = 4 << 10;

/// The encoders and uploads kept for the next submission.
#[derive(Default)]
pub(crate) struct Pending {
    /// Clears of reused pool buffers, run after the uploads' copies and before the kept
    /// encoders.
    clears: Option<wgpu::CommandEncoder>,
    /// The bytes of the gathered uploads, each starting at a multiple of 4.
    upload: Vec<u8>,
    /// Each gathered upload's buffer, its offset in `upload` and its length in bytes.
    targets: Vec<(wgpu::Buffer, u64, u64)>,
    /// Finished encoders, in recording order.
    buffers: Vec<wgpu::CommandBuffer>,
}

impl Pending {
    fn is_empty(&self) -> bool {
        self.clears.is_none() && self.targets.is_empty() && self.buffers.is_empty()
    }
}

impl GpuContext {
    /// Finishes `enc` and keeps it for the next submission (see the module notes): for work
    /// whose results stay on the GPU and that nothing on the host waits for yet.
    pub fn defer(&self, enc: Encoder) -> Result<(), GpuError> {
        let buf = enc.finish();
        match self.pending.lock() {
            Ok(mut p) => p.buffers.push(buf),
            // Another thread panicked while holding the lock: submit at once instead.
            Err(_) => {
                self.count_submission();
                self.queue.submit([buf]);
            }
        }
        self.check_lost()
    }

    /// Submits everything kept ([`GpuContext::defer`]) in one submission, without waiting.
    pub fn flush(&self) -> Result<(), GpuError> {
        self.submit_kept(None);
        self.check_lost()
    }

    /// Whether encoders, clears or uploads are kept for the next submission.
    pub fn has_deferred(&self) -> bool {
        self.pending.lock().map(|p| !p.is_empty()).unwrap_or(false)
    }

    /// How many submissions this context has made: what batching saves, for the tests and
    /// benchmarks that count them.
    pub fn submissions(&self) -> u64 {
        self.submissions.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Counts a submission: its number ([`GpuContext::submissions`] after it).
    fn count_submission(&self) -> u64 {
        self.submissions
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed)
            + 1
    }

    /// Records a clear of `buf` (an idle pool buffer handed out again) into the encoder that
    /// runs first in the next submission.
    pub(crate) fn clear_first(&self, buf: &wgpu::Buffer) {
        let Ok(mut p) = self.pending.lock() else {
            let mut enc = self.device.create_command_encoder(&Default::default());
            enc.clear_buffer(buf, 0, None);
            self.count_submission();
            self.queue.submit([enc.finish()]);
            return;
        };
        p.clears
            .get_or_insert_with(|| self.device.create_command_encoder(&Default::default()))
            .clear_buffer(buf, 0, None);
    }

    /// Writes `bytes` (a multiple of 4 long) to the start of `buf` before the next
    /// submission's work: gathered into that submission's one upload when short, in a queue
    /// write of its own when long (see the module notes for what `buf` may be).
    pub(crate) fn upload(&self, buf: &wgpu::Buffer, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        if bytes.len() <= BATCHED_UPLOAD_BYTES {
            if let Ok(mut p) = self.pending.lock() {
                if p.upload.len() + bytes.len() > MAX_BATCH_BYTES {
                    // A long run of uploads with no submission: the batch stops growing.
                    drop(p);
                    self.recording.count_upload(false);
                    self.queue.write_buffer(buf, 0, bytes);
                    return;
                }
                let at = p.upload.len() as u64;
                p.upload.extend_from_slice(bytes);
                p.targets.push((buf.clone(), at, bytes.len() as u64));
                self.recording.count_upload(true);
                return;
            }
        }
        self.recording.count_upload(false);
        self.queue.write_buffer(buf, 0, bytes);
    }

    /// What runs first in a submission: the copies of the gathered uploads (written here to
    /// a staging buffer, returned to be dropped once the submission is made), then the
    /// clears of reused buffers — the order a queue write and the clears had. Errors in
    /// making them (no memory for the staging buffer) are kept for
    /// [`GpuContext::check_lost`] to report: this runs wherever work is submitted, inside an
    /// error scope or not.
    fn head(&self, kept: &mut Pending) -> (Vec<wgpu::CommandBuffer>, Option<GpuBuffer>) {
        let clears = kept.clears.take().map(wgpu::CommandEncoder::finish);
        if kept.targets.is_empty() {
            return (clears.into_iter().collect(), None);
        }
        let oom_scope = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation_scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let bytes = (kept.upload.len() as u64)
            .next_power_of_two()
            .max(MIN_STAGING_BYTES);
        let staging = self.pooled(
            "uploads",
            bytes,
            wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            Contents::Overwritten,
        );
        self.recording.count_upload(false);
        self.queue.write_buffer(&staging, 0, &kept.upload);
        let mut enc = self.device.create_command_encoder(&Default::default());
        for (buf, at, len) in kept.targets.drain(..) {
            enc.copy_buffer_to_buffer(&staging, at, &buf, 0, len);
        }
        let copies = enc.finish();
        let validation = pollster::block_on(validation_scope.pop());
        let oom = pollster::block_on(oom_scope.pop());
        if let Some(e) = oom.or(validation) {
            self.note_upload_error(format!("uploading parameters and arrays: {e}"));
        }
        let first = std::iter::once(copies).chain(clears).collect();
        (first, Some(staging))
    }

    /// Submits the kept encoders and then `last`, in one submission (none when there is
    /// nothing to submit): the submission's number ([`GpuContext::submissions`] after it)
    /// and wgpu's index of it.
    pub(crate) fn submit_kept(
        &self,
        last: Option<wgpu::CommandBuffer>,
    ) -> Option<(u64, wgpu::SubmissionIndex)> {
        // Taken even from a lock poisoned by a panic elsewhere: the gathered uploads must go
        // with the work that reads them.
        let mut kept = std::mem::take(
            &mut *self
                .pending
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner),
        );
        if kept.is_empty() && last.is_none() {
            return None;
        }
        let (head, staging) = self.head(&mut kept);
        let all: Vec<wgpu::CommandBuffer> =
            head.into_iter().chain(kept.buffers).chain(last).collect();
        let number = self.count_submission();
        let index = self.queue.submit(all);
        // Into the pool's quarantine only now that its copies are submitted: reusable after
        // the next reclaim, and the queue runs this submission before any later write to it.
        drop(staging);
        Some((number, index))
    }
}
