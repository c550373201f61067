//! Per-thread slots: each slot owns one mailbox (CGT paper section 2.3: a
//! stamp per triangle and a packet counter), its scratch bytes (packets,
//! traversal state: `mem::scratch`) and a claim flag, so threads that
//! share a built context (`&Context`, or a `const sheaf_context *` in C) can
//! each trace with their own mailbox without locks.
//!
//! A slot is claimed with an atomic compare-and-swap and released when its
//! [`SlotGuard`] drops, so two threads asking for the same slot get
//! [`Error::SlotBusy`] instead of sharing stamps. With `&mut Slots` (the
//! context's exclusive calls) every slot is handed out at once, no flags.

use core::marker::PhantomData;
use core::ptr::NonNull;
use core::sync::atomic::{AtomicU32, Ordering};

use crate::error::{Error, Pool, Result};

// `AtomicU32::from_ptr` needs the u32 pool's alignment to suit the atomic.
const _: () = assert!(core::mem::align_of::<AtomicU32>() == core::mem::align_of::<u32>());

/// The slots' memory, carved from the context's arena: `count` runs of
/// `per_slot` stamps, `count` packet counters, `count` runs of
/// `scratch_per_slot` scratch bytes, `count` scratch marks (the fewest
/// bytes a slot's scratch ever had left) and `count` claim flags.
pub struct Slots<'a> {
    stamps: NonNull<u32>,
    per_slot: usize,
    packets: NonNull<u32>,
    scratch: NonNull<u8>,
    scratch_per_slot: usize,
    low: NonNull<u32>,
    busy: NonNull<u32>,
    count: usize,
    _pools: PhantomData<&'a mut [u32]>,
}

// SAFETY: the pools are plain u32s and bytes owned by this value for 'a. Shared access
// (`&Slots` on several threads) touches only the claim flags, atomically,
// and a slot's stamps, counter, scratch and mark only while its flag is held
// (`claim`), so no two threads ever reach the same non-atomic memory.
unsafe impl Send for Slots<'_> {}
// SAFETY: as for Send.
unsafe impl Sync for Slots<'_> {}

impl<'a> Slots<'a> {
    /// `count` slots carved from `a`, each with `stamps` mailbox stamps
    /// and `scratch` scratch bytes (`context::slot_scratch_bytes`).
    #[deny(clippy::arithmetic_side_effects)]
    pub fn carve(
        a: &mut impl super::Carve<'a>,
        count: usize,
        stamps: usize,
        scratch: usize,
    ) -> Result<Self> {
        let total = |per: usize| per.checked_mul(count).ok_or(super::TOO_BIG);
        let stamps = a.take(total(stamps)?)?;
        let packets = a.take(count)?;
        let scratch = a.take(total(scratch)?)?;
        let low = a.take(count)?;
        let busy = a.take(count)?;
        Ok(Slots::new(stamps, packets, scratch, low, busy))
    }

    /// Slots over `stamps` (`per_slot` stamps per slot, `packets.len()`
    /// slots) and `scratch` (equal runs per slot) with their scratch marks
    /// `low` and claim flags `busy` (one each per slot; all released).
    pub fn new(
        stamps: &'a mut [u32],
        packets: &'a mut [u32],
        scratch: &'a mut [u8],
        low: &'a mut [u32],
        busy: &'a mut [u32],
    ) -> Self {
        let count = packets.len();
        assert_eq!(busy.len(), count, "one claim flag per slot");
        assert_eq!(low.len(), count, "one scratch mark per slot");
        let per_slot = stamps.len().checked_div(count).unwrap_or(0);
        assert_eq!(per_slot * count, stamps.len(), "equal stamp runs per slot");
        let scratch_per_slot = scratch.len().checked_div(count).unwrap_or(0);
        assert_eq!(
            scratch_per_slot * count,
            scratch.len(),
            "equal scratch runs per slot"
        );
        busy.fill(0);
        low.fill(scratch_per_slot.min(u32::MAX as usize) as u32);
        Slots {
            stamps: NonNull::from(stamps).cast(),
            per_slot,
            packets: NonNull::from(packets).cast(),
            scratch: NonNull::from(scratch).cast(),
            scratch_per_slot,
            low: NonNull::from(low).cast(),
            busy: NonNull::from(busy).cast(),
            count,
            _pools: PhantomData,
        }
    }

    /// Number of slots (`Limits::max_threads`).
    pub fn count(&self) -> usize {
        self.count
    }

    /// The most scratch bytes any call has used in any slot (the slots'
    /// high-water mark). `&mut self`: no call holds a slot meanwhile.
    pub fn scratch_high_water(&mut self) -> usize {
        self.all()
            .map(|(_, _, scratch, low)| {
                let low = low.load(Ordering::Relaxed) as usize;
                scratch.len() - low.min(scratch.len())
            })
            .max()
            .unwrap_or(0)
    }

    /// Slot `i`'s stamps, packet counter, scratch and mark, as raw pointers: no reference
    /// is made here, so `&self` hands out nothing mutable. The references
    /// are made by whoever holds exclusive use of the slot (a
    /// [`SlotGuard`] through its `&mut self`, or [`Slots::all`] through
    /// `&mut Slots`), and borrow from that.
    ///
    /// # Safety
    /// `i < count`.
    unsafe fn raw_parts(&self, i: usize) -> RawParts {
        debug_assert!(i < self.count);
        let sc = self.scratch_per_slot;
        // SAFETY: `i < count`, so the runs `[i * per_slot, (i + 1) * per_slot)`
        // of stamps and scratch, counter `i` and mark `i` lie inside the pools borrowed
        // for 'a (offsets in bounds of one allocation); only pointers are
        // formed, nothing is read or written.
        unsafe {
            (
                NonNull::slice_from_raw_parts(self.stamps.add(i * self.per_slot), self.per_slot),
                self.packets.add(i),
                NonNull::slice_from_raw_parts(self.scratch.add(i * sc), sc),
                self.low.add(i),
            )
        }
    }

    /// The claim flag of slot `i < count`.
    fn flag(&self, i: usize) -> &AtomicU32 {
        debug_assert!(i < self.count);
        // SAFETY: in bounds (`i < count`), aligned (const assert above), and
        // the flags are only ever accessed atomically after `new`.
        unsafe { AtomicU32::from_ptr(self.busy.as_ptr().add(i)) }
    }

    /// Claim slot `slot` for the calling thread until the guard drops.
    ///
    /// Errors: `Capacity { pool: Threads }` when `slot >= count`,
    /// `SlotBusy` while another guard holds it.
    pub fn claim(&self, slot: u32) -> Result<SlotGuard<'_, 'a>> {
        let i = slot as usize;
        if i >= self.count {
            return Err(Error::Capacity {
                pool: Pool::Threads,
                needed: u64::from(slot) + 1,
                available: self.count as u64,
            });
        }
        self.flag(i)
            .compare_exchange(0, 1, Ordering::Acquire, Ordering::Relaxed)
            .map_err(|_| Error::SlotBusy { slot })?;
        super::hg::acquired(self.flag(i).as_ptr() as usize);
        Ok(SlotGuard { slots: self, i })
    }

    /// Every slot's stamps, counter, scratch and mark at once (exclusive access:
    /// no guard can be alive while `self` is mutably borrowed).
    pub fn all(&mut self) -> impl Iterator<Item = SlotParts<'_>> + '_ {
        let this = &*self;
        (0..self.count).map(move |i| {
            // SAFETY: `i < count`, so the pointers are in bounds and valid
            // for 'a; each slot is yielded once, so the references never
            // alias one another, and the `&mut self` borrow, held by the
            // iterator, rules out guards and other callers for as long as
            // the references live. The mark is a u32 aligned for the atomic
            // (const assert above), only ever accessed atomically after `new`.
            unsafe {
                let (stamps, packet, scratch, low) = this.raw_parts(i);
                (
                    &mut *stamps.as_ptr(),
                    &mut *packet.as_ptr(),
                    &mut *scratch.as_ptr(),
                    AtomicU32::from_ptr(low.as_ptr()),
                )
            }
        })
    }

    /// Claim the highest free slot (for calls without a slot argument:
    /// callers naming slots usually start at 0).
    ///
    /// Errors: `Capacity { pool: Threads }` while every slot is claimed.
    pub fn claim_free(&self) -> Result<SlotGuard<'_, 'a>> {
        (0..self.count as u32)
            .rev()
            .find_map(|s| self.claim(s).ok())
            .ok_or(Error::Capacity {
                pool: Pool::Threads,
                needed: self.count as u64 + 1,
                available: self.count as u64,
            })
    }
}

/// `SlotParts` as pointers.
type RawParts = (NonNull<[u32]>, NonNull<u32>, NonNull<[u8]>, NonNull<u32>);

/// A slot's stamps, packet counter, scratch bytes and scratch mark (the
/// fewest scratch bytes ever left: `mem::Scratch::tracked`).
pub type SlotParts<'s> = (&'s mut [u32], &'s mut u32, &'s mut [u8], &'s AtomicU32);

/// A claimed slot; released on drop.
pub struct SlotGuard<'s, 'a> {
    slots: &'s Slots<'a>,
    i: usize,
}

impl SlotGuard<'_, '_> {
    /// The slot's stamps, packet counter, scratch and scratch mark.
    pub fn parts(&mut self) -> SlotParts<'_> {
        // SAFETY: `i < count` (checked in `claim`), so the pointers are in
        // bounds and valid for 'a; this guard holds the slot's flag, so no
        // other thread or guard uses the slot; the references borrow from
        // `&mut self`, so a second call cannot overlap them and they end
        // before the guard drops and releases the flag. The mark is a u32
        // aligned for the atomic, only ever accessed atomically after `new`.
        unsafe {
            let (stamps, packet, scratch, low) = self.slots.raw_parts(self.i);
            (
                &mut *stamps.as_ptr(),
                &mut *packet.as_ptr(),
                &mut *scratch.as_ptr(),
                AtomicU32::from_ptr(low.as_ptr()),
            )
        }
    }
}

impl Drop for SlotGuard<'_, '_> {
    fn drop(&mut self) {
        let flag = self.slots.flag(self.i);
        super::hg::released(flag.as_ptr() as usize);
        // A locked swap, not a plain store: see `mem::hg`.
        flag.swap(0, Ordering::Release);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_slot_is_claimed_once_at_a_time() {
        let (mut st, mut pk, mut busy) = ([0u32; 6], [0u32; 3], [7u32; 3]);
        let mut sc = [0u8; 3 * 8];
        let mut low = [0u32; 3];
        let slots = Slots::new(&mut st, &mut pk, &mut sc, &mut low, &mut busy);
        let mut a = slots.claim(1).unwrap();
        assert_eq!(slots.claim(1).err(), Some(Error::SlotBusy { slot: 1 }));
        let mut b = slots.claim(2).unwrap();
        a.parts().0.fill(5);
        *b.parts().1 = 9;
        b.parts().2.fill(4);
        assert_eq!(slots.claim_free().map(|g| g.i).ok(), Some(0));
        let c = slots.claim(0).unwrap();
        assert!(slots.claim_free().is_err());
        drop(c);
        drop(a);
        assert!(slots.claim(1).is_ok());
        assert!(matches!(
            slots.claim(3),
            Err(Error::Capacity {
                pool: Pool::Threads,
                ..
            })
        ));
        drop(b);
        assert_eq!(st, [0, 0, 5, 5, 0, 0]);
        assert_eq!(pk, [0, 0, 9]);
        assert!(sc[..16].iter().all(|&b| b == 0) && sc[16..].iter().all(|&b| b == 4));
    }

    #[cfg(feature = "std")]
    #[test]
    fn threads_with_their_own_slots_do_not_interfere() {
        let (mut st, mut pk, mut busy) = ([0u32; 4 * 64], [0u32; 4], [0u32; 4]);
        let mut low = [0u32; 4];
        let slots = Slots::new(&mut st, &mut pk, &mut [], &mut low, &mut busy);
        std::thread::scope(|s| {
            for t in 0..4u32 {
                let slots = &slots;
                s.spawn(move || {
                    for round in 0..200u32 {
                        let mut g = slots.claim(t).unwrap();
                        let (stamps, packet, _, _) = g.parts();
                        stamps.fill(t * 1000 + round);
                        *packet = round;
                        assert!(stamps.iter().all(|&v| v == t * 1000 + round));
                    }
                });
            }
        });
        for (t, run) in st.chunks(64).enumerate() {
            assert!(run.iter().all(|&v| v == t as u32 * 1000 + 199));
        }
    }

    #[test]
    fn no_slots() {
        let slots = Slots::new(&mut [], &mut [], &mut [], &mut [], &mut []);
        assert_eq!(slots.count(), 0);
        assert!(slots.claim(0).is_err());
    }
}
