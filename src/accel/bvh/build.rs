//! Per-frame BVH build: binned SAH (BVH paper section 5.1, after Wald 2007,
//! "On fast construction of SAH-based bounding volume hierarchies",
//! sections 3-4), single-threaded, into the preallocated pools.
//!
//! 1. Read the triangles once: classify (`Scene::classify`), write one
//!    `PrimRef` (box and caller id) per traceable triangle into the build
//!    scratch, and the scene and centroid bounds. Fail with a capacity error
//!    before anything a traversal reads is written.
//! 2. Top-down split with an explicit work stack of `MAX_DEPTH + 1` entries
//!    (one child is processed, the other pushed; no recursion). Per node:
//!    `bins` bins along each of the three axes over the centroid bounds
//!    (Wald 2007, section 3.2: `bin = k1 (c - cmin)`,
//!    `k1 = bins (1 - eps) / extent`), the SAH of every bin plane (two
//!    sweeps, the three axes side by side in SIMD lanes), and an in-place
//!    partition of the `PrimRef` range.
//! 3. A node becomes a leaf with one triangle, at `MAX_DEPTH`, or when it
//!    holds at most `leaf_size` triangles and its SAH leaf cost `N` is not
//!    above the best split's `C_trav + (A_L N_L + A_R N_R) / A` (Eq. 1 of
//!    Wald 2007, triangle test cost 1). Leaves store their triangles in leaf
//!    order (`tris`, `proj`, `tri_ids`), and `slot_of` maps caller ids back.
//!
//! # Deviations
//! - Nodes of at most `SWEEP_MAX` (12) references are split by the full
//!   SAH sweep over their centroids sorted along each axis (every object
//!   split, so never worse than the bins) instead of binning: below about
//!   the bin count, resetting and sweeping the bins costs more than sorting.
//! - Nodes holding more than `leaf_size` triangles whose centroids all
//!   coincide (no bin plane separates them: duplicated triangles, common in
//!   the conference scene) are split at the object median, so such a heap
//!   of N copies still ends in leaves of `leaf_size` after `log2 N` levels;
//!   the sweep prefers the most balanced of equal-cost splits for the same
//!   reason.
//! - Every stored box is padded by `BOX_PAD * (max |coordinate| + diagonal)`
//!   of the scene (see `mod.rs`, Exactness); `BvhInfo::bounds` and the SAH
//!   figures use the unpadded boxes.
//! - Child centroid bounds are gathered during the partition pass instead of
//!   a separate pass over each child.
//!
//! NOTE(perf): bunny (69,630 triangles) costs about 180 M instructions per
//! build (callgrind), down from 230 M before the sweep for small nodes, the
//! two bin sets, the SIMD bin index and the side-by-side axis sweeps; see
//! the `perf` test below for times.

use super::build_spatial as spatial;
use super::refs::{Box3, PoolRoom, reference_capacity};
use super::{
    BuildQuality, Bvh, BvhInfo, BvhNode, BvhParams, BvhPools, MAX_BINS, MAX_DEPTH, PrimRef,
};
use crate::error::{Error, Pool, Result};
use crate::geom::{Aabb, Excluded, INVALID_ID, ProjTri, Scene, TriTest, TriVerts};
use crate::mem::par::{MAX_WORKERS, Par, Parts, atomic_u32};
use core::sync::atomic::AtomicU32;
use glam::Vec3A;

/// Half areas of three boxes, one per lane (x: `b[0]`, ...).
#[inline(always)]
fn areas3(b: &[Box3; 3]) -> Vec3A {
    let (d0, d1, d2) = (
        b[0].max - b[0].min,
        b[1].max - b[1].min,
        b[2].max - b[2].min,
    );
    let dx = Vec3A::new(d0.x, d1.x, d2.x);
    let dy = Vec3A::new(d0.y, d1.y, d2.y);
    let dz = Vec3A::new(d0.z, d1.z, d2.z);
    dx * dy + dy * dz + dz * dx
}

/// The lane of the smallest of `cost` (lanes in `ok` only; ties: the lowest
/// lane), or `None`.
#[inline(always)]
fn min_lane(cost: Vec3A, ok: u32) -> Option<usize> {
    let mut best: Option<usize> = None;
    for a in 0..3 {
        if ok & (1 << a) != 0 && best.is_none_or(|b| cost[a] < cost[b]) {
            best = Some(a);
        }
    }
    best
}

/// Twice the centroid of a reference (the factor cancels in binning).
#[inline(always)]
fn centroid2(r: &PrimRef) -> Vec3A {
    let b = Box3::of(r);
    b.min + b.max
}

/// A node waiting to be split: its `PrimRef` range, box and centroid box.
#[derive(Clone, Copy, Debug)]
struct Task {
    node: u32,
    begin: u32,
    end: u32,
    /// End of the node's share of the references: `refs[end..cap]` is its
    /// part of the spatial-split reserve.
    cap: u32,
    depth: u32,
    bounds: Box3,
    cent: Box3,
}

/// Binning of one node along the three axes (objects) and in space
/// (`build_spatial.rs`). The calling thread's top bins its large nodes on
/// every worker of `par`, each a share of the references into its own
/// bins, merged in worker order: bin boxes and counts are minima, maxima
/// and sums, the same whatever the shares, so the tree is too. A job's
/// binner has one set of bins and runs alone.
struct Binner<'s> {
    bins: usize,
    /// One per worker of `par`.
    m: &'s mut [Bins],
    sm: &'s mut [spatial::SpatialBins],
    par: &'s dyn Par,
}

/// Nodes of at least this many references bin on every worker.
const PAR_BINNING: usize = 4096;

/// The bins of a `Binner`: two sets of three axes (in the build scratch,
/// not on the caller's stack).
#[derive(Clone, Copy)]
struct Bins {
    boxes: [[[Box3; MAX_BINS as usize]; 3]; 2],
    counts: [[[u32; MAX_BINS as usize]; 3]; 2],
}

const EMPTY_BINS: Bins = Bins {
    boxes: [[[Box3::EMPTY; MAX_BINS as usize]; 3]; 2],
    counts: [[[0; MAX_BINS as usize]; 3]; 2],
};

const NO_TASK: Task = Task {
    node: 0,
    begin: 0,
    end: 0,
    cap: 0,
    depth: 0,
    bounds: Box3::EMPTY,
    cent: Box3::EMPTY,
};

/// Bytes of `BvhPools::scratch`: the larger of the SAH build's and the
/// fast build's (per-worker radix counts, jobs).
pub const SCRATCH: usize = if SAH_SCRATCH > super::build_morton::SCRATCH {
    SAH_SCRATCH
} else {
    super::build_morton::SCRATCH
};

/// The best bin plane of a node: references with bin `< pos` on `axis` go left.
#[derive(Clone, Copy, Debug)]
struct Split {
    axis: usize,
    pos: usize,
    /// `A_L N_L + A_R N_R` (half areas).
    cost: f32,
    left: Box3,
    right: Box3,
}

/// Bin mapping of a node (Wald 2007, section 3.2): bin
/// `floor(clamp(k (c - cmin), 0, bins - 1))`, `k = bins (1 - eps) / extent`.
///
/// NOTE(perf): the floor uses the `2^23` rounding trick on all three axes in
/// one SIMD register; three saturating float-to-int casts cost about as
/// much as the rest of the binning.
#[derive(Clone, Copy, Debug)]
struct BinMap {
    cmin: Vec3A,
    k: Vec3A,
    top: f32,
}

/// `2^23`: `y + 2^23` holds `round(y)` in its low mantissa bits for `0 <= y < 2^22`.
const ROUND: f32 = 8_388_608.0;

impl BinMap {
    fn new(cent: &Box3, bins: usize) -> BinMap {
        let ext = cent.max - cent.min;
        let scale = bins as f32 * (1.0 - 1e-6);
        // An axis without extent maps everything to bin 0 (no plane there).
        let k = Vec3A::select(
            ext.cmpgt(Vec3A::ZERO),
            Vec3A::splat(scale) / ext,
            Vec3A::ZERO,
        );
        BinMap {
            cmin: cent.min,
            k,
            top: (bins - 1) as f32,
        }
    }
    /// Bins of a (doubled) centroid on the three axes, in `0..bins` whatever
    /// the input (NaN: bin 0, as `max` returns its second operand then).
    #[inline(always)]
    fn bins3(&self, c: Vec3A) -> [usize; 3] {
        let y = ((c - self.cmin) * self.k)
            .max(Vec3A::ZERO)
            .min(Vec3A::splat(self.top));
        let r = y + Vec3A::splat(ROUND);
        // round(y) > y: one less for the floor.
        let down = (r - Vec3A::splat(ROUND)).cmpgt(y).bitmask();
        [
            ((r.x.to_bits() & 0xff) - (down & 1)) as usize,
            ((r.y.to_bits() & 0xff) - ((down >> 1) & 1)) as usize,
            ((r.z.to_bits() & 0xff) - ((down >> 2) & 1)) as usize,
        ]
    }
    /// Whether a centroid's bin on `axis` is below `pos` (`1 <= pos < bins`):
    /// `floor(clamp(x)) < pos` iff `x < pos`, and NaN (bin 0) is below.
    #[inline(always)]
    fn below(&self, c: Vec3A, axis: usize, pos: f32) -> bool {
        let x = (c[axis] - self.cmin[axis]) * self.k[axis];
        x < pos || x.is_nan()
    }
}

/// Nodes of at least this many references bin into two sets.
const TWO_SETS: usize = 64;

impl Bins {
    #[inline(always)]
    fn add(&mut self, set: usize, r: &PrimRef, map: &BinMap) {
        let bx = Box3::of(r);
        let i = map.bins3(bx.min + bx.max);
        for (a, &ia) in i.iter().enumerate() {
            // `& 63`: in range already; lets the compiler drop the checks.
            let b = ia & (MAX_BINS as usize - 1);
            self.boxes[set][a][b].grow(&bx);
            self.counts[set][a][b] += 1;
        }
    }

    /// `other`'s first `nb` bins of set 0 merged into these.
    fn merge(&mut self, other: &Bins, nb: usize) {
        for a in 0..3 {
            for i in 0..nb {
                self.boxes[0][a][i].grow(&other.boxes[0][a][i]);
                self.counts[0][a][i] += other.counts[0][a][i];
            }
        }
    }

    /// `refs` binned into set 0's first `nb` bins, through two interleaved
    /// sets (even and odd references) in large nodes.
    ///
    /// NOTE(perf): references in mesh order are spatially coherent, so
    /// consecutive ones mostly fall into the same bins; with one set each
    /// bin update waits for the previous one's store.
    fn fill(&mut self, refs: &[PrimRef], map: &BinMap, nb: usize) {
        let sets = if refs.len() >= TWO_SETS { 2 } else { 1 };
        for set in 0..sets {
            for a in 0..3 {
                self.boxes[set][a][..nb].fill(Box3::EMPTY);
                self.counts[set][a][..nb].fill(0);
            }
        }
        if sets == 2 {
            let mut pairs = refs.chunks_exact(2);
            for pr in &mut pairs {
                self.add(0, &pr[0], map);
                self.add(1, &pr[1], map);
            }
            if let [r] = pairs.remainder() {
                self.add(0, r, map);
            }
            for a in 0..3 {
                for i in 0..nb {
                    let (b1, n1) = (self.boxes[1][a][i], self.counts[1][a][i]);
                    self.boxes[0][a][i].grow(&b1);
                    self.counts[0][a][i] += n1;
                }
            }
        } else {
            for r in refs {
                self.add(0, r, map);
            }
        }
    }
}

impl Binner<'_> {
    /// The workers that bin a node of `n` references.
    fn workers(&self, n: usize) -> usize {
        if n >= PAR_BINNING { self.m.len() } else { 1 }
    }

    /// Bin `refs` and return the cheapest plane, or `None` when no plane has
    /// references on both sides (all centroids in one bin on every axis).
    fn find(&mut self, refs: &[PrimRef], map: &BinMap) -> Option<Split> {
        let nb = self.bins;
        let w = self.workers(refs.len());
        if w == 1 {
            self.m[0].fill(refs, map, nb);
        } else {
            let parts = Parts::even(&mut self.m[..w], w);
            self.par.run(&|k| {
                let part = &refs[crate::mem::par::share(refs.len(), k, w)];
                parts.get(k)[0].fill(part, map, nb);
            });
            let (first, rest) = self.m.split_at_mut(1);
            for o in &rest[..w - 1] {
                first[0].merge(o, nb);
            }
        }
        // The three axes' sweeps run side by side, one per lane.
        let (counts, boxes) = (&self.m[0].counts[0], &self.m[0].boxes[0]);
        let count3 = |i: usize| {
            Vec3A::new(
                counts[0][i] as f32,
                counts[1][i] as f32,
                counts[2][i] as f32,
            )
        };
        let mut left_area = [Vec3A::ZERO; MAX_BINS as usize];
        let mut left_n = [Vec3A::ZERO; MAX_BINS as usize];
        let (mut acc, mut n) = ([Box3::EMPTY; 3], Vec3A::ZERO);
        for i in 0..nb - 1 {
            for a in 0..3 {
                acc[a].grow(&boxes[a][i]);
            }
            n += count3(i);
            left_area[i] = areas3(&acc);
            left_n[i] = n;
        }
        let axes = map.k.cmpne(Vec3A::ZERO);
        let (mut acc, mut n) = ([Box3::EMPTY; 3], Vec3A::ZERO);
        let (mut best_cost, mut best_pos) = (Vec3A::INFINITY, Vec3A::ZERO);
        for i in (1..nb).rev() {
            for a in 0..3 {
                acc[a].grow(&boxes[a][i]);
            }
            n += count3(i);
            let (la, ln) = (left_area[i - 1], left_n[i - 1]);
            let cost = la * ln + areas3(&acc) * n;
            // Strict: of equal costs the highest plane, as NaN never wins.
            let take = cost.cmplt(best_cost) & n.cmpgt(Vec3A::ZERO) & ln.cmpgt(Vec3A::ZERO) & axes;
            best_cost = Vec3A::select(take, cost, best_cost);
            best_pos = Vec3A::select(take, Vec3A::splat(i as f32), best_pos);
        }
        let axis = min_lane(best_cost, best_pos.cmpgt(Vec3A::ZERO).bitmask())?;
        let best = (best_cost[axis], axis, best_pos[axis] as usize);
        let mut s = Split {
            axis: best.1,
            pos: best.2,
            cost: best.0,
            left: Box3::EMPTY,
            right: Box3::EMPTY,
        };
        for (i, b) in self.m[0].boxes[0][s.axis][..nb].iter().enumerate() {
            if i < s.pos {
                s.left.grow(b);
            } else {
                s.right.grow(b);
            }
        }
        Some(s)
    }
}

impl Binner<'_> {
    /// Bin `refs` (a node's, within `bounds`) in space and return the
    /// cheapest slab plane whose duplicates fit `room`, or `None`.
    fn spatial(
        &mut self,
        refs: &[PrimRef],
        scene: &Scene<'_>,
        bounds: &Box3,
        room: usize,
    ) -> Option<(spatial::SpatialSplit, spatial::Slabs)> {
        let slabs = spatial::Slabs::new(bounds);
        let w = self.workers(refs.len());
        if w == 1 {
            spatial::fill(&mut self.sm[0], refs, scene, &slabs);
        } else {
            let parts = Parts::even(&mut self.sm[..w], w);
            self.par.run(&|k| {
                let part = &refs[crate::mem::par::share(refs.len(), k, w)];
                spatial::fill(&mut parts.get(k)[0], part, scene, &slabs);
            });
            let (first, rest) = self.sm.split_at_mut(1);
            for o in &rest[..w - 1] {
                spatial::merge(&mut first[0], o);
            }
        }
        spatial::best(&self.sm[0], slabs, refs.len(), room)
    }
}

/// Partition `refs` in place: bin `< s.pos` first (Hoare's two scans,
/// which keep runs of spatially coherent references in place). Returns the
/// left count and the centroid boxes of both sides.
fn partition(refs: &mut [PrimRef], map: &BinMap, s: &Split) -> (usize, Box3, Box3) {
    let (mut cl, mut cr) = (Box3::EMPTY, Box3::EMPTY);
    let (axis, pos) = (s.axis, s.pos as f32);
    let (mut i, mut j) = (0usize, refs.len());
    loop {
        // [0, i) left, [j, len) right, [i, j) not yet seen.
        let ci = loop {
            if i == j {
                return (i, cl, cr);
            }
            let c = centroid2(&refs[i]);
            if !map.below(c, axis, pos) {
                break c;
            }
            cl.grow_point(c);
            i += 1;
        };
        let cj = loop {
            j -= 1;
            if j == i {
                cr.grow_point(ci);
                return (i, cl, cr);
            }
            let c = centroid2(&refs[j]);
            if map.below(c, axis, pos) {
                break c;
            }
            cr.grow_point(c);
        };
        refs.swap(i, j);
        cl.grow_point(cj);
        cr.grow_point(ci);
        i += 1;
    }
}

/// Nodes of at most this many references are split by a full sweep over
/// their sorted centroids instead of binning (see the module Deviations).
const SWEEP_MAX: usize = 12;

/// `SWEEP_MAX` of the `High` build.
pub const SWEEP_HIGH: usize = 32;

/// A split of a node: axis, left count, `A_L N_L + A_R N_R`, the children's
/// boxes and centroid boxes.
type Cut = (usize, usize, f32, Box3, Box3, Box3, Box3);

/// Best split of a small node (2 <= refs.len() <= SWEEP_HIGH) by the full
/// SAH sweep: references sorted by centroid on each axis, every prefix
/// evaluated. On return `refs` is ordered for the chosen axis.
fn sweep_split(refs: &mut [PrimRef]) -> Cut {
    let n = refs.len();
    debug_assert!((2..=SWEEP_HIGH).contains(&n));
    if n == 2 {
        // One possible split; order the pair along the axis where their
        // centroids lie farthest apart.
        let (b0, b1) = (Box3::of(&refs[0]), Box3::of(&refs[1]));
        let (c0, c1) = (b0.min + b0.max, b1.min + b1.max);
        let ad = (c1 - c0).abs();
        let axis = if ad.x >= ad.y && ad.x >= ad.z {
            0
        } else if ad.y >= ad.z {
            1
        } else {
            2
        };
        let cost = b0.half_area() + b1.half_area();
        let pt = |c: Vec3A| Box3 { min: c, max: c };
        return if c1[axis] < c0[axis] {
            refs.swap(0, 1);
            (axis, 1, cost, b1, b0, pt(c1), pt(c0))
        } else {
            (axis, 1, cost, b0, b1, pt(c0), pt(c1))
        };
    }
    // NOTE(perf): scratch arrays sized by the node (most are tiny).
    match n {
        3..=4 => sweep::<4>(refs),
        5..=8 => sweep::<8>(refs),
        9..=SWEEP_MAX => sweep::<SWEEP_MAX>(refs),
        _ => sweep::<SWEEP_HIGH>(refs),
    }
}

/// `sweep_split` for `3 <= refs.len() <= M`.
#[inline(always)]
fn sweep<const M: usize>(refs: &mut [PrimRef]) -> Cut {
    let n = refs.len();
    let mut boxes = [Box3::EMPTY; M];
    let mut cent = [Vec3A::ZERO; M];
    for (i, r) in refs.iter().enumerate() {
        boxes[i] = Box3::of(r);
        cent[i] = boxes[i].min + boxes[i].max;
    }
    let mut orders = [[0u8; M]; 3];
    for (a, order) in orders.iter_mut().enumerate() {
        // Insertion sort of (key, index) by key (stable).
        let mut key = [0.0f32; M];
        for (i, c) in cent[..n].iter().enumerate() {
            let k = c[a];
            let mut j = i;
            while j > 0 && key[j - 1] > k {
                key[j] = key[j - 1];
                order[j] = order[j - 1];
                j -= 1;
            }
            key[j] = k;
            order[j] = i as u8;
        }
    }
    // The three axes' sweeps side by side, one per lane.
    let mut left_area = [Vec3A::ZERO; M];
    let mut acc = [Box3::EMPTY; 3];
    for i in 0..n - 1 {
        for a in 0..3 {
            acc[a].grow(&boxes[orders[a][i] as usize]);
        }
        left_area[i] = areas3(&acc);
    }
    let mut acc = [Box3::EMPTY; 3];
    let (mut best_cost, mut best_pos) = (Vec3A::INFINITY, Vec3A::ZERO);
    let nf = Vec3A::splat(n as f32);
    for i in (1..n).rev() {
        for a in 0..3 {
            acc[a].grow(&boxes[orders[a][i] as usize]);
        }
        // Left: order[..i], right: order[i..].
        let fi = Vec3A::splat(i as f32);
        let cost = left_area[i - 1] * fi + areas3(&acc) * (nf - fi);
        // Equal costs (coincident references): the more balanced split.
        let balanced = (fi * 2.0 - nf).abs().cmplt((best_pos * 2.0 - nf).abs());
        let take = cost.cmplt(best_cost) | (cost.cmpeq(best_cost) & balanced);
        best_cost = Vec3A::select(take, cost, best_cost);
        best_pos = Vec3A::select(take, fi, best_pos);
    }
    let found = best_pos.cmpgt(Vec3A::ZERO).bitmask();
    let best = match min_lane(best_cost, found) {
        Some(a) => (a, best_pos[a] as usize, best_cost[a]),
        // NaN areas (overflowing coordinates): split in the middle.
        None => (0, n / 2, f32::NAN),
    };
    let best_order = &orders[best.0];
    let mut tmp = [PrimRef::default(); M];
    tmp[..n].copy_from_slice(refs);
    let (mut bl, mut br, mut cl, mut cr) = (Box3::EMPTY, Box3::EMPTY, Box3::EMPTY, Box3::EMPTY);
    for i in 0..n {
        let o = best_order[i] as usize;
        refs[i] = tmp[o];
        if i < best.1 {
            bl.grow(&boxes[o]);
            cl.grow_point(cent[o]);
        } else {
            br.grow(&boxes[o]);
            cr.grow_point(cent[o]);
        }
    }
    (best.0, best.1, best.2, bl, br, cl, cr)
}

/// Box and centroid box of `refs`.
fn bounds_of(refs: &[PrimRef]) -> (Box3, Box3) {
    let (mut b, mut c) = (Box3::EMPTY, Box3::EMPTY);
    for r in refs {
        let x = Box3::of(r);
        b.grow(&x);
        c.grow_point(x.min + x.max);
    }
    (b, c)
}

/// The object median of `refs` (at least two), for nodes whose
/// centroids coincide: axis 0, the left count, the references used, and
/// the children's boxes and centroid boxes.
fn median(refs: &[PrimRef]) -> (usize, usize, usize, Box3, Box3, Box3, Box3) {
    let nl = refs.len() / 2;
    let (bl, cl) = bounds_of(&refs[..nl]);
    let (br, cr) = bounds_of(&refs[nl..]);
    (0, nl, refs.len(), bl, br, cl, cr)
}

/// What the first pass over the scene found (`gather`).
pub(super) struct Gathered {
    /// Traceable triangles (their `PrimRef`s are `refs[..n]`).
    pub n: usize,
    /// Bounds and centroid bounds (doubled centroids) of the references.
    pub bounds: Box3,
    pub cent: Box3,
    /// The stored boxes' padding (module docs of `bvh`, Exactness).
    pub pad: Vec3A,
    /// The info of the build before its tree: counts and parameters.
    pub info: BvhInfo,
}

/// The capacity error of a build of `needed` triangles in a pool of
/// `available`.
fn capacity(needed: usize, available: usize) -> Error {
    Error::Capacity {
        pool: Pool::Triangles,
        needed: needed as u64,
        available: available as u64,
    }
}

/// Whether the pools hold a tree of `n` traceable triangles built with
/// `p` (the checks of both builds once their triangles are counted).
pub(super) fn room_for(pools: &BvhPools<'_>, p: &BvhParams, n: usize) -> Result<()> {
    // The LOW build writes its references at the triangles' own indices
    // (checked against the input count); the SAH builds one per traceable
    // triangle.
    let refs = if p.quality == BuildQuality::Low {
        usize::MAX
    } else {
        pools.refs.len()
    };
    for avail in [refs, pools.tris.len(), pools.tri_ids.len()] {
        if n > avail {
            return Err(capacity(n, avail));
        }
    }
    if (2 * n).saturating_sub(1) > pools.nodes.len() {
        return Err(capacity(n, pools.nodes.len() / 2));
    }
    if p.test == TriTest::Projection && pools.proj.len() < n {
        return Err(Error::InvalidArgument(
            "the projection test needs Limits::projection_test",
        ));
    }
    Ok(())
}

/// Every refusal of a build of `scene`, before it writes anything: the
/// input count against the pools indexed by triangle, then `room_for` the
/// input count, which suffices unless the pools are smaller than the
/// input; only then are the traceable triangles counted (a pass the
/// build makes again).
fn check_room(pools: &BvhPools<'_>, scene: &Scene<'_>, p: &BvhParams) -> Result<()> {
    let n_in = scene.triangle_count() as usize;
    let room = if p.quality == BuildQuality::Low {
        pools.slot_of.len().min(pools.refs.len())
    } else {
        pools.slot_of.len()
    };
    if n_in > room {
        return Err(capacity(n_in, room));
    }
    if room_for(pools, p, n_in).is_ok() {
        return Ok(());
    }
    let n = (0..n_in as u32)
        .filter(|&t| Scene::classify(&scene.triangle(t)).is_none())
        .count();
    room_for(pools, p, n)
}

/// Pass 1 of every build: read and classify the triangles, write one
/// `PrimRef` per traceable one (the build scratch only), and check every
/// pool's capacity. On error nothing a traversal reads has changed.
pub(super) fn gather(
    pools: &mut BvhPools<'_>,
    scene: &Scene<'_>,
    p: &BvhParams,
) -> Result<Gathered> {
    let n_in = scene.triangle_count();
    let cap = |needed: u64, available: usize| Error::Capacity {
        pool: Pool::Triangles,
        needed,
        available: available as u64,
    };
    if n_in as usize > pools.slot_of.len() {
        return Err(cap(n_in as u64, pools.slot_of.len()));
    }
    let refs_cap = pools.refs.len();
    let (mut n, mut bad_nf, mut bad_za) = (0usize, 0u32, 0u32);
    let (mut bounds, mut cent) = (Box3::EMPTY, Box3::EMPTY);
    for t in 0..n_in {
        let tri = scene.triangle(t);
        match Scene::classify(&tri) {
            None => {
                let bx = Box3::of_tri(&tri);
                bounds.grow(&bx);
                cent.grow_point(bx.min + bx.max);
                if n < refs_cap {
                    pools.refs[n] = PrimRef {
                        min: bx.min.into(),
                        id: t,
                        max: bx.max.into(),
                        _pad: 0,
                    };
                }
                n += 1;
            }
            Some(Excluded::NonFinite) => bad_nf += 1,
            Some(Excluded::ZeroArea) => bad_za += 1,
        }
    }
    room_for(pools, p, n)?;
    let info = BvhInfo {
        bounds: if n > 0 {
            bounds.aabb()
        } else {
            Aabb::default()
        },
        triangles_in: n_in,
        triangles: n as u32,
        references: n as u32,
        excluded_non_finite: bad_nf,
        excluded_zero_area: bad_za,
        leaf_size: p.leaf_size,
        bins: if p.quality == BuildQuality::High {
            MAX_BINS
        } else {
            p.bins
        },
        test: p.test,
        quality: p.quality,
        ..BvhInfo::default()
    };
    Ok(Gathered {
        n,
        bounds,
        cent,
        pad: super::box_pad(bounds.min, bounds.max),
        info,
    })
}

/// Rebuild `bvh` from `scene` with the build `p.quality` names. On error
/// the previous build stays valid and every traversal answers as before;
/// an error found after validation drops its 4-wide tree (the builds
/// write the reference pool it lives in), so its wide walks take the
/// binary tree until the next build.
///
/// Errors: invalid `p`; `Capacity { pool: Triangles }` when the scene has
/// more triangles than the pools hold (ids, stored triangles, nodes); the
/// projection test without its pool.
pub fn build(bvh: &mut Bvh<'_>, scene: &Scene<'_>, p: &BvhParams) -> Result<BvhInfo> {
    build_with(bvh, scene, p, &crate::mem::par::Serial)
}

/// `build` on the caller's workers (`mem::par`), the same tree for any
/// number: the fast build (`Low`) runs every phase on them; the SAH builds
/// split the top of the tree on the calling thread and the subtrees below
/// it on the workers.
pub fn build_with(
    bvh: &mut Bvh<'_>,
    scene: &Scene<'_>,
    p: &BvhParams,
    par: &dyn crate::mem::par::Par,
) -> Result<BvhInfo> {
    p.validate()?;
    // Both builds write the reference pool, where the wide tree lives:
    // every refusal is decided before the wide tree is dropped, so a
    // refused build leaves both trees as they were.
    check_room(bvh.pools_mut(), scene, p)?;
    bvh.drop_wide();
    let pools = bvh.pools_mut();
    if p.quality == BuildQuality::Low {
        let info = super::build_morton::build(pools, scene, p, par)?;
        bvh.set_params(*p);
        return Ok(bvh.commit(info));
    }
    let workers = crate::mem::par::workers_of(par)?;
    let g = gather(pools, scene, p)?;

    // From here on nothing fails.
    pools.slot_of[..g.info.triangles_in as usize].fill(INVALID_ID);
    let info = if g.n == 0 {
        g.info
    } else {
        crate::fault_point!(BvhBuild);
        binned_sah(pools, scene, p, &g, par, workers)
    };
    bvh.set_params(*p);
    Ok(bvh.commit(info))
}

/// Most subtrees the calling thread hands to the workers.
const MAX_JOBS: usize = 256;

/// References of a node below which the calling thread hands its subtree
/// to a worker: about 64 jobs per build.
fn job_size(n: usize) -> usize {
    (n / 64).max(256)
}

/// A subtree built by one worker (`binned_sah`): its root task (the root's
/// node is in the top), the region of nodes below its root, and what it
/// built.
#[derive(Clone, Copy, Debug)]
struct Job {
    task: Task,
    region: u32,
    root: BvhNode,
    nodes: u32,
    refs: u32,
    sums: Sums,
}

/// What a part of the build adds to the tree's figures.
#[derive(Clone, Copy, Debug, Default)]
struct Sums {
    inner: f64,
    leaf: f64,
    leaves: u32,
    depth: u32,
}

const NO_JOB: Job = Job {
    task: NO_TASK,
    region: 0,
    root: BvhNode {
        min: [0.0; 3],
        first: 0,
        max: [0.0; 3],
        meta: 0,
    },
    nodes: 0,
    refs: 0,
    sums: Sums {
        inner: 0.0,
        leaf: 0.0,
        leaves: 0,
        depth: 0,
    },
};

/// Bytes of the SAH build's scratch: per worker the bins, the spatial bins
/// and a work stack, then the jobs.
const SAH_SCRATCH: usize = (crate::mem::scratch::bytes::<Bins>(MAX_WORKERS)
    + crate::mem::scratch::bytes::<spatial::SpatialBins>(MAX_WORKERS)
    + crate::mem::scratch::bytes::<Task>(MAX_WORKERS * (MAX_DEPTH + 1))
    + crate::mem::scratch::bytes::<Job>(MAX_JOBS))
.next_multiple_of(64);

/// Where one worker (or the calling thread, for the top) writes: nodes
/// `base..` and the stored triangles of slots `slot_base..`; the node at
/// index `root`, which lies outside (in the top), goes to `root_node`.
struct Out<'a> {
    nodes: &'a mut [BvhNode],
    base: u32,
    root: u32,
    root_node: BvhNode,
    tris: &'a mut [TriVerts],
    proj: &'a mut [ProjTri],
    ids: &'a mut [u32],
    slot_base: usize,
    /// `slot_of`, written here when no triangle is stored twice (else
    /// after the build, lowest slot first).
    slot_of: Option<&'a [AtomicU32]>,
}

impl Out<'_> {
    #[inline(always)]
    fn node(&mut self, i: u32, n: BvhNode) {
        if i == self.root {
            self.root_node = n;
        } else {
            self.nodes[(i - self.base) as usize] = n;
        }
    }
    #[inline(always)]
    fn put(&mut self, scene: &Scene<'_>, s: usize, id: u32) {
        let k = s - self.slot_base;
        let tri = scene.triangle(id);
        self.tris[k] = tri;
        if let Some(p) = self.proj.get_mut(k) {
            *p = ProjTri::new(&tri);
        }
        self.ids[k] = id;
        if let Some(so) = self.slot_of {
            so[id as usize].store(s as u32, core::sync::atomic::Ordering::Relaxed);
        }
    }
}

/// What every node split reads: the build's parameters and constants.
struct Frame<'a> {
    scene: &'a Scene<'a>,
    p: &'a BvhParams,
    pad: Vec3A,
    root_area: f32,
    sweep_max: usize,
    bins: usize,
    spatial_on: bool,
}

/// Split `task` and its descendants (depth first, left child first,
/// children numbered from `next`), over `refs`, which holds references
/// `rbase..`. With `job`, the calling thread's top: a task the closure
/// takes becomes a job (it returns false when the jobs are full) instead
/// of being split here. Returns the next node number and the next slot.
// The top and every job call it with their own parts of the pools and of
// the scratch, which cannot live in one struct shared by the workers.
#[allow(clippy::too_many_arguments)]
fn grow(
    f: &Frame<'_>,
    refs: &mut [PrimRef],
    rbase: usize,
    first: Task,
    mut next: u32,
    mut slot: usize,
    out: &mut Out<'_>,
    binner: &mut Binner<'_>,
    stack: &mut [Task],
    sums: &mut Sums,
    mut job: Option<&mut dyn FnMut(Task, usize) -> bool>,
) -> (u32, usize) {
    let (p, scene, leaf_size) = (f.p, f.scene, f.p.leaf_size as usize);
    let mut sp = 0usize;
    let mut task = first;
    loop {
        let (begin, end, cap) = (
            task.begin as usize - rbase,
            task.end as usize - rbase,
            task.cap as usize - rbase,
        );
        let count = end - begin;
        if let Some(take) = job.as_mut()
            && take(task, sp)
        {
            if sp == 0 {
                break;
            }
            sp -= 1;
            task = stack[sp];
            continue;
        }
        let area = task.bounds.half_area();
        let splits = |cost: f32| {
            let split_cost = p.traversal_cost + cost / area;
            // NaN costs (overflowing coordinates) split rather than keep
            // a large leaf.
            count > leaf_size || count as f32 > split_cost || split_cost.is_nan()
        };
        // Some((axis, left count, references used, left box, right box,
        // left cent, right cent)).
        let mut split = None;
        if count > 1 && (task.depth as usize) < MAX_DEPTH {
            // The best object split, its references not yet partitioned.
            enum Object {
                Swept(Cut),
                Binned(Split, BinMap),
                Median,
            }
            let object = if count <= f.sweep_max {
                let cut = sweep_split(&mut refs[begin..end]);
                Object::Swept(cut)
            } else {
                let map = BinMap::new(&task.cent, binner.bins);
                match binner.find(&refs[begin..end], &map) {
                    Some(s) => Object::Binned(s, map),
                    None => Object::Median,
                }
            };
            let (ocost, ol, or) = match &object {
                Object::Swept(c) => (c.2, c.3, c.4),
                Object::Binned(s, _) => (s.cost, s.left, s.right),
                Object::Median => (f32::INFINITY, Box3::EMPTY, Box3::EMPTY),
            };
            // Section 4.3: space is binned only where the object split's
            // children overlap (by `OVERLAP` of the node's area), in nodes
            // not too small to matter.
            let overlap = Box3 {
                min: ol.min.max(or.min),
                max: ol.max.min(or.max),
            };
            let overlapping = matches!(object, Object::Median)
                || (overlap.min.cmple(overlap.max).all()
                    && overlap.half_area() > spatial::OVERLAP * area);
            let room = cap - end;
            let spatial = if f.spatial_on
                && room > 0
                && count >= spatial::MIN_COUNT
                && overlapping
                && area >= spatial::MIN_AREA * f.root_area
            {
                binner
                    .spatial(&refs[begin..end], scene, &task.bounds, room)
                    .filter(|(s, _)| s.cost < spatial::GAIN * ocost)
            } else {
                None
            };
            if let Some((s, slabs)) = spatial
                && splits(s.cost)
            {
                let q = spatial::partition(&mut refs[begin..cap], count, scene, &slabs, &s);
                if q.left > 0 && q.left < q.used {
                    split = Some((s.axis, q.left, q.used, q.bl, q.br, q.cl, q.cr));
                }
            }
            if split.is_none() {
                split = match object {
                    Object::Swept((axis, nl, cost, bl, br, cl, cr)) => {
                        splits(cost).then_some((axis, nl, count, bl, br, cl, cr))
                    }
                    Object::Binned(s, map) if splits(s.cost) => {
                        let (nl, cl, cr) = partition(&mut refs[begin..end], &map, &s);
                        Some(if nl > 0 && nl < count {
                            (s.axis, nl, count, s.left, s.right, cl, cr)
                        } else {
                            // Cannot happen (binning and partition agree); stay safe.
                            median(&refs[begin..end])
                        })
                    }
                    Object::Binned(..) => None,
                    // All centroids coincide: object median.
                    Object::Median => (count > leaf_size).then(|| median(&refs[begin..end])),
                };
            }
        }
        let padded = task.bounds.padded(f.pad);
        match split {
            Some((axis, nl, used, bl, br, cl, cr)) => {
                let left = next;
                next += 2;
                out.node(task.node, BvhNode::inner(&padded, left, axis));
                sums.inner += area as f64;
                // The reserve left over is shared by the children's
                // reference counts: the right block moves up past the left
                // child's share.
                let free = cap - begin - used;
                let left_share = (free as u64 * nl as u64 / used as u64) as usize;
                let mid = begin + nl;
                let right = mid + left_share;
                if left_share > 0 {
                    refs.copy_within(mid..begin + used, right);
                }
                let depth = task.depth + 1;
                stack[sp] = Task {
                    node: left + 1,
                    begin: (rbase + right) as u32,
                    end: (rbase + right + used - nl) as u32,
                    cap: task.cap,
                    depth,
                    bounds: br,
                    cent: cr,
                };
                sp += 1;
                task = Task {
                    node: left,
                    begin: task.begin,
                    end: (rbase + mid) as u32,
                    cap: (rbase + right) as u32,
                    depth,
                    bounds: bl,
                    cent: cl,
                };
                continue;
            }
            None => {
                out.node(task.node, BvhNode::leaf(&padded, slot as u32, count as u32));
                sums.leaf += area as f64 * count as f64;
                sums.leaves += 1;
                sums.depth = sums.depth.max(task.depth);
                for r in &refs[begin..end] {
                    out.put(scene, slot, r.id);
                    slot += 1;
                }
            }
        }
        if sp == 0 {
            break;
        }
        sp -= 1;
        task = stack[sp];
    }
    (next, slot)
}

/// The top-down binned SAH (the module docs' second pass) over `refs[..g.n]`,
/// with spatial splits (`build_spatial.rs`) into `refs[g.n..]` when the
/// `High` build has a reserve. The calling thread splits the top down to
/// subtrees of at most `job_size` references, the workers build those
/// (each into its own region of nodes and slots), and the regions are
/// moved together in job order: the same tree for any number of workers.
fn binned_sah(
    pools: &mut BvhPools<'_>,
    scene: &Scene<'_>,
    p: &BvhParams,
    g: &Gathered,
    par: &dyn Par,
    workers: usize,
) -> BvhInfo {
    let n = g.n;
    let mut info = g.info;
    let total = reference_capacity(&PoolRoom::of(pools, p), p, n, n);
    let high = p.quality == BuildQuality::High;
    let f = Frame {
        scene,
        p,
        pad: g.pad,
        root_area: g.bounds.half_area(),
        sweep_max: if high { SWEEP_HIGH } else { SWEEP_MAX },
        bins: if high {
            MAX_BINS as usize
        } else {
            p.bins as usize
        },
        spatial_on: total > n,
    };
    let proj_on = p.test == TriTest::Projection;
    let BvhPools {
        nodes,
        tris,
        proj,
        tri_ids,
        slot_of,
        refs,
        scratch,
    } = pools;
    let refs = &mut refs[..total];
    let scratch = crate::mem::Scratch::new(scratch);
    // Per worker of this build only (the scratch holds `MAX_WORKERS`):
    // a small geometry's build does not fill sixteen sets of bins.
    let (bins, scratch) = scratch.take_copies(workers, &EMPTY_BINS);
    let (sbins, scratch) = scratch.take_copies(workers, &spatial::EMPTY_SPATIAL);
    let (stacks, scratch) = scratch.take_copies(workers * (MAX_DEPTH + 1), &NO_TASK);
    let (jobs, _) = scratch.take_copies(MAX_JOBS, &NO_JOB);

    // 1. The top on the calling thread, down to the jobs (in depth-first
    // order, so their reference ranges follow each other).
    let root = Task {
        node: 0,
        begin: 0,
        end: n as u32,
        cap: total as u32,
        depth: 0,
        bounds: g.bounds,
        cent: g.cent,
    };
    let cut = job_size(n);
    let mut n_jobs = 0usize;
    let mut top = Sums::default();
    let top_next = {
        let mut out = Out {
            nodes: &mut nodes[..],
            base: 0,
            root: u32::MAX,
            root_node: BvhNode::default(),
            tris: &mut [],
            proj: &mut [],
            ids: &mut [],
            slot_base: 0,
            slot_of: None,
        };
        let mut take = |t: Task, pending: usize| {
            let count = (t.end - t.begin) as usize;
            // A split adds one task; the jobs must hold every pending one.
            let full = n_jobs + pending + 2 > MAX_JOBS;
            if count <= cut || t.depth as usize >= MAX_DEPTH || full {
                jobs[n_jobs] = Job { task: t, ..NO_JOB };
                n_jobs += 1;
                true
            } else {
                false
            }
        };
        let (next, _) = grow(
            &f,
            refs,
            0,
            root,
            1,
            0,
            &mut out,
            &mut Binner {
                bins: f.bins,
                m: &mut bins[..],
                sm: &mut sbins[..],
                par,
            },
            &mut stacks[..MAX_DEPTH + 1],
            &mut top,
            Some(&mut take),
        );
        next
    };
    let jobs = &mut jobs[..n_jobs];

    // 2. Each job's region: `2c - 2` nodes below a root of `c` references
    // (its share of the reserve included), after the top and the regions
    // before it; the jobs in runs of about equal reference counts, one run
    // per worker.
    let mut region = top_next;
    for j in jobs.iter_mut() {
        j.region = region;
        region += 2 * (j.task.cap - j.task.begin) - 2;
    }
    let mut jb = [0usize; MAX_WORKERS + 1];
    let mut nb = [top_next as usize; MAX_WORKERS + 1];
    let mut rb = [0usize; MAX_WORKERS + 1];
    {
        let (mut k, mut acc) = (0usize, 0usize);
        for w in 1..workers {
            while k < jobs.len() && acc < total * w / workers {
                acc += (jobs[k].task.cap - jobs[k].task.begin) as usize;
                k += 1;
            }
            jb[w] = k;
            nb[w] = jobs.get(k).map_or(region as usize, |j| j.region as usize);
            rb[w] = jobs.get(k).map_or(total, |j| j.task.begin as usize);
        }
        jb[workers] = jobs.len();
        nb[workers] = region as usize;
        rb[workers] = total;
    }
    // A triangle stored twice (spatial splits) takes its lowest slot,
    // after the build; else each job writes its triangles' slots.
    let dedup = f.spatial_on;
    let pb = if proj_on { rb } else { [0; MAX_WORKERS + 1] };
    let w1 = workers + 1;
    {
        let js = Parts::at(&mut *jobs, &jb[..w1]);
        let ns = Parts::at(&mut nodes[..region as usize], &nb[..w1]);
        let rs = Parts::at(&mut *refs, &rb[..w1]);
        let ts = Parts::at(&mut tris[..total], &rb[..w1]);
        let ps = Parts::at(
            if proj_on { &mut proj[..total] } else { &mut [] },
            &pb[..w1],
        );
        let is = Parts::at(&mut tri_ids[..total], &rb[..w1]);
        let bs = Parts::even(&mut bins[..workers], workers);
        let ss = Parts::even(&mut sbins[..workers], workers);
        let ks = Parts::even(&mut stacks[..workers * (MAX_DEPTH + 1)], workers);
        let so = (!dedup).then(|| atomic_u32(&mut slot_of[..]));
        par.run(&|w| {
            let (mine, part, rp) = (js.get(w), ns.get(w), rs.get(w));
            let (tp, pp, ip) = (ts.get(w), ps.get(w), is.get(w));
            let mut binner = Binner {
                bins: f.bins,
                m: bs.get(w),
                sm: ss.get(w),
                par: &crate::mem::par::Serial,
            };
            let stack = ks.get(w);
            let (base, rbase) = (ns.start(w) as u32, rs.start(w));
            let mut out = Out {
                nodes: part,
                base,
                root: 0,
                root_node: BvhNode::default(),
                tris: tp,
                proj: pp,
                ids: ip,
                slot_base: rbase,
                slot_of: so,
            };
            for j in mine.iter_mut() {
                out.root = j.task.node;
                let mut sums = Sums::default();
                let (next, slot) = grow(
                    &f,
                    rp,
                    rbase,
                    j.task,
                    j.region,
                    j.task.begin as usize,
                    &mut out,
                    &mut binner,
                    stack,
                    &mut sums,
                    None,
                );
                j.root = out.root_node;
                j.nodes = next - j.region;
                j.refs = (slot - j.task.begin as usize) as u32;
                j.sums = sums;
            }
        });
    }

    // 3. The regions moved down in job order (nodes, and with a reserve the
    // stored triangles), their links shifted, the roots written.
    let (mut to, mut slot_to) = (top_next as usize, 0usize);
    let mut sums = top;
    for j in jobs.iter() {
        let (from, used) = (j.region as usize, j.nodes as usize);
        let (sfrom, sused) = (j.task.begin as usize, j.refs as usize);
        let (shift, sshift) = ((from - to) as u32, (sfrom - slot_to) as u32);
        if sshift > 0 {
            tris.copy_within(sfrom..sfrom + sused, slot_to);
            if proj_on {
                proj.copy_within(sfrom..sfrom + sused, slot_to);
            }
            tri_ids.copy_within(sfrom..sfrom + sused, slot_to);
        }
        let fix = |nd: &mut BvhNode| {
            nd.first -= if nd.is_leaf() { sshift } else { shift };
        };
        if shift > 0 || sshift > 0 {
            nodes.copy_within(from..from + used, to);
            nodes[to..to + used].iter_mut().for_each(fix);
        }
        let mut r = j.root;
        fix(&mut r);
        nodes[j.task.node as usize] = r;
        to += used;
        slot_to += sused;
        sums.inner += j.sums.inner;
        sums.leaf += j.sums.leaf;
        sums.leaves += j.sums.leaves;
        sums.depth = sums.depth.max(j.sums.depth);
    }
    if dedup {
        for (s, &id) in tri_ids[..slot_to].iter().enumerate().rev() {
            slot_of[id as usize] = s as u32;
        }
    }
    info.nodes = to as u32;
    info.references = slot_to as u32;
    info.leaves = sums.leaves;
    info.depth = sums.depth;
    info.sah_cost =
        ((p.traversal_cost as f64 * sums.inner + sums.leaf) / f.root_area as f64) as f32;
    info
}

#[cfg(test)]
pub(crate) use crate::accel::testkit as testutil;

#[cfg(test)]
mod tests {
    use super::testutil::{Store, deep_tris, soup};
    use super::*;
    use crate::accel::bvh::BvhView;
    use glam::Vec3;

    fn check_invariants(v: &BvhView<'_>, scene: &Scene<'_>, p: &BvhParams) {
        let info = v.info;
        let n = info.references as usize;
        let split = info.references != info.triangles;
        assert!(info.references >= info.triangles);
        assert!(!split || p.quality != BuildQuality::Medium);
        assert_eq!(info.triangles_in, scene.triangle_count());
        assert_eq!(
            info.triangles + info.excluded_non_finite + info.excluded_zero_area,
            info.triangles_in
        );
        // Every valid triangle stored (exactly once without spatial
        // splits), slot_of naming one of its slots.
        let mut seen = vec![false; info.triangles_in as usize];
        for s in 0..n {
            let id = v.tri_ids[s] as usize;
            assert!(split || !seen[id], "triangle {id} stored twice");
            seen[id] = true;
            assert_eq!(v.tri_ids[v.slot_of[id] as usize] as usize, id);
            assert!(split || v.slot_of[id] as usize == s);
            assert_eq!(v.tris[s], scene.triangle(id as u32));
            if p.test == TriTest::Projection {
                assert_eq!(v.proj[s], ProjTri::new(&v.tris[s]));
            }
        }
        for id in 0..info.triangles_in {
            let valid = Scene::classify(&scene.triangle(id)).is_none();
            assert_eq!(valid, seen[id as usize], "triangle {id}");
            if !valid {
                assert_eq!(v.slot_of[id as usize], INVALID_ID);
            }
        }
        if n == 0 {
            assert_eq!(info.nodes, 0);
            return;
        }
        // The leaves that name each triangle, for the split trees' check
        // that their boxes cover it.
        let mut boxes_of: Vec<Vec<Aabb>> = vec![Vec::new(); info.triangles_in as usize];
        // Walk the tree.
        let contains = |outer: &Aabb, inner: &Aabb| {
            inner.min.cmpge(outer.min).all() && inner.max.cmple(outer.max).all()
        };
        let mut covered = vec![0u32; n];
        let (mut leaves, mut depth, mut reached) = (0u32, 0u32, 1u32);
        let mut todo = vec![(0usize, 0u32)];
        while let Some((i, d)) = todo.pop() {
            let node = &v.nodes[i];
            let b = node.aabb();
            assert!(!b.is_empty());
            if node.is_leaf() {
                leaves += 1;
                depth = depth.max(d);
                let c = node.count();
                assert!(
                    c <= info.leaf_size || d as usize == MAX_DEPTH,
                    "leaf of {c} at depth {d}"
                );
                let ids = &v.tri_ids[node.first as usize..(node.first + c) as usize];
                for (k, id) in ids.iter().enumerate() {
                    assert!(
                        !ids[..k].contains(id),
                        "triangle {id} named twice by a leaf"
                    );
                }
                for s in node.first..node.first + c {
                    covered[s as usize] += 1;
                    let id = v.tri_ids[s as usize] as usize;
                    boxes_of[id].push(b);
                    let t = &v.tris[s as usize];
                    for p in [t.v0, t.v1, t.v2] {
                        assert!(
                            split || b.contains(Vec3::from(p)),
                            "triangle {s} outside its leaf"
                        );
                    }
                }
            } else {
                let l = node.first as usize;
                assert!(l + 1 < info.nodes as usize && l > i);
                reached += 2;
                for c in [l, l + 1] {
                    assert!(
                        contains(&b, &v.nodes[c].aabb()),
                        "child {c} outside node {i}: {:?} {:?} {:?}",
                        b,
                        v.nodes[c],
                        node
                    );
                    todo.push((c, d + 1));
                }
            }
        }
        assert!(
            covered.iter().all(|&c| c == 1),
            "every slot in exactly one leaf"
        );
        assert_eq!(reached, info.nodes);
        assert_eq!(leaves, info.leaves);
        assert_eq!(depth, info.depth);
        assert!(depth as usize <= MAX_DEPTH);
        assert_eq!(info.nodes, 2 * leaves - 1);
        // Unpadded bounds are the triangles' bounds; the root box holds them.
        let mut bb = Aabb::EMPTY;
        for t in v.tris {
            for p in [t.v0, t.v1, t.v2] {
                bb.grow(Vec3::from(p));
            }
        }
        assert_eq!(bb, info.bounds);
        // Split trees: points all over each triangle lie in a box of a
        // leaf that names it.
        if split {
            for (id, boxes) in boxes_of.iter().enumerate() {
                if boxes.is_empty() {
                    continue;
                }
                let t = scene.triangle(id as u32);
                for i in 0..=8 {
                    for j in 0..=8 - i {
                        let (u, w) = (i as f32 / 8.0, j as f32 / 8.0);
                        let q = Vec3::from(t.v0) * (1.0 - u - w)
                            + Vec3::from(t.v1) * u
                            + Vec3::from(t.v2) * w;
                        assert!(
                            boxes.iter().any(|b| b.contains(q)),
                            "triangle {id}: {q} in none of its leaves' boxes"
                        );
                    }
                }
            }
        }
        assert!(contains(&v.nodes[0].aabb(), &bb));
        assert!(
            info.sah_cost.is_finite() && info.sah_cost >= 1.0,
            "sah {}",
            info.sah_cost
        );
    }

    fn build_check(v: &[f32], ix: &[u32], p: &BvhParams) -> BvhInfo {
        build_check_in(v, ix, p, 0)
    }

    /// `build_check` with a spatial-split reserve of `reserve` references.
    fn build_check_in(v: &[f32], ix: &[u32], p: &BvhParams, reserve: usize) -> BvhInfo {
        let scene = Scene::from_f32(v, ix).unwrap();
        let n = scene.triangle_count() as usize;
        let mut st = Store::with_refs(n, n + reserve, p.test == TriTest::Projection);
        let mut bvh = st.bvh();
        let info = build(&mut bvh, &scene, p).unwrap();
        let view = bvh.view().unwrap();
        assert_eq!(*view.info, info);
        check_invariants(&view, &scene, p);
        info
    }

    #[test]
    fn builtin_scenes_invariants() {
        for &name in crate::scenes::BUILTIN_NAMES {
            let s = crate::scenes::builtin(name).unwrap();
            let qualities = [BuildQuality::Low, BuildQuality::Medium, BuildQuality::High];
            for ((leaf_size, bins, test), quality) in [
                (4, 16, TriTest::MollerTrumbore),
                (1, 2, TriTest::Watertight),
                (8, 64, TriTest::Projection),
                (64, 7, TriTest::MollerTrumbore),
            ]
            .into_iter()
            .flat_map(|c| qualities.map(|q| (c, q)))
            {
                let p = BvhParams {
                    leaf_size,
                    bins,
                    traversal_cost: 1.0,
                    test,
                    quality,
                    width: 4,
                    presplit: false,
                };
                let info = build_check(&s.mesh.vertices, &s.mesh.indices, &p);
                assert_eq!(info.triangles as usize, s.mesh.triangle_count(), "{name}");
            }
        }
    }

    /// The `High` build's spatial splits: within the reserve, each
    /// triangle's parts covering it (`check_invariants`), a lower SAH than
    /// the same build without a reserve where it splits, none at all on
    /// the other qualities.
    #[test]
    fn spatial_splits_stay_in_their_reserve() {
        let (mut split_any, mut lower, mut presplit_any) = (false, 0usize, false);
        for &name in crate::scenes::BUILTIN_NAMES {
            let s = crate::scenes::builtin(name).unwrap();
            let (v, ix) = (&s.mesh.vertices, &s.mesh.indices);
            let n = s.mesh.triangle_count();
            for test in [TriTest::MollerTrumbore, TriTest::Projection] {
                let p = BvhParams {
                    test,
                    quality: BuildQuality::High,
                    ..BvhParams::default()
                };
                let plain = build_check(v, ix, &p);
                assert_eq!(plain.references, plain.triangles);
                for reserve in [1, 7, n / 4, 2 * n] {
                    let info = build_check_in(v, ix, &p, reserve);
                    assert!(info.references as usize <= n + reserve, "{name}");
                    if info.references > info.triangles {
                        split_any = true;
                        eprintln!(
                            "{name} {test:?} reserve {reserve}: {} references for {n}, SAH {} against {}",
                            info.references, info.sah_cost, plain.sah_cost
                        );
                        lower += usize::from(info.sah_cost < plain.sah_cost);
                    }
                }
                // MEDIUM leaves the reserve alone; LOW pre-splits into it
                // when asked.
                let medium = BvhParams {
                    quality: BuildQuality::Medium,
                    ..p
                };
                let info = build_check_in(v, ix, &medium, n);
                assert_eq!(info.references, info.triangles, "{name}");
                let low = BvhParams {
                    quality: BuildQuality::Low,
                    ..p
                };
                let info = build_check_in(v, ix, &low, n);
                assert_eq!(info.references, info.triangles, "{name} LOW");
                for reserve in [1, 7, n / 4] {
                    let low = BvhParams {
                        presplit: true,
                        ..low
                    };
                    let info = build_check_in(v, ix, &low, reserve);
                    assert!(info.references as usize <= n + reserve, "{name}");
                    presplit_any |= info.references > info.triangles;
                }
            }
        }
        assert!(
            split_any && lower > 0,
            "no built-in scene split a reference"
        );
        assert!(presplit_any, "no built-in scene pre-split a triangle");
    }

    /// Large crossing triangles (a fan of long slivers through one point):
    /// the case spatial splits exist for. The split tree's SAH is well
    /// below the object-split tree's.
    #[test]
    fn spatial_splits_cut_long_slivers() {
        let tris: Vec<[[f32; 3]; 3]> = (0..256)
            .map(|i| {
                let a = i as f32 * core::f32::consts::PI / 256.0;
                let (c, s) = (a.cos() * 10.0, a.sin() * 10.0);
                [[-c, -s, 0.0], [c, s, 0.0], [c, s, 0.05]]
            })
            .collect();
        let (v, ix) = soup(&tris);
        let p = BvhParams {
            quality: BuildQuality::High,
            ..BvhParams::default()
        };
        let plain = build_check(&v, &ix, &p);
        let split = build_check_in(&v, &ix, &p, 256);
        assert!(split.references > 256 && split.references <= 512);
        assert!(
            split.sah_cost < plain.sah_cost,
            "{} against {}",
            split.sah_cost,
            plain.sah_cost
        );
        // The fast build pre-splits them into the same reserve.
        let low = BvhParams {
            quality: BuildQuality::Low,
            presplit: true,
            ..p
        };
        let plain = build_check(&v, &ix, &low);
        let split = build_check_in(&v, &ix, &low, 256);
        assert!(split.references > 256 && split.references <= 512);
        assert!(
            split.sah_cost < 0.8 * plain.sah_cost,
            "LOW {} against {}",
            split.sah_cost,
            plain.sah_cost
        );
    }

    /// The builds on any number of workers (run in reverse order) give
    /// the calling thread's tree bit for bit: nodes, stored triangles,
    /// ids, slots and figures, with and without spatial splits, and the
    /// fast build's pre-splits.
    #[test]
    fn workers_build_as_the_calling_thread() {
        use crate::accel::testkit::Backwards;
        let mut largest = 0;
        for name in ["gears", "animated", "balls"] {
            let s = crate::scenes::builtin(name).unwrap();
            let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
            let n = scene.triangle_count() as usize;
            largest = largest.max(n);
            for (quality, reserve, test) in [
                (BuildQuality::Medium, 0, TriTest::MollerTrumbore),
                (BuildQuality::High, n / 2, TriTest::Projection),
                (BuildQuality::High, 0, TriTest::MollerTrumbore),
                (BuildQuality::Low, n / 4, TriTest::Projection),
            ] {
                let p = BvhParams {
                    quality,
                    test,
                    presplit: true,
                    ..BvhParams::default()
                };
                let mut results = Vec::new();
                for workers in [0, 1, 2, 3, 16] {
                    let mut st = Store::with_refs(n, n + reserve, test == TriTest::Projection);
                    let mut bvh = st.bvh();
                    let info = if workers == 0 {
                        build(&mut bvh, &scene, &p).unwrap()
                    } else {
                        build_with(&mut bvh, &scene, &p, &Backwards(workers)).unwrap()
                    };
                    let v = bvh.view().unwrap();
                    check_invariants(&v, &scene, &p);
                    let bits = |x: &[f32]| x.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                    let nodes: Vec<u8> = bytemuck::cast_slice(v.nodes).to_vec();
                    let tris: Vec<f32> = v
                        .tris
                        .iter()
                        .flat_map(|t| t.v0.into_iter().chain(t.v1).chain(t.v2))
                        .collect();
                    let proj: Vec<u8> = bytemuck::cast_slice(v.proj).to_vec();
                    results.push((
                        info,
                        nodes,
                        bits(&tris),
                        proj,
                        v.tri_ids.to_vec(),
                        v.slot_of.to_vec(),
                    ));
                }
                let first = &results[0];
                assert!(first.0.nodes > 1, "{name}");
                for r in &results[1..] {
                    assert!(
                        r == first,
                        "{name} {quality:?} reserve {reserve}: a worker count changed the tree"
                    );
                }
            }
        }
        // The top's nodes bin on every worker in at least one scene.
        assert!(largest >= 2 * PAR_BINNING, "{largest} triangles");
    }

    #[test]
    fn coincident_triangles() {
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let (v, ix) = soup(&vec![t; 1000]);
        let info = build_check(&v, &ix, &BvhParams::default());
        assert_eq!(info.triangles, 1000);
        assert!(info.depth <= 10, "depth {}", info.depth);
        // Mixed: a heap of copies inside a spread-out scene.
        let mut tris = vec![t; 300];
        for i in 0..300 {
            let o = i as f32 * 0.37;
            tris.push([[o, 2.0, 0.0], [o + 0.2, 2.0, 0.1], [o, 2.3, 0.5]]);
        }
        let info = build_check(
            &soup(&tris).0,
            &soup(&tris).1,
            &BvhParams {
                leaf_size: 2,
                ..Default::default()
            },
        );
        assert_eq!(info.triangles, 600);
        assert!((info.depth as usize) < MAX_DEPTH);
    }

    #[test]
    fn deep_scene_hits_depth_limit_safely() {
        let (v, ix) = soup(&deep_tris());
        let info = build_check(
            &v,
            &ix,
            &BvhParams {
                leaf_size: 1,
                bins: 2,
                ..Default::default()
            },
        );
        assert_eq!(info.depth as usize, MAX_DEPTH);
    }

    #[test]
    fn empty_and_degenerate() {
        let info = build_check(&[], &[], &BvhParams::default());
        assert_eq!((info.triangles, info.nodes, info.leaves), (0, 0, 0));
        let nan = f32::NAN;
        let (v, ix) = soup(&[
            [[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
            [[0.0; 3], [0.0; 3], [0.0; 3]],
            [[nan, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            [[f32::INFINITY, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        ]);
        let info = build_check(&v, &ix, &BvhParams::default());
        assert_eq!(
            (
                info.triangles,
                info.nodes,
                info.excluded_zero_area,
                info.excluded_non_finite
            ),
            (0, 0, 2, 2)
        );
        // One valid triangle among degenerate ones.
        let (v, ix) = soup(&[
            [[0.0; 3], [0.0; 3], [0.0; 3]],
            [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        ]);
        let info = build_check(&v, &ix, &BvhParams::default());
        assert_eq!((info.triangles, info.nodes, info.leaves), (1, 1, 1));
    }

    /// A refused build, whichever check refuses it, leaves both trees as
    /// they were: the binary tree, and the wide tree in the reference
    /// pool (every refusal comes before the pool is written).
    #[test]
    fn errors_leave_previous_build() {
        let s = crate::scenes::builtin("tetra").unwrap();
        let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
        let n = scene.triangle_count() as usize;
        for quality in [BuildQuality::Low, BuildQuality::Medium] {
            let mut st = Store::new(n, false);
            let mut bvh = st.bvh();
            let p = BvhParams {
                quality,
                ..BvhParams::default()
            };
            let first = build(&mut bvh, &scene, &p).unwrap();
            let nodes: Vec<BvhNode> = bvh.view().unwrap().nodes.to_vec();
            let ids: Vec<u32> = bvh.view().unwrap().tri_ids.to_vec();
            let wide: Vec<PrimRef> = bvh.pools_mut().refs.to_vec();
            // Too many triangles.
            let big = crate::scenes::builtin("balls").unwrap();
            let big_scene = Scene::from_f32(&big.mesh.vertices, &big.mesh.indices).unwrap();
            assert!(matches!(
                build(&mut bvh, &big_scene, &p),
                Err(Error::Capacity {
                    pool: Pool::Triangles,
                    ..
                })
            ));
            // Bad parameters, projection without its pool.
            for bad in [
                BvhParams { leaf_size: 0, ..p },
                BvhParams { leaf_size: 65, ..p },
                BvhParams { bins: 1, ..p },
                BvhParams { bins: 65, ..p },
                BvhParams {
                    traversal_cost: f32::NAN,
                    ..p
                },
                BvhParams {
                    traversal_cost: 0.0,
                    ..p
                },
                BvhParams {
                    test: TriTest::Projection,
                    ..p
                },
            ] {
                assert!(
                    matches!(
                        build(&mut bvh, &scene, &bad),
                        Err(Error::InvalidArgument(_))
                    ),
                    "{bad:?}"
                );
            }
            let v = bvh.view().unwrap();
            assert!(first.wide_nodes > 0);
            assert_eq!(*v.info, first, "{quality:?}");
            assert_eq!(v.nodes, &nodes[..]);
            assert_eq!(v.tri_ids, &ids[..]);
            check_invariants(&v, &scene, &p);
            assert!(
                bvh.pools_mut().refs == &wide[..],
                "{quality:?}: the wide tree's pool"
            );
            // Node pool too small (the other pools large enough).
            let mut st2 = Store::new(n, false);
            st2.nodes.truncate(n);
            let mut bvh2 = st2.bvh();
            assert!(matches!(
                build(&mut bvh2, &scene, &p),
                Err(Error::Capacity { .. })
            ));
            assert!(bvh2.view().is_none());
        }
    }

    /// Pools smaller than the input but large enough for its traceable
    /// triangles: the build is accepted (the check counts them).
    #[test]
    fn excluded_triangles_do_not_count_against_the_pools() {
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let flat = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
        let (v, ix) = soup(&[t, flat, flat, t]);
        let scene = Scene::from_f32(&v, &ix).unwrap();
        for quality in [BuildQuality::Low, BuildQuality::Medium] {
            let mut st = Store::new(4, false);
            st.tris.truncate(2);
            st.nodes.truncate(3);
            let mut bvh = st.bvh();
            let p = BvhParams {
                quality,
                ..BvhParams::default()
            };
            let info = build(&mut bvh, &scene, &p).unwrap();
            assert_eq!((info.triangles, info.excluded_zero_area), (2, 2));
        }
    }

    #[test]
    fn sah_not_worse_than_median_like() {
        // A binned SAH tree over a uniform-ish scene has a modest cost.
        let s = crate::scenes::builtin("balls").unwrap();
        let info = build_check(&s.mesh.vertices, &s.mesh.indices, &BvhParams::default());
        assert!(info.sah_cost < 200.0, "sah {}", info.sah_cost);
        assert!(info.leaves as usize >= s.mesh.triangle_count() / 8);
    }
}

#[cfg(test)]
mod perf {
    //! `cargo test --release --lib bvh::build::perf -- --ignored --nocapture`:
    //! build time and single-ray / 2x2 SIMD ray throughput on the OBJ scenes
    //! of ../shared/scenes (skipped when absent).
    use super::testutil::Store;
    use super::*;
    use crate::accel::bvh::{traverse_simd, traverse_single};
    use crate::counters::Counters;
    use crate::geom::{Hit4, M4, Mt, Ray, Ray4};
    use glam::Vec3;

    /// CPU time of this thread in seconds (Linux; wall time elsewhere would
    /// count other processes on a busy machine).
    fn cpu() -> f64 {
        std::fs::read_to_string("/proc/thread-self/schedstat")
            .ok()
            .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok())
            .map_or(0.0, |ns| ns as f64 * 1e-9)
    }

    use crate::accel::testkit::load_obj as load;

    #[test]
    #[ignore]
    fn perf_obj_scenes() {
        let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes");
        for file in [
            "bunny/bunny_tinybvh.obj",
            "crytek_sponza/crytek_sponza.obj",
            "conference/conference.obj",
            "sibenik/sibenik.obj",
            "legocar/legocar.obj",
        ] {
            let Some((v, ix)) = load(&dir.join(file)) else {
                eprintln!("{file}: not found, skipped");
                continue;
            };
            let scene = Scene::from_f32(&v, &ix).unwrap();
            let n = scene.triangle_count() as usize;
            // SHEAF_PERF_RESERVE=P: a reference reserve of P% (HIGH's
            // spatial splits, LOW's pre-splits).
            let reserve = std::env::var("SHEAF_PERF_RESERVE").map_or(0, |r| r.parse().unwrap());
            let mut st = Store::with_refs(n, n + n * reserve / 100, false);
            let mut bvh = st.bvh();
            // SHEAF_PERF_QUALITY=low|medium|high: one build alone (for perf);
            // SHEAF_PERF_WIDTH=2: without the 4-wide tree (its collapse).
            let only = std::env::var("SHEAF_PERF_QUALITY").unwrap_or_default();
            let width = std::env::var("SHEAF_PERF_WIDTH").map_or(4, |w| w.parse().unwrap());
            for quality in [BuildQuality::Low, BuildQuality::Medium, BuildQuality::High] {
                if !only.is_empty() && !format!("{quality:?}").eq_ignore_ascii_case(&only) {
                    continue;
                }
                // SHEAF_PERF_PRESPLIT=1: LOW pre-splits into the reserve.
                let presplit = std::env::var("SHEAF_PERF_PRESPLIT").is_ok_and(|v| v == "1");
                let p = BvhParams {
                    quality,
                    width,
                    presplit,
                    ..BvhParams::default()
                };
                perf_one(file, &scene, &mut bvh, &p);
            }
        }
    }

    fn perf_one(file: &str, scene: &Scene<'_>, bvh: &mut Bvh<'_>, p: &BvhParams) {
        let n = scene.triangle_count() as usize;
        {
            // Mean thread CPU time over at least 1 s of builds (the clock
            // ticks coarsely on some kernels).
            let mut info = build(bvh, scene, p).unwrap();
            let (t0, mut reps, mut fastest) = (cpu(), 0u32, f64::INFINITY);
            while cpu() - t0 < 1.0 || reps < 5 {
                let t = std::time::Instant::now();
                info = build(bvh, scene, p).unwrap();
                fastest = fastest.min(t.elapsed().as_secs_f64());
                reps += 1;
            }
            let mean = (cpu() - t0) / reps as f64;
            println!(
                "{file} {:?}: {n} tris, build: mean thread CPU time {:.2} ms ({:.2} Mtris/s) over {reps} builds, fastest wall {:.2} ms ({:.2} Mtris/s); nodes {} leaves {} depth {} sah {:.1} references {:.3} per triangle",
                p.quality,
                mean * 1e3,
                n as f64 / mean / 1e6,
                fastest * 1e3,
                n as f64 / fastest / 1e6,
                info.nodes,
                info.leaves,
                info.depth,
                info.sah_cost,
                info.references as f64 / info.triangles.max(1) as f64
            );
            {
                // One worker, then two joined (this thread and one helper),
                // in 11 interleaved rounds: the median wall times and the
                // median of the rounds' ratios.
                let join = crate::mem::par::Join::new();
                let stop = core::sync::atomic::AtomicBool::new(false);
                let (mut one, mut two, mut gain) = (Vec::new(), Vec::new(), Vec::new());
                std::thread::scope(|sc| {
                    sc.spawn(|| {
                        while !stop.load(core::sync::atomic::Ordering::Relaxed) {
                            let _ = join.help(1, 2);
                        }
                    });
                    // Every session (the 11 builds and the last, empty one
                    // after `stop`) takes the helper once.
                    for _ in 0..11 {
                        let t = std::time::Instant::now();
                        build(bvh, scene, p).unwrap();
                        let a = t.elapsed().as_secs_f64();
                        let t = std::time::Instant::now();
                        join.lead(2, |par| build_with(bvh, scene, p, par).unwrap());
                        let b = t.elapsed().as_secs_f64();
                        one.push(a);
                        two.push(b);
                        gain.push(a / b);
                    }
                    stop.store(true, core::sync::atomic::Ordering::Relaxed);
                    join.lead(2, |_| ());
                });
                let median = |v: &mut Vec<f64>| {
                    v.sort_by(f64::total_cmp);
                    v[v.len() / 2]
                };
                println!(
                    "{file} {:?}: 1 worker {:.2} ms, 2 joined workers {:.2} ms (median walls), 2-worker gain {:.2}x (median of 11 rounds)",
                    p.quality,
                    median(&mut one) * 1e3,
                    median(&mut two) * 1e3,
                    median(&mut gain)
                );
            }
            if p.quality == BuildQuality::Medium {
                // Refit to the same vertices (its cost does not depend on
                // how far they moved).
                let (t0, mut reps, mut fastest) = (cpu(), 0u32, f64::INFINITY);
                while cpu() - t0 < 1.0 || reps < 5 {
                    let t = std::time::Instant::now();
                    crate::accel::bvh::refit::refit(bvh, scene).unwrap();
                    fastest = fastest.min(t.elapsed().as_secs_f64());
                    reps += 1;
                }
                println!(
                    "{file}: refit: mean thread CPU time {:.2} ms over {reps} refits, fastest wall {:.2} ms",
                    (cpu() - t0) / reps as f64 * 1e3,
                    fastest * 1e3
                );
            }
            let info = *bvh.info().unwrap();
            // Primary rays of the "outside" view of tests/common (1024 x 1024).
            let (lo, hi) = (info.bounds.min, info.bounds.max);
            let c = 0.5 * (lo + hi);
            let r = 0.5 * (hi - lo).length();
            let fov = 45.0f32;
            let eye =
                c + Vec3::new(0.6, 0.45, 1.0).normalize() * (r / (fov.to_radians() * 0.5).sin());
            let cam = crate::Camera {
                eye: eye.to_array(),
                look_at: c.to_array(),
                up: [0.0, 1.0, 0.0],
                fov_y_deg: fov,
            };
            let (w, h) = (1024u32, 1024u32);
            let pr = crate::render::PrimaryRays::new(&cam, w, h).unwrap();
            let view = bvh.view().unwrap();
            let rays: Vec<Ray> = (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| pr.ray(x, y))
                .collect();
            let mut ctr = Counters::default();
            let t = cpu();
            let mut hits = 0u32;
            for ray in &rays {
                hits += traverse_single::intersect::<Mt>(&view, ray, &mut ctr).is_hit() as u32;
            }
            let ts = cpu() - t;
            // 2x2 quads.
            let mut quads = Vec::new();
            for y in (0..h).step_by(2) {
                for x in (0..w).step_by(2) {
                    quads.push(Ray4::from_rays(&[
                        pr.ray(x, y),
                        pr.ray(x + 1, y),
                        pr.ray(x, y + 1),
                        pr.ray(x + 1, y + 1),
                    ]));
                }
            }
            let active = vec![M4::TRUE; quads.len()];
            let mut out = vec![Hit4::MISS; quads.len()];
            let mut c4 = Counters::default();
            let t = cpu();
            traverse_simd::intersect::<Mt>(&view, &quads, &active, &mut out, true, &mut c4);
            let tq = cpu() - t;
            println!(
                "    1024^2 outside view, MT: single {:.2} Mrays/s ({:.1} box + {:.1} tri tests/ray, {:.0}% hit), 2x2 SIMD {:.2} Mrays/s ({:.1} box tests/quad)",
                rays.len() as f64 / ts / 1e6,
                ctr.aabb_tests as f64 / rays.len() as f64,
                ctr.tri_tests as f64 / rays.len() as f64,
                100.0 * hits as f64 / rays.len() as f64,
                rays.len() as f64 / tq / 1e6,
                c4.aabb_tests as f64 / quads.len() as f64,
            );
        }
    }
}
