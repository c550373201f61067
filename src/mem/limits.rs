//! `Limits`: every pool size of a context derives from these numbers.

use crate::error::{Error, Result};

/// `a * n + b` for the default pool rules; below 2^64 for any u32 `n` and
/// the small constants used here, saturating rather than wrapping anyway.
#[deny(clippy::arithmetic_side_effects)]
const fn lin(a: u64, n: u32, b: u64) -> u64 {
    a.saturating_mul(n as u64).saturating_add(b)
}

/// Capacities fixed at context creation (C: `sheaf_limits`).
///
/// A zero in a `max_grid_*` knob means "derive from `max_triangles`"; see
/// the field docs for the rule.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Most triangles a scene may have (including ones excluded at build).
    pub max_triangles: u32,
    /// Most vertices a scene may have.
    pub max_vertices: u32,
    /// Largest image a render call accepts.
    pub max_image_width: u32,
    pub max_image_height: u32,
    /// Largest square tile (pixels per side) a render call works on at once.
    pub max_tile: u32,
    /// Most threads that render or trace concurrently (one scratch slot each).
    pub max_threads: u32,
    /// Most grid cells. 0: `8 * max_triangles + 64`, room for lambda up to 8
    /// (CGT paper section 3 uses lambda = 5).
    pub max_grid_cells: u32,
    /// Most triangle references in grid cells. 0: `16 * max_triangles + 1024`.
    pub max_grid_refs: u32,
    /// Reserve 48 bytes per triangle for the precomputed projection test
    /// (`TriTest::Projection`); without it that test cannot be selected.
    pub projection_test: bool,
    /// Which structures get pools, a bit set of `SHEAF_STRUCTURE_GRID` (169
    /// bytes per triangle with the default grid rules and 8 threads),
    /// `SHEAF_STRUCTURE_BVH` (140 bytes per triangle) and
    /// `SHEAF_STRUCTURE_KD` (237 bytes per triangle with the default kd
    /// rules, 112 of them build scratch) and `SHEAF_STRUCTURE_PGRID`
    /// (perspective and light grids: about 190 bytes per triangle with the
    /// default pair pools, plus about 45 bytes per pixel of the largest
    /// image for the deferred frame buffers), at least one. A structure
    /// without pools cannot be built; model no more than the scene needs.
    pub structures: u32,
    /// Most kd-tree nodes. 0: `4 * max_triangles + 1024` (the OBJ scenes
    /// need 0.6 to 3.7 per triangle with the default `KdParams`).
    pub max_kd_nodes: u32,
    /// Most triangle references in kd-tree leaves. 0: `12 * max_triangles +
    /// 1024` (the OBJ scenes need 3.4 to 6.1 per triangle, the gears scene
    /// 20). At least `max_triangles` (every triangle needs a reference;
    /// fewer is `InvalidArgument`). A build that runs out makes leaves
    /// early (`KdInfo::forced_leaves`).
    pub max_kd_refs: u32,
    /// Most cells of the perspective grid and, separately, of each light
    /// grid (tiles x depth slices). 0: `max(ceil(w / 8) * ceil(h / 8), 64 *
    /// 64) * 32` for the largest image, room for the default `PgridParams`.
    pub max_pgrid_cells: u32,
    /// Most (triangle, cell) pairs of the perspective grid and, separately,
    /// of each light grid. 0: `8 * max_triangles + 262144` (a triangle
    /// spans every cell its projection and depth range touch: large ones
    /// near the eye span thousands).
    pub max_pgrid_refs: u32,
    /// Most geometries of the two-level scene (`accel::twolevel`: each
    /// geometry its own BVH, placed by instances). 0: no two-level scene.
    /// With a grid, kd-tree or perspective grid in `structures`, the scene
    /// can also be flattened into up to `max_triangles` world triangles
    /// for them (`twolevel::flatten`: 56 bytes per triangle).
    pub max_geometries: u32,
    /// Most instances of the two-level scene. 0: `max_geometries`.
    pub max_instances: u32,
    /// Triangles all geometries may reserve together (140 bytes each, as
    /// the BVH). 0: `max_triangles`.
    pub max_scene_triangles: u32,
    /// Largest packet side a call may ask for (`TraceParams::packet`, a
    /// render tile's packets, a perspective grid's sorting tile): 2, 4, 8,
    /// 16 or 32. Each slot's scratch grows with its square (about 1 KiB
    /// per ray at 32 with every renderer; see `context::slot_scratch_bytes`);
    /// a call asking for more gets `Capacity { pool: PacketSide }`.
    pub max_packet_side: u32,
    /// Most bounces a Whitted frame may ask for (`max_reflect +
    /// max_refract`), 0..=8: each is one more level of packets in a slot's
    /// scratch. More gets `Capacity { pool: Bounces }`.
    pub max_bounces: u32,
    /// Which renderers get slot scratch, a bit set of
    /// `SHEAF_RENDERER_TILES` (`render_with`, `render_rows_in_slot`),
    /// `SHEAF_RENDERER_WHITTED` and `SHEAF_RENDERER_DEFERRED`; 0: none,
    /// for a context that only traces rays. A render call whose renderer
    /// is left out gets `InvalidArgument`.
    pub renderers: u32,
    /// Most triangle references of the BVH's leaves. 0: `max_triangles`,
    /// one per triangle. Above `max_triangles` the difference is the
    /// reserve of the `High` build's spatial splits (`accel::bvh::
    /// build_spatial`) and, with `BvhParams::presplit`, of the `Low`
    /// build's pre-splits (`accel::bvh::presplit`), which may reference a
    /// triangle from several leaves: 136 bytes per reserved reference (184 with
    /// `projection_test`). A quarter of `max_triangles` (34 bytes per
    /// triangle) gives the OBJ test scenes' HIGH trees SAH costs within 3 %
    /// of a reserve as large as `max_triangles`. Fewer than `max_triangles`
    /// is `InvalidArgument`.
    pub max_bvh_refs: u32,
}

impl Limits {
    /// `structures` bit: the uniform grid (C: `SHEAF_STRUCTURE_GRID`).
    /// cbindgen:ignore
    pub const GRID: u32 = 1;
    /// `structures` bit: the BVH (C: `SHEAF_STRUCTURE_BVH`).
    /// cbindgen:ignore
    pub const BVH: u32 = 2;
    /// `structures` bit: the kd-tree (C: `SHEAF_STRUCTURE_KD`).
    /// cbindgen:ignore
    pub const KD: u32 = 4;
    /// `structures` bit: the perspective grid for camera rays and the
    /// spherical light grids for shadow rays, with the per-pixel frame
    /// buffers their deferred frames need (C: `SHEAF_STRUCTURE_PGRID`).
    /// Its pools scale with the largest image (about 45 bytes per pixel),
    /// so `for_triangles` leaves it out.
    /// cbindgen:ignore
    pub const PGRID: u32 = 8;
    /// Every structure bit this version knows.
    /// cbindgen:ignore
    pub const ALL_STRUCTURES: u32 = Self::GRID | Self::BVH | Self::KD | Self::PGRID;

    /// `renderers` bit: packet tiles, `render_with` and
    /// `render_rows_in_slot` (C: `SHEAF_RENDERER_TILES`).
    /// cbindgen:ignore
    pub const TILES: u32 = 1;
    /// `renderers` bit: Whitted frames (C: `SHEAF_RENDERER_WHITTED`).
    /// cbindgen:ignore
    pub const WHITTED: u32 = 2;
    /// `renderers` bit: deferred frames (C: `SHEAF_RENDERER_DEFERRED`).
    /// cbindgen:ignore
    pub const DEFERRED: u32 = 4;
    /// Every renderer bit this version knows.
    /// cbindgen:ignore
    pub const ALL_RENDERERS: u32 = Self::TILES | Self::WHITTED | Self::DEFERRED;
    /// Largest packet side any call can ask for (the default).
    /// cbindgen:ignore
    pub const PACKET_SIDE: u32 = 32;
    /// Most Whitted bounces any frame can ask for (the default).
    /// cbindgen:ignore
    pub const BOUNCES: u32 = 8;

    /// Whether `renderer` (a `Limits::TILES`-style bit) has slot scratch.
    pub const fn renders(&self, renderer: u32) -> bool {
        self.renderers & renderer != 0
    }

    /// Whether `structure` (a `Limits::GRID`-style bit) has pools.
    pub const fn has(&self, structure: u32) -> bool {
        self.structures & structure != 0
    }
    /// Limits for scenes of up to `n` triangles with defaults for the rest:
    /// `3n` vertices, 4096 x 4096 images, 64-pixel tiles, 8 threads.
    pub const fn for_triangles(n: u32) -> Limits {
        Limits {
            max_triangles: n,
            max_vertices: n.saturating_mul(3),
            max_image_width: 4096,
            max_image_height: 4096,
            max_tile: 64,
            max_threads: 8,
            max_grid_cells: 0,
            max_grid_refs: 0,
            projection_test: false,
            structures: Self::GRID | Self::BVH | Self::KD,
            max_kd_nodes: 0,
            max_kd_refs: 0,
            max_pgrid_cells: 0,
            max_pgrid_refs: 0,
            max_geometries: 0,
            max_instances: 0,
            max_scene_triangles: 0,
            max_packet_side: Self::PACKET_SIDE,
            max_bounces: Self::BOUNCES,
            renderers: Self::ALL_RENDERERS,
            max_bvh_refs: 0,
        }
    }

    /// Triangle references of the BVH's leaves after the default rule (0
    /// without a BVH).
    pub const fn bvh_refs(&self) -> u32 {
        if !self.has(Self::BVH) {
            0
        } else if self.max_bvh_refs != 0 {
            self.max_bvh_refs
        } else {
            self.max_triangles
        }
    }

    /// `Capacity { pool: PacketSide }` unless `side <= max_packet_side`.
    pub fn check_packet_side(&self, side: u32) -> Result<()> {
        if side > self.max_packet_side {
            return Err(Error::Capacity {
                pool: crate::error::Pool::PacketSide,
                needed: side.into(),
                available: self.max_packet_side.into(),
            });
        }
        Ok(())
    }

    /// `InvalidArgument` unless `renderer` (a `Limits::TILES`-style bit) is
    /// in `renderers`.
    pub fn check_renderer(&self, renderer: u32) -> Result<()> {
        if self.renders(renderer) {
            return Ok(());
        }
        Err(Error::InvalidArgument(match renderer {
            Self::TILES => "no tile-renderer scratch: Limits::renderers lacks TILES",
            Self::WHITTED => "no Whitted scratch: Limits::renderers lacks WHITTED",
            _ => "no deferred-frame scratch: Limits::renderers lacks DEFERRED",
        }))
    }

    /// Instance capacity of the two-level scene after the default rule (0
    /// without one).
    pub const fn scene_instances(&self) -> u32 {
        if self.max_geometries == 0 {
            0
        } else if self.max_instances != 0 {
            self.max_instances
        } else {
            self.max_geometries
        }
    }

    /// Triangle budget of the two-level scene's geometries after the
    /// default rule (0 without one).
    pub const fn scene_triangles(&self) -> u32 {
        if self.max_geometries == 0 {
            0
        } else if self.max_scene_triangles != 0 {
            self.max_scene_triangles
        } else {
            self.max_triangles
        }
    }

    // Every pool size below is computed in u64 from u32 fields and stays
    // below 2^64 (the largest, `frame_pixels`, saturates instead of
    // wrapping); the lints make any unchecked operation a build error.

    /// kd-tree node capacity after applying the default rule.
    #[deny(clippy::arithmetic_side_effects)]
    pub const fn kd_nodes(&self) -> u64 {
        if self.max_kd_nodes != 0 {
            self.max_kd_nodes as u64
        } else {
            lin(4, self.max_triangles, 1024)
        }
    }

    /// kd-tree reference capacity after applying the default rule.
    #[deny(clippy::arithmetic_side_effects)]
    pub const fn kd_refs(&self) -> u64 {
        if self.max_kd_refs != 0 {
            self.max_kd_refs as u64
        } else {
            lin(12, self.max_triangles, 1024)
        }
    }

    /// kd-tree build events (scratch): the root's list and its children's
    /// (`KdInfo::events_peak` is 12.0 to 12.2 per triangle on the test
    /// scenes); a build short of events makes leaves early.
    #[deny(clippy::arithmetic_side_effects)]
    pub const fn kd_events(&self) -> u64 {
        lin(14, self.max_triangles, 1024)
    }

    /// Perspective/light grid cell capacity (each grid) after the default rule.
    #[deny(clippy::arithmetic_side_effects)]
    pub const fn pgrid_cells(&self) -> u64 {
        if self.max_pgrid_cells != 0 {
            return self.max_pgrid_cells as u64;
        }
        // < 2^29 * 2^29 * 2^5 = 2^63.
        let tiles = (self.max_image_width.div_ceil(8) as u64)
            .saturating_mul(self.max_image_height.div_ceil(8) as u64);
        let tiles = if tiles > 64 * 64 { tiles } else { 64 * 64 };
        tiles.saturating_mul(32)
    }

    /// Perspective/light grid pair capacity (each grid) after the default rule.
    #[deny(clippy::arithmetic_side_effects)]
    pub const fn pgrid_refs(&self) -> u64 {
        if self.max_pgrid_refs != 0 {
            self.max_pgrid_refs as u64
        } else {
            lin(8, self.max_triangles, 262_144)
        }
    }

    /// Pixels of the deferred frame buffers: the largest image padded to
    /// whole tiles of up to `max_tile` pixels. Saturates at `u64::MAX`
    /// (which `validate` refuses): `(2^32 - 16 + 16)^2` would wrap to 0.
    #[deny(clippy::arithmetic_side_effects)]
    pub const fn frame_pixels(&self) -> u64 {
        let w = (self.max_image_width as u64).saturating_add(self.max_tile as u64);
        let h = (self.max_image_height as u64).saturating_add(self.max_tile as u64);
        w.saturating_mul(h)
    }

    /// Grid cell capacity after applying the default rule.
    #[deny(clippy::arithmetic_side_effects)]
    pub const fn grid_cells(&self) -> u64 {
        if self.max_grid_cells != 0 {
            self.max_grid_cells as u64
        } else {
            lin(8, self.max_triangles, 64)
        }
    }

    /// Grid reference capacity after applying the default rule.
    #[deny(clippy::arithmetic_side_effects)]
    pub const fn grid_refs(&self) -> u64 {
        if self.max_grid_refs != 0 {
            self.max_grid_refs as u64
        } else {
            lin(16, self.max_triangles, 1024)
        }
    }

    /// Checks that every field is in its domain and every pool fits in memory.
    pub fn validate(&self) -> Result<()> {
        if self.max_threads == 0 || self.max_threads > 1024 {
            return Err(Error::InvalidArgument("max_threads must be in 1..=1024"));
        }
        if self.max_tile < 2 || !self.max_tile.is_multiple_of(2) || self.max_tile > 1024 {
            return Err(Error::InvalidArgument(
                "max_tile must be even and in 2..=1024",
            ));
        }
        if self.max_image_width == 0 || self.max_image_height == 0 {
            return Err(Error::InvalidArgument(
                "max_image_width and max_image_height must be > 0",
            ));
        }
        if !matches!(self.max_packet_side, 2 | 4 | 8 | 16 | 32) {
            return Err(Error::InvalidArgument(
                "max_packet_side must be 2, 4, 8, 16 or 32",
            ));
        }
        if self.max_bounces > Self::BOUNCES {
            return Err(Error::InvalidArgument("max_bounces must be in 0..=8"));
        }
        if self.renderers & !Self::ALL_RENDERERS != 0 {
            return Err(Error::InvalidArgument(
                "renderers must name no unknown bits",
            ));
        }
        if self.structures & !Self::ALL_STRUCTURES != 0 || self.structures == 0 {
            return Err(Error::InvalidArgument(
                "structures must name at least one structure and no unknown bits",
            ));
        }
        if self.has(Self::PGRID)
            && (self.pgrid_cells() > u32::MAX as u64 - 1
                || self.pgrid_refs() > u32::MAX as u64
                || self.frame_pixels() > u32::MAX as u64)
        {
            return Err(Error::InvalidArgument(
                "perspective grid pools and frame pixels must stay below 2^32 entries",
            ));
        }
        // Every triangle of a kd-tree sits in at least one leaf, so fewer
        // references than triangles can never build (fuzzing found the
        // build refusing with a `triangles` capacity error instead).
        if self.has(Self::KD) && self.max_kd_refs != 0 && self.max_kd_refs < self.max_triangles {
            return Err(Error::InvalidArgument(
                "max_kd_refs must be 0 or at least max_triangles (every triangle needs a leaf reference)",
            ));
        }
        if self.grid_cells() > u32::MAX as u64 - 1 || self.grid_refs() > u32::MAX as u64 {
            return Err(Error::InvalidArgument(
                "grid pools must stay below 2^32 entries",
            ));
        }
        if self.has(Self::BVH) && self.max_bvh_refs != 0 && self.max_bvh_refs < self.max_triangles {
            return Err(Error::InvalidArgument(
                "max_bvh_refs must be 0 or at least max_triangles (every triangle needs a leaf reference)",
            ));
        }
        // A BVH of n references has 2n - 1 nodes numbered in a u32 (the
        // binary builds step node numbers by 2), as has the two-level
        // scene's top level over its instances.
        let bvh_triangles = self.bvh_refs();
        if bvh_triangles
            .max(self.scene_triangles())
            .max(self.scene_instances())
            > 1 << 31
        {
            return Err(Error::InvalidArgument(
                "a BVH holds at most 2^31 triangles, a two-level scene 2^31 instances",
            ));
        }
        // A flattened scene is a mesh of 3 indices per world triangle,
        // counted in a u32.
        if self.max_geometries != 0
            && self.structures & !Self::BVH != 0
            && self.max_triangles > u32::MAX / 3
        {
            return Err(Error::InvalidArgument(
                "a flattened two-level scene holds at most 2^32 / 3 world triangles",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pool_rules_saturate_instead_of_wrapping() {
        let mut l = Limits::for_triangles(u32::MAX);
        l.max_image_width = 0xFFFF_FFF0;
        l.max_image_height = 0xFFFF_FFF0;
        l.max_tile = 16;
        // (2^32)^2 wrapped to 0 before: a 5 MB context that then panicked.
        assert_eq!(l.frame_pixels(), u64::MAX);
        l.structures = Limits::PGRID;
        assert!(l.validate().is_err());
        assert_eq!(l.kd_events(), 14 * u32::MAX as u64 + 1024);
        assert!(l.pgrid_cells() < u64::MAX && l.pgrid_cells() > 1 << 50);
    }

    /// Counts that node numbers or flattened indices in a u32 could not
    /// hold are refused; their edges are accepted.
    #[test]
    fn counts_past_u32_numbering_are_refused() {
        let ok = |f: &dyn Fn(&mut Limits)| {
            let mut l = Limits::for_triangles(1 << 10);
            // The grid's own bounds apply whatever the structures.
            (l.max_grid_cells, l.max_grid_refs) = (16, 16);
            f(&mut l);
            l.validate().is_ok()
        };
        assert!(ok(&|l| {
            l.structures = Limits::BVH;
            l.max_triangles = 1 << 31;
        }));
        assert!(!ok(&|l| {
            l.structures = Limits::BVH;
            l.max_triangles = (1 << 31) + 1;
        }));
        assert!(!ok(&|l| {
            l.max_geometries = 1;
            l.max_instances = (1 << 31) + 1;
        }));
        assert!(!ok(&|l| {
            l.structures = Limits::KD;
            l.max_geometries = 1;
            l.max_scene_triangles = 16;
            l.max_triangles = u32::MAX / 3 + 1;
        }));
        assert!(ok(&|l| {
            l.structures = Limits::KD;
            l.max_geometries = 1;
            l.max_scene_triangles = 16;
            l.max_triangles = u32::MAX / 3;
        }));
    }

    #[test]
    fn required_bytes_never_wraps_to_a_small_size() {
        // Every field at or near its u32 maximum, in combinations: either
        // refused or at least as large as the triangle pool alone.
        for n in [0u32, 1, 1 << 20, u32::MAX / 64, u32::MAX / 2, u32::MAX] {
            for structures in [
                Limits::GRID,
                Limits::BVH,
                Limits::KD,
                Limits::PGRID,
                Limits::ALL_STRUCTURES,
            ] {
                for big in [0u32, u32::MAX - 1, u32::MAX] {
                    let mut l = Limits::for_triangles(n);
                    l.structures = structures;
                    l.max_vertices = big;
                    l.max_grid_cells = big.min(u32::MAX - 1);
                    l.max_grid_refs = big;
                    l.max_kd_nodes = big;
                    l.max_kd_refs = if big == 0 { 0 } else { big.max(n) };
                    l.max_pgrid_refs = big;
                    l.max_image_width = big.max(1);
                    l.max_threads = 1024;
                    l.projection_test = true;
                    if let Ok(b) = crate::context::required_bytes(&l) {
                        assert!(b as u64 >= 36 * n as u64, "{l:?}: {b} bytes");
                    }
                }
            }
        }
    }
}
