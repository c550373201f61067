//! What a thread slot lends one call: its mailbox (CGT section 2.3) and
//! its scratch (`mem::scratch`), where packets, hits, masks, traversal
//! state and bounce levels live instead of on the caller's stack.
//!
//! Each module that takes scratch declares its bytes beside its code, as a
//! `const fn` of the packet's quads (`accel::packet::scratch`, each
//! family's `scratch`); the sums live above the families, in the context:
//! `context::accel_scratch` (the tiny-lane split and the largest family
//! traversal) and `context::slot_scratch_bytes` (what the callers hold on
//! top), counted once per slot in `required_bytes`.
#![forbid(unsafe_code)]

use super::mailbox::Mailbox;
use crate::mem::Scratch;

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
    /// CGT packet with the mailbox traces; 0 for none) and `scratch` bytes
    /// of scratch. `SlotBuf::new` (in `context`, where the families'
    /// scratch is summed) sizes it for any family's largest packets.
    pub fn with_scratch(stamps: usize, scratch: usize) -> SlotBuf {
        SlotBuf {
            stamps: std::vec![0; stamps],
            packet: 0,
            scratch: std::vec![0; scratch],
        }
    }

    pub fn slot(&mut self) -> Slot<'_> {
        Slot::new(
            Mailbox::new(&mut self.stamps, &mut self.packet),
            Scratch::new(&mut self.scratch),
        )
    }
}
