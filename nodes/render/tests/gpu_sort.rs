//! The GPU prefix sum and radix sort (wgpu; on CI Mesa's lavapipe) against the host: the scan
//! over one, two and three levels of blocks; the sort of pairs with many equal keys over
//! several blocks, by all 32 key bits and by the low 12, with the values read from a buffer or
//! taken as the indices (whatever the values buffer held before). Skips with a message when
//! no GPU adapter is found (fails under `CI=true`, where `.ci/run` installs lavapipe).

mod gpu_common;
use gpu_common::context;

/// Keys with many repeats (a small generator, fixed seed), some with high bits set.
fn keys(n: usize) -> Vec<u32> {
    let mut state = 0x9e37_79b9_u32;
    (0..n)
        .map(|i| {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            if i % 7 == 0 {
                state | 0xf000_0000
            } else {
                state % 50
            }
        })
        .collect()
}

#[test]
fn the_sort_is_the_hosts_stable_sort_with_values_or_indices() {
    let Some(ctx) = context("the_sort_is_the_hosts_stable_sort_with_values_or_indices") else {
        return;
    };
    let n = 1000;
    let keys = keys(n);
    for bits in [32, 12] {
        let mask = if bits == 32 {
            u32::MAX
        } else {
            (1 << bits) - 1
        };
        let mut want: Vec<(u32, u32)> = keys.iter().zip(0..).map(|(&k, i)| (k, i)).collect();
        want.sort_by_key(|&(k, _)| k & mask);
        let values: Vec<u32> = (0..n as u32).map(|i| i * 3 + 1).collect();
        for indices in [false, true] {
            let keys_buf = ctx.storage_init("keys", &keys).unwrap();
            // Values, or what a reused buffer might hold: the sort of indices never reads it.
            let vals_buf = ctx
                .storage_init(
                    "values",
                    &values.iter().map(|v| v ^ 0xdead).collect::<Vec<_>>(),
                )
                .unwrap();
            let vals_buf = if indices {
                vals_buf
            } else {
                ctx.storage_init("values", &values).unwrap()
            };
            let keys2 = ctx.storage("keys (scratch)", 4 * n as u64).unwrap();
            let vals2 = ctx.storage("values (scratch)", 4 * n as u64).unwrap();
            let mut enc = ctx.encoder();
            let (k, v) = if indices {
                ctx.record_sort_indices(
                    &mut enc,
                    &keys_buf,
                    &vals_buf,
                    (&keys2, &vals2),
                    n as u32,
                    bits,
                )
            } else {
                ctx.record_sort(
                    &mut enc,
                    &keys_buf,
                    &vals_buf,
                    (&keys2, &vals2),
                    n as u32,
                    bits,
                )
            }
            .unwrap();
            let got = ctx.read_after(enc, &[(k, 0, n), (v, 0, n)]).unwrap();
            let want_keys: Vec<u32> = want.iter().map(|&(k, _)| k).collect();
            let want_vals: Vec<u32> = want
                .iter()
                .map(|&(_, i)| if indices { i } else { values[i as usize] })
                .collect();
            assert_eq!(got[0], want_keys, "keys, {bits} bits, indices {indices}");
            assert_eq!(got[1], want_vals, "values, {bits} bits, indices {indices}");
        }
    }
    let mut enc = ctx.encoder();
    let b = ctx.storage("b", 16).unwrap();
    assert!(ctx
        .record_sort_indices(&mut enc, &b, &b, (&b, &b), 4, 0)
        .is_err());
}

/// The prefix sum over one, two and three levels of 256-value blocks (past 65,536 values the
/// block sums are themselves scanned in blocks) equals the host's running sum.
#[test]
fn the_scan_is_the_hosts_running_sum_over_every_level() {
    let Some(ctx) = context("the_scan_is_the_hosts_running_sum_over_every_level") else {
        return;
    };
    for n in [200usize, 65_537, 300_001] {
        let vals: Vec<u32> = (0..n as u32)
            .map(|i| i.wrapping_mul(2_654_435_761) >> 30)
            .collect();
        let buf = ctx.storage_init("data", &vals).unwrap();
        let mut enc = ctx.encoder();
        ctx.record_scan(&mut enc, &buf, n as u32).unwrap();
        let got = ctx.read_after(enc, &[(&buf, 0, n)]).unwrap().remove(0);
        let want: Vec<u32> = vals
            .iter()
            .scan(0u32, |acc, &v| {
                let before = *acc;
                *acc += v;
                Some(before)
            })
            .collect();
        assert_eq!(got, want, "{n} values");
    }
}
