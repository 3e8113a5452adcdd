//! Buffers of the hot paths: uninitialised slots for records written sparsely, and buffers
//! filled in parallel (a serial `vec![0.0; n]` of a multi-megabyte gradient is a memset
//! that leaves the other threads idle).

use rayon::prelude::*;
use std::mem::MaybeUninit;

/// Elements per parallel task of [`filled_par`] (fixed, so the work split never depends on
/// the thread count; the result does not either).
const FILL_CHUNK: usize = 1 << 14;

/// A vector of `n` uninitialised slots (no zero-filling of buffers that are written
/// sparsely and read only where written).
pub(crate) fn uninit_vec<T>(n: usize) -> Vec<MaybeUninit<T>> {
    let mut v = Vec::with_capacity(n);
    // SAFETY: `MaybeUninit<T>` needs no initialisation and the capacity is `n`.
    unsafe { v.set_len(n) };
    v
}

/// `vec![value; n]`, written by the rayon pool in fixed chunks when `n` is large.
pub(crate) fn filled_par<T: Copy + Send + Sync>(n: usize, value: T) -> Vec<T> {
    if n < 2 * FILL_CHUNK {
        return vec![value; n];
    }
    let mut v = uninit_vec::<T>(n);
    v.par_chunks_mut(FILL_CHUNK).for_each(|c| {
        for slot in c {
            slot.write(value);
        }
    });
    let mut v = std::mem::ManuallyDrop::new(v);
    // SAFETY: every one of the `n` slots was written above; `MaybeUninit<T>` has the layout
    // of `T`, so the allocation (pointer, length, capacity) is a valid `Vec<T>`.
    unsafe { Vec::from_raw_parts(v.as_mut_ptr() as *mut T, v.len(), v.capacity()) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filled_par_equals_vec_macro_at_every_size_class() {
        for n in [
            0,
            1,
            7,
            FILL_CHUNK,
            2 * FILL_CHUNK - 1,
            2 * FILL_CHUNK,
            5 * FILL_CHUNK + 3,
        ] {
            assert_eq!(filled_par(n, 1.5f32), vec![1.5f32; n], "n = {n}");
            assert_eq!(filled_par(n, [0u32, 7]), vec![[0u32, 7]; n], "n = {n}");
        }
        let b = filled_par(3 * FILL_CHUNK, true);
        assert!(b.iter().all(|&x| x));
    }
}
