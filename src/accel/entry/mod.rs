//! Entry points into trees (AEPSA paper section 2.1): "the common ancestor
//! node in the tree of all leaves that contain objects overlapped fully or
//! partially by the ray proxy frustum". Shared vocabulary of the searches
//! (`entry::mlrta`, `entry::aepsa`) and the trees they search
//! (the kd-tree, and the BVH as the paper's further work, section 8):
//! `EntryTree`, the `CandidateQueue` both searches fill in phase 1, the
//! phase-1 descent (`find_candidates`) and phase 2's branch test
//! (`branch_holds`) they share, and `Search`: a whole search (both phases,
//! counted or not), given what sets MLRTA and AEPSA apart, the leaf that
//! freezes phase 1 and phase 2.
//!
//! # Reading of the spec
//! Sections 2.2, 3.1-3.3 and the appendix leave the traversal order and the
//! fate of candidates on backtracking open; this reading agrees with the
//! three worked examples (Figures 2, 3 and 4, reproduced as tests in
//! `entry::mlrta` and `entry::aepsa`):
//! - Phase 1 (both searches) is a front-to-back depth-first descent of the
//!   ray proxy frustum: children near/far by the sign of the packet's
//!   direction sum on the split axis (`dir_signs`), a child skipped when the
//!   frustum misses its box (`Frustum::cull_box`). A node with both
//!   children's boxes overlapped is a bifurcation, and a candidate only
//!   while the descent is inside its near child: backtracking out of a
//!   subtree drops the candidates inside it (they cannot be ancestors of
//!   the leaf finally found), and a node whose near child was explored
//!   without success is no candidate when its far child is entered. The
//!   candidates are thus the ancestors of the leaf found whose untaken (far)
//!   branch is still pending, then the leaf itself. MLRTA freezes at the
//!   first occupied leaf, AEPSA at the first leaf with a triangle the
//!   four-plane test does not cull (`LeafGoal`).
//! - Phase 2: MLRTA checks the bifurcation stack bottom-up (deepest first),
//!   all of it: a candidate whose untaken branch holds an occupied leaf
//!   whose box the frustum overlaps becomes the entry point. AEPSA takes
//!   the queue top-down and returns the first candidate whose untaken
//!   branch holds a leaf with a frustum-overlapped triangle; the last
//!   candidate, the leaf itself, is returned when nothing above qualifies.
//! - When phase 1 finds no leaf there is no entry point: every ray of the
//!   packet misses.
//!
//! Either way the entry point is an ancestor-or-self of every leaf the
//! descent can reach (every box on its path overlapped) that holds a
//! triangle the frustum overlaps: such a leaf after the frozen one in
//! depth-first order has its lowest common ancestor with it among the
//! candidates, and that candidate's untaken branch holds it. Any triangle a
//! ray of the packet hits is such a triangle in such a leaf (the frustum
//! culls nothing a ray hits, and the leaf holding the hit point has every
//! box on its path overlapped), so traversal from the entry point is exact.
//!
//! # Deviations
//! - The appendix's phase 2 tests each candidate's branch for "an occupied
//!   leaf overlapped by the ray proxy frustum" as MLRTA does; AEPSA here
//!   asks for an overlapped triangle (the four-plane test) by default, and
//!   `entry::aepsa::phase2_with` takes MLRTA's test for the paper's
//!   Figure 6 comparison (same candidates, same entry point, never more
//!   nodes).
//! - A tree deeper than `MAX_ENTRY_DEPTH` (no build here makes one) is not
//!   searched past that depth: the search answers the root, or a shallower
//!   candidate, which stays correct.

pub mod aepsa;
pub mod mlrta;

pub use crate::accel::method::EntrySearch;
use crate::counters::Counters;
use crate::geom::frustum::Frustum;
use crate::geom::{Aabb, F4, M4, Ray4};

/// Where the rays of a frustum enter a tree: a node, its depth (root 0) and
/// its box (for a kd-tree the box the splits above it carve out).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EntryPoint {
    pub node: u32,
    pub depth: u32,
    pub aabb: Aabb,
}

// ---------------------------------------------------------------------------
// The searches' shared machinery.

/// Deepest level any tree the searches walk reaches (root 0): at least the
/// kd-tree's and the BVH's build bounds (each family asserts it at compile
/// time). Every fixed array below has `MAX_ENTRY_DEPTH + 1` entries.
pub const MAX_ENTRY_DEPTH: usize = 48;

/// Most entries of a candidate queue: one bifurcation per level above the
/// leaf, plus the leaf.
pub const MAX_CANDIDATES: usize = MAX_ENTRY_DEPTH + 1;

/// A binary tree as the entry-point searches see it: nodes by index, boxes
/// handed down from the root (a kd-tree derives a child's box from its
/// parent's and the split; a BVH stores it).
///
/// Contract: `children` is called exactly once per node a search visits
/// (the tests count visits through it); indices come from `root` and
/// `children` only.
pub trait EntryTree {
    /// The root and its box; `None` for a tree without nodes.
    fn root(&self) -> Option<(u32, Aabb)>;
    /// The (left, right) children of `node` with their boxes, given
    /// `node`'s box `aabb`; `None` for a leaf.
    fn children(&self, node: u32, aabb: &Aabb) -> Option<[(u32, Aabb); 2]>;
    /// Split axis (0..=2) of inner node `node`: the near child is the left
    /// one unless the packet's direction sum is negative on it.
    fn split_axis(&self, node: u32) -> usize;
    /// Triangles (references) in leaf `node`.
    fn leaf_count(&self, node: u32) -> usize;
    /// Whether some triangle of leaf `node` survives the frustum's
    /// four-plane test (`Frustum::cull_triangle_planes`, section 3.1).
    fn leaf_overlapped(&self, node: u32, f: &Frustum) -> bool;
    /// The depth a search that finds no leaf counts (`Counters::
    /// entry_depth_sum`): the tree's average leaf depth, rounded down.
    fn miss_depth(&self) -> u32;
}

/// Which leaf ends phase 1's descent and qualifies a branch in phase 2.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LeafGoal {
    /// An occupied leaf (count > 0) whose box the frustum overlaps: MLRTA
    /// (section 2.2).
    Occupied,
    /// An occupied leaf with a triangle the four-plane test does not cull:
    /// AEPSA (section 3.1).
    Overlapped,
}

impl LeafGoal {
    #[inline]
    fn reached<E: EntryTree + ?Sized>(self, tree: &E, node: u32, f: &Frustum) -> bool {
        tree.leaf_count(node) > 0 && (self == LeafGoal::Occupied || tree.leaf_overlapped(node, f))
    }
}

/// One entry of the candidate queue (AEPSA) or bifurcation stack (MLRTA):
/// a node, its depth and box, and the branch the descent did not take.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    pub node: u32,
    pub depth: u32,
    pub aabb: Aabb,
    /// The far child and its box (still pending when the descent froze);
    /// `None` for the last candidate, the leaf the descent froze at.
    pub untaken: Option<(u32, Aabb)>,
}

impl Candidate {
    const NONE: Candidate = Candidate {
        node: 0,
        depth: 0,
        aabb: Aabb::EMPTY,
        untaken: None,
    };
    #[inline]
    pub fn entry_point(&self) -> EntryPoint {
        EntryPoint {
            node: self.node,
            depth: self.depth,
            aabb: self.aabb,
        }
    }
}

/// Phase 1's output: the candidates root first (AEPSA's queue order; MLRTA
/// reads the same list from the end as its bifurcation stack), the leaf
/// last. Empty when the descent found no leaf: every ray misses.
#[derive(Clone, Copy, Debug)]
pub struct CandidateQueue {
    items: [Candidate; MAX_CANDIDATES],
    len: usize,
    /// Nodes phase 1 visited.
    pub visited: u32,
}

impl Default for CandidateQueue {
    fn default() -> Self {
        Self::new()
    }
}

impl CandidateQueue {
    pub const fn new() -> Self {
        CandidateQueue {
            items: [Candidate::NONE; MAX_CANDIDATES],
            len: 0,
            visited: 0,
        }
    }
    /// Empty, nothing visited (the items are left as they are).
    #[inline]
    pub fn clear(&mut self) {
        self.len = 0;
        self.visited = 0;
    }
    #[inline]
    pub fn as_slice(&self) -> &[Candidate] {
        &self.items[..self.len]
    }
    #[inline]
    pub fn len(&self) -> usize {
        self.len
    }
    /// No leaf found: the packet misses.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// The leaf the descent froze at (the last candidate).
    #[inline]
    pub fn leaf(&self) -> Option<&Candidate> {
        self.as_slice().last()
    }
    /// `false` (nothing pushed) when full.
    #[inline]
    fn push(&mut self, c: Candidate) -> bool {
        if self.len == MAX_CANDIDATES {
            return false;
        }
        self.items[self.len] = c;
        self.len += 1;
        true
    }
    #[inline]
    fn pop(&mut self) -> Option<Candidate> {
        self.len = self.len.checked_sub(1)?;
        Some(self.items[self.len])
    }
    /// A tree deeper than `MAX_ENTRY_DEPTH` (never built here): the root as
    /// the only candidate, which is always a correct entry point.
    fn bail(&mut self, root: u32, aabb: Aabb) {
        self.len = 0;
        self.push(Candidate {
            node: root,
            depth: 0,
            aabb,
            untaken: None,
        });
    }
}

/// Phase 2's output.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Phase2 {
    pub entry: EntryPoint,
    /// Nodes visited searching untaken branches.
    pub visited: u32,
    /// Candidates whose untaken branch was searched.
    pub tested: u32,
}

/// A whole search: the entry point (or a miss) and what it cost.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct EntryResult {
    /// `None`: no leaf reached, every ray of the packet misses.
    pub entry: Option<EntryPoint>,
    /// Phase 1's candidates, the leaf included (0 on a miss).
    pub candidates: u32,
    /// Candidates phase 2 searched below.
    pub tested: u32,
    pub phase1_nodes: u32,
    pub phase2_nodes: u32,
}

impl EntryResult {
    /// Combine the phases' outputs (`p2` is `None` exactly on a miss).
    pub fn from_phases(q: &CandidateQueue, p2: Option<Phase2>) -> EntryResult {
        EntryResult {
            entry: p2.map(|p| p.entry),
            candidates: q.len() as u32,
            tested: p2.map_or(0, |p| p.tested),
            phase1_nodes: q.visited,
            phase2_nodes: p2.map_or(0, |p| p.visited),
        }
    }
    /// Nodes both phases visited.
    #[inline]
    pub fn nodes(&self) -> u32 {
        self.phase1_nodes + self.phase2_nodes
    }
    /// Add this search to `entry_searches`, `entry_depth_sum` (the tree's
    /// `miss_depth` on a miss), `entry_nodes` and `entry_misses`.
    pub fn record<E: EntryTree + ?Sized>(&self, tree: &E, ctr: &mut Counters) {
        ctr.entry_searches += 1;
        ctr.entry_nodes += self.nodes() as u64;
        match &self.entry {
            Some(e) => ctr.entry_depth_sum += e.depth as u64,
            None => {
                ctr.entry_misses += 1;
                ctr.entry_depth_sum += tree.miss_depth() as u64;
            }
        }
    }
}

/// Whether the frustum overlaps box `b` (not culled by its planes).
#[inline(always)]
fn admits(f: &Frustum, b: &Aabb) -> bool {
    !f.cull_box(&b.min.to_array(), &b.max.to_array())
}

/// `(near, far)` of an inner node's `(left, right)` children.
#[inline(always)]
fn near_far(ch: [(u32, Aabb); 2], axis: usize, neg: &[bool; 3]) -> [(u32, Aabb); 2] {
    if neg[axis.min(2)] { [ch[1], ch[0]] } else { ch }
}

/// Phase 1 of both searches: the front-to-back depth-first descent of the
/// frustum (near child by `neg`, the sign of the packet's direction sum,
/// see `dir_signs`), skipping children whose box it misses, until the first
/// leaf reaching `goal`. A node with both children overlapped is pushed as
/// a candidate with its far child; backtracking out of its near subtree
/// pops it (the far child is then entered as a plain node), so the queue
/// ends as the leaf's ancestors whose far branch is pending, then the leaf.
pub fn find_candidates<E: EntryTree + ?Sized>(
    tree: &E,
    f: &Frustum,
    neg: [bool; 3],
    goal: LeafGoal,
) -> CandidateQueue {
    let mut q = CandidateQueue::new();
    find_candidates_into(tree, f, neg, goal, &mut q);
    q
}

/// `find_candidates` into `q` (emptied first): `accel::packet::start` keeps the
/// queue (about 3 KiB) in the slot's scratch, not on the caller's stack.
#[inline(never)]
pub fn find_candidates_into<E: EntryTree + ?Sized>(
    tree: &E,
    f: &Frustum,
    neg: [bool; 3],
    goal: LeafGoal,
    q: &mut CandidateQueue,
) {
    q.clear();
    let Some((root, root_box)) = tree.root() else {
        return;
    };
    if !admits(f, &root_box) {
        return;
    }
    let (mut node, mut aabb, mut depth) = (root, root_box, 0u32);
    loop {
        q.visited += 1;
        match tree.children(node, &aabb) {
            None => {
                if goal.reached(tree, node, f) {
                    let c = Candidate {
                        node,
                        depth,
                        aabb,
                        untaken: None,
                    };
                    if !q.push(c) {
                        q.bail(root, root_box);
                    }
                    return;
                }
            }
            Some(ch) => {
                if depth as usize >= MAX_ENTRY_DEPTH {
                    q.bail(root, root_box);
                    return;
                }
                let [near, far] = near_far(ch, tree.split_axis(node), &neg);
                let (go_near, go_far) = (admits(f, &near.1), admits(f, &far.1));
                if go_near && go_far {
                    let c = Candidate {
                        node,
                        depth,
                        aabb,
                        untaken: Some(far),
                    };
                    if !q.push(c) {
                        q.bail(root, root_box);
                        return;
                    }
                }
                if go_near || go_far {
                    (node, aabb) = if go_near { near } else { far };
                    depth += 1;
                    continue;
                }
            }
        }
        // Dead end: resume at the deepest pending far branch. Its
        // bifurcation leaves the queue: its near subtree failed, so it is
        // no ancestor-with-a-pending-branch of the leaf to come.
        let Some(c) = q.pop() else {
            return;
        };
        let Some((n, b)) = c.untaken else {
            return;
        };
        (node, aabb, depth) = (n, b, c.depth + 1);
    }
}

/// Phase 2's test of one candidate: whether the branch `start` (a node at
/// `depth` whose box the frustum overlaps) holds a leaf reaching `goal`
/// through boxes the frustum overlaps, searched front to back as phase 1;
/// the nodes visited are added to `visited`. A tree deeper than
/// `MAX_ENTRY_DEPTH` answers `true` (a shallower, still correct, entry).
pub fn branch_holds<E: EntryTree + ?Sized>(
    tree: &E,
    f: &Frustum,
    neg: [bool; 3],
    start: (u32, Aabb),
    depth: u32,
    goal: LeafGoal,
    visited: &mut u32,
) -> bool {
    let mut st = [(0u32, Aabb::EMPTY, 0u32); MAX_ENTRY_DEPTH + 1];
    let mut sp = 0usize;
    let ((mut node, mut aabb), mut depth) = (start, depth);
    loop {
        *visited += 1;
        match tree.children(node, &aabb) {
            None => {
                if goal.reached(tree, node, f) {
                    return true;
                }
            }
            Some(ch) => {
                if depth as usize >= MAX_ENTRY_DEPTH {
                    return true;
                }
                let [near, far] = near_far(ch, tree.split_axis(node), &neg);
                let (go_near, go_far) = (admits(f, &near.1), admits(f, &far.1));
                if go_near && go_far {
                    if sp == st.len() {
                        return true;
                    }
                    st[sp] = (far.0, far.1, depth + 1);
                    sp += 1;
                }
                if go_near || go_far {
                    (node, aabb) = if go_near { near } else { far };
                    depth += 1;
                    continue;
                }
            }
        }
        if sp == 0 {
            return false;
        }
        sp -= 1;
        (node, aabb, depth) = st[sp];
    }
}

// ---------------------------------------------------------------------------
// A whole search.

/// What sets one search apart from the other (`mlrta::Mlrta`,
/// `aepsa::Aepsa`): the leaf its phase 1 freezes at and its phase 2. A
/// whole search, from phase 1 to the counters, is written here once.
pub trait Search {
    /// The leaf phase 1's descent freezes at (`find_candidates`).
    const GOAL: LeafGoal;

    /// Phase 2 on phase 1's candidates (`None` when there are none).
    fn phase2<E: EntryTree + ?Sized>(
        tree: &E,
        f: &Frustum,
        neg: [bool; 3],
        q: &CandidateQueue,
    ) -> Option<Phase2>;

    /// Phase 1: the candidates, root first, the first leaf reaching `GOAL`
    /// last (empty when the frustum reaches none).
    fn phase1<E: EntryTree + ?Sized>(tree: &E, f: &Frustum, neg: [bool; 3]) -> CandidateQueue {
        find_candidates(tree, f, neg, Self::GOAL)
    }

    /// Both phases, with their statistics; counts nothing.
    fn search<E: EntryTree + ?Sized>(tree: &E, f: &Frustum, neg: [bool; 3]) -> EntryResult {
        let q = Self::phase1(tree, f, neg);
        EntryResult::from_phases(&q, Self::phase2(tree, f, neg, &q))
    }

    /// The entry point for the rays `f` bounds (`None`: all miss), counted
    /// in `ctr` (`EntryResult::record`), with phase 1's queue in `q`
    /// (`accel::packet::start`'s, in the slot's scratch). `neg`: the
    /// packet's direction signs (`dir_signs`).
    fn counted<E: EntryTree + ?Sized>(
        tree: &E,
        f: &Frustum,
        neg: [bool; 3],
        q: &mut CandidateQueue,
        ctr: &mut Counters,
    ) -> Option<EntryPoint> {
        find_candidates_into(tree, f, neg, Self::GOAL, q);
        let r = EntryResult::from_phases(q, Self::phase2(tree, f, neg, q));
        r.record(tree, ctr);
        r.entry
    }
}

/// Which way a packet travels on each axis: `true` where the sum of its
/// live lanes' directions is negative (a zero sum: the first live lane's
/// sign bit), the near-child rule of the BVH packet traversals
/// (`bvh::traverse_masked`). `live`: active lanes with valid rays
/// (`live_mask`).
pub fn dir_signs(rays: &[Ray4], live: &[M4]) -> [bool; 3] {
    let mut sum = [F4::ZERO; 3];
    let mut first = None;
    for (r, m) in rays.iter().zip(live) {
        if !m.any() {
            continue;
        }
        if first.is_none() {
            let i = m.bitmask().trailing_zeros() as usize;
            first = Some([r.dir[0][i], r.dir[1][i], r.dir[2][i]]);
        }
        for (s, d) in sum.iter_mut().zip(&r.dir) {
            *s += F4::select(*m, *d, F4::ZERO);
        }
    }
    let d0 = first.unwrap_or([0.0; 3]);
    core::array::from_fn(|a| {
        let s = sum[a].element_sum();
        if s != 0.0 {
            s < 0.0
        } else {
            d0[a].is_sign_negative()
        }
    })
}

/// The lanes of `active` whose rays are valid (`Ray::is_valid`, 4-wide):
/// the `live` mask `Frustum::new` and `dir_signs` take.
#[inline]
pub fn live_mask(r: &Ray4, active: M4) -> M4 {
    let fin = |x: F4| x.abs().cmplt(F4::INFINITY);
    active
        & fin(r.org[0])
        & fin(r.org[1])
        & fin(r.org[2])
        & fin(r.dir[0])
        & fin(r.dir[1])
        & fin(r.dir[2])
        & (r.dir[0].cmpne(F4::ZERO) | r.dir[1].cmpne(F4::ZERO) | r.dir[2].cmpne(F4::ZERO))
        & r.tmin.cmpge(F4::ZERO)
        & r.tmin.cmple(r.tmax)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::accel::bvh;
    use crate::accel::bvh::BvhView;
    use crate::accel::bvh::packet::Walk;
    use crate::accel::bvh::traverse_masked::Masked;
    use crate::accel::bvh::traverse_masked::tests::{Start, check_sets_from};
    use crate::accel::bvh::traverse_partition::Partition;
    use crate::accel::bvh::traverse_ranged::Ranged;
    use crate::accel::method::TraceParams;
    use crate::accel::testkit::Store;
    use crate::accel::testkit::{built, lattice, packets, ray_sets};
    use crate::geom::frustum::RayKind;
    use crate::geom::{Mt, Wt};
    use std::cell::Cell;

    /// What the frustum reaches by brute force: every node whose box and
    /// all its ancestors' boxes it overlaps, with parent and depth.
    pub struct Reach {
        /// By node (`n`: the tree's node count): (parent, depth) when
        /// reached (the root is its own parent), else `u32::MAX`.
        pub up: Vec<(u32, u32)>,
        /// By node: its place in the depth-first order of the reached
        /// nodes and its reached subtree's size, so a subtree is one range
        /// of places (`covers` in constant time).
        order: Vec<(u32, u32)>,
        /// Reached leaves.
        pub leaves: Vec<u32>,
    }

    impl Reach {
        pub fn new<E: EntryTree + ?Sized>(tree: &E, f: &Frustum, n: usize) -> Reach {
            let mut r = Reach {
                up: vec![(u32::MAX, u32::MAX); n],
                order: vec![(u32::MAX, 0); n],
                leaves: Vec::new(),
            };
            let Some((root, b)) = tree.root() else {
                return r;
            };
            if !admits(f, &b) {
                return r;
            }
            // Depth first from a stack: a node's descendants are popped
            // right after it, so its subtree is the next `size` places.
            let mut popped = Vec::new();
            let mut st = vec![(root, b, root, 0u32)];
            while let Some((n, b, p, d)) = st.pop() {
                r.up[n as usize] = (p, d);
                r.order[n as usize] = (popped.len() as u32, 1);
                popped.push(n);
                match tree.children(n, &b) {
                    None => r.leaves.push(n),
                    Some(ch) => {
                        for (c, cb) in ch {
                            if admits(f, &cb) {
                                st.push((c, cb, n, d + 1));
                            }
                        }
                    }
                }
            }
            for &n in popped[1..].iter().rev() {
                let (p, size) = (r.up[n as usize].0, r.order[n as usize].1);
                r.order[p as usize].1 += size;
            }
            r
        }
        pub fn depth(&self, n: u32) -> u32 {
            let d = self.up[n as usize].1;
            assert!(d != u32::MAX, "node {n} not reached");
            d
        }
        /// Whether `a` is `x` or one of its ancestors.
        pub fn covers(&self, a: u32, x: u32) -> bool {
            // `depth` asserts both were reached.
            let _ = (self.depth(a), self.depth(x));
            let ((pa, size), (px, _)) = (self.order[a as usize], self.order[x as usize]);
            pa <= px && px < pa + size
        }
        /// The lowest common ancestor of `nodes` (`None` when empty): that
        /// of the first and the last of them in depth-first order.
        pub fn lca(&self, nodes: &[u32]) -> Option<u32> {
            let place = |&n: &u32| {
                let _ = self.depth(n);
                self.order[n as usize].0
            };
            let mut a = nodes.iter().copied().min_by_key(place)?;
            let mut x = nodes.iter().copied().max_by_key(place)?;
            while self.depth(x) > self.depth(a) {
                x = self.up[x as usize].0;
            }
            while self.depth(a) > self.depth(x) {
                a = self.up[a as usize].0;
            }
            while a != x {
                a = self.up[a as usize].0;
                x = self.up[x as usize].0;
            }
            Some(a)
        }
        /// The entry point the spec defines for `goal`: the common ancestor
        /// of the reached leaves reaching it.
        pub fn entry<E: EntryTree + ?Sized>(
            &self,
            tree: &E,
            f: &Frustum,
            goal: LeafGoal,
        ) -> Option<u32> {
            let l: Vec<u32> = self
                .leaves
                .iter()
                .copied()
                .filter(|&n| goal.reached(tree, n, f))
                .collect();
            self.lca(&l)
        }
    }

    /// One packet of a test image: quads, live lanes, frustum kind.
    pub struct Pk {
        pub quads: Vec<Ray4>,
        pub live: Vec<M4>,
        pub kind: RayKind,
        pub what: String,
    }

    /// Packets of side `sides` over the BVH test ray sets of `view` (primary,
    /// shadow, reflection, mixed, random, bundle), each with every frustum
    /// kind of its set.
    pub fn scene_packets(
        b: &BvhView<'_>,
        view: &crate::scenes::View,
        light: glam::Vec3,
        (w, h): (u32, u32),
        sides: &[u32],
    ) -> Vec<Pk> {
        let mut out = Vec::new();
        for set in ray_sets::<Mt>(b, view, light, w, h, 0xe17e ^ w as u64) {
            for &n in sides {
                for (k, (quads, active, _)) in packets(&set, n).into_iter().enumerate() {
                    let live: Vec<M4> = quads
                        .iter()
                        .zip(&active)
                        .map(|(r, a)| live_mask(r, *a))
                        .collect();
                    for &kind in set.kinds {
                        out.push(Pk {
                            quads: quads.clone(),
                            live: live.clone(),
                            kind,
                            what: format!("{} n={n} #{k} {kind:?}", set.name),
                        });
                    }
                }
            }
        }
        out
    }

    /// The entry-point search of `check_sets_from`: the frustum of the
    /// packet's live lanes (the options' kind, the root box; none: start
    /// at the root), then MLRTA or AEPSA on the BVH. `seen` counts starts
    /// below the root, at the root, and misses.
    fn searcher<'c>(
        alg: EntrySearch,
        seen: &'c Cell<[u64; 3]>,
    ) -> impl Fn(&BvhView<'_>, &[Ray4], &[M4], &TraceParams) -> Start + 'c {
        move |b, quads, active, opt| {
            let live: Vec<M4> = quads
                .iter()
                .zip(active)
                .map(|(r, a)| live_mask(r, *a))
                .collect();
            let bump = |i: usize| {
                let mut c = seen.get();
                c[i] += 1;
                seen.set(c);
            };
            let Some(root) = b.nodes.first() else {
                bump(1);
                return Start::Root;
            };
            let Some(f) = Frustum::new(opt.bvh.kind, quads, &live, &root.aabb()) else {
                bump(1);
                return Start::Root;
            };
            let neg = dir_signs(quads, &live);
            let r = match alg {
                EntrySearch::Mlrta => mlrta::search(b, &f, neg),
                _ => aepsa::search(b, &f, neg),
            };
            match r.entry {
                Some(e) => {
                    bump((e.node == 0) as usize);
                    Start::At(e)
                }
                None => {
                    bump(2);
                    Start::Miss
                }
            }
        }
    }

    /// BVH packets of traversal `W` started at `alg`'s entry points (every
    /// set, side, kind, culling on and off, nearest hit and occlusion; a
    /// miss: not traced) equal single rays bitwise, on the built-in scenes
    /// and the lattice; the searches do start below the root and miss.
    fn check_bvh_packets<W: Walk>(alg: EntrySearch) {
        let seen = Cell::new([0u64; 3]);
        let search = searcher(alg, &seen);
        for name in crate::scenes::BUILTIN_NAMES {
            let s = crate::scenes::builtin(name).unwrap();
            let mut st = Store::new(0, false);
            let bvh = built::<Mt>(&mut st, &s.mesh.vertices, &s.mesh.indices, 4);
            let b = bvh.view().unwrap();
            let sets = ray_sets::<Mt>(
                &b,
                &s.views[0],
                s.light,
                48,
                40,
                0xb0e ^ *name.as_bytes().first().unwrap() as u64,
            );
            check_sets_from::<W, Mt>(name, &b, &sets, &search);
        }
        let (v, ix, sets) = lattice();
        let mut st = Store::new(0, false);
        let bvh = built::<Wt>(&mut st, &v, &ix, 1);
        check_sets_from::<W, Wt>("lattice", &bvh.view().unwrap(), &sets, &search);
        let [below, root, miss] = seen.get();
        assert!(
            miss > 0 && 5 * below > below + root + miss,
            "{alg:?}: {:?}",
            seen.get()
        );
    }

    #[test]
    fn bvh_masked_from_mlrta_entry_points() {
        check_bvh_packets::<Masked>(EntrySearch::Mlrta);
    }

    #[test]
    fn bvh_masked_from_aepsa_entry_points() {
        check_bvh_packets::<Masked>(EntrySearch::Aepsa);
    }

    #[test]
    fn bvh_ranged_from_mlrta_entry_points() {
        check_bvh_packets::<Ranged>(EntrySearch::Mlrta);
    }

    #[test]
    fn bvh_ranged_from_aepsa_entry_points() {
        check_bvh_packets::<Ranged>(EntrySearch::Aepsa);
    }

    #[test]
    fn bvh_partition_from_mlrta_entry_points() {
        check_bvh_packets::<Partition>(EntrySearch::Mlrta);
    }

    #[test]
    fn bvh_partition_from_aepsa_entry_points() {
        check_bvh_packets::<Partition>(EntrySearch::Aepsa);
    }

    /// On the BVH as on the kd-tree: MLRTA's and AEPSA's entry points are
    /// the common ancestors of the reached occupied leaves and of the
    /// reached leaves with overlapped triangles, a miss exactly when there
    /// are none; every reached leaf with a triangle `cull_triangle` keeps
    /// lies below both; AEPSA's is inside MLRTA's. Also on a BVH at the
    /// depth limit (a chain of leaves down to depth 48), searched to the
    /// bottom.
    #[test]
    fn bvh_entry_points_are_common_ancestors() {
        struct Sc {
            name: String,
            v: Vec<f32>,
            ix: Vec<u32>,
            views: Vec<crate::scenes::View>,
            light: glam::Vec3,
        }
        let mut scenes: Vec<Sc> = Vec::new();
        for name in crate::scenes::BUILTIN_NAMES {
            let s = crate::scenes::builtin(name).unwrap();
            scenes.push(Sc {
                name: name.to_string(),
                v: s.mesh.vertices,
                ix: s.mesh.indices,
                views: s.views[..s.views.len().min(2)].to_vec(),
                light: s.light,
            });
        }
        let (v, ix) = crate::accel::testkit::soup(&crate::accel::testkit::deep_tris());
        let deep_view = crate::scenes::View {
            eye: glam::Vec3::ZERO,
            look_at: glam::Vec3::new(1.0, 0.005, 0.005),
            up: glam::Vec3::Z,
            fov_y_deg: 0.5,
        };
        scenes.push(Sc {
            name: "deep".into(),
            v,
            ix,
            views: vec![deep_view],
            light: glam::Vec3::ONE,
        });
        let mut misses = 0;
        for Sc {
            name,
            v,
            ix,
            views,
            light,
        } in &scenes
        {
            let mut st = Store::new(0, false);
            let bvh = if name == "deep" {
                let scene = crate::geom::Scene::from_f32(v, ix).unwrap();
                st = Store::new(scene.triangle_count() as usize, false);
                let mut bvh = st.bvh();
                let p = crate::accel::bvh::BvhParams {
                    leaf_size: 1,
                    bins: 2,
                    traversal_cost: 1.0,
                    test: crate::geom::TriTest::Watertight,
                    quality: crate::accel::bvh::BuildQuality::Medium,
                    width: 4,
                    presplit: false,
                };
                crate::accel::bvh::build::build(&mut bvh, &scene, &p).unwrap();
                bvh
            } else {
                built::<Mt>(&mut st, v, ix, 4)
            };
            let b = bvh.view().unwrap();
            let (mut n, mut miss) = (0, 0);
            for view in views {
                for pk in scene_packets(&b, view, *light, (32, 32), &[4, 16]) {
                    let Some(f) = Frustum::new(pk.kind, &pk.quads, &pk.live, &b.nodes[0].aabb())
                    else {
                        continue;
                    };
                    let what = format!("{name} {}", pk.what);
                    let neg = dir_signs(&pk.quads, &pk.live);
                    let reach = Reach::new(&b, &f, b.nodes.len());
                    let m = mlrta::search(&b, &f, neg);
                    let a = aepsa::search(&b, &f, neg);
                    let me = reach.entry(&b, &f, LeafGoal::Occupied);
                    let ae = reach.entry(&b, &f, LeafGoal::Overlapped);
                    assert_eq!(m.entry.map(|e| e.node), me, "{what}: {m:?}");
                    assert_eq!(a.entry.map(|e| e.node), ae, "{what}: {a:?}");
                    n += 1;
                    miss += a.entry.is_none() as u32;
                    for e in [m.entry, a.entry].iter().flatten() {
                        assert_eq!(e.depth, reach.depth(e.node));
                        assert_eq!(e.aabb, b.nodes[e.node as usize].aabb());
                        for &l in &reach.leaves {
                            if reach.covers(e.node, l) {
                                continue;
                            }
                            let nd = &b.nodes[l as usize];
                            let first = nd.first as usize;
                            let keeps = b.tris[first..first + nd.count() as usize]
                                .iter()
                                .any(|t| !f.cull_triangle(t));
                            assert!(!keeps, "{what}: leaf {l} not below {e:?}");
                        }
                    }
                    if let (Some(me), Some(ae)) = (m.entry, a.entry) {
                        assert!(reach.covers(me.node, ae.node), "{what}");
                    }
                }
            }
            assert!(n > 0, "{name}");
            misses += miss;
            if name == "deep" {
                assert!(b.info.depth as usize >= bvh::MAX_DEPTH - 8, "{:?}", b.info);
            }
        }
        assert!(misses > 0);
    }

    #[test]
    fn live_mask_and_dir_signs_match_the_bvh_packets() {
        use crate::geom::Ray;
        use glam::Vec3;
        let r = |d: Vec3| Ray::new(Vec3::ZERO, d, 0.0, 1.0);
        let mut bad = r(Vec3::X);
        bad.tmin = 2.0;
        let q = [
            Ray4::from_rays(&[
                r(Vec3::new(1.0, -2.0, 0.0)),
                r(Vec3::ZERO),
                bad,
                r(Vec3::new(f32::NAN, 0.0, 1.0)),
            ]),
            Ray4::from_rays(&[
                r(Vec3::new(1.0, 1.0, -0.0)),
                r(Vec3::new(-5.0, 0.5, 0.0)),
                r(Vec3::X),
                r(Vec3::X),
            ]),
        ];
        let live = [
            live_mask(&q[0], M4::TRUE),
            live_mask(&q[1], M4::new(true, false, true, true)),
        ];
        assert_eq!(live[0].bitmask(), 0b0001);
        assert_eq!(live[1].bitmask(), 0b1101);
        // x: 1 + 1 + 1 + 1 > 0; y: -2 + 1 < 0; z: 0 + -0: the first live
        // lane's sign (+0).
        assert_eq!(dir_signs(&q, &live), [false, true, false]);
        assert_eq!(dir_signs(&q[1..], &live[1..]), [false, false, true]);
    }

    #[test]
    fn queue_and_result_bookkeeping() {
        let mut q = CandidateQueue::new();
        assert!(q.is_empty() && q.leaf().is_none());
        for d in 0..MAX_CANDIDATES as u32 {
            assert!(q.push(Candidate {
                depth: d,
                ..Candidate::NONE
            }));
        }
        assert!(!q.push(Candidate::NONE));
        assert_eq!(q.len(), MAX_CANDIDATES);
        assert_eq!(q.pop().unwrap().depth, MAX_ENTRY_DEPTH as u32);
        q.bail(7, Aabb::EMPTY);
        assert_eq!(q.as_slice().len(), 1);
        assert_eq!(q.leaf().unwrap().node, 7);
        let r = EntryResult::from_phases(&CandidateQueue::new(), None);
        assert_eq!(r.entry, None);
        assert_eq!(MAX_ENTRY_DEPTH, 48);
    }
}
