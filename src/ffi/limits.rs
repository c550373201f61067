//! `sheaf_limits`: every pool size of a context (the crate's `Limits`, whose
//! field docs are the reference), with its one boolean received as a byte.

use super::sized::{self, versioned};
use super::{flag, guard_free};
use crate::Limits;
use crate::error::Result;

/// Capacities fixed at context creation: the crate's `Limits` field by
/// field (see its docs in `src/mem/limits.rs` for each default rule).
/// Start from `sheaf_limits_default`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct sheaf_limits {
    /// `sizeof` the struct the caller was built with, set by
    /// `sheaf_limits_default` (docs/c-api.md, "Upgrading").
    pub size: u32,
    /// Most triangles a scene may have (including ones excluded at build).
    pub max_triangles: u32,
    /// Most vertices a scene may have.
    pub max_vertices: u32,
    /// Largest image a render call accepts.
    pub max_image_width: u32,
    pub max_image_height: u32,
    /// Largest square tile (pixels per side) a render call works on at
    /// once: even, 2..=1024.
    pub max_tile: u32,
    /// Most threads that render or trace concurrently (one slot each), 1..=1024.
    pub max_threads: u32,
    /// Most grid cells. 0: `8 * max_triangles + 64`.
    pub max_grid_cells: u32,
    /// Most triangle references in grid cells. 0: `16 * max_triangles + 1024`.
    pub max_grid_refs: u32,
    /// 1: reserve 48 bytes per triangle for the precomputed projection test
    /// (`SHEAF_TRI_TEST_PROJECTION`); 0: that test cannot be selected.
    /// Other values: `SHEAF_STATUS_INVALID_ARGUMENT`.
    pub projection_test: u32,
    /// Which structures get pools: `SHEAF_STRUCTURE_GRID`, `_BVH`, `_KD`,
    /// `_PGRID` bits, at least one.
    pub structures: u32,
    /// Most kd-tree nodes. 0: `4 * max_triangles + 1024`.
    pub max_kd_nodes: u32,
    /// Most kd-tree leaf references. 0: `12 * max_triangles + 1024`; else
    /// at least `max_triangles`.
    pub max_kd_refs: u32,
    /// Most cells of the perspective grid and of each light grid. 0: derived
    /// from the largest image.
    pub max_pgrid_cells: u32,
    /// Most (triangle, cell) pairs of each perspective or light grid. 0:
    /// `8 * max_triangles + 262144`.
    pub max_pgrid_refs: u32,
    /// Most geometries of the two-level scene. 0: none.
    pub max_geometries: u32,
    /// Most instances of the two-level scene. 0: `max_geometries`.
    pub max_instances: u32,
    /// Triangles all geometries may reserve together (140 bytes each). 0:
    /// `max_triangles`.
    pub max_scene_triangles: u32,
    /// Largest packet side a call may ask for: 2, 4, 8, 16 or 32 (the
    /// default). Each thread slot's scratch grows with its square; a call
    /// asking for more gets `SHEAF_STATUS_CAPACITY_PACKET_SIDE`.
    pub max_packet_side: u32,
    /// Most bounces (`max_reflect + max_refract`) a Whitted frame may ask
    /// for, 0..=8 (default 8); more: `SHEAF_STATUS_CAPACITY_BOUNCES`.
    pub max_bounces: u32,
    /// Which renderers get thread-slot scratch: `SHEAF_RENDERER_TILES`,
    /// `_WHITTED`, `_DEFERRED` bits (default: all); 0 for a context that
    /// only traces rays. A render call whose renderer is left out gets
    /// `SHEAF_STATUS_INVALID_ARGUMENT`.
    pub renderers: u32,
    /// Most triangle references of the BVH's leaves. 0: `max_triangles`;
    /// the excess is the reserve of `SHEAF_BUILD_QUALITY_HIGH`'s spatial
    /// splits and of the LOW build's pre-splits (`sheaf_bvh_params.
    /// presplit`; 136 bytes per reference, 184 with the projection test);
    /// fewer than `max_triangles`: `SHEAF_STATUS_INVALID_ARGUMENT`.
    pub max_bvh_refs: u32,
}

impl sheaf_limits {
    pub fn of(l: &Limits) -> sheaf_limits {
        sheaf_limits {
            size: core::mem::size_of::<sheaf_limits>() as u32,
            max_triangles: l.max_triangles,
            max_vertices: l.max_vertices,
            max_image_width: l.max_image_width,
            max_image_height: l.max_image_height,
            max_tile: l.max_tile,
            max_threads: l.max_threads,
            max_grid_cells: l.max_grid_cells,
            max_grid_refs: l.max_grid_refs,
            projection_test: l.projection_test.into(),
            structures: l.structures,
            max_kd_nodes: l.max_kd_nodes,
            max_kd_refs: l.max_kd_refs,
            max_pgrid_cells: l.max_pgrid_cells,
            max_pgrid_refs: l.max_pgrid_refs,
            max_geometries: l.max_geometries,
            max_instances: l.max_instances,
            max_scene_triangles: l.max_scene_triangles,
            max_packet_side: l.max_packet_side,
            max_bounces: l.max_bounces,
            renderers: l.renderers,
            max_bvh_refs: l.max_bvh_refs,
        }
    }

    /// The crate's limits (the byte checked; the rest by `Limits::validate`).
    pub fn to_core(&self) -> Result<Limits> {
        Ok(Limits {
            max_triangles: self.max_triangles,
            max_vertices: self.max_vertices,
            max_image_width: self.max_image_width,
            max_image_height: self.max_image_height,
            max_tile: self.max_tile,
            max_threads: self.max_threads,
            max_grid_cells: self.max_grid_cells,
            max_grid_refs: self.max_grid_refs,
            projection_test: flag(
                self.projection_test,
                "sheaf_limits.projection_test must be 0 or 1",
            )?,
            structures: self.structures,
            max_kd_nodes: self.max_kd_nodes,
            max_kd_refs: self.max_kd_refs,
            max_pgrid_cells: self.max_pgrid_cells,
            max_pgrid_refs: self.max_pgrid_refs,
            max_geometries: self.max_geometries,
            max_instances: self.max_instances,
            max_scene_triangles: self.max_scene_triangles,
            max_packet_side: self.max_packet_side,
            max_bounces: self.max_bounces,
            renderers: self.renderers,
            max_bvh_refs: self.max_bvh_refs,
        })
    }
}

versioned!(
    sheaf_limits => Limits,
    [
        max_triangles,
        max_vertices,
        max_image_width,
        max_image_height,
        max_tile,
        max_threads,
        max_grid_cells,
        max_grid_refs,
        projection_test,
        structures,
        max_kd_nodes,
        max_kd_refs,
        max_pgrid_cells,
        max_pgrid_refs,
        max_geometries,
        max_instances,
        max_scene_triangles,
        max_packet_side,
        max_bounces,
        renderers,
        max_bvh_refs,
    ],
    sheaf_limits::of(&Limits::for_triangles(0))
);

/// Write limits for scenes of up to `max_triangles` triangles to `*out`:
/// `3 * max_triangles` vertices, 4096 x 4096 images, 64-pixel tiles, 8
/// threads, grid pools derived from the triangle count (0 in
/// `max_grid_cells` / `max_grid_refs`), packets up to 32 x 32, 8 Whitted
/// bounces and every renderer. Adjust fields afterwards as needed.
///
/// `size` is `sizeof *out` as the caller was compiled (sheaf.h's
/// `sheaf_limits_default(n, out)` macro passes it): an older header's
/// struct gets the fields it has, a newer one's unknown fields zeros.
///
/// `out` must not be NULL. Errors: `SHEAF_STATUS_INVALID_ARGUMENT` when
/// `size` is no size of this struct. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_limits_default(
    max_triangles: u32,
    out: *mut sheaf_limits,
    size: usize,
) -> super::sheaf_status {
    guard_free(|| {
        sized::write(
            out,
            size,
            sheaf_limits::of(&Limits::for_triangles(max_triangles)),
        )
    })
}
