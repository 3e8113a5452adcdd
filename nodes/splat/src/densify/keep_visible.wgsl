// The `KeepVisible` opacity reset on the GPU, in f32: the twin of `peak_alpha_ratios` and
// `reset_opacities_keep_visible` (densify/mod.rs). The host records the projection
// (`project.wgsl`) of every Gaussian with unit opacity (logit 16.6) from each training view,
// then `peak_ratio` keeps each Gaussian's largest alpha per unit opacity at the pixel centre
// nearest its projected centre; `keep_visible` lowers each opacity to no less than the one at
// which that pixel keeps `keep_alpha`. A maximum does not depend on the order of the views,
// and each invocation owns its Gaussian: the result is the same run to run. (`SPLAT_STRIDE`
// and `finite` come from the prelude.)

struct KeepConst {
    // Gaussians (of this dispatch's chunk); the view's size.
    n: u32,
    width: u32,
    height: u32,
    // The reset's opacity (`2 · prune_opacity`), the alpha kept at the peak pixel and the
    // highest opacity kept.
    value: f32,
    keep_alpha: f32,
    max_opacity: f32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> kc: KeepConst;
@group(0) @binding(1) var<storage, read> splats: array<f32>;       // SPLAT_STRIDE per Gaussian
@group(0) @binding(2) var<storage, read> rects: array<vec4<u32>>;  // w: 0 visible
@group(0) @binding(3) var<storage, read_write> ratios: array<f32>;  // starts at 0
@group(0) @binding(4) var<storage, read_write> logits: array<f32>;

fn item(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * 256u;
}

// One view: each visible Gaussian's alpha per unit opacity at the pixel centre nearest its
// projected centre (the compensation times the falloff), kept when larger.
@compute @workgroup_size(256)
fn peak_ratio(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = item(gid, nwg);
    if (i >= kc.n || rects[i].w != 0u) {
        return;
    }
    let o = i * SPLAT_STRIDE;
    let m = vec2<f32>(splats[o], splats[o + 1u]);
    let px = clamp(floor(m.x), 0.0, f32(kc.width) - 1.0) + 0.5;
    let py = clamp(floor(m.y), 0.0, f32(kc.height) - 1.0) + 0.5;
    let dx = m.x - px;
    let dy = m.y - py;
    let power = 0.5 * (splats[o + 2u] * dx * dx + splats[o + 4u] * dy * dy) + splats[o + 3u] * dx * dy;
    let ratio = splats[o + 5u] * exp(-max(power, 0.0));
    if (finite(ratio) && ratio > ratios[i]) {
        ratios[i] = ratio;
    }
}

// Every logit to at most `logit(max(value, floor))`, the floor `min(keep_alpha / ratio,
// max_opacity)`, or 0 where even `max_opacity` leaves the peak pixel under the rasteriser's
// cutoff (`keep_visible_floor`); a NaN becomes the cap, as `f32::min`.
@compute @workgroup_size(256)
fn keep_visible(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = item(gid, nwg);
    if (i >= kc.n) {
        return;
    }
    let r = ratios[i];
    var floor_opacity = 0.0;
    if (kc.max_opacity * r >= ALPHA_THRESHOLD) {
        floor_opacity = min(kc.keep_alpha / r, kc.max_opacity);
    }
    let p = max(kc.value, floor_opacity);
    let cap = log(p / (1.0 - p));
    let l = logits[i];
    if ((bitcast<u32>(l) & 0x7fffffffu) > 0x7f800000u || l > cap) {
        logits[i] = cap;
    }
}
