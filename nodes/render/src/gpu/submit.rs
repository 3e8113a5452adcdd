//! Submissions: work recorded for the queue waits on the context until something needs it
//! run, so that many small encoders (a step's views, its clears and its optimiser update) go
//! to the device in one submission instead of one each, each paying the host's latency.
//!
//! - [`GpuContext::defer`] finishes an encoder and keeps it, in order, without submitting;
//! - [`GpuContext::submit`], [`GpuContext::submit_no_wait`], a read-back
//!   ([`GpuContext::read_after`]), [`GpuContext::wait`] and [`GpuContext::flush`] submit
//!   everything kept, then their own work, in one `queue.submit`;
//! - a pooled buffer handed out again zeroed is cleared in an encoder that runs first in the
//!   next submission: it is idle, so no kept work uses it, and what it is recorded into comes
//!   later (`gpu/pool.rs`).
//!
//! Order is unchanged: the queue runs the kept encoders in the order they were recorded, so
//! deferring changes when work starts, never what it computes. Two rules keep it so. A queue
//! write (`queue.write_buffer`) runs before the next submission's encoders, so it may target
//! only a buffer that no kept encoder uses and that is not cleared by the next submission: a
//! fresh or reused buffer that its writer overwrites whole (`GpuContext::storage_init`,
//! `GpuContext::uniform`). And the pool reclaims dropped buffers only when nothing is kept
//! ([`GpuContext::reclaim`]): a kept encoder may still use them.

use super::{GpuContext, GpuError};

/// The encoders kept for the next submission.
#[derive(Default)]
pub(crate) struct Pending {
    /// Clears of reused pool buffers, run before everything else.
    clears: Option<wgpu::CommandEncoder>,
    /// Finished encoders, in recording order.
    buffers: Vec<wgpu::CommandBuffer>,
}

impl Pending {
    fn is_empty(&self) -> bool {
        self.clears.is_none() && self.buffers.is_empty()
    }
}

impl GpuContext {
    /// Finishes `enc` and keeps it for the next submission (see the module notes): for work
    /// whose results stay on the GPU and that nothing on the host waits for yet.
    pub fn defer(&self, enc: wgpu::CommandEncoder) -> Result<(), GpuError> {
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

    /// Whether encoders are kept for the next submission.
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

    /// Submits the kept encoders and then `last`, in one submission (none when there is
    /// nothing to submit): the submission's number ([`GpuContext::submissions`] after it)
    /// and wgpu's index of it.
    pub(crate) fn submit_kept(
        &self,
        last: Option<wgpu::CommandBuffer>,
    ) -> Option<(u64, wgpu::SubmissionIndex)> {
        let kept = self
            .pending
            .lock()
            .map(|mut p| std::mem::take(&mut *p))
            .unwrap_or_default();
        if kept.is_empty() && last.is_none() {
            return None;
        }
        let all: Vec<wgpu::CommandBuffer> = kept
            .clears
            .map(wgpu::CommandEncoder::finish)
            .into_iter()
            .chain(kept.buffers)
            .chain(last)
            .collect();
        let number = self.count_submission();
        Some((number, self.queue.submit(all)))
    }
}
