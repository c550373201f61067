//! Ranged traversal of large ray packets (Overbeck, Ramamoorthi, Mark 2008,
//! section 3.2 and Appendix A.1; introduced for BVHs by Wald, Boulos,
//! Shirley 2007).
//!
//! Figure 2 with the per-cell box tests replaced by `getFirstHit`: the index
//! `i_a` of the first alive SIMD ray (quad) is carried down the tree and on
//! the stack, so quads before it are never tested again below; the frustum
//! is consulted only when `R[i_a]` itself misses. At a leaf `getLastHit`
//! finds `i_e`, one past the last alive quad, and every quad in `[i_a, i_e)`
//! is tested against each unculled triangle, alive or not.
//!
//! Shared machinery (packet setup, slab and triangle tests) is in `packet.rs`;
//! the exactness argument and its tests are in `traverse_masked`. Results
//! equal `traverse_single` lane by lane, bitwise.
//!
//! # Deviations
//! - Quads without live lanes (inactive, invalid, or occluded) never test
//!   alive and are skipped, uncounted, in the triangle loop; dead quads in
//!   `[i_a, i_e)` with live lanes are tested and counted (the cost the paper
//!   attributes to Ranged traversal).
//! - See `traverse_masked` for child order and occlusion, and for the
//!   fallbacks every packet gets (`accel::fallback`: tiny directions and
//!   incoherent packets lane by lane, by the 4-wide single ray). Ranged traversal
//!   does not switch to Partition traversal as Masked traversal does:
//!   measured on coherent camera packets whose quads it scans past dead
//!   (long needles, sliver triangles), the switch made it up to 2x slower,
//!   and without it no stress class left Ranged above its single ray's
//!   time once the coherence test is in (`sheaf bench --stress`).

use super::packet::{Packet, Walk};
use super::{BvhNode, BvhView, LeafAt, MAX_DEPTH, TriangleTest};
use crate::accel::slot::Slot;
use crate::counters::Counters;
use crate::geom::{Hit4, Ray4, Wide};

/// `getFirstHit`: the first quad from `ia` on alive in `n`'s box, or `nq`.
#[inline(always)]
pub(crate) fn first_hit<T: TriangleTest>(
    p: &Packet<'_, T>,
    n: &BvhNode,
    ia: usize,
    depth: usize,
    ctr: &mut Counters,
) -> usize {
    let nq = p.nq;
    if p.alive(ia, n, depth, ctr).any() {
        return ia;
    }
    if !p.frustum_admits(n, ctr) {
        return nq;
    }
    for i in ia + 1..nq {
        if p.alive(i, n, depth, ctr).any() {
            return i;
        }
    }
    nq
}

/// `getLastHit`: one past the last quad after `ia` alive in `n`'s box, or
/// `ia + 1`.
#[inline(always)]
pub(crate) fn last_hit<T: TriangleTest>(
    p: &Packet<'_, T>,
    n: &BvhNode,
    ia: usize,
    depth: usize,
    ctr: &mut Counters,
) -> usize {
    let mut ie = p.nq - 1;
    while ie > ia {
        if p.alive(ie, n, depth, ctr).any() {
            return ie + 1;
        }
        ie -= 1;
    }
    ia + 1
}

/// Appendix A.1's leaf: every quad in `[ia, ie)` against each stored
/// triangle of leaf `at` the frustum does not cull. True when every lane
/// is done (occlusion).
#[inline(always)]
pub(crate) fn test_leaf<L: Wide, T: TriangleTest, const ANY: bool>(
    p: &mut Packet<'_, T>,
    b: &BvhView<'_>,
    hits: &mut [Hit4],
    grp: &[crate::accel::group::Group<L, T>],
    at: LeafAt,
    (ia, ie): (usize, usize),
    ctr: &mut Counters,
) -> bool {
    let (first, depth) = (at.first as usize, at.depth);
    for j in first..first + at.count as usize {
        if p.frustum_culls(b, j, ctr) {
            continue;
        }
        let id = b.tri_ids[j];
        // The aligned groups of `L::G` quads overlapping [ia, ie).
        let groups = ia / L::G..ie.div_ceil(L::G);
        for g in groups {
            let g0 = g * L::G;
            let mut sel = 0u32;
            for k in 0..L::G {
                sel |= u32::from((ia..ie).contains(&(g0 + k))) << k;
            }
            p.test_group::<L, ANY>(b, hits, &grp[g], g, sel, j, id, depth, ctr);
        }
    }
    ANY && p.done()
}

/// Appendix A.1.
pub(crate) struct Ranged;

impl Walk for Ranged {
    #[inline(always)]
    fn walk<L: Wide, T: TriangleTest, const ANY: bool>(
        p: &mut Packet<'_, T>,
        b: &BvhView<'_>,
        rays: &[Ray4],
        hits: &mut [Hit4],
        start: (usize, usize),
        slot: &mut Slot<'_>,
        ctr: &mut Counters,
    ) {
        let nodes = b.nodes;
        let nq = p.nq;
        let (grp, _) = p.groups::<L>(rays, slot);
        let mut st_node = [0u32; MAX_DEPTH + 1];
        let mut st_ia = [0u16; MAX_DEPTH + 1];
        let mut st_depth = [0u8; MAX_DEPTH + 1];
        let mut sp = 0usize;
        let (mut node, mut depth) = start;
        let mut ia = 0usize;
        loop {
            let n = &nodes[node];
            ia = first_hit(p, n, ia, depth, ctr);
            if ia < nq {
                if !n.is_leaf() {
                    let (near, far) = p.children(n);
                    st_node[sp] = far as u32;
                    st_ia[sp] = ia as u16;
                    st_depth[sp] = (depth + 1) as u8;
                    sp += 1;
                    node = near;
                    depth += 1;
                    continue;
                }
                let ie = last_hit(p, n, ia, depth, ctr);
                let leaf = n.leaf_at(depth);
                if test_leaf::<L, T, ANY>(p, b, hits, grp, leaf, (ia, ie), ctr) {
                    return;
                }
            }
            if sp == 0 {
                return;
            }
            sp -= 1;
            node = st_node[sp] as usize;
            ia = st_ia[sp] as usize;
            depth = st_depth[sp] as usize;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Ranged;
    crate::accel::bvh::traverse_masked::tests::walk_matches_single!(Ranged);
}
