//! The kd-tree as an `EntryTree`, so the entry-point searches
//! (`accel::entry`: MLRTA, AEPSA) can start kd packets below the root.

use super::KdView;
use crate::accel::entry::EntryTree;
use crate::geom::Aabb;
use crate::geom::frustum::Frustum;

/// The kd-tree as the searches see it: boxes carved by the splits from
/// `KdInfo::root`; a leaf's triangles are its references.
impl EntryTree for KdView<'_> {
    #[inline]
    fn root(&self) -> Option<(u32, Aabb)> {
        (!self.nodes.is_empty()).then_some((0, self.info.root))
    }
    #[inline]
    fn children(&self, node: u32, aabb: &Aabb) -> Option<[(u32, Aabb); 2]> {
        let n = &self.nodes[node as usize];
        if n.is_leaf() {
            return None;
        }
        let (l, r) = KdView::child_boxes(n, aabb);
        let left = n.left() as u32;
        Some([(left, l), (left + 1, r)])
    }
    #[inline]
    fn split_axis(&self, node: u32) -> usize {
        self.nodes[node as usize].axis()
    }
    #[inline]
    fn leaf_count(&self, node: u32) -> usize {
        self.nodes[node as usize].count()
    }
    #[inline]
    fn leaf_overlapped(&self, node: u32, f: &Frustum) -> bool {
        let n = &self.nodes[node as usize];
        self.leaf_refs(n)
            .iter()
            .any(|&s| !f.cull_triangle_planes(&self.tris[s as usize]))
    }
    #[inline]
    fn miss_depth(&self) -> u32 {
        self.info.avg_leaf_depth as u32
    }
}
