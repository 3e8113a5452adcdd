// One view's gradients added into the step's sums on the GPU — the WGSL twin of the trainer's
// `merge_grads` (the step's gradient is the sum of its views' gradients, added view after view
// in the order they were drawn) and of `Densifier::accumulate_scaled` (the densification
// statistic: the norm of each visible Gaussian's screen-space mean gradient in NDC-normalised
// units, times the batch factor, with a count). One invocation per Gaussian; the views come
// one dispatch after another, so every sum has a fixed order and no atomics are needed.

struct AccConst {
    // Gaussians, SH values per Gaussian (3·coefficients), leading SH values that may be
    // non-zero, whether to gather the statistic.
    n: u32,
    sh_width: u32,
    sh_cols: u32,
    stats: u32,
    // Half the image size (the NDC scale of the screen gradient) and the statistic's factor.
    half_w: f32,
    half_h: f32,
    factor: f32,
    pad: f32,
}

@group(0) @binding(0) var<uniform> c: AccConst;
@group(0) @binding(1) var<storage, read> view_grads: array<f32>;     // 11 per Gaussian
@group(0) @binding(2) var<storage, read> view_sh: array<f32>;        // sh_width per Gaussian
@group(0) @binding(3) var<storage, read> screen: array<f32>;         // 10 per Gaussian
@group(0) @binding(4) var<storage, read> rects: array<vec4<u32>>;    // z: tiles touched
@group(0) @binding(5) var<storage, read_write> acc_grads: array<f32>;
@group(0) @binding(6) var<storage, read_write> acc_sh: array<f32>;
@group(0) @binding(7) var<storage, read_write> acc_visible: array<u32>;
@group(0) @binding(8) var<storage, read_write> grad2d: array<f32>;
@group(0) @binding(9) var<storage, read_write> count: array<u32>;
// The step's overflow flag (bound whole): set once a view's pairs outgrew its forward pass's
// slots; from then on the step's views add nothing (the trainer runs them again).
@group(0) @binding(13) var<storage, read_write> overflow: array<u32>;

@compute @workgroup_size(256)
fn accumulate(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if (i >= c.n || overflow[0] != 0u) {
        return;
    }
    let og = i * GRAD_STRIDE;
    for (var q = 0u; q < GRAD_STRIDE; q++) {
        acc_grads[og + q] = acc_grads[og + q] + view_grads[og + q];
    }
    let os = i * c.sh_width;
    for (var q = 0u; q < c.sh_cols; q++) {
        acc_sh[os + q] = acc_sh[os + q] + view_sh[os + q];
    }
    let vis = rects[i].z > 0u;
    if (vis) {
        acc_visible[i] = 1u;
        if (c.stats != 0u) {
            let x = screen[i * SCREEN_STRIDE] * c.half_w * c.factor;
            let y = screen[i * SCREEN_STRIDE + 1u] * c.half_h * c.factor;
            let norm = sqrt(x * x + y * y);
            if (finite(norm)) {
                grad2d[i] = grad2d[i] + norm;
            }
            count[i] = count[i] + 1u;
        }
    }
}

// The composited (Gaussian, pixel) pairs of one render, as the CPU renderer counts them: the
// sum of each pixel's count (the second word of its info), as per-block partial sums of 256
// pixels that the host adds in block order. Integer sums: exact in any order.
struct PairConst {
    pixels: u32,
    blocks: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(10) var<uniform> pc: PairConst;
@group(0) @binding(11) var<storage, read> info: array<u32>;          // 2 per pixel
@group(0) @binding(12) var<storage, read_write> pair_partials: array<u32>;

var<workgroup> part: array<u32, 256>;

@compute @workgroup_size(256)
fn count_pairs(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) li: u32) {
    let block = wid.x + wid.y * nwg.x;
    let p = block * 256u + li;
    var v = 0u;
    if (p < pc.pixels) {
        v = info[2u * p + 1u];
    }
    part[li] = v;
    workgroupBarrier();
    for (var s = 128u; s > 0u; s = s >> 1u) {
        if (li < s) {
            part[li] = part[li] + part[li + s];
        }
        workgroupBarrier();
    }
    if (li == 0u && block < pc.blocks) {
        pair_partials[block] = part[0];
    }
}

// The view's pair count (`pair_count[at]`, the offsets' exclusive sum) against its forward
// pass's slots: one invocation sets the step's flag when it outgrew them.
struct FlagConst {
    at: u32,
    slots: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(14) var<uniform> fc: FlagConst;
@group(0) @binding(15) var<storage, read> pair_count: array<u32>;

@compute @workgroup_size(1)
fn flag_overflow() {
    if (pair_count[fc.at] > fc.slots) {
        overflow[0] = 1u;
    }
}

// A step's sums zeroed at its start (`c.n` Gaussians of `c.sh_width` words each), unless the
// overflow flag is set: a step recorded behind one whose pairs outgrew their slots must leave
// that step's sums as they are, for the host to complete them when it runs the views again.
@group(0) @binding(16) var<storage, read_write> zeroed: array<u32>;

@compute @workgroup_size(256)
fn clear_sums(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = gid.x + gid.y * nwg.x * 256u;
    if (idx >= c.n * c.sh_width || overflow[0] != 0u) {
        return;
    }
    zeroed[idx] = 0u;
}
