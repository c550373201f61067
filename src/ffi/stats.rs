//! `sheaf_stats`: what the last build and the last render produced.

use crate::context::Stats;
use crate::trace::Counters;

/// Statistics of a context: the last successful grid and BVH builds and the last
/// render (`sheaf_context_stats`). All zero before the first build.
///
/// `sheaf_context_trace` and `sheaf_context_occluded` do not update the
/// counters (they may run concurrently); `counters` and `trace_ns` describe
/// the last `sheaf_context_render`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sheaf_stats {
    /// Triangles in the scene of the last build.
    pub triangles_in: u32,
    /// Triangles stored in the grid (the others were excluded).
    pub triangles: u32,
    /// Triangles left out because a vertex has a NaN or infinite coordinate.
    pub excluded_non_finite: u32,
    /// Triangles left out because they have zero area.
    pub excluded_zero_area: u32,
    /// Grid cells per axis.
    pub grid_res: [u32; 3],
    /// Triangle references stored in grid cells.
    pub grid_refs: u32,
    /// Grid cells in total (product of `grid_res`).
    pub grid_cells: u64,
    /// Macrocell side in cells (1: no macrocells).
    pub macrocell: u32,
    /// Macrocells per axis.
    pub macro_res: [u32; 3],
    /// Cells per triangle actually used (lower than asked only in fit mode).
    pub lambda: f32,
    /// Triangle test of the grid (a `sheaf_tri_test`).
    pub test: super::raw::sheaf_tri_test,
    /// Wall time of the last build in nanoseconds.
    pub build_ns: u64,
    /// Counters of the last render.
    pub counters: Counters,
    /// Wall time of the last render in nanoseconds.
    pub trace_ns: u64,
    /// BVH of the last BVH build: nodes, leaves, deepest leaf, stored triangles.
    pub bvh_nodes: u32,
    pub bvh_leaves: u32,
    pub bvh_depth: u32,
    pub bvh_triangles: u32,
    /// SAH cost of that BVH.
    pub bvh_sah_cost: f32,
    /// Triangle test of the BVH (a `sheaf_tri_test`).
    pub bvh_test: super::raw::sheaf_tri_test,
    /// Wall time of the last BVH build in nanoseconds.
    pub bvh_build_ns: u64,
    /// kd-tree of the last kd build (the AEPSA paper's Table 1): nodes,
    /// leaves, empty leaves, deepest leaf, stored triangles, leaf references.
    pub kd_nodes: u32,
    pub kd_leaves: u32,
    pub kd_empty_leaves: u32,
    pub kd_depth: u32,
    pub kd_triangles: u32,
    pub kd_refs: u32,
    /// Mean depth of the kd-tree's leaves.
    pub kd_avg_leaf_depth: f32,
    /// Triangle test of the kd-tree (a `sheaf_tri_test`).
    pub kd_test: super::raw::sheaf_tri_test,
    /// Wall time of the last kd build in nanoseconds.
    pub kd_build_ns: u64,
}

impl sheaf_stats {
    pub fn of(s: &Stats) -> sheaf_stats {
        let g = &s.grid;
        sheaf_stats {
            triangles_in: g.triangles_in,
            triangles: g.triangles,
            excluded_non_finite: g.excluded_non_finite,
            excluded_zero_area: g.excluded_zero_area,
            grid_res: g.res,
            grid_refs: g.refs,
            grid_cells: g.cells(),
            macrocell: g.macrocell,
            macro_res: g.macro_res,
            lambda: g.lambda,
            test: super::sheaf_tri_test::of(g.test) as u32,
            build_ns: s.build_ns,
            counters: s.counters,
            trace_ns: s.trace_ns,
            bvh_nodes: s.bvh.nodes,
            bvh_leaves: s.bvh.leaves,
            bvh_depth: s.bvh.depth,
            bvh_triangles: s.bvh.triangles,
            bvh_sah_cost: s.bvh.sah_cost,
            bvh_test: super::sheaf_tri_test::of(s.bvh.test) as u32,
            bvh_build_ns: s.bvh_build_ns,
            kd_nodes: s.kd.nodes,
            kd_leaves: s.kd.leaves,
            kd_empty_leaves: s.kd.empty_leaves,
            kd_depth: s.kd.depth,
            kd_triangles: s.kd.triangles,
            kd_refs: s.kd.refs,
            kd_avg_leaf_depth: s.kd.avg_leaf_depth,
            kd_test: super::sheaf_tri_test::of(s.kd.test) as u32,
            kd_build_ns: s.kd_build_ns,
        }
    }
}

// No padding anywhere (C sees the same offsets on every ABI): all fields
// before `build_ns` fill 64 bytes, and `sheaf_counters` is all u64.
const _: () = {
    use core::mem::{offset_of, size_of};
    assert!(offset_of!(sheaf_stats, build_ns) == 64);
    assert!(size_of::<Counters>() % 8 == 0);
    assert!(offset_of!(sheaf_stats, bvh_nodes) == offset_of!(sheaf_stats, trace_ns) + 8);
    assert!(offset_of!(sheaf_stats, kd_nodes) == offset_of!(sheaf_stats, bvh_build_ns) + 8);
    assert!(size_of::<sheaf_stats>() == offset_of!(sheaf_stats, kd_build_ns) + 8);
};
