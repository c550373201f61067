//! Deferred frames: camera rays first into a per-pixel hit buffer, then per
//! light all shadow rays at once, then shading. This is the frame of the
//! perspective/light grid paper (sections 3 and 4), whose light grids need
//! every hit point of the frame before any shadow ray is traced, and whose
//! timing breakdown (Figure 10) splits a frame into these phases:
//!
//! 1. primary structure build (the perspective grid, `PrimaryPass::Pgrid`);
//! 2. primary traversal: tracing tiles of `tile * group` pixels, each a work
//!    item; with `PrimaryPass::Traced` any other method traces the tiles;
//! 3. per light, data rearrangement: shadow rays made and mapped to light
//!    tiles, sorted, counted, chunked, compacted (`accel::pgrid::reorder`);
//! 4. per light, shadow structure build (the light grid);
//! 5. per light, shadow traversal: chunks as work items, shadow bits in
//!    pixel space; with `ShadowPass::Traced` any other method traces shadow
//!    packets from the light per pixel tile, as `render_tiles` does;
//! 6. shading (Lambert, every light, spot factors).
//!
//! Work items run through a `Workers`: on the calling thread (`OnCaller`)
//! or on a caller's thread pool (the CLI's). Each item owns a disjoint
//! range of the output buffers, so no item waits for another.
//!
//! The rays are exactly those of `render_rows` (camera rays through pixel
//! centres; shadow rays from the light to `p + n * eps`, `PointLight::at`),
//! so with one light the image equals `render_rows`' with the same triangle
//! test.

pub(crate) mod frame;

use super::{
    Frame, Packets, PixelRect, PointLight, PrimaryRays, SHADOW_OFFSET, ShadowPacket, Tracer,
    demorton, encode, shadow_packet,
};
use crate::accel::pgrid::reorder::Pairs;
use crate::accel::pgrid::{
    self as pgrid, CamView, CellsInfo, Chunk, LightFrame, LightView, ReorderInfo, traverse_primary,
    traverse_shadow,
};
use crate::accel::slot::Slot;
use crate::error::{Error, Result};
use crate::geom::{F4, Hit4, INVALID_ID, M4, Ray, Ray4, TriVerts};
use crate::mem::Slots;
use crate::mem::par::{MAX_WORKERS, Par, Parts, Serial, atomic_u32, share};
use crate::trace::{Counters, TraceParams};
use core::ops::Range;
use core::sync::atomic::Ordering;
use glam::Vec3;

/// Slot scratch of a deferred frame whose tiles have up to `q` quads,
/// `traced` being what the tiny-lane split and a family take under a traced
/// pass (`context::accel_scratch`): the most of a traced tile (quads,
/// masks, hits, shadow distances, and the traced pass under them), a
/// perspective-grid sorting tile (quads, masks, hits, and
/// `traverse_primary::scratch`) and a light-grid shadow batch (quads,
/// masks and occlusion of `traverse_shadow::MAX_QUADS` quads, and
/// `traverse_shadow::SCRATCH`).
pub const fn scratch(q: usize, traced: usize) -> usize {
    use crate::accel::slot::max;
    use crate::mem::scratch::bytes;
    let tile = bytes::<Ray4>(q) + bytes::<M4>(q) + bytes::<Hit4>(q);
    let traced_tile = tile + bytes::<F4>(q) + traced;
    let pgrid_tile = tile + crate::accel::pgrid::traverse_primary::scratch(q);
    let s = traverse_shadow::MAX_QUADS;
    let light_batch = bytes::<Ray4>(s) + 2 * bytes::<M4>(s) + traverse_shadow::SCRATCH;
    max(traced_tile, max(pgrid_tile, light_batch))
}

/// How camera rays are traced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PrimaryPass {
    /// The perspective grid (built by the render call).
    Pgrid,
    /// A method of the built grid, BVH or kd-tree.
    Traced(TraceParams),
}

/// How shadow rays are traced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ShadowPass {
    /// A spherical light grid per light, rays sorted into light tiles.
    LightGrid,
    /// A method of the built grid, BVH or kd-tree, in packets from the
    /// light per pixel tile (or ray by ray for single-ray methods).
    Traced(TraceParams),
}

/// Most lights of a deferred frame (one shadow bit each).
pub const MAX_LIGHTS: usize = 8;

/// A deferred frame.
#[derive(Clone, Copy, Debug)]
pub struct DeferredJob<'a> {
    pub frame: &'a Frame,
    /// Lights (at most `MAX_LIGHTS`); empty: `frame.light` alone.
    pub lights: &'a [PointLight],
    pub primary: PrimaryPass,
    pub shadow: ShadowPass,
}

impl<'a> DeferredJob<'a> {
    pub fn lights(&self) -> &'a [PointLight] {
        if self.lights.is_empty() {
            core::slice::from_ref(&self.frame.light)
        } else {
            self.lights
        }
    }

    /// Checks the lights and the passes' params, and that the context's
    /// limits `l` hold the frame (deferred renderer, packet sides; the
    /// perspective grid's tile is checked where it is built).
    pub fn validate(&self, l: &crate::mem::Limits) -> Result<()> {
        l.check_renderer(crate::mem::Limits::DEFERRED)?;
        if self.lights.len() > MAX_LIGHTS {
            return Err(Error::InvalidArgument(
                "a deferred frame takes at most 8 lights",
            ));
        }
        for l in self.lights() {
            l.validate()?;
        }
        if let PrimaryPass::Traced(p) = &self.primary {
            p.validate_for(l)?;
        }
        if let ShadowPass::Traced(p) = &self.shadow {
            p.validate_for(l)?;
        }
        Ok(())
    }
}

/// Wall time of each phase of the last deferred frame, in nanoseconds
/// (the paper's Figure 10; 0 without `std`), summed over lights.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PhaseTimes {
    pub primary_build: u64,
    pub primary_trace: u64,
    pub rearrange: u64,
    pub shadow_build: u64,
    pub shadow_trace: u64,
    pub shade: u64,
}

impl PhaseTimes {
    pub fn total(&self) -> u64 {
        self.primary_build
            + self.primary_trace
            + self.rearrange
            + self.shadow_build
            + self.shadow_trace
            + self.shade
    }
}

/// What the last deferred frame did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DeferredInfo {
    pub times: PhaseTimes,
    /// The perspective grid (zeros with a traced primary pass).
    pub camera: CellsInfo,
    /// The last light's grid (zeros with traced shadows).
    pub light: CellsInfo,
    /// Reordering summed over lights (`max_tile_rays`: the maximum).
    pub reorder: ReorderInfo,
    /// Shadow rays over all lights.
    pub shadow_rays: u64,
    /// Camera rays that hit.
    pub hits: u64,
}

/// Runs work items, each with a mailbox and counters of the thread that
/// runs it. Implementations may run items concurrently (the items own
/// disjoint outputs); the returned counters are the sum.
pub trait Workers {
    fn run<'m, I, F>(
        &mut self,
        slots: &mut dyn Iterator<Item = Slot<'m>>,
        items: &mut (dyn Iterator<Item = I> + Send),
        work: &F,
    ) -> Counters
    where
        I: Send,
        F: Fn(I, &mut Slot<'_>, &mut Counters) + Sync;

    /// The same threads as a `Par`, for the phases that are joined builds
    /// rather than work items (the perspective and light grid builds, the
    /// light frustum, the map, the sort and the chunking). `Serial` by
    /// default: those phases then run on the calling thread.
    fn par(&self) -> &dyn Par {
        &Serial
    }
}

/// Runs every item on the calling thread with the first mailbox.
pub struct OnCaller;

impl Workers for OnCaller {
    fn run<'m, I, F>(
        &mut self,
        slots: &mut dyn Iterator<Item = Slot<'m>>,
        items: &mut (dyn Iterator<Item = I> + Send),
        work: &F,
    ) -> Counters
    where
        I: Send,
        F: Fn(I, &mut Slot<'_>, &mut Counters) + Sync,
    {
        let mut ctr = Counters::default();
        let (mut none, mut p) = ([0u32; 0], 0u32);
        let mut slot = slots.next().unwrap_or_else(|| {
            Slot::new(
                crate::accel::mailbox::Mailbox::new(&mut none, &mut p),
                crate::mem::Scratch::empty(),
            )
        });
        for it in items {
            work(it, &mut slot, &mut ctr);
        }
        ctr
    }
}

/// Runs work items on the workers of a `Par` (the C ABI's joined frame):
/// each worker takes one of the first `workers()` slots and pulls items
/// from the shared iterator until it runs dry; a worker without a slot
/// (fewer slots than workers) runs no items, since items need a slot's
/// scratch. The joined phases (`par()`) use every worker.
pub struct OnPar<'p>(pub &'p dyn Par);

impl Workers for OnPar<'_> {
    fn run<'m, I, F>(
        &mut self,
        slots: &mut dyn Iterator<Item = Slot<'m>>,
        items: &mut (dyn Iterator<Item = I> + Send),
        work: &F,
    ) -> Counters
    where
        I: Send,
        F: Fn(I, &mut Slot<'_>, &mut Counters) + Sync,
    {
        // 1..=MAX_WORKERS: `Context::render_deferred` checks `par()` first.
        let workers = self.0.workers();
        let mut mine: [Option<Slot<'m>>; MAX_WORKERS] = core::array::from_fn(|_| None);
        for (m, s) in mine.iter_mut().zip(slots.take(workers)) {
            *m = Some(s);
        }
        let mut ctrs = [Counters::default(); MAX_WORKERS];
        {
            let queue = crate::mem::par::Turns::new(items);
            let (ss, cs) = (
                Parts::even(&mut mine[..workers], workers),
                Parts::even(&mut ctrs[..workers], workers),
            );
            self.0.run(&|w| {
                let ctr = &mut cs.get(w)[0];
                let mut drain = |slot: &mut Slot<'_>| {
                    while let Some(it) = queue.with(|q| q.next()) {
                        work(it, slot, ctr);
                    }
                };
                // Items need a slot's scratch: a worker without one (more
                // workers than slots) joins the `par()` phases only.
                if let Some(slot) = &mut ss.get(w)[0] {
                    drain(slot);
                }
            });
        }
        let mut sum = Counters::default();
        ctrs[..workers].iter().for_each(|c| sum.add(c));
        sum
    }

    fn par(&self) -> &dyn Par {
        self.0
    }
}

/// The threads of a deferred frame and the context's slots their work
/// items take: each phase hands every slot out afresh.
pub struct Crew<'c, 'a, W> {
    pub workers: &'c mut W,
    pub slots: &'c mut Slots<'a>,
}

impl<W: Workers> Crew<'_, '_, W> {
    /// `Workers::run` on every slot.
    fn run<I, F>(&mut self, items: &mut (dyn Iterator<Item = I> + Send), work: &F) -> Counters
    where
        I: Send,
        F: Fn(I, &mut Slot<'_>, &mut Counters) + Sync,
    {
        self.workers
            .run(&mut self.slots.all().map(Slot::of), items, work)
    }

    /// `Workers::par`: the threads of the joined phases.
    pub fn par(&self) -> &dyn Par {
        self.workers.par()
    }
}

/// Per-pixel buffers of deferred frames, carved at context creation
/// (`Limits::frame_pixels` entries each, laid out tile by tile).
pub struct FrameBuffers<'a> {
    /// Nearest triangle per pixel (`INVALID_ID`: miss) and its t.
    pub prim: &'a mut [u32],
    pub t: &'a mut [f32],
    /// The current light's shadow ray direction per pixel (x NaN: none).
    pub dirs: &'a mut [[f32; 3]],
    /// Shadow bits, one per light.
    pub shadow: &'a mut [u8],
    /// Light tile and pixel of every shadow ray, sorted by tile.
    pub ray_tiles: &'a mut [u32],
    pub ray_ids: &'a mut [u32],
    /// Occlusion of the sorted shadow rays.
    pub occ: &'a mut [u8],
    pub chunks: &'a mut [Chunk],
    /// Per light tile: 0 without rays, else 1 + the last slice its rays
    /// reach (`accel::pgrid::build::build_light`), `MAX_LIGHT_TILES`.
    pub reach: &'a mut [u32],
}

impl<'a> FrameBuffers<'a> {
    /// The buffers under `l` (empty without `Limits::PGRID`):
    /// `frame_pixels` entries each, a chunk per `MIN_CHUNK` pixels plus
    /// one per light tile, and the light tiles' reach.
    #[deny(clippy::arithmetic_side_effects)]
    pub fn carve(a: &mut impl crate::mem::Carve<'a>, l: &crate::mem::Limits) -> Result<Self> {
        use crate::mem::{Limits, TOO_BIG, entries, when};
        let px = if l.has(Limits::PGRID) {
            entries(l.frame_pixels())?
        } else {
            0
        };
        let chunks = px
            .checked_div(pgrid::MIN_CHUNK as usize)
            .and_then(|c| c.checked_add(px.min(pgrid::MAX_LIGHT_TILES)))
            .ok_or(TOO_BIG)?;
        Ok(FrameBuffers {
            prim: a.take(px)?,
            t: a.take(px)?,
            dirs: a.take(px)?,
            shadow: a.take(px)?,
            ray_tiles: a.take(px)?,
            ray_ids: a.take(px)?,
            occ: a.take(px)?,
            chunks: a.take(chunks)?,
            reach: a.take(when(px > 0, pgrid::MAX_LIGHT_TILES))?,
        })
    }
}

/// Tile-major layout of the frame buffers: tile `(tx, ty)` of `side`
/// pixels owns `side^2` consecutive entries, row by row.
#[derive(Clone, Copy, Debug)]
pub struct TileLayout {
    pub side: u32,
    pub tiles_x: u32,
    pub tiles_y: u32,
    pub width: u32,
    pub height: u32,
}

impl TileLayout {
    pub fn new(side: u32, width: u32, height: u32) -> TileLayout {
        TileLayout {
            side,
            tiles_x: width.div_ceil(side),
            tiles_y: height.div_ceil(side),
            width,
            height,
        }
    }
    pub fn len(&self) -> usize {
        (self.tiles_x * self.tiles_y * self.side * self.side) as usize
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    #[inline]
    pub fn index(&self, x: u32, y: u32) -> usize {
        let (tx, ty) = (x / self.side, y / self.side);
        let tile = (ty * self.tiles_x + tx) as usize;
        tile * (self.side * self.side) as usize
            + ((y % self.side) * self.side + x % self.side) as usize
    }
    /// Pixel of entry `i` (may lie outside the image in edge tiles).
    #[inline]
    pub fn pixel(&self, i: usize) -> (u32, u32) {
        let ss = (self.side * self.side) as usize;
        let tile = (i / ss) as u32;
        let local = (i % ss) as u32;
        (
            (tile % self.tiles_x) * self.side + local % self.side,
            (tile / self.tiles_x) * self.side + local / self.side,
        )
    }
}

/// Side of the tracing tiles of a pass.
pub fn tile_side(primary: &PrimaryPass, tile: u32, group: u32) -> u32 {
    match primary {
        PrimaryPass::Pgrid => tile * group,
        PrimaryPass::Traced(p) if p.tile_side() > 0 => p.tile_side(),
        PrimaryPass::Traced(_) => 8,
    }
}

const DUMMY: Ray = Ray {
    org: [0.0; 3],
    dir: [1.0, 0.0, 0.0],
    tmin: 0.0,
    tmax: 0.0,
};

/// Nearest hits per entry of a `TileLayout`: the triangle (`INVALID_ID`:
/// a miss) and its t; the frame buffers' `prim` and `t`, or a tile's share.
pub struct Nearest<'a> {
    pub prim: &'a mut [u32],
    pub t: &'a mut [f32],
}

/// One tracing tile, a work item of the camera pass: its first pixel
/// (x0, y0) and its `side^2` entries of the hit buffers, row by row.
struct Tile<'a> {
    x0: u32,
    y0: u32,
    hits: Nearest<'a>,
}

/// Phase 2: nearest hits of every camera ray into `hits` (layout `lay`).
/// `cam` is the perspective grid when `primary` is `Pgrid`, whose sorting
/// tiles are `cam.tile` pixels (`lay.side / group`).
pub fn primary_pass<T: Tracer + ?Sized, W: Workers>(
    tracer: &T,
    cam: Option<&CamView<'_>>,
    primary: &PrimaryPass,
    rays: &PrimaryRays,
    lay: &TileLayout,
    hits: Nearest<'_>,
    crew: &mut Crew<'_, '_, W>,
) -> Counters {
    let ss = (lay.side * lay.side) as usize;
    let n = lay.len();
    let mut items = hits.prim[..n]
        .chunks_mut(ss)
        .zip(hits.t[..n].chunks_mut(ss))
        .enumerate();
    // A traced pass's packets (tiles of `lay.side`) and their traversal,
    // chosen once for every tile.
    let traced = match primary {
        PrimaryPass::Traced(params) => {
            let p = TraceParams {
                packet: lay.side,
                ..*params
            };
            Some((p, tracer.packets(&p, false)))
        }
        PrimaryPass::Pgrid => None,
    };
    let work = |(tile, (p, tt)): (usize, (&mut [u32], &mut [f32])),
                slot: &mut Slot<'_>,
                ctr: &mut Counters| {
        let (x0, y0) = lay.pixel(tile * ss);
        let tile = Tile {
            x0,
            y0,
            hits: Nearest { prim: p, t: tt },
        };
        match (&traced, cam) {
            (Some(traced), _) => traced_tile(tracer, traced, rays, lay, tile, slot, ctr),
            (None, Some(cam)) => pgrid_tile(cam, rays, lay, tile, slot, ctr),
            (None, None) => tile.hits.prim.fill(INVALID_ID),
        }
    };
    crew.run(&mut items, &work)
}

/// One tracing tile through the perspective grid: its k x k sorting tiles,
/// each with its own cells (indirect mapping).
fn pgrid_tile(
    cam: &CamView<'_>,
    rays: &PrimaryRays,
    lay: &TileLayout,
    tile: Tile<'_>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let Tile {
        x0,
        y0,
        hits: Nearest { prim, t },
    } = tile;
    let sort = cam.tile;
    let st = cam.cells.info.tiles;
    let side = lay.side;
    let ts = side / sort;
    let half = sort / 2;
    let nq = (half * half) as usize;
    let (quads, s) = slot.reborrow().take(nq, Ray4::from_rays(&[DUMMY; 4]));
    let (active, s) = s.take(nq, M4::FALSE);
    let (hits, mut slot) = s.take(nq, Hit4::MISS);
    prim.fill(INVALID_ID);
    for sy in 0..ts {
        for sx in 0..ts {
            let (px, py) = (x0 + sx * sort, y0 + sy * sort);
            if px >= lay.width || py >= lay.height {
                continue;
            }
            for q in 0..nq {
                let (qx, qy) = (q as u32 % half, q as u32 / half);
                let mut lanes = [DUMMY; 4];
                let mut m = [false; 4];
                for (i, (dx, dy)) in LANES.iter().enumerate() {
                    let (x, y) = (px + 2 * qx + dx, py + 2 * qy + dy);
                    if x < lay.width && y < lay.height {
                        lanes[i] = rays.ray(x, y);
                        m[i] = true;
                    }
                }
                quads[q] = Ray4::from_rays(&lanes);
                active[q] = M4::new(m[0], m[1], m[2], m[3]);
                hits[q] = Hit4::MISS;
            }
            let tile = (py / sort) * st[0] + px / sort;
            traverse_primary::trace_tile(cam, tile, quads, active, hits, &mut slot, ctr);
            for q in 0..nq {
                let (qx, qy) = (q as u32 % half, q as u32 / half);
                for (i, (dx, dy)) in LANES.iter().enumerate() {
                    if active[q].test(i) {
                        let local =
                            ((sy * sort + 2 * qy + dy) * side + sx * sort + 2 * qx + dx) as usize;
                        prim[local] = hits[q].prim[i];
                        t[local] = hits[q].t[i];
                    }
                }
            }
        }
    }
}

/// Lane (dx, dy) of a 2x2 quad, in `Ray4` lane order.
const LANES: [(u32, u32); 4] = [(0, 0), (1, 0), (0, 1), (1, 1)];

/// One tile traced with a packet method (Morton quads, as `render_tiles`,
/// with the pass's parameters and traversal `traced`) or ray by ray.
fn traced_tile<T: Tracer + ?Sized>(
    tracer: &T,
    traced: &(TraceParams, Packets<'_>),
    rays: &PrimaryRays,
    lay: &TileLayout,
    tile: Tile<'_>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let Tile {
        x0,
        y0,
        hits: Nearest { prim, t },
    } = tile;
    let side = lay.side;
    let (p, packets) = traced;
    prim.fill(INVALID_ID);
    if p.tile_side() == 0 {
        for ly in 0..side {
            for lx in 0..side {
                let (x, y) = (x0 + lx, y0 + ly);
                if x < lay.width && y < lay.height {
                    let h = tracer.intersect(&rays.ray(x, y), ctr);
                    prim[(ly * side + lx) as usize] = h.prim;
                    t[(ly * side + lx) as usize] = h.t;
                }
            }
        }
        return;
    }
    let nq = ((side / 2) * (side / 2)) as usize;
    let (quads, s) = slot.reborrow().take(nq, Ray4::from_rays(&[DUMMY; 4]));
    let (active, s) = s.take(nq, M4::FALSE);
    let (hits, mut slot) = s.take(nq, Hit4::MISS);
    let rect = PixelRect::image(lay.width, lay.height);
    rays.packet(x0, y0, side, &rect, quads, active);
    hits.fill(Hit4::MISS);
    packets.run(p, quads, active, hits, &mut slot, ctr);
    for q in 0..nq {
        let (qx, qy) = demorton(q);
        for (i, (dx, dy)) in LANES.iter().enumerate() {
            if active[q].test(i) {
                let local = ((2 * qy + dy) * side + 2 * qx + dx) as usize;
                prim[local] = hits[q].prim[i];
                t[local] = hits[q].t[i];
            }
        }
    }
}

/// The facing normal and hit point of pixel (x, y)'s hit.
#[inline]
fn surface_of(ray: &Ray, t: f32, tri: &TriVerts) -> (Vec3, Vec3) {
    let d = Vec3::from(ray.dir);
    let mut n = tri.normal().normalize_or_zero();
    if n.dot(d) > 0.0 {
        n = -n;
    }
    (Vec3::from(ray.org) + d * t, n)
}

/// The shadow ray towards `light` of the surface camera ray `ray` hits at
/// `t` on `tri` (None: the surface faces away or is outside a spot's
/// cone): the ray every renderer shoots, `PointLight::at`.
#[inline]
pub fn shadow_ray(ray: &Ray, t: f32, tri: &TriVerts, light: &PointLight, eps: f32) -> Option<Ray> {
    let (p, n) = surface_of(ray, t, tri);
    light.at(p, n, true, eps).1
}

/// Shadow rays of one light: how many, their length range, and the mean
/// of their unit directions (for the light frustum's forward axis).
#[derive(Clone, Copy, Debug)]
pub struct ShadowRays {
    pub count: u32,
    pub near: f32,
    pub far: f32,
    pub mean_dir: Vec3,
}

/// A triangle by id, from the structure that found the hits.
pub type TriOf<'a> = &'a (dyn Fn(u32) -> Option<TriVerts> + Sync);

/// The surfaces the camera rays hit, what shadow rays and shading are made
/// from: per entry of `lay` the nearest triangle `prim` (`tri_of` looks it
/// up) at `t` along camera ray `rays`, and the shadow rays' offset `eps`.
#[derive(Clone, Copy)]
pub struct Surfaces<'a> {
    pub tri_of: TriOf<'a>,
    pub rays: &'a PrimaryRays,
    pub lay: &'a TileLayout,
    pub eps: f32,
    pub prim: &'a [u32],
    pub t: &'a [f32],
}

/// Phase 3a: the shadow ray of every pixel for `light` into `dirs` (x NaN
/// where there is none: miss, facing away, outside a spot's cone), tiles
/// as work items; then their count, length range and mean direction.
pub fn make_shadow_rays<W: Workers>(
    hits: &Surfaces<'_>,
    light: &PointLight,
    dirs: &mut [[f32; 3]],
    crew: &mut Crew<'_, '_, W>,
) -> ShadowRays {
    let Surfaces {
        tri_of,
        rays,
        lay,
        eps,
        prim,
        t,
    } = *hits;
    let ss = (lay.side * lay.side) as usize;
    let n = lay.len();
    let mut items = dirs[..n].chunks_mut(ss).enumerate();
    let work = |(tile, d): (usize, &mut [[f32; 3]]), _: &mut Slot<'_>, _: &mut Counters| {
        for (k, dk) in d.iter_mut().enumerate() {
            let i = tile * ss + k;
            dk[0] = f32::NAN;
            if prim[i] == INVALID_ID {
                continue;
            }
            let (x, y) = lay.pixel(i);
            let Some(tri) = tri_of(prim[i]) else { continue };
            if let Some(r) = shadow_ray(&rays.ray(x, y), t[i], &tri, light, eps) {
                *dk = r.dir;
            }
        }
    };
    crew.run(&mut items, &work);
    shadow_stats(&dirs[..n], crew.par())
}

/// Blocks the shadow rays' statistics are summed in: fixed, so the mean
/// direction rounds alike on any worker count.
const STAT_BLOCKS: usize = 64;

/// Count, length range and mean unit direction of the shadow rays in
/// `dirs` (x NaN: none), blocks of pixels split among `par`'s workers and
/// summed in block order.
fn shadow_stats(dirs: &[[f32; 3]], par: &dyn Par) -> ShadowRays {
    const NONE: ShadowRays = ShadowRays {
        count: 0,
        near: f32::INFINITY,
        far: 0.0,
        mean_dir: Vec3::ZERO,
    };
    let (n, workers) = (dirs.len(), par.workers());
    let mut blocks = [NONE; STAT_BLOCKS];
    {
        let bs = Parts::even(&mut blocks, workers);
        par.run(&|w| {
            let first = bs.start(w);
            for (k, s) in bs.get(w).iter_mut().enumerate() {
                for d in &dirs[share(n, first + k, STAT_BLOCKS)] {
                    if d[0].is_nan() {
                        continue;
                    }
                    let d = Vec3::from(*d);
                    let len = d.length();
                    s.count += 1;
                    s.near = s.near.min(len);
                    s.far = s.far.max(len);
                    s.mean_dir += d / len;
                }
            }
        });
    }
    blocks.iter().fold(NONE, |a, b| ShadowRays {
        count: a.count + b.count,
        near: a.near.min(b.near),
        far: a.far.max(b.far),
        mean_dir: a.mean_dir + b.mean_dir,
    })
}

/// Light tiles per side for `rays` shadow rays: `max` (the parameter), or
/// fewer when there are not 8 rays per tile on average: a small frame gets
/// a coarse light grid (fewer pairs to build, no emptier tiles).
pub fn light_tiles(max: u32, rays: u32) -> u32 {
    let side = libm::ceilf(libm::sqrtf(rays as f32 / 8.0)) as u32;
    side.clamp(1, max)
}

/// Phase 3b: the light's frustum, `tiles` per side, over the (a, b)
/// rectangle of this frame's shadow rays (and a spot's cone), and each
/// ray's (a, b) into the pools of `ab` (a in `tiles`, b in `ids`, as bits)
/// for `map_to_tiles`, the pixels split among `par`'s workers.
pub(crate) fn light_frame(
    light: &PointLight,
    s: &ShadowRays,
    tiles: u32,
    lay: &TileLayout,
    dirs: &[[f32; 3]],
    ab: Pairs<'_>,
    par: &dyn Par,
) -> LightFrame {
    let fwd = if light.is_spot() {
        Vec3::from(light.spot_direction).normalize()
    } else if s.mean_dir.length() > 1e-3 * s.count as f32 {
        s.mean_dir.normalize()
    } else {
        Vec3::Z
    };
    let helper = if fwd.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let right = fwd.cross(helper).normalize();
    let up = right.cross(fwd).normalize();
    let mut f = LightFrame {
        pos: Vec3::from(light.position),
        fwd,
        right,
        up,
        tiles: [tiles, tiles],
        ..LightFrame::default()
    };
    // Each worker's share of the pixels: their (a, b), and its range.
    let (n, workers) = (lay.len(), par.workers());
    let mut ranges = [[
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::INFINITY,
        f32::NEG_INFINITY,
    ]; MAX_WORKERS];
    {
        let (aa, bb) = (
            Parts::even(&mut ab.tiles[..n], workers),
            Parts::even(&mut ab.ids[..n], workers),
        );
        let out = Parts::even(&mut ranges[..workers], workers);
        par.run(&|w| {
            let (aa, bb, first) = (aa.get(w), bb.get(w), aa.start(w));
            let r = &mut out.get(w)[0];
            for (k, (ak, bk)) in aa.iter_mut().zip(bb.iter_mut()).enumerate() {
                let d = dirs[first + k];
                if d[0].is_nan() {
                    continue;
                }
                let (a, b) = f.angles(Vec3::from(d));
                (*ak, *bk) = (a.to_bits(), b.to_bits());
                *r = [r[0].min(a), r[1].max(a), r[2].min(b), r[3].max(b)];
            }
        });
    }
    let [mut a_lo, mut a_hi, mut b_lo, mut b_hi] = ranges[..workers].iter().fold(
        [
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ],
        |x, r| {
            [
                x[0].min(r[0]),
                x[1].max(r[1]),
                x[2].min(r[2]),
                x[3].max(r[3]),
            ]
        },
    );
    if light.is_spot() {
        // The cone's rectangle (section 4.1, Figure 6); rays are inside it.
        let c = crate::accel::pgrid::pseudo_of_angle(light.spot_angle_deg.to_radians());
        a_lo = a_lo.max(-c);
        a_hi = a_hi.min(c);
        b_lo = b_lo.max(-c);
        b_hi = b_hi.min(c);
    }
    if s.count == 0 {
        (a_lo, a_hi, b_lo, b_hi) = (0.0, 0.0, 0.0, 0.0);
    }
    let pad = 1e-4;
    f.a0 = a_lo - pad;
    f.b0 = b_lo - pad;
    f.inv_da = tiles as f32 / (a_hi - a_lo + 2.0 * pad);
    f.inv_db = tiles as f32 / (b_hi - b_lo + 2.0 * pad);
    f
}

/// Phase 3c (the map step): compact the shadow rays into (light tile,
/// pixel) `pairs`, reading the (a, b) bits `light_frame` left there, and
/// fill `reach` (per tile, 1 + the last slice of `depth` its rays reach;
/// 0: no ray). Each worker of `par` compacts its share of the pixels to
/// the start of that share: the pairs' parts of the two pools, one per
/// worker, are returned for the sort (`reorder::reorder`, phase 3d).
pub(crate) fn map_to_tiles(
    f: &LightFrame,
    depth: &crate::accel::pgrid::Slices,
    lay: &TileLayout,
    dirs: &[[f32; 3]],
    pairs: Pairs<'_>,
    reach: &mut [u32],
    par: &dyn Par,
) -> [Range<usize>; MAX_WORKERS] {
    let (n, workers) = (lay.len(), par.workers());
    let reach = atomic_u32(&mut reach[..(f.tiles[0] * f.tiles[1]) as usize]);
    reach.iter().for_each(|r| r.store(0, Ordering::Relaxed));
    let mut got = [0usize; MAX_WORKERS];
    {
        let (ts, is) = (
            Parts::even(&mut pairs.tiles[..n], workers),
            Parts::even(&mut pairs.ids[..n], workers),
        );
        let out = Parts::even(&mut got[..workers], workers);
        par.run(&|w| {
            let (ts, is, first) = (ts.get(w), is.get(w), share(n, w, workers).start);
            let mut k = 0;
            for j in 0..ts.len() {
                let i = first + j;
                if dirs[i][0].is_nan() {
                    continue;
                }
                let a = f32::from_bits(ts[j]);
                let b = f32::from_bits(is[j]);
                let tx = crate::accel::pgrid::tile_coord((a - f.a0) * f.inv_da, f.tiles[0]);
                let ty = crate::accel::pgrid::tile_coord((b - f.b0) * f.inv_db, f.tiles[1]);
                let tile = ty * f.tiles[0] + tx;
                let last = depth.hi(Vec3::from(dirs[i]).length()) + 1;
                // Most rays of a tile reach no further than the last one:
                // read first, and pay for the atomic max only to raise it.
                let r = &reach[tile as usize];
                if r.load(Ordering::Relaxed) < last {
                    r.fetch_max(last, Ordering::Relaxed);
                }
                ts[k] = tile;
                is[k] = i as u32;
                k += 1;
            }
            out.get(w)[0] = k;
        });
    }
    core::array::from_fn(|w| {
        if w < workers {
            let at = share(n, w, workers).start;
            at..at + got[w]
        } else {
            n..n
        }
    })
}

/// The shadow rays of a light sorted into its light tiles: their
/// `chunks`, the pixel of each sorted ray (`ids`), and each pixel's ray
/// direction (`dirs`, from the light).
#[derive(Clone, Copy)]
pub struct SortedRays<'a> {
    pub chunks: &'a [Chunk],
    pub ids: &'a [u32],
    pub dirs: &'a [[f32; 3]],
}

/// Where a light's occluded pixels are marked: bit `bit` of each pixel's
/// `shadow` byte.
pub struct ShadowBits<'a> {
    pub shadow: &'a mut [u8],
    pub bit: u8,
}

/// Phase 5 with the light grid: the chunks' rays traced in work items cut
/// by estimated cost (see below), each writing the occlusion of its rays
/// to its range of `occ`; then the shadow bit of every occluded ray's
/// pixel is set.
pub fn light_grid_pass<W: Workers>(
    g: &LightView<'_>,
    sorted: &SortedRays<'_>,
    occ: &mut [u8],
    bits: ShadowBits<'_>,
    r: u32,
    crew: &mut Crew<'_, '_, W>,
) -> Counters {
    let chunks = sorted.chunks;
    // Work items by estimated cost, a ray costing its light tile's pairs:
    // each item about the cost of r average rays. Crowded, dense tiles are
    // cut finer than their chunks (down to 16 rays), sparse ones bundled
    // (a CUDA block loads one tile's triangles, so the paper cannot merge
    // sparse tiles; a CPU thread can). Items are contiguous sorted rays.
    let cells = g.cells;
    let slices = cells.info.depth.count;
    let cost = move |c: &Chunk| -> u64 {
        let (a, b) = (c.tile * slices, (c.tile + 1) * slices);
        (cells.start[b as usize] - cells.start[a as usize]) as u64 + 1
    };
    let rays: u64 = chunks.iter().map(|c| c.count as u64).sum();
    let total: u64 = chunks.iter().map(|c| c.count as u64 * cost(c)).sum();
    // In u128: `total` may pass 2^52 before it is scaled by the chunk.
    let budget = (u128::from(total) * u128::from(r) / u128::from(rays.max(1))).max(1) as u64;
    let mut rest = &mut occ[..];
    let (mut k, mut o) = (0usize, 0u32);
    let mut items = core::iter::from_fn(move || {
        if k >= chunks.len() {
            return None;
        }
        let (k0, o0) = (k, o);
        let (mut spent, mut n) = (0u64, 0u32);
        while k < chunks.len() {
            let c = &chunks[k];
            let per = cost(c);
            let left = c.count - o;
            let can = if spent == 0 {
                ((budget / per) as u32).max(pgrid::MIN_CHUNK)
            } else {
                ((budget - spent) / per) as u32
            };
            let take = can.min(left);
            if take == 0 {
                break;
            }
            spent += take as u64 * per;
            n += take;
            o += take;
            if o == c.count {
                k += 1;
                o = 0;
            }
            if spent >= budget {
                break;
            }
        }
        let (mine, tail) = core::mem::take(&mut rest).split_at_mut(n as usize);
        rest = tail;
        Some(((k0, o0), mine))
    });
    let work =
        |((k0, o0), out): ((usize, u32), &mut [u8]), slot: &mut Slot<'_>, ctr: &mut Counters| {
            // Walk the chunk pieces of this item.
            let (mut k, mut o, mut at) = (k0, o0, 0usize);
            while at < out.len() {
                let c = &chunks[k];
                let take = ((c.count - o) as usize).min(out.len() - at);
                let piece = Chunk {
                    tile: c.tile,
                    start: c.start + o,
                    count: take as u32,
                };
                trace_one_chunk(g, sorted, &piece, &mut out[at..at + take], slot, ctr);
                at += take;
                k += 1;
                o = 0;
            }
        };
    let ctr = crew.run(&mut items, &work);
    let n: usize = chunks.iter().map(|c| c.count as usize).sum();
    for (&o, &id) in occ[..n].iter().zip(&sorted.ids[..n]) {
        if o != 0 {
            bits.shadow[id as usize] |= 1 << bits.bit;
        }
    }
    ctr
}

/// Chunk `c` of `sorted`: its rays as 2x2 rays in sorted order, traced in
/// batches, their occlusion into `out`.
fn trace_one_chunk(
    g: &LightView<'_>,
    sorted: &SortedRays<'_>,
    c: &Chunk,
    out: &mut [u8],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let (light, ray_ids, dirs) = (g.frame.pos, sorted.ids, sorted.dirs);
    // A batch's quads in the slot's scratch (`scratch` covers it).
    const Q: usize = traverse_shadow::MAX_QUADS;
    let (quads, s) = slot.reborrow().take(Q, Ray4::from_rays(&[DUMMY; 4]));
    let (active, s) = s.take(Q, M4::FALSE);
    let (occluded, mut slot) = s.take(Q, M4::FALSE);
    let ids = &ray_ids[c.start as usize..(c.start + c.count) as usize];
    for (b, batch) in ids.chunks(4 * traverse_shadow::MAX_QUADS).enumerate() {
        let nq = batch.len().div_ceil(4);
        for q in 0..nq {
            let mut lanes = [DUMMY; 4];
            let mut m = [false; 4];
            for i in 0..4 {
                if let Some(&id) = batch.get(4 * q + i) {
                    lanes[i] = Ray::new(light, Vec3::from(dirs[id as usize]), 0.0, 1.0);
                    m[i] = true;
                }
            }
            quads[q] = Ray4::from_rays(&lanes);
            active[q] = M4::new(m[0], m[1], m[2], m[3]);
        }
        traverse_shadow::trace_chunk(
            g,
            c.tile,
            &quads[..nq],
            &active[..nq],
            &mut occluded[..nq],
            &mut slot,
            ctr,
        );
        let base = b * 4 * traverse_shadow::MAX_QUADS;
        for k in 0..batch.len() {
            out[base + k] = occluded[k / 4].test(k % 4) as u8;
        }
    }
}

/// Phase 5 with another method: shadow packets from the light per tile of
/// the layout (split in depth as `render_tiles` does), or ray by ray.
pub fn traced_shadow_pass<T: Tracer + ?Sized, W: Workers>(
    tracer: &T,
    params: &TraceParams,
    light: &PointLight,
    lay: &TileLayout,
    dirs: &[[f32; 3]],
    bits: ShadowBits<'_>,
    crew: &mut Crew<'_, '_, W>,
) -> Counters {
    let org = Vec3::from(light.position);
    let bit = bits.bit;
    let ss = (lay.side * lay.side) as usize;
    let n = lay.len();
    let mut items = bits.shadow[..n].chunks_mut(ss).zip(dirs[..n].chunks(ss));
    let side = lay.side;
    let packet = params.tile_side() > 0;
    // The tiles' shadow packets and their traversal, chosen once.
    let p = TraceParams {
        packet: side,
        ..*params
    };
    let shadowed = tracer.packets(&p, true);
    let work = |(sh, d): (&mut [u8], &[[f32; 3]]), slot: &mut Slot<'_>, ctr: &mut Counters| {
        if !packet {
            for k in 0..ss {
                if !d[k][0].is_nan()
                    && tracer.occluded(&Ray::new(org, Vec3::from(d[k]), 0.0, 1.0), ctr)
                {
                    sh[k] |= 1 << bit;
                }
            }
            return;
        }
        // Packets of the tile in Morton order, so quarters are sub-packets.
        let nq = ss / 4;
        let (quads, s) = slot.reborrow().take(nq, Ray4::from_rays(&[DUMMY; 4]));
        let (active, s) = s.take(nq, M4::FALSE);
        let (hits, s) = s.take(nq, Hit4::MISS);
        let (dist, mut slot) = s.take(nq, F4::ZERO);
        for q in 0..nq {
            let (qx, qy) = demorton(q);
            let mut lanes = [DUMMY; 4];
            let mut m = [false; 4];
            for (i, (dx, dy)) in LANES.iter().enumerate() {
                let local = ((2 * qy + dy) * side + 2 * qx + dx) as usize;
                if !d[local][0].is_nan() {
                    let dir = Vec3::from(d[local]);
                    lanes[i] = Ray::new(org, dir, 0.0, 1.0);
                    dist[q][i] = dir.length();
                    m[i] = true;
                }
            }
            quads[q] = Ray4::from_rays(&lanes);
            active[q] = M4::new(m[0], m[1], m[2], m[3]);
            hits[q] = Hit4::MISS;
        }
        let packet = ShadowPacket {
            rays: quads,
            active,
            dist,
        };
        shadow_packet(&shadowed, &p, packet, hits, &mut slot, ctr);
        for q in 0..nq {
            let (qx, qy) = demorton(q);
            for (i, (dx, dy)) in LANES.iter().enumerate() {
                if active[q].test(i) && hits[q].prim[i] != INVALID_ID {
                    let local = ((2 * qy + dy) * side + 2 * qx + dx) as usize;
                    sh[local] |= 1 << bit;
                }
            }
        }
    };
    crew.run(&mut items, &work)
}

/// Phase 6: Lambert shading of every pixel with every light, a light whose
/// shadow bit is set contributing nothing; RGBA8 into `pixels` (`stride`
/// bytes per row), bands of rows as work items.
pub fn shade<W: Workers>(
    hits: &Surfaces<'_>,
    frame: &Frame,
    lights: &[PointLight],
    shadow: &[u8],
    pixels: &mut [u8],
    stride: usize,
    crew: &mut Crew<'_, '_, W>,
) {
    let Surfaces {
        tri_of,
        rays,
        lay,
        eps,
        prim,
        t,
    } = *hits;
    const BAND: usize = 8;
    let sh = &frame.shading;
    let h = frame.height as usize;
    let len = pixels.len().min(h * stride);
    // Saturating: a one-row frame accepts any stride.
    let mut items = pixels[..len]
        .chunks_mut(BAND.saturating_mul(stride))
        .enumerate();
    let work = |(b, rows): (usize, &mut [u8]), _: &mut Slot<'_>, _: &mut Counters| {
        for ry in 0..BAND {
            let y = (b * BAND + ry) as u32;
            if y >= frame.height {
                break;
            }
            for x in 0..frame.width {
                let i = lay.index(x, y);
                let tri = if prim[i] == INVALID_ID {
                    None
                } else {
                    tri_of(prim[i])
                };
                let c = match tri {
                    Some(tri) => {
                        let (p, n) = surface_of(&rays.ray(x, y), t[i], &tri);
                        let mut sum = Vec3::ZERO;
                        for (l, light) in lights.iter().enumerate() {
                            let (lit, _) = light.at(p, n, false, eps);
                            let lit = if sh.shadows && shadow[i] & (1 << l) != 0 {
                                0.0
                            } else {
                                lit
                            };
                            sum += Vec3::from(light.color) * lit;
                        }
                        Vec3::from(sh.albedo) * (Vec3::splat(sh.ambient) + sum)
                    }
                    None => Vec3::from(sh.background),
                };
                let at = ry * stride + x as usize * 4;
                rows[at..at + 4].copy_from_slice(&[encode(c.x), encode(c.y), encode(c.z), 255]);
            }
        }
    };
    crew.run(&mut items, &work);
}

/// Shadow-ray end point offset for a scene of `scale`.
pub fn shadow_eps(scale: f32) -> f32 {
    SHADOW_OFFSET * scale
}
