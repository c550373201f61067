//! Counters every traversal fills: the bottom layer (nothing here imports
//! from above). `count!` compiles a hot-loop update out without the
//! `counters` feature.
#![forbid(unsafe_code)]

use bytemuck::{Pod, Zeroable};

/// A hot-loop counter update (`count!(ctr.cells += 1)`), compiled out
/// without the `counters` feature: the cheap switch of CGT's statistics.
macro_rules! count {
    ($($t:tt)*) => {
        #[cfg(feature = "counters")]
        {
            $($t)*;
        }
    };
}
pub(crate) use count;

/// Counters of one trace or render call (C: `sheaf_counters`). Each thread
/// fills its own and the caller adds them up. Only `rays`, `packets`,
/// `stray_lanes`, `packets_no_cull`, `packets_split` and the entry-search
/// counters are kept in every build; the per-cell, per-node and
/// per-triangle ones need the `counters` feature (off by default, on in
/// the CLI) and read 0 without it.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
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
    /// Shadow packets split because their hit points spread too far in depth.
    pub packets_split: u64,
    /// Ray-box tests of BVH traversals and split-plane steps of kd-tree
    /// traversals (one per single ray or per 2x2 SIMD ray at a node).
    pub aabb_tests: u64,
    /// Tree nodes rejected by frustum culling for a whole packet.
    pub culled_nodes: u64,
    /// `aabb_tests` by node depth (root 0; deeper levels add to the last
    /// bin): the histograms of the BVH paper's Figure 6.
    /// (C: `SHEAF_DEPTH_BINS` entries; the literal keeps the header self-contained.)
    pub aabb_by_depth: [u64; 32],
    /// `tri_tests` of tree traversals by leaf depth.
    pub tri_by_depth: [u64; 32],
    /// Entry-point searches run (one per packet with MLRTA or AEPSA).
    pub entry_searches: u64,
    /// Sum of the entry points' depths (root 0); searches that found no
    /// leaf count the tree's average leaf depth, as the AEPSA paper's
    /// section 5 does, rounded down.
    pub entry_depth_sum: u64,
    /// Nodes the searches visited (phase 1 and phase 2).
    pub entry_nodes: u64,
    /// Searches whose frustum overlaps no triangle: the packet is a miss
    /// without traversal.
    pub entry_misses: u64,
}

/// Depth bins of the per-depth counters (C: `SHEAF_DEPTH_BINS`).
pub const DEPTH_BINS: usize = 32;

impl Default for Counters {
    fn default() -> Self {
        Zeroable::zeroed()
    }
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
        self.packets_split += o.packets_split;
        self.aabb_tests += o.aabb_tests;
        self.culled_nodes += o.culled_nodes;
        self.entry_searches += o.entry_searches;
        self.entry_depth_sum += o.entry_depth_sum;
        self.entry_nodes += o.entry_nodes;
        self.entry_misses += o.entry_misses;
        for d in 0..DEPTH_BINS {
            self.aabb_by_depth[d] += o.aabb_by_depth[d];
            self.tri_by_depth[d] += o.tri_by_depth[d];
        }
    }
    /// Record `n` ray-box tests at `depth` (compiled out without `counters`).
    #[inline(always)]
    pub fn aabb_at(&mut self, depth: usize, n: u64) {
        let _ = (depth, n);
        count!(self.aabb_tests += n);
        count!(self.aabb_by_depth[depth.min(DEPTH_BINS - 1)] += n);
    }
    /// Record `n` ray-triangle tests in a leaf at `depth`.
    #[inline(always)]
    pub fn tri_at(&mut self, depth: usize, n: u64) {
        let _ = (depth, n);
        count!(self.tri_tests += n);
        count!(self.tri_by_depth[depth.min(DEPTH_BINS - 1)] += n);
    }
}

/// A clock reading for the wall times in `Stats` (None without `std`: the
/// times read 0).
#[cfg(feature = "std")]
pub(crate) fn now() -> Option<std::time::Instant> {
    Some(std::time::Instant::now())
}
#[cfg(not(feature = "std"))]
pub(crate) fn now() -> Option<()> {
    None
}
/// Nanoseconds since `now()` (0 without `std`).
#[cfg(feature = "std")]
pub(crate) fn elapsed_ns(t: Option<std::time::Instant>) -> u64 {
    t.map_or(0, |t| t.elapsed().as_nanos() as u64)
}
#[cfg(not(feature = "std"))]
pub(crate) fn elapsed_ns(_: Option<()>) -> u64 {
    0
}
