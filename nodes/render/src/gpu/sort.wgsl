// One pass of a stable least-significant-digit radix sort of (u32 key, u32 value) pairs on
// 4-bit digits, deterministic by construction (no atomics): `count` ranks each element among
// the equal digits before it in its block of 256 — an exclusive prefix sum over the block of
// one-hot digit counters, sixteen 16-bit fields in eight words per element — and writes the
// block's digit histogram (digit-major, so an exclusive scan of it gives every (digit, block)
// its output offset); `scatter` moves each pair to offset + rank. A sort whose values are the
// elements' indices reads none in its first pass (`index_values`): each element's value is
// its index.

struct Params {
    n: u32,
    blocks: u32,
    shift: u32,
    index_values: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> keys_in: array<u32>;
@group(0) @binding(2) var<storage, read> vals_in: array<u32>;
@group(0) @binding(3) var<storage, read_write> ranks: array<u32>;
@group(0) @binding(4) var<storage, read_write> hist: array<u32>;
@group(0) @binding(5) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(6) var<storage, read_write> vals_out: array<u32>;

var<workgroup> counters: array<array<u32, 8>, 256>;

// Field `d` (a 16-bit digit counter) of a thread's eight words.
fn field(li: u32, d: u32) -> u32 {
    return (counters[li][d / 2u] >> ((d % 2u) * 16u)) & 0xffffu;
}

@compute @workgroup_size(256)
fn count(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_index) li: u32) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * 256u + li;
    var d = 16u;
    if (block < p.blocks && i < p.n) {
        d = (keys_in[i] >> p.shift) & 15u;
    }
    for (var w = 0u; w < 8u; w++) {
        counters[li][w] = 0u;
    }
    if (d < 16u) {
        counters[li][d / 2u] = 1u << ((d % 2u) * 16u);
    }
    workgroupBarrier();
    // Inclusive prefix sums (Hillis–Steele); a field never exceeds 256, so no carry.
    for (var off = 1u; off < 256u; off = off << 1u) {
        var t: array<u32, 8>;
        if (li >= off) {
            t = counters[li - off];
        }
        workgroupBarrier();
        if (li >= off) {
            for (var w = 0u; w < 8u; w++) {
                counters[li][w] = counters[li][w] + t[w];
            }
        }
        workgroupBarrier();
    }
    if (block >= p.blocks) {
        return;
    }
    if (i < p.n) {
        ranks[i] = field(li, d) - 1u;
    }
    if (li < 16u) {
        hist[li * p.blocks + block] = field(255u, li);
    }
}

@compute @workgroup_size(256)
fn scatter(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) li: u32) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * 256u + li;
    if (block >= p.blocks || i >= p.n) {
        return;
    }
    let k = keys_in[i];
    let d = (k >> p.shift) & 15u;
    let dst = hist[d * p.blocks + block] + ranks[i];
    keys_out[dst] = k;
    if (p.index_values != 0u) {
        vals_out[dst] = i;
    } else {
        vals_out[dst] = vals_in[i];
    }
}
