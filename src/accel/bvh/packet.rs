//! What the three large-packet traversals share (BVH paper section 3):
//! the prepared packet (`Packet`: live lanes, per-quad slab data
//! `QuadBox`, triangle-test precomputation, per-lane far ends, the
//! frustum of section 4), the `Walk` each traversal implements (Masked,
//! Ranged, Partition), the packet size classes (through
//! `accel::packet::by_class`) and the lane-by-lane coherence fallback
//! (`alone`). The 2x2 SIMD ray (`traverse_simd`) uses the same `QuadBox`.
//!
//! # Exactness
//! `QuadBox::entry` is the single ray's slab test lane by lane (same
//! operations, same NaN handling), and the leaf test is the single ray's
//! triangle test with the tie rule `geom::closer`, so a box or triangle is
//! accepted for a lane exactly when the single ray accepts it.
#![forbid(unsafe_code)]

use super::frustum::Frustum;
use super::traverse_single;
use super::{BvhNode, BvhOptions, BvhView, MAX_DEPTH, TriangleTest};
use crate::accel::entry::EntryPoint;
use crate::accel::fallback;
use crate::accel::packet::{SizeClass, by_class};
use crate::counters::{Counters, count};
use crate::geom::lane::mask_from_bits;
use crate::geom::{F4, Hit4, INVALID_ID, M4, Ray4, RayLanes};

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

/// A large-packet traversal: walks one prepared packet through the tree.
pub(crate) trait Walk {
    /// `start`: the node to start at and its depth (the root: `(0, 0)`).
    fn walk<T: TriangleTest, const ANY: bool, const Q: usize>(
        p: &mut Packet<T, Q>,
        b: &BvhView<'_>,
        rays: &[Ray4],
        hits: &mut [Hit4],
        start: (usize, usize),
        ctr: &mut Counters,
    );
}

/// Split the input into packets of at most 256 quads, each traced with
/// scratch sized by its class (1, 4, 16, 64 or 256 quads) on the stack,
/// from `entry` (every packet of the input) or the root. An entry node
/// outside the tree starts at the root.
pub(crate) fn dispatch<W: Walk, T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    opt: &BvhOptions,
    entry: Option<&EntryPoint>,
    ctr: &mut Counters,
) {
    let start = match entry {
        Some(e) if (e.node as usize) < b.nodes.len() => {
            (e.node as usize, (e.depth as usize).min(MAX_DEPTH))
        }
        _ => (0, 0),
    };
    let n = rays.len().min(active.len()).min(hits.len());
    let mut run = Run::<W, T, ANY> {
        b,
        rays: &rays[..n],
        active: &active[..n],
        hits: &mut hits[..n],
        opt,
        start,
        ctr,
        _w: core::marker::PhantomData,
    };
    by_class(n, &mut run);
}

/// A large-packet call as the packet driver's size classes see it.
struct Run<'x, 'b, W, T, const ANY: bool> {
    b: &'x BvhView<'b>,
    rays: &'x [Ray4],
    active: &'x [M4],
    hits: &'x mut [Hit4],
    opt: &'x BvhOptions,
    start: (usize, usize),
    ctr: &'x mut Counters,
    _w: core::marker::PhantomData<(W, T)>,
}

impl<W: Walk, T: TriangleTest, const ANY: bool> SizeClass for Run<'_, '_, W, T, ANY> {
    #[inline]
    fn packet<const Q: usize>(&mut self, r: core::ops::Range<usize>) {
        let (rays, active) = (&self.rays[r.clone()], &self.active[r.clone()]);
        let hits = &mut self.hits[r];
        packet::<W, T, ANY, Q>(self.b, rays, active, hits, self.opt, self.start, self.ctr);
    }
}

fn packet<W: Walk, T: TriangleTest, const ANY: bool, const Q: usize>(
    b: &BvhView<'_>,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    opt: &BvhOptions,
    start: (usize, usize),
    ctr: &mut Counters,
) {
    if let Some(mut p) = Packet::<T, Q>::new(b, rays, active, hits, opt, ctr) {
        if !p.coherent {
            return alone::<T, ANY>(b, rays, &p.live[..p.nq], hits, ctr);
        }
        W::walk::<T, ANY, Q>(&mut p, b, rays, hits, start, ctr);
    }
}

/// The coherence fallback (`trace::fallback`): every live lane traced by
/// `traverse_single` (from the root: the same hit as from any entry point).
#[inline(never)]
pub(crate) fn alone<T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    rays: &[Ray4],
    live: &[M4],
    hits: &mut [Hit4],
    ctr: &mut Counters,
) {
    let n = fallback::each_lane(live, |q, i| {
        let ray = rays[q].lane(i);
        let h = if ANY {
            traverse_single::any_hit::<T>(b, &ray, ctr)
        } else {
            traverse_single::intersect::<T>(b, &ray, ctr)
        };
        hits[q].set_lane(i, h);
    });
    // The single ray counted these rays again.
    ctr.rays -= n;
}

/// One packet of `nq <= Q` quads during traversal.
pub(crate) struct Packet<T: TriangleTest, const Q: usize> {
    pub nq: usize,
    /// Slab-test data per quad (reciprocals, direction signs).
    qb: [QuadBox; Q],
    /// Triangle-test precomputation per quad.
    pre: [T::Pre<F4>; Q],
    /// Lanes still traced: active, valid and (occlusion) not yet occluded.
    pub live: [M4; Q],
    /// Per quad and lane: `min(tmax, best.t)`, the end of the interval a
    /// box must overlap.
    tfar: [F4; Q],
    /// Live lanes in the packet.
    n_live: u32,
    /// Near child first when the packet's direction sum is negative on the
    /// split axis.
    neg: [bool; 3],
    pub frustum: Option<Frustum>,
    /// Whether the live lanes pass `fallback::coherent` (else the packet
    /// is traced lane by lane, and gets no frustum).
    pub coherent: bool,
}

impl<T: TriangleTest, const Q: usize> Packet<T, Q> {
    /// Write `Hit::MISS` to every active lane, count the packet and its
    /// rays, and prepare the live lanes; `None` when nothing is to be traced.
    pub(crate) fn new(
        b: &BvhView<'_>,
        rays: &[Ray4],
        active: &[M4],
        hits: &mut [Hit4],
        opt: &BvhOptions,
        ctr: &mut Counters,
    ) -> Option<Self> {
        let nq = rays.len().min(active.len()).min(hits.len()).min(Q);
        ctr.packets += 1;
        let mut live = [M4::FALSE; Q];
        let mut n_live = 0;
        let mut sum = [F4::ZERO; 3];
        for q in 0..nq {
            let (r, m) = (&rays[q], active[q]);
            if !m.any() {
                continue;
            }
            // Ray::is_valid, 4-wide: finite origin and direction, a
            // non-zero direction, 0 <= tmin <= tmax.
            let fin = |x: F4| x.abs().cmplt(F4::INFINITY);
            let valid = fin(r.org[0])
                & fin(r.org[1])
                & fin(r.org[2])
                & fin(r.dir[0])
                & fin(r.dir[1])
                & fin(r.dir[2])
                & (r.dir[0].cmpne(F4::ZERO) | r.dir[1].cmpne(F4::ZERO) | r.dir[2].cmpne(F4::ZERO))
                & r.tmin.cmpge(F4::ZERO)
                & r.tmin.cmple(r.tmax);
            let h = &mut hits[q];
            h.t = F4::select(m, F4::INFINITY, h.t);
            h.u = F4::select(m, F4::ZERO, h.u);
            h.v = F4::select(m, F4::ZERO, h.v);
            for i in 0..4 {
                if m.test(i) {
                    h.prim[i] = INVALID_ID;
                }
            }
            let l = m & valid;
            for (sa, da) in sum.iter_mut().zip(&r.dir) {
                *sa += F4::select(l, *da, F4::ZERO);
            }
            live[q] = l;
            n_live += l.bitmask().count_ones();
        }
        ctr.rays += n_live as u64;
        if n_live == 0 || b.nodes.is_empty() {
            return None;
        }
        let coherent =
            fallback::coherent(&rays[..nq], &live[..nq], b.info.bounds.diagonal().length());
        let frustum = if opt.culling && coherent {
            let f = Frustum::new(opt.kind, &rays[..nq], &live[..nq], &b.nodes[0].aabb());
            if f.is_none() {
                ctr.packets_no_cull += 1;
            }
            f
        } else {
            None
        };
        // Scratch of quads past nq repeats the last quad (never read).
        let at = |q: usize| &rays[q.min(nq - 1)];
        let qb: [QuadBox; Q] = core::array::from_fn(|q| QuadBox::new(at(q)));
        let pre: [T::Pre<F4>; Q] =
            core::array::from_fn(|q| T::prepare(&RayLanes::from_ray4(at(q))));
        let tfar: [F4; Q] = core::array::from_fn(|q| at(q).tmax);
        // A zero sum on an axis: the first live lane decides.
        let q0 = live[..nq].iter().position(|m| m.any()).unwrap_or(0);
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
        Some(Packet {
            nq,
            qb,
            pre,
            live,
            tfar,
            n_live,
            neg,
            frustum,
            coherent,
        })
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

    /// `rayIntersectTriangle(R[q], T[i])`: the live lanes of quad `q`
    /// against stored triangle `i` (caller id `id`), each lane keeping its
    /// nearest hit (tie rule of `geom::ray`); for occlusion, lanes that hit
    /// are done.
    #[inline(always)]
    // Inner-loop leaf test (per quad and triangle): a struct would be rebuilt per call.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn test<const ANY: bool>(
        &mut self,
        b: &BvhView<'_>,
        rays: &[Ray4],
        hits: &mut [Hit4],
        q: usize,
        i: usize,
        id: u32,
        depth: usize,
        ctr: &mut Counters,
    ) {
        let lm = self.live[q];
        if !lm.any() {
            return;
        }
        ctr.tri_at(depth, lm.bitmask().count_ones() as u64);
        let h = T::intersect(
            &RayLanes::from_ray4(&rays[q]),
            &self.pre[q],
            T::prim(b.store(), i),
        );
        let hm = h.mask & lm;
        if !hm.any() {
            return;
        }
        let hq = &mut hits[q];
        let take = if ANY { hm } else { hm & hq.closer(h.t, id) };
        if !take.any() {
            return;
        }
        hq.t = F4::select(take, h.t, hq.t);
        hq.u = F4::select(take, h.u, hq.u);
        hq.v = F4::select(take, h.v, hq.v);
        for k in 0..4 {
            if take.test(k) {
                hq.prim[k] = id;
            }
        }
        // A taken hit lies in [tmin, tmax) and not beyond best.t.
        self.tfar[q] = F4::select(take, h.t, self.tfar[q]);
        if ANY {
            self.live[q] &= !take;
            self.n_live -= take.bitmask().count_ones();
        }
    }

    /// Whether every lane is done (occlusion).
    #[inline(always)]
    pub(crate) fn done(&self) -> bool {
        self.n_live == 0
    }
}
