//! The context contract: exact memory, validation, capacity errors that leave
//! the previous frame intact, exclusions counted, robust rays.

mod common;

use sheaf::geom::INVALID_ID;
use sheaf::{
    Band, BuildQuality, BvhParams, Context, Error, GridParams, Hit, Limits, Method, OwnedContext,
    Pool, Ray, Scene, required_bytes,
};

/// 64-byte aligned scratch buffer for `Context::new_in`.
fn aligned(bytes: usize) -> Vec<u8> {
    // Over-allocate, then the tests slice at an aligned offset.
    vec![0u8; bytes + 128]
}
fn aligned_slice(buf: &mut [u8], len: usize) -> &mut [u8] {
    let off = buf.as_ptr().align_offset(64);
    &mut buf[off..off + len]
}

fn two_quads() -> (Vec<f32>, Vec<u32>) {
    // Quad A at z = 0 and quad B at z = 1, both spanning [-1, 1]^2.
    let v = vec![
        -1.0, -1.0, 0.0, 1.0, -1.0, 0.0, 1.0, 1.0, 0.0, -1.0, 1.0, 0.0, //
        -1.0, -1.0, 1.0, 1.0, -1.0, 1.0, 1.0, 1.0, 1.0, -1.0, 1.0, 1.0,
    ];
    let i = vec![0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7];
    (v, i)
}

fn down_rays() -> Vec<Ray> {
    (0..16)
        .map(|k| {
            let x = -0.9 + 0.12 * (k % 4) as f32;
            let y = -0.8 + 0.11 * (k / 4) as f32;
            Ray {
                org: [x, y, 5.0],
                tmin: 0.0,
                dir: [0.0, 0.0, -1.0],
                tmax: f32::INFINITY,
            }
        })
        .collect()
}

#[test]
fn required_bytes_is_exact() {
    let limits = Limits::for_triangles(1000);
    let need = required_bytes(&limits).unwrap();
    let mut buf = aligned(need);
    assert!(Context::new_in(aligned_slice(&mut buf, need), &limits).is_ok());
    let short = Context::new_in(aligned_slice(&mut buf, need - 1), &limits).err();
    assert_eq!(
        short,
        Some(Error::BufferTooSmall {
            needed: need as u64,
            available: need as u64 - 1
        })
    );
    let off = buf.as_ptr().align_offset(64) + 8;
    let mis = Context::new_in(&mut buf[off..off + need], &limits).err();
    assert_eq!(mis, Some(Error::Misaligned { required: 64 }));
}

#[test]
fn bad_limits_are_rejected() {
    let mut l = Limits::for_triangles(10);
    l.max_threads = 0;
    assert!(matches!(required_bytes(&l), Err(Error::InvalidArgument(_))));
    let mut l = Limits::for_triangles(10);
    l.max_tile = 3;
    assert!(matches!(
        OwnedContext::new(&l),
        Err(Error::InvalidArgument(_))
    ));
}

#[test]
fn out_of_range_index_is_an_error() {
    let (v, mut i) = two_quads();
    i[7] = 8;
    let e = Scene::from_f32(&v, &i).err();
    assert_eq!(
        e,
        Some(Error::IndexOutOfRange {
            triangle: 2,
            index: 8,
            vertex_count: 8
        })
    );
    assert!(matches!(
        Scene::new(bytemuck::cast_slice(&v), 10, 8, &i),
        Err(Error::InvalidArgument(_))
    ));
    assert!(matches!(
        Scene::new(bytemuck::cast_slice(&v), 16, 8, &i),
        Err(Error::InvalidArgument(_))
    ));
}

#[test]
fn trace_before_build_is_not_built() {
    let mut ctx = OwnedContext::new(&Limits::for_triangles(4)).unwrap();
    let rays = down_rays();
    let mut hits = vec![Hit::MISS; rays.len()];
    assert_eq!(
        ctx.trace(Method::GridDda, &rays, &mut hits),
        Err(Error::NotBuilt)
    );
}

#[test]
fn nearest_hits_and_occlusion_on_two_quads() {
    let (v, i) = two_quads();
    let mut ctx = OwnedContext::new(&Limits::for_triangles(4)).unwrap();
    ctx.build_grid(&Scene::from_f32(&v, &i).unwrap(), &GridParams::default())
        .unwrap();
    let rays = down_rays();
    let mut hits = vec![Hit::MISS; rays.len()];
    ctx.trace(Method::GridDda, &rays, &mut hits).unwrap();
    for h in &hits {
        assert!(h.prim == 2 || h.prim == 3, "upper quad first: {h:?}");
        assert_eq!(h.t, 4.0);
    }
    // Shadow rays from below the lower quad to above the upper one are blocked,
    // rays that stop between the quads are blocked by the lower quad only when it is crossed.
    let up: Vec<Ray> = rays
        .iter()
        .map(|r| Ray {
            org: [r.org[0], r.org[1], 0.5],
            dir: [0.0, 0.0, 1.0],
            tmax: 0.4,
            ..*r
        })
        .collect();
    let mut occ = vec![true; up.len()];
    ctx.occluded(Method::GridDda, &up, &mut occ).unwrap();
    assert!(
        occ.iter().all(|o| !o),
        "segments between the quads are free"
    );
    let through: Vec<Ray> = up.iter().map(|r| Ray { tmax: 0.6, ..*r }).collect();
    ctx.occluded(Method::GridDda, &through, &mut occ).unwrap();
    assert!(
        occ.iter().all(|o| *o),
        "segments crossing the upper quad are blocked"
    );
    assert!(ctx.stats().counters.rays as usize == through.len());
}

#[test]
fn non_finite_and_zero_area_triangles_are_excluded_and_counted() {
    let (mut v, mut i) = two_quads();
    v[0] = f32::NAN; // vertex 0: triangles 0 and 1
    i.extend_from_slice(&[4, 4, 5]); // zero area (repeated vertex)
    i.extend_from_slice(&[4, 5, 5]);
    let mut ctx = OwnedContext::new(&Limits::for_triangles(8)).unwrap();
    let info = ctx
        .build_grid(&Scene::from_f32(&v, &i).unwrap(), &GridParams::default())
        .unwrap();
    assert_eq!(
        (
            info.triangles_in,
            info.triangles,
            info.excluded_non_finite,
            info.excluded_zero_area
        ),
        (6, 2, 2, 2)
    );
    let rays = down_rays();
    let mut hits = vec![Hit::MISS; rays.len()];
    ctx.trace(Method::GridDda, &rays, &mut hits).unwrap();
    assert!(hits.iter().all(|h| h.prim == 2 || h.prim == 3));
}

#[test]
fn capacity_errors_name_the_pool_and_keep_the_previous_grid() {
    let (v, i) = two_quads();
    let mut limits = Limits::for_triangles(4);
    limits.max_grid_refs = 64;
    limits.max_grid_cells = 1_000_000;
    // lambda 1000 x 4 triangles wants about 4000 cells: fits the cell pool
    // but not the 64 references.
    let mut ctx = OwnedContext::new(&limits).unwrap();
    let scene = Scene::from_f32(&v, &i).unwrap();
    let before = ctx.build_grid(&scene, &GridParams::default()).unwrap();
    let rays = down_rays();
    let mut hits0 = vec![Hit::MISS; rays.len()];
    ctx.trace(Method::GridDda, &rays, &mut hits0).unwrap();

    // Too many triangles.
    let (v2, i2) = {
        let mut v2 = v.clone();
        v2.extend_from_slice(&v);
        let mut i2 = i.clone();
        i2.extend(i.iter().map(|x| x + 8));
        (v2, i2)
    };
    let big = Scene::from_f32(&v2, &i2).unwrap();
    assert_eq!(
        ctx.build_grid(&big, &GridParams::default()).err(),
        Some(Error::Capacity {
            pool: Pool::Triangles,
            needed: 8,
            available: 4
        })
    );
    // Too many references: a high lambda makes each quad cover many cells.
    let err = ctx
        .build_grid(
            &scene,
            &GridParams {
                lambda: 1000.0,
                ..GridParams::default()
            },
        )
        .err();
    match err {
        Some(Error::Capacity {
            pool: Pool::GridRefs,
            needed,
            available: 64,
        }) => assert!(needed > 64),
        other => panic!("expected a grid_refs capacity error, got {other:?}"),
    }
    let msg = format!("{}", err.unwrap());
    assert!(
        msg.contains("grid_refs") && msg.contains("available 64"),
        "{msg}"
    );
    // Too many cells without fit (another context); fit mode lowers lambda instead.
    let mut few_cells = Limits::for_triangles(4);
    few_cells.max_grid_cells = 20;
    let mut small = OwnedContext::new(&few_cells).unwrap();
    let err = small
        .build_grid(
            &scene,
            &GridParams {
                lambda: 50.0,
                ..GridParams::default()
            },
        )
        .err();
    assert!(
        matches!(
            err,
            Some(Error::Capacity {
                pool: Pool::GridCells,
                available: 20,
                ..
            })
        ),
        "{err:?}"
    );

    // The previous grid is intact: same info, same hits.
    assert_eq!(ctx.stats().grid, before);
    let mut hits1 = vec![Hit::MISS; rays.len()];
    ctx.trace(Method::GridDda, &rays, &mut hits1).unwrap();
    assert_eq!(hits0, hits1);

    let mut fit_limits = Limits::for_triangles(4);
    fit_limits.max_grid_cells = 20;
    let mut fit = OwnedContext::new(&fit_limits).unwrap();
    let info = fit
        .build_grid(
            &scene,
            &GridParams {
                lambda: 50.0,
                fit: true,
                ..GridParams::default()
            },
        )
        .unwrap();
    assert!(info.cells() <= 20 && info.lambda < 50.0, "{info:?}");
}

/// Fuzz run 8's one finding: a context whose limits hold no triangles
/// carves no BVH build scratch, and the LOW build of the empty scene took
/// that scratch before seeing it had nothing to sort (a panic, which the C
/// ABI turned into `POISONED`). Every build quality builds the empty scene
/// there, and rays miss.
#[test]
fn a_context_of_no_triangles_builds_the_empty_scene() {
    let mut ctx = OwnedContext::new(&Limits::for_triangles(0)).unwrap();
    for quality in [BuildQuality::Low, BuildQuality::Medium, BuildQuality::High] {
        let p = BvhParams {
            quality,
            ..BvhParams::default()
        };
        let info = ctx.build_bvh(&Scene::empty(), &p).unwrap();
        assert_eq!((info.triangles, info.quality), (0, quality));
        let mut hits = vec![Hit::MISS; 16];
        ctx.trace(Method::BvhRanged, &down_rays(), &mut hits)
            .unwrap();
        assert!(hits.iter().all(|h| h.prim == INVALID_ID));
    }
}

#[test]
fn empty_scene_and_invalid_rays_miss() {
    let mut ctx = OwnedContext::new(&Limits::for_triangles(4)).unwrap();
    ctx.build_grid(&Scene::empty(), &GridParams::default())
        .unwrap();
    let mut hits = vec![Hit::MISS; 16];
    ctx.trace(Method::GridDda, &down_rays(), &mut hits).unwrap();
    assert!(hits.iter().all(|h| h.prim == INVALID_ID));

    let (v, i) = two_quads();
    ctx.build_grid(&Scene::from_f32(&v, &i).unwrap(), &GridParams::default())
        .unwrap();
    let base = Ray {
        org: [0.1, 0.1, 5.0],
        tmin: 0.0,
        dir: [0.0, 0.0, -1.0],
        tmax: f32::INFINITY,
    };
    let bad = [
        Ray {
            dir: [0.0, 0.0, 0.0],
            ..base
        },
        Ray {
            dir: [f32::NAN, 0.0, -1.0],
            ..base
        },
        Ray {
            org: [f32::INFINITY, 0.0, 5.0],
            ..base
        },
        Ray {
            tmin: 2.0,
            tmax: 1.0,
            ..base
        },
        Ray { tmin: -1.0, ..base },
        Ray {
            dir: [f32::INFINITY, 0.0, -1.0],
            ..base
        },
    ];
    let mut hits = vec![
        Hit {
            t: 1.0,
            prim: 0,
            u: 0.0,
            v: 0.0
        };
        bad.len()
    ];
    ctx.trace(Method::GridDda, &bad, &mut hits).unwrap();
    assert!(hits.iter().all(|h| *h == Hit::MISS), "{hits:?}");
}

#[test]
fn rays_along_grid_axes_and_inside_the_grid_are_exact() {
    // Rays with two zero direction components, starting inside the grid,
    // along cell boundaries, match brute force.
    let s = common::builtin_scenes()
        .into_iter()
        .find(|s| s.name == "tetra")
        .unwrap();
    let scene = s.scene();
    let mut ctx = OwnedContext::new(&Limits::for_triangles(s.triangles())).unwrap();
    let info = ctx.build_grid(&scene, &GridParams::default()).unwrap();
    let (lo, hi) = (info.bounds.min, info.bounds.max);
    let mut rays = Vec::new();
    for k in 0..=8 {
        for j in 0..=8 {
            let f = |a: f32, b: f32, t: f32| a + (b - a) * t;
            let (u, w) = (k as f32 / 8.0, j as f32 / 8.0);
            for axis in 0..3 {
                for sign in [1.0f32, -1.0] {
                    let mut o = [f(lo.x, hi.x, u), f(lo.y, hi.y, w), f(lo.z, hi.z, 0.5)];
                    o.rotate_right(axis);
                    let mut d = [0.0, 0.0, sign];
                    d.rotate_right(axis);
                    rays.push(Ray {
                        org: o,
                        tmin: 0.0,
                        dir: d,
                        tmax: f32::INFINITY,
                    });
                }
            }
        }
    }
    let mut hits = vec![Hit::MISS; rays.len()];
    ctx.trace(Method::GridDda, &rays, &mut hits).unwrap();
    let mut hit_count = 0;
    for (r, h) in rays.iter().zip(&hits) {
        let want = sheaf::reference::nearest(&scene, r);
        if want.prim != h.prim {
            let want = sheaf::reference::with_edge_distance(&scene, r, want);
            assert!(
                want.gap <= 1e-5 || want.edge <= 1e-5,
                "{r:?}: got {h:?}, f64 {want:?}"
            );
        }
        hit_count += h.is_hit() as u32;
    }
    assert!(
        hit_count > 50,
        "the axis rays must hit the tetrahedra ({hit_count})"
    );
}

#[test]
fn projection_test_needs_its_pool() {
    let (v, i) = two_quads();
    let scene = Scene::from_f32(&v, &i).unwrap();
    let p = GridParams {
        test: sheaf::TriTest::Projection,
        ..GridParams::default()
    };
    let mut ctx = OwnedContext::new(&Limits::for_triangles(4)).unwrap();
    assert!(matches!(
        ctx.build_grid(&scene, &p),
        Err(Error::InvalidArgument(_))
    ));
    let mut l = Limits::for_triangles(4);
    l.projection_test = true;
    // One projection pool per structure with pools (grid, BVH and kd-tree by default).
    let extra = sheaf::mem::pool_bytes::<sheaf::geom::ProjTri>(4);
    assert_eq!(
        required_bytes(&l).unwrap(),
        required_bytes(&Limits::for_triangles(4)).unwrap() + 3 * extra
    );
    let grid_only = |mut l: Limits| {
        l.structures = Limits::GRID;
        l
    };
    assert_eq!(
        required_bytes(&grid_only(l)).unwrap(),
        required_bytes(&grid_only(Limits::for_triangles(4))).unwrap() + extra
    );
    let mut ctx = OwnedContext::new(&l).unwrap();
    ctx.build_grid(&scene, &p).unwrap();
    let rays = down_rays();
    let mut hits = vec![Hit::MISS; rays.len()];
    ctx.trace(Method::GridDda, &rays, &mut hits).unwrap();
    assert!(
        hits.iter()
            .all(|h| (h.prim == 2 || h.prim == 3) && h.t == 4.0),
        "{hits:?}"
    );
}

/// Threads sharing `&OwnedContext`, each with its own slot, render bands of
/// a frame (CGT packets with mailboxes, BVH packets) and trace packets: the
/// image equals the one-call render byte for byte, the hits the exclusive
/// `trace_with`'s. A slot out of range or held by another call is refused.
#[test]
fn threads_with_their_own_slots_render_the_same_frame() {
    use sheaf::scenes::builtin;
    use sheaf::{Camera, Frame, PointLight, Shading, TraceParams};
    let sc = builtin("gears").unwrap();
    let scene = Scene::from_f32(&sc.mesh.vertices, &sc.mesh.indices).unwrap();
    let mut limits = Limits::for_triangles(sc.mesh.triangle_count() as u32);
    limits.max_threads = 3;
    let mut ctx = OwnedContext::new(&limits).unwrap();
    ctx.build_grid(&scene, &GridParams::default()).unwrap();
    ctx.build_bvh(&scene, &Default::default()).unwrap();
    let v = sc.views[0];
    let frame = Frame {
        camera: Camera {
            eye: v.eye.to_array(),
            look_at: v.look_at.to_array(),
            up: v.up.to_array(),
            fov_y_deg: v.fov_y_deg,
        },
        light: PointLight {
            position: sc.light.to_array(),
            color: [1.0; 3],
            ..Default::default()
        },
        shading: Shading::default(),
        width: 80,
        height: 72,
    };
    let stride = 4 * 80 + 12;
    for method in [Method::GridCgt, Method::BvhRanged] {
        let p = TraceParams {
            method,
            packet: 8,
            ..TraceParams::default()
        };
        let mut want = vec![0u8; stride * 72];
        ctx.render_with(&p, &p, &frame, &mut want, stride).unwrap();
        let rays: Vec<Ray> = (0..72 * 80)
            .map(|k| {
                let (x, y) = (k % 80, k / 80);
                let d = (x as f32 - 40.0, y as f32 - 36.0);
                Ray {
                    org: v.eye.to_array(),
                    tmin: 0.0,
                    dir: (v.look_at - v.eye + glam::Vec3::new(d.0, d.1, 0.0) * 0.05).to_array(),
                    tmax: f32::INFINITY,
                }
            })
            .collect();
        let mut want_hits = vec![Hit::MISS; rays.len()];
        ctx.trace_with(&p, &rays, &mut want_hits).unwrap();
        assert!(want_hits.iter().filter(|h| h.is_hit()).count() > rays.len() / 4);
        let mut got = vec![0u8; stride * 72];
        let shared = &ctx;
        std::thread::scope(|s| {
            // Bands of 13 rows (not a multiple of the tile side), three threads.
            let bands: Vec<(u32, &mut [u8])> = got
                .chunks_mut(13 * stride)
                .enumerate()
                .map(|(i, b)| (13 * i as u32, b))
                .collect();
            let mut per_slot: [Vec<(u32, &mut [u8])>; 3] = Default::default();
            for (i, b) in bands.into_iter().enumerate() {
                per_slot[i % 3].push(b);
            }
            for (slot, bands) in per_slot.into_iter().enumerate() {
                let (rays, want_hits) = (&rays, &want_hits);
                s.spawn(move || {
                    for (y0, band) in bands {
                        let y1 = (y0 + 13).min(72);
                        let len = band.len().min((y1 - y0) as usize * stride);
                        shared
                            .render_rows_in_slot(
                                slot as u32,
                                &p,
                                &p,
                                &frame,
                                Band {
                                    y0,
                                    y1,
                                    pixels: &mut band[..len],
                                    stride,
                                },
                            )
                            .unwrap();
                    }
                    let mut hits = vec![Hit::MISS; rays.len()];
                    shared
                        .trace_in_slot(slot as u32, &p, rays, &mut hits)
                        .unwrap();
                    assert_eq!(&hits, want_hits);
                });
            }
        });
        assert!(got == want, "{method:?}: banded render differs");
    }
    // Refusals change nothing.
    let p = TraceParams::default();
    let mut band = vec![7u8; 4 * 80];
    assert!(matches!(
        ctx.render_rows_in_slot(
            3,
            &p,
            &p,
            &frame,
            Band {
                y0: 0,
                y1: 1,
                pixels: &mut band,
                stride: 320
            }
        ),
        Err(Error::Capacity {
            pool: Pool::Threads,
            ..
        })
    ));
    assert!(matches!(
        ctx.render_rows_in_slot(
            0,
            &p,
            &p,
            &frame,
            Band {
                y0: 5,
                y1: 5,
                pixels: &mut band,
                stride: 320
            }
        ),
        Err(Error::InvalidArgument(_))
    ));
    assert!(band.iter().all(|&b| b == 7));
}

/// Ray streams (rays and hits as structures of arrays) answer as ray
/// arrays do, bit for bit, for every method at two packet sides and a
/// count that ends inside a quad and inside a packet, invalid rays
/// included; occlusion likewise. Arrays of other lengths are refused and
/// nothing is written.
#[test]
fn ray_streams_answer_as_ray_arrays() {
    use sheaf::{HitStream, KdParams, RayStream, TraceParams};
    let s = sheaf::scenes::builtin("gears").unwrap();
    let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
    let mut ctx =
        OwnedContext::new(&Limits::for_triangles(s.mesh.indices.len() as u32 / 3)).unwrap();
    ctx.build_grid(&scene, &GridParams::default()).unwrap();
    ctx.build_bvh(&scene, &BvhParams::default()).unwrap();
    ctx.build_kd(&scene, &KdParams::default()).unwrap();
    // 29 x 23 = 667 rays: neither a multiple of 4 nor of a packet.
    let mut rays = s.views[0].rays(29, 23);
    rays[5].tmin = -1.0;
    rays[6].dir = [0.0; 3];
    rays[7].org[0] = f32::NAN;
    let n = rays.len();
    let cols = common::ray_stream::Columns::of(&rays);
    let stream = cols.stream();
    let mut hits = 0;
    for &method in Method::ALL {
        for packet in [4, 16] {
            let p = TraceParams {
                method,
                packet,
                ..TraceParams::default()
            };
            let mut want = vec![Hit::MISS; n];
            ctx.trace_in_slot(0, &p, &rays, &mut want).unwrap();
            let (mut t, mut u, mut v, mut prim) =
                (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0; n]);
            let mut out = HitStream {
                t: &mut t,
                u: &mut u,
                v: &mut v,
                prim: &mut prim,
            };
            ctx.trace_stream(Some(0), &p, &stream, &mut out).unwrap();
            for (i, w) in want.iter().enumerate() {
                let got = (t[i].to_bits(), u[i].to_bits(), v[i].to_bits(), prim[i]);
                let w = (w.t.to_bits(), w.u.to_bits(), w.v.to_bits(), w.prim);
                assert_eq!(got, w, "{} packet {packet}: ray {i}", method.name());
            }
            hits += want.iter().filter(|h| h.is_hit()).count();
            let mut blocked = vec![false; n];
            ctx.occluded_in_slot(0, &p, &rays, &mut blocked).unwrap();
            let mut got = vec![true; n];
            ctx.occluded_stream(None, &p, &stream, &mut got).unwrap();
            assert_eq!(got, blocked, "{} packet {packet}: occlusion", method.name());
        }
    }
    assert!(hits > 0, "the view sees the scene");
    let short = RayStream {
        tmax: &cols.0[7][1..],
        ..stream
    };
    let p = TraceParams::default();
    let (mut t, mut u, mut v, mut prim) = (vec![7.0; n], vec![0.0; n], vec![0.0; n], vec![0; n]);
    let mut out = HitStream {
        t: &mut t,
        u: &mut u,
        v: &mut v,
        prim: &mut prim,
    };
    assert!(matches!(
        ctx.trace_stream(None, &p, &short, &mut out),
        Err(Error::InvalidArgument(_))
    ));
    let mut few = HitStream {
        t: &mut t[1..],
        u: &mut u[1..],
        v: &mut v[1..],
        prim: &mut prim[1..],
    };
    assert!(matches!(
        ctx.trace_stream(None, &p, &stream, &mut few),
        Err(Error::InvalidArgument(_))
    ));
    assert!(t.iter().all(|&x| x == 7.0), "a refused call writes nothing");
}

/// Camera packets made in the kernel (`trace_camera`) answer every pixel
/// as the ray array of `sheaf_frame_camera_ray`'s rays does, bit for bit:
/// every method, every packet side, a rectangle off the image's corner
/// whose sides are no multiple of a packet, hits written `row` apart with
/// the gaps left alone. Bad rectangles, rows and buffers are refused with
/// nothing written.
#[test]
fn camera_packets_answer_as_ray_arrays() {
    use sheaf::{KdParams, PixelRect, PrimaryRays, TraceParams};
    let s = sheaf::scenes::builtin("gears").unwrap();
    let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
    let mut ctx =
        OwnedContext::new(&Limits::for_triangles(s.mesh.indices.len() as u32 / 3)).unwrap();
    ctx.build_grid(&scene, &GridParams::default()).unwrap();
    ctx.build_bvh(&scene, &BvhParams::default()).unwrap();
    ctx.build_kd(&scene, &KdParams::default()).unwrap();
    let v = &s.views[0];
    let cam = sheaf::Camera {
        eye: v.eye.to_array(),
        look_at: v.look_at.to_array(),
        up: v.up.to_array(),
        fov_y_deg: v.fov_y_deg,
    };
    let (w, h) = (61, 47);
    let pr = PrimaryRays::new(&cam, w, h).unwrap();
    let rect = PixelRect {
        x0: 3,
        y0: 5,
        x1: 3 + 37,
        y1: 5 + 29,
    };
    let (rw, rh) = rect.size();
    let row = rw as usize + 3;
    let pixels: Vec<(u32, u32)> = (rect.y0..rect.y1)
        .flat_map(|y| (rect.x0..rect.x1).map(move |x| (x, y)))
        .collect();
    let rays: Vec<Ray> = pixels.iter().map(|&(x, y)| pr.ray(x, y)).collect();
    let gap = Hit {
        t: -7.0,
        ..Hit::MISS
    };
    let mut seen = 0;
    for &method in Method::ALL {
        for packet in [2, 4, 8, 16, 32] {
            let p = TraceParams {
                method,
                packet,
                ..TraceParams::default()
            };
            let mut want = vec![Hit::MISS; rays.len()];
            ctx.trace_in_slot(0, &p, &rays, &mut want).unwrap();
            let mut got = vec![gap; (rh as usize - 1) * row + rw as usize];
            ctx.trace_camera(Some(0), &p, &pr, rect, &mut got, row)
                .unwrap();
            for (k, &(x, y)) in pixels.iter().enumerate() {
                let g = got[(y - rect.y0) as usize * row + (x - rect.x0) as usize];
                let bits = |h: &Hit| (h.t.to_bits(), h.u.to_bits(), h.v.to_bits(), h.prim);
                assert_eq!(
                    bits(&g),
                    bits(&want[k]),
                    "{} packet {packet}: pixel ({x}, {y})",
                    method.name()
                );
            }
            let gaps = got
                .chunks(row)
                .flat_map(|r| r.get(rw as usize..).unwrap_or(&[]))
                .filter(|h| h.t == -7.0)
                .count();
            assert_eq!(gaps, (rh as usize - 1) * 3, "the gaps between rows stay");
            seen += want.iter().filter(|h| h.is_hit()).count();
        }
    }
    assert!(seen > 0, "the view sees the scene");
    let p = TraceParams::default();
    let mut got = vec![gap; (rh as usize - 1) * row + rw as usize];
    let bad_rects = [
        PixelRect { x1: 3, ..rect },
        PixelRect { x1: w + 1, ..rect },
        PixelRect {
            y0: 30,
            y1: 29,
            ..rect
        },
    ];
    for r in bad_rects {
        let e = ctx.trace_camera(None, &p, &pr, r, &mut got, row);
        assert!(matches!(e, Err(Error::InvalidArgument(_))), "{r:?}");
    }
    let n = got.len();
    let short = ctx.trace_camera(None, &p, &pr, rect, &mut got[..n - 1], row);
    assert!(matches!(short, Err(Error::InvalidArgument(_))));
    let narrow = ctx.trace_camera(None, &p, &pr, rect, &mut got, rw as usize - 1);
    assert!(matches!(narrow, Err(Error::InvalidArgument(_))));
    assert!(
        got.iter().all(|h| h.t == -7.0),
        "a refused call writes nothing"
    );
    let nan = sheaf::Camera {
        fov_y_deg: f32::NAN,
        ..cam
    };
    assert!(PrimaryRays::new(&nan, w, h).is_err());
}
