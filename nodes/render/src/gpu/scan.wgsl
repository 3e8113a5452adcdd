// Exclusive prefix sums of u32 values on the GPU, in fixed order (no atomics): each workgroup
// scans a block of 256 values in shared memory and writes its total; the host scans the
// totals the same way (recursively) and `add_sums` adds each block's offset.

struct Params {
    n: u32,
    blocks: u32,
    _a: u32,
    _b: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read_write> sums: array<u32>;

var<workgroup> s: array<u32, 256>;

@compute @workgroup_size(256)
fn scan_blocks(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) li: u32) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * 256u + li;
    var v = 0u;
    if (block < p.blocks && i < p.n) {
        v = data[i];
    }
    s[li] = v;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off = off << 1u) {
        var t = 0u;
        if (li >= off) {
            t = s[li - off];
        }
        workgroupBarrier();
        s[li] = s[li] + t;
        workgroupBarrier();
    }
    if (block < p.blocks) {
        if (i < p.n) {
            data[i] = s[li] - v;
        }
        if (li == 255u) {
            sums[block] = s[255];
        }
    }
}

@compute @workgroup_size(256)
fn add_sums(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) li: u32) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * 256u + li;
    if (block < p.blocks && i < p.n) {
        data[i] = data[i] + sums[block];
    }
}
