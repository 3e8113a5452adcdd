// The radiance field's per-ray and per-sample kernels on the GPU (`gpu/mod.rs`): the CPU's
// maths (`field/mod.rs`, `field/backward.rs`, `volume.rs`, `occupancy.rs`, `train.rs`), one
// invocation per ray for everything that runs along a ray (marching, weights, compositing,
// losses and their backward, in sample order as on the CPU), one per sample or cell for the
// rest. Sums that reach the weights run in a fixed order; the only atomics add integers.
//
// Rays: 16 floats each — origin (3), unit direction (3), background (3), target colour (3),
// target distance and its weight, stratification jitter, training image (u32 bits; F_NO_IMAGE
// = the mean embedding). Samples: positions px/py/pz in [0, 1]³ (contracted, rescaled), and
// 4 floats each — distance t, length dt, contracted midpoint m, ray (u32 bits).

struct FieldParams {
    center: vec4<f32>,   // contraction centre (xyz), 1 / radius (w)
    rw: f32,             // radius
    near: f32,
    far: f32,
    delta: f32,          // contracted step
    n_rays: u32,
    occ_res: u32,
    ld: u32,             // row stride of the sample batches
    n: u32,              // samples (or cells of an occupancy batch)
    emb_dim: u32,
    n_images: u32,
    inv_rays: f32,
    depth_w: f32,
    depth_sigma: f32,
    dist_w: f32,
    min_color_w: f32,
    emb_off: u32,        // first embedding parameter
    mode: u32,           // color_input: 1 = columns are the compacted live samples
    first: u32,          // occ_values: first cell of the batch
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> f: FieldParams;
@group(0) @binding(1) var<storage, read> rays: array<f32>;
@group(0) @binding(2) var<storage, read> occ: array<u32>;
@group(0) @binding(3) var<storage, read_write> starts: array<u32>;
@group(0) @binding(4) var<storage, read_write> px: array<f32>;
@group(0) @binding(5) var<storage, read_write> py: array<f32>;
@group(0) @binding(6) var<storage, read_write> pz: array<f32>;
@group(0) @binding(7) var<storage, read_write> samp: array<f32>;
@group(0) @binding(8) var<storage, read_write> steps: array<u32>;
@group(0) @binding(9) var<storage, read> dout: array<f32>;
@group(0) @binding(10) var<storage, read> params: array<f32>;
@group(0) @binding(11) var<storage, read_write> cin: array<f32>;
@group(0) @binding(12) var<storage, read_write> alive: array<u32>;
@group(0) @binding(13) var<storage, read_write> alive_count: array<u32>;
@group(0) @binding(14) var<storage, read> mean_emb: array<f32>;
@group(0) @binding(15) var<storage, read> cout: array<f32>;
@group(0) @binding(16) var<storage, read_write> wg: array<f32>;
@group(0) @binding(17) var<storage, read_write> d_dout: array<f32>;
@group(0) @binding(18) var<storage, read_write> dc2: array<f32>;
@group(0) @binding(19) var<storage, read_write> ray_out: array<f32>;
@group(0) @binding(20) var<storage, read_write> flags: array<u32>;
@group(0) @binding(21) var<storage, read> occ_scale: array<f32>;
@group(0) @binding(22) var<storage, read_write> ema: array<f32>;
@group(0) @binding(23) var<storage, read_write> ray_state: array<u32>;
@group(0) @binding(24) var<storage, read_write> seg_off: array<u32>;
@group(0) @binding(25) var<storage, read_write> seg_idx: array<u32>;
@group(0) @binding(26) var<storage, read> dout_seg: array<f32>;
@group(0) @binding(27) var<storage, read_write> dout_all: array<f32>;
@group(0) @binding(28) var<storage, read_write> gpx: array<f32>;
@group(0) @binding(29) var<storage, read_write> gpy: array<f32>;
@group(0) @binding(30) var<storage, read_write> gpz: array<f32>;
@group(0) @binding(34) var<storage, read_write> occ_out: array<u32>;

fn index(wid: vec3<u32>, nwg: vec3<u32>, lid: u32) -> u32 {
    return (wid.x + wid.y * nwg.x) * 256u + lid;
}

fn ray_f(r: u32, k: u32) -> f32 {
    return rays[r * 16u + k];
}

// Truncated exponential: the argument clamped to [F_EXP_MIN, F_EXP_MAX], NaN to the minimum.
fn trunc_exp(x: f32) -> f32 {
    var y = x;
    if (!(y >= F_EXP_MIN)) {
        y = F_EXP_MIN;
    }
    if (y > F_EXP_MAX) {
        y = F_EXP_MAX;
    }
    return exp(y);
}

fn sigmoid(x: f32) -> f32 {
    if (!(x == x)) {
        return 0.5;
    }
    return 1.0 / (1.0 + exp(-x));
}

// ---------------------------------------------------------------------------------------------
// Marching (`Field::march`).

struct Ray {
    o: vec3<f32>,   // origin, field units
    d: vec3<f32>,
}

fn field_ray(r: u32) -> Ray {
    let s = f.center.w;
    let o = vec3<f32>((ray_f(r, 0u) - f.center.x) * s, (ray_f(r, 1u) - f.center.y) * s,
                      (ray_f(r, 2u) - f.center.z) * s);
    return Ray(o, vec3<f32>(ray_f(r, 3u), ray_f(r, 4u), ray_f(r, 5u)));
}

fn at(ray: Ray, t: f32) -> vec3<f32> {
    return vec3<f32>(ray.o.x + ray.d.x * t / f.rw, ray.o.y + ray.d.y * t / f.rw,
                     ray.o.z + ray.d.z * t / f.rw);
}

fn norm2(x: vec3<f32>) -> f32 {
    return x.x * x.x + x.y * x.y + x.z * x.z;
}

fn max_stretch(r: f32) -> f32 {
    if (r <= 1.0) {
        return 1.0;
    }
    return (2.0 * r - 1.0) / (r * r);
}

fn step_at(ray: Ray, t: f32) -> f32 {
    let r = sqrt(norm2(at(ray, t)));
    return f.delta * f.rw / max_stretch(r);
}

fn contract(x: vec3<f32>) -> vec3<f32> {
    let r2 = norm2(x);
    if (r2 <= 1.0) {
        return x;
    }
    let r = sqrt(r2);
    let s = (2.0 - 1.0 / r) / r;
    return x * s;
}

fn occ_axis(v: f32) -> u32 {
    let u = (v + F_CONTRACTED_RADIUS) / (2.0 * F_CONTRACTED_RADIUS) * f32(f.occ_res);
    if (!(u > 0.0)) {
        return 0u;
    }
    if (u >= f32(f.occ_res)) {
        return f.occ_res - 1u;
    }
    return min(u32(u), f.occ_res - 1u);
}

fn occupied(c: vec3<f32>) -> bool {
    let res = f.occ_res;
    let i = occ_axis(c.x) + occ_axis(c.y) * res + occ_axis(c.z) * res * res;
    return occ[i] != 0u;
}

// `f32::min` / `f32::max` of the CPU: the non-NaN operand wins.
fn min_f(a: f32, b: f32) -> f32 {
    if (!(a == a)) {
        return b;
    }
    if (b < a) {
        return b;
    }
    return a;
}

fn max_f(a: f32, b: f32) -> f32 {
    if (!(a == a)) {
        return b;
    }
    if (b > a) {
        return b;
    }
    return a;
}

// One marching step: the sample's length and midpoint contracted position.
struct Step {
    dt: f32,
    tm: f32,
    c: vec3<f32>,
}

fn march_step(ray: Ray, t: f32) -> Step {
    let dt = max_f(min_f(step_at(ray, t), f.far - t), 1e-6);
    let tm = t + 0.5 * dt;
    return Step(dt, tm, contract(at(ray, tm)));
}

@compute @workgroup_size(256)
fn march_count(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    let r = index(wid, nwg, lid);
    if (r >= f.n_rays) {
        return;
    }
    let ray = field_ray(r);
    var t = f.near + ray_f(r, 14u) * step_at(ray, f.near);
    var k = 0u;
    var n = 0u;
    while (t < f.far && k < F_MAX_MARCH) {
        let s = march_step(ray, t);
        if (occupied(s.c)) {
            n += 1u;
        }
        t += s.dt;
        k += 1u;
    }
    starts[r] = n;
    steps[r] = k;
}

@compute @workgroup_size(256)
fn march_write(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    let r = index(wid, nwg, lid);
    if (r >= f.n_rays) {
        return;
    }
    let ray = field_ray(r);
    var t = f.near + ray_f(r, 14u) * step_at(ray, f.near);
    var k = 0u;
    var i = starts[r];
    let end = starts[r + 1u];
    while (t < f.far && k < F_MAX_MARCH && i < end) {
        let s = march_step(ray, t);
        if (occupied(s.c)) {
            px[i] = (s.c.x + 2.0) * 0.25;
            py[i] = (s.c.y + 2.0) * 0.25;
            pz[i] = (s.c.z + 2.0) * 0.25;
            samp[4u * i] = s.tm;
            samp[4u * i + 1u] = s.dt;
            samp[4u * i + 2u] = (f32(k) + 0.5) * f.delta;
            samp[4u * i + 3u] = bitcast<f32>(r);
            i += 1u;
        }
        t += s.dt;
        k += 1u;
    }
}

// ---------------------------------------------------------------------------------------------
// The colour network's input: geometry features, SH(direction), appearance embedding.

fn sh_row(d: vec3<f32>, k: u32) -> f32 {
    let x = d.x;
    let y = d.y;
    let z = d.z;
    let xx = x * x;
    let yy = y * y;
    let zz = z * z;
    switch k {
        case 0u: { return 0.2820948; }
        case 1u: { return 0.4886025 * y; }
        case 2u: { return 0.4886025 * z; }
        case 3u: { return 0.4886025 * x; }
        case 4u: { return 1.0925484 * x * y; }
        case 5u: { return 1.0925484 * y * z; }
        case 6u: { return 0.9461747 * zz - 0.31539157; }
        case 7u: { return 1.0925484 * x * z; }
        case 8u: { return 0.5462742 * (xx - yy); }
        case 9u: { return 0.5900436 * y * (3.0 * xx - yy); }
        case 10u: { return 2.8906114 * x * y * z; }
        case 11u: { return 0.4570458 * y * (5.0 * zz - 1.0); }
        case 12u: { return 0.37317633 * z * (5.0 * zz - 3.0); }
        case 13u: { return 0.4570458 * x * (5.0 * zz - 1.0); }
        case 14u: { return 1.4453057 * z * (xx - yy); }
        default: { return 0.5900436 * x * (xx - 3.0 * yy); }
    }
}

@compute @workgroup_size(256)
fn color_input(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    let j = index(wid, nwg, lid);
    var cols = f.n;
    if (f.mode == 1u) {
        cols = alive_count[0];
    }
    if (j >= cols) {
        return;
    }
    var i = j;
    if (f.mode == 1u) {
        i = alive[j];
    }
    let r = bitcast<u32>(samp[4u * i + 3u]);
    let ld = f.ld;
    for (var k = 0u; k < F_GEO; k++) {
        cin[k * ld + j] = dout[(1u + k) * ld + i];
    }
    let d = vec3<f32>(ray_f(r, 3u), ray_f(r, 4u), ray_f(r, 5u));
    for (var k = 0u; k < F_SH; k++) {
        cin[(F_GEO + k) * ld + j] = sh_row(d, k);
    }
    let image = bitcast<u32>(ray_f(r, 15u));
    for (var k = 0u; k < f.emb_dim; k++) {
        var e = 0.0;
        if (image == F_NO_IMAGE || image >= f.n_images) {
            e = mean_emb[k];
        } else {
            e = params[f.emb_off + image * f.emb_dim + k];
        }
        cin[(F_GEO + F_SH + k) * ld + j] = e;
    }
}

// ---------------------------------------------------------------------------------------------
// Training along a ray: weights, compositing, the losses and their gradient, the weights'
// backward (`volume.rs`, `Field::add_ray_output_grad`, the loss loop of `train_step`).
// ray_out per ray: rgb (3), opacity, Σ w t, rgb loss, depth loss, distortion loss, coloured
// samples (u32 bits), kept samples (u32 bits); rendering: marched samples, samples through the
// density network (u32 bits).

fn sigma_of(i: u32) -> f32 {
    return trunc_exp(dout[i]);
}

fn rgb_of(i: u32, k: u32) -> f32 {
    return sigmoid(cout[k * f.ld + i]);
}

@compute @workgroup_size(256)
fn ray_train(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
             @builtin(local_invocation_index) lid: u32) {
    let r = index(wid, nwg, lid);
    if (r >= f.n_rays) {
        return;
    }
    let a = starts[r];
    let b = starts[r + 1u];
    let ld = f.ld;
    // Weights; colour up to and including the sample after which T < threshold.
    var trans_acc = 1.0;
    var nc = b - a;
    for (var i = a; i < b; i++) {
        let trans = exp(-sigma_of(i) * samp[4u * i + 1u]);
        wg[2u * i] = trans_acc * (1.0 - trans);
        trans_acc *= trans;
        if (trans_acc < F_TRANSMITTANCE && nc == b - a) {
            nc = i - a + 1u;
        }
    }
    var acc = 0.0;
    var dep = 0.0;
    for (var i = a; i < b; i++) {
        let w = wg[2u * i];
        acc += w;
        dep += w * samp[4u * i];
    }
    var c = vec3<f32>(0.0);
    for (var i = a; i < a + nc; i++) {
        let w = wg[2u * i];
        c = vec3<f32>(c.x + w * rgb_of(i, 0u), c.y + w * rgb_of(i, 1u), c.z + w * rgb_of(i, 2u));
    }
    let bg = vec3<f32>(ray_f(r, 6u), ray_f(r, 7u), ray_f(r, 8u));
    let out = vec3<f32>(c.x + (1.0 - acc) * bg.x, c.y + (1.0 - acc) * bg.y, c.z + (1.0 - acc) * bg.z);
    var l_rgb = 0.0;
    var dc = vec3<f32>(0.0);
    for (var k = 0u; k < 3u; k++) {
        let e = out[k] - ray_f(r, 9u + k);
        l_rgb += e * e / 3.0;
        dc[k] = 2.0 * e / 3.0 * f.inv_rays;
    }
    // ∂L/∂w: the background term on every sample, the colour term on coloured ones.
    let d_a = 0.0 - (dc.x * bg.x + dc.y * bg.y + dc.z * bg.z);
    for (var i = a; i < b; i++) {
        var g = d_a;
        let w = wg[2u * i];
        if (i < a + nc) {
            let col = vec3<f32>(rgb_of(i, 0u), rgb_of(i, 1u), rgb_of(i, 2u));
            g += dc.x * col.x + dc.y * col.y + dc.z * col.z;
            for (var k = 0u; k < 3u; k++) {
                dc2[k * ld + i] = w * dc[k] * col[k] * (1.0 - col[k]);
            }
        } else {
            for (var k = 0u; k < 3u; k++) {
                dc2[k * ld + i] = 0.0;
            }
        }
        wg[2u * i + 1u] = g;
    }
    // DS-NeRF depth loss.
    var l_depth = 0.0;
    let z = ray_f(r, 12u);
    let zw = ray_f(r, 13u);
    if (f.depth_w > 0.0 && zw > 0.0 && b > a) {
        let scale = f.depth_w * zw * f.inv_rays;
        let s = max_f(f.depth_sigma * z, 1e-4);
        let inv = 1.0 / (2.0 * s * s);
        var l = 0.0;
        for (var i = a; i < b; i++) {
            let dd = samp[4u * i] - z;
            let kk = exp(-(dd * dd) * inv) * samp[4u * i + 1u];
            if (kk == 0.0) {
                continue;
            }
            let w = wg[2u * i];
            l += -log(w + F_DEPTH_LOG_EPS) * kk;
            wg[2u * i + 1u] += scale * (-kk / (w + F_DEPTH_LOG_EPS));
        }
        l_depth = l * zw;
    }
    // mip-NeRF 360 distortion, O(n).
    var l_dist = 0.0;
    if (f.dist_w > 0.0 && b > a) {
        let scale = f.dist_w * f.inv_rays;
        let ds = f.delta;
        var w_tot = 0.0;
        var wm_tot = 0.0;
        for (var i = a; i < b; i++) {
            let w = wg[2u * i];
            w_tot += w;
            wm_tot += w * samp[4u * i + 2u];
        }
        var w_before = 0.0;
        var wm_before = 0.0;
        for (var i = a; i < b; i++) {
            let w = wg[2u * i];
            let m = samp[4u * i + 2u];
            let w_after = w_tot - w_before - w;
            let wm_after = wm_tot - wm_before - w * m;
            let s = m * w_before - wm_before + wm_after - m * w_after;
            l_dist += w * s + w * w * ds / 3.0;
            wg[2u * i + 1u] += scale * (2.0 * s + 2.0 * w * ds / 3.0);
            w_before += w;
            wm_before += w * m;
        }
    }
    // Weights backward: ∂L/∂σ_i = δ_i (g_i T_{i+1} − Σ_{k>i} g_k w_k), then through trunc_exp.
    var suffix = 0.0;
    for (var i = a; i < b; i++) {
        suffix += wg[2u * i + 1u] * wg[2u * i];
    }
    var tr = 1.0;
    for (var i = a; i < b; i++) {
        let sigma = sigma_of(i);
        let dt = samp[4u * i + 1u];
        tr *= exp(-sigma * dt);
        let g = wg[2u * i + 1u];
        suffix -= g * wg[2u * i];
        d_dout[i] = dt * (g * tr - suffix) * sigma;
    }
    let o = 12u * r;
    ray_out[o] = out.x;
    ray_out[o + 1u] = out.y;
    ray_out[o + 2u] = out.z;
    ray_out[o + 3u] = acc;
    ray_out[o + 4u] = dep;
    ray_out[o + 5u] = l_rgb;
    ray_out[o + 6u] = l_depth;
    ray_out[o + 7u] = l_dist;
    ray_out[o + 8u] = bitcast<f32>(nc);
    ray_out[o + 9u] = bitcast<f32>(b - a);
}

// ---------------------------------------------------------------------------------------------
// Rendering: densities segment by segment (`Field::densities_until_termination`). Each round
// evaluates the next `f.mode` samples of every ray still going (16, 32, 64, then 128), and a
// ray stops once its transmittance falls below the cut-off — computed as `ray_render` computes
// it. ray_state per ray: the next sample (once stopped: the end of the evaluated ones), going
// (1/0), transmittance, samples evaluated.

@compute @workgroup_size(256)
fn seg_count(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
             @builtin(local_invocation_index) lid: u32) {
    let r = index(wid, nwg, lid);
    if (r >= f.n_rays) {
        return;
    }
    let end = starts[r + 1u];
    if (f.first == 0u) {
        ray_state[4u * r] = starts[r];
        ray_state[4u * r + 1u] = u32(end > starts[r]);
        ray_state[4u * r + 2u] = bitcast<u32>(1.0);
        ray_state[4u * r + 3u] = 0u;
    }
    var cnt = 0u;
    if (ray_state[4u * r + 1u] == 1u) {
        cnt = min(f.mode, end - ray_state[4u * r]);
    }
    seg_off[r] = cnt;
}

// After the exclusive scan of the counts: each ray's segment, gathered.
@compute @workgroup_size(256)
fn seg_gather(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) lid: u32) {
    let r = index(wid, nwg, lid);
    if (r >= f.n_rays) {
        return;
    }
    let first = ray_state[4u * r];
    let o = seg_off[r];
    let cnt = seg_off[r + 1u] - o;
    for (var j = 0u; j < cnt; j++) {
        let i = first + j;
        seg_idx[o + j] = i;
        gpx[o + j] = px[i];
        gpy[o + j] = py[i];
        gpz[o + j] = pz[i];
    }
}

// The segment's network outputs back to their samples' columns (`f.first` = the segment
// batch's row stride, `f.n` = its samples).
@compute @workgroup_size(256)
fn seg_scatter(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    let q = index(wid, nwg, lid);
    if (q >= f.n) {
        return;
    }
    let i = seg_idx[q];
    for (var k = 0u; k < 1u + F_GEO; k++) {
        dout_all[k * f.ld + i] = dout_seg[k * f.first + q];
    }
}

@compute @workgroup_size(256)
fn seg_advance(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) lid: u32) {
    let r = index(wid, nwg, lid);
    if (r >= f.n_rays || ray_state[4u * r + 1u] == 0u) {
        return;
    }
    let first = ray_state[4u * r];
    let cnt = seg_off[r + 1u] - seg_off[r];
    var tr = bitcast<f32>(ray_state[4u * r + 2u]);
    var going = 1u;
    var next = first + cnt;
    for (var i = first; i < first + cnt; i++) {
        tr *= exp(-trunc_exp(dout_all[i]) * samp[4u * i + 1u]);
        if (tr < F_TRANSMITTANCE) {
            going = 0u;
            next = i + 1u;
            break;
        }
    }
    if (next >= starts[r + 1u]) {
        going = 0u;
    }
    ray_state[4u * r] = next;
    ray_state[4u * r + 1u] = going;
    ray_state[4u * r + 2u] = bitcast<u32>(tr);
    ray_state[4u * r + 3u] += cnt;
}

// ---------------------------------------------------------------------------------------------
// Rendering along a ray: weights until the transmittance cut-off, and which samples get a
// colour (weight ≥ min_color_w); then, after the colour network, the composite.

@compute @workgroup_size(256)
fn ray_render(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) lid: u32) {
    let r = index(wid, nwg, lid);
    if (r >= f.n_rays) {
        return;
    }
    let a = starts[r];
    let end = starts[r + 1u];
    // Only the samples whose densities were evaluated (the transmittance falls below the
    // cut-off at the last of them, or they are all the ray's).
    let b = min(ray_state[4u * r], end);
    var trans_acc = 1.0;
    var acc = 0.0;
    var dep = 0.0;
    var kept = b;
    var i = a;
    loop {
        if (i >= b) {
            break;
        }
        let trans = exp(-sigma_of(i) * samp[4u * i + 1u]);
        let w = trans_acc * (1.0 - trans);
        trans_acc *= trans;
        wg[2u * i] = w;
        acc += w;
        dep += w * samp[4u * i];
        flags[i] = u32(w >= f.min_color_w);
        i += 1u;
        if (trans_acc < F_TRANSMITTANCE) {
            kept = i;
            break;
        }
    }
    for (var k = kept; k < end; k++) {
        flags[k] = 0u;
    }
    let o = 12u * r;
    ray_out[o + 3u] = acc;
    ray_out[o + 4u] = dep;
    ray_out[o + 9u] = bitcast<f32>(kept - a);
    ray_out[o + 10u] = bitcast<f32>(end - a);
    ray_out[o + 11u] = bitcast<f32>(ray_state[4u * r + 3u]);
}

// After the in-place exclusive scan of `flags` (n + 1 words): the live samples' indices in
// order, and their count.
@compute @workgroup_size(256)
fn compact(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let i = index(wid, nwg, lid);
    if (i == 0u) {
        alive_count[0] = flags[f.n];
    }
    if (i >= f.n) {
        return;
    }
    if (flags[i + 1u] > flags[i]) {
        alive[flags[i]] = i;
    }
}

@compute @workgroup_size(256)
fn ray_composite(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) lid: u32) {
    let r = index(wid, nwg, lid);
    if (r >= f.n_rays) {
        return;
    }
    let a = starts[r];
    let b = starts[r + 1u];
    var c = vec3<f32>(0.0);
    var nc = 0u;
    for (var i = a; i < b; i++) {
        if (flags[i + 1u] > flags[i]) {
            let j = flags[i];
            let w = wg[2u * i];
            c = vec3<f32>(c.x + w * rgb_of(j, 0u), c.y + w * rgb_of(j, 1u), c.z + w * rgb_of(j, 2u));
            nc += 1u;
        }
    }
    let o = 12u * r;
    let acc = ray_out[o + 3u];
    let bg = vec3<f32>(ray_f(r, 6u), ray_f(r, 7u), ray_f(r, 8u));
    ray_out[o] = c.x + (1.0 - acc) * bg.x;
    ray_out[o + 1u] = c.y + (1.0 - acc) * bg.y;
    ray_out[o + 2u] = c.z + (1.0 - acc) * bg.z;
    ray_out[o + 8u] = bitcast<f32>(nc);
}

// ---------------------------------------------------------------------------------------------
// Occupancy grid (`OccupancyGrid::update`): EMA of σ·step per cell, then the flags against
// min(mean EMA, threshold).

@compute @workgroup_size(256)
fn occ_values(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) lid: u32) {
    let i = index(wid, nwg, lid);
    if (i >= f.n) {
        return;
    }
    var v = sigma_of(i) * occ_scale[i];
    if (finite(v)) {
        v = max_f(v, 0.0);
    } else {
        v = 0.0;
    }
    let e = f.first + i;
    ema[e] = max_f(ema[e] * F_OCC_DECAY, v);
}

var<workgroup> partial_sums: array<f32, 256>;

// One workgroup: each invocation sums its stride of cells in order, then a fixed tree.
@compute @workgroup_size(256)
fn occ_flags(@builtin(local_invocation_index) lid: u32) {
    let cells = f.n;
    var s = 0.0;
    for (var i = lid; i < cells; i += 256u) {
        s += ema[i];
    }
    partial_sums[lid] = s;
    for (var h = 128u; h > 0u; h /= 2u) {
        workgroupBarrier();
        if (lid < h) {
            partial_sums[lid] += partial_sums[lid + h];
        }
    }
    workgroupBarrier();
    let mean = partial_sums[0] / f32(max(cells, 1u));
    let thr = min_f(mean, F_OCC_THRESHOLD);
    for (var i = lid; i < cells; i += 256u) {
        occ_out[i] = u32(ema[i] > thr);
    }
}
