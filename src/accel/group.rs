//! Leaf tests on wide lanes, shared by every family's packets:
//! a packet's 2x2 quads joined into aligned groups of `L::G` quads (one
//! `F4`, `F8` or `F16` lane group per `isa` level, `geom::wide`), each leaf
//! triangle tested against a group's live lanes in one call, the hits
//! written back quad by quad with the nearest-hit tie rule.
//!
//! A traversal keeps its per-quad state (live lanes, intervals, hits) as
//! 4-wide quads; only the triangle test, where the cycles of a leaf go,
//! runs wide. Groups are joined once per packet (`join`), not per test:
//! joining per test was measured slower than the 4-wide test it feeds
//! (docs/studies/lane-widths.md, "The packet setup and the first wide lanes").
//!
//! # Exactness
//! The wide triangle tests are the 4-wide tests lane for lane (element-wise
//! operations, `geom::wide`'s unit tests check them bitwise), the
//! precomputation of a group is the quads' (`TriangleTest::prepare` is
//! element-wise), and lanes of quads outside the selection, or past the
//! packet's last quad (the group repeats that quad: finite data), are
//! masked off before any hit is taken.
#![forbid(unsafe_code)]

use super::slot::Slot;
use crate::geom::lane::mask_from_bits;
use crate::geom::triangle::TriHit;
use crate::geom::{Cull, F4, Hit4, Hook, M4, Ray4, RayLanes, TriangleTest, Wide};

/// `L::G` consecutive quads joined into `L`-wide lanes, with their
/// triangle-test precomputation.
#[derive(Clone, Copy)]
pub(crate) struct Group<L: Wide, T: TriangleTest> {
    pub r: RayLanes<L>,
    pub pre: T::Pre<L>,
}

/// Scratch bytes of the groups of `nq` quads at the widest level a test
/// may force (`Isa::Avx512`), or any narrower one.
pub(crate) const fn bytes<T: TriangleTest>(nq: usize) -> usize {
    use crate::geom::{F8, F16};
    use crate::mem::scratch::bytes as b;
    let (a, c, d) = (
        b::<Group<F4, T>>(nq),
        b::<Group<F8, T>>(nq.div_ceil(2)),
        b::<Group<F16, T>>(nq.div_ceil(4)),
    );
    let m = if a > c { a } else { c };
    if m > d { m } else { d }
}

/// `bytes` of the triangle test with the largest groups.
pub(crate) const fn max_bytes(nq: usize) -> usize {
    use crate::geom::{Mt, Pt, Wt};
    let (a, b, c) = (bytes::<Mt>(nq), bytes::<Wt>(nq), bytes::<Pt>(nq));
    let m = if a > b { a } else { b };
    if m > c { m } else { c }
}

/// The groups of `rays` (quads `g L::G ..`; past the last quad a group
/// repeats it), carved from `slot`.
#[inline(always)]
pub(crate) fn join<'a, L: Wide, T: TriangleTest>(
    rays: &[Ray4],
    slot: &'a mut Slot<'_>,
) -> (&'a mut [Group<L, T>], Slot<'a>) {
    let nq = rays.len();
    slot.split_from(nq.div_ceil(L::G), |g| {
        let r = RayLanes::<L>::join(|k| &rays[(g * L::G + k).min(nq - 1)]);
        Group {
            pre: T::prepare(&r),
            r,
        }
    })
}

/// Selection bits of group `g` of a packet of `nq` quads: bit `k` for
/// each quad `g L::G + k` that exists.
#[inline(always)]
pub(crate) fn all<L: Wide>(g: usize, nq: usize) -> u32 {
    let n = (nq - g * L::G).min(L::G);
    (1u32 << n) - 1
}

/// Lane bits (bit `4k + i`: lane `i` of quad `g L::G + k`) of the quads of
/// group `g` selected by `sel`, from each quad's mask `m(q)`.
#[inline(always)]
pub(crate) fn lane_bits<L: Wide>(g: usize, sel: u32, m: impl Fn(usize) -> M4) -> u32 {
    let mut bits = 0u32;
    for k in 0..L::G {
        if sel >> k & 1 != 0 {
            bits |= m(g * L::G + k).bitmask() << (4 * k);
        }
    }
    bits
}

/// Quads with lanes in `bits` (`lane_bits`).
#[inline(always)]
pub(crate) fn quads_in(bits: u32) -> u32 {
    (0..8).filter(|k| bits >> (4 * k) & 15 != 0).count() as u32
}

/// Triangle `prim` against the lanes `bits` of `grp`, without its `cull`
/// side (`Cull::apply`): the test's result and the lane bits that hit.
#[inline(always)]
pub(crate) fn test<L: Wide, T: TriangleTest>(
    grp: &Group<L, T>,
    prim: &T::Prim,
    bits: u32,
    cull: Cull,
) -> (TriHit<L>, u32) {
    let mut h = T::intersect(&grp.r, &grp.pre, prim);
    cull.apply::<T, L>(&grp.r.dir, prim, &mut h);
    let hb = L::mask_bits(h.mask) & bits;
    (h, hb)
}

/// Quad `k` of `r`: its origins and directions.
#[inline(always)]
pub(crate) fn quad_ray<L: Wide>(r: &RayLanes<L>, k: usize) -> ([F4; 3], [F4; 3]) {
    (r.org.map(|x| x.quad(k)), r.dir.map(|x| x.quad(k)))
}

/// For each quad `k` of a group with hit lanes in `hb`: `f(k, lanes, (t,
/// u, v))`.
#[inline(always)]
pub(crate) fn each_hit<L: Wide>(
    h: &TriHit<L>,
    hb: u32,
    mut f: impl FnMut(usize, M4, (F4, F4, F4)),
) {
    for k in 0..L::G {
        let m = (hb >> (4 * k)) & 15;
        if m != 0 {
            f(
                k,
                mask_from_bits(m),
                (h.t.quad(k), h.u.quad(k), h.v.quad(k)),
            );
        }
    }
}

/// Lanes `hm` of `hq`, rays `ray()` (origins, directions), hit triangle
/// `id` at `(t, u, v)`: those nearer than their best so far (all of them,
/// with `ANY`) and accepted by `filter` take it; the taken lanes.
#[inline(always)]
pub(crate) fn take<const ANY: bool>(
    hq: &mut Hit4,
    hm: M4,
    hit: (F4, F4, F4),
    id: u32,
    filter: &Hook<'_>,
    ray: impl Fn() -> ([F4; 3], [F4; 3]),
) -> M4 {
    let (t, u, v) = hit;
    let take = if ANY { hm } else { hm & hq.closer(t, id) };
    let take = filter.quad_with(take, hit, id, ray);
    if take.any() {
        hq.t = F4::select(take, t, hq.t);
        hq.u = F4::select(take, u, hq.u);
        hq.v = F4::select(take, v, hq.v);
        for k in 0..4 {
            if take.test(k) {
                hq.prim[k] = id;
            }
        }
    }
    take
}
