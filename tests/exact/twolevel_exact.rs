//! Two-level scenes are exact: every BVH method through instances (the
//! single ray, the 4-wide single ray, the 2x2 SIMD ray, Masked, Ranged,
//! Partition and Ranged on the 4-wide tree at 4x4, 8x8 and 16x16) returns
//! the two-level single ray's triangle, geometry, instance and bitwise t,
//! and its occlusion answer, lane by lane: camera rays in the renderer's
//! packet layout, shadow rays toward a light, and incoherent rays, on
//! instances rotated, scaled unevenly, mirrored and overlapping, with
//! instance and geometry masks. The grid and the kd-tree trace the same
//! scene flattened into world triangles, each packet method bitwise its own
//! single ray; every family, the two-level BVH included, agrees with the
//! f64 oracle on the flattened scene, and the perspective grid equals the
//! flattened mesh's BVH.

use crate::common;

use common::exact::{RES, packets};
use common::oracle::{Tally, classify_hit};
use glam::Vec3;
use sheaf::accel::bvh::{BuildQuality, BvhParams};
use sheaf::scenes::View;
use sheaf::trace::RayKind;
use sheaf::{
    Affine, Cull, GeometryParams, Limits, Method, OwnedContext, Ray, RayControls, SceneHit,
    TraceParams, TriTest, UpdateMode,
};

/// A view of the committed scene from its centre plus `dir` times its
/// extent.
pub(crate) fn view_of(info: &sheaf::TwoLevelInfo, dir: Vec3) -> View {
    let (lo, hi) = (info.bounds.min, info.bounds.max);
    let c = 0.5 * (lo + hi);
    View {
        eye: c + dir * (hi - lo),
        look_at: c,
        up: Vec3::Y,
        fov_y_deg: 45.0,
    }
}

/// `n` rays from points within `from` of the scene's half extent around
/// its centre toward points within `to` of it (xorshift from `seed`).
pub(crate) fn random_rays(
    info: &sheaf::TwoLevelInfo,
    seed: u64,
    n: usize,
    from: f32,
    to: f32,
) -> Vec<Ray> {
    let (lo, hi) = (info.bounds.min, info.bounds.max);
    let (c, d) = (0.5 * (lo + hi), hi - lo);
    let mut seed = seed;
    let mut f = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 40) as f32 / (1u64 << 24) as f32
    };
    let mut pt = |s: f32| c + Vec3::new(f() - 0.5, f() - 0.5, f() - 0.5) * 2.0 * s * d;
    (0..n)
        .map(|_| {
            let (o, t) = (pt(from), pt(to));
            Ray::new(o, t - o, 0.0, f32::INFINITY)
        })
        .collect()
}

const NAMES: [&str; 4] = ["tetra", "gears", "balls", "animated"];

/// Triangles of the built-in meshes the scene places.
pub(crate) fn mesh_triangles() -> u32 {
    NAMES
        .iter()
        .map(|n| sheaf::scenes::builtin(n).unwrap().mesh.indices.len() as u32 / 3)
        .sum()
}

/// A scene of the built-in meshes, each placed two or three times.
fn scene(test: TriTest) -> OwnedContext {
    let mut l = Limits::for_triangles(16);
    l.structures = Limits::BVH;
    l.projection_test = test == TriTest::Projection;
    scene_in(test, l)
}

/// The scene in a context of limits `l` (its two-level fields set here).
pub(crate) fn scene_in(test: TriTest, mut l: Limits) -> OwnedContext {
    let meshes: Vec<_> = NAMES
        .iter()
        .map(|n| sheaf::scenes::builtin(n).unwrap().mesh)
        .collect();
    l.max_threads = 2;
    l.max_geometries = NAMES.len() as u32;
    l.max_instances = 12;
    l.max_scene_triangles = mesh_triangles();
    let mut ctx = OwnedContext::new(&l).unwrap();
    for (g, m) in meshes.iter().enumerate() {
        let p = GeometryParams {
            mode: UpdateMode::Refit,
            bvh: BvhParams {
                test,
                quality: match g % 3 {
                    0 => BuildQuality::Medium,
                    1 => BuildQuality::Low,
                    _ => BuildQuality::High,
                },
                ..BvhParams::default()
            },
            // Geometry 2 is seen by mask bits 0 and 2 only: mask 2 skips
            // it in every instance.
            mask: if g == 2 { 0b101 } else { !0 },
            ..GeometryParams::default()
        };
        let s = sheaf::Scene::from_f32(&m.vertices, &m.indices).unwrap();
        ctx.set_geometry(g as u32, &s, &p).unwrap();
    }
    for (i, (g, x, mask)) in placements().iter().enumerate() {
        ctx.set_instance(i as u32, *g, x, *mask).unwrap();
    }
    ctx.commit_scene().unwrap();
    ctx
}

/// The instances: geometry, transform, mask.
fn placements() -> [(u32, Affine, u32); 8] {
    [
        (0, Affine::IDENTITY, !0),
        (1, Affine::rotated(30.0, 1, [0.5; 3], [0.3, 0.0, -0.2]), !0),
        (
            2,
            Affine::rotated(-70.0, 2, [1.0, 2.5, 0.25], [-1.0, 0.5, 0.0]),
            !0,
        ),
        (
            0,
            Affine::rotated(45.0, 0, [-1.0, 1.0, 1.0], [0.2, 0.1, 0.4]),
            1,
        ),
        (1, Affine::rotated(10.0, 2, [3.0; 3], [0.0, -0.5, 1.5]), !0),
        (2, Affine::rotated(0.0, 0, [1.0; 3], [0.05, 0.0, 0.0]), 2),
        (3, Affine::rotated(20.0, 1, [0.3; 3], [1.0, 1.0, 0.0]), !0),
        (
            3,
            Affine::rotated(-20.0, 0, [0.2, 0.3, 0.2], [-0.5, -0.5, 0.5]),
            1,
        ),
    ]
}

pub(crate) fn same(a: &SceneHit, b: &SceneHit) -> bool {
    (a.prim, a.geometry, a.instance) == (b.prim, b.geometry, b.instance)
        && a.t.to_bits() == b.t.to_bits()
        && a.u.to_bits() == b.u.to_bits()
        && a.v.to_bits() == b.v.to_bits()
}

/// Every method on `rays` (packets in their order) against the single ray.
pub(crate) fn check(
    ctx: &mut OwnedContext,
    what: &str,
    rays: &[Ray],
    n: u32,
    kind: RayKind,
    masks: &[u32],
) -> usize {
    let mut hits = 0;
    let mut methods = vec![
        (Method::BvhSingle, 2),
        (Method::BvhWide, 2),
        (Method::BvhSimd, 2),
    ];
    for m in [
        Method::BvhMasked,
        Method::BvhRanged,
        Method::BvhPartition,
        Method::BvhWideRanged,
        Method::BvhFrustum,
    ] {
        methods.push((m, n));
    }
    // Every mask without culling, and the first mask culling either side.
    let controls =
        masks
            .iter()
            .map(|&mask| RayControls::from(mask))
            .chain([Cull::Back, Cull::Front].map(|cull| RayControls {
                mask: masks[0],
                cull,
                ..RayControls::default()
            }));
    for ctl in controls {
        let mut want = vec![SceneHit::MISS; rays.len()];
        ctx.trace_scene(rays, ctl, &mut want).unwrap();
        let mut want_occ = vec![false; rays.len()];
        ctx.occluded_scene(rays, ctl, &mut want_occ).unwrap();
        for (w, o) in want.iter().zip(&want_occ) {
            assert_eq!(w.is_hit(), *o, "{what}: occluded is hit");
        }
        hits += want.iter().filter(|h| h.is_hit()).count();
        for &(method, packet) in &methods {
            let mut p = TraceParams {
                method,
                packet,
                ..TraceParams::default()
            };
            p.bvh.kind = kind;
            let mut got = vec![SceneHit::MISS; rays.len()];
            ctx.trace_scene_with(&p, rays, ctl, &mut got).unwrap();
            for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                assert!(
                    same(g, w),
                    "{what} {method:?} {packet} {ctl:?} ray {k} {:?}: {g:?} want {w:?}",
                    rays[k]
                );
            }
            let mut occ = vec![false; rays.len()];
            ctx.occluded_scene_with(&p, rays, ctl, &mut occ).unwrap();
            assert_eq!(
                occ, want_occ,
                "{what} {method:?} {packet} {ctl:?}: occlusion"
            );
            if matches!(method, Method::BvhSingle | Method::BvhFrustum) {
                check_stream(ctx, Some(&p), rays, ctl, &want, &want_occ, what);
            }
        }
        check_stream(ctx, None, rays, ctl, &want, &want_occ, what);
    }
    hits
}

/// `rays` as a ray stream (structures of arrays) give `want` and
/// `want_occ` bit for bit, with `p` (or single rays).
fn check_stream(
    ctx: &OwnedContext,
    p: Option<&TraceParams>,
    rays: &[Ray],
    ctl: RayControls,
    want: &[SceneHit],
    want_occ: &[bool],
    what: &str,
) {
    let n = rays.len();
    let cols = common::ray_stream::Columns::of(rays);
    let stream = cols.stream();
    let (mut t, mut u, mut v) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    let (mut prim, mut geometry, mut instance) = (vec![0; n], vec![0; n], vec![0; n]);
    let mut out = sheaf::SceneHitStream {
        t: &mut t,
        u: &mut u,
        v: &mut v,
        prim: &mut prim,
        geometry: &mut geometry,
        instance: &mut instance,
    };
    ctx.trace_scene_stream(p, Some(0), &stream, ctl, &mut out)
        .unwrap();
    for (k, w) in want.iter().enumerate() {
        let g = SceneHit {
            t: t[k],
            u: u[k],
            v: v[k],
            prim: prim[k],
            geometry: geometry[k],
            instance: instance[k],
        };
        assert!(
            same(&g, w),
            "{what} stream {p:?} {ctl:?} ray {k}: {g:?} want {w:?}"
        );
    }
    let mut occ = vec![false; n];
    ctx.occluded_scene_stream(p, None, &stream, ctl, &mut occ)
        .unwrap();
    assert_eq!(occ, want_occ, "{what} stream {p:?} {ctl:?}: occlusion");
}

fn check_test(test: TriTest) {
    let mut ctx = scene(test);
    let info = ctx.commit_scene().unwrap();
    let (lo, hi) = (info.bounds.min, info.bounds.max);
    let (c, d) = (0.5 * (lo + hi), hi - lo);
    let view = view_of(&info, Vec3::new(0.7, 0.5, 1.1));
    let camera = view.rays(RES as u32, RES as u32);
    let light = c + Vec3::new(-0.3, 1.2, 0.4) * d;
    let mut total = 0;
    for n in [4usize, 8, 16] {
        // Camera rays in the renderer's packet layout.
        let ordered: Vec<Ray> = packets(&camera, n)
            .iter()
            .flat_map(|(_, idx)| idx.iter().map(|&i| camera[i]))
            .collect();
        total += check(
            &mut ctx,
            "camera",
            &ordered,
            n as u32,
            RayKind::Primary,
            &[!0, 1, 2],
        );
        // Shadow rays from the camera rays' hits toward the light.
        let mut hits = vec![SceneHit::MISS; ordered.len()];
        ctx.trace_scene(&ordered, !0, &mut hits).unwrap();
        let shadow: Vec<Ray> = ordered
            .iter()
            .zip(&hits)
            .map(|(r, h)| {
                let t = if h.is_hit() { h.t } else { 1.0 };
                let p = Vec3::from(r.org) + (t * 0.999) * Vec3::from(r.dir);
                Ray::new(p, light - p, 0.0, 1.0)
            })
            .collect();
        check(
            &mut ctx,
            "shadow",
            &shadow,
            n as u32,
            RayKind::Shadow,
            &[!0],
        );
    }
    // Packets with odd lanes (the top level's frustum and the lanes'
    // own tests at instances): tmin > 0, short and mixed tmax, directions
    // with zero (+-0) and tiny components, tiny directions, invalid lanes.
    let edge: Vec<Ray> = packets(&camera, 8)
        .iter()
        .flat_map(|(_, idx)| idx.iter().map(|&i| camera[i]))
        .enumerate()
        .map(|(k, r)| {
            let (o, mut d) = (Vec3::from(r.org), Vec3::from(r.dir));
            let (mut tmin, mut tmax) = (0.0, f32::INFINITY);
            match k % 11 {
                1 => tmin = 0.4 * (c - o).length() / d.length(),
                2 => tmax = 0.7 * (c - o).length() / d.length(),
                3 => d.y = 0.0,
                4 => d.x = -0.0,
                5 => d *= 1e-20,
                6 => d = Vec3::new(0.0, -1.0, 0.0),
                7 => tmax = f32::from_bits(1),
                8 => tmin = f32::NAN,
                9 => tmax = -1.0,
                _ => {}
            }
            if k % 64 == 63 {
                d = Vec3::new(0.0, 0.0, -1e-19);
            }
            Ray::new(o, d, tmin, tmax)
        })
        .collect();
    total += check(&mut ctx, "edge", &edge, 8, RayKind::Auto, &[!0]);
    // Incoherent rays through the scene.
    let random = random_rays(&info, 0x9e37_79b9_7f4a_7c15, 1024, 0.8, 0.3);
    total += check(&mut ctx, "random", &random, 8, RayKind::Secondary, &[!0, 2]);
    assert!(total > 4000, "{test:?}: {total} hits");
}

#[test]
fn every_method_through_instances_moller_trumbore() {
    check_test(TriTest::MollerTrumbore);
}

#[test]
fn every_method_through_instances_watertight() {
    check_test(TriTest::Watertight);
}

#[test]
fn every_method_through_instances_projection() {
    check_test(TriTest::Projection);
}

/// An instance moved or refit between frames: every method follows.
#[test]
fn moved_and_refit_instances_stay_exact() {
    let mut ctx = scene(TriTest::MollerTrumbore);
    let mut a = sheaf::scenes::animated::Animated::new(1);
    a.set_time(2.5);
    let s = sheaf::Scene::from_f32(&a.mesh.vertices, &a.mesh.indices).unwrap();
    let u = ctx.update_geometry(3, &s).unwrap();
    assert!(u.refit.is_some());
    ctx.set_instance(
        6,
        3,
        &Affine::rotated(50.0, 1, [0.35; 3], [0.2, 0.8, 0.1]),
        !0,
    )
    .unwrap();
    ctx.remove_instance(5).unwrap();
    let info = ctx.commit_scene().unwrap();
    assert_eq!(info.instances, 7);
    let view = view_of(&info, Vec3::new(-0.8, 0.4, 1.0));
    let camera = view.rays(RES as u32, RES as u32);
    let ordered: Vec<Ray> = packets(&camera, 8)
        .iter()
        .flat_map(|(_, idx)| idx.iter().map(|&i| camera[i]))
        .collect();
    assert!(check(&mut ctx, "moved", &ordered, 8, RayKind::Primary, &[!0]) > 500);
}

/// The grid and the kd-tree trace the scene flattened into world
/// triangles: each packet method equals its own single ray bitwise, with
/// the same (geometry, instance, triangle) ids; a mask change or a new
/// commit is refused until they are rebuilt.
#[test]
fn grid_and_kd_trace_the_flattened_scene() {
    let mut l = Limits::for_triangles(2 * mesh_triangles());
    l.structures = Limits::GRID | Limits::KD;
    let mut ctx = scene_in(TriTest::MollerTrumbore, l);
    let info = ctx.commit_scene().unwrap();
    let (lo, hi) = (info.bounds.min, info.bounds.max);
    let c = 0.5 * (lo + hi);
    let view = view_of(&info, Vec3::new(0.7, 0.5, 1.1));
    let camera = view.rays(RES as u32, RES as u32);
    let ordered: Vec<Ray> = packets(&camera, 8)
        .iter()
        .flat_map(|(_, idx)| idx.iter().map(|&i| camera[i]))
        .collect();
    let trace = |ctx: &mut OwnedContext, method, packet, mask| {
        let p = TraceParams {
            method,
            packet,
            ..TraceParams::default()
        };
        let mut got = vec![SceneHit::MISS; ordered.len()];
        ctx.trace_scene_with(&p, &ordered, mask, &mut got)
            .map(|_| got)
    };
    let mut total = 0;
    for mask in [!0u32, 1, 2] {
        ctx.build_grid_scene(&sheaf::GridParams::default(), mask)
            .unwrap();
        ctx.build_kd_scene(&sheaf::KdParams::default(), mask)
            .unwrap();
        let (_, flat) = ctx.flat_scene().unwrap();
        assert_eq!(flat.mask, mask);
        for (single, packets) in [
            (Method::GridDda, &[Method::GridCgt][..]),
            (Method::KdSingle, &[Method::KdSimd, Method::KdPacket][..]),
        ] {
            let want = trace(&mut ctx, single, 2, mask).unwrap();
            total += want.iter().filter(|h| h.is_hit()).count();
            for &packet in packets {
                let got = trace(&mut ctx, packet, 8, mask).unwrap();
                for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert!(
                        same(g, w),
                        "{packet:?} mask {mask} ray {k}: {g:?} want {w:?}"
                    );
                }
                // Occlusion of shadow rays from the hits toward a light.
                let light = c + Vec3::new(-0.3, 1.2, 0.4) * (hi - lo);
                let shadow: Vec<Ray> = ordered
                    .iter()
                    .zip(&want)
                    .map(|(r, h)| {
                        let t = if h.is_hit() { h.t } else { 1.0 };
                        let p = Vec3::from(r.org) + (t * 0.999) * Vec3::from(r.dir);
                        Ray::new(p, light - p, 0.0, 1.0)
                    })
                    .collect();
                let occ = |ctx: &mut OwnedContext, method| {
                    let p = TraceParams {
                        method,
                        packet: 8,
                        ..TraceParams::default()
                    };
                    let mut o = vec![false; shadow.len()];
                    ctx.occluded_scene_with(&p, &shadow, mask, &mut o).unwrap();
                    o
                };
                let (o_single, o_packet) = (occ(&mut ctx, single), occ(&mut ctx, packet));
                let bad = o_single
                    .iter()
                    .zip(&o_packet)
                    .filter(|(a, b)| a != b)
                    .count();
                assert_eq!(
                    bad, 0,
                    "{packet:?} mask {mask}: occlusion differs on {bad} rays"
                );
                assert!(o_single.iter().any(|&o| o) && o_single.iter().any(|&o| !o));
            }
        }
        // Another mask than the build's is refused, as is any grid method
        // after a new commit until the grid is rebuilt.
        assert!(matches!(
            trace(&mut ctx, Method::GridDda, 2, mask ^ 4),
            Err(sheaf::Error::InvalidArgument(_))
        ));
    }
    assert!(total > 3000, "{total} hits");
    ctx.commit_scene().unwrap();
    assert!(matches!(
        trace(&mut ctx, Method::KdSingle, 2, 2),
        Err(sheaf::Error::NotBuilt)
    ));
    ctx.build_kd_scene(&sheaf::KdParams::default(), 2).unwrap();
    assert!(trace(&mut ctx, Method::KdSingle, 2, 2).is_ok());
    assert!(matches!(
        trace(&mut ctx, Method::GridDda, 2, 2),
        Err(sheaf::Error::NotBuilt)
    ));
    // A failed build for another mask changes nothing the kd-tree answers.
    let before = trace(&mut ctx, Method::KdSingle, 2, 2).unwrap();
    let bad = sheaf::GridParams {
        lambda: -1.0,
        ..sheaf::GridParams::default()
    };
    assert!(ctx.build_grid_scene(&bad, 1).is_err());
    let after = trace(&mut ctx, Method::KdSingle, 2, 2).unwrap();
    assert!(before.iter().zip(&after).all(|(a, b)| same(a, b)));
}

/// Every family answers for the same scene: on the flattened scene, the
/// grid's and the kd-tree's single rays and the two-level BVH agree with
/// the f64 oracle within `common::oracle`'s named tolerances (the
/// two-level BVH too: no transform tolerance was needed), and a deferred
/// frame's
/// perspective grid gives the flattened mesh's BVH single ray bitwise.
#[test]
fn every_family_agrees_with_the_oracle_on_the_flattened_scene() {
    let (w, h) = (94u32, 71u32);
    let n = 2 * mesh_triangles();
    let mut l = Limits::for_triangles(n);
    l.structures = Limits::ALL_STRUCTURES;
    l.max_image_width = w;
    l.max_image_height = h;
    l.max_pgrid_refs = 8 * n + (1 << 21);
    let mut ctx = scene_in(TriTest::MollerTrumbore, l);
    let info = ctx.commit_scene().unwrap();
    let (lo, hi) = (info.bounds.min, info.bounds.max);
    let c = 0.5 * (lo + hi);
    let view = view_of(&info, Vec3::new(0.6, 0.6, 1.0));
    ctx.build_grid_scene(&sheaf::GridParams::default(), !0)
        .unwrap();
    ctx.build_kd_scene(&sheaf::KdParams::default(), !0).unwrap();
    ctx.build_pgrid_scene(&sheaf::PgridParams::default(), !0)
        .unwrap();
    // A copy of the flattened mesh, and each scene hit's world triangle.
    let (verts, count) = {
        let (s, f) = ctx.flat_scene().unwrap();
        let v: Vec<f32> = (0..f.triangles)
            .flat_map(|i| {
                let t = s.triangle(i);
                [t.v0, t.v1, t.v2].into_iter().flatten()
            })
            .collect();
        (v, f.triangles)
    };
    let idx: Vec<u32> = (0..3 * count).collect();
    let flat = sheaf::Scene::from_f32(&verts, &idx).unwrap();
    let world: std::collections::HashMap<(u32, u32), u32> = (0..count)
        .map(|i| {
            let hit = ctx
                .scene_prim(
                    Limits::GRID,
                    &sheaf::Hit {
                        prim: i,
                        ..sheaf::Hit::MISS
                    },
                )
                .unwrap();
            ((hit.instance, hit.prim), i)
        })
        .collect();
    assert_eq!(
        world.len(),
        count as usize,
        "world triangles map one to one"
    );
    let camera = view.rays(w, h);
    // The camera rays and incoherent rays through the scene.
    let mut rays = camera.clone();
    rays.extend(random_rays(&info, 0x2545_f491_4f6c_dd1d, 4096, 0.8, 0.3));
    let oracle = common::par_map(&rays, |r| sheaf::reference::nearest(&flat, r));
    let mut report = Vec::new();
    for (what, method) in [
        ("grid", Some(Method::GridDda)),
        ("kd", Some(Method::KdSingle)),
        ("two-level BVH", None),
    ] {
        let mut got = vec![SceneHit::MISS; rays.len()];
        match method {
            Some(m) => ctx.trace_scene_with(
                &TraceParams {
                    method: m,
                    ..TraceParams::default()
                },
                &rays,
                !0,
                &mut got,
            ),
            None => ctx.trace_scene(&rays, !0, &mut got),
        }
        .unwrap();
        // The named tolerances of `reference_equivalence` (the two-level
        // BVH, which maps rays into object space instead of meeting the
        // flattening's rounded world triangles, needed no other).
        let mut t = Tally::default();
        for (k, ((r, g), o)) in rays.iter().zip(&got).zip(&oracle).enumerate() {
            let hit = sheaf::Hit {
                t: g.t,
                prim: if g.is_hit() {
                    world[&(g.instance, g.prim)]
                } else {
                    sheaf::geom::INVALID_ID
                },
                ..sheaf::Hit::MISS
            };
            classify_hit(&flat, k, r, &hit, o, &mut t, what);
        }
        report.push(format!("{what}: {t:?}"));
        assert!(
            t.errors.is_empty(),
            "{what}: {} errors, first {:?}",
            t.errors.len(),
            &t.errors[..t.errors.len().min(4)]
        );
        assert!(t.exact as usize > rays.len() * 9 / 10, "{what}: {t:?}");
    }
    println!("{}", report.join("\n"));
    // The deferred frame against the flattened mesh's BVH single ray.
    let mut want = vec![sheaf::Hit::MISS; camera.len()];
    ctx.build_bvh(&flat, &BvhParams::default()).unwrap();
    ctx.trace(Method::BvhSingle, &camera, &mut want).unwrap();
    let cam = sheaf::Camera {
        eye: view.eye.to_array(),
        look_at: view.look_at.to_array(),
        up: view.up.to_array(),
        fov_y_deg: view.fov_y_deg,
    };
    let frame = sheaf::Frame {
        camera: cam,
        light: sheaf::PointLight::new((c + (hi - lo)).to_array(), [1.0; 3]),
        shading: sheaf::Shading::default(),
        width: w,
        height: h,
    };
    let mut px = vec![0u8; (4 * w * h) as usize];
    ctx.render_deferred(
        &sheaf::DeferredJob {
            frame: &frame,
            lights: &[],
            primary: sheaf::PrimaryPass::Pgrid,
            shadow: sheaf::ShadowPass::LightGrid,
        },
        &mut px,
        4 * w as usize,
        &mut sheaf::OnCaller,
    )
    .unwrap();
    let mut hits = 0;
    for y in 0..h {
        for x in 0..w {
            let (got, _) = ctx.deferred_pixel(x, y).unwrap();
            let exp = want[(y * w + x) as usize];
            assert_eq!(
                (got.prim, got.t.to_bits()),
                (exp.prim, exp.t.to_bits()),
                "pixel ({x}, {y})"
            );
            hits += got.is_hit() as usize;
            if got.is_hit() {
                let s = ctx.scene_prim(Limits::PGRID, &got).unwrap();
                assert_eq!(world[&(s.instance, s.prim)], got.prim);
            }
        }
    }
    assert!(hits > camera.len() / 4, "{hits} pixels hit");
    // A build for another mask flattens again: the frame's hits no longer
    // map (the perspective grid was loaded from the other flattening).
    let (px_hit, _) = ctx.deferred_pixel(w / 2, h / 2).unwrap();
    ctx.build_grid_scene(&sheaf::GridParams::default(), 1)
        .unwrap();
    assert!(matches!(
        ctx.scene_prim(Limits::PGRID, &px_hit),
        Err(sheaf::Error::NotBuilt)
    ));
}

/// Culling skips exactly one side, in the geometry's own space (instance 3
/// mirrors): a ray whose nearest hit faces it keeps that hit with back
/// faces culled, and loses it with front faces culled; every hit kept
/// faces the kept way (checked in f64 where the f32 sign is clear).
#[test]
fn culling_skips_one_side_in_object_space() {
    for test in [
        TriTest::MollerTrumbore,
        TriTest::Watertight,
        TriTest::Projection,
    ] {
        culling_skips_one_side(test);
    }
}

fn culling_skips_one_side(test: TriTest) {
    let mut ctx = scene(test);
    let info = ctx.commit_scene().unwrap();
    // Camera rays (mostly front faces) and rays from points inside the
    // scene's box (also from inside closed meshes: back faces).
    let view = view_of(&info, Vec3::new(0.7, 0.5, 1.1));
    let mut rays = view.rays(RES as u32, RES as u32);
    rays.extend(random_rays(&info, 0x853c_49e6_748f_ea9b, 4096, 0.5, 0.5));
    let meshes: Vec<_> = NAMES
        .iter()
        .map(|n| sheaf::scenes::builtin(n).unwrap().mesh)
        .collect();
    let place = placements();
    // dir . n of hit `h`'s triangle in its geometry's space, in f64.
    let facing = |r: &Ray, h: &SceneHit| -> f64 {
        let m = &meshes[h.geometry as usize];
        let inv = place[h.instance as usize].1.inverse().unwrap();
        let d = inv.vector(r.dir).map(f64::from);
        let v = |k: usize| {
            let i = m.indices[3 * h.prim as usize + k] as usize;
            [0, 1, 2].map(|a| m.vertices[3 * i + a] as f64)
        };
        let (a, b, cc) = (v(0), v(1), v(2));
        let (e1, e2) = (
            [0, 1, 2].map(|i| b[i] - a[i]),
            [0, 1, 2].map(|i| cc[i] - a[i]),
        );
        let n = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let dn = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
        let scale =
            (d.iter().map(|x| x * x).sum::<f64>() * n.iter().map(|x| x * x).sum::<f64>()).sqrt();
        dn / scale.max(f64::MIN_POSITIVE)
    };
    let trace = |ctx: &mut OwnedContext, cull| {
        let mut h = vec![SceneHit::MISS; rays.len()];
        ctx.trace_scene(
            &rays,
            RayControls {
                mask: !0,
                cull,
                ..RayControls::default()
            },
            &mut h,
        )
        .unwrap();
        h
    };
    let (all, back, front) = (
        trace(&mut ctx, Cull::None),
        trace(&mut ctx, Cull::Back),
        trace(&mut ctx, Cull::Front),
    );
    let (mut fronts, mut backs, mut mirrored) = (0, 0, 0);
    for (k, r) in rays.iter().enumerate() {
        let (a, b, f) = (&all[k], &back[k], &front[k]);
        if a.is_hit() {
            let side = facing(r, a);
            if side < -1e-6 {
                fronts += 1;
                assert!(same(a, b), "ray {k}: front hit lost with back faces culled");
                assert!(
                    !same(a, f),
                    "ray {k}: front hit kept with front faces culled"
                );
            } else if side > 1e-6 {
                backs += 1;
                assert!(same(a, f), "ray {k}: back hit lost with front faces culled");
                assert!(!same(a, b), "ray {k}: back hit kept with back faces culled");
            }
            mirrored += (a.instance == 3) as usize;
        }
        assert!(
            !b.is_hit() || facing(r, b) < 1e-6,
            "ray {k}: kept a back face"
        );
        assert!(
            !f.is_hit() || facing(r, f) > -1e-6,
            "ray {k}: kept a front face"
        );
    }
    println!("{test:?}: {fronts} front, {backs} back hits, {mirrored} on the mirrored instance");
    assert!(
        fronts > 1000 && backs > 100 && mirrored >= 10,
        "{fronts} {backs} {mirrored}"
    );
}

/// Camera packets made in the kernel through instances
/// (`trace_scene_camera`): every BVH method and single rays, each mask and
/// culling side, give every pixel of a rectangle off the image's corner the
/// single ray's hit of `PrimaryRays::ray`, bit for bit.
#[test]
fn camera_packets_through_instances() {
    use sheaf::{PixelRect, PrimaryRays};
    let mut ctx = scene(TriTest::Watertight);
    let info = ctx.commit_scene().unwrap();
    let v = view_of(&info, Vec3::new(0.7, 0.5, 1.1));
    let cam = sheaf::Camera {
        eye: v.eye.to_array(),
        look_at: v.look_at.to_array(),
        up: v.up.to_array(),
        fov_y_deg: v.fov_y_deg,
    };
    let (w, h) = (RES as u32 + 5, RES as u32 + 2);
    let pr = PrimaryRays::new(&cam, w, h).unwrap();
    let rect = PixelRect {
        x0: 2,
        y0: 1,
        x1: w - 1,
        y1: h,
    };
    let (rw, rh) = rect.size();
    let row = rw as usize;
    let pixels: Vec<(u32, u32)> = (rect.y0..rect.y1)
        .flat_map(|y| (rect.x0..rect.x1).map(move |x| (x, y)))
        .collect();
    let rays: Vec<Ray> = pixels.iter().map(|&(x, y)| pr.ray(x, y)).collect();
    let mut total = 0;
    let controls = [
        RayControls::from(!0),
        RayControls::from(2),
        RayControls {
            mask: !0,
            cull: Cull::Back,
            ..RayControls::default()
        },
    ];
    for ctl in controls {
        let mut want = vec![SceneHit::MISS; rays.len()];
        ctx.trace_scene(&rays, ctl, &mut want).unwrap();
        total += want.iter().filter(|h| h.is_hit()).count();
        let mut params = vec![None];
        for (method, packet) in [
            (Method::BvhSimd, 2),
            (Method::BvhMasked, 8),
            (Method::BvhRanged, 16),
            (Method::BvhFrustum, 8),
            (Method::BvhFrustum, 16),
            (Method::BvhFrustum, 32),
        ] {
            params.push(Some(TraceParams {
                method,
                packet,
                ..TraceParams::default()
            }));
        }
        for p in &params {
            let mut got = vec![SceneHit::MISS; rh as usize * row];
            ctx.trace_scene_camera(p.as_ref(), Some(0), &pr, rect, ctl, &mut got, row)
                .unwrap();
            for (k, &(x, y)) in pixels.iter().enumerate() {
                let g = &got[(y - rect.y0) as usize * row + (x - rect.x0) as usize];
                assert!(
                    same(g, &want[k]),
                    "{p:?} {ctl:?} pixel ({x}, {y}): {g:?} want {:?}",
                    want[k]
                );
            }
        }
    }
    assert!(total > 1000, "{total} hits");
}
