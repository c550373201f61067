//! Frustum-first traversal of n x n packets through the 4-wide tree
//! (`Method::BvhFrustum`): a node visit costs a constant number of
//! operations for the whole packet, not a scan of its quads.
//!
//! At a wide node the packet's interval frustum (the bounds of its live
//! lanes' origins and reciprocal directions, Wald, Boulos, Shirley 2007,
//! section 4.3; Embree 3's `node_intersector_frustum.h`) is tested against
//! all four children at once, one 4-wide slab test whose lanes are the
//! children. The children it admits are then tested with the packet's first
//! live ray (Wald et al. 2007's "first active ray"; the group `i_a` carried
//! on the stack as in Ranged traversal, BVH paper section 3.2), again all
//! four at once; only a child the frustum admits but the first ray misses
//! is scanned lane group by lane group from `i_a` (a group is `L::G` quads
//! side by side: 16 rays per slab test with AVX-512) until a live lane
//! enters it. The children are visited in the order of the frustum's near
//! distance (no per-ray sorting), the others pushed with it, and a popped
//! child whose near distance lies beyond every lane's nearest hit is
//! dropped untested. At a leaf each group from `i_a` on gets one slab test
//! against the leaf's box, and only groups with an entering live lane test
//! its triangles, each triangle broadcast against the group's lanes
//! (Fuetterling et al. 2015, section 4: large packets on a 4-wide tree).
//! In packets of at least `FRUSTA_MIN_LANES` lanes each group also has
//! its own interval frustum, the groups' frusta side by side as lanes
//! (`GroupFrusta`): one wide test of the leaf's box (and of a child box in
//! `first_group`) against them picks the groups whose exact slab test
//! runs, so such a leaf is box-tested only by the groups near it (Wald et
//! al. 2007's frustum, one per group rather than per packet).
//! Each group keeps its nearest hits as lanes (`GroupHit`), written back
//! to the packet's quads once, after the walk. The packet is set up lane
//! group by lane group at the walk's width (`setup`: three passes over
//! its lane groups instead of a dozen over its quads), and its first
//! frustum is made from the live lanes' bounds gathered in the first
//! (`GroupBounds`), so a packet none of whose lanes may enter the root's
//! children (a camera packet beside the model) ends before its coherence
//! test, reciprocals and triangle-test lanes are made. A packet the
//! coherence test fails is tried again as its four Morton quarters (down
//! to 4x4 rays) before its lanes go alone. An occlusion packet
//! left with at most `HYBRID_LANES` live lanes finishes them one by one
//! with the wide single ray (`traverse_wide::walk_from`) over the subtrees
//! still on its stack (Benthin, Wald, Woop, Ernst, Mark 2012, section 4).
//!
//! # Exactness
//! The frustum test is conservative in floating point: each bound is a
//! corner of the interval product (box plane - origin) x reciprocal,
//! computed with the operations the lanes use (IEEE subtraction and
//! multiplication are monotone in each argument), so its near bound never
//! exceeds, and its far bound never falls below, any live lane's own slab
//! terms; NaN bounds (0 x inf, an axis whose live lanes have mixed
//! direction signs) constrain nothing, as NaN slab terms constrain nothing
//! in the single ray's test. The group frusta are the same arithmetic with
//! each group's own extremes as lanes (an axis whose live directions'
//! signs differ across the packet is left out, which only admits more),
//! and a group's far end there never falls below a live lane's. A child
//! or a group is therefore dropped only when no
//! live lane's own slab test (the single ray's arithmetic, `QuadBox`, lane
//! by lane) enters it by that lane's nearest hit so far, and a lane tests
//! the triangles of every leaf whose box it enters: the set of triangles a
//! lane tests contains its nearest one (module docs of `bvh`), and the tie
//! rule makes the order irrelevant. Results equal `traverse_single` lane by
//! lane, bitwise. The hybrid finish keeps this: the stack holds every
//! subtree a live lane may still enter, and there each lane runs the
//! single ray's own tests.
//!
//! # Deviations
//! - Packets starting at an entry point (MLRTA, AEPSA: binary nodes),
//!   packets with a live lane of tiny direction, and BVHs without a wide
//!   tree run the binary Ranged traversal (as `traverse_wide_ranged`),
//!   set up by the generic quad-by-quad setup (`bvh::packet`).
//! - The plane frustum of section 4 (`Packet::frustum`) is not consulted:
//!   the interval frustum replaces it at inner nodes, and the leaf's
//!   per-group box test replaces its per-triangle culling.
//! - The paper's frusta exist per ray kind; the interval frustum is the
//!   same for every kind (it bounds the lanes, not a camera model), so
//!   camera, shadow, reflection and refraction packets take one path.

use super::packet::{self, LaneBounds, PacketIn};
use super::traverse_ranged::Ranged;
use super::traverse_wide::{Stack, WideRay, walk_from};
use super::wide::{WIDTH, WideNode, insert_by};
use super::{BvhView, MAX_DEPTH, TriangleTest};
use crate::accel::fallback;
use crate::accel::group::{self, Group};
use crate::accel::packet::{PacketArgs, PacketSig, Start};
use crate::accel::slot::Slot;
use crate::counters::{Counters, count};
use crate::geom::triangle::TriHit;
use crate::geom::{F4, Hit, Hit4, INVALID_ID, M4, Ray4, RayLanes, Wide};
use crate::isa;
use glam::Vec4;

/// Stack entries: an expansion pushes all (up to `WIDTH`) children it
/// keeps and the walk pops the nearest at once, so at most `WIDTH - 1`
/// stay per wide level above the node expanded, `WIDTH` at it: `WIDTH *
/// MAX_DEPTH` leaves a level of margin over that bound.
const STACK: usize = WIDTH * MAX_DEPTH;

/// One lane group (`L::G` quads) as the slab tests read it: the single
/// ray's `RayBox` terms lane by lane, the live lanes as bits, and each
/// lane's far end `min(tmax, best.t)` (lanes not live: tmin +inf, tfar
/// -inf, so they bound nothing and enter nothing).
#[derive(Clone, Copy)]
pub(crate) struct GroupBox<L: Wide> {
    org: [L; 3],
    rcp: [L; 3],
    neg: [L::Mask; 3],
    tmin: L,
    tfar: L,
    live: u32,
    /// Bit `a` set when every lane's direction has the sign bit on axis
    /// `a`, clear when none has; `MIXED` otherwise.
    signs: u32,
}

impl<L: Wide> GroupBox<L> {
    /// A group without active lanes (its directions, where the setup keeps
    /// them until they become reciprocals, are +x: finite and non-zero).
    #[inline(always)]
    fn dead() -> Self {
        let (zero, no) = (L::splat(0.0), L::mask_from_bits(0));
        GroupBox {
            org: [zero; 3],
            rcp: [L::splat(1.0), zero, zero],
            neg: [no; 3],
            tmin: L::splat(f32::INFINITY),
            tfar: L::splat(f32::NEG_INFINITY),
            live: 0,
            signs: 0,
        }
    }
}

/// `GroupBox::signs` of a group whose lanes' direction signs differ.
const MIXED: u32 = u32::MAX;

/// Scratch bytes of the groups of `nq` quads (their boxes, hit records
/// and frusta) at the lane width that needs the most.
pub(crate) const fn bytes(nq: usize) -> usize {
    use crate::geom::{F8, F16};
    use crate::mem::scratch::bytes as b;
    // Groups, then chunks of `L::WIDTH` groups' frusta.
    let (g4, g8, g16) = (nq, nq.div_ceil(2), nq.div_ceil(4));
    let (a, c, d) = (
        b::<GroupBox<F4>>(g4) + b::<GroupHit<F4>>(g4) + b::<GroupFrusta<F4>>(g4.div_ceil(4)),
        b::<GroupBox<F8>>(g8) + b::<GroupHit<F8>>(g8) + b::<GroupFrusta<F8>>(g8.div_ceil(8)),
        b::<GroupBox<F16>>(g16) + b::<GroupHit<F16>>(g16) + b::<GroupFrusta<F16>>(g16.div_ceil(16)),
    );
    let m = if a > c { a } else { c };
    if m > d { m } else { d }
}

/// One lane group's nearest hits so far, kept as lanes during the walk
/// (the hits' `Hit4` quads are read once before it and written once after
/// it): a leaf's hit lanes are kept with one compare and four selects,
/// not quad by quad.
#[derive(Clone, Copy)]
pub(crate) struct GroupHit<L: Wide> {
    t: L,
    u: L,
    v: L,
    /// The triangle ids as the lanes' bits (`f32::from_bits`): kept by a
    /// select like t, u and v, not lane by lane. Selects, joins and
    /// splits only move bits (no arithmetic touches these lanes), so an id
    /// that is a NaN pattern (`INVALID_ID`) comes back unchanged.
    prim: L,
}

impl<L: Wide> GroupHit<L> {
    /// Group `g`'s hits from the packet's `hits` (past the last quad the
    /// group repeats it, as its lanes do).
    #[inline(always)]
    fn read(hits: &[Hit4], g: usize) -> Self {
        let nq = hits.len();
        let q = |k: usize| (g * L::G + k).min(nq - 1);
        GroupHit {
            t: L::join(|k| hits[q(k)].t),
            u: L::join(|k| hits[q(k)].u),
            v: L::join(|k| hits[q(k)].v),
            prim: L::join(|k| F4::from_array(hits[q(k)].prim.map(f32::from_bits))),
        }
    }

    /// A group's record with no hit in any lane (`Hit::MISS`'s fields).
    #[inline(always)]
    fn miss() -> Self {
        GroupHit {
            t: L::splat(f32::INFINITY),
            u: L::splat(0.0),
            v: L::splat(0.0),
            prim: L::splat(f32::from_bits(INVALID_ID)),
        }
    }

    /// `other` in the lanes `bits`, this record in the rest.
    #[inline(always)]
    fn select(self, bits: u32, other: &Self) -> Self {
        let m = L::mask_from_bits(bits);
        GroupHit {
            t: L::select(m, other.t, self.t),
            u: L::select(m, other.u, self.u),
            v: L::select(m, other.v, self.v),
            prim: L::select(m, other.prim, self.prim),
        }
    }

    /// Back to the quads of group `g` that exist (lanes no hit was taken
    /// for still hold what `read` found).
    #[inline(always)]
    fn write(&self, hits: &mut [Hit4], g: usize) {
        let nq = hits.len();
        for k in 0..L::G.min(nq - g * L::G) {
            let h = &mut hits[g * L::G + k];
            h.t = self.t.quad(k);
            h.u = self.u.quad(k);
            h.v = self.v.quad(k);
            h.prim = self.prim.quad(k).to_array().map(f32::to_bits);
        }
    }

    /// Lanes of `hb` (hit lanes of a test of triangle `id`) whose hit beats
    /// the one kept: nearer, or as near with a smaller id (`Hit4::closer`).
    #[inline(always)]
    fn closer(&self, t: L, hb: u32, id: u32) -> u32 {
        let lt = L::mask_bits(t.lt(self.t)) & hb;
        let mut eq = L::mask_bits(t.eq(self.t)) & hb;
        let mut take = lt;
        while eq != 0 {
            let i = eq.trailing_zeros() as usize;
            eq &= eq - 1;
            take |= u32::from(id < self.prim.get(i).to_bits()) << i;
        }
        take
    }

    /// Lanes `take` keep the hit `h` on triangle `id`.
    #[inline(always)]
    fn keep(&mut self, h: &TriHit<L>, take: u32, id: u32) {
        let m = L::mask_from_bits(take);
        self.t = L::select(m, h.t, self.t);
        self.u = L::select(m, h.u, self.u);
        self.v = L::select(m, h.v, self.v);
        self.prim = L::select(m, L::splat(f32::from_bits(id)), self.prim);
    }
}

impl<L: Wide> GroupBox<L> {
    /// Live lanes entering the box `(lo, hi)` by their far ends: `QuadBox::entry`'s
    /// arithmetic on `L` lanes.
    #[inline(always)]
    fn enters(&self, lo: [f32; 3], hi: [f32; 3]) -> u32 {
        let mut t0 = self.tmin;
        let mut t1 = self.tfar;
        if self.signs != MIXED {
            // Every lane has the same near plane per axis: the select
            // below picks it lane by lane, so picking it once gives the
            // same bits.
            for a in 0..3 {
                let (np, fp) = if self.signs >> a & 1 != 0 {
                    (hi[a], lo[a])
                } else {
                    (lo[a], hi[a])
                };
                let near = (L::splat(np) - self.org[a]) * self.rcp[a];
                let far = (L::splat(fp) - self.org[a]) * self.rcp[a];
                t0 = t0.raise(near);
                t1 = t1.lower(far);
            }
            return t0.le_bits(t1) & self.live;
        }
        for a in 0..3 {
            let l = (L::splat(lo[a]) - self.org[a]) * self.rcp[a];
            let h = (L::splat(hi[a]) - self.org[a]) * self.rcp[a];
            let near = L::select(self.neg[a], h, l);
            let far = L::select(self.neg[a], l, h);
            t0 = t0.raise(near);
            t1 = t1.lower(far);
        }
        t0.le_bits(t1) & self.live
    }
}

/// The interval frusta of up to `L::WIDTH` lane groups side by side: lane
/// `i` of chunk `c` bounds group `c L::WIDTH + i`'s live lanes as
/// `Frustum` bounds the packet's, so one wide test checks a box against
/// every group of the chunk, and a group's exact slab test (`GroupBox::enters`)
/// runs only where its frustum admits the box. An axis whose live lanes'
/// direction signs differ across the packet is not tested (`Signs`); a
/// group without a live lane (and a lane past the last group) admits nothing.
#[derive(Clone, Copy)]
pub(crate) struct GroupFrusta<L: Wide> {
    onear: [L; 3],
    ofar: [L; 3],
    big: [L; 3],
    small: [L; 3],
    tmin: L,
    tfar: L,
}

/// Per axis, the direction sign every live lane of the packet shares: 1
/// (sign bit clear), -1 (set), or 0 (both occur: the group frusta skip
/// the axis).
type Signs = [i8; 3];

/// Packets of fewer lanes (rays, counting a last group's padding) have no
/// group frusta, and their own instance of the walk. Measured (AVX-512,
/// interleaved A/B against Embree-16; docs/studies/bvh-traversal.md, "How
/// the walk got here"): with frusta, 8x8 camera packets (64 lanes, 4 groups)
/// traced 7 % slower on crytek sponza; 16x16 (256 lanes) within
/// -3 % .. +5 % on sponza and conference, 32x32 8-30 % faster on sponza,
/// conference and legocar. Counted in lanes, not groups, so that narrower ISA levels
/// (more, smaller groups) draw the line at the same packet size; only
/// AVX-512 was measured.
const FRUSTA_MIN_LANES: usize = 128;

/// Groups of chunk `c` (bits; `L::WIDTH` groups per chunk) from `ia` on
/// whose frusta admit the box `(lo, hi)` (packets with group frusta).
#[inline(always)]
fn admitted<L: Wide>(
    lv: &Leaves<'_, '_, L, impl TriangleTest>,
    c: usize,
    ia: usize,
    (lo, hi): ([f32; 3], [f32; 3]),
) -> u32 {
    let w = L::WIDTH;
    let bits = lv.gf[c].admits(lo, hi, &lv.signs);
    if c == ia / w {
        bits & !((1u32 << (ia % w)) - 1)
    } else {
        bits
    }
}

/// What `across` reduces: a group's live origins or reciprocals on an
/// axis, or its lanes' `tmin` or far ends (lanes not live hold +inf and
/// -inf there already).
#[derive(Clone, Copy)]
enum Term {
    Org(usize),
    Rcp(usize),
    Tmin,
    Tfar,
}

/// Lane `i`: the smallest (`MAX`: largest) `term` of group `gb[i]`'s live
/// lanes (+inf, `MAX` -inf, without one, and past the last group), by one
/// transposing reduction (`Wide::extremes_across`) in `v`.
#[inline(always)]
fn across<L: Wide, const MAX: bool>(
    v: &mut [L; 16],
    gb: &[GroupBox<L>],
    live: &[L::Mask; 16],
    term: Term,
) -> L {
    let fill = L::splat(if MAX {
        f32::NEG_INFINITY
    } else {
        f32::INFINITY
    });
    for i in 0..L::WIDTH {
        v[i] = match (gb.get(i), term) {
            (None, _) => fill,
            (Some(g), Term::Org(a)) => L::select(live[i], g.org[a], fill),
            (Some(g), Term::Rcp(a)) => L::select(live[i], g.rcp[a], fill),
            (Some(g), Term::Tmin) => g.tmin,
            (Some(g), Term::Tfar) => g.tfar,
        };
    }
    L::extremes_across::<MAX>(&mut v[..L::WIDTH])
}

impl<L: Wide> GroupFrusta<L> {
    /// The frusta of the groups `gb` (at most `L::WIDTH`): each extreme of
    /// every group at once, by transposing reductions (`across`). A group
    /// without a live lane gets tmin +inf and far end -inf: it admits
    /// nothing.
    #[inline(always)]
    fn new(gb: &[GroupBox<L>], signs: &Signs) -> Self {
        let nan = L::splat(f32::NAN);
        let mut f = GroupFrusta {
            onear: [nan; 3],
            ofar: [nan; 3],
            big: [nan; 3],
            small: [nan; 3],
            tmin: L::splat(f32::INFINITY),
            tfar: L::splat(f32::NEG_INFINITY),
        };
        if gb.is_empty() {
            return f;
        }
        let mut live = [L::mask_from_bits(0); 16];
        for (m, g) in live.iter_mut().zip(gb) {
            *m = L::mask_from_bits(g.live);
        }
        let mut v = [L::splat(0.0); 16];
        for (a, &sa) in signs.iter().enumerate() {
            if sa == 0 {
                continue;
            }
            let omin = across::<L, false>(&mut v, gb, &live, Term::Org(a));
            let omax = across::<L, true>(&mut v, gb, &live, Term::Org(a));
            let rmin = across::<L, false>(&mut v, gb, &live, Term::Rcp(a));
            let rmax = across::<L, true>(&mut v, gb, &live, Term::Rcp(a));
            (f.onear[a], f.ofar[a], f.big[a], f.small[a]) = if sa > 0 {
                (omax, omin, rmax, rmin)
            } else {
                (omin, omax, rmin, rmax)
            };
        }
        f.tmin = across::<L, false>(&mut v, gb, &live, Term::Tmin);
        f.tfar = across::<L, true>(&mut v, gb, &live, Term::Tfar);
        f
    }

    /// Groups (bits) whose frustum admits the box `(lo, hi)`: `Frustum::test_boxes`'s
    /// arithmetic with the groups as lanes.
    #[inline(always)]
    fn admits(&self, lo: [f32; 3], hi: [f32; 3], signs: &Signs) -> u32 {
        let zero = L::splat(0.0);
        let mut t0 = self.tmin;
        let mut t1 = self.tfar;
        for a in 0..3 {
            let (near, far) = match signs[a] {
                1 => {
                    let x = L::splat(lo[a]) - self.onear[a];
                    let y = L::splat(hi[a]) - self.ofar[a];
                    (
                        x * L::select(x.lt(zero), self.big[a], self.small[a]),
                        y * L::select(zero.le(y), self.big[a], self.small[a]),
                    )
                }
                -1 => {
                    let x = L::splat(hi[a]) - self.onear[a];
                    let y = L::splat(lo[a]) - self.ofar[a];
                    (
                        x * L::select(zero.lt(x), self.big[a], self.small[a]),
                        y * L::select(y.le(zero), self.big[a], self.small[a]),
                    )
                }
                _ => continue,
            };
            t0 = t0.raise(near);
            t1 = t1.lower(far);
        }
        t0.le_bits(t1)
    }

    /// Group `i` of the chunk now bounds the far ends `tfar` (its largest).
    #[inline(always)]
    fn set_tfar(&mut self, i: usize, tfar: f32) {
        self.tfar = L::select(L::mask_from_bits(1 << i), L::splat(tfar), self.tfar);
    }
}

/// The packet's interval frustum, laid out for a 4-wide test whose lanes
/// are a wide node's children (or, for the two-level top level, two
/// binary nodes: `twolevel::traverse_packet`). Per axis, with `s` the live lanes' common
/// direction sign (+1 or -1; NaN bounds when they differ):
/// - near bound `x * (x s < 0 ? big : small)`, `x = near plane - onear`;
/// - far bound `y * (y s >= 0 ? big : small)`, `y = far plane - ofar`;
///
/// where the near plane is the box's min for `s = +1` (max for -1), `onear`
/// the lanes' largest origin (smallest for -1), `ofar` the other extreme,
/// `big` and `small` the reciprocals of largest and smallest magnitude.
pub(crate) struct Frustum {
    near_max: [bool; 3],
    onear: [Vec4; 3],
    ofar: [Vec4; 3],
    s: [Vec4; 3],
    big: [Vec4; 3],
    small: [Vec4; 3],
    tmin: Vec4,
    /// The largest far end of a live lane.
    tfar: f32,
}

/// The live lanes' extremes a `Frustum` is made of: per axis the smallest
/// and largest origin and reciprocal direction, and whether every live
/// lane's direction has the sign bit set (`all_neg`) or clear (`all_pos`);
/// the smallest `tmin` and largest far end.
struct Extremes {
    o: [(f32, f32); 3],
    r: [(f32, f32); 3],
    all_neg: [bool; 3],
    all_pos: [bool; 3],
    tmin: f32,
    tfar: f32,
}

impl Frustum {
    /// The frustum of the groups' live lanes.
    #[inline(always)]
    fn new<L: Wide>(gb: &[GroupBox<L>]) -> Frustum {
        let inf = f32::INFINITY;
        let (mut omin, mut omax) = ([L::splat(inf); 3], [L::splat(-inf); 3]);
        let (mut rmin, mut rmax) = ([L::splat(inf); 3], [L::splat(-inf); 3]);
        let (mut tmin, mut tfar) = (L::splat(inf), L::splat(-inf));
        let (mut all_neg, mut all_pos) = ([true; 3], [true; 3]);
        let mn = |a: L, b: L| a.lower(b);
        let mx = |a: L, b: L| a.raise(b);
        for g in gb.iter().filter(|g| g.live != 0) {
            let m = L::mask_from_bits(g.live);
            for a in 0..3 {
                omin[a] = mn(omin[a], L::select(m, g.org[a], L::splat(inf)));
                omax[a] = mx(omax[a], L::select(m, g.org[a], L::splat(-inf)));
                rmin[a] = mn(rmin[a], L::select(m, g.rcp[a], L::splat(inf)));
                rmax[a] = mx(rmax[a], L::select(m, g.rcp[a], L::splat(-inf)));
                let nb = L::mask_bits(g.neg[a]) & g.live;
                all_neg[a] &= nb == g.live;
                all_pos[a] &= nb == 0;
            }
            tmin = mn(tmin, g.tmin);
            tfar = mx(tfar, g.tfar);
        }
        // Plain loops, not `map` closures: the lane reductions must inline into
        // the caller's ISA (an outlined closure would call the wide lane
        // reads as functions).
        let mut e = Extremes {
            o: [(0.0, 0.0); 3],
            r: [(0.0, 0.0); 3],
            all_neg,
            all_pos,
            tmin: tmin.lane_min(),
            tfar: tfar.lane_max(),
        };
        for a in 0..3 {
            e.o[a] = (omin[a].lane_min(), omax[a].lane_max());
            e.r[a] = (rmin[a].lane_min(), rmax[a].lane_max());
        }
        Frustum::of(&e)
    }

    /// The frustum of a packet's live lanes from their bounds gathered quad
    /// by quad (the two-level walk), before any group exists. On an axis
    /// whose live directions share a sign, `1 / d` falls as `d` grows
    /// (IEEE division is monotone), so the reciprocals' extremes are the
    /// reciprocals of the directions' extremes: the same bits as `new`
    /// finds from the groups' reciprocals.
    #[inline(always)]
    pub(crate) fn from_bounds(lb: &LaneBounds) -> Frustum {
        let (lo, hi) = (|v: F4| v.min_element(), |v: F4| v.max_element());
        Frustum::of(&Extremes {
            o: core::array::from_fn(|a| (lo(lb.omin[a]), hi(lb.omax[a]))),
            r: core::array::from_fn(|a| (1.0 / hi(lb.dmax[a]), 1.0 / lo(lb.dmin[a]))),
            all_neg: core::array::from_fn(|a| lb.pos[a] == 0),
            all_pos: core::array::from_fn(|a| lb.neg[a] == 0),
            tmin: lo(lb.tmin),
            tfar: hi(lb.tmax),
        })
    }

    /// The frustum of `e` (the struct docs).
    #[inline(always)]
    fn of(e: &Extremes) -> Frustum {
        let mut f = Frustum {
            near_max: [false; 3],
            onear: [Vec4::ZERO; 3],
            ofar: [Vec4::ZERO; 3],
            s: [Vec4::ONE; 3],
            big: [Vec4::NAN; 3],
            small: [Vec4::NAN; 3],
            tmin: Vec4::splat(e.tmin),
            tfar: e.tfar,
        };
        for a in 0..3 {
            let ((o0, o1), (r0, r1)) = (e.o[a], e.r[a]);
            if e.all_pos[a] {
                f.onear[a] = Vec4::splat(o1);
                f.ofar[a] = Vec4::splat(o0);
                f.big[a] = Vec4::splat(r1);
                f.small[a] = Vec4::splat(r0);
            } else if e.all_neg[a] {
                f.near_max[a] = true;
                f.s[a] = Vec4::NEG_ONE;
                f.onear[a] = Vec4::splat(o0);
                f.ofar[a] = Vec4::splat(o1);
                f.big[a] = Vec4::splat(r0);
                f.small[a] = Vec4::splat(r1);
            }
        }
        f
    }

    /// Children of `n` some live lane may enter (bits), and the frustum's
    /// near distance to each.
    #[inline(always)]
    fn test(&self, n: &WideNode) -> (u32, Vec4) {
        self.test_boxes(&n.min, &n.max)
    }

    /// Of the four boxes `(min[..][i], max[..][i])`, those some live lane
    /// may enter (bits), and the frustum's near distance to each.
    #[inline(always)]
    pub(crate) fn test_boxes(&self, min: &[[f32; 4]; 3], max: &[[f32; 4]; 3]) -> (u32, Vec4) {
        let mut t0 = self.tmin;
        let mut t1 = Vec4::splat(self.tfar);
        for a in 0..3 {
            let (lo, hi) = (Vec4::from_array(min[a]), Vec4::from_array(max[a]));
            let (np, fp) = if self.near_max[a] { (hi, lo) } else { (lo, hi) };
            let x = np - self.onear[a];
            let near = x * Vec4::select(
                (x * self.s[a]).cmplt(Vec4::ZERO),
                self.big[a],
                self.small[a],
            );
            let y = fp - self.ofar[a];
            let far = y * Vec4::select(
                (y * self.s[a]).cmpge(Vec4::ZERO),
                self.big[a],
                self.small[a],
            );
            t0 = Vec4::select(near.cmpgt(t0), near, t0);
            t1 = Vec4::select(far.cmplt(t1), far, t1);
        }
        (t0.cmple(t1).bitmask(), t0)
    }

    /// The largest far end of a live lane.
    #[inline(always)]
    pub(crate) fn tfar(&self) -> f32 {
        self.tfar
    }

    /// A live lane's largest far end is now `tfar` (its nearest hits have
    /// come closer, or lanes have left).
    #[inline(always)]
    pub(crate) fn set_tfar(&mut self, tfar: f32) {
        self.tfar = tfar;
    }

    /// The largest far end of a live lane, again: from the group frusta
    /// (each holds its groups' largest) when there are any, else from the
    /// groups.
    #[inline(always)]
    fn refresh<L: Wide, const FR: bool>(&mut self, gf: &[GroupFrusta<L>], gb: &[GroupBox<L>]) {
        let mut m = L::splat(f32::NEG_INFINITY);
        if !FR {
            for g in gb {
                m = m.raise(g.tfar);
            }
        } else {
            for c in gf {
                m = m.raise(c.tfar);
            }
        }
        self.tfar = m.lane_max();
    }
}

/// One ray's slab test against the four children of `n` (`traverse_wide`'s
/// arithmetic): lane `i` of group `g`.
#[inline(always)]
fn first_ray<L: Wide>(g: &GroupBox<L>, i: usize, n: &WideNode) -> u32 {
    let (mut t0, mut t1) = (Vec4::splat(g.tmin.get(i)), Vec4::splat(g.tfar.get(i)));
    for a in 0..3 {
        let (lo, hi) = (Vec4::from_array(n.min[a]), Vec4::from_array(n.max[a]));
        let (o, r) = (Vec4::splat(g.org[a].get(i)), Vec4::splat(g.rcp[a].get(i)));
        let (np, fp) = if L::mask_get(g.neg[a], i) {
            (hi, lo)
        } else {
            (lo, hi)
        };
        let near = (np - o) * r;
        let far = (fp - o) * r;
        t0 = Vec4::select(near.cmpgt(t0), near, t0);
        t1 = Vec4::select(far.cmplt(t1), far, t1);
    }
    t0.cmple(t1).bitmask()
}

/// Child `c`'s box.
#[inline(always)]
fn child_box(n: &WideNode, c: usize) -> ([f32; 3], [f32; 3]) {
    (
        [n.min[0][c], n.min[1][c], n.min[2][c]],
        [n.max[0][c], n.max[1][c], n.max[2][c]],
    )
}

/// The first group from `ia` on with a live lane entering `(lo, hi)`, or
/// the group count.
#[inline(always)]
fn first_group<L: Wide, const FR: bool>(
    lv: &Leaves<'_, '_, L, impl TriangleTest>,
    ia: usize,
    (lo, hi): ([f32; 3], [f32; 3]),
    depth: usize,
    ctr: &mut Counters,
) -> usize {
    if !FR {
        for (g, x) in lv.gb.iter().enumerate().skip(ia) {
            if x.live == 0 {
                continue;
            }
            ctr.aabb_at(depth, 1);
            if x.enters(lo, hi) != 0 {
                return g;
            }
        }
        return lv.gb.len();
    }
    let w = L::WIDTH;
    for c in ia / w..lv.gf.len() {
        let mut bits = admitted::<L>(lv, c, ia, (lo, hi));
        while bits != 0 {
            let g = c * w + bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let x = &lv.gb[g];
            if x.live == 0 {
                continue;
            }
            ctr.aabb_at(depth, 1);
            if x.enters(lo, hi) != 0 {
                return g;
            }
        }
    }
    lv.gb.len()
}

/// `Method::BvhFrustum` on the packet contract (`accel::packet::PacketSig`)
/// at a lane width, its `Kernel` chosen once per call (`trace::scene`'s
/// kernel table): a packet the wide walk takes (from the root, on a BVH
/// with a wide tree, no live lane of tiny direction) is set up and walked
/// here (`setup`); the others go to the binary Ranged walk with the
/// generic setup (`bvh::packet::walk_from`).
pub struct FrustumFirst<T, const ANY: bool>(core::marker::PhantomData<T>);

impl<'b, T: TriangleTest, const ANY: bool> isa::LaneFn<PacketSig<BvhView<'b>>>
    for FrustumFirst<T, ANY>
{
    #[inline(always)]
    fn call<L: Wide>(args: PacketArgs<'_, BvhView<'b>>) {
        let (b, p, rays, active, hits, mut slot, ctr) = args;
        let pk = PacketIn { rays, active, hits };
        let entry = match packet::start(b, p, &pk, &mut slot, ctr) {
            Start::Root => None,
            Start::At(e) => Some(e),
            Start::Miss => return crate::accel::packet::all_miss(active, pk.hits, ctr),
        };
        Self::from::<L>(b, p, pk, entry.as_ref(), &mut slot, ctr)
    }
}

impl<T: TriangleTest, const ANY: bool> FrustumFirst<T, ANY> {
    /// One packet from `entry` (the root when `None`): the wide walk when
    /// it takes the packet, else the binary Ranged walk.
    #[inline(always)]
    pub(crate) fn from<L: Wide>(
        b: &BvhView<'_>,
        p: &crate::accel::method::TraceParams,
        pk: PacketIn<'_>,
        entry: Option<&crate::accel::entry::EntryPoint>,
        slot: &mut Slot<'_>,
        ctr: &mut Counters,
    ) {
        let PacketIn { rays, active, hits } = pk;
        if entry.is_none() && !b.wide.is_empty() {
            let whole = PacketIn {
                rays,
                active,
                hits: &mut *hits,
            };
            if setup::<L, T, ANY>(b, whole, p.fallbacks, slot, ctr) {
                return;
            }
        }
        let pk = PacketIn { rays, active, hits };
        packet::walk_from::<L, Ranged, T, ANY>(b, p, pk, entry, slot, ctr)
    }
}

/// The live lanes' extremes at the walk's lane width, gathered while the
/// setup makes each group's `GroupBox`: the first frustum is made of
/// them (`Frustum::of`), and the coherence test's origin box.
struct GroupBounds<L: Wide> {
    omin: [L; 3],
    omax: [L; 3],
    dmin: [L; 3],
    dmax: [L; 3],
    tmin: L,
    tmax: L,
    /// Per axis, whether some live lane's direction has the sign bit set
    /// (`neg`) or clear (`pos`).
    neg: [bool; 3],
    pos: [bool; 3],
}

impl<L: Wide> GroupBounds<L> {
    #[inline(always)]
    fn new() -> Self {
        let (inf, ninf) = (L::splat(f32::INFINITY), L::splat(f32::NEG_INFINITY));
        GroupBounds {
            omin: [inf; 3],
            omax: [ninf; 3],
            dmin: [inf; 3],
            dmax: [ninf; 3],
            tmin: inf,
            tmax: ninf,
            neg: [false; 3],
            pos: [false; 3],
        }
    }

    /// Widen by the lanes `live` (mask `m`) of a group with origins `org`,
    /// directions `dir` and sign bits `neg`.
    #[inline(always)]
    fn add(
        &mut self,
        (org, dir): (&[L; 3], &[L; 3]),
        (tmin, tmax): (L, L),
        m: L::Mask,
        live: u32,
        neg: &[u32; 3],
    ) {
        for (a, &n) in neg.iter().enumerate() {
            self.neg[a] |= n & live != 0;
            self.pos[a] |= !n & live != 0;
        }
        if live == (1u32 << (4 * L::G)) - 1 {
            // Every lane live (most camera groups): no selects.
            for a in 0..3 {
                self.omin[a] = self.omin[a].lower(org[a]);
                self.omax[a] = self.omax[a].raise(org[a]);
                self.dmin[a] = self.dmin[a].lower(dir[a]);
                self.dmax[a] = self.dmax[a].raise(dir[a]);
            }
            self.tmin = self.tmin.lower(tmin);
            self.tmax = self.tmax.raise(tmax);
            return;
        }
        let (inf, ninf) = (L::splat(f32::INFINITY), L::splat(f32::NEG_INFINITY));
        for a in 0..3 {
            self.omin[a] = self.omin[a].lower(L::select(m, org[a], inf));
            self.omax[a] = self.omax[a].raise(L::select(m, org[a], ninf));
            self.dmin[a] = self.dmin[a].lower(L::select(m, dir[a], inf));
            self.dmax[a] = self.dmax[a].raise(L::select(m, dir[a], ninf));
        }
        self.tmin = self.tmin.lower(L::select(m, tmin, inf));
        self.tmax = self.tmax.raise(L::select(m, tmax, ninf));
    }

    /// The live lanes' frustum (`Frustum::from_bounds`'s arithmetic: on
    /// an axis whose live directions share a sign the reciprocals'
    /// extremes are those of the directions' extremes).
    #[inline(always)]
    fn frustum(&self) -> Frustum {
        let mut e = Extremes {
            o: [(0.0, 0.0); 3],
            r: [(0.0, 0.0); 3],
            all_neg: self.pos.map(|p| !p),
            all_pos: self.neg.map(|n| !n),
            tmin: self.tmin.lane_min(),
            tfar: self.tmax.lane_max(),
        };
        for a in 0..3 {
            e.o[a] = (self.omin[a].lane_min(), self.omax[a].lane_max());
            e.r[a] = (1.0 / self.dmax[a].lane_max(), 1.0 / self.dmin[a].lane_min());
        }
        Frustum::of(&e)
    }

    /// The packet's `Signs`: +1 (-1) on an axis where no live lane's
    /// direction has the sign bit set (clear), else 0.
    fn signs(&self) -> Signs {
        core::array::from_fn(|a| match (self.neg[a], self.pos[a]) {
            (false, _) => 1,
            (true, false) => -1,
            _ => 0,
        })
    }
}

/// Lane bits of group `g`'s valid rays (`Ray4::valid` at the group's
/// width: finite origin and direction, a non-zero direction,
/// `0 <= tmin <= tmax`).
#[inline(always)]
fn valid_bits<L: Wide>(org: &[L; 3], dir: &[L; 3], tmin: L, tmax: L) -> u32 {
    let (zero, inf, ninf) = (
        L::splat(0.0),
        L::splat(f32::INFINITY),
        L::splat(f32::NEG_INFINITY),
    );
    let fin = |x: L| ninf.lt(x) & x.lt(inf);
    let m = fin(org[0])
        & fin(org[1])
        & fin(org[2])
        & fin(dir[0])
        & fin(dir[1])
        & fin(dir[2])
        & !(dir[0].eq(zero) & dir[1].eq(zero) & dir[2].eq(zero))
        & zero.le(tmin)
        & tmin.le(tmax);
    L::mask_bits(m)
}

/// Lane bits whose direction is tiny (`fallback::tiny`: every component's
/// magnitude below `TINY_DIR`; a valid lane's direction is not zero).
#[inline(always)]
fn tiny_bits<L: Wide>(dir: &[L; 3]) -> u32 {
    let (lo, hi) = (L::splat(-fallback::TINY_DIR), L::splat(fallback::TINY_DIR));
    let small = |x: L| lo.lt(x) & x.lt(hi);
    L::mask_bits(small(dir[0]) & small(dir[1]) & small(dir[2]))
}

/// Write `Hit::MISS` to the active lanes of `hits`.
#[inline(always)]
fn miss_active(hits: &mut [Hit4], active: &[M4]) {
    for (h, m) in hits.iter_mut().zip(active) {
        h.miss(*m);
    }
}

/// The packet's setup at the walk's lane width, and the walk: three
/// passes over its lane groups (not over its quads).
/// 1. Each group's rays joined into lanes: the valid and live lanes,
///    direction signs, tiny directions, and the live
///    lanes' bounds (`GroupBounds`), written as its `GroupBox` (its
///    directions where the reciprocals go, until pass 2).
/// 2. A packet with no live lane, or whose first frustum the root's
///    children all refuse, writes its misses and ends; one that fails
///    the coherence test (the cone around its first live direction,
///    read from the `GroupBox`es, and its origins' spread) ends as
///    `Incoherent` before any reciprocal is made; else each group's
///    reciprocals and triangle-test lanes (`Group`, from the `GroupBox`:
///    no second join) are made.
/// 3. Each group's hit record: `Hit::MISS` in its active lanes, the
///    caller's hits in the others.
///
/// `Tiny` for a packet with a live lane of tiny direction, `Incoherent`
/// for one the coherence test fails: nothing written, nothing counted.
#[inline(always)]
fn one<L: Wide, T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    pk: PacketIn<'_>,
    fallbacks: bool,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) -> Outcome {
    // `setup` hands over slices of one length.
    let PacketIn { rays, active, hits } = pk;
    let nq = rays.len();
    debug_assert!(active.len() == nq && hits.len() == nq);
    if nq == 0 {
        return Outcome::Done;
    }
    if !active.iter().any(|m| m.any()) {
        // A shadow batch's packet of misses and unlit points only.
        ctr.packets += 1;
        return Outcome::Done;
    }
    let q = |g: usize, k: usize| (g * L::G + k).min(nq - 1);
    let mut bounds = GroupBounds::<L>::new();
    let (mut n_live, mut tiny) = (0u32, 0u32);
    let (gb, mut slot) = slot.split_from(nq.div_ceil(L::G), |g| {
        let act = group::lane_bits::<L>(g, group::all::<L>(g, nq), |i| active[i]);
        if act == 0 {
            // A shadow batch's misses and unlit points: nothing to join.
            return GroupBox::dead();
        }
        let r = RayLanes::<L>::join(|k| &rays[q(g, k)]);
        let live = act & valid_bits(&r.org, &r.dir, r.tmin, r.tmax);
        // Sign bits of each axis's directions, every lane of the group
        // (live or not: the slab test reads them all).
        let mut neg = [0u32; 3];
        for k in 0..L::G {
            let d = &rays[q(g, k)].dir;
            for a in 0..3 {
                neg[a] |= d[a].is_negative_bitmask() << (4 * k);
            }
        }
        let full = (1u32 << (4 * L::G)) - 1;
        let signs = if neg.iter().all(|&n| n == 0 || n == full) {
            (0..3).fold(0, |s, a| s | u32::from(neg[a] == full) << a)
        } else {
            MIXED
        };
        let lm = L::mask_from_bits(live);
        if live != 0 {
            n_live += live.count_ones();
            tiny |= tiny_bits(&r.dir) & live;
            bounds.add((&r.org, &r.dir), (r.tmin, r.tmax), lm, live, &neg);
        }
        GroupBox {
            org: r.org,
            // The directions until pass 2 makes them reciprocals.
            rcp: r.dir,
            neg: [
                L::mask_from_bits(neg[0]),
                L::mask_from_bits(neg[1]),
                L::mask_from_bits(neg[2]),
            ],
            tmin: L::select(lm, r.tmin, L::splat(f32::INFINITY)),
            tfar: L::select(lm, r.tmax, L::splat(f32::NEG_INFINITY)),
            live,
            signs,
        }
    });
    if tiny != 0 {
        return Outcome::Tiny;
    }
    let mut fr = bounds.frustum();
    if n_live == 0 || refused(b, &fr, ctr) {
        ctr.packets += 1;
        ctr.rays += n_live as u64;
        miss_active(hits, active);
        return Outcome::Done;
    }
    let gb: &mut [GroupBox<L>] = gb;
    // The coherence cone around the first live lane's direction, tested
    // before pass 2 so that an incoherent packet (split, or traced lane by
    // lane) makes no reciprocals it would throw away.
    let cone = if fallbacks {
        let first = gb.iter().enumerate().flat_map(|(g, x)| {
            let mut bits = x.live;
            core::iter::from_fn(move || {
                let i = bits.trailing_zeros() as usize;
                bits &= bits.wrapping_sub(1);
                (i < 32).then(|| {
                    let r = &rays[q(g, i / 4)];
                    glam::Vec3::new(r.dir[0][i % 4], r.dir[1][i % 4], r.dir[2][i % 4])
                })
            })
        });
        fallback::Cone::<L>::first(first)
    } else {
        None
    };
    // No usable direction (no cone): nothing to compare, the lanes pass
    // (`coherent`).
    if let Some(c) = &cone {
        let close = {
            let (lo, hi) = (&bounds.omin, &bounds.omax);
            let lo = glam::Vec3::new(lo[0].lane_min(), lo[1].lane_min(), lo[2].lane_min());
            let hi = glam::Vec3::new(hi[0].lane_max(), hi[1].lane_max(), hi[2].lane_max());
            fallback::origins_close(lo, hi, b.info.bounds.diagonal().length())
        };
        if !close {
            return Outcome::Incoherent;
        }
        // A plain loop, not a closure: it stays compiled at the ISA.
        for x in gb.iter() {
            // `x.rcp` still holds the directions.
            if c.leaves(&x.rcp, L::mask_from_bits(x.live)) {
                return Outcome::Incoherent;
            }
        }
    }
    // Pass 2.
    let one = L::splat(1.0);
    let (grp, mut slot) = slot.split_from(gb.len(), |g| {
        let x = &mut gb[g];
        // The group's rays as pass 1 joined them: equal in the live lanes
        // (the only ones a triangle test's result is read for).
        let r = RayLanes {
            org: x.org,
            dir: x.rcp,
            tmin: x.tmin,
            tmax: x.tfar,
        };
        x.rcp = [one / x.rcp[0], one / x.rcp[1], one / x.rcp[2]];
        Group {
            pre: T::prepare(&r),
            r,
        }
    });
    let grp: &[Group<L, T>] = grp;
    ctr.packets += 1;
    ctr.rays += n_live as u64;
    // Pass 3.
    let miss = GroupHit::<L>::miss();
    let (gh, slot) = slot.split_from(gb.len(), |g| {
        let act = group::lane_bits::<L>(g, group::all::<L>(g, nq), |i| active[i]);
        GroupHit::read(hits, g).select(act, &miss)
    });
    walk_groups::<L, T, ANY>(
        b,
        rays,
        grp,
        gb,
        gh,
        &mut fr,
        bounds.signs(),
        n_live,
        slot,
        ctr,
    );
    for (g, h) in gh.iter().enumerate() {
        h.write(hits, g);
    }
    Outcome::Done
}

/// What `one` did with a packet.
enum Outcome {
    /// Traced (answers written, packet and rays counted).
    Done,
    /// A live lane has a tiny direction: nothing written or counted.
    Tiny,
    /// The coherence test failed: nothing written or counted.
    Incoherent,
}

/// Parts of at most this many quads (a 4x4 sub-tile, or one lane group
/// where that is larger) that fail the coherence test go lane by lane:
/// smaller packets pay their setup for too few rays.
const SPLIT_MIN: usize = 4;

/// Most Morton quarters an incoherent packet is split into at once
/// (`setup`'s work list: three levels below a packet of `MAX_QUADS`).
const PARTS: usize = 16;

/// A packet the wide walk takes: set up and walked by `one`. A packet the
/// coherence test fails is split into its four Morton quarters (each a
/// run of a quarter of its quads: in Morton order, a square sub-tile of
/// a camera tile and of the secondary packets made from it), each tried
/// as a packet in turn; a
/// part of `SPLIT_MIN` quads that still fails goes lane by lane with the
/// single ray. `false` (nothing written, nothing counted) for a packet
/// with a live lane of tiny direction: the generic setup takes it.
#[inline(always)]
fn setup<L: Wide, T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    pk: PacketIn<'_>,
    fallbacks: bool,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) -> bool {
    let PacketIn { rays, active, hits } = pk;
    let nq = rays.len().min(active.len()).min(hits.len());
    if b.nodes.is_empty() {
        return false;
    }
    // The parts count as the one packet they are.
    let packets = ctr.packets;
    // A work list, not recursion: everything stays inlined at the ISA.
    let mut todo = [(0usize, 0usize); PARTS];
    let (mut n, mut top) = (1, true);
    todo[0] = (0, nq);
    while n > 0 {
        n -= 1;
        let (s, e) = todo[n];
        let part = PacketIn {
            rays: &rays[s..e],
            active: &active[s..e],
            hits: &mut hits[s..e],
        };
        match one::<L, T, ANY>(b, part, fallbacks, slot, ctr) {
            Outcome::Done => {}
            // Only the whole packet can have a tiny lane (the parts are
            // of a packet without one).
            Outcome::Tiny if top => return false,
            Outcome::Incoherent if e - s > SPLIT_MIN.max(L::G) && n + 4 <= PARTS => {
                let q = (e - s).div_ceil(4);
                for k in (0..4).rev() {
                    let (ps, pe) = (s + k * q, (s + (k + 1) * q).min(e));
                    if ps < pe {
                        todo[n] = (ps, pe);
                        n += 1;
                    }
                }
            }
            _ => alone_all::<T, ANY>(b, &rays[s..e], &active[s..e], &mut hits[s..e], slot, ctr),
        }
        top = false;
    }
    ctr.packets = packets + 1;
    true
}

/// Every live lane of the quads traced alone by the wide single ray,
/// counted as one packet.
#[inline(always)]
fn alone_all<T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    miss_active(hits, active);
    let (live, _) = slot.split_from(rays.len(), |q| active[q] & rays[q].valid());
    ctr.packets += 1;
    ctr.rays += live
        .iter()
        .map(|m| m.bitmask().count_ones() as u64)
        .sum::<u64>();
    crate::accel::packet::alone::<BvhView, T, ANY>(b, rays, live, hits, ctr);
}

/// Whether the root's children all refuse the packet's first frustum.
#[inline(always)]
fn refused(b: &BvhView<'_>, fr: &Frustum, ctr: &mut Counters) -> bool {
    let root = &b.wide[0];
    let valid = valid_children(root);
    let refused = fr.test(root).0 & valid == 0;
    let _ = &ctr; // read only with the `counters` feature
    if refused {
        count!(ctr.culled_nodes += valid.count_ones() as u64);
    }
    refused
}

/// The walk of a set-up packet: its groups' frusta (packets of at least
/// `FRUSTA_MIN_LANES` lanes), then the tree from the root.
// The packet's groups, first frustum, signs and live lanes, the scratch.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn walk_groups<L: Wide, T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    rays: &[Ray4],
    grp: &[Group<L, T>],
    gb: &mut [GroupBox<L>],
    gh: &mut [GroupHit<L>],
    fr: &mut Frustum,
    signs: Signs,
    n_live: u32,
    mut slot: Slot<'_>,
    ctr: &mut Counters,
) {
    let ng = gb.len();
    // Too few rays to cull many groups per leaf: no frusta, every
    // group's exact test runs.
    let nf = if ng * L::WIDTH >= FRUSTA_MIN_LANES {
        ng.div_ceil(L::WIDTH)
    } else {
        0
    };
    let signs = if nf > 0 { signs } else { [0; 3] };
    // A plain loop, not `split_from`'s closure: the frusta's lane
    // reductions must inline into the caller's ISA.
    let empty = GroupFrusta::new(&[], &signs);
    let (gf, _) = slot.split(nf, empty);
    for (c, f) in gf.iter_mut().enumerate() {
        *f = GroupFrusta::new(&gb[c * L::WIDTH..ng.min((c + 1) * L::WIDTH)], &signs);
    }
    let leaves = Leaves {
        b,
        rays,
        grp,
        n_live,
        gb,
        gh,
        gf,
        signs,
    };
    // Two instances: packets without group frusta pay nothing for them.
    if nf > 0 {
        walk_tree::<L, T, ANY, true>(leaves, fr, ctr);
    } else {
        walk_tree::<L, T, ANY, false>(leaves, fr, ctr);
    }
}

/// What a leaf visit reads and updates: the tree, the packet's groups,
/// their boxes, hit records and frusta, and the live lane count.
struct Leaves<'x, 'b, L: Wide, T: TriangleTest> {
    b: &'x BvhView<'b>,
    rays: &'x [Ray4],
    grp: &'x [Group<L, T>],
    gb: &'x mut [GroupBox<L>],
    gh: &'x mut [GroupHit<L>],
    /// The groups' frusta, `L::WIDTH` groups per chunk (none for packets
    /// of fewer than `FRUSTA_MIN_LANES` lanes), and the packet's
    /// direction signs they are made for.
    gf: &'x mut [GroupFrusta<L>],
    signs: Signs,
    n_live: u32,
}

/// The frustum-first walk of the wide tree from its root.
#[inline(always)]
fn walk_tree<L: Wide, T: TriangleTest, const ANY: bool, const FR: bool>(
    mut lv: Leaves<'_, '_, L, T>,
    fr: &mut Frustum,
    ctr: &mut Counters,
) {
    let wide = lv.b.wide;
    let ng = lv.gb.len();

    // Stack: wide node, child slot, first group, frustum near distance.
    let mut st_w = [0u32; STACK];
    let mut st_c = [0u8; STACK];
    let mut st_ia = [0u16; STACK];
    let mut st_t = [0f32; STACK];
    let mut st_d = [0u8; STACK];
    let mut sp = 0usize;
    // The node being expanded (`None`: pop).
    let mut cur = Some((0usize, first_group_live(lv.gb), 0usize));
    loop {
        let (w, mut ia, depth) = match cur.take() {
            Some(x) => x,
            None => {
                // Pop until a child some lane may still enter.
                let mut next = None;
                while sp > 0 {
                    sp -= 1;
                    if st_t[sp] > fr.tfar {
                        continue;
                    }
                    let (w, c) = (st_w[sp] as usize, st_c[sp] as usize);
                    let (ia, depth) = (st_ia[sp] as usize, st_d[sp] as usize);
                    let n = &wide[w];
                    if n.count[c] == 0 {
                        next = Some((n.child[c] as usize, ia, depth));
                        break;
                    }
                    let (done, shrank) = leaf::<L, T, ANY, FR>(&mut lv, (w, c, ia), depth, ctr);
                    if done {
                        return;
                    }
                    if ANY && lv.n_live <= HYBRID_LANES {
                        let pending = (0..sp).rev().map(|e| {
                            let n = &wide[st_w[e] as usize];
                            let c = st_c[e] as usize;
                            (n.child[c], n.count[c], st_d[e] as usize)
                        });
                        return finish_alone::<L, T>(&mut lv, pending, ctr);
                    }
                    if shrank {
                        // Nearest hits: the far ends fell. Occlusion: a whole
                        // group is done, its lanes bound nothing any more.
                        if ANY {
                            *fr = Frustum::new::<L>(lv.gb);
                        } else {
                            fr.refresh::<L, FR>(lv.gf, lv.gb);
                        }
                    }
                }
                match next {
                    Some(x) => x,
                    None => return,
                }
            }
        };
        if ANY {
            // Occlusion: groups die during the walk. The first group
            // carried may have ended (its lanes all occluded): the first
            // ray then comes from the next live group, not from a scan of
            // every admitted child from a dead one. Dead groups enter
            // nothing, so skipping them drops no child a live lane enters.
            while ia < ng && lv.gb[ia].live == 0 {
                ia += 1;
            }
        }
        if ia >= ng {
            continue;
        }
        let n = &wide[w];
        let (fm, t0) = fr.test(n);
        let valid = valid_children(n);
        let mut fm = fm & valid;
        ctr.aabb_at(depth + 1, WIDTH as u64);
        count!(ctr.culled_nodes += (valid & !fm).count_ones() as u64);
        if fm == 0 {
            continue;
        }
        // The first live lane of group `ia` against the admitted children.
        let lead = lv.gb[ia].live;
        let first = if lead != 0 {
            first_ray::<L>(&lv.gb[ia], lead.trailing_zeros() as usize, n)
        } else {
            0
        };
        let ts = t0.to_array();
        let mut kids = [(0.0f32, 0usize, 0usize); WIDTH];
        let mut k = 0;
        while fm != 0 {
            let c = fm.trailing_zeros() as usize;
            fm &= fm - 1;
            let ic = if first >> c & 1 != 0 {
                ia
            } else {
                first_group::<L, FR>(&lv, ia, child_box(n, c), depth + 1, ctr)
            };
            if ic < ng {
                insert_by(&mut kids, k, (ts[c], c, ic), |e| e.0);
                k += 1;
            }
        }
        // Far children on the stack, the nearest visited now.
        for &(t, c, ic) in kids[..k].iter().rev() {
            st_w[sp] = w as u32;
            st_c[sp] = c as u8;
            st_ia[sp] = ic as u16;
            st_t[sp] = t;
            st_d[sp] = (depth + 1) as u8;
            sp += 1;
        }
    }
}

/// Occlusion packets with at most this many live lanes left finish them one
/// by one (`finish_alone`). Measured (AVX-512, 16x16 shadow packets;
/// docs/studies/bvh-traversal.md, "Tried and dropped"): 0 to 16
/// lanes trace alike on sponza and conference, 64 lanes is 4 % slower; the
/// frustum walk's leaves already test only the groups with an entering
/// lane.
const HYBRID_LANES: u32 = 4;

/// Stack entries of the single ray walking one pending subtree: at most
/// `WIDTH - 1` per wide level below it and `WIDTH` at the last, so it
/// never overflows.
const ALONE_STACK: usize = (WIDTH - 1) * MAX_DEPTH + 1;

/// The hybrid finish (Benthin, Wald, Woop, Ernst, Mark 2012, section 4):
/// each live lane walks the `pending` subtrees (child reference and depth,
/// in the packet's pop order) alone with the wide single ray, and stops at
/// its first hit. The pending subtrees hold every leaf a live lane may
/// still enter (the packet dropped only what no live lane enters), and
/// each lane runs its own slab tests there, so its answer is the single
/// ray's.
#[inline(always)]
fn finish_alone<L: Wide, T: TriangleTest>(
    lv: &mut Leaves<'_, '_, L, T>,
    pending: impl Iterator<Item = (u32, u32, usize)> + Clone,
    ctr: &mut Counters,
) {
    let mut st = Stack::<ALONE_STACK>::new();
    for g in 0..lv.gb.len() {
        let mut bits = lv.gb[g].live;
        while bits != 0 {
            let i = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let ray = lv.rays[g * L::G + i / 4].lane(i % 4);
            let r = WideRay::<T>::new(&ray);
            let mut best = Hit::MISS;
            for start in pending.clone() {
                let done =
                    walk_from::<T, true, ALONE_STACK>(lv.b, &r, start, &mut best, &mut st, ctr);
                // The stack holds every subtree: never `None`.
                debug_assert!(done.is_some());
                if done != Some(false) {
                    break;
                }
            }
            if best.prim != INVALID_ID {
                let gh = &mut lv.gh[g];
                gh.t.set(i, best.t);
                gh.u.set(i, best.u);
                gh.v.set(i, best.v);
                gh.prim.set(i, f32::from_bits(best.prim));
            }
        }
        lv.gb[g].live = 0;
    }
    lv.n_live = 0;
}

/// Slots of `n` that hold a child.
#[inline(always)]
fn valid_children(n: &WideNode) -> u32 {
    let mut m = 0;
    for c in 0..WIDTH {
        m |= u32::from(n.child[c] != WideNode::EMPTY) << c;
    }
    m
}

/// The first group with a live lane.
fn first_group_live<L: Wide>(gb: &[GroupBox<L>]) -> usize {
    gb.iter().position(|g| g.live != 0).unwrap_or(gb.len())
}

/// Leaf child `c` of wide node `w`: every group from `ia` on with a live
/// lane entering its box tests its triangles with those lanes. Whether
/// every lane is done (occlusion), and whether the frustum may shrink: a
/// lane took a hit (nearest hits), a group has no live lane left
/// (occlusion).
#[inline(always)]
fn leaf<L: Wide, T: TriangleTest, const ANY: bool, const FR: bool>(
    lv: &mut Leaves<'_, '_, L, T>,
    (w, c, ia): (usize, usize, usize),
    depth: usize,
    ctr: &mut Counters,
) -> (bool, bool) {
    let n = &lv.b.wide[w];
    let mut shrank = false;
    let bx = child_box(n, c);
    let tris = (n.child[c] as usize, n.count[c] as usize);
    if !FR {
        // Plain range loop (no chunk bookkeeping) for packets without frusta.
        for g in ia..lv.gb.len() {
            match leaf_group::<L, T, ANY>(lv, g, tris, bx, depth, ctr) {
                None => return (true, true),
                Some(s) => shrank |= s,
            }
        }
        return (false, shrank);
    }
    let w = L::WIDTH;
    for ch in ia / w..lv.gf.len() {
        let mut adm = admitted::<L>(lv, ch, ia, bx);
        while adm != 0 {
            let g = ch * w + adm.trailing_zeros() as usize;
            adm &= adm - 1;
            match leaf_group::<L, T, ANY>(lv, g, tris, bx, depth, ctr) {
                None => return (true, true),
                Some(false) => {}
                Some(true) => {
                    shrank = true;
                    // The group's far ends fell (nearest hits), or its
                    // last live lane is done (occlusion): its frustum
                    // bounds less.
                    let tfar = if ANY {
                        f32::NEG_INFINITY
                    } else {
                        lv.gb[g].tfar.lane_max()
                    };
                    lv.gf[ch].set_tfar(g % w, tfar);
                }
            }
        }
    }
    (false, shrank)
}

/// Group `g`'s visit of a leaf (its triangles `first .. first + count`,
/// its box `bx`): its live lanes entering the box test the triangles.
/// `None` when every lane of the packet is done (occlusion), else whether
/// the group's far ends fell (nearest hits) or it has no live lane left
/// (occlusion).
#[inline(always)]
fn leaf_group<L: Wide, T: TriangleTest, const ANY: bool>(
    lv: &mut Leaves<'_, '_, L, T>,
    g: usize,
    (first, count): (usize, usize),
    bx: ([f32; 3], [f32; 3]),
    depth: usize,
    ctr: &mut Counters,
) -> Option<bool> {
    let b = lv.b;
    let gb = &mut lv.gb[g];
    if gb.live == 0 {
        return Some(false);
    }
    ctr.aabb_at(depth, 1);
    let mut bits = gb.enters(bx.0, bx.1);
    if bits == 0 {
        // The group's lanes skip the leaf's triangles.
        count!(ctr.culled += count as u64);
        return Some(false);
    }
    let gh = &mut lv.gh[g];
    let mut took = false;
    for j in first..first + count {
        ctr.tri_at(depth, bits.count_ones() as u64);
        let (h, hb) = group::test(&lv.grp[g], T::prim(b.store(), j), bits, b.cull);
        if hb == 0 {
            continue;
        }
        let id = b.tri_ids[j];
        // A hit lies in [tmin, tmax): for occlusion every hit lane is
        // done, else the lanes it beats keep it (tie rule).
        let mut take = if ANY { hb } else { gh.closer(h.t, hb, id) };
        if take != 0 && b.filter.on() {
            let r = &lv.grp[g].r;
            take = b.filter.bits(take, id, |k, i| {
                let (org, dir) = group::quad_ray(r, k);
                let lane = |x: [F4; 3]| [x[0][i], x[1][i], x[2][i]];
                let hit = (h.t.quad(k)[i], h.u.quad(k)[i], h.v.quad(k)[i]);
                (lane(org), lane(dir), hit)
            });
        }
        if take == 0 {
            continue;
        }
        gh.keep(&h, take, id);
        gb.tfar = L::select(L::mask_from_bits(take), h.t, gb.tfar);
        took = true;
        if ANY {
            gb.live &= !take;
            lv.n_live -= take.count_ones();
            if lv.n_live == 0 {
                return None;
            }
            bits &= !take;
            if bits == 0 {
                break;
            }
        }
    }
    Some(took && (!ANY || gb.live == 0))
}

#[cfg(test)]
mod tests {
    use super::FrustumFirst;
    use crate::accel::bvh::packet::{PacketIn, TestWalk};
    use crate::accel::bvh::{BvhView, TriangleTest};
    use crate::accel::entry::EntryPoint;
    use crate::accel::method::TraceParams;
    use crate::accel::slot::Slot;
    use crate::counters::Counters;
    use crate::geom::Wide;

    /// The frustum-first walk as the shared walk checks drive it.
    struct Frustum;

    impl TestWalk for Frustum {
        fn packet<L: Wide, T: TriangleTest, const ANY: bool>(
            b: &BvhView<'_>,
            opt: &TraceParams,
            pk: PacketIn<'_>,
            entry: Option<&EntryPoint>,
            slot: &mut Slot<'_>,
            ctr: &mut Counters,
        ) {
            FrustumFirst::<T, ANY>::from::<L>(b, opt, pk, entry, slot, ctr)
        }
    }

    crate::accel::bvh::traverse_masked::tests::walk_matches_single!(Frustum);

    /// Rays along -z whose x and y direction components are +0.0, -0.0 or
    /// both within one packet (reciprocals +inf and -inf, 0 x inf products
    /// in the frusta, axes left out for mixed signs), every fourth one
    /// starting on the lattice's box planes, at every packet size (128
    /// rays and more have group frusta): bitwise the single ray.
    #[test]
    fn frustum_axis_aligned_rays() {
        use crate::accel::bvh::RayKind;
        use crate::accel::bvh::build::testutil::Store;
        use crate::accel::bvh::traverse_masked::tests::check_sets;
        use crate::accel::testkit::{RaySet, built, lattice};
        use crate::geom::{Mt, Ray, Wt};
        use glam::Vec3;
        let (v, ix, _) = lattice();
        let (w, h) = (64u32, 64u32);
        let mut sets = Vec::new();
        for (name, zero) in [
            ("axis-pos-zero", 0),
            ("axis-mixed-zero", 1),
            ("axis-neg-zero", 2),
        ] {
            let mut rays = Vec::new();
            for y in 0..h {
                for x in 0..w {
                    let off = if x % 4 == 0 { 0.0 } else { 0.25 };
                    let o = Vec3::new(x as f32 * 0.5 + off, y as f32 * 0.5, 10.0);
                    let s = match zero {
                        0 => 0.0,
                        2 => -0.0,
                        _ if (x / 8 + y / 8) % 2 == 0 => 0.0,
                        _ => -0.0,
                    };
                    let d = Vec3::new(s, s, -1.0);
                    rays.push(Some(Ray::new(o, d, 0.0, f32::INFINITY)));
                }
            }
            sets.push(RaySet {
                name,
                w,
                h,
                rays,
                kinds: &[RayKind::Auto],
            });
        }
        for leaf in [1, 4] {
            let mut st = Store::new(0, false);
            let bvh = built::<Mt>(&mut st, &v, &ix, leaf);
            check_sets::<Frustum, Mt>("axis", &bvh.view().unwrap(), &sets);
            let mut st = Store::new(0, false);
            let bvh = built::<Wt>(&mut st, &v, &ix, leaf);
            check_sets::<Frustum, Wt>("axis", &bvh.view().unwrap(), &sets);
        }
    }
}
