//! What the large-packet traversals share (BVH paper section 3): the
//! prepared packet (`Packet`: live lanes, per-quad slab data `QuadBox`,
//! triangle-test precomputation, per-lane far ends, the frustum of
//! section 4), the `Walk` each traversal implements (the paper's Masked,
//! Ranged and Partition; WideRanged and FrustumFirst on the 4-wide tree),
//! the split of long inputs into packets of `MAX_QUADS` quads and the
//! lane-by-lane coherence fallback (`alone`). The 2x2 SIMD ray (`traverse_simd`) uses the same `QuadBox`.
//!
//! # Setup
//! One pass over a packet's quads (`Lanes::new`) writes the misses, finds
//! the live lanes, tiny directions, the direction sum and the coherence
//! test's cone and origin box (`fallback::Coherence`); then a second pass
//! writes each quad's triangle-test precomputation, far ends and slab data
//! (the first two into slices filled first). The frustum-first walk sets
//! its packets up itself, lane group by lane group at its lane width
//! (`traverse_frustum`), and hands the packets it does not take to
//! `walk_from`. Setup and walk run in the
//! walk's `isa::LaneFn` (`Walked`), so the setup is compiled for the walk's ISA
//! (32 vector registers with AVX-512) and runs on the quads while they
//! are in cache.
//!
//! # Scratch
//! A packet's per-quad arrays (up to 256 quads: tens of KiB) are slices of
//! the calling thread slot's scratch (`accel::slot`), `nq` long, not
//! arrays on the stack; what a `Walk` needs per quad (Masked's masks,
//! Partition's index list) comes from the rest. `SCRATCH` is the most
//! this takes for one packet.
//!
//! # Exactness
//! `QuadBox::entry` is the single ray's slab test lane by lane (same
//! operations, same NaN handling), and the leaf test is the single ray's
//! triangle test with the tie rule `geom::closer`, so a box or triangle is
//! accepted for a lane exactly when the single ray accepts it.
#![forbid(unsafe_code)]

use super::frustum::Frustum;
use super::{BvhNode, BvhView, MAX_DEPTH, TriangleTest};
use crate::accel::entry::{EntryPoint, EntrySearch};
use crate::accel::fallback;
use crate::accel::group::{self, Group};
use crate::accel::method::TraceParams;
use crate::accel::packet::{self, PacketArgs, PacketSig, Start};
use crate::accel::slot::Slot;
use crate::counters::{Counters, count};
use crate::geom::lane::mask_from_bits;
use crate::geom::{Aabb, F4, Hit4, Hook, M4, Mt, Pt, Ray4, RayLanes, Wide, Wt};
use crate::isa;
use crate::mem::scratch::bytes;

/// Slot scratch one packet of up to `q` quads takes in the generic walks,
/// for the triangle test whose precomputation is largest: the per-quad
/// arrays of `Packet` (live lanes, `QuadBox`, precomputation, far ends),
/// the lane groups, Masked's masks and Partition's index list (both held
/// after a switch). `bvh::scratch` adds the frustum walk's.
pub(crate) const fn scratch(q: usize) -> usize {
    bytes::<M4>(q)
        + bytes::<QuadBox>(q)
        + max(
            max(bytes::<Pre<Mt>>(q), bytes::<Pre<Wt>>(q)),
            bytes::<Pre<Pt>>(q),
        )
        + bytes::<F4>(q)
        + group::max_bytes(q)
        + bytes::<bool>(q)
        + bytes::<u16>(q)
}

/// A triangle test's per-quad precomputation.
type Pre<T> = <T as TriangleTest>::Pre<F4>;

const fn max(a: usize, b: usize) -> usize {
    if a > b { a } else { b }
}

/// Per-quad data of the 4-wide slab test (the same arithmetic as
/// `traverse_single::RayBox`, lane by lane).
#[derive(Clone, Copy, Debug)]
pub(crate) struct QuadBox {
    org: [F4; 3],
    rcp: [F4; 3],
    /// Lanes whose direction has the sign bit set on each axis.
    neg: [M4; 3],
    tmin: F4,
}

impl QuadBox {
    #[inline(always)]
    pub(crate) fn new(r: &Ray4) -> QuadBox {
        let one = F4::ONE;
        QuadBox {
            org: r.org,
            rcp: [one / r.dir[0], one / r.dir[1], one / r.dir[2]],
            neg: [
                mask_from_bits(r.dir[0].is_negative_bitmask()),
                mask_from_bits(r.dir[1].is_negative_bitmask()),
                mask_from_bits(r.dir[2].is_negative_bitmask()),
            ],
            tmin: r.tmin,
        }
    }

    /// Lanes whose `[tmin, tmax]` overlaps `n`'s box, and their entry t.
    /// NaN slab terms (zero direction, origin on a plane) never replace the
    /// running interval, as in the single-ray test.
    #[inline(always)]
    pub(crate) fn entry(&self, n: &BvhNode, tmax: F4) -> (M4, F4) {
        let mut t0 = self.tmin;
        let mut t1 = tmax;
        for a in 0..3 {
            let lo = (F4::splat(n.min[a]) - self.org[a]) * self.rcp[a];
            let hi = (F4::splat(n.max[a]) - self.org[a]) * self.rcp[a];
            let near = F4::select(self.neg[a], hi, lo);
            let far = F4::select(self.neg[a], lo, hi);
            t0 = F4::select(near.cmpgt(t0), near, t0);
            t1 = F4::select(far.cmplt(t1), far, t1);
        }
        (t0.cmple(t1), t0)
    }
}

/// Whether a walk of the 4-wide tree can take this packet: it starts at
/// the root (entry points are binary nodes), the BVH has a wide tree, and
/// no live lane has a tiny direction (`tiny`: `Packet::tiny`, left in the
/// packet when the fallbacks are off; `traverse_wide`'s deviations).
/// Otherwise the binary Ranged walk answers.
#[inline(always)]
pub(crate) fn wide_walk_applies(tiny: bool, b: &BvhView<'_>, start: (usize, usize)) -> bool {
    start == (0, 0) && !b.wide.is_empty() && !tiny
}

/// A large-packet traversal: walks one prepared packet through the tree.
pub(crate) trait Walk {
    /// `start`: the node to start at and its depth (the root: `(0, 0)`);
    /// `slot`: the scratch left after the packet's (for per-quad state).
    fn walk<L: Wide, T: TriangleTest, const ANY: bool>(
        p: &mut Packet<'_, T>,
        b: &BvhView<'_>,
        rays: &[Ray4],
        hits: &mut [Hit4],
        start: (usize, usize),
        slot: &mut Slot<'_>,
        ctr: &mut Counters,
    );
}

/// One packet of at most `MAX_QUADS` quads (`trace::scene::Tracing::run`
/// splits longer inputs): its quads, their active lanes and their hits,
/// read up to the shortest length.
pub(crate) struct PacketIn<'x> {
    pub rays: &'x [Ray4],
    pub active: &'x [M4],
    pub hits: &'x mut [Hit4],
}

/// A large-packet walk `Wk` on the packet contract
/// (`accel::packet::PacketSig`) at a lane width: where the packet starts
/// (`start`), then `walk_from`. Its `Kernel` is chosen once per call
/// (`trace::scene`'s kernel table).
pub struct Walked<Wk, T, const ANY: bool>(core::marker::PhantomData<(Wk, T)>);

impl<'b, Wk: Walk, T: TriangleTest, const ANY: bool> isa::LaneFn<PacketSig<BvhView<'b>>>
    for Walked<Wk, T, ANY>
{
    #[inline(always)]
    fn call<L: Wide>(args: PacketArgs<'_, BvhView<'b>>) {
        let (b, p, rays, active, hits, mut slot, ctr) = args;
        let pk = PacketIn { rays, active, hits };
        let e = match start(b, p, &pk, &mut slot, ctr) {
            Start::Root => None,
            Start::At(e) => Some(e),
            Start::Miss => return packet::all_miss(active, pk.hits, ctr),
        };
        walk_from::<L, Wk, T, ANY>(b, p, pk, e.as_ref(), &mut slot, ctr)
    }
}

/// Where a packet starts: the root, or with `TraceParams::entry` the
/// MLRTA or AEPSA entry point of its frustum (`accel::packet::start`;
/// `Start::Miss` when the search proved every ray misses).
#[inline(always)]
pub(crate) fn start(
    b: &BvhView<'_>,
    p: &TraceParams,
    pk: &PacketIn<'_>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) -> Start {
    if p.entry == EntrySearch::None {
        return Start::Root;
    }
    let root = b.nodes.first().map_or(Aabb::EMPTY, |n| n.aabb());
    packet::start(b, p, pk.rays, pk.active, &root, slot, ctr).1
}

/// Nearest hits (or with `ANY` occlusion) of the active lanes of one
/// packet into its hits by the walk `Wk` on `L` lanes, the contract of
/// every large-packet traversal: active lanes are written (`Hit::MISS`
/// when nothing is hit, and for invalid rays; for occlusion `prim !=
/// INVALID_ID` marks an occluded lane, with some occluder's t and id);
/// inactive lanes are left untouched. `entry`: start at this node instead
/// of the root (an MLRTA or AEPSA entry point of a frustum bounding every
/// live ray, see `bvh::entry`; a node outside the tree starts at the
/// root). `slot`'s scratch holds the per-quad arrays (`scratch`). The
/// packet is set up and walked at the kernel's lane width, so the setup
/// pass is compiled for the walk's ISA too.
#[inline(always)]
pub(crate) fn walk_from<L: Wide, Wk: Walk, T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    opt: &TraceParams,
    pk: PacketIn<'_>,
    entry: Option<&EntryPoint>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let start = match entry {
        Some(e) if (e.node as usize) < b.nodes.len() => {
            (e.node as usize, (e.depth as usize).min(MAX_DEPTH))
        }
        _ => (0, 0),
    };
    let PacketIn { rays, active, hits } = pk;
    // Its lanes first (a packet with none live, or incoherent, takes no
    // more scratch), then its per-quad arrays, then the walk.
    let nq = rays.len().min(active.len()).min(hits.len());
    let (live, mut slot) = slot.split(nq, M4::FALSE);
    let Some(lanes) = Lanes::new(b, rays, active, hits, live, opt.fallbacks, ctr) else {
        return;
    };
    if !lanes.coherent {
        return packet::alone::<BvhView, T, ANY>(b, rays, live, hits, ctr);
    }
    // Per quad, in one pass over the rays: triangle-test
    // precomputation, far ends and slab data, each written once.
    let (pre, mut slot) = slot.split(nq, T::prepare(&RayLanes::from_ray4(&rays[0])));
    let (tfar, mut slot) = slot.split(nq, F4::ZERO);
    let (qb, mut slot) = slot.split_from(nq, |q| {
        let r = &rays[q];
        (pre[q], tfar[q]) = (T::prepare(&RayLanes::from_ray4(r)), r.tmax);
        QuadBox::new(r)
    });
    let quads = Quads {
        live,
        qb,
        pre,
        tfar,
    };
    let mut p = Packet::<T>::new(b, rays, opt, lanes, quads, ctr);
    Wk::walk::<L, T, ANY>(&mut p, b, rays, hits, start, &mut slot, ctr)
}

/// A large-packet traversal the unit tests drive from a given entry point
/// (`dispatch_at`): each `Walk` by `walk_from`; the frustum-first walk
/// by its own start (`traverse_frustum::FrustumFirst::from`).
#[cfg(test)]
pub(crate) trait TestWalk {
    fn packet<L: Wide, T: TriangleTest, const ANY: bool>(
        b: &BvhView<'_>,
        opt: &TraceParams,
        pk: PacketIn<'_>,
        entry: Option<&EntryPoint>,
        slot: &mut Slot<'_>,
        ctr: &mut Counters,
    );
}

#[cfg(test)]
impl<Wk: Walk> TestWalk for Wk {
    #[inline(always)]
    fn packet<L: Wide, T: TriangleTest, const ANY: bool>(
        b: &BvhView<'_>,
        opt: &TraceParams,
        pk: PacketIn<'_>,
        entry: Option<&EntryPoint>,
        slot: &mut Slot<'_>,
        ctr: &mut Counters,
    ) {
        walk_from::<L, Wk, T, ANY>(b, opt, pk, entry, slot, ctr)
    }
}

/// `TestWalk::packet` at the lane width of `opt.isa` on an input of any
/// length (consecutive packets of `MAX_QUADS` quads, as `Tracing::run`
/// splits them), for the unit tests that drive one walk from a given entry
/// point (a trace call runs the kernel table's choice).
#[cfg(test)]
pub(crate) fn dispatch_at<Wk: TestWalk, T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    pk: PacketIn<'_>,
    opt: &TraceParams,
    entry: Option<&EntryPoint>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    struct Sig;
    impl isa::Sig for Sig {
        type Args<'a> = (
            &'a BvhView<'a>,
            PacketIn<'a>,
            &'a TraceParams,
            Option<&'a EntryPoint>,
            Slot<'a>,
            &'a mut Counters,
        );
        type Out = ();
    }
    struct At<Wk, T, const ANY: bool>(core::marker::PhantomData<(Wk, T)>);
    impl<Wk: TestWalk, T: TriangleTest, const ANY: bool> isa::LaneFn<Sig> for At<Wk, T, ANY> {
        #[inline(always)]
        fn call<L: Wide>(args: <Sig as isa::Sig>::Args<'_>) {
            let (b, pk, opt, entry, mut slot, ctr) = args;
            let PacketIn { rays, active, hits } = pk;
            let n = rays.len().min(active.len()).min(hits.len());
            for r in packet::packet_ranges(n) {
                let pk = PacketIn {
                    rays: &rays[r.clone()],
                    active: &active[r.clone()],
                    hits: &mut hits[r],
                };
                Wk::packet::<L, T, ANY>(b, opt, pk, entry, &mut slot, ctr)
            }
        }
    }
    let args = (b, pk, opt, entry, slot.reborrow(), ctr);
    isa::run_fn::<Sig, At<Wk, T, ANY>>(opt.isa, args)
}

/// The live lanes' extremes quad by quad, of which the two-level packet
/// walk makes its interval frustum (`Frustum::from_bounds`; the
/// frustum-first walk gathers them at its lane width): per axis the lane-wise smallest and largest
/// origin and direction, and which lanes' directions have the sign bit set
/// and clear; the smallest `tmin` and largest `tmax`. Lanes that are not
/// live leave every bound as it was.
#[derive(Clone, Copy)]
pub(crate) struct LaneBounds {
    pub omin: [F4; 3],
    pub omax: [F4; 3],
    pub dmin: [F4; 3],
    pub dmax: [F4; 3],
    /// Per axis: bit `i` of some quad's live lane `i` whose direction has
    /// the sign bit set (`neg`) or clear (`pos`).
    pub neg: [u32; 3],
    pub pos: [u32; 3],
    pub tmin: F4,
    pub tmax: F4,
}

impl LaneBounds {
    pub(crate) const EMPTY: LaneBounds = LaneBounds {
        omin: [F4::INFINITY; 3],
        omax: [F4::NEG_INFINITY; 3],
        dmin: [F4::INFINITY; 3],
        dmax: [F4::NEG_INFINITY; 3],
        neg: [0; 3],
        pos: [0; 3],
        tmin: F4::INFINITY,
        tmax: F4::NEG_INFINITY,
    };

    /// Widen by the lanes `l` of quad `r` (a branch for quads with every
    /// lane live measured no faster: sponza, AVX-512).
    #[inline(always)]
    pub(crate) fn add(&mut self, r: &Ray4, l: M4) {
        let (inf, ninf) = (F4::INFINITY, F4::NEG_INFINITY);
        let lb = l.bitmask();
        for a in 0..3 {
            let (o, d) = (r.org[a], r.dir[a]);
            self.omin[a] = self.omin[a].min(F4::select(l, o, inf));
            self.omax[a] = self.omax[a].max(F4::select(l, o, ninf));
            self.dmin[a] = self.dmin[a].min(F4::select(l, d, inf));
            self.dmax[a] = self.dmax[a].max(F4::select(l, d, ninf));
            let nb = d.is_negative_bitmask();
            self.neg[a] |= nb & lb;
            self.pos[a] |= !nb & lb;
        }
        self.tmin = self.tmin.min(F4::select(l, r.tmin, inf));
        self.tmax = self.tmax.max(F4::select(l, r.tmax, ninf));
    }
}

/// A packet's live lanes, before its other per-quad arrays exist.
struct Lanes {
    n_live: u32,
    neg: [bool; 3],
    /// Whether the live lanes pass `fallback::coherent` (else the packet
    /// is traced lane by lane, and gets no `Packet`).
    coherent: bool,
    /// Whether a live lane has a tiny direction (`fallback::tiny`, checked
    /// whether the fallbacks are on or not).
    tiny: bool,
}

impl Lanes {
    /// Write `Hit::MISS` to every active lane, count the packet and its
    /// rays, and write the live lanes of its `live.len()` quads to `live`;
    /// `None` when nothing is to be traced (no live lane). One pass over
    /// the quads, which also finds tiny directions, the direction sum and
    /// (with the fallbacks) whether the live lanes are coherent.
    #[inline(always)]
    fn new(
        b: &BvhView<'_>,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        live: &mut [M4],
        fallbacks: bool,
        ctr: &mut Counters,
    ) -> Option<Lanes> {
        let nq = live.len();
        ctr.packets += 1;
        let mut n_live = 0;
        let mut sum = [F4::ZERO; 3];
        let mut tiny = M4::FALSE;
        let mut coherence = fallback::Coherence::new();
        for q in 0..nq {
            let (r, m) = (&rays[q], active[q]);
            if !m.any() {
                continue;
            }
            let valid = r.valid();
            hits[q].miss(m);
            let l = m & valid;
            live[q] = l;
            if !l.any() {
                // Every accumulator below takes live lanes only: a quad of
                // inactive slots (a shadow batch's misses and unlit
                // points) costs its miss write alone.
                continue;
            }
            for (sa, da) in sum.iter_mut().zip(&r.dir) {
                *sa += F4::select(l, *da, F4::ZERO);
            }
            n_live += l.bitmask().count_ones();
            tiny |= fallback::tiny(true, r, l);
            if fallbacks {
                coherence.add(r, l);
            }
        }
        ctr.rays += n_live as u64;
        if n_live == 0 || b.nodes.is_empty() {
            return None;
        }
        let diag = b.info.bounds.diagonal().length();
        let coherent = !fallbacks || coherence.close(diag);
        // A zero sum on an axis: the first live lane decides.
        let q0 = live.iter().position(|m| m.any()).unwrap_or(0);
        let f = live[q0].bitmask().trailing_zeros() as usize;
        let sum = [
            sum[0].element_sum(),
            sum[1].element_sum(),
            sum[2].element_sum(),
        ];
        let neg = core::array::from_fn(|a| {
            if sum[a] != 0.0 {
                sum[a] < 0.0
            } else {
                rays[q0].dir[a][f].is_sign_negative()
            }
        });
        Some(Lanes {
            n_live,
            neg,
            coherent,
            tiny: tiny.any(),
        })
    }
}

/// A packet's per-quad arrays, `nq` long each, in the slot's scratch.
struct Quads<'s, T: TriangleTest> {
    live: &'s mut [M4],
    qb: &'s mut [QuadBox],
    pre: &'s mut [T::Pre<F4>],
    tfar: &'s mut [F4],
}

/// One packet of `nq <= MAX_QUADS` quads during traversal (its per-quad arrays
/// borrowed from the slot's scratch for `'s`).
pub(crate) struct Packet<'s, T: TriangleTest> {
    pub nq: usize,
    /// Slab-test data per quad (reciprocals, direction signs).
    qb: &'s [QuadBox],
    /// Triangle-test precomputation per quad.
    pre: &'s [T::Pre<F4>],
    /// Lanes still traced: active, valid and (occlusion) not yet occluded.
    pub live: &'s mut [M4],
    /// Per quad and lane: `min(tmax, best.t)`, the end of the interval a
    /// box must overlap.
    tfar: &'s mut [F4],
    /// Live lanes in the packet.
    n_live: u32,
    /// Near child first when the packet's direction sum is negative on the
    /// split axis.
    neg: [bool; 3],
    pub frustum: Option<Frustum>,
    /// `TraceParams::fallbacks` (Masked's switch to Partition).
    pub fallbacks: bool,
    /// A live lane has a tiny direction (`wide_walk_applies`).
    pub tiny: bool,
}

impl<'s, T: TriangleTest> Packet<'s, T> {
    /// The packet of coherent `lanes` (`Lanes::new`) over its prepared
    /// `quads`, and with `opt.bvh.culling` its frustum.
    fn new(
        b: &BvhView<'_>,
        rays: &[Ray4],
        opt: &TraceParams,
        lanes: Lanes,
        quads: Quads<'s, T>,
        ctr: &mut Counters,
    ) -> Self {
        let Quads {
            live,
            qb,
            pre,
            tfar,
        } = quads;
        let nq = live.len();
        let frustum = if opt.bvh.culling {
            let f = Frustum::new(opt.bvh.kind, &rays[..nq], live, &b.nodes[0].aabb());
            if f.is_none() {
                ctr.packets_no_cull += 1;
            }
            f
        } else {
            None
        };
        Packet {
            nq,
            qb,
            pre,
            live,
            tfar,
            n_live: lanes.n_live,
            neg: lanes.neg,
            frustum,
            fallbacks: opt.fallbacks,
            tiny: lanes.tiny,
        }
    }

    /// Near and far child of inner node `n`, by the packet's direction.
    #[inline(always)]
    pub(crate) fn children(&self, n: &BvhNode) -> (usize, usize) {
        let l = n.first as usize;
        if self.neg[n.axis()] {
            (l + 1, l)
        } else {
            (l, l + 1)
        }
    }

    /// A key ordering boxes front to back along the packet's direction
    /// (the sum of the box's min and max, signed by the direction sum's
    /// sign on each axis): the visiting order of a wide node's children.
    #[inline(always)]
    pub(crate) fn near_key(&self, n: &BvhNode) -> f32 {
        let mut k = 0.0;
        for a in 0..3 {
            let c = n.min[a] + n.max[a];
            k += if self.neg[a] { -c } else { c };
        }
        k
    }

    /// `rayIntersectsAABB(R[q], B)`: the lanes of quad `q` alive in `n`'s
    /// box (no test, and none, for a quad without live lanes).
    #[inline(always)]
    pub(crate) fn alive(&self, q: usize, n: &BvhNode, depth: usize, ctr: &mut Counters) -> M4 {
        let lm = self.live[q];
        if !lm.any() {
            return M4::FALSE;
        }
        ctr.aabb_at(depth, 1);
        self.qb[q].entry(n, self.tfar[q]).0 & lm
    }

    /// `frustumIntersectsAABB(F, B)` (true without a frustum).
    #[inline(always)]
    pub(crate) fn frustum_admits(&self, n: &BvhNode, ctr: &mut Counters) -> bool {
        let _ = &ctr;
        let culled = self
            .frustum
            .as_ref()
            .is_some_and(|f| f.cull_box(&n.min, &n.max));
        if culled {
            count!(ctr.culled_nodes += 1);
        }
        !culled
    }

    /// `!frustumIntersectsTriangle(F, T[j])` for stored triangle `i`.
    #[inline(always)]
    pub(crate) fn frustum_culls(&self, b: &BvhView<'_>, i: usize, ctr: &mut Counters) -> bool {
        let _ = &ctr;
        let culled = self
            .frustum
            .as_ref()
            .is_some_and(|f| f.cull_triangle(&b.tris[i]));
        if culled {
            count!(ctr.culled += 1);
        }
        culled
    }

    /// `rayIntersectTriangle(R[q], T[i])` for the quads `qs[..n]` (`n <=
    /// L::G`) at once, joined into one `L`-wide lane group (`geom::wide`):
    /// the live lanes of each against stored triangle `i` (caller id `id`),
    /// each lane keeping its nearest hit (tie rule of `geom::ray`); for
    /// occlusion, lanes that hit are done. Lanes of quads `qs[n..]` are off.
    #[inline(always)]
    // Inner-loop leaf test (per quad group and triangle): a struct would be rebuilt per call.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn test<L: Wide, const ANY: bool>(
        &mut self,
        b: &BvhView<'_>,
        rays: &[Ray4],
        hits: &mut [Hit4],
        qs: [usize; 4],
        n: usize,
        i: usize,
        id: u32,
        depth: usize,
        ctr: &mut Counters,
    ) {
        // Lanes past `n` repeat quad `qs[n - 1]` (finite data, masked off).
        let q = |k: usize| qs[k.min(n - 1)];
        let live = &*self.live;
        let bits = group::lane_bits::<L>(0, (1 << n) - 1, |k| live[q(k)]);
        if bits == 0 {
            return;
        }
        ctr.tri_at(depth, bits.count_ones() as u64);
        let grp = Group::<L, T> {
            r: RayLanes::<L>::join(|k| &rays[q(k)]),
            pre: T::join_pre::<L>(|k| self.pre[q(k)]),
        };
        let (h, hb) = group::test(&grp, T::prim(b.store(), i), bits, b.cull);
        group::each_hit(&h, hb, |k, m, hit| {
            let ray = || (rays[q(k)].org, rays[q(k)].dir);
            self.take::<ANY>(hits, q(k), m, hit, id, &b.filter, ray);
        });
    }

    /// `test` for the quads `g L::G + k` of aligned group `g` (`group`)
    /// whose bit `k` is set in `sel`: the group's lanes were joined once
    /// per packet, not per test.
    #[inline(always)]
    // Inner-loop leaf test (per quad group and triangle).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn test_group<L: Wide, const ANY: bool>(
        &mut self,
        b: &BvhView<'_>,
        hits: &mut [Hit4],
        grp: &Group<L, T>,
        g: usize,
        sel: u32,
        i: usize,
        id: u32,
        depth: usize,
        ctr: &mut Counters,
    ) {
        let live = &*self.live;
        let bits = group::lane_bits::<L>(g, sel, |q| live[q]);
        if bits == 0 {
            return;
        }
        ctr.tri_at(depth, bits.count_ones() as u64);
        let (h, hb) = group::test(grp, T::prim(b.store(), i), bits, b.cull);
        let g0 = g * L::G;
        group::each_hit(&h, hb, |k, m, hit| {
            let ray = || group::quad_ray(&grp.r, k);
            self.take::<ANY>(hits, g0 + k, m, hit, id, &b.filter, ray);
        });
    }

    /// The packet's quads in aligned groups of `L::G` (`group::join`),
    /// carved from `slot`.
    #[inline(always)]
    pub(crate) fn groups<'a, L: Wide>(
        &self,
        rays: &[Ray4],
        slot: &'a mut Slot<'_>,
    ) -> (&'a mut [Group<L, T>], Slot<'a>) {
        group::join::<L, T>(&rays[..self.nq], slot)
    }

    /// Lanes `hm` of quad `q` hit triangle `id` at `(t, u, v)`: those
    /// nearer than their best so far (any, for occlusion) take it.
    /// The lanes taken.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // the hit, its lanes, and the filter with its rays
    pub(crate) fn take<const ANY: bool>(
        &mut self,
        hits: &mut [Hit4],
        q: usize,
        hm: M4,
        hit: (F4, F4, F4),
        id: u32,
        filter: &Hook<'_>,
        ray: impl Fn() -> ([F4; 3], [F4; 3]),
    ) -> M4 {
        let take = group::take::<ANY>(&mut hits[q], hm, hit, id, filter, ray);
        if !take.any() {
            return take;
        }
        // A taken hit lies in [tmin, tmax) and not beyond best.t.
        self.tfar[q] = F4::select(take, hit.0, self.tfar[q]);
        if ANY {
            self.live[q] &= !take;
            self.n_live -= take.bitmask().count_ones();
        }
        take
    }

    /// Whether every lane is done (occlusion).
    #[inline(always)]
    pub(crate) fn done(&self) -> bool {
        self.n_live == 0
    }
}
