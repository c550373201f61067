//! Uniform grid rebuilt from scratch every frame, with a macrocell layer.
//!
//! Source: Wald, Ize, Kensler, Knoll, Parker 2006, "Ray Tracing Animated
//! Scenes using Coherent Grid Traversal".
//!
//! | file | implements |
//! |---|---|
//! | `build.rs` | section 3: resolution from lambda x N, bounding-box insertion with a counting sort into preallocated pools; section 2.4: macrocell occupancy flags |
//! | `traverse_cgt.rs` | sections 2.2-2.4: coherent grid traversal of n x n packets: slices, frustum, macrocells, mailboxing, SIMD frustum culling; incoherent and over-wide packets fall back to the 3DDDA (sections 2.2, 4.7; `trace::fallback`) |
//! | `traverse_single.rs` | the single-ray baseline: 3DDDA (Amanatides and Woo 1987) with macrocell skipping, nearest hit and occlusion |
//!
//! # Deviations
//! - Triangle boxes are widened by `INSERT_EPS` cells before insertion, so a
//!   3DDDA whose cell stepping rounds to the neighbouring cell still finds
//!   the triangle (exactness over a few extra references).
//! - The counting sort needs the exact reference count before anything is
//!   written, so the build reads the triangles three times; in exchange a
//!   capacity error leaves the previous frame's grid untouched.

pub mod build;
pub mod traverse_cgt;
pub mod traverse_single;

use crate::counters::Counters;
use crate::error::Result;
use crate::geom::{Aabb, Hit, Hook, ProjTri, Ray, TriTest, TriVerts, TriangleTest};
use crate::mem::{Carve, Limits, TOO_BIG, entries, when};
use glam::Vec3;

/// Slot scratch this module's packet code takes (`accel::slot`): a CGT
/// packet's per-quad state, for packets of up to `q` quads.
pub const fn scratch(q: usize) -> usize {
    traverse_cgt::scratch(q)
}

/// Tunables of the grid (C: `sheaf_grid_params`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridParams {
    /// Cells per triangle, lambda (section 3, Figure 6: best near 5).
    pub lambda: f32,
    /// Macrocell side M in cells (section 2.4: M = 6); 0 or 1 disables macrocells.
    pub macrocell: u32,
    /// Ray-triangle test used by every traversal of this grid.
    pub test: TriTest,
    /// When the cells for `lambda` exceed `Limits::max_grid_cells`, lower
    /// lambda to fit instead of failing.
    pub fit: bool,
}

impl Default for GridParams {
    fn default() -> Self {
        GridParams {
            lambda: 5.0,
            macrocell: 6,
            test: TriTest::MollerTrumbore,
            fit: false,
        }
    }
}

/// What the last build produced (all counts exact).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GridInfo {
    /// Cells per axis.
    pub res: [u32; 3],
    /// World-space bounds of the grid (the valid triangles' bounds, padded
    /// so no axis is flat).
    pub bounds: Aabb,
    /// Bounds of the stored triangles, unpadded (what `BvhInfo::bounds`
    /// holds too: the scene scale shading offsets derive from).
    pub scene_bounds: Aabb,
    pub cell_size: Vec3,
    /// Cells per world unit, per axis.
    pub inv_cell: Vec3,
    /// Macrocell side M (1: no macrocells) and macrocells per axis.
    pub macrocell: u32,
    pub macro_res: [u32; 3],
    /// Triangles in the scene, stored, and excluded (non-finite / zero area).
    pub triangles_in: u32,
    pub triangles: u32,
    pub excluded_non_finite: u32,
    pub excluded_zero_area: u32,
    /// Triangle references in cells.
    pub refs: u32,
    /// Lambda actually used (lower than asked only in fit mode).
    pub lambda: f32,
    pub test: TriTest,
}

impl GridInfo {
    pub fn cells(&self) -> u64 {
        self.res[0] as u64 * self.res[1] as u64 * self.res[2] as u64
    }
}

/// The pools a grid lives in (carved once from the arena).
pub struct GridPools<'a> {
    pub tris: &'a mut [TriVerts],
    /// Projection-test data (empty unless `Limits::projection_test`).
    pub proj: &'a mut [ProjTri],
    pub tri_ids: &'a mut [u32],
    pub cell_start: &'a mut [u32],
    pub refs: &'a mut [u32],
    pub macro_bits: &'a mut [u32],
}

impl<'a> GridPools<'a> {
    /// The grid's pools under `l` (empty without `Limits::GRID`): the
    /// triangles, `grid_cells` cells (plus the end), `grid_refs`
    /// references and a bit per 32 macrocells. Every size checked.
    #[deny(clippy::arithmetic_side_effects)]
    pub fn carve(a: &mut impl Carve<'a>, l: &Limits) -> Result<Self> {
        let on = l.has(Limits::GRID);
        let n = when(on, l.max_triangles as usize);
        let cells = if on { entries(l.grid_cells())? } else { 0 };
        Ok(GridPools {
            tris: a.take(n)?,
            proj: a.take(when(l.projection_test, n))?,
            tri_ids: a.take(n)?,
            cell_start: a.take(cells.checked_add(1).ok_or(TOO_BIG)?)?,
            refs: a.take(if on { entries(l.grid_refs())? } else { 0 })?,
            macro_bits: a.take(when(on, cells.div_ceil(32).checked_add(1).ok_or(TOO_BIG)?))?,
        })
    }
}

/// A per-frame grid: pools plus what the last successful build wrote.
pub struct Grid<'a> {
    pools: GridPools<'a>,
    info: Option<GridInfo>,
}

/// Read-only view of a built grid; `Sync`, shared by all tracing threads.
#[derive(Clone, Copy)]
pub struct GridView<'r> {
    pub info: &'r GridInfo,
    /// Stored triangles (compact order) and their ids in the caller's index buffer.
    pub tris: &'r [TriVerts],
    /// Projection-test data of the stored triangles (empty for other tests).
    pub proj: &'r [ProjTri],
    pub tri_ids: &'r [u32],
    /// Cell `c` holds `refs[cell_start[c]..cell_start[c + 1]]`, cells in x-fastest order.
    pub cell_start: &'r [u32],
    pub refs: &'r [u32],
    /// One bit per macrocell, set when any of its cells holds a reference.
    pub macro_bits: &'r [u32],
    /// Who decides on each candidate hit (`geom::filter`).
    pub filter: Hook<'r>,
}

impl<'a> Grid<'a> {
    pub(crate) fn pools_mut(&mut self) -> &mut GridPools<'a> {
        &mut self.pools
    }
    pub(crate) fn set_info(&mut self, info: GridInfo) {
        self.info = Some(info);
    }
    pub fn new(pools: GridPools<'a>) -> Self {
        Grid { pools, info: None }
    }
    /// The last successful build, if any.
    pub fn view(&self) -> Option<GridView<'_>> {
        let info = self.info.as_ref()?;
        let cells = info.cells() as usize;
        Some(GridView {
            info,
            tris: &self.pools.tris[..info.triangles as usize],
            proj: if info.test == TriTest::Projection {
                &self.pools.proj[..info.triangles as usize]
            } else {
                &[]
            },
            tri_ids: &self.pools.tri_ids[..info.triangles as usize],
            cell_start: &self.pools.cell_start[..cells + 1],
            refs: &self.pools.refs[..info.refs as usize],
            macro_bits: &self.pools.macro_bits[..],
            filter: Hook::None,
        })
    }
    pub fn info(&self) -> Option<&GridInfo> {
        self.info.as_ref()
    }
}

impl<'r> GridView<'r> {
    /// This view with candidate hits decided by `filter`.
    #[inline(always)]
    pub fn filtered(self, filter: Hook<'r>) -> Self {
        GridView { filter, ..self }
    }

    /// This view, without its filter when a call forces opacity
    /// (`TraceParams::opaque`).
    #[inline(always)]
    pub fn opaque_if(&self, opaque: bool) -> Self {
        if opaque {
            self.filtered(Hook::None)
        } else {
            *self
        }
    }
    /// The stored triangles, as every triangle test reads them.
    #[inline(always)]
    pub fn store(&self) -> crate::geom::TriStore<'r> {
        crate::geom::TriStore {
            tris: self.tris,
            proj: self.proj,
        }
    }
}

impl GridView<'_> {
    /// Linear index of cell (x, y, z).
    #[inline(always)]
    pub fn cell_index(&self, c: [i32; 3]) -> usize {
        let r = &self.info.res;
        (c[0] as usize) + r[0] as usize * ((c[1] as usize) + r[1] as usize * c[2] as usize)
    }
    /// References of cell `idx`.
    #[inline(always)]
    pub fn cell(&self, idx: usize) -> &[u32] {
        &self.refs[self.cell_start[idx] as usize..self.cell_start[idx + 1] as usize]
    }
    /// Whether macrocell (x, y, z) holds any reference.
    #[inline(always)]
    pub fn macro_occupied(&self, m: [i32; 3]) -> bool {
        let r = &self.info.macro_res;
        let i = (m[0] as usize) + r[0] as usize * ((m[1] as usize) + r[1] as usize * m[2] as usize);
        self.macro_bits[i >> 5] & (1 << (i & 31)) != 0
    }
}

/// The grid under the family contract: the 3DDDA for single rays, CGT for
/// `Method::GridCgt` packets (the 2x2 SIMD ray goes lane by lane).
impl crate::accel::Accel for GridView<'_> {
    #[inline]
    fn test(&self) -> TriTest {
        self.info.test
    }
    // The contract's bounds are the stored triangles' (unpadded), which the
    // grid keeps in `scene_bounds`; its `bounds` field is the padded grid box.
    #[allow(clippy::misnamed_getters)]
    #[inline]
    fn bounds(&self) -> Aabb {
        self.info.scene_bounds
    }
    fn triangle(&self, prim: u32) -> Option<TriVerts> {
        // Stored triangles are in the caller's order minus exclusions, so a
        // binary search over the ids finds the slot.
        let i = self.tri_ids.binary_search(&prim).ok()?;
        Some(self.tris[i])
    }
    #[inline]
    fn intersect<T: TriangleTest>(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
        traverse_single::intersect::<T>(self, ray, ctr)
    }
    #[inline]
    fn occluded<T: TriangleTest>(&self, ray: &Ray, ctr: &mut Counters) -> bool {
        traverse_single::occluded::<T>(self, ray, ctr)
    }
    #[inline]
    fn any_hit<T: TriangleTest>(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
        traverse_single::any_hit::<T>(self, ray, ctr)
    }
}
