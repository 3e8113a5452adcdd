// Dense layers of the field's MLPs on the GPU (`mlp/gpu.rs`), over channel-major batches as
// on the CPU (`mlp/mod.rs`): `rows × ld` floats, column c of row k at `k·ld + c`.
//
// dense: y[o][c] = store(b[o] + Σ_i W(o, i) · x[i][c]), the sum in i order, one invocation
//   per column; the workgroup loads the weights tile by tile (8 outputs × 64 inputs) into
//   workgroup memory. W(o, i) = w[w_off + o·w_so + i·w_si], so the same kernel runs the
//   forward product (w_so = inp, w_si = 1) and the input gradient through the transposed
//   weights (w_so = 1, w_si = rows of the forward output). Outputs o in [o_begin, o_end) go to
//   row o − o_begin + y_row0 of y. Store: 0 linear, 1 ReLU (NaN → 0), 2 kept where
//   mask[o][c] > 0 (the ReLU backward through the layer below), else 0.
//   Columns from `count[0]` on are left alone when `use_count` is 1 (a batch sized on the
//   device), from `ncols` on otherwise.
// wgrad_partial[_tiled] / wgrad_reduce: the weight and bias gradients without atomics. The
//   batch is cut into chunks of WGRAD_CHUNK columns; each (chunk, weight) sums its chunk's
//   columns in order, then each weight adds its chunks in order: the same bytes for any
//   scheduling. wgrad_partial reads the batches straight from memory, one invocation per
//   (chunk, weight); wgrad_partial_tiled takes 16 × 16 weights a workgroup and brings their
//   rows of dy and x through workgroup memory — the same sums, bit for bit.

struct Dense {
    inp: u32,      // inputs summed over
    ncols: u32,    // columns to compute
    ld: u32,       // row stride of x, y and mask
    w_off: u32,
    w_so: u32,
    w_si: u32,
    b_off: u32,    // NO_BIAS: none
    store: u32,
    o_begin: u32,
    o_end: u32,
    y_row0: u32,
    use_count: u32,
}

const NO_BIAS: u32 = 0xffffffffu;
const TILE_O: u32 = 8u;
const TILE_I: u32 = 64u;

@group(0) @binding(0) var<uniform> d: Dense;
@group(0) @binding(1) var<storage, read> w: array<f32>;
@group(0) @binding(2) var<storage, read> x: array<f32>;
@group(0) @binding(3) var<storage, read_write> y: array<f32>;
@group(0) @binding(4) var<storage, read> mask: array<f32>;
@group(0) @binding(5) var<storage, read> count: array<u32>;

// The tile: for input ii of the tile, outputs o0..o0+3 in w_tile[2·ii] and o0+4..o0+7 in
// w_tile[2·ii + 1], so each input is two 4-wide multiply-adds.
var<workgroup> w_tile: array<vec4<f32>, 128>; // TILE_O × TILE_I
var<workgroup> wg_cols: u32;

fn tile_weight(o: u32, i: u32) -> f32 {
    if (o < d.o_end && i < d.inp) {
        return w[d.w_off + o * d.w_so + i * d.w_si];
    }
    return 0.0;
}

fn bias(o: u32) -> f32 {
    if (d.b_off != NO_BIAS && o < d.o_end) {
        return w[d.b_off + o];
    }
    return 0.0;
}

fn store_out(o: u32, c: u32, acc: f32) {
    if (o >= d.o_end) {
        return;
    }
    var v = acc;
    if (d.store == 1u) {
        if (!(v > 0.0)) {
            v = 0.0;
        }
    } else if (d.store == 2u) {
        if (!(mask[o * d.ld + c] > 0.0)) {
            v = 0.0;
        }
    }
    y[(o - d.o_begin + d.y_row0) * d.ld + c] = v;
}

@compute @workgroup_size(256)
fn dense(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_index) lid: u32) {
    let base = (wid.x + wid.y * nwg.x) * 256u;
    let c = base + lid;
    if (lid == 0u) {
        var cols = d.ncols;
        if (d.use_count == 1u) {
            cols = min(cols, count[0]);
        }
        wg_cols = cols;
    }
    let cols = workgroupUniformLoad(&wg_cols);
    if (base >= cols) {
        return;
    }
    let live = c < cols;
    var o0 = d.o_begin;
    loop {
        if (o0 >= d.o_end) {
            break;
        }
        var lo = vec4<f32>(bias(o0), bias(o0 + 1u), bias(o0 + 2u), bias(o0 + 3u));
        var hi = vec4<f32>(bias(o0 + 4u), bias(o0 + 5u), bias(o0 + 6u), bias(o0 + 7u));
        var i0 = 0u;
        loop {
            if (i0 >= d.inp) {
                break;
            }
            workgroupBarrier();
            if (lid < 2u * TILE_I) {
                let i = i0 + lid / 2u;
                let k = o0 + 4u * (lid % 2u);
                w_tile[lid] = vec4<f32>(tile_weight(k, i), tile_weight(k + 1u, i),
                                        tile_weight(k + 2u, i), tile_weight(k + 3u, i));
            }
            workgroupBarrier();
            if (live) {
                let ni = min(TILE_I, d.inp - i0);
                for (var ii = 0u; ii < ni; ii++) {
                    let xv = vec4<f32>(x[(i0 + ii) * d.ld + c]);
                    lo = fma(w_tile[2u * ii], xv, lo);
                    hi = fma(w_tile[2u * ii + 1u], xv, hi);
                }
            }
            i0 += TILE_I;
        }
        if (live) {
            store_out(o0, c, lo.x);
            store_out(o0 + 1u, c, lo.y);
            store_out(o0 + 2u, c, lo.z);
            store_out(o0 + 3u, c, lo.w);
            store_out(o0 + 4u, c, hi.x);
            store_out(o0 + 5u, c, hi.y);
            store_out(o0 + 6u, c, hi.z);
            store_out(o0 + 7u, c, hi.w);
        }
        o0 += TILE_O;
    }
}

struct WGrad {
    inp: u32,       // rows of x (plus one bias column in the weight index)
    out: u32,       // rows of dy
    ld: u32,        // row stride of dy and x
    ncols: u32,     // columns summed over
    chunks: u32,    // ceil(ncols / WGRAD_CHUNK)
    w_off: u32,     // gradient of W (out × inp row-major) in g
    b_off: u32,     // gradient of b in g
    pad: u32,
}

@group(0) @binding(6) var<uniform> wg: WGrad;
@group(0) @binding(7) var<storage, read> dy: array<f32>;
@group(0) @binding(8) var<storage, read_write> partial: array<f32>;
@group(0) @binding(9) var<storage, read_write> g: array<f32>;

// Thread (chunk, q): q = o·(inp + 1) + i, i = inp being the bias.
@compute @workgroup_size(256)
fn wgrad_partial(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) lid: u32) {
    let idx = (wid.x + wid.y * nwg.x) * 256u + lid;
    let q_n = wg.out * (wg.inp + 1u);
    if (idx >= q_n * wg.chunks) {
        return;
    }
    let chunk = idx / q_n;
    let q = idx % q_n;
    let o = q / (wg.inp + 1u);
    let i = q % (wg.inp + 1u);
    let c0 = chunk * WGRAD_CHUNK;
    let c1 = min(c0 + WGRAD_CHUNK, wg.ncols);
    var s = 0.0;
    if (i == wg.inp) {
        for (var c = c0; c < c1; c++) {
            s += dy[o * wg.ld + c];
        }
    } else {
        for (var c = c0; c < c1; c++) {
            s = fma(dy[o * wg.ld + c], x[i * wg.ld + c], s);
        }
    }
    partial[idx] = s;
}

// Workgroup (chunk, block of 16 outputs × 16 inputs), one weight per invocation: the block's
// rows of dy and x go through workgroup memory 64 columns at a time, and each weight adds its
// chunk's columns in order (the bias is the input whose x is 1). Writes partial[chunk][q],
// q = o·(inp + 1) + i.
const WG_BLOCK: u32 = 16u;
const WG_COLS: u32 = 64u;

var<workgroup> dy_tile: array<f32, 1024>; // WG_BLOCK × WG_COLS
var<workgroup> x_tile: array<f32, 1024>;

@compute @workgroup_size(256)
fn wgrad_partial_tiled(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                       @builtin(local_invocation_index) lid: u32) {
    let group = wid.x + wid.y * nwg.x;
    let o_blocks = (wg.out + WG_BLOCK - 1u) / WG_BLOCK;
    let i_blocks = (wg.inp + 1u + WG_BLOCK - 1u) / WG_BLOCK;
    if (group >= wg.chunks * o_blocks * i_blocks) {
        return;
    }
    let chunk = group / (o_blocks * i_blocks);
    let rest = group % (o_blocks * i_blocks);
    let o_first = (rest / i_blocks) * WG_BLOCK;
    let i_first = (rest % i_blocks) * WG_BLOCK;
    let lo = lid / WG_BLOCK;
    let li = lid % WG_BLOCK;
    let c0 = chunk * WGRAD_CHUNK;
    let c1 = min(c0 + WGRAD_CHUNK, wg.ncols);
    var s = 0.0;
    for (var ct = c0; ct < c1; ct += WG_COLS) {
        workgroupBarrier();
        for (var t = lid; t < WG_BLOCK * WG_COLS; t += 256u) {
            let row = t / WG_COLS;
            let c = ct + t % WG_COLS;
            var dv = 0.0;
            var xv = 0.0;
            if (c < c1) {
                let o = o_first + row;
                if (o < wg.out) {
                    dv = dy[o * wg.ld + c];
                }
                let i = i_first + row;
                if (i < wg.inp) {
                    xv = x[i * wg.ld + c];
                } else if (i == wg.inp) {
                    xv = 1.0;
                }
            }
            dy_tile[t] = dv;
            x_tile[t] = xv;
        }
        workgroupBarrier();
        let nc = min(WG_COLS, c1 - ct);
        for (var cc = 0u; cc < nc; cc++) {
            s = fma(dy_tile[lo * WG_COLS + cc], x_tile[li * WG_COLS + cc], s);
        }
    }
    let o = o_first + lo;
    let i = i_first + li;
    if (o < wg.out && i <= wg.inp) {
        partial[chunk * wg.out * (wg.inp + 1u) + o * (wg.inp + 1u) + i] = s;
    }
}

@compute @workgroup_size(256)
fn wgrad_reduce(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) lid: u32) {
    let q = (wid.x + wid.y * nwg.x) * 256u + lid;
    let q_n = wg.out * (wg.inp + 1u);
    if (q >= q_n) {
        return;
    }
    var s = 0.0;
    for (var ch = 0u; ch < wg.chunks; ch++) {
        s += partial[ch * q_n + q];
    }
    let o = q / (wg.inp + 1u);
    let i = q % (wg.inp + 1u);
    if (i == wg.inp) {
        g[wg.b_off + o] += s;
    } else {
        g[wg.w_off + o * wg.inp + i] += s;
    }
}
