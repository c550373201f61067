//! `sheaf_stats`: what the last build and the last render produced.

use crate::Counters;
use crate::context::Stats;

/// Statistics of a context: the last successful build of each structure,
/// the last render, and the last deferred frame (`sheaf_context_stats`).
/// All zero before the first build.
///
/// `sheaf_context_trace` and `sheaf_context_occluded` do not update the
/// counters (they may run concurrently); `counters` and `trace_ns` describe
/// the last render call of any kind (`sheaf_context_render`,
/// `_render_with`, `_render_whitted`, `_render_deferred`).
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
    /// Triangles loaded by the last `sheaf_context_build_pgrid`, and how
    /// many of them the grids leave out (NaN/infinite vertex or zero area).
    pub pgrid_triangles: u32,
    pub pgrid_excluded: u32,
    /// Triangle test of the perspective and light grids (a `sheaf_tri_test`).
    pub pgrid_test: super::raw::sheaf_tri_test,
    /// The perspective grid of the last deferred frame (zeros when its
    /// camera rays were traced otherwise): sorting tiles per side, depth
    /// slices, cells (tiles x slices), (triangle, cell) pairs, triangles
    /// listed in a cell, triangles left out as back faces.
    pub camera_tiles: [u32; 2],
    pub camera_slices: u32,
    pub camera_cells: u32,
    pub camera_refs: u32,
    pub camera_mapped: u32,
    pub camera_backfaces: u32,
    /// The light grid of the last light of that frame (zeros when its
    /// shadow rays were traced otherwise): light tiles per side, depth
    /// slices, cells, (triangle, cell) pairs, triangles listed in a cell.
    pub light_tiles: [u32; 2],
    pub light_slices: u32,
    pub light_cells: u32,
    pub light_refs: u32,
    pub light_mapped: u32,
    /// Shadow ray reordering of that frame (paper section 4.3, Algorithm
    /// 1), summed over lights: rays sorted into light tiles, light tiles
    /// with at least one ray, chunks made (at least `reorder_tiles_used`);
    /// `reorder_max_tile_rays`: the rays of the most crowded light tile of
    /// any light.
    pub reorder_rays: u32,
    pub reorder_tiles_used: u32,
    pub reorder_chunks: u32,
    pub reorder_max_tile_rays: u32,
    /// Wall time of each phase of the last deferred frame in nanoseconds
    /// (the paper's Figure 10), summed over lights: perspective grid build,
    /// camera rays, shadow ray rearrangement (making, mapping, sorting,
    /// chunking), light grid builds, shadow rays, shading. Their sum is
    /// that frame's `trace_ns`.
    pub primary_build_ns: u64,
    pub primary_trace_ns: u64,
    pub rearrange_ns: u64,
    pub shadow_build_ns: u64,
    pub shadow_trace_ns: u64,
    pub shade_ns: u64,
    /// Shadow rays of that frame over all lights.
    pub shadow_rays: u64,
    /// Camera rays of that frame that hit a triangle.
    pub hits: u64,
}

impl sheaf_stats {
    pub fn of(s: &Stats) -> sheaf_stats {
        let g = &s.grid;
        let d = &s.deferred;
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
            pgrid_triangles: s.pgrid.triangles,
            pgrid_excluded: s.pgrid.excluded,
            pgrid_test: s
                .pgrid
                .params
                .map_or(0, |p| super::sheaf_tri_test::of(p.test) as u32),
            camera_tiles: d.camera.tiles,
            camera_slices: d.camera.depth.count,
            camera_cells: d.camera.cells(),
            camera_refs: d.camera.refs,
            camera_mapped: d.camera.mapped,
            camera_backfaces: d.camera.backfaces,
            light_tiles: d.light.tiles,
            light_slices: d.light.depth.count,
            light_cells: d.light.cells(),
            light_refs: d.light.refs,
            light_mapped: d.light.mapped,
            reorder_rays: d.reorder.rays,
            reorder_tiles_used: d.reorder.tiles_used,
            reorder_chunks: d.reorder.chunks,
            reorder_max_tile_rays: d.reorder.max_tile_rays,
            primary_build_ns: d.times.primary_build,
            primary_trace_ns: d.times.primary_trace,
            rearrange_ns: d.times.rearrange,
            shadow_build_ns: d.times.shadow_build,
            shadow_trace_ns: d.times.shadow_trace,
            shade_ns: d.times.shade,
            shadow_rays: d.shadow_rays,
            hits: d.hits,
        }
    }
}

// No padding anywhere (C sees the same offsets on every ABI): all fields
// before `build_ns` fill 64 bytes, and `sheaf_counters` is all u64.
const _: () = {
    use core::mem::{offset_of, size_of};
    assert!(offset_of!(sheaf_stats, build_ns) == 64);
    assert!(size_of::<Counters>().is_multiple_of(8));
    assert!(offset_of!(sheaf_stats, bvh_nodes) == offset_of!(sheaf_stats, trace_ns) + 8);
    assert!(offset_of!(sheaf_stats, kd_nodes) == offset_of!(sheaf_stats, bvh_build_ns) + 8);
    assert!(offset_of!(sheaf_stats, pgrid_triangles) == offset_of!(sheaf_stats, kd_build_ns) + 8);
    // 20 u32 (an even number) from pgrid_triangles, then the u64s.
    assert!(
        offset_of!(sheaf_stats, primary_build_ns) == offset_of!(sheaf_stats, pgrid_triangles) + 80
    );
    assert!(size_of::<sheaf_stats>() == offset_of!(sheaf_stats, hits) + 8);
};
