// The table gradient with float atomics, for measuring what the deterministic sum of
// `hashgrid.wgsl` costs (built only with the `determinism-cost` feature; appended to
// `hashgrid.wgsl`, whose helpers it uses): each (point, corner, feature) adds its term straight
// into the entry with a compare-exchange loop, in whatever order the invocations run.

@group(0) @binding(12) var<storage, read_write> grad_bits: array<atomic<u32>>;

// grad[j] += v, atomically: retry until no other invocation changed the word in between.
fn add_atomic(j: u32, v: f32) {
    var old = atomicLoad(&grad_bits[j]);
    loop {
        let r = atomicCompareExchangeWeak(&grad_bits[j], old, bitcast<u32>(bitcast<f32>(old) + v));
        if (r.exchanged) {
            break;
        }
        old = r.old_value;
    }
}

@compute @workgroup_size(256)
fn scatter_atomic(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                  @builtin(local_invocation_id) lid: vec3<u32>) {
    let i = index(wid, nwg, lid);
    if (i >= p.n) {
        return;
    }
    let cell = cell_of(i);
    for (var c = 0u; c < 8u; c++) {
        let g = p.table_off + corner_entry(cell, c) * p.features;
        let w = corner_weight(cell, c);
        for (var k = 0u; k < p.features; k++) {
            add_atomic(g + k, w * d_out[(p.row + k) * p.ld + i]);
        }
    }
}
