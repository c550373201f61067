//! Whitted frames (render::whitted): the packet path writes the same bytes
//! as the single-ray path with the same structure, for reflective,
//! refractive and mixed materials, several lights and every packet size;
//! total internal reflection keeps a path's weight; bad materials and
//! bounce limits are rejected. Every BVH traversal renders the BVH single
//! ray's image, which is also the grid's.

use crate::common;

use common::{TestScene, builtin_scenes};
use glam::Vec3;
use sheaf::render::material::{DEFAULT_MATERIAL, Material, MaterialRange, Materials};
use sheaf::render::whitted::{
    self, WhittedJob, WhittedParams, render_whitted_rows, render_whitted_tiles,
};
use sheaf::render::{Band, PointLight, render_rows};
use sheaf::scenes::View;
use sheaf::{
    Camera, Counters, Error, Frame, GridParams, Limits, Method, OwnedContext, Ray, Scene, Shading,
    TraceParams,
};

/// Limits that hold any Whitted job (packets to 32 x 32, 8 bounces).
const ANY_LIMITS: Limits = Limits::for_triangles(1);

/// Packet methods checked against their structure's single-ray method.
const METHODS: &[Method] = &[Method::GridCgt];
const SIDES: &[u32] = &[4, 8, 16];
/// Not multiples of 16: partial tiles on both axes.
const W: u32 = 72;
const H: u32 = 56;

fn context(vertices: &[f32], indices: &[u32]) -> OwnedContext {
    let mut l = Limits::for_triangles((indices.len() / 3) as u32);
    l.max_vertices = (vertices.len() / 3) as u32;
    let mut ctx = OwnedContext::new(&l).unwrap();
    let scene = Scene::from_f32(vertices, indices).unwrap();
    ctx.build_grid(&scene, &GridParams::default()).unwrap();
    ctx
}

fn frame(v: &View, light: Vec3, w: u32, h: u32) -> Frame {
    Frame {
        camera: Camera {
            eye: v.eye.to_array(),
            look_at: v.look_at.to_array(),
            up: v.up.to_array(),
            fov_y_deg: v.fov_y_deg,
        },
        light: PointLight {
            position: light.to_array(),
            color: [1.0; 3],
            ..Default::default()
        },
        shading: Shading::default(),
        width: w,
        height: h,
    }
}

/// Render `job` whole: packets (`render_whitted_tiles`, in bands of `band`
/// tiles) or single rays (`render_whitted_rows`) with `job.primary.method`'s
/// structure.
fn render(ctx: &mut OwnedContext, job: &WhittedJob<'_>, packets: bool, band: u32) -> Vec<u8> {
    job.validate(&ANY_LIMITS).unwrap();
    let (w, h) = (job.frame.width, job.frame.height);
    let stride = w as usize * 4;
    let mut px = vec![0u8; stride * h as usize];
    let rays = ctx.check_frame(job.frame, px.len(), stride).unwrap();
    let (tr, mut mbs) = ctx.parts().unwrap();
    let tr = tr.with_single(job.primary.method).unwrap();
    let mut slot = mbs.next().unwrap();
    let mut ctr = Counters::default();
    if packets {
        let rows = (band * job.primary.packet) as usize;
        for (k, chunk) in px.chunks_mut(rows * stride).enumerate() {
            let y0 = (k * rows) as u32;
            let y1 = (y0 + rows as u32).min(h);
            let band = Band {
                y0,
                y1,
                pixels: chunk,
                stride,
            };
            render_whitted_tiles(&tr, job, &rays, band, &mut slot, &mut ctr);
        }
    } else {
        let band = Band {
            y0: 0,
            y1: h,
            pixels: &mut px,
            stride,
        };
        render_whitted_rows(&tr, job, &rays, band, &mut ctr);
    }
    px
}

fn assert_same(what: &str, got: &[u8], want: &[u8], w: u32) {
    if let Some(k) = (0..want.len() / 4).find(|&k| got[4 * k..4 * k + 4] != want[4 * k..4 * k + 4])
    {
        let bad = (0..want.len() / 4)
            .filter(|&k| got[4 * k..4 * k + 4] != want[4 * k..4 * k + 4])
            .count();
        panic!(
            "{what}: {bad} pixels differ, first ({}, {}): packets {:?}, single rays {:?}",
            k as u32 % w,
            k as u32 / w,
            &got[4 * k..4 * k + 4],
            &want[4 * k..4 * k + 4]
        );
    }
}

const REFLECTIVE: Material = Material {
    diffuse: [0.8, 0.78, 0.72],
    reflect: 0.5,
    transmit: 0.0,
    ior: 1.0,
};
const REFRACTIVE: Material = Material {
    diffuse: [0.8, 0.78, 0.72],
    reflect: 0.0,
    transmit: 0.6,
    ior: 1.5,
};
const BOTH: Material = Material {
    diffuse: [0.2, 0.5, 0.9],
    reflect: 0.3,
    transmit: 0.5,
    ior: 1.33,
};
const RED: Material = Material {
    diffuse: [0.9, 0.1, 0.1],
    reflect: 0.0,
    transmit: 0.0,
    ior: 1.0,
};

/// Ranges of 5 triangles cycling through the four materials and the default.
fn mixed_ranges(triangles: u32) -> Vec<MaterialRange> {
    (0..triangles.div_ceil(5))
        .map(|j| MaterialRange {
            first: 5 * j,
            material: if j % 5 == 4 { DEFAULT_MATERIAL } else { j % 5 },
        })
        .collect()
}

fn check_scene(s: &TestScene) {
    let mut ctx = context(&s.vertices, &s.indices);
    let table = [REFLECTIVE, REFRACTIVE, BOTH, RED];
    let ranges = mixed_ranges(s.triangles());
    let configs: [(&str, Materials<'_>); 3] = [
        ("reflective", Materials::uniform(&REFLECTIVE)),
        ("refractive", Materials::uniform(&REFRACTIVE)),
        (
            "mixed",
            Materials {
                materials: &table,
                ranges: &ranges,
            },
        ),
    ];
    // A second light beside the scene's, for the multi-light case.
    let lights = [
        PointLight {
            position: s.light.to_array(),
            color: [0.7, 0.7, 0.6],
            ..Default::default()
        },
        PointLight {
            position: (s.light * Vec3::new(-1.0, 1.0, 1.0) + Vec3::Z).to_array(),
            color: [0.2, 0.3, 0.4],
            ..Default::default()
        },
    ];
    let params = WhittedParams {
        max_reflect: 2,
        max_refract: 2,
    };
    for (v, (vname, view)) in s.views.iter().take(3).enumerate() {
        let fr = frame(view, s.light, W, H);
        for (mname, materials) in configs {
            // Two lights with the mixed materials only.
            let light_cases: &[bool] = if mname == "mixed" {
                &[false, true]
            } else {
                &[false]
            };
            for &multi in light_cases {
                let mut single = WhittedJob::new(&fr, materials, params, TraceParams::dda());
                if multi {
                    single.lights = &lights;
                }
                let want = render(&mut ctx, &single, false, 0);
                // The materials matter: not the plain diffuse frame.
                let plain = render(
                    &mut ctx,
                    &WhittedJob {
                        materials: Materials::NONE,
                        ..single
                    },
                    false,
                    0,
                );
                assert_ne!(
                    want, plain,
                    "{} {vname} {mname}: materials changed nothing",
                    s.name
                );
                for &method in METHODS {
                    for &n in SIDES {
                        let p = TraceParams {
                            method,
                            packet: n,
                            ..TraceParams::default()
                        };
                        let job = WhittedJob {
                            primary: p,
                            shadow: p,
                            secondary: p,
                            ..single
                        };
                        let what = format!(
                            "{} {vname} {mname} lights={} {} {n}x{n}",
                            s.name,
                            job.lights().len(),
                            method.name()
                        );
                        assert_same(&what, &render(&mut ctx, &job, true, 100), &want, W);
                        if n == 8 && v == 0 {
                            // Bands of one tile row.
                            assert_same(
                                &format!("{what} bands"),
                                &render(&mut ctx, &job, true, 1),
                                &want,
                                W,
                            );
                            // Other rays one at a time, or in smaller packets (sub-tiles).
                            let (dda, four, two) = (
                                TraceParams::dda(),
                                TraceParams { packet: 4, ..p },
                                TraceParams { packet: 2, ..p },
                            );
                            for (sh, sec) in [(p, dda), (dda, p), (four, two), (two, four)] {
                                let job = WhittedJob {
                                    shadow: sh,
                                    secondary: sec,
                                    ..job
                                };
                                let what = format!(
                                    "{what} shadow {} {} secondary {} {}",
                                    sh.method.name(),
                                    sh.packet,
                                    sec.method.name(),
                                    sec.packet
                                );
                                assert_same(&what, &render(&mut ctx, &job, true, 100), &want, W);
                            }
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn packets_match_single_rays_tetra() {
    check_scene(
        &builtin_scenes()
            .into_iter()
            .find(|s| s.name == "tetra")
            .unwrap(),
    );
}

#[test]
fn packets_match_single_rays_balls() {
    check_scene(
        &builtin_scenes()
            .into_iter()
            .find(|s| s.name == "balls")
            .unwrap(),
    );
}

#[test]
fn packets_match_single_rays_gears() {
    check_scene(
        &builtin_scenes()
            .into_iter()
            .find(|s| s.name == "gears")
            .unwrap(),
    );
}

#[test]
fn packets_match_single_rays_animated() {
    check_scene(
        &builtin_scenes()
            .into_iter()
            .find(|s| s.name == "animated")
            .unwrap(),
    );
}

/// Deep paths (8 bounces) and 32 x 32 packets, on a thread with a 2 MB stack
/// (32 x 32 tiles with 8 bounces need about 900 KB, see the module docs).
#[test]
fn deep_paths_and_large_packets() {
    std::thread::Builder::new()
        .stack_size(2 << 20)
        .spawn(|| {
            let s = builtin_scenes()
                .into_iter()
                .find(|s| s.name == "balls")
                .unwrap();
            let mut ctx = context(&s.vertices, &s.indices);
            let fr = frame(&s.views[0].1, s.light, 64, 48);
            let p = |max_reflect, max_refract| WhittedParams {
                max_reflect,
                max_refract,
            };
            for (params, m) in [
                (p(8, 0), REFLECTIVE),
                (p(0, 8), REFRACTIVE),
                (p(4, 4), BOTH),
            ] {
                let single =
                    WhittedJob::new(&fr, Materials::uniform(&m), params, TraceParams::dda());
                let want = render(&mut ctx, &single, false, 0);
                for n in [2, 32] {
                    let p = TraceParams::cgt(n);
                    // Branching trees: secondary rays singly (CGT is slow on them).
                    let sec = if params.max_reflect > 0 && params.max_refract > 0 {
                        TraceParams::dda()
                    } else {
                        p
                    };
                    let job = WhittedJob {
                        primary: p,
                        shadow: p,
                        secondary: sec,
                        ..single
                    };
                    assert_same(
                        &format!("balls {params:?} {n}x{n}"),
                        &render(&mut ctx, &job, true, 100),
                        &want,
                        fr.width,
                    );
                }
            }
        })
        .unwrap()
        .join()
        .unwrap();
}

/// Without reflective or transmissive materials a Whitted frame is the
/// plain frame of `render_rows`, bit for bit.
#[test]
fn diffuse_frames_equal_plain_frames() {
    for s in builtin_scenes() {
        let mut ctx = context(&s.vertices, &s.indices);
        let fr = frame(&s.views[0].1, s.light, W, H);
        let stride = W as usize * 4;
        let mut plain = vec![0u8; stride * H as usize];
        {
            let rays = ctx.check_frame(&fr, plain.len(), stride).unwrap();
            let tr = ctx.tracer().unwrap();
            let band = Band {
                y0: 0,
                y1: H,
                pixels: &mut plain,
                stride,
            };
            render_rows(&tr, &fr, &rays, band, &mut Counters::default());
        }
        let diffuse = Material::diffuse([0.3, 0.6, 0.9]);
        let single = WhittedJob::new(
            &fr,
            Materials::NONE,
            WhittedParams::default(),
            TraceParams::dda(),
        );
        assert_same(
            &format!("{} single", s.name),
            &render(&mut ctx, &single, false, 0),
            &plain,
            W,
        );
        let job = WhittedJob {
            primary: TraceParams::cgt(8),
            shadow: TraceParams::cgt(8),
            ..single
        };
        assert_same(
            &format!("{} cgt 8x8", s.name),
            &render(&mut ctx, &job, true, 100),
            &plain,
            W,
        );
        // A diffuse material table changes colours, not the bytes' origin.
        let table = WhittedJob {
            materials: Materials::uniform(&diffuse),
            ..single
        };
        assert_ne!(render(&mut ctx, &table, false, 0), plain);
    }
}

/// A UV sphere of radius 1 at the origin, every triangle wound so its
/// normal points outwards (so rays from inside are leaving the glass).
fn sphere(rings: u32, segments: u32) -> (Vec<f32>, Vec<u32>) {
    let mut v = Vec::new();
    for r in 0..=rings {
        let th = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let ph = 2.0 * std::f32::consts::PI * s as f32 / segments as f32;
            v.extend_from_slice(&[th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()]);
        }
    }
    let at = |r: u32, s: u32| r * segments + s % segments;
    let p = |i: u32| Vec3::from_slice(&v[3 * i as usize..3 * i as usize + 3]);
    let mut ix = Vec::new();
    for r in 0..rings {
        for s in 0..segments {
            let (a, b, c, d) = (at(r, s), at(r, s + 1), at(r + 1, s), at(r + 1, s + 1));
            for [i, j, k] in [[a, c, b], [b, c, d]] {
                let n = (p(j) - p(i)).cross(p(k) - p(i));
                if n.length_squared() < 1e-12 {
                    continue; // pole slivers
                }
                if n.dot(p(i) + p(j) + p(k)) < 0.0 {
                    ix.extend([i, k, j])
                } else {
                    ix.extend([i, j, k])
                }
            }
        }
    }
    (v, ix)
}

/// Glass (transmit 1, ior 1.5) seen from inside: rays meeting the surface
/// beyond the critical angle (41.8 degrees) are totally reflected and stay
/// inside. Red diffuse, blue background, white ambient, black light: a path
/// that stays inside ends red (its remaining weight shaded locally at the
/// bounce limit), one that leaves ends blue, and every colour's components
/// add up to 1 (weight conserved, no NaN).
#[test]
fn total_internal_reflection_conserves_weight() {
    let (v, ix) = sphere(48, 96);
    let mut ctx = context(&v, &ix);
    let glass = Material {
        diffuse: [1.0, 0.0, 0.0],
        reflect: 0.0,
        transmit: 1.0,
        ior: 1.5,
    };
    let mut fr = frame(
        &View {
            eye: Vec3::new(0.8, 0.0, 0.0),
            look_at: Vec3::new(0.8, 1.0, 0.0),
            up: Vec3::Z,
            fov_y_deg: 90.0,
        },
        Vec3::ZERO,
        64,
        64,
    );
    fr.light.color = [0.0; 3];
    fr.shading = Shading {
        albedo: [0.0; 3],
        ambient: 1.0,
        background: [0.0, 0.0, 1.0],
        shadows: true,
    };
    let single = WhittedJob::new(
        &fr,
        Materials::uniform(&glass),
        WhittedParams {
            max_reflect: 0,
            max_refract: 2,
        },
        TraceParams::dda(),
    );
    let tr = ctx.tracer().unwrap();
    let mut ctr = Counters::default();
    let mut radiance = |o: Vec3, d: Vec3| {
        whitted::radiance(&tr, &single, &Ray::new(o, d, 0.0, f32::INFINITY), &mut ctr)
    };
    // Grazing (cos_i = sqrt(1 - 0.81) = 0.44, 64 degrees): trapped.
    let c = radiance(Vec3::new(0.9, 0.0, 0.0), Vec3::Y);
    assert!(
        (c[0] - 1.0).abs() < 1e-5 && c[1] == 0.0 && c[2].abs() < 1e-5,
        "grazing ray from inside: {c:?}"
    );
    // Radial: leaves the glass.
    let c = radiance(Vec3::new(0.1, 0.0, 0.0), Vec3::X);
    assert!(
        c[0].abs() < 1e-5 && (c[2] - 1.0).abs() < 1e-5,
        "radial ray from inside: {c:?}"
    );
    // Every pixel: finite, weights sum to 1, both outcomes present.
    let rays = sheaf::render::PrimaryRays::new(&fr.camera, fr.width, fr.height).unwrap();
    let (mut trapped, mut left) = (0, 0);
    for y in 0..fr.height {
        for x in 0..fr.width {
            let r = rays.ray(x, y);
            let c = whitted::radiance(&tr, &single, &r, &mut ctr);
            assert!(c.iter().all(|x| x.is_finite()), "pixel ({x}, {y}): {c:?}");
            assert!(
                (c[0] + c[1] + c[2] - 1.0).abs() < 1e-4,
                "pixel ({x}, {y}): weights {c:?} do not add up to 1"
            );
            trapped += (c[0] > 0.999) as u32;
            left += (c[2] > 0.999) as u32;
        }
    }
    assert!(
        trapped > 100 && left > 100,
        "trapped {trapped}, left {left}"
    );
    // And the packet path agrees.
    let want = render(&mut ctx, &single, false, 0);
    for n in SIDES {
        let p = TraceParams::cgt(*n);
        let job = WhittedJob {
            primary: p,
            shadow: p,
            secondary: p,
            ..single
        };
        assert_same(
            &format!("glass sphere {n}x{n}"),
            &render(&mut ctx, &job, true, 100),
            &want,
            fr.width,
        );
    }
}

#[test]
fn invalid_materials_and_limits_are_rejected() {
    let fr = frame(
        &View::z_up(Vec3::new(0.0, -5.0, 0.0), Vec3::ZERO),
        Vec3::Z,
        8,
        8,
    );
    let ok = WhittedJob::new(
        &fr,
        Materials::uniform(&BOTH),
        WhittedParams::default(),
        TraceParams::cgt(8),
    );
    assert!(ok.validate(&ANY_LIMITS).is_ok());
    let invalid =
        |j: WhittedJob<'_>| matches!(j.validate(&ANY_LIMITS), Err(Error::InvalidArgument(_)));
    let bad_mats = [
        Material {
            reflect: 0.7,
            transmit: 0.4,
            ..BOTH
        },
        Material {
            reflect: -0.1,
            ..BOTH
        },
        Material {
            transmit: f32::NAN,
            ..BOTH
        },
        Material {
            diffuse: [0.0, 2.0, 0.0],
            ..BOTH
        },
        Material { ior: 0.0, ..BOTH },
        Material { ior: -1.5, ..BOTH },
        Material {
            ior: f32::INFINITY,
            ..BOTH
        },
    ];
    for m in &bad_mats {
        assert!(
            invalid(WhittedJob {
                materials: Materials::uniform(m),
                ..ok
            }),
            "{m:?}"
        );
    }
    let table = [BOTH, RED];
    let unsorted = [
        MaterialRange {
            first: 10,
            material: 0,
        },
        MaterialRange {
            first: 2,
            material: 1,
        },
    ];
    assert!(invalid(WhittedJob {
        materials: Materials {
            materials: &table,
            ranges: &unsorted
        },
        ..ok
    }));
    let past = [MaterialRange {
        first: 0,
        material: 2,
    }];
    assert!(invalid(WhittedJob {
        materials: Materials {
            materials: &table,
            ranges: &past
        },
        ..ok
    }));
    let fine = [
        MaterialRange {
            first: 0,
            material: DEFAULT_MATERIAL,
        },
        MaterialRange {
            first: 4,
            material: 1,
        },
    ];
    assert!(
        WhittedJob {
            materials: Materials {
                materials: &table,
                ranges: &fine
            },
            ..ok
        }
        .validate(&ANY_LIMITS)
        .is_ok()
    );
    assert!(invalid(WhittedJob {
        params: WhittedParams {
            max_reflect: 5,
            max_refract: 4
        },
        ..ok
    }));
    assert!(
        WhittedJob {
            params: WhittedParams {
                max_reflect: 0,
                max_refract: whitted::MAX_BOUNCES
            },
            ..ok
        }
        .validate(&ANY_LIMITS)
        .is_ok()
    );
    let nan_light = [PointLight {
        position: [f32::NAN, 0.0, 0.0],
        color: [1.0; 3],
        ..Default::default()
    }];
    assert!(invalid(WhittedJob {
        lights: &nan_light,
        ..ok
    }));
    assert!(invalid(WhittedJob {
        primary: TraceParams::cgt(6),
        ..ok
    }));
}

/// Timings for the report: `cargo test --release --test exact whitted:: -- --ignored --nocapture`.
#[test]
#[ignore]
fn timing_512() {
    for name in ["balls", "gears"] {
        let s = builtin_scenes()
            .into_iter()
            .find(|s| s.name == name)
            .unwrap();
        let mut ctx = context(&s.vertices, &s.indices);
        let fr = frame(&s.views[0].1, s.light, 512, 512);
        let table = [REFLECTIVE, REFRACTIVE, BOTH, RED];
        let ranges = mixed_ranges(s.triangles());
        for (mname, materials) in [
            ("reflect 0.5", Materials::uniform(&REFLECTIVE)),
            ("transmit 0.6", Materials::uniform(&REFRACTIVE)),
            (
                "mixed",
                Materials {
                    materials: &table,
                    ranges: &ranges,
                },
            ),
        ] {
            let single = WhittedJob::new(
                &fr,
                materials,
                WhittedParams {
                    max_reflect: 2,
                    max_refract: 2,
                },
                TraceParams::dda(),
            );
            let time = |ctx: &mut OwnedContext, job: &WhittedJob<'_>, packets: bool| {
                let t = std::time::Instant::now();
                let px = render(ctx, job, packets, 100);
                (t.elapsed().as_secs_f64() * 1e3, px)
            };
            let (ts, want) = time(&mut ctx, &single, false);
            let p = TraceParams::cgt(8);
            let job = WhittedJob {
                primary: p,
                shadow: p,
                secondary: p,
                ..single
            };
            let (tp, got) = time(&mut ctx, &job, true);
            assert_same(name, &got, &want, 512);
            let (td, got) = time(
                &mut ctx,
                &WhittedJob {
                    secondary: TraceParams::dda(),
                    ..job
                },
                true,
            );
            assert_same(name, &got, &want, 512);
            println!(
                "{name:6} {mname:12} 512x512 r2/t2: grid-dda {ts:6.0} ms, grid-cgt 8x8 {tp:6.0} ms ({:.2}x), \
                 grid-cgt 8x8 with grid-dda secondary {td:6.0} ms ({:.2}x)",
                ts / tp,
                ts / td
            );
        }
    }
}

/// The BVH traversals render the same Whitted image as the BVH's single
/// ray: SIMD, Masked, Ranged and Partition at 4x4 to 32x32, with and without
/// culling, the paper's mixed setup (Ranged camera and shadow rays,
/// Partition reflection and refraction rays) included; and that image is
/// the grid's (same triangle test, same rays).
#[test]
fn bvh_traversals_render_the_same_whitted_frames() {
    for s in builtin_scenes() {
        let mut ctx = context(&s.vertices, &s.indices);
        ctx.build_bvh(&s.scene(), &sheaf::BvhParams::default())
            .unwrap();
        let (v, light) = (&s.views[0].1, s.light);
        let f = frame(v, light, 64, 48);
        let ranges = mixed_ranges(s.triangles());
        let mats = [REFLECTIVE, REFRACTIVE, BOTH, RED];
        let materials = Materials {
            materials: &mats,
            ranges: &ranges,
        };
        let params = WhittedParams {
            max_reflect: 2,
            max_refract: 2,
        };
        let stride = 64 * 4;
        let mut want = vec![0u8; stride * 48];
        let single = TraceParams::bvh(Method::BvhSingle, 0);
        ctx.render_whitted(
            &WhittedJob::new(&f, materials, params, single),
            &mut want,
            stride,
        )
        .unwrap();
        let mut grid = vec![0u8; stride * 48];
        ctx.render_whitted(
            &WhittedJob::new(&f, materials, params, TraceParams::dda()),
            &mut grid,
            stride,
        )
        .unwrap();
        assert_same(
            &format!("{} bvh-single vs grid-dda", s.name),
            &grid,
            &want,
            64,
        );
        let mut cases = vec![WhittedJob::new(
            &f,
            materials,
            params,
            TraceParams::bvh(Method::BvhSimd, 2),
        )];
        for m in [
            Method::BvhMasked,
            Method::BvhRanged,
            Method::BvhPartition,
            Method::BvhWideRanged,
            Method::BvhFrustum,
        ] {
            for n in [4, 16, 32] {
                for culling in [true, false] {
                    let p = TraceParams {
                        bvh: sheaf::trace::BvhOptions {
                            culling,
                            ..Default::default()
                        },
                        ..TraceParams::bvh(m, n)
                    };
                    cases.push(WhittedJob::new(&f, materials, params, p));
                }
            }
        }
        let ranged = TraceParams::bvh(Method::BvhRanged, 16);
        cases.push(WhittedJob {
            secondary: TraceParams::bvh(Method::BvhPartition, 16),
            ..WhittedJob::new(&f, materials, params, ranged)
        });
        for job in &cases {
            let mut got = vec![0u8; stride * 48];
            ctx.render_whitted(job, &mut got, stride).unwrap();
            let what = format!(
                "{} {} {} culling {}",
                s.name,
                job.primary.method.name(),
                job.primary.packet,
                job.primary.bvh.culling
            );
            assert_same(&what, &got, &want, 64);
        }
    }
}
