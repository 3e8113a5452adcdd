//! Read-backs collected later: [`GpuContext::read_later`] records the copies and submits them
//! without waiting, and the [`ReadTicket`] it returns waits for that submission alone
//! ([`ReadTicket::wait`]), not for work submitted after it. A loop that submits step `k + 1`
//! before it collects step `k`'s numbers keeps the device busy with `k + 1` while the host
//! reads `k`'s and records `k + 2`.

use super::pool::Contents;
use super::{GpuBuffer, GpuContext, GpuError};
use std::sync::mpsc;

/// The answer of a staging buffer's mapping.
type Mapped = Result<(), wgpu::BufferAsyncError>;

/// A read-back submitted by [`GpuContext::read_later`], whose words [`ReadTicket::wait`]
/// returns.
pub struct ReadTicket {
    /// The staging buffer the parts were copied into and its mapping's answer (`None` when
    /// there is nothing to read).
    staging: Option<(GpuBuffer, mpsc::Receiver<Mapped>)>,
    /// Each part's words.
    sizes: Vec<usize>,
    /// The submission that copies them: its number on the context and wgpu's index.
    submission: Option<(u64, wgpu::SubmissionIndex)>,
}

impl GpuContext {
    /// Appends to `enc` a copy of each part (buffer, first word, words) into one staging
    /// buffer and submits it after what is kept ([`GpuContext::defer`]), without waiting:
    /// [`ReadTicket::wait`] returns each part's words once that submission has run.
    pub fn read_later(
        &self,
        mut enc: crate::gpu::Encoder,
        parts: &[(&wgpu::Buffer, u64, usize)],
    ) -> Result<ReadTicket, GpuError> {
        let sizes: Vec<usize> = parts.iter().map(|p| p.2).collect();
        let total: u64 = sizes.iter().map(|&w| 4 * w as u64).sum();
        let staging = (total > 0).then(|| {
            self.pooled(
                "readback",
                total,
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                Contents::Overwritten,
            )
        });
        if let Some(staging) = &staging {
            let mut at = 0;
            for &(buf, first, words) in parts {
                let bytes = 4 * words as u64;
                if bytes > 0 {
                    enc.copy_buffer_to_buffer(buf, 4 * first, staging, at, bytes);
                }
                at += bytes;
            }
        }
        let submission = self.submit_kept(Some(enc.finish()));
        let staging = staging.map(|staging| {
            let (tx, rx) = mpsc::channel();
            staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
                let _ = tx.send(r);
            });
            (staging, rx)
        });
        let _ = self.device.poll(wgpu::PollType::Poll);
        self.check_lost()?;
        Ok(ReadTicket {
            staging,
            sizes,
            submission,
        })
    }
}

impl ReadTicket {
    /// Waits for the submission that copied the parts (not for anything submitted later) and
    /// returns each part's words. It counts as one of [`GpuContext::host_waits`]; as one of
    /// [`GpuContext::draining_waits`] when nothing was submitted after it.
    pub fn wait(mut self, ctx: &GpuContext) -> Result<Vec<Vec<u32>>, GpuError> {
        let submission = self.submission.take();
        let Some((staging, mapped)) = self.staging.take() else {
            // Nothing to read: the wait is for the submission alone.
            if let Some(submission) = submission {
                wait_for(ctx, submission)?;
            }
            return Ok(self.sizes.iter().map(|_| Vec::new()).collect());
        };
        let read = Self::read(ctx, &staging, &mapped, submission, &self.sizes);
        match read {
            Ok(_) => staging.unmap(),
            // Never returned to the pool in an unknown mapping state.
            Err(_) => staging.discard(),
        }
        read
    }

    fn read(
        ctx: &GpuContext,
        staging: &wgpu::Buffer,
        mapped: &mpsc::Receiver<Mapped>,
        submission: Option<(u64, wgpu::SubmissionIndex)>,
        sizes: &[usize],
    ) -> Result<Vec<Vec<u32>>, GpuError> {
        let submission = submission
            .ok_or_else(|| ctx.device_error("a read-back's copies were never submitted".into()))?;
        wait_for(ctx, submission)?;
        // The wait ran the mapping's callback once the copies ran; never block on it (a lost
        // device may keep it forever).
        mapped
            .try_recv()
            .map_err(|_| {
                ctx.device_error("the read-back never completed (is the device lost?)".into())
            })?
            .map_err(|e| ctx.device_error(format!("read-back failed: {e}")))?;
        let data = staging
            .slice(..)
            .get_mapped_range()
            .map_err(|e| ctx.device_error(format!("read-back mapping: {e}")))?;
        let mut out = Vec::with_capacity(sizes.len());
        let mut at = 0;
        for &words in sizes {
            out.push(
                data[at..at + 4 * words]
                    .chunks_exact(4)
                    .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect(),
            );
            at += 4 * words;
        }
        Ok(out)
    }
}

/// Waits for one submission (counted in [`GpuContext::host_waits`], and in
/// [`GpuContext::draining_waits`] when nothing was submitted after it).
fn wait_for(
    ctx: &GpuContext,
    (number, index): (u64, wgpu::SubmissionIndex),
) -> Result<(), GpuError> {
    ctx.count_wait(number == ctx.submissions());
    let started = std::time::Instant::now();
    let polled = ctx.device.poll(wgpu::PollType::Wait {
        submission_index: Some(index),
        timeout: None,
    });
    ctx.add_wait_time(started);
    if let Err(e) = polled {
        // A lost device fails its submissions, and the wait for one says only that: the
        // loss (its callback runs as the device is polled) is the error to report.
        let _ = ctx.device.poll(wgpu::PollType::wait_indefinitely());
        ctx.check_lost()?;
        return Err(ctx.device_error(format!("waiting for a read-back: {e}")));
    }
    ctx.check_lost()
}

impl Drop for ReadTicket {
    /// A ticket dropped before its wait frees its staging buffer: a buffer whose mapping is
    /// pending cannot go back to the pool.
    fn drop(&mut self) {
        if let Some((staging, _)) = self.staging.take() {
            staging.discard();
        }
    }
}
