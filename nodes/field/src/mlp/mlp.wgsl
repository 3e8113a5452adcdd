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
// wgrad_partial / wgrad_reduce: the weight and bias gradients without atomics. The batch is cut
//   into chunks of WGRAD_CHUNK columns; each (chunk, weight) sums its chunk's columns in order,
//   then each weight adds its chunks in order: the same bytes for any scheduling.

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

var<workgroup> w_tile: array<f32, 512>; // TILE_O × TILE_I
var<workgroup> wg_cols: u32;

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
        var acc: array<f32, 8>;
        for (var k = 0u; k < TILE_O; k++) {
            let o = o0 + k;
            var b = 0.0;
            if (d.b_off != NO_BIAS && o < d.o_end) {
                b = w[d.b_off + o];
            }
            acc[k] = b;
        }
        var i0 = 0u;
        loop {
            if (i0 >= d.inp) {
                break;
            }
            workgroupBarrier();
            for (var t = lid; t < TILE_O * TILE_I; t += 256u) {
                let o = o0 + t / TILE_I;
                let i = i0 + t % TILE_I;
                var v = 0.0;
                if (o < d.o_end && i < d.inp) {
                    v = w[d.w_off + o * d.w_so + i * d.w_si];
                }
                w_tile[t] = v;
            }
            workgroupBarrier();
            if (live) {
                let ni = min(TILE_I, d.inp - i0);
                for (var ii = 0u; ii < ni; ii++) {
                    let xv = x[(i0 + ii) * d.ld + c];
                    for (var k = 0u; k < TILE_O; k++) {
                        acc[k] = fma(w_tile[k * TILE_I + ii], xv, acc[k]);
                    }
                }
            }
            i0 += TILE_I;
        }
        if (live) {
            for (var k = 0u; k < TILE_O; k++) {
                let o = o0 + k;
                if (o < d.o_end) {
                    var v = acc[k];
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
            }
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
