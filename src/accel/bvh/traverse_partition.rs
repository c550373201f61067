//! Partition traversal of large ray packets (Overbeck, Ramamoorthi, Mark
//! 2008, section 3.3 and Appendix A.2), the paper's new algorithm.
//!
//! A list `I` of quad indices is partitioned in place at every cell by
//! `partRays`: the frustum test first, then each of the first `i_a` listed
//! quads against the cell's box, alive ones swapped to the front. `i_a`
//! (one past the last alive quad) is the only state on the stack; deeper
//! cells only reorder `I[0..i_a]`, so after a pop the first `i_a` entries
//! are again the quads alive in the popped cell's parent. At a leaf exactly
//! the alive quads `I[0..i_a]` are tested against each unculled triangle.
//!
//! Shared machinery (packet setup, slab and triangle tests) is in `packet.rs`;
//! the exactness argument and its tests are in `traverse_masked`. Results
//! equal `traverse_single` lane by lane, bitwise.
//!
//! # Deviations
//! - Two slips in the Appendix pseudo-code are corrected: `partRays`
//!   returns 0 (no quad alive), not `size(R)`, when the frustum culls the
//!   box, and `i_a` starts at the number of quads, not 0, so the root tests
//!   every quad. The unused `getLastHit` call at the leaf (line 19) is left
//!   out: it would only add box tests.
//! - `I` starts with the quads that have live lanes (others can never be
//!   alive), so `i_a` starts at their number.
//! - See `traverse_masked` for child order and occlusion.
//! - `walk_from` starts `I` at a given quad: Masked traversal hands its
//!   stacked subtrees to it when it switches (`traverse_masked::to_partition`).

use super::packet::{Packet, Walk};
use super::{BvhNode, BvhView, MAX_DEPTH, TriangleTest};
use crate::accel::slot::Slot;
use crate::counters::Counters;
use crate::geom::{Hit4, Ray4, Wide};

/// `partRays`: move the quads of `idx[..ia]` alive in `n`'s box to the
/// front (in place) and return how many there are.
#[inline(always)]
fn part_rays<T: TriangleTest>(
    p: &Packet<'_, T>,
    n: &BvhNode,
    idx: &mut [u16],
    ia: usize,
    depth: usize,
    ctr: &mut Counters,
) -> usize {
    if !p.frustum_admits(n, ctr) {
        return 0;
    }
    let mut ie = 0;
    for i in 0..ia {
        if p.alive(idx[i] as usize, n, depth, ctr).any() {
            idx.swap(ie, i);
            ie += 1;
        }
    }
    ie
}

/// Appendix A.2.
pub(crate) struct Partition;

impl Walk for Partition {
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
        let (idx, _) = slot.split(p.nq, 0u16);
        let from = Subtree {
            node: start.0,
            depth: start.1,
            first: 0,
        };
        Self::walk_from::<L, T, ANY>(p, b, rays, hits, from, idx, ctr)
    }
}

/// Where a Partition walk starts: at `node` (at `depth`), with `I`
/// holding the live quads from `first` on (quads before it known dead
/// below `node`, as Ranged's `i_a`; a walk from the root passes 0).
#[derive(Clone, Copy)]
pub(crate) struct Subtree {
    pub node: usize,
    pub depth: usize,
    pub first: usize,
}

impl Partition {
    /// `walk` from `from`. `idx`: room for `I` (`p.nq` entries, from the
    /// slot's scratch; its contents are not read).
    #[inline(always)]
    pub(crate) fn walk_from<L: Wide, T: TriangleTest, const ANY: bool>(
        p: &mut Packet<'_, T>,
        b: &BvhView<'_>,
        rays: &[Ray4],
        hits: &mut [Hit4],
        from: Subtree,
        idx: &mut [u16],
        ctr: &mut Counters,
    ) {
        let (start, first) = ((from.node, from.depth), from.first);
        let nodes = b.nodes;
        // I: the quads with live lanes.
        let mut ia = 0usize;
        for q in first..p.nq {
            if p.live[q].any() {
                idx[ia] = q as u16;
                ia += 1;
            }
        }
        let mut st_node = [0u32; MAX_DEPTH + 1];
        let mut st_ia = [0u16; MAX_DEPTH + 1];
        let mut st_depth = [0u8; MAX_DEPTH + 1];
        let mut sp = 0usize;
        let (mut node, mut depth) = start;
        loop {
            let n = &nodes[node];
            ia = part_rays(p, n, idx, ia, depth, ctr);
            if ia > 0 {
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
                let first = n.first as usize;
                for j in first..first + n.count() as usize {
                    if p.frustum_culls(b, j, ctr) {
                        continue;
                    }
                    let id = b.tri_ids[j];
                    // `L::G` listed quads per test.
                    for g in idx[..ia].chunks(L::G) {
                        let mut qs = [0usize; 4];
                        for (k, &q) in g.iter().enumerate() {
                            qs[k] = q as usize;
                        }
                        p.test::<L, ANY>(b, rays, hits, qs, g.len(), j, id, depth, ctr);
                    }
                }
                if ANY && p.done() {
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
    use super::Partition;
    crate::accel::bvh::traverse_masked::tests::walk_matches_single!(Partition);
}
