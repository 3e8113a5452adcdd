// The projection's backward on the GPU: the WGSL twin of `project::project_vjp_lanes` and of
// the colour backward of `backward::gaussian` (sh.rs), in f32. One invocation per Gaussian
// turns its screen-space gradient — dL/d(mean2d x, y; conic a, b, c; opacity; colour r, g, b;
// depth), the layout of the CPU's pair sums — into gradients of its raw parameters. A
// Gaussian whose forward intermediates fail (invalid, behind the near plane, degenerate
// covariance) gets zeros, as on the CPU.

struct Cam {
    r0: vec4<f32>,
    r1: vec4<f32>,
    r2: vec4<f32>,
    focal: vec4<f32>,
    lim: vec4<f32>,
    centre: vec4<f32>,
    size: vec4<u32>,
    counts: vec4<u32>,
    misc: vec4<f32>,
}

@group(0) @binding(0) var<uniform> cam: Cam;
@group(0) @binding(1) var<storage, read> means: array<f32>;
@group(0) @binding(2) var<storage, read> log_scales: array<f32>;
@group(0) @binding(3) var<storage, read> quats: array<f32>;
@group(0) @binding(4) var<storage, read> logits: array<f32>;
@group(0) @binding(5) var<storage, read> sh: array<f32>;
@group(0) @binding(6) var<storage, read> screen: array<f32>;          // SCREEN_STRIDE
@group(0) @binding(7) var<storage, read_write> grads: array<f32>;     // GRAD_STRIDE
@group(0) @binding(8) var<storage, read_write> sh_grads: array<f32>;  // K·3

fn coef(i: u32, k: u32, c: u32) -> f32 {
    return sh[(i * cam.counts.y + k) * 3u + c];
}

fn zero_out(i: u32) {
    for (var q = 0u; q < GRAD_STRIDE; q++) {
        grads[i * GRAD_STRIDE + q] = 0.0;
    }
    for (var q = 0u; q < cam.counts.y * 3u; q++) {
        sh_grads[i * cam.counts.y * 3u + q] = 0.0;
    }
}

// The SH basis at `d` (sh.rs `basis`).
fn basis(deg: u32, d: vec3<f32>) -> array<f32, 16> {
    var y: array<f32, 16>;
    y[0] = C0;
    if (deg >= 1u) {
        y[1] = -C1 * d.y;
        y[2] = C1 * d.z;
        y[3] = -C1 * d.x;
    }
    if (deg >= 2u) {
        let xx = d.x * d.x;
        let yy = d.y * d.y;
        let zz = d.z * d.z;
        y[4] = C20 * d.x * d.y;
        y[5] = C21 * d.y * d.z;
        y[6] = C22 * (2.0 * zz - xx - yy);
        y[7] = C23 * d.x * d.z;
        y[8] = C24 * (xx - yy);
        if (deg >= 3u) {
            y[9] = C30 * d.y * (3.0 * xx - yy);
            y[10] = C31 * d.x * d.y * d.z;
            y[11] = C32 * d.y * (4.0 * zz - xx - yy);
            y[12] = C33 * d.z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            y[13] = C34 * d.x * (4.0 * zz - xx - yy);
            y[14] = C35 * d.z * (xx - yy);
            y[15] = C36 * d.x * (xx - 3.0 * yy);
        }
    }
    return y;
}

// dL/d(direction) from dL/dY_k (sh.rs `basis_vjp`), the components taken as independent.
fn basis_vjp(deg: u32, d: vec3<f32>, g: array<f32, 16>) -> vec3<f32> {
    var gd = vec3<f32>(0.0);
    if (deg < 1u) {
        return gd;
    }
    let x = d.x;
    let y = d.y;
    let z = d.z;
    gd.y -= C1 * g[1];
    gd.z += C1 * g[2];
    gd.x -= C1 * g[3];
    if (deg < 2u) {
        return gd;
    }
    let xx = x * x;
    let yy = y * y;
    let zz = z * z;
    gd.x += C20 * y * g[4];
    gd.y += C20 * x * g[4];
    gd.y += C21 * z * g[5];
    gd.z += C21 * y * g[5];
    gd.x -= 2.0 * C22 * x * g[6];
    gd.y -= 2.0 * C22 * y * g[6];
    gd.z += 4.0 * C22 * z * g[6];
    gd.x += C23 * z * g[7];
    gd.z += C23 * x * g[7];
    gd.x += 2.0 * C24 * x * g[8];
    gd.y -= 2.0 * C24 * y * g[8];
    if (deg < 3u) {
        return gd;
    }
    gd.x += 6.0 * C30 * x * y * g[9];
    gd.y += 3.0 * C30 * (xx - yy) * g[9];
    gd.x += C31 * y * z * g[10];
    gd.y += C31 * x * z * g[10];
    gd.z += C31 * x * y * g[10];
    gd.x -= 2.0 * C32 * x * y * g[11];
    gd.y += C32 * (4.0 * zz - xx - 3.0 * yy) * g[11];
    gd.z += 8.0 * C32 * y * z * g[11];
    gd.x -= 6.0 * C33 * x * z * g[12];
    gd.y -= 6.0 * C33 * y * z * g[12];
    gd.z += C33 * (6.0 * zz - 3.0 * xx - 3.0 * yy) * g[12];
    gd.x += C34 * (4.0 * zz - 3.0 * xx - yy) * g[13];
    gd.y -= 2.0 * C34 * x * y * g[13];
    gd.z += 8.0 * C34 * x * z * g[13];
    gd.x += 2.0 * C35 * x * z * g[14];
    gd.y -= 2.0 * C35 * y * z * g[14];
    gd.z += C35 * (xx - yy) * g[14];
    gd.x += 3.0 * C36 * (xx - yy) * g[15];
    gd.y -= 6.0 * C36 * x * y * g[15];
    return gd;
}

@compute @workgroup_size(256)
fn project_vjp(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if (i >= cam.counts.x) {
        return;
    }
    let mu = vec3<f32>(means[3u * i], means[3u * i + 1u], means[3u * i + 2u]);
    let ls = vec3<f32>(log_scales[3u * i], log_scales[3u * i + 1u], log_scales[3u * i + 2u]);
    let q = vec4<f32>(quats[4u * i], quats[4u * i + 1u], quats[4u * i + 2u], quats[4u * i + 3u]);
    let logit = logits[i];
    let n2 = dot(q, q);
    let ok = finite(mu.x) && finite(mu.y) && finite(mu.z) && finite(ls.x) && finite(ls.y)
        && finite(ls.z) && finite(q.x) && finite(q.y) && finite(q.z) && finite(q.w) && finite(logit)
        && n2 >= MIN_QUAT_NORM2 && finite(n2);
    let pc = vec3<f32>(dot(cam.r0.xyz, mu) + cam.r0.w, dot(cam.r1.xyz, mu) + cam.r1.w, dot(cam.r2.xyz, mu) + cam.r2.w);
    if (!ok || !(pc.z >= cam.centre.w)) {
        zero_out(i);
        return;
    }
    // Forward intermediates (as project.wgsl).
    let s = exp(ls);
    let qnorm = sqrt(n2);
    let qn = q / qnorm;
    let qw = qn.x;
    let qx = qn.y;
    let qy = qn.z;
    let qz = qn.w;
    let rot0 = vec3<f32>(1.0 - (qy * qy + qz * qz) * 2.0, (qx * qy - qw * qz) * 2.0, (qx * qz + qw * qy) * 2.0);
    let rot1 = vec3<f32>((qx * qy + qw * qz) * 2.0, 1.0 - (qx * qx + qz * qz) * 2.0, (qy * qz - qw * qx) * 2.0);
    let rot2 = vec3<f32>((qx * qz - qw * qy) * 2.0, (qy * qz + qw * qx) * 2.0, 1.0 - (qx * qx + qy * qy) * 2.0);
    let rc0 = vec3<f32>(rot0.x, rot1.x, rot2.x);
    let rc1 = vec3<f32>(rot0.y, rot1.y, rot2.y);
    let rc2 = vec3<f32>(rot0.z, rot1.z, rot2.z);
    let w0 = cam.r0.xyz;
    let w1 = cam.r1.xyz;
    let w2 = cam.r2.xyz;
    // a = W R (rows); mp = a · diag(s).
    let a0 = vec3<f32>(dot(w0, rc0), dot(w0, rc1), dot(w0, rc2));
    let a1 = vec3<f32>(dot(w1, rc0), dot(w1, rc1), dot(w1, rc2));
    let a2 = vec3<f32>(dot(w2, rc0), dot(w2, rc1), dot(w2, rc2));
    let mp0 = a0 * s;
    let mp1 = a1 * s;
    let mp2 = a2 * s;
    let fx = cam.focal.x;
    let fy = cam.focal.y;
    let x = pc.x;
    let y = pc.y;
    let z = pc.z;
    let u = x / z;
    let v = y / z;
    let clamped_x = u > cam.lim.x || u < -cam.lim.y;
    let clamped_y = v > cam.lim.z || v < -cam.lim.w;
    let limit_x = select(-cam.lim.y, cam.lim.x, u > cam.lim.x);
    let limit_y = select(-cam.lim.w, cam.lim.z, v > cam.lim.z);
    let txz = select(u, limit_x, clamped_x);
    let tyz = select(v, limit_y, clamped_y);
    let j00 = fx / z;
    let j02 = txz * -fx / z;
    let j11 = fy / z;
    let j12 = tyz * -fy / z;
    let tm0 = j00 * mp0 + j02 * mp2;
    let tm1 = j11 * mp1 + j12 * mp2;
    let x_raw = vec3<f32>(dot(tm0, tm0), dot(tm0, tm1), dot(tm1, tm1));
    let det_raw = x_raw.x * x_raw.z - x_raw.y * x_raw.y;
    let p = x_raw.x + EPS2D;
    let r = x_raw.z + EPS2D;
    let det_blur = p * r - x_raw.y * x_raw.y;
    if (!(finite(x_raw.x) && finite(x_raw.y) && finite(x_raw.z)) || !(det_blur > 0.0)) {
        zero_out(i);
        return;
    }
    let inv_det = 1.0 / det_blur;
    let ka = r * inv_det;
    let kb = -x_raw.y * inv_det;
    let kc = p * inv_det;
    let ratio = det_raw * inv_det;
    let o = 1.0 / (1.0 + exp(-logit));

    let gs = i * SCREEN_STRIDE;
    let g_mean2d = vec2<f32>(screen[gs], screen[gs + 1u]);
    let g_conic = vec3<f32>(screen[gs + 2u], screen[gs + 3u], screen[gs + 4u]);
    let g_opacity = screen[gs + 5u];
    let g_color = vec3<f32>(screen[gs + 6u], screen[gs + 7u], screen[gs + 8u]);
    let g_depth = screen[gs + 9u];

    // G_X = −K G_K K, with b in both off-diagonal entries of G_K.
    let k = mat2x2<f32>(ka, kb, kb, kc);
    let gk = mat2x2<f32>(g_conic.x, g_conic.y * 0.5, g_conic.y * 0.5, g_conic.z);
    var gx = (k * gk * k) * -1.0;
    var g_obase = g_opacity;
    if (cam.counts.w != 0u) {
        let comp = sqrt(max(ratio, MIN_COMPENSATION_RATIO));
        g_obase = g_opacity * comp;
        let g_comp = g_opacity * o;
        let g_ratio = g_comp / (comp * 2.0);
        if (ratio > MIN_COMPENSATION_RATIO) {
            let adj = mat2x2<f32>(x_raw.z, -x_raw.y, -x_raw.y, x_raw.x);
            gx = gx + g_ratio * (adj * inv_det - ratio * k);
        }
    }
    // Σ2d_raw = T Tᵀ ⇒ G_T = 2 G_X T.
    let gt0 = (gx[0][0] * tm0 + gx[1][0] * tm1) * 2.0;
    let gt1 = (gx[0][1] * tm0 + gx[1][1] * tm1) * 2.0;
    let g_j00 = dot(gt0, mp0);
    let g_j02 = dot(gt0, mp2);
    let g_j11 = dot(gt1, mp1);
    let g_j12 = dot(gt1, mp2);
    let g_mp0 = j00 * gt0;
    let g_mp1 = j11 * gt1;
    let g_mp2 = j02 * gt0 + j12 * gt1;
    let z2 = z * z;
    let z3 = z2 * z;
    var g_pc = vec3<f32>(g_mean2d.x * fx / z, g_mean2d.y * fy / z, -((g_mean2d.x * fx * x + g_mean2d.y * fy * y) / z2));
    g_pc.z = g_pc.z - (g_j00 * fx / z2 + g_j11 * fy / z2);
    if (clamped_x) {
        g_pc.z = g_pc.z + g_j02 * fx * limit_x / z2;
    } else {
        g_pc.x = g_pc.x - g_j02 * fx / z2;
        g_pc.z = g_pc.z + g_j02 * 2.0 * fx * x / z3;
    }
    if (clamped_y) {
        g_pc.z = g_pc.z + g_j12 * fy * limit_y / z2;
    } else {
        g_pc.y = g_pc.y - g_j12 * fy / z2;
        g_pc.z = g_pc.z + g_j12 * 2.0 * fy * y / z3;
    }
    g_pc.z = g_pc.z + g_depth;
    var g_mean = g_pc.x * w0 + g_pc.y * w1 + g_pc.z * w2;
    // M' = A diag(s): G_A = G_M' diag(s), G_s = colsum(A ∘ G_M') · s; G_R = Wᵀ G_A.
    let ga0 = g_mp0 * s;
    let ga1 = g_mp1 * s;
    let ga2 = g_mp2 * s;
    let g_ls = (g_mp0 * a0 + g_mp1 * a1 + g_mp2 * a2) * s;
    // gr[r][col] = Σ_i ga_i[col] · W[i][r].
    let grr0 = ga0 * w0.x + ga1 * w1.x + ga2 * w2.x; // row r = 0: (col 0, 1, 2)
    let grr1 = ga0 * w0.y + ga1 * w1.y + ga2 * w2.y;
    let grr2 = ga0 * w0.z + ga1 * w1.z + ga2 * w2.z;
    let gqn = vec4<f32>(
        (-qz * grr0.y + qy * grr0.z + qz * grr1.x - qx * grr1.z - qy * grr2.x + qx * grr2.y) * 2.0,
        (qy * grr0.y + qz * grr0.z + qy * grr1.x - qx * grr1.y * 2.0 - qw * grr1.z + qz * grr2.x
            + qw * grr2.y - qx * grr2.z * 2.0) * 2.0,
        (-(qy * grr0.x * 2.0) + qx * grr0.y + qw * grr0.z + qx * grr1.x + qz * grr1.z - qw * grr2.x
            + qz * grr2.y - qy * grr2.z * 2.0) * 2.0,
        (-(qz * grr0.x * 2.0) - qw * grr0.y + qx * grr0.z + qw * grr1.x - qz * grr1.y * 2.0
            + qy * grr1.z + qx * grr2.x + qy * grr2.y) * 2.0);
    let dotq = dot(gqn, qn);
    let g_quat = (gqn - qn * dotq) / qnorm;
    let g_logit = g_obase * o * (1.0 - o);

    // Colour: max(0.5 + Σ coef·Y(dir), 0) with dir = normalize(mean − centre).
    let deg = cam.counts.z;
    let kk = cam.counts.y;
    let nb = (deg + 1u) * (deg + 1u);
    let vdir = mu - cam.centre.xyz;
    let len = length(vdir);
    let base = i * kk * 3u;
    for (var qq = 0u; qq < kk * 3u; qq++) {
        sh_grads[base + qq] = 0.0;
    }
    if (len > 0.0) {
        let dir = vdir / len;
        let yb = basis(deg, dir);
        var raw = vec3<f32>(0.5);
        for (var b = 0u; b < nb; b++) {
            raw += vec3<f32>(coef(i, b, 0u), coef(i, b, 1u), coef(i, b, 2u)) * yb[b];
        }
        let gc = select(vec3<f32>(0.0), g_color, raw > vec3<f32>(0.0));
        var gy: array<f32, 16>;
        for (var b = 0u; b < nb; b++) {
            sh_grads[base + b * 3u] = gc.x * yb[b];
            sh_grads[base + b * 3u + 1u] = gc.y * yb[b];
            sh_grads[base + b * 3u + 2u] = gc.z * yb[b];
            gy[b] = gc.x * coef(i, b, 0u) + gc.y * coef(i, b, 1u) + gc.z * coef(i, b, 2u);
        }
        let gd = basis_vjp(deg, dir, gy);
        let dd = dot(gd, dir);
        g_mean = g_mean + (gd - dir * dd) / len;
    }
    let og = i * GRAD_STRIDE;
    grads[og] = g_mean.x;
    grads[og + 1u] = g_mean.y;
    grads[og + 2u] = g_mean.z;
    grads[og + 3u] = g_ls.x;
    grads[og + 4u] = g_ls.y;
    grads[og + 5u] = g_ls.z;
    grads[og + 6u] = g_quat.x;
    grads[og + 7u] = g_quat.y;
    grads[og + 8u] = g_quat.z;
    grads[og + 9u] = g_quat.w;
    grads[og + 10u] = g_logit;
}
