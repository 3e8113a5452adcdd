// The end of a field training step on the GPU (`gpu/train.rs`): the appearance embeddings'
// gradient, the step's losses and its non-finite guard, and Adam (`train.rs`'s `Adam::step`),
// which leaves the parameters alone when the guard rejected the step.
//
// status: [non-finite gradient values, step rejected, Σ rgb loss, Σ depth loss,
// Σ distortion loss (f32 bits), coloured samples, 2 spare].

struct StepParams {
    n: u32,              // parameters
    n_rays: u32,
    emb_dim: u32,
    n_images: u32,
    emb_off: u32,
    levels: u32,         // hash-grid levels (2 words each in `levels`)
    ld: u32,             // row stride of the embedding gradient
    pad0: u32,
    step_size: f32,      // lr / (1 − β1^t)
    inv_bc2: f32,        // 1 / (1 − β2^t)
    beta1: f32,
    one_minus_beta1: f32,
    beta2: f32,
    one_minus_beta2: f32,
    eps: f32,
    // The same two for t − 1: Adam's count when the step before, still unresolved on the
    // host as this one was recorded, was rejected (its status in `prev_status`).
    step_size_skip: f32,
    inv_bc2_skip: f32,
    pad1: u32,
    pad2: u32,
    pad3: u32,
}

@group(0) @binding(0) var<uniform> s: StepParams;
@group(0) @binding(1) var<storage, read> grad: array<f32>;
@group(0) @binding(2) var<storage, read_write> status: array<u32>;
@group(0) @binding(3) var<storage, read_write> status_atomic: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read> ray_out: array<f32>;
@group(0) @binding(5) var<storage, read> levels: array<u32>;
@group(0) @binding(6) var<storage, read_write> params: array<f32>;
@group(0) @binding(7) var<storage, read_write> adam_m: array<f32>;
@group(0) @binding(8) var<storage, read_write> adam_v: array<f32>;
@group(0) @binding(9) var<storage, read> d_emb: array<f32>;
@group(0) @binding(10) var<storage, read> starts: array<u32>;
@group(0) @binding(11) var<storage, read_write> ray_emb: array<f32>;
@group(0) @binding(12) var<storage, read> rays: array<f32>;
@group(0) @binding(13) var<storage, read_write> grad_rw: array<f32>;
// The status of the step before (zeros: applied, or already counted on the host).
@group(0) @binding(14) var<storage, read> prev_status: array<u32>;

fn index(wid: vec3<u32>, nwg: vec3<u32>, lid: u32) -> u32 {
    return (wid.x + wid.y * nwg.x) * 256u + lid;
}

// Each ray's embedding gradient over its coloured samples, in order: thread (ray, k).
@compute @workgroup_size(256)
fn emb_ray(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let q = index(wid, nwg, lid);
    if (q >= s.n_rays * s.emb_dim) {
        return;
    }
    let r = q / s.emb_dim;
    let k = q % s.emb_dim;
    let a = starts[r];
    let nc = bitcast<u32>(ray_out[12u * r + 8u]);
    var acc = 0.0;
    for (var i = a; i < a + nc; i++) {
        acc += d_emb[k * s.ld + i];
    }
    ray_emb[q] = acc;
}

// Each (image, k): its rays' sums in ray order.
@compute @workgroup_size(256)
fn emb_reduce(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) lid: u32) {
    let q = index(wid, nwg, lid);
    if (q >= s.n_images * s.emb_dim) {
        return;
    }
    let image = q / s.emb_dim;
    let k = q % s.emb_dim;
    var acc = 0.0;
    for (var r = 0u; r < s.n_rays; r++) {
        if (bitcast<u32>(rays[16u * r + 15u]) == image) {
            acc += ray_emb[r * s.emb_dim + k];
        }
    }
    grad_rw[s.emb_off + q] += acc;
}

@compute @workgroup_size(256)
fn count_nonfinite(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                   @builtin(local_invocation_index) lid: u32) {
    let i = index(wid, nwg, lid);
    if (i >= s.n) {
        return;
    }
    if (!finite(grad[i])) {
        atomicAdd(&status_atomic[0], 1u);
    }
}

// One invocation: the losses summed in ray order, and the verdict.
@compute @workgroup_size(1)
fn finish_step() {
    var l = vec3<f32>(0.0);
    var colored = 0u;
    for (var r = 0u; r < s.n_rays; r++) {
        let o = 12u * r;
        l = vec3<f32>(l.x + ray_out[o + 5u], l.y + ray_out[o + 6u], l.z + ray_out[o + 7u]);
        colored += bitcast<u32>(ray_out[o + 8u]);
    }
    var bad = status[0];
    for (var lv = 0u; lv < s.levels; lv++) {
        if (levels[2u * lv + 1u] != 0u) {
            bad += 1u;
        }
    }
    status[0] = bad;
    status[1] = u32(bad > 0u || !finite(l.x) || !finite(l.y) || !finite(l.z));
    status[2] = bitcast<u32>(l.x);
    status[3] = bitcast<u32>(l.y);
    status[4] = bitcast<u32>(l.z);
    status[5] = colored;
}

@compute @workgroup_size(256)
fn adam(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let i = index(wid, nwg, lid);
    if (i >= s.n || status[1] != 0u) {
        return;
    }
    // Adam's count t is one less when the step before was rejected.
    let prev_rejected = prev_status[1] != 0u;
    let step_size = select(s.step_size, s.step_size_skip, prev_rejected);
    let inv_bc2 = select(s.inv_bc2, s.inv_bc2_skip, prev_rejected);
    let gi = grad[i];
    let m = s.beta1 * adam_m[i] + s.one_minus_beta1 * gi;
    let v = s.beta2 * adam_v[i] + s.one_minus_beta2 * gi * gi;
    adam_m[i] = m;
    adam_v[i] = v;
    params[i] -= step_size * m / (sqrt(v * inv_bc2) + s.eps);
}
