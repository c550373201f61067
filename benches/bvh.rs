//! BVH: per-frame binned SAH build, and traversal by single rays, 2x2 SIMD
//! rays and n x n packets (Overbeck, Ramamoorthi, Mark 2008: section 5.1 for
//! the build, section 3 for Masked, Ranged and Partition traversal).
//!
//! Groups, each over the scenes of `bench_scenes.rs`:
//! - `bvh_build`: one full rebuild, `Throughput::Elements` = triangles.
//! - `bvh_trace`: the scene view's primary rays at 256 x 256 through
//!   `Context::trace_with` on one thread: `single`, `simd`, and each
//!   large-packet traversal at 8x8 and 16x16, `Throughput::Elements` = rays.
//!
//! `cargo bench --bench bvh`; `cargo bench --bench bvh -- sponza` for one scene.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use sheaf::{BvhParams, Hit, Method, OwnedContext, TraceParams};
use std::hint::black_box;
use std::time::Duration;

#[path = "bench_scenes.rs"]
mod bench_scenes;
use bench_scenes::{SIDE, bench_scenes, limits, packet_order, primary_rays};

fn bvh(c: &mut Criterion) {
    let scenes = bench_scenes();
    let params = BvhParams::default();
    let mut ctxs = Vec::with_capacity(scenes.len());
    for s in &scenes {
        let mut l = limits(s);
        l.structures = sheaf::Limits::BVH;
        let mut ctx = OwnedContext::new(&l).expect("context");
        let info = ctx.build_bvh(&s.scene(), &params).expect("bvh build");
        eprintln!(
            "{:<10} {:>7} triangles, {} nodes, {} leaves, depth {}, SAH cost {:.1}, {} bytes with only BVH pools ({:.1} bytes/triangle)",
            s.name,
            info.triangles,
            info.nodes,
            info.leaves,
            info.depth,
            info.sah_cost,
            sheaf::required_bytes(&l).expect("limits"),
            sheaf::required_bytes(&l).expect("limits") as f64 / s.triangles() as f64
        );
        let rays = primary_rays(&s.view);
        let hits = vec![Hit::MISS; rays.len()];
        ctxs.push((ctx, rays, hits));
    }

    let mut g = c.benchmark_group("bvh_build");
    for (s, (ctx, _, _)) in scenes.iter().zip(ctxs.iter_mut()) {
        let scene = s.scene();
        g.throughput(Throughput::Elements(s.triangles() as u64));
        g.bench_function(BenchmarkId::from_parameter(s.name), |b| {
            b.iter(|| {
                ctx.build_bvh(black_box(&scene), &params)
                    .expect("bvh build")
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("bvh_trace");
    for (s, (ctx, rays, hits)) in scenes.iter().zip(ctxs.iter_mut()) {
        let mut cases = vec![
            (
                "single".to_string(),
                TraceParams::bvh(Method::BvhSingle, 0),
                2,
            ),
            ("simd".to_string(), TraceParams::bvh(Method::BvhSimd, 0), 2),
        ];
        for m in [Method::BvhMasked, Method::BvhRanged, Method::BvhPartition] {
            for n in [8u32, 16] {
                cases.push((
                    format!("{} {n}x{n}", &m.name()[4..]),
                    TraceParams::bvh(m, n),
                    n as usize,
                ));
            }
        }
        for (label, p, n) in cases {
            let ordered = packet_order(rays, SIDE as usize, n);
            let ctr = ctx.trace_with(&p, &ordered, hits).expect("trace");
            eprintln!(
                "{:<10} {label:<16} per ray {:.2} box tests {:.2} triangle tests; {} nodes, {} triangles culled",
                s.name,
                ctr.aabb_tests as f64 / ordered.len() as f64,
                ctr.tri_tests as f64 / ordered.len() as f64,
                ctr.culled_nodes,
                ctr.culled
            );
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
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    targets = bvh
}
criterion_main!(benches);
