// The projection on the GPU: the WGSL twin of `project::project_lanes` and the colour of
// `forward::project_chunk` (gsplat classic EWA, see project/mod.rs), in f32. One invocation
// per Gaussian writes its screen-space splat, its tile rectangle, its sort key and its tile
// count; a Gaussian that is culled or invalid gets the key 0xffffffff and no tiles.

struct Cam {
    r0: vec4<f32>,          // row 0 of the world-to-camera rotation, w = t.x
    r1: vec4<f32>,
    r2: vec4<f32>,
    focal: vec4<f32>,       // fx, fy, cx, cy
    lim: vec4<f32>,         // Jacobian clamp of x/z: +, −; of y/z: +, −
    centre: vec4<f32>,      // camera centre (world), w = near
    size: vec4<u32>,        // width, height, tiles_x, tiles_y
    counts: vec4<u32>,      // n, stored SH coefficients K, active degree, antialiased
    misc: vec4<f32>,        // max_alpha, −, −, −
}

@group(0) @binding(0) var<uniform> cam: Cam;
@group(0) @binding(1) var<storage, read> means: array<f32>;      // 3 per Gaussian
@group(0) @binding(2) var<storage, read> log_scales: array<f32>; // 3
@group(0) @binding(3) var<storage, read> quats: array<f32>;      // 4 (w, x, y, z)
@group(0) @binding(4) var<storage, read> logits: array<f32>;     // 1
@group(0) @binding(5) var<storage, read> sh: array<f32>;         // K·3, [k·3 + c]
@group(0) @binding(6) var<storage, read_write> splats: array<f32>;  // SPLAT_STRIDE
// x0 | x1 << 16, y0 | y1 << 16 (tiles [x0, x1) × [y0, y1)), tile count, status (0 visible,
// 1 culled, 2 invalid).
@group(0) @binding(7) var<storage, read_write> rects: array<vec4<u32>>;
@group(0) @binding(8) var<storage, read_write> keys: array<u32>;

fn cull(i: u32, s: u32) {
    keys[i] = 0xffffffffu;
    rects[i] = vec4<u32>(0u, 0u, 0u, s);
}

fn sh_coef(i: u32, k: u32, c: u32) -> f32 {
    return sh[(i * cam.counts.y + k) * 3u + c];
}

// Colour: max(0.5 + Σ_k coef_k · Y_k(dir), 0) per channel (sh.rs).
fn color(i: u32, dir: vec3<f32>) -> vec3<f32> {
    let deg = cam.counts.z;
    var y: array<f32, 16>;
    y[0] = C0;
    let x = dir.x;
    let yy_ = dir.y;
    let z = dir.z;
    if (deg >= 1u) {
        y[1] = -C1 * yy_;
        y[2] = C1 * z;
        y[3] = -C1 * x;
    }
    if (deg >= 2u) {
        let xx = x * x;
        let yy = yy_ * yy_;
        let zz = z * z;
        y[4] = 1.0925484305920792 * x * yy_;
        y[5] = -1.0925484305920792 * yy_ * z;
        y[6] = 0.31539156525252005 * (2.0 * zz - xx - yy);
        y[7] = -1.0925484305920792 * x * z;
        y[8] = 0.5462742152960396 * (xx - yy);
        if (deg >= 3u) {
            y[9] = -0.5900435899266435 * yy_ * (3.0 * xx - yy);
            y[10] = 2.890611442640554 * x * yy_ * z;
            y[11] = -0.4570457994644658 * yy_ * (4.0 * zz - xx - yy);
            y[12] = 0.3731763325901154 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            y[13] = -0.4570457994644658 * x * (4.0 * zz - xx - yy);
            y[14] = 1.445305721320277 * z * (xx - yy);
            y[15] = -0.5900435899266435 * x * (xx - 3.0 * yy);
        }
    }
    let n = (deg + 1u) * (deg + 1u);
    var c = vec3<f32>(0.5);
    for (var k = 0u; k < n; k++) {
        c += vec3<f32>(sh_coef(i, k, 0u), sh_coef(i, k, 1u), sh_coef(i, k, 2u)) * y[k];
    }
    return max(c, vec3<f32>(0.0));
}

@compute @workgroup_size(256)
fn project(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if (i >= cam.counts.x) {
        return;
    }
    let mu = vec3<f32>(means[3u * i], means[3u * i + 1u], means[3u * i + 2u]);
    let ls = vec3<f32>(log_scales[3u * i], log_scales[3u * i + 1u], log_scales[3u * i + 2u]);
    let q = vec4<f32>(quats[4u * i], quats[4u * i + 1u], quats[4u * i + 2u], quats[4u * i + 3u]);
    let logit = logits[i];
    var ok = finite(mu.x) && finite(mu.y) && finite(mu.z) && finite(ls.x) && finite(ls.y)
        && finite(ls.z) && finite(q.x) && finite(q.y) && finite(q.z) && finite(q.w) && finite(logit);
    let n2 = dot(q, q);
    ok = ok && n2 >= MIN_QUAT_NORM2 && finite(n2);
    for (var k = 0u; k < (cam.counts.z + 1u) * (cam.counts.z + 1u); k++) {
        ok = ok && finite(sh_coef(i, k, 0u)) && finite(sh_coef(i, k, 1u)) && finite(sh_coef(i, k, 2u));
    }
    if (!ok) {
        cull(i, 2u);
        return;
    }
    let pc = vec3<f32>(dot(cam.r0.xyz, mu) + cam.r0.w, dot(cam.r1.xyz, mu) + cam.r1.w, dot(cam.r2.xyz, mu) + cam.r2.w);
    if (!(pc.z >= cam.centre.w)) {
        cull(i, 1u);
        return;
    }
    let s = exp(ls);
    let qn = q / sqrt(n2);
    let w = qn.x;
    let x = qn.y;
    let y = qn.z;
    let z = qn.w;
    // Columns of R(q) (rot[row][col]); a = W·R, mp = a·S.
    let rot0 = vec3<f32>(1.0 - (y * y + z * z) * 2.0, (x * y - w * z) * 2.0, (x * z + w * y) * 2.0);
    let rot1 = vec3<f32>((x * y + w * z) * 2.0, 1.0 - (x * x + z * z) * 2.0, (y * z - w * x) * 2.0);
    let rot2 = vec3<f32>((x * z - w * y) * 2.0, (y * z + w * x) * 2.0, 1.0 - (x * x + y * y) * 2.0);
    // (W R)[i][j] = W row i · R column j; mp = (W R)·S scales column j by s[j].
    let rc0 = vec3<f32>(rot0.x, rot1.x, rot2.x);
    let rc1 = vec3<f32>(rot0.y, rot1.y, rot2.y);
    let rc2 = vec3<f32>(rot0.z, rot1.z, rot2.z);
    let w0 = cam.r0.xyz;
    let w1 = cam.r1.xyz;
    let w2 = cam.r2.xyz;
    let mp0 = vec3<f32>(dot(w0, rc0), dot(w0, rc1), dot(w0, rc2)) * s;
    let mp1 = vec3<f32>(dot(w1, rc0), dot(w1, rc1), dot(w1, rc2)) * s;
    let mp2 = vec3<f32>(dot(w2, rc0), dot(w2, rc1), dot(w2, rc2)) * s;
    let fx = cam.focal.x;
    let fy = cam.focal.y;
    let u = pc.x / pc.z;
    let v = pc.y / pc.z;
    let txz = clamp(u, -cam.lim.y, cam.lim.x);
    let tyz = clamp(v, -cam.lim.w, cam.lim.z);
    let j00 = fx / pc.z;
    let j02 = txz * -fx / pc.z;
    let j11 = fy / pc.z;
    let j12 = tyz * -fy / pc.z;
    // tm[0][k] = j00·mp[0][k] + j02·mp[2][k]; tm[1][k] = j11·mp[1][k] + j12·mp[2][k].
    let tm0 = j00 * mp0 + j02 * mp2;
    let tm1 = j11 * mp1 + j12 * mp2;
    let x_raw = vec3<f32>(dot(tm0, tm0), dot(tm0, tm1), dot(tm1, tm1));
    if (!(finite(x_raw.x) && finite(x_raw.y) && finite(x_raw.z))) {
        cull(i, 2u);
        return;
    }
    let det_raw = x_raw.x * x_raw.z - x_raw.y * x_raw.y;
    let p = x_raw.x + EPS2D;
    let r = x_raw.z + EPS2D;
    let det_blur = p * r - x_raw.y * x_raw.y;
    if (!(det_blur > 0.0)) {
        cull(i, 1u);
        return;
    }
    let inv_det = 1.0 / det_blur;
    let conic = vec3<f32>(r * inv_det, -x_raw.y * inv_det, p * inv_det);
    var opacity = 1.0 / (1.0 + exp(-logit));
    if (cam.counts.w != 0u) {
        opacity = opacity * sqrt(max(det_raw * inv_det, MIN_COMPENSATION_RATIO));
    }
    if (!(opacity >= ALPHA_THRESHOLD)) {
        cull(i, 1u);
        return;
    }
    let extend = min(sqrt(log(opacity / ALPHA_THRESHOLD) * 2.0), MAX_EXTEND);
    let rx = ceil(extend * sqrt(p));
    let ry = ceil(extend * sqrt(r));
    if (rx <= 0.0 && ry <= 0.0) {
        cull(i, 1u);
        return;
    }
    let m = vec2<f32>(pc.x * fx / pc.z + cam.focal.z, pc.y * fy / pc.z + cam.focal.w);
    if (!(finite(m.x) && finite(m.y))) {
        cull(i, 2u);
        return;
    }
    let wd = f32(cam.size.x);
    let ht = f32(cam.size.y);
    if (m.x + rx <= 0.0 || m.x - rx >= wd || m.y + ry <= 0.0 || m.y - ry >= ht) {
        cull(i, 1u);
        return;
    }
    // Tiles [x0, x1) × [y0, y1): floor / ceil of the box edges in tile units, clamped.
    let tx = m.x / TILE;
    let ty = m.y / TILE;
    let x0 = u32(clamp(floor(tx - rx / TILE), 0.0, f32(cam.size.z)));
    let x1 = u32(clamp(ceil(tx + rx / TILE), 0.0, f32(cam.size.z)));
    let y0 = u32(clamp(floor(ty - ry / TILE), 0.0, f32(cam.size.w)));
    let y1 = u32(clamp(ceil(ty + ry / TILE), 0.0, f32(cam.size.w)));
    if (x1 <= x0 || y1 <= y0) {
        cull(i, 1u);
        return;
    }
    let vdir = mu - cam.centre.xyz;
    let vlen = length(vdir);
    var dir = vec3<f32>(0.0, 0.0, 1.0);
    if (vlen > 0.0) {
        dir = vdir / vlen;
    }
    let rgb = color(i, dir);
    let o = i * SPLAT_STRIDE;
    splats[o] = m.x;
    splats[o + 1u] = m.y;
    splats[o + 2u] = conic.x;
    splats[o + 3u] = conic.y;
    splats[o + 4u] = conic.z;
    splats[o + 5u] = opacity;
    splats[o + 6u] = rgb.x;
    splats[o + 7u] = rgb.y;
    splats[o + 8u] = rgb.z;
    splats[o + 9u] = pc.z;
    splats[o + 10u] = 0.0;
    splats[o + 11u] = 0.0;
    rects[i] = vec4<u32>(x0 | (x1 << 16u), y0 | (y1 << 16u), (x1 - x0) * (y1 - y0), 0u);
    keys[i] = bitcast<u32>(pc.z);
}
