//! Coherent grid traversal is exact: every packet configuration returns the
//! same triangle and bitwise the same t as the 3DDDA with the same triangle
//! test, on every scene and view, for primary packets, shadow packets from
//! the light, and adversarial packets.

use crate::common;

use common::{TestScene, builtin_scenes, obj_scenes};
use glam::Vec3;
use sheaf::accel::grid::traverse_cgt::{self, CgtOptions};
use sheaf::accel::grid::{GridView, traverse_single};
use sheaf::accel::slot::SlotBuf;
use sheaf::geom::TriangleTest;
use sheaf::geom::{F4, Hit4, M4, Mt, Pt, Ray4, Wt};
use sheaf::{Counters, GridParams, Hit, Isa, Limits, OwnedContext, Ray, TraceParams, TriTest};

/// Group row-major rays of a `w x h` image into n x n packets of 2x2 quads.
fn packets(rays: &[Ray], w: usize, h: usize, n: usize) -> Vec<(Vec<Ray4>, Vec<usize>)> {
    let mut out = Vec::new();
    for ty in (0..h).step_by(n) {
        for tx in (0..w).step_by(n) {
            let mut quads = Vec::new();
            let mut idx = Vec::new();
            for qy in (ty..ty + n).step_by(2) {
                for qx in (tx..tx + n).step_by(2) {
                    let ids = [
                        qy * w + qx,
                        qy * w + qx + 1,
                        (qy + 1) * w + qx,
                        (qy + 1) * w + qx + 1,
                    ];
                    quads.push(Ray4::from_rays(&ids.map(|i| rays[i])));
                    idx.extend(ids);
                }
            }
            out.push((quads, idx));
        }
    }
    out
}

fn single<T: TriangleTest>(g: &GridView, rays: &[Ray], any: bool) -> Vec<Hit> {
    let mut c = Counters::default();
    rays.iter()
        .map(|r| {
            if any {
                traverse_single::any_hit::<T>(g, r, &mut c)
            } else {
                traverse_single::intersect::<T>(g, r, &mut c)
            }
        })
        .collect()
}

struct Run<'a> {
    g: GridView<'a>,
    /// A thread slot: the mailbox (one stamp per stored triangle) and the
    /// packets' scratch.
    own: SlotBuf,
}

impl Run<'_> {
    fn check<T: TriangleTest>(
        &mut self,
        what: &str,
        rays: &[Ray],
        w: usize,
        h: usize,
        any: bool,
    ) -> Counters {
        let want = single::<T>(&self.g, rays, any);
        let mut total = Counters::default();
        for n in [2usize, 4, 8, 16, 32] {
            if !w.is_multiple_of(n) || !h.is_multiple_of(n) {
                continue;
            }
            // Every option set at the CPU's lane width; all options on at
            // the other widths too (`sheaf::isa`, emulated where the CPU
            // lacks them).
            sheaf::isa::set_emulation(true);
            let own = sheaf::isa::effective(Isa::Auto);
            let mut combos = vec![
                (true, true, true, Isa::Auto),
                (false, true, true, Isa::Auto),
                (true, false, true, Isa::Auto),
                (true, true, false, Isa::Auto),
                (false, false, false, Isa::Auto),
            ];
            for isa in [Isa::Sse2, Isa::Avx2, Isa::Avx512] {
                if isa != own {
                    combos.push((true, true, true, isa));
                }
            }
            for (mc, slot, cull, isa) in combos {
                let p = TraceParams {
                    cgt: CgtOptions {
                        macrocells: mc,
                        mailbox: slot,
                        culling: cull,
                    },
                    isa,
                    ..TraceParams::default()
                };
                let mut slot = self.own.slot();
                let mut ctr = Counters::default();
                for (quads, idx) in packets(rays, w, h, n) {
                    let active = vec![M4::TRUE; quads.len()];
                    let mut hits = vec![Hit4::MISS; quads.len()];
                    if any {
                        traverse_cgt::occluded::<T>(
                            &self.g, &quads, &active, &mut hits, &p, &mut slot, &mut ctr,
                        );
                    } else {
                        traverse_cgt::intersect::<T>(
                            &self.g, &quads, &active, &mut hits, &p, &mut slot, &mut ctr,
                        );
                    }
                    for (k, &ri) in idx.iter().enumerate() {
                        let got = hits[k / 4].lane(k % 4);
                        let exp = want[ri];
                        let ok = if any {
                            got.is_hit() == exp.is_hit()
                        } else {
                            got.prim == exp.prim && got.t.to_bits() == exp.t.to_bits()
                        };
                        assert!(
                            ok,
                            "{what} {:?} n={n} {:?} {isa:?} any={any}: ray {ri} {:?}\n  cgt  {got:?}\n  3dda {exp:?}",
                            T::KIND,
                            p.cgt,
                            rays[ri]
                        );
                    }
                }
                total.add(&ctr);
            }
        }
        total
    }
}

fn scene_ctx(s: &TestScene, test: TriTest) -> OwnedContext {
    let mut l = Limits::for_triangles(s.triangles());
    l.max_vertices = (s.vertices.len() / 3) as u32;
    l.projection_test = true;
    let mut ctx = OwnedContext::new(&l).unwrap();
    ctx.build_grid(
        &s.scene(),
        &GridParams {
            test,
            ..GridParams::default()
        },
    )
    .unwrap();
    ctx
}

fn check_scene(s: &TestScene, res: usize) {
    for test in [
        TriTest::MollerTrumbore,
        TriTest::Watertight,
        TriTest::Projection,
    ] {
        let ctx = scene_ctx(s, test);
        let g = ctx.tracer().unwrap().grid.unwrap();
        let mut run = Run {
            g,
            own: SlotBuf::new(g.tris.len()),
        };
        let mut sum = Counters::default();
        for (vname, view) in &s.views {
            let what = format!("{} {vname}", s.name);
            let rays = view.rays(res as u32, res as u32);
            let c = match test {
                TriTest::MollerTrumbore => run.check::<Mt>(&what, &rays, res, res, false),
                TriTest::Watertight => run.check::<Wt>(&what, &rays, res, res, false),
                TriTest::Projection => run.check::<Pt>(&what, &rays, res, res, false),
            };
            sum.add(&c);
            // Shadow packets traced from the light towards the primary hits
            // (common origin: the light), stopping just before the surface.
            let hits = single::<Mt>(&g, &rays, false);
            let light = s.light;
            let shadow: Vec<Ray> = rays
                .iter()
                .zip(&hits)
                .map(|(r, h)| {
                    let p = if h.is_hit() {
                        Vec3::from(r.org) + Vec3::from(r.dir) * h.t
                    } else {
                        Vec3::from(r.org) + Vec3::from(r.dir)
                    };
                    Ray::new(light, p - light, 0.0, 1.0 - 1e-4)
                })
                .collect();
            let c = match test {
                TriTest::MollerTrumbore => {
                    run.check::<Mt>(&(what.clone() + " shadow"), &shadow, res, res, true)
                }
                TriTest::Watertight => {
                    run.check::<Wt>(&(what.clone() + " shadow"), &shadow, res, res, true)
                }
                TriTest::Projection => {
                    run.check::<Pt>(&(what.clone() + " shadow"), &shadow, res, res, true)
                }
            };
            sum.add(&c);
        }
        println!(
            "{:>10} {test:?}: {} packets, {} rays, {} stray lanes, {} cells, {} tests, {} mailbox skips, {} culled",
            s.name,
            sum.packets,
            sum.rays,
            sum.stray_lanes,
            sum.cells,
            sum.tri_tests,
            sum.mailbox_skips,
            sum.culled
        );
        assert!(
            sum.culled > 0 && sum.mailbox_skips > 0,
            "culling and mailboxing must be exercised"
        );
    }
}

#[test]
fn cgt_equals_3dda_on_builtin_scenes() {
    for s in builtin_scenes() {
        check_scene(&s, 64);
    }
}

#[test]
fn cgt_equals_3dda_on_obj_scenes() {
    for s in obj_scenes() {
        check_scene(&s, 32);
    }
}

#[test]
fn adversarial_packets_stay_exact() {
    // Random directions inside a packet (mixed signs on every axis), from a
    // common origin inside the grid and from scattered origins.
    let s = builtin_scenes()
        .into_iter()
        .find(|s| s.name == "animated")
        .unwrap();
    let ctx = scene_ctx(&s, TriTest::MollerTrumbore);
    let g = ctx.tracer().unwrap().grid.unwrap();
    let mut run = Run {
        g,
        own: SlotBuf::new(g.tris.len()),
    };
    let (lo, hi) = (g.info.bounds.min, g.info.bounds.max);
    let mut x = 0x2545f4914f6cdd1du64;
    let mut rnd = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 40) as f32 / (1u64 << 24) as f32
    };
    let centre = 0.5 * (lo + hi);
    for common in [true, false] {
        let rays: Vec<Ray> = (0..32 * 32)
            .map(|_| {
                let o = if common {
                    centre
                } else {
                    lo + (hi - lo) * Vec3::new(rnd(), rnd(), rnd())
                };
                let mut d = Vec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5);
                if rnd() < 0.1 {
                    d.x = 0.0; // axis-parallel components too
                }
                Ray::new(o, d, 0.0, f32::INFINITY)
            })
            .collect();
        let c = run.check::<Mt>("adversarial", &rays, 32, 32, false);
        assert!(
            c.stray_lanes > 0,
            "mixed signs must send lanes to the 3DDDA"
        );
        run.check::<Mt>("adversarial shadow", &rays, 32, 32, true);
    }
    // Active lanes with invalid rays are written as misses (the sentinel
    // below must not survive in them).
    let mut bad = s.views[0].1.rays(4, 4);
    bad[0].dir = [f32::NAN, 0.0, 1.0];
    bad[5].tmin = -1.0;
    let quads: Vec<Ray4> = packets(&bad, 4, 4, 4).remove(0).0;
    let sentinel = Hit4 {
        t: F4::splat(-7.0),
        prim: [42; 4],
        u: F4::ZERO,
        v: F4::ZERO,
    };
    let mut hits = vec![sentinel; quads.len()];
    let mut slot = run.own.slot();
    let all = vec![M4::TRUE; quads.len()];
    traverse_cgt::intersect::<Mt>(
        &g,
        &quads,
        &all,
        &mut hits,
        &TraceParams::default(),
        &mut slot,
        &mut Counters::default(),
    );
    assert!(
        hits.iter().all(|h| h.prim.iter().all(|&p| p != 42)),
        "{hits:?}"
    );
    // Inactive lanes are left untouched.
    let rays = s.views[0].1.rays(4, 4);
    let quads: Vec<Ray4> = packets(&rays, 4, 4, 4).remove(0).0;
    let active = vec![M4::new(true, false, true, false); quads.len()];
    let sentinel = Hit4 {
        t: F4::splat(-7.0),
        prim: [42; 4],
        u: F4::ZERO,
        v: F4::ZERO,
    };
    let mut hits = vec![sentinel; quads.len()];
    let mut slot = run.own.slot();
    traverse_cgt::intersect::<Mt>(
        &g,
        &quads,
        &active,
        &mut hits,
        &TraceParams::default(),
        &mut slot,
        &mut Counters::default(),
    );
    for h in &hits {
        assert_eq!((h.prim[1], h.t[1], h.prim[3], h.t[3]), (42, -7.0, 42, -7.0));
    }
}

#[test]
fn context_trace_with_cgt_matches_dda_and_renders_identical_images() {
    use sheaf::render::{Camera, Frame, PointLight, Shading};
    use sheaf::{Method, TraceParams};
    for s in builtin_scenes()
        .into_iter()
        .chain(obj_scenes().into_iter().filter(|s| s.name == "bunny"))
    {
        let mut ctx = scene_ctx(&s, TriTest::MollerTrumbore);
        for (vname, view) in &s.views {
            // Rays in 2x2-quad order for packets: any order is exact, this
            // one is also coherent.
            let rays = view.rays(48, 48);
            let mut want = vec![Hit::MISS; rays.len()];
            ctx.trace(Method::GridDda, &rays, &mut want).unwrap();
            for n in [2u32, 4, 8, 16, 32] {
                let mut got = vec![Hit::MISS; rays.len()];
                ctx.trace_with(&TraceParams::cgt(n), &rays, &mut got)
                    .unwrap();
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert!(
                        g.prim == w.prim && g.t.to_bits() == w.t.to_bits(),
                        "{} {vname} n={n} ray {i}: {g:?} vs {w:?}",
                        s.name
                    );
                }
                let mut occ_d = vec![false; rays.len()];
                let mut occ_c = vec![true; rays.len()];
                ctx.occluded(Method::GridDda, &rays, &mut occ_d).unwrap();
                ctx.occluded_with(&TraceParams::cgt(n), &rays, &mut occ_c)
                    .unwrap();
                assert_eq!(occ_d, occ_c, "{} {vname} n={n}: occlusion differs", s.name);
            }
            // Whole frames: every packet size (and splitting on/off) gives
            // the 3DDDA's image pixel for pixel (70 x 50: partial tiles too).
            let frame = Frame {
                camera: Camera {
                    eye: view.eye.to_array(),
                    look_at: view.look_at.to_array(),
                    up: view.up.to_array(),
                    fov_y_deg: view.fov_y_deg,
                },
                light: PointLight {
                    position: s.light.to_array(),
                    color: [1.0; 3],
                    ..Default::default()
                },
                shading: Shading::default(),
                width: 70,
                height: 50,
            };
            let stride = 70 * 4;
            let mut base = vec![0u8; stride * 50];
            let dda = TraceParams::dda();
            ctx.render_with(&dda, &dda, &frame, &mut base, stride)
                .unwrap();
            for n in [2u32, 4, 8, 16, 32] {
                for split in [0.0f32, 1.5] {
                    let p = TraceParams {
                        split,
                        ..TraceParams::cgt(n)
                    };
                    let mut img = vec![0u8; stride * 50];
                    let c = ctx.render_with(&p, &p, &frame, &mut img, stride).unwrap();
                    let diff = img
                        .chunks(4)
                        .zip(base.chunks(4))
                        .filter(|(a, b)| a != b)
                        .count();
                    assert_eq!(
                        diff, 0,
                        "{} {vname} n={n} split={split}: {diff} pixels differ from the 3DDDA image",
                        s.name
                    );
                    assert!(c.packets > 0);
                }
            }
        }
    }
}
