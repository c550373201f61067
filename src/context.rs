//! The context: every pool carved from one buffer at creation, then reused by
//! every frame. After `Context::new_in` nothing here allocates.
#![forbid(unsafe_code)]

use crate::accel::bvh::{self, Bvh, BvhInfo, BvhNode, BvhParams, BvhPools, BvhView, PrimRef};
use crate::accel::entry::{self, EntryPoint, EntrySearch, EntryTree};
use crate::accel::grid::traverse_cgt::{self, Mailbox};
use crate::accel::grid::{self, Grid, GridInfo, GridParams, GridPools, GridView};
use crate::accel::kd::{self, KdInfo, KdNode, KdParams, KdPools, KdTree, KdView};
use crate::accel::pgrid::{self, Chunk, Pgrid, PgridParams, PgridPools, SceneInfo};
use crate::error::{Error, Pool, Result};
use crate::geom::frustum::Frustum;
use crate::geom::{Hit, Hit4, M4, Mt, Pt, Ray, Ray4, Scene, TriTest, TriVerts, TriangleTest, Wt};
use crate::mem::{Arena, Limits, Slots};
use crate::render::deferred::{
    self, DeferredInfo, DeferredJob, FrameBuffers, PrimaryPass, ShadowPass, TileLayout, Workers,
};
use crate::render::whitted::{self, WhittedJob};
use crate::render::{self, Frame, PointLight, PrimaryRays, Tracer};
use crate::trace::{Counters, Method, TraceParams};

/// Pool sizes derived from `Limits`, in the order they are carved. A
/// structure left out of `Limits::structures` gets empty pools.
struct Layout {
    tris: usize,
    proj: usize,
    cells: usize,
    refs: usize,
    macro_words: usize,
    slots: usize,
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
        })
    }

    /// Total bytes, `InvalidArgument` when the sum does not fit a `usize`.
    fn bytes(&self) -> Result<usize> {
        let twice = |n: usize| n.checked_mul(2);
        let pools = [
            pool::<TriVerts>(self.tris),
            pool::<crate::geom::ProjTri>(self.proj),
            pool::<u32>(self.tris),
            self.cells.checked_add(1).and_then(pool::<u32>),
            pool::<u32>(self.refs),
            pool::<u32>(self.macro_words),
            self.stamps.checked_mul(self.slots).and_then(pool::<u32>),
            pool::<u32>(self.slots).and_then(twice),
            twice(self.bvh_tris).and_then(pool::<BvhNode>),
            pool::<TriVerts>(self.bvh_tris),
            pool::<crate::geom::ProjTri>(self.bvh_proj),
            pool::<u32>(self.bvh_tris),
            pool::<u32>(self.bvh_tris),
            pool::<PrimRef>(self.bvh_tris),
            pool::<KdNode>(self.kd_nodes),
            pool::<u32>(self.kd_refs),
            pool::<TriVerts>(self.kd_tris),
            pool::<crate::geom::ProjTri>(self.kd_proj),
            pool::<u32>(self.kd_tris),
            pool::<u32>(self.kd_tris),
            pool::<u64>(self.kd_events),
            pool::<u8>(self.kd_tris),
            pool::<TriVerts>(self.pg_tris),
            pool::<crate::geom::ProjTri>(self.pg_proj),
            pool::<u8>(self.pg_tris),
            pool::<[f32; 4]>(self.pg_tris),
            pool::<u32>(self.pg_cells).and_then(twice),
            pool::<u32>(self.pg_refs).and_then(twice),
            pool::<u32>(self.pg_refs),
            pool::<u32>(self.pg_scratch).and_then(twice),
            pool::<u32>(self.px),
            pool::<f32>(self.px),
            pool::<[f32; 3]>(self.px),
            pool::<u8>(self.px),
            pool::<u32>(self.px).and_then(twice),
            pool::<u8>(self.px),
            pool::<Chunk>(self.chunks),
            pool::<u32>(if self.px > 0 {
                pgrid::MAX_LIGHT_TILES
            } else {
                0
            }),
        ];
        pools
            .into_iter()
            .try_fold(0usize, |sum, b| sum.checked_add(b?))
            .filter(|&b| b <= isize::MAX as usize)
            .ok_or(Error::InvalidArgument(
                "limits need more memory than can be addressed",
            ))
    }
}

/// `pool_bytes`, checked.
fn pool<T>(n: usize) -> Option<usize> {
    crate::mem::pool_bytes_checked::<T>(n)
}

/// Exact number of bytes `Context::new_in` needs for `limits` (the buffer
/// must also start on a 64-byte boundary).
pub fn required_bytes(limits: &Limits) -> Result<usize> {
    Layout::of(limits)?.bytes()
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
    frame: FrameBuffers<'a>,
    /// Layout of the frame buffers in the last deferred frame, its
    /// camera rays and shadow-ray offset.
    frame_layout: Option<TileLayout>,
    frame_rays: Option<(PrimaryRays, f32)>,
    /// Per-thread slots, each a mailbox (CGT section 2.3): `max_triangles`
    /// stamps and a packet counter, claimed by `*_in_slot` calls.
    slots: Slots<'a>,
    stats: Stats,
}

#[cfg(feature = "std")]
fn now() -> Option<std::time::Instant> {
    Some(std::time::Instant::now())
}
#[cfg(not(feature = "std"))]
fn now() -> Option<()> {
    None
}
#[cfg(feature = "std")]
fn elapsed_ns(t: Option<std::time::Instant>) -> u64 {
    t.map_or(0, |t| t.elapsed().as_nanos() as u64)
}
#[cfg(not(feature = "std"))]
fn elapsed_ns(_: Option<()>) -> u64 {
    0
}

impl<'a> Context<'a> {
    /// Create a context over `buf` (at least `required_bytes(limits)` bytes,
    /// 64-byte aligned). Never allocates.
    pub fn new_in(buf: &'a mut [u8], limits: &Limits) -> Result<Context<'a>> {
        let layout = Layout::of(limits)?;
        let need = layout.bytes()?;
        if buf.len() < need {
            return Err(Error::BufferTooSmall {
                needed: need as u64,
                available: buf.len() as u64,
            });
        }
        let mut arena = Arena::new(buf)?;
        let pools = GridPools {
            tris: arena.take(layout.tris)?,
            proj: arena.take(layout.proj)?,
            tri_ids: arena.take(layout.tris)?,
            cell_start: arena.take(layout.cells + 1)?,
            refs: arena.take(layout.refs)?,
            macro_bits: arena.take(layout.macro_words)?,
        };
        let slots = Slots::new(
            arena.take(layout.stamps * layout.slots)?,
            arena.take(layout.slots)?,
            arena.take(layout.slots)?,
        );
        let bvh = BvhPools {
            nodes: arena.take(2 * layout.bvh_tris)?,
            tris: arena.take(layout.bvh_tris)?,
            proj: arena.take(layout.bvh_proj)?,
            tri_ids: arena.take(layout.bvh_tris)?,
            slot_of: arena.take(layout.bvh_tris)?,
            refs: arena.take(layout.bvh_tris)?,
        };
        let kd = KdPools {
            nodes: arena.take(layout.kd_nodes)?,
            refs: arena.take(layout.kd_refs)?,
            tris: arena.take(layout.kd_tris)?,
            proj: arena.take(layout.kd_proj)?,
            tri_ids: arena.take(layout.kd_tris)?,
            slot_of: arena.take(layout.kd_tris)?,
            events: arena.take(layout.kd_events)?,
            side: arena.take(layout.kd_tris)?,
        };
        let pg = PgridPools {
            tris: arena.take(layout.pg_tris)?,
            proj: arena.take(layout.pg_proj)?,
            ok: arena.take(layout.pg_tris)?,
            px_box: arena.take(layout.pg_tris)?,
            cam_start: arena.take(layout.pg_cells)?,
            cam_tris: arena.take(layout.pg_refs)?,
            light_start: arena.take(layout.pg_cells)?,
            light_tris: arena.take(layout.pg_refs)?,
            keys: arena.take(layout.pg_refs)?,
            tmp_keys: arena.take(layout.pg_scratch)?,
            tmp_vals: arena.take(layout.pg_scratch)?,
        };
        let frame = FrameBuffers {
            prim: arena.take(layout.px)?,
            t: arena.take(layout.px)?,
            dirs: arena.take(layout.px)?,
            shadow: arena.take(layout.px)?,
            ray_tiles: arena.take(layout.px)?,
            ray_ids: arena.take(layout.px)?,
            occ: arena.take(layout.px)?,
            chunks: arena.take(layout.chunks)?,
            reach: arena.take(if layout.px > 0 {
                pgrid::MAX_LIGHT_TILES
            } else {
                0
            })?,
        };
        debug_assert_eq!(arena.used(), need);
        Ok(Context {
            limits: *limits,
            grid: Grid::new(pools),
            bvh: Bvh::new(bvh),
            kd: KdTree::new(kd),
            pgrid: Pgrid::new(pg),
            frame,
            frame_layout: None,
            frame_rays: None,
            slots,
            stats: Stats::default(),
        })
    }

    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// Statistics of the last build and trace/render call.
    pub fn stats(&self) -> &Stats {
        &self.stats
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
        if !self.limits.has(Limits::GRID) {
            return Err(Error::InvalidArgument(
                "no grid pools: Limits::structures lacks GRID",
            ));
        }
        self.check_scene(scene)?;
        let t = now();
        let info = grid::build::build(
            &mut self.grid,
            scene,
            params,
            self.limits.grid_cells(),
            self.limits.grid_refs(),
        )?;
        self.stats.build_ns = elapsed_ns(t);
        self.stats.grid = info;
        Ok(info)
    }

    /// Rebuild the BVH from `scene` (binned SAH, BVH paper section 5.1).
    /// On error the previous BVH stays valid.
    pub fn build_bvh(&mut self, scene: &Scene<'_>, params: &BvhParams) -> Result<BvhInfo> {
        if !self.limits.has(Limits::BVH) {
            return Err(Error::InvalidArgument(
                "no BVH pools: Limits::structures lacks BVH",
            ));
        }
        self.check_scene(scene)?;
        let t = now();
        let info = bvh::build::build(&mut self.bvh, scene, params)?;
        self.stats.bvh_build_ns = elapsed_ns(t);
        self.stats.bvh = info;
        Ok(info)
    }

    /// Rebuild the kd-tree from `scene` (O(N log N) SAH with perfect
    /// splits, AEPSA paper section 5.1). On error the previous tree stays
    /// valid.
    pub fn build_kd(&mut self, scene: &Scene<'_>, params: &KdParams) -> Result<KdInfo> {
        if !self.limits.has(Limits::KD) {
            return Err(Error::InvalidArgument(
                "no kd-tree pools: Limits::structures lacks KD",
            ));
        }
        self.check_scene(scene)?;
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
        if !self.limits.has(Limits::PGRID) {
            return Err(Error::InvalidArgument(
                "no perspective grid pools: Limits::structures lacks PGRID",
            ));
        }
        self.check_scene(scene)?;
        params.validate()?;
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
    /// by `workers` (`OnCaller`: the calling thread, slot 0's mailbox).
    /// The perspective grid and the light grids are built here, per frame;
    /// the phase times land in `stats().deferred`.
    pub fn render_deferred<W: Workers>(
        &mut self,
        job: &DeferredJob<'_>,
        pixels: &mut [u8],
        stride: usize,
        workers: &mut W,
    ) -> Result<DeferredInfo> {
        job.validate()?;
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
                tr.with_single(s.method)?;
                tr.with_single(p.method)?
            }
            (PrimaryPass::Traced(p), _) => tr.with_single(p.method)?,
            (_, ShadowPass::Traced(s)) => tr.with_single(s.method)?,
            _ => tr,
        };
        let mut info = DeferredInfo::default();
        let mut ctr = Counters::default();
        // From here on the frame buffers are overwritten: the last frame's
        // pixels are gone, even if a grid build below fails.
        self.frame_layout = None;
        // Phase 1: the perspective grid.
        if job.primary == PrimaryPass::Pgrid {
            let t = now();
            info.camera = pgrid::build::build_camera(&mut self.pgrid, &rays.pinhole())?;
            info.times.primary_build = elapsed_ns(t);
        }
        let Context {
            pgrid: pg,
            frame: buf,
            slots,
            ..
        } = self;
        macro_rules! mailboxes {
            () => {{ slots.all().map(|(st, p)| Mailbox::new(st, p)) }};
        }
        // Phase 2: camera rays.
        let t = now();
        let cam = pg.camera();
        ctr.add(&deferred::primary_pass(
            &tr,
            cam.as_ref(),
            &job.primary,
            &rays,
            &lay,
            pp.tile,
            buf.prim,
            buf.t,
            workers,
            &mut mailboxes!(),
        ));
        info.times.primary_trace = elapsed_ns(t);
        let from_pgrid = job.primary == PrimaryPass::Pgrid;
        // Hits are looked up where the primary pass found them.
        macro_rules! tri_of {
            () => {{
                let pg_tris = pg.triangles();
                let pg_ok = &*pg.pools.ok;
                move |id: u32| -> Option<TriVerts> {
                    if from_pgrid {
                        let t = pg_tris?;
                        (pg_ok.get(id as usize) == Some(&1)).then(|| t.tris[id as usize])
                    } else {
                        tr.triangle(id)
                    }
                }
            }};
        }
        let scale = if from_pgrid {
            scale_of(&pg.scene.bounds)
        } else {
            tr.scene_scale()
        };
        let eps = deferred::shadow_eps(scale);
        info.hits = buf.prim[..lay.len()]
            .iter()
            .filter(|&&p| p != crate::geom::INVALID_ID)
            .count() as u64;
        let lights = job.lights();
        buf.shadow[..lay.len()].fill(0);
        if job.frame.shading.shadows {
            for (l, light) in lights.iter().enumerate() {
                // Phase 3: shadow rays, mapped and sorted into light tiles.
                let t = now();
                let s = deferred::make_shadow_rays(
                    &tri_of!(),
                    light,
                    &rays,
                    &lay,
                    eps,
                    buf.prim,
                    buf.t,
                    buf.dirs,
                    workers,
                    &mut mailboxes!(),
                );
                info.shadow_rays += s.count as u64;
                match job.shadow {
                    ShadowPass::Traced(p) => {
                        info.times.rearrange += elapsed_ns(t);
                        let t = now();
                        ctr.add(&deferred::traced_shadow_pass(
                            &tr,
                            &p,
                            light,
                            &lay,
                            buf.dirs,
                            buf.shadow,
                            l as u8,
                            workers,
                            &mut mailboxes!(),
                        ));
                        info.times.shadow_trace += elapsed_ns(t);
                    }
                    ShadowPass::LightGrid => {
                        let f = deferred::light_frame(
                            light,
                            &s,
                            deferred::light_tiles(pp.light_tiles, s.count),
                            &lay,
                            buf.dirs,
                            buf.ray_tiles,
                            buf.ray_ids,
                        );
                        let depth = pgrid::Slices::new(
                            s.near,
                            s.far,
                            pp.light_slices,
                            pgrid::LIGHT_DEPTH_PAD,
                        );
                        let k = deferred::map_to_tiles(
                            &f,
                            &depth,
                            &lay,
                            buf.dirs,
                            buf.ray_tiles,
                            buf.ray_ids,
                            buf.reach,
                        );
                        info.times.rearrange += elapsed_ns(t);
                        // Phase 4: the light grid, over the tiles and
                        // slices the rays reach.
                        let t = now();
                        info.light = pgrid::build::build_light(
                            pg,
                            &f,
                            s.near,
                            s.far,
                            pp.light_slices,
                            buf.reach,
                        )?;
                        info.times.shadow_build += elapsed_ns(t);
                        let t = now();
                        let r = deferred::rearrange(
                            &f,
                            k,
                            buf,
                            pg.pools.tmp_keys,
                            pg.pools.tmp_vals,
                            pp.chunk,
                        );
                        info.reorder.rays += r.rays;
                        info.reorder.tiles_used += r.tiles_used;
                        info.reorder.chunks += r.chunks;
                        info.reorder.max_tile_rays =
                            info.reorder.max_tile_rays.max(r.max_tile_rays);
                        info.times.rearrange += elapsed_ns(t);
                        // Phase 5: chunks.
                        let t = now();
                        let g = pg.light_view().ok_or(Error::NotBuilt)?;
                        ctr.add(&deferred::light_grid_pass(
                            &g,
                            &buf.chunks[..r.chunks as usize],
                            buf.ray_ids,
                            buf.dirs,
                            buf.occ,
                            buf.shadow,
                            l as u8,
                            pp.chunk,
                            workers,
                            &mut mailboxes!(),
                        ));
                        info.times.shadow_trace += elapsed_ns(t);
                    }
                }
            }
        }
        // Phase 6: shading.
        let t = now();
        deferred::shade(
            &tri_of!(),
            job.frame,
            lights,
            &rays,
            &lay,
            eps,
            buf.prim,
            buf.t,
            buf.shadow,
            pixels,
            stride,
            workers,
            &mut mailboxes!(),
        );
        info.times.shade = elapsed_ns(t);
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
    pub fn parts(&mut self) -> Result<(SceneTracer<'_>, impl Iterator<Item = Mailbox<'_>>)> {
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
        // One mailbox per thread slot; without grid pools (no stamps) the
        // mailboxes are empty, which only the grid's CGT would use.
        let mbs = self.slots.all().map(|(st, p)| Mailbox::new(st, p));
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
            &mut |i, h: &Hit4, lane| hits[i] = h.lane(lane),
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
            &mut |i, h: &Hit4, lane| occluded[i] = h.prim[lane] != crate::geom::INVALID_ID,
            true,
        )
    }

    /// Trace `rays` as packets (or one by one) on the calling thread with
    /// slot 0's mailbox, handing each result to `out(ray index, hits, lane)`.
    fn batch(
        &mut self,
        p: &TraceParams,
        rays: &[Ray],
        out: &mut dyn FnMut(usize, &Hit4, usize),
        any: bool,
    ) -> Result<Counters> {
        p.validate()?;
        let t = now();
        let ctr = {
            let (tr, mut mbs) = self.parts()?;
            let tr = tr.with_single(p.method)?;
            let mut mb = mbs.next().ok_or(Error::Capacity {
                pool: Pool::Threads,
                needed: 1,
                available: 0,
            })?;
            batch_on(&tr, &mut mb, p, rays.len(), &|i| rays[i], out, any)
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
            &mut |i, h: &Hit4, lane| hits[i] = h.lane(lane),
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
            &mut |i, h: &Hit4, lane| occluded[i] = h.prim[lane] != crate::geom::INVALID_ID,
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
        p.validate()?;
        let tr = self.scene_tracer()?.with_single(p.method)?;
        self.with_slot(slot, |mb| {
            batch_on(&tr, mb, p, rays.len(), &|i| rays[i], out, any)
        })
    }

    /// Run `f` with thread slot `slot`'s mailbox, claimed for the call
    /// (`Error::SlotBusy` while another call holds it; `Capacity(Threads)`
    /// when `slot >= max_threads`).
    pub fn with_slot<R>(&self, slot: u32, f: impl FnOnce(&mut Mailbox<'_>) -> R) -> Result<R> {
        let mut guard = self.slots.claim(slot)?;
        let (st, pk) = guard.parts();
        Ok(f(&mut Mailbox::new(st, pk)))
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
        primary.validate()?;
        shadow.validate()?;
        // The one light check of every render call (Whitted and deferred
        // frames check theirs in their job's validate).
        frame.light.validate()?;
        let rays = self.check_frame(frame, pixels.len(), stride)?;
        let t = now();
        let mut ctr = Counters::default();
        {
            let (tr, mut mbs) = self.parts()?;
            tr.with_single(shadow.method)?;
            let tr = tr.with_single(primary.method)?;
            let mut mb = mbs.next().ok_or(Error::Capacity {
                pool: Pool::Threads,
                needed: 1,
                available: 0,
            })?;
            let band = Band {
                frame,
                rays: &rays,
                y0: 0,
                y1: frame.height,
                stride,
            };
            band.render(&tr, primary, shadow, pixels, &mut mb, &mut ctr);
            crate::fault_point!(Render);
        }
        self.stats.trace_ns = elapsed_ns(t);
        self.stats.counters = ctr;
        Ok(ctr)
    }

    /// Render rows `[y0, y1)` of `*frame` from any thread sharing `&self`,
    /// with thread slot `slot`'s mailbox (claimed for the call:
    /// `Error::SlotBusy` while another call holds it). `band` holds only
    /// those rows, row `y0` first, `stride` bytes apart. Threads rendering
    /// disjoint bands with distinct slots make the image `render_with`
    /// makes, byte for byte. Does not update `stats`.
    #[allow(clippy::too_many_arguments)]
    pub fn render_rows_in_slot(
        &self,
        slot: u32,
        primary: &TraceParams,
        shadow: &TraceParams,
        frame: &Frame,
        y0: u32,
        y1: u32,
        band: &mut [u8],
        stride: usize,
    ) -> Result<Counters> {
        primary.validate()?;
        shadow.validate()?;
        frame.light.validate()?;
        let rays = self.check_rows(frame, y0, y1, band.len(), stride)?;
        let tr = self.scene_tracer()?;
        tr.with_single(shadow.method)?;
        let tr = tr.with_single(primary.method)?;
        let rows = Band {
            frame,
            rays: &rays,
            y0,
            y1,
            stride,
        };
        self.with_slot(slot, |mb| {
            let mut ctr = Counters::default();
            rows.render(&tr, primary, shadow, band, mb, &mut ctr);
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
        job.validate()?;
        let rays = self.check_frame(job.frame, pixels.len(), stride)?;
        let t = now();
        let mut ctr = Counters::default();
        {
            let (tr, mut mbs) = self.parts()?;
            tr.with_single(job.shadow.method)?;
            tr.with_single(job.secondary.method)?;
            let tr = tr.with_single(job.primary.method)?;
            let mut mb = mbs.next().ok_or(Error::Capacity {
                pool: Pool::Threads,
                needed: 1,
                available: 0,
            })?;
            match job
                .primary
                .tile_side()
                .max(job.shadow.tile_side())
                .max(job.secondary.tile_side())
            {
                0 => whitted::render_whitted_rows(
                    &tr,
                    job,
                    &rays,
                    0,
                    job.frame.height,
                    pixels,
                    stride,
                    &mut ctr,
                ),
                side => {
                    let job = WhittedJob {
                        primary: TraceParams {
                            packet: side,
                            ..job.primary
                        },
                        ..*job
                    };
                    whitted::render_whitted_tiles(
                        &tr,
                        &job,
                        &rays,
                        0,
                        job.frame.height,
                        pixels,
                        stride,
                        &mut mb,
                        &mut ctr,
                    )
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

/// Trace `count` rays, ray `i` being `read(i)`, as packets of
/// `p.packet`^2 rays (or 2x2 batches for single-ray methods) with mailbox
/// `mb`, handing each result to `out(ray index, hits, lane)`. Shared by the
/// Rust calls and the C ABI's, so both form the same packets.
pub(crate) fn batch_on(
    tr: &SceneTracer<'_>,
    mb: &mut Mailbox<'_>,
    p: &TraceParams,
    count: usize,
    read: &dyn Fn(usize) -> Ray,
    out: &mut dyn FnMut(usize, &Hit4, usize),
    any: bool,
) -> Counters {
    // 256 quads: the largest packet, 32 x 32 rays.
    const QUADS: usize = 256;
    let mut ctr = Counters::default();
    let per = if p.method.is_packet() {
        (p.packet * p.packet) as usize
    } else {
        4
    };
    let mut quads =
        [Ray4::from_rays(&[Ray::new(glam::Vec3::ZERO, glam::Vec3::X, 0.0, 0.0); 4]); QUADS];
    let mut active = [M4::FALSE; QUADS];
    let mut hits = [Hit4::MISS; QUADS];
    let mut start = 0;
    while start < count {
        let n = (count - start).min(per);
        let nq = crate::trace::pack_quads(n, |k| read(start + k), &mut quads, &mut active);
        hits[..nq].fill(Hit4::MISS);
        if any {
            tr.occluded_packet(
                p,
                &quads[..nq],
                &active[..nq],
                &mut hits[..nq],
                mb,
                &mut ctr,
            );
        } else {
            tr.intersect_packet(
                p,
                &quads[..nq],
                &active[..nq],
                &mut hits[..nq],
                mb,
                &mut ctr,
            );
        }
        for k in 0..n {
            out(start + k, &hits[k / 4], k % 4);
        }
        start += n;
    }
    ctr
}

/// Rows `[y0, y1)` of a frame; the buffer given to `render` starts at row `y0`.
struct Band<'f> {
    frame: &'f Frame,
    rays: &'f PrimaryRays,
    y0: u32,
    y1: u32,
    stride: usize,
}

impl Band<'_> {
    /// Packet methods render n x n tiles (n the larger tile side of the two
    /// classes), single-ray methods row by row.
    fn render(
        &self,
        tr: &SceneTracer<'_>,
        primary: &TraceParams,
        shadow: &TraceParams,
        pixels: &mut [u8],
        mb: &mut Mailbox<'_>,
        ctr: &mut Counters,
    ) {
        let (frame, rays, y0, y1, stride) = (self.frame, self.rays, self.y0, self.y1, self.stride);
        match primary.tile_side().max(shadow.tile_side()) {
            0 => render::render_rows(tr, frame, rays, y0, y1, pixels, stride, ctr),
            side => {
                let tile = TraceParams {
                    packet: side,
                    ..*primary
                };
                render::render_tiles(
                    tr, &tile, shadow, frame, rays, y0, y1, pixels, stride, mb, ctr,
                );
            }
        }
    }
}

/// A built grid ready to trace, shared across threads.
#[derive(Clone, Copy)]
pub struct GridTracer<'r> {
    pub view: GridView<'r>,
}

impl Tracer for GridTracer<'_> {
    #[inline]
    fn intersect(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
        match self.view.info.test {
            TriTest::MollerTrumbore => grid::traverse_single::intersect::<Mt>(&self.view, ray, ctr),
            TriTest::Watertight => grid::traverse_single::intersect::<Wt>(&self.view, ray, ctr),
            TriTest::Projection => grid::traverse_single::intersect::<Pt>(&self.view, ray, ctr),
        }
    }
    #[inline]
    fn occluded(&self, ray: &Ray, ctr: &mut Counters) -> bool {
        match self.view.info.test {
            TriTest::MollerTrumbore => grid::traverse_single::occluded::<Mt>(&self.view, ray, ctr),
            TriTest::Watertight => grid::traverse_single::occluded::<Wt>(&self.view, ray, ctr),
            TriTest::Projection => grid::traverse_single::occluded::<Pt>(&self.view, ray, ctr),
        }
    }
    fn intersect_packet(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        mb: &mut Mailbox<'_>,
        ctr: &mut Counters,
    ) {
        match (p.method, self.view.info.test) {
            (Method::GridCgt, TriTest::MollerTrumbore) => {
                traverse_cgt::intersect::<Mt>(&self.view, rays, active, hits, &p.cgt, mb, ctr)
            }
            (Method::GridCgt, TriTest::Watertight) => {
                traverse_cgt::intersect::<Wt>(&self.view, rays, active, hits, &p.cgt, mb, ctr)
            }
            (Method::GridCgt, TriTest::Projection) => {
                traverse_cgt::intersect::<Pt>(&self.view, rays, active, hits, &p.cgt, mb, ctr)
            }
            _ => lane_by_lane(rays, active, hits, |r, c| self.intersect(r, c), ctr),
        }
    }
    fn occluded_packet(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        mb: &mut Mailbox<'_>,
        ctr: &mut Counters,
    ) {
        match (p.method, self.view.info.test) {
            (Method::GridCgt, TriTest::MollerTrumbore) => {
                traverse_cgt::occluded::<Mt>(&self.view, rays, active, hits, &p.cgt, mb, ctr)
            }
            (Method::GridCgt, TriTest::Watertight) => {
                traverse_cgt::occluded::<Wt>(&self.view, rays, active, hits, &p.cgt, mb, ctr)
            }
            (Method::GridCgt, TriTest::Projection) => {
                traverse_cgt::occluded::<Pt>(&self.view, rays, active, hits, &p.cgt, mb, ctr)
            }
            (_, TriTest::MollerTrumbore) => lane_by_lane(
                rays,
                active,
                hits,
                |r, c| grid::traverse_single::any_hit::<Mt>(&self.view, r, c),
                ctr,
            ),
            (_, TriTest::Watertight) => lane_by_lane(
                rays,
                active,
                hits,
                |r, c| grid::traverse_single::any_hit::<Wt>(&self.view, r, c),
                ctr,
            ),
            (_, TriTest::Projection) => lane_by_lane(
                rays,
                active,
                hits,
                |r, c| grid::traverse_single::any_hit::<Pt>(&self.view, r, c),
                ctr,
            ),
        }
    }
    fn triangle(&self, prim: u32) -> Option<TriVerts> {
        // Stored triangles are in the caller's order minus exclusions, so a
        // binary search over the ids finds the slot.
        let i = self.view.tri_ids.binary_search(&prim).ok()?;
        Some(self.view.tris[i])
    }
    fn scene_scale(&self) -> f32 {
        scale_of(&self.view.info.scene_bounds)
    }
}

/// A built BVH ready to trace, shared across threads.
#[derive(Clone, Copy)]
pub struct BvhTracer<'r> {
    pub view: BvhView<'r>,
}

/// Dispatch on the BVH's triangle test: `$f::<T>($args)` with T = Mt, Wt or Pt.
macro_rules! by_test {
    ($test:expr, $f:ident ( $($a:expr),* )) => {
        match $test {
            TriTest::MollerTrumbore => $f::<Mt>($($a),*),
            TriTest::Watertight => $f::<Wt>($($a),*),
            TriTest::Projection => $f::<Pt>($($a),*),
        }
    };
}

impl BvhTracer<'_> {
    /// Where a BVH packet starts: `Some(None)` at the root, `Some(Some(e))`
    /// at the entry point `p.entry` finds, `None` when its frustum overlaps
    /// no triangle (every ray misses).
    fn start(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        ctr: &mut Counters,
    ) -> Option<Option<EntryPoint>> {
        if !matches!(
            p.method,
            Method::BvhMasked | Method::BvhRanged | Method::BvhPartition
        ) || p.entry == EntrySearch::None
        {
            return Some(None);
        }
        let bounds = self
            .view
            .nodes
            .first()
            .map_or(crate::geom::Aabb::EMPTY, |n| n.aabb());
        match search_entry(&self.view, p, rays, active, &bounds, ctr).1 {
            Start::Root => Some(None),
            Start::At(e) => Some(Some(e)),
            Start::Miss => None,
        }
    }
}

impl Tracer for BvhTracer<'_> {
    #[inline]
    fn intersect(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
        use bvh::traverse_single::intersect;
        by_test!(self.view.info.test, intersect(&self.view, ray, ctr))
    }
    #[inline]
    fn occluded(&self, ray: &Ray, ctr: &mut Counters) -> bool {
        use bvh::traverse_single::occluded;
        by_test!(self.view.info.test, occluded(&self.view, ray, ctr))
    }
    fn intersect_packet(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        _: &mut Mailbox<'_>,
        ctr: &mut Counters,
    ) {
        let (v, o, test) = (&self.view, &p.bvh, self.view.info.test);
        let Some(e) = self.start(p, rays, active, ctr) else {
            return all_miss(active, hits, ctr);
        };
        let e = e.as_ref();
        match p.method {
            Method::BvhSimd => {
                use bvh::traverse_simd::intersect;
                by_test!(test, intersect(v, rays, active, hits, ctr))
            }
            Method::BvhMasked => {
                use bvh::traverse_masked::intersect;
                by_test!(test, intersect(v, rays, active, hits, o, e, ctr))
            }
            Method::BvhRanged => {
                use bvh::traverse_ranged::intersect;
                by_test!(test, intersect(v, rays, active, hits, o, e, ctr))
            }
            Method::BvhPartition => {
                use bvh::traverse_partition::intersect;
                by_test!(test, intersect(v, rays, active, hits, o, e, ctr))
            }
            _ => lane_by_lane(rays, active, hits, |r, c| self.intersect(r, c), ctr),
        }
    }
    fn occluded_packet(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        _: &mut Mailbox<'_>,
        ctr: &mut Counters,
    ) {
        let (v, o, test) = (&self.view, &p.bvh, self.view.info.test);
        let Some(e) = self.start(p, rays, active, ctr) else {
            return all_miss(active, hits, ctr);
        };
        let e = e.as_ref();
        match p.method {
            Method::BvhSimd => {
                use bvh::traverse_simd::occluded;
                by_test!(test, occluded(v, rays, active, hits, ctr))
            }
            Method::BvhMasked => {
                use bvh::traverse_masked::occluded;
                by_test!(test, occluded(v, rays, active, hits, o, e, ctr))
            }
            Method::BvhRanged => {
                use bvh::traverse_ranged::occluded;
                by_test!(test, occluded(v, rays, active, hits, o, e, ctr))
            }
            Method::BvhPartition => {
                use bvh::traverse_partition::occluded;
                by_test!(test, occluded(v, rays, active, hits, o, e, ctr))
            }
            _ => {
                use bvh::traverse_single::any_hit;
                lane_by_lane(
                    rays,
                    active,
                    hits,
                    |r, c| by_test!(test, any_hit(v, r, c)),
                    ctr,
                )
            }
        }
    }
    fn triangle(&self, prim: u32) -> Option<TriVerts> {
        self.view.triangle(prim)
    }
    fn scene_scale(&self) -> f32 {
        scale_of(&self.view.info.bounds)
    }
}

/// Occlusion masks as `Tracer` hits: active lanes get `Hit::OCCLUDED` (kd
/// packets know no occluder id) or `Hit::MISS`; inactive lanes are untouched.
fn mark_occluded(occ: &[M4], active: &[M4], hits: &mut [Hit4]) {
    for ((o, m), h) in occ.iter().zip(active).zip(hits.iter_mut()) {
        for i in (0..4).filter(|&i| m.test(i)) {
            h.set_lane(i, if o.test(i) { Hit::OCCLUDED } else { Hit::MISS });
        }
    }
}

/// Count the active lanes of a packet whose rays were answered without
/// traversal (an entry search found that every ray misses).
fn count_rays(active: &[M4], ctr: &mut Counters) {
    ctr.rays += active
        .iter()
        .map(|m| m.bitmask().count_ones() as u64)
        .sum::<u64>();
}

/// A packet every active ray of which misses (entry search found no leaf).
fn all_miss(active: &[M4], hits: &mut [Hit4], ctr: &mut Counters) {
    count_rays(active, ctr);
    for (m, h) in active.iter().zip(hits.iter_mut()) {
        for i in (0..4).filter(|&i| m.test(i)) {
            h.set_lane(i, Hit::MISS);
        }
    }
}

/// Where a tree packet starts (`search_entry`).
enum Start {
    Root,
    At(EntryPoint),
    /// The frustum overlaps no triangle: every ray misses.
    Miss,
}

/// The packet's frustum (of `p.bvh.kind`; `None` without live lanes or when
/// none can be built) and, with `p.entry`, the entry point MLRTA or AEPSA
/// finds for it in `tree` (counted in `ctr`).
fn search_entry<E: EntryTree + ?Sized>(
    tree: &E,
    p: &TraceParams,
    rays: &[Ray4],
    active: &[M4],
    bounds: &crate::geom::Aabb,
    ctr: &mut Counters,
) -> (Option<Frustum>, Start) {
    let nq = rays
        .len()
        .min(active.len())
        .min(kd::traverse_packet::MAX_QUADS);
    let mut live = [M4::FALSE; kd::traverse_packet::MAX_QUADS];
    for q in 0..nq {
        live[q] = entry::live_mask(&rays[q], active[q]);
    }
    let f = Frustum::new(p.bvh.kind, &rays[..nq], &live[..nq], bounds);
    let (Some(fr), false) = (f, p.entry == EntrySearch::None) else {
        return (f, Start::Root);
    };
    let neg = entry::dir_signs(&rays[..nq], &live[..nq]);
    let e = match p.entry {
        EntrySearch::Mlrta => entry::mlrta::mlrta(tree, &fr, neg, ctr),
        _ => entry::aepsa::aepsa(tree, &fr, neg, ctr),
    };
    (f, e.map_or(Start::Miss, Start::At))
}

/// A built kd-tree as a `Tracer`.
#[derive(Clone, Copy)]
pub struct KdTracer<'r> {
    pub view: KdView<'r>,
}

impl KdTracer<'_> {
    /// Frustum and start of a `KdPacket` packet; the frustum only when
    /// culling is on.
    fn packet_start(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        ctr: &mut Counters,
    ) -> (Option<Frustum>, Start) {
        if !p.bvh.culling && p.entry == EntrySearch::None {
            return (None, Start::Root);
        }
        let (f, start) = search_entry(&self.view, p, rays, active, &self.view.info.root, ctr);
        (if p.bvh.culling { f } else { None }, start)
    }
}

impl Tracer for KdTracer<'_> {
    #[inline]
    fn intersect(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
        use kd::traverse_single::intersect;
        by_test!(self.view.info.test, intersect(&self.view, ray, ctr))
    }
    #[inline]
    fn occluded(&self, ray: &Ray, ctr: &mut Counters) -> bool {
        use kd::traverse_single::occluded;
        by_test!(self.view.info.test, occluded(&self.view, ray, ctr))
    }
    fn intersect_packet(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        _: &mut Mailbox<'_>,
        ctr: &mut Counters,
    ) {
        let (v, test) = (&self.view, self.view.info.test);
        match p.method {
            Method::KdSimd => {
                use kd::traverse_simd::intersect;
                for ((r, m), h) in rays.iter().zip(active).zip(hits.iter_mut()) {
                    let got = by_test!(test, intersect(v, r, *m, ctr));
                    for i in 0..4 {
                        if m.test(i) {
                            h.set_lane(i, got.lane(i));
                        }
                    }
                }
            }
            Method::KdPacket => {
                use kd::traverse_packet::intersect;
                let (f, start) = self.packet_start(p, rays, active, ctr);
                match start {
                    Start::Miss => all_miss(active, hits, ctr),
                    Start::Root => by_test!(
                        test,
                        intersect(v, rays, active, hits, f.as_ref(), None, ctr)
                    ),
                    Start::At(e) => by_test!(
                        test,
                        intersect(v, rays, active, hits, f.as_ref(), Some(&e), ctr)
                    ),
                }
            }
            _ => lane_by_lane(rays, active, hits, |r, c| self.intersect(r, c), ctr),
        }
    }
    fn occluded_packet(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        _: &mut Mailbox<'_>,
        ctr: &mut Counters,
    ) {
        let (v, test) = (&self.view, self.view.info.test);
        match p.method {
            Method::KdSimd => {
                use kd::traverse_simd::occluded;
                for ((r, m), h) in rays.iter().zip(active).zip(hits.iter_mut()) {
                    let o = by_test!(test, occluded(v, r, *m, ctr));
                    mark_occluded(&[o], core::slice::from_ref(m), core::slice::from_mut(h));
                }
            }
            Method::KdPacket => {
                use kd::traverse_packet::occluded;
                let (f, start) = self.packet_start(p, rays, active, ctr);
                let n = rays
                    .len()
                    .min(active.len())
                    .min(hits.len())
                    .min(kd::traverse_packet::MAX_QUADS);
                let mut occ = [M4::FALSE; kd::traverse_packet::MAX_QUADS];
                match start {
                    Start::Miss => count_rays(&active[..n], ctr),
                    Start::Root => by_test!(
                        test,
                        occluded(
                            v,
                            &rays[..n],
                            &active[..n],
                            &mut occ[..n],
                            f.as_ref(),
                            None,
                            ctr
                        )
                    ),
                    Start::At(e) => by_test!(
                        test,
                        occluded(
                            v,
                            &rays[..n],
                            &active[..n],
                            &mut occ[..n],
                            f.as_ref(),
                            Some(&e),
                            ctr
                        )
                    ),
                }
                mark_occluded(&occ[..n], &active[..n], &mut hits[..n]);
            }
            _ => {
                use kd::traverse_single::any_hit;
                lane_by_lane(
                    rays,
                    active,
                    hits,
                    |r, c| by_test!(test, any_hit(v, r, c)),
                    ctr,
                )
            }
        }
    }
    fn triangle(&self, prim: u32) -> Option<TriVerts> {
        self.view.triangle(prim)
    }
    fn scene_scale(&self) -> f32 {
        scale_of(&self.view.info.bounds)
    }
}

/// Scene scale of the stored triangles' (unpadded) bounds, the same for
/// every structure built from one scene, so shading offsets (and images) do
/// not depend on the structure.
fn scale_of(b: &crate::geom::Aabb) -> f32 {
    if b.is_empty() {
        1.0
    } else {
        b.diagonal().length()
    }
}

/// A packet traced one active lane at a time by a single-ray method.
fn lane_by_lane(
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    f: impl Fn(&Ray, &mut Counters) -> Hit,
    ctr: &mut Counters,
) {
    for ((r, m), h) in rays.iter().zip(active).zip(hits.iter_mut()) {
        for i in 0..4 {
            if m.test(i) {
                h.set_lane(i, f(&r.lane(i), ctr));
            }
        }
    }
}

/// Every structure a context has built, shared across threads: packet
/// calls go to the structure of `TraceParams::method`, single-ray calls
/// (`Tracer::intersect`, `occluded`) to the single-ray method `single`.
#[derive(Clone, Copy)]
pub struct SceneTracer<'r> {
    pub grid: Option<GridView<'r>>,
    pub bvh: Option<BvhView<'r>>,
    pub kd: Option<KdView<'r>>,
    /// `Method::GridDda`, `Method::BvhSingle` or `Method::KdSingle`.
    pub single: Method,
}

impl<'r> SceneTracer<'r> {
    /// The same structures with single-ray calls going to `method`'s
    /// structure; `NotBuilt` when that structure has not been built.
    pub fn with_single(&self, method: Method) -> Result<SceneTracer<'r>> {
        let built = match method.structure() {
            crate::trace::Structure::Grid => self.grid.is_some(),
            crate::trace::Structure::Bvh => self.bvh.is_some(),
            crate::trace::Structure::Kd => self.kd.is_some(),
        };
        if !built {
            return Err(Error::NotBuilt);
        }
        Ok(SceneTracer {
            single: method.single(),
            ..*self
        })
    }
    /// The grid part (None when no grid is built).
    pub fn grid(&self) -> Option<GridTracer<'r>> {
        self.grid.map(|view| GridTracer { view })
    }
    /// The BVH part (None when no BVH is built).
    pub fn bvh(&self) -> Option<BvhTracer<'r>> {
        self.bvh.map(|view| BvhTracer { view })
    }
    /// The kd-tree part (None when no kd-tree is built).
    pub fn kd(&self) -> Option<KdTracer<'r>> {
        self.kd.map(|view| KdTracer { view })
    }
    /// The tracer of `method`'s structure, as a trait object.
    #[inline]
    fn of(&self, method: Method) -> Option<AnyTracer<'r>> {
        match method.structure() {
            crate::trace::Structure::Grid => self.grid().map(AnyTracer::Grid),
            crate::trace::Structure::Bvh => self.bvh().map(AnyTracer::Bvh),
            crate::trace::Structure::Kd => self.kd().map(AnyTracer::Kd),
        }
    }
}

/// One structure's tracer (static dispatch by match).
enum AnyTracer<'r> {
    Grid(GridTracer<'r>),
    Bvh(BvhTracer<'r>),
    Kd(KdTracer<'r>),
}

impl Tracer for SceneTracer<'_> {
    #[inline]
    fn intersect(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
        match self.of(self.single) {
            Some(AnyTracer::Grid(g)) => g.intersect(ray, ctr),
            Some(AnyTracer::Bvh(b)) => b.intersect(ray, ctr),
            Some(AnyTracer::Kd(k)) => k.intersect(ray, ctr),
            None => Hit::MISS,
        }
    }
    #[inline]
    fn occluded(&self, ray: &Ray, ctr: &mut Counters) -> bool {
        match self.of(self.single) {
            Some(AnyTracer::Grid(g)) => g.occluded(ray, ctr),
            Some(AnyTracer::Bvh(b)) => b.occluded(ray, ctr),
            Some(AnyTracer::Kd(k)) => k.occluded(ray, ctr),
            None => false,
        }
    }
    fn intersect_packet(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        mb: &mut Mailbox<'_>,
        ctr: &mut Counters,
    ) {
        match self.of(p.method) {
            Some(AnyTracer::Grid(g)) => g.intersect_packet(p, rays, active, hits, mb, ctr),
            Some(AnyTracer::Bvh(b)) => b.intersect_packet(p, rays, active, hits, mb, ctr),
            Some(AnyTracer::Kd(k)) => k.intersect_packet(p, rays, active, hits, mb, ctr),
            None => lane_by_lane(rays, active, hits, |_, _| Hit::MISS, ctr),
        }
    }
    fn occluded_packet(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        mb: &mut Mailbox<'_>,
        ctr: &mut Counters,
    ) {
        match self.of(p.method) {
            Some(AnyTracer::Grid(g)) => g.occluded_packet(p, rays, active, hits, mb, ctr),
            Some(AnyTracer::Bvh(b)) => b.occluded_packet(p, rays, active, hits, mb, ctr),
            Some(AnyTracer::Kd(k)) => k.occluded_packet(p, rays, active, hits, mb, ctr),
            None => lane_by_lane(rays, active, hits, |_, _| Hit::MISS, ctr),
        }
    }
    /// The triangle from the structure of `single` (the primary method's):
    /// a structure left over from an older frame is never consulted.
    /// NOTE(perf): the BVH finds a triangle by id in O(1) (`slot_of`), the
    /// grid by binary search (23 % of a Whitted frame on conference, perf).
    fn triangle(&self, prim: u32) -> Option<TriVerts> {
        match self.of(self.single) {
            Some(AnyTracer::Grid(g)) => g.triangle(prim),
            Some(AnyTracer::Bvh(b)) => b.triangle(prim),
            Some(AnyTracer::Kd(k)) => k.triangle(prim),
            None => None,
        }
    }
    fn scene_scale(&self) -> f32 {
        match self.of(self.single) {
            Some(AnyTracer::Grid(g)) => g.scene_scale(),
            Some(AnyTracer::Bvh(b)) => b.scene_scale(),
            Some(AnyTracer::Kd(k)) => k.scene_scale(),
            None => 1.0,
        }
    }
}

#[allow(dead_code)]
fn _assert_sync() {
    fn is_sync<T: Sync>() {}
    is_sync::<GridTracer<'_>>();
    is_sync::<SceneTracer<'_>>();
    let _ = <Mt as TriangleTest>::KIND;
}

/// A context that owns its memory: exactly one allocation, made at creation
/// (std only). Offers the same calls as `Context`.
#[cfg(feature = "std")]
pub struct OwnedContext {
    inner: crate::mem::owned::Lent<Context<'static>>,
}

#[cfg(feature = "std")]
impl OwnedContext {
    /// Allocate `required_bytes(limits)` once and create the context in it.
    pub fn new(limits: &Limits) -> Result<OwnedContext> {
        let bytes = required_bytes(limits)?;
        let inner = crate::mem::owned::Lent::new(bytes, |buf| Context::new_in(buf, limits))?;
        Ok(OwnedContext { inner })
    }
    pub fn limits(&self) -> &Limits {
        self.inner.get().limits()
    }
    pub fn stats(&self) -> &Stats {
        self.inner.get().stats()
    }
    pub fn check_scene(&self, scene: &Scene<'_>) -> Result<()> {
        self.inner.get().check_scene(scene)
    }
    pub fn build_grid(&mut self, scene: &Scene<'_>, params: &GridParams) -> Result<GridInfo> {
        self.inner.get_mut().build_grid(scene, params)
    }
    pub fn build_bvh(&mut self, scene: &Scene<'_>, params: &BvhParams) -> Result<BvhInfo> {
        self.inner.get_mut().build_bvh(scene, params)
    }
    pub fn build_pgrid(&mut self, scene: &Scene<'_>, params: &PgridParams) -> Result<SceneInfo> {
        self.inner.get_mut().build_pgrid(scene, params)
    }
    pub fn deferred_pixel(&self, x: u32, y: u32) -> Option<(Hit, u8)> {
        self.inner.get().deferred_pixel(x, y)
    }
    pub fn trace_in_slot(
        &self,
        slot: u32,
        p: &TraceParams,
        rays: &[Ray],
        hits: &mut [Hit],
    ) -> Result<Counters> {
        self.inner.get().trace_in_slot(slot, p, rays, hits)
    }
    pub fn occluded_in_slot(
        &self,
        slot: u32,
        p: &TraceParams,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<Counters> {
        self.inner.get().occluded_in_slot(slot, p, rays, occluded)
    }
    #[allow(clippy::too_many_arguments)]
    pub fn render_rows_in_slot(
        &self,
        slot: u32,
        primary: &TraceParams,
        shadow: &TraceParams,
        frame: &Frame,
        y0: u32,
        y1: u32,
        band: &mut [u8],
        stride: usize,
    ) -> Result<Counters> {
        self.inner
            .get()
            .render_rows_in_slot(slot, primary, shadow, frame, y0, y1, band, stride)
    }
    pub fn deferred_shadow_ray(&self, x: u32, y: u32, light: &PointLight) -> Option<Ray> {
        self.inner.get().deferred_shadow_ray(x, y, light)
    }
    pub fn render_deferred<W: Workers>(
        &mut self,
        job: &DeferredJob<'_>,
        pixels: &mut [u8],
        stride: usize,
        workers: &mut W,
    ) -> Result<DeferredInfo> {
        self.inner
            .get_mut()
            .render_deferred(job, pixels, stride, workers)
    }
    pub fn build_kd(&mut self, scene: &Scene<'_>, params: &KdParams) -> Result<KdInfo> {
        self.inner.get_mut().build_kd(scene, params)
    }
    pub fn tracer(&self) -> Result<SceneTracer<'_>> {
        self.inner.get().tracer()
    }
    pub fn trace(&mut self, method: Method, rays: &[Ray], hits: &mut [Hit]) -> Result<Counters> {
        self.inner.get_mut().trace(method, rays, hits)
    }
    pub fn occluded(
        &mut self,
        method: Method,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<Counters> {
        self.inner.get_mut().occluded(method, rays, occluded)
    }
    pub fn check_frame(
        &self,
        frame: &Frame,
        pixels_len: usize,
        stride: usize,
    ) -> Result<PrimaryRays> {
        self.inner.get().check_frame(frame, pixels_len, stride)
    }
    pub fn render(
        &mut self,
        method: Method,
        frame: &Frame,
        pixels: &mut [u8],
        stride: usize,
    ) -> Result<Counters> {
        self.inner.get_mut().render(method, frame, pixels, stride)
    }
    pub fn render_with(
        &mut self,
        primary: &TraceParams,
        shadow: &TraceParams,
        frame: &Frame,
        pixels: &mut [u8],
        stride: usize,
    ) -> Result<Counters> {
        self.inner
            .get_mut()
            .render_with(primary, shadow, frame, pixels, stride)
    }
    pub fn trace_with(
        &mut self,
        p: &TraceParams,
        rays: &[Ray],
        hits: &mut [Hit],
    ) -> Result<Counters> {
        self.inner.get_mut().trace_with(p, rays, hits)
    }
    pub fn occluded_with(
        &mut self,
        p: &TraceParams,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<Counters> {
        self.inner.get_mut().occluded_with(p, rays, occluded)
    }
    pub fn parts(&mut self) -> Result<(SceneTracer<'_>, impl Iterator<Item = Mailbox<'_>>)> {
        self.inner.get_mut().parts()
    }
    pub fn record(&mut self, ctr: Counters, trace_ns: u64) {
        self.inner.get_mut().record(ctr, trace_ns)
    }
    pub fn render_whitted(
        &mut self,
        job: &WhittedJob<'_>,
        pixels: &mut [u8],
        stride: usize,
    ) -> Result<Counters> {
        self.inner.get_mut().render_whitted(job, pixels, stride)
    }
}
