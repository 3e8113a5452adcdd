// The training losses on the GPU: the WGSL twin of loss/mod.rs (`photometric`, `weighted_l2`)
// and of the fused SSIM of loss/fused.rs, in f32 with the CPU's tap order and fused
// multiply-adds. Images are interleaved rows of 3·W values; the prediction is read with a
// stride (`p.stride` words per pixel, colour in the first three), everything else is dense.
//
// SSIM (valid padding, 11-tap separable window) takes four passes over 256-thread blocks:
//   h_moments   five horizontal moment rows (x, y, x², y², xy) per input row → `moments`
//   v_ssim      vertical sums → the SSIM map value and its partials dS/dμx, dS/dE[x²],
//               dS/dE[xy] per map value → `part`; map values summed per block
//   v_adjoint   vertical adjoint of the partials per input row → `moments` planes 0..2
//   ssim_grad   horizontal adjoint, chain rule `A + 2x·B + y·C`, plus the pixel term;
//               writes the gradient, pixel term summed per block
// Without SSIM, `pixel` does the L2/L1 term alone; `weighted` is the weighted L2.
//
// Determinism: every value is computed by one thread in a fixed order, and each block sums
// its 256 values by the same shared-memory tree into its own slot of `sums` (no atomics); the
// host adds the slots in index order. The gradient is written, not added.

struct Params {
    width: u32,
    height: u32,
    stride: u32,               // f32 words per pixel of `pred`
    mode: u32,                 // pixel, ssim_grad: 0 L2, 1 L1; weighted: 0 normal, 1 all zero
    k: f32,                    // pixel-term gradient factor (L2 2s/n, L1 s/n, weighted 2s/N)
    gs: f32,                   // SSIM gradient factor, −s·λ / map values
    c1: f32,                   // SSIM stabilisers
    c2: f32,
    win: array<vec4<f32>, 3>,  // the 11 window taps (the last word unused)
    // x: 1 when the target holds bytes (four per word, values `u8_values[byte]`: a photo
    // kept as it was decoded), 0 when it holds f32 values.
    target_form: vec4<u32>,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> pred: array<f32>;             // p.stride words per pixel
@group(0) @binding(2) var<storage, read> tgt: array<u32>;              // the target, H·W·3
@group(0) @binding(3) var<storage, read> weights: array<f32>;          // one per pixel
@group(0) @binding(4) var<storage, read_write> moments: array<f32>;    // 5 planes of H·M
@group(0) @binding(5) var<storage, read_write> part: array<f32>;       // 3 planes of (H−10)·M
@group(0) @binding(6) var<storage, read_write> grad: array<f32>;       // H·W·3, written
@group(0) @binding(7) var<storage, read_write> sums: array<f32>;       // one per block
@group(0) @binding(9) var<storage, read> u8_values: array<f32>;        // 256: byte k's value

// Value i of the target: its f32 bits, or its byte's value (exactly the host's).
fn tgt_at(i: u32) -> f32 {
    if (p.target_form.x == 0u) {
        return bitcast<f32>(tgt[i]);
    }
    return u8_values[(tgt[i >> 2u] >> (8u * (i & 3u))) & 0xffu];
}

var<workgroup> red: array<f32, 256>;

fn block_index(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}

fn tap(k: u32) -> f32 {
    return p.win[k / 4u][k % 4u];
}

// Interleaved value `v` (pixel v / 3, channel v % 3) of the prediction.
fn pred_at(v: u32) -> f32 {
    return pred[(v / 3u) * p.stride + v % 3u];
}

// Interleaved map row length 3·(W − 10).
fn map_row() -> u32 {
    return 3u * (p.width - SSIM_HALO);
}

// Sums the block's 256 values `v` by a fixed tree into `sums[block]` (blocks that start at or
// past `count` are the spill of a two-dimensional dispatch and write nothing). Called by every
// thread of the block, in uniform control flow.
fn block_sum(block: u32, li: u32, v: f32, count: u32) {
    red[li] = v;
    workgroupBarrier();
    for (var s = LOSS_BLOCK / 2u; s > 0u; s = s >> 1u) {
        if (li < s) {
            red[li] = red[li] + red[li + s];
        }
        workgroupBarrier();
    }
    if (li == 0u && block * LOSS_BLOCK < count) {
        sums[block] = red[0];
    }
}

// The L2 (mode 0) or L1 (mode 1) gradient step of one value with factor k (no SSIM part):
// (gradient, loss contribution).
fn pixel_step(diff: f32) -> vec2<f32> {
    if (p.mode == 0u) {
        return vec2<f32>(p.k * diff, diff * diff);
    }
    var g = 0.0;
    if (diff > 0.0) {
        g = p.k;
    } else if (diff < 0.0) {
        g = -p.k;
    }
    return vec2<f32>(g, abs(diff));
}

// The pixel term alone (no SSIM): one thread per value.
@compute @workgroup_size(256)
fn pixel(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_index) li: u32) {
    let block = block_index(wid, nwg);
    let n = 3u * p.width * p.height;
    let i = block * LOSS_BLOCK + li;
    var contrib = 0.0;
    if (i < n) {
        let r = pixel_step(pred_at(i) - tgt_at(i));
        grad[i] = r.x;
        contrib = r.y;
    }
    block_sum(block, li, contrib, n);
}

// The weighted L2: k = 2·scale / denominator; weights that are not finite or not positive
// count as 0 (no loss, zero gradient); mode 1 writes zeros (a denominator that is not
// positive).
@compute @workgroup_size(256)
fn weighted(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) li: u32) {
    let block = block_index(wid, nwg);
    let n = 3u * p.width * p.height;
    let i = block * LOSS_BLOCK + li;
    var contrib = 0.0;
    if (i < n) {
        let raw = weights[i / 3u];
        // Finite and positive, tested on the bits (WGSL may assume floats are finite).
        let bits = bitcast<u32>(raw);
        let finite = (bits & 0x7f800000u) != 0x7f800000u;
        var g = 0.0;
        if (p.mode == 0u && finite && raw > 0.0) {
            let d = pred_at(i) - tgt_at(i);
            g = p.k * raw * d;
            contrib = raw * d * d;
        }
        grad[i] = g;
    }
    block_sum(block, li, contrib, n);
}

// SSIM pass 1: per input row and map column j, the five horizontal moment sums
// Σ_k w_k f(v[j + 3k]) in tap order, into planes x, y, x², y², xy of `moments`.
@compute @workgroup_size(256)
fn h_moments(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
             @builtin(local_invocation_index) li: u32) {
    let m = map_row();
    let plane = p.height * m;
    let i = block_index(wid, nwg) * LOSS_BLOCK + li;
    if (i >= plane) {
        return;
    }
    let base = (i / m) * 3u * p.width + i % m;
    var mx = 0.0;
    var my = 0.0;
    var exx = 0.0;
    var eyy = 0.0;
    var exy = 0.0;
    for (var k = 0u; k < SSIM_WINDOW; k++) {
        let v = base + 3u * k;
        let x = pred_at(v);
        let y = tgt_at(v);
        let w = tap(k);
        mx = fma(w, x, mx);
        my = fma(w, y, my);
        exx = fma(w, x * x, exx);
        eyy = fma(w, y * y, eyy);
        exy = fma(w, x * y, exy);
    }
    moments[i] = mx;
    moments[plane + i] = my;
    moments[2u * plane + i] = exx;
    moments[3u * plane + i] = eyy;
    moments[4u * plane + i] = exy;
}

// SSIM pass 2: per map value, the vertical sums of the five moments, the SSIM value and its
// partials (loss/fused.rs `ssim_window`: one division), partials into `part`, values summed.
@compute @workgroup_size(256)
fn v_ssim(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
          @builtin(local_invocation_index) li: u32) {
    let block = block_index(wid, nwg);
    let m = map_row();
    let plane = p.height * m;
    let count = (p.height - SSIM_HALO) * m;
    let i = block * LOSS_BLOCK + li;
    var s = 0.0;
    if (i < count) {
        var mo = array<f32, 5>(0.0, 0.0, 0.0, 0.0, 0.0);
        for (var k = 0u; k < SSIM_WINDOW; k++) {
            let w = tap(k);
            let o = i + k * m;    // row oy + k, column j
            for (var q = 0u; q < 5u; q++) {
                mo[q] = fma(w, moments[q * plane + o], mo[q]);
            }
        }
        let mx = mo[0];
        let my = mo[1];
        let mx2 = mx * mx;
        let my2 = my * my;
        let mxy = mx * my;
        let n1 = 2.0 * mxy + p.c1;
        let n2 = 2.0 * (mo[4] - mxy) + p.c2;
        let d1 = mx2 + my2 + p.c1;
        let d2 = (mo[2] - mx2) + (mo[3] - my2) + p.c2;
        let inv = 1.0 / (d1 * d2);
        s = n1 * n2 * inv;
        part[i] = 2.0 * inv * (my * (n2 - n1) + mx * s * (d1 - d2));
        part[count + i] = -s * d1 * inv;
        part[2u * count + i] = 2.0 * n1 * inv;
    }
    block_sum(block, li, s, count);
}

// SSIM pass 3: per input row y and map column j, the vertical adjoint of the three partials
// (map rows y − k, k ascending, that exist), into planes 0..2 of `moments`.
@compute @workgroup_size(256)
fn v_adjoint(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
             @builtin(local_invocation_index) li: u32) {
    let m = map_row();
    let plane = p.height * m;
    let oh = p.height - SSIM_HALO;
    let count = oh * m;
    let i = block_index(wid, nwg) * LOSS_BLOCK + li;
    if (i >= plane) {
        return;
    }
    let y = i / m;
    let j = i % m;
    var klo = 0u;
    if (y + 1u > oh) {
        klo = y + 1u - oh;
    }
    let khi = min(y, SSIM_HALO);
    var a = 0.0;
    var b = 0.0;
    var c = 0.0;
    for (var k = klo; k <= khi; k++) {
        let w = tap(k);
        let o = (y - k) * m + j;
        a = fma(w, part[o], a);
        b = fma(w, part[count + o], b);
        c = fma(w, part[2u * count + o], c);
    }
    moments[i] = a;
    moments[plane + i] = b;
    moments[2u * plane + i] = c;
}

// SSIM pass 4: per value, the horizontal adjoint (taps with j = i − 3k inside the map row),
// the chain rule through the moments `A + 2x·B + y·C` times gs, plus the pixel term; writes
// the gradient and sums the pixel term.
@compute @workgroup_size(256)
fn ssim_grad(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
             @builtin(local_invocation_index) li: u32) {
    let block = block_index(wid, nwg);
    let m = map_row();
    let plane = p.height * m;
    let l = 3u * p.width;
    let n = l * p.height;
    let i = block * LOSS_BLOCK + li;
    var contrib = 0.0;
    if (i < n) {
        let col = i % l;
        let row = (i / l) * m;
        var a = 0.0;
        var b = 0.0;
        var c = 0.0;
        // The taps k with 0 ≤ col − 3k < m, in increasing k: a loop over that range rather
        // than a test inside all 11 iterations — the same sums, but on lavapipe (Mesa 22.3)
        // every dispatch of the tested form grew the process by about the size of the
        // submission's buffers (400 kB per call at 64×48; `tests/gpu_memory.rs`).
        let k_hi = min(SSIM_WINDOW - 1u, col / 3u);
        var k_lo = 0u;
        if (col >= m) {
            k_lo = (col - m) / 3u + 1u;
        }
        for (var k = k_lo; k <= k_hi; k++) {
            let w = tap(k);
            let o = row + col - 3u * k;
            a = fma(w, moments[o], a);
            b = fma(w, moments[plane + o], b);
            c = fma(w, moments[2u * plane + o], c);
        }
        let x = pred_at(i);
        let t = tgt_at(i);
        let d = fma(t, c, fma(2.0 * x, b, a));
        let r = pixel_step(x - t);
        grad[i] = fma(p.gs, d, r.x);
        contrib = r.y;
    }
    block_sum(block, li, contrib, n);
}
