//! The per-thread mailbox (CGT paper section 2.3): a packet tests each
//! triangle once even when it meets it in several cells. Shared by the
//! uniform grid's CGT and the perspective and light grids (whose
//! triangles span several depth slices).
#![forbid(unsafe_code)]

/// Per-thread mailbox: one stamp per stored triangle and the number of the
/// current packet. A triangle stamped with the packet's number has already
/// been tested against it.
///
/// Stamps and counter belong together and persist across calls and builds
/// (a context keeps one pair per thread slot): packet numbers only grow, so
/// stamps from earlier packets or frames never match. Start a pair with
/// zeroed stamps and a zero counter.
pub struct Mailbox<'m> {
    stamps: &'m mut [u32],
    packet: &'m mut u32,
}

impl<'m> Mailbox<'m> {
    pub fn new(stamps: &'m mut [u32], packet: &'m mut u32) -> Self {
        Mailbox { stamps, packet }
    }
    /// The same mailbox, borrowed for a shorter time.
    #[inline]
    pub fn reborrow(&mut self) -> Mailbox<'_> {
        Mailbox {
            stamps: self.stamps,
            packet: self.packet,
        }
    }
    /// Whether there is a stamp for every one of `n` triangles (a context
    /// without grid or perspective grid pools has empty mailboxes).
    #[inline]
    pub fn covers(&self, n: usize) -> bool {
        n <= self.stamps.len()
    }
    /// Start a new packet over `n` triangles.
    #[inline]
    pub fn next_packet(&mut self, n: usize) {
        *self.packet = self.packet.wrapping_add(1);
        if *self.packet == 0 {
            // Every 2^32 packets: forget all stamps once.
            self.stamps.fill(0);
            *self.packet = 1;
        }
        debug_assert!(n <= self.stamps.len());
    }
    /// True the first time `tri` is seen in this packet.
    #[inline(always)]
    pub fn first_visit(&mut self, tri: usize) -> bool {
        let s = &mut self.stamps[tri];
        let first = *s != *self.packet;
        *s = *self.packet;
        first
    }
}
