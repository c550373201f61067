//! Radix sort of (key, value) pairs, without `std`: the perspective and
//! light grids' sort (GPU paper, sections 3 and 4.2; the paper uses the GPU
//! SplitSort, any stable key sort gives the same lists), the shadow rays'
//! sort into light tiles, and the Morton order of the BVH's fast build
//! (`accel::bvh::build_morton`).
//!
//! Least significant digit first, 11 bits per pass, only as many passes as
//! the keys have bits (the paper, too, splits on the 18 bits its cell ids
//! need). Stable, so pairs emitted in triangle (or pixel) order stay in
//! that order within a key. On several workers (a [`Par`]) each pass
//! counts and scatters one share per worker: the counts, summed digit by
//! digit in worker order, give every (worker, digit) its own positions, so
//! the order is the same for any worker count.

use super::par::{MAX_WORKERS, Par, Parts, atomic_u32, share};
use core::ops::Range;
use core::sync::atomic::Ordering;

/// Bits per pass.
pub const DIGIT: u32 = 11;
/// Count entries per worker a pass of [`DIGIT`] bits takes.
pub const BUCKETS: usize = 1 << DIGIT;

/// `par.workers()` even shares of `0..n`.
pub fn even_parts(n: usize, workers: usize) -> [Range<usize>; MAX_WORKERS] {
    core::array::from_fn(|w| {
        if w < workers {
            share(n, w, workers)
        } else {
            n..n
        }
    })
}

/// The scratch of a sort: key and value pools at least as long as the
/// pairs, and the radix counts ([`BUCKETS`] per worker).
pub struct SortScratch<'a> {
    pub tmp_keys: &'a mut [u32],
    pub tmp_vals: &'a mut [u32],
    pub counts: &'a mut [u32],
}

/// Sort (stably, least significant digit first) the pairs at `parts` of
/// `keys` and `vals` (one part per worker of
/// `par`, in order, disjoint) by key into `keys[..total]` and
/// `vals[..total]`, `total` the pairs in all parts (returned), keys below
/// `2^key_bits`, with `tmp_keys`, `tmp_vals` (at least `total` long) and
/// `counts` (`workers * BUCKETS` entries) as scratch. Parts may leave gaps:
/// the first pass gathers them, so several workers can each emit pairs into
/// their own region of one pool and sort them without a compaction.
// The pools, their scratch and the parts are separate borrows of the
// caller's pools (`accel::pgrid::build`, `reorder`), each sort its own.
#[allow(clippy::too_many_arguments)]
pub fn radix_sort_with(
    keys: &mut [u32],
    vals: &mut [u32],
    tmp_keys: &mut [u32],
    tmp_vals: &mut [u32],
    parts: &[Range<usize>],
    key_bits: u32,
    counts: &mut [u32],
    par: &dyn Par,
) -> usize {
    let workers = parts.len();
    assert!(
        workers == par.workers() && counts.len() >= workers * BUCKETS,
        "radix_sort_with: one part per worker and BUCKETS counts each"
    );
    let total: usize = parts.iter().map(|r| r.len()).sum();
    if total == 0 {
        return 0;
    }
    let gathered = parts.first().is_none_or(|r| r.start == 0)
        && parts.windows(2).all(|p| p[0].end == p[1].start);
    let passes = match key_bits.div_ceil(DIGIT) {
        0 if gathered => return total,
        p => p.max(1),
    };
    let even = even_parts(total, workers);
    let (tk, tv) = (&mut tmp_keys[..total], &mut tmp_vals[..total]);
    for p in 0..passes {
        let (shift, src) = (p * DIGIT, if p == 0 { parts } else { &even[..workers] });
        if p % 2 == 0 {
            let (from, to) = (Pairs { keys, vals }, PairsMut { keys: tk, vals: tv });
            radix_pass(from, to, src, shift, DIGIT, counts, par);
        } else {
            let (from, to) = (Pairs { keys: tk, vals: tv }, PairsMut { keys, vals });
            radix_pass(from, to, src, shift, DIGIT, counts, par);
        }
    }
    if passes % 2 == 1 {
        let (ks, vs) = (
            Parts::even(&mut keys[..total], workers),
            Parts::even(&mut vals[..total], workers),
        );
        let (tk, tv) = (&*tk, &*tv);
        par.run(&|w| {
            let (k, v, at) = (ks.get(w), vs.get(w), ks.start(w));
            k.copy_from_slice(&tk[at..at + k.len()]);
            v.copy_from_slice(&tv[at..at + v.len()]);
        });
    }
    total
}

/// Keys and their values side by side: a radix pass's source.
#[derive(Clone, Copy)]
pub struct Pairs<'a> {
    pub keys: &'a [u32],
    pub vals: &'a [u32],
}

/// Keys and their values side by side: a radix pass's destination.
pub struct PairsMut<'a> {
    pub keys: &'a mut [u32],
    pub vals: &'a mut [u32],
}

/// One stable counting pass on digit `shift..shift + digit` from the parts
/// `src` of `from` (one per worker, in order) into `to[..total]`: each worker
/// counts its part, the counts become each worker's first position per
/// digit (digit-major, then worker order: stable), each worker scatters its
/// part. `counts` holds `workers << digit` entries.
pub fn radix_pass(
    from: Pairs<'_>,
    to: PairsMut<'_>,
    src: &[Range<usize>],
    shift: u32,
    digit: u32,
    counts: &mut [u32],
    par: &dyn Par,
) {
    let (sk, sv, dk, dv) = (from.keys, from.vals, to.keys, to.vals);
    let (buckets, workers) = (1usize << digit, src.len());
    let mask = (buckets - 1) as u32;
    let counts = &mut counts[..workers * buckets];
    {
        let cs = Parts::even(&mut *counts, workers);
        par.run(&|w| {
            let c = cs.get(w);
            c.fill(0);
            for &k in &sk[src[w].clone()] {
                c[((k >> shift) & mask) as usize] += 1;
            }
        });
    }
    let mut sum = 0u32;
    for d in 0..buckets {
        for w in 0..workers {
            let x = counts[w * buckets + d];
            counts[w * buckets + d] = sum;
            sum += x;
        }
    }
    // The prefix sums give every (worker, digit) its own positions: each
    // position is stored once.
    let (ks, vs) = (atomic_u32(dk), atomic_u32(dv));
    let cs = Parts::even(counts, workers);
    par.run(&|w| {
        let c = cs.get(w);
        let r = src[w].clone();
        for (&k, &v) in sk[r.clone()].iter().zip(&sv[r]) {
            let d = ((k >> shift) & mask) as usize;
            let at = c[d] as usize;
            ks[at].store(k, Ordering::Relaxed);
            vs[at].store(v, Ordering::Relaxed);
            c[d] += 1;
        }
    });
}

/// Bits needed for keys below `n`.
pub fn bits_for(n: u32) -> u32 {
    32 - n.saturating_sub(1).leading_zeros()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mem::par::Serial;

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
            let mut counts = [0u32; BUCKETS];
            #[allow(clippy::single_range_in_vec_init)]
            let all = [0..n];
            radix_sort_with(
                &mut keys,
                &mut vals,
                &mut tk,
                &mut tv,
                &all,
                bits,
                &mut counts,
                &Serial,
            );
            for i in 0..n {
                assert_eq!((keys[i], vals[i]), want[i], "bits {bits} at {i}");
            }
        }
    }

    #[test]
    fn workers_sort_parts_with_gaps_as_one_thread_sorts_them_gathered() {
        use crate::accel::testkit::Backwards;
        let mut seed = 99u32;
        let mut rnd = || {
            seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
            seed >> 8
        };
        for (bits, workers) in [(0u32, 3usize), (5, 2), (11, 3), (17, 7), (23, 4)] {
            // Worker w's pairs sit at the start of its region of 300 entries.
            let lens: Vec<usize> = (0..workers)
                .map(|w| [0, 1, 250, 300, 17][(w * 3) % 5])
                .collect();
            let mut keys = vec![u32::MAX; 300 * workers];
            let mut vals = vec![u32::MAX; 300 * workers];
            let mut want = Vec::new();
            for (w, &len) in lens.iter().enumerate() {
                for i in 0..len {
                    let k = if bits == 0 {
                        0
                    } else {
                        rnd() & ((1 << bits) - 1)
                    };
                    keys[300 * w + i] = k;
                    vals[300 * w + i] = want.len() as u32;
                    want.push((k, want.len() as u32));
                }
            }
            want.sort_by_key(|p| p.0);
            let parts: Vec<_> = (0..workers).map(|w| 300 * w..300 * w + lens[w]).collect();
            let (mut tk, mut tv) = (vec![0u32; want.len()], vec![0u32; want.len()]);
            let mut counts = vec![0u32; workers * BUCKETS];
            let total = radix_sort_with(
                &mut keys,
                &mut vals,
                &mut tk,
                &mut tv,
                &parts,
                bits,
                &mut counts,
                &Backwards(workers),
            );
            assert_eq!(total, want.len());
            let got: Vec<_> = keys[..total]
                .iter()
                .copied()
                .zip(vals[..total].iter().copied())
                .collect();
            assert_eq!(got, want, "bits {bits}, {workers} workers");
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
