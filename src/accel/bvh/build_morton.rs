//! The fast build (`BuildQuality::Low`): a linear BVH over the Morton order
//! of the triangles' centroids (Lauterbach, Garland, Sengupta, Luebke,
//! Manocha 2009, "Fast BVH Construction on GPUs", section 3, LBVH; the
//! top-down split at the highest differing bit as in Karras 2012,
//! "Maximizing Parallelism in the Construction of BVHs, Octrees, and k-d
//! Trees", section 3). Embree's `RTC_BUILD_QUALITY_LOW` is this kind of
//! build.
//!
//! 1. Pass 1 is every build's (`build::gather`): references and the
//!    centroid bounds, all capacity checks.
//! 2. Each centroid is quantised to 10 bits per axis over the centroid
//!    bounds and its bits interleaved into a 30-bit Morton code (x in the
//!    highest bit of each triple).
//! 3. The (code, triangle id) pairs are radix sorted (`mem::sort`, three
//!    11-bit passes) in the node pool, which the tree has not reached yet,
//!    and the triangles are stored in that order.
//! 4. The tree is emitted top-down with an explicit stack: a range of
//!    sorted codes splits where its highest differing bit flips (a binary
//!    search; the node's axis is that bit's axis, the left child lower on
//!    it); a range whose codes are all equal splits at its middle; a range
//!    of at most `leaf_size` triangles, or at `MAX_DEPTH`, is a leaf.
//! 5. One reverse pass over the nodes fits every box bottom-up (refit's
//!    `fit_boxes`: children follow their parent).
//!
//! # Exactness
//! The boxes are exactly those the binned build would give the same
//! shape (padded, `refit::fit_boxes`); every traversal's guarantee holds
//! whatever the shape, so every method returns on this tree the triangle
//! and bitwise t it returns on the SAH tree. `tests/bvh_exact.rs` runs every
//! method on it.
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
//!   memory the SAH build does not.

use super::build::{Gathered, split};
use super::refit::{fit_boxes, sah};
use super::{BvhNode, BvhParams, BvhPools, MAX_DEPTH};
use crate::geom::{Aabb, Scene};
use crate::mem::sort::radix_sort;
use glam::Vec3A;

/// Bits per axis of a Morton code.
const BITS: u32 = 10;

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
    fn new(cent_min: Vec3A, cent_max: Vec3A) -> Quantizer {
        let ext = cent_max - cent_min;
        let cells = (1u32 << BITS) as f32 * (1.0 - 1e-6);
        // An axis without extent maps everything to cell 0.
        let scale = Vec3A::select(
            ext.cmpgt(Vec3A::ZERO),
            Vec3A::splat(cells) / ext,
            Vec3A::ZERO,
        );
        Quantizer {
            min: cent_min,
            scale,
        }
    }
    /// The Morton code of a doubled centroid (NaN-free: pass 1 stores
    /// finite triangles only; the clamp keeps rounding at the top in range).
    #[inline(always)]
    fn code(&self, c: Vec3A) -> u32 {
        let top = ((1u32 << BITS) - 1) as f32;
        let q = ((c - self.min) * self.scale)
            .max(Vec3A::ZERO)
            .min(Vec3A::splat(top));
        (spread(q.x as u32) << 2) | (spread(q.y as u32) << 1) | spread(q.z as u32)
    }
}

/// Steps 2-5 of the module docs over `pools.refs[..g.n]` (`g.n > 0`, every
/// capacity checked by `gather`). Writes the nodes, the stored triangles,
/// `tri_ids` and `slot_of` (reset by the caller); returns the info.
pub(super) fn emit(
    pools: &mut BvhPools<'_>,
    scene: &Scene<'_>,
    p: &BvhParams,
    g: &Gathered,
) -> crate::accel::bvh::BvhInfo {
    let n = g.n;
    let mut info = g.info;
    let (nodes, mut stored, refs, _) = split(pools, p);

    // 2-3. Codes and ids in the node pool (2n - 1 nodes of 8 words hold the
    // four arrays of n words), sorted.
    {
        let words: &mut [u32] = bytemuck::cast_slice_mut(&mut nodes[..2 * n - 1]);
        let (keys, rest) = words.split_at_mut(n);
        let (vals, rest) = rest.split_at_mut(n);
        let (tmp_keys, rest) = rest.split_at_mut(n);
        let tmp_vals = &mut rest[..n];
        let qz = Quantizer::new(g.cent.min, g.cent.max);
        for ((k, v), r) in keys.iter_mut().zip(vals.iter_mut()).zip(&refs[..n]) {
            let c = Vec3A::from(r.min) + Vec3A::from(r.max);
            *k = qz.code(c);
            *v = r.id;
        }
        radix_sort(keys, vals, tmp_keys, tmp_vals, 3 * BITS);
        for (s, &id) in vals.iter().enumerate() {
            stored.put(scene, s, id);
        }
        // The sorted codes move to the reference pool (free now), since
        // the nodes overwrite the sort's arrays.
        let codes: &mut [u32] = bytemuck::cast_slice_mut(&mut refs[..n]);
        codes[..n].copy_from_slice(keys);
    }

    // 4. Top-down emission; boxes come in step 5.
    let codes: &[u32] = &bytemuck::cast_slice::<_, u32>(&refs[..n])[..n];
    let leaf_size = p.leaf_size as usize;
    // (node, begin, end, depth) of right children still to emit.
    let mut stack = [(0u32, 0u32, 0u32, 0u32); MAX_DEPTH + 1];
    let mut sp = 0usize;
    let (mut node, mut begin, mut end, mut depth) = (0u32, 0usize, n, 0u32);
    let mut next = 1u32;
    loop {
        let count = end - begin;
        if count > leaf_size && (depth as usize) < MAX_DEPTH {
            let (a, b) = (codes[begin], codes[end - 1]);
            let (mid, axis) = if a == b {
                (begin + count / 2, 0)
            } else {
                // Sorted codes share every bit above `h`: the range's
                // first code with bit `h` set starts the right child.
                let h = 31 - (a ^ b).leading_zeros();
                let bit = 1u32 << h;
                let first = codes[begin..end].partition_point(|&c| c & bit == 0);
                (begin + first, axis_of_bit(h))
            };
            let left = next;
            next += 2;
            nodes[node as usize] = BvhNode::inner(&Aabb::EMPTY, left, axis);
            depth += 1;
            stack[sp] = (left + 1, mid as u32, end as u32, depth);
            sp += 1;
            (node, end) = (left, mid);
            continue;
        }
        nodes[node as usize] = BvhNode::leaf(&Aabb::EMPTY, begin as u32, count as u32);
        info.leaves += 1;
        info.depth = info.depth.max(depth);
        if sp == 0 {
            break;
        }
        sp -= 1;
        let (nd, b, e, d) = stack[sp];
        (node, begin, end, depth) = (nd, b as usize, e as usize, d);
    }

    // 5. Boxes bottom-up.
    let nn = next as usize;
    fit_boxes(&mut nodes[..nn], &stored.tris[..n], g.pad);
    info.nodes = next;
    info.sah_cost = sah(&nodes[..nn], p.traversal_cost) as f32;
    info
}
