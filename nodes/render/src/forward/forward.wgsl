// The forward rasteriser on the GPU: the WGSL twin of the CPU forward (forward/tile.rs and
// tiles.rs): tile binning in (tile, depth, index) order and per-tile front-to-back compositing
// with gsplat classic maths — α = min(max_alpha, opacity · exp(power)), skipped below 1/255,
// a pixel stops before a Gaussian that would take its transmittance to 1e-4 or below. No
// atomics: every sum runs in list order, so the same inputs give the same bytes.

struct Params {
    n: u32,
    pairs: u32,
    tiles_x: u32,
    tiles_y: u32,
    width: u32,
    height: u32,
    max_alpha: f32,
    cutoff: u32,             // 0: hard 1/255 step; 1: the tests' C¹ smoothstep (forward/mod.rs)
    background: vec4<f32>,
    // x: the first Gaussian whose splat is in the second splat binding; y: the same for the
    // screen-space gradients; z: 1 when `mask` holds a pixel mask; w: the most pairs a tile
    // may hold on an adapter that caps loop iterations (0: no cap); pair_splits: the first
    // pair slot of the pair slots' second, third and fourth bindings (buffers past one
    // binding, gpu/chunk.rs).
    splits: vec4<u32>,
    pair_splits: vec4<u32>,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> rects: array<vec4<u32>>;     // from project.wgsl
@group(0) @binding(2) var<storage, read> order: array<u32>;          // rank → Gaussian
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;   // per rank: tiles, then offsets
@group(0) @binding(4) var<storage, read_write> tile_keys: array<u32>;
@group(0) @binding(5) var<storage, read_write> pair_vals: array<u32>;
@group(0) @binding(6) var<storage, read_write> ranges: array<vec2<u32>>;
@group(0) @binding(7) var<storage, read> splats: array<f32>;
@group(0) @binding(8) var<storage, read_write> image: array<f32>;    // IMAGE_STRIDE per pixel
@group(0) @binding(9) var<storage, read_write> pixel_info: array<vec2<u32>>; // last, pairs
// The rank of each pair, by emit position; the sorted pairs carry emit positions (so the
// backward pass can give every pair its own gradient slot).
@group(0) @binding(10) var<storage, read_write> pair_rank: array<u32>;
@group(0) @binding(11) var<storage, read> splats_hi: array<f32>;
// Per pixel, 0: the pixel is neither composited nor back-propagated (background, alpha 0,
// depth 0, no pairs: render_masked on the CPU). Read only when splits.z is 1.
@group(0) @binding(12) var<storage, read> mask: array<u32>;

// Value q of Gaussian g's splat, from whichever binding holds it.
fn splat(g: u32, q: u32) -> f32 {
    if (g < p.splits.x) {
        return splats[g * SPLAT_STRIDE + q];
    }
    return splats_hi[(g - p.splits.x) * SPLAT_STRIDE + q];
}

fn linear(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * 256u;
}

// counts[r] = tiles of the Gaussian of rank r (the host then scans them into offsets).
@compute @workgroup_size(256)
fn gather_counts(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = linear(gid, nwg);
    if (r < p.n) {
        counts[r] = rects[order[r]].z;
    }
}

// The pairs of rank r at its offset, tiles in row-major order: tile + 1 (0 marks an unused
// slot: a forward pass sized ahead of its count has `p.pairs` slots, and the zeroed slots past
// the count sort first and belong to no tile), emit position, rank. Pairs past the slots are
// not written (the count, `counts[n]`, then exceeds `p.pairs`: the caller discards the pass).
@compute @workgroup_size(256)
fn emit_pairs(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = linear(gid, nwg);
    if (r >= p.n) {
        return;
    }
    let m = rects[order[r]];
    if (m.z == 0u) {
        return;
    }
    let x0 = m.x & 0xffffu;
    let x1 = m.x >> 16u;
    let y0 = m.y & 0xffffu;
    let y1 = m.y >> 16u;
    var o = counts[r];
    for (var ty = y0; ty < y1; ty++) {
        for (var tx = x0; tx < x1; tx++) {
            if (o < p.pairs) {
                tile_keys[o] = ty * p.tiles_x + tx + 1u;
                pair_vals[o] = o;
                pair_rank[o] = r;
            }
            o++;
        }
    }
}

// ranges[t] = [start, end) of tile t in the sorted pairs (zeroed by the host first); unused
// slots (key 0) sort first and mark nothing.
@compute @workgroup_size(256)
fn tile_ranges(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear(gid, nwg);
    if (i >= p.pairs) {
        return;
    }
    let key = tile_keys[i];
    if (key == 0u) {
        return;
    }
    let t = key - 1u;
    if (i == 0u || tile_keys[i - 1u] != key) {
        ranges[t].x = i;
    }
    if (i + 1u == p.pairs || tile_keys[i + 1u] != key) {
        ranges[t].y = i + 1u;
    }
}

var<workgroup> batch: array<array<f32, 10>, 256>;
var<workgroup> done_lanes: atomic<u32>;
var<workgroup> all_done: u32;

@compute @workgroup_size(16, 16)
fn rasterize(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
             @builtin(local_invocation_index) li: u32) {
    let tile = wid.y * p.tiles_x + wid.x;
    let px = wid.x * 16u + lid.x;
    let py = wid.y * 16u + lid.y;
    let inside = px < p.width && py < p.height;
    let range = ranges[tile];
    let start = range.x;
    let end = range.y;
    // A tile past the adapter's loop cap would be cut short (lavapipe ends an invocation's
    // loops after 65,535 iterations in all): the pair count takes a value no pass can have,
    // which the host turns into an error.
    if (li == 0u && p.splits.w != 0u && end - start > p.splits.w) {
        counts[p.n] = TILES_PAST_LOOP_CAP;
    }
    let cx = f32(px) + 0.5;
    let cy = f32(py) + 0.5;
    var masked = false;
    if (inside && p.splits.z == 1u) {
        masked = mask[py * p.width + px] == 0u;
    }
    var done = !inside || masked;
    var t = 1.0;
    var c = vec3<f32>(0.0);
    var d = 0.0;
    var last = 0u;
    var pairs = 0u;
    var base = start;
    // How many of the tile's pixels are done: each adds 1 to an integer count once, when it
    // is done (the count does not depend on the order of the adds). Thread 0 summing 256 flags
    // before every batch kept the other 255 waiting, and cost it 256 loop iterations a batch:
    // lavapipe ends an invocation's loops after 65,535 in all, which cut tiles of more than
    // about 32,700 pairs short.
    var counted = false;
    if (li == 0u) {
        atomicStore(&done_lanes, 0u);
    }
    workgroupBarrier();
    loop {
        if (base >= end) {
            break;
        }
        if (done && !counted) {
            atomicAdd(&done_lanes, 1u);
            counted = true;
        }
        workgroupBarrier();
        if (li == 0u) {
            all_done = atomicLoad(&done_lanes);
        }
        if (workgroupUniformLoad(&all_done) == 256u) {
            break;
        }
        let idx = base + li;
        if (idx < end) {
            let gi = order[pair_rank[pair_vals[idx]]];
            for (var q = 0u; q < 10u; q++) {
                batch[li][q] = splat(gi, q);
            }
        }
        workgroupBarrier();
        let n = min(256u, end - base);
        for (var j = 0u; j < n; j++) {
            if (done) {
                break;
            }
            let s = batch[j];
            let dx = s[0] - cx;
            let dy = s[1] - cy;
            let power = -0.5 * (s[2] * dx * dx + s[4] * dy * dy) - s[3] * dx * dy;
            if (power > 0.0) {
                continue;
            }
            let a1 = min(p.max_alpha, s[5] * exp(power));
            var alpha = a1;
            if (p.cutoff == 1u) {
                let x = clamp((a1 - ALPHA_THRESHOLD) * (1.0 / ALPHA_THRESHOLD), 0.0, 1.0);
                alpha = a1 * (x * x * (3.0 - 2.0 * x));
                if (!(a1 > ALPHA_THRESHOLD)) {
                    continue;
                }
            } else if (!(alpha >= ALPHA_THRESHOLD)) {
                continue;
            }
            let next_t = t * (1.0 - alpha);
            if (next_t <= TRANSMITTANCE_THRESHOLD) {
                done = true;
                break;
            }
            let w = alpha * t;
            c += w * vec3<f32>(s[6], s[7], s[8]);
            d += w * s[9];
            t = next_t;
            last = base - start + j + 1u;
            pairs++;
        }
        workgroupBarrier();
        base += 256u;
    }
    if (!inside) {
        return;
    }
    let pix = py * p.width + px;
    let o = pix * IMAGE_STRIDE;
    let rgb = c + t * p.background.xyz;
    let a = 1.0 - t;
    image[o] = rgb.x;
    image[o + 1u] = rgb.y;
    image[o + 2u] = rgb.z;
    image[o + 3u] = a;
    image[o + 4u] = select(0.0, d / a, a >= DEPTH_ALPHA_EPS);
    image[o + 5u] = t;
    image[o + 6u] = bitcast<f32>(last);
    pixel_info[pix] = vec2<u32>(last, pairs);
}
