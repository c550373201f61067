//! kd-tree: per-frame SAH builds (the default binned build and the exact
//! O(N log N) sweep with perfect splits, AEPSA paper section 5.1) and
//! traversal by single rays, 2x2 SIMD rays (Wald
//! 2004) and n x n frustum packets started at the root or at the entry
//! point MLRTA or AEPSA finds (AEPSA paper sections 2.2 and 3).
//!
//! Groups, each over the scenes of `bench_scenes.rs`:
//! - `kd_build`: one full rebuild by each build (`exact`, `binned`),
//!   `Throughput::Elements` = triangles (flat sampling: sponza's exact
//!   build alone takes about 1.3 s).
//! - `kd_trace`: the scene view's camera rays at 256 x 256 through
//!   `Context::trace_with` on one thread: `single`, `simd`, and `packet`
//!   at 8x8 and 16x16 with entry search none, MLRTA and AEPSA,
//!   `Throughput::Elements` = rays.
//! - `kd_shadow`: the same cases for shadow rays through
//!   `Context::occluded_with` (shadow frusta, `RayKind::Shadow`): one per
//!   pixel from the scene's light to just off the camera ray's nearest hit
//!   (`BenchScene::shadow_rays`; pixels that missed get an empty ray).
//!
//! `cargo bench --bench kd` (about six minutes on two cores);
//! `cargo bench --bench kd -- sponza` for one scene,
//! `cargo bench --bench kd -- kd_shadow` for one group.

use criterion::{
    BenchmarkId, Criterion, SamplingMode, Throughput, criterion_group, criterion_main,
};
use sheaf::accel::kd::KdParams;
use sheaf::trace::{EntrySearch, RayKind};
use sheaf::{Counters, Hit, Limits, Method, OwnedContext, TraceParams};
use std::hint::black_box;
use std::time::Duration;

#[path = "bench_scenes.rs"]
mod bench_scenes;
use bench_scenes::{SIDE, bench_scenes, limits, packet_order, primary_rays};

/// The traversals: label, parameters (primary kind), packet side.
fn cases() -> Vec<(String, TraceParams, usize)> {
    let mut cases = vec![
        (
            "single".to_string(),
            TraceParams::bvh(Method::KdSingle, 0),
            2,
        ),
        ("simd".to_string(), TraceParams::bvh(Method::KdSimd, 0), 2),
    ];
    for n in [8u32, 16] {
        for &e in EntrySearch::ALL {
            cases.push((
                format!("packet {n}x{n} {}", e.name()),
                TraceParams::bvh(Method::KdPacket, n).with_entry(e),
                n as usize,
            ));
        }
    }
    cases
}

fn per_ray(name: &str, label: &str, ctr: &Counters, rays: usize) {
    let r = |x: u64| x as f64 / rays as f64;
    eprintln!(
        "{name:<10} {label:<20} per ray {:.2} split steps {:.2} triangle tests; {} nodes, {} triangles culled; {} entry searches, mean depth {:.1}",
        r(ctr.aabb_tests),
        r(ctr.tri_tests),
        ctr.culled_nodes,
        ctr.culled,
        ctr.entry_searches,
        ctr.entry_depth_sum as f64 / ctr.entry_searches.max(1) as f64,
    );
}

fn kd(c: &mut Criterion) {
    let scenes = bench_scenes();
    let params = KdParams::default();
    let mut ctxs = Vec::with_capacity(scenes.len());
    for s in &scenes {
        let mut l = limits(s);
        l.structures = Limits::KD;
        let mut ctx = OwnedContext::new(&l).expect("context");
        let info = ctx.build_kd(&s.scene(), &params).expect("kd build");
        let bytes = sheaf::required_bytes(&l).expect("limits");
        eprintln!(
            "{:<10} {:>7} triangles, {} nodes, {} leaves, {:.1} refs/triangle, depth {} (mean leaf {:.1}), {} forced leaves, SAH cost {:.1}, {bytes} bytes with only kd pools ({:.1} bytes/triangle)",
            s.name,
            info.triangles,
            info.nodes,
            info.leaves,
            info.refs as f64 / info.triangles.max(1) as f64,
            info.depth,
            info.avg_leaf_depth,
            info.forced_leaves,
            info.sah_cost,
            bytes as f64 / s.triangles() as f64
        );
        let rays = primary_rays(&s.view);
        let mut hits = vec![Hit::MISS; rays.len()];
        ctx.trace(Method::KdSingle, &rays, &mut hits)
            .expect("trace");
        let shadow = s.shadow_rays(&rays, &hits);
        ctxs.push((ctx, rays, shadow, hits));
    }

    // Builds take up to 1.3 s on the OBJ scenes: flat sampling runs each of the
    // 10 samples once instead of criterion's 1 + 2 + ... + 10 iterations.
    let mut g = c.benchmark_group("kd_build");
    g.sampling_mode(SamplingMode::Flat);
    for (s, (ctx, ..)) in scenes.iter().zip(ctxs.iter_mut()) {
        let scene = s.scene();
        g.throughput(Throughput::Elements(s.triangles() as u64));
        // The exact sweep first: the binned tree, built last, is the one
        // the trace groups walk.
        let exact = KdParams {
            quality: sheaf::BuildQuality::High,
            ..params
        };
        for (label, p) in [("exact", &exact), ("binned", &params)] {
            g.bench_function(BenchmarkId::new(s.name, label), |b| {
                b.iter(|| ctx.build_kd(black_box(&scene), p).expect("kd build"))
            });
        }
    }
    g.finish();

    let mut g = c.benchmark_group("kd_trace");
    for (s, (ctx, rays, _, hits)) in scenes.iter().zip(ctxs.iter_mut()) {
        for (label, p, n) in cases() {
            let p = p.with_kind(RayKind::Primary);
            let ordered = packet_order(rays, SIDE as usize, n);
            let ctr = ctx.trace_with(&p, &ordered, hits).expect("trace");
            per_ray(s.name, &label, &ctr, ordered.len());
            g.throughput(Throughput::Elements(ordered.len() as u64));
            g.bench_function(BenchmarkId::new(s.name, label), |b| {
                b.iter(|| {
                    ctx.trace_with(&p, black_box(&ordered), hits)
                        .expect("trace")
                })
            });
        }
    }
    g.finish();

    let mut g = c.benchmark_group("kd_shadow");
    for (s, (ctx, _, shadow, _)) in scenes.iter().zip(ctxs.iter_mut()) {
        let mut occluded = vec![false; shadow.len()];
        for (label, p, n) in cases() {
            let p = p.with_kind(RayKind::Shadow);
            let ordered = packet_order(shadow, SIDE as usize, n);
            let ctr = ctx
                .occluded_with(&p, &ordered, &mut occluded)
                .expect("occluded");
            per_ray(s.name, &format!("shadow {label}"), &ctr, ordered.len());
            g.throughput(Throughput::Elements(ordered.len() as u64));
            g.bench_function(BenchmarkId::new(s.name, label), |b| {
                b.iter(|| {
                    ctx.occluded_with(&p, black_box(&ordered), &mut occluded)
                        .expect("occluded")
                })
            });
        }
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(2));
    targets = kd
}
criterion_main!(benches);
