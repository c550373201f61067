//! kd-tree packet traversals are exact: the 2x2 SIMD ray and the n x n
//! frustum packets at every packet side, from the root and from the entry
//! points MLRTA and AEPSA find, with and without frustum culling, return the
//! same triangle and bitwise the same t (the same occlusion answer) as the
//! single-ray kd traversal, lane by lane, for primary, shadow, reflection and
//! refraction rays on every scene and view (AEPSA paper sections 2-3). The
//! BVH packets with entry points are checked the same way against the BVH
//! single ray.

use crate::common;

use common::{TestScene, builtin_scenes, obj_scenes, par_map};
use sheaf::accel::bvh::BvhParams;
use sheaf::accel::kd::KdParams;
use sheaf::accel::slot::SlotBuf;
use sheaf::trace::EntrySearch;

use sheaf::geom::{Hit4, M4, Ray4};
use sheaf::render::{SHADOW_OFFSET, Tracer};
use sheaf::trace::RayKind;
use sheaf::{BuildQuality, Counters, Hit, Limits, Method, OwnedContext, Ray, TraceParams, TriTest};

use common::exact::{Class, RES, check_class, check_random_packets, reference, secondary, shadow};

/// The kd methods: SIMD, and packets of every side with every entry search.
pub(crate) fn kd_cases() -> Vec<(Method, usize, EntrySearch)> {
    let mut cases = vec![(Method::KdSimd, 2, EntrySearch::None)];
    for n in [4, 8, 16, 32] {
        for &e in EntrySearch::ALL {
            cases.push((Method::KdPacket, n, e));
        }
    }
    cases
}

/// The BVH packet traversals from entry points (root starts: bvh_exact.rs).
fn bvh_entry_cases() -> Vec<(Method, usize, EntrySearch)> {
    let mut cases = Vec::new();
    for m in [Method::BvhMasked, Method::BvhRanged, Method::BvhPartition] {
        for n in [8, 16] {
            cases.push((m, n, EntrySearch::Mlrta));
            cases.push((m, n, EntrySearch::Aepsa));
        }
    }
    cases
}

/// Each scene with each kd build, each build with a triangle test: the
/// items the suites spread over the cores (independent checks). The
/// default binned tree (`Low`) and the exact one take both tests.
fn with_tests(scenes: &[TestScene]) -> Vec<(&TestScene, TriTest, BuildQuality)> {
    use BuildQuality::{High, Low, Medium};
    use TriTest::{MollerTrumbore as Mt, Watertight as Wt};
    let items = [(Mt, Low), (Wt, High), (Wt, Low), (Mt, Medium)];
    scenes
        .iter()
        .flat_map(|s| items.map(|(t, q)| (s, t, q)))
        .collect()
}

fn check_scene(&(s, test, quality): &(&TestScene, TriTest, BuildQuality)) {
    {
        let mut l = Limits::for_triangles(s.triangles());
        l.max_vertices = (s.vertices.len() / 3) as u32;
        l.structures = Limits::KD | Limits::BVH;
        let mut ctx = OwnedContext::new(&l).unwrap();
        let info = ctx
            .build_kd(
                &s.scene(),
                &KdParams {
                    test,
                    quality,
                    ..KdParams::default()
                },
            )
            .unwrap();
        ctx.build_bvh(
            &s.scene(),
            &BvhParams {
                test,
                ..BvhParams::default()
            },
        )
        .unwrap();
        let all = ctx.tracer().unwrap();
        let (tr, bvh) = (all.kd().unwrap(), all.bvh().unwrap());
        // The BVH's entry cases once per test (with the default kd tree).
        let bvh_cases = if quality == BuildQuality::Low {
            bvh_entry_cases()
        } else {
            Vec::new()
        };
        let kd_cases = kd_cases();
        let eps = SHADOW_OFFSET * info.bounds.diagonal().length();
        let mut sum = Counters::default();
        for (vname, view) in &s.views {
            let what = format!("{} {vname} {test:?} {quality:?}", s.name);
            let rays = view.rays(RES as u32, RES as u32);
            let all = vec![true; rays.len()];
            let primary = Class {
                name: "primary",
                rays: rays.clone(),
                active: all,
                kind: RayKind::Primary,
                any: false,
            };
            sum.add(&check_class(&tr, &kd_cases, &what, &primary));
            if !bvh_cases.is_empty() {
                check_class(&bvh, &bvh_cases, &what, &primary);
            }
            let hits = reference(&tr, &primary);
            // Shadow rays from the light to just off the hit surfaces.
            let shadow = shadow(&tr, &rays, &hits, s.light, eps);
            sum.add(&check_class(&tr, &kd_cases, &what, &shadow));
            if !bvh_cases.is_empty() {
                check_class(&bvh, &bvh_cases, &what, &shadow);
            }
            let (refl, refr) = secondary(&tr, &rays, &hits, eps);
            sum.add(&check_class(&tr, &kd_cases, &what, &refl));
            sum.add(&check_class(&tr, &kd_cases, &what, &refr));
        }
        println!(
            "{:>10} {test:?} {quality:?}: {} nodes, depth {}: {} packets, {} rays, {} split steps, {} triangle tests, {} nodes and {} triangles culled, {} entry searches (mean depth {:.1}, {} misses)",
            s.name,
            info.nodes,
            info.depth,
            sum.packets,
            sum.rays,
            sum.aabb_tests,
            sum.tri_tests,
            sum.culled_nodes,
            sum.culled,
            sum.entry_searches,
            sum.entry_depth_sum as f64 / sum.entry_searches.max(1) as f64,
            sum.entry_misses
        );
        if cfg!(feature = "counters") && info.triangles > 100 {
            assert!(
                sum.culled_nodes > 0
                    && sum.culled > 0
                    && sum.entry_searches > 0
                    && sum.entry_depth_sum > 0,
                "{}: frustum culling must be exercised",
                s.name
            );
        }
    }
}

#[test]
fn builtin_scenes_every_packet_method_equals_the_single_ray() {
    par_map(&with_tests(&builtin_scenes()), check_scene);
}

#[test]
fn obj_scenes_every_packet_method_equals_the_single_ray() {
    let scenes = obj_scenes();
    if scenes.is_empty() {
        eprintln!("note: no OBJ scenes: skipped");
    }
    par_map(&with_tests(&scenes), check_scene);
}

/// Incoherent packets: random directions (mixed signs), scattered origins,
/// some lanes inactive, some invalid (NaN, zero direction).
#[test]
fn random_packets_equal_the_single_ray() {
    let s = &builtin_scenes()[1];
    let mut l = Limits::for_triangles(s.triangles());
    l.structures = Limits::KD;
    let mut ctx = OwnedContext::new(&l).unwrap();
    let info = ctx.build_kd(&s.scene(), &KdParams::default()).unwrap();
    let tr = ctx.tracer().unwrap().kd().unwrap();
    check_random_packets(&tr, &kd_cases(), &s.name, &info.bounds);
}

/// The context's calls: `trace_with` gives the single ray's answers for
/// every kd method and entry search, `occluded_with` the single ray's
/// occlusion, and a capacity error leaves the kd-tree as it was.
#[test]
fn context_calls_and_failed_builds() {
    let s = &builtin_scenes()[2];
    let mut l = Limits::for_triangles(s.triangles());
    l.max_vertices = (s.vertices.len() / 3) as u32;
    l.structures = Limits::KD;
    let mut ctx = OwnedContext::new(&l).unwrap();
    assert_eq!(
        ctx.trace(Method::KdSingle, &[], &mut []).unwrap_err(),
        sheaf::Error::NotBuilt
    );
    let info = ctx.build_kd(&s.scene(), &KdParams::default()).unwrap();
    assert!(
        ctx.build_bvh(&s.scene(), &BvhParams::default()).is_err(),
        "no BVH pools"
    );
    let rays = s.views[0].1.rays(32, 32);
    let mut hits = vec![Hit::MISS; rays.len()];
    let mut want = vec![Hit::MISS; rays.len()];
    ctx.trace(Method::KdSingle, &rays, &mut want).unwrap();
    assert!(want.iter().any(|h| h.is_hit()));
    let mut occ_want = vec![false; rays.len()];
    let shadow: Vec<Ray> = rays.iter().map(|r| Ray { tmax: 0.9, ..*r }).collect();
    ctx.occluded(Method::KdSingle, &shadow, &mut occ_want)
        .unwrap();
    for (m, n, e) in kd_cases() {
        let p = TraceParams {
            method: m,
            packet: n as u32,
            entry: e,
            ..TraceParams::default()
        };
        ctx.trace_with(&p, &rays, &mut hits).unwrap();
        assert_eq!(hits, want, "{} {n} {e:?}", m.name());
        let mut occ = vec![false; rays.len()];
        ctx.occluded_with(&p, &shadow, &mut occ).unwrap();
        assert_eq!(occ, occ_want, "{} {n} {e:?} occluded", m.name());
    }
    // Too many triangles: the previous kd-tree stays and traces the same.
    let big: Vec<u32> = (0..(l.max_triangles + 1) * 3).map(|i| i % 3).collect();
    let verts = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    let too_big = sheaf::Scene::from_f32(&verts, &big).unwrap();
    assert!(ctx.build_kd(&too_big, &KdParams::default()).is_err());
    assert_eq!(ctx.stats().kd, info);
    ctx.trace(Method::KdSingle, &rays, &mut hits).unwrap();
    assert_eq!(hits, want);
}

/// Occlusion packets write exactly their active lanes, quad by quad: lanes
/// of a later quad follow that quad's mask, not the first one's, and
/// inactive lanes keep what the caller had there.
#[test]
fn occluded_packets_write_only_active_lanes() {
    let s = &builtin_scenes()[0];
    let mut l = Limits::for_triangles(s.triangles());
    l.max_vertices = (s.vertices.len() / 3) as u32;
    l.structures = Limits::KD;
    let mut ctx = OwnedContext::new(&l).unwrap();
    ctx.build_kd(&s.scene(), &KdParams::default()).unwrap();
    let tr = ctx.tracer().unwrap().kd().unwrap();
    let rays = s.views[0].1.rays(8, 8);
    let quads: Vec<Ray4> = rays
        .chunks(4)
        .map(|c| Ray4::from_rays(&[c[0], c[1], c[2], c[3]]))
        .collect();
    // Quad 0 has one active lane; the others alternate patterns.
    let active: Vec<M4> = (0..quads.len())
        .map(|q| {
            if q == 0 {
                M4::new(true, false, false, false)
            } else {
                M4::new(q % 2 == 0, true, q % 3 == 0, true)
            }
        })
        .collect();
    let sentinel = Hit {
        t: -1.0,
        prim: 7,
        u: 0.0,
        v: 0.0,
    };
    let mut own = SlotBuf::new(0);
    let mut slot = own.slot();
    let mut ctr = Counters::default();
    for (m, e) in [
        (Method::KdSimd, EntrySearch::None),
        (Method::KdPacket, EntrySearch::None),
        (Method::KdPacket, EntrySearch::Aepsa),
    ] {
        let p = TraceParams {
            method: m,
            packet: 8,
            entry: e,
            ..TraceParams::default()
        };
        let mut hits = vec![Hit4::MISS; quads.len()];
        for h in &mut hits {
            for i in 0..4 {
                h.set_lane(i, sentinel);
            }
        }
        tr.occluded_packet(&p, &quads, &active, &mut hits, &mut slot, &mut ctr);
        for (q, (r, a)) in quads.iter().zip(&active).enumerate() {
            for i in 0..4 {
                let got = hits[q].lane(i);
                if a.test(i) {
                    assert_eq!(
                        got.is_hit(),
                        tr.occluded(&r.lane(i), &mut ctr),
                        "{} quad {q} lane {i}",
                        m.name()
                    );
                    assert_ne!(got, sentinel);
                } else {
                    assert_eq!(
                        got,
                        sentinel,
                        "{} quad {q} lane {i}: inactive lane written",
                        m.name()
                    );
                }
            }
        }
    }
}
