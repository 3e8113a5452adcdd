// Adam on the GPU: the WGSL twin of `adam_elem` / `update_chunk_body` (adam/mod.rs), one
// invocation per value of one parameter group. The host computes the step's constants exactly
// as the CPU's `Adam::step` does (bias corrections in f64, rounded to f32) and dispatches this
// kernel once per group. The update is element-wise (every value is read and written by one
// invocation), so it is deterministic; it differs from the CPU's bits only where the GPU's
// square root and division round differently (WGSL allows a few ULP).
//
// The gradients come in the layout of `project_vjp.wgsl` (11 values per Gaussian: mean 3,
// log-scale 3, quaternion 4, opacity logit 1; SH in the parameters' own layout), read at
// `grad_offset + i·grad_stride + c`.

struct AdamConst {
    // Gaussians, values per Gaussian, gradient stride, gradient offset.
    n: u32,
    width: u32,
    grad_stride: u32,
    grad_offset: u32,
    // Values of each Gaussian with the first step size; leading values updated at all;
    // whether every Gaussian is updated (1) or only the visible ones (0).
    split: u32,
    cols: u32,
    dense: u32,
    pad0: u32,
    // lr / (1 − β1ᵗ) for values < split and ≥ split; β1, β2.
    step_a: f32,
    step_b: f32,
    b1: f32,
    b2: f32,
    // 1 / √(1 − β2ᵗ), ε.
    inv_sqrt_bc2: f32,
    eps: f32,
    pad1: f32,
    pad2: f32,
}

@group(0) @binding(0) var<uniform> c: AdamConst;
@group(0) @binding(1) var<storage, read_write> params: array<f32>;
@group(0) @binding(2) var<storage, read> grads: array<f32>;
@group(0) @binding(3) var<storage, read_write> m1: array<f32>;
@group(0) @binding(4) var<storage, read_write> m2: array<f32>;
@group(0) @binding(5) var<storage, read> visible: array<u32>;
// The training state's overflow flag (bound whole): while a step's views are incomplete (one
// outgrew its pair slots), its update and those recorded behind it change nothing; the host
// runs them again once it has seen the flag.
@group(0) @binding(6) var<storage, read> overflow: array<u32>;

@compute @workgroup_size(256)
fn adam(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = gid.x + gid.y * nwg.x * 256u;
    if (idx >= c.n * c.width || overflow[0] != 0u) {
        return;
    }
    let i = idx / c.width;
    let k = idx - i * c.width;
    if (k >= c.cols || (c.dense == 0u && visible[i] == 0u)) {
        return;
    }
    let g = grads[c.grad_offset + i * c.grad_stride + k];
    var step = c.step_b;
    if (k < c.split) {
        step = c.step_a;
    }
    // The CPU's order of operations, kept unfused.
    let mn = c.b1 * m1[idx] + (1.0 - c.b1) * g;
    let vn = c.b2 * m2[idx] + (1.0 - c.b2) * g * g;
    m1[idx] = mn;
    m2[idx] = vn;
    params[idx] = params[idx] - step * mn / (sqrt(vn) * c.inv_sqrt_bc2 + c.eps);
}
