//! The exact kd-tree build (`BuildQuality::High`): the SAH compiler of the
//! AEPSA paper's section 5.1, in O(N log N) after Wald and Havran 2006 ("On building fast
//! kd-trees for ray tracing, and on doing that in O(N log N)", section 4),
//! single-threaded, into the preallocated pools.
//!
//! 1. Read the triangles once: classify (`Scene::classify`), store the
//!    traceable ones (`tris`, `tri_ids`, `slot_of`), and fail with a
//!    capacity error before anything a traversal reads is written
//!    (`store`, as the binned build does).
//! 2. Make the split events: per stored triangle and axis a start and an
//!    end event at its box's extent, packed in a `u64` whose order is the
//!    sweep order (axis, position, start before end, slot). Sort them once.
//!    Every node's event list then has three axis segments of `2 N` events.
//! 3. Per node, one sweep over each axis segment gives the SAH cost of
//!    every event plane (`C_trav + (1 - bonus) (A_L N_L + A_R N_R) / A`,
//!    the bonus when one side is empty: the bias towards cutting off empty
//!    space); the node becomes a leaf when no plane beats the leaf cost `N`
//!    or at the depth limit. Otherwise triangles are classified left, right
//!    or both by the chosen event's index, and the node's list is split
//!    into the children's lists by a stable pass: both stay sorted without
//!    another sort (the O(N log N) of Wald and Havran). A triangle in both
//!    children is clipped to each child's box ("perfect splits"): its new
//!    events, few (O(sqrt N) per node in practice), are sorted and merged
//!    into the children's lists; one that misses a child's box leaves it.
//! 4. Depth first with an explicit stack of `MAX_DEPTH + 1` pending right
//!    children, whose event lists stay at the bottom of the event pool
//!    while the left child is built above them.
//!
//! # Deviations
//! - Triangle boxes are padded by `ROOT_PAD` times the scene's scale (as the
//!   root box), so a triangle within rounding distance of a split plane is
//!   stored on both sides: a ray's computed hit point always lies in a leaf
//!   interval that holds the triangle, and single-ray kd traversal finds
//!   exactly the brute-force nearest hit (see `mod.rs`, Exactness).
//! - Planar triangles get a start and an end event at the same position
//!   (pbrt's handling, not Wald and Havran's planar events and side choice).
//! - When the node, reference or event pool cannot hold a split the SAH
//!   wants, the node becomes a leaf and `KdInfo::forced_leaves` counts it.

use super::store::{SLOT_BITS, Stored, half_area, store};
use super::{KdInfo, KdNode, KdParams, KdPools, MAX_DEPTH};
use crate::error::{Error, Pool, Result};
use crate::geom::{Aabb, Scene, TriVerts};
use crate::mem::par::Serial;
use glam::Vec3;

/// Events per stored triangle (start and end on each axis).
pub const EVENTS_PER_TRI: usize = 6;

const SLOT_MASK: u64 = (1 << SLOT_BITS) - 1;
/// Event type bit: starts sort before ends at the same position.
const END: u64 = 1 << SLOT_BITS;

/// An f32 as a u32 in the same order (-0 is folded into +0 by the caller).
#[inline(always)]
fn order_key(x: f32) -> u64 {
    let b = x.to_bits();
    (if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }) as u64
}

#[inline(always)]
fn from_key(k: u32) -> f32 {
    f32::from_bits(if k & 0x8000_0000 != 0 {
        k & 0x7fff_ffff
    } else {
        !k
    })
}

#[inline(always)]
fn event(axis: usize, pos: f32, end: bool, slot: u32) -> u64 {
    ((axis as u64) << 62) | (order_key(pos + 0.0) << 30) | if end { END } else { 0 } | slot as u64
}

#[inline(always)]
fn ev_pos(e: u64) -> f32 {
    from_key((e >> 30) as u32)
}
#[inline(always)]
fn ev_end(e: u64) -> bool {
    e & END != 0
}
#[inline(always)]
fn ev_slot(e: u64) -> usize {
    (e & SLOT_MASK) as usize
}

/// `parent`'s events of triangles whose side flag passes `keep`, merged by
/// key with the sorted `new` events, into `out`; returns the count.
#[inline]
fn merge(
    parent: &[u64],
    new: &[u64],
    keep: impl Fn(u8) -> bool,
    side: &[u8],
    out: &mut [u64],
) -> usize {
    let (mut w, mut j) = (0usize, 0usize);
    for &e in parent {
        if !keep(side[ev_slot(e)]) {
            continue;
        }
        while j < new.len() && new[j] < e {
            out[w] = new[j];
            w += 1;
            j += 1;
        }
        out[w] = e;
        w += 1;
    }
    for &e in &new[j..] {
        out[w] = e;
        w += 1;
    }
    w
}

/// The box of triangle `t` clipped to box `b` (Sutherland-Hodgman in f64
/// against the six planes), or `None` when they do not meet.
pub(super) fn clip_triangle(t: &TriVerts, b: &Aabb) -> Option<Aabb> {
    let mut poly = [[0.0f64; 3]; 10];
    let mut tmp = [[0.0f64; 3]; 10];
    for (p, v) in poly.iter_mut().zip([t.v0, t.v1, t.v2]) {
        *p = [v[0] as f64, v[1] as f64, v[2] as f64];
    }
    let mut n = 3usize;
    for axis in 0..3 {
        for (plane, keep_above) in [(b.min[axis] as f64, true), (b.max[axis] as f64, false)] {
            let inside = |p: &[f64; 3]| {
                if keep_above {
                    p[axis] >= plane
                } else {
                    p[axis] <= plane
                }
            };
            let mut m = 0usize;
            for i in 0..n {
                let (p, q) = (poly[i], poly[(i + 1) % n]);
                let (pi, qi) = (inside(&p), inside(&q));
                if pi {
                    tmp[m] = p;
                    m += 1;
                }
                if pi != qi {
                    let f = (plane - p[axis]) / (q[axis] - p[axis]);
                    let mut x = [
                        p[0] + f * (q[0] - p[0]),
                        p[1] + f * (q[1] - p[1]),
                        p[2] + f * (q[2] - p[2]),
                    ];
                    x[axis] = plane;
                    tmp[m] = x;
                    m += 1;
                }
            }
            n = m;
            if n == 0 {
                return None;
            }
            poly[..n].copy_from_slice(&tmp[..n]);
        }
    }
    let mut out = Aabb::EMPTY;
    for p in &poly[..n] {
        out.grow(Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32));
    }
    Some(out)
}

/// A node waiting to be built.
#[derive(Clone, Copy, Debug)]
struct Task {
    node: u32,
    depth: u32,
    /// Its triangles; its events are `6 n` at `base` in the event pool.
    n: u32,
    base: usize,
    bounds: Aabb,
}

/// The best plane of a node.
#[derive(Clone, Copy, Debug)]
struct Split {
    axis: usize,
    /// Index of the chosen event inside the axis segment.
    index: usize,
    pos: f32,
    cost: f32,
}

/// The sweep: the cheapest event plane strictly inside the node's box.
fn find_split(ev: &[u64], n: usize, b: &Aabb, p: &KdParams) -> Option<Split> {
    let area = half_area(b);
    // A flat or NaN box has no split.
    let inv = if area > 0.0 { 1.0 / area } else { return None };
    let d = b.max - b.min;
    let mut best: Option<Split> = None;
    for axis in 0..3 {
        let (o1, o2) = ((axis + 1) % 3, (axis + 2) % 3);
        // Areas of the child boxes as linear functions of the plane.
        let cap = d[o1] * d[o2];
        let perim = d[o1] + d[o2];
        let seg = &ev[2 * n * axis..2 * n * (axis + 1)];
        let (lo, hi) = (b.min[axis], b.max[axis]);
        let (mut nl, mut nr) = (0usize, n);
        for (i, &e) in seg.iter().enumerate() {
            let end = ev_end(e);
            if end {
                nr -= 1;
            }
            let x = ev_pos(e);
            if x > lo && x < hi {
                let al = cap + (x - lo) * perim;
                let ar = cap + (hi - x) * perim;
                let bonus = if nl == 0 || nr == 0 {
                    1.0 - p.empty_bonus
                } else {
                    1.0
                };
                let cost = p.traversal_cost + bonus * (al * nl as f32 + ar * nr as f32) * inv;
                if best.is_none_or(|s| cost < s.cost) {
                    best = Some(Split {
                        axis,
                        index: i,
                        pos: x,
                        cost,
                    });
                }
            }
            if !end {
                nl += 1;
            }
        }
    }
    best
}

/// Build statistics gathered on the way.
#[derive(Default)]
struct Tally {
    leaves: u32,
    empty: u32,
    refs: u32,
    depth_sum: u64,
    max_depth: u32,
    forced: u32,
    sah_inner: f64,
    sah_leaf: f64,
}

/// The exact build (`BuildQuality::High`), steps 1-4 of the module docs.
pub(super) fn sweep(pools: &mut KdPools<'_>, scene: &Scene<'_>, p: &KdParams) -> Result<KdInfo> {
    let stored = store(pools, scene, p, &Serial, 1, |pools, n| {
        // (`Limits::validate` keeps these pools above the triangle count.)
        if pools.events.len() < EVENTS_PER_TRI * n {
            return Err(Error::Capacity {
                pool: Pool::Triangles,
                needed: n as u64,
                available: (pools.events.len() / EVENTS_PER_TRI) as u64,
            });
        }
        Ok(())
    })?;
    let Stored { n, mut info, pad } = match stored {
        Ok(s) => s,
        Err(empty) => return Ok(empty),
    };
    let (root, max_depth) = (info.root, info.max_depth);

    // 2. The events of the stored triangles.
    for s in 0..n {
        let tri = pools.tris[s];
        for a in 0..3 {
            let lo = tri.v0[a].min(tri.v1[a]).min(tri.v2[a]);
            let hi = tri.v0[a].max(tri.v1[a]).max(tri.v2[a]);
            pools.events[2 * s + 2 * n * a] = event(a, lo - pad.x, false, s as u32);
            pools.events[2 * s + 1 + 2 * n * a] = event(a, hi + pad.x, true, s as u32);
        }
    }
    pools.events[..EVENTS_PER_TRI * n].sort_unstable();

    // 3-4. Depth first.
    let events = &mut *pools.events;
    let nodes = &mut *pools.nodes;
    let refs = &mut *pools.refs;
    let side = &mut *pools.side;
    let tris = &*pools.tris;
    let root_area = half_area(&root) as f64;
    let mut t = Tally::default();
    let mut next = 1usize;
    let mut stack = [Task {
        node: 0,
        depth: 0,
        n: 0,
        base: 0,
        bounds: root,
    }; MAX_DEPTH + 1];
    let mut sp = 0usize;
    // References promised to pending right children.
    let mut pending_refs = 0usize;
    // High-water mark of the event pool.
    let mut peak = EVENTS_PER_TRI * n;
    let mut task = Task {
        node: 0,
        depth: 0,
        n: n as u32,
        base: 0,
        bounds: root,
    };
    loop {
        let nn = task.n as usize;
        let base = task.base;
        let area = half_area(&task.bounds) as f64;
        let mut split = None;
        if nn > 0 && task.depth < max_depth {
            let ev = &events[base..base + EVENTS_PER_TRI * nn];
            if let Some(sp_) = find_split(ev, nn, &task.bounds, p)
                && sp_.cost < nn as f32
            {
                split = Some(sp_);
            }
        }
        if let Some(sx) = split {
            // Classify by the chosen event's index (1 left, 2 right, 3 both).
            let seg = base + 2 * nn * sx.axis;
            for &e in &events[seg..seg + 2 * nn] {
                side[ev_slot(e)] = 0;
            }
            for (i, &e) in events[seg..seg + 2 * nn].iter().enumerate() {
                if i < sx.index && !ev_end(e) {
                    side[ev_slot(e)] |= 1;
                } else if i > sx.index && ev_end(e) {
                    side[ev_slot(e)] |= 2;
                }
            }
            let mut lbox = task.bounds;
            lbox.max[sx.axis] = sx.pos;
            let mut rbox = task.bounds;
            rbox.min[sx.axis] = sx.pos;
            // Perfect splits: a straddler's events in each child come from
            // the triangle clipped to that child's (padded) box; one that
            // misses a child's box leaves that child.
            let tmp = base + EVENTS_PER_TRI * nn;
            let mut straddlers = 0usize;
            for &e in &events[seg..seg + 2 * nn] {
                straddlers += (!ev_end(e) && side[ev_slot(e)] == 3) as usize;
            }
            let mut fits = tmp + 2 * EVENTS_PER_TRI * straddlers <= events.len();
            let (mut ln, mut rn) = (0usize, 0usize);
            if fits && straddlers > 0 {
                let grow = |b: &Aabb| Aabb {
                    min: b.min - pad,
                    max: b.max + pad,
                };
                let (lp, rp) = (grow(&lbox), grow(&rbox));
                let (head, scratch) = events.split_at_mut(tmp);
                let (new_l, new_r) = scratch.split_at_mut(EVENTS_PER_TRI * straddlers);
                for &e in &head[seg..seg + 2 * nn] {
                    let sl = ev_slot(e);
                    if ev_end(e) || side[sl] != 3 {
                        continue;
                    }
                    let tri = &tris[sl];
                    let cl = clip_triangle(tri, &lp);
                    let cr = clip_triangle(tri, &rp);
                    // Rounding could clip a straddler away on both sides:
                    // keep it in both with the whole child boxes.
                    let (cl, cr) = match (cl, cr) {
                        (None, None) => (Some(lbox), Some(rbox)),
                        c => c,
                    };
                    // Bit 4: clipped (its events come from `new_l`/`new_r` only).
                    side[sl] = 4 | cl.is_some() as u8 | (cr.is_some() as u8) << 1;
                    for (c, out, w) in [(cl, &mut *new_l, &mut ln), (cr, &mut *new_r, &mut rn)] {
                        if let Some(c) = c {
                            for a in 0..3 {
                                out[*w] = event(a, c.min[a] - pad.x, false, sl as u32);
                                out[*w + 1] = event(a, c.max[a] + pad.x, true, sl as u32);
                                *w += 2;
                            }
                        }
                    }
                }
                new_l[..ln].sort_unstable();
                new_r[..rn].sort_unstable();
            }
            let (mut nl, mut nr) = (0usize, 0usize);
            for &e in &events[seg..seg + 2 * nn] {
                if !ev_end(e) {
                    nl += (side[ev_slot(e)] & 1) as usize;
                    nr += ((side[ev_slot(e)] >> 1) & 1) as usize;
                }
            }
            let (el, er) = (EVENTS_PER_TRI * nl, EVENTS_PER_TRI * nr);
            // Merged lists go above the sorted new events: right, then left.
            let out = tmp + 2 * EVENTS_PER_TRI * straddlers;
            fits = fits
                && next + 2 <= nodes.len()
                && out + el + er <= events.len()
                && (t.refs as usize) + pending_refs + nl + nr <= refs.len()
                && next + 2 <= KdNode::MAX_COUNT as usize;
            if fits {
                peak = peak.max(out + el + er);
                let (src, dst) = events.split_at_mut(out);
                let parent = &src[base..tmp];
                let new_l = &src[tmp..tmp + ln];
                let new_r =
                    &src[tmp + EVENTS_PER_TRI * straddlers..tmp + EVENTS_PER_TRI * straddlers + rn];
                // Lists stay sorted by key: the one-sided triangles' events
                // in the parent's order, merged with the clipped ones.
                let wr = merge(parent, new_r, |sd| sd == 2, side, &mut dst[..er]);
                let wl = merge(parent, new_l, |sd| sd == 1, side, &mut dst[er..er + el]);
                debug_assert!(wr == er && wl == el);
                events.copy_within(out..out + er + el, base);
                let left = next as u32;
                next += 2;
                nodes[task.node as usize] = KdNode::inner(sx.axis, sx.pos, left);
                t.sah_inner += area;
                let depth = task.depth + 1;
                stack[sp] = Task {
                    node: left + 1,
                    depth,
                    n: nr as u32,
                    base,
                    bounds: rbox,
                };
                sp += 1;
                pending_refs += nr;
                task = Task {
                    node: left,
                    depth,
                    n: nl as u32,
                    base: base + er,
                    bounds: lbox,
                };
                continue;
            }
            t.forced += 1;
        }
        // A leaf: its triangles are the starts of the first axis segment.
        let first = t.refs as usize;
        for (j, &e) in events[base..base + 2 * nn]
            .iter()
            .filter(|e| !ev_end(**e))
            .enumerate()
        {
            refs[first + j] = ev_slot(e) as u32;
        }
        nodes[task.node as usize] = KdNode::leaf(first as u32, nn as u32);
        t.refs += nn as u32;
        t.leaves += 1;
        t.empty += (nn == 0) as u32;
        t.depth_sum += task.depth as u64;
        t.max_depth = t.max_depth.max(task.depth);
        t.sah_leaf += area * nn as f64;
        if sp == 0 {
            break;
        }
        sp -= 1;
        task = stack[sp];
        pending_refs -= task.n as usize;
    }
    info.nodes = next as u32;
    info.leaves = t.leaves;
    info.empty_leaves = t.empty;
    info.refs = t.refs;
    info.depth = t.max_depth;
    info.avg_leaf_depth = (t.depth_sum as f64 / t.leaves as f64) as f32;
    info.forced_leaves = t.forced;
    info.events_peak = peak as u32;
    info.sah_cost = ((p.traversal_cost as f64 * t.sah_inner + t.sah_leaf) / root_area) as f32;
    Ok(info)
}
