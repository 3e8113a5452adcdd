// Densification on the GPU — the device half of `Densifier::step_post_update` (grow, prune,
// opacity reset) over the training state's buffers. Every test is an integer comparison of
// order keys against boundaries the host computed with the CPU's own expressions
// (`densify/thresholds.rs`), so each Gaussian is decided as on the CPU; the new set is laid
// out by exclusive prefix sums (`scan.wgsl`) in the CPU's order: the survivors of the old set,
// then the surviving clones, then the split children (placed by the host, which draws their
// positions).
//
// Per-Gaussian arrays are read as u32 words: no float is loaded, compared or computed here.

// The integer that orders floats as `<` does; −0 and +0 share a key (`thresholds::ord_key`).
fn ord_key(b_in: u32) -> u32 {
    var b = b_in;
    if (b == 0x80000000u) {
        b = 0u;
    }
    if ((b >> 31u) == 1u) {
        return ~b;
    }
    return b | 0x80000000u;
}

fn is_nan(b: u32) -> bool {
    return (b & 0x7fffffffu) > 0x7f800000u;
}

fn is_finite(b: u32) -> bool {
    return (b & 0x7f800000u) != 0x7f800000u;
}

const KEY_NEG_INF: u32 = 0x007fffffu;
const KEY_POS_INF: u32 = 0xff800000u;

fn flat_index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * 256u;
}

struct DecideConst {
    // Gaussians; entries of the grow table (counts 0..table_len−1).
    n: u32,
    table_len: u32,
    // Grow: a candidate is cloned when its largest log-scale's key is at most `clone_key`,
    // split otherwise.
    clone_key: u32,
    // Prune: an opacity logit whose key is below `logit_key`, or (with `large`) a largest
    // log-scale whose key is above `big_key`.
    logit_key: u32,
    big_key: u32,
    large: u32,
    // Whether this refinement grows at all.
    grow: u32,
    // How many Gaussians the cap still allows (0xffffffff: no cap).
    room: u32,
}

@group(0) @binding(0) var<uniform> dc: DecideConst;
@group(0) @binding(1) var<storage, read> grad2d: array<u32>;
@group(0) @binding(2) var<storage, read> count: array<u32>;
@group(0) @binding(3) var<storage, read> scales: array<u32>;     // 3 per Gaussian
@group(0) @binding(4) var<storage, read> logits: array<u32>;
@group(0) @binding(5) var<storage, read> means: array<u32>;      // 3 per Gaussian
@group(0) @binding(6) var<storage, read> grow_table: array<u32>; // per count: least key that grows
@group(0) @binding(7) var<storage, read_write> clone_rank: array<u32>; // n + 1: 0/1, then scanned
@group(0) @binding(8) var<storage, read_write> split_rank: array<u32>; // n + 1: 0/1, then scanned
@group(0) @binding(9) var<storage, read_write> pruned: array<u32>;
@group(0) @binding(10) var<storage, read_write> overflow: atomic<u32>;

// The key of the largest log-scale, NaNs ignored (−∞ when all are NaN), as `max_log_scale`.
fn max_log_key(i: u32) -> u32 {
    var m = KEY_NEG_INF;
    for (var a = 0u; a < 3u; a++) {
        let b = scales[3u * i + a];
        if (!is_nan(b)) {
            m = max(m, ord_key(b));
        }
    }
    return m;
}

// `PruneRule::prunes` for Gaussian `i` with its largest log-scale key `m`.
fn prunes(i: u32, m: u32) -> bool {
    let o = logits[i];
    if (is_nan(o) || ord_key(o) < dc.logit_key) {
        return true;
    }
    if (m == KEY_NEG_INF || m == KEY_POS_INF) {
        return true;
    }
    for (var a = 0u; a < 3u; a++) {
        if (!is_finite(means[3u * i + a])) {
            return true;
        }
    }
    return dc.large != 0u && m > dc.big_key;
}

@compute @workgroup_size(256)
fn decide(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat_index(gid, nwg);
    if (i >= dc.n) {
        return;
    }
    let m = max_log_key(i);
    pruned[i] = select(0u, 1u, prunes(i, m));
    var grows = false;
    if (dc.grow != 0u) {
        let c = count[i];
        if (c >= dc.table_len) {
            // The host's bound on the counts was wrong: it refuses the result.
            atomicMax(&overflow, 1u);
            return;
        }
        // The CPU skips sums whose average is ≤ the threshold: a NaN sum grows.
        let g = grad2d[i];
        grows = is_nan(g) || ord_key(g) >= grow_table[c];
    }
    clone_rank[i] = select(0u, 1u, grows && m <= dc.clone_key);
    split_rank[i] = select(0u, 1u, grows && m > dc.clone_key);
}

@group(0) @binding(11) var<storage, read> quats: array<u32>;      // 4 per Gaussian
@group(0) @binding(12) var<storage, read_write> keep_old: array<u32>;   // n + 1
@group(0) @binding(13) var<storage, read_write> keep_clone: array<u32>; // n + 1
@group(0) @binding(14) var<storage, read_write> parents: array<u32>;    // 12 per split

// After the candidates were scanned: the cap (clones first, then splits, in index order, as
// the CPU truncates its lists), what survives, and each taken split's parent record (index,
// mean, log-scales, quaternion, opacity logit) at its rank, for the host to draw children.
@compute @workgroup_size(256)
fn take(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat_index(gid, nwg);
    let n = dc.n;
    if (i >= n) {
        return;
    }
    let nc = min(clone_rank[n], dc.room);
    let ns = min(split_rank[n], dc.room - nc);
    let rc = clone_rank[i];
    let rs = split_rank[i];
    let cloned = clone_rank[i + 1u] != rc && rc < nc;
    let split = split_rank[i + 1u] != rs && rs < ns;
    let gone = pruned[i] != 0u;
    keep_old[i] = select(0u, 1u, !split && !gone);
    keep_clone[i] = select(0u, 1u, cloned && !gone);
    if (split) {
        let o = 12u * rs;
        parents[o] = i;
        for (var a = 0u; a < 3u; a++) {
            parents[o + 1u + a] = means[3u * i + a];
            parents[o + 4u + a] = scales[3u * i + a];
        }
        for (var a = 0u; a < 4u; a++) {
            parents[o + 7u + a] = quats[4u * i + a];
        }
        parents[o + 11u] = logits[i];
    }
}

struct CompactConst {
    // Gaussians of the old set, words per Gaussian, survivors of the old set (where the
    // clones start), whether clones copy the values (parameters) or stay zero (moments).
    n: u32,
    width: u32,
    kept_old: u32,
    copy_clones: u32,
}

@group(0) @binding(15) var<uniform> cc: CompactConst;
@group(0) @binding(16) var<storage, read> src: array<u32>;
@group(0) @binding(17) var<storage, read_write> dst: array<u32>;
@group(0) @binding(18) var<storage, read> old_rank: array<u32>;   // keep_old, scanned
@group(0) @binding(19) var<storage, read> clone_pos: array<u32>;  // keep_clone, scanned

// One word of one array of the old set into the new set: survivors at their rank, clones
// after all survivors. One invocation per (Gaussian, word).
@compute @workgroup_size(256)
fn compact(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = flat_index(gid, nwg);
    let i = t / cc.width;
    let q = t % cc.width;
    if (i >= cc.n) {
        return;
    }
    let v = src[t];
    let r = old_rank[i];
    if (old_rank[i + 1u] != r) {
        dst[r * cc.width + q] = v;
    }
    let c = clone_pos[i];
    if (cc.copy_clones != 0u && clone_pos[i + 1u] != c) {
        dst[(cc.kept_old + c) * cc.width + q] = v;
    }
}

struct GatherConst {
    // Rows to gather, words per row, the first destination row.
    rows: u32,
    width: u32,
    base: u32,
    pad: u32,
}

@group(0) @binding(20) var<uniform> gc: GatherConst;
@group(0) @binding(21) var<storage, read> rows_from: array<u32>;

// Row `rows_from[r]` of `src` into row `base + r` of `dst` (the split children's colours).
@compute @workgroup_size(256)
fn gather(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = flat_index(gid, nwg);
    let r = t / gc.width;
    let q = t % gc.width;
    if (r >= gc.rows) {
        return;
    }
    dst[(gc.base + r) * gc.width + q] = src[rows_from[r] * gc.width + q];
}

struct ClampConst {
    n: u32,
    // The cap (`logit(value)` as the host rounds it) and its key.
    cap: u32,
    cap_key: u32,
    pad: u32,
}

@group(0) @binding(22) var<uniform> kc: ClampConst;
@group(0) @binding(23) var<storage, read_write> opacity: array<u32>;

// The opacity reset: every logit to at most the cap (a NaN becomes the cap), as `f32::min`.
@compute @workgroup_size(256)
fn clamp_logits(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat_index(gid, nwg);
    if (i >= kc.n) {
        return;
    }
    let o = opacity[i];
    if (is_nan(o) || ord_key(o) > kc.cap_key) {
        opacity[i] = kc.cap;
    }
}
