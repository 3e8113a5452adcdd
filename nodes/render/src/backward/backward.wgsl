// The compositing backward on the GPU: the WGSL twin of the CPU's backward tile kernel and
// per-Gaussian sums (backward/mod.rs, tile.rs, gaussian.rs), for a loss on the colour.
//
// 1. `rasterize_backward`: per tile, the list is walked back to front from the tile's
//    largest last-contributor position; each pixel recovers T_i = T_{i+1} / (1 − α_i) from
//    the forward's final T and keeps R = Σ_behind G_j α_j T_j + T_N g·background, so that
//    dL/dα_i = (G_i T_{i+1} − R) / (1 − α_i) with G_i = g·c_i. Per (tile, Gaussian) pair the
//    256 pixels' Q = dL/dα₁·e^{power} (zero where the α clamp is active), Q·dx, Q·dy, Q·dx²,
//    Q·dx·dy, Q·dy² and g·α·T are summed in a fixed order in shared memory (two levels, see
//    "Per-pair sums" below) into the pair's own slot (its emit position): no atomics, no two
//    tiles write the same memory.
// 2. `gaussian_sums`: per Gaussian, its pair slots summed in emit order (tiles row-major),
//    turned into dL/d(mean2d, conic, opacity, colour) with dσ = ½dx²·da + dx·dy·db +
//    ½dy²·dc + (a dx + b dy)·d(mean_x) + (b dx + c dy)·d(mean_y), dα₁/dσ = −o·e^{−σ}.

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
@group(0) @binding(1) var<storage, read> rects: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> order: array<u32>;
@group(0) @binding(3) var<storage, read> counts: array<u32>;      // per rank: pair offset
@group(0) @binding(4) var<storage, read> pair_rank: array<u32>;
@group(0) @binding(5) var<storage, read> sorted_e: array<u32>;    // emit positions, tile-sorted
@group(0) @binding(6) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(7) var<storage, read> splats: array<f32>;
@group(0) @binding(8) var<storage, read> image: array<f32>;       // forward.wgsl IMAGE_STRIDE
@group(0) @binding(9) var<storage, read> d_rgb: array<f32>;       // 3 per pixel
@group(0) @binding(10) var<storage, read_write> pair_grads: array<f32>; // PAIR_STRIDE per pair
@group(0) @binding(11) var<storage, read_write> screen: array<f32>;     // SCREEN_STRIDE per Gaussian
@group(0) @binding(12) var<storage, read> splats_hi: array<f32>;
@group(0) @binding(13) var<storage, read_write> pair_grads_b: array<f32>;
@group(0) @binding(14) var<storage, read_write> screen_hi: array<f32>;
@group(0) @binding(15) var<storage, read_write> pair_grads_c: array<f32>;
@group(0) @binding(16) var<storage, read_write> pair_grads_d: array<f32>;

// Value q of Gaussian g's splat, from whichever binding holds it.
fn splat(g: u32, q: u32) -> f32 {
    if (g < p.splits.x) {
        return splats[g * SPLAT_STRIDE + q];
    }
    return splats_hi[(g - p.splits.x) * SPLAT_STRIDE + q];
}

// Value q of pair slot e, and its write, in whichever of the four bindings holds the slot.
fn pair_get(e: u32, q: u32) -> f32 {
    let s = p.pair_splits;
    if (e < s.x) {
        return pair_grads[e * PAIR_STRIDE + q];
    }
    if (e < s.y) {
        return pair_grads_b[(e - s.x) * PAIR_STRIDE + q];
    }
    if (e < s.z) {
        return pair_grads_c[(e - s.y) * PAIR_STRIDE + q];
    }
    return pair_grads_d[(e - s.z) * PAIR_STRIDE + q];
}

// Value q of Gaussian g's screen-space gradient, written in whichever binding holds it.
fn screen_set(g: u32, q: u32, v: f32) {
    if (g < p.splits.y) {
        screen[g * SCREEN_STRIDE + q] = v;
    } else {
        screen_hi[(g - p.splits.y) * SCREEN_STRIDE + q] = v;
    }
}

fn pair_set(e: u32, q: u32, v: f32) {
    let s = p.pair_splits;
    if (e < s.x) {
        pair_grads[e * PAIR_STRIDE + q] = v;
    } else if (e < s.y) {
        pair_grads_b[(e - s.x) * PAIR_STRIDE + q] = v;
    } else if (e < s.z) {
        pair_grads_c[(e - s.y) * PAIR_STRIDE + q] = v;
    } else {
        pair_grads_d[(e - s.z) * PAIR_STRIDE + q] = v;
    }
}

var<workgroup> batch: array<array<f32, 10>, 256>;
var<workgroup> batch_e: array<u32, 256>;
// Per-pair sums. Each pixel (thread li = 16·y + x) writes its 9 values into `red`, one row
// per value (value-major: red[q·RED_ROW + li]); then, in two fixed-order levels,
//   level 1: 144 threads, one per (value q, column x): part[q][x] = the column's 16 pixels
//            in row order, ((v(x,0) + v(x,1)) + v(x,2)) + … + v(x,15), reading red[q][x + 16k];
//   level 2: 9 threads, one per value: the 16 column partials in column order,
//            ((part[q][0] + part[q][1]) + …) + part[q][15], written to the pair's slot.
// The order depends on nothing but the pixel positions, so the bytes are the same every run.
// Two barriers per pair (after the writes, after level 1) instead of a 256-wide tree's ten
// (after the writes, after each of its 8 levels, after the slot's write), and 144 + 9
// threads busy instead of 128, 64, …, 1; the same 255 adds per value.
// On a real GPU (32 shared-memory banks of 4 bytes): the writes are 32 consecutive words per
// warp; in level 1 a warp's 32 lanes are the 16 columns of two values, each half reading 16
// consecutive words — columns rather than contiguous runs of 16 pixels, which would put a
// half-warp's lanes 16 words apart, on 2 banks (8-way conflicts or worse) — and RED_ROW's 16
// words of padding put the second value's 16 lanes on the other 16 banks (a row of 256 would
// put both halves on the same ones: 2-way conflicts). A lane's 16 loads have fixed addresses,
// so they can all be in flight at once, leaving 15 dependent adds per level. PART_ROW = 17
// puts level 2's 9 lanes on 9 different banks, and level 2 writes the slot's 9 floats from 9
// consecutive lanes: one coalesced store.
const RED_ROW: u32 = 272u;
const PART_ROW: u32 = 17u;
var<workgroup> red: array<f32, 2448>;  // 9 × RED_ROW
var<workgroup> part: array<f32, 153>;  // 9 × PART_ROW
var<workgroup> lasts: array<u32, 256>;
var<workgroup> tile_last: u32;

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
fn rasterize_backward(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
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
            batch_e[li] = e;
            let gi = order[pair_rank[e]];
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
            // No barrier after level 2: the next pair's writes to `red` come after this
            // barrier (level 1 is done), and its writes to `part` after its own first one.
            if (li < 9u) {
                pair_set(batch_e[b], li, value_sum(li));
            }
        }
        // Level 2 of the batch's last pair still reads batch_e: wait before reloading it.
        workgroupBarrier();
        hi = lo;
    }
}

@compute @workgroup_size(256)
fn gaussian_sums(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let rk = gid.x + gid.y * nwg.x * 256u;
    if (rk >= p.n) {
        return;
    }
    let gi = order[rk];
    let cnt = rects[gi].z;
    var s: array<f32, 10>;
    let off = counts[rk];
    for (var k = 0u; k < cnt; k++) {
        for (var q = 0u; q < 9u; q++) {
            s[q] = s[q] + pair_get(off + k, q);
        }
    }
    if (cnt == 0u) {
        for (var q = 0u; q < SCREEN_STRIDE; q++) {
            screen_set(gi, q, 0.0);
        }
        return;
    }
    let ca = splat(gi, 2u);
    let cb = splat(gi, 3u);
    let cc = splat(gi, 4u);
    let op = splat(gi, 5u);
    screen_set(gi, 0u, -op * (ca * s[1] + cb * s[2]));
    screen_set(gi, 1u, -op * (cb * s[1] + cc * s[2]));
    screen_set(gi, 2u, -op * 0.5 * s[3]);
    screen_set(gi, 3u, -op * s[4]);
    screen_set(gi, 4u, -op * 0.5 * s[5]);
    screen_set(gi, 5u, s[0]);
    screen_set(gi, 6u, s[6]);
    screen_set(gi, 7u, s[7]);
    screen_set(gi, 8u, s[8]);
    screen_set(gi, 9u, 0.0);
}
