//! n x n ray packets through the kd-tree, driven by the packet's frustum,
//! from the root or from an entry point (the AEPSA paper's section 2 and
//! its "plain packet tracing"; Wald 2004's packet traversal widened to
//! `(n/2)^2` SIMD rays; Reshetov, Soupikov, Hurley 2005 for the frustum
//! and the entry point).
//!
//! A packet is `rays.len()` 2x2 quads (at most 256: 32 x 32 rays), every
//! lane with its own interval `[t0, t1]`. All traced lanes share their
//! direction signs, hence the near and far child of every split. At an
//! inner node the packet first culls the child boxes its frustum misses,
//! then one pass over the quads alive in the node narrows every lane's
//! interval by `split_interval` and tells whether some lane needs the near
//! child, the far child, or both; the packet goes near (pushing the far
//! child when needed) or far. At a leaf the triangles the frustum does not
//! cull are tested against the lanes inside the leaf, and a lane is done
//! once its nearest hit lies at or before the end of its leaf interval.
//!
//! # Exactness
//! Lane by lane this is the single ray's traversal (`mod.rs`, Exactness):
//! the same intervals, hence the same leaves in the same order and the
//! same stop. A pushed far child keeps no intervals: when it is popped,
//! every lane's interval is recomputed by the slab test of the child's box
//! (`clip4`), which equals the interval the descent would have given. The
//! traversal starts at an entry point with the slab test of its box, which
//! equals the single ray's interval there; the entry is valid when its
//! subtree holds every leaf with a triangle the frustum does not cull, as
//! the rays' hits are on such triangles. Culled boxes lie beyond a frustum
//! plane by more than the rounding of any ray's slab test, and culled
//! triangles are hit by no ray, so culling removes nothing a lane would
//! have visited or hit. For the same reason, when one child of a node is
//! culled, every lane's split `t_s` lies beyond its interval there, and
//! the other child is entered with the intervals unchanged (what
//! `split_interval` gives) without per-quad work.
//!
//! # Memory
//! Scratch from the thread slot (`SCRATCH` bytes), sized by the packet's
//! class (1, 4, 16, 64 or 256 quads, as the BVH packets; a power of two,
//! so quad indices masked with `Q - 1` need no bounds checks): per quad
//! the reciprocal directions, the triangle test's precomputation, the live
//! lanes and the current interval; a stack of `MAX_DEPTH + 1` entries
//! `(node, depth, box, quads)` (64 bytes each), where `quads` marks the
//! quads with some lane in the far child when it was pushed (the only ones
//! to recompute when it is popped). No allocation, no recursion.
//!
//! # Deviations
//! - Lanes whose direction sign bits differ from the packet's first live
//!   lane on some axis (`Counters::stray_lanes`) are traced one by one with
//!   `traverse_single::from_node` from the packet's start node and box.
//! - Lanes with tiny directions (`accel::fallback::tiny`) never reach this
//!   traversal: the trace call (`trace::scene::Tracing`, with
//!   `accel::packet::quieted`) traces them with
//!   `traverse_single` and the packet on quads where they are replaced
//!   (their subnormal arithmetic slows every quad holding one).
//! - After the stray lanes, a packet failing `accel::fallback::coherent`
//!   (directions over more than a 30 degree cone, or origins over a quarter
//!   of the scene) is traced lane by lane the same way (the AEPSA paper's
//!   system traces incoherent packets with another algorithm, section 5.1,
//!   Reshetov 2006's omni-directional traversal; here the single ray).
//! - Inputs longer than 256 quads are traced as consecutive packets of 256
//!   with the same frustum and entry point (both stay valid for a subset).
//! - An entry point whose node lies outside the tree is ignored (the
//!   packet starts at the root).
//! - Leaves with fewer than `CORNER_TEST_QUADS` quads inside cull their
//!   triangles by the frustum's four planes only, without the corner-ray
//!   test of `Frustum::cull_triangle` (NOTE(perf) in `walk`'s leaf loop).
//!
//! # Counters
//! `rays` (valid active lanes), `packets` (per packet of at most 256
//! quads), `stray_lanes`, `aabb_at` one per quad and split step (steps
//! past a culled sibling and the slab tests of popped boxes are not
//! counted), `tri_at` the live lanes of each quad-triangle test,
//! `culled_nodes` / `culled` for frustum rejections.

use super::traverse_simd::{clip4, lane_from, lane_signs, stray_bits, valid4};
use super::{KdView, MAX_DEPTH, TriangleTest};
use crate::accel::entry::{EntryPoint, EntrySearch};
use crate::accel::fallback;
use crate::accel::group;
use crate::accel::packet::{self, PacketArgs, PacketSig, Start};
use crate::accel::slot::Slot;
use crate::counters::{Counters, count};
use crate::geom::frustum::Frustum;
use crate::geom::lane::mask_from_bits;
use crate::geom::{Aabb, F4, Hit, Hit4, M4, Ray4, Wide};
use crate::isa;
use crate::mem::scratch::bytes;
use core::marker::PhantomData;

/// Most quads traced as one packet (32 x 32 rays), for every family.
pub use crate::accel::packet::MAX_QUADS;

/// Slot scratch a packet of up to `q` quads takes: per quad the live
/// lanes, origins and reciprocal directions (3 each), tmin, tmax, the
/// interval (2), the split's t_s, the active list, the leaf's lanes, the
/// quads' lane groups with the triangle test's precomputation
/// (`accel::group`, the largest kind and width); and the stack.
pub const fn scratch(q: usize) -> usize {
    2 * bytes::<M4>(q)
        + 11 * bytes::<F4>(q)
        + bytes::<u16>(q)
        + group::max_bytes(q)
        + bytes::<Entry>(MAX_DEPTH + 1)
}

/// `Q` values, each `fill`, from the slot's scratch as an array (indices
/// masked with `Q - 1` need no bounds check), and the rest of the slot.
#[inline(always)]
fn carve<'s, T: Copy, const Q: usize>(
    slot: &'s mut Slot<'_>,
    fill: T,
) -> (&'s mut [T; Q], Slot<'s>) {
    let (v, rest) = slot.split(Q, fill);
    (v.try_into().expect("split returns Q values"), rest)
}

/// Quads in a leaf from which triangles are culled with the full
/// `Frustum::cull_triangle` (planes and corner rays); fewer: the planes
/// only (`Frustum::cull_triangle_planes`).
const CORNER_TEST_QUADS: usize = 8;

/// One packet as the traversal takes it: its quads, their active lanes,
/// and where its answers go: nearest hits, or with `ANY` occlusion masks
/// (the other one empty).
struct Packet<'p> {
    rays: &'p [Ray4],
    active: &'p [M4],
    hits: &'p mut [Hit4],
    occ: &'p mut [M4],
}

impl<'p> Packet<'p> {
    /// Nearest hits of the active lanes of `rays` into `hits`, the three
    /// read up to the shortest length.
    fn nearest(rays: &'p [Ray4], active: &'p [M4], hits: &'p mut [Hit4]) -> Self {
        let n = rays.len().min(active.len()).min(hits.len());
        Packet {
            rays: &rays[..n],
            active: &active[..n],
            hits: &mut hits[..n],
            occ: &mut [],
        }
    }
    /// Occlusion of the active lanes of `rays` into `occ`, the three read
    /// up to the shortest length.
    fn occlusion(rays: &'p [Ray4], active: &'p [M4], occ: &'p mut [M4]) -> Self {
        let n = rays.len().min(active.len()).min(occ.len());
        Packet {
            rays: &rays[..n],
            active: &active[..n],
            hits: &mut [],
            occ: &mut occ[..n],
        }
    }
    /// The same packet, borrowed again.
    #[inline(always)]
    fn reborrow(&mut self) -> Packet<'_> {
        Packet {
            rays: self.rays,
            active: self.active,
            hits: &mut *self.hits,
            occ: &mut *self.occ,
        }
    }
}

/// What guides a packet through the tree besides its rays: the frustum
/// bounding every active valid ray (culling; `None`: none), an entry point
/// whose subtree holds every leaf with a triangle that frustum does not
/// cull (`None`: the root; see the module docs) and
/// `TraceParams::fallbacks`.
#[derive(Clone, Copy)]
struct Guides<'g> {
    frustum: Option<&'g Frustum>,
    entry: Option<&'g EntryPoint>,
    fallbacks: bool,
}

/// `pk`'s answers (`ANY`: occlusion, anything in `[tmin, tmax)`): active
/// lanes are written (`Hit::MISS` when nothing is hit, and for invalid
/// rays, see `Ray::is_valid`; an occlusion mask lane set when active and
/// occluded, cleared otherwise); inactive lanes of hits are left untouched.
/// Guided by `g`, at the lane width of `isa`; the slot lends the scratch
/// (`SCRATCH` bytes). For the unit tests, which drive the walk with a given
/// frustum and entry point; a trace call runs `Packets` through its kernel.
#[cfg(test)]
fn traced<T: TriangleTest, const ANY: bool>(
    k: &KdView<'_>,
    pk: Packet<'_>,
    g: Guides<'_>,
    isa: isa::Isa,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let n = pk.rays.len();
    let args = (k, pk, g, slot.reborrow(), ctr);
    with_class!(n, |Q| isa::run_fn::<Sig, At<T, ANY, Q>>(isa, args))
}

/// `dispatch`'s arguments, one tuple (`isa::Sig`), for `traced`.
#[cfg(test)]
struct Sig;

#[cfg(test)]
impl isa::Sig for Sig {
    type Args<'a> = (
        &'a KdView<'a>,
        Packet<'a>,
        Guides<'a>,
        Slot<'a>,
        &'a mut Counters,
    );
    type Out = ();
}

/// `dispatch` at a lane width and size class (`traced`).
#[cfg(test)]
struct At<T, const ANY: bool, const Q: usize>(PhantomData<T>);

#[cfg(test)]
impl<T: TriangleTest, const ANY: bool, const Q: usize> isa::LaneFn<Sig> for At<T, ANY, Q> {
    #[inline(always)]
    fn call<L: Wide>(args: <Sig as isa::Sig>::Args<'_>) {
        let (k, pk, g, mut slot, ctr) = args;
        dispatch::<L, T, ANY, Q>(k, pk, g, &mut slot, ctr)
    }
}

/// `Method::KdPacket` on the packet contract (`accel::packet::PacketSig`)
/// at a lane width, for packets of size class `Q` (`class`): the packet's
/// frustum (when culling is on) and entry point (`TraceParams::entry`,
/// `accel::packet::start`), then `dispatch`. Its `Kernel` is chosen once
/// per call (`KdView::kernel`, the class of `TraceParams::packet`).
pub struct Packets<T, const ANY: bool, const Q: usize>(PhantomData<T>);

impl<'k, T: TriangleTest, const ANY: bool, const Q: usize> isa::LaneFn<PacketSig<KdView<'k>>>
    for Packets<T, ANY, Q>
{
    #[inline(always)]
    fn call<L: Wide>(args: PacketArgs<'_, KdView<'k>>) {
        let (k, p, rays, active, hits, mut slot, ctr) = args;
        // The frustum only when culling is on.
        let (f, start) = if !p.bvh.culling && p.entry == EntrySearch::None {
            (None, Start::Root)
        } else {
            let (f, s) = packet::start(k, p, rays, active, &k.info.root, &mut slot, ctr);
            (if p.bvh.culling { f } else { None }, s)
        };
        let e = match start {
            // Every ray misses: for occlusion too, a miss is `Hit::MISS`.
            Start::Miss => return packet::all_miss(active, hits, ctr),
            Start::Root => None,
            Start::At(e) => Some(e),
        };
        let g = Guides {
            frustum: f.as_ref(),
            entry: e.as_ref(),
            fallbacks: p.fallbacks,
        };
        if ANY {
            let n = rays.len().min(active.len()).min(hits.len()).min(MAX_QUADS);
            let (occ, mut slot) = slot.split(n, M4::FALSE);
            let pk = Packet::occlusion(rays, active, occ);
            dispatch::<L, T, true, Q>(k, pk, g, &mut slot, ctr);
            packet::mark_occluded(occ, &active[..n], &mut hits[..n]);
        } else {
            let pk = Packet::nearest(rays, active, hits);
            dispatch::<L, T, false, Q>(k, pk, g, &mut slot, ctr);
        }
    }
}

/// The size class of a packet of `nq` quads: 1, 4, 16, 64 or 256
/// (`MAX_QUADS`) quads, the smallest holding it. A packet's per-quad
/// arrays are fixed-size arrays of its class (indices masked with `Q - 1`
/// need no bounds check).
pub(crate) const fn class(nq: usize) -> usize {
    match nq {
        0 | 1 => 1,
        2..=4 => 4,
        5..=16 => 16,
        17..=64 => 64,
        _ => MAX_QUADS,
    }
}

/// `$body` with `const $Q` the size class of `$nq` quads (`class`): the
/// one place a class becomes a type.
macro_rules! with_class {
    ($nq:expr, |$Q:ident| $body:expr) => {
        match $crate::accel::kd::traverse_packet::class($nq) {
            1 => {
                const $Q: usize = 1;
                $body
            }
            4 => {
                const $Q: usize = 4;
                $body
            }
            16 => {
                const $Q: usize = 16;
                $body
            }
            64 => {
                const $Q: usize = 64;
                $body
            }
            _ => {
                const $Q: usize = $crate::accel::packet::MAX_QUADS;
                $body
            }
        }
    };
}
pub(crate) use with_class;

/// Consecutive packets of at most `Q` quads (a size class, `class`) on
/// `L` lanes: `pk` cut into packets.
#[inline(always)]
fn dispatch<L: Wide, T: TriangleTest, const ANY: bool, const Q: usize>(
    k: &KdView<'_>,
    pk: Packet<'_>,
    g: Guides<'_>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let n = pk.rays.len();
    let mut s = 0;
    while s < n {
        let e = (s + Q).min(n);
        let (h, o) = if ANY {
            (&mut [][..], &mut pk.occ[s..e])
        } else {
            (&mut pk.hits[s..e], &mut [][..])
        };
        let part = Packet {
            rays: &pk.rays[s..e],
            active: &pk.active[s..e],
            hits: h,
            occ: o,
        };
        packet::<L, T, ANY, Q>(k, part, g, slot, ctr);
        s = e;
    }
}

/// A pushed far child: its node, depth and box, and the quads with some
/// lane inside it when it was pushed (bit `q`).
#[derive(Clone, Copy)]
struct Entry {
    node: u32,
    depth: u32,
    bx: Aabb,
    quads: [u64; MAX_QUADS / 64],
}

/// One packet of `pk.rays.len() <= Q` quads (`Q` a power of two) on `L`
/// lanes: its setup (`set_up`, in baseline code: it has no wide lanes),
/// then the walk.
#[inline(always)]
fn packet<L: Wide, T: TriangleTest, const ANY: bool, const Q: usize>(
    k: &KdView<'_>,
    mut pk: Packet<'_>,
    g: Guides<'_>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    // Outputs of the active lanes, and the live ones: active and valid.
    let (live, mut slot) = carve::<M4, Q>(slot, M4::FALSE);
    let Some(ready) = set_up::<T, ANY, Q>(k, pk.reborrow(), g, live, ctr) else {
        return;
    };
    walk::<L, T, ANY, Q>(k, pk, g.frustum, ready, &mut slot, ctr)
}

/// A packet ready to walk (`set_up`'s answer): its live lanes and their
/// count, the near side of every split (`neg`: the first live lane's
/// direction signs), and where the walk starts: node, depth and box.
struct Ready<'l, const Q: usize> {
    live: &'l mut [M4; Q],
    n_live: u32,
    neg: [bool; 3],
    node: usize,
    depth: usize,
    bx: Aabb,
}

/// A packet's setup: its active lanes' outputs written (misses), its live
/// lanes (active and valid) into `live`, where it starts (`g.entry` or
/// the root, culled by `g.frustum`), its stray lanes (`lane_signs`) and,
/// when incoherent, all its lanes traced alone. The walk's lanes and
/// start, or `None` when nothing is left to walk.
#[inline(never)]
fn set_up<'l, T: TriangleTest, const ANY: bool, const Q: usize>(
    k: &KdView<'_>,
    pk: Packet<'_>,
    g: Guides<'_>,
    live: &'l mut [M4; Q],
    ctr: &mut Counters,
) -> Option<Ready<'l, Q>> {
    let Packet {
        rays,
        active,
        hits,
        occ,
    } = pk;
    let nq = rays.len().min(Q);
    ctr.packets += 1;
    let mut n_live = 0u32;
    for q in 0..nq {
        let m = active[q];
        if ANY {
            occ[q] = M4::FALSE;
        } else if m.any() {
            hits[q].miss(m);
        }
        let l = m & valid4(&rays[q]);
        live[q] = l;
        n_live += l.bitmask().count_ones();
    }
    ctr.rays += n_live as u64;
    if n_live == 0 || k.nodes.is_empty() || k.info.triangles == 0 {
        return None;
    }
    let (node0, depth0, bx0) = match g.entry {
        Some(e) if (e.node as usize) < k.nodes.len() => (e.node as usize, e.depth as usize, e.aabb),
        _ => (0, 0, k.info.root),
    };
    if let Some(f) = g.frustum
        && f.cull_box(&bx0.min.to_array(), &bx0.max.to_array())
    {
        count!(ctr.culled_nodes += 1);
        return None;
    }
    // Near sides from the first live lane; lanes going another way alone.
    let q0 = live[..nq].iter().position(|m| m.any()).unwrap_or(0);
    let neg = lane_signs(&rays[q0], live[q0].bitmask().trailing_zeros() as usize);
    // A lane traced alone from the start: its answer into the output.
    let mut alone = |q: usize, i: usize, ctr: &mut Counters| {
        let h: Hit = lane_from::<T, ANY>(k, &rays[q], i, node0, depth0, &bx0, ctr);
        if ANY {
            occ[q].set(i, h.is_hit());
        } else {
            hits[q].set_lane(i, h);
        }
    };
    for q in 0..nq {
        let s = stray_bits(&rays[q], neg) & live[q].bitmask();
        if s == 0 {
            continue;
        }
        ctr.stray_lanes += s.count_ones() as u64;
        for i in 0..4 {
            if s & (1 << i) != 0 {
                alone(q, i, ctr);
            }
        }
        live[q] &= !mask_from_bits(s);
        n_live -= s.count_ones();
    }
    if n_live == 0 {
        return None;
    }
    // Incoherent packets (`trace::fallback`): every lane still live (all
    // with the first lane's direction signs) alone.
    if !fallback::coherent(
        g.fallbacks,
        rays,
        &live[..nq],
        k.info.bounds.diagonal().length(),
    ) {
        fallback::each_lane(&live[..nq], |q, i| alone(q, i, ctr));
        return None;
    }
    Some(Ready {
        live,
        n_live,
        neg,
        node: node0,
        depth: depth0,
        bx: bx0,
    })
}

#[inline(always)]
fn walk<L: Wide, T: TriangleTest, const ANY: bool, const Q: usize>(
    k: &KdView<'_>,
    pk: Packet<'_>,
    frustum: Option<&Frustum>,
    ready: Ready<'_, Q>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let Packet {
        rays, hits, occ, ..
    } = pk;
    let Ready {
        live,
        mut n_live,
        neg,
        mut node,
        mut depth,
        mut bx,
    } = ready;
    let nq = rays.len().min(Q);
    // Per-quad constants from the slot's scratch; past nq they stay as
    // filled (never read: only quads below nq enter `act`).
    let z = F4::ZERO;
    let (ox, mut slot) = carve::<F4, Q>(slot, z);
    let (oy, mut slot) = carve::<F4, Q>(&mut slot, z);
    let (oz, mut slot) = carve::<F4, Q>(&mut slot, z);
    let (rx, mut slot) = carve::<F4, Q>(&mut slot, z);
    let (ry, mut slot) = carve::<F4, Q>(&mut slot, z);
    let (rz, mut slot) = carve::<F4, Q>(&mut slot, z);
    let (tmin, mut slot) = carve::<F4, Q>(&mut slot, z);
    let (tmax, mut slot) = carve::<F4, Q>(&mut slot, z);
    for (q, r) in rays[..nq].iter().enumerate() {
        (ox[q], oy[q], oz[q]) = (r.org[0], r.org[1], r.org[2]);
        rx[q] = F4::ONE / r.dir[0];
        ry[q] = F4::ONE / r.dir[1];
        rz[q] = F4::ONE / r.dir[2];
        (tmin[q], tmax[q]) = (r.tmin, r.tmax);
    }
    let (org, rcp) = ([&*ox, &*oy, &*oz], [&*rx, &*ry, &*rz]);
    let (tmin, tmax) = (&*tmin, &*tmax);
    // The quads in groups of the lane width, with the triangle test's
    // per-ray precomputation (`accel::group`).
    let (grp, mut slot) = group::join::<L, T>(&rays[..nq], &mut slot);
    // Current intervals (valid for the quads in `act`).
    let (t0, mut slot) = carve::<F4, Q>(&mut slot, z);
    let (t1, mut slot) = carve::<F4, Q>(&mut slot, z);
    // Quads with a live lane inside the current node, and per entry of
    // `act` the split's t_s (inner node) or the lanes inside (leaf).
    let (act, mut slot) = carve::<u16, Q>(&mut slot, 0);
    let (tsb, mut slot) = carve::<F4, Q>(&mut slot, z);
    let (lm, mut slot) = carve::<M4, Q>(&mut slot, M4::FALSE);
    let slab = |q: usize, bx: &Aabb| {
        clip4(
            &bx.min.to_array(),
            &bx.max.to_array(),
            &[org[0][q], org[1][q], org[2][q]],
            &[rcp[0][q], rcp[1][q], rcp[2][q]],
            neg,
            tmin[q],
            tmax[q],
        )
    };
    let mut na = 0usize;
    for q in 0..nq {
        if live[q].any() {
            let (a0, a1) = slab(q, &bx);
            if (live[q] & a0.cmple(a1)).any() {
                (t0[q], t1[q]) = (a0, a1);
                act[na] = q as u16;
                na += 1;
            }
        }
    }
    if na == 0 {
        return;
    }
    let nodes = k.nodes;
    let empty = Entry {
        node: 0,
        depth: 0,
        bx: Aabb::EMPTY,
        quads: [0; MAX_QUADS / 64],
    };
    let (st, _) = carve::<Entry, { MAX_DEPTH + 1 }>(&mut slot, empty);
    let mut sp = 0usize;
    let words = Q.div_ceil(64);
    loop {
        let n = &nodes[node];
        if !n.is_leaf() {
            let a = n.axis();
            let l = n.left();
            let (lb, rb) = KdView::child_boxes(n, &bx);
            let (near, far, nb, fb) = if neg[a] {
                (l + 1, l, rb, lb)
            } else {
                (l, l + 1, lb, rb)
            };
            // frustumIntersectsAABB on both children first: a culled
            // child needs no interval work.
            let (mut use_near, mut use_far) = (true, true);
            if let Some(f) = frustum {
                if f.cull_box(&nb.min.to_array(), &nb.max.to_array()) {
                    count!(ctr.culled_nodes += 1);
                    use_near = false;
                }
                if f.cull_box(&fb.min.to_array(), &fb.max.to_array()) {
                    count!(ctr.culled_nodes += 1);
                    use_far = false;
                }
            }
            depth += 1;
            if use_near != use_far {
                // One child culled: no lane passes within the margin of
                // it, so every lane's split t_s lies beyond its interval
                // (near: t_s >= t1, far: t_s <= t0) and `split_interval`
                // leaves the intervals as they are. No per-quad work.
                (node, bx) = if use_near { (near, nb) } else { (far, fb) };
                continue;
            }
            if use_near {
                ctr.aabb_at(depth - 1, na as u64);
                let s = F4::splat(n.split());
                let (oa, ra) = (&org[a], &rcp[a]);
                let mut need_near = M4::FALSE;
                let mut need_far = M4::FALSE;
                // Live lanes whose near / far interval is shorter than the
                // node's (none: the child keeps the intervals as they are).
                let mut cut_near = M4::FALSE;
                let mut cut_far = M4::FALSE;
                let mut far_q = [0u64; MAX_QUADS / 64];
                for (i, &qi) in act[..na].iter().enumerate() {
                    let q = qi as usize & (Q - 1);
                    // `split_interval`, lane by lane (NaN t_s: no change).
                    let ts = (s - oa[q]) * ra[q];
                    tsb[i] = ts;
                    let (a0, a1, lv) = (t0[q], t1[q], live[q]);
                    let (lt, gt) = (ts.cmplt(a1), ts.cmpgt(a0));
                    let near_hi = F4::select(lt, ts, a1);
                    let far_lo = F4::select(gt, ts, a0);
                    need_near |= lv & a0.cmple(near_hi);
                    let nf = lv & far_lo.cmple(a1);
                    need_far |= nf;
                    cut_near |= lv & lt;
                    cut_far |= lv & gt;
                    far_q[(q >> 6) & (MAX_QUADS / 64 - 1)] |= (nf.any() as u64) << (q & 63);
                }
                let go_near = need_near.any();
                let go_far = need_far.any();
                if go_near {
                    if go_far {
                        st[sp] = Entry {
                            node: far as u32,
                            depth: depth as u32,
                            bx: fb,
                            quads: far_q,
                        };
                        sp += 1;
                    }
                    node = near;
                    bx = nb;
                    if cut_near.any() {
                        na = enter_child::<true, Q>(act, na, tsb, t0, t1, live);
                    }
                    continue;
                }
                if go_far {
                    node = far;
                    bx = fb;
                    if cut_far.any() {
                        na = enter_child::<false, Q>(act, na, tsb, t0, t1, live);
                    }
                    continue;
                }
            }
        } else {
            // The lanes inside this leaf; the others never visit it.
            for (m, &qi) in lm[..na].iter_mut().zip(&act[..na]) {
                let q = qi as usize & (Q - 1);
                *m = live[q] & t0[q].cmple(t1[q]);
            }
            for &s in k.leaf_refs(n) {
                let s = s as usize;
                if let Some(f) = frustum {
                    // NOTE(perf): the corner-ray part of `cull_triangle`
                    // (f64) costs more than the 4-wide tests it saves
                    // unless many quads are in the leaf: below
                    // `CORNER_TEST_QUADS` only the four planes cull
                    // (balls, 512 x 512 camera rays: 4 x 4 packets 5.0 ->
                    // 5.7 Mrays/s, 16 x 16 6.7 -> 7.2; `packet_speed`).
                    let culled = if na >= CORNER_TEST_QUADS {
                        f.cull_triangle(&k.tris[s])
                    } else {
                        f.cull_triangle_planes(&k.tris[s])
                    };
                    if culled {
                        count!(ctr.culled += 1);
                        continue;
                    }
                }
                let prim = T::prim(k.store(), s);
                let id = k.tri_ids[s];
                // The quads in `act` (ascending) by lane group.
                let mut i = 0;
                while i < na {
                    let (i0, gi) = (i, act[i] as usize / L::G);
                    let mut bits = 0u32;
                    while i < na && act[i] as usize / L::G == gi {
                        bits |= lm[i].bitmask() << (4 * (act[i] as usize % L::G));
                        i += 1;
                    }
                    if bits == 0 {
                        continue;
                    }
                    ctr.tri_at(depth, bits.count_ones() as u64);
                    let (h, hb) = group::test(&grp[gi], prim, bits, crate::geom::Cull::None);
                    group::each_hit(&h, hb, |kq, hm, hit| {
                        let q = (gi * L::G + kq) & (Q - 1);
                        let ray = || group::quad_ray(&grp[gi].r, kq);
                        if ANY {
                            let hm = k.filter.quad_with(hm, hit, id, ray);
                            if !hm.any() {
                                return;
                            }
                            // Occlusion: a lane with a hit is done.
                            occ[q] |= hm;
                            live[q] &= !hm;
                            n_live -= hm.bitmask().count_ones();
                            for j in i0..i {
                                if act[j] as usize == q {
                                    lm[j] &= !hm;
                                }
                            }
                        } else {
                            group::take::<false>(&mut hits[q], hm, hit, id, &k.filter, ray);
                        }
                    });
                    if ANY && n_live == 0 {
                        return;
                    }
                }
            }
            // Early termination, per lane: nothing beyond this leaf can be
            // nearer (the single ray's rule, a miss's t = inf included).
            for (m, &qi) in lm[..na].iter().zip(&act[..na]) {
                let q = qi as usize & (Q - 1);
                let bt = if ANY { F4::INFINITY } else { hits[q].t };
                let done = *m & bt.cmple(t1[q]);
                if done.any() {
                    live[q] &= !done;
                    n_live -= done.bitmask().count_ones();
                }
            }
            if n_live == 0 {
                return;
            }
        }
        // Pop the next far child some live lane still enters; its
        // intervals are the slab test of its box.
        loop {
            if sp == 0 {
                return;
            }
            sp -= 1;
            let e = &st[sp];
            na = 0;
            for (w, &bits) in e.quads[..words].iter().enumerate() {
                let mut b = bits;
                while b != 0 {
                    let q = (w * 64 + b.trailing_zeros() as usize) & (Q - 1);
                    b &= b - 1;
                    let lv = live[q];
                    if !lv.any() {
                        continue;
                    }
                    let (a0, a1) = slab(q, &e.bx);
                    if (lv & a0.cmple(a1)).any() {
                        (t0[q], t1[q]) = (a0, a1);
                        act[na] = q as u16;
                        na += 1;
                    }
                }
            }
            if na > 0 {
                (node, depth, bx) = (e.node as usize, e.depth as usize, e.bx);
                break;
            }
        }
    }
}

/// The intervals of the child `walk` enters, from the node's, for the
/// quads `act[..na]` with the split's t_s in `tsb` (by place in `act`):
/// the near child's `[t0, min(t1, t_s)]` (`NEAR`) or the far child's
/// `[max(t0, t_s), t1]` (`split_interval`, lane by lane). `act` keeps the
/// quads with a live lane inside; returns how many.
#[inline(always)]
fn enter_child<const NEAR: bool, const Q: usize>(
    act: &mut [u16; Q],
    na: usize,
    tsb: &[F4; Q],
    t0: &mut [F4; Q],
    t1: &mut [F4; Q],
    live: &[M4; Q],
) -> usize {
    let mut j = 0;
    for i in 0..na {
        let qi = act[i];
        let q = qi as usize & (Q - 1);
        let ts = tsb[i];
        let (lo, hi) = if NEAR {
            let a1 = t1[q];
            let near_hi = F4::select(ts.cmplt(a1), ts, a1);
            t1[q] = near_hi;
            (t0[q], near_hi)
        } else {
            let a0 = t0[q];
            let far_lo = F4::select(ts.cmpgt(a0), ts, a0);
            t0[q] = far_lo;
            (far_lo, t1[q])
        };
        act[j] = qi;
        j += (live[q] & lo.cmple(hi)).any() as usize;
    }
    j
}

/// Packet exactness: every packet side, frustum kind and start (root,
/// entry point) against `traverse_single`, lane by lane, bitwise.
#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::{BvhView, RayKind};
    use crate::accel::kd::traverse_simd::tests::{deep_rays, ties, with_trees};
    use crate::accel::kd::traverse_single::{self, tests::same};
    use crate::accel::method::TraceParams;
    use crate::accel::slot::SlotBuf;
    use crate::accel::testkit::{Packed, RaySet, lattice, packets, ray_sets};
    use crate::geom::INVALID_ID;
    use crate::geom::TriangleTest;
    use crate::geom::{Mt, Pt, Ray, Wt};
    use glam::Vec3;

    const SENTINEL: Hit = Hit {
        t: -7.0,
        prim: 0xdead,
        u: 3.0,
        v: 4.0,
    };

    /// Parent, depth, box and pre-order range of every node of a kd-tree,
    /// and the leaves holding each stored triangle.
    struct Tree {
        parent: Vec<usize>,
        depth: Vec<u32>,
        bx: Vec<Aabb>,
        /// Pre-order index of each node; its subtree is `pre..end`.
        pre: Vec<usize>,
        end: Vec<usize>,
        leaves_of: Vec<Vec<usize>>,
        deepest_leaf: usize,
    }

    fn tree(k: &KdView<'_>) -> Tree {
        let n = k.nodes.len();
        let mut t = Tree {
            parent: vec![usize::MAX; n],
            depth: vec![0; n],
            bx: vec![Aabb::EMPTY; n],
            pre: vec![0; n],
            end: vec![0; n],
            leaves_of: vec![Vec::new(); k.tris.len()],
            deepest_leaf: 0,
        };
        if n == 0 {
            return t;
        }
        t.bx[0] = k.info.root;
        let mut order = Vec::new();
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            t.pre[i] = order.len();
            order.push(i);
            let nd = k.nodes[i];
            if nd.is_leaf() {
                for &s in k.leaf_refs(&nd) {
                    t.leaves_of[s as usize].push(i);
                }
                if t.depth[i] > t.depth[t.deepest_leaf] || !k.nodes[t.deepest_leaf].is_leaf() {
                    t.deepest_leaf = i;
                }
            } else {
                let (lb, rb) = KdView::child_boxes(&nd, &t.bx[i]);
                for (c, b) in [(nd.left() + 1, rb), (nd.left(), lb)] {
                    t.parent[c] = i;
                    t.depth[c] = t.depth[i] + 1;
                    t.bx[c] = b;
                    stack.push(c);
                }
            }
        }
        for &i in order.iter().rev() {
            let nd = k.nodes[i];
            t.end[i] = if nd.is_leaf() {
                t.pre[i] + 1
            } else {
                t.end[nd.left()].max(t.end[nd.left() + 1])
            };
        }
        t
    }

    /// The deepest node whose subtree holds all the leaves given to `add`.
    struct Lca<'t> {
        t: &'t Tree,
        node: Option<usize>,
    }

    impl Lca<'_> {
        /// Add the leaves of stored triangle `s`; `false` once the answer
        /// is the root (nothing can change it).
        fn add(&mut self, s: usize) -> bool {
            let t = self.t;
            for &l in &t.leaves_of[s] {
                let mut n = self.node.unwrap_or(l);
                while !(t.pre[n] <= t.pre[l] && t.pre[l] < t.end[n]) {
                    n = t.parent[n];
                }
                self.node = Some(n);
            }
            self.node != Some(0)
        }
        /// The entry point (the deepest leaf when no leaf was added: every
        /// node is then valid).
        fn entry(&self) -> EntryPoint {
            let n = self.node.unwrap_or(self.t.deepest_leaf);
            EntryPoint {
                node: n as u32,
                depth: self.t.depth[n],
                aabb: self.t.bx[n],
            }
        }
    }

    /// The entry point of frustum `f` by brute force: the deepest node
    /// holding every leaf with a stored triangle `cull_triangle` keeps.
    fn entry_brute(k: &KdView<'_>, t: &Tree, f: &Frustum) -> EntryPoint {
        let mut lca = Lca { t, node: None };
        for s in 0..k.tris.len() {
            if !f.cull_triangle(&k.tris[s]) && !lca.add(s) {
                break;
            }
        }
        lca.entry()
    }

    /// `entry_brute`, faster: the BVH over the same mesh skips the
    /// triangles inside boxes `f` culls (all their vertices lie beyond one
    /// plane, so `cull_triangle` culls them too); the rest go through
    /// `cull_triangle`. `entry_helper_matches_brute_force` checks the two
    /// agree.
    fn entry_of(k: &KdView<'_>, t: &Tree, b: &BvhView<'_>, f: &Frustum) -> EntryPoint {
        let mut lca = Lca { t, node: None };
        let mut stack = if b.nodes.is_empty() { vec![] } else { vec![0] };
        while let Some(i) = stack.pop() {
            let n = &b.nodes[i];
            if f.cull_box(&n.min, &n.max) {
                continue;
            }
            let first = n.first as usize;
            if n.is_leaf() {
                for j in first..first + n.count() as usize {
                    let s = k.slot_of[b.tri_ids[j] as usize];
                    if s != INVALID_ID && !f.cull_triangle(&b.tris[j]) && !lca.add(s as usize) {
                        return lca.entry();
                    }
                }
            } else {
                stack.extend([first, first + 1]);
            }
        }
        lca.entry()
    }

    fn live_of(quads: &[Ray4], active: &[M4]) -> Vec<M4> {
        quads
            .iter()
            .zip(active)
            .map(|(r, m)| {
                let v = |i| m.test(i) && r.lane(i).is_valid();
                M4::new(v(0), v(1), v(2), v(3))
            })
            .collect()
    }

    /// The single ray's answers to an input, by quad and lane: the nearest
    /// hit and occlusion.
    struct Single<'s> {
        near: &'s dyn Fn(usize, usize) -> Hit,
        occl: &'s dyn Fn(usize, usize) -> bool,
    }

    /// `Guides` as a trace call with the default parameters has them.
    fn guides<'g>(frustum: Option<&'g Frustum>, entry: Option<&'g EntryPoint>) -> Guides<'g> {
        Guides {
            frustum,
            entry,
            fallbacks: TraceParams::default().fallbacks,
        }
    }

    /// One input through `traced` for nearest hits and for occlusion,
    /// every lane compared with `single`.
    fn check_packet<T: TriangleTest>(
        k: &KdView<'_>,
        quads: &[Ray4],
        active: &[M4],
        g: Guides<'_>,
        single: &Single<'_>,
        what: &dyn Fn() -> String,
        slot: &mut Slot<'_>,
    ) -> Counters {
        let mut fill = Hit4::MISS;
        for i in 0..4 {
            fill.set_lane(i, SENTINEL);
        }
        let mut hits = vec![fill; quads.len()];
        let mut occ = vec![M4::TRUE; quads.len()];
        let mut ctr = Counters::default();
        let isa = TraceParams::default().isa;
        let pk = Packet::nearest(quads, active, &mut hits);
        traced::<T, false>(k, pk, g, isa, slot, &mut ctr);
        let pk = Packet::occlusion(quads, active, &mut occ);
        traced::<T, true>(k, pk, g, isa, slot, &mut ctr);
        let mut valid = 0;
        for (q, (h, m)) in hits.iter().zip(active).enumerate() {
            for i in 0..4 {
                let got = h.lane(i);
                if !m.test(i) {
                    assert!(
                        same(&got, &SENTINEL),
                        "{}: inactive {q}.{i} written",
                        what()
                    );
                    assert!(!occ[q].test(i), "{}: inactive {q}.{i} occluded", what());
                    continue;
                }
                let ray = quads[q].lane(i);
                valid += ray.is_valid() as u64;
                let want = (single.near)(q, i);
                assert!(
                    same(&got, &want),
                    "{} ({:?}): quad {q} lane {i} {ray:?}: packet {got:?} single {want:?}",
                    what(),
                    T::KIND
                );
                assert_eq!(
                    occ[q].test(i),
                    (single.occl)(q, i),
                    "{} ({:?}): quad {q} lane {i} {ray:?} occluded",
                    what(),
                    T::KIND
                );
            }
        }
        assert_eq!(ctr.rays, 2 * valid, "{}", what());
        assert_eq!(
            ctr.packets,
            2 * quads.len().div_ceil(MAX_QUADS) as u64,
            "{}",
            what()
        );
        ctr
    }

    /// Every set at every packet side: no frustum from the root and from
    /// the root as an entry point; per frustum kind of the set the frustum
    /// from the root, the frustum with its entry point, and the entry
    /// point alone. Then the whole image as one input (packets of 256
    /// quads) and a 3-quad input. Returns the counters.
    fn check_sets<T: TriangleTest>(
        name: &str,
        k: &KdView<'_>,
        b: &BvhView<'_>,
        sets: &[RaySet],
    ) -> Counters {
        let t = tree(k);
        let mut total = Counters::default();
        let root = EntryPoint {
            node: 0,
            depth: 0,
            aabb: k.info.root,
        };
        for set in sets {
            let mut c1 = Counters::default();
            let single: Vec<(Hit, bool)> = set
                .rays
                .iter()
                .map(|r| {
                    r.map_or((Hit::MISS, false), |r| {
                        (
                            traverse_single::intersect::<T>(k, &r, &mut c1),
                            traverse_single::occluded::<T>(k, &r, &mut c1),
                        )
                    })
                })
                .collect();
            let mut own = SlotBuf::new(0);
            let mut run = |quads: &[Ray4], active: &[M4], pix: &[[Option<usize>; 4]], n: u32| {
                let near = |q: usize, i: usize| single[pix[q][i].unwrap()].0;
                let occl = |q: usize, i: usize| single[pix[q][i].unwrap()].1;
                let want = Single {
                    near: &near,
                    occl: &occl,
                };
                let live = live_of(quads, active);
                let mut configs: Vec<(Option<Frustum>, Option<EntryPoint>, String)> = vec![
                    (None, None, "no frustum, root".into()),
                    (None, Some(root), "no frustum, root entry".into()),
                ];
                for &kind in set.kinds {
                    if let Some(f) = Frustum::new(kind, quads, &live, &k.info.root) {
                        let e = entry_of(k, &t, b, &f);
                        configs.push((Some(f), None, format!("{kind:?} frustum, root")));
                        configs.push((Some(f), Some(e), format!("{kind:?} frustum, {e:?}")));
                        configs.push((None, Some(e), format!("{kind:?} entry only, {e:?}")));
                    }
                }
                for (f, e, c) in &configs {
                    let what = || format!("{name} {} n={n} {c}", set.name);
                    let g = guides(f.as_ref(), e.as_ref());
                    let ctr = check_packet::<T>(k, quads, active, g, &want, &what, &mut own.slot());
                    total.add(&ctr);
                }
            };
            for n in [2u32, 4, 8, 16, 32] {
                for (quads, active, pix) in packets(set, n) {
                    run(&quads, &active, &pix, n);
                }
            }
            let (mut quads, mut active, mut pix) = (vec![], vec![], vec![]);
            for (q, a, p) in packets(set, 2) {
                quads.extend(q);
                active.extend(a);
                pix.extend(p);
            }
            run(&quads, &active, &pix, 0);
            run(&quads[5..8], &active[5..8], &pix[5..8], 0);
        }
        total
    }

    /// `check_sets` over the ray sets of `traverse_masked::tests` (primary,
    /// shadow, reflection, mixed, random, bundle) for the first view.
    fn check_scene<T: TriangleTest + TriangleTest>(name: &str, side: u32) -> Counters {
        let s = crate::scenes::builtin(name).unwrap();
        let mut total = Counters::default();
        with_trees::<T>(&s.mesh.vertices, &s.mesh.indices, 0, |k, b| {
            let sets = ray_sets::<T>(
                b,
                &s.views[0],
                s.light,
                side,
                side,
                0x7a3 ^ name.len() as u64,
            );
            total = check_sets::<T>(name, k, b, &sets);
        });
        total
    }

    fn check_builtin(names: &[&str]) {
        for &name in names {
            let c = check_scene::<Mt>(name, 48);
            assert!(c.stray_lanes > 0, "{name}: {c:?}");
            if cfg!(feature = "counters") {
                assert!(
                    c.culled_nodes > 0 && c.culled > 0 && c.tri_tests > 0 && c.aabb_tests > 0,
                    "{name}: {c:?}"
                );
            }
            check_scene::<Wt>(name, 48);
            check_scene::<Pt>(name, 40);
        }
    }

    #[test]
    fn packet_matches_single_tetra_gears() {
        check_builtin(&["tetra", "gears"]);
    }

    #[test]
    fn packet_matches_single_balls_animated() {
        check_builtin(&["balls", "animated"]);
    }

    /// The lattice of `traverse_masked::tests`: frustum planes through
    /// vertices and edges, watertight rays through shared vertices.
    #[test]
    fn packet_matches_single_lattice() {
        let (v, ix, sets) = lattice();
        fn run<T: TriangleTest + TriangleTest>(v: &[f32], ix: &[u32], sets: &[RaySet]) -> Counters {
            let mut c = Counters::default();
            with_trees::<T>(v, ix, 0, |k, b| c = check_sets::<T>("lattice", k, b, sets));
            c
        }
        let c = run::<Wt>(&v, &ix, &sets);
        if cfg!(feature = "counters") {
            assert!(c.culled_nodes > 0 && c.culled > 0, "{c:?}");
        }
        run::<Mt>(&v, &ix, &sets);
        run::<Pt>(&v, &ix, &sets);
    }

    /// Coincident triangles (every hit a tie), an empty scene, a tree at
    /// the depth limit (full stacks), and an entry point outside the tree.
    #[test]
    fn packet_edge_cases() {
        fn run<T: TriangleTest + TriangleTest>(
            name: &str,
            v: &[f32],
            ix: &[u32],
            max_depth: u32,
            sets: &dyn Fn(&BvhView<'_>) -> Vec<RaySet>,
        ) -> Counters {
            let mut c = Counters::default();
            with_trees::<T>(v, ix, max_depth, |k, b| {
                c = check_sets::<T>(name, k, b, &sets(b))
            });
            c
        }
        let view = crate::scenes::View {
            eye: Vec3::new(0.3, 0.2, 3.0),
            look_at: Vec3::new(0.3, 0.2, 0.0),
            up: Vec3::Y,
            fov_y_deg: 40.0,
        };
        let light = Vec3::new(0.2, 0.2, 4.0);
        let (v, ix) = ties();
        run::<Mt>("ties", &v, &ix, 0, &|b| {
            ray_sets::<Mt>(b, &view, light, 36, 36, 3)
        });
        run::<Wt>("ties", &v, &ix, 0, &|b| {
            ray_sets::<Wt>(b, &view, light, 36, 36, 4)
        });
        run::<Pt>("ties", &v, &ix, 0, &|b| {
            ray_sets::<Pt>(b, &view, light, 36, 36, 5)
        });
        run::<Mt>("empty", &[], &[], 0, &|b| {
            ray_sets::<Mt>(b, &view, light, 8, 8, 6)
        });
        let (v, ix) = crate::accel::testkit::soup(&crate::accel::testkit::deep_tris());
        let deep = |_: &BvhView<'_>| {
            vec![RaySet {
                name: "deep",
                w: 32,
                h: 32,
                rays: deep_rays(32).into_iter().map(Some).collect(),
                kinds: &[RayKind::Primary, RayKind::Shadow, RayKind::Secondary],
            }]
        };
        let c = run::<Wt>("deep", &v, &ix, MAX_DEPTH as u32, &deep);
        if cfg!(feature = "counters") {
            assert!(c.tri_tests > 0, "{c:?}");
        }
        run::<Mt>("deep", &v, &ix, MAX_DEPTH as u32, &deep);
        // An entry point naming no node: the packet starts at the root.
        let s = crate::scenes::builtin("tetra").unwrap();
        with_trees::<Mt>(&s.mesh.vertices, &s.mesh.indices, 0, |k, b| {
            let sets = ray_sets::<Mt>(b, &s.views[0], s.light, 16, 16, 9);
            let bad = EntryPoint {
                node: u32::MAX,
                depth: 0,
                aabb: Aabb::EMPTY,
            };
            let mut c1 = Counters::default();
            for (quads, active, pix) in packets(&sets[0], 16) {
                let rays: Vec<Option<Ray>> = sets[0].rays.clone();
                let near = |q: usize, i: usize| {
                    traverse_single::intersect::<Mt>(
                        k,
                        &rays[pix[q][i].unwrap()].unwrap(),
                        &mut Counters::default(),
                    )
                };
                let occl = |q: usize, i: usize| {
                    traverse_single::occluded::<Mt>(
                        k,
                        &rays[pix[q][i].unwrap()].unwrap(),
                        &mut Counters::default(),
                    )
                };
                c1.add(&check_packet::<Mt>(
                    k,
                    &quads,
                    &active,
                    guides(None, Some(&bad)),
                    &Single {
                        near: &near,
                        occl: &occl,
                    },
                    &|| "bad entry".into(),
                    &mut SlotBuf::new(0).slot(),
                ));
            }
            assert!(c1.rays > 0);
        });
    }

    /// The BVH-pruned entry helper equals the plain brute force.
    #[test]
    fn entry_helper_matches_brute_force() {
        let mut checked = 0;
        let mut below_root = 0;
        for name in ["tetra", "gears"] {
            let s = crate::scenes::builtin(name).unwrap();
            with_trees::<Mt>(&s.mesh.vertices, &s.mesh.indices, 0, |k, b| {
                let t = tree(k);
                for set in ray_sets::<Mt>(b, &s.views[0], s.light, 32, 32, 11) {
                    for n in [2u32, 8, 32] {
                        for (quads, active, _) in packets(&set, n).iter().step_by(7) {
                            let live = live_of(quads, active);
                            for &kind in set.kinds {
                                if let Some(f) = Frustum::new(kind, quads, &live, &k.info.root) {
                                    let e = entry_of(k, &t, b, &f);
                                    assert_eq!(
                                        e,
                                        entry_brute(k, &t, &f),
                                        "{name} {} n={n}",
                                        set.name
                                    );
                                    checked += 1;
                                    below_root += (e.node != 0) as u32;
                                }
                            }
                        }
                    }
                }
            });
        }
        assert!(checked > 100 && below_root > 50, "{checked} {below_root}");
    }

    /// Release-mode throughput of camera rays on `balls` (SPD view, 512 x
    /// 512, Moller-Trumbore, one thread): kd single, 2x2 SIMD and packets
    /// of side 4..32 with and without the primary frustum (built inside
    /// the timed loop), against the BVH's single, 2x2 SIMD and Masked 16 x
    /// 16 traversals. `cargo test --release --lib
    /// kd::traverse_packet::tests::packet_speed -- --ignored --nocapture`
    /// (add `--no-default-features --features std` to time without
    /// counters).
    #[test]
    #[ignore]
    fn packet_speed() {
        use crate::accel::bvh::packet::dispatch_at as dispatch;
        use crate::accel::bvh::traverse_masked::Masked;
        use crate::accel::bvh::{BvhOptions, traverse_simd as bvh_simd};
        use crate::accel::kd::traverse_simd;
        use crate::accel::testkit::camera;
        use std::time::Instant;
        let s = crate::scenes::builtin("balls").unwrap();
        let (w, h) = (512u32, 512u32);
        with_trees::<Mt>(&s.mesh.vertices, &s.mesh.indices, 0, |k, b| {
            let pr = camera(&s.views[0], w, h);
            let set = RaySet {
                name: "primary",
                w,
                h,
                rays: (0..h)
                    .flat_map(|y| (0..w).map(move |x| (x, y)))
                    .map(|(x, y)| Some(pr.ray(x, y)))
                    .collect(),
                kinds: &[RayKind::Primary],
            };
            println!(
                "balls ({} triangles, kd {} nodes, depth {}), {w}x{h} primary rays, Moller-Trumbore, one thread",
                k.info.triangles, k.info.nodes, k.info.depth
            );
            let sides = [2u32, 4, 8, 16, 32];
            let pk: Vec<Vec<Packed>> = sides.iter().map(|&n| packets(&set, n)).collect();
            let by_side = |n: u32| &pk[sides.iter().position(|&x| x == n).unwrap()];
            type Run<'t> = Box<dyn FnMut(&mut Counters) -> u64 + 't>;
            // Sum of hit ids (equal for every kd method: exactness).
            let sum = |hs: &[Hit4]| -> u64 {
                hs.iter()
                    .flat_map(|h| h.prim)
                    .map(|p| p as u64)
                    .sum::<u64>()
            };
            let mut runs: Vec<(String, bool, Run<'_>)> = Vec::new();
            let p2 = by_side(2);
            runs.push((
                "kd single".into(),
                true,
                Box::new(move |c| {
                    let mut x = 0;
                    for (q, a, _) in p2 {
                        for i in 0..4 {
                            if a[0].test(i) {
                                x += traverse_single::intersect::<Mt>(k, &q[0].lane(i), c).prim
                                    as u64;
                            }
                        }
                    }
                    x
                }),
            ));
            runs.push((
                "kd simd (2x2)".into(),
                true,
                Box::new(move |c| {
                    let mut x = 0;
                    for (q, a, _) in p2 {
                        let hh = traverse_simd::intersect::<Mt>(k, &q[0], a[0], true, c);
                        x += sum(&[hh]);
                    }
                    x
                }),
            ));
            for n in [4u32, 8, 16, 32] {
                for cull in [false, true] {
                    let pn = by_side(n);
                    let mut hits = vec![Hit4::MISS; pn[0].0.len()];
                    let mut own = SlotBuf::new(0);
                    runs.push((
                        format!(
                            "kd packet {n}x{n} frustum {}",
                            if cull { "on" } else { "off" }
                        ),
                        true,
                        Box::new(move |c| {
                            let mut x = 0;
                            for (q, a, _) in pn {
                                let f = if cull {
                                    Frustum::new(RayKind::Primary, q, a, &k.info.root)
                                } else {
                                    None
                                };
                                let pk = Packet::nearest(q, a, &mut hits);
                                let g = guides(f.as_ref(), None);
                                let isa = TraceParams::default().isa;
                                traced::<Mt, false>(k, pk, g, isa, &mut own.slot(), c);
                                x += sum(&hits);
                            }
                            x
                        }),
                    ));
                }
            }
            runs.push((
                "bvh single".into(),
                false,
                Box::new(move |c| {
                    let mut x = 0;
                    for (q, a, _) in p2 {
                        for i in 0..4 {
                            if a[0].test(i) {
                                x += crate::accel::bvh::traverse_single::intersect::<Mt>(
                                    b,
                                    &q[0].lane(i),
                                    c,
                                )
                                .prim as u64;
                            }
                        }
                    }
                    x
                }),
            ));
            let mut h1 = [Hit4::MISS];
            runs.push((
                "bvh simd (2x2)".into(),
                false,
                Box::new(move |c| {
                    let mut x = 0;
                    for (q, a, _) in p2 {
                        bvh_simd::intersect::<Mt>(b, q, a, &mut h1, true, c);
                        x += sum(&h1);
                    }
                    x
                }),
            ));
            let p16 = by_side(16);
            let mut h16 = vec![Hit4::MISS; p16[0].0.len()];
            let mut own = crate::accel::slot::SlotBuf::new(0);
            let opt = crate::accel::method::TraceParams::with_bvh(BvhOptions {
                culling: true,
                kind: RayKind::Primary,
            });
            runs.push((
                "bvh masked 16x16 culling on".into(),
                false,
                Box::new(move |c| {
                    let mut x = 0;
                    for (q, a, _) in p16 {
                        let s = &mut own.slot();
                        let pk = crate::accel::bvh::packet::PacketIn {
                            rays: q,
                            active: a,
                            hits: &mut h16,
                        };
                        dispatch::<Masked, Mt, false>(b, pk, &opt, None, s, c);
                        x += sum(&h16);
                    }
                    x
                }),
            ));
            // This thread's time on a CPU (ns; other processes on a busy
            // machine then cost little), else wall time.
            let start = Instant::now();
            let cpu_ns = || -> f64 {
                std::fs::read_to_string("/proc/thread-self/schedstat")
                    .ok()
                    .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
                    .unwrap_or_else(|| start.elapsed().as_nanos() as f64)
            };
            // Best of 5 passes timing 6 runs each (the CPU time may tick
            // in ms), passes interleaved over the methods.
            let mut best = vec![f64::INFINITY; runs.len()];
            let mut ctrs = vec![Counters::default(); runs.len()];
            let mut sums = vec![0u64; runs.len()];
            for (j, (_, _, f)) in runs.iter_mut().enumerate() {
                (sums[j], ctrs[j]) = {
                    let mut c = Counters::default();
                    (f(&mut c), c)
                };
            }
            for _ in 0..5 {
                for (j, (_, _, f)) in runs.iter_mut().enumerate() {
                    let mut c = Counters::default();
                    let t0 = cpu_ns();
                    for _ in 0..6 {
                        f(&mut c);
                    }
                    best[j] = best[j].min((cpu_ns() - t0) * 1e-9 / 6.0);
                }
            }
            let rays = (w * h) as f64;
            println!(
                "| method | Mrays/s | split steps/ray | tri tests/ray | culled nodes/pkt | culled tris/pkt |"
            );
            println!("|---|---|---|---|---|---|");
            for (j, (name, _, _)) in runs.iter().enumerate() {
                let c = &ctrs[j];
                let np = c.packets.max(1) as f64;
                println!(
                    "| {name} | {:.2} | {:.2} | {:.2} | {:.1} | {:.1} |",
                    rays / best[j] / 1e6,
                    c.aabb_tests as f64 / rays,
                    c.tri_tests as f64 / rays,
                    c.culled_nodes as f64 / np,
                    c.culled as f64 / np
                );
            }
            for (j, (name, kd, _)) in runs.iter().enumerate() {
                if *kd {
                    assert_eq!(sums[j], sums[0], "{name}");
                }
            }
        });
    }
}
