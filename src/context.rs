//! The context: every pool carved from one buffer at creation, then reused by
//! every frame. After `Context::new_in` nothing here allocates.
#![forbid(unsafe_code)]

use crate::accel::bvh::refit::{RefitInfo, RefitParams};
use crate::accel::bvh::{self, Bvh, BvhInfo, BvhParams, BvhPools};
use crate::accel::grid::{self, Grid, GridInfo, GridParams, GridPools};
use crate::accel::kd::{self, KdInfo, KdParams, KdPools, KdTree};
use crate::accel::pgrid::{self, Pgrid, PgridParams, PgridPools, SceneInfo};
use crate::accel::slot::max;
use crate::accel::twolevel::flatten::{Flat, FlatPools};
use crate::accel::twolevel::{self, TwoLevel, TwoLevelPools};
use crate::counters::{Counters, elapsed_ns, now};
use crate::error::{Error, Pool, Result};
use crate::geom::Scene;
use crate::mem::{Arena, Carve, Limits, Sizer, Slots, when};
use crate::render::deferred::{self, DeferredInfo, FrameBuffers, TileLayout};
use crate::render::{PrimaryRays, whitted};

mod render;
mod scene;
mod trace;

use crate::render::scratch as tile_scratch;

pub use crate::trace::SceneTracer;
pub use crate::trace::scene::{BvhTracer, GridTracer, KdTracer};

/// Scratch bytes the tiny-lane split and the packet traversal of any family
/// in `structures` (a `Limits::GRID`-style bit set: the grid, BVH and
/// kd-tree; the perspective grids are traced by the deferred frame alone,
/// which counts them) take at most, for packets of up to `q` quads: the
/// sum of what each family declares beside its code (`grid::scratch`,
/// `bvh::scratch`, `kd::scratch`), here above the families so that none
/// of them imports the others. The match over `Structure` is exhaustive,
/// so a new family fails to compile until it names its bytes (it must also
/// join `FAMILIES`, which the compiler cannot check);
/// `tests/exact/scratch.rs` drives every `Method::ALL` at its limits
/// against this sum, which a missing term fails.
pub const fn accel_scratch(q: usize, structures: u32) -> usize {
    use crate::accel::method::Structure;
    const FAMILIES: [Structure; 3] = [Structure::Grid, Structure::Bvh, Structure::Kd];
    let mut family = 0;
    let mut i = 0;
    while i < FAMILIES.len() {
        let s = FAMILIES[i];
        let (bit, bytes) = match s {
            Structure::Grid => (Limits::GRID, grid::scratch(q)),
            Structure::Bvh => (Limits::BVH, bvh::scratch(q)),
            Structure::Kd => (Limits::KD, kd::scratch(q)),
        };
        if structures & bit != 0 {
            family = max(family, bytes);
        }
        i += 1;
    }
    crate::accel::packet::scratch(q) + family
}

/// A thread slot outside any context sized for every family's largest
/// packets (`accel_scratch`): for tools and tests that call the packet
/// traversals directly.
#[cfg(feature = "std")]
impl crate::accel::slot::SlotBuf {
    /// A mailbox of `stamps` stamps (one per triangle of the structure a
    /// CGT packet with the mailbox traces; 0 for none) and the scratch of
    /// the tiny-lane split and any family's traversal of the largest packets.
    pub fn new(stamps: usize) -> Self {
        let all = Limits::ALL_STRUCTURES;
        Self::with_scratch(stamps, accel_scratch(crate::accel::packet::MAX_QUADS, all))
    }
}

/// Scratch bytes of one thread slot under `l`, the one sum of every
/// module's declared scratch: over the calls `l` allows, the most a caller
/// of a packet traversal holds plus what the tiny-lane split and a family
/// of `structures` take under it (`accel_scratch`). The
/// callers:
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
        // The geometries' BVHs under the top level, or the flattened
        // scene's grid or kd-tree, each with the tiny-lane split
        // (`trace::scene::Tracing`) above it.
        let under = accel_scratch(
            q,
            Limits::BVH | (l.structures & (Limits::GRID | Limits::KD)),
        );
        most = max(most, scene::scratch(q) + under);
    }
    if l.renders(Limits::TILES) {
        most = max(most, tile_scratch(q) + accel);
    }
    if l.renders(Limits::WHITTED) {
        most = max(most, whitted::scratch(q, l.max_bounces) + accel);
    }
    if l.renders(Limits::DEFERRED) && l.has(Limits::PGRID) {
        most = max(most, deferred::scratch(q, accel));
    }
    most.next_multiple_of(crate::mem::ARENA_ALIGN)
}

/// Every pool of a context, in the order they are carved.
struct Pools<'a> {
    grid: GridPools<'a>,
    slots: Slots<'a>,
    bvh: BvhPools<'a>,
    kd: KdPools<'a>,
    pg: PgridPools<'a>,
    frame: FrameBuffers<'a>,
    scene: twolevel::CarvedPools<'a>,
    flat: FlatPools<'a>,
}

/// The one list of a context's pools, each family's sized by its own
/// rule from the limits (`*Pools::carve`, next to the pools):
/// `required_bytes` runs it over a `Sizer`, `Context::new_in` over the
/// caller's buffer, so the two agree by construction.
fn carve<'a>(a: &mut impl Carve<'a>, l: &Limits) -> Result<Pools<'a>> {
    l.validate()?;
    // Mailbox stamps, one per triangle, for the structures that meet a
    // triangle repeatedly (the grid, the perspective grids).
    let stamps = when(
        l.has(Limits::GRID | Limits::PGRID),
        l.max_triangles as usize,
    );
    Ok(Pools {
        grid: GridPools::carve(a, l)?,
        slots: Slots::carve(a, l.max_threads as usize, stamps, slot_scratch_bytes(l))?,
        bvh: BvhPools::carve(
            a,
            l.has(Limits::BVH),
            l.max_triangles as usize,
            l.bvh_refs() as usize,
            l.projection_test,
        )?,
        kd: KdPools::carve(a, l)?,
        pg: PgridPools::carve(a, l)?,
        frame: FrameBuffers::carve(a, l)?,
        scene: TwoLevelPools::carve(a, l)?,
        flat: FlatPools::carve(a, l)?,
    })
}

/// Exact number of bytes `Context::new_in` needs for `limits` (the buffer
/// must also start on a 64-byte boundary).
pub fn required_bytes(limits: &Limits) -> Result<usize> {
    let mut sizer = Sizer::default();
    carve(&mut sizer, limits)?;
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
    /// The two-level scene and its world triangles (`context::scene`).
    world: scene::World<'a>,
    /// Which commit each structure was built from.
    sources: scene::Sources,
    /// The single mesh's filter (`set_filter`).
    mesh_filter: Option<crate::geom::Filter>,
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

/// The context's structures as a `SceneTracer` (single rays to the
/// grid), each view with its filter hook (`scene::hook`), borrowing only
/// the fields it reads: a deferred frame lends the others out.
macro_rules! structures {
    ($c:ident) => {{
        let hook = |s| crate::context::scene::hook(&$c.sources, s, $c.mesh_filter, &$c.world);
        crate::trace::SceneTracer {
            grid: $c
                .grid
                .view()
                .map(|v| v.filtered(hook(crate::mem::Limits::GRID))),
            bvh: $c
                .bvh
                .view()
                .map(|v| v.filtered(hook(crate::mem::Limits::BVH))),
            kd: $c
                .kd
                .view()
                .map(|v| v.filtered(hook(crate::mem::Limits::KD))),
            single: crate::trace::Method::GridDda,
            pgrid_filter: hook(crate::mem::Limits::PGRID),
        }
    }};
}
pub(crate) use structures;

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
            grid,
            slots,
            bvh,
            kd,
            pg,
            frame,
            scene,
            flat,
        } = carve(&mut arena, limits)?;
        debug_assert_eq!(arena.used(), need);
        Ok(Context {
            limits: *limits,
            grid: Grid::new(grid),
            bvh: Bvh::new(bvh),
            kd: KdTree::new(kd),
            pgrid: Pgrid::new(pg),
            world: scene::World {
                scene: TwoLevel::new(scene.pools()),
                flat: Flat::new(flat),
            },
            sources: scene::Sources::default(),
            mesh_filter: None,
            frame,
            frame_layout: None,
            frame_rays: None,
            slots,
            stats: Stats::default(),
            #[cfg(feature = "std")]
            owned: None,
        })
    }

    /// The single mesh's filter from now on (`geom::filter`; `None`:
    /// every candidate accepted), asked by every structure built from the
    /// mesh (geometry 0, no instance), unless a call forces opacity
    /// (`TraceParams::opaque`).
    pub fn set_filter(&mut self, filter: Option<crate::geom::Filter>) {
        self.mesh_filter = filter;
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
    /// step on them; the SAH builds split the top of the tree on the
    /// calling thread and the subtrees below it on the workers. Every
    /// quality gives the same tree for any number of workers.
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

    /// Rebuild the kd-tree from `scene` by `params.quality`'s build (the
    /// binned SAH build by default, the exact O(N log N) sweep of the AEPSA
    /// paper's section 5.1 with `High`). On error the previous tree stays
    /// valid.
    pub fn build_kd(&mut self, scene: &Scene<'_>, params: &KdParams) -> Result<KdInfo> {
        self.build_kd_with(scene, params, &crate::Serial)
    }

    /// `build_kd` on the caller's workers (as `build_bvh_with`): the
    /// binned builds split every step among them and make the same tree
    /// for any number of workers; `High` runs on the calling thread.
    pub fn build_kd_with(
        &mut self,
        scene: &Scene<'_>,
        params: &KdParams,
        par: &dyn crate::Par,
    ) -> Result<KdInfo> {
        self.check_scene(scene)?;
        let info = self.kd_over(scene, params, par)?;
        self.sources.set(Limits::KD, None);
        Ok(info)
    }

    /// The kd-tree build after the scene's checks.
    fn kd_over(
        &mut self,
        scene: &Scene<'_>,
        params: &KdParams,
        par: &dyn crate::Par,
    ) -> Result<KdInfo> {
        if !self.limits.has(Limits::KD) {
            return Err(Error::InvalidArgument(
                "no kd-tree pools: Limits::structures lacks KD",
            ));
        }
        let t = now();
        let info = kd::build::build_with(&mut self.kd, scene, params, par)?;
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

    /// Record counters and time of a frame rendered by the caller's threads
    /// (through `tracer()` and `render::render_rows`).
    pub fn record(&mut self, ctr: Counters, trace_ns: u64) {
        self.stats.counters = ctr;
        self.stats.trace_ns = trace_ns;
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
