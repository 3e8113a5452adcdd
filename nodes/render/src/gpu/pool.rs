//! The context's buffer pool: buffers that kernels are done with wait here, by exact size and
//! usage, for the next request of the same shape, so that a training loop does not allocate
//! its per-step buffers (images, per-Gaussian arrays between refinements, parameter blocks,
//! read-back staging) at every step.
//!
//! A [`GpuBuffer`] dropped by its owner is not reusable at once: a command encoder that
//! recorded it may not be submitted yet, and a reuse (a clear, a queue write) would run before
//! that work. Dropped buffers wait in quarantine until [`GpuContext::reclaim`], which a caller
//! runs where no encoder that recorded a pooled buffer is left unsubmitted (it waits while
//! encoders, clears or uploads are kept for the next submission, `gpu/submit.rs`): the
//! training device
//! at the start of each step, the whole-render entry points when they return. Everything
//! submitted before a reuse runs before it (wgpu orders one queue's work), so a reclaimed
//! buffer is free.
//!
//! Buffers are handed out at the exact size asked for (a binding of the whole buffer means
//! the same as for a new one), and a storage buffer handed out again is cleared on the queue
//! before anything later runs, so it reads as zeros like a new one: reuse changes no result.
//!
//! The idle buffers are bounded ([`DEFAULT_IDLE_BYTES`], or [`GpuContext::with_pool_limit`]):
//! when a reclaimed buffer would pass the bound, the longest-idle buffers are freed first.
//! [`GpuContext::trim_pool`] frees all of them.

use super::GpuContext;
use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex};

/// The idle bytes a pool keeps by default (256 MiB).
pub const DEFAULT_IDLE_BYTES: u64 = 256 << 20;

/// A buffer's shape in the pool: its size in bytes and its usages.
type Shape = (u64, wgpu::BufferUsages);

/// The idle buffers, and what the pool has done.
#[derive(Default)]
struct Idle {
    /// Idle buffers by shape.
    by_shape: HashMap<Shape, Vec<wgpu::Buffer>>,
    /// The shapes of idle buffers in the order they came back (oldest first).
    returned: VecDeque<Shape>,
    /// Bytes held idle.
    bytes: u64,
    /// Buffers dropped since the last [`GpuContext::reclaim`] (possibly still recorded in an
    /// unsubmitted encoder).
    quarantine: Vec<wgpu::Buffer>,
    stats: PoolStats,
}

/// What a pool has done since its context opened.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PoolStats {
    /// Buffers created because no idle one had the shape.
    pub created: u64,
    /// Buffers handed out again.
    pub reused: u64,
    /// Idle buffers freed to stay within the bound (or by a trim).
    pub freed: u64,
    /// Bytes held idle now.
    pub idle_bytes: u64,
    /// Buffers dropped and waiting for the next reclaim.
    pub quarantined: u64,
}

/// The shared part of a pool.
pub(crate) struct Pool {
    idle: Mutex<Idle>,
    limit: std::sync::atomic::AtomicU64,
}

impl Default for Pool {
    fn default() -> Pool {
        Pool {
            idle: Mutex::default(),
            limit: DEFAULT_IDLE_BYTES.into(),
        }
    }
}

impl Pool {
    /// An idle buffer of this shape, if the pool holds one.
    fn take(&self, shape: Shape) -> Option<wgpu::Buffer> {
        let mut idle = self.idle.lock().ok()?;
        let buf = idle.by_shape.get_mut(&shape).and_then(Vec::pop)?;
        if let Some(at) = idle.returned.iter().rposition(|s| *s == shape) {
            idle.returned.remove(at);
        }
        idle.bytes -= shape.0;
        idle.stats.reused += 1;
        Some(buf)
    }

    /// Counts a buffer created for want of an idle one.
    fn count_created(&self) {
        if let Ok(mut idle) = self.idle.lock() {
            idle.stats.created += 1;
        }
    }

    /// Takes `buf` back into quarantine (reusable after the next [`Pool::reclaim`]).
    fn give_back(&self, buf: wgpu::Buffer) {
        if let Ok(mut idle) = self.idle.lock() {
            idle.quarantine.push(buf);
        }
    }

    /// Makes the quarantined buffers reusable, freeing the longest-idle buffers to stay
    /// within the bound (a buffer that alone passes it is freed).
    fn reclaim(&self) {
        let limit = self.limit.load(std::sync::atomic::Ordering::Relaxed);
        let Ok(mut idle) = self.idle.lock() else {
            return;
        };
        for buf in std::mem::take(&mut idle.quarantine) {
            let shape = (buf.size(), buf.usage());
            if shape.0 > limit {
                idle.stats.freed += 1;
                continue;
            }
            while idle.bytes + shape.0 > limit {
                idle.free_oldest();
            }
            idle.bytes += shape.0;
            idle.by_shape.entry(shape).or_default().push(buf);
            idle.returned.push_back(shape);
        }
    }

    /// Frees every idle buffer.
    fn trim(&self) {
        if let Ok(mut idle) = self.idle.lock() {
            while idle.bytes > 0 {
                idle.free_oldest();
            }
        }
    }

    fn stats(&self) -> PoolStats {
        self.idle
            .lock()
            .map(|i| PoolStats {
                idle_bytes: i.bytes,
                quarantined: i.quarantine.len() as u64,
                ..i.stats
            })
            .unwrap_or_default()
    }
}

impl Idle {
    /// Frees the buffer that has been idle longest.
    fn free_oldest(&mut self) {
        let Some(shape) = self.returned.pop_front() else {
            self.bytes = 0;
            return;
        };
        if let Some(list) = self.by_shape.get_mut(&shape) {
            if !list.is_empty() {
                // Dropping the handle frees the memory once no submitted work uses it.
                list.remove(0);
                self.bytes -= shape.0;
                self.stats.freed += 1;
            }
            if list.is_empty() {
                self.by_shape.remove(&shape);
            }
        }
    }
}

/// A buffer from the context's pool: used as a [`wgpu::Buffer`] (it dereferences to one) and
/// returned to the pool when dropped.
pub struct GpuBuffer {
    buf: Option<wgpu::Buffer>,
    pool: Arc<Pool>,
}

impl std::ops::Deref for GpuBuffer {
    type Target = wgpu::Buffer;
    fn deref(&self) -> &wgpu::Buffer {
        // Present from creation until the drop takes it.
        self.buf.as_ref().unwrap_or_else(|| unreachable!())
    }
}

impl Drop for GpuBuffer {
    fn drop(&mut self) {
        if let Some(buf) = self.buf.take() {
            self.pool.give_back(buf);
        }
    }
}

impl GpuBuffer {
    /// Frees the buffer instead of returning it to the pool (a read-back buffer whose mapping
    /// failed cannot be copied into again).
    pub(crate) fn discard(mut self) {
        self.buf = None;
    }
}

impl std::fmt::Debug for GpuBuffer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuBuffer")
            .field("size", &self.size())
            .finish()
    }
}

/// Whether a buffer handed out again must be cleared first.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Contents {
    /// It must read as zeros, like a new buffer.
    Zeroed,
    /// The caller overwrites all of it before any kernel reads it.
    Overwritten,
}

impl GpuContext {
    /// A buffer of exactly `bytes` bytes with `usage`, from the pool when it holds one of that
    /// shape (cleared first when `contents` is [`Contents::Zeroed`]), else a new one.
    pub(crate) fn pooled(
        &self,
        what: &str,
        bytes: u64,
        usage: wgpu::BufferUsages,
        contents: Contents,
    ) -> GpuBuffer {
        let pool = Arc::clone(&self.pool);
        if let Some(buf) = pool.take((bytes, usage)) {
            if contents == Contents::Zeroed {
                // Idle, so no kept encoder uses it: cleared first in the next submission,
                // before any work recorded with it (`gpu/submit.rs`).
                self.clear_first(&buf);
            }
            return GpuBuffer {
                buf: Some(buf),
                pool,
            };
        }
        pool.count_created();
        let buf = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(what),
            size: bytes,
            usage,
            mapped_at_creation: false,
        });
        GpuBuffer {
            buf: Some(buf),
            pool,
        }
    }

    /// Bounds the bytes the buffer pool keeps idle (default [`DEFAULT_IDLE_BYTES`]; 0 keeps
    /// none: every buffer is freed at the reclaim after its drop).
    pub fn with_pool_limit(self, bytes: u64) -> GpuContext {
        self.pool
            .limit
            .store(bytes, std::sync::atomic::Ordering::Relaxed);
        self.pool.trim();
        self
    }

    /// Frees every idle buffer of the pool (buffers in use or in quarantine are unaffected).
    pub fn trim_pool(&self) {
        self.pool.trim();
    }

    /// Makes the buffers dropped since the last call reusable. Call it only where no command
    /// encoder that recorded a pooled buffer is still being recorded (between training steps,
    /// after a whole render): a buffer reused while such an encoder waits would be cleared or
    /// overwritten before that encoder's work runs. While encoders or uploads are kept for
    /// the next submission ([`GpuContext::defer`], [`GpuContext::uniform`]) it does nothing:
    /// they may use the dropped buffers, which wait for a later call.
    pub fn reclaim(&self) {
        if !self.has_deferred() {
            self.pool.reclaim();
        }
    }

    /// What the buffer pool has done: buffers created and reused, idle bytes.
    pub fn pool_stats(&self) -> PoolStats {
        self.pool.stats()
    }
}
