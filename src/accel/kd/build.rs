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

use super::{KdInfo, KdNode, KdParams, KdPools, KdTree, MAX_DEPTH, ROOT_PAD};
use crate::accel::bvh::BuildQuality;
use crate::error::{Error, Pool, Result};
use crate::geom::{Aabb, Excluded, INVALID_ID, ProjTri, Scene, TriTest, TriVerts};
use crate::math;
use crate::mem::par::{MAX_WORKERS, Par, Parts, Serial, workers_of};
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
#[inline(always)]
pub(super) fn half_area(b: &Aabb) -> f32 {
    let d = (b.max - b.min).max(Vec3::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
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

/// Step 3's sweep: the cheapest event plane strictly inside the node's box.
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

/// Rebuild `kd` from `scene` on the calling thread. On error the previous
/// build stays valid.
pub fn build(kd: &mut KdTree<'_>, scene: &Scene<'_>, p: &KdParams) -> Result<KdInfo> {
    build_with(kd, scene, p, &Serial)
}

/// Rebuild `kd` from `scene` by `p.quality`'s build, the binned ones on
/// `par`'s workers (the tree is the same for any worker count; `High`
/// runs on the calling thread). On error the previous build stays valid.
pub fn build_with(
    kd: &mut KdTree<'_>,
    scene: &Scene<'_>,
    p: &KdParams,
    par: &dyn Par,
) -> Result<KdInfo> {
    p.validate()?;
    let workers = workers_of(par)?;
    let info = if p.quality == BuildQuality::High {
        sweep(kd.pools_mut(), scene, p)?
    } else {
        super::build_binned::build(kd.pools_mut(), scene, p, par, workers)?
    };
    kd.set_info(Some(info));
    Ok(info)
}

/// What one worker found in its share of the triangles.
#[derive(Clone, Copy, Default)]
struct Found {
    valid: u32,
    non_finite: u32,
    zero_area: u32,
    bounds: Option<Aabb>,
}

/// The stored triangles (step 1 of both builds).
pub(super) struct Stored {
    /// Stored triangles.
    pub n: usize,
    /// The counts, bounds, root box and parameters filled in.
    pub info: KdInfo,
    /// The padding of every reference box (`ROOT_PAD` of the scene's scale).
    pub pad: Vec3,
}

/// Step 1 of both builds on `par`'s workers: classify the triangles (flags
/// in `side`), check the pools (`fits(pools, n)` adds a build's own
/// checks), then store the traceable triangles in caller order. Nothing a
/// traversal reads is written before every check passed. With no
/// traceable triangle the tree is one empty leaf, returned as
/// `Ok(Err(info))`: the build is done.
pub(super) fn store(
    pools: &mut KdPools<'_>,
    scene: &Scene<'_>,
    p: &KdParams,
    par: &dyn Par,
    workers: usize,
    fits: impl FnOnce(&KdPools<'_>, usize) -> Result<()>,
) -> Result<core::result::Result<Stored, KdInfo>> {
    let n_in = scene.triangle_count() as usize;
    let cap = |needed: usize, available: usize| Error::Capacity {
        pool: Pool::Triangles,
        needed: needed as u64,
        available: available as u64,
    };
    let room = pools.slot_of.len().min(pools.side.len());
    if n_in > room {
        return Err(cap(n_in, room));
    }
    let mut found = [Found::default(); MAX_WORKERS];
    {
        let (fs, sd) = (
            Parts::even(&mut found[..workers], workers),
            Parts::even(&mut pools.side[..n_in], workers),
        );
        par.run(&|w| {
            let (side, first) = (sd.get(w), sd.start(w));
            let mut f = Found::default();
            for (k, flag) in side.iter_mut().enumerate() {
                let tri = scene.triangle((first + k) as u32);
                *flag = match Scene::classify(&tri) {
                    None => {
                        let b = f.bounds.get_or_insert(Aabb::EMPTY);
                        for v in [tri.v0, tri.v1, tri.v2] {
                            b.grow(Vec3::from(v));
                        }
                        f.valid += 1;
                        0
                    }
                    Some(Excluded::NonFinite) => {
                        f.non_finite += 1;
                        1
                    }
                    Some(Excluded::ZeroArea) => {
                        f.zero_area += 1;
                        2
                    }
                };
            }
            fs.get(w)[0] = f;
        });
    }
    let (mut n, mut bad_nf, mut bad_za) = (0usize, 0u32, 0u32);
    let mut bounds = Aabb::EMPTY;
    let mut start = [0usize; MAX_WORKERS + 1];
    for (w, f) in found[..workers].iter().enumerate() {
        n += f.valid as usize;
        start[w + 1] = n;
        bad_nf += f.non_finite;
        bad_za += f.zero_area;
        if let Some(b) = f.bounds {
            bounds.grow(b.min);
            bounds.grow(b.max);
        }
    }
    if n > MAX_TRIS as usize {
        return Err(cap(n, MAX_TRIS as usize));
    }
    for avail in [pools.tris.len(), pools.tri_ids.len(), pools.refs.len()] {
        if n > avail {
            return Err(cap(n, avail));
        }
    }
    if pools.nodes.is_empty() {
        return Err(cap(n, 0));
    }
    let proj = p.test == TriTest::Projection;
    if proj && pools.proj.len() < n {
        return Err(Error::InvalidArgument(
            "the projection test needs Limits::projection_test",
        ));
    }
    fits(pools, n)?;

    // From here on nothing fails.
    crate::fault_point!(KdBuild);
    let n_tris = n as u32;
    let mut info = KdInfo {
        triangles_in: n_in as u32,
        triangles: n_tris,
        excluded_non_finite: bad_nf,
        excluded_zero_area: bad_za,
        max_depth: p.depth_for(n_tris),
        test: p.test,
        quality: p.quality,
        bins: if p.quality == BuildQuality::High {
            0
        } else {
            p.bins
        },
        ..KdInfo::default()
    };
    if n == 0 {
        pools.slot_of[..n_in].fill(INVALID_ID);
        pools.nodes[0] = KdNode::leaf(0, 0);
        info.nodes = 1;
        info.leaves = 1;
        info.empty_leaves = 1;
        return Ok(Err(info));
    }
    {
        let bd = &start[..workers + 1];
        let (ts, is) = (
            Parts::at(&mut pools.tris[..n], bd),
            Parts::at(&mut pools.tri_ids[..n], bd),
        );
        let ps = Parts::at(if proj { &mut pools.proj[..n] } else { &mut [] }, {
            if proj { bd } else { &[] }
        });
        let ss = Parts::even(&mut pools.slot_of[..n_in], workers);
        let side = &pools.side[..n_in];
        par.run(&|w| {
            let (tris, ids, slots) = (ts.get(w), is.get(w), ss.get(w));
            let pj = if proj { ps.get(w) } else { &mut [] };
            let first = ss.start(w);
            let mut k = 0usize;
            for (j, slot) in slots.iter_mut().enumerate() {
                let t = first + j;
                if side[t] != 0 {
                    *slot = INVALID_ID;
                    continue;
                }
                let tri = scene.triangle(t as u32);
                tris[k] = tri;
                if let Some(x) = pj.get_mut(k) {
                    *x = ProjTri::new(&tri);
                }
                ids[k] = t as u32;
                *slot = (start[w] + k) as u32;
                k += 1;
            }
        });
    }
    info.bounds = bounds;
    let m = bounds.min.abs().max(bounds.max.abs()).max_element();
    let diag = bounds.diagonal();
    let pad = Vec3::splat(ROOT_PAD * (m + math::sqrt(diag.dot(diag))));
    info.root = Aabb {
        min: bounds.min - pad,
        max: bounds.max + pad,
    };
    Ok(Ok(Stored { n, info, pad }))
}

/// The exact build (`BuildQuality::High`), steps 1-4 of the module docs.
fn sweep(pools: &mut KdPools<'_>, scene: &Scene<'_>, p: &KdParams) -> Result<KdInfo> {
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

#[cfg(test)]
pub(crate) mod testutil {
    //! Owned pools for tests.
    use super::super::{KdNode, KdPools, KdTree};
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
        /// Pools for `n` triangles with the default sizing rules of `Limits`
        /// (nodes `4n + 1024`, references `12n + 1024`, events `16n + 1024`).
        pub fn new(n: usize, proj: bool) -> Store {
            Store {
                nodes: vec![KdNode::default(); 4 * n + 1024],
                refs: vec![0; 12 * n + 1024],
                tris: vec![TriVerts::default(); n],
                proj: vec![ProjTri::default(); if proj { n } else { 0 }],
                ids: vec![0; n],
                slot: vec![0; n],
                events: vec![0; 16 * n + 1024],
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

#[cfg(test)]
mod tests {
    use super::testutil::Store;
    use super::*;
    use crate::accel::kd::{KdNode, KdView};

    /// Every stored triangle sits in the leaves its padded box reaches,
    /// node boxes nest, and the tallies agree with the tree.
    fn check_invariants(v: &KdView<'_>) {
        let info = v.info;
        let mut stack = vec![(0usize, info.root, 0u32)];
        let (mut leaves, mut empty, mut refs, mut depth_sum) = (0u32, 0u32, 0u32, 0u64);
        let mut seen = vec![false; v.tris.len()];
        while let Some((n, b, d)) = stack.pop() {
            let node: &KdNode = &v.nodes[n];
            assert!(d <= info.max_depth);
            if node.is_leaf() {
                leaves += 1;
                empty += (node.count() == 0) as u32;
                refs += node.count() as u32;
                depth_sum += d as u64;
                // Every triangle of a leaf meets its box (padded by far
                // more than the build's padding): a leaf naming another
                // part of the reference pool fails here.
                let slack = 1e-3 * info.root.diagonal().length();
                for &s in v.leaf_refs(node) {
                    seen[s as usize] = true;
                    let t = &v.tris[s as usize];
                    let lo = Vec3::from(t.v0).min(t.v1.into()).min(t.v2.into());
                    let hi = Vec3::from(t.v0).max(t.v1.into()).max(t.v2.into());
                    assert!(
                        (lo - slack).cmple(b.max).all() && (hi + slack).cmpge(b.min).all(),
                        "leaf {n}: triangle {s} outside its box"
                    );
                }
                continue;
            }
            let (l, r) = KdView::child_boxes(node, &b);
            let s = node.split();
            assert!(
                s > b.min[node.axis()] && s < b.max[node.axis()],
                "split inside the node"
            );
            stack.push((node.left(), l, d + 1));
            stack.push((node.left() + 1, r, d + 1));
        }
        assert!(seen.iter().all(|&x| x), "every triangle in some leaf");
        assert_eq!(
            (leaves, empty, refs),
            (info.leaves, info.empty_leaves, info.refs)
        );
        assert!((depth_sum as f64 / leaves as f64 - info.avg_leaf_depth as f64).abs() < 1e-3);
        assert_eq!(info.nodes as usize, 2 * leaves as usize - 1);
    }

    #[test]
    fn builtin_scenes_invariants() {
        for name in crate::scenes::BUILTIN_NAMES {
            let sc = crate::scenes::builtin(name).unwrap();
            let scene = Scene::from_f32(&sc.mesh.vertices, &sc.mesh.indices).unwrap();
            let mut st = Store::new(scene.triangle_count() as usize, false);
            roomy(&mut st, scene.triangle_count() as usize);
            let mut kd = st.kd();
            for quality in QUALITIES {
                let p = KdParams {
                    quality,
                    ..KdParams::default()
                };
                let info = build(&mut kd, &scene, &p).unwrap();
                check_invariants(&kd.view().unwrap());
                assert!(
                    info.empty_leaves > 0 && info.forced_leaves == 0 && info.quality == quality,
                    "{name}: {info:?}"
                );
            }
        }
    }

    /// Roomy pools: gears' fan triangles need 20 references and 6 nodes
    /// each, and the `Low` build's lists as many (the default limits make
    /// forced leaves there).
    fn roomy(st: &mut Store, n: usize) {
        st.refs.resize(32 * n, 0);
        st.nodes.resize(16 * n, KdNode::default());
        st.events.resize(64 * n, 0);
    }

    const QUALITIES: [BuildQuality; 3] =
        [BuildQuality::Low, BuildQuality::Medium, BuildQuality::High];

    /// The binned builds make the same tree on any number of workers, in
    /// any order and on real threads: the same nodes, references and
    /// stored triangles, and the same `KdInfo`.
    #[test]
    fn workers_build_the_same_tree() {
        use crate::accel::testkit::Backwards;
        use crate::mem::par::{Helped, Join};
        for &name in crate::scenes::BUILTIN_NAMES {
            let sc = crate::scenes::builtin(name).unwrap();
            let scene = Scene::from_f32(&sc.mesh.vertices, &sc.mesh.indices).unwrap();
            let n = scene.triangle_count() as usize;
            let mut big = Store::new(n, false);
            roomy(&mut big, n);
            // Pools too small for the tree the SAH wants: forced leaves,
            // in the same places for any worker count.
            let mut tight = Store::new(n, false);
            tight.refs.truncate(n + n / 2 + 8);
            tight.nodes.truncate(n / 2 + 8);
            tight.events.truncate(9 * n + 1024);
            // Few nodes, many references: most jobs outgrow their node
            // shares and are built again in the rest.
            let mut lean = Store::new(n, false);
            roomy(&mut lean, n);
            lean.nodes.truncate(n / 8 + 8);
            for (st, forced) in [(&mut big, false), (&mut tight, true), (&mut lean, true)] {
                let mut kd = st.kd();
                for quality in [BuildQuality::Low, BuildQuality::Medium] {
                    let p = KdParams {
                        quality,
                        ..KdParams::default()
                    };
                    let snap = |kd: &KdTree<'_>| {
                        let v = kd.view().unwrap();
                        (
                            *v.info,
                            v.nodes.to_vec(),
                            v.refs.to_vec(),
                            v.tri_ids.to_vec(),
                        )
                    };
                    build(&mut kd, &scene, &p).unwrap();
                    let want = snap(&kd);
                    check_invariants(&kd.view().unwrap());
                    assert!(want.0.nodes > 1, "{name}: one leaf");
                    assert_eq!(
                        want.0.forced_leaves > 0,
                        forced,
                        "{name} {quality:?}: {:?}",
                        want.0
                    );
                    for workers in [2usize, 3, 16] {
                        build_with(&mut kd, &scene, &p, &Backwards(workers)).unwrap();
                        assert!(
                            snap(&kd) == want,
                            "{name} {quality:?}: {workers} workers backwards"
                        );
                    }
                    let join = Join::new();
                    std::thread::scope(|t| {
                        let j = &join;
                        t.spawn(move || assert_eq!(j.help(1, 2), Helped::Done(0)));
                        join.lead(2, |par| build_with(&mut kd, &scene, &p, par))
                    })
                    .unwrap();
                    assert!(snap(&kd) == want, "{name} {quality:?}: 2 threads");
                }
            }
        }
    }

    #[test]
    fn empty_degenerate_and_tiny_pools() {
        // No traceable triangle: a single empty leaf.
        let v = [
            0.0f32,
            0.0,
            0.0,
            1.0,
            0.0,
            0.0,
            2.0,
            0.0,
            0.0,
            f32::NAN,
            0.0,
            0.0,
        ];
        let ix = [0u32, 1, 2, 0, 1, 3];
        let scene = Scene::from_f32(&v, &ix).unwrap();
        let mut st = Store::new(2, false);
        let mut kd = st.kd();
        let info = build(&mut kd, &scene, &KdParams::default()).unwrap();
        assert_eq!(
            (
                info.triangles,
                info.excluded_zero_area,
                info.excluded_non_finite,
                info.leaves
            ),
            (0, 1, 1, 1)
        );
        // Pools just big enough for the root: splits are refused, the tree
        // is one leaf with every triangle, counted as forced.
        let sc = crate::scenes::builtin("tetra").unwrap();
        let scene = Scene::from_f32(&sc.mesh.vertices, &sc.mesh.indices).unwrap();
        let n = scene.triangle_count() as usize;
        let mut st = Store::new(n, false);
        st.events.truncate(EVENTS_PER_TRI * n);
        let mut kd = st.kd();
        // The binned builds need their job list and two root lists: a
        // capacity error, nothing written.
        assert!(build(&mut kd, &scene, &KdParams::default()).is_err());
        assert!(kd.view().is_none());
        let high = KdParams {
            quality: BuildQuality::High,
            ..KdParams::default()
        };
        let info = build(&mut kd, &scene, &high).unwrap();
        assert_eq!(
            (info.leaves, info.forced_leaves, info.refs as usize),
            (1, 1, n)
        );
        check_invariants(&kd.view().unwrap());
        // Too few triangle slots: an error, and the previous tree stays.
        let mut st = Store::new(n, false);
        st.tris.truncate(n - 1);
        let mut kd = st.kd();
        assert!(build(&mut kd, &scene, &KdParams::default()).is_err());
        assert!(kd.view().is_none());
    }

    use crate::accel::testkit::shared_scene as obj;

    /// The binned builds against the BVH SAH build and the exact kd build,
    /// and the binned tree's camera rays against the exact tree's, in
    /// interleaved rounds (each round times every configuration once; the
    /// medians of the per-round ratios are printed). 1024x1024 camera
    /// rays from inside the scene's box looking along x, kd packets 16x16
    /// from the root, one thread. `KD_ROUNDS` rounds (default 7).
    #[test]
    #[ignore]
    fn binned_against_exact() {
        use crate::mem::par::Join;
        use crate::render::{PixelRect, PrimaryRays};
        use crate::{BvhParams, Limits, Method, OwnedContext, TraceParams};
        use std::time::Instant;
        let rounds: usize = std::env::var("KD_ROUNDS").map_or(7, |r| r.parse().unwrap());
        let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
        println!("load at start: {}", load.trim());
        println!(
            "| scene | tris | kd Medium / BVH SAH build | kd Low / BVH SAH | Medium 1 / 2 threads | Low 1 / 2 threads | exact / Medium build | Medium SAH / exact SAH | refs/tri Medium, exact | camera Mrays/s Medium / exact | Low / exact | hits differing |"
        );
        println!("|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|");
        for file in [
            "bunny/bunny_tinybvh.obj",
            "conference/conference.obj",
            "crytek_sponza/crytek_sponza.obj",
            "sibenik/sibenik.obj",
        ] {
            let Some((v, ix)) = obj(file) else {
                println!("{file}: not found, skipped");
                continue;
            };
            let scene = Scene::from_f32(&v, &ix).unwrap();
            let n = scene.triangle_count();
            let mut l = Limits::for_triangles(n);
            l.max_vertices = (v.len() / 3) as u32;
            l.structures = Limits::KD | Limits::BVH;
            let new = || OwnedContext::new(&l).unwrap();
            let (mut fast, mut exact, mut coarse) = (new(), new(), new());
            let q = |quality| KdParams {
                quality,
                ..KdParams::default()
            };
            let (low, med, high) = (
                q(BuildQuality::Low),
                q(BuildQuality::Medium),
                q(BuildQuality::High),
            );
            let hi_info = exact.build_kd(&scene, &high).unwrap();
            let info = fast.build_kd(&scene, &med).unwrap();
            coarse.build_kd(&scene, &low).unwrap();
            let b = info.bounds;
            let (c, e) = ((b.min + b.max) * 0.5, b.max - b.min);
            let cam = crate::Camera {
                eye: (c - Vec3::new(0.45 * e.x, 0.0, 0.0)).to_array(),
                look_at: (c + Vec3::new(e.x, 0.0, 0.0)).to_array(),
                up: [0.0, 1.0, 0.0],
                fov_y_deg: 60.0,
            };
            let (w, h) = (1024u32, 1024u32);
            let rays = PrimaryRays::new(&cam, w, h).unwrap();
            let tp = TraceParams {
                method: Method::KdPacket,
                packet: 16,
                ..TraceParams::default()
            };
            let trace = |ctx: &OwnedContext, hits: &mut Vec<crate::Hit>| {
                let t = Instant::now();
                ctx.trace_camera(None, &tp, &rays, PixelRect::image(w, h), hits, w as usize)
                    .unwrap();
                t.elapsed().as_secs_f64()
            };
            let timed = |f: &mut dyn FnMut()| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64()
            };
            let joined = |ctx: &mut OwnedContext, p: &KdParams| {
                let join = Join::new();
                std::thread::scope(|t| {
                    let j = &join;
                    t.spawn(move || j.help(1, 2));
                    join.lead(2, |par| ctx.build_kd_with(&scene, p, par))
                })
                .unwrap();
            };
            let (mut hf, mut he) = (
                vec![crate::Hit::MISS; (w * h) as usize],
                vec![crate::Hit::MISS; (w * h) as usize],
            );
            let mut hl = hf.clone();
            let mut r: [Vec<f64>; 7] = Default::default();
            for _ in 0..rounds {
                let bvh = timed(&mut || {
                    exact.build_bvh(&scene, &BvhParams::default()).unwrap();
                });
                let l1 = timed(&mut || {
                    fast.build_kd(&scene, &low).unwrap();
                });
                let l2 = timed(&mut || joined(&mut fast, &low));
                let m2 = timed(&mut || joined(&mut fast, &med));
                let m1 = timed(&mut || {
                    fast.build_kd(&scene, &med).unwrap();
                });
                let hb = timed(&mut || {
                    exact.build_kd(&scene, &high).unwrap();
                });
                let (tf, te, tl) = (
                    trace(&fast, &mut hf),
                    trace(&exact, &mut he),
                    trace(&coarse, &mut hl),
                );
                for (k, x) in [
                    m1 / bvh,
                    l1 / bvh,
                    m1 / m2,
                    l1 / l2,
                    hb / m1,
                    te / tf,
                    te / tl,
                ]
                .into_iter()
                .enumerate()
                {
                    r[k].push(x);
                }
            }
            let med_of = |v: &mut Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v[v.len() / 2]
            };
            let differ = hf
                .iter()
                .chain(&hl)
                .zip(he.iter().chain(&he))
                .filter(|(a, b)| a.prim != b.prim || a.t.to_bits() != b.t.to_bits())
                .count();
            let m: Vec<f64> = r.iter_mut().map(med_of).collect();
            println!(
                "| {} | {n} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.3} | {:.2}, {:.2} | {:.2} | {:.2} | {differ} |",
                file.split('/').next().unwrap(),
                m[0],
                m[1],
                m[2],
                m[3],
                m[4],
                info.sah_cost / hi_info.sah_cost,
                info.refs as f64 / info.triangles as f64,
                hi_info.refs as f64 / hi_info.triangles as f64,
                m[5],
                m[6]
            );
        }
    }

    /// Table 1 of the AEPSA paper for the OBJ scenes (skips absent files).
    #[test]
    #[ignore]
    fn table1_obj_scenes() {
        for file in [
            "legocar/legocar.obj",
            "bunny/bunny_tinybvh.obj",
            "sibenik/sibenik.obj",
            "crytek_sponza/crytek_sponza.obj",
            "conference/conference.obj",
        ] {
            if std::env::var("KD_ONLY").is_ok_and(|f| !file.contains(&f)) {
                continue;
            }
            let Some((v, ix)) = obj(file) else {
                eprintln!("{file}: not found, skipped");
                continue;
            };
            let scene = Scene::from_f32(&v, &ix).unwrap();
            let mut st = Store::new(scene.triangle_count() as usize, false);
            let mut kd = st.kd();
            let time = |f: &mut dyn FnMut()| {
                let mut t = [0.0f64; 5];
                for x in &mut t {
                    let t0 = std::time::Instant::now();
                    f();
                    *x = t0.elapsed().as_secs_f64() * 1e3;
                }
                t.sort_by(f64::total_cmp);
                t[2]
            };
            let mut bst = crate::accel::testkit::Store::new(scene.triangle_count() as usize, false);
            let mut bvh = bst.bvh();
            for q in [BuildQuality::Low, BuildQuality::Medium] {
                let bp = crate::BvhParams {
                    quality: q,
                    ..crate::BvhParams::default()
                };
                let ms = time(&mut || {
                    crate::accel::bvh::build::build(&mut bvh, &scene, &bp).unwrap();
                });
                println!("{file}: BVH {q:?} build {ms:.1} ms");
            }
            for q in [BuildQuality::Low, BuildQuality::Medium, BuildQuality::High] {
                let mut p = KdParams {
                    quality: q,
                    ..KdParams::default()
                };
                if let Ok(c) = std::env::var("KD_TRAV") {
                    p.traversal_cost = c.parse().unwrap();
                }
                if let Ok(c) = std::env::var("KD_BINS") {
                    p.bins = c.parse().unwrap();
                }
                let mut info = build(&mut kd, &scene, &p).unwrap();
                let ms = time(&mut || info = build(&mut kd, &scene, &p).unwrap());
                if q != BuildQuality::High {
                    use crate::mem::par::Join;
                    let join = Join::new();
                    let ms2 = time(&mut || {
                        std::thread::scope(|t| {
                            let j = &join;
                            t.spawn(move || j.help(1, 2));
                            join.lead(2, |par| build_with(&mut kd, &scene, &p, par))
                        })
                        .unwrap();
                    });
                    println!(
                        "{file} {q:?}: 2 joined threads {ms2:.1} ms ({:.2}x)",
                        ms / ms2
                    );
                }
                check_invariants(&kd.view().unwrap());
                println!(
                    "{file} {q:?}: tris {} leaves {} empty {:.2}% avg depth {:.2} max {} refs/tri {:.2} nodes/tri {:.2} events/tri {:.2} forced {} sah {:.1} build {:.1} ms",
                    info.triangles,
                    info.leaves,
                    100.0 * info.empty_leaves as f64 / info.leaves as f64,
                    info.avg_leaf_depth,
                    info.depth,
                    info.refs as f64 / info.triangles as f64,
                    info.nodes as f64 / info.triangles as f64,
                    info.events_peak as f64 / info.triangles as f64,
                    info.forced_leaves,
                    info.sah_cost,
                    ms
                );
            }
        }
    }
}
