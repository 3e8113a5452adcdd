//! Host side of the GPU prefix sum and radix sort (`scan.wgsl`, `sort.wgsl`).

use super::{GpuContext, GpuError};

/// Elements per workgroup block in the scan and the sort.
const BLOCK: u32 = 256;

impl GpuContext {
    /// Records an in-place exclusive prefix sum of the first `n` u32 words of `data`.
    pub fn record_scan(
        &self,
        enc: &mut crate::gpu::Encoder,
        data: &wgpu::Buffer,
        n: u32,
    ) -> Result<(), GpuError> {
        if n == 0 {
            return Ok(());
        }
        let blocks = n.div_ceil(BLOCK);
        let sums = self.storage("scan block sums", 4 * u64::from(blocks))?;
        let params = self.uniform("scan params", &[n, blocks, 0, 0]);
        let k = &self.kernels.sort;
        self.dispatch(
            enc,
            &k.scan_blocks,
            &[(0, &params), (1, data), (2, &sums)],
            self.groups(blocks),
        );
        if blocks > 1 {
            self.record_scan(enc, &sums, blocks)?;
            self.dispatch(
                enc,
                &k.add_sums,
                &[(0, &params), (1, data), (2, &sums)],
                self.groups(blocks),
            );
        }
        Ok(())
    }

    /// Records a stable sort of `n` (key, value) pairs by the low `bits` bits of the key
    /// (4 bits per pass); returns the buffers holding the result (either the inputs or the
    /// scratch pair, by the parity of the passes).
    pub fn record_sort<'a>(
        &self,
        enc: &mut crate::gpu::Encoder,
        keys: &'a wgpu::Buffer,
        vals: &'a wgpu::Buffer,
        scratch: (&'a wgpu::Buffer, &'a wgpu::Buffer),
        n: u32,
        bits: u32,
    ) -> Result<(&'a wgpu::Buffer, &'a wgpu::Buffer), GpuError> {
        self.record_sort_values(enc, keys, vals, scratch, n, bits, false)
    }

    /// [`GpuContext::record_sort`] of the pairs (key `i`, `i`): the sorted values are the
    /// keys' order, and `vals` (written by the sort, never read) needs no upload of the
    /// indices. `bits` must be positive (no pass would leave `vals` unwritten).
    pub fn record_sort_indices<'a>(
        &self,
        enc: &mut crate::gpu::Encoder,
        keys: &'a wgpu::Buffer,
        vals: &'a wgpu::Buffer,
        scratch: (&'a wgpu::Buffer, &'a wgpu::Buffer),
        n: u32,
        bits: u32,
    ) -> Result<(&'a wgpu::Buffer, &'a wgpu::Buffer), GpuError> {
        if bits == 0 {
            return Err(GpuError::Invalid(
                "a sort of indices by 0 key bits writes no order".into(),
            ));
        }
        self.record_sort_values(enc, keys, vals, scratch, n, bits, true)
    }

    /// The sort, its values read from `vals` or (`indices`) the indices in the first pass.
    #[allow(clippy::too_many_arguments)]
    fn record_sort_values<'a>(
        &self,
        enc: &mut crate::gpu::Encoder,
        keys: &'a wgpu::Buffer,
        vals: &'a wgpu::Buffer,
        scratch: (&'a wgpu::Buffer, &'a wgpu::Buffer),
        n: u32,
        bits: u32,
        indices: bool,
    ) -> Result<(&'a wgpu::Buffer, &'a wgpu::Buffer), GpuError> {
        let mut src = (keys, vals);
        let mut dst = scratch;
        if n == 0 {
            return Ok(src);
        }
        let blocks = n.div_ceil(BLOCK);
        let ranks = self.storage("sort ranks", 4 * u64::from(n))?;
        let hist = self.storage("sort histogram", 4 * 16 * u64::from(blocks))?;
        let k = &self.kernels.sort;
        for pass in 0..bits.div_ceil(4) {
            let index_values = u32::from(indices && pass == 0);
            let params = self.uniform("sort params", &[n, blocks, 4 * pass, index_values]);
            self.dispatch(
                enc,
                &k.sort_count,
                &[(0, &params), (1, src.0), (3, &ranks), (4, &hist)],
                self.groups(blocks),
            );
            self.record_scan(enc, &hist, 16 * blocks)?;
            self.dispatch(
                enc,
                &k.sort_scatter,
                &[
                    (0, &params),
                    (1, src.0),
                    (2, src.1),
                    (3, &ranks),
                    (4, &hist),
                    (5, dst.0),
                    (6, dst.1),
                ],
                self.groups(blocks),
            );
            std::mem::swap(&mut src, &mut dst);
        }
        Ok(src)
    }
}

/// The compiled scan and sort kernels (`scan.wgsl`, `sort.wgsl`).
pub(crate) struct Kernels {
    scan_blocks: wgpu::ComputePipeline,
    add_sums: wgpu::ComputePipeline,
    sort_count: wgpu::ComputePipeline,
    sort_scatter: wgpu::ComputePipeline,
}

impl Kernels {
    pub(crate) fn new(m: super::ModuleSetup<'_>) -> Kernels {
        let [scan_blocks, add_sums] = super::pipelines(
            m,
            "scan.wgsl",
            include_str!("scan.wgsl"),
            ["scan_blocks", "add_sums"],
        );
        let [sort_count, sort_scatter] = super::pipelines(
            m,
            "sort.wgsl",
            include_str!("sort.wgsl"),
            ["count", "scatter"],
        );
        Kernels {
            scan_blocks,
            add_sums,
            sort_count,
            sort_scatter,
        }
    }
}
