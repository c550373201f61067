//! Ranged traversal of large packets through the 4-wide tree
//! (`Method::BvhWideRanged`): the BVH paper's Ranged traversal (section
//! 3.2, Appendix A.1; `traverse_ranged`) with each wide node's children
//! tested at once. At a wide node every child gets `getFirstHit` from the
//! node's first alive quad `i_a` (the frustum consulted only when `R[i_a]`
//! misses it); the children some quad enters are visited front to back
//! along the packet's direction, the far ones pushed with their own `i_a`
//! and tested again when popped (the hits found meanwhile may cull them).
//! A leaf child gets `getLastHit` and the Ranged leaf test. The wide tree
//! is Wald, Benthin, Boulos 2008's (section 3) and Dammertz et al. 2008's
//! (`wide.rs`); this walk lets large packets use it as the wide single ray
//! does.
//!
//! # Exactness
//! The per-quad box tests, the frustum tests and the leaf test are
//! Ranged's (`Packet::alive`, `frustum_admits`, `test_leaf`), on boxes that
//! are the binary tree's bit for bit: a child is skipped only when no quad
//! from `i_a` on has a live lane entering it by its nearest hit so far,
//! so the results equal `traverse_single` lane by lane, bitwise.
//!
//! # Deviations
//! - Packets starting at an entry point (MLRTA, AEPSA: binary nodes),
//!   packets with a live lane of tiny direction (possible with the
//!   fallbacks off; `traverse_wide`'s deviations), and BVHs without a wide
//!   tree (`BvhParams::width` 2, or a pool too small for it) run the
//!   binary Ranged traversal.
//! - The children's order is by the sum of each box's corners along the
//!   packet's direction signs (the wide nodes keep no split axis).

use super::packet::{Packet, Walk, wide_walk_applies};
use super::traverse_ranged::{Ranged, first_hit, last_hit, test_leaf};
use super::wide::{WIDTH, WideNode, insert_by};
use super::{BvhNode, BvhView, LeafAt, MAX_DEPTH, TriangleTest};
use crate::accel::slot::Slot;
use crate::counters::Counters;
use crate::geom::{Hit4, Ray4, Wide};

/// Stack entries: at most `WIDTH - 1` pushed per wide level.
const STACK: usize = (WIDTH - 1) * MAX_DEPTH + 1;

/// Child `c`'s box as a binary node (what the packet's tests read).
#[inline(always)]
fn child_box(n: &WideNode, c: usize) -> BvhNode {
    BvhNode {
        min: [n.min[0][c], n.min[1][c], n.min[2][c]],
        first: 0,
        max: [n.max[0][c], n.max[1][c], n.max[2][c]],
        meta: 0,
    }
}

/// What the walk does next.
enum Step {
    /// Test the children of wide node `w` from quad `ia` (depth of `w`).
    Expand {
        w: usize,
        ia: usize,
        depth: usize,
    },
    /// Visit child `c` of wide node `w` from quad `ia`; `retest`: its
    /// `getFirstHit` is stale (it was pushed).
    Child {
        w: usize,
        c: usize,
        ia: usize,
        depth: usize,
        retest: bool,
    },
    Pop,
}

pub(crate) struct WideRanged;

impl Walk for WideRanged {
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
        if !wide_walk_applies(p.tiny, b, start) {
            return Ranged::walk::<L, T, ANY>(p, b, rays, hits, start, slot, ctr);
        }
        let wide = b.wide;
        let nq = p.nq;
        let (grp, _) = p.groups::<L>(rays, slot);
        let mut st_w = [0u32; STACK];
        let mut st_c = [0u8; STACK];
        let mut st_ia = [0u16; STACK];
        let mut st_depth = [0u8; STACK];
        let mut sp = 0usize;
        let mut step = Step::Expand {
            w: 0,
            ia: 0,
            depth: 0,
        };
        loop {
            step = match step {
                Step::Pop => {
                    if sp == 0 {
                        return;
                    }
                    sp -= 1;
                    Step::Child {
                        w: st_w[sp] as usize,
                        c: st_c[sp] as usize,
                        ia: st_ia[sp] as usize,
                        depth: st_depth[sp] as usize,
                        retest: true,
                    }
                }
                Step::Child {
                    w,
                    c,
                    mut ia,
                    depth,
                    retest,
                } => {
                    let n = &wide[w];
                    let cb = child_box(n, c);
                    if retest {
                        ia = first_hit(p, &cb, ia, depth, ctr);
                        if ia >= nq {
                            step = Step::Pop;
                            continue;
                        }
                    }
                    if n.count[c] == 0 {
                        Step::Expand {
                            w: n.child[c] as usize,
                            ia,
                            depth,
                        }
                    } else {
                        let ie = last_hit(p, &cb, ia, depth, ctr);
                        let leaf = LeafAt {
                            first: n.child[c],
                            count: n.count[c],
                            depth,
                        };
                        if test_leaf::<L, T, ANY>(p, b, hits, grp, leaf, (ia, ie), ctr) {
                            return;
                        }
                        Step::Pop
                    }
                }
                Step::Expand { w, ia, depth } => {
                    let n = &wide[w];
                    // (order key, child, its first alive quad), sorted.
                    let mut kids = [(0.0f32, 0usize, 0usize); WIDTH];
                    let mut k = 0;
                    for c in 0..WIDTH {
                        if n.child[c] == WideNode::EMPTY {
                            continue;
                        }
                        let cb = child_box(n, c);
                        let ic = first_hit(p, &cb, ia, depth + 1, ctr);
                        if ic < nq {
                            insert_by(&mut kids, k, (p.near_key(&cb), c, ic), |e| e.0);
                            k += 1;
                        }
                    }
                    if k == 0 {
                        Step::Pop
                    } else {
                        for &(_, c, ic) in kids[1..k].iter().rev() {
                            st_w[sp] = w as u32;
                            st_c[sp] = c as u8;
                            st_ia[sp] = ic as u16;
                            st_depth[sp] = (depth + 1) as u8;
                            sp += 1;
                        }
                        Step::Child {
                            w,
                            c: kids[0].1,
                            ia: kids[0].2,
                            depth: depth + 1,
                            retest: false,
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::WideRanged;
    crate::accel::bvh::traverse_masked::tests::walk_matches_single!(WideRanged);
}
