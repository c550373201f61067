//! The fast kd build (`BuildQuality::Low`, the default, and `Medium`):
//! binned SAH after Shevtsov, Soupikov and Kapustin 2007 ("Highly
//! parallel fast kd-tree construction for interactive ray tracing of
//! dynamic scenes", sections 3-4; Wald and Havran 2006, section 5, name
//! binning as the fast variant of their sweep), on the caller's workers
//! (`mem::par`), the same tree for any worker count.
//!
//! 1. The triangles are classified and stored as the exact build stores
//!    them (`store`, each worker its share); each worker then makes the
//!    references of its share: the triangle's box padded by
//!    `ROOT_PAD` of the scene's scale, and its slot.
//! 2. The top of the tree, level by level (breadth first), in two passes
//!    per level: each worker takes a run of the level's nodes and picks
//!    each one's plane (below) and counts its children's references; the
//!    leader numbers the children and places their lists in the other
//!    half of the scratch; each worker then writes its nodes' children
//!    lists. Nodes of at most `job_size(n)` references, leaves and nodes
//!    whose children do not fit are carried to the next level unchanged.
//!    The top ends when no node of a level splits.
//! 3. The carried nodes are the jobs: each gets a region of the scratch,
//!    the node pool and the reference pool in proportion to its references,
//!    and a worker builds its subtree there depth first (the pending right
//!    children's lists at the bottom of the region, as in `build_sweep.rs`).
//! 4. The leader closes the gaps between the regions (nodes and
//!    references moved down, child and reference indices shifted), then
//!    builds the jobs that outgrew their shares again, in order, in the
//!    pools' rest and the scratch up to the next such job's list.
//!
//! Each node's plane: every reference is binned by its box's lower and
//! upper end on each axis ("min-max binning": `KdParams::bins` bins over
//! the node's box, fewer in small nodes, about two references per bin);
//! the bin boundary of least SAH cost (`build_sweep.rs`'s formula, the
//! empty-space bonus included) splits when it beats the leaf cost. Nodes
//! of at most `traversal_cost` references are leaves without a search
//! (no split can cost less). A reference goes left when its box starts
//! below the plane and right when it ends above it. A reference on both
//! sides is clipped to each child: `Medium` clips the triangle to the
//! split plane moved by the padding towards the other child, pads the
//! part's box and intersects it with the reference's box (the box of the
//! triangle clipped to the child box, as `build_sweep.rs`'s perfect
//! splits, or a little larger: the cut by the ancestors' planes is kept
//! from the reference's box); `Low` intersects the reference's box with
//! the child's padded box.
//!
//! # Exactness
//! Each leaf holds every triangle whose padded, clipped box meets the
//! leaf's box, as the exact build's leaves do: the tree keeps the
//! invariants `mod.rs` (Exactness) argues from, so every kd method
//! returns on it the triangle and bitwise t of the kd single ray, and
//! the single ray the brute-force nearest hit.
//!
//! # Deviations
//! - Binned planes lie on bin boundaries: empty space is cut off to the
//!   nearest boundary, not to a triangle's box.
//! - A bin index is the clamped place rounded by adding 2^23 (the float
//!   to integer conversion of the baseline ISA is scalar); the bins only
//!   estimate the counts, which `count` then takes by comparing floats.
//! - A job's subtree has its share of the pools; a job that outgrows it
//!   stops and the leader builds it again, after the others, in what they
//!   left (its list stays at the start of its scratch share). Leaves are
//!   forced (`KdInfo::forced_leaves`) only in that second build, where
//!   the exact build, with one pool for the whole tree, may not force
//!   them.
//! - `KdInfo::events_peak` counts the scratch words the top's two levels
//!   and the jobs' lists held (the regions are spread over the whole
//!   scratch).

use super::store::{Stored, half_area, store};
use super::{KdInfo, KdNode, KdParams, KdPools, MAX_DEPTH};
use crate::accel::bvh::BuildQuality;
use crate::error::{Error, Pool, Result};
use crate::geom::{Aabb, Scene, TriVerts};
use crate::mem::par::{MAX_WORKERS, Par, Parts, share};
use bytemuck::{Pod, Zeroable};
use glam::{Vec3, Vec3A};

/// A triangle reference during the build: its padded (and clipped) box
/// and its stored slot (28 bytes; the event pool holds 4 per triangle by
/// the default limits).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct Ref {
    lo: [f32; 3],
    hi: [f32; 3],
    slot: u32,
}

/// Most nodes of one level of the top, and so most jobs.
pub const MAX_JOBS: usize = 256;

/// Most bins (`MAX_BINS`, a power of two).
const BINS: usize = crate::accel::bvh::MAX_BINS as usize;
const _: () = assert!(BINS.is_power_of_two());

/// References of a node the top hands to a job (about 64 jobs per build).
fn job_size(n: usize) -> usize {
    (n / 64).max(512)
}

/// A node of a level of the top; the last level's are the jobs.
#[repr(C)]
#[derive(Clone, Copy, Default, Pod, Zeroable)]
struct Node {
    sah_inner: f64,
    sah_leaf: f64,
    depth_sum: u64,
    min: [f32; 3],
    max: [f32; 3],
    node: u32,
    depth: u32,
    /// Its list in the scratch.
    off: u32,
    n: u32,
    /// The plane pass 1 picked (`split` 1), and its children's references
    /// (upper bounds; pass 2 writes the exact counts on the children).
    axis: u32,
    pos: f32,
    split: u32,
    nl: u32,
    nr: u32,
    /// A job's results: its root node, what it used of its regions, its tallies.
    root_a: u32,
    root_b: u32,
    nodes_used: u32,
    refs_used: u32,
    leaves: u32,
    empty: u32,
    max_depth: u32,
    forced: u32,
    peak: u32,
    /// A job's references before it (its regions' place).
    at: u32,
    /// 1: the job outgrew its share of the pools (built again at the end).
    overflow: u32,
    /// 1: the SAH (or the depth limit) made it a leaf; carried nodes and
    /// job roots are not searched again.
    settled: u32,
    _pad: u32,
}

const NODE_WORDS: usize = core::mem::size_of::<Node>() / 8;

impl Node {
    fn bounds(&self) -> Aabb {
        Aabb {
            min: self.min.into(),
            max: self.max.into(),
        }
    }
}

/// What every step reads.
struct Cx<'a> {
    tris: &'a [TriVerts],
    pad: Vec3,
    p: KdParams,
    max_depth: u32,
}

/// Split plane of a node.
#[derive(Clone, Copy)]
struct Plane {
    axis: usize,
    pos: f32,
    cost: f32,
}

/// The cheapest plane strictly inside `b` for the references `refs`.
fn choose(refs: &[Ref], b: &Aabb, p: &KdParams) -> Option<Plane> {
    let area = half_area(b);
    let inv = if area > 0.0 { 1.0 / area } else { return None };
    let n = refs.len();
    // Fewer bins in small nodes: about two references per bin.
    let k = (p.bins as usize).min((n / 2).max(4));
    if k <= 16 {
        binned::<16>(refs, b, p, k, inv)
    } else {
        binned::<BINS>(refs, b, p, k, inv)
    }
}

/// `choose` by `k` bins (`k <= K`; `K` a power of two sizes the counters,
/// so small nodes clear few).
fn binned<const K: usize>(
    refs: &[Ref],
    b: &Aabb,
    p: &KdParams,
    k: usize,
    inv: f32,
) -> Option<Plane> {
    let n = refs.len();
    let d = Vec3A::from(b.max - b.min);
    let scale = Vec3A::select(
        d.cmpgt(Vec3A::ZERO),
        Vec3A::splat(k as f32) / d,
        Vec3A::ZERO,
    );
    let (min, top) = (Vec3A::from(b.min), Vec3A::splat((k - 1) as f32));
    // A start's or end's bin: its place in bins, clamped into them (NaN
    // to bin 0), rounded by adding 2^23 (the integer in the low mantissa
    // bits; round(v - 0.5) is floor(v) but at ties). Bins only estimate
    // the counts; the references are classified by comparing floats.
    let bin = |v: [f32; 3]| {
        let t = ((Vec3A::from(v) - min) * scale - Vec3A::splat(0.5))
            .max(Vec3A::ZERO)
            .min(top)
            + Vec3A::splat(8_388_608.0);
        t.to_array().map(|x| x.to_bits() as usize & (K - 1))
    };
    // Per axis the starts' and ends' bins (masks keep the indexing
    // unchecked: the clamp keeps every bin below `k`).
    let mut lo = [[0u32; K]; 3];
    let mut hi = [[0u32; K]; 3];
    for r in refs {
        let (i, j) = (bin(r.lo), bin(r.hi));
        for a in 0..3 {
            lo[a][i[a]] += 1;
            hi[a][j[a]] += 1;
        }
    }
    // The sweep compares the area-weighted counts; the cost is made of
    // the best one.
    let n = n as u32;
    let keep = 1.0 - p.empty_bonus;
    let (mut best_w, mut best_at) = (f32::INFINITY, None);
    for axis in 0..3 {
        if d[axis] <= 0.0 {
            continue;
        }
        let (o1, o2) = ((axis + 1) % 3, (axis + 2) % 3);
        let (cap, perim) = (d[o1] * d[o2], d[o1] + d[o2]);
        let step = d[axis] / k as f32;
        let (mut nl, mut nr) = (0u32, n);
        for i in 1..k {
            nl += lo[axis][i - 1];
            nr -= hi[axis][i - 1];
            let off = step * i as f32;
            let w = (cap + off * perim) * nl as f32 + (cap + (d[axis] - off) * perim) * nr as f32;
            let w = if nl == 0 || nr == 0 { w * keep } else { w };
            if w < best_w {
                let x = b.min[axis] + off;
                if x > b.min[axis] && x < b.max[axis] {
                    (best_w, best_at) = (w, Some((axis, x)));
                }
            }
        }
    }
    best_at.map(|(axis, pos)| Plane {
        axis,
        pos,
        cost: p.traversal_cost + best_w * inv,
    })
}

/// References of `refs` going left and right of `pl` (upper bounds: a
/// perfect split may clip a reference out of a child).
#[inline]
fn count(refs: &[Ref], pl: &Plane) -> (usize, usize) {
    let (mut l, mut r) = (0usize, 0usize);
    for q in refs {
        let (left, right) = sides(q, pl);
        l += left as usize;
        r += right as usize;
    }
    (l, r)
}

/// Whether reference `q` goes left (its box starts below the plane) and
/// right (it ends above it, or does not go left: a box of no width on the
/// plane goes right), for `count` and `divide` alike.
#[inline(always)]
fn sides(q: &Ref, pl: &Plane) -> (bool, bool) {
    let left = q.lo[pl.axis] < pl.pos;
    (left, q.hi[pl.axis] > pl.pos || !left)
}

/// The children boxes of `b` at `pl`.
fn children(b: &Aabb, pl: &Plane) -> (Aabb, Aabb) {
    let (mut l, mut r) = (*b, *b);
    l.max[pl.axis] = pl.pos;
    r.min[pl.axis] = pl.pos;
    (l, r)
}

/// `src`'s references into the children's lists `left` and `right` (sized
/// by `count`); returns how many each got.
fn divide(
    src: &[Ref],
    pl: &Plane,
    b: &Aabb,
    cx: &Cx<'_>,
    left: &mut [Ref],
    right: &mut [Ref],
) -> (usize, usize) {
    let (lb, rb) = children(b, pl);
    let perfect = cx.p.quality != BuildQuality::Low;
    let (mut wl, mut wr) = (0usize, 0usize);
    for q in src {
        let (l, r) = sides(q, pl);
        if !(l && r) {
            if l {
                left[wl] = *q;
                wl += 1;
            } else {
                right[wr] = *q;
                wr += 1;
            }
            continue;
        }
        let padded = |c: Aabb| Ref {
            lo: Vec3::from(q.lo).max(c.min - cx.pad).into(),
            hi: Vec3::from(q.hi).min(c.max + cx.pad).into(),
            slot: q.slot,
        };
        let (cl, cr) = if perfect {
            let tri = &cx.tris[q.slot as usize];
            let (bl, br) = halves(tri, pl.axis, pl.pos + cx.pad.x, pl.pos - cx.pad.x);
            let within = |c: Option<Aabb>| {
                let c = c?;
                let r = Ref {
                    lo: (c.min - cx.pad).max(q.lo.into()).into(),
                    hi: (c.max + cx.pad).min(q.hi.into()).into(),
                    slot: q.slot,
                };
                (0..3).all(|a| r.lo[a] <= r.hi[a]).then_some(r)
            };
            match (within(bl), within(br)) {
                // Rounding could clip a straddler away on both sides:
                // keep it in both with its box in the child boxes.
                (None, None) => (Some(padded(lb)), Some(padded(rb))),
                c => c,
            }
        } else {
            // `Low`: the reference's box in each child's padded box.
            (Some(padded(lb)), Some(padded(rb)))
        };
        if let Some(c) = cl {
            left[wl] = c;
            wl += 1;
        }
        if let Some(c) = cr {
            right[wr] = c;
            wr += 1;
        }
    }
    (wl, wr)
}

/// The boxes of the parts of triangle `t` at or below `below` and at or
/// above `above` on `axis` (edge crossings in f64), `None` when empty.
fn halves(t: &TriVerts, axis: usize, below: f32, above: f32) -> (Option<Aabb>, Option<Aabb>) {
    let v = [t.v0, t.v1, t.v2];
    let mut out = [None::<Aabb>; 2];
    for (side, plane) in [(0usize, below), (1, above)] {
        let inside = |p: &[f32; 3]| {
            if side == 0 {
                p[axis] <= plane
            } else {
                p[axis] >= plane
            }
        };
        let mut b = Aabb::EMPTY;
        let mut any = false;
        for i in 0..3 {
            let (p, q) = (&v[i], &v[(i + 1) % 3]);
            if inside(p) {
                b.grow(Vec3::from(*p));
                any = true;
            }
            if inside(p) != inside(q) {
                let (pa, qa) = (p[axis] as f64, q[axis] as f64);
                let f = (plane as f64 - pa) / (qa - pa);
                let mut x = [0f32; 3];
                for (k, xk) in x.iter_mut().enumerate() {
                    *xk = (p[k] as f64 + f * (q[k] as f64 - p[k] as f64)) as f32;
                }
                x[axis] = plane;
                b.grow(Vec3::from(x));
                any = true;
            }
        }
        out[side] = any.then_some(b);
    }
    (out[0], out[1])
}

/// The plane a node of `refs` splits at, if the SAH wants a split.
#[inline]
fn wanted(refs: &[Ref], b: &Aabb, depth: u32, cx: &Cx<'_>) -> Option<Plane> {
    // A split costs at least `traversal_cost`, a leaf `n`.
    if refs.len() as f32 <= cx.p.traversal_cost || depth >= cx.max_depth {
        return None;
    }
    choose(refs, b, &cx.p).filter(|pl| pl.cost < refs.len() as f32)
}

/// Build `pools` from `scene` on `par`'s `workers` (`p` validated, not `High`).
pub(super) fn build(
    pools: &mut KdPools<'_>,
    scene: &Scene<'_>,
    p: &KdParams,
    par: &dyn Par,
    workers: usize,
) -> Result<KdInfo> {
    // The job list (two levels) at the start of the event pool, the
    // references after it, in two halves for the top's levels.
    let words = pools.events.len();
    // One job per 1024 words of the pool (the two lists take about a
    // thirtieth of it), at most `MAX_JOBS`.
    let jobs_cap = (words / 1024).min(MAX_JOBS);
    let ref_words = words - 2 * jobs_cap * NODE_WORDS;
    let ref_cap = ref_words * 8 / core::mem::size_of::<Ref>();
    let stored = store(pools, scene, p, par, workers, |_, n| {
        if jobs_cap == 0 || ref_cap < 2 * n {
            return Err(Error::Capacity {
                pool: Pool::Triangles,
                needed: n as u64,
                available: (ref_cap / 2) as u64,
            });
        }
        Ok(())
    })?;
    let Stored { n, mut info, pad } = match stored {
        Ok(s) => s,
        Err(empty) => return Ok(empty),
    };
    let KdPools {
        nodes,
        refs,
        tris,
        events,
        ..
    } = pools;
    let (desc, scratch) = events.split_at_mut(2 * jobs_cap * NODE_WORDS);
    let (cur, nxt) = bytemuck::cast_slice_mut::<u64, Node>(desc).split_at_mut(jobs_cap);
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(scratch);
    let sc: &mut [Ref] =
        bytemuck::cast_slice_mut(&mut bytes[..ref_cap * core::mem::size_of::<Ref>()]);
    let cx = Cx {
        tris: &tris[..n],
        pad,
        p: *p,
        max_depth: info.max_depth,
    };
    let root = info.root;
    let root_area = half_area(&root) as f64;

    // 1. The references of the stored triangles.
    {
        let rs = Parts::even(&mut sc[..n], workers);
        par.run(&|w| {
            let (out, first) = (rs.get(w), rs.start(w));
            for (k, r) in out.iter_mut().enumerate() {
                let t = &cx.tris[first + k];
                let lo = Vec3::from(t.v0).min(t.v1.into()).min(t.v2.into());
                let hi = Vec3::from(t.v0).max(t.v1.into()).max(t.v2.into());
                *r = Ref {
                    lo: (lo - pad).into(),
                    hi: (hi + pad).into(),
                    slot: (first + k) as u32,
                };
            }
        });
    }

    // 2. The top, level by level: lists alternate between the halves.
    let half = ref_cap / 2;
    let mut levels = (&mut *cur, &mut *nxt);
    levels.0[0] = Node {
        min: root.min.into(),
        max: root.max.into(),
        n: n as u32,
        ..Node::default()
    };
    let mut m = 1usize;
    let mut in_upper = false;
    let mut next_node = 1usize;
    let mut top_inner = 0.0f64;
    let mut peak = n;
    let big = job_size(n);
    loop {
        let (lv, nx) = (&mut *levels.0, &mut *levels.1);
        let lv = &mut lv[..m];
        let src_at = if in_upper { half } else { 0 };
        // Pass 1: planes and counts.
        let runs = runs_of(lv, workers);
        {
            let ls = Parts::at(&mut *lv, &runs[..workers + 1]);
            let sc = &*sc;
            par.run(&|w| {
                for nd in ls.get(w).iter_mut() {
                    nd.split = 0;
                    if (nd.n as usize) <= big || nd.settled == 1 {
                        continue;
                    }
                    let list = &sc[src_at + nd.off as usize..][..nd.n as usize];
                    match wanted(list, &nd.bounds(), nd.depth, &cx) {
                        Some(pl) => {
                            let (l, r) = count(list, &pl);
                            (nd.axis, nd.pos, nd.split) = (pl.axis as u32, pl.pos, 1);
                            (nd.nl, nd.nr) = (l as u32, r as u32);
                        }
                        None => nd.settled = 1,
                    }
                }
            });
        }
        // The leader numbers the children and places their lists; a node
        // splits only when every later node of the level can still be
        // carried (one job entry and its list each).
        let (mut k, mut at, mut any) = (0usize, 0usize, false);
        let mut later: usize = lv.iter().map(|nd| nd.n as usize).sum();
        let nodes_len = nodes.len().min(KdNode::MAX_COUNT as usize);
        for (i, nd) in lv.iter_mut().enumerate() {
            later -= nd.n as usize;
            let (c, rest) = ((nd.nl + nd.nr) as usize, m - i - 1);
            let splits = nd.split == 1
                && k + 2 + rest <= jobs_cap
                && at + c + later <= half
                && at + c + later <= refs.len()
                && next_node + 2 <= nodes_len;
            if splits {
                let (l, r) = children(
                    &nd.bounds(),
                    &Plane {
                        axis: nd.axis as usize,
                        pos: nd.pos,
                        cost: 0.0,
                    },
                );
                nodes[nd.node as usize] = KdNode::inner(nd.axis as usize, nd.pos, next_node as u32);
                top_inner += half_area(&nd.bounds()) as f64;
                for (j, (b, cnt)) in [(l, nd.nl), (r, nd.nr)].into_iter().enumerate() {
                    nx[k + j] = Node {
                        min: b.min.into(),
                        max: b.max.into(),
                        node: (next_node + j) as u32,
                        depth: nd.depth + 1,
                        off: (at + j * nd.nl as usize) as u32,
                        n: cnt,
                        ..Node::default()
                    };
                }
                next_node += 2;
                (k, at, any) = (k + 2, at + c, true);
            } else {
                // Carried: the checks above kept room for it.
                nd.split = 0;
                nx[k] = Node {
                    off: at as u32,
                    ..*nd
                };
                (k, at) = (k + 1, at + nd.n as usize);
            }
        }
        if !any {
            break;
        }
        // Pass 2: the children's lists (and the carried nodes' copies).
        {
            let mut ob = [0usize; MAX_WORKERS + 1];
            let mut kb = [0usize; MAX_WORKERS + 1];
            let (mut kk, mut j) = (0usize, 0usize);
            for w in 0..workers {
                while j < runs[w + 1] {
                    kk += 1 + lv[j].split as usize;
                    j += 1;
                }
                kb[w + 1] = kk;
                ob[w + 1] = if kk < k { nx[kk].off as usize } else { at };
            }
            let (src, dst) = if in_upper {
                let (a, b) = sc.split_at_mut(half);
                (&*b, a)
            } else {
                let (a, b) = sc.split_at_mut(half);
                (&*a, b)
            };
            let (ls, ns, ds) = (
                Parts::at(&mut *lv, &runs[..workers + 1]),
                Parts::at(&mut nx[..k], &kb[..workers + 1]),
                Parts::at(&mut dst[..at], &ob[..workers + 1]),
            );
            par.run(&|w| {
                let (mine, kids, out, base) = (ls.get(w), ns.get(w), ds.get(w), ds.start(w));
                let mut kk = 0usize;
                for nd in mine.iter() {
                    let list = &src[nd.off as usize..][..nd.n as usize];
                    if nd.split == 0 {
                        let o = kids[kk].off as usize - base;
                        out[o..o + list.len()].copy_from_slice(list);
                        kk += 1;
                        continue;
                    }
                    let o = kids[kk].off as usize - base;
                    let (l, r) = out[o..o + (nd.nl + nd.nr) as usize].split_at_mut(nd.nl as usize);
                    let pl = Plane {
                        axis: nd.axis as usize,
                        pos: nd.pos,
                        cost: 0.0,
                    };
                    let (wl, wr) = divide(list, &pl, &nd.bounds(), &cx, l, r);
                    kids[kk].n = wl as u32;
                    kids[kk + 1].n = wr as u32;
                    kk += 2;
                }
            });
        }
        peak = peak.max(half + at);
        m = k;
        in_upper = !in_upper;
        levels = (levels.1, levels.0);
    }
    let jobs = &mut levels.0[..m];
    let top_next = next_node;

    // 3. The jobs' lists packed at the scratch's start, then spread over
    // it in proportion to their references (each moved up, the last
    // first); the node and reference pools are shared out the same way.
    let mut total = 0usize;
    for j in jobs.iter_mut() {
        let from = j.off as usize + if in_upper { half } else { 0 };
        sc.copy_within(from..from + j.n as usize, total);
        j.at = total as u32;
        total += j.n as usize;
    }
    let nodes_len = nodes.len().min(KdNode::MAX_COUNT as usize);
    let node_cap = nodes_len - top_next;
    let (refs_len, total_) = (refs.len(), total.max(1));
    // Region starts of the job with `at` references before it.
    let region = |at: usize| {
        let part = |cap: usize| (at as u128 * cap as u128 / total_ as u128) as usize;
        (part(ref_cap), top_next + part(node_cap), part(refs_len))
    };
    for j in jobs.iter_mut().rev() {
        let to = region(j.at as usize).0;
        sc.copy_within(j.at as usize..(j.at + j.n) as usize, to);
    }
    let runs = runs_of(jobs, workers);
    let (mut sb, mut nb, mut rb) = (
        [0usize; MAX_WORKERS + 1],
        [0; MAX_WORKERS + 1],
        [0; MAX_WORKERS + 1],
    );
    for w in 0..=workers {
        let at = jobs.get(runs[w]).map_or(total, |j| j.at as usize);
        (sb[w], nb[w], rb[w]) = region(at);
    }
    {
        let (js, ss, ns, rs) = (
            Parts::at(&mut *jobs, &runs[..workers + 1]),
            Parts::at(&mut *sc, &sb[..workers + 1]),
            Parts::at(&mut nodes[..nodes_len], &nb[..workers + 1]),
            Parts::at(&mut refs[..], &rb[..workers + 1]),
        );
        par.run(&|w| {
            let mine = js.get(w);
            let (s, nd, rf) = (ss.get(w), ns.get(w), rs.get(w));
            let origin = (ss.start(w), ns.start(w), rs.start(w));
            for j in mine.iter_mut() {
                let (a, b) = (region(j.at as usize), region((j.at + j.n) as usize));
                let out = Share {
                    nodes: &mut nd[a.1 - origin.1..b.1 - origin.1],
                    nodes_at: a.1,
                    refs: &mut rf[a.2 - origin.2..b.2 - origin.2],
                    refs_at: a.2,
                };
                subtree(j, &mut s[a.0 - origin.0..b.0 - origin.0], out, &cx, true);
            }
        });
    }

    // 4. The regions moved down in order, indices shifted; the job roots.
    // Then the jobs that outgrew their shares, in order, in the rest.
    let (mut to, mut rto) = (top_next, 0usize);
    let (mut inner, mut leaf) = (top_inner, 0.0f64);
    let mut depth_sum = 0u64;
    let mut job_peak = 0usize;
    // A retried job's leaf needs its references: the ones later retried
    // jobs are owed stay free (their shares exceeded their lists).
    let mut owed: usize = jobs
        .iter()
        .filter(|j| j.overflow == 1)
        .map(|j| j.n as usize)
        .sum();
    let mut retry_ends = [0usize; MAX_JOBS];
    let mut retries = 0usize;
    for j in jobs.iter().filter(|j| j.overflow == 1) {
        retry_ends[retries] = region(j.at as usize).0;
        retries += 1;
    }
    for again in [false, true] {
        for j in jobs.iter_mut() {
            if (j.overflow == 1) != again {
                continue;
            }
            let (from, rfrom) = if again {
                owed -= j.n as usize;
                // The scratch up to the next retried job's list (the
                // finished jobs' lists are dead).
                let s0 = region(j.at as usize).0;
                let s1 = retry_ends[..retries]
                    .iter()
                    .copied()
                    .find(|&e| e > s0)
                    .unwrap_or(ref_cap);
                let out = Share {
                    nodes: &mut nodes[to..nodes_len],
                    nodes_at: to,
                    refs: &mut refs[rto..refs_len - owed],
                    refs_at: rto,
                };
                subtree(j, &mut sc[s0..s1], out, &cx, false);
                (to, rto)
            } else {
                let (_, from, rfrom) = region(j.at as usize);
                (from, rfrom)
            };
            let (used, rused) = (j.nodes_used as usize, j.refs_used as usize);
            let (shift, rshift) = ((from - to) as u32, (rfrom - rto) as u32);
            let moved = |nd: KdNode| {
                if nd.is_leaf() {
                    KdNode::leaf(nd.a - rshift, nd.count() as u32)
                } else {
                    KdNode::inner(nd.axis(), nd.split(), nd.left() as u32 - shift)
                }
            };
            // Either pool's region may move alone: the leaves name
            // references, the inner nodes children.
            if shift > 0 {
                nodes.copy_within(from..from + used, to);
            }
            if shift > 0 || rshift > 0 {
                for nd in &mut nodes[to..to + used] {
                    *nd = moved(*nd);
                }
            }
            if rshift > 0 {
                refs.copy_within(rfrom..rfrom + rused, rto);
            }
            nodes[j.node as usize] = moved(KdNode {
                a: j.root_a,
                b: j.root_b,
            });
            to += used;
            rto += rused;
            info.leaves += j.leaves;
            info.empty_leaves += j.empty;
            info.forced_leaves += j.forced;
            info.depth = info.depth.max(j.max_depth);
            depth_sum += j.depth_sum;
            inner += j.sah_inner;
            leaf += j.sah_leaf;
            job_peak += j.peak as usize;
        }
    }
    info.nodes = to as u32;
    info.refs = rto as u32;
    info.avg_leaf_depth = (depth_sum as f64 / info.leaves as f64) as f32;
    let words = |refs: usize| (refs * core::mem::size_of::<Ref>()).div_ceil(8);
    info.events_peak = (2 * jobs_cap * NODE_WORDS + words(peak.max(job_peak))) as u32;
    info.sah_cost = ((p.traversal_cost as f64 * inner + leaf) / root_area) as f32;
    Ok(info)
}

/// Runs of `nodes` of about equal reference counts, one per worker (the
/// bounds `0..=workers`).
fn runs_of(nodes: &[Node], workers: usize) -> [usize; MAX_WORKERS + 1] {
    let weight = |nd: &Node| nd.n as usize + 1;
    let total: usize = nodes.iter().map(weight).sum();
    let mut b = [nodes.len(); MAX_WORKERS + 1];
    b[0] = 0;
    let (mut k, mut acc) = (0usize, 0usize);
    let each = share(total, 0, workers).len();
    for (w, bw) in b.iter_mut().enumerate().take(workers).skip(1) {
        while k < nodes.len() && acc < each * w {
            acc += weight(&nodes[k]);
            k += 1;
        }
        *bw = k;
    }
    b
}

/// Where a job writes: nodes from the pool's `nodes_at`, references from
/// its `refs_at`.
struct Share<'a> {
    nodes: &'a mut [KdNode],
    nodes_at: usize,
    refs: &'a mut [u32],
    refs_at: usize,
}

/// A pending right child of the depth-first build.
#[derive(Clone, Copy)]
struct Task {
    node: usize,
    depth: u32,
    n: usize,
    base: usize,
    bounds: Aabb,
}

/// Step 3: job `j`'s subtree, depth first, its list at the start of its
/// scratch region `sc` (left there), its nodes in `nodes` (the pool's
/// `nodes_at..`), its references in `refs` (the pool's `refs_at..`). On
/// the `first_try`, a split that does not fit the scratch, node or
/// reference share stops the job (`overflow`); otherwise it makes a
/// forced leaf.
fn subtree(j: &mut Node, sc: &mut [Ref], out: Share<'_>, cx: &Cx<'_>, first_try: bool) {
    let Share {
        nodes,
        nodes_at,
        refs,
        refs_at,
    } = out;
    j.overflow = 0;
    let mut stack = [Task {
        node: 0,
        depth: 0,
        n: 0,
        base: 0,
        bounds: Aabb::EMPTY,
    }; MAX_DEPTH + 1];
    let (mut sp, mut next, mut nref, mut pending) = (0usize, 0usize, 0usize, 0usize);
    let mut root = KdNode::default();
    let mut set = |nodes: &mut [KdNode], at: usize, nd: KdNode| {
        if at < nodes_at {
            root = nd;
        } else {
            nodes[at - nodes_at] = nd;
        }
    };
    let (mut inner, mut leaf, mut depth_sum) = (0.0f64, 0.0f64, 0u64);
    let (mut leaves, mut empty, mut forced, mut max_depth) = (0u32, 0u32, 0u32, 0u32);
    let mut peak = j.n as usize;
    let mut task = Task {
        node: j.node as usize,
        depth: j.depth,
        n: j.n as usize,
        base: 0,
        bounds: j.bounds(),
    };
    loop {
        let (nn, base) = (task.n, task.base);
        let area = half_area(&task.bounds) as f64;
        // A root the top already searched in vain is a leaf.
        let settled = task.node == j.node as usize && j.settled == 1;
        let plane = if settled {
            None
        } else {
            wanted(&sc[base..base + nn], &task.bounds, task.depth, cx)
        };
        if let Some(pl) = plane {
            let top = base + nn;
            // Each child's list holds at most `nn`: with room for both
            // bounds, counting first decides nothing (what fits them fits
            // the counts).
            let (cl, cr) = if top + 2 * nn <= sc.len() && nref + pending + 2 * nn <= refs.len() {
                (nn, nn)
            } else {
                count(&sc[base..base + nn], &pl)
            };
            let room = next + 2 <= nodes.len()
                && nref + pending + cl + cr <= refs.len()
                && top + cl + cr <= sc.len();
            if !room && first_try {
                // Out of this job's share: the leader builds it again in
                // what the other jobs left (its list is still at the start).
                j.overflow = 1;
                return;
            }
            if room {
                let (src, dst) = sc.split_at_mut(top);
                let (r, l) = dst[..cl + cr].split_at_mut(cr);
                let (wl, wr) = divide(&src[base..], &pl, &task.bounds, cx, l, r);
                peak = peak.max(top + cr + wl);

                // The right list at the bottom (pending), the left above
                // it; the job's own list stays where it is.
                let (rb_at, lb_at) = if task.node == j.node as usize {
                    sc.copy_within(top + cr..top + cr + wl, top + wr);
                    (top, top + wr)
                } else {
                    sc.copy_within(top..top + wr, base);
                    sc.copy_within(top + cr..top + cr + wl, base + wr);
                    (base, base + wr)
                };
                let left = nodes_at + next;
                next += 2;
                set(
                    nodes,
                    task.node,
                    KdNode::inner(pl.axis, pl.pos, left as u32),
                );
                inner += area;
                let (lb, rb) = children(&task.bounds, &pl);
                stack[sp] = Task {
                    node: left + 1,
                    depth: task.depth + 1,
                    n: wr,
                    base: rb_at,
                    bounds: rb,
                };
                sp += 1;
                pending += wr;
                task = Task {
                    node: left,
                    depth: task.depth + 1,
                    n: wl,
                    base: lb_at,
                    bounds: lb,
                };
                continue;
            }
            forced += 1;
        }
        for (k, q) in sc[base..base + nn].iter().enumerate() {
            refs[nref + k] = q.slot;
        }
        set(
            nodes,
            task.node,
            KdNode::leaf((refs_at + nref) as u32, nn as u32),
        );
        nref += nn;
        leaves += 1;
        empty += (nn == 0) as u32;
        depth_sum += task.depth as u64;
        max_depth = max_depth.max(task.depth);
        leaf += area * nn as f64;
        if sp == 0 {
            break;
        }
        sp -= 1;
        task = stack[sp];
        pending -= task.n;
    }
    (j.root_a, j.root_b) = (root.a, root.b);
    (j.nodes_used, j.refs_used) = (next as u32, nref as u32);
    (j.leaves, j.empty, j.forced, j.max_depth) = (leaves, empty, forced, max_depth);
    (j.sah_inner, j.sah_leaf, j.depth_sum) = (inner, leaf, depth_sum);
    j.peak = peak as u32;
}
