//! What every family's packet query shares, written once. A trace call
//! chooses its family's `Kernel` once (method, triangle test, culling,
//! occlusion and lane width: the kernel table of `trace::scene`) and calls
//! it per packet; single-ray methods run the family's single ray lane by
//! lane (`LaneByLane`).
//!
//! - `MAX_QUADS`: the largest packet, 32 x 32 rays in 256 quads of 2x2.
//! - `PacketSig`, `Kernel`: the packet contract and a chosen traversal.
//! - `lane_by_lane`: the single ray for each active lane (single-ray
//!   methods, and methods a family lacks).
//! - `quieted`: lanes with tiny directions (`fallback::tiny`) of every
//!   n x n packet method go alone, the rest of the packet without them.
//! - `all_miss`: a packet an entry-point search proved to miss.
//! - `start`: where a tree packet starts (`accel::entry`).
//!
//! # Exactness
//! Everything here either calls the family's exact traversals or writes
//! misses that an entry search proved (see `accel::entry`).
#![forbid(unsafe_code)]

use super::Accel;
use super::entry::{self, EntryPoint, EntrySearch, EntryTree};
use super::fallback;
use super::method::TraceParams;
use super::slot::Slot;
use crate::counters::Counters;
use crate::geom::frustum::Frustum;
use crate::geom::{Aabb, Hit, Hit4, M4, Ray, Ray4, TriangleTest, Wide};
use crate::isa;
use crate::mem::scratch::bytes;
use core::marker::PhantomData;

/// Quads in the largest packet: 32 x 32 rays.
pub const MAX_QUADS: usize = 256;

/// Quads of a packet of `side` x `side` rays (one for a 2x2 batch): the
/// `q` every slot-scratch function below takes, from
/// `Limits::max_packet_side`.
pub const fn quads(side: u32) -> usize {
    let h = (side / 2) as usize;
    if h == 0 { 1 } else { h * h }
}

/// The packets an input of `n` quads is traced as: consecutive ranges of
/// at most `MAX_QUADS` quads.
#[inline]
pub fn packet_ranges(n: usize) -> impl Iterator<Item = core::ops::Range<usize>> {
    (0..n)
        .step_by(MAX_QUADS)
        .map(move |s| s..(s + MAX_QUADS).min(n))
}

/// Slot scratch a call holds while a family traces packets of up to `q`
/// quads: the tiny-lane split of `quieted` (quieted quads, the
/// packet's lanes, the tiny lanes).
pub const fn scratch(q: usize) -> usize {
    bytes::<Ray4>(q) + bytes::<M4>(q) + bytes::<M4>(q)
}

/// Slot scratch `start` takes (the live lanes, the entry search's
/// candidate queue), given back before the family's traversal: a family's
/// `scratch` covers the larger of the two.
pub const fn start_scratch(q: usize) -> usize {
    bytes::<M4>(q) + bytes::<entry::CandidateQueue>(1)
}

/// The packet contract's signature (`isa::Sig`): the family's view, the
/// call's parameters, the packet's quads, their active lanes and hits
/// (inactive lanes are left untouched), the thread slot and the counters.
/// Every family's packet traversals are `isa::LaneFn`s of it.
pub struct PacketSig<A>(PhantomData<A>);

impl<A: Accel> isa::Sig for PacketSig<A> {
    type Args<'a>
        = (
        &'a A,
        &'a TraceParams,
        &'a [Ray4],
        &'a [M4],
        &'a mut [Hit4],
        Slot<'a>,
        &'a mut Counters,
    )
    where
        Self: 'a;
    type Out = ();
}

/// The packet contract's arguments (`PacketSig`), one tuple.
pub type PacketArgs<'a, A> = <PacketSig<A> as isa::Sig>::Args<'a>;

/// A family's packet traversal for a trace call (`trace::scene`'s kernel
/// table): the method, triangle test, culling, occlusion and lane width
/// chosen once, called per packet with `PacketArgs` on one packet of at
/// most `MAX_QUADS` quads (`Tracing::run` splits longer inputs).
pub type Kernel<A> = isa::Chosen<PacketSig<A>>;

/// The tiny-direction fallback of every n x n packet method (`Tracing`
/// in `trace::scene` calls it when some active lane of its packet, at most
/// `MAX_QUADS` quads, has a tiny direction, `any_tiny`): the packet is
/// traced by `packet` on quads whose tiny lanes are replaced and inactive
/// (`fallback::quieted`: no SIMD operation meets their subnormal
/// numbers), then each tiny lane by `single`, the family's single ray,
/// which counts its own rays. The split lives in the slot's scratch
/// (`scratch`), the family gets the rest.
#[inline(never)]
pub fn quieted(
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
    packet: impl FnOnce(&[Ray4], &[M4], &mut [Hit4], Slot<'_>, &mut Counters),
    single: impl Fn(&Ray, &mut Counters) -> Hit,
) {
    let n = rays.len().min(active.len()).min(hits.len()).min(MAX_QUADS);
    if n == 0 {
        return;
    }
    let (r, h) = (&rays[..n], &mut hits[..n]);
    let (qr, mut slot) = slot.split(n, r[0]);
    let (qa, mut slot) = slot.split(n, M4::FALSE);
    let (tiny, mut slot) = slot.split(n, M4::FALSE);
    fallback::split_tiny(r, &active[..n], qr, qa, tiny);
    packet(qr, qa, h, slot.reborrow(), ctr);
    fallback::each_lane(tiny, |q, i| {
        h[q].set_lane(i, single(&r[q].lane(i), ctr));
    });
}

/// The family's single ray for each active lane: the kernel of a
/// single-ray method, and of a method the family lacks
/// (`trace::scene`'s kernel table).
pub struct LaneByLane<T, const ANY: bool>(PhantomData<T>);

impl<A: Accel, T: TriangleTest, const ANY: bool> isa::LaneFn<PacketSig<A>> for LaneByLane<T, ANY> {
    #[inline(always)]
    fn call<W: Wide>(args: PacketArgs<'_, A>) {
        let (a, _, rays, active, hits, _, ctr) = args;
        lane_by_lane(rays, active, hits, |r, c| single::<A, T, ANY>(a, r, c), ctr)
    }
}

/// Whether some active lane has a tiny direction (`fallback::tiny`).
#[inline]
pub fn any_tiny(rays: &[Ray4], active: &[M4]) -> bool {
    rays.iter()
        .zip(active)
        .any(|(r, m)| fallback::tiny(true, r, *m).any())
}

/// The coherence and budget fallbacks of every family's packets: each
/// live lane traced by the family's fastest single ray (`Accel::fastest`; its result replaces the
/// lane's hit; from the root, the same hit as from any entry point). The
/// packet counted these rays already, the single ray counts them again, so
/// they are taken off once here.
#[inline(never)]
pub fn alone<A: Accel, T: TriangleTest, const ANY: bool>(
    a: &A,
    rays: &[Ray4],
    live: &[M4],
    hits: &mut [Hit4],
    ctr: &mut Counters,
) {
    let n = fallback::each_lane(live, |q, i| {
        hits[q].set_lane(i, a.fastest::<T, ANY>(&rays[q].lane(i), ctr));
    });
    ctr.rays -= n;
}

/// The family's single ray: nearest hit, or with `ANY` some hit.
#[inline(always)]
fn single<A: Accel, T: TriangleTest, const ANY: bool>(a: &A, r: &Ray, c: &mut Counters) -> Hit {
    if ANY {
        a.any_hit::<T>(r, c)
    } else {
        a.intersect::<T>(r, c)
    }
}

/// A packet traced one active lane at a time by a single-ray method.
pub fn lane_by_lane(
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

/// Occlusion masks as hits: active lanes get `Hit::OCCLUDED` (kd packets
/// know no occluder id) or `Hit::MISS`; inactive lanes are untouched.
pub fn mark_occluded(occ: &[M4], active: &[M4], hits: &mut [Hit4]) {
    for ((o, m), h) in occ.iter().zip(active).zip(hits.iter_mut()) {
        for i in (0..4).filter(|&i| m.test(i)) {
            h.set_lane(i, if o.test(i) { Hit::OCCLUDED } else { Hit::MISS });
        }
    }
}

/// Count the active lanes of a packet answered without traversal (an
/// entry search found that every ray misses).
fn count_rays(active: &[M4], ctr: &mut Counters) {
    ctr.rays += active
        .iter()
        .map(|m| m.bitmask().count_ones() as u64)
        .sum::<u64>();
}

/// A packet every active ray of which misses (entry search found no leaf).
pub fn all_miss(active: &[M4], hits: &mut [Hit4], ctr: &mut Counters) {
    count_rays(active, ctr);
    for (m, h) in active.iter().zip(hits.iter_mut()) {
        for i in (0..4).filter(|&i| m.test(i)) {
            h.set_lane(i, Hit::MISS);
        }
    }
}

/// Where a tree packet starts (`start`).
pub enum Start {
    Root,
    At(EntryPoint),
    /// The frustum overlaps no triangle: every ray misses.
    Miss,
}

/// The packet's frustum (of `p.bvh.kind`; `None` without live lanes or when
/// none can be built) and, with `p.entry`, the entry point MLRTA or AEPSA
/// finds for it in `tree` (counted in `ctr`). The live lanes borrow the
/// slot's scratch (`start_scratch`) for the call.
pub fn start<E: EntryTree + ?Sized>(
    tree: &E,
    p: &TraceParams,
    rays: &[Ray4],
    active: &[M4],
    bounds: &Aabb,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) -> (Option<Frustum>, Start) {
    let nq = rays.len().min(active.len()).min(MAX_QUADS);
    let (live, mut rest) = slot.split(nq, M4::FALSE);
    for (l, (r, m)) in live.iter_mut().zip(rays.iter().zip(active)) {
        *l = entry::live_mask(r, *m);
    }
    let live = &*live;
    let f = Frustum::new(p.bvh.kind, &rays[..nq], live, bounds);
    let (Some(fr), false) = (f, p.entry == EntrySearch::None) else {
        return (f, Start::Root);
    };
    let neg = entry::dir_signs(&rays[..nq], live);
    // Phase 1's candidate queue in the scratch too (`start_scratch`).
    const EMPTY: entry::CandidateQueue = entry::CandidateQueue::new();
    let (q, _) = rest.scratch.reborrow().take_copies(1, &EMPTY);
    let e = match p.entry {
        EntrySearch::Mlrta => entry::mlrta::mlrta_in(tree, &fr, neg, &mut q[0], ctr),
        _ => entry::aepsa::aepsa_in(tree, &fr, neg, &mut q[0], ctr),
    };
    (f, e.map_or(Start::Miss, Start::At))
}
