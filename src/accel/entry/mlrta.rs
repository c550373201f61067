//! MLRTA entry-point search (Reshetov, Soupikov, Hurley 2005, as the AEPSA
//! paper's section 2.2 describes it), generic over `EntryTree`: the
//! kd-tree (implemented here) and the BVH (`bvh::entry`).
//!
//! 1. Phase 1: the frustum descends front to back, pushing every node whose
//!    children it both overlaps on the bifurcation stack, until the first
//!    occupied leaf; the stack is then frozen and the leaf is the current
//!    entry point (`find_candidates` with `LeafGoal::Occupied`).
//! 2. Phase 2: every node on the stack, deepest first, is tested: if the
//!    branch not taken below it holds an occupied leaf whose box the frustum
//!    overlaps, it becomes the entry point. The last one to qualify (the
//!    shallowest) is returned with its box.
//!
//! See `accel::entry` for the reading of the spec (backtracking, near/far
//! order, misses) shared with AEPSA, and `entry::Search` for the rest of
//! a search; this module holds what is MLRTA's own: its leaf goal and its
//! phase 2 (`Mlrta`).
//!
//! # Counters
//! `mlrta_in` (`Search::counted`) adds one search to `entry_searches`, its
//! entry depth (the tree's average leaf depth on a miss) to
//! `entry_depth_sum`, both phases' visited nodes to `entry_nodes` and
//! misses to `entry_misses`; `search`, `phase1` and `phase2` count nothing
//! (for benchmarks), `EntryResult::record` does it for them.

use crate::accel::entry::{
    CandidateQueue, EntryPoint, EntryResult, EntryTree, LeafGoal, Phase2, Search, branch_holds,
};
use crate::counters::Counters;
use crate::geom::frustum::Frustum;

/// MLRTA as a `Search`: phase 1 freezes at the first occupied leaf; phase 2
/// tests every candidate, bottom-up.
pub struct Mlrta;

impl Search for Mlrta {
    const GOAL: LeafGoal = LeafGoal::Occupied;

    /// Phase 2 on any candidate list (`None` when it is empty): the leaf
    /// (last candidate) is the entry point until a candidate above it,
    /// tested bottom-up, all of them, has an occupied leaf with an
    /// overlapped box in its untaken branch.
    fn phase2<E: EntryTree + ?Sized>(
        tree: &E,
        f: &Frustum,
        neg: [bool; 3],
        q: &CandidateQueue,
    ) -> Option<Phase2> {
        let c = q.as_slice();
        let mut p = Phase2 {
            entry: c.last()?.entry_point(),
            visited: 0,
            tested: 0,
        };
        for c in c.iter().rev() {
            let Some(branch) = c.untaken else {
                continue;
            };
            p.tested += 1;
            if branch_holds(
                tree,
                f,
                neg,
                branch,
                c.depth + 1,
                Self::GOAL,
                &mut p.visited,
            ) {
                p.entry = c.entry_point();
            }
        }
        Some(p)
    }
}

/// MLRTA's entry point, counted (`Search::counted`; the queue is
/// `accel::packet::start`'s, in the slot's scratch).
pub fn mlrta_in<E: EntryTree + ?Sized>(
    tree: &E,
    f: &Frustum,
    neg: [bool; 3],
    q: &mut CandidateQueue,
    ctr: &mut Counters,
) -> Option<EntryPoint> {
    Mlrta::counted(tree, f, neg, q, ctr)
}

/// Both phases, with their statistics; counts nothing (`Search::search`).
pub fn search<E: EntryTree + ?Sized>(tree: &E, f: &Frustum, neg: [bool; 3]) -> EntryResult {
    Mlrta::search(tree, f, neg)
}

/// Phase 1: the bifurcation stack (root first, the first occupied leaf
/// last; empty when the frustum reaches no occupied leaf).
pub fn phase1<E: EntryTree + ?Sized>(tree: &E, f: &Frustum, neg: [bool; 3]) -> CandidateQueue {
    Mlrta::phase1(tree, f, neg)
}

/// MLRTA's phase 2 (`Mlrta`) on any candidate list.
pub fn phase2<E: EntryTree + ?Sized>(
    tree: &E,
    f: &Frustum,
    neg: [bool; 3],
    q: &CandidateQueue,
) -> Option<Phase2> {
    Mlrta::phase2(tree, f, neg, q)
}

#[cfg(test)]
pub(crate) mod tests {
    //! Hand-made kd-trees of the AEPSA paper's worked examples (Figures 2,
    //! 3 and 4), shared with `aepsa`'s tests.
    use super::*;
    use crate::accel::kd::{KdInfo, KdNode, KdView};
    use crate::geom::Aabb;
    use crate::geom::frustum::{FrustumKind, RayKind};
    use crate::geom::{M4, Ray, Ray4, TriVerts};
    use glam::Vec3;
    use std::cell::RefCell;

    /// A node of a hand-made tree, by array index.
    pub enum Spec {
        /// Split axis, position, left child (the right one follows it).
        Inner(usize, f32, u32),
        /// The leaf's triangles.
        Leaf(Vec<[[f32; 3]; 3]>),
    }

    /// Owned pools of a hand-made kd-tree.
    pub struct HandTree {
        pub info: KdInfo,
        pub nodes: Vec<KdNode>,
        pub refs: Vec<u32>,
        pub tris: Vec<TriVerts>,
        pub ids: Vec<u32>,
    }

    impl HandTree {
        pub fn new(root: Aabb, spec: &[Spec]) -> HandTree {
            let (mut nodes, mut refs, mut tris) = (Vec::new(), Vec::new(), Vec::new());
            let (mut leaves, mut empty) = (0, 0);
            for s in spec {
                nodes.push(match s {
                    Spec::Inner(axis, split, left) => KdNode::inner(*axis, *split, *left),
                    Spec::Leaf(ts) => {
                        leaves += 1;
                        empty += ts.is_empty() as u32;
                        let first = refs.len() as u32;
                        for t in ts {
                            refs.push(tris.len() as u32);
                            tris.push(TriVerts {
                                v0: t[0],
                                v1: t[1],
                                v2: t[2],
                            });
                        }
                        KdNode::leaf(first, ts.len() as u32)
                    }
                });
            }
            let n = tris.len() as u32;
            let info = KdInfo {
                bounds: root,
                root,
                nodes: nodes.len() as u32,
                leaves,
                empty_leaves: empty,
                refs: refs.len() as u32,
                avg_leaf_depth: 2.0,
                triangles_in: n,
                triangles: n,
                ..KdInfo::default()
            };
            HandTree {
                info,
                nodes,
                refs,
                tris,
                ids: (0..n).collect(),
            }
        }
        pub fn view(&self) -> KdView<'_> {
            KdView {
                info: &self.info,
                nodes: &self.nodes,
                refs: &self.refs,
                tris: &self.tris,
                proj: &[],
                tri_ids: &self.ids,
                slot_of: &self.ids,
                filter: crate::geom::Hook::None,
            }
        }
    }

    /// An `EntryTree` that logs the nodes a search visits (the `children`
    /// calls, one per visit by the trait's contract).
    pub struct Logged<'t, E: EntryTree> {
        pub tree: &'t E,
        pub log: RefCell<Vec<u32>>,
    }

    impl<'t, E: EntryTree> Logged<'t, E> {
        pub fn new(tree: &'t E) -> Self {
            Logged {
                tree,
                log: RefCell::new(Vec::new()),
            }
        }
        /// The visits since the last call.
        pub fn take(&self) -> Vec<u32> {
            core::mem::take(&mut *self.log.borrow_mut())
        }
    }

    impl<E: EntryTree> EntryTree for Logged<'_, E> {
        fn root(&self) -> Option<(u32, Aabb)> {
            self.tree.root()
        }
        fn children(&self, node: u32, aabb: &Aabb) -> Option<[(u32, Aabb); 2]> {
            self.log.borrow_mut().push(node);
            self.tree.children(node, aabb)
        }
        fn split_axis(&self, node: u32) -> usize {
            self.tree.split_axis(node)
        }
        fn leaf_count(&self, node: u32) -> usize {
            self.tree.leaf_count(node)
        }
        fn leaf_overlapped(&self, node: u32, f: &Frustum) -> bool {
            self.tree.leaf_overlapped(node, f)
        }
        fn miss_depth(&self) -> u32 {
            self.tree.miss_depth()
        }
    }

    /// The frustum (section 4.1) of four corner rays from `eye` through
    /// `corners` (in cyclic order), a one-quad camera packet.
    pub fn corner_frustum(eye: Vec3, corners: [Vec3; 4], bounds: &Aabb) -> (Frustum, Ray4) {
        // Lanes TL, TR, BL, BR; the cyclic order TL, TR, BR, BL.
        let lanes = [corners[0], corners[1], corners[3], corners[2]];
        let rays = lanes.map(|c| Ray::new(eye, c - eye, 0.0, f32::INFINITY));
        let q = Ray4::from_rays(&rays);
        let f = Frustum::new(RayKind::Primary, &[q], &[M4::TRUE], bounds).unwrap();
        assert_eq!(f.kind, FrustumKind::Primary);
        (f, q)
    }

    /// A worked example: the tree, the frustum, the packet's direction
    /// signs, and the array index of each of the figure's node numbers.
    pub struct Figure {
        pub tree: HandTree,
        pub f: Frustum,
        pub neg: [bool; 3],
        pub idx: Vec<u32>,
    }

    impl Figure {
        /// Figure numbers of array indices.
        pub fn fig(&self, nodes: &[u32]) -> Vec<u32> {
            nodes
                .iter()
                .map(|n| self.idx.iter().position(|i| i == n).unwrap() as u32)
                .collect()
        }
        /// Array index of figure node `n`.
        pub fn at(&self, n: u32) -> u32 {
            self.idx[n as usize]
        }
    }

    fn aabb(min: [f32; 3], max: [f32; 3]) -> Aabb {
        Aabb {
            min: min.into(),
            max: max.into(),
        }
    }

    /// A triangle in the quadrant with lower corner (x, y) of Figures 3
    /// and 4 (cells of side 2, z in [0, 1]).
    fn quadrant_tri(x: f32, y: f32) -> [[f32; 3]; 3] {
        [
            [x + 0.8, y + 0.8, 0.3],
            [x + 1.5, y + 0.8, 0.5],
            [x + 0.8, y + 1.5, 0.7],
        ]
    }

    /// Figures 3 and 4: the complete tree 0; 1, 2; 3, 4, 5, 6 (array
    /// order = figure numbers) over [0, 4]^2 x [0, 1]: 0 splits x at 2,
    /// 1 and 2 split y at 2. `occupied`: which of leaves 3..6 hold a
    /// triangle. Rays look down -z from `eye`.
    fn complete(occupied: [bool; 4], eye: Vec3, corners: [[f32; 2]; 4]) -> Figure {
        let root = aabb([0.0; 3], [4.0, 4.0, 1.0]);
        let leaf = |i: usize, x: f32, y: f32| {
            Spec::Leaf(if occupied[i] {
                vec![quadrant_tri(x, y)]
            } else {
                vec![]
            })
        };
        let tree = HandTree::new(
            root,
            &[
                Spec::Inner(0, 2.0, 1),
                Spec::Inner(1, 2.0, 3),
                Spec::Inner(1, 2.0, 5),
                leaf(0, 0.0, 0.0),
                leaf(1, 0.0, 2.0),
                leaf(2, 2.0, 0.0),
                leaf(3, 2.0, 2.0),
            ],
        );
        let c = corners.map(|[x, y]| Vec3::new(x, y, 0.5));
        let (f, _) = corner_frustum(eye, c, &root);
        Figure {
            tree,
            f,
            neg: [false, false, true],
            idx: (0..7).collect(),
        }
    }

    /// Figure 3: every leaf occupied, the frustum overlaps them all.
    pub fn figure3() -> Figure {
        complete(
            [true; 4],
            Vec3::new(2.0, 2.0, 50.0),
            [[-1.0, -1.0], [5.0, -1.0], [5.0, 5.0], [-1.0, 5.0]],
        )
    }

    /// Figure 4: the frustum overlaps leaves 3, 4 and 5 (a quadrilateral
    /// cross-section reaching across both splits but short of the corner
    /// (2, 2)); 3 holds an overlapped triangle, 4 and 5 are empty, 6 is
    /// occupied but its box is not overlapped.
    pub fn figure4() -> Figure {
        complete(
            [true, false, false, true],
            Vec3::new(1.5, 1.5, 50.0),
            [[0.5, 0.5], [3.1, 0.5], [1.85, 1.85], [0.5, 3.1]],
        )
    }

    /// Figure 2 (the figure itself is not in the text; this tree matches
    /// its description): eight triangles in [0, 8] x [0, 4] x [0, 1], at
    /// most two per leaf, nodes numbered depth first: 0 splits x at 4 into
    /// 1 and 6; 1 splits y at 2 into leaf 2 and 3; 3 splits x at 2 into
    /// leaves 4 and 5; 6 splits y at 2 into leaf 7 and 8; 8 splits y at 3
    /// into leaves 9 and 10. The frustum enters from the left (+x) in the
    /// band y in [1.6, 2.6]: it crosses occupied leaf 2 missing its
    /// triangles (below the band), then 4 (empty), 5 (triangles above the
    /// band), 7 (empty), and reaches leaf 9's two triangles; leaf 10's box
    /// lies above the band.
    pub fn figure2() -> Figure {
        let root = aabb([0.0; 3], [8.0, 4.0, 1.0]);
        // Figure number -> array index (children adjacent).
        let idx = vec![0, 1, 3, 4, 7, 8, 2, 5, 6, 9, 10];
        let mut spec: Vec<Option<Spec>> = (0..11).map(|_| None).collect();
        let mut put = |fig: usize, s: Spec| spec[idx[fig] as usize] = Some(s);
        put(0, Spec::Inner(0, 4.0, idx[1]));
        put(1, Spec::Inner(1, 2.0, idx[2]));
        put(
            2,
            Spec::Leaf(vec![
                [[0.5, 0.3, 0.2], [1.5, 1.2, 0.8], [0.5, 1.2, 0.5]],
                [[2.5, 0.3, 0.2], [3.5, 1.2, 0.8], [2.5, 1.2, 0.5]],
            ]),
        );
        put(3, Spec::Inner(0, 2.0, idx[4]));
        put(4, Spec::Leaf(vec![]));
        put(
            5,
            Spec::Leaf(vec![
                [[2.3, 3.1, 0.2], [3.7, 3.8, 0.8], [2.3, 3.8, 0.5]],
                [[2.5, 3.2, 0.3], [3.5, 3.2, 0.3], [3.0, 3.9, 0.9]],
            ]),
        );
        put(6, Spec::Inner(1, 2.0, idx[7]));
        put(7, Spec::Leaf(vec![]));
        put(8, Spec::Inner(1, 3.0, idx[9]));
        put(
            9,
            Spec::Leaf(vec![
                [[4.8, 2.1, 0.3], [5.4, 2.5, 0.3], [4.8, 2.5, 0.7]],
                [[6.0, 2.1, 0.3], [6.6, 2.5, 0.7], [6.0, 2.5, 0.7]],
            ]),
        );
        put(
            10,
            Spec::Leaf(vec![
                [[4.5, 3.2, 0.2], [5.5, 3.8, 0.8], [4.5, 3.8, 0.5]],
                [[6.5, 3.2, 0.2], [7.5, 3.8, 0.8], [6.5, 3.8, 0.5]],
            ]),
        );
        let spec: Vec<Spec> = spec.into_iter().map(|s| s.unwrap()).collect();
        let tree = HandTree::new(root, &spec);
        let eye = Vec3::new(-200.0, 2.1, 0.5);
        let c = [[1.6, 0.2], [2.6, 0.2], [2.6, 0.8], [1.6, 0.8]].map(|[y, z]| Vec3::new(4.0, y, z));
        let (f, _) = corner_frustum(eye, c, &root);
        Figure {
            tree,
            f,
            neg: [false; 3],
            idx,
        }
    }

    /// Search `S` on a figure: (phase-1 visits, candidates, phase-2 visits,
    /// entry, depth, candidates tested), in figure numbers.
    pub fn run<S: Search>(fig: &Figure) -> (Vec<u32>, Vec<u32>, Vec<u32>, u32, u32, u32) {
        let v = fig.tree.view();
        let lg = Logged::new(&v);
        let q = S::phase1(&lg, &fig.f, fig.neg);
        let p1 = fig.fig(&lg.take());
        assert_eq!(p1.len() as u32, q.visited);
        let cands: Vec<u32> = q.as_slice().iter().map(|c| c.node).collect();
        let p = S::phase2(&lg, &fig.f, fig.neg, &q).unwrap();
        let p2 = fig.fig(&lg.take());
        assert_eq!(p2.len() as u32, p.visited);
        let e = fig.fig(&[p.entry.node])[0];
        (p1, fig.fig(&cands), p2, e, p.entry.depth, p.tested)
    }

    #[test]
    fn figure2_mlrta_returns_the_root() {
        let fig = figure2();
        let (p1, cands, p2, e, depth, tested) = run::<Mlrta>(&fig);
        // Stack [2, 1, 0] (2 on top); 1's branch finds occupied leaf 5,
        // 0's finds leaf 9: the root is returned.
        assert_eq!(p1, [0, 1, 2]);
        assert_eq!(cands, [0, 1, 2]);
        assert_eq!(p2, [3, 4, 5, 6, 7, 8, 9]);
        assert_eq!((e, depth, tested), (0, 0, 2));
    }

    #[test]
    fn figure3_mlrta_tests_every_candidate() {
        let fig = figure3();
        let (p1, cands, p2, e, depth, tested) = run::<Mlrta>(&fig);
        // Stack [3, 1, 0]: 1 -> 4 occupied (entry 1), 0 -> 2 -> 5 (entry 0).
        assert_eq!(p1, [0, 1, 3]);
        assert_eq!(cands, [0, 1, 3]);
        assert_eq!(p2, [4, 2, 5]);
        assert_eq!((e, depth, tested), (0, 0, 2));
    }

    #[test]
    fn figure4_mlrta_keeps_the_leaf() {
        let fig = figure4();
        let (p1, cands, p2, e, depth, tested) = run::<Mlrta>(&fig);
        // 1 -> 4 empty; 0 -> 2 -> 5 empty (6's box not overlapped).
        assert_eq!(p1, [0, 1, 3]);
        assert_eq!(cands, [0, 1, 3]);
        assert_eq!(p2, [4, 2, 5]);
        assert_eq!((e, depth, tested), (3, 2, 2));
    }
}
