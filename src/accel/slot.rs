//! What a thread slot lends one call: its mailbox (CGT section 2.3) and
//! its scratch (`mem::scratch`), where packets, hits, masks, traversal
//! state and bounce levels live instead of on the caller's stack.
//!
//! `SLOT_SCRATCH_BYTES` is the scratch of one slot: the deepest chain of
//! scratch a call can take (a caller's packets, the driver's tiny-lane
//! split, a family's traversal), each part a constant of the module that
//! takes it. `required_bytes` counts it once per slot.
#![forbid(unsafe_code)]

use super::mailbox::Mailbox;
use crate::mem::Scratch;

/// Scratch bytes of one thread slot.
pub const SLOT_SCRATCH_BYTES: usize = (caller_max() + super::packet::SCRATCH + family_max())
    .next_multiple_of(crate::mem::arena::ARENA_ALIGN);

const fn max(a: usize, b: usize) -> usize {
    if a > b { a } else { b }
}

/// The most any caller of the packet driver holds while it runs.
const fn caller_max() -> usize {
    max(
        max(crate::trace::scene::SCRATCH, crate::render::SCRATCH),
        max(
            crate::render::whitted::SCRATCH,
            crate::render::deferred::SCRATCH,
        ),
    )
}

/// The most any family's packet traversal takes.
const fn family_max() -> usize {
    max(
        max(super::bvh::SCRATCH, super::grid::SCRATCH),
        max(super::kd::SCRATCH, super::pgrid::SCRATCH),
    )
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
        let (stamps, packet, scratch) = parts;
        Slot::new(Mailbox::new(stamps, packet), Scratch::new(scratch))
    }

    /// The same slot, borrowed for a shorter time.
    #[inline]
    pub fn reborrow(&mut self) -> Slot<'_> {
        Slot {
            mailbox: self.mailbox.reborrow(),
            scratch: self.scratch.reborrow(),
        }
    }

    /// `n` values of `T`, each `fill`, from the scratch, and the slot with
    /// the rest of it, both borrowed from `self` (`Scratch::split`).
    #[inline]
    pub fn split<T: Copy>(&mut self, n: usize, fill: T) -> (&mut [T], Slot<'_>) {
        self.reborrow().take(n, fill)
    }

    /// `split` for all of `'s` (`Scratch::take`): a function can carve
    /// several arrays and hand them and the rest back to its caller.
    #[inline]
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
    /// CGT packet with the mailbox traces; 0 for none) and a full slot's
    /// scratch.
    pub fn new(stamps: usize) -> SlotBuf {
        SlotBuf {
            stamps: std::vec![0; stamps],
            packet: 0,
            scratch: std::vec![0; SLOT_SCRATCH_BYTES],
        }
    }

    pub fn slot(&mut self) -> Slot<'_> {
        Slot::new(
            Mailbox::new(&mut self.stamps, &mut self.packet),
            Scratch::new(&mut self.scratch),
        )
    }
}
