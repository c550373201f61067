//! What a thread slot lends one call: its mailbox (CGT section 2.3) and
//! its scratch (`mem::scratch`), where packets, hits, masks, traversal
//! state and bounce levels live instead of on the caller's stack.
//!
//! `accel_scratch` is what a packet call and a family's traversal take at
//! most (the tiny-lane split, `accel::packet::quieted`, then the family's
//! arrays),
//! each part a function of the packet size declared by the module that
//! takes it. A context's slot adds what its callers (`trace::batch_on`,
//! the renderers) hold on top: `context::slot_scratch_bytes`, counted once
//! per slot in `required_bytes`.
#![forbid(unsafe_code)]

use super::mailbox::Mailbox;
use crate::mem::Scratch;

/// Scratch bytes the tiny-lane split and the packet traversal of any family
/// in `structures` (a `Limits::GRID`-style bit set: the grid, BVH and
/// kd-tree; the perspective grids are traced by the deferred frame alone,
/// which counts them) take at most, for packets of up to `q` quads.
pub const fn accel_scratch(q: usize, structures: u32) -> usize {
    use crate::mem::Limits;
    // A family's bytes when its structure has pools, else none.
    const fn of(structures: u32, bit: u32, bytes: usize) -> usize {
        if structures & bit != 0 { bytes } else { 0 }
    }
    let s = structures;
    let family = max(
        max(
            of(s, Limits::BVH, super::bvh::scratch(q)),
            of(s, Limits::GRID, super::grid::scratch(q)),
        ),
        of(s, Limits::KD, super::kd::scratch(q)),
    );
    super::packet::scratch(q) + family
}

/// The larger of two sizes (const).
pub const fn max(a: usize, b: usize) -> usize {
    if a > b { a } else { b }
}

/// A claimed thread slot's mailbox and scratch, for one call.
pub struct Slot<'s> {
    pub mailbox: Mailbox<'s>,
    pub scratch: Scratch<'s>,
}

impl<'s> Slot<'s> {
    pub fn new(mailbox: Mailbox<'s>, scratch: Scratch<'s>) -> Slot<'s> {
        Slot { mailbox, scratch }
    }

    /// A slot over its parts (`mem::SlotParts`).
    pub fn of(parts: crate::mem::SlotParts<'s>) -> Slot<'s> {
        let (stamps, packet, scratch, low) = parts;
        Slot::new(Mailbox::new(stamps, packet), Scratch::tracked(scratch, low))
    }

    /// The same slot, borrowed for a shorter time.
    #[inline(always)]
    pub fn reborrow(&mut self) -> Slot<'_> {
        Slot {
            mailbox: self.mailbox.reborrow(),
            scratch: self.scratch.reborrow(),
        }
    }

    /// `n` values of `T`, each `fill`, from the scratch, and the slot with
    /// the rest of it, both borrowed from `self` (`Scratch::split`).
    #[inline(always)]
    pub fn split<T: Copy>(&mut self, n: usize, fill: T) -> (&mut [T], Slot<'_>) {
        self.reborrow().take(n, fill)
    }

    /// `split` with value `i` being `value(i)` (`Scratch::take_from`).
    #[inline(always)]
    pub fn split_from<T: Copy>(
        &mut self,
        n: usize,
        value: impl FnMut(usize) -> T,
    ) -> (&mut [T], Slot<'_>) {
        let s = self.reborrow();
        let (vals, scratch) = s.scratch.take_from(n, value);
        (
            vals,
            Slot {
                mailbox: s.mailbox,
                scratch,
            },
        )
    }

    /// `split` for all of `'s` (`Scratch::take`): a function can carve
    /// several arrays and hand them and the rest back to its caller.
    #[inline(always)]
    pub fn take<T: Copy>(self, n: usize, fill: T) -> (&'s mut [T], Slot<'s>) {
        let (vals, scratch) = self.scratch.take(n, fill);
        (
            vals,
            Slot {
                mailbox: self.mailbox,
                scratch,
            },
        )
    }
}

/// A thread slot of its own, outside any context (std): for tools and
/// tests that call the packet traversals directly.
#[cfg(feature = "std")]
pub struct SlotBuf {
    stamps: std::vec::Vec<u32>,
    packet: u32,
    scratch: std::vec::Vec<u8>,
}

#[cfg(feature = "std")]
impl SlotBuf {
    /// A mailbox of `stamps` stamps (one per triangle of the structure a
    /// CGT packet with the mailbox traces; 0 for none) and the scratch of
    /// the tiny-lane split and any family's traversal of the largest packets
    /// (`accel_scratch`).
    pub fn new(stamps: usize) -> SlotBuf {
        let all = crate::mem::Limits::ALL_STRUCTURES;
        SlotBuf {
            stamps: std::vec![0; stamps],
            packet: 0,
            scratch: std::vec![0; accel_scratch(super::packet::MAX_QUADS, all)],
        }
    }

    pub fn slot(&mut self) -> Slot<'_> {
        Slot::new(
            Mailbox::new(&mut self.stamps, &mut self.packet),
            Scratch::new(&mut self.scratch),
        )
    }
}
