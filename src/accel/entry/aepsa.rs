//! AEPSA, the Accelerated Entry Point Search Algorithm (the AEPSA paper's
//! sections 3.1-3.3 and Appendix A), generic over `EntryTree` (kd-tree,
//! BVH).
//!
//! 1. Phase 1 (section 3.1): the descent of MLRTA, but the candidate queue
//!    is frozen only at the first leaf holding a triangle the frustum
//!    overlaps by the four-plane test (`Frustum::cull_triangle_planes`), not
//!    at the first occupied leaf: entry points come out deeper.
//! 2. Phase 2 (section 3.2): the queue is taken top-down, from the highest
//!    candidate, and the first whose untaken branch holds such a leaf is
//!    returned with its box; the candidates below it are never tested. The
//!    last candidate, the leaf itself, is returned when none above
//!    qualifies.
//!
//! `phase2_with` runs phase 2 on any candidate list with either leaf test,
//! for the paper's Figure 6 comparison (MLRTA's phase 1 for both searches).
//! See `accel::entry` for the reading of the spec shared with MLRTA, and
//! `entry::Search` for the rest of a search; this module holds what is
//! AEPSA's own: its leaf goal and its phase 2 (`Aepsa`).
//!
//! # Deviations
//! - Phase 2 asks each branch for a leaf with an overlapped triangle (the
//!   test phase 1 froze with); the appendix's pseudo-code asks for an
//!   occupied leaf, as MLRTA (`phase2_with(.., LeafGoal::Occupied)`). With
//!   the triangle test an entry point is never shallower, but a branch
//!   search may go on past occupied leaves MLRTA would stop at.
//!
//! # Counters
//! As `mlrta`: `aepsa_in` counts, `search` and the phases do not.

use crate::accel::entry::{
    CandidateQueue, EntryPoint, EntryResult, EntryTree, LeafGoal, Phase2, Search, branch_holds,
};
use crate::counters::Counters;
use crate::geom::frustum::Frustum;

/// AEPSA as a `Search`: phase 1 freezes at the first leaf with an
/// overlapped triangle; phase 2 takes the candidates top-down with the
/// same test.
pub struct Aepsa;

impl Search for Aepsa {
    const GOAL: LeafGoal = LeafGoal::Overlapped;

    /// Phase 2 with the triangle test (`phase2_with`).
    fn phase2<E: EntryTree + ?Sized>(
        tree: &E,
        f: &Frustum,
        neg: [bool; 3],
        q: &CandidateQueue,
    ) -> Option<Phase2> {
        phase2_with(tree, f, neg, q, Self::GOAL)
    }
}

/// AEPSA's entry point, counted (`Search::counted`; the queue is
/// `accel::packet::start`'s, in the slot's scratch).
pub fn aepsa_in<E: EntryTree + ?Sized>(
    tree: &E,
    f: &Frustum,
    neg: [bool; 3],
    q: &mut CandidateQueue,
    ctr: &mut Counters,
) -> Option<EntryPoint> {
    Aepsa::counted(tree, f, neg, q, ctr)
}

/// Both phases, with their statistics; counts nothing (`Search::search`).
pub fn search<E: EntryTree + ?Sized>(tree: &E, f: &Frustum, neg: [bool; 3]) -> EntryResult {
    Aepsa::search(tree, f, neg)
}

/// Phase 1: the candidate queue (root first, the first leaf with an
/// overlapped triangle last; empty when there is none on the frustum's way).
pub fn phase1<E: EntryTree + ?Sized>(tree: &E, f: &Frustum, neg: [bool; 3]) -> CandidateQueue {
    Aepsa::phase1(tree, f, neg)
}

/// Phase 2 on any candidate list (AEPSA's or MLRTA's; `None` when empty):
/// top-down, the first candidate whose untaken branch holds a leaf reaching
/// `goal` (through overlapped boxes), else the last candidate.
pub fn phase2_with<E: EntryTree + ?Sized>(
    tree: &E,
    f: &Frustum,
    neg: [bool; 3],
    q: &CandidateQueue,
    goal: LeafGoal,
) -> Option<Phase2> {
    let c = q.as_slice();
    let last = c.last()?;
    let (mut visited, mut tested) = (0, 0);
    for c in c {
        let Some(branch) = c.untaken else {
            break;
        };
        tested += 1;
        if branch_holds(tree, f, neg, branch, c.depth + 1, goal, &mut visited) {
            return Some(Phase2 {
                entry: c.entry_point(),
                visited,
                tested,
            });
        }
    }
    Some(Phase2 {
        entry: last.entry_point(),
        visited,
        tested,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::traverse_masked::tests::built;
    use crate::accel::entry::EntryPoint;
    use crate::accel::entry::mlrta;
    use crate::accel::entry::mlrta::Mlrta;
    use crate::accel::entry::mlrta::tests::{Logged, figure2, figure3, figure4, run};
    use crate::accel::entry::tests::{Reach, scene_packets};
    use crate::accel::entry::{EntryTree, dir_signs};
    use crate::accel::kd::build::build;
    use crate::accel::kd::build::testutil::Store;
    use crate::accel::kd::traverse_single::{self, KdRay, Visit};
    use crate::accel::kd::{KdParams, KdView, clip};
    use crate::geom::{Hit, M4, Mt, Ray4, Scene};

    /// Figure 2: AEPSA passes leaf 2 (its triangles lie outside the
    /// frustum), drops 0 and 1 on the way back, and freezes the queue [9]:
    /// leaf 9 is the entry point, three levels below MLRTA's root.
    #[test]
    fn figure2_aepsa_enters_at_leaf_9() {
        let fig = figure2();
        let (p1, cands, p2, e, depth, tested) = run::<Aepsa>(&fig);
        assert_eq!(p1, [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]);
        assert_eq!(cands, [9]);
        assert!(p2.is_empty());
        assert_eq!((e, depth, tested), (9, 3, 0));
        assert_eq!(run::<Mlrta>(&fig).3, 0);
        // The entry point's box is leaf 9's.
        let r = search(&fig.tree.view(), &fig.f, fig.neg);
        let e = r.entry.unwrap();
        assert_eq!(e.node, fig.at(9));
        assert_eq!(e.aabb.min.to_array(), [4.0, 2.0, 0.0]);
        assert_eq!(e.aabb.max.to_array(), [8.0, 3.0, 1.0]);
        // Figure 6's comparison: AEPSA's phase 2 on MLRTA's stack [0, 1, 2]
        // stops at 0 (same entry), after 0's branch only.
        let v = fig.tree.view();
        let lg = Logged::new(&v);
        let q = mlrta::phase1(&v, &fig.f, fig.neg);
        for goal in [LeafGoal::Overlapped, LeafGoal::Occupied] {
            let p = phase2_with(&lg, &fig.f, fig.neg, &q, goal).unwrap();
            assert_eq!(fig.fig(&lg.take()), [6, 7, 8, 9]);
            assert_eq!((p.entry.node, p.tested), (0, 1));
        }
    }

    /// Figure 3: the first candidate (the root) already has an occupied
    /// overlapped leaf (5) in its untaken branch: one test, where MLRTA
    /// tests every candidate.
    #[test]
    fn figure3_aepsa_tests_one_candidate() {
        let fig = figure3();
        let (p1, cands, p2, e, depth, tested) = run::<Aepsa>(&fig);
        assert_eq!(p1, [0, 1, 3]);
        assert_eq!(cands, [0, 1, 3]);
        assert_eq!(p2, [2, 5]);
        assert_eq!((e, depth, tested), (0, 0, 1));
        let m = run::<Mlrta>(&fig);
        assert_eq!((m.3, m.5), (0, 2));
    }

    /// Figure 4: nothing above leaf 3 qualifies; AEPSA tests every candidate
    /// and visits the nodes MLRTA visits (top-down instead of bottom-up).
    #[test]
    fn figure4_aepsa_visits_what_mlrta_visits() {
        let fig = figure4();
        let a = run::<Aepsa>(&fig);
        let m = run::<Mlrta>(&fig);
        assert_eq!(a.0, [0, 1, 3]);
        assert_eq!(a.1, [0, 1, 3]);
        assert_eq!(a.2, [2, 5, 4]);
        assert_eq!((a.3, a.4, a.5), (3, 2, 2));
        let (mut sa, mut sm) = (a.2.clone(), m.2.clone());
        sa.sort();
        sm.sort();
        assert_eq!(sa, sm);
        assert_eq!((a.0, a.3, a.4), (m.0, m.3, m.4));
    }

    /// A frustum that misses the scene, or reaches only empty leaves and
    /// leaves whose triangles it misses: no entry point, counted as a miss
    /// at the tree's average leaf depth.
    #[test]
    fn misses_and_counters() {
        use crate::accel::entry::mlrta::tests::corner_frustum;
        use glam::Vec3;
        let fig = figure2();
        let v = fig.tree.view();
        let root = fig.tree.info.root;
        // Above the band of leaf 9's triangles: y in [2.65, 2.95], only
        // through leaves 4, 5 (triangles above y = 3.1) and 9 (triangles
        // below 2.5).
        let c =
            [[2.65, 0.2], [2.95, 0.2], [2.95, 0.8], [2.65, 0.8]].map(|[y, z]| Vec3::new(4.0, y, z));
        let (f, _) = corner_frustum(Vec3::new(-200.0, 2.8, 0.5), c, &root);
        let mut ctr = Counters::default();
        let q = &mut CandidateQueue::new();
        assert_eq!(Aepsa::counted(&v, &f, fig.neg, q, &mut ctr), None);
        let r = search(&v, &f, fig.neg);
        assert_eq!((r.candidates, r.tested, r.phase2_nodes), (0, 0, 0));
        assert!(r.phase1_nodes > 0);
        assert_eq!(ctr.entry_searches, 1);
        assert_eq!(ctr.entry_misses, 1);
        assert_eq!(ctr.entry_nodes, r.nodes() as u64);
        assert_eq!(ctr.entry_depth_sum, v.miss_depth() as u64);
        // MLRTA freezes at occupied leaf 5 (candidates [0, 5]), and 0's
        // untaken branch holds occupied leaf 9, whose box the band crosses.
        let e = Mlrta::counted(&v, &f, fig.neg, q, &mut ctr).unwrap();
        assert_eq!((fig.fig(&[e.node]), e.depth), (vec![0], 0));
        let p1 = mlrta::phase1(&v, &f, fig.neg);
        let c: Vec<u32> = p1.as_slice().iter().map(|c| c.node).collect();
        assert_eq!(fig.fig(&c), [0, 5]);
        assert_eq!(ctr.entry_searches, 2);
        assert_eq!(ctr.entry_misses, 1);
        assert_eq!(ctr.entry_depth_sum, v.miss_depth() as u64);
        // Beside the scene: the root box is culled, nothing is visited.
        let c = [[5.0, 0.2], [6.0, 0.2], [6.0, 0.8], [5.0, 0.8]].map(|[y, z]| Vec3::new(4.0, y, z));
        let (f, _) = corner_frustum(Vec3::new(-200.0, 5.5, 0.5), c, &root);
        for r in [search(&v, &f, fig.neg), mlrta::search(&v, &f, fig.neg)] {
            assert_eq!(r, crate::accel::entry::EntryResult::default());
        }
        // Figure 2 counted: 10 + 0 nodes, depth 3.
        let mut ctr = Counters::default();
        Aepsa::counted(&v, &fig.f, fig.neg, q, &mut ctr);
        assert_eq!(
            (ctr.entry_nodes, ctr.entry_depth_sum, ctr.entry_misses),
            (10, 3, 0)
        );
    }

    /// A chain deeper than `MAX_ENTRY_DEPTH` (no build makes one), met in
    /// phase 1 or in a phase-2 branch: the searches answer the root and
    /// never run out of their fixed stacks.
    #[test]
    fn deeper_than_the_bound_answers_the_root() {
        use crate::accel::entry::MAX_ENTRY_DEPTH;
        use crate::accel::entry::mlrta::tests::{HandTree, Spec, corner_frustum};
        use crate::geom::Aabb;
        use glam::Vec3;
        let tri = [[0.1, 0.1, 0.5], [0.2, 0.1, 0.5], [0.1, 0.2, 0.5]];
        let far_tri = [[0.8, 0.8, 0.5], [0.9, 0.8, 0.5], [0.8, 0.9, 0.5]];
        let root = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        let levels = MAX_ENTRY_DEPTH as u32 + 6;
        for front in [false, true] {
            // front: the root splits x at 0.25 into a leaf holding `tri`
            // (found first) and the chain. The chain: inner nodes splitting
            // x at 0.5 (the left child an empty leaf, the right one the
            // next inner node), ending in a leaf holding `far_tri`.
            let mut spec = Vec::new();
            if front {
                spec.push(Spec::Inner(0, 0.25, 1));
                spec.push(Spec::Leaf(vec![tri]));
            }
            let base = spec.len() as u32;
            for k in 0..levels {
                spec.push(Spec::Inner(0, 0.5, base + 2 * k + 1));
                spec.push(Spec::Leaf(vec![]));
            }
            spec.push(Spec::Leaf(vec![far_tri]));
            let t = HandTree::new(root, &spec);
            let v = t.view();
            let c = [[-1.0, -1.0], [2.0, -1.0], [2.0, 2.0], [-1.0, 2.0]]
                .map(|[x, y]| Vec3::new(x, y, 0.5));
            let (f, _) = corner_frustum(Vec3::new(0.5, 0.5, 20.0), c, &root);
            let neg = [false, false, true];
            for r in [search(&v, &f, neg), mlrta::search(&v, &f, neg)] {
                let e = r.entry.unwrap();
                assert_eq!((e.node, e.depth), (0, 0), "front {front}: {r:?}");
                assert!(r.nodes() as usize <= 4 * MAX_ENTRY_DEPTH, "{r:?}");
            }
        }
    }

    /// Per scene and packet: both searches' entry points are the common
    /// ancestor of the leaves the spec names (every box on the way
    /// overlapped; MLRTA: occupied, AEPSA: a triangle the four-plane test
    /// keeps), a miss exactly when there is none; every such leaf holding a
    /// triangle `cull_triangle` keeps lies below the entry point; single kd
    /// rays started at the entry point with its box equal single rays from
    /// the root bitwise, and a miss means every ray misses. Figure 6: on
    /// MLRTA's candidates AEPSA's phase 2 with MLRTA's test returns MLRTA's
    /// entry point visiting no more nodes; with the triangle test it returns
    /// one at least as deep, inside MLRTA's.
    #[test]
    fn entry_points_on_builtin_scenes() {
        let mut tally = [0u64; 8];
        for name in crate::scenes::BUILTIN_NAMES {
            let s = crate::scenes::builtin(name).unwrap();
            let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
            let mut st = Store::new(scene.triangle_count() as usize, false);
            let mut kd = st.kd();
            build(&mut kd, &scene, &KdParams::default()).unwrap();
            let k = kd.view().unwrap();
            let mut bst = crate::accel::bvh::build::testutil::Store::new(0, false);
            let bvh = built::<Mt>(&mut bst, &s.mesh.vertices, &s.mesh.indices, 4);
            let b = bvh.view().unwrap();
            for view in &s.views[..s.views.len().min(2)] {
                for pk in scene_packets(&b, view, s.light, (48, 48), &[4, 8, 16]) {
                    let Some(f) = Frustum::new(pk.kind, &pk.quads, &pk.live, &k.info.root) else {
                        continue;
                    };
                    let what = format!("{name} {}", pk.what);
                    let neg = dir_signs(&pk.quads, &pk.live);
                    check_packet(&k, &f, neg, &pk.quads, &pk.live, &what, &mut tally);
                }
            }
        }
        let [
            packets,
            misses,
            deeper,
            non_root,
            more_nodes,
            mnodes,
            anodes,
            fewer,
        ] = tally;
        println!(
            "entry searches on the built-in scenes: {packets} packets, {misses} misses, AEPSA deeper than MLRTA {deeper}, AEPSA below the root {non_root}; \
             Figure 6 (MLRTA's candidates): phase-2 nodes MLRTA {mnodes}, AEPSA {anodes}, AEPSA fewer {fewer}, more {more_nodes}"
        );
        assert!(
            misses > 0 && deeper > 0 && non_root > packets / 10,
            "{tally:?}"
        );
    }

    fn check_packet(
        k: &KdView<'_>,
        f: &Frustum,
        neg: [bool; 3],
        quads: &[Ray4],
        live: &[M4],
        what: &str,
        tally: &mut [u64; 8],
    ) {
        tally[0] += 1;
        let reach = Reach::new(k, f, k.nodes.len());
        let m = mlrta::search(k, f, neg);
        let a = search(k, f, neg);
        let me = reach.entry(k, f, LeafGoal::Occupied);
        let ae = reach.entry(k, f, LeafGoal::Overlapped);
        assert_eq!(m.entry.map(|e| e.node), me, "{what}: MLRTA {m:?}");
        assert_eq!(a.entry.map(|e| e.node), ae, "{what}: AEPSA {a:?}");
        // The brief's statement: every reached leaf with a triangle
        // `cull_triangle` keeps lies below the entry point.
        for r in [&m, &a] {
            if let Some(e) = &r.entry {
                assert_eq!(e.depth, reach.depth(e.node), "{what}");
                assert!(
                    r.candidates >= 1 && r.tested < r.candidates,
                    "{what}: {r:?}"
                );
                for &l in &reach.leaves {
                    if reach.covers(e.node, l) {
                        continue;
                    }
                    let n = &k.nodes[l as usize];
                    let keeps = k
                        .leaf_refs(n)
                        .iter()
                        .any(|&s| !f.cull_triangle(&k.tris[s as usize]));
                    assert!(!keeps, "{what}: leaf {l} not below {e:?}");
                }
            }
        }
        let Some(me) = m.entry else {
            assert!(a.entry.is_none(), "{what}");
            tally[1] += 1;
            check_rays(k, &[None], quads, live, what);
            return;
        };
        match &a.entry {
            None => tally[1] += 1,
            Some(ae) => {
                assert!(reach.covers(me.node, ae.node), "{what}: {me:?} {ae:?}");
                tally[2] += (ae.depth > me.depth) as u64;
                tally[3] += (ae.depth > 0) as u64;
            }
        }
        // Figure 6: AEPSA's phase 2 on MLRTA's candidates.
        let q = mlrta::phase1(k, f, neg);
        let pm = mlrta::phase2(k, f, neg, &q).unwrap();
        let po = phase2_with(k, f, neg, &q, LeafGoal::Occupied).unwrap();
        assert_eq!(po.entry, pm.entry, "{what}");
        assert!(
            po.visited <= pm.visited && po.tested <= pm.tested,
            "{what}: {po:?} {pm:?}"
        );
        tally[7] += (po.visited < pm.visited) as u64;
        let pa = phase2_with(k, f, neg, &q, LeafGoal::Overlapped).unwrap();
        assert!(pa.entry.depth >= pm.entry.depth, "{what}: {pa:?} {pm:?}");
        assert!(reach.covers(pm.entry.node, pa.entry.node), "{what}");
        if let Some(ae) = &a.entry {
            // Never below the common ancestor of the overlapped leaves.
            assert!(
                reach.covers(pa.entry.node, ae.node),
                "{what}: {pa:?} {ae:?}"
            );
        }
        tally[4] += (pa.visited > pm.visited) as u64;
        tally[5] += pm.visited as u64;
        tally[6] += pa.visited as u64;
        let mut entries = vec![Some(me)];
        for e in [a.entry, Some(pa.entry)] {
            if !entries.contains(&e) {
                entries.push(e);
            }
        }
        check_rays(k, &entries, quads, live, what);
    }

    /// Every live lane traced from each of `entries` (its box clipping the
    /// ray, as the kd packets do) equals the single ray from the root; no
    /// entry point: the single ray misses.
    fn check_rays(
        k: &KdView<'_>,
        entries: &[Option<EntryPoint>],
        quads: &[Ray4],
        live: &[M4],
        what: &str,
    ) {
        let mut ctr = Counters::default();
        for (q, (r4, m)) in quads.iter().zip(live).enumerate() {
            for i in 0..4 {
                if !m.test(i) {
                    continue;
                }
                let ray = r4.lane(i);
                let want = traverse_single::intersect::<Mt>(k, &ray, &mut ctr);
                let kr = KdRay::new(&ray);
                for entry in entries {
                    let mut got = Hit::MISS;
                    if let Some(e) = entry {
                        let (t0, t1) = clip(
                            &e.aabb.min.to_array(),
                            &e.aabb.max.to_array(),
                            &kr.org,
                            &kr.rcp,
                            &kr.neg,
                            ray.tmin,
                            ray.tmax,
                        );
                        if t0 <= t1 {
                            let at = Visit {
                                node: e.node as usize,
                                depth: e.depth as usize,
                                t0,
                                t1,
                            };
                            traverse_single::from_node::<Mt, false>(
                                k, &ray, &kr, at, &mut got, &mut ctr,
                            );
                        }
                    }
                    assert!(
                        traverse_single::tests::same(&got, &want),
                        "{what}: lane {q}.{i} {ray:?} from {entry:?}: {got:?}, from the root {want:?}"
                    );
                }
            }
        }
    }
}
