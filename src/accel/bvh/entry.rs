//! The BVH as an `EntryTree`, so the entry-point searches (the AEPSA
//! paper's further work, section 8: "the use of AEPSA with bounding volume
//! hierarchies") can start BVH packets below the root. The searches live
//! in `entry::mlrta` and `entry::aepsa`; the trace layer calls
//! them with a `BvhView` (one family never calls another).
//!
//! A BVH node's box is its stored box; every leaf is occupied. Packets of
//! all three large-packet traversals start at an entry point through the
//! `entry` argument of their `intersect`/`occluded`: BVH results do not
//! depend on the visiting order (see `mod.rs`, Exactness), so packets from
//! an entry point whose subtree holds every triangle the frustum overlaps
//! equal the single ray bitwise.
//!
//! # Deviations
//! - `BvhInfo` keeps no average leaf depth: a search that finds no leaf
//!   counts `floor(log2(leaves))` in `entry_depth_sum`, the leaf depth of a
//!   balanced tree with as many leaves.

use super::BvhView;
use crate::accel::entry::EntryTree;
use crate::geom::Aabb;
use crate::geom::frustum::Frustum;

impl EntryTree for BvhView<'_> {
    #[inline]
    fn root(&self) -> Option<(u32, Aabb)> {
        self.nodes.first().map(|n| (0, n.aabb()))
    }
    #[inline]
    fn children(&self, node: u32, _aabb: &Aabb) -> Option<[(u32, Aabb); 2]> {
        let n = &self.nodes[node as usize];
        if n.is_leaf() {
            return None;
        }
        let l = n.first;
        Some([
            (l, self.nodes[l as usize].aabb()),
            (l + 1, self.nodes[l as usize + 1].aabb()),
        ])
    }
    #[inline]
    fn split_axis(&self, node: u32) -> usize {
        self.nodes[node as usize].axis()
    }
    #[inline]
    fn leaf_count(&self, node: u32) -> usize {
        self.nodes[node as usize].count() as usize
    }
    #[inline]
    fn leaf_overlapped(&self, node: u32, f: &Frustum) -> bool {
        let n = &self.nodes[node as usize];
        let first = n.first as usize;
        self.tris[first..first + n.count() as usize]
            .iter()
            .any(|t| !f.cull_triangle_planes(t))
    }
    #[inline]
    fn miss_depth(&self) -> u32 {
        self.info.leaves.max(1).ilog2()
    }
}
