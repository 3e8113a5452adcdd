//! Buffers larger than one storage binding. An adapter caps one binding well below its
//! largest buffer (lavapipe at 128 MiB, where a degree-3 Gaussian's SH coefficients, 192
//! bytes, capped a training set at about 700,000 Gaussians when bound whole). Two schemes:
//!
//! - Per-Gaussian arrays that kernels touch only at their own Gaussian (parameters, SH,
//!   gradients, Adam's moments, statistics): projection, its VJP, the per-view sums and Adam
//!   run over chunks of Gaussians, each chunk binding its own range of every such buffer and
//!   indexing it from 0 ([`GpuContext::dispatch_items`]). These buffers are checked against
//!   the adapter's largest buffer only ([`GpuContext::storage_items`]).
//! - Buffers read or written at any index (the screen-space splats and gradients, the
//!   backward's pair slots) are bound as up to four consecutive ranges, and the kernels pick
//!   one by the index (`splits` and `pair_splits` in their parameters;
//!   [`GpuContext::split_ranges`]).
//!
//! Each value is computed by the same invocation from the same inputs whichever chunk or range
//! it falls in, so the bytes are those of a whole-buffer run.

use super::{GpuContext, GpuError};

/// One binding of [`GpuContext::dispatch_items`]: (binding, buffer, 32-bit words per item).
/// Item `i` sits at word `i · words`; each chunk binds the range of its own items, which the
/// kernel sees as items 0, 1, ….
pub type ItemBinding<'a> = (u32, &'a wgpu::Buffer, u64);

impl GpuContext {
    /// Caps every storage binding at `bytes` (never above the adapter's own limit), so that the
    /// tests can make small sets run in chunks and check that chunking changes no bit.
    #[doc(hidden)]
    pub fn with_binding_limit(mut self, bytes: u64) -> GpuContext {
        self.binding_limit = self.binding_limit.min(bytes.max(1024));
        self
    }

    /// A storage buffer of `bytes` bytes that kernels bind only by range: checked against the
    /// adapter's largest buffer, not its largest binding.
    pub fn storage_items(&self, what: &str, bytes: u64) -> Result<super::GpuBuffer, GpuError> {
        self.storage_within(what, bytes, self.limits.max_buffer_size)
    }

    /// [`GpuContext::storage_items`] holding `data`.
    pub fn storage_items_init(
        &self,
        what: &str,
        data: &[u32],
    ) -> Result<super::GpuBuffer, GpuError> {
        self.storage_init_within(what, data, self.limits.max_buffer_size)
    }

    /// How many items one chunk of a dispatch may hold, with `words` words per item for each
    /// binding: a multiple of the offset alignment (so every chunk's range starts aligned),
    /// each range within the binding limit.
    fn chunk_items(&self, words: &[u64]) -> Result<u64, GpuError> {
        let widest = words.iter().copied().max().unwrap_or(1).max(1);
        let per = self.range_items(widest);
        if per == 0 {
            return Err(GpuError::TooLarge {
                what: format!("one chunk of Gaussians with {widest} values each (one binding)"),
                bytes: 4 * widest * u64::from(self.limits.min_storage_buffer_offset_alignment),
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
    pub fn dispatch_items(
        &self,
        enc: &mut crate::gpu::Encoder,
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
            let mut all = vec![(0, &*u)];
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

/// Buffers read or written at any index (the screen-space splats and gradients, the
/// backward's pair slots) are bound as `k` consecutive ranges of items, and the kernels pick
/// one by the item's index (`splits` and `pair_splits` in their parameters): `k` times the
/// adapter's binding limit.
impl GpuContext {
    /// The most items of `words` words one range holds: a multiple of the offset alignment,
    /// so every range starts aligned.
    fn range_items(&self, words: u64) -> u64 {
        let align = u64::from(self.limits.min_storage_buffer_offset_alignment.max(4));
        self.binding_limit / (4 * words.max(1)) / align * align
    }

    /// The first item of each range after the first, for a buffer of `items` items of
    /// `words` words bound as `k` ranges (`k − 1` values; `items` for ranges left empty).
    pub fn split_points(&self, items: u64, words: u64, k: usize) -> Vec<u32> {
        let per = if items * words * 4 <= self.binding_limit {
            items
        } else {
            self.range_items(words)
        };
        (1..k).map(|i| (per * i as u64).min(items) as u32).collect()
    }

    /// A buffer of `items` items of `words` words for [`GpuContext::split_ranges`]'s `k`
    /// bindings: a [`GpuError::TooLarge`] naming `what` when `k` bindings cannot hold it.
    pub fn storage_split(
        &self,
        what: &str,
        items: u64,
        words: u64,
        k: usize,
    ) -> Result<super::GpuBuffer, GpuError> {
        let fits =
            items * words * 4 <= self.binding_limit || items <= self.range_items(words) * k as u64;
        if !fits {
            return Err(GpuError::TooLarge {
                what: format!("{what} ({k} bindings)"),
                bytes: 4 * words * items,
                limit: k as u64 * self.binding_limit,
                adapter: self.adapter.to_string(),
            });
        }
        self.storage_items(what, 4 * words * items)
    }

    /// The `k` bindings of a [`GpuContext::storage_split`] buffer, at [`GpuContext::split_points`];
    /// a range left empty binds the first range again (never read).
    pub fn split_ranges<'a>(
        &self,
        buf: &'a wgpu::Buffer,
        items: u64,
        words: u64,
        k: usize,
    ) -> Vec<wgpu::BindingResource<'a>> {
        let mut bounds = vec![0u64];
        bounds.extend(
            self.split_points(items, words, k)
                .into_iter()
                .map(u64::from),
        );
        bounds.push(items);
        if bounds[1] >= items {
            return (0..k).map(|_| buf.as_entire_binding()).collect();
        }
        let range = |first: u64, count: u64| {
            wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: buf,
                offset: 4 * words * first,
                size: std::num::NonZeroU64::new(4 * words * count),
            })
        };
        (0..k)
            .map(|i| {
                let (a, b) = (bounds[i], bounds[i + 1]);
                if b > a {
                    range(a, b - a)
                } else {
                    range(0, bounds[1])
                }
            })
            .collect()
    }

    /// [`GpuContext::dispatch`] with whole buffers and ready resources (ranges).
    pub fn dispatch_mixed(
        &self,
        enc: &mut crate::gpu::Encoder,
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
