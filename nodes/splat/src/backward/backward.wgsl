// The compositing backward on the GPU: the WGSL twin of the CPU's backward tile kernel and
// per-Gaussian sums (backward/mod.rs, tile.rs, gaussian.rs), for a loss on the colour.
//
// 1. `rasterize_backward`: per tile, the list is walked back to front from the tile's
//    largest last-contributor position; each pixel recovers T_i = T_{i+1} / (1 − α_i) from
//    the forward's final T and keeps R = Σ_behind G_j α_j T_j + T_N g·background, so that
//    dL/dα_i = (G_i T_{i+1} − R) / (1 − α_i) with G_i = g·c_i. Per (tile, Gaussian) pair the
//    256 pixels' Q = dL/dα₁·e^{power} (zero where the α clamp is active), Q·dx, Q·dy, Q·dx²,
//    Q·dx·dy, Q·dy² and g·α·T are summed by a fixed-order tree in shared memory into the
//    pair's own slot (its emit position): no atomics, no two tiles write the same memory.
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

const SPLAT_STRIDE: u32 = 12u;
const IMAGE_STRIDE: u32 = 7u;
const PAIR_STRIDE: u32 = 10u;    // Q, Q·dx, Q·dy, Q·dx², Q·dx·dy, Q·dy², g·α·T (3), −
const SCREEN_STRIDE: u32 = 10u;  // mean2d x, y; conic a, b, c; opacity; colour r, g, b; depth
const ALPHA_THRESHOLD: f32 = 0.003921568627450980;

var<workgroup> batch: array<array<f32, 10>, 256>;
var<workgroup> batch_e: array<u32, 256>;
var<workgroup> red: array<array<f32, 10>, 256>;
var<workgroup> lasts: array<u32, 256>;
var<workgroup> tile_last: u32;

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
            let o = order[pair_rank[e]] * SPLAT_STRIDE;
            for (var q = 0u; q < 10u; q++) {
                batch[li][q] = splats[o + q];
            }
        }
        workgroupBarrier();
        for (var jj = hi; jj > lo; jj--) {
            let j = jj - 1u;
            let b = j - lo;
            var c: array<f32, 10>;
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
            red[li] = c;
            workgroupBarrier();
            for (var off = 128u; off > 0u; off = off >> 1u) {
                if (li < off) {
                    for (var q = 0u; q < 9u; q++) {
                        red[li][q] = red[li][q] + red[li + off][q];
                    }
                }
                workgroupBarrier();
            }
            if (li == 0u) {
                let o = batch_e[b] * PAIR_STRIDE;
                for (var q = 0u; q < 9u; q++) {
                    pair_grads[o + q] = red[0][q];
                }
            }
            workgroupBarrier();
        }
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
        let o = (off + k) * PAIR_STRIDE;
        for (var q = 0u; q < 9u; q++) {
            s[q] = s[q] + pair_grads[o + q];
        }
    }
    let os = gi * SCREEN_STRIDE;
    if (cnt == 0u) {
        for (var q = 0u; q < SCREEN_STRIDE; q++) {
            screen[os + q] = 0.0;
        }
        return;
    }
    let g0 = gi * SPLAT_STRIDE;
    let ca = splats[g0 + 2u];
    let cb = splats[g0 + 3u];
    let cc = splats[g0 + 4u];
    let op = splats[g0 + 5u];
    screen[os] = -op * (ca * s[1] + cb * s[2]);
    screen[os + 1u] = -op * (cb * s[1] + cc * s[2]);
    screen[os + 2u] = -op * 0.5 * s[3];
    screen[os + 3u] = -op * s[4];
    screen[os + 4u] = -op * 0.5 * s[5];
    screen[os + 5u] = s[0];
    screen[os + 6u] = s[6];
    screen[os + 7u] = s[7];
    screen[os + 8u] = s[8];
    screen[os + 9u] = 0.0;
}
