// The table gradient in 64-bit fixed point (appended to `hashgrid.wgsl`, whose helpers it
// uses): order-free, so deterministic with atomics. Per level:
//
// level_max: the largest |d_out| of the level's rows (atomicMax on the bits of a non-negative
//   f32, which order as the values do; non-finite values are left out and set the level's flag).
// scatter_fixed: each term w · d, scaled by 2^s and rounded to an integer, is added to its
//   entry's 64-bit accumulator as two u32 words with atomicAdd, the low word's carry added to
//   the high word: integer addition modulo 2^64 does not depend on the order. s is chosen from
//   the level's largest |d| so that no accumulator can overflow: an entry's sum is at most
//   Σ_i |d_i| ≤ n · max |d| (the eight weights of a point add up to 1), and
//   n · 2^(e+1) · 2^s ≤ 2^62 for max |d| < 2^(e+1).
// fixed_to_float: grad += the accumulator × 2^-s.

@group(0) @binding(12) var<storage, read_write> fixed: array<atomic<u32>>; // 2 per table float
@group(0) @binding(13) var<storage, read_write> level_max: array<atomic<u32>>; // per level: max bits, flag

fn ceil_log2(x: u32) -> i32 {
    if (x <= 1u) {
        return 0;
    }
    return i32(32u - countLeadingZeros(x - 1u));
}

// The level's scale exponent s (see the notes above).
fn scale_exponent() -> i32 {
    let bits = atomicLoad(&level_max[2u * p.level]);
    let e = i32((bits >> 23u) & 0xffu) - 127;
    return 62 - ceil_log2(p.n) - (e + 1);
}

@compute @workgroup_size(256)
fn level_max_abs(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_id) lid: vec3<u32>) {
    let i = index(wid, nwg, lid);
    if (i >= p.n) {
        return;
    }
    for (var k = 0u; k < p.features; k++) {
        let a = abs(d_out[(p.row + k) * p.ld + i]);
        if (is_finite(a)) {
            atomicMax(&level_max[2u * p.level], bitcast<u32>(a));
        } else {
            atomicMax(&level_max[2u * p.level + 1u], 1u);
        }
    }
}

// Adds round(v) (|v| < 2^62, an integer-valued f32 after rounding) to the accumulator at j.
fn add_fixed(j: u32, v: f32) {
    let q = round(v);
    var hi: i32;
    var lo: u32;
    if (abs(q) < 2147483648.0) {
        let s = i32(q);
        lo = bitcast<u32>(s);
        hi = select(0, -1, s < 0);
    } else {
        // q is a multiple of 256 here: both parts are exact.
        hi = i32(floor(q / 4294967296.0));
        lo = u32(q - f32(hi) * 4294967296.0);
    }
    let old = atomicAdd(&fixed[2u * j], lo);
    let carry = select(0u, 1u, old + lo < old);
    atomicAdd(&fixed[2u * j + 1u], bitcast<u32>(hi) + carry);
}

@compute @workgroup_size(256)
fn scatter_fixed(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_id) lid: vec3<u32>) {
    let i = index(wid, nwg, lid);
    if (i >= p.n) {
        return;
    }
    let s = scale_exponent();
    let cell = cell_of(i);
    for (var c = 0u; c < 8u; c++) {
        let g = p.table_off + corner_entry(cell, c) * p.features;
        let w = corner_weight(cell, c);
        for (var k = 0u; k < p.features; k++) {
            let d = d_out[(p.row + k) * p.ld + i];
            if (is_finite(d)) {
                add_fixed(g + k, ldexp(w * d, s));
            }
        }
    }
}

@compute @workgroup_size(256)
fn fixed_to_float(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                  @builtin(local_invocation_id) lid: vec3<u32>) {
    let t = index(wid, nwg, lid);
    if (t >= p.size * p.features) {
        return;
    }
    let j = p.table_off + t;
    var lo = atomicLoad(&fixed[2u * j]);
    var hi = atomicLoad(&fixed[2u * j + 1u]);
    if (lo == 0u && hi == 0u) {
        return;
    }
    // The magnitude of the two's-complement value, then its sign.
    let negative = (hi & 0x80000000u) != 0u;
    if (negative) {
        lo = ~lo + 1u;
        hi = ~hi + select(0u, 1u, lo == 0u);
    }
    var v = f32(hi) * 4294967296.0 + f32(lo);
    if (negative) {
        v = -v;
    }
    grad[j] = grad[j] + ldexp(v, -scale_exponent());
}
