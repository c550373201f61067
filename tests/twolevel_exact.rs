//! Two-level scenes are exact: every BVH method through instances (the
//! single ray, the 4-wide single ray, the 2x2 SIMD ray, Masked, Ranged,
//! Partition and Ranged on the 4-wide tree at 4x4, 8x8 and 16x16) returns
//! the two-level single ray's triangle, geometry, instance and bitwise t,
//! and its occlusion answer, lane by lane: camera rays in the renderer's
//! packet layout, shadow rays toward a light, and incoherent rays, on
//! instances rotated, scaled unevenly, mirrored and overlapping, with
//! instance and geometry masks (issue 19; DESIGN.md "Correctness").

mod common;

use common::exact::{RES, packets};
use common::view_rays;
use glam::Vec3;
use sheaf::accel::bvh::{BuildQuality, BvhParams};
use sheaf::scenes::View;
use sheaf::trace::RayKind;
use sheaf::{
    Affine, GeometryParams, Limits, Method, OwnedContext, Ray, SceneHit, TraceParams, TriTest,
    UpdateMode,
};

fn rot(deg: f32, axis: usize, s: [f32; 3], t: [f32; 3]) -> Affine {
    Affine::rotated(deg, axis, s, t)
}

/// A scene of the built-in meshes, each placed two or three times.
fn scene(test: TriTest) -> OwnedContext {
    let names = ["tetra", "gears", "balls", "animated"];
    let meshes: Vec<_> = names
        .iter()
        .map(|n| sheaf::scenes::builtin(n).unwrap().mesh)
        .collect();
    let total: usize = meshes.iter().map(|m| m.indices.len() / 3).sum();
    let mut l = Limits::for_triangles(16);
    l.structures = Limits::BVH;
    l.max_threads = 2;
    l.max_geometries = names.len() as u32;
    l.max_instances = 12;
    l.max_scene_triangles = total as u32;
    let mut ctx = OwnedContext::new(&l).unwrap();
    for (g, m) in meshes.iter().enumerate() {
        let p = GeometryParams {
            mode: UpdateMode::Refit,
            bvh: BvhParams {
                test,
                quality: if g % 2 == 0 {
                    BuildQuality::Medium
                } else {
                    BuildQuality::Low
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
    let placements = [
        (0, Affine::IDENTITY, !0),
        (1, rot(30.0, 1, [0.5; 3], [0.3, 0.0, -0.2]), !0),
        (2, rot(-70.0, 2, [1.0, 2.5, 0.25], [-1.0, 0.5, 0.0]), !0),
        (0, rot(45.0, 0, [-1.0, 1.0, 1.0], [0.2, 0.1, 0.4]), 1),
        (1, rot(10.0, 2, [3.0; 3], [0.0, -0.5, 1.5]), !0),
        (2, rot(0.0, 0, [1.0; 3], [0.05, 0.0, 0.0]), 2),
        (3, rot(20.0, 1, [0.3; 3], [1.0, 1.0, 0.0]), !0),
        (3, rot(-20.0, 0, [0.2, 0.3, 0.2], [-0.5, -0.5, 0.5]), 1),
    ];
    for (i, (g, x, mask)) in placements.iter().enumerate() {
        ctx.set_instance(i as u32, *g, x, *mask).unwrap();
    }
    ctx.commit_scene().unwrap();
    ctx
}

fn same(a: &SceneHit, b: &SceneHit) -> bool {
    (a.prim, a.geometry, a.instance) == (b.prim, b.geometry, b.instance)
        && a.t.to_bits() == b.t.to_bits()
        && a.u.to_bits() == b.u.to_bits()
        && a.v.to_bits() == b.v.to_bits()
}

/// Every method on `rays` (packets in their order) against the single ray.
fn check(
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
    ] {
        methods.push((m, n));
    }
    for &mask in masks {
        let mut want = vec![SceneHit::MISS; rays.len()];
        ctx.trace_scene(rays, mask, &mut want).unwrap();
        let mut want_occ = vec![false; rays.len()];
        ctx.occluded_scene(rays, mask, &mut want_occ).unwrap();
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
            ctx.trace_scene_with(&p, rays, mask, &mut got).unwrap();
            for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                assert!(
                    same(g, w),
                    "{what} {method:?} {packet} mask {mask} ray {k} {:?}: {g:?} want {w:?}",
                    rays[k]
                );
            }
            let mut occ = vec![false; rays.len()];
            ctx.occluded_scene_with(&p, rays, mask, &mut occ).unwrap();
            assert_eq!(
                occ, want_occ,
                "{what} {method:?} {packet} mask {mask}: occlusion"
            );
        }
    }
    hits
}

fn check_test(test: TriTest) {
    let mut ctx = scene(test);
    let info = ctx.commit_scene().unwrap();
    let (lo, hi) = (info.bounds.min, info.bounds.max);
    let (c, d) = (0.5 * (lo + hi), hi - lo);
    let view = View {
        eye: c + Vec3::new(0.7, 0.5, 1.1) * d,
        look_at: c,
        up: Vec3::Y,
        fov_y_deg: 45.0,
    };
    let camera = view_rays(&view, RES as u32, RES as u32);
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
    // Incoherent rays through the scene.
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut f = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 40) as f32 / (1u64 << 24) as f32
    };
    let mut pt = |s: f32| c + Vec3::new(f() - 0.5, f() - 0.5, f() - 0.5) * 2.0 * s * d;
    let random: Vec<Ray> = (0..1024)
        .map(|_| {
            let o = pt(0.8);
            let to = pt(0.3);
            Ray::new(o, to - o, 0.0, f32::INFINITY)
        })
        .collect();
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

/// An instance moved or refit between frames: every method follows.
#[test]
fn moved_and_refit_instances_stay_exact() {
    let mut ctx = scene(TriTest::MollerTrumbore);
    let mut a = sheaf::scenes::animated::Animated::new(1);
    a.set_time(2.5);
    let s = sheaf::Scene::from_f32(&a.mesh.vertices, &a.mesh.indices).unwrap();
    let u = ctx.update_geometry(3, &s).unwrap();
    assert!(u.refit.is_some());
    ctx.set_instance(6, 3, &rot(50.0, 1, [0.35; 3], [0.2, 0.8, 0.1]), !0)
        .unwrap();
    ctx.remove_instance(5).unwrap();
    let info = ctx.commit_scene().unwrap();
    assert_eq!(info.instances, 7);
    let (lo, hi) = (info.bounds.min, info.bounds.max);
    let c = 0.5 * (lo + hi);
    let view = View {
        eye: c + Vec3::new(-0.8, 0.4, 1.0) * (hi - lo),
        look_at: c,
        up: Vec3::Y,
        fov_y_deg: 45.0,
    };
    let camera = view_rays(&view, RES as u32, RES as u32);
    let ordered: Vec<Ray> = packets(&camera, 8)
        .iter()
        .flat_map(|(_, idx)| idx.iter().map(|&i| camera[i]))
        .collect();
    assert!(check(&mut ctx, "moved", &ordered, 8, RayKind::Primary, &[!0]) > 500);
}
