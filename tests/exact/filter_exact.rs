//! Any-hit filters keep every method exact: with the cut-out filter of
//! `common::filter` (a pure function of the candidate), every packet
//! method of the grid, the BVH and the kd-tree returns its own single
//! ray's triangle and bitwise t (its occlusion answer), lane by lane, at
//! every lane width, for primary, shadow, reflection and refraction rays
//! (`common::exact::check_class`); the same through the two-level scene's
//! instances (every BVH method) and on the flattened scene (grid and
//! kd-tree), with the geometry's own triangle and instance ids in the
//! candidate. The filter is not a no-op (hits move behind the holes, and
//! every hit it leaves is one it accepts), force-opaque calls and opaque
//! geometries skip it (no call, the unfiltered hits), and each method's
//! filter calls are printed against its single ray's.

use crate::bvh_exact::bvh_cases;
use crate::common;
use crate::kd_exact::kd_cases;
use crate::twolevel_exact::{check, mesh_triangles, same, scene_in, view_of};

use common::exact::{Class, RES, check_class, packets, reference, secondary, shadow};
use common::filter::{counted, keep, plain};
use common::{TestScene, builtin_scenes, par_map};
use glam::Vec3;
use sheaf::render::SHADOW_OFFSET;
use sheaf::trace::RayKind;
use sheaf::{
    Candidate, GeometryParams, Hit, Isa, Limits, Method, OwnedContext, Ray, RayControls, SceneHit,
    TraceParams, TriTest,
};
use std::sync::atomic::{AtomicU64, Ordering};

/// Class `c`'s answers with `p` (occlusion as a hit on triangle 0 or a
/// miss, as `common::exact::reference`).
fn answers(ctx: &mut OwnedContext, p: &TraceParams, c: &Class) -> Vec<Hit> {
    if !c.any {
        return traced(ctx, p, &c.rays);
    }
    let mut o = vec![false; c.rays.len()];
    ctx.occluded_with(p, &c.rays, &mut o).unwrap();
    o.iter()
        .map(|&o| {
            if o {
                Hit {
                    t: 0.0,
                    prim: 0,
                    u: 0.0,
                    v: 0.0,
                }
            } else {
                Hit::MISS
            }
        })
        .collect()
}

fn params(method: Method) -> TraceParams {
    TraceParams {
        method,
        ..TraceParams::default()
    }
}

/// The candidate a hit of `r` on the single mesh was.
fn candidate(r: &Ray, h: &Hit) -> Candidate {
    Candidate {
        org: r.org,
        dir: r.dir,
        t: h.t,
        u: h.u,
        v: h.v,
        prim: h.prim,
        geometry: 0,
        instance: sheaf::geom::INVALID_ID,
    }
}

/// A context with the grid, the BVH and the kd-tree built over `s`.
fn context(s: &TestScene, test: TriTest) -> OwnedContext {
    let mut l = Limits::for_triangles(s.triangles());
    l.max_vertices = (s.vertices.len() / 3) as u32;
    l.structures = Limits::GRID | Limits::BVH | Limits::KD;
    let mut ctx = OwnedContext::new(&l).unwrap();
    let scene = s.scene();
    ctx.build_grid(
        &scene,
        &sheaf::GridParams {
            test,
            ..Default::default()
        },
    )
    .unwrap();
    ctx.build_bvh(
        &scene,
        &sheaf::BvhParams {
            test,
            ..Default::default()
        },
    )
    .unwrap();
    ctx.build_kd(
        &scene,
        &sheaf::KdParams {
            test,
            ..Default::default()
        },
    )
    .unwrap();
    ctx
}

/// `rays` traced (or tested for occlusion) with `p`.
fn traced(ctx: &mut OwnedContext, p: &TraceParams, rays: &[Ray]) -> Vec<Hit> {
    let mut h = vec![Hit::MISS; rays.len()];
    ctx.trace_with(p, rays, &mut h).unwrap();
    h
}

fn check_scene(&(s, test): &(&TestScene, TriTest)) -> String {
    let mut ctx = context(s, test);
    let calls = AtomicU64::new(0);
    let eps = SHADOW_OFFSET * {
        let b = sheaf::accel::Accel::bounds(&ctx.tracer().unwrap().bvh().unwrap());
        (b.max - b.min).length()
    };
    let mut report = String::new();
    // Hits the cut-out moved, of all hits.
    let mut total = (0, 0);
    for (vname, view) in &s.views {
        let what = format!("{} {vname} {test:?}", s.name);
        let rays = view.rays(RES as u32, RES as u32);
        // The filter moves hits, and every family's single ray leaves
        // only hits it accepts, never nearer than the unfiltered hit; its
        // occlusion answer is whether a filtered hit exists.
        ctx.set_filter(None);
        let open = traced(&mut ctx, &params(Method::BvhSingle), &rays);
        ctx.set_filter(Some(counted(&calls)));
        let cut = traced(&mut ctx, &params(Method::BvhSingle), &rays);
        total.0 += open.iter().zip(&cut).filter(|(a, b)| a != b).count();
        total.1 += open.iter().filter(|h| h.is_hit()).count();
        for single in [Method::GridDda, Method::BvhSingle, Method::KdSingle] {
            let cut = traced(&mut ctx, &params(single), &rays);
            for (k, (o, c)) in open.iter().zip(&cut).enumerate() {
                assert!(
                    !c.is_hit() || (keep(&candidate(&rays[k], c)) && c.t >= o.t),
                    "{what} {single:?} ray {k}: filtered hit {c:?}, unfiltered {o:?}"
                );
            }
            let mut occ = vec![false; rays.len()];
            ctx.occluded_with(&params(single), &rays, &mut occ).unwrap();
            for (k, (o, c)) in occ.iter().zip(&cut).enumerate() {
                assert_eq!(*o, c.is_hit(), "{what} {single:?} ray {k}: occluded");
            }
        }
        // Force-opaque calls skip the filter: the unfiltered hits, no call.
        let before = calls.load(Ordering::Relaxed);
        for m in [Method::BvhSingle, Method::GridCgt, Method::KdPacket] {
            let p = TraceParams {
                opaque: true,
                ..params(m)
            };
            assert_eq!(traced(&mut ctx, &p, &rays), open, "{what} {m:?} opaque");
        }
        assert_eq!(
            calls.load(Ordering::Relaxed),
            before,
            "{what}: opaque calls"
        );
        // Every method against its family's single ray, every ray class.
        let all = ctx.tracer().unwrap();
        let tr = all.bvh().unwrap();
        let primary = Class {
            name: "primary",
            rays: rays.clone(),
            active: vec![true; rays.len()],
            kind: RayKind::Primary,
            any: false,
        };
        let hits = reference(&tr, &primary);
        // Shadow rays from the light to just off the hit surfaces.
        let shadow = shadow(&tr, &rays, &hits, s.light, eps);
        let (refl, refr) = secondary(&tr, &rays, &hits, eps);
        let classes = [primary, shadow, refl, refr];
        let (bvh, kd) = (bvh_cases(), kd_cases());
        for c in &classes {
            check_class(&all.bvh().unwrap(), &bvh, &what, c);
            check_class(&all.kd().unwrap(), &kd, &what, c);
        }
        // CGT (its mailbox is the context's) against the 3DDDA.
        for c in &classes {
            let want = answers(&mut ctx, &params(Method::GridDda), c);
            for (n, isa) in [(4, Isa::Auto), (8, Isa::Auto), (16, Isa::Auto)]
                .into_iter()
                .chain([Isa::Sse2, Isa::Avx2, Isa::Avx512].map(|i| (8, i)))
            {
                let p = TraceParams {
                    packet: n,
                    isa,
                    ..params(Method::GridCgt)
                };
                // The rays in packet order (the renderer's packets).
                let order: Vec<usize> = packets(&c.rays, n as usize)
                    .into_iter()
                    .flat_map(|(_, idx)| idx)
                    .collect();
                let c = Class {
                    rays: order.iter().map(|&i| c.rays[i]).collect(),
                    active: Vec::new(),
                    ..*c
                };
                let got = answers(&mut ctx, &p, &c);
                let want: Vec<Hit> = order.iter().map(|&i| want[i]).collect();
                for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert!(
                        g.prim == w.prim && g.t.to_bits() == w.t.to_bits(),
                        "{what} {}: GridCgt {n}x{n} {isa:?} ray {k}: {g:?} want {w:?}",
                        c.name
                    );
                }
            }
        }
        // Filter calls per ray: each method's against its single ray's,
        // the rays in 8x8 packets.
        let ordered: Vec<Ray> = packets(&rays, 8)
            .into_iter()
            .flat_map(|(_, idx)| idx.into_iter().map(|i| rays[i]))
            .collect();
        let mut row = format!("{what}: filter calls per 1000 camera rays:");
        for &m in Method::ALL {
            let p = TraceParams {
                packet: 8,
                ..params(m)
            };
            let at = calls.load(Ordering::Relaxed);
            traced(&mut ctx, &p, &ordered);
            let n = calls.load(Ordering::Relaxed) - at;
            assert!(n > 0, "{what} {m:?}: the filter was never called");
            row += &format!(" {} {}", m.name(), 1000 * n / rays.len() as u64);
        }
        report += &row;
        report.push('\n');
    }
    let (moved, hit) = total;
    assert!(
        moved * 8 >= hit && moved > 0,
        "{} {test:?}: the cut-out moved {moved} of {hit} hits",
        s.name
    );
    report
}

#[test]
fn every_method_equals_its_single_ray_with_a_filter() {
    let scenes = builtin_scenes();
    let items: Vec<_> = scenes
        .iter()
        .flat_map(|s| [(s, TriTest::MollerTrumbore), (s, TriTest::Watertight)])
        .collect();
    for r in par_map(&items, check_scene) {
        print!("{r}");
    }
}

/// The geometries `instances_and_the_flattened_scene_with_filters` cuts.
const CUT: [u32; 3] = [0, 1, 2];

/// The cut-out keeps a two-level hit on a geometry it cuts (its
/// candidate as the geometry's).
fn kept(h: &SceneHit) -> bool {
    !h.is_hit()
        || !CUT.contains(&h.geometry)
        || keep(&Candidate {
            org: [0.0; 3],
            dir: [0.0; 3],
            t: h.t,
            u: h.u,
            v: h.v,
            prim: h.prim,
            geometry: h.geometry,
            instance: h.instance,
        })
}

#[test]
fn instances_and_the_flattened_scene_with_filters() {
    let mut l = Limits::for_triangles(2 * mesh_triangles());
    l.structures = Limits::BVH | Limits::GRID | Limits::KD;
    let mut ctx = scene_in(TriTest::MollerTrumbore, l);
    let info = ctx.commit_scene().unwrap();
    let view = view_of(&info, Vec3::new(0.7, 0.5, 1.1));
    let camera = view.rays(RES as u32, RES as u32);
    let ordered: Vec<Ray> = packets(&camera, 8)
        .iter()
        .flat_map(|(_, idx)| idx.iter().map(|&i| camera[i]))
        .collect();
    let single = |ctx: &mut OwnedContext, ctl: RayControls| {
        let mut h = vec![SceneHit::MISS; ordered.len()];
        ctx.trace_scene(&ordered, ctl, &mut h).unwrap();
        h
    };
    let open = single(&mut ctx, RayControls::default());
    // The geometries of `CUT` cut out; filters on unset ids are refused.
    let calls = AtomicU64::new(0);
    for g in CUT {
        ctx.set_geometry_filter(g, Some(counted(&calls))).unwrap();
    }
    assert!(matches!(
        ctx.set_geometry_filter(9, Some(plain())),
        Err(sheaf::Error::InvalidArgument(_))
    ));
    let cut = single(&mut ctx, RayControls::default());
    let moved = open.iter().zip(&cut).filter(|(a, b)| !same(a, b)).count();
    let hit = open.iter().filter(|h| h.is_hit()).count();
    assert!(moved * 8 >= hit, "the cut-out moved {moved} of {hit} hits");
    assert!(cut.iter().all(kept));
    // Force-opaque rays see the unfiltered scene without a call.
    let at = calls.load(Ordering::Relaxed);
    let opaque = RayControls {
        opaque: true,
        ..RayControls::default()
    };
    assert!(
        single(&mut ctx, opaque)
            .iter()
            .zip(&open)
            .all(|(a, b)| same(a, b))
    );
    assert_eq!(calls.load(Ordering::Relaxed), at);
    // Every BVH method through the instances against the single ray.
    check(
        &mut ctx,
        "filtered camera",
        &ordered,
        8,
        RayKind::Primary,
        &[!0, 2],
    );
    // The grid and the kd-tree over the flattened scene: ids mapped back.
    ctx.build_grid_scene(&sheaf::GridParams::default(), !0)
        .unwrap();
    ctx.build_kd_scene(&sheaf::KdParams::default(), !0).unwrap();
    let with = |ctx: &mut OwnedContext, method, ctl| {
        let p = TraceParams {
            packet: 8,
            ..params(method)
        };
        let mut h = vec![SceneHit::MISS; ordered.len()];
        ctx.trace_scene_with(&p, &ordered, ctl, &mut h).unwrap();
        let mut o = vec![false; ordered.len()];
        ctx.occluded_scene_with(&p, &ordered, ctl, &mut o).unwrap();
        (h, o)
    };
    for (one, many) in [
        (Method::GridDda, &[Method::GridCgt][..]),
        (Method::KdSingle, &[Method::KdSimd, Method::KdPacket][..]),
    ] {
        let (want, want_occ) = with(&mut ctx, one, RayControls::default());
        assert!(want.iter().all(kept), "{one:?}: a rejected hit");
        let (flat_open, _) = with(&mut ctx, one, opaque);
        let moved = want
            .iter()
            .zip(&flat_open)
            .filter(|(a, b)| !same(a, b))
            .count();
        assert!(
            moved * 8 >= hit,
            "{one:?}: the cut-out moved {moved} of {hit} hits"
        );
        for &m in many {
            let (got, occ) = with(&mut ctx, m, RayControls::default());
            for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                assert!(same(g, w), "{m:?} ray {k}: {g:?} want {w:?}");
            }
            assert_eq!(occ, want_occ, "{m:?}: occlusion");
        }
    }
    // An opaque geometry skips its filter.
    let m = sheaf::scenes::builtin("gears").unwrap().mesh;
    let gears = sheaf::Scene::from_f32(&m.vertices, &m.indices).unwrap();
    let p = GeometryParams {
        filter: Some(plain()),
        opaque: true,
        ..GeometryParams::default()
    };
    ctx.set_geometry(1, &gears, &p).unwrap();
    ctx.set_geometry_filter(0, None).unwrap();
    ctx.set_geometry_filter(2, None).unwrap();
    ctx.commit_scene().unwrap();
    let at = calls.load(Ordering::Relaxed);
    let after = single(&mut ctx, RayControls::default());
    assert!(after.iter().zip(&open).all(|(a, b)| same(a, b)));
    assert_eq!(
        calls.load(Ordering::Relaxed),
        at,
        "an opaque geometry's filter was asked"
    );
}

/// Candidates seen by `record`, which keeps what `keep` keeps.
struct Seen(std::sync::Mutex<Vec<Candidate>>);

extern "C" fn record(user: *mut std::ffi::c_void, c: &Candidate) -> bool {
    // SAFETY: the test passes a pointer to a `Seen` that outlives its traces.
    let seen = unsafe { &*(user as *const Seen) };
    seen.0.lock().unwrap().push(*c);
    keep(c)
}

/// Every method hands the filter the ray it traces (its origin and
/// direction, bit for bit) and the single mesh's ids; renders take the
/// calls' force-opaque flag too.
#[test]
fn candidates_carry_the_ray_and_renders_force_opacity() {
    let s = builtin_scenes()
        .into_iter()
        .find(|s| s.name == "gears")
        .unwrap();
    let mut ctx = context(&s, TriTest::MollerTrumbore);
    let seen = Seen(std::sync::Mutex::new(Vec::new()));
    let user = &seen as *const Seen as *mut std::ffi::c_void;
    ctx.set_filter(Some(sheaf::Filter::new(record, user)));
    let (_, view) = &s.views[0];
    let rays = view.rays(RES as u32, RES as u32);
    let ordered: Vec<Ray> = packets(&rays, 8)
        .into_iter()
        .flat_map(|(_, idx)| idx.into_iter().map(|i| rays[i]))
        .collect();
    let bits = |o: [f32; 3], d: [f32; 3]| (o.map(f32::to_bits), d.map(f32::to_bits));
    let known: std::collections::HashSet<_> = ordered.iter().map(|r| bits(r.org, r.dir)).collect();
    for &m in Method::ALL {
        seen.0.lock().unwrap().clear();
        let p = TraceParams {
            packet: 8,
            ..params(m)
        };
        traced(&mut ctx, &p, &ordered);
        let got = std::mem::take(&mut *seen.0.lock().unwrap());
        assert!(!got.is_empty(), "{m:?}: no candidate");
        for c in &got {
            assert!(
                known.contains(&bits(c.org, c.dir)),
                "{m:?}: a candidate of another ray: {c:?}"
            );
            assert!(
                c.geometry == 0 && c.instance == sheaf::geom::INVALID_ID,
                "{m:?}: {c:?}"
            );
            assert!(
                c.t > 0.0 && c.u >= 0.0 && c.v >= 0.0 && c.u + c.v <= 1.0 + 1e-6,
                "{m:?}: {c:?}"
            );
        }
    }
    // A frame (camera and shadow rays) with force-opaque parameters is the
    // unfiltered frame, without a call; without the flag the cut-out shows.
    let frame = sheaf::Frame {
        camera: sheaf::Camera {
            eye: view.eye.to_array(),
            look_at: view.look_at.to_array(),
            up: view.up.to_array(),
            fov_y_deg: view.fov_y_deg,
        },
        light: sheaf::PointLight::new(s.light.to_array(), [0.9, 0.8, 0.7]),
        shading: sheaf::Shading::default(),
        width: 64,
        height: 48,
    };
    let render = |ctx: &mut OwnedContext, opaque: bool| {
        let p = TraceParams {
            packet: 8,
            opaque,
            ..params(Method::BvhFrustum)
        };
        let mut px = vec![0u8; 64 * 48 * 4];
        ctx.render_with(&p, &p, &frame, &mut px, 64 * 4).unwrap();
        px
    };
    ctx.set_filter(None);
    let open = render(&mut ctx, false);
    ctx.set_filter(Some(sheaf::Filter::new(record, user)));
    seen.0.lock().unwrap().clear();
    assert_eq!(render(&mut ctx, true), open, "force-opaque frame");
    assert!(
        seen.0.lock().unwrap().is_empty(),
        "force-opaque frame asked the filter"
    );
    assert_ne!(
        render(&mut ctx, false),
        open,
        "the cut-out does not show in the frame"
    );
}
