// The multiresolution hash encoding on the GPU (`hashgrid/gpu.rs`): the CPU's maths
// (`hashgrid/mod.rs`), one level per dispatch.
//
// encode: one invocation per column i < ld of the channel-major output; columns past n and
//   values that are not finite are written as 0, as on the CPU.
// Backward, with no atomics: emit writes each (point, corner) pair's table entry as its key,
//   its pair number 8·i + c as its value and its trilinear weight; a stable radix sort by
//   entry (`gpu/sort.wgsl`) keeps each entry's pairs in (point, corner) order; ranges finds
//   each entry's run; reduce adds the run, in that order, to the entry's gradient — the order
//   in which the CPU adds them, point after point.

struct Params {
    n: u32,          // points
    ld: u32,         // row stride of the encoding and of its gradient
    res: u32,        // cells per axis
    size: u32,       // table entries of the level
    dense: u32,      // 1: indexed densely (no hashing)
    row: u32,        // first row of the level in the encoding (level · F)
    table_off: u32,  // first float of the level in the table and its gradient
    features: u32,   // F
    pairs: u32,      // 8 · n
    level: u32,      // the level's number
    pad1: u32,
    pad2: u32,
    primes: vec4<u32>, // the hash's primes (x, y, z)
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> px: array<f32>;
@group(0) @binding(2) var<storage, read> py: array<f32>;
@group(0) @binding(3) var<storage, read> pz: array<f32>;
@group(0) @binding(4) var<storage, read> table: array<f32>;
@group(0) @binding(5) var<storage, read_write> enc_out: array<f32>;
@group(0) @binding(6) var<storage, read_write> keys: array<u32>;
@group(0) @binding(7) var<storage, read_write> vals: array<u32>;
@group(0) @binding(8) var<storage, read_write> weights: array<f32>;
@group(0) @binding(9) var<storage, read> d_out: array<f32>;
@group(0) @binding(10) var<storage, read_write> grad: array<f32>;
@group(0) @binding(11) var<storage, read_write> ranges: array<u32>; // 2 per entry: [start, end)

// One point's cell on the level: the low and high corner terms per axis and the fractions.
struct Cell {
    lo: vec3<u32>,
    hi: vec3<u32>,
    fr: vec3<f32>,
}

fn axis_cell(v: f32, a: u32, cell: ptr<function, Cell>) {
    let r = f32(p.res);
    // Clamped to [0, r]; NaN, negatives and −0 become +0 (as on the CPU).
    var x = 0.0;
    if (v * r > 0.0) {
        x = min(v * r, r);
    }
    var i0 = u32(x);
    if (i0 >= p.res) {
        i0 = p.res - 1u;
    }
    (*cell).fr[a] = x - f32(i0);
    if (p.dense == 1u) {
        let stride = p.res + 1u;
        let s = select(select(stride * stride, stride, a == 1u), 1u, a == 0u);
        (*cell).lo[a] = i0 * s;
        (*cell).hi[a] = (i0 + 1u) * s;
    } else {
        (*cell).lo[a] = i0 * p.primes[a];
        (*cell).hi[a] = (i0 + 1u) * p.primes[a];
    }
}

fn cell_of(i: u32) -> Cell {
    var cell: Cell;
    axis_cell(px[i], 0u, &cell);
    axis_cell(py[i], 1u, &cell);
    axis_cell(pz[i], 2u, &cell);
    return cell;
}

// Corner c's table entry.
fn corner_entry(cell: Cell, c: u32) -> u32 {
    let ix = select(cell.lo.x, cell.hi.x, (c & 1u) == 1u);
    let iy = select(cell.lo.y, cell.hi.y, ((c >> 1u) & 1u) == 1u);
    let iz = select(cell.lo.z, cell.hi.z, ((c >> 2u) & 1u) == 1u);
    if (p.dense == 1u) {
        return ix + iy + iz;
    }
    return (ix ^ iy ^ iz) & (p.size - 1u);
}

// Corner c's trilinear weight (wx · wy · wz, in the CPU's order).
fn corner_weight(cell: Cell, c: u32) -> f32 {
    let wx = select(1.0 - cell.fr.x, cell.fr.x, (c & 1u) == 1u);
    let wy = select(1.0 - cell.fr.y, cell.fr.y, ((c >> 1u) & 1u) == 1u);
    let wz = select(1.0 - cell.fr.z, cell.fr.z, ((c >> 2u) & 1u) == 1u);
    return wx * wy * wz;
}

fn index(wid: vec3<u32>, nwg: vec3<u32>, lid: vec3<u32>) -> u32 {
    return (wid.x + wid.y * nwg.x) * 256u + lid.x;
}

fn is_finite(v: f32) -> bool {
    return (bitcast<u32>(v) & 0x7f800000u) != 0x7f800000u;
}

@compute @workgroup_size(256)
fn encode(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
          @builtin(local_invocation_id) lid: vec3<u32>) {
    let i = index(wid, nwg, lid);
    if (i >= p.ld) {
        return;
    }
    if (i >= p.n) {
        for (var k = 0u; k < p.features; k++) {
            enc_out[(p.row + k) * p.ld + i] = 0.0;
        }
        return;
    }
    let cell = cell_of(i);
    var acc: array<f32, 8>;
    for (var k = 0u; k < 8u; k++) {
        acc[k] = 0.0;
    }
    for (var c = 0u; c < 8u; c++) {
        let e = p.table_off + corner_entry(cell, c) * p.features;
        let w = corner_weight(cell, c);
        for (var k = 0u; k < p.features; k++) {
            acc[k] = acc[k] + w * table[e + k];
        }
    }
    for (var k = 0u; k < p.features; k++) {
        enc_out[(p.row + k) * p.ld + i] = select(0.0, acc[k], is_finite(acc[k]));
    }
}

@compute @workgroup_size(256)
fn emit(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_id) lid: vec3<u32>) {
    let i = index(wid, nwg, lid);
    if (i >= p.n) {
        return;
    }
    let cell = cell_of(i);
    for (var c = 0u; c < 8u; c++) {
        let j = 8u * i + c;
        keys[j] = corner_entry(cell, c);
        vals[j] = j;
        weights[j] = corner_weight(cell, c);
    }
}

@compute @workgroup_size(256)
fn find_ranges(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_id) lid: vec3<u32>) {
    let j = index(wid, nwg, lid);
    if (j >= p.pairs) {
        return;
    }
    let k = keys[j];
    if (j == 0u || keys[j - 1u] != k) {
        ranges[2u * k] = j;
    }
    if (j + 1u == p.pairs || keys[j + 1u] != k) {
        ranges[2u * k + 1u] = j + 1u;
    }
}

@compute @workgroup_size(256)
fn reduce(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
          @builtin(local_invocation_id) lid: vec3<u32>) {
    let e = index(wid, nwg, lid);
    if (e >= p.size) {
        return;
    }
    let start = ranges[2u * e];
    let end = ranges[2u * e + 1u];
    if (start == end) {
        return;
    }
    let g = p.table_off + e * p.features;
    for (var k = 0u; k < p.features; k++) {
        var acc = grad[g + k];
        let d_row = (p.row + k) * p.ld;
        for (var j = start; j < end; j++) {
            let v = vals[j];
            acc = acc + weights[v] * d_out[d_row + (v >> 3u)];
        }
        grad[g + k] = acc;
    }
}
