//! Per-call scratch carved from a thread slot's bytes: the packet rays,
//! hits, masks, traversal state and bounce levels that would otherwise
//! live on the caller's stack (tens to hundreds of KiB at 32x32 packets).
//!
//! A [`Scratch`] is a bump region used like a stack: `split` hands out a
//! typed slice from the front and the rest as a new, shorter `Scratch`, both
//! borrowed from the parent, so a callee can only use what its caller left
//! and everything is given back when the borrows end. Nothing is freed and
//! nothing allocates; how many bytes a slot needs follows from the limits
//! (`context::slot_scratch_bytes`), counted in `required_bytes`. A slot's
//! scratch keeps its high-water mark (the fewest bytes ever left after a
//! take), so tests and users can see the bytes a call really used.

use core::mem::{MaybeUninit, align_of, size_of};
use core::sync::atomic::{AtomicU32, Ordering::Relaxed};

/// Bytes `n` values of `T` may take from a [`Scratch`], alignment padding
/// included (for the constants that size a slot's scratch).
pub const fn bytes<T>(n: usize) -> usize {
    n * size_of::<T>() + align_of::<T>() - 1
}

/// Scratch bytes of one thread slot, borrowed for `'a`.
pub struct Scratch<'a> {
    buf: &'a mut [MaybeUninit<u8>],
    /// The fewest bytes left after any take, for a slot's scratch (its
    /// high-water mark is its length less this). Atomic only so that a
    /// slot can move between threads: one thread at a time uses it (the
    /// slot's claim), so plain loads and stores suffice.
    low: Option<&'a AtomicU32>,
}

impl<'a> Scratch<'a> {
    /// Scratch over `buf` (its contents are never read before written).
    pub fn new(buf: &'a mut [u8]) -> Scratch<'a> {
        // SAFETY: `MaybeUninit<u8>` has the layout of `u8`, and every byte
        // pattern is a valid `u8`, so whatever is written through the
        // `MaybeUninit` view (values of any `Copy` type, see `split`) leaves
        // `buf` valid as `u8` for its owner afterwards.
        let buf = unsafe { &mut *(buf as *mut [u8] as *mut [MaybeUninit<u8>]) };
        Scratch { buf, low: None }
    }

    /// Scratch over `buf` that lowers `low` to the fewest bytes ever left
    /// after a take (a thread slot's high-water mark).
    pub fn tracked(buf: &'a mut [u8], low: &'a AtomicU32) -> Scratch<'a> {
        Scratch {
            low: Some(low),
            ..Scratch::new(buf)
        }
    }

    /// No scratch at all (every `split` of more than nothing panics).
    pub fn empty() -> Scratch<'static> {
        Scratch {
            buf: &mut [],
            low: None,
        }
    }

    /// Bytes left.
    pub fn remaining(&self) -> usize {
        self.buf.len()
    }

    /// The same bytes, borrowed for a shorter time.
    #[inline(always)]
    pub fn reborrow(&mut self) -> Scratch<'_> {
        Scratch {
            buf: self.buf,
            low: self.low,
        }
    }

    /// `n` values of `T`, each `fill`, from the front, and the rest, both
    /// borrowed from `self` (`take` on a reborrow).
    #[inline(always)]
    pub fn split<T: Copy>(&mut self, n: usize, fill: T) -> (&mut [T], Scratch<'_>) {
        self.reborrow().take(n, fill)
    }

    /// `n` values of `T`, each `fill`, from the front, and the rest, for
    /// all of `'a` (so a function can hand both back to its caller).
    ///
    /// # Panics
    /// When fewer than `bytes::<T>(n)` bytes are left: the slot constant
    /// does not cover some call path, a sheaf bug (the C ABI reports it as
    /// `SHEAF_STATUS_PANIC`).
    #[inline(always)]
    pub fn take<T: Copy>(self, n: usize, fill: T) -> (&'a mut [T], Scratch<'a>) {
        self.take_copies(n, &fill)
    }

    /// `take` with `fill` read through a reference: for large `T` (pass a
    /// `const`'s address) no copy of it is made on the caller's stack.
    #[inline(always)]
    pub fn take_copies<T: Copy>(self, n: usize, fill: &T) -> (&'a mut [T], Scratch<'a>) {
        self.take_from(n, |_| *fill)
    }

    /// `n` values, value `i` being `value(i)` (each written once: no fill
    /// before the real values), from the front, and the rest.
    ///
    /// # Panics
    /// As `take`.
    // Always inlined, so that `value` is too and runs at the caller's ISA
    // (an AVX-512 kernel's lane operations would be calls in a copy of
    // this function compiled for the baseline).
    #[inline(always)]
    pub fn take_from<T: Copy>(
        self,
        n: usize,
        mut value: impl FnMut(usize) -> T,
    ) -> (&'a mut [T], Scratch<'a>) {
        let pad = self.buf.as_ptr().align_offset(align_of::<T>());
        let need = n
            .checked_mul(size_of::<T>())
            .and_then(|b| b.checked_add(pad));
        let Some(need) = need.filter(|&b| b <= self.buf.len()) else {
            exhausted(
                n.saturating_mul(size_of::<T>()),
                core::any::type_name::<T>(),
                self.buf.len(),
            )
        };
        let (head, rest) = self.buf.split_at_mut(need);
        let p = head[pad..].as_mut_ptr().cast::<T>();
        for i in 0..n {
            // SAFETY: `p` is aligned for T (`align_offset`), and `head[pad..]`
            // holds `n * size_of::<T>()` bytes borrowed exclusively here, so
            // every `p.add(i)`, i < n, is in bounds and writable. T is Copy:
            // overwriting earlier contents drops nothing.
            unsafe { p.add(i).write(value(i)) };
        }
        // SAFETY: the `n` values were all written just above; the slice
        // borrows `head`, exclusively ours for 'a.
        let vals = unsafe { core::slice::from_raw_parts_mut(p, n) };
        if let Some(low) = self.low {
            let left = rest.len().min(u32::MAX as usize) as u32;
            if left < low.load(Relaxed) {
                low.store(left, Relaxed);
            }
        }
        (
            vals,
            Scratch {
                buf: rest,
                low: self.low,
            },
        )
    }
}

/// `take_from`'s panic, out of its inlined body.
#[cold]
#[inline(never)]
fn exhausted(wanted: usize, ty: &str, left: usize) -> ! {
    panic!(
        "slot scratch exhausted: {wanted} bytes of {ty} wanted, {left} left (slot_scratch_bytes misses a call path, or a call exceeds the limits unchecked)"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_are_aligned_disjoint_and_nest() {
        let mut raw = [0u8; 256];
        let mut s = Scratch::new(&mut raw[1..]);
        let (a, mut rest) = s.split(3, 7u8);
        let (b, mut rest) = rest.split(4, 1.5f64);
        assert_eq!(b.as_ptr() as usize % align_of::<f64>(), 0);
        b[3] = 2.0;
        let left = rest.remaining();
        {
            let (c, _) = rest.split(2, [9u32; 2]);
            assert_eq!(c, &[[9, 9]; 2]);
        }
        assert_eq!(rest.remaining(), left);
        assert_eq!(a, &[7, 7, 7]);
        assert_eq!(b, &[1.5, 1.5, 1.5, 2.0]);
        assert!((255 - 3 - 32 - 7..=255 - 3 - 32).contains(&left));
    }

    #[test]
    fn the_mark_keeps_the_deepest_take() {
        let mut raw = [0u64; 32];
        let low = AtomicU32::new(256);
        let mut s = Scratch::tracked(bytemuck::cast_slice_mut(&mut raw), &low);
        {
            let (_, mut rest) = s.split(10, 0u64);
            let _ = rest.split(6, 0u8);
        }
        let _ = s.split(4, 0u8);
        assert_eq!(low.load(Relaxed), 256 - 80 - 6);
    }

    #[test]
    #[should_panic(expected = "slot scratch exhausted")]
    fn running_out_is_a_bug() {
        let mut raw = [0u8; 16];
        let mut s = Scratch::new(&mut raw);
        let _ = s.split(5, 0u32);
    }

    #[test]
    fn the_bound_covers_any_start() {
        for off in 0..16 {
            let mut raw = [0u8; 64];
            let n = (64 - off - bytes::<[u32; 4]>(0)) / 16;
            let mut s = Scratch::new(&mut raw[off..off + bytes::<[u32; 4]>(n)]);
            let (v, _) = s.split(n, [0u32; 4]);
            assert_eq!(v.len(), n);
        }
    }
}
