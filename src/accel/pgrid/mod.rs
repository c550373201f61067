//! Perspective grids for camera rays and spherical light grids for shadow
//! rays, rebuilt every frame, with shadow rays sorted into light tiles and
//! crowded tiles split into chunks.
//!
//! Source: "Fast ray tracing of dynamic scenes with primary and shadow rays
//! on grids", a GPU paper of 2010.
//! sheaf runs the same algorithm on CPU threads: a CUDA block becomes a
//! work item (a tracing tile or a chunk) taken by a worker thread, the warp
//! becomes the 2x2 SIMD ray, and shared memory becomes the cell's triangle
//! list, read once per triangle for all rays of the tile.
//!
//! | file | implements |
//! |---|---|
//! | `build.rs` | section 3: (triangle, cell) pairs for every cell a triangle spans, back faces optionally removed, sorted by cell id, a scan giving each cell's range; section 4.1: the same over the light's (a, b) space, clamped to the hit points' rectangle and distance range |
//! | `traverse_primary.rs` | section 3: the rays of a tile visit its cells front to back and stop at the first slice where they all have their nearest hit; indirect mapping (sorting tiles traced in k x k groups) |
//! | `reorder.rs` | sections 4.2 and 4.3, Algorithm 1: shadow rays mapped to light tiles, sorted, tile boundaries, counts, chunks of at most r rays, empty tiles compacted away |
//! | `traverse_shadow.rs` | section 4.4: a chunk's shadow rays traced through its light tile's cells front to back from the light, occlusion only |
//!
//! # Exactness
//! Every triangle is listed in every cell it may touch: its tile range comes
//! from conservative bounds (clipped projection for the camera, angular
//! span for the light, both padded) and its slice range from padded depths.
//! A ray stops after slice `s` only when its nearest hit lies at or before
//! slice `s` with the same padding, so a closer triangle would have been
//! listed in a slice already visited. Hence primary hits equal the
//! single-ray reference's (same triangle, bitwise t) and shadow bits equal
//! occlusion rays traced one by one.
//!
//! # Deviations
//! - The sort is a least-significant-digit radix sort (`mem::sort`) on one CPU thread, 11
//!   bits per pass, instead of the GPU SplitSort; the segmented scan, the
//!   chunking and the stream compaction of Algorithm 1 are one pass over the
//!   sorted keys.
//! - Depth slices are spaced geometrically between the near and far bounds
//!   (the paper does not give its spacing); the first slice reaches down to
//!   the eye (or the light), so nothing in front of the near bound is lost.
//! - Removing back faces (`PgridParams::cull_backfaces`) changes results
//!   on open models, since every reference in sheaf is two-sided; it is off
//!   by default and the exactness tests run without it.

pub mod build;
pub mod reorder;
pub mod traverse_primary;
pub mod traverse_shadow;

use core::cmp::Ordering;

use crate::error::Result;
use crate::geom::{Aabb, ProjTri, TriTest, TriVerts, TriangleTest};
use crate::isa::Isa;
use crate::math;
use crate::mem::{Carve, Limits};
use glam::Vec3;

pub use reorder::{Chunk, ReorderInfo};

/// Tunables of the perspective grid and the light grids (C:
/// `sheaf_pgrid_params`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PgridParams {
    /// Side of a sorting tile in pixels (triangles are sorted into these).
    pub tile: u32,
    /// Sorting tiles per side of a tracing tile (indirect mapping, section
    /// 3: the paper found 2 x 2 best). 1: direct mapping.
    pub group: u32,
    /// Depth slices of the camera frustum.
    pub slices: u32,
    /// Light tiles per side of the light frustum's (a, b) rectangle (at most 256).
    pub light_tiles: u32,
    /// Depth slices of a light grid (constant distance from the light).
    pub light_slices: u32,
    /// Most shadow rays per chunk, r (section 4.3: load balance). 16..=4096.
    pub chunk: u32,
    /// Leave out triangles facing away from the eye (changes results on
    /// open models: sheaf's references are two-sided).
    pub cull_backfaces: bool,
    /// Ray-triangle test of both grids.
    pub test: TriTest,
    /// Lane width of both grids' triangle tests (`Isa::Auto`: the CPU's
    /// widest, capped by `SHEAF_ISA`; a forced level the CPU lacks is
    /// rejected by `validate`, as `TraceParams::isa`).
    pub isa: Isa,
}

impl Default for PgridParams {
    fn default() -> Self {
        PgridParams {
            tile: 8,
            group: 2,
            slices: 32,
            light_tiles: 64,
            light_slices: 32,
            chunk: 256,
            cull_backfaces: false,
            test: TriTest::MollerTrumbore,
            isa: Isa::Auto,
        }
    }
}

/// Most light tiles (256 per side).
pub const MAX_LIGHT_TILES: usize = 256 * 256;

/// Smallest chunk size r: bounds the chunk pool (`Limits::frame_pixels`
/// / 16 plus one per light tile).
pub const MIN_CHUNK: u32 = 16;

impl PgridParams {
    /// Checks every field's domain (tile side even, at most 32; tracing
    /// tile `tile * group` within `max_tile` is checked at render).
    pub fn validate(&self) -> crate::error::Result<()> {
        use crate::error::Error::InvalidArgument;
        if !matches!(self.tile, 2 | 4 | 8 | 16 | 32) {
            return Err(InvalidArgument("pgrid tile must be 2, 4, 8, 16 or 32"));
        }
        if !matches!(self.group, 1 | 2 | 4) || self.tile * self.group > 64 {
            return Err(InvalidArgument(
                "pgrid group must be 1, 2 or 4, and tile * group at most 64",
            ));
        }
        if !(1..=1024).contains(&self.slices) || !(1..=1024).contains(&self.light_slices) {
            return Err(InvalidArgument("pgrid slices must be in 1..=1024"));
        }
        if !(1..=256).contains(&self.light_tiles) {
            return Err(InvalidArgument("light_tiles must be in 1..=256"));
        }
        if !(MIN_CHUNK..=4096).contains(&self.chunk) {
            return Err(InvalidArgument(
                "chunk (rays per chunk) must be in 16..=4096",
            ));
        }
        crate::isa::resolve(self.isa)?;
        Ok(())
    }
}

/// Relative padding of camera depths when slices are assigned: a depth
/// `q . fwd` carries rounding relative to `|q|`, up to `sqrt(1 + tan^2)`
/// times the depth at the image's corners for wide fields of view.
pub const DEPTH_PAD: f32 = 1e-3;
/// Relative padding of distances from a light (a length's rounding is
/// relative to itself; a light far away makes thin slices, which a wide
/// pad would smear every triangle across).
pub const LIGHT_DEPTH_PAD: f32 = 2e-5;

/// Depth slices spaced (nearly) geometrically: slice `s` spans
/// `[z0 r^s, z0 r^(s+1))` with `log2_approx` for the logarithm, slice 0
/// reaching down to 0 and the last one to infinity.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Slices {
    pub z0: f32,
    /// Relative padding of `lo` and `hi`.
    pub pad: f32,
    /// `1 / ln r` (0: one slice for everything).
    pub inv_log: f32,
    pub count: u32,
}

impl Slices {
    /// `count` slices between `near` and `far` (near raised to `far * 1e-4`),
    /// depths padded by `pad` (relative) when slices are looked up.
    pub fn new(near: f32, far: f32, count: u32, pad: f32) -> Slices {
        let far = if far.is_finite() && far > 0.0 {
            far
        } else {
            1.0
        };
        let z0 = near.max(far * 1e-4).min(far);
        let span = log2_approx(far) - log2_approx(z0);
        let inv_log = if count > 1 && span > 0.0 {
            count as f32 / span
        } else {
            0.0
        };
        Slices {
            z0,
            pad,
            inv_log,
            count: count.max(1),
        }
    }

    /// Slice of depth `z`, clamped.
    #[inline]
    pub fn of(&self, z: f32) -> u32 {
        // Unless `z > z0`; NaN goes to slice 0 too.
        if z.partial_cmp(&self.z0) != Some(Ordering::Greater) || self.inv_log == 0.0 {
            return 0;
        }
        let s = (log2_approx(z) - log2_approx(self.z0)) * self.inv_log;
        (s as u32).min(self.count - 1)
    }

    /// First slice that may hold depth `z` (padded down).
    #[inline]
    pub fn lo(&self, z: f32) -> u32 {
        self.of(z * (1.0 - self.pad) - self.z0 * self.pad)
    }

    /// Last slice that may hold depth `z` (padded up).
    #[inline]
    pub fn hi(&self, z: f32) -> u32 {
        self.of(z * (1.0 + self.pad) + self.z0 * self.pad)
    }
}

/// log2 of a positive float read from its bits: exponent plus mantissa,
/// linear between powers of two (off by at most 0.09). Monotone, which is
/// all slicing needs (every slice lookup uses it), and far cheaper than `ln`.
#[inline(always)]
pub fn log2_approx(x: f32) -> f32 {
    x.to_bits() as f32 * (1.0 / (1u32 << 23) as f32) - 127.0
}

/// A pinhole camera as the perspective grid sees it: pixel `(x, y)`'s ray
/// has direction `fwd + right * (x - cx) * sx + down * (y - cy) * sy`
/// (pixel centres at `x + 0.5`). Made by `render::PrimaryRays::pinhole`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pinhole {
    pub eye: Vec3,
    pub right: Vec3,
    pub down: Vec3,
    pub fwd: Vec3,
    /// Half extents of the image plane at depth 1.
    pub half_w: f32,
    pub half_h: f32,
    pub width: u32,
    pub height: u32,
}

impl Pinhole {
    /// Pixel coordinates of a point `q` relative to the eye at depth
    /// `z = q . fwd > 0`.
    #[inline]
    pub fn pixel(&self, q: Vec3, z: f32) -> (f32, f32) {
        let x = (q.dot(self.right) / z + self.half_w) * (self.width as f32 / (2.0 * self.half_w));
        let y = (q.dot(self.down) / z + self.half_h) * (self.height as f32 / (2.0 * self.half_h));
        (x, y)
    }
}

/// A light's frustum in (a, b) space (section 4.1): `a` the azimuth from
/// `fwd` in the forward-right plane, `b` the elevation in the forward-up
/// plane, and the rectangle `[a0, a0 + tiles[0] / inv_da] x [b0, ...]`.
/// Angles are measured as pseudo-angles (`pseudo_angle`): monotone in the
/// true angle, so the grid is the paper's with tiles spaced slightly
/// unevenly, for a division instead of an `atan2`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LightFrame {
    pub pos: Vec3,
    pub fwd: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    pub a0: f32,
    pub b0: f32,
    /// Tiles per radian.
    pub inv_da: f32,
    pub inv_db: f32,
    pub tiles: [u32; 2],
}

impl LightFrame {
    /// (a, b) of direction `q` from the light, as pseudo-angles.
    #[inline]
    pub fn angles(&self, q: Vec3) -> (f32, f32) {
        let z = q.dot(self.fwd);
        (
            pseudo_angle(q.dot(self.right), z),
            pseudo_angle(q.dot(self.up), z),
        )
    }

    /// Light tile of direction `q` (clamped into the rectangle).
    #[inline]
    pub fn tile_of(&self, q: Vec3) -> u32 {
        let (a, b) = self.angles(q);
        let tx = tile_coord((a - self.a0) * self.inv_da, self.tiles[0]);
        let ty = tile_coord((b - self.b0) * self.inv_db, self.tiles[1]);
        ty * self.tiles[0] + tx
    }
}

/// A monotone stand-in for `atan2(x, z)` (the angle from +z towards +x)
/// on `[-2, 2]`: `x / (|x| + |z|)` ahead (`z >= 0`), continued behind so
/// that -2 and 2 are the cut at angle +-pi and 0 is straight ahead. Exact
/// in ordering, one division, no transcendental.
#[inline]
pub fn pseudo_angle(x: f32, z: f32) -> f32 {
    let s = x.abs() + z.abs();
    if s.is_nan() || s <= 0.0 {
        return 0.0;
    }
    let p = x / s;
    if z >= 0.0 {
        p
    } else if x >= 0.0 {
        2.0 - p
    } else {
        -2.0 - p
    }
}

/// The pseudo-angle of a true angle in `[0, pi / 2]`.
pub fn pseudo_of_angle(rad: f32) -> f32 {
    pseudo_angle(math::sin(rad), math::cos(rad))
}

/// Tile index of a continuous tile coordinate, clamped to `0..n`.
#[inline]
pub fn tile_coord(x: f32, n: u32) -> u32 {
    if x.is_nan() || x <= 0.0 {
        return 0;
    }
    (x as u32).min(n - 1)
}

/// One built grid (camera or light): the cell ranges over the sorted
/// triangle list. Cell id = `tile * slices + slice`, so a tile's cells are
/// contiguous, front to back.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CellsInfo {
    /// Tiles per side.
    pub tiles: [u32; 2],
    pub depth: Slices,
    /// (triangle, cell) pairs.
    pub refs: u32,
    /// Triangles listed in at least one cell.
    pub mapped: u32,
    /// Triangles left out as back faces (camera grid, `cull_backfaces`).
    pub backfaces: u32,
    /// Time of the build in nanoseconds (0 without `std`).
    pub build_ns: u64,
}

impl CellsInfo {
    pub fn cells(&self) -> u32 {
        self.tiles[0] * self.tiles[1] * self.depth.count
    }
}

/// A built grid's cells, read-only.
#[derive(Clone, Copy, Debug)]
pub struct CellsView<'r> {
    pub start: &'r [u32],
    pub tris: &'r [u32],
    pub info: CellsInfo,
}

impl<'r> CellsView<'r> {
    /// Triangles of cell (tile, slice).
    #[inline]
    pub fn cell(&self, tile: u32, slice: u32) -> &'r [u32] {
        let c = (tile * self.info.depth.count + slice) as usize;
        &self.tris[self.start[c] as usize..self.start[c + 1] as usize]
    }
}

/// The scene's triangles by id (the pgrid's store).
pub use crate::geom::TriStore as Triangles;

/// Pools of the perspective and light grids, carved at context creation.
pub struct PgridPools<'a> {
    /// Scene triangles by id, their projection data, and 1 for traceable.
    pub tris: &'a mut [TriVerts],
    pub proj: &'a mut [ProjTri],
    pub ok: &'a mut [u8],
    /// Per triangle, the camera grid's padded pixel bounds `[x0, y0, x1,
    /// y1]` (per-quad culling in `traverse_primary`); after a light grid
    /// build, that grid's padded (a, b) bounds `[a0, b0, a1, b1]` instead
    /// (per-quad culling in `traverse_shadow`). One pool: a frame traces
    /// its camera rays before any shadow ray.
    pub px_box: &'a mut [[f32; 4]],
    /// Camera grid: cell starts (cells + 1) and sorted triangle ids (refs).
    pub cam_start: &'a mut [u32],
    pub cam_tris: &'a mut [u32],
    /// Light grid: the same.
    pub light_start: &'a mut [u32],
    pub light_tris: &'a mut [u32],
    /// Sort keys of the pairs (refs), and radix sort scratch (max of refs
    /// and frame pixels) shared by the builds and the ray reordering.
    pub keys: &'a mut [u32],
    pub tmp_keys: &'a mut [u32],
    pub tmp_vals: &'a mut [u32],
    /// Radix counts of the joined sorts: `mem::sort::BUCKETS` per worker,
    /// `MAX_WORKERS` workers.
    pub counts: &'a mut [u32],
}

/// Radix counts of the perspective grids' joined sorts.
const COUNTS: usize = crate::mem::par::MAX_WORKERS * crate::mem::sort::BUCKETS;

impl<'a> PgridPools<'a> {
    /// The perspective and light grids' pools under `l` (empty without
    /// `Limits::PGRID`): the triangles, `pgrid_cells` cells (plus the end)
    /// and `pgrid_refs` pairs per grid, sort scratch for the larger of
    /// the pairs and the frame's pixels, and the sorts' radix counts.
    #[deny(clippy::arithmetic_side_effects)]
    pub fn carve(a: &mut impl Carve<'a>, l: &Limits) -> Result<Self> {
        use crate::mem::{TOO_BIG, entries, when};
        let on = l.has(Limits::PGRID);
        let n = when(on, l.max_triangles as usize);
        let rule = |v: u64| if on { entries(v) } else { Ok(0) };
        let cells = when(on, rule(l.pgrid_cells())?.checked_add(1).ok_or(TOO_BIG)?);
        let refs = rule(l.pgrid_refs())?;
        let sort = rule(l.pgrid_refs().max(l.frame_pixels()))?;
        Ok(PgridPools {
            tris: a.take(n)?,
            proj: a.take(when(l.projection_test, n))?,
            ok: a.take(n)?,
            px_box: a.take(n)?,
            cam_start: a.take(cells)?,
            cam_tris: a.take(refs)?,
            light_start: a.take(cells)?,
            light_tris: a.take(refs)?,
            keys: a.take(refs)?,
            tmp_keys: a.take(sort)?,
            tmp_vals: a.take(sort)?,
            counts: a.take(when(cells > 0, COUNTS))?,
        })
    }
}

/// The scene as loaded for the perspective grids.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SceneInfo {
    pub triangles: u32,
    /// Triangles excluded (degenerate or not finite).
    pub excluded: u32,
    pub bounds: Aabb,
    pub params: Option<PgridParams>,
}

/// Perspective and light grids of one context.
pub struct Pgrid<'a> {
    pub pools: PgridPools<'a>,
    pub scene: SceneInfo,
    pub cam: CellsInfo,
    pub pinhole: Pinhole,
    pub cam_built: bool,
    pub light: CellsInfo,
    pub light_frame: LightFrame,
    pub light_built: bool,
}

impl<'a> Pgrid<'a> {
    pub fn new(pools: PgridPools<'a>) -> Self {
        Pgrid {
            pools,
            scene: SceneInfo::default(),
            cam: CellsInfo::default(),
            pinhole: Pinhole::default(),
            cam_built: false,
            light: CellsInfo::default(),
            light_frame: LightFrame::default(),
            light_built: false,
        }
    }

    /// Scene triangles, once `load` succeeded.
    pub fn triangles(&self) -> Option<Triangles<'_>> {
        self.scene.params?;
        Some(Triangles {
            tris: &self.pools.tris[..self.scene.triangles as usize],
            proj: &self.pools.proj[..if self.pools.proj.is_empty() {
                0
            } else {
                self.scene.triangles as usize
            }],
        })
    }

    /// The camera grid, once built.
    pub fn camera(&self) -> Option<CamView<'_>> {
        if !self.cam_built {
            return None;
        }
        Some(CamView {
            tris: self.triangles()?,
            cells: CellsView {
                start: self.pools.cam_start,
                tris: self.pools.cam_tris,
                info: self.cam,
            },
            pinhole: self.pinhole,
            test: self.scene.params?.test,
            isa: self.scene.params?.isa,
            tile: self.scene.params?.tile,
            px_box: &self.pools.px_box[..self.scene.triangles as usize],
            filter: crate::geom::Hook::None,
        })
    }

    /// The light grid of the last `build_light`, once built.
    pub fn light_view(&self) -> Option<LightView<'_>> {
        if !self.light_built {
            return None;
        }
        Some(LightView {
            tris: self.triangles()?,
            cells: CellsView {
                start: self.pools.light_start,
                tris: self.pools.light_tris,
                info: self.light,
            },
            frame: self.light_frame,
            test: self.scene.params?.test,
            isa: self.scene.params?.isa,
            ab_box: &self.pools.px_box[..self.scene.triangles as usize],
            filter: crate::geom::Hook::None,
        })
    }
}

/// A built perspective grid, ready to trace camera rays.
#[derive(Clone, Copy, Debug)]
pub struct CamView<'r> {
    pub tris: Triangles<'r>,
    pub cells: CellsView<'r>,
    pub pinhole: Pinhole,
    pub test: TriTest,
    /// Lane width of the triangle tests (`PgridParams::isa`).
    pub isa: Isa,
    /// Sorting tile side in pixels.
    pub tile: u32,
    /// Padded pixel bounds of every triangle.
    pub px_box: &'r [[f32; 4]],
    /// Who decides on each candidate hit (`geom::filter`).
    pub filter: crate::geom::Hook<'r>,
}

/// A built light grid, ready to trace shadow rays from its light.
#[derive(Clone, Copy, Debug)]
pub struct LightView<'r> {
    pub tris: Triangles<'r>,
    pub cells: CellsView<'r>,
    pub frame: LightFrame,
    pub test: TriTest,
    /// Lane width of the triangle tests, as `CamView::isa`.
    pub isa: Isa,
    /// Padded (a, b) bounds of every triangle listed in the grid.
    pub ab_box: &'r [[f32; 4]],
    /// Who decides on each candidate hit (`geom::filter`).
    pub filter: crate::geom::Hook<'r>,
}
