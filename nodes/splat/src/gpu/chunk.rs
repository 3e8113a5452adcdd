//! Per-Gaussian arrays larger than one binding: kernels that touch only their own item's
//! values (projection, its VJP, the per-view sums, Adam) run over chunks of items, each chunk
//! binding its own range of every per-item buffer and indexing it from 0.
//!
//! An adapter caps one storage binding well below its largest buffer: lavapipe at 128 MiB,
//! where a degree-3 Gaussian's SH coefficients (192 bytes), their gradients and their two
//! Adam moments cap a training set at about 700,000 Gaussians when bound whole. Such buffers
//! are allocated up to the adapter's buffer limit ([`GpuContext::storage_items`]) and are only
//! ever bound by range ([`GpuContext::dispatch_items`]). Buffers that kernels read at any
//! index (the screen-space splats, the tile lists) stay within one binding; they are 48 bytes
//! per Gaussian or less, so the SH-sized arrays are no longer what limits the set.
//!
//! Each item's values are computed by the same invocation with the same inputs whichever
//! chunk it falls in, so a chunked dispatch writes the same bytes as a whole one.

use super::{GpuContext, GpuError};

/// One binding of [`GpuContext::dispatch_items`]: (binding, buffer, 32-bit words per item).
/// Item `i` sits at word `i · words`; each chunk binds the range of its own items, which the
/// kernel sees as items 0, 1, ….
pub(super) type ItemBinding<'a> = (u32, &'a wgpu::Buffer, u64);

impl GpuContext {
    /// Caps every storage binding at `bytes` (never above the adapter's own limit), so that the
    /// tests can make small sets run in chunks and check that chunking changes no bit.
    #[doc(hidden)]
    pub fn with_binding_limit(mut self, bytes: u64) -> GpuContext {
        self.binding_limit = self.binding_limit.min(bytes.max(1024));
        self
    }

    /// A storage buffer of `bytes` bytes that kernels bind only through
    /// [`GpuContext::dispatch_items`]: checked against the adapter's largest buffer, not its largest binding.
    pub(super) fn storage_items(&self, what: &str, bytes: u64) -> Result<wgpu::Buffer, GpuError> {
        self.storage_within(what, bytes, self.limits.max_buffer_size)
    }

    /// [`GpuContext::storage_items`] holding `data`.
    pub(super) fn storage_items_init(
        &self,
        what: &str,
        data: &[u32],
    ) -> Result<wgpu::Buffer, GpuError> {
        let buf = self.storage_items(what, 4 * data.len() as u64)?;
        if !data.is_empty() {
            self.queue
                .write_buffer(&buf, 0, &super::words_to_bytes(data));
        }
        Ok(buf)
    }

    /// How many items one chunk of a dispatch over `items` items may hold, with `words` words
    /// per item for each binding: a multiple of the offset alignment (so every
    /// chunk's range starts aligned), each range within the binding limit.
    pub(super) fn chunk_items(&self, words: &[u64]) -> Result<u64, GpuError> {
        let widest = words.iter().copied().max().unwrap_or(1).max(1);
        let align = u64::from(self.limits.min_storage_buffer_offset_alignment.max(4));
        let fit = self.binding_limit / (4 * widest);
        let per = fit / align * align;
        if per == 0 {
            return Err(GpuError::TooLarge {
                what: format!("one chunk of {align} items of {widest} values"),
                bytes: 4 * widest * align,
                limit: self.binding_limit,
                adapter: self.adapter.to_string(),
            });
        }
        Ok(per)
    }

    /// Records `pipeline` over `items` items with `threads` invocations per item (workgroups
    /// of 256), in as few chunks as keep every binding's range within the binding limit.
    /// `uniform` is bound at 0, with each chunk's item count written at word `count_word`.
    /// One chunk binds every buffer whole: exactly the unchunked dispatch.
    pub(super) fn dispatch_items(
        &self,
        enc: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::ComputePipeline,
        (uniform, count_word): (&[u32], usize),
        bindings: &[ItemBinding<'_>],
        items: u32,
        threads: u32,
    ) -> Result<(), GpuError> {
        let widths: Vec<u64> = bindings.iter().map(|b| b.2).collect();
        let per = self.chunk_items(&widths)?;
        let invocations = |n: u64| -> Result<u32, GpuError> {
            u32::try_from(n * u64::from(threads)).map_err(|_| {
                GpuError::Invalid(format!("{n} items × {threads} invocations overflow"))
            })
        };
        let mut words = uniform.to_vec();
        if u64::from(items) <= per {
            let whole = bindings.iter().map(|&(i, buf, _)| (i, buf));
            let u = self.uniform("chunk constants", &words);
            let mut all = vec![(0, &u)];
            all.extend(whole);
            let groups = self.groups(invocations(u64::from(items))?.div_ceil(256));
            self.dispatch(enc, pipeline, &all, groups);
            return Ok(());
        }
        let mut first = 0u64;
        while first < u64::from(items) {
            let count = per.min(u64::from(items) - first);
            words[count_word] = count as u32;
            let u = self.uniform("chunk constants", &words);
            let mut entries = vec![wgpu::BindGroupEntry {
                binding: 0,
                resource: u.as_entire_binding(),
            }];
            for &(binding, buffer, w) in bindings {
                entries.push(wgpu::BindGroupEntry {
                    binding,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer,
                        offset: 4 * w * first,
                        size: std::num::NonZeroU64::new(4 * w * count),
                    }),
                });
            }
            let groups = self.groups(invocations(count)?.div_ceil(256));
            self.dispatch_entries(enc, pipeline, &entries, groups);
            first += count;
        }
        Ok(())
    }
}

/// Buffers read at any index (the screen-space splats, the pair slots of the backward) are
/// bound as two ranges, items `[0, split)` and `[split, items)`, and the kernels pick one by
/// the item's index (`splits` in their parameters): twice the adapter's binding limit.
impl GpuContext {
    /// Where a buffer of `items` items of `words` words splits into its two bindings: `items`
    /// when one binding holds it all, else the most items one binding holds (a multiple of
    /// the offset alignment, so the second range starts aligned).
    pub(super) fn split_at(&self, items: u64, words: u64) -> u32 {
        let words = words.max(1);
        if items * words * 4 <= self.binding_limit {
            return items as u32;
        }
        let align = u64::from(self.limits.min_storage_buffer_offset_alignment.max(4));
        let fit = self.binding_limit / (4 * words) / align * align;
        fit.min(items) as u32
    }

    /// A buffer of `items` items of `words` words for [`GpuContext::split_at`]'s two
    /// bindings: a [`GpuError::TooLarge`] naming `what` when two bindings cannot hold it.
    pub(super) fn storage_split(
        &self,
        what: &str,
        items: u64,
        words: u64,
    ) -> Result<wgpu::Buffer, GpuError> {
        let split = u64::from(self.split_at(items, words));
        if (items - split) * words * 4 > self.binding_limit || (split == 0 && items > 0) {
            return Err(GpuError::TooLarge {
                what: format!("{what} (read through two bindings)"),
                bytes: 4 * words * items,
                limit: 2 * self.binding_limit,
                adapter: self.adapter.to_string(),
            });
        }
        self.storage_items(what, 4 * words * items)
    }

    /// The two bindings of a [`GpuContext::storage_split`] buffer: the whole buffer twice when
    /// it is not split.
    pub(super) fn split_ranges<'a>(
        &self,
        buf: &'a wgpu::Buffer,
        items: u64,
        words: u64,
    ) -> [wgpu::BindingResource<'a>; 2] {
        let split = u64::from(self.split_at(items, words));
        if split >= items {
            return [buf.as_entire_binding(), buf.as_entire_binding()];
        }
        let range = |first: u64, count: u64| {
            wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: buf,
                offset: 4 * words * first,
                size: std::num::NonZeroU64::new(4 * words * count),
            })
        };
        [range(0, split), range(split, items - split)]
    }

    /// [`GpuContext::dispatch`] with whole buffers and ready resources (ranges).
    pub(super) fn dispatch_mixed(
        &self,
        enc: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::ComputePipeline,
        whole: &[(u32, &wgpu::Buffer)],
        ranged: Vec<(u32, wgpu::BindingResource<'_>)>,
        groups: [u32; 2],
    ) {
        let mut entries: Vec<wgpu::BindGroupEntry<'_>> = whole
            .iter()
            .map(|(b, buf)| wgpu::BindGroupEntry {
                binding: *b,
                resource: buf.as_entire_binding(),
            })
            .collect();
        entries.extend(
            ranged
                .into_iter()
                .map(|(binding, resource)| wgpu::BindGroupEntry { binding, resource }),
        );
        self.dispatch_entries(enc, pipeline, &entries, groups);
    }
}
