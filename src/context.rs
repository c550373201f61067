//! The context: every pool carved from one buffer at creation, then reused by
//! every frame. After `Context::new_in` nothing here allocates.
#![forbid(unsafe_code)]

use crate::accel::bvh::refit::{RefitInfo, RefitParams};
use crate::accel::bvh::{self, Bvh, BvhInfo, BvhParams, BvhPools};
use crate::accel::grid::{self, Grid, GridInfo, GridParams, GridPools};
use crate::accel::kd::{self, KdInfo, KdParams, KdPools, KdTree};
use crate::accel::pgrid::{self, Pgrid, PgridParams, PgridPools, SceneInfo};
use crate::accel::slot::{Slot, accel_scratch, max};
use crate::accel::twolevel::{self, TwoLevel};
use crate::counters::{elapsed_ns, now};
use crate::error::{Error, Pool, Result};
use crate::geom::{Hit, Hit4, Ray, Scene};
use crate::mem::{Arena, Carve, Limits, Sizer, Slots};
use crate::render::deferred::{
    self, DeferredInfo, DeferredJob, FrameBuffers, PrimaryPass, ShadowPass, TileLayout, Workers,
};
use crate::render::whitted::{self, WhittedJob};
use crate::render::{
    self, Band, CameraRays, Frame, PixelRect, PointLight, PrimaryRays, TileParams, Tracer,
};
mod scene;

pub use crate::trace::SceneTracer;
pub use crate::trace::scene::{BvhTracer, GridTracer, KdTracer};
use crate::trace::{
    Counters, HitStream, Method, RaySource, RayStream, TraceParams, batch_on, per_ray,
};

/// Scratch bytes of one thread slot under `l`, the one sum of every
/// module's declared scratch: over the calls `l` allows, the most a caller
/// of the packet driver holds plus what the driver and a family of
/// `structures` take under it (`accel::slot::accel_scratch`). The callers:
/// `trace::batch_on`'s packet; a two-level batch with `max_geometries`
/// (its geometries are BVHs, its flattened scene a grid or kd-tree); per renderer in `renderers`, a render tile,
/// a Whitted tile's `max_bounces + 1` levels, a deferred frame's tiles
/// (`deferred::scratch`, with its perspective and light grids). All for
/// packets of up to `max_packet_side` squared rays: calls beyond these
/// limits are refused with a status before they take any scratch.
pub const fn slot_scratch_bytes(l: &Limits) -> usize {
    let q = crate::accel::packet::quads(l.max_packet_side);
    let accel = accel_scratch(q, l.structures);
    let mut most = crate::trace::scene::scratch(q) + accel;
    if l.max_geometries > 0 {
        // The geometries' BVHs under the top level (which splits off tiny
        // lanes itself, without the driver), or the flattened scene's grid
        // or kd-tree under the driver.
        let flat = l.structures & (Limits::GRID | Limits::KD);
        let flat = if flat != 0 { accel_scratch(q, flat) } else { 0 };
        let under = max(crate::accel::bvh::scratch(q), flat);
        most = max(most, scene::scratch(q) + under);
    }
    if l.renders(Limits::TILES) {
        most = max(most, render::scratch(q) + accel);
    }
    if l.renders(Limits::WHITTED) {
        most = max(most, whitted::scratch(q, l.max_bounces) + accel);
    }
    if l.renders(Limits::DEFERRED) && l.has(Limits::PGRID) {
        most = max(most, deferred::scratch(q, accel));
    }
    most.next_multiple_of(crate::mem::arena::ARENA_ALIGN)
}

/// Pool sizes derived from `Limits`, in the order they are carved. A
/// structure left out of `Limits::structures` gets empty pools.
struct Layout {
    tris: usize,
    proj: usize,
    cells: usize,
    refs: usize,
    macro_words: usize,
    slots: usize,
    /// Scratch bytes per thread slot (`slot_scratch_bytes`).
    slot_scratch: usize,
    /// Mailbox stamps per thread slot: one per triangle with a grid or
    /// perspective grids (the structures that meet triangles repeatedly).
    stamps: usize,
    /// BVH: triangles (0 without `Limits::BVH`) and their projection data.
    bvh_tris: usize,
    bvh_proj: usize,
    /// kd-tree: triangles (0 without `Limits::KD`), projection data, nodes,
    /// leaf references, build events.
    kd_tris: usize,
    kd_proj: usize,
    kd_nodes: usize,
    kd_refs: usize,
    kd_events: usize,
    /// Perspective/light grids (0 without `Limits::PGRID`): triangles,
    /// cells + 1 and pairs of each grid, sort scratch, frame pixels, chunks.
    pg_tris: usize,
    pg_proj: usize,
    pg_cells: usize,
    pg_refs: usize,
    pg_scratch: usize,
    px: usize,
    chunks: usize,
    /// Two-level scene (0 without `Limits::max_geometries`): the
    /// geometries' triangle budget and its projection data, geometries,
    /// instances.
    sc_tris: usize,
    sc_proj: usize,
    sc_geoms: usize,
    sc_insts: usize,
    /// The two-level scene flattened into world triangles for the grid,
    /// kd-tree and perspective grids (`twolevel::flatten`): `max_triangles`
    /// with a two-level scene and one of them, else 0.
    flat: usize,
}

/// A pool size from a u64 rule, refused when it does not fit a `usize`
/// (32-bit targets).
fn entries(v: u64) -> Result<usize> {
    usize::try_from(v)
        .map_err(|_| Error::InvalidArgument("limits need more memory than can be addressed"))
}

/// Sizes and byte sums of the layout: every operation checked (the lints
/// make an unchecked one a build error), so no `Limits`, on 32 or 64 bits,
/// can wrap a size into a small buffer.
#[deny(clippy::arithmetic_side_effects, clippy::cast_possible_truncation)]
impl Layout {
    fn of(l: &Limits) -> Result<Layout> {
        l.validate()?;
        let n = l.max_triangles as usize;
        let grid = l.has(Limits::GRID);
        let cells = if grid { entries(l.grid_cells())? } else { 0 };
        let bvh_tris = if l.has(Limits::BVH) { n } else { 0 };
        let kd = l.has(Limits::KD);
        let kd_tris = if kd { n } else { 0 };
        let pg = l.has(Limits::PGRID);
        let px = if pg { entries(l.frame_pixels())? } else { 0 };
        let big = Error::InvalidArgument("limits need more memory than can be addressed");
        Ok(Layout {
            tris: if grid { n } else { 0 },
            proj: if grid && l.projection_test { n } else { 0 },
            cells,
            refs: if grid { entries(l.grid_refs())? } else { 0 },
            macro_words: if grid {
                cells.div_ceil(32).checked_add(1).ok_or(big)?
            } else {
                0
            },
            slots: l.max_threads as usize,
            slot_scratch: slot_scratch_bytes(l),
            stamps: if grid || pg { n } else { 0 },
            bvh_tris,
            bvh_proj: if l.projection_test { bvh_tris } else { 0 },
            kd_tris,
            kd_proj: if l.projection_test { kd_tris } else { 0 },
            kd_nodes: if kd { entries(l.kd_nodes())? } else { 0 },
            kd_refs: if kd { entries(l.kd_refs())? } else { 0 },
            kd_events: if kd { entries(l.kd_events())? } else { 0 },
            pg_tris: if pg { n } else { 0 },
            pg_proj: if pg && l.projection_test { n } else { 0 },
            pg_cells: if pg {
                entries(l.pgrid_cells())?.checked_add(1).ok_or(big)?
            } else {
                0
            },
            pg_refs: if pg { entries(l.pgrid_refs())? } else { 0 },
            pg_scratch: if pg {
                entries(l.pgrid_refs().max(l.frame_pixels()))?
            } else {
                0
            },
            px,
            chunks: if pg {
                px.checked_div(pgrid::MIN_CHUNK as usize)
                    .and_then(|c| c.checked_add(px.min(pgrid::MAX_LIGHT_TILES)))
                    .ok_or(big)?
            } else {
                0
            },
            sc_tris: l.scene_triangles() as usize,
            sc_proj: if l.projection_test {
                l.scene_triangles() as usize
            } else {
                0
            },
            sc_geoms: l.max_geometries as usize,
            sc_insts: l.scene_instances() as usize,
            flat: if l.max_geometries > 0 && l.has(Limits::GRID | Limits::KD | Limits::PGRID) {
                n
            } else {
                0
            },
        })
    }
}

/// Radix counts of the perspective grids' joined sorts.
const PG_COUNTS: usize = crate::mem::par::MAX_WORKERS * crate::mem::sort::BUCKETS;

/// The thread slots' pools: mailbox stamps, packet counters, scratch,
/// scratch marks and claim flags (`Slots::new`).
type SlotPools<'a> = (
    &'a mut [u32],
    &'a mut [u32],
    &'a mut [u8],
    &'a mut [u32],
    &'a mut [u32],
);

/// Every pool of a context, as `carve` takes them.
struct Pools<'a> {
    grid: GridPools<'a>,
    /// Mailbox stamps, packet counters, scratch, scratch marks and claim
    /// flags of the thread slots.
    slots: SlotPools<'a>,
    bvh: BvhPools<'a>,
    kd: KdPools<'a>,
    pg: PgridPools<'a>,
    frame: FrameBuffers<'a>,
    /// The two-level scene's pools, its geometry table as bytes (a table
    /// of `GeomState`, made in `new_in`).
    scene: (SceneBlas<'a>, &'a mut [u8]),
    flat: twolevel::flatten::FlatPools<'a>,
}

/// The two-level scene's pools but its geometry table.
struct SceneBlas<'a> {
    blas: BvhPools<'a>,
    runs: &'a mut [crate::mem::regions::Run],
    insts: &'a mut [twolevel::Instance],
    tlas: &'a mut [bvh::BvhNode],
    order: &'a mut [u32],
}

/// The one list of a context's pools: `required_bytes` runs it over a
/// `Sizer`, `Context::new_in` over the caller's buffer, so the two agree
/// by construction. Sizes derived here are checked, as in `Layout::of`.
#[deny(clippy::arithmetic_side_effects)]
fn carve<'a>(a: &mut impl Carve<'a>, l: &Layout) -> Result<Pools<'a>> {
    let big = Error::InvalidArgument("limits need more memory than can be addressed");
    let twice = |n: usize| n.checked_mul(2).ok_or(big);
    Ok(Pools {
        grid: GridPools {
            tris: a.take(l.tris)?,
            proj: a.take(l.proj)?,
            tri_ids: a.take(l.tris)?,
            cell_start: a.take(l.cells.checked_add(1).ok_or(big)?)?,
            refs: a.take(l.refs)?,
            macro_bits: a.take(l.macro_words)?,
        },
        slots: (
            a.take(l.stamps.checked_mul(l.slots).ok_or(big)?)?,
            a.take(l.slots)?,
            a.take(l.slot_scratch.checked_mul(l.slots).ok_or(big)?)?,
            a.take(l.slots)?,
            a.take(l.slots)?,
        ),
        bvh: BvhPools {
            nodes: a.take(twice(l.bvh_tris)?)?,
            tris: a.take(l.bvh_tris)?,
            proj: a.take(l.bvh_proj)?,
            tri_ids: a.take(l.bvh_tris)?,
            slot_of: a.take(l.bvh_tris)?,
            refs: a.take(l.bvh_tris)?,
            scratch: a.take(if l.bvh_tris > 0 {
                bvh::build::SCRATCH
            } else {
                0
            })?,
        },
        kd: KdPools {
            nodes: a.take(l.kd_nodes)?,
            refs: a.take(l.kd_refs)?,
            tris: a.take(l.kd_tris)?,
            proj: a.take(l.kd_proj)?,
            tri_ids: a.take(l.kd_tris)?,
            slot_of: a.take(l.kd_tris)?,
            events: a.take(l.kd_events)?,
            side: a.take(l.kd_tris)?,
        },
        pg: PgridPools {
            tris: a.take(l.pg_tris)?,
            proj: a.take(l.pg_proj)?,
            ok: a.take(l.pg_tris)?,
            px_box: a.take(l.pg_tris)?,
            cam_start: a.take(l.pg_cells)?,
            cam_tris: a.take(l.pg_refs)?,
            light_start: a.take(l.pg_cells)?,
            light_tris: a.take(l.pg_refs)?,
            keys: a.take(l.pg_refs)?,
            tmp_keys: a.take(l.pg_scratch)?,
            tmp_vals: a.take(l.pg_scratch)?,
            counts: a.take(if l.pg_cells > 0 { PG_COUNTS } else { 0 })?,
        },
        frame: FrameBuffers {
            prim: a.take(l.px)?,
            t: a.take(l.px)?,
            dirs: a.take(l.px)?,
            shadow: a.take(l.px)?,
            ray_tiles: a.take(l.px)?,
            ray_ids: a.take(l.px)?,
            occ: a.take(l.px)?,
            chunks: a.take(l.chunks)?,
            reach: a.take(if l.px > 0 { pgrid::MAX_LIGHT_TILES } else { 0 })?,
        },
        scene: (
            SceneBlas {
                blas: BvhPools {
                    nodes: a.take(twice(l.sc_tris)?)?,
                    tris: a.take(l.sc_tris)?,
                    proj: a.take(l.sc_proj)?,
                    tri_ids: a.take(l.sc_tris)?,
                    slot_of: a.take(l.sc_tris)?,
                    refs: a.take(l.sc_tris)?,
                    scratch: a.take(if l.sc_geoms > 0 {
                        bvh::build::SCRATCH
                    } else {
                        0
                    })?,
                },
                runs: a.take(if l.sc_geoms > 0 {
                    l.sc_geoms.checked_add(1).ok_or(big)?
                } else {
                    0
                })?,
                insts: a.take(l.sc_insts)?,
                tlas: a.take(twice(l.sc_insts)?)?,
                order: a.take(l.sc_insts)?,
            },
            a.take(
                crate::mem::scratch::bytes::<twolevel::GeomState>(1)
                    .checked_mul(l.sc_geoms)
                    .ok_or(big)?,
            )?,
        ),
        flat: twolevel::flatten::FlatPools {
            tris: a.take(l.flat)?,
            indices: a.take(l.flat.checked_mul(3).ok_or(big)?)?,
            ids: a.take(l.flat)?,
        },
    })
}

/// Exact number of bytes `Context::new_in` needs for `limits` (the buffer
/// must also start on a 64-byte boundary).
pub fn required_bytes(limits: &Limits) -> Result<usize> {
    let mut sizer = Sizer::default();
    carve(&mut sizer, &Layout::of(limits)?)?;
    Ok(sizer.bytes())
}

/// Statistics of the last build and the last trace/render call.
#[derive(Clone, Copy, Debug, Default)]
pub struct Stats {
    pub grid: GridInfo,
    /// Wall time of the last grid build in nanoseconds (0 without `std`).
    pub build_ns: u64,
    pub bvh: BvhInfo,
    /// Wall time of the last BVH build in nanoseconds (0 without `std`).
    pub bvh_build_ns: u64,
    pub kd: KdInfo,
    /// Wall time of the last kd-tree build in nanoseconds (0 without `std`).
    pub kd_build_ns: u64,
    /// Triangles loaded for the perspective/light grids (`build_pgrid`).
    pub pgrid: SceneInfo,
    /// Phases of the last deferred frame (`render_deferred`).
    pub deferred: DeferredInfo,
    /// Counters of the last trace, occluded or render call.
    pub counters: Counters,
    /// Wall time of the last trace, occluded or render call (0 without `std`).
    pub trace_ns: u64,
}

/// A sheaf context: fixed pools, the current structure, per-thread slots.
///
/// Thread safety: `&Context` may be shared by threads that trace or render
/// (those take `&self`); `build` takes `&mut self`.
pub struct Context<'a> {
    limits: Limits,
    grid: Grid<'a>,
    bvh: Bvh<'a>,
    kd: KdTree<'a>,
    pgrid: Pgrid<'a>,
    /// The two-level scene (`accel::twolevel`; empty pools without
    /// `Limits::max_geometries`).
    scene: TwoLevel<'a>,
    /// The two-level scene in world triangles, and which commit each
    /// structure was built from (`context::scene`).
    flat: twolevel::flatten::Flat<'a>,
    sources: scene::Sources,
    frame: FrameBuffers<'a>,
    /// Layout of the frame buffers in the last deferred frame, its
    /// camera rays and shadow-ray offset.
    frame_layout: Option<TileLayout>,
    frame_rays: Option<(PrimaryRays, f32)>,
    /// Per-thread slots, each a mailbox (CGT section 2.3: `max_triangles`
    /// stamps and a packet counter) and `slot_scratch_bytes` of scratch
    /// (packets, traversal state), claimed by `*_in_slot` calls.
    slots: Slots<'a>,
    stats: Stats,
    /// The allocation the pools above borrow, for a context made by
    /// `Context::new` (`OwnedContext`): last, so it is freed after them.
    #[cfg(feature = "std")]
    owned: Option<crate::mem::owned::OwnedBuffer>,
}

impl<'a> Context<'a> {
    /// Create a context over `buf` (at least `required_bytes(limits)` bytes,
    /// 64-byte aligned). Never allocates (but the process's first context
    /// copies `SHEAF_ISA` when that is set: `crate::isa`).
    pub fn new_in(buf: &'a mut [u8], limits: &Limits) -> Result<Context<'a>> {
        // SHEAF_ISA, once per process (allocates only when it is set).
        crate::isa::read_env();
        let need = required_bytes(limits)?;
        if buf.len() < need {
            return Err(Error::BufferTooSmall {
                needed: need as u64,
                available: buf.len() as u64,
            });
        }
        let mut arena = Arena::new(buf)?;
        let Pools {
            grid: pools,
            slots: (stamps, packets, scratch, low, busy),
            bvh,
            kd,
            pg,
            frame,
            scene: (sc, geom_bytes),
            flat,
        } = carve(&mut arena, &Layout::of(limits)?)?;
        let slots = Slots::new(stamps, packets, scratch, low, busy);
        let n_geoms = limits.max_geometries as usize;
        let (geoms, _) =
            crate::mem::Scratch::new(geom_bytes).take(n_geoms, twolevel::GeomState::default());
        let scene = TwoLevel::new(twolevel::TwoLevelPools {
            blas: sc.blas,
            runs: sc.runs,
            geoms,
            insts: sc.insts,
            tlas: sc.tlas,
            order: sc.order,
        });
        debug_assert_eq!(arena.used(), need);
        Ok(Context {
            limits: *limits,
            grid: Grid::new(pools),
            bvh: Bvh::new(bvh),
            kd: KdTree::new(kd),
            pgrid: Pgrid::new(pg),
            scene,
            flat: twolevel::flatten::Flat::new(flat),
            sources: scene::Sources::default(),
            frame,
            frame_layout: None,
            frame_rays: None,
            slots,
            stats: Stats::default(),
            #[cfg(feature = "std")]
            owned: None,
        })
    }

    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// Statistics of the last build and trace/render call.
    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// The most slot scratch any call has used since creation, in bytes,
    /// against `slot_scratch_bytes(self.limits())` reserved per slot: what
    /// a caller tuning `Limits` (packet side, bounces, renderers) can
    /// measure on its own frames.
    pub fn scratch_high_water(&mut self) -> usize {
        self.slots.scratch_high_water()
    }

    /// Check `scene` against the limits without building.
    pub fn check_scene(&self, scene: &Scene<'_>) -> Result<()> {
        if scene.triangle_count() > self.limits.max_triangles {
            return Err(Error::Capacity {
                pool: Pool::Triangles,
                needed: scene.triangle_count() as u64,
                available: self.limits.max_triangles as u64,
            });
        }
        if scene.vertex_count() > self.limits.max_vertices {
            return Err(Error::Capacity {
                pool: Pool::Vertices,
                needed: scene.vertex_count() as u64,
                available: self.limits.max_vertices as u64,
            });
        }
        Ok(())
    }

    /// Rebuild the grid from `scene`. On error the previous grid stays valid.
    pub fn build_grid(&mut self, scene: &Scene<'_>, params: &GridParams) -> Result<GridInfo> {
        self.build_grid_with(scene, params, &crate::Serial)
    }

    /// `build_grid` on the caller's workers (as `build_bvh_with`): every
    /// step but the resolution split among them; the same grid for any
    /// number of workers.
    pub fn build_grid_with(
        &mut self,
        scene: &Scene<'_>,
        params: &GridParams,
        par: &dyn crate::Par,
    ) -> Result<GridInfo> {
        self.check_scene(scene)?;
        let info = self.grid_over(scene, params, par)?;
        self.sources.set(Limits::GRID, None);
        Ok(info)
    }

    /// The grid build after the scene's checks (`build_grid_with`, and
    /// the flattened two-level scene's).
    fn grid_over(
        &mut self,
        scene: &Scene<'_>,
        params: &GridParams,
        par: &dyn crate::Par,
    ) -> Result<GridInfo> {
        if !self.limits.has(Limits::GRID) {
            return Err(Error::InvalidArgument(
                "no grid pools: Limits::structures lacks GRID",
            ));
        }
        let t = now();
        let info = grid::build::build_with(
            &mut self.grid,
            scene,
            params,
            self.limits.grid_cells(),
            self.limits.grid_refs(),
            par,
        )?;
        self.stats.build_ns = elapsed_ns(t);
        self.stats.grid = info;
        Ok(info)
    }

    /// Rebuild the BVH from `scene` (binned SAH, BVH paper section 5.1).
    /// On error the previous BVH stays valid.
    pub fn build_bvh(&mut self, scene: &Scene<'_>, params: &BvhParams) -> Result<BvhInfo> {
        self.build_bvh_with(scene, params, &crate::Serial)
    }

    /// `build_bvh` on the caller's workers (`mem::par::Par`: a thread
    /// pool's broadcast, or threads joined through `mem::par::Join`); sheaf
    /// starts no thread. The fast build (`BuildQuality::Low`) runs every
    /// step on them and gives the same tree for any number of workers; the
    /// SAH builds run on the calling thread.
    pub fn build_bvh_with(
        &mut self,
        scene: &Scene<'_>,
        params: &BvhParams,
        par: &dyn crate::Par,
    ) -> Result<BvhInfo> {
        if !self.limits.has(Limits::BVH) {
            return Err(Error::InvalidArgument(
                "no BVH pools: Limits::structures lacks BVH",
            ));
        }
        self.check_scene(scene)?;
        let t = now();
        let info = bvh::build::build_with(&mut self.bvh, scene, params, par)?;
        self.stats.bvh_build_ns = elapsed_ns(t);
        self.stats.bvh = info;
        Ok(info)
    }

    /// Refit the built BVH to `scene`'s moved vertices (same triangles):
    /// its boxes recomputed bottom-up, its shape kept (`bvh::refit`); past
    /// `params.rebuild_above` SAH growth, rebuilt with the last build's
    /// parameters instead. On error the previous BVH stays valid (when the
    /// rebuild fails, the refit tree: exact like any tree).
    pub fn refit_bvh(&mut self, scene: &Scene<'_>, params: &RefitParams) -> Result<RefitInfo> {
        self.refit_bvh_with(scene, params, &crate::Serial)
    }

    /// `refit_bvh` on the caller's workers (as `build_bvh_with`): the
    /// triangle passes and leaf boxes are split among them, and a rebuild
    /// past `params.rebuild_above` runs on them too. The refit tree is the
    /// same for any number of workers.
    pub fn refit_bvh_with(
        &mut self,
        scene: &Scene<'_>,
        params: &RefitParams,
        par: &dyn crate::Par,
    ) -> Result<RefitInfo> {
        if !self.limits.has(Limits::BVH) {
            return Err(Error::InvalidArgument(
                "no BVH pools: Limits::structures lacks BVH",
            ));
        }
        params.validate()?;
        self.check_scene(scene)?;
        let t = now();
        let mut r = bvh::refit::refit_with(&mut self.bvh, scene, par)?;
        if params.rebuild_above > 0.0 && r.growth() > params.rebuild_above {
            let bp = self.bvh.params();
            // A failed rebuild keeps the refit tree (valid and exact).
            if let Some(info) = self.bvh.info() {
                self.stats.bvh = *info;
            }
            let info = bvh::build::build_with(&mut self.bvh, scene, &bp, par)?;
            r.rebuilt = true;
            r.sah_after = info.sah_cost;
        }
        r.ns = elapsed_ns(t);
        if let Some(info) = self.bvh.info() {
            self.stats.bvh = *info;
        }
        Ok(r)
    }

    /// Rebuild the kd-tree from `scene` (O(N log N) SAH with perfect
    /// splits, AEPSA paper section 5.1). On error the previous tree stays
    /// valid.
    pub fn build_kd(&mut self, scene: &Scene<'_>, params: &KdParams) -> Result<KdInfo> {
        self.check_scene(scene)?;
        let info = self.kd_over(scene, params)?;
        self.sources.set(Limits::KD, None);
        Ok(info)
    }

    /// The kd-tree build after the scene's checks.
    fn kd_over(&mut self, scene: &Scene<'_>, params: &KdParams) -> Result<KdInfo> {
        if !self.limits.has(Limits::KD) {
            return Err(Error::InvalidArgument(
                "no kd-tree pools: Limits::structures lacks KD",
            ));
        }
        let t = now();
        let info = kd::build::build(&mut self.kd, scene, params)?;
        self.stats.kd_build_ns = elapsed_ns(t);
        self.stats.kd = info;
        Ok(info)
    }

    /// Load `scene` for perspective grids and light grids with `params`
    /// (section 3 and 4 of the perspective/light grid paper). The grids
    /// themselves depend on the camera and the lights and are built by
    /// every `render_deferred` call that uses them.
    pub fn build_pgrid(&mut self, scene: &Scene<'_>, params: &PgridParams) -> Result<SceneInfo> {
        self.check_scene(scene)?;
        let info = self.pgrid_over(scene, params)?;
        self.sources.set(Limits::PGRID, None);
        Ok(info)
    }

    /// The perspective grids' scene load after the scene's checks.
    fn pgrid_over(&mut self, scene: &Scene<'_>, params: &PgridParams) -> Result<SceneInfo> {
        if !self.limits.has(Limits::PGRID) {
            return Err(Error::InvalidArgument(
                "no perspective grid pools: Limits::structures lacks PGRID",
            ));
        }
        params.validate()?;
        // Its sorting tiles are traced as packets of that side.
        self.limits.check_packet_side(params.tile)?;
        if params.test == crate::geom::TriTest::Projection && !self.limits.projection_test {
            return Err(Error::InvalidArgument(
                "the projection test needs Limits::projection_test",
            ));
        }
        let info = pgrid::build::load(&mut self.pgrid, scene, params)?;
        self.stats.pgrid = info;
        Ok(info)
    }

    /// Render a deferred frame (`render::deferred`): camera rays, then per
    /// light every shadow ray, then shading, each phase's work items run
    /// by `workers` (`OnCaller`: the calling thread, slot 0's mailbox;
    /// `OnPar`: the workers of a `Par`). The perspective grid and the light
    /// grids are built here, per frame, on `workers.par()` as joined builds,
    /// as are the light frustum, the map and the sort of the shadow rays;
    /// the frame is the same for any worker count. A `par()` of more than
    /// `MAX_WORKERS` workers is refused before anything is written. The
    /// phase times land in `stats().deferred`.
    pub fn render_deferred<W: Workers>(
        &mut self,
        job: &DeferredJob<'_>,
        pixels: &mut [u8],
        stride: usize,
        workers: &mut W,
    ) -> Result<DeferredInfo> {
        job.validate(&self.limits)?;
        // The joined phases take 1 to MAX_WORKERS workers.
        crate::mem::par::workers_of(workers.par())?;
        let rays = self.check_frame(job.frame, pixels.len(), stride)?;
        if !self.limits.has(Limits::PGRID) {
            return Err(Error::InvalidArgument(
                "deferred frames need Limits::PGRID (their per-pixel buffers)",
            ));
        }
        let grids = job.primary == PrimaryPass::Pgrid || job.shadow == ShadowPass::LightGrid;
        let pp = match self.pgrid.scene.params {
            Some(p) => p,
            None if grids => return Err(Error::NotBuilt),
            None => PgridParams::default(),
        };
        let side = deferred::tile_side(&job.primary, pp.tile, pp.group);
        if side > self.limits.max_tile {
            return Err(Error::InvalidArgument(
                "the tracing tile (pgrid tile * group, or the packet side) exceeds Limits::max_tile",
            ));
        }
        if matches!(job.shadow, ShadowPass::Traced(p) if p.tile_side() > 0) && side > 32 {
            return Err(Error::InvalidArgument(
                "traced shadow packets take the tracing tile's side, at most 32 (pgrid tile * group)",
            ));
        }
        let lay = TileLayout::new(side, job.frame.width, job.frame.height);
        let t_all = now();
        let tr = SceneTracer {
            grid: self.grid.view(),
            bvh: self.bvh.view(),
            kd: self.kd.view(),
            single: Method::GridDda,
        };
        let tr = match (&job.primary, &job.shadow) {
            (PrimaryPass::Traced(p), ShadowPass::Traced(s)) => {
                tr.check(s.method)?;
                tr.with_single(p.method)?
            }
            (PrimaryPass::Traced(p), _) => tr.with_single(p.method)?,
            (_, ShadowPass::Traced(s)) => tr.with_single(s.method)?,
            _ => tr,
        };
        // From here on the frame buffers are overwritten: the last frame's
        // pixels are gone, even if a grid build below fails.
        self.frame_layout = None;
        let parts = deferred::frame::Parts {
            pg: &mut self.pgrid,
            buf: &mut self.frame,
            slots: &mut self.slots,
        };
        let (info, ctr, eps) =
            deferred::frame::run(parts, &tr, job, &rays, &lay, &pp, pixels, stride, workers)?;
        let _ = t_all;
        self.stats.counters = ctr;
        self.stats.trace_ns = info.times.total();
        self.stats.deferred = info;
        self.frame_layout = Some(lay);
        self.frame_rays = Some((rays, eps));
        Ok(info)
    }

    /// Pixel (x, y) of the last deferred frame: the camera ray's nearest
    /// triangle and t (`INVALID_ID`, infinity: a miss) and the shadow bits
    /// (bit l: light l's shadow ray was occluded). None outside the frame
    /// or before the first successful `render_deferred`.
    pub fn deferred_pixel(&self, x: u32, y: u32) -> Option<(Hit, u8)> {
        let lay = self.frame_layout?;
        if x >= lay.width || y >= lay.height {
            return None;
        }
        let i = lay.index(x, y);
        let prim = self.frame.prim[i];
        let hit = Hit {
            t: if prim == crate::geom::INVALID_ID {
                f32::INFINITY
            } else {
                self.frame.t[i]
            },
            prim,
            u: 0.0,
            v: 0.0,
        };
        Some((hit, self.frame.shadow[i]))
    }

    /// The shadow ray towards `light` of pixel (x, y) of the last deferred
    /// frame (None: a miss, or no shadow ray), bit for bit the ray the
    /// frame traced, for checking its shadow bits against a reference.
    pub fn deferred_shadow_ray(&self, x: u32, y: u32, light: &PointLight) -> Option<Ray> {
        let (hit, _) = self.deferred_pixel(x, y)?;
        let (rays, eps) = self.frame_rays?;
        if !hit.is_hit() {
            return None;
        }
        let tri = match self.pgrid.triangles() {
            Some(t) => *t.tris.get(hit.prim as usize)?,
            None => self.scene_tracer().ok()?.triangle(hit.prim)?,
        };
        deferred::shadow_ray(&rays.ray(x, y), hit.t, &tri, light, eps)
    }

    /// The built structures with single-ray calls going to the first built
    /// of grid, BVH, kd-tree.
    fn scene_tracer(&self) -> Result<SceneTracer<'_>> {
        let t = SceneTracer {
            grid: self.grid.view(),
            bvh: self.bvh.view(),
            kd: self.kd.view(),
            single: Method::GridDda,
        };
        let single = if t.grid.is_some() {
            Method::GridDda
        } else if t.bvh.is_some() {
            Method::BvhSingle
        } else if t.kd.is_some() {
            Method::KdSingle
        } else {
            return Err(Error::NotBuilt);
        };
        Ok(SceneTracer { single, ..t })
    }

    /// The built structures, for tracing from several threads. Single-ray
    /// calls use the grid's 3DDDA when a grid is built, else the BVH's
    /// single-ray traversal (see `SceneTracer::with_single`).
    pub fn tracer(&self) -> Result<SceneTracer<'_>> {
        self.scene_tracer()
    }

    /// The built structures and one mailbox per thread slot, for tracing
    /// and rendering from several threads (each thread takes one mailbox).
    /// A slot's scratch holds packets up to `Limits::max_packet_side`:
    /// handing a `Tracer` larger packets with it panics (the context's own
    /// calls refuse them with a status first).
    pub fn parts(&mut self) -> Result<(SceneTracer<'_>, impl Iterator<Item = Slot<'_>>)> {
        let t = SceneTracer {
            grid: self.grid.view(),
            bvh: self.bvh.view(),
            kd: self.kd.view(),
            single: Method::GridDda,
        };
        let t = SceneTracer {
            single: self.scene_tracer()?.single,
            ..t
        };
        // One mailbox and scratch per thread slot; without grid pools (no
        // stamps) the mailboxes are empty, which only the grid's CGT uses.
        let mbs = self.slots.all().map(Slot::of);
        Ok((t, mbs))
    }

    /// Nearest hits of `rays` into `hits` (same length) with `method` and
    /// its default packet settings (`TraceParams`).
    pub fn trace(&mut self, method: Method, rays: &[Ray], hits: &mut [Hit]) -> Result<Counters> {
        self.trace_with(
            &TraceParams {
                method,
                ..TraceParams::default()
            },
            rays,
            hits,
        )
    }

    /// Nearest hits of `rays` into `hits` (same length). Packet methods take
    /// the rays in order as packets of `p.packet`^2 rays, every 4 rays one
    /// 2x2 quad in `Ray4` lane order (a last, smaller packet is padded with
    /// inactive lanes).
    pub fn trace_with(
        &mut self,
        p: &TraceParams,
        rays: &[Ray],
        hits: &mut [Hit],
    ) -> Result<Counters> {
        if rays.len() != hits.len() {
            return Err(Error::InvalidArgument(
                "rays and hits must have the same length",
            ));
        }
        self.batch(
            p,
            rays,
            &mut |i, h: &Hit4, n| hits[i..i + n].copy_from_slice(&h.hits()[..n]),
            false,
        )
    }

    /// Occlusion of `rays` with `method` (default packet settings).
    pub fn occluded(
        &mut self,
        method: Method,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<Counters> {
        self.occluded_with(
            &TraceParams {
                method,
                ..TraceParams::default()
            },
            rays,
            occluded,
        )
    }

    /// Occlusion of `rays` into `occluded` (same length): any hit in
    /// `[tmin, tmax)`. Packets are formed as in `trace_with`.
    pub fn occluded_with(
        &mut self,
        p: &TraceParams,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<Counters> {
        if rays.len() != occluded.len() {
            return Err(Error::InvalidArgument(
                "rays and results must have the same length",
            ));
        }
        self.batch(
            p,
            rays,
            &mut per_ray(|i, h: &Hit4, l| occluded[i] = h.prim[l] != crate::geom::INVALID_ID),
            true,
        )
    }

    /// Trace `rays` as packets (or one by one) on the calling thread with
    /// slot 0's mailbox, handing the results to `out` quad by quad
    /// (`trace_quads`).
    fn batch(
        &mut self,
        p: &TraceParams,
        rays: &[Ray],
        out: &mut dyn FnMut(usize, &Hit4, usize),
        any: bool,
    ) -> Result<Counters> {
        p.validate_for(&self.limits)?;
        let t = now();
        let ctr = {
            let (tr, mut mbs) = self.parts()?;
            let tr = tr.with_single(p.method)?;
            let mut slot = mbs.next().ok_or(Error::Capacity {
                pool: Pool::Threads,
                needed: 1,
                available: 0,
            })?;
            batch_on(&tr, &mut slot, p, rays.len(), |i| rays[i], out, any)
        };
        self.stats.trace_ns = elapsed_ns(t);
        self.stats.counters = ctr;
        Ok(ctr)
    }

    /// `trace_with` from any thread sharing `&self`, with thread slot
    /// `slot`'s mailbox (claimed for the call: `Error::SlotBusy` while
    /// another call holds it). Does not update `stats`.
    pub fn trace_in_slot(
        &self,
        slot: u32,
        p: &TraceParams,
        rays: &[Ray],
        hits: &mut [Hit],
    ) -> Result<Counters> {
        if rays.len() != hits.len() {
            return Err(Error::InvalidArgument(
                "rays and hits must have the same length",
            ));
        }
        self.batch_in_slot(
            slot,
            p,
            rays,
            &mut |i, h: &Hit4, n| hits[i..i + n].copy_from_slice(&h.hits()[..n]),
            false,
        )
    }

    /// `occluded_with` from any thread sharing `&self`, with thread slot
    /// `slot`'s mailbox (see `trace_in_slot`).
    pub fn occluded_in_slot(
        &self,
        slot: u32,
        p: &TraceParams,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<Counters> {
        if rays.len() != occluded.len() {
            return Err(Error::InvalidArgument(
                "rays and results must have the same length",
            ));
        }
        self.batch_in_slot(
            slot,
            p,
            rays,
            &mut per_ray(|i, h: &Hit4, l| occluded[i] = h.prim[l] != crate::geom::INVALID_ID),
            true,
        )
    }

    fn batch_in_slot(
        &self,
        slot: u32,
        p: &TraceParams,
        rays: &[Ray],
        out: &mut dyn FnMut(usize, &Hit4, usize),
        any: bool,
    ) -> Result<Counters> {
        self.trace_quads(Some(slot), p, rays.len(), |i| rays[i], out, any)
    }

    /// Trace (`any`: test occlusion of) `count` rays, ray `i` being
    /// `rays.ray(i)` (a closure reading an array, or a `RayStream`), from
    /// any thread sharing `&self`, handing each result to `out(i, hits,
    /// lane)`: packets as `trace_with` forms them, on thread slot `slot`
    /// (see `with_slot`; `None` takes the highest free slot). The calls of
    /// the C ABI come here. Does not update `stats`.
    pub fn trace_each(
        &self,
        slot: Option<u32>,
        p: &TraceParams,
        count: usize,
        rays: impl RaySource,
        out: impl FnMut(usize, &Hit4, usize),
        any: bool,
    ) -> Result<Counters> {
        self.trace_quads(slot, p, count, rays, per_ray(out), any)
    }

    /// `trace_each` handing the results out quad by quad: `out(i, hits,
    /// n)` for rays `i .. i + n` (lanes `0 .. n` of `hits`, `n <= 4`), so a
    /// caller storing lanes side by side (hit streams, camera pixels)
    /// writes whole quads.
    pub fn trace_quads(
        &self,
        slot: Option<u32>,
        p: &TraceParams,
        count: usize,
        rays: impl RaySource,
        out: impl FnMut(usize, &Hit4, usize),
        any: bool,
    ) -> Result<Counters> {
        p.validate_for(&self.limits)?;
        let tr = self.scene_tracer()?.with_single(p.method)?;
        self.with_slot(slot, |slot| batch_on(&tr, slot, p, count, rays, out, any))
    }

    /// Nearest hits of a ray stream (rays and hits as structures of
    /// arrays, `trace::stream`) with `p.method`, from any thread sharing
    /// `&self`, on thread slot `slot` as `trace_each`: the packets and the
    /// hits of `trace_with` on the same rays, bit for bit, without the
    /// array-of-structs conversion. Does not update `stats`.
    pub fn trace_stream(
        &self,
        slot: Option<u32>,
        p: &TraceParams,
        rays: &RayStream<'_>,
        hits: &mut HitStream<'_>,
    ) -> Result<Counters> {
        let n = rays.count()?;
        hits.check(n)?;
        self.trace_quads(slot, p, n, *rays, |i, h, k| hits.put_quad(i, h, k), false)
    }

    /// Occlusion of a ray stream into `occluded` (one per ray), as
    /// `occluded_with` answers it, on thread slot `slot` as `trace_each`.
    /// Does not update `stats`.
    pub fn occluded_stream(
        &self,
        slot: Option<u32>,
        p: &TraceParams,
        rays: &RayStream<'_>,
        occluded: &mut [bool],
    ) -> Result<Counters> {
        let n = rays.count()?;
        crate::trace::stream::one_per_ray(&[occluded.len()], n)?;
        let out = |i: usize, h: &Hit4, l: usize| occluded[i] = h.prim[l] != crate::geom::INVALID_ID;
        self.trace_each(slot, p, n, *rays, out, true)
    }

    /// Nearest hits of the camera rays through the pixels of `rect` (inside
    /// `camera`'s image), made in the kernel as packets of `p.packet`^2
    /// pixels (`render::CameraRays`: no ray array, no conversion), pixel
    /// (x, y)'s hit into `hits[(y - rect.y0) * row + (x - rect.x0)]`;
    /// other elements are left alone. The hits of `trace_with` on the rays
    /// `camera.ray(x, y)`, bit for bit. From any thread sharing `&self`,
    /// on thread slot `slot` as `trace_each` (threads tracing disjoint
    /// tiles or row bands of one image into one buffer, each its own
    /// slot). Does not update `stats`.
    pub fn trace_camera(
        &self,
        slot: Option<u32>,
        p: &TraceParams,
        camera: &PrimaryRays,
        rect: PixelRect,
        hits: &mut [Hit],
        row: usize,
    ) -> Result<Counters> {
        let rays = CameraRays::new(camera, rect, Some(p))?;
        rect.check_results(hits.len(), row)?;
        let mut at = rays.index(row);
        let out = |i: usize, h: &Hit4, _: usize| {
            for (k, hit) in at.quad(i).into_iter().zip(h.hits()) {
                if let Some(k) = k {
                    hits[k] = hit;
                }
            }
        };
        self.trace_quads(slot, p, rays.count(), rays, out, false)
    }

    /// Run `f` with thread slot `slot` (its mailbox and scratch), claimed
    /// for the call (`Error::SlotBusy` while another call holds it;
    /// `Capacity(Threads)` when `slot >= max_threads`). `None`: the highest
    /// free slot (`Capacity(Threads)` while every slot is held), which a
    /// concurrent call naming that slot then finds busy. The slot's scratch
    /// holds packets up to `Limits::max_packet_side` (see `parts`).
    pub fn with_slot<R>(&self, slot: Option<u32>, f: impl FnOnce(&mut Slot<'_>) -> R) -> Result<R> {
        let mut guard = match slot {
            Some(s) => self.slots.claim(s)?,
            None => self.slots.claim_free()?,
        };
        Ok(f(&mut Slot::of(guard.parts())))
    }

    /// Check a frame against the limits and the framebuffer size.
    pub fn check_frame(
        &self,
        frame: &Frame,
        pixels_len: usize,
        stride: usize,
    ) -> Result<PrimaryRays> {
        self.check_rows(frame, 0, frame.height, pixels_len, stride)
    }

    /// Check a frame against the limits, and a band of its rows
    /// `[y0, y1)` against the band's buffer (row `y0` first).
    pub fn check_rows(
        &self,
        frame: &Frame,
        y0: u32,
        y1: u32,
        pixels_len: usize,
        stride: usize,
    ) -> Result<PrimaryRays> {
        let (w, h) = (frame.width, frame.height);
        if w == 0 || h == 0 {
            return Err(Error::InvalidArgument("image width and height must be > 0"));
        }
        if w > self.limits.max_image_width || h > self.limits.max_image_height {
            return Err(Error::Capacity {
                pool: Pool::Image,
                needed: w as u64 * h as u64,
                available: self.limits.max_image_width as u64 * self.limits.max_image_height as u64,
            });
        }
        if stride < w as usize * 4 {
            return Err(Error::InvalidArgument(
                "framebuffer stride must be >= 4 * width",
            ));
        }
        if y0 >= y1 || y1 > h {
            return Err(Error::InvalidArgument(
                "rows must satisfy y0 < y1 <= height",
            ));
        }
        let need = ((y1 - y0 - 1) as usize)
            .checked_mul(stride)
            .and_then(|b| b.checked_add(w as usize * 4));
        if need.is_none_or(|n| pixels_len < n) {
            return Err(Error::InvalidArgument(
                "framebuffer smaller than height * stride",
            ));
        }
        PrimaryRays::new(&frame.camera, w, h)
    }

    /// Render a whole frame on the calling thread with `method` for every
    /// ray (default packet settings).
    pub fn render(
        &mut self,
        method: Method,
        frame: &Frame,
        pixels: &mut [u8],
        stride: usize,
    ) -> Result<Counters> {
        let p = TraceParams {
            method,
            ..TraceParams::default()
        };
        self.render_with(&p, &p, frame, pixels, stride)
    }

    /// Render a whole frame on the calling thread: `primary` for camera
    /// rays, `shadow` for shadow rays.
    pub fn render_with(
        &mut self,
        primary: &TraceParams,
        shadow: &TraceParams,
        frame: &Frame,
        pixels: &mut [u8],
        stride: usize,
    ) -> Result<Counters> {
        self.limits.check_renderer(Limits::TILES)?;
        primary.validate_for(&self.limits)?;
        shadow.validate_for(&self.limits)?;
        // The one light check of every render call (Whitted and deferred
        // frames check theirs in their job's validate).
        frame.light.validate()?;
        let rays = self.check_frame(frame, pixels.len(), stride)?;
        let t = now();
        let mut ctr = Counters::default();
        {
            let (tr, mut mbs) = self.parts()?;
            tr.check(shadow.method)?;
            let tr = tr.with_single(primary.method)?;
            let mut slot = mbs.next().ok_or(Error::Capacity {
                pool: Pool::Threads,
                needed: 1,
                available: 0,
            })?;
            let shot = Shot { frame, rays: &rays };
            let band = Band {
                y0: 0,
                y1: frame.height,
                pixels,
                stride,
            };
            shot.render(&tr, primary, shadow, band, &mut slot, &mut ctr);
            crate::fault_point!(Render);
        }
        self.stats.trace_ns = elapsed_ns(t);
        self.stats.counters = ctr;
        Ok(ctr)
    }

    /// Render rows `[band.y0, band.y1)` of `*frame` from any thread sharing
    /// `&self`, with thread slot `slot`'s mailbox (claimed for the call:
    /// `Error::SlotBusy` while another call holds it). `band.pixels` holds
    /// only those rows, row `y0` first, `band.stride` bytes apart. Threads
    /// rendering disjoint bands with distinct slots make the image
    /// `render_with` makes, byte for byte. Does not update `stats`.
    pub fn render_rows_in_slot(
        &self,
        slot: u32,
        primary: &TraceParams,
        shadow: &TraceParams,
        frame: &Frame,
        band: Band<'_>,
    ) -> Result<Counters> {
        self.limits.check_renderer(Limits::TILES)?;
        primary.validate_for(&self.limits)?;
        shadow.validate_for(&self.limits)?;
        frame.light.validate()?;
        let rays = self.check_rows(frame, band.y0, band.y1, band.pixels.len(), band.stride)?;
        let tr = self.scene_tracer()?;
        tr.check(shadow.method)?;
        let tr = tr.with_single(primary.method)?;
        let shot = Shot { frame, rays: &rays };
        self.with_slot(Some(slot), |slot| {
            let mut ctr = Counters::default();
            shot.render(&tr, primary, shadow, band, slot, &mut ctr);
            ctr
        })
    }

    /// Render a Whitted frame (shadows, reflections, refractions; BVH paper
    /// sections 2.4 and 6) on the calling thread: `job.primary`,
    /// `job.shadow` and `job.secondary` choose the method per ray class.
    /// Packet methods render n x n tiles, n the largest tile side of the
    /// three (`TraceParams::tile_side`), and camera packets take that side;
    /// single-ray methods alone render ray tree by ray tree. Hit triangles
    /// are looked up in the primary method's structure. The image does not
    /// depend on these choices.
    pub fn render_whitted(
        &mut self,
        job: &WhittedJob<'_>,
        pixels: &mut [u8],
        stride: usize,
    ) -> Result<Counters> {
        job.validate(&self.limits)?;
        let rays = self.check_frame(job.frame, pixels.len(), stride)?;
        let t = now();
        let mut ctr = Counters::default();
        {
            let (tr, mut mbs) = self.parts()?;
            tr.check(job.shadow.method)?;
            tr.check(job.secondary.method)?;
            let tr = tr.with_single(job.primary.method)?;
            let mut slot = mbs.next().ok_or(Error::Capacity {
                pool: Pool::Threads,
                needed: 1,
                available: 0,
            })?;
            let band = Band {
                y0: 0,
                y1: job.frame.height,
                pixels,
                stride,
            };
            match job
                .primary
                .tile_side()
                .max(job.shadow.tile_side())
                .max(job.secondary.tile_side())
            {
                0 => whitted::render_whitted_rows(&tr, job, &rays, band, &mut ctr),
                side => {
                    let job = WhittedJob {
                        primary: TraceParams {
                            packet: side,
                            ..job.primary
                        },
                        ..*job
                    };
                    whitted::render_whitted_tiles(&tr, &job, &rays, band, &mut slot, &mut ctr)
                }
            }
        }
        crate::fault_point!(Whitted);
        self.stats.trace_ns = elapsed_ns(t);
        self.stats.counters = ctr;
        Ok(ctr)
    }

    /// Record counters and time of a frame rendered by the caller's threads
    /// (through `tracer()` and `render::render_rows`).
    pub fn record(&mut self, ctr: Counters, trace_ns: u64) {
        self.stats.counters = ctr;
        self.stats.trace_ns = trace_ns;
    }
}

/// A frame and its camera rays, rendered band by band.
struct Shot<'f> {
    frame: &'f Frame,
    rays: &'f PrimaryRays,
}

impl Shot<'_> {
    /// Packet methods render n x n tiles (n the larger tile side of the two
    /// classes), single-ray methods row by row.
    fn render(
        &self,
        tr: &SceneTracer<'_>,
        primary: &TraceParams,
        shadow: &TraceParams,
        band: Band<'_>,
        slot: &mut Slot<'_>,
        ctr: &mut Counters,
    ) {
        let (frame, rays) = (self.frame, self.rays);
        match primary.tile_side().max(shadow.tile_side()) {
            0 => render::render_rows(tr, frame, rays, band, ctr),
            side => {
                let params = TileParams {
                    primary: TraceParams {
                        packet: side,
                        ..*primary
                    },
                    shadow: *shadow,
                };
                render::render_tiles(tr, &params, frame, rays, band, slot, ctr);
            }
        }
    }
}

/// A context that owns its memory: exactly one allocation, made at creation
/// (std only; `Context::new`). It is a `Context` in every other way: the
/// allocation travels with it and is freed when it drops.
#[cfg(feature = "std")]
pub type OwnedContext = Context<'static>;

#[cfg(feature = "std")]
impl Context<'static> {
    /// Allocate `required_bytes(limits)` once and create the context in it.
    pub fn new(limits: &Limits) -> Result<Context<'static>> {
        let bytes = required_bytes(limits)?;
        crate::mem::owned::build_over(bytes, |buf| Context::new_in(buf, limits))
    }
}

#[cfg(feature = "std")]
impl crate::mem::owned::Keeps for Context<'static> {
    fn keep(&mut self, buf: crate::mem::owned::OwnedBuffer) {
        self.owned = Some(buf);
    }
}
