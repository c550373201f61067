//! Thread-slot scratch follows the limits: each family's calls, driven at
//! the largest packet side the limits allow (every packet method, triangle
//! test, entry search and frustum kind, nearest and occlusion, with a
//! tiny-direction lane so the tiny-lane split runs too), use at
//! most the bytes `slot_scratch_bytes` declares for those limits, and no
//! more than a little alignment padding less (the slots' high-water mark,
//! `Context::scratch_high_water`). Calls beyond the limits get a status,
//! never a panic. The renderers are measured the same way: packet tiles,
//! Whitted frames at their deepest bounce, deferred frames.

use sheaf::accel::bvh::BvhParams;
use sheaf::accel::kd::KdParams;
use sheaf::render::{Camera, Frame, PointLight, Shading};
use sheaf::scenes::{BuiltinScene, builtin};
use sheaf::trace::{EntrySearch, RayKind, Structure};
use sheaf::{Affine, GeometryParams, SceneHit};
use sheaf::{
    Context, DeferredJob, Error, GridParams, Hit, Limits, Method, OnCaller, OwnedContext,
    PgridParams, PrimaryPass, Ray, Scene, ShadowPass, TraceParams, TriTest, slot_scratch_bytes,
};
use sheaf::{Isa, Material, Materials, Pool, WhittedJob, WhittedParams};

const TESTS: [TriTest; 3] = [
    TriTest::MollerTrumbore,
    TriTest::Watertight,
    TriTest::Projection,
];

/// Bytes a slot may reserve beyond the deepest call: each declared array
/// may need up to its alignment less one byte of padding, and the slot is
/// rounded up to 64 bytes.
const SLACK: usize = 1024;

fn limits(s: &BuiltinScene, structures: u32, side: u32, renderers: u32) -> Limits {
    let mut l = Limits::for_triangles(s.mesh.triangle_count() as u32);
    l.max_vertices = s.mesh.vertex_count() as u32;
    l.structures = structures;
    l.projection_test = true;
    l.max_packet_side = side;
    l.renderers = renderers;
    l.max_image_width = 64;
    l.max_image_height = 64;
    l.max_threads = 1;
    l
}

/// `side` x `side` rays from the scene's reference view, lane 0 with a
/// tiny direction towards the scene (the tiny-lane split), and as many again from
/// the light towards the scene (finite, for the shadow kinds).
fn rays(s: &BuiltinScene, side: u32) -> Vec<Ray> {
    let v = s.views[0];
    let fwd = (v.look_at - v.eye).normalize();
    let right = fwd.cross(v.up).normalize();
    let up = right.cross(fwd);
    let mut rays = Vec::new();
    for (org, aim) in [(v.eye, v.look_at), (s.light, v.look_at)] {
        let d = (aim - org).length();
        for k in 0..side * side {
            let (x, y) = (
                (k % side) as f32 / side as f32 - 0.5,
                (k / side) as f32 / side as f32 - 0.5,
            );
            // A narrow cone: one coherent packet, as a camera tile.
            let dir = fwd * d + (right * x + up * y) * 0.05 * d;
            rays.push(Ray {
                org: org.to_array(),
                dir: dir.to_array(),
                tmin: 0.0,
                tmax: if org == v.eye { f32::INFINITY } else { 0.999 },
            });
        }
    }
    // Tiny, and aimed at the scene, so it enters the two-level scene's
    // instances too (the split under the top level).
    rays[0].dir = (fwd * 1e-20).to_array();
    rays
}

/// Trace `rays` in packets of `side` with `p`'s method, nearest and any
/// hit; combinations the method does not take (`InvalidArgument`) are
/// skipped, any other error fails.
fn trace_all(ctx: &mut Context<'_>, p: &TraceParams, rays: &[Ray]) -> bool {
    let mut hits = vec![Hit::MISS; rays.len()];
    let mut occ = vec![false; rays.len()];
    match ctx.trace_with(p, rays, &mut hits) {
        Err(Error::InvalidArgument(_)) => return false,
        r => r.unwrap_or_else(|e| panic!("{p:?}: {e}")),
    };
    ctx.occluded_with(p, rays, &mut occ)
        .unwrap_or_else(|e| panic!("{p:?}: {e}"));
    true
}

/// Every packet method of `structure` at side `side`, with every lane
/// width (the widest groups are not always the widest lanes), entry
/// search and split, and for the frustum packets every ray kind.
fn params_of(structure: Structure, side: u32) -> Vec<TraceParams> {
    let mut out = Vec::new();
    for &method in Method::ALL {
        if !method.is_packet() || method.structure() != structure {
            continue;
        }
        let frustum = method == Method::BvhFrustum;
        let kinds: &[RayKind] = if frustum {
            &[
                RayKind::Auto,
                RayKind::Primary,
                RayKind::Shadow,
                RayKind::Secondary,
            ]
        } else {
            &[RayKind::Auto]
        };
        // Renderers split shadow packets in depth by `split` (0: whole).
        let splits: &[f32] = &[0.0, 2.0];
        for &isa in Isa::ALL {
            for &entry in EntrySearch::ALL {
                for &kind in kinds {
                    for &split in splits {
                        let mut p = TraceParams {
                            method,
                            packet: side,
                            entry,
                            split,
                            isa,
                            ..TraceParams::default()
                        };
                        p.bvh.kind = kind;
                        out.push(p);
                    }
                }
            }
        }
    }
    out
}

fn check(what: &str, ctx: &mut Context<'_>, l: &Limits) {
    check_less(what, ctx, l, 0);
}

/// `check`, for calls that may not reach `unreached` of the declared bytes
/// (allowed on top of the padding).
fn check_less(what: &str, ctx: &mut Context<'_>, l: &Limits, unreached: usize) {
    let used = ctx.scratch_high_water();
    let declared = slot_scratch_bytes(l);
    println!("{what}: {used} of {declared} bytes per slot");
    assert!(used <= declared, "{what}: {used} > {declared}");
    assert!(
        declared - used <= SLACK + unreached,
        "{what}: {declared} bytes declared, {used} used: the declaration is {} bytes too large",
        declared - used - unreached
    );
}

#[test]
fn each_family_uses_the_scratch_its_limits_declare() {
    let s = builtin("balls").unwrap();
    let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
    for side in [8u32, 32] {
        let rays = rays(&s, side);
        for (name, bit, structure) in [
            ("grid", Limits::GRID, Structure::Grid),
            ("bvh", Limits::BVH, Structure::Bvh),
            ("kd", Limits::KD, Structure::Kd),
        ] {
            let l = limits(&s, bit, side, 0);
            let mut owned = OwnedContext::new(&l).unwrap();
            let ctx = &mut owned;
            let mut traced = 0;
            for test in TESTS {
                match structure {
                    Structure::Grid => {
                        let g = GridParams {
                            test,
                            ..GridParams::default()
                        };
                        ctx.build_grid(&scene, &g).unwrap();
                    }
                    Structure::Bvh => {
                        let b = BvhParams {
                            test,
                            ..BvhParams::default()
                        };
                        ctx.build_bvh(&scene, &b).unwrap();
                    }
                    Structure::Kd => {
                        let k = KdParams {
                            test,
                            ..KdParams::default()
                        };
                        ctx.build_kd(&scene, &k).unwrap();
                    }
                }
                for p in params_of(structure, side) {
                    traced += trace_all(ctx, &p, &rays) as usize;
                }
            }
            assert!(traced > 0, "{name}: no packet method traced");
            check(&format!("{name}, {side}x{side} packets"), ctx, &l);

            // A packet larger than the limits: a status, nothing traced.
            if side < 32 {
                let p = TraceParams {
                    method: params_of(structure, side)[0].method,
                    packet: 2 * side,
                    ..TraceParams::default()
                };
                let mut hits = vec![Hit::MISS; rays.len()];
                assert_eq!(
                    ctx.trace_with(&p, &rays, &mut hits).err(),
                    Some(Error::Capacity {
                        pool: Pool::PacketSide,
                        needed: 2 * side as u64,
                        available: side as u64,
                    })
                );
                assert!(hits.iter().all(|h| *h == Hit::MISS));
            }
        }
    }
}

/// Two parallel mirrors, z = -1 and z = 1: rays between them bounce for
/// ever and stay coherent, as do shadow rays from a light off to one side.
fn mirrors() -> (Vec<f32>, Vec<u32>) {
    let mut v = Vec::new();
    for z in [-1.0f32, 1.0] {
        for (x, y) in [
            (-100.0, -100.0),
            (1000.0, -100.0),
            (1000.0, 1000.0),
            (-100.0, 1000.0),
        ] {
            v.extend_from_slice(&[x, y, z]);
        }
    }
    (v, vec![0, 1, 2, 0, 2, 3, 4, 6, 5, 4, 7, 6])
}

#[test]
fn the_two_level_scene_uses_the_scratch_its_limits_declare() {
    let s = builtin("balls").unwrap();
    let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
    for side in [8u32, 32] {
        let rays = rays(&s, side);
        let mut l = limits(&s, Limits::BVH, side, 0);
        l.max_geometries = 1;
        l.max_instances = 2;
        let mut owned = OwnedContext::new(&l).unwrap();
        let mut traced = 0;
        for test in TESTS {
            let g = GeometryParams {
                bvh: BvhParams {
                    test,
                    ..BvhParams::default()
                },
                ..GeometryParams::default()
            };
            owned.set_geometry(0, &scene, &g).unwrap();
            owned.set_instance(0, 0, &Affine::IDENTITY, !0).unwrap();
            owned
                .set_instance(1, 0, &Affine::translation([0.5, 0.0, 0.0]), !0)
                .unwrap();
            owned.commit_scene().unwrap();
            let mut hits = vec![SceneHit::MISS; rays.len()];
            let mut occ = vec![false; rays.len()];
            for p in params_of(Structure::Bvh, side) {
                match owned.trace_scene_with(&p, &rays, !0u32, &mut hits) {
                    Err(Error::InvalidArgument(_)) => continue,
                    r => r.unwrap_or_else(|e| panic!("{p:?}: {e}")),
                };
                owned
                    .occluded_scene_with(&p, &rays, !0u32, &mut occ)
                    .unwrap_or_else(|e| panic!("{p:?}: {e}"));
                traced += 1;
            }
        }
        assert!(traced > 0);
        check(&format!("two-level, {side}x{side} packets"), &mut owned, &l);
    }
}

fn frame_of(s: &BuiltinScene) -> Frame {
    Frame {
        camera: s.views[0].camera(),
        light: PointLight::new(s.light.to_array(), [1.0; 3]),
        shading: Shading::default(),
        width: 64,
        height: 64,
    }
}

/// Build the BVH with `test` and run `render` with every BVH packet method
/// at every lane width.
fn each_bvh_method(
    ctx: &mut Context<'_>,
    scene: &Scene<'_>,
    side: u32,
    mut render: impl FnMut(&mut Context<'_>, TraceParams),
) {
    for test in TESTS {
        let b = BvhParams {
            test,
            ..BvhParams::default()
        };
        ctx.build_bvh(scene, &b).unwrap();
        for p in params_of(Structure::Bvh, side) {
            if p.entry == EntrySearch::None && p.bvh.kind == RayKind::Auto {
                render(ctx, p);
            }
        }
    }
}

/// The tiny-direction split (`accel::packet::quieted`: a quad, its lanes, its tiny
/// lanes per quad), which rendered rays, none of them tiny, never take.
fn tiny_split(side: u32) -> usize {
    use sheaf::accel::packet::{quads, scratch};
    scratch(quads(side))
}

#[test]
fn each_renderer_uses_the_scratch_its_limits_declare() {
    let s = builtin("balls").unwrap();
    let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
    let frame = frame_of(&s);
    let mut px = vec![0u8; 64 * 64 * 4];
    let stride = 64 * 4;
    for side in [8u32, 32] {
        // Packet tiles.
        let l = limits(&s, Limits::BVH, side, Limits::TILES);
        let mut owned = OwnedContext::new(&l).unwrap();
        each_bvh_method(&mut owned, &scene, side, |ctx, p| {
            ctx.render_with(&p, &p, &frame, &mut px, stride).unwrap();
        });
        let split = tiny_split(side);
        check_less(&format!("tiles, {side}x{side}"), &mut owned, &l, split);

        // Whitted frames at their deepest bounce, for a few limits: every
        // ray reflects at every bounce, in coherent packets.
        let mirror = Material {
            reflect: 1.0,
            ..Material::diffuse([0.5; 3])
        };
        let (mv, mi) = mirrors();
        let between = Scene::from_f32(&mv, &mi).unwrap();
        let inside = Frame {
            camera: Camera {
                eye: [0.0, 0.0, 0.0],
                look_at: [10.0, 10.0, -3.0],
                up: [0.0, 0.0, 1.0],
                fov_y_deg: 20.0,
            },
            light: PointLight::new([-50.0, -50.0, 0.5], [1.0; 3]),
            ..frame
        };
        let job = |reflect, p| {
            let params = WhittedParams {
                max_reflect: reflect,
                max_refract: 0,
            };
            WhittedJob::new(&inside, Materials::uniform(&mirror), params, p)
        };
        for bounces in [0u32, 3, 8] {
            let mut l = limits(&s, Limits::BVH, side, Limits::WHITTED);
            l.max_bounces = bounces;
            let mut owned = OwnedContext::new(&l).unwrap();
            each_bvh_method(&mut owned, &between, side, |ctx, p| {
                ctx.render_whitted(&job(bounces, p), &mut px, stride)
                    .unwrap();
            });
            let what = format!("whitted, {side}x{side}, {bounces} bounces");
            // Each level's arrays may leave their own alignment padding.
            check_less(&what, &mut owned, &l, split + 320 * bounces as usize);
            // One more bounce than the limits allow (9 is beyond any
            // context's: `InvalidArgument`).
            let p = params_of(Structure::Bvh, side)[0];
            let err = owned
                .render_whitted(&job(bounces + 1, p), &mut px, stride)
                .err();
            if bounces < 8 {
                let beyond = Error::Capacity {
                    pool: Pool::Bounces,
                    needed: bounces as u64 + 1,
                    available: bounces as u64,
                };
                assert_eq!(err, Some(beyond));
            } else {
                assert!(matches!(err, Some(Error::InvalidArgument(_))), "{err:?}");
            }
        }

        // Deferred frames: the perspective and light grids, and traced
        // passes.
        let l = limits(&s, Limits::BVH | Limits::PGRID, side, Limits::DEFERRED);
        let mut owned = OwnedContext::new(&l).unwrap();
        let deferred = |ctx: &mut Context<'_>, primary, shadow, px: &mut [u8]| {
            let job = DeferredJob {
                frame: &frame,
                lights: &[],
                primary,
                shadow,
            };
            ctx.render_deferred(&job, px, stride, &mut OnCaller)
                .unwrap();
        };
        for test in TESTS {
            for &isa in Isa::ALL {
                // Few light tiles: full shadow batches.
                let pg = PgridParams {
                    tile: side,
                    group: 1,
                    test,
                    isa,
                    light_tiles: 2,
                    ..PgridParams::default()
                };
                match owned.build_pgrid(&scene, &pg) {
                    Err(Error::InvalidArgument(_)) => continue, // not this CPU
                    r => r.unwrap(),
                };
                deferred(
                    &mut owned,
                    PrimaryPass::Pgrid,
                    ShadowPass::LightGrid,
                    &mut px,
                );
            }
        }
        each_bvh_method(&mut owned, &scene, side, |ctx, p| {
            deferred(ctx, PrimaryPass::Traced(p), ShadowPass::Traced(p), &mut px);
        });
        check_less(&format!("deferred, {side}x{side}"), &mut owned, &l, split);

        // A renderer left out of the limits: a status.
        let p = params_of(Structure::Bvh, side)[0];
        let err = owned.render_with(&p, &p, &frame, &mut px, stride).err();
        assert!(matches!(err, Some(Error::InvalidArgument(_))), "{err:?}");
        // A sorting tile larger than the packets: a status.
        let pg = PgridParams {
            tile: 2 * side,
            ..PgridParams::default()
        };
        if side < 32 {
            assert!(matches!(
                owned.build_pgrid(&scene, &pg).err(),
                Some(Error::Capacity {
                    pool: Pool::PacketSide,
                    ..
                })
            ));
        }
    }
}

#[test]
fn smaller_limits_reserve_less() {
    let l = Limits::for_triangles(1000);
    let shadow8 = Limits {
        max_packet_side: 8,
        renderers: 0,
        structures: Limits::BVH,
        ..l
    };
    let whitted32 = Limits {
        renderers: Limits::WHITTED,
        structures: Limits::BVH,
        ..l
    };
    let (d, s8, w32) = (
        slot_scratch_bytes(&l),
        slot_scratch_bytes(&shadow8),
        slot_scratch_bytes(&whitted32),
    );
    println!("bytes per slot: default limits {d}, 8x8 BVH packets only {s8}, 32x32 Whitted {w32}");
    assert!(
        s8 * 8 < d,
        "8x8 packets alone should need far less: {s8} of {d}"
    );
    // The Whitted tile is the largest caller: 32x32 Whitted alone needs
    // what every renderer together needs.
    assert_eq!(w32, d);
    // required_bytes counts them once per slot (with a slot's few other
    // words: its packet counter, mark and claim flag, rounded up).
    let per_slot = |l: &Limits| {
        let one = Limits {
            max_threads: 1,
            ..*l
        };
        let two = Limits {
            max_threads: 2,
            ..*l
        };
        sheaf::required_bytes(&two).unwrap() - sheaf::required_bytes(&one).unwrap()
    };
    for (l, bytes) in [(shadow8, s8), (whitted32, w32)] {
        assert!((bytes..bytes + 256).contains(&per_slot(&l)), "{l:?}");
    }
}
