//! Radix sort of (key, value) pairs, without `std`: the perspective and
//! light grids' sort (GPU paper, sections 3 and 4.2; the paper uses the GPU
//! SplitSort, any stable key sort gives the same lists) and the Morton
//! order of the BVH's fast build (`accel::bvh::build_morton`).
//!
//! Least significant digit first, 11 bits per pass, only as many passes as
//! the keys have bits (the paper, too, splits on the 18 bits its cell ids
//! need). Stable, so pairs emitted in triangle (or pixel) order stay in
//! that order within a key.

/// Bits per pass.
const DIGIT: u32 = 11;

/// Sort `keys` (all below `2^key_bits`) and `vals` by key, in place, with
/// `tmp_keys` and `tmp_vals` (at least as long) as scratch.
pub fn radix_sort(
    keys: &mut [u32],
    vals: &mut [u32],
    tmp_keys: &mut [u32],
    tmp_vals: &mut [u32],
    key_bits: u32,
) {
    let n = keys.len();
    debug_assert!(vals.len() == n && tmp_keys.len() >= n && tmp_vals.len() >= n);
    let passes = key_bits.div_ceil(DIGIT);
    let (tk, tv) = (&mut tmp_keys[..n], &mut tmp_vals[..n]);
    for p in 0..passes {
        let shift = p * DIGIT;
        if p % 2 == 0 {
            pass(keys, vals, tk, tv, shift);
        } else {
            pass(tk, tv, keys, vals, shift);
        }
    }
    if passes % 2 == 1 {
        keys.copy_from_slice(tk);
        vals.copy_from_slice(tv);
    }
}

/// One counting pass on digit `shift..shift + DIGIT`, from `s*` into `d*`.
fn pass(sk: &[u32], sv: &[u32], dk: &mut [u32], dv: &mut [u32], shift: u32) {
    const MASK: u32 = (1 << DIGIT) - 1;
    let mut count = [0u32; 1 << DIGIT];
    for &k in sk {
        count[((k >> shift) & MASK) as usize] += 1;
    }
    let mut sum = 0;
    for c in count.iter_mut() {
        let x = *c;
        *c = sum;
        sum += x;
    }
    for (&k, &v) in sk.iter().zip(sv) {
        let d = ((k >> shift) & MASK) as usize;
        dk[count[d] as usize] = k;
        dv[count[d] as usize] = v;
        count[d] += 1;
    }
}

/// Bits needed for keys below `n`.
pub fn bits_for(n: u32) -> u32 {
    32 - n.saturating_sub(1).leading_zeros()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sorts_stably_for_every_pass_count() {
        for bits in [1u32, 5, 11, 12, 22, 23, 32] {
            let n = 1000;
            let mut s = 12345u32;
            let mut keys: [u32; 1000] = [0; 1000];
            let mut vals: [u32; 1000] = [0; 1000];
            for i in 0..n {
                s = s.wrapping_mul(1664525).wrapping_add(1013904223);
                keys[i] = if bits == 32 { s } else { s & ((1 << bits) - 1) };
                vals[i] = i as u32;
            }
            let mut want: [(u32, u32); 1000] = [(0, 0); 1000];
            for i in 0..n {
                want[i] = (keys[i], vals[i]);
            }
            want.sort_by_key(|p| p.0); // stable
            let (mut tk, mut tv) = ([0u32; 1000], [0u32; 1000]);
            radix_sort(&mut keys, &mut vals, &mut tk, &mut tv, bits);
            for i in 0..n {
                assert_eq!((keys[i], vals[i]), want[i], "bits {bits} at {i}");
            }
        }
    }

    #[test]
    fn bits_for_counts() {
        assert_eq!(bits_for(0), 0);
        assert_eq!(bits_for(1), 0);
        assert_eq!(bits_for(2), 1);
        assert_eq!(bits_for(2048), 11);
        assert_eq!(bits_for(2049), 12);
    }
}
