//! Per-frame kd-tree build: the SAH compiler of the AEPSA paper's section
//! 5.1, in O(N log N) after Wald and Havran 2006 ("On building fast
//! kd-trees for ray tracing, and on doing that in O(N log N)", section 4),
//! single-threaded, into the preallocated pools.
//!
//! 1. Read the triangles once: classify (`Scene::classify`), store the
//!    traceable ones (`tris`, `tri_ids`, `slot_of`), and fail with a
//!    capacity error before anything a traversal reads is written.
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
//!    children gets its box clipped to each child on the split axis: its
//!    end event moves to the split plane in the left list (appended after
//!    that segment's events, where the sort would put it) and its start
//!    event in the right list (prepended).
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
//! - Straddling triangles are clipped by their boxes, not by the exact
//!   polygon ("perfect splits"): the child lists stay exact supersets, the
//!   tree a little less tight.
//! - Planar triangles get a start and an end event at the same position
//!   (pbrt's handling, not Wald and Havran's planar events and side choice).
//! - When the node, reference or event pool cannot hold a split the SAH
//!   wants, the node becomes a leaf and `KdInfo::forced_leaves` counts it.

use super::{KdInfo, KdNode, KdParams, KdTree, MAX_DEPTH, ROOT_PAD};
use crate::error::{Error, Pool, Result};
use crate::geom::{Aabb, Excluded, INVALID_ID, ProjTri, Scene, TriTest};
use crate::math;
use glam::Vec3;

/// Events per stored triangle (start and end on each axis).
pub const EVENTS_PER_TRI: usize = 6;

/// Most stored triangles a kd-tree accepts (the slot field of an event).
pub const MAX_TRIS: u32 = (1 << SLOT_BITS) - 1;

const SLOT_BITS: u32 = 29;
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
/// The same event at another position (the clipped box of a straddler).
#[inline(always)]
fn ev_moved(e: u64, pos: f32) -> u64 {
    (e & !(0xffff_ffffu64 << 30)) | (order_key(pos + 0.0) << 30)
}

#[inline(always)]
fn half_area(b: &Aabb) -> f32 {
    let d = (b.max - b.min).max(Vec3::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
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

/// Step 3's sweep: the cheapest event plane strictly inside the node's box.
fn find_split(ev: &[u64], n: usize, b: &Aabb, p: &KdParams) -> Option<Split> {
    let area = half_area(b);
    if !(area > 0.0) {
        return None;
    }
    let inv = 1.0 / area;
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

/// Rebuild `kd` from `scene`. On error the previous build stays valid.
pub fn build(kd: &mut KdTree<'_>, scene: &Scene<'_>, p: &KdParams) -> Result<KdInfo> {
    p.validate()?;
    let n_in = scene.triangle_count();
    let pools = kd.pools_mut();
    let cap = |pool: Pool, needed: u64, available: usize| Error::Capacity {
        pool,
        needed,
        available: available as u64,
    };
    if n_in as usize > pools.slot_of.len() {
        return Err(cap(Pool::Triangles, n_in as u64, pools.slot_of.len()));
    }

    // 1. Count (nothing is written before every capacity is known to fit).
    let (mut n, mut bad_nf, mut bad_za) = (0usize, 0u32, 0u32);
    let mut bounds = Aabb::EMPTY;
    for t in 0..n_in {
        let tri = scene.triangle(t);
        match Scene::classify(&tri) {
            None => {
                for v in [tri.v0, tri.v1, tri.v2] {
                    bounds.grow(Vec3::from(v));
                }
                n += 1;
            }
            Some(Excluded::NonFinite) => bad_nf += 1,
            Some(Excluded::ZeroArea) => bad_za += 1,
        }
    }
    if n > MAX_TRIS as usize {
        return Err(cap(Pool::Triangles, n as u64, MAX_TRIS as usize));
    }
    for avail in [
        pools.tris.len(),
        pools.tri_ids.len(),
        pools.side.len(),
        pools.refs.len(),
    ] {
        if n > avail {
            return Err(cap(Pool::Triangles, n as u64, avail));
        }
    }
    // (`Limits::validate` keeps these pools above the triangle count.)
    if pools.events.len() < EVENTS_PER_TRI * n {
        return Err(cap(
            Pool::Triangles,
            n as u64,
            pools.events.len() / EVENTS_PER_TRI,
        ));
    }
    if pools.nodes.is_empty() {
        return Err(cap(Pool::Triangles, n as u64, 0));
    }
    let proj = p.test == TriTest::Projection;
    if proj && pools.proj.len() < n {
        return Err(Error::InvalidArgument(
            "the projection test needs Limits::projection_test",
        ));
    }

    // From here on nothing fails.
    let max_depth = p.depth_for(n as u32);
    let mut info = KdInfo {
        triangles_in: n_in,
        triangles: n as u32,
        excluded_non_finite: bad_nf,
        excluded_zero_area: bad_za,
        max_depth,
        test: p.test,
        ..KdInfo::default()
    };
    pools.slot_of[..n_in as usize].fill(INVALID_ID);
    if n == 0 {
        pools.nodes[0] = KdNode::leaf(0, 0);
        info.nodes = 1;
        info.leaves = 1;
        info.empty_leaves = 1;
        kd.set_info(Some(info));
        return Ok(info);
    }
    info.bounds = bounds;
    let m = bounds.min.abs().max(bounds.max.abs()).max_element();
    let diag = bounds.diagonal();
    let pad = Vec3::splat(ROOT_PAD * (m + math::sqrt(diag.dot(diag))));
    let root = Aabb {
        min: bounds.min - pad,
        max: bounds.max + pad,
    };
    info.root = root;

    // 1b. Store the triangles; 2. their events.
    let mut s = 0usize;
    for t in 0..n_in {
        let tri = scene.triangle(t);
        if Scene::classify(&tri).is_some() {
            continue;
        }
        pools.tris[s] = tri;
        if proj {
            pools.proj[s] = ProjTri::new(&tri);
        }
        pools.tri_ids[s] = t;
        pools.slot_of[t as usize] = s as u32;
        for a in 0..3 {
            let lo = tri.v0[a].min(tri.v1[a]).min(tri.v2[a]);
            let hi = tri.v0[a].max(tri.v1[a]).max(tri.v2[a]);
            pools.events[2 * s + 2 * n * a] = event(a, lo - pad.x, false, s as u32);
            pools.events[2 * s + 1 + 2 * n * a] = event(a, hi + pad.x, true, s as u32);
        }
        s += 1;
    }
    pools.events[..EVENTS_PER_TRI * n].sort_unstable();

    // 3-4. Depth first.
    let events = &mut *pools.events;
    let nodes = &mut *pools.nodes;
    let refs = &mut *pools.refs;
    let side = &mut *pools.side;
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
            if let Some(sp_) = find_split(ev, nn, &task.bounds, p) {
                if sp_.cost < nn as f32 {
                    split = Some(sp_);
                }
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
            let (mut nl, mut nr) = (0usize, 0usize);
            for &e in &events[seg..seg + 2 * nn] {
                if !ev_end(e) {
                    nl += (side[ev_slot(e)] & 1) as usize;
                    nr += (side[ev_slot(e)] >> 1) as usize;
                }
            }
            let (el, er) = (EVENTS_PER_TRI * nl, EVENTS_PER_TRI * nr);
            let fits = next + 2 <= nodes.len()
                && base + EVENTS_PER_TRI * nn + el + er <= events.len()
                && (t.refs as usize) + pending_refs + nl + nr <= refs.len()
                && next + 2 <= KdNode::MAX_COUNT as usize;
            if fits {
                // Right list, then left list, above the node's own list.
                let (rb, lb) = (base + EVENTS_PER_TRI * nn, base + EVENTS_PER_TRI * nn + er);
                let (mut wr, mut wl) = (rb, lb);
                let (src, dst) = events.split_at_mut(rb);
                let src = &src[base..];
                for a in 0..3 {
                    let seg = &src[2 * nn * a..2 * nn * (a + 1)];
                    if a == sx.axis {
                        // Straddlers start at the plane on the right.
                        for &e in seg {
                            if !ev_end(e) && side[ev_slot(e)] == 3 {
                                dst[wr - rb] = ev_moved(e, sx.pos);
                                wr += 1;
                            }
                        }
                    }
                    for &e in seg {
                        let sd = side[ev_slot(e)];
                        let moved = a == sx.axis && sd == 3;
                        if sd & 1 != 0 && !(moved && ev_end(e)) {
                            dst[wl - rb] = e;
                            wl += 1;
                        }
                        if sd & 2 != 0 && !(moved && !ev_end(e)) {
                            dst[wr - rb] = e;
                            wr += 1;
                        }
                    }
                    if a == sx.axis {
                        // ... and end at it on the left.
                        for &e in seg {
                            if ev_end(e) && side[ev_slot(e)] == 3 {
                                dst[wl - rb] = ev_moved(e, sx.pos);
                                wl += 1;
                            }
                        }
                    }
                }
                debug_assert!(wr == rb + er && wl == lb + el);
                events.copy_within(rb..rb + er + el, base);
                let left = next as u32;
                next += 2;
                nodes[task.node as usize] = KdNode::inner(sx.axis, sx.pos, left);
                t.sah_inner += area;
                let mut lbox = task.bounds;
                lbox.max[sx.axis] = sx.pos;
                let mut rbox = task.bounds;
                rbox.min[sx.axis] = sx.pos;
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
    info.sah_cost = ((p.traversal_cost as f64 * t.sah_inner + t.sah_leaf) / root_area) as f32;
    kd.set_info(Some(info));
    Ok(info)
}

#[cfg(test)]
pub(crate) mod testutil {
    //! Owned pools for tests.
    use super::super::{KdNode, KdPools, KdTree};
    use super::EVENTS_PER_TRI;
    use crate::geom::{ProjTri, TriVerts};

    pub struct Store {
        pub nodes: Vec<KdNode>,
        pub refs: Vec<u32>,
        pub tris: Vec<TriVerts>,
        pub proj: Vec<ProjTri>,
        pub ids: Vec<u32>,
        pub slot: Vec<u32>,
        pub events: Vec<u64>,
        pub side: Vec<u8>,
    }

    impl Store {
        /// Pools for `n` triangles with the default sizing rules of `Limits`.
        pub fn new(n: usize, proj: bool) -> Store {
            Store {
                nodes: vec![KdNode::default(); 8 * n + 64],
                refs: vec![0; 6 * n + 64],
                tris: vec![TriVerts::default(); n],
                proj: vec![ProjTri::default(); if proj { n } else { 0 }],
                ids: vec![0; n],
                slot: vec![0; n],
                events: vec![0; 4 * EVENTS_PER_TRI * n + 64],
                side: vec![0; n],
            }
        }
        pub fn kd(&mut self) -> KdTree<'_> {
            KdTree::new(KdPools {
                nodes: &mut self.nodes,
                refs: &mut self.refs,
                tris: &mut self.tris,
                proj: &mut self.proj,
                tri_ids: &mut self.ids,
                slot_of: &mut self.slot,
                events: &mut self.events,
                side: &mut self.side,
            })
        }
    }
}
