//! The one dispatch of a trace call, made once per call in one place
//! (`Tracing::new`, from `batch_on`): `Method` picks the family
//! (`Method::structure`), the structure's triangle test (and its culling)
//! picks the monomorphised traversals (`geom::with_test!`), the kernel
//! table (`Kernels`, one row per method and family) picks the traversal,
//! and `TraceParams::isa` its lane width (`isa::Chosen`). The batch loop
//! (`packets`) forms each packet once, and `Tracing::run` calls the
//! chosen kernel on it.
//! The renderers see every structure as a `Tracer` and choose with
//! `Tracer::packets` once per frame (per band of tiles); the Rust and C
//! trace calls go through `batch_on`.
#![forbid(unsafe_code)]

use crate::accel::bvh::BvhView;
use crate::accel::grid::GridView;
use crate::accel::kd::KdView;
use crate::accel::packet::{self, Kernel, LaneByLane, MAX_QUADS};
use crate::accel::slot::Slot;
use crate::accel::{Accel, method::Method, method::Structure, method::TraceParams};
use crate::counters::Counters;
use crate::error::{Error, Result};
use crate::geom::{Hit, Hit4, Hook, M4, Ray, Ray4, TriTest, TriVerts, TriangleTest, with_test};
use crate::isa::Chosen;

/// Slot scratch `batch_on` holds while its kernel runs: one packet's
/// quads, lane masks and hits, for packets of up to `q` quads.
pub const fn scratch(q: usize) -> usize {
    use crate::mem::scratch::bytes;
    bytes::<Ray4>(q) + bytes::<M4>(q) + bytes::<Hit4>(q)
}

/// What a structure offers the renderer: nearest hits and occlusion for
/// single rays and for packets of 2x2 quads, and the triangle a hit refers
/// to (for its normal).
pub trait Tracer: Sync {
    fn intersect(&self, ray: &Ray, ctr: &mut Counters) -> Hit;
    fn occluded(&self, ray: &Ray, ctr: &mut Counters) -> bool;
    /// The packet traversal of `p` (nearest hits, or with `any` occlusion),
    /// chosen once (`Tracing`) for the many packets of a frame or a call:
    /// `Packets::run` traces each.
    fn packets(&self, p: &TraceParams, any: bool) -> Packets<'_>;
    /// Nearest hits of the active lanes of one packet (`p.method` decides
    /// how; single-ray methods trace lane by lane). `slot` is the calling
    /// thread's. Chooses the traversal for this packet: loops over packets
    /// choose once with `packets`.
    fn intersect_packet(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        slot: &mut Slot<'_>,
        ctr: &mut Counters,
    ) {
        self.packets(p, false).run(p, rays, active, hits, slot, ctr)
    }
    /// Occlusion of the active lanes of one packet: a hit (`prim !=
    /// INVALID_ID`) marks an occluded lane. As `intersect_packet`.
    fn occluded_packet(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        slot: &mut Slot<'_>,
        ctr: &mut Counters,
    ) {
        self.packets(p, true).run(p, rays, active, hits, slot, ctr)
    }
    fn triangle(&self, prim: u32) -> Option<TriVerts>;
    /// Scale of the scene, for the shadow-ray origin offset.
    fn scene_scale(&self) -> f32;
}

/// A packet traversal chosen once (`Tracer::packets`): the family's view
/// with its `Tracing`, or no structure.
#[derive(Clone, Copy)]
pub enum Packets<'r> {
    Grid(GridView<'r>, Tracing<GridView<'r>>),
    Bvh(BvhView<'r>, Tracing<BvhView<'r>>),
    Kd(KdView<'r>, Tracing<KdView<'r>>),
    /// The method's structure is not built: every active lane misses.
    Unbuilt,
}

impl Packets<'_> {
    /// Trace the active lanes of `rays` (`Tracing::run`) with `p`, the
    /// parameters the choice was made for (or ones differing only in what
    /// the kernels read per packet: `bvh.kind`, `split`).
    #[inline]
    pub fn run(
        &self,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        slot: &mut Slot<'_>,
        ctr: &mut Counters,
    ) {
        match self {
            Packets::Grid(a, k) => k.run(a, p, rays, active, hits, slot, ctr),
            Packets::Bvh(a, k) => k.run(a, p, rays, active, hits, slot, ctr),
            Packets::Kd(a, k) => k.run(a, p, rays, active, hits, slot, ctr),
            Packets::Unbuilt => packet::lane_by_lane(rays, active, hits, |_, _| Hit::MISS, ctr),
        }
    }
}

/// Every family is a `Tracer` through the contract (`tracing_of`). One
/// impl per family, not a blanket `impl<A: Accel>`: the packet methods are
/// then ordinary functions, compiled once in this crate, so a caller in
/// another crate (a test, the CLI) links to them instead of instantiating
/// the packet traversals again at every lane width.
macro_rules! family_tracer {
    ($($view:ident => $variant:ident),*) => {$(
        impl Tracer for $view<'_> {
            #[inline]
            fn intersect(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
                with_test!(self.test(), |T| single::<Self, T>(self, ray, ctr))
            }
            #[inline]
            fn occluded(&self, ray: &Ray, ctr: &mut Counters) -> bool {
                with_test!(self.test(), |T| occluded::<Self, T>(self, ray, ctr))
            }
            fn packets(&self, p: &TraceParams, any: bool) -> Packets<'_> {
                let v = self.opaque_if(p.opaque);
                Packets::$variant(v, v.tracing(p, any))
            }
            fn triangle(&self, prim: u32) -> Option<TriVerts> {
                Accel::triangle(self, prim)
            }
            fn scene_scale(&self) -> f32 {
                scale_of(&self.bounds())
            }
        }
    )*};
}

family_tracer!(GridView => Grid, BvhView => Bvh, KdView => Kd);

macro_rules! family_tracing {
    ($($view:ident),*) => {$(
        impl<'r> $view<'r> {
            /// The family's `Tracing` for a trace call (`tracing_of`): an
            /// ordinary function, compiled once in this crate, so generic
            /// callers (`batch_on` in another crate) do not instantiate the
            /// family's kernels again.
            pub fn tracing(&self, p: &TraceParams, any: bool) -> Tracing<$view<'r>> {
                tracing_of(self, p, any)
            }
        }
    )*};
}

family_tracing!(GridView, BvhView, KdView);

/// The one choice of a trace call on family `a`: its kernel for `p`
/// (method and lane width, `Kernels::kernel`), triangle test and whether it
/// answers occlusion (`any`). Callers outside this module use the
/// families' `tracing`.
#[inline]
fn tracing_of<A: Kernels>(a: &A, p: &TraceParams, any: bool) -> Tracing<A> {
    with_test!(a.test(), |T| Tracing::either::<T>(p, any))
}

impl<'r> Tracing<BvhView<'r>> {
    /// The choice `tracing_of` makes, on BVHs built with triangle test
    /// `test` (the two-level scene's geometries, `Context::trace_scene_each`;
    /// their views carry the call's culling, `BvhView::cull`).
    pub fn of_test(test: TriTest, p: &TraceParams, any: bool) -> Self {
        with_test!(test, |T| Tracing::either::<T>(p, any))
    }
}

/// A trace call's choice on one family, made once and run per packet
/// (`run`): the family's kernel (the kernel table's traversal for the
/// method at its lane width, with the triangle test, culling and
/// occlusion) and, for the n x n packet methods, the family's fastest
/// single ray for the lanes with tiny directions (`accel::packet::quieted`).
pub struct Tracing<A: Accel> {
    kernel: Kernel<A>,
    single: fn(&A, &Ray, &mut Counters) -> Hit,
    split_tiny: bool,
}

impl<A: Accel> Clone for Tracing<A> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<A: Accel> Copy for Tracing<A> {}

/// The kernel table: each family's packet traversal for each method, with
/// triangle test (and culling) `T`, nearest hits or with `ANY` occlusion,
/// at the lane width of `p.isa` (`Chosen::new`; `Chosen::baseline` for
/// traversals without wide lanes). Every method is named in every
/// family's row (no wildcard): a new `Method` fails to compile until each
/// family says how it traces it. A method of another family runs the
/// family's single ray lane by lane (`LaneByLane`).
pub trait Kernels: Accel + Sized {
    fn kernel<T: TriangleTest, const ANY: bool>(p: &TraceParams) -> Kernel<Self>;
}

impl Kernels for GridView<'_> {
    fn kernel<T: TriangleTest, const ANY: bool>(p: &TraceParams) -> Kernel<Self> {
        use crate::accel::grid::traverse_cgt::Cgt;
        match p.method {
            Method::GridCgt => Chosen::new::<Cgt<T, ANY>>(p.isa),
            Method::GridDda
            | Method::BvhSingle
            | Method::BvhSimd
            | Method::BvhMasked
            | Method::BvhRanged
            | Method::BvhPartition
            | Method::BvhWide
            | Method::BvhWideRanged
            | Method::BvhFrustum
            | Method::KdSingle
            | Method::KdSimd
            | Method::KdPacket => Chosen::baseline::<LaneByLane<T, ANY>>(),
        }
    }
}

impl Kernels for BvhView<'_> {
    fn kernel<T: TriangleTest, const ANY: bool>(p: &TraceParams) -> Kernel<Self> {
        use crate::accel::bvh::packet::Walked;
        use crate::accel::bvh::traverse_frustum::FrustumFirst;
        use crate::accel::bvh::traverse_masked::Masked;
        use crate::accel::bvh::traverse_partition::Partition;
        use crate::accel::bvh::traverse_ranged::Ranged;
        use crate::accel::bvh::traverse_wide_ranged::WideRanged;
        use crate::accel::bvh::{traverse_simd, traverse_wide};
        match p.method {
            Method::BvhFrustum => Chosen::new::<FrustumFirst<T, ANY>>(p.isa),
            Method::BvhMasked => Chosen::new::<Walked<Masked, T, ANY>>(p.isa),
            Method::BvhRanged => Chosen::new::<Walked<Ranged, T, ANY>>(p.isa),
            Method::BvhPartition => Chosen::new::<Walked<Partition, T, ANY>>(p.isa),
            Method::BvhWideRanged => Chosen::new::<Walked<WideRanged, T, ANY>>(p.isa),
            Method::BvhSimd => Chosen::baseline::<traverse_simd::Simd<T, ANY>>(),
            Method::BvhWide => Chosen::baseline::<traverse_wide::ByLane<T, ANY>>(),
            Method::BvhSingle
            | Method::GridDda
            | Method::GridCgt
            | Method::KdSingle
            | Method::KdSimd
            | Method::KdPacket => Chosen::baseline::<LaneByLane<T, ANY>>(),
        }
    }
}

impl Kernels for KdView<'_> {
    fn kernel<T: TriangleTest, const ANY: bool>(p: &TraceParams) -> Kernel<Self> {
        use crate::accel::kd::traverse_packet::{Packets, with_class};
        use crate::accel::kd::traverse_simd::Simd;
        match p.method {
            Method::KdPacket => {
                let nq = packet::quads(p.packet);
                with_class!(nq, |Q| Chosen::new::<Packets<T, ANY, Q>>(p.isa))
            }
            Method::KdSimd => Chosen::baseline::<Simd<T, ANY>>(),
            Method::KdSingle
            | Method::GridDda
            | Method::GridCgt
            | Method::BvhSingle
            | Method::BvhSimd
            | Method::BvhMasked
            | Method::BvhRanged
            | Method::BvhPartition
            | Method::BvhWide
            | Method::BvhWideRanged
            | Method::BvhFrustum => Chosen::baseline::<LaneByLane<T, ANY>>(),
        }
    }
}

impl<A: Kernels> Tracing<A> {
    /// `A`'s kernel for `p` with triangle test (and culling) `T`:
    /// nearest hits, or with `ANY` occlusion.
    pub fn new<T: TriangleTest, const ANY: bool>(p: &TraceParams) -> Self {
        Tracing {
            kernel: A::kernel::<T, ANY>(p),
            single: fastest::<A, T, ANY>,
            split_tiny: p.method.is_packet() && p.fallbacks,
        }
    }

    /// `new` with `ANY` = `any`.
    #[inline]
    fn either<T: TriangleTest>(p: &TraceParams, any: bool) -> Self {
        if any {
            Self::new::<T, true>(p)
        } else {
            Self::new::<T, false>(p)
        }
    }

    /// Trace the active lanes of `rays` (one packet, or consecutive
    /// packets of `MAX_QUADS` quads) on `a` with `p`: the parameters the
    /// choice was made for, or ones differing only in what the kernels
    /// read per packet (the two-level walk's `bvh.kind`). Inactive lanes of
    /// `hits` are left untouched.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // the packet contract's
    pub fn run(
        &self,
        a: &A,
        p: &TraceParams,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        slot: &mut Slot<'_>,
        ctr: &mut Counters,
    ) {
        let n = rays.len().min(active.len()).min(hits.len());
        for r in packet::packet_ranges(n) {
            let (rays, active, hits) = (&rays[r.clone()], &active[r.clone()], &mut hits[r]);
            if self.split_tiny && packet::any_tiny(rays, active) {
                let k = &self.kernel;
                let traced =
                    |r: &[Ray4], m: &[M4], h: &mut [Hit4], s: Slot<'_>, c: &mut Counters| {
                        k.call((a, p, r, m, h, s, c))
                    };
                let single = |r: &Ray, c: &mut Counters| (self.single)(a, r, c);
                packet::quieted(rays, active, hits, slot, ctr, traced, single);
            } else {
                self.kernel
                    .call((a, p, rays, active, hits, slot.reborrow(), ctr))
            }
        }
    }

    /// `run` as a closure (the two-level walk's per-geometry traversal).
    #[allow(clippy::type_complexity)] // the packet contract's arguments
    pub fn as_fn(
        &self,
    ) -> impl Fn(&A, &TraceParams, &[Ray4], &[M4], &mut [Hit4], &mut Slot<'_>, &mut Counters) + Copy + '_
    {
        move |a, p, r, m, h, s, c| self.run(a, p, r, m, h, s, c)
    }
}

/// `Accel::fastest` as a function pointer (`Tracing::single`).
fn fastest<A: Accel, T: TriangleTest, const ANY: bool>(a: &A, r: &Ray, c: &mut Counters) -> Hit {
    a.fastest::<T, ANY>(r, c)
}

#[inline(always)]
fn single<A: Accel, T: crate::geom::TriangleTest>(a: &A, ray: &Ray, ctr: &mut Counters) -> Hit {
    a.intersect::<T>(ray, ctr)
}

#[inline(always)]
fn occluded<A: Accel, T: crate::geom::TriangleTest>(a: &A, ray: &Ray, ctr: &mut Counters) -> bool {
    a.occluded::<T>(ray, ctr)
}

/// Scene scale of the stored triangles' (unpadded) bounds, the same for
/// every structure built from one scene, so shading offsets (and images) do
/// not depend on the structure.
pub fn scale_of(b: &crate::geom::Aabb) -> f32 {
    if b.is_empty() {
        1.0
    } else {
        b.diagonal().length()
    }
}

/// A built grid ready to trace (the family contract's `GridView`).
pub type GridTracer<'r> = GridView<'r>;
/// A built BVH ready to trace.
pub type BvhTracer<'r> = BvhView<'r>;
/// A built kd-tree ready to trace.
pub type KdTracer<'r> = KdView<'r>;

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
    /// The perspective grids' filter hook (`geom::filter`; the others'
    /// are their views').
    pub pgrid_filter: Hook<'r>,
}

impl<'r> SceneTracer<'r> {
    /// The same structures with single-ray calls going to `method`'s
    /// structure; `NotBuilt` when that structure has not been built.
    pub fn with_single(&self, method: Method) -> Result<SceneTracer<'r>> {
        self.check(method)?;
        Ok(SceneTracer {
            single: method.single(),
            ..*self
        })
    }
    /// `NotBuilt` when `method`'s structure has not been built.
    pub fn check(&self, method: Method) -> Result<()> {
        let built = match method.structure() {
            Structure::Grid => self.grid.is_some(),
            Structure::Bvh => self.bvh.is_some(),
            Structure::Kd => self.kd.is_some(),
        };
        if built { Ok(()) } else { Err(Error::NotBuilt) }
    }
    /// The grid part (None when no grid is built).
    pub fn grid(&self) -> Option<GridTracer<'r>> {
        self.grid
    }
    /// The BVH part (None when no BVH is built).
    pub fn bvh(&self) -> Option<BvhTracer<'r>> {
        self.bvh
    }
    /// The kd-tree part (None when no kd-tree is built).
    pub fn kd(&self) -> Option<KdTracer<'r>> {
        self.kd
    }
}

/// `$e` on the structure of `$method` bound to `$t` (any `Accel`), or
/// `$none` when that structure is not built.
macro_rules! on_family {
    ($s:expr, $method:expr, |$t:ident| $e:expr, $none:expr) => {
        match $method.structure() {
            Structure::Grid => match &$s.grid {
                Some($t) => $e,
                None => $none,
            },
            Structure::Bvh => match &$s.bvh {
                Some($t) => $e,
                None => $none,
            },
            Structure::Kd => match &$s.kd {
                Some($t) => $e,
                None => $none,
            },
        }
    };
}

impl Tracer for SceneTracer<'_> {
    #[inline]
    fn intersect(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
        on_family!(
            self,
            self.single,
            |t| Tracer::intersect(t, ray, ctr),
            Hit::MISS
        )
    }
    #[inline]
    fn occluded(&self, ray: &Ray, ctr: &mut Counters) -> bool {
        on_family!(self, self.single, |t| Tracer::occluded(t, ray, ctr), false)
    }
    fn packets(&self, p: &TraceParams, any: bool) -> Packets<'_> {
        on_family!(self, p.method, |t| t.packets(p, any), Packets::Unbuilt)
    }
    /// The triangle from the structure of `single` (the primary method's):
    /// a structure left over from an older frame is never consulted.
    /// NOTE(perf): the BVH finds a triangle by id in O(1) (`slot_of`), the
    /// grid by binary search (23 % of a Whitted frame on conference, perf).
    fn triangle(&self, prim: u32) -> Option<TriVerts> {
        on_family!(self, self.single, |t| Accel::triangle(t, prim), None)
    }
    fn scene_scale(&self) -> f32 {
        on_family!(self, self.single, |t| scale_of(&t.bounds()), 1.0)
    }
}

/// Rays per packet of a trace call: `p.packet`^2 for packet methods, a
/// 2x2 batch for single-ray methods.
pub fn packet_rays(p: &TraceParams) -> usize {
    if p.method.is_packet() {
        (p.packet * p.packet) as usize
    } else {
        4
    }
}

/// How the batch loop (`packets`) forms packets: `count` rays, `per` to a
/// packet (at most `MAX_QUADS` quads: the call's limits were checked), each
/// packet's results `k` per quad, starting as `miss`.
#[derive(Clone, Copy)]
pub struct Batch<H> {
    pub count: usize,
    pub per: usize,
    pub miss: H,
    pub k: usize,
}

/// The one batch loop of every trace call, single mesh and two-level: the
/// `count` rays `rays.ray(i)` packed `per` at a time into 2x2 quads in the
/// slot's scratch, each packet's `H` results traced by `trace(quads,
/// active, results, rest of the slot)` and handed to `out(first ray,
/// results, rays)`. Each packet is formed here once (`Tracing::run` finds
/// it within `MAX_QUADS`). Generic over the rays and both closures, so
/// each caller's conversions inline into the packing loop (no indirect
/// call per ray).
#[inline]
pub fn packets<H: Copy>(
    slot: &mut Slot<'_>,
    b: Batch<H>,
    rays: impl super::RaySource,
    mut trace: impl FnMut(&[Ray4], &[M4], &mut [H], &mut Slot<'_>),
    mut out: impl FnMut(usize, &[H], usize),
) {
    let Batch {
        count,
        per,
        miss,
        k,
    } = b;
    let nq_max = per.div_ceil(4).min(MAX_QUADS);
    let blank = Ray4::from_rays(&[Ray::new(glam::Vec3::ZERO, glam::Vec3::X, 0.0, 0.0); 4]);
    let (quads, s) = slot.reborrow().take(nq_max, blank);
    let (active, s) = s.take(nq_max, M4::FALSE);
    let (res, mut s) = s.take(k * nq_max, miss);
    let mut start = 0;
    while start < count {
        let n = (count - start).min(per);
        let nq = rays.pack(start, n, quads, active);
        res[..k * nq].fill(miss);
        trace(&quads[..nq], &active[..nq], &mut res[..k * nq], &mut s);
        out(start, &res[..k * nq], n);
        start += n;
    }
}

/// Trace `count` rays, ray `i` being `rays.ray(i)`, as packets of
/// `p.packet`^2 rays (or 2x2 batches for single-ray methods) with mailbox
/// `slot` (`packets`), handing the results out quad by quad: `out(i,
/// hits, n)` for rays `i .. i + n` (`n <= 4`, lanes `0 .. n` of `hits`;
/// `per_ray` turns a per-ray closure into one). Shared by the Rust calls
/// and the C ABI's, so both form the same packets. `rays` is an array of
/// structs read by index, a ray stream whose quads are loads
/// (`stream.rs`), or camera rays made in the kernel
/// (`render::CameraRays`); a quad's hits go out as whole lanes (no
/// per-ray lane pick).
pub fn batch_on(
    tr: &SceneTracer<'_>,
    slot: &mut Slot<'_>,
    p: &TraceParams,
    count: usize,
    rays: impl super::RaySource,
    mut out: impl FnMut(usize, &Hit4, usize),
    any: bool,
) -> Counters {
    let mut ctr = Counters::default();
    let c = &mut ctr;
    let quads = |start: usize, hits: &[Hit4], n: usize| {
        for (q, h) in hits.iter().enumerate() {
            out(start + 4 * q, h, (n - 4 * q).min(4));
        }
    };
    let batch = Batch {
        count,
        per: packet_rays(p),
        miss: Hit4::MISS,
        k: 1,
    };
    // The family, its kernel (method, triangle test, lane width) and
    // occlusion chosen once; each packet is one call of the kernel.
    on_family!(
        tr,
        p.method,
        |a| {
            let a = &a.opaque_if(p.opaque);
            let k = a.tracing(p, any);
            let trace =
                |q: &[Ray4], m: &[M4], h: &mut [Hit4], s: &mut Slot<'_>| k.run(a, p, q, m, h, s, c);
            packets(slot, batch, rays, trace, quads)
        },
        // Not built (`Context::trace_quads` refuses the call before):
        // every ray misses.
        packets(slot, batch, rays, |_, _, _, _| {}, quads)
    );
    ctr
}

/// A quad consumer for `batch_on` made of a per-ray one: `out(i, hits,
/// lane)` for each ray `i` of the quad, lanes unrolled (each lane picked
/// by a constant index).
#[inline(always)]
pub fn per_ray(mut out: impl FnMut(usize, &Hit4, usize)) -> impl FnMut(usize, &Hit4, usize) {
    move |i, h, n| {
        for l in 0..4 {
            if l < n {
                out(i + l, h, l)
            }
        }
    }
}
