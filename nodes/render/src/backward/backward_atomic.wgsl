// The compositing backward with float atomics instead of ordered pair slots: a measuring
// device for what the determinism of backward.wgsl costs (gpu/backward.rs,
// `backward_gpu_atomic`), not used by training.
//
// `rasterize_backward_atomic` is backward.wgsl's `rasterize_backward` line for line — the
// same back-to-front walk and the same two-level fixed-order sums over the tile's 256 pixels
// (column sums, then the 16 columns; the same barriers) — except at the end of each (tile,
// Gaussian) pair: instead of writing the tile's sums into the pair's own slot for
// `gaussian_sums` to add up in tile order, level 2's 9 lanes convert them to
// dL/d(mean2d, conic, opacity, colour) (gaussian_sums' conversion, which is linear in the
// sums) and each adds one of them straight into the Gaussian's SCREEN_STRIDE slot with a
// float atomic add. So there is no pair buffer and no second pass; `screen` must be zeroed
// beforehand (the depth entry and Gaussians that reach no tile stay zero).
//
// WGSL has no float atomics: `add_f32` emulates one with a compare-exchange loop on the
// bits, as a wgpu port without float-atomic extensions must. The order in which tiles add
// into one Gaussian's slot is whatever order the workgroups reach it, so the result is not
// bit-reproducible by design on real GPUs.

struct Params {
    n: u32,
    pairs: u32,
    tiles_x: u32,
    tiles_y: u32,
    width: u32,
    height: u32,
    max_alpha: f32,
    cutoff: u32,
    background: vec4<f32>,
    // x: the first Gaussian whose splat is in the second splat binding; y: the same for the
    // screen-space gradients; pair_splits: the first pair slot of the pair slots' second,
    // third and fourth bindings (buffers past one binding, gpu/chunk.rs).
    splits: vec4<u32>,
    pair_splits: vec4<u32>,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(2) var<storage, read> order: array<u32>;
@group(0) @binding(4) var<storage, read> pair_rank: array<u32>;
@group(0) @binding(5) var<storage, read> sorted_e: array<u32>;    // emit positions, tile-sorted
@group(0) @binding(6) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(7) var<storage, read> splats: array<f32>;
@group(0) @binding(8) var<storage, read> image: array<f32>;       // forward.wgsl IMAGE_STRIDE
@group(0) @binding(9) var<storage, read> d_rgb: array<f32>;       // 3 per pixel
@group(0) @binding(11) var<storage, read_write> screen: array<atomic<u32>>; // f32 bits, SCREEN_STRIDE per Gaussian
@group(0) @binding(12) var<storage, read> splats_hi: array<f32>;
@group(0) @binding(14) var<storage, read_write> screen_hi: array<atomic<u32>>;

fn splat(g: u32, q: u32) -> f32 {
    if (g < p.splits.x) {
        return splats[g * SPLAT_STRIDE + q];
    }
    return splats_hi[(g - p.splits.x) * SPLAT_STRIDE + q];
}

var<workgroup> batch: array<array<f32, 10>, 256>;
var<workgroup> batch_g: array<u32, 256>;
// Per-pair sums, as in backward.wgsl (see its comments): red[q·RED_ROW + li], then
// part[q·PART_ROW + x].
const RED_ROW: u32 = 272u;
const PART_ROW: u32 = 17u;
var<workgroup> red: array<f32, 2448>;  // 9 × RED_ROW
var<workgroup> part: array<f32, 153>;  // 9 × PART_ROW
var<workgroup> lasts: array<u32, 256>;
var<workgroup> tile_last: u32;

// screen[i] += v as f32, atomically: retry the compare-exchange until no other invocation
// changed the word between the read and the write.
// Value q of Gaussian g, in whichever of the two bindings holds it (`splits.y`).
fn add_f32(g: u32, q: u32, v: f32) {
    if (g < p.splits.y) {
        let i = g * SCREEN_STRIDE + q;
        var old = atomicLoad(&screen[i]);
        loop {
            let r = atomicCompareExchangeWeak(&screen[i], old, bitcast<u32>(bitcast<f32>(old) + v));
            if (r.exchanged) {
                break;
            }
            old = r.old_value;
        }
    } else {
        let i = (g - p.splits.y) * SCREEN_STRIDE + q;
        var old = atomicLoad(&screen_hi[i]);
        loop {
            let r = atomicCompareExchangeWeak(&screen_hi[i], old, bitcast<u32>(bitcast<f32>(old) + v));
            if (r.exchanged) {
                break;
            }
            old = r.old_value;
        }
    }
}

// Level 1 of the per-pair sums, by threads 0–143: part[q][x] = Σ_y red[q][16y + x], y in order.
fn column_sums(li: u32) {
    if (li < 144u) {
        let q = li >> 4u;
        let x = li & 15u;
        let base = q * RED_ROW + x;
        var s = red[base];
        for (var k = 16u; k < 256u; k += 16u) {
            s = s + red[base + k];
        }
        part[q * PART_ROW + x] = s;
    }
}

// Level 2 of the per-pair sums: value q's 16 column partials, x in order.
fn value_sum(q: u32) -> f32 {
    let o = q * PART_ROW;
    var s = part[o];
    for (var x = 1u; x < 16u; x++) {
        s = s + part[o + x];
    }
    return s;
}

@compute @workgroup_size(16, 16)
fn rasterize_backward_atomic(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
                      @builtin(local_invocation_index) li: u32) {
    let tile = wid.y * p.tiles_x + wid.x;
    let px = wid.x * 16u + lid.x;
    let py = wid.y * 16u + lid.y;
    let inside = px < p.width && py < p.height;
    let start = ranges[tile].x;
    let cx = f32(px) + 0.5;
    let cy = f32(py) + 0.5;
    var t = 1.0;
    var last = 0u;
    var g = vec3<f32>(0.0);
    var r = 0.0;
    if (inside) {
        let pix = py * p.width + px;
        t = image[pix * IMAGE_STRIDE + 5u];
        last = bitcast<u32>(image[pix * IMAGE_STRIDE + 6u]);
        g = vec3<f32>(d_rgb[3u * pix], d_rgb[3u * pix + 1u], d_rgb[3u * pix + 2u]);
        r = t * dot(g, p.background.xyz);
    }
    lasts[li] = last;
    workgroupBarrier();
    if (li == 0u) {
        var m = 0u;
        for (var j = 0u; j < 256u; j++) {
            m = max(m, lasts[j]);
        }
        tile_last = m;
    }
    var hi = workgroupUniformLoad(&tile_last);
    loop {
        if (hi == 0u) {
            break;
        }
        var lo = 0u;
        if (hi > 256u) {
            lo = hi - 256u;
        }
        let k = lo + li;
        if (k < hi) {
            let e = sorted_e[start + k];
            let gi = order[pair_rank[e]];
            batch_g[li] = gi;
            for (var q = 0u; q < 10u; q++) {
                batch[li][q] = splat(gi, q);
            }
        }
        workgroupBarrier();
        for (var jj = hi; jj > lo; jj--) {
            let j = jj - 1u;
            let b = j - lo;
            var c: array<f32, 9>;
            if (inside && j < last) {
                let dx = batch[b][0] - cx;
                let dy = batch[b][1] - cy;
                let power = -0.5 * (batch[b][2] * dx * dx + batch[b][4] * dy * dy) - batch[b][3] * dx * dy;
                if (power <= 0.0) {
                    let e = exp(power);
                    let a1 = batch[b][5] * e;
                    let ac = min(p.max_alpha, a1);
                    var alpha = ac;
                    var da_da1 = 1.0;
                    var kept = ac >= ALPHA_THRESHOLD;
                    if (p.cutoff == 1u) {
                        let x = clamp((ac - ALPHA_THRESHOLD) * (1.0 / ALPHA_THRESHOLD), 0.0, 1.0);
                        let sm = x * x * (3.0 - 2.0 * x);
                        alpha = ac * sm;
                        da_da1 = sm + ac * (6.0 * x * (1.0 - x) / ALPHA_THRESHOLD);
                        kept = ac > ALPHA_THRESHOLD;
                    }
                    if (kept) {
                        let before = t / (1.0 - alpha);
                        let col = vec3<f32>(batch[b][6], batch[b][7], batch[b][8]);
                        let gi = dot(g, col);
                        let d_alpha = (gi * t - r) / (1.0 - alpha);
                        r = r + gi * alpha * before;
                        t = before;
                        let w = alpha * before;
                        var q = 0.0;
                        if (a1 <= p.max_alpha) {
                            q = d_alpha * da_da1 * e;
                        }
                        c[0] = q;
                        c[1] = q * dx;
                        c[2] = q * dy;
                        c[3] = q * dx * dx;
                        c[4] = q * dx * dy;
                        c[5] = q * dy * dy;
                        c[6] = g.x * w;
                        c[7] = g.y * w;
                        c[8] = g.z * w;
                    }
                }
            }
            for (var q = 0u; q < 9u; q++) {
                red[q * RED_ROW + li] = c[q];
            }
            workgroupBarrier();
            column_sums(li);
            workgroupBarrier();
            if (li < 9u) {
                // Level 2 and gaussian_sums' conversion, applied to this tile's share (it is
                // linear in the sums): lane li adds entry li straight into the Gaussian's
                // slot — −o(a s₁ + b s₂), −o(b s₁ + c s₂), −½o s₃, −o s₄, −½o s₅, s₀, s₆, s₇,
                // s₈ — with selects rather than a branch per lane, which SIMD back-ends run
                // one after the other. Every lane also sums s₂ (the same order, so the same
                // bits as lane 2's own), which lanes 0 and 1 need.
                let ca = batch[b][2];
                let cb = batch[b][3];
                let cc = batch[b][4];
                let op = batch[b][5];
                let sum_of = array<u32, 9>(1u, 1u, 3u, 4u, 5u, 0u, 6u, 7u, 8u);
                let sa = value_sum(sum_of[li]);
                let sb = value_sum(2u);
                let one = li == 1u;
                let mean = select(ca, cb, one) * sa + select(cb, cc, one) * sb;
                let m = select(1.0, select(-op, -op * 0.5, li == 2u || li == 4u), li < 5u);
                let v = m * select(sa, mean, li < 2u);
                add_f32(batch_g[b], li, v);
            }
        }
        // Level 2 of the batch's last pair still reads batch and batch_g: wait before
        // reloading them.
        workgroupBarrier();
        hi = lo;
    }
}
