//! Tracing front end: which method traces which rays, and the counters every
//! method fills. Structures know nothing of each other; this layer picks one.
#![forbid(unsafe_code)]

use bytemuck::{Pod, Zeroable};

/// Counters of one trace or render call (C: `sheaf_counters`). Each thread
/// fills its own and the caller adds them up.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct Counters {
    /// Rays traced (primary, shadow, any kind).
    pub rays: u64,
    /// Grid cells whose triangles were tested.
    pub cells: u64,
    /// Empty macrocells skipped.
    pub macro_skips: u64,
    /// Ray-triangle tests (one per ray, or per lane of a packet test).
    pub tri_tests: u64,
    /// Packets traced (packet methods).
    pub packets: u64,
    /// Packet lanes traced singly because they do not move along the
    /// packet's major axis like its first ray (CGT section 2.2).
    pub stray_lanes: u64,
    /// Triangles skipped because the packet had already tested them (mailbox).
    pub mailbox_skips: u64,
    /// Triangles rejected by frustum culling for a whole packet.
    pub culled: u64,
    /// Packets that could not use frustum culling (no common origin).
    pub packets_no_cull: u64,
}

impl Counters {
    pub fn add(&mut self, o: &Counters) {
        self.rays += o.rays;
        self.cells += o.cells;
        self.macro_skips += o.macro_skips;
        self.tri_tests += o.tri_tests;
        self.packets += o.packets;
        self.stray_lanes += o.stray_lanes;
        self.mailbox_skips += o.mailbox_skips;
        self.culled += o.culled;
        self.packets_no_cull += o.packets_no_cull;
    }
}

/// Traversal method (C: `sheaf_method`). Codes are stable; later methods get
/// new numbers.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Method {
    /// Uniform grid, single-ray 3DDDA with macrocell skipping (the baseline).
    #[default]
    GridDda = 0,
}

impl Method {
    pub const ALL: &'static [Method] = &[Method::GridDda];
    pub fn name(self) -> &'static str {
        match self {
            Method::GridDda => "grid-dda",
        }
    }
    pub fn from_name(s: &str) -> Option<Method> {
        Method::ALL.iter().copied().find(|m| m.name() == s)
    }
}
