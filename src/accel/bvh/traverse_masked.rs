//! Masked traversal of large ray packets (Overbeck, Ramamoorthi, Mark 2008,
//! section 3.1, Figure 2; Wald et al. 2001, Reshetov et al. 2005).
//!
//! The packet `R` is `rays.len()` SIMD rays (2x2 `Ray4` quads, `R[i]` =
//! quad `i`), at most 256 (32 x 32 rays) at a time. At each cell, the
//! frustum test first (section 4), then every quad is tested against the
//! cell's box in order; at an inner cell the first quad that hits sends the
//! whole packet down (near child first, far child pushed), at a leaf all
//! quads are tested and the mask `rayMasks[i]` decides which quads are
//! tested against the leaf's (unculled) triangles.
//!
//! What the three large-packet traversals share (the paper presents Ranged
//! and Partition as changes to Figure 2) is in `packet.rs`: `Packet`
//! (per-quad slab data, triangle-test precomputation, live lanes, frustum,
//! in the thread slot's scratch) and the dispatch of inputs to packet
//! classes; this file holds their exactness harness (`tests`).
//!
//! # Exactness
//! A quad is *alive* in a box when one of its live lanes overlaps the box
//! within `[tmin, min(tmax, best.t)]` (inclusive, the single-ray slab test
//! lane by lane, with that lane's current nearest hit). A lane's nearest
//! triangle lies in boxes that test alive for it whatever has been found
//! before, frusta cull only what no ray hits (see `frustum`), and every lane
//! keeps its nearest hit by the tie rule, so the result equals
//! `traverse_single` bitwise, whatever the visiting order. The same holds
//! from an entry point (`entry`, an MLRTA or AEPSA search's node, see
//! `bvh::entry`): every triangle a live lane hits lies in its subtree.
//!
//! # Deviations
//! - Lanes, not only quads: an active but invalid ray (`Ray::is_valid`) is a
//!   miss and takes no part; a quad whose lanes are all inactive, invalid or
//!   (for occlusion) done is dead without a test.
//! - Near/far child by the sign of the packet's direction sum on the split
//!   axis (the paper leaves `nearChild(R)` unspecified).
//! - Occlusion: a lane with any hit is done; traversal ends when all are.
//! - A leaf's quads are tested against its triangles in all their live
//!   lanes (the paper's SIMD ray is the unit); a lane's hit is kept even if
//!   the lane itself missed the leaf's box (it is a true hit, and the
//!   nearest of a superset is the same).
//!
//! # Fallbacks (`accel::fallback`)
//! - Lanes with tiny directions (`fallback::tiny`) never reach these
//!   traversals: the trace call (`trace::scene::Tracing`, with
//!   `accel::packet::quieted`) traces them with
//!   the 4-wide single ray (`traverse_wide`, `Accel::fastest`) and the packet on quads where they are replaced
//!   (their subnormal arithmetic slows every quad holding one).
//! - Every packet of the three traversals is checked by
//!   `fallback::coherent` after its setup; an incoherent one (directions
//!   over more than a 30 degree cone, origins over a quarter of the scene)
//!   is traced lane by lane by the 4-wide single ray (`packet::alone`).
//! - Masked traversal counts its box tests of quads with live lanes that
//!   find them dead and alive (`fallback::Waste`); after a leaf, once more
//!   than `fallback::MAX_DEAD_PER_ALIVE` tests per alive one were wasted,
//!   the subtrees left on its stack are walked by Partition traversal
//!   (`to_partition`; section 5.2.1: Masked and Ranged traversal reach a
//!   breaking point as coherence degrades, Partition traversal is robust to
//!   it; "Masked traversal is superseded"). Ranged traversal does not
//!   switch (see `traverse_ranged`).
//!
//! # Counters
//! `rays` (valid active lanes), `packets` (per packet of at most 256
//! quads), `aabb_at` one per quad-box test, `tri_at` the live lanes of each
//! quad-triangle test, `culled_nodes` / `culled` for frustum rejections,
//! `packets_no_cull` when culling is on but no frustum could be built.

use super::packet::{Packet, Walk};
use super::traverse_partition::{Partition, Subtree};
use super::{BvhView, MAX_DEPTH, TriangleTest};
use crate::accel::fallback;
use crate::accel::slot::Slot;
use crate::counters::Counters;
use crate::geom::{Hit4, Ray4, Wide};

/// Most quads traced as one packet (32 x 32 rays), for every family.
pub use crate::accel::packet::MAX_QUADS;

/// The switch of Masked traversal to Partition traversal
/// (`trace::fallback`): the subtrees still on the stack (`pending`, next
/// first: node, depth, first quad that may be alive there), each walked by
/// Partition with the live quads from that first one. Every pending node
/// is one the packet would have visited, and Partition is exact from any
/// node, so the result is the same.
// Inlined into the lane width's `#[target_feature]` function, like every
// lane-generic helper (`isa::z16`'s intrinsics are single instructions
// only there).
#[inline(always)]
pub(crate) fn to_partition<L: Wide, T: TriangleTest, const ANY: bool>(
    p: &mut Packet<'_, T>,
    b: &BvhView<'_>,
    rays: &[Ray4],
    hits: &mut [Hit4],
    pending: impl Iterator<Item = (usize, usize, usize)>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    fallback::record(0);
    // One index list for every subtree: each walk refills it.
    let (idx, _) = slot.split(p.nq, 0u16);
    for (node, depth, first) in pending {
        let from = Subtree { node, depth, first };
        Partition::walk_from::<L, T, ANY>(p, b, rays, hits, from, idx, ctr);
        if ANY && p.done() {
            return;
        }
    }
}

/// Figure 2.
pub(crate) struct Masked;

impl Walk for Masked {
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
        // rayMasks: which quads are alive in the current leaf (given back
        // to the slot before a switch to Partition).
        let (grp, mut slot) = p.groups::<L>(rays, slot);
        let (masks, _) = slot.split(nq, false);
        let mut st_node = [0u32; MAX_DEPTH + 1];
        let mut st_depth = [0u8; MAX_DEPTH + 1];
        let mut sp = 0usize;
        let (mut node, mut depth) = start;
        // Box tests of quads with live lanes, and how many found them alive
        // (the switch to Partition, `fallback::Waste`).
        let mut waste = fallback::Waste::new(nq, p.fallbacks);
        loop {
            let n = &nodes[node];
            let leaf = n.is_leaf();
            let mut any_hit = false;
            if p.frustum_admits(n, ctr) {
                for (q, mq) in masks.iter_mut().enumerate() {
                    let m = p.alive(q, n, depth, ctr).any();
                    *mq = m;
                    waste.tested(p.live[q].any(), m);
                    if m {
                        any_hit = true;
                        if !leaf {
                            break;
                        }
                    }
                }
            }
            if any_hit {
                if !leaf {
                    let (near, far) = p.children(n);
                    st_node[sp] = far as u32;
                    st_depth[sp] = (depth + 1) as u8;
                    sp += 1;
                    node = near;
                    depth += 1;
                    continue;
                }
                let first = n.first as usize;
                for i in first..first + n.count() as usize {
                    if p.frustum_culls(b, i, ctr) {
                        continue;
                    }
                    let id = b.tri_ids[i];
                    // Aligned groups of `L::G` quads, those with masks set.
                    for (g, ms) in masks.chunks(L::G).enumerate() {
                        let mut sel = 0u32;
                        for (k, &m) in ms.iter().enumerate() {
                            sel |= u32::from(m) << k;
                        }
                        if sel != 0 {
                            p.test_group::<L, ANY>(b, hits, &grp[g], g, sel, i, id, depth, ctr);
                        }
                    }
                }
                if ANY && p.done() {
                    return;
                }
                if waste.too_high() {
                    let pending = (0..sp)
                        .rev()
                        .map(|k| (st_node[k] as usize, st_depth[k] as usize, 0));
                    return to_partition::<L, T, ANY>(p, b, rays, hits, pending, &mut slot, ctr);
                }
            }
            if sp == 0 {
                return;
            }
            sp -= 1;
            node = st_node[sp] as usize;
            depth = st_depth[sp] as usize;
        }
    }
}

/// The packet-exactness harness of the three large-packet traversals:
/// packets of every kind and size against `traverse_single`, lane by lane.
#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::accel::bvh::build::build;
    use crate::accel::bvh::build::testutil::Store;
    use crate::accel::bvh::packet::dispatch_at as dispatch;
    use crate::accel::bvh::packet::{PacketIn, TestWalk};
    use crate::accel::bvh::traverse_single;
    use crate::accel::bvh::{BvhParams, RayKind};
    use crate::accel::entry::EntryPoint;
    use crate::accel::mailbox::Mailbox;
    use crate::accel::method::BvhOptions;
    use crate::accel::method::TraceParams;
    use crate::accel::slot::Slot;
    pub use crate::accel::testkit::{RaySet, built, camera, lattice, packets, ray_sets, same};
    use crate::counters::DEPTH_BINS;
    use crate::geom::M4;
    use crate::geom::{Hit, INVALID_ID, Mt, Pt, Ray, Scene, TriTest, Wt};
    use crate::mem::Scratch;
    use glam::Vec3;

    const SENTINEL: Hit = Hit {
        t: -7.0,
        prim: 0xdead,
        u: 3.0,
        v: 4.0,
    };

    /// Where a checked packet starts: what an entry-point search decided.
    #[derive(Clone, Copy, Debug)]
    pub enum Start {
        Root,
        At(EntryPoint),
        /// No entry point: the packet is not traced, its active lanes miss.
        Miss,
    }

    /// An entry-point search per packet: `(tree, quads, active, options)`.
    pub type Search<'s> = &'s dyn Fn(&BvhView<'_>, &[Ray4], &[M4], &TraceParams) -> Start;

    /// What a checked packet's lanes must answer: `reference(quad, lane)`,
    /// the single ray's hit, and `what()`, the case named in a failure.
    pub struct Expect<'a> {
        pub reference: &'a dyn Fn(usize, usize) -> Hit,
        pub what: &'a dyn Fn() -> String,
    }

    /// Trace `quads` (a packet, or several concatenated) with traversal `W`
    /// from `start` and compare every lane with `traverse_single`; returns
    /// the counters.
    pub fn check_packet<W: TestWalk, T: TriangleTest>(
        b: &BvhView<'_>,
        quads: &[Ray4],
        active: &[M4],
        opt: &TraceParams,
        start: Start,
        any: bool,
        expect: Expect<'_>,
    ) -> Counters {
        let Expect { reference, what } = expect;
        let mut fill = Hit4::MISS;
        for i in 0..4 {
            fill.set_lane(i, SENTINEL);
        }
        let mut hits = vec![fill; quads.len()];
        let mut ctr = Counters::default();
        let entry = match &start {
            Start::Root => None,
            Start::At(e) => Some(e),
            Start::Miss => {
                // What the trace layer does: every active lane misses.
                for (h, m) in hits.iter_mut().zip(active) {
                    for i in 0..4 {
                        if m.test(i) {
                            h.set_lane(i, Hit::MISS);
                        }
                    }
                }
                None
            }
        };
        let traced = !matches!(start, Start::Miss);
        // Exactly the scratch `bvh::scratch` promises, misaligned: a
        // packet taking more panics. One buffer per thread: zeroing a new
        // one per packet was a quarter of these tests' time.
        thread_local! {
            static RAW: core::cell::RefCell<Vec<u8>> = core::cell::RefCell::new(vec![
                0u8;
                crate::accel::bvh::scratch(crate::accel::packet::MAX_QUADS) + 1
            ]);
        }
        RAW.with_borrow_mut(|raw| {
            let mut pk = 0;
            let mut slot = Slot::new(Mailbox::new(&mut [], &mut pk), Scratch::new(&mut raw[1..]));
            let s = &mut slot;
            if traced && any {
                let pk = PacketIn {
                    rays: quads,
                    active,
                    hits: &mut hits,
                };
                dispatch::<W, T, true>(b, pk, opt, entry, s, &mut ctr);
            } else if traced {
                let pk = PacketIn {
                    rays: quads,
                    active,
                    hits: &mut hits,
                };
                dispatch::<W, T, false>(b, pk, opt, entry, s, &mut ctr);
            }
        });
        let mut valid = 0;
        for (q, (h, m)) in hits.iter().zip(active).enumerate() {
            for i in 0..4 {
                let got = h.lane(i);
                if !m.test(i) {
                    assert!(
                        same(&got, &SENTINEL),
                        "{}: inactive lane {q}.{i} written",
                        what()
                    );
                    continue;
                }
                let ray = quads[q].lane(i);
                valid += ray.is_valid() as u64;
                let want = reference(q, i);
                if any {
                    assert_eq!(
                        got.is_hit(),
                        want.is_hit(),
                        "{}: quad {q} lane {i} {ray:?} occluded",
                        what()
                    );
                    if got.is_hit() {
                        assert!(
                            got.t >= ray.tmin
                                && got.t < ray.tmax
                                && b.slot_of[got.prim as usize] != INVALID_ID
                        );
                    } else {
                        assert!(same(&got, &Hit::MISS));
                    }
                } else {
                    assert!(
                        same(&got, &want),
                        "{}: quad {q} lane {i} {ray:?}: packet {got:?} single {want:?}",
                        what()
                    );
                }
            }
        }
        if !traced {
            return ctr;
        }
        assert_eq!(ctr.rays, valid, "{}", what());
        assert_eq!(
            ctr.packets,
            quads.len().div_ceil(MAX_QUADS) as u64,
            "{}",
            what()
        );
        ctr
    }

    /// Every set at every packet side, culling on and off, every kind of
    /// the set, nearest hit and occlusion; then the whole image as one input
    /// (chunks of 256 quads) and a 3-quad packet.
    pub fn check_sets<W: TestWalk, T: TriangleTest>(
        name: &str,
        b: &BvhView<'_>,
        sets: &[RaySet],
    ) -> Counters {
        check_sets_from::<W, T>(name, b, sets, &|_, _, _, _| Start::Root)
    }

    /// `check_sets` with every packet (and every whole input) started
    /// where `search` says.
    pub fn check_sets_from<W: TestWalk, T: TriangleTest>(
        name: &str,
        b: &BvhView<'_>,
        sets: &[RaySet],
        search: Search<'_>,
    ) -> Counters {
        let mut total = Counters::default();
        for set in sets {
            let mut c1 = Counters::default();
            let near: Vec<Hit> = set
                .rays
                .iter()
                .map(|r| {
                    r.map_or(Hit::MISS, |r| {
                        traverse_single::intersect::<T>(b, &r, &mut c1)
                    })
                })
                .collect();
            let occl: Vec<bool> = set
                .rays
                .iter()
                .map(|r| r.is_some_and(|r| traverse_single::occluded::<T>(b, &r, &mut c1)))
                .collect();
            let reference = |pix: &[[Option<usize>; 4]], q: usize, i: usize, any: bool| {
                let at = pix[q][i].unwrap();
                if any {
                    if occl[at] {
                        Hit {
                            t: 0.0,
                            prim: 0,
                            u: 0.0,
                            v: 0.0,
                        }
                    } else {
                        Hit::MISS
                    }
                } else {
                    near[at]
                }
            };
            for n in [2u32, 4, 8, 16, 32] {
                for (quads, active, pix) in packets(set, n) {
                    for any in [false, true] {
                        for culling in [true, false] {
                            for &kind in set.kinds {
                                let opt = TraceParams::with_bvh(BvhOptions { culling, kind });
                                let start = search(b, &quads, &active, &opt);
                                let what = || {
                                    format!(
                                        "{name} {} n={n} {opt:?} any={any} ({:?}) from {start:?}",
                                        set.name,
                                        T::KIND
                                    )
                                };
                                let c = check_packet::<W, T>(
                                    b,
                                    &quads,
                                    &active,
                                    &opt,
                                    start,
                                    any,
                                    Expect {
                                        reference: &|q, i| reference(&pix, q, i, any),
                                        what: &what,
                                    },
                                );
                                total.add(&c);
                            }
                        }
                    }
                }
            }
            let (mut quads, mut active, mut pix) = (vec![], vec![], vec![]);
            for (q, a, p) in packets(set, 2) {
                quads.extend(q);
                active.extend(a);
                pix.extend(p);
            }
            for (s, e) in [(0, quads.len()), (5, 8)] {
                for any in [false, true] {
                    let opt = TraceParams::with_bvh(BvhOptions {
                        culling: true,
                        kind: set.kinds[0],
                    });
                    let start = search(b, &quads[s..e], &active[s..e], &opt);
                    let what = || {
                        format!(
                            "{name} {} quads {s}..{e} any={any} ({:?}) from {start:?}",
                            set.name,
                            T::KIND
                        )
                    };
                    check_packet::<W, T>(
                        b,
                        &quads[s..e],
                        &active[s..e],
                        &opt,
                        start,
                        any,
                        Expect {
                            reference: &|q, i| reference(&pix, s + q, i, any),
                            what: &what,
                        },
                    );
                }
            }
        }
        total
    }

    /// `check_sets` over the ray sets of every view of a scene.
    pub fn check_scene<W: TestWalk, T: TriangleTest>(
        name: &str,
        v: &[f32],
        ix: &[u32],
        views: &[crate::scenes::View],
        light: Vec3,
        leaf: u32,
    ) -> Counters {
        let mut st = Store::new(0, false);
        let bvh = built::<T>(&mut st, v, ix, leaf);
        let b = bvh.view().unwrap();
        let mut total = Counters::default();
        for (vi, view) in views.iter().enumerate() {
            let sets = ray_sets::<T>(
                &b,
                view,
                light,
                80,
                72,
                0x1234_5678 ^ (vi as u64) << 20 ^ ix.len() as u64,
            );
            total.add(&check_sets::<W, T>(&format!("{name} view {vi}"), &b, &sets));
        }
        total
    }

    pub fn check_lattice<W: TestWalk>() {
        let (v, ix, sets) = lattice();
        for leaf in [1, 4] {
            let mut st = Store::new(0, false);
            let bvh = built::<Wt>(&mut st, &v, &ix, leaf);
            let c = check_sets::<W, Wt>("lattice", &bvh.view().unwrap(), &sets);
            if cfg!(feature = "counters") {
                assert!(c.culled_nodes > 0 && c.culled > 0, "{c:?}");
            }
            let mut st = Store::new(0, false);
            let bvh = built::<Mt>(&mut st, &v, &ix, leaf);
            check_sets::<W, Mt>("lattice", &bvh.view().unwrap(), &sets);
        }
    }

    /// `check_scene` for every built-in scene with Moller-Trumbore and
    /// watertight tests (and the projection test on one scene), on the
    /// scene's first view (tests/exact/bvh_exact.rs checks every view, through
    /// the trace calls, at every lane width).
    pub fn check_builtin<W: TestWalk>(scenes: &[&str]) {
        for &name in scenes {
            let s = crate::scenes::builtin(name).unwrap();
            let views = &s.views[..1];
            let c =
                check_scene::<W, Mt>(name, &s.mesh.vertices, &s.mesh.indices, views, s.light, 4);
            if cfg!(feature = "counters") {
                assert!(
                    c.culled_nodes > 0 && c.culled > 0 && c.tri_tests > 0,
                    "{name}: {c:?}"
                );
            }
            check_scene::<W, Wt>(name, &s.mesh.vertices, &s.mesh.indices, views, s.light, 2);
            if name == "tetra" {
                check_scene::<W, Pt>(name, &s.mesh.vertices, &s.mesh.indices, views, s.light, 8);
            }
        }
    }

    /// Degenerate inputs: an empty BVH, coincident triangles (ties).
    pub fn check_edge_cases<W: TestWalk>() {
        let view = crate::scenes::View {
            eye: Vec3::new(0.3, 0.2, 3.0),
            look_at: Vec3::new(0.3, 0.2, 0.0),
            up: Vec3::Y,
            fov_y_deg: 40.0,
        };
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let mut tris = vec![t; 60];
        tris.extend(vec![
            [[0.0, 0.0, 0.5], [1.0, 0.0, 0.5], [0.0, 1.0, 0.5]];
            30
        ]);
        tris.reverse();
        let (v, ix) = crate::accel::bvh::build::testutil::soup(&tris);
        for leaf in [1, 3] {
            check_scene::<W, Mt>("ties", &v, &ix, &[view], Vec3::new(0.2, 0.2, 4.0), leaf);
            check_scene::<W, Wt>("ties", &v, &ix, &[view], Vec3::new(0.2, 0.2, 4.0), leaf);
        }
        check_scene::<W, Mt>("empty", &[], &[], &[view], Vec3::ONE, 4);
        // A BVH at the depth limit (leaves at MAX_DEPTH), rays from the
        // origin down the whole chain: the stacks must hold.
        let (v, ix) = crate::accel::bvh::build::testutil::soup(
            &crate::accel::bvh::build::testutil::deep_tris(),
        );
        let scene = Scene::from_f32(&v, &ix).unwrap();
        let mut st = Store::new(scene.triangle_count() as usize, false);
        let mut bvh = st.bvh();
        build(
            &mut bvh,
            &scene,
            &BvhParams {
                leaf_size: 1,
                bins: 2,
                traversal_cost: 1.0,
                test: TriTest::Watertight,
                quality: crate::accel::bvh::BuildQuality::Medium,
                width: 4,
                presplit: false,
            },
        )
        .unwrap();
        let b = bvh.view().unwrap();
        assert!(b.info.depth as usize >= MAX_DEPTH - 8, "{:?}", b.info);
        let (w, h) = (32u32, 32u32);
        let grid = |x: u32, y: u32| {
            Vec3::new(
                1.0,
                0.001 + 0.008 * x as f32 / w as f32,
                0.001 + 0.008 * y as f32 / h as f32,
            )
        };
        let rays: Vec<Option<Ray>> = (0..h)
            .flat_map(|y| {
                (0..w).map(move |x| Some(Ray::new(Vec3::ZERO, grid(x, y), 0.0, f32::INFINITY)))
            })
            .collect();
        let far: Vec<Option<Ray>> = (0..h)
            .flat_map(|y| (0..w).map(move |x| Some(Ray::new(Vec3::ZERO, grid(x, y), 1e3, 1e8))))
            .collect();
        // Whole 2x2 quads of active but invalid rays (tmin > tmax) among
        // valid ones, as a shadow batch's inactive slots: the setup pass
        // skips such quads.
        let holes: Vec<Option<Ray>> = (0..h)
            .flat_map(|y| {
                (0..w).map(move |x| {
                    let (lo, hi) = if (x / 2 + y / 2) % 3 == 0 {
                        (2.0, 1.0)
                    } else {
                        (0.0, f32::INFINITY)
                    };
                    Some(Ray::new(Vec3::ZERO, grid(x, y), lo, hi))
                })
            })
            .collect();
        let sets = [
            RaySet {
                name: "deep-holes",
                w,
                h,
                rays: holes,
                kinds: &[RayKind::Primary, RayKind::Shadow],
            },
            RaySet {
                name: "deep",
                w,
                h,
                rays,
                kinds: &[RayKind::Primary, RayKind::Secondary],
            },
            RaySet {
                name: "deep-far",
                w,
                h,
                rays: far,
                kinds: &[RayKind::Shadow],
            },
        ];
        let c = check_sets::<W, Wt>("deep", &b, &sets);
        assert!(
            !cfg!(feature = "counters") || c.tri_by_depth[DEPTH_BINS - 1] > 0,
            "{c:?}"
        );
    }

    /// Release-mode throughput of 16 x 16 primary packets, culling on and
    /// off, with the test counts (`cargo test --release --lib
    /// bvh::traverse_masked::tests::packet_speed -- --ignored --nocapture`;
    /// build with `--no-default-features --features std` to time without
    /// counters). Scenes: built-in `balls` (SPD view) and the OBJ
    /// `conference` of ../shared/scenes (inside view), if present.
    #[test]
    #[ignore]
    fn packet_speed() {
        use crate::accel::bvh::traverse_partition::Partition;
        use crate::accel::bvh::traverse_ranged::Ranged;
        use crate::accel::bvh::traverse_simd;
        use crate::accel::slot::SlotBuf;
        use std::time::Instant;
        fn packet_in<'x>(rays: &'x [Ray4], active: &'x [M4], hits: &'x mut [Hit4]) -> PacketIn<'x> {
            PacketIn { rays, active, hits }
        }
        let mut scenes: Vec<(String, Vec<f32>, Vec<u32>, crate::scenes::View)> = Vec::new();
        let s = crate::scenes::builtin("balls").unwrap();
        scenes.push((
            "balls".into(),
            s.mesh.vertices.clone(),
            s.mesh.indices.clone(),
            s.views[0],
        ));
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../shared/scenes/conference/conference.obj"
        );
        let opts = tobj::LoadOptions {
            triangulate: true,
            single_index: false,
            ..Default::default()
        };
        if let Ok((models, _)) = tobj::load_obj(path, &opts) {
            let (mut v, mut ix) = (Vec::new(), Vec::new());
            for m in models {
                let base = (v.len() / 3) as u32;
                v.extend_from_slice(&m.mesh.positions);
                ix.extend(m.mesh.indices.iter().map(|i| i + base));
            }
            let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
            for p in v.chunks_exact(3) {
                lo = lo.min(Vec3::from_slice(p));
                hi = hi.max(Vec3::from_slice(p));
            }
            let c = 0.5 * (lo + hi);
            let view = crate::scenes::View {
                eye: c + Vec3::new(0.07, 0.03, -0.05) * (hi - lo),
                look_at: hi * 0.8 + lo * 0.2,
                up: Vec3::Y,
                fov_y_deg: 70.0,
            };
            scenes.push(("conference".into(), v, ix, view));
        } else {
            println!("note: {path} not loaded");
        }
        let (w, h, side) = (1024u32, 1024u32, 16u32);
        println!(
            "{w}x{h} primary rays, {side}x{side} packets, Moller-Trumbore, one thread; per ray: box tests, triangle tests (lanes), culled nodes / triangles per packet"
        );
        println!(
            "| scene | method | culling | Mrays/s | aabb/ray | tri/ray | culled nodes/pkt | culled tris/pkt | no-cull pkts |"
        );
        println!("|---|---|---|---|---|---|---|---|---|");
        for (name, v, ix, view) in &scenes {
            let mut st = Store::new(0, false);
            let bvh = built::<Mt>(&mut st, v, ix, 4);
            let b = bvh.view().unwrap();
            let pr = camera(view, w, h);
            let set = RaySet {
                name: "primary",
                w,
                h,
                rays: (0..h)
                    .flat_map(|y| (0..w).map(move |x| (x, y)))
                    .map(|(x, y)| Some(pr.ray(x, y)))
                    .collect(),
                kinds: &[RayKind::Primary],
            };
            let pk = packets(&set, side);
            let mut hits: Vec<Vec<Hit4>> = pk
                .iter()
                .map(|(q, _, _)| vec![Hit4::MISS; q.len()])
                .collect();
            let rays = (w * h) as f64;
            type Trace<'t> = Box<dyn FnMut(&[Ray4], &[M4], &mut [Hit4], &mut Counters) + 't>;
            let (b, pk) = (&b, &pk);
            let opt = |culling| {
                TraceParams::with_bvh(BvhOptions {
                    culling,
                    kind: RayKind::Primary,
                })
            };
            let mut runs: Vec<(&str, &str, Trace<'_>)> = vec![
                (
                    "bvh-single",
                    "-",
                    Box::new(move |q, a, hs, c| {
                        for (k, (r, m)) in q.iter().zip(a).enumerate() {
                            for i in 0..4 {
                                if m.test(i) {
                                    hs[k].set_lane(
                                        i,
                                        traverse_single::intersect::<Mt>(b, &r.lane(i), c),
                                    );
                                }
                            }
                        }
                    }),
                ),
                (
                    "bvh-simd (2x2)",
                    "-",
                    Box::new(move |q, a, hs, c| {
                        traverse_simd::intersect::<Mt>(b, q, a, hs, true, c)
                    }),
                ),
            ];
            for (culling, cs) in [(false, "off"), (true, "on")] {
                let o = opt(culling);
                runs.push((
                    "masked",
                    cs,
                    Box::new({
                        let mut own = SlotBuf::new(0);
                        move |q, a, hs, c| {
                            dispatch::<Masked, Mt, false>(
                                b,
                                packet_in(q, a, hs),
                                &o,
                                None,
                                &mut own.slot(),
                                c,
                            )
                        }
                    }),
                ));
                runs.push((
                    "ranged",
                    cs,
                    Box::new({
                        let mut own = SlotBuf::new(0);
                        move |q, a, hs, c| {
                            dispatch::<Ranged, Mt, false>(
                                b,
                                packet_in(q, a, hs),
                                &o,
                                None,
                                &mut own.slot(),
                                c,
                            )
                        }
                    }),
                ));
                runs.push((
                    "partition",
                    cs,
                    Box::new({
                        let mut own = SlotBuf::new(0);
                        move |q, a, hs, c| {
                            dispatch::<Partition, Mt, false>(
                                b,
                                packet_in(q, a, hs),
                                &o,
                                None,
                                &mut own.slot(),
                                c,
                            )
                        }
                    }),
                ));
            }
            // Best of 3 passes of 3 runs each, passes interleaved over the
            // methods so a burst of load on the machine hits them alike.
            let mut best = vec![f64::INFINITY; runs.len()];
            let mut ctrs = vec![Counters::default(); runs.len()];
            for pass in 0..3 {
                for (j, (_, _, f)) in runs.iter_mut().enumerate() {
                    for rep in 0..3 {
                        let mut c = Counters::default();
                        let t0 = Instant::now();
                        for ((q, a, _), hs) in pk.iter().zip(hits.iter_mut()) {
                            f(q, a, hs, &mut c);
                        }
                        best[j] = best[j].min(t0.elapsed().as_secs_f64());
                        if pass == 0 && rep == 0 {
                            ctrs[j] = c;
                        }
                    }
                }
            }
            for (j, (method, culling, _)) in runs.iter().enumerate() {
                let ctr = &ctrs[j];
                let np = ctr.packets.max(1) as f64;
                println!(
                    "| {name} | {method} | {culling} | {:.2} | {:.2} | {:.2} | {:.1} | {:.1} | {} |",
                    rays / best[j] / 1e6,
                    ctr.aabb_tests as f64 / rays,
                    ctr.tri_tests as f64 / rays,
                    ctr.culled_nodes as f64 / np,
                    ctr.culled as f64 / np,
                    ctr.packets_no_cull
                );
            }
        }
    }

    /// The checks every large-packet walk `$W` (a `TestWalk`) runs
    /// against the single ray, written once: the built-in scenes, the
    /// edge cases, the lattice.
    macro_rules! walk_matches_single {
        ($W:ty) => {
            #[test]
            fn matches_single_tetra_gears() {
                $crate::accel::bvh::traverse_masked::tests::check_builtin::<$W>(&[
                    "tetra", "gears",
                ]);
            }

            #[test]
            fn matches_single_balls_animated() {
                $crate::accel::bvh::traverse_masked::tests::check_builtin::<$W>(&[
                    "balls", "animated",
                ]);
            }

            #[test]
            fn matches_single_edge_cases() {
                $crate::accel::bvh::traverse_masked::tests::check_edge_cases::<$W>();
            }

            #[test]
            fn matches_single_lattice() {
                $crate::accel::bvh::traverse_masked::tests::check_lattice::<$W>();
            }
        };
    }
    pub(crate) use walk_matches_single;

    walk_matches_single!(Masked);
}
