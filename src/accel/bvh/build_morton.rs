//! The fast build (`BuildQuality::Low`): a linear BVH over the Morton order
//! of the triangles' centroids (Lauterbach, Garland, Sengupta, Luebke,
//! Manocha 2009, "Fast BVH Construction on GPUs", section 3, LBVH; the
//! top-down split at the highest differing bit as in Karras 2012,
//! "Maximizing Parallelism in the Construction of BVHs, Octrees, and k-d
//! Trees", section 3). Embree's `RTC_BUILD_QUALITY_LOW` is this kind of
//! build. Every phase runs on the caller's workers (`mem::par`; one worker
//! is the plain single-threaded build), and the tree does not depend on
//! how many there are.
//!
//! 1. Each worker classifies its share of the triangles and writes their
//!    references (box and id) in place; the leader merges the bounds and
//!    counts and checks every pool's capacity (nothing a traversal reads
//!    is written before).
//!    With `BvhParams::presplit` and a reserve of references, large, thin
//!    triangles are then split into parts (`presplit.rs`), written after
//!    the triangles' own references.
//! 2. Each centroid is quantised to 10 bits per axis over the centroid
//!    bounds and interleaved into a 30-bit Morton code (x in the highest
//!    bit of each triple); the (code, reference index) pairs of the valid
//!    references go to the node pool, which the tree has not reached yet.
//! 3. The pairs are radix sorted, three 10-bit passes, each worker
//!    counting and scattering its share (`radix_pass`), and the triangles
//!    are stored in that order (pre-split: first the parts' boxes, from
//!    which the leaf boxes are fitted, then the triangles in their place).
//! 4. The tree is emitted top-down with an explicit stack: a range of
//!    sorted codes splits where its highest differing bit flips (a binary
//!    search; the node's axis is that bit's axis, the left child lower on
//!    it); a range whose codes are all equal splits at its middle; a range
//!    of at most `leaf_size` triangles, or at `MAX_DEPTH`, is a leaf (a
//!    leaf-sized range naming one pre-split triangle twice is split before
//!    the repeat, so a leaf names each triangle once). The
//!    leader emits the top of the tree down to ranges of at most
//!    `job_size(n)` triangles; those subtrees are the workers' jobs, each
//!    emitted into a region of the node pool big enough for any subtree of
//!    its size (`2c - 2` nodes below a root of `c` triangles).
//! 5. The workers fit each region's boxes bottom-up (`refit::fit`), the
//!    leader closes the gaps between the regions and fits the top
//!    (children follow their parent everywhere, as refit's reverse pass
//!    needs).
//!
//! # Exactness
//! The boxes are exactly those the binned build would give the same
//! shape (padded, `refit::leaf_box`); every traversal's guarantee holds
//! whatever the shape, so every method returns on this tree the triangle
//! and bitwise t it returns on the SAH tree. A pre-split tree's leaf boxes
//! are fitted to the parts' boxes instead, which hold every hit point of
//! the parts (`presplit.rs`, "Exactness"). `tests/exact/bvh_exact.rs`
//! runs every method on both and checks their single ray against the SAH
//! tree's.
//!
//! # Deviations
//! - The codes' 10 bits per axis separate up to 1024 cells per axis of the
//!   centroid bounds; triangles sharing a cell are split at the middle of
//!   their range, in sort order (the mesh order within a cell).
//! - No SAH anywhere: `bins` and `traversal_cost` are unused, leaves hold
//!   up to `leaf_size` triangles, and `BvhInfo::sah_cost` weighs the padded
//!   boxes (the SAH builds weigh unpadded ones; the padding is 1e-5 of the
//!   scene's size).
//! - The sort scratch (four `u32` per triangle) lives in the node pool and
//!   the sorted codes in the reference pool, so the fast build needs no
//!   memory per triangle the SAH build does not; its per-worker counts
//!   (`SCRATCH`) are fixed.

use super::presplit;
use super::refit::{fit, half_area, sah_sum};
use super::refs::{Box3, PoolRoom, reference_capacity};
use super::{BvhInfo, BvhNode, BvhParams, BvhPools, MAX_DEPTH, PrimRef};
use crate::error::{Error, Pool, Result};
use crate::geom::{Aabb, Excluded, INVALID_ID, ProjTri, Scene, TriTest, TriVerts};
use crate::mem::par::{MAX_WORKERS, Par, Parts, atomic_u32, share};
use crate::mem::sort::{Pairs, PairsMut, even_parts, radix_pass};
use core::sync::atomic::{AtomicU32, Ordering};
use glam::Vec3A;

/// Bits per axis of a Morton code.
const BITS: u32 = 10;
/// Bits per radix pass (three passes sort the 30-bit codes).
const DIGIT: u32 = 10;
const BUCKETS: usize = 1 << DIGIT;

/// Most worker jobs (subtrees) a build hands out; ranges beyond it are
/// emitted by the leader.
const MAX_JOBS: usize = 1024;

/// What one worker found in its share of the triangles (step 1).
#[derive(Clone, Copy)]
struct Found {
    valid: u32,
    non_finite: u32,
    zero_area: u32,
    bounds: Box3,
    cent: Box3,
}

const NOT_FOUND: Found = Found {
    valid: 0,
    non_finite: 0,
    zero_area: 0,
    bounds: Box3::EMPTY,
    cent: Box3::EMPTY,
};

/// A subtree a worker emits (step 4): its root node (written by the
/// leader's parent split, in the top), its range, its depth, its region.
#[derive(Clone, Copy, Default)]
struct Job {
    root: u32,
    begin: u32,
    /// The root's split (the leader splits the root).
    mid: u32,
    end: u32,
    depth: u32,
    /// First node of the region, and the nodes the subtree used there.
    region: u32,
    used: u32,
    leaves: u32,
    max_depth: u32,
    /// The region's share of the SAH sum (`refit::sah_sum`).
    sah: f64,
}

/// Bytes of the build scratch the fast build takes: per-worker findings
/// and radix counts, and the job list.
pub const SCRATCH: usize = (crate::mem::scratch::bytes::<Found>(MAX_WORKERS)
    + crate::mem::scratch::bytes::<[u32; BUCKETS]>(MAX_WORKERS)
    + crate::mem::scratch::bytes::<Job>(MAX_JOBS))
.next_multiple_of(64);

/// Triangles of a range below which the leader hands the subtree to a
/// worker: about 64 jobs per build (a lopsided split may still hand out
/// smaller ones).
fn job_size(n: usize) -> usize {
    (n / 64).max(256)
}

/// The 10 low bits of `v` spread to every third bit (bit i to bit 3i).
#[inline(always)]
fn spread(v: u32) -> u32 {
    let mut x = v & 0x3ff;
    x = (x | (x << 16)) & 0x0300_00ff;
    x = (x | (x << 8)) & 0x0300_f00f;
    x = (x | (x << 4)) & 0x030c_30c3;
    (x | (x << 2)) & 0x0924_9249
}

/// The axis bit `h` of a code encodes (x: `h % 3 == 2`).
#[inline(always)]
fn axis_of_bit(h: u32) -> usize {
    2 - (h % 3) as usize
}

/// Quantises doubled centroids to `0..2^BITS` per axis over `cent`.
struct Quantizer {
    min: Vec3A,
    scale: Vec3A,
}

impl Quantizer {
    fn new(cent: &Box3) -> Quantizer {
        let ext = cent.max - cent.min;
        let cells = (1u32 << BITS) as f32 * (1.0 - 1e-6);
        // An axis without extent maps everything to cell 0.
        let scale = Vec3A::select(
            ext.cmpgt(Vec3A::ZERO),
            Vec3A::splat(cells) / ext,
            Vec3A::ZERO,
        );
        Quantizer {
            min: cent.min,
            scale,
        }
    }
    /// The Morton code of a doubled centroid (finite: step 1 keeps finite
    /// triangles only; the clamp keeps rounding at the top in range).
    #[inline(always)]
    fn code(&self, c: Vec3A) -> u32 {
        let top = ((1u32 << BITS) - 1) as f32;
        let q = ((c - self.min) * self.scale)
            .max(Vec3A::ZERO)
            .min(Vec3A::splat(top));
        (spread(q.x as u32) << 2) | (spread(q.y as u32) << 1) | spread(q.z as u32)
    }
}

/// Build `pools` from `scene` on `par`'s workers (`p.quality` is `Low`,
/// `p` validated, the pools' room checked by `build::check_room`). On
/// error nothing a traversal reads has changed.
pub(super) fn build(
    pools: &mut BvhPools<'_>,
    scene: &Scene<'_>,
    p: &BvhParams,
    par: &dyn Par,
) -> Result<BvhInfo> {
    let workers = crate::mem::par::workers_of(par)?;
    let n_in = scene.triangle_count() as usize;
    let cap = |needed: usize, available: usize| Error::Capacity {
        pool: Pool::Triangles,
        needed: needed as u64,
        available: available as u64,
    };
    // References are written in place (at the triangle's index).
    let room = pools.slot_of.len().min(pools.refs.len());
    if n_in > room {
        return Err(cap(n_in, room));
    }
    let pool_room = PoolRoom::of(pools, p);
    let base = BvhInfo {
        leaf_size: p.leaf_size,
        bins: p.bins,
        test: p.test,
        quality: p.quality,
        ..BvhInfo::default()
    };
    if n_in == 0 {
        // Nothing to sort; and pools of no triangles (a context whose
        // limits hold none) carve no build scratch (fuzz run 8).
        return Ok(base);
    }
    let BvhPools {
        nodes,
        tris,
        proj,
        tri_ids,
        slot_of,
        refs,
        scratch,
    } = pools;
    let scratch = crate::mem::Scratch::new(scratch);
    let (found, scratch) = scratch.take(workers, NOT_FOUND);
    let (counts, scratch) = scratch.take(workers, [0u32; BUCKETS]);
    let (jobs, _) = scratch.take(MAX_JOBS, Job::default());

    // 1. References and findings per worker (with a reserve, each
    // triangle's `presplit::excess` too).
    let may_split = p.presplit && pool_room.reserve() > 0;
    {
        let (rs, fs) = (
            Parts::even(&mut refs[..n_in], workers),
            Parts::even(&mut *found, workers),
        );
        par.run(&|w| {
            let (first, out) = (rs.start(w), rs.get(w));
            fs.get(w)[0] = if may_split {
                find::<true>(scene, first, out)
            } else {
                find::<false>(scene, first, out)
            };
        });
    }
    let mut all = NOT_FOUND;
    for f in found.iter() {
        all.valid += f.valid;
        all.non_finite += f.non_finite;
        all.zero_area += f.zero_area;
        all.bounds.grow(&f.bounds);
        all.cent.grow(&f.cent);
    }
    let n = all.valid as usize;
    let proj_on = p.test == TriTest::Projection;
    // `build::check_room` refused, before anything was written, every
    // build whose traceable triangles the pools cannot hold.
    debug_assert!(
        n <= tris.len().min(tri_ids.len())
            && (2 * n).saturating_sub(1) <= nodes.len()
            && (!proj_on || n <= proj.len())
    );

    // From here on nothing fails.
    let mut info = BvhInfo {
        bounds: if n > 0 {
            all.bounds.aabb()
        } else {
            Aabb::default()
        },
        triangles_in: n_in as u32,
        triangles: n as u32,
        references: n as u32,
        excluded_non_finite: all.non_finite,
        excluded_zero_area: all.zero_area,
        ..base
    };
    slot_of[..n_in].fill(INVALID_ID);
    if n == 0 {
        return Ok(info);
    }
    crate::fault_point!(BvhBuild);
    let pad = super::box_pad(all.bounds.min, all.bounds.max);

    // 1b. Pre-splitting into the reserve, when asked and the limits give one.
    let reserve = reference_capacity(&pool_room, p, n, n_in) - n;
    let added = (reserve > 0)
        .then(|| presplit::presplit(refs, n_in, reserve, scene, &all.bounds, par, workers));
    let (big_n, cent) = match &added {
        Some(a) => (n + a.valid, a.cent),
        None => (n, all.cent),
    };
    let n = big_n;
    info.references = n as u32;

    // 2-3. Codes and reference indices in the node pool (2n - 1 nodes of 8
    // words hold the four arrays of n words), sorted; the triangles (with
    // pre-splitting, first the parts' boxes) stored in that order.
    {
        let words: &mut [u32] = bytemuck::cast_slice_mut(&mut nodes[..2 * n - 1]);
        let (keys, rest) = words.split_at_mut(n);
        let (vals, rest) = rest.split_at_mut(n);
        let (tmp_keys, rest) = rest.split_at_mut(n);
        let tmp_vals = &mut rest[..n];
        let qz = Quantizer::new(&cent);
        // Worker w's pairs start after the valid references before its
        // share: its triangles' own, then (pre-split) its parts' slots.
        let n_own = all.valid as usize;
        let mut start = [0usize; MAX_WORKERS + 1];
        let mut start_x = [n_own; MAX_WORKERS + 1];
        for w in 0..workers {
            start[w + 1] = start[w] + found[w].valid as usize;
            start_x[w + 1] = start_x[w] + added.as_ref().map_or(0, |a| a.valid_per[w]);
        }
        {
            let (own_k, x_k) = keys.split_at_mut(n_own);
            let (own_v, x_v) = vals.split_at_mut(n_own);
            let xb = start_x.map(|x| x - n_own);
            let (ks, vs) = (
                Parts::at(own_k, &start[..workers + 1]),
                Parts::at(own_v, &start[..workers + 1]),
            );
            let (xks, xvs) = (
                Parts::at(x_k, &xb[..workers + 1]),
                Parts::at(x_v, &xb[..workers + 1]),
            );
            let slots = added.as_ref().map(|a| a.slot_bounds);
            let refs = &refs[..];
            par.run(&|w| {
                // The valid references of `range`: codes and indices.
                let put = |k: &mut [u32], v: &mut [u32], range: core::ops::Range<usize>| {
                    let valid = refs[range.clone()]
                        .iter()
                        .zip(range)
                        .filter(|(r, _)| r._pad != presplit::EXCLUDED);
                    for ((k, v), (r, i)) in k.iter_mut().zip(v).zip(valid) {
                        *k = qz.code(Vec3A::from(r.min) + Vec3A::from(r.max));
                        *v = i as u32;
                    }
                };
                put(ks.get(w), vs.get(w), share(n_in, w, workers));
                if let Some(sb) = slots {
                    put(xks.get(w), xvs.get(w), sb[w]..sb[w + 1]);
                }
            });
        }
        let (counts, even) = (
            counts.as_flattened_mut(),
            &even_parts(n, workers)[..workers],
        );
        // Three passes of DIGIT bits, the pairs ending in the tmp arrays.
        for pass in 0..3 {
            let (from, to) = if pass % 2 == 0 {
                let to = PairsMut {
                    keys: &mut *tmp_keys,
                    vals: &mut *tmp_vals,
                };
                (Pairs { keys, vals }, to)
            } else {
                (
                    Pairs {
                        keys: tmp_keys,
                        vals: tmp_vals,
                    },
                    PairsMut { keys, vals },
                )
            };
            radix_pass(from, to, even, pass * DIGIT, DIGIT, counts, par);
        }
        let (keys, vals) = (&*tmp_keys, &*tmp_vals);
        let ts = Parts::even(&mut tris[..n], workers);
        let is = Parts::even(&mut tri_ids[..n], workers);
        if added.is_some() {
            // The parts' boxes (as the stored triangles' corners, which
            // `refit::fit` unites) and ids, read before the codes
            // overwrite the references.
            let all_refs = &refs[..];
            par.run(&|w| {
                let (t, ids) = (ts.get(w), is.get(w));
                let at = ts.start(w);
                for (k, &v) in vals[at..at + t.len()].iter().enumerate() {
                    let r = &all_refs[v as usize];
                    t[k] = TriVerts {
                        v0: r.min,
                        v1: r.max,
                        v2: r.min,
                    };
                    ids[k] = r.id;
                }
            });
            let codes: &mut [u32] = bytemuck::cast_slice_mut(&mut refs[..n]);
            let cs = Parts::even(&mut codes[..n], workers);
            par.run(&|w| {
                let c = cs.get(w);
                let at = cs.start(w);
                c.copy_from_slice(&keys[at..at + c.len()]);
            });
        } else {
            let codes: &mut [u32] = bytemuck::cast_slice_mut(&mut refs[..n]);
            let cs = Parts::even(&mut codes[..n], workers);
            let ps = Parts::even(if proj_on { &mut proj[..n] } else { &mut [] }, workers);
            let slots = atomic_u32(&mut slot_of[..n_in]);
            par.run(&|w| {
                let (c, t, pj, ids) = (cs.get(w), ts.get(w), ps.get(w), is.get(w));
                let at = cs.start(w);
                c.copy_from_slice(&keys[at..at + c.len()]);
                // Without pre-splitting a reference's index is its triangle's id.
                ids.copy_from_slice(&vals[at..at + c.len()]);
                store::<false>(scene, vals, at, t, pj, slots);
            });
        }
    }

    // 4. The top on the leader, down to the jobs.
    let split_on = added.is_some();
    let codes: &[u32] = &bytemuck::cast_slice::<_, u32>(&refs[..n])[..n];
    let leaf_size = p.leaf_size as usize;
    let traversal_cost = p.traversal_cost;
    let nodes = &mut nodes[..2 * n - 1];
    let mut top = Emitted::default();
    let (top_next, n_jobs) = {
        let mut sink = Sink {
            leaf_size,
            stop: job_size(n),
            jobs: &mut jobs[..],
            n_jobs: 0,
            ids: split_on.then_some(&tri_ids[..n]),
        };
        let next = emit(
            codes,
            nodes,
            0,
            &[(0, 0, n as u32, 0)],
            1,
            &mut top,
            &mut sink,
        );
        (next, sink.n_jobs)
    };
    // Each job's root split here, its region after the top and the
    // regions before it: `2c - 2` nodes below a root of `c` triangles.
    let jobs = &mut jobs[..n_jobs];
    let mut region = top_next;
    for j in jobs.iter_mut() {
        let (mid, axis) = split(codes, j.begin as usize, j.end as usize);
        nodes[j.root as usize] = BvhNode::inner(&Aabb::EMPTY, region, axis);
        j.mid = mid as u32;
        j.region = region;
        region += 2 * (j.end - j.begin) - 2;
    }
    // Jobs in runs of about equal triangle counts, one run per worker.
    let mut jb = [0usize; MAX_WORKERS + 1];
    let mut nb = [top_next as usize; MAX_WORKERS + 1];
    {
        let total: usize = jobs.iter().map(|j| (j.end - j.begin) as usize).sum();
        let (mut k, mut acc) = (0usize, 0usize);
        for w in 1..workers {
            while k < jobs.len() && acc < total * w / workers {
                acc += (jobs[k].end - jobs[k].begin) as usize;
                k += 1;
            }
            jb[w] = k;
            nb[w] = jobs.get(k).map_or(region as usize, |j| j.region as usize);
        }
        jb[workers] = jobs.len();
        nb[workers] = region as usize;
    }
    {
        let (js, ns) = (
            Parts::at(&mut *jobs, &jb[..workers + 1]),
            Parts::at(&mut *nodes, &nb[..workers + 1]),
        );
        let (tris, ids) = (&tris[..n], split_on.then_some(&tri_ids[..n]));
        par.run(&|w| {
            let (mine, part) = (js.get(w), ns.get(w));
            let base = ns.start(w);
            let mut sink = Sink {
                leaf_size,
                stop: 0,
                jobs: &mut [],
                n_jobs: 0,
                ids,
            };
            for j in mine.iter_mut() {
                let mut e = Emitted::default();
                let d = j.depth + 1;
                let kids = [
                    (j.region, j.begin, j.mid, d),
                    (j.region + 1, j.mid, j.end, d),
                ];
                let end = emit(codes, part, base, &kids, j.region + 2, &mut e, &mut sink);
                j.used = end - j.region;
                j.leaves = e.leaves;
                j.max_depth = e.depth;
                // 5. The region's boxes bottom-up (children in the region).
                let (a, b) = (j.region as usize - base, end as usize - base);
                fit(&mut part[a..b], j.region as usize, b - a, tris, pad);
                j.sah = sah_sum(&part[a..b], traversal_cost);
            }
        });
    }

    // 5. Close the gaps (regions moved down, in order) and fit the top.
    let mut to = top_next as usize;
    info.leaves = top.leaves;
    info.depth = top.depth;
    for j in jobs.iter() {
        let (from, used) = (j.region as usize, j.used as usize);
        let shift = (from - to) as u32;
        if shift > 0 {
            nodes.copy_within(from..from + used, to);
            for nd in &mut nodes[to..to + used] {
                if !nd.is_leaf() {
                    nd.first -= shift;
                }
            }
        }
        // The job's root points at its region's first pair.
        nodes[j.root as usize].first -= shift;
        to += used;
        info.leaves += j.leaves;
        info.depth = info.depth.max(j.max_depth);
    }
    let nn = to;
    // The top last: a job root's children are its (moved) region's first pair.
    fit(&mut nodes[..nn], 0, top_next as usize, &tris[..n], pad);
    info.nodes = nn as u32;
    let sum = sah_sum(&nodes[..top_next as usize], traversal_cost)
        + jobs.iter().map(|j| j.sah).sum::<f64>();
    info.sah_cost = (sum / half_area(&nodes[0]).max(f64::MIN_POSITIVE)) as f32;

    // 6. Pre-split: the stored triangles in place of the parts' boxes, and
    // each triangle's lowest slot (the same for any number of workers).
    if split_on {
        let ts = Parts::even(&mut tris[..n], workers);
        let ps = Parts::even(if proj_on { &mut proj[..n] } else { &mut [] }, workers);
        let ids = &tri_ids[..n];
        let slots = atomic_u32(&mut slot_of[..n_in]);
        par.run(&|w| store::<true>(scene, ids, ts.start(w), ts.get(w), ps.get(w), slots));
    }
    Ok(info)
}

/// The stored triangles of slots `at..at + t.len()`, whose ids are
/// `ids[at..]` (read ahead), with their projection data when `pj` has
/// room, each slot recorded in `slots` by its triangle (with `LOWEST`, the
/// lowest of a pre-split triangle's slots, whichever worker comes first).
fn store<const LOWEST: bool>(
    scene: &Scene<'_>,
    ids: &[u32],
    at: usize,
    t: &mut [TriVerts],
    pj: &mut [ProjTri],
    slots: &[AtomicU32],
) {
    let mine = &ids[..at + t.len()];
    for (k, &id) in mine[at..].iter().enumerate() {
        scene.prefetch_ahead(mine, at + k);
        let tri = scene.triangle(id);
        t[k] = tri;
        if let Some(x) = pj.get_mut(k) {
            *x = ProjTri::new(&tri);
        }
        let (slot, s) = (&slots[id as usize], (at + k) as u32);
        if LOWEST {
            slot.fetch_min(s, Ordering::Relaxed);
        } else {
            slot.store(s, Ordering::Relaxed);
        }
    }
}

/// What `emit` hands out: subtrees as jobs (the top's), and with
/// pre-splitting the stored references' triangle ids (`ids`), so that a
/// leaf never names one triangle twice.
struct Sink<'a> {
    /// Ranges of more than `leaf_size` and at most `stop` triangles are
    /// offered as jobs.
    leaf_size: usize,
    stop: usize,
    jobs: &'a mut [Job],
    n_jobs: usize,
    ids: Option<&'a [u32]>,
}

impl Sink<'_> {
    fn job(&mut self, j: Job) -> bool {
        match self.jobs.get_mut(self.n_jobs) {
            Some(x) => {
                *x = j;
                self.n_jobs += 1;
                true
            }
            None => false,
        }
    }
    /// The first reference of `begin..end` whose triangle an earlier one
    /// names (two parts of one pre-split triangle), where the range is
    /// split instead of becoming a leaf.
    fn repeat(&self, begin: usize, end: usize) -> Option<usize> {
        let ids = &self.ids?[begin..end];
        (1..ids.len())
            .find(|&i| ids[..i].contains(&ids[i]))
            .map(|i| begin + i)
    }
}

/// Step 1 for the triangles `first..first + out.len()`: their references
/// (`_pad` `presplit::EXCLUDED`: excluded; else 0, or with `EXCESS` the
/// bits of the triangle's `presplit::excess`) and what they hold.
fn find<const EXCESS: bool>(scene: &Scene<'_>, first: usize, out: &mut [PrimRef]) -> Found {
    let mut f = NOT_FOUND;
    for (k, r) in out.iter_mut().enumerate() {
        let t = (first + k) as u32;
        let tri = scene.triangle(t);
        match Scene::classify(&tri) {
            None => {
                let bx = Box3::of_tri(&tri);
                f.bounds.grow(&bx);
                f.cent.grow_point(bx.min + bx.max);
                *r = PrimRef {
                    min: bx.min.into(),
                    id: t,
                    max: bx.max.into(),
                    _pad: if EXCESS {
                        presplit::excess(&tri, &bx).to_bits()
                    } else {
                        0
                    },
                };
                f.valid += 1;
            }
            Some(e) => {
                *r = PrimRef {
                    id: t,
                    _pad: presplit::EXCLUDED,
                    ..PrimRef::default()
                };
                match e {
                    Excluded::NonFinite => f.non_finite += 1,
                    Excluded::ZeroArea => f.zero_area += 1,
                }
            }
        }
    }
    f
}

/// Where step 4 splits the sorted `codes[begin..end]`: the first code with
/// the highest differing bit set, and that bit's axis; the middle (axis 0)
/// when all codes are equal.
#[inline]
fn split(codes: &[u32], begin: usize, end: usize) -> (usize, usize) {
    let (a, b) = (codes[begin], codes[end - 1]);
    if a == b {
        return (begin + (end - begin) / 2, 0);
    }
    // Sorted codes share every bit above `h`.
    let h = 31 - (a ^ b).leading_zeros();
    let bit = 1u32 << h;
    let first = codes[begin..end].partition_point(|&c| c & bit == 0);
    (begin + first, axis_of_bit(h))
}

/// Leaves and deepest leaf an emission wrote.
#[derive(Default)]
struct Emitted {
    leaves: u32,
    depth: u32,
}

/// Step 4 from the ranges `starts` (node, begin, end, depth; emitted in
/// order), children allocated from `next` on, into `part` (the nodes
/// `base..`); ranges of more than `sink.leaf_size` and at most
/// `sink.stop` triangles are offered to `sink` as jobs (which takes them,
/// or they are emitted here).
/// Returns the next free node.
fn emit(
    codes: &[u32],
    part: &mut [BvhNode],
    base: usize,
    starts: &[(u32, u32, u32, u32)],
    mut next: u32,
    out: &mut Emitted,
    sink: &mut Sink<'_>,
) -> u32 {
    let (leaf_size, stop) = (sink.leaf_size, sink.stop);
    // (node, begin, end, depth) of ranges still to emit.
    let mut stack = [(0u32, 0u32, 0u32, 0u32); MAX_DEPTH + 2];
    let mut sp = 0usize;
    for &s in starts.iter().rev() {
        stack[sp] = s;
        sp += 1;
    }
    while sp > 0 {
        sp -= 1;
        let (mut node, b, e, mut depth) = stack[sp];
        let (begin, mut end) = (b as usize, e as usize);
        loop {
            let count = end - begin;
            let deep = (depth as usize) >= MAX_DEPTH;
            // A leaf-sized range naming a triangle twice splits before
            // the repeat.
            let repeat = (count <= leaf_size && !deep && sink.ids.is_some())
                .then(|| sink.repeat(begin, end))
                .flatten();
            let inner = (count > leaf_size && !deep) || repeat.is_some();
            let taken = inner
                && repeat.is_none()
                && count <= stop
                && sink.job(Job {
                    root: node,
                    begin: begin as u32,
                    end: end as u32,
                    depth,
                    ..Job::default()
                });
            if taken {
                // The job writes this node's subtree.
                break;
            }
            if !inner {
                part[node as usize - base] =
                    BvhNode::leaf(&Aabb::EMPTY, begin as u32, count as u32);
                out.leaves += 1;
                out.depth = out.depth.max(depth);
                break;
            }
            let (mut mid, axis) = split(codes, begin, end);
            if let Some(r) = repeat {
                mid = r;
            }
            let left = next;
            next += 2;
            part[node as usize - base] = BvhNode::inner(&Aabb::EMPTY, left, axis);
            depth += 1;
            stack[sp] = (left + 1, mid as u32, end as u32, depth);
            sp += 1;
            (node, end) = (left, mid);
        }
    }
    next
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::BuildQuality;
    use crate::accel::testkit::Store;
    use crate::mem::par::{Helped, Join, Serial};

    #[test]
    fn morton_codes_interleave_x_highest() {
        assert_eq!(spread(0b11), 0b1001);
        let q = Quantizer {
            min: Vec3A::ZERO,
            scale: Vec3A::ONE,
        };
        assert_eq!(q.code(Vec3A::new(1.0, 0.0, 0.0)), 0b100);
        assert_eq!(q.code(Vec3A::new(0.0, 1.0, 0.0)), 0b010);
        assert_eq!(q.code(Vec3A::new(0.0, 0.0, 1.0)), 0b001);
        assert_eq!(axis_of_bit(2), 0);
        assert_eq!(axis_of_bit(1), 1);
        assert_eq!(axis_of_bit(0), 2);
    }

    /// The tree does not depend on the number of workers: 1, 2 and 3
    /// joined workers build the same nodes and store the same triangles.
    #[test]
    fn workers_build_the_same_tree() {
        for &name in crate::scenes::BUILTIN_NAMES {
            let s = crate::scenes::builtin(name).unwrap();
            let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
            let p = BvhParams {
                quality: BuildQuality::Low,
                ..BvhParams::default()
            };
            let mut st = Store::new(scene.triangle_count() as usize, false);
            let mut bvh = st.bvh();
            let want = build(bvh.pools_mut(), &scene, &p, &Serial).unwrap();
            let want_nodes = bvh.pools_mut().nodes[..want.nodes as usize].to_vec();
            let want_ids = bvh.pools_mut().tri_ids[..want.triangles as usize].to_vec();
            for workers in [2usize, 3] {
                let join = Join::new();
                let got = std::thread::scope(|sc| {
                    for me in 1..workers {
                        let j = &join;
                        sc.spawn(move || assert_eq!(j.help(me, workers), Helped::Done(0)));
                    }
                    join.lead(workers, |par| build(bvh.pools_mut(), &scene, &p, par))
                })
                .unwrap();
                assert_eq!(got, want, "{name}, {workers} workers");
                let pools = bvh.pools_mut();
                assert!(
                    pools.nodes[..got.nodes as usize] == want_nodes[..],
                    "{name}"
                );
                assert!(
                    pools.tri_ids[..got.triangles as usize] == want_ids[..],
                    "{name}"
                );
            }
        }
    }
}
