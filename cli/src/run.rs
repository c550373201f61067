//! Contexts sized for a scene, frames rendered in row bands on several
//! threads, PNG output.

use anyhow::{Context as _, Result, anyhow, bail};
use rayon::prelude::*;
use rayon::{ThreadPool, ThreadPoolBuilder};
use sheaf::Slot;
use sheaf::accel::grid::traverse_cgt::Mailbox;
use sheaf::mem::Scratch;
use sheaf::render::whitted::{WhittedJob, render_whitted_rows, render_whitted_tiles};
use sheaf::render::{Band, PrimaryRays, TileParams, Tracer, render_rows, render_tiles};
use sheaf::{
    Counters, Error, Frame, GridInfo, GridParams, Limits, Method, OwnedContext, Pool, Scene,
    TraceParams,
};
use std::borrow::BorrowMut;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Rows per band handed to a thread at a time: small enough to balance
/// cheap sky rows against busy ones, large enough that taking a band costs
/// nothing next to tracing it.
const BAND_ROWS: usize = 8;

/// Threads to render with: `requested` (1..=1024) or the available cores,
/// at most `Limits::for_triangles`' default of 8.
pub fn threads(requested: Option<u32>) -> Result<u32> {
    match requested {
        Some(n) if (1..=1024).contains(&n) => Ok(n),
        Some(n) => Err(anyhow!("--threads {n}: must be in 1..=1024")),
        None => {
            let cap = Limits::for_triangles(0).max_threads;
            Ok(std::thread::available_parallelism()
                .map_or(1, |n| n.get() as u32)
                .min(cap))
        }
    }
}

/// Limits for `scene` rendered at `size` by `threads` threads (grid pools by
/// the default rule: room for lambda up to about 7).
pub fn limits(scene: &Scene<'_>, size: (u32, u32), threads: u32) -> Limits {
    let mut l = Limits::for_triangles(scene.triangle_count());
    l.max_vertices = scene.vertex_count();
    l.max_image_width = size.0;
    l.max_image_height = size.1;
    l.max_threads = threads;
    l
}

/// Create a context for `limits` and build `scene` in it. When the grid
/// needs more cells or references than `limits` gives (a large lambda, huge
/// triangles), the pool is grown to what the build reported times `headroom`
/// and the context created again, so the caller ends with one context that
/// fits. Returns the context and the first build's info.
pub fn context_for(
    scene: &Scene<'_>,
    mut limits: Limits,
    params: &GridParams,
    headroom: f64,
) -> Result<(OwnedContext, GridInfo)> {
    // The projection test's 48 bytes per triangle only when it is chosen.
    limits.projection_test = params.test == sheaf::TriTest::Projection;
    for _ in 0..3 {
        let mut ctx = OwnedContext::new(&limits).context("creating the context")?;
        match ctx.build_grid(scene, params) {
            Ok(info) => return Ok((ctx, info)),
            Err(Error::Capacity {
                pool: pool @ (Pool::GridCells | Pool::GridRefs),
                needed,
                ..
            }) => {
                let grown = ((needed as f64 * headroom).ceil() as u64).max(needed);
                let grown = u32::try_from(grown).map_err(|_| {
                    anyhow!("the grid needs {needed} {}: more than 2^32", pool.name())
                })?;
                match pool {
                    Pool::GridCells => limits.max_grid_cells = grown,
                    _ => limits.max_grid_refs = grown,
                }
            }
            Err(e) => bail!("building the grid: {e}"),
        }
    }
    Err(anyhow!(
        "building the grid: pools still too small after growing them"
    ))
}

/// Build the BVH (default parameters, triangle test `test`) when one of
/// `params` traces it; returns its info then.
pub fn build_bvh_if_used(
    ctx: &mut OwnedContext,
    scene: &Scene<'_>,
    test: sheaf::TriTest,
    params: &[TraceParams],
    threads: u32,
) -> Result<Option<sheaf::accel::bvh::BvhInfo>> {
    if !params
        .iter()
        .any(|p| p.method.structure() == sheaf::trace::Structure::Bvh)
    {
        return Ok(None);
    }
    let p = sheaf::accel::bvh::BvhParams {
        test,
        ..Default::default()
    };
    ctx.build_bvh_with(scene, &p, &Broadcast::of(threads))
        .map(Some)
        .context("building the BVH")
}

/// Build the kd-tree (default `KdParams`: the binned build, on `threads`
/// joined threads; triangle test `test`) when one of `params` traces it;
/// returns its info then.
pub fn build_kd_if_used(
    ctx: &mut OwnedContext,
    scene: &Scene<'_>,
    test: sheaf::TriTest,
    params: &[TraceParams],
    threads: u32,
) -> Result<Option<sheaf::accel::kd::KdInfo>> {
    if !params
        .iter()
        .any(|p| p.method.structure() == sheaf::trace::Structure::Kd)
    {
        return Ok(None);
    }
    let p = sheaf::accel::kd::KdParams {
        test,
        ..Default::default()
    };
    ctx.build_kd_with(scene, &p, &Broadcast::of(threads))
        .map(Some)
        .context("building the kd-tree")
}

/// `limits` with kd-tree pools that hold `scene`'s tree (parameters `p`)
/// without leaves forced by full pools: a probe context with only the
/// kd-tree's pools is built; while the build forces leaves, its node and
/// reference pools are doubled (at most 3 times). Returns the limits (only
/// `max_kd_nodes` and `max_kd_refs` changed) and the probe's last build.
/// The build's event scratch has no knob: leaves it forces stay.
pub fn kd_limits(
    scene: &Scene<'_>,
    limits: Limits,
    p: &sheaf::accel::kd::KdParams,
) -> Result<(Limits, sheaf::accel::kd::KdInfo)> {
    let mut probe = Limits {
        structures: Limits::KD,
        ..limits
    };
    probe.projection_test = p.test == sheaf::TriTest::Projection;
    let mut info;
    let mut tries = 0;
    loop {
        let mut ctx = OwnedContext::new(&probe).context("creating the kd-tree context")?;
        info = ctx.build_kd(scene, p).context("building the kd-tree")?;
        if info.forced_leaves == 0 || tries == 3 {
            break;
        }
        tries += 1;
        let grow = |x: u64| u32::try_from(2 * x).unwrap_or(u32::MAX);
        probe.max_kd_nodes = grow(probe.kd_nodes());
        probe.max_kd_refs = grow(probe.kd_refs());
    }
    Ok((
        Limits {
            max_kd_nodes: probe.max_kd_nodes,
            max_kd_refs: probe.max_kd_refs,
            ..limits
        },
        info,
    ))
}

/// Whether `m` runs `TraceParams::entry` before its packets.
pub fn uses_entry(m: Method) -> bool {
    matches!(
        m,
        Method::KdPacket | Method::BvhMasked | Method::BvhRanged | Method::BvhPartition
    )
}

/// Render `frame` into `pixels` (RGBA8, stride `4 * width`) on `threads`
/// threads, each with its own mailbox slot of the context, and record the
/// counters and the wall time in the context's stats.
pub fn render_frame(
    ctx: &mut OwnedContext,
    primary: &TraceParams,
    shadow: &TraceParams,
    frame: &Frame,
    pixels: &mut [u8],
    threads: u32,
) -> Result<Counters> {
    let stride = frame.width as usize * 4;
    let rays = ctx
        .check_frame(frame, pixels.len(), stride)
        .context("frame")?;
    let start = Instant::now();
    let (tracer, slots) = ctx.parts()?;
    tracer.with_single(shadow.method)?;
    let tracer = tracer.with_single(primary.method)?;
    let slots: Vec<Slot<'_>> = slots.take(threads as usize).collect();
    let whole = Band {
        y0: 0,
        y1: frame.height,
        pixels,
        stride,
    };
    let ctr = render_bands(&tracer, primary, shadow, frame, &rays, whole, slots);
    ctx.record(ctr, start.elapsed().as_nanos() as u64);
    Ok(ctr)
}

/// `whole` (the frame's rows) in bands of rows (a multiple of the packet
/// side), taken in order by whichever thread is free; one thread per mailbox.
fn render_bands<T: Tracer>(
    tracer: &T,
    primary: &TraceParams,
    shadow: &TraceParams,
    frame: &Frame,
    rays: &PrimaryRays,
    whole: Band<'_>,
    slots: Vec<Slot<'_>>,
) -> Counters {
    let side = primary.tile_side().max(shadow.tile_side());
    let params = TileParams {
        primary: TraceParams {
            packet: side,
            ..*primary
        },
        shadow: *shadow,
    };
    let stride = whole.stride;
    bands(
        side,
        frame.height,
        whole.pixels,
        stride,
        slots,
        |y0, y1, pixels, slot, ctr| {
            let band = Band {
                y0,
                y1,
                pixels,
                stride,
            };
            if side > 0 {
                render_tiles(tracer, &params, frame, rays, band, slot, ctr);
            } else {
                render_rows(tracer, frame, rays, band, ctr);
            }
        },
    )
}

/// Split `height` rows of `pixels` into bands of whole tile rows (tiles of
/// `side` pixels; 0: single rays), run `work(y0, y1, band pixels, mailbox,
/// counters)` on each on a pool of one thread per mailbox, and return the
/// summed counters.
fn bands(
    side: u32,
    height: u32,
    pixels: &mut [u8],
    stride: usize,
    slots: Vec<Slot<'_>>,
    work: impl Fn(u32, u32, &mut [u8], &mut Slot<'_>, &mut Counters) + Sync,
) -> Counters {
    let side = side as usize;
    let band_rows = if side > 0 {
        side * BAND_ROWS.div_ceil(side)
    } else {
        BAND_ROWS
    };
    let pixels = &mut pixels[..height as usize * stride];
    let bands = pixels.par_chunks_mut(band_rows * stride).enumerate();
    par_mailboxes(slots, bands, |(i, band), slot, ctr| {
        let y0 = (i * band_rows) as u32;
        let y1 = (y0 + band_rows as u32).min(height);
        work(y0, y1, band, slot, ctr);
    })
}

/// Stack of each render thread: the Whitted packet path needs about 850 KB
/// at 32x32 with 8 bounces (`sheaf::render::whitted`, Memory).
const THREAD_STACK: usize = 4 << 20;

/// The rayon pool of `threads` threads (stacks of `THREAD_STACK` bytes),
/// made on first use and kept: frames and studies call this per frame, and
/// a frame should not pay for starting threads.
pub fn pool(threads: usize) -> Arc<ThreadPool> {
    static POOLS: Mutex<Vec<Arc<ThreadPool>>> = Mutex::new(Vec::new());
    let threads = threads.max(1);
    let mut pools = POOLS.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(p) = pools.iter().find(|p| p.current_num_threads() == threads) {
        return Arc::clone(p);
    }
    let p = Arc::new(
        ThreadPoolBuilder::new()
            .num_threads(threads)
            .stack_size(THREAD_STACK)
            .thread_name(|i| format!("sheaf-render-{i}"))
            .build()
            .expect("start the render threads"),
    );
    pools.push(Arc::clone(&p));
    p
}

/// Thread slots (owned, or borrowed: `M` is `Slot` or `&mut Slot`) lent
/// to the jobs of a pool, one at a time each: a job takes one when it
/// starts folding its items and gives it back when it ends. A pool of as
/// many threads as slots never runs more jobs at once, and a job never
/// waits for another inside (the work never calls into rayon), so one is
/// always free.
struct Lender<M>(Mutex<Vec<M>>);

/// A slot lent by `Lender`, given back on drop.
struct Lent<'s, M> {
    slots: &'s Lender<M>,
    mailbox: Option<M>,
}

impl<M> Lender<M> {
    fn take(&self) -> Lent<'_, M> {
        let mailbox = self.0.lock().unwrap_or_else(|p| p.into_inner()).pop();
        assert!(mailbox.is_some(), "a mailbox per pool thread");
        Lent {
            slots: self,
            mailbox,
        }
    }
}

impl<M> Lent<'_, M> {
    fn get<'m>(&mut self) -> &mut Slot<'m>
    where
        M: BorrowMut<Slot<'m>>,
    {
        self.mailbox
            .as_mut()
            .expect("a lent mailbox until dropped")
            .borrow_mut()
    }
}

impl<M> Drop for Lent<'_, M> {
    fn drop(&mut self) {
        if let Some(m) = self.mailbox.take() {
            self.slots
                .0
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .push(m);
        }
    }
}

/// Run `work(item, mailbox, counters)` over `items` on a pool of one thread
/// per mailbox (at least one), each job with a mailbox of its own; returns
/// the summed counters.
pub fn par_mailboxes<'m, M, I, F>(slots: Vec<M>, items: I, work: F) -> Counters
where
    M: BorrowMut<Slot<'m>> + Send,
    I: ParallelIterator,
    F: Fn(I::Item, &mut Slot<'m>, &mut Counters) + Sync,
{
    assert!(!slots.is_empty(), "at least one thread slot");
    let pool = pool(slots.len());
    let slots = Lender(Mutex::new(slots));
    pool.install(|| {
        items
            .fold(
                || (slots.take(), Counters::default()),
                |(mut slot, mut ctr), item| {
                    work(item, slot.get(), &mut ctr);
                    (slot, ctr)
                },
            )
            .map(|(_, ctr)| ctr)
            .reduce(Counters::default, |mut a, b| {
                a.add(&b);
                a
            })
    })
}

/// Render a Whitted frame (`job`) into `pixels` (RGBA8, stride `4 * width`)
/// on `threads` threads, as `render_frame` does for plain frames.
pub fn render_whitted_frame(
    ctx: &mut OwnedContext,
    job: &WhittedJob<'_>,
    pixels: &mut [u8],
    threads: u32,
) -> Result<Counters> {
    job.validate(ctx.limits()).context("Whitted parameters")?;
    let frame = job.frame;
    let stride = frame.width as usize * 4;
    let rays = ctx
        .check_frame(frame, pixels.len(), stride)
        .context("frame")?;
    let start = Instant::now();
    let (tracer, slots) = ctx.parts()?;
    tracer.with_single(job.shadow.method)?;
    tracer.with_single(job.secondary.method)?;
    let tracer = tracer.with_single(job.primary.method)?;
    let slots: Vec<Slot<'_>> = slots.take(threads as usize).collect();
    let side = job
        .primary
        .tile_side()
        .max(job.shadow.tile_side())
        .max(job.secondary.tile_side());
    let tiled = WhittedJob {
        primary: TraceParams {
            packet: side,
            ..job.primary
        },
        ..*job
    };
    let ctr = bands(
        side,
        frame.height,
        pixels,
        stride,
        slots,
        |y0, y1, pixels, slot, ctr| {
            let band = Band {
                y0,
                y1,
                pixels,
                stride,
            };
            if side > 0 {
                render_whitted_tiles(&tracer, &tiled, &rays, band, slot, ctr);
            } else {
                render_whitted_rows(&tracer, job, &rays, band, ctr);
            }
        },
    );
    ctx.record(ctr, start.elapsed().as_nanos() as u64);
    Ok(ctr)
}

/// Write RGBA8 `pixels` (`width x height`, tightly packed) as a PNG.
pub fn write_png(path: &Path, pixels: &[u8], width: u32, height: u32) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    image::save_buffer_with_format(
        path,
        pixels,
        width,
        height,
        image::ExtendedColorType::Rgba8,
        image::ImageFormat::Png,
    )
    .with_context(|| format!("cannot write {}", path.display()))
}

/// `rays / ns` in millions per second (0 for no time).
pub fn mrays(rays: u64, ns: u64) -> f64 {
    if ns == 0 {
        0.0
    } else {
        rays as f64 * 1e3 / ns as f64
    }
}

pub fn ms(ns: u64) -> f64 {
    ns as f64 * 1e-6
}

/// `84x12x90`.
pub fn res(info: &GridInfo) -> String {
    format!("{}x{}x{}", info.res[0], info.res[1], info.res[2])
}

// ---------------------------------------------------------------------------
// Deferred frames (`render::deferred`): work items on threads, pools grown

/// Wall time of the work items of one `Workers::run` call.
#[derive(Clone, Copy, Debug, Default)]
pub struct ItemTimes {
    /// Items run, the sum and the maximum of their wall times.
    pub count: u64,
    pub sum_ns: u64,
    pub max_ns: u64,
    /// Wall time of the whole call (first item taken to last finished).
    pub wall_ns: u64,
    /// Threads that ran items.
    pub threads: u32,
    /// The 99th percentile of the item times (0 unless `Threads::keep_items`).
    pub p99_ns: u64,
}

impl ItemTimes {
    fn add(&mut self, ns: u64) {
        self.count += 1;
        self.sum_ns += ns;
        self.max_ns = self.max_ns.max(ns);
    }
    fn merge(&mut self, o: &ItemTimes) {
        self.count += o.count;
        self.sum_ns += o.sum_ns;
        self.max_ns = self.max_ns.max(o.max_ns);
    }
    pub fn mean_ns(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum_ns as f64 / self.count as f64
        }
    }
    /// Slowest item over the mean item (1: perfectly even; 0: no items).
    pub fn imbalance(&self) -> f64 {
        let m = self.mean_ns();
        if m > 0.0 { self.max_ns as f64 / m } else { 0.0 }
    }
    /// The 99th percentile item over the mean item (0 without `p99_ns`).
    pub fn tail(&self) -> f64 {
        let m = self.mean_ns();
        if m > 0.0 { self.p99_ns as f64 / m } else { 0.0 }
    }
    /// Busy time of all threads over `threads x wall` (1: no thread idle).
    pub fn efficiency(&self) -> f64 {
        let cap = self.wall_ns as f64 * self.threads.max(1) as f64;
        if cap > 0.0 {
            (self.sum_ns as f64 / cap).min(1.0)
        } else {
            0.0
        }
    }
}

/// `Workers` on a rayon pool: one thread per mailbox taken (at most
/// `threads`), items pulled in order by whichever thread is free (rayon's
/// `par_bridge`), counters summed. Every call's item times are appended to `runs`
/// (callers clear it per frame): a deferred frame with one light and
/// shadows makes four calls, camera rays, shadow-ray making, the shadow
/// pass (one item per chunk with the light grid) and shading
/// (`shadow_pass`).
pub struct Threads {
    threads: usize,
    /// The same threads (at most `MAX_WORKERS`) for the frame's joined phases.
    par: Broadcast,
    pub runs: Vec<ItemTimes>,
    /// Keep every item's time of every call in `item_runs` (one list per
    /// entry of `runs`), in the order the iterator gave the items, and
    /// fill `ItemTimes::p99_ns`; `items` is the last call's list.
    pub keep_items: bool,
    pub items: Vec<u64>,
    pub item_runs: Vec<Vec<u64>>,
}

/// Calls a one-light deferred frame with shadows makes through `Workers`.
pub const DEFERRED_RUNS: usize = 4;

impl Threads {
    /// The shadow pass of the last one-light deferred frame with shadows
    /// (the third of its `DEFERRED_RUNS` calls) and its item times (empty
    /// unless `keep_items`).
    pub fn shadow_pass(&self) -> Option<(ItemTimes, &[u64])> {
        let n = self.runs.len();
        if n < DEFERRED_RUNS {
            return None;
        }
        let k = n - 2;
        let items = self.item_runs.get(k).map_or(&[][..], |v| &v[..]);
        Some((self.runs[k], items))
    }
}

impl Threads {
    pub fn new(threads: u32) -> Threads {
        let threads = threads.max(1) as usize;
        Threads {
            threads,
            par: Broadcast::of(threads as u32),
            runs: Vec::new(),
            keep_items: false,
            items: Vec::new(),
            item_runs: Vec::new(),
        }
    }
}

/// A pool's threads as a `Par`: a joined build's task runs once on every
/// thread of the pool (rayon's broadcast), the thread's index as worker.
pub struct Broadcast(pub Arc<ThreadPool>);

impl Broadcast {
    /// The pool of `threads` threads (at most `MAX_WORKERS`).
    pub fn of(threads: u32) -> Broadcast {
        Broadcast(pool(
            (threads.max(1) as usize).min(sheaf::mem::par::MAX_WORKERS),
        ))
    }
}

impl sheaf::mem::par::Par for Broadcast {
    fn workers(&self) -> usize {
        self.0.current_num_threads()
    }
    fn run(&self, task: &(dyn Fn(usize) + Sync)) {
        self.0.broadcast(|c| task(c.index()));
    }
}

impl sheaf::render::deferred::Workers for Threads {
    fn par(&self) -> &dyn sheaf::mem::par::Par {
        &self.par
    }

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
        let mut mbs: Vec<Slot<'_>> = slots.take(self.threads).collect();
        // A context without mailbox slots still runs (as `OnCaller` does).
        let (mut none, mut p) = ([0u32; 0], 0u32);
        if mbs.is_empty() {
            mbs.push(Slot::new(Mailbox::new(&mut none, &mut p), Scratch::empty()));
        }
        let threads = mbs.len() as u32;
        let pool = pool(mbs.len());
        let slots = Lender(Mutex::new(mbs));
        let keep = self.keep_items;
        /// What the jobs sum: counters, item times, (index, ns) per item.
        type Acc = (Counters, ItemTimes, Vec<(usize, u64)>);
        let start = Instant::now();
        let (ctr, mut times, mut all): Acc = pool.install(|| {
            // Items in the iterator's order, pulled by whichever thread is free.
            items
                .enumerate()
                .par_bridge()
                .fold(
                    || (slots.take(), Acc::default()),
                    |(mut slot, (mut ctr, mut times, mut all)), (i, it)| {
                        let t = Instant::now();
                        work(it, slot.get(), &mut ctr);
                        let ns = t.elapsed().as_nanos() as u64;
                        times.add(ns);
                        if keep {
                            all.push((i, ns));
                        }
                        (slot, (ctr, times, all))
                    },
                )
                .map(|(_, acc)| acc)
                .reduce(Acc::default, |(mut c, mut t, mut a), (c2, t2, a2)| {
                    c.add(&c2);
                    t.merge(&t2);
                    a.extend(a2);
                    (c, t, a)
                })
        });
        times.wall_ns = start.elapsed().as_nanos() as u64;
        times.threads = threads;
        if keep {
            all.sort_unstable();
            self.items = all.iter().map(|&(_, ns)| ns).collect();
            let mut sorted = self.items.clone();
            sorted.sort_unstable();
            if let Some(last) = sorted.len().checked_sub(1) {
                times.p99_ns = sorted[(last * 99).div_ceil(100)];
            }
        }
        // Item lists are kept per call (empty when `keep_items` is off).
        self.item_runs.truncate(self.runs.len());
        self.item_runs.resize(self.runs.len(), Vec::new());
        self.item_runs
            .push(if keep { self.items.clone() } else { Vec::new() });
        self.runs.push(times);
        ctr
    }
}

/// What a deferred frame's context is rebuilt with when its perspective or
/// light grid outgrows the pools: the scene, the grid's parameters, which
/// other structures the traced passes need, and the pgrid parameters.
pub struct DeferredSetup<'s> {
    pub scene: &'s Scene<'s>,
    pub grid: GridParams,
    pub bvh: bool,
    pub kd: bool,
    pub pgrid: sheaf::PgridParams,
}

impl DeferredSetup<'_> {
    /// A context for `limits` (with `Limits::PGRID` added) holding the
    /// grid (its pools grown as `context_for` does), the BVH and kd-tree
    /// when asked for, and the scene loaded for the perspective grids.
    pub fn context(&self, mut limits: Limits) -> Result<(OwnedContext, GridInfo)> {
        limits.structures |= Limits::PGRID;
        if self.bvh {
            limits.structures |= Limits::BVH;
        }
        if self.kd {
            limits.structures |= Limits::KD;
        }
        let (mut ctx, info) = context_for(self.scene, limits, &self.grid, 1.0)?;
        let test = self.grid.test;
        if self.bvh {
            let p = sheaf::accel::bvh::BvhParams {
                test,
                ..Default::default()
            };
            ctx.build_bvh(self.scene, &p).context("building the BVH")?;
        }
        if self.kd {
            let p = sheaf::accel::kd::KdParams {
                test,
                ..Default::default()
            };
            ctx.build_kd(self.scene, &p)
                .context("building the kd-tree")?;
        }
        let pp = sheaf::PgridParams { test, ..self.pgrid };
        ctx.build_pgrid(self.scene, &pp)
            .context("loading the scene for the perspective grids")?;
        Ok((ctx, info))
    }

    /// `render_deferred`; when a perspective or light grid needs more
    /// cells or pairs than the context has, the pool is grown to what the
    /// build reported times 1.25 (later frames' grids differ), the context
    /// made again by `context` and the frame rendered again. Returns the
    /// frame's info and whether the context was replaced.
    pub fn render(
        &self,
        ctx: &mut OwnedContext,
        job: &sheaf::DeferredJob<'_>,
        pixels: &mut [u8],
        workers: &mut Threads,
    ) -> Result<(sheaf::DeferredInfo, bool)> {
        let stride = job.frame.width as usize * 4;
        let mut grown = false;
        for _ in 0..4 {
            workers.runs.clear();
            workers.item_runs.clear();
            match ctx.render_deferred(job, pixels, stride, workers) {
                Ok(info) => return Ok((info, grown)),
                Err(Error::Capacity {
                    pool: pool @ (Pool::PgridCells | Pool::PgridRefs),
                    needed,
                    ..
                }) => {
                    let mut l = *ctx.limits();
                    let more = u32::try_from(((needed as f64 * 1.25).ceil() as u64).max(needed))
                        .map_err(|_| {
                            anyhow!(
                                "the perspective grids need {needed} {}: more than 2^32",
                                pool.name()
                            )
                        })?;
                    if pool == Pool::PgridCells {
                        l.max_pgrid_cells = more;
                    } else {
                        l.max_pgrid_refs = more;
                    }
                    *ctx = self.context(l)?.0;
                    grown = true;
                }
                Err(e) => bail!("deferred frame: {e}"),
            }
        }
        Err(anyhow!(
            "deferred frame: perspective grid pools still too small after growing them"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sheaf::render::deferred::Workers;

    #[test]
    fn threads_run_every_item_once_and_time_each() {
        let mut stamps = [0u32; 8];
        let mut packets = [0u32; 3];
        let mut st = stamps.chunks_mut(2);
        let mut mbs = packets.iter_mut().map(move |p| {
            Slot::new(
                Mailbox::new(st.next().unwrap_or(&mut []), p),
                Scratch::empty(),
            )
        });
        let mut w = Threads::new(2);
        w.keep_items = true;
        let mut items = 0..100u64;
        let ctr = w.run(&mut mbs, &mut items, &|i, _mb, c: &mut Counters| {
            c.rays += i;
            if i == 7 {
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
        });
        assert_eq!(ctr.rays, 4950);
        let t = w.runs[0];
        assert_eq!(t.count, 100);
        assert!(t.threads <= 2 && t.threads >= 1);
        assert!(t.max_ns >= 5_000_000 && t.max_ns <= t.sum_ns && t.sum_ns <= t.wall_ns * 2);
        assert!(t.imbalance() > 1.0 && t.p99_ns > 0);
        // Item times in item order: item 7 is the slow one.
        assert_eq!(w.items.len(), 100);
        assert_eq!(w.items[7], t.max_ns);
    }

    #[test]
    fn threads_without_mailboxes_still_run() {
        let mut w = Threads::new(4);
        let mut none = std::iter::empty();
        let mut items = 0..10u64;
        let ctr = w.run(&mut none, &mut items, &|i, _mb, c: &mut Counters| {
            c.rays += i
        });
        assert_eq!(ctr.rays, 45);
        assert_eq!(w.runs[0].threads, 1);
    }
}
