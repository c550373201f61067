//! `sheaf_limits`: every pool size of a context (the crate's `Limits`, whose
//! field docs are the reference), with its one boolean received as a
//! `uint32_t` 0 or 1.
//!
//! The C struct is written out field by field (cbindgen reads it for
//! sheaf.h, and its layout is the ABI); everything else about the mirror
//! comes from one list, `mirror!`'s, which cannot drift from either
//! struct: a field of `Limits` missing from it leaves `to_core`'s `Limits`
//! incomplete, one of `sheaf_limits` leaves `of`'s struct incomplete and
//! `versioned!`'s size assertion short; a name in it that either struct
//! lacks, a type other than a count or a boolean, or a list out of the C
//! struct's order is a compile error; and each field goes to the field of
//! its own name. Fields are appended to all three at the end
//! (docs/c-api.md, "Upgrading").

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

/// How one field of `Limits` crosses the C ABI: a count as itself, the
/// boolean as a `uint32_t` 0 or 1 (checked coming in, as [`flag`] checks).
trait Field: Sized {
    /// The field for C.
    fn to_c(self) -> u32;
    /// The field from C; `bad` names the field's refusal.
    fn from_c(c: u32, bad: &'static str) -> Result<Self>;
}

impl Field for u32 {
    fn to_c(self) -> u32 {
        self
    }
    fn from_c(c: u32, _: &'static str) -> Result<u32> {
        Ok(c)
    }
}

impl Field for bool {
    fn to_c(self) -> u32 {
        self.into()
    }
    fn from_c(c: u32, bad: &'static str) -> Result<bool> {
        flag(c, bad)
    }
}

/// The mirror of `Limits`, written once: the fields of `sheaf_limits`
/// after `size`, in declaration order, give `sheaf_limits::of`,
/// `sheaf_limits::to_core` and the versioned field list (see the module
/// docs for why it cannot drift).
macro_rules! mirror {
    ($($f:ident),+ $(,)?) => {
        impl sheaf_limits {
            pub fn of(l: &Limits) -> sheaf_limits {
                sheaf_limits {
                    size: core::mem::size_of::<sheaf_limits>() as u32,
                    $($f: Field::to_c(l.$f),)+
                }
            }

            /// The crate's limits (the boolean checked; the rest by
            /// `Limits::validate`).
            pub fn to_core(&self) -> Result<Limits> {
                Ok(Limits {
                    $($f: Field::from_c(
                        self.$f,
                        concat!("sheaf_limits.", stringify!($f), " must be 0 or 1"),
                    )?,)+
                })
            }
        }

        versioned!(
            sheaf_limits => Limits,
            [$($f),+],
            sheaf_limits::of(&Limits::for_triangles(0))
        );
    };
}

mirror!(
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
