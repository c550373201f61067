//! BVH packet traversals are exact: the 4-wide single ray, the 2x2 SIMD
//! ray and the Masked, Ranged and Partition traversals at every packet
//! side, with and without frustum culling, return the same triangle and
//! bitwise the same t (the same occlusion answer) as the single-ray BVH traversal, lane by lane, for
//! primary, shadow, reflection and refraction rays on every scene and view
//! (BVH paper sections 3 and 4).

use crate::common;

use common::{TestScene, builtin_scenes, obj_scenes, par_map};
use sheaf::accel::bvh::{BuildQuality, BvhParams};
use sheaf::render::SHADOW_OFFSET;
use sheaf::trace::{EntrySearch, RayKind, Tracer};
use sheaf::{Counters, Hit, Limits, Method, OwnedContext, Ray, TraceParams, TriTest};

use common::exact::{Class, RES, check_class, check_random_packets, reference, secondary, shadow};

/// The BVH packet methods from the root: SIMD, Masked, Ranged, Partition at
/// every side (entry points: kd_exact.rs).
pub(crate) fn bvh_cases() -> Vec<(Method, usize, EntrySearch)> {
    let mut cases = vec![
        (Method::BvhSimd, 2, EntrySearch::None),
        (Method::BvhWide, 2, EntrySearch::None),
    ];
    for m in [
        Method::BvhMasked,
        Method::BvhRanged,
        Method::BvhPartition,
        Method::BvhWideRanged,
        Method::BvhFrustum,
    ] {
        cases.extend([4, 8, 16, 32].map(|n| (m, n, EntrySearch::None)));
    }
    cases
}

/// Every packet method on the binned SAH tree with both triangle tests,
/// and on the fast (Morton) tree, whose single ray must also answer as the
/// SAH tree's does: the shape decides speed only. Returns whether the
/// pre-split LOW tree holds more references than triangles.
fn check_scene(s: &TestScene) -> bool {
    let mut l = Limits::for_triangles(s.triangles());
    l.max_vertices = (s.vertices.len() / 3) as u32;
    l.structures = Limits::BVH;
    let mut sah_tree = OwnedContext::new(&l).unwrap();
    let mut presplit = false;
    for (test, quality, reserve) in [
        (TriTest::MollerTrumbore, BuildQuality::Medium, true),
        (TriTest::Watertight, BuildQuality::Medium, false),
        (TriTest::Watertight, BuildQuality::Low, false),
        (TriTest::MollerTrumbore, BuildQuality::Low, true),
        (TriTest::MollerTrumbore, BuildQuality::High, true),
    ] {
        // A reserve of references: the HIGH tree's spatial splits, the
        // LOW tree's pre-split triangles (`presplit`).
        let mut l = l;
        if reserve {
            l.max_bvh_refs = l.max_triangles + l.max_triangles / 4;
        }
        let mut ctx = OwnedContext::new(&l).unwrap();
        let p = BvhParams {
            test,
            quality,
            presplit: reserve,
            ..BvhParams::default()
        };
        let info = ctx.build_bvh(&s.scene(), &p).unwrap();
        if quality == BuildQuality::Low && reserve {
            presplit = info.references > info.triangles;
        }
        if quality != BuildQuality::Medium {
            sah_tree
                .build_bvh(
                    &s.scene(),
                    &BvhParams {
                        quality: BuildQuality::Medium,
                        ..p
                    },
                )
                .unwrap();
        }
        let tr = ctx.tracer().unwrap().bvh().unwrap();
        let eps = SHADOW_OFFSET * info.bounds.diagonal().length();
        let mut sum = Counters::default();
        for (vname, view) in &s.views {
            let what = format!("{} {vname} {test:?} {quality:?}", s.name);
            let rays = view.rays(RES as u32, RES as u32);
            if quality != BuildQuality::Medium {
                let sah = sah_tree.tracer().unwrap().bvh().unwrap();
                let mut ctr = Counters::default();
                for (i, r) in rays.iter().enumerate() {
                    let (a, b) = (tr.intersect(r, &mut ctr), sah.intersect(r, &mut ctr));
                    assert!(
                        a.prim == b.prim && a.t.to_bits() == b.t.to_bits(),
                        "{what}: ray {i}: {a:?} on this tree, {b:?} on the SAH tree"
                    );
                }
            }
            let all = vec![true; rays.len()];
            let primary = Class {
                name: "primary",
                rays: rays.clone(),
                active: all,
                kind: RayKind::Primary,
                any: false,
            };
            sum.add(&check_class(&tr, &bvh_cases(), &what, &primary));
            let hits = reference(&tr, &primary);
            // Shadow rays from the light to just off the hit surfaces.
            let shadow = shadow(&tr, &rays, &hits, s.light, eps);
            sum.add(&check_class(&tr, &bvh_cases(), &what, &shadow));
            let (refl, refr) = secondary(&tr, &rays, &hits, eps);
            sum.add(&check_class(&tr, &bvh_cases(), &what, &refl));
            sum.add(&check_class(&tr, &bvh_cases(), &what, &refr));
        }
        println!(
            "{:>10} {test:?} {quality:?}: {} nodes, depth {}: {} packets, {} rays, {} box tests, {} triangle tests, {} nodes and {} triangles culled, {} packets without frustum",
            s.name,
            info.nodes,
            info.depth,
            sum.packets,
            sum.rays,
            sum.aabb_tests,
            sum.tri_tests,
            sum.culled_nodes,
            sum.culled,
            sum.packets_no_cull
        );
        if cfg!(feature = "counters") && info.triangles > 100 {
            assert!(
                sum.culled_nodes > 0 && sum.culled > 0,
                "{}: frustum culling must be exercised",
                s.name
            );
        }
    }
    presplit
}

#[test]
fn builtin_scenes_every_packet_method_equals_the_single_ray() {
    let split = par_map(&builtin_scenes(), check_scene);
    assert!(
        split.iter().any(|&s| s),
        "no built-in scene's LOW tree was pre-split"
    );
}

#[test]
fn obj_scenes_every_packet_method_equals_the_single_ray() {
    let scenes = obj_scenes();
    if scenes.is_empty() {
        eprintln!("note: no OBJ scenes: skipped");
    }
    par_map(&scenes, check_scene);
}

/// Incoherent packets: random directions (mixed signs), scattered origins,
/// some lanes inactive, some invalid (NaN, zero direction).
#[test]
fn random_packets_equal_the_single_ray() {
    let s = &builtin_scenes()[1];
    let mut l = Limits::for_triangles(s.triangles());
    l.structures = Limits::BVH;
    let mut ctx = OwnedContext::new(&l).unwrap();
    let info = ctx.build_bvh(&s.scene(), &BvhParams::default()).unwrap();
    let tr = ctx.tracer().unwrap().bvh().unwrap();
    check_random_packets(&tr, &bvh_cases(), &s.name, &info.bounds);
}

/// The context's calls: `trace_with` and `occluded_with` give the single
/// ray's answers for every BVH method, and a capacity error leaves the BVH
/// as it was.
#[test]
fn context_calls_and_failed_builds() {
    let s = &builtin_scenes()[2];
    let mut l = Limits::for_triangles(s.triangles());
    l.max_vertices = (s.vertices.len() / 3) as u32;
    let mut ctx = OwnedContext::new(&l).unwrap();
    assert_eq!(
        ctx.trace(Method::BvhSingle, &[], &mut []).unwrap_err(),
        sheaf::Error::NotBuilt
    );
    ctx.build_bvh(&s.scene(), &BvhParams::default()).unwrap();
    // A grid method without a grid is NotBuilt, not a wrong answer.
    let rays = s.views[0].1.rays(32, 32);
    let mut hits = vec![Hit::MISS; rays.len()];
    assert_eq!(
        ctx.trace(Method::GridDda, &rays, &mut hits).unwrap_err(),
        sheaf::Error::NotBuilt
    );
    let mut want = vec![Hit::MISS; rays.len()];
    ctx.trace(Method::BvhSingle, &rays, &mut want).unwrap();
    assert!(want.iter().any(|h| h.is_hit()));
    for m in [
        Method::BvhSimd,
        Method::BvhWide,
        Method::BvhMasked,
        Method::BvhRanged,
        Method::BvhPartition,
        Method::BvhWideRanged,
        Method::BvhFrustum,
    ] {
        for n in [4, 8, 16, 32] {
            ctx.trace_with(&TraceParams::bvh(m, n), &rays, &mut hits)
                .unwrap();
            assert_eq!(hits, want, "{} {n}", m.name());
        }
    }
    // Too many triangles: the previous BVH stays and traces the same.
    let big: Vec<u32> = (0..(l.max_triangles + 1) * 3).map(|i| i % 3).collect();
    let verts = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    let too_big = sheaf::Scene::from_f32(&verts, &big).unwrap();
    assert!(matches!(
        ctx.build_bvh(&too_big, &BvhParams::default()),
        Err(sheaf::Error::Capacity { .. })
    ));
    assert!(
        ctx.build_bvh(
            &s.scene(),
            &BvhParams {
                leaf_size: 0,
                ..BvhParams::default()
            }
        )
        .is_err()
    );
    ctx.trace(Method::BvhRanged, &rays, &mut hits).unwrap();
    assert_eq!(hits, want);
    // A build that fails after writing the reference pool, where the wide
    // tree lives (the projection test without its pool, at both qualities),
    // keeps the binary tree and drops the wide one: the wide methods still
    // answer `want`, and so does a refit of that tree.
    assert!(!l.projection_test);
    for quality in [BuildQuality::Medium, BuildQuality::Low] {
        let p = BvhParams {
            test: TriTest::Projection,
            quality,
            ..BvhParams::default()
        };
        assert!(ctx.build_bvh(&s.scene(), &p).is_err());
        for m in [
            Method::BvhWide,
            Method::BvhWideRanged,
            Method::BvhFrustum,
            Method::BvhRanged,
        ] {
            ctx.trace_with(&TraceParams::bvh(m, 8), &rays, &mut hits)
                .unwrap();
            assert_eq!(hits, want, "{} after a failed {quality:?} build", m.name());
        }
        ctx.refit_bvh(&s.scene(), &sheaf::RefitParams::default())
            .unwrap();
        ctx.trace_with(&TraceParams::bvh(Method::BvhWide, 8), &rays, &mut hits)
            .unwrap();
        assert_eq!(hits, want);
    }
    // A rebuild brings the wide tree back.
    let info = ctx.build_bvh(&s.scene(), &BvhParams::default()).unwrap();
    assert!(info.wide_nodes > 0);
    // No BVH pools: a clear error.
    let mut l2 = l;
    l2.structures = Limits::GRID;
    let mut grid_only = OwnedContext::new(&l2).unwrap();
    assert!(matches!(
        grid_only.build_bvh(&s.scene(), &BvhParams::default()),
        Err(sheaf::Error::InvalidArgument(_))
    ));
    assert!(sheaf::required_bytes(&l2).unwrap() < sheaf::required_bytes(&l).unwrap());
}

/// A structure left over from an older scene is never consulted: build the
/// grid and the BVH from one scene, rebuild only the grid from another, and
/// the grid's frame equals a fresh grid-only context's. And `structures`
/// must name a structure.
#[test]
fn stale_structures_do_not_shade_new_frames() {
    let scenes = builtin_scenes();
    let (a, b) = (&scenes[0], &scenes[2]);
    let n = a.triangles().max(b.triangles());
    let mut l = Limits::for_triangles(n);
    l.max_vertices = ((a.vertices.len().max(b.vertices.len())) / 3) as u32;
    let frame = sheaf::Frame {
        camera: sheaf::Camera {
            eye: b.views[0].1.eye.to_array(),
            look_at: b.views[0].1.look_at.to_array(),
            up: b.views[0].1.up.to_array(),
            fov_y_deg: 45.0,
        },
        light: sheaf::PointLight {
            position: b.light.to_array(),
            color: [1.0; 3],
            ..Default::default()
        },
        shading: sheaf::Shading::default(),
        width: 48,
        height: 32,
    };
    let mut both = OwnedContext::new(&l).unwrap();
    both.build_grid(&a.scene(), &sheaf::GridParams::default())
        .unwrap();
    both.build_bvh(&a.scene(), &BvhParams::default()).unwrap();
    both.build_grid(&b.scene(), &sheaf::GridParams::default())
        .unwrap();
    let mut fresh = OwnedContext::new(&l).unwrap();
    fresh
        .build_grid(&b.scene(), &sheaf::GridParams::default())
        .unwrap();
    let (mut got, mut want) = (vec![0u8; 48 * 32 * 4], vec![0u8; 48 * 32 * 4]);
    for m in [Method::GridDda, Method::GridCgt] {
        both.render(m, &frame, &mut got, 48 * 4).unwrap();
        fresh.render(m, &frame, &mut want, 48 * 4).unwrap();
        assert!(
            got == want,
            "{}: the old BVH shaded the new grid's hits",
            m.name()
        );
    }
    let mut none = l;
    none.structures = 0;
    assert!(matches!(
        OwnedContext::new(&none),
        Err(sheaf::Error::InvalidArgument(_))
    ));
}

/// Refit: the animated scene built at t = 0 and refit to later times. The
/// refit tree's single ray equals a fresh build's bitwise (both equal a
/// brute-force search over the same triangles), every packet method equals
/// the refit tree's single ray, bad input changes nothing, and the
/// automatic rebuild fires past its threshold.
/// A HIGH tree with spatial splits, refit to moved vertices (its clipped
/// leaf boxes become whole-triangle boxes), answers as a fresh build of
/// the moved scene, with every packet method equal to its single ray.
#[test]
fn refit_of_a_split_tree_stays_exact() {
    use sheaf::RefitParams;
    let s = builtin_scenes()
        .into_iter()
        .find(|s| s.name == "gears")
        .expect("the gears scene");
    let mut l = Limits::for_triangles(s.triangles());
    l.max_vertices = (s.vertices.len() / 3) as u32;
    l.structures = Limits::BVH;
    l.max_bvh_refs = l.max_triangles + l.max_triangles / 4;
    let (mut ctx, mut fresh) = (
        OwnedContext::new(&l).unwrap(),
        OwnedContext::new(&l).unwrap(),
    );
    let high = BvhParams {
        quality: BuildQuality::High,
        ..BvhParams::default()
    };
    let info = ctx.build_bvh(&s.scene(), &high).unwrap();
    assert!(info.references > info.triangles, "{info:?}");
    // Every vertex moved: a twist about z growing with height.
    let moved: Vec<f32> = s
        .vertices
        .chunks_exact(3)
        .flat_map(|v| {
            let a = 0.05 * v[2];
            let (c, sn) = (a.cos(), a.sin());
            [c * v[0] - sn * v[1], sn * v[0] + c * v[1], v[2] * 1.02]
        })
        .collect();
    let scene = sheaf::Scene::from_f32(&moved, &s.indices).unwrap();
    let r = ctx.refit_bvh(&scene, &RefitParams::default()).unwrap();
    assert!(!r.rebuilt, "{r:?}");
    fresh.build_bvh(&scene, &BvhParams::default()).unwrap();
    for (vname, view) in &s.views {
        let rays = view.rays(RES as u32, RES as u32);
        refit_equals_rebuild(
            &mut ctx,
            &mut fresh,
            &rays,
            &format!("refit split tree {vname}"),
        );
    }
}

/// The refit tree of `ctx` answers `rays` as the fresh build of `fresh`,
/// bit for bit, and every packet method on it as its single ray.
fn refit_equals_rebuild(
    ctx: &mut OwnedContext,
    fresh: &mut OwnedContext,
    rays: &[Ray],
    what: &str,
) {
    let mut want = vec![Hit::MISS; rays.len()];
    let mut got = vec![Hit::MISS; rays.len()];
    fresh.trace(Method::BvhSingle, rays, &mut want).unwrap();
    ctx.trace(Method::BvhSingle, rays, &mut got).unwrap();
    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
        assert!(
            g.prim == w.prim && g.t.to_bits() == w.t.to_bits(),
            "{what} ray {i}: refit {g:?}, rebuild {w:?}"
        );
    }
    assert!(want.iter().any(|h| h.is_hit()), "{what}: no hit");
    let tr = ctx.tracer().unwrap().bvh().unwrap();
    let primary = Class {
        name: "primary",
        rays: rays.to_vec(),
        active: vec![true; rays.len()],
        kind: RayKind::Primary,
        any: false,
    };
    check_class(&tr, &bvh_cases(), what, &primary);
}

#[test]
fn refit_keeps_every_method_exact() {
    use sheaf::RefitParams;
    use sheaf::scenes::animated::Animated;
    let mut a = Animated::new(1);
    let view = a.views()[0];
    let mut l = Limits::for_triangles((a.mesh.indices.len() / 3) as u32);
    l.max_vertices = (a.mesh.vertices.len() / 3) as u32;
    l.structures = Limits::BVH;
    let (mut ctx, mut fresh) = (
        OwnedContext::new(&l).unwrap(),
        OwnedContext::new(&l).unwrap(),
    );
    fn scene(a: &Animated) -> sheaf::Scene<'_> {
        sheaf::Scene::from_f32(&a.mesh.vertices, &a.mesh.indices).unwrap()
    }
    ctx.build_bvh(&scene(&a), &BvhParams::default()).unwrap();
    let rays = view.rays(RES as u32, RES as u32);
    for t in [0.25f32, 1.0, 3.0] {
        a.set_time(t);
        let r = ctx.refit_bvh(&scene(&a), &RefitParams::default()).unwrap();
        assert!(
            !r.rebuilt && r.sah_before > 0.0 && r.sah_after > 0.0,
            "{r:?}"
        );
        fresh.build_bvh(&scene(&a), &BvhParams::default()).unwrap();
        refit_equals_rebuild(&mut ctx, &mut fresh, &rays, &format!("refit t {t}"));
    }

    // Bad input: a non-finite vertex, another triangle count: errors, and
    // the refit tree answers as before.
    let mut before = vec![Hit::MISS; rays.len()];
    ctx.trace(Method::BvhSingle, &rays, &mut before).unwrap();
    let mut v = a.mesh.vertices.clone();
    v[0] = f32::NAN;
    let bad = sheaf::Scene::from_f32(&v, &a.mesh.indices).unwrap();
    assert!(ctx.refit_bvh(&bad, &RefitParams::default()).is_err());
    let fewer = sheaf::Scene::from_f32(&a.mesh.vertices, &a.mesh.indices[3..]).unwrap();
    assert!(ctx.refit_bvh(&fewer, &RefitParams::default()).is_err());
    let bad_params = RefitParams { rebuild_above: 0.5 };
    assert!(ctx.refit_bvh(&scene(&a), &bad_params).is_err());
    let mut after = vec![Hit::MISS; rays.len()];
    ctx.trace(Method::BvhSingle, &rays, &mut after).unwrap();
    assert!(
        before
            .iter()
            .zip(&after)
            .all(|(x, y)| x.prim == y.prim && x.t.to_bits() == y.t.to_bits())
    );

    // Every triangle moved elsewhere (the vertex buffer rotated): the SAH
    // cost grows past 1.5x; with that threshold the refit becomes a
    // rebuild, with a fresh build's tree.
    let n3 = a.mesh.vertices.len();
    let moved: Vec<f32> = (0..n3)
        .map(|i| a.mesh.vertices[(i + 3 * 997) % n3])
        .collect();
    let far = sheaf::Scene::from_f32(&moved, &a.mesh.indices).unwrap();
    let r = ctx.refit_bvh(&far, &RefitParams::default()).unwrap();
    assert!(!r.rebuilt && r.growth() > 1.5, "{r:?}");
    ctx.build_bvh(&scene(&a), &BvhParams::default()).unwrap();
    let r = ctx
        .refit_bvh(&far, &RefitParams { rebuild_above: 1.5 })
        .unwrap();
    let fresh_info = fresh.build_bvh(&far, &BvhParams::default()).unwrap();
    assert!(r.rebuilt && r.sah_after == fresh_info.sah_cost, "{r:?}");
    // No tree built: NotBuilt.
    let mut empty = OwnedContext::new(&l).unwrap();
    assert!(
        empty
            .refit_bvh(&scene(&a), &RefitParams::default())
            .is_err()
    );
}
