//! The incoherence fallbacks (`sheaf::trace::fallback`): packets that
//! trigger them (incoherent packets, wide CGT frusta, Masked and Ranged
//! packets switching to Partition, lanes with tiny directions) return the
//! single-ray baseline's triangle and bitwise t (and its occlusion answer),
//! each fallback triggers where it should (its counters) and the coherence
//! test passes camera packets, the switch turns every fallback off, and
//! tracing with or without them allocates nothing.
//!
//! The fallback switch and counters are process-wide, so every test here
//! holds `LOCK`; the allocation count is per thread.

use sheaf::scenes::{Mesh, View};
use sheaf::trace::{EntrySearch, Structure, fallback};
use sheaf::{
    Camera, GridParams, Hit, Limits, Method, OwnedContext, Ray, Scene, TraceParams, TriTest,
};
use sheaf_stress::{self as stress, RayClass};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::{Mutex, MutexGuard};

struct Counting;

thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

fn count_one() {
    let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
}

// SAFETY: forwards to the system allocator; only counts calls (per thread).
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        count_one();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        count_one();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocs() -> u64 {
    ALLOCS.with(|c| c.get())
}

static LOCK: Mutex<()> = Mutex::new(());

/// The lock: the tests read the process-wide fallback statistics.
fn lock() -> MutexGuard<'static, ()> {
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// Rays per class: 8 blocks of 32 x 32 (every packet full).
const N: usize = 8 * 1024;

/// A scene with every structure built, its main view and its mesh.
struct Built {
    name: &'static str,
    ctx: OwnedContext,
    view: View,
    mesh: Mesh,
}

fn built(name: &'static str, test: TriTest) -> Built {
    let s = stress::stress_scene(name)
        .or_else(|| sheaf::scenes::builtin(name))
        .expect("a scene name");
    let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
    let n = scene.triangle_count();
    let mut limits = Limits::for_triangles(n);
    limits.max_vertices = scene.vertex_count();
    // Room for huge triangles in the grid and for the kd-tree's needles.
    limits.max_grid_cells = 64 * n + 4096;
    limits.max_grid_refs = 256 * n + 4096;
    limits.max_kd_nodes = 64 * n + 4096;
    limits.max_kd_refs = 256 * n + 4096;
    let mut ctx = OwnedContext::new(&limits).unwrap();
    ctx.build_grid(
        &scene,
        &GridParams {
            test,
            ..GridParams::default()
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
        &sheaf::accel::kd::KdParams {
            test,
            ..Default::default()
        },
    )
    .unwrap();
    Built {
        name,
        ctx,
        view: s.views[0],
        mesh: s.mesh,
    }
}

/// `n` camera rays of `view` in the order of `stress::stress_rays` (every
/// packet an image tile).
fn camera_rays(view: &View, n: usize) -> Vec<Ray> {
    let (w, h) = stress::stress_image_size(n);
    let cam = Camera {
        eye: view.eye.to_array(),
        look_at: view.look_at.to_array(),
        up: view.up.to_array(),
        fov_y_deg: view.fov_y_deg,
    };
    let pr = sheaf::render::PrimaryRays::new(&cam, w, h).unwrap();
    (0..n)
        .map(|k| {
            let (x, y) = stress::stress_pixel(k, n);
            pr.ray(x, y)
        })
        .collect()
}

/// Every packet method (and the 2x2 SIMD rays) at the sides given.
fn methods(sides: &[u32]) -> Vec<TraceParams> {
    let mut v = Vec::new();
    for &n in sides {
        v.push(TraceParams::cgt(n));
        for m in [
            Method::BvhMasked,
            Method::BvhRanged,
            Method::BvhPartition,
            Method::BvhWideRanged,
            Method::BvhFrustum,
        ] {
            v.push(TraceParams::bvh(m, n));
        }
        for e in [EntrySearch::None, EntrySearch::Mlrta, EntrySearch::Aepsa] {
            v.push(TraceParams::bvh(Method::KdPacket, n).with_entry(e));
        }
    }
    v.push(TraceParams::bvh(Method::BvhSimd, 8));
    v.push(TraceParams::bvh(Method::KdSimd, 8));
    v
}

fn label(p: &TraceParams) -> String {
    format!(
        "{} {}x{} {:?}",
        p.method.name(),
        p.packet,
        p.packet,
        p.entry
    )
}

/// What fell back during `f`.
fn fell_back(f: impl FnOnce()) -> fallback::FallbackStats {
    let a = fallback::stats();
    f();
    let b = fallback::stats();
    fallback::FallbackStats {
        packets: b.packets - a.packets,
        lanes: b.lanes - a.lanes,
    }
}

/// The single rays' answers on a ray set, per structure (grid, BVH, kd):
/// nearest hits and occlusion.
type Baselines = Vec<(Vec<Hit>, Vec<bool>)>;

fn baselines(b: &mut Built, rays: &[Ray]) -> Baselines {
    [Method::GridDda, Method::BvhSingle, Method::KdSingle]
        .iter()
        .map(|&m| {
            let p = TraceParams::bvh(m, 8);
            let mut h = vec![Hit::MISS; rays.len()];
            b.ctx.trace_with(&p, rays, &mut h).unwrap();
            let mut o = vec![false; rays.len()];
            b.ctx.occluded_with(&p, rays, &mut o).unwrap();
            (h, o)
        })
        .collect()
}

/// What fell back while a method traced, and the lanes it sent alone
/// because their directions differ from the packet's first lane (CGT
/// section 2.2, kd packets: `Counters::stray_lanes`).
#[derive(Debug)]
struct Traced {
    fb: fallback::FallbackStats,
    strays: u64,
}

/// Trace `rays` with `p` (nearest hits and occlusion); assert they equal
/// its structure's single ray (`base`) ray by ray, bitwise.
fn check(b: &mut Built, what: &str, p: &TraceParams, rays: &[Ray], base: &Baselines) -> Traced {
    let (want, want_occ) = &base[match p.method.single() {
        Method::GridDda => 0,
        Method::BvhSingle => 1,
        _ => 2,
    }];
    let mut got = vec![Hit::MISS; rays.len()];
    let mut got_occ = vec![false; rays.len()];
    let mut strays = 0;
    let fb = fell_back(|| {
        strays += b.ctx.trace_with(p, rays, &mut got).unwrap().stray_lanes;
        strays += b
            .ctx
            .occluded_with(p, rays, &mut got_occ)
            .unwrap()
            .stray_lanes;
    });
    for (k, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            g.prim == w.prim && g.t.to_bits() == w.t.to_bits(),
            "{} {what}: {}: ray {k} {:?}\n  packet {g:?}\n  single {w:?}",
            b.name,
            label(p),
            rays[k]
        );
    }
    for (k, (g, w)) in got_occ.iter().zip(want_occ).enumerate() {
        assert_eq!(
            g,
            w,
            "{} {what} occlusion: {}: ray {k} {:?}",
            b.name,
            label(p),
            rays[k]
        );
    }
    Traced { fb, strays }
}

/// Valid rays of `rays` (the lanes a traversal traces).
fn valid(rays: &[Ray]) -> u64 {
    rays.iter().filter(|r| r.is_valid()).count() as u64
}

#[test]
fn incoherent_packets_go_lane_by_lane_and_stay_exact() {
    let _g = lock();
    for name in ["closed-box", "huge-triangles", "gears"] {
        for test in [TriTest::MollerTrumbore, TriTest::Watertight] {
            let mut b = built(name, test);
            let rays = stress::stress_rays(RayClass::RandomInPacket, &b.mesh, &b.view, N, 7);
            let mixed = stress::stress_rays(RayClass::MixedSigns, &b.mesh, &b.view, N, 8);
            let (base, base_mixed) = (baselines(&mut b, &rays), baselines(&mut b, &mixed));
            for p in methods(&[4, 8, 16]) {
                let t = check(&mut b, "random-in-packet", &p, &rays, &base);
                // Directions uniform on the sphere (from one origin, or
                // from origins all over the scene): every BVH packet fails
                // the coherence test, so every lane goes alone, in both
                // calls (nearest hits and occlusion). CGT and kd packets
                // first send the lanes whose directions differ from the
                // first lane's alone (strays); the few lanes left may pass
                // (a handful within 30 degrees). A quad of SIMD rays passes
                // when its four directions are within 30 degrees (chance
                // 3e-4), and a kd quad whenever one lane is left after its
                // strays (one ray is coherent).
                if cfg!(feature = "counters") {
                    let all = 2 * valid(&rays);
                    let alone = t.fb.lanes + t.strays;
                    assert!(t.fb.lanes > 0, "{name}: {}: {t:?}", label(&p));
                    if !p.method.is_packet() {
                    } else if p.method.structure() == Structure::Bvh {
                        assert_eq!(alone, all, "{name}: {}: {t:?}", label(&p));
                    } else {
                        assert!(alone >= all * 95 / 100, "{name}: {}: {t:?}", label(&p));
                    }
                }
                // Camera rays with flipped components: alone either as
                // strays (CGT, kd: what remains is coherent) or by the
                // coherence test.
                let t = check(&mut b, "mixed-signs", &p, &mixed, &base_mixed);
                if cfg!(feature = "counters") {
                    assert!(t.fb.lanes + t.strays > 0, "{name}: {}: {t:?}", label(&p));
                }
            }
        }
    }
}

#[test]
fn other_stress_classes_stay_exact_with_the_fallbacks() {
    let _g = lock();
    // The scenes on threads of their own: this test reads no fallback
    // statistics (the lock keeps the other tests' deltas clean).
    std::thread::scope(|s| {
        for name in ["closed-box", "huge-triangles", "coincident-degenerate"] {
            s.spawn(move || {
                let mut b = built(name, TriTest::MollerTrumbore);
                for class in [
                    RayClass::AxisParallel,
                    RayClass::ZeroLength,
                    RayClass::NonFinite,
                ] {
                    let rays = stress::stress_rays(class, &b.mesh, &b.view, N, 9);
                    let base = baselines(&mut b, &rays);
                    for p in methods(&[8]) {
                        check(&mut b, class.name(), &p, &rays, &base);
                    }
                }
            });
        }
    });
}

#[test]
fn cgt_budget_falls_back_on_wide_frusta_and_stays_exact() {
    let _g = lock();
    // 16x16 packets of a 64x64 image: coherent (about 11 degrees wide, the
    // coherence test passes), but their frusta cover many cells of the
    // gears' fine grid per ray.
    let mut b = built("gears", TriTest::MollerTrumbore);
    let rays = camera_rays(&b.view, 4096);
    let base = baselines(&mut b, &rays);
    let fb = check(&mut b, "camera", &TraceParams::cgt(16), &rays, &base).fb;
    if cfg!(feature = "counters") {
        assert!(fb.packets > 0, "{fb:?}");
        assert!(fb.lanes > 0 && fb.lanes < 2 * valid(&rays), "{fb:?}");
    }
}

#[test]
fn masked_switches_to_partition_and_stays_exact() {
    let _g = lock();
    for name in ["gears", "animated"] {
        let mut b = built(name, TriTest::MollerTrumbore);
        let rays = camera_rays(&b.view, 4096);
        let grazing = stress::stress_rays(RayClass::Grazing, &b.mesh, &b.view, N, 11);
        let (base, base_grazing) = (baselines(&mut b, &rays), baselines(&mut b, &grazing));
        for m in [Method::BvhMasked, Method::BvhRanged] {
            let p = TraceParams::bvh(m, 16);
            let fb = check(&mut b, "camera", &p, &rays, &base).fb;
            // Camera packets pass the coherence test (no lane alone); the
            // switch records packets without lanes. Ranged never switches.
            if cfg!(feature = "counters") {
                if m == Method::BvhMasked {
                    assert!(fb.packets > 0, "{name}: {}: {fb:?}", label(&p));
                } else {
                    assert_eq!(fb.packets, 0, "{name}: {}: {fb:?}", label(&p));
                }
                assert_eq!(fb.lanes, 0, "{name}: {}: {fb:?}", label(&p));
            }
            check(&mut b, "grazing", &p, &grazing, &base_grazing);
        }
    }
}

#[test]
fn coherent_camera_packets_pass_the_coherence_test() {
    let _g = lock();
    for name in ["tetra", "animated", "closed-box", "teapot-stadium"] {
        let mut b = built(name, TriTest::MollerTrumbore);
        // 128 x 128 pixels.
        let rays = camera_rays(&b.view, 16 * 1024);
        let base = baselines(&mut b, &rays);
        for p in methods(&[8, 16]) {
            if p.method == Method::GridCgt {
                continue; // its budget may fall back on wide frusta
            }
            let fb = check(&mut b, "camera", &p, &rays, &base).fb;
            if cfg!(feature = "counters") {
                assert_eq!(fb.lanes, 0, "{name}: {}: {fb:?}", label(&p));
            }
        }
    }
}

#[test]
fn the_switch_turns_every_fallback_off() {
    let _g = lock();
    let mut b = built("closed-box", TriTest::MollerTrumbore);
    let rays = stress::stress_rays(RayClass::RandomInPacket, &b.mesh, &b.view, N, 3);
    let mut hits = vec![Hit::MISS; rays.len()];
    let fb = fell_back(|| {
        for p in methods(&[4, 16]) {
            let off = TraceParams {
                fallbacks: false,
                ..p
            };
            b.ctx.trace_with(&off, &rays, &mut hits).unwrap();
        }
    });
    assert_eq!(fb, fallback::FallbackStats::default());
    if cfg!(feature = "counters") {
        let fb = fell_back(|| {
            b.ctx
                .trace_with(&TraceParams::bvh(Method::BvhRanged, 8), &rays, &mut hits)
                .unwrap();
        });
        assert_eq!(fb.lanes, valid(&rays), "{fb:?}");
    }
}

#[test]
fn tracing_with_and_without_fallbacks_allocates_nothing() {
    let _g = lock();
    let mut b = built("huge-triangles", TriTest::MollerTrumbore);
    let classes: Vec<Vec<Ray>> = [
        RayClass::RandomInPacket,
        RayClass::AxisParallel,
        RayClass::Grazing,
        RayClass::NonFinite,
    ]
    .iter()
    .map(|&c| stress::stress_rays(c, &b.mesh, &b.view, N, 5))
    .chain(std::iter::once(camera_rays(&b.view, N)))
    .collect();
    let mut ps = methods(&[4, 8, 16]);
    for m in [Method::GridDda, Method::BvhSingle, Method::KdSingle] {
        ps.push(TraceParams::bvh(m, 8));
    }
    let mut hits = vec![Hit::MISS; N];
    let mut occ = vec![false; N];
    for on in [true, false] {
        for rays in &classes {
            for p in &ps {
                let p = &TraceParams {
                    fallbacks: on,
                    ..*p
                };
                let before = allocs();
                b.ctx.trace_with(p, rays, &mut hits).unwrap();
                b.ctx.occluded_with(p, rays, &mut occ).unwrap();
                let n = allocs() - before;
                assert_eq!(n, 0, "{}: fallbacks {on}: {n} allocations", label(p));
            }
        }
    }
}

#[test]
fn tiny_directions_go_alone_and_stay_exact() {
    let _g = lock();
    // Camera rays some of whose directions are scaled by 1e-30 or 1e-39
    // (subnormal components): valid rays a quad's SIMD arithmetic would
    // slow down for all four lanes; every packet method traces them alone.
    let mut b = built("skinny-diagonal", TriTest::MollerTrumbore);
    let rays = stress::stress_rays(RayClass::ZeroLength, &b.mesh, &b.view, N, 13);
    let tiny = rays
        .iter()
        .filter(|r| {
            let m = r.dir.iter().fold(0.0f32, |m, d| m.max(d.abs()));
            r.is_valid() && m > 0.0 && m < fallback::TINY_DIR
        })
        .count() as u64;
    assert!(tiny > 100, "{tiny}");
    let base = baselines(&mut b, &rays);
    for p in methods(&[4, 16]) {
        let t = check(&mut b, "zero-length", &p, &rays, &base);
        if cfg!(feature = "counters") {
            assert!(
                t.fb.lanes >= 2 * tiny,
                "{}: {tiny} tiny rays: {t:?}",
                label(&p)
            );
        }
    }
}
