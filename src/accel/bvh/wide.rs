//! The 4-wide tree: the built binary tree collapsed into nodes of up to four
//! children whose boxes are stored side by side, so one ray tests all four
//! at once with 4-wide SIMD (Dammertz, Hanika, Keller 2008, "Shallow
//! Bounding Volume Hierarchies for Fast SIMD Ray Tracing of Incoherent
//! Rays", section 2; Wald, Benthin, Boulos 2008, "Getting Rid of Packets",
//! section 3: the collapse of a binary SAH tree; Embree's BVH4).
//!
//! Every build collapses its binary tree into the BVH's reference pool (`BvhPools::refs`), which the builds only use as scratch
//! and which is free once a build is done: the 4-wide tree costs no memory
//! beyond the binary tree's 140 bytes per triangle. Starting from a binary
//! inner node, the inner child with the largest box surface is replaced by
//! its two children until there are four (or only leaves are left); the
//! binary leaves stay the leaves, so the triangles keep their leaf order
//! and the stored triangles are shared by both trees. A refit keeps the
//! wide tree's shape and recomputes its boxes bottom-up (`refit`), as it
//! does the binary tree's.
//!
//! # Exactness
//! A wide node's child boxes are the binary nodes' boxes, bit for bit
//! (padded as the build pads), and a box is skipped only when its entry
//! lies strictly beyond the nearest hit so far, whatever the order
//! children are visited in. A merged leaf also tests triangles whose own
//! binary leaf box the ray misses; that changes nothing while every hit
//! lies inside its triangle's padded box, which holds except for rays of
//! tiny direction (`fallback::TINY_DIR`): the wide walks hand those to the
//! binary ones.
//!
//! # Deviations
//! - The papers build the 4-wide tree directly with the SAH; sheaf
//!   collapses whichever binary tree the build quality made, so the two
//!   trees share their leaves and every build quality gets a wide tree.
//! - When the reference pool cannot hold the collapsed tree (one wide
//!   node per 4 references, `max_triangles / 4` nodes; trees of small
//!   leaves can exceed it), the BVH has no wide tree (`BvhInfo::wide_nodes` is 0) and
//!   the wide single ray walks the binary tree: same answers, binary speed.
//! - The leaves are not structure-of-arrays blocks of v0 and precomputed
//!   edges: they point at the stored triangles (36-byte records in leaf
//!   order) that the binary tree shares, and `leaf4` gathers four of them
//!   into lanes. Measured (perf, cpu-clock samples, conference camera rays
//!   through the wide single ray, 2026-11-26): the gather's loads and
//!   shuffles are at most 10.6% of the walk's samples, the walk's own lines
//!   (node tests, child order, stack) about 60%; the packet traversals test one triangle
//!   across many rays and never gather. Blocks padded per leaf would not
//!   fit the 140 bytes per triangle, and a store shared with the binary
//!   tree would change every reader of the triangles for that share. The
//!   watertight test needs the vertices themselves (v0 + e1 is not v1).

use super::{BvhNode, MAX_DEPTH};
use crate::geom::TriVerts;
use crate::mem::par::{MAX_WORKERS, Par, Parts};
use crate::mem::prefetch::prefetch;
use bytemuck::{Pod, Zeroable};
use glam::Vec3A;

/// Children of a wide node.
pub const WIDTH: usize = 4;

/// One 4-wide node (128 bytes, two cache lines): the children's boxes axis
/// by axis (`min[a][c]`, `max[a][c]`), then per child either a wide node
/// (`count` 0, `child` its index) or a binary leaf (`count` > 0 triangles
/// from stored triangle `child`). Unused slots have an empty box (min +inf,
/// max -inf: every slab test misses it) and `child` `EMPTY`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct WideNode {
    pub min: [[f32; WIDTH]; 3],
    pub max: [[f32; WIDTH]; 3],
    pub child: [u32; WIDTH],
    pub count: [u32; WIDTH],
}

const _: () = assert!(core::mem::size_of::<WideNode>() == 128);

impl WideNode {
    /// `child` of an unused slot.
    pub const EMPTY: u32 = u32::MAX;

    const NONE: WideNode = WideNode {
        min: [[f32::INFINITY; WIDTH]; 3],
        max: [[f32::NEG_INFINITY; WIDTH]; 3],
        child: [Self::EMPTY; WIDTH],
        count: [0; WIDTH],
    };

    fn set(&mut self, c: usize, n: &BvhNode, child: u32, count: u32) {
        for a in 0..3 {
            self.min[a][c] = n.min[a];
            self.max[a][c] = n.max[a];
        }
        self.child[c] = child;
        self.count[c] = count;
    }

    /// Child `c`'s box (a refit).
    #[inline(always)]
    fn set_box(&mut self, c: usize, (lo, hi): (Vec3A, Vec3A)) {
        for a in 0..3 {
            self.min[a][c] = lo[a];
            self.max[a][c] = hi[a];
        }
    }
}

/// The stored triangles under binary node `c` as one leaf (`first`,
/// `count`) when it is a leaf or its subtree holds at most `merge`
/// triangles (a subtree's triangles are consecutive in leaf order: from
/// its leftmost leaf's first to its rightmost leaf's end), else `None`.
fn range(nodes: &[BvhNode], c: usize, merge: u32) -> Option<(u32, u32)> {
    let n = &nodes[c];
    if n.is_leaf() {
        return Some((n.first, n.count()));
    }
    // An inner node holds at least two triangles: past a `merge` of 1
    // without walking its spines (the collapse's usual case).
    if merge <= 1 {
        return None;
    }
    // A subtree of at most `merge` triangles has at most `merge` leaves,
    // so both spines reach a leaf within `merge` steps: a longer one
    // settles the answer without walking a large subtree's spines.
    let (mut l, mut r) = (n, n);
    for _ in 0..merge {
        if l.is_leaf() && r.is_leaf() {
            break;
        }
        if !l.is_leaf() {
            l = &nodes[l.first as usize];
        }
        if !r.is_leaf() {
            r = &nodes[r.first as usize + 1];
        }
    }
    if !(l.is_leaf() && r.is_leaf()) {
        return None;
    }
    let count = r.first + r.count() - l.first;
    (count <= merge).then_some((l.first, count))
}

/// When the reference pool cannot hold the wide tree with the binary
/// leaves as its leaves, subtrees of at most this many triangles become
/// one leaf (the default leaf size; measured on the built-in scenes: 0.18-0.30
/// wide nodes per binary leaf with it). Merging is the fallback, not the
/// rule: a merged leaf is tested whole by every ray entering its box, and
/// on the SAH trees it cost 2.7x the binary tree's triangle tests per
/// camera ray (crytek sponza 13.4 against 5.0, conference 11.7 against
/// 4.4; 4.3 and 4.5 with the binary leaves kept), which the frustum
/// packets paid in full (docs/studies/bvh-build.md, "The 4-wide tree").
pub const MERGE: u32 = 4;

/// Inserts `x` into `list[..k]`, kept ascending by `key`; equal keys keep
/// their arrival order. The wide walks order a node's children (at most
/// `WIDTH`) this way.
#[inline(always)]
pub(crate) fn insert_by<T: Copy>(list: &mut [T; WIDTH], k: usize, x: T, key: impl Fn(&T) -> f32) {
    let kx = key(&x);
    let mut j = k;
    while j > 0 && key(&list[j - 1]) > kx {
        list[j] = list[j - 1];
        j -= 1;
    }
    list[j] = x;
}

/// Wide nodes a pool of `bytes` holds.
pub(crate) fn capacity(bytes: usize) -> usize {
    bytes / core::mem::size_of::<WideNode>()
}

/// Collapse the binary tree `nodes` into `out` keeping its leaves, or,
/// when `out` cannot hold that tree, merging subtrees of at most `MERGE`
/// triangles into leaves (`collapse`). The wide nodes written (0 when
/// neither fits) and whether the pool also holds their map (`Map`).
pub(crate) fn collapse_fitting(nodes: &[BvhNode], out: &mut [WideNode]) -> (u32, bool) {
    match collapse(nodes, out, 1) {
        (0, _) => collapse(nodes, out, MERGE),
        n => n,
    }
}

/// Where each wide child's box comes from: the binary node it copies,
/// 16 bytes per wide node, stored from the end of the wide tree's pool
/// backwards (wide node `w` at entry `len - 1 - w` of the pool seen as
/// `[u32; 4]`s, eight to a node), where it fits beside the nodes. A refit
/// then copies the refit binary boxes (`refit_from_map`) instead of
/// reading the triangles and uniting boxes bottom-up again.
struct Map;

impl Map {
    /// Entries of a pool of `nodes` wide nodes.
    const PER_NODE: usize = core::mem::size_of::<WideNode>() / 16;
    /// Whether `used` wide nodes and their map fit a pool of `cap`.
    fn fits(used: usize, cap: usize) -> bool {
        used * (Self::PER_NODE + 1) <= cap * Self::PER_NODE
    }
    /// Entry of wide node `w` in a pool of `cap` wide nodes.
    fn at(cap: usize, w: usize) -> usize {
        cap * Self::PER_NODE - 1 - w
    }
}

/// Collapse the binary tree `nodes` into `out`, root at 0, each node's
/// wide children after it, subtrees of at most `merge` triangles as one
/// leaf. Returns the wide nodes written, or 0 when `out` cannot hold them
/// (or `nodes` is empty): then there is no wide tree; and whether their
/// `Map` fits beside them (then it is written).
///
/// A child whose two children are both leaves (a twig) is opened before
/// any other: left as a child it would become a wide node of two leaves.
/// Opening twigs first makes 0.43 wide nodes per binary leaf on the SAH
/// trees of the built-in scenes against 0.49 (largest surface first
/// alone), which is what lets them fit the pool with their binary leaves;
/// the triangle and box tests per ray did not change (crytek sponza and
/// conference, camera and shadow rays, within 0.3 %).
///
/// The walk waits on cache misses (each candidate's children, then the
/// wide node it writes), not on its arithmetic: the grandchildren are
/// prefetched when a candidate is looked at and a wide node's lines when
/// it is numbered. Measured on the LOW trees (1 thread, interleaved
/// rounds): crytek sponza 8.2 -> 5.8 ms, conference 10.3 -> 7.2 ms.
pub(crate) fn collapse(nodes: &[BvhNode], out: &mut [WideNode], merge: u32) -> (u32, bool) {
    if nodes.is_empty() || out.is_empty() {
        return (0, false);
    }
    let cap = out.len();
    let mut mapped = Map::fits(1, cap);
    let root = &nodes[0];
    if root.is_leaf() {
        out[0] = WideNode::NONE;
        out[0].set(0, root, root.first, root.count());
        if mapped {
            bytemuck::cast_slice_mut::<_, [u32; WIDTH]>(out)[Map::at(cap, 0)] = [0; WIDTH];
        }
        return (1, mapped);
    }
    // Binary inner nodes still to become wide node `st_wide`; a wide node
    // is pushed only at a deeper binary level than its parent, so the
    // stack never holds more than 3 per level.
    let mut st_bin = [0u32; 3 * MAX_DEPTH + 1];
    let mut st_wide = [0u32; 3 * MAX_DEPTH + 1];
    let mut sp = 1usize;
    let mut used = 1usize;
    while sp > 0 {
        sp -= 1;
        let (b, w) = (st_bin[sp] as usize, st_wide[sp] as usize);
        let l = nodes[b].first as usize;
        // Each candidate's leaf range and opening priority, worked out
        // once when it enters (not again in every round).
        let look = |c: usize| {
            let r = range(nodes, c, merge);
            // A leaf range is never opened (key -1); a twig first
            // (infinite key); else the largest surface.
            let key = if r.is_some() {
                -1.0f32
            } else {
                let l = nodes[c].first as usize;
                // The grandchildren are read when `c` is opened or its
                // wide node expanded: their lines on the way now (the
                // walk is bound by these misses, not by its arithmetic).
                for g in [&nodes[l], &nodes[l + 1]] {
                    if !g.is_leaf() {
                        prefetch(&nodes[g.first as usize]);
                        prefetch(&nodes[g.first as usize + 1]);
                    }
                }
                if range(nodes, l, merge).is_some() && range(nodes, l + 1, merge).is_some() {
                    f32::INFINITY
                } else {
                    let d = nodes[c].aabb().diagonal();
                    d.x * d.y + d.y * d.z + d.z * d.x
                }
            };
            (c, r, key)
        };
        let mut kids = [look(l), look(l + 1), (0, None, 0.0), (0, None, 0.0)];
        let mut k = 2;
        while k < WIDTH {
            // The first candidate of the largest key above -1 (as the
            // strict comparison of a scan in order picks it).
            let mut pick = None;
            let mut best = -1.0f32;
            for (i, &(_, _, key)) in kids[..k].iter().enumerate() {
                if key > best {
                    best = key;
                    pick = Some(i);
                }
            }
            let Some(i) = pick else { break };
            let cl = nodes[kids[i].0].first as usize;
            kids[i] = look(cl);
            kids[k] = look(cl + 1);
            k += 1;
        }
        let mut wn = WideNode::NONE;
        for (c, &(kid, r, _)) in kids[..k].iter().enumerate() {
            let n = &nodes[kid];
            if let Some((first, count)) = r {
                wn.set(c, n, first, count);
            } else {
                if used == out.len() || sp == st_bin.len() {
                    return (0, false);
                }
                wn.set(c, n, used as u32, 0);
                // Its two lines are written when it is popped.
                prefetch(&out[used]);
                st_bin[sp] = kid as u32;
                st_wide[sp] = used as u32;
                sp += 1;
                used += 1;
                mapped &= Map::fits(used, cap);
            }
        }
        out[w] = wn;
        if mapped {
            let mut m = [0u32; WIDTH];
            for (m, &(kid, _, _)) in m.iter_mut().zip(&kids[..k]) {
                *m = kid as u32;
            }
            bytemuck::cast_slice_mut::<_, [u32; WIDTH]>(out)[Map::at(cap, w)] = m;
        }
    }
    (used as u32, mapped)
}

/// How many wide nodes ahead `refit_from_map` requests binary nodes.
const MAP_AHEAD: usize = 8;

/// Refit the first `n` wide nodes of the pool `pool` (collapsed from the
/// binary tree `nodes` with their `Map`, same shapes since) by copying
/// each child's box from its binary node, whose refit boxes are final:
/// bitwise the boxes a collapse of the refit tree would copy. Every node
/// on its own, split among `par`'s workers.
pub(crate) fn refit_from_map(pool: &mut [WideNode], n: usize, nodes: &[BvhNode], par: &dyn Par) {
    let cap = pool.len();
    let (wide, rest) = pool.split_at_mut(n);
    let map: &[[u32; WIDTH]] = bytemuck::cast_slice(rest);
    // Entry of wide node w within `rest`, which starts after n nodes.
    let entry = |w: usize| Map::at(cap, w) - n * Map::PER_NODE;
    let workers = par.workers();
    debug_assert!((1..=MAX_WORKERS).contains(&workers));
    let parts = Parts::even(wide, workers);
    par.run(&|w| {
        let at = parts.start(w);
        let part = parts.get(w);
        let end = at + part.len();
        for (i, node) in part.iter_mut().enumerate() {
            // The binary nodes a few wide nodes on, which lie anywhere in
            // the pool: their lines on the way (the copy waits on them).
            if at + i + MAP_AHEAD < end {
                for &b in &map[entry(at + i + MAP_AHEAD)] {
                    if let Some(b) = nodes.get(b as usize) {
                        prefetch(b);
                    }
                }
            }
            let m = &map[entry(at + i)];
            for c in 0..WIDTH {
                if node.child[c] != WideNode::EMPTY {
                    let b = &nodes[m[c] as usize];
                    node.set_box(c, (Vec3A::from(b.min), Vec3A::from(b.max)));
                }
            }
        }
    });
}

/// Refit the wide tree `wide` (collapsed from a tree since refit, same
/// shape) to the stored triangles `tris`: a leaf child's box is its
/// triangles' box padded by `pad`, an inner child's the union of its wide
/// node's children. Children follow their parent, so one reverse pass
/// meets them first. Bitwise the boxes a collapse of the refit binary tree
/// would copy: the union of padded boxes is the padded union (`leaf_box`).
pub(crate) fn refit(wide: &mut [WideNode], tris: &[TriVerts], pad: Vec3A, par: &dyn Par) {
    // Leaf children on every worker (they read only the triangles), then
    // inner children bottom-up on this one.
    // 1..=MAX_WORKERS: checked by the only caller (`refit_with`,
    // `mem::par::workers_of`) before anything is written.
    let workers = par.workers();
    debug_assert!((1..=MAX_WORKERS).contains(&workers));
    {
        let parts = Parts::even(&mut *wide, workers);
        par.run(&|w| {
            for node in parts.get(w).iter_mut() {
                for c in 0..WIDTH {
                    let (child, count) = (node.child[c], node.count[c]);
                    if child != WideNode::EMPTY && count > 0 {
                        let first = child as usize;
                        let b = super::refit::leaf_box(&tris[first..first + count as usize], pad);
                        node.set_box(c, b);
                    }
                }
            }
        });
    }
    for i in (0..wide.len()).rev() {
        for c in 0..WIDTH {
            let (child, count) = (wide[i].child[c], wide[i].count[c]);
            if child == WideNode::EMPTY || count > 0 {
                continue;
            }
            // Empty slots hold +inf / -inf: they leave the union alone.
            let w = &wide[child as usize];
            let lo = |a: usize| w.min[a].iter().copied().fold(f32::INFINITY, f32::min);
            let hi = |a: usize| w.max[a].iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let b = (
                Vec3A::new(lo(0), lo(1), lo(2)),
                Vec3A::new(hi(0), hi(1), hi(2)),
            );
            wide[i].set_box(c, b);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::build::build;
    use crate::accel::bvh::build::testutil::{Store, deep_tris, soup};
    use crate::accel::bvh::{BuildQuality, BvhParams};
    use crate::geom::Scene;

    /// Every wide child box is a binary node's box, and the wide leaves
    /// cover the stored triangles once, each a run of whole binary leaves
    /// of at most `MERGE` triangles (or one binary leaf).
    fn check(nodes: &[BvhNode], wide: &[WideNode]) {
        let starts: Vec<u32> = nodes
            .iter()
            .filter(|n| n.is_leaf())
            .map(|n| n.first)
            .collect();
        let ends: Vec<u32> = nodes
            .iter()
            .filter(|n| n.is_leaf())
            .map(|n| n.first + n.count())
            .collect();
        let mut seen = Vec::new();
        let mut reached = vec![false; wide.len()];
        reached[0] = true;
        for (i, w) in wide.iter().enumerate() {
            assert!(reached[i], "wide node {i} is nobody's child");
            let mut used = 0;
            for c in 0..WIDTH {
                if w.child[c] == WideNode::EMPTY {
                    assert!(w.min[0][c] > w.max[0][c]);
                    continue;
                }
                used += 1;
                if w.count[c] > 0 {
                    seen.push((w.child[c], w.count[c]));
                } else {
                    let j = w.child[c] as usize;
                    assert!(j > i && !reached[j]);
                    reached[j] = true;
                }
                // The box is some binary node's box, bit for bit.
                let bits = |x: f32| x.to_bits();
                assert!(nodes.iter().any(|n| {
                    (0..3).all(|a| {
                        bits(n.min[a]) == bits(w.min[a][c]) && bits(n.max[a]) == bits(w.max[a][c])
                    })
                }));
            }
            assert!(used >= 1 && (used >= 2 || wide.len() == 1));
        }
        seen.sort();
        let mut next = 0;
        for &(first, count) in &seen {
            assert_eq!(first, next, "the wide leaves cover every triangle once");
            assert!(starts.contains(&first) && ends.contains(&(first + count)));
            let one = nodes
                .iter()
                .any(|n| n.is_leaf() && n.first == first && n.count() == count);
            assert!(one || count <= MERGE);
            next = first + count;
        }
        assert_eq!(Some(next), ends.iter().max().copied());
    }

    #[test]
    fn collapse_keeps_every_leaf_and_box() {
        for &name in crate::scenes::BUILTIN_NAMES {
            let s = crate::scenes::builtin(name).unwrap();
            let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
            for (quality, leaf_size) in [(BuildQuality::Medium, 4), (BuildQuality::Low, 1)] {
                let mut st = Store::new(scene.triangle_count() as usize, false);
                let mut bvh = st.bvh();
                let p = BvhParams {
                    quality,
                    leaf_size,
                    ..BvhParams::default()
                };
                let info = build(&mut bvh, &scene, &p).unwrap();
                let v = bvh.view().unwrap();
                assert!(info.wide_nodes > 0, "{name} {quality:?}: no wide tree");
                check(v.nodes, v.wide);
                assert!(info.wide_nodes <= info.nodes / 2 + 1);
                // The SAH trees fit with their own leaves; trees of one
                // triangle per leaf (as many leaves as triangles) do not,
                // and get merged leaves.
                let leaves = v
                    .wide
                    .iter()
                    .flat_map(|w| (0..WIDTH).map(move |c| (w.child[c], w.count[c])));
                let merged =
                    leaves
                        .filter(|&(c, n)| c != WideNode::EMPTY && n > 0)
                        .any(|(c, n)| {
                            !v.nodes
                                .iter()
                                .any(|b| b.is_leaf() && b.first == c && b.count() == n)
                        });
                assert_eq!(merged, leaf_size == 1, "{name} {quality:?}");
            }
        }
    }

    /// A refit moves every box of the wide tree with the binary tree's:
    /// every wide child box is still a binary node's box, bit for bit.
    #[test]
    fn refit_keeps_the_wide_boxes_the_binary_ones() {
        let mut a = crate::scenes::animated::Animated::new(1);
        let n = a.mesh.indices.len() / 3;
        let mut st = Store::new(n, false);
        let mut bvh = st.bvh();
        let scene = Scene::from_f32(&a.mesh.vertices, &a.mesh.indices).unwrap();
        let before = build(&mut bvh, &scene, &BvhParams::default()).unwrap();
        let boxes0 = bvh.view().unwrap().wide.to_vec();
        a.set_time(2.0);
        let scene = Scene::from_f32(&a.mesh.vertices, &a.mesh.indices).unwrap();
        crate::accel::bvh::refit::refit(&mut bvh, &scene).unwrap();
        let v = bvh.view().unwrap();
        assert_eq!(v.info.wide_nodes, before.wide_nodes);
        assert_ne!(v.wide, &boxes0[..], "the boxes moved");
        check(v.nodes, v.wide);
        // The map's copies are the boxes fitted from the triangles.
        let mut fitted = v.wide.to_vec();
        let b = v.info.bounds;
        let pad = crate::accel::bvh::box_pad(Vec3A::from(b.min), Vec3A::from(b.max));
        refit(&mut fitted, v.tris, pad, &crate::mem::par::Serial);
        assert_eq!(v.wide, &fitted[..]);
    }

    #[test]
    fn collapse_refuses_a_small_pool_and_handles_deep_trees() {
        let (v, ix) = soup(&deep_tris());
        let scene = Scene::from_f32(&v, &ix).unwrap();
        let mut st = Store::new(scene.triangle_count() as usize, false);
        let mut bvh = st.bvh();
        let p = BvhParams {
            leaf_size: 1,
            bins: 2,
            ..BvhParams::default()
        };
        let info = build(&mut bvh, &scene, &p).unwrap();
        let nodes = bvh.view().unwrap().nodes.to_vec();
        let mut out = vec![WideNode::NONE; nodes.len()];
        let n = collapse(&nodes, &mut out, MERGE).0 as usize;
        assert!(n > 0 && info.depth as usize == MAX_DEPTH);
        check(&nodes, &out[..n]);
        assert_eq!(collapse(&nodes, &mut out[..n - 1], MERGE), (0, false));
        assert_eq!(collapse(&[], &mut out, 1), (0, false));
        // A pool of exactly the nodes holds no map: the tree stands alone.
        let mut exact = out[..n].to_vec();
        assert_eq!(collapse(&nodes, &mut exact, MERGE), (n as u32, false));
        check(&nodes, &exact);
    }
}
