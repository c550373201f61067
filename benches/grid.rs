//! Uniform grid: per-frame build and single-ray 3DDDA trace (CGT paper,
//! section 3 for the build; Amanatides and Woo 1987 for the traversal).
//!
//! Groups, each over the same scenes:
//! - `grid_build`: one full rebuild, `Throughput::Elements` = triangles, so
//!   criterion reports triangles/s.
//! - `grid_trace_dda`: primary rays of the scene's fixed view at 256 x 256
//!   through `Context::trace` on one thread, `Throughput::Elements` = rays.
//! - `grid_trace_cgt`: the same rays as 4x4, 8x8 and 16x16 packets through
//!   coherent grid traversal (`Context::trace_with`), one thread.
//!
//! Scenes: the built-in `animated` (frame 0) and `balls` (SPD sphereflake),
//! and the OBJ files bunny (bunny_tinybvh), crytek_sponza and conference
//! from `../shared/scenes` (skipped with a message when absent). Views are
//! fixed (no randomness): the builtins' reference views, an outside view of
//! the bunny, inside views of sponza and conference. Setup prints each
//! scene's `required_bytes` for `Limits::for_triangles(n)`.
//!
//! `cargo bench --bench grid` (about two minutes on two cores);
//! `cargo bench --bench grid -- sponza` for one scene.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use sheaf::{GridParams, Hit, Limits, Method, OwnedContext, TraceParams, required_bytes};
use std::hint::black_box;
use std::time::Duration;

#[path = "bench_scenes.rs"]
mod bench_scenes;
use bench_scenes::{SIDE, bench_scenes, limits, packet_order, primary_rays};

fn grid(c: &mut Criterion) {
    let scenes = bench_scenes();
    let params = GridParams::default();
    let mut ctxs = Vec::with_capacity(scenes.len());
    for s in &scenes {
        let n = s.triangles();
        let bytes = required_bytes(&Limits::for_triangles(n)).expect("valid limits");
        let mut ctx = OwnedContext::new(&limits(s)).expect("context");
        let info = ctx.build_grid(&s.scene(), &params).expect("grid build");
        let rays = primary_rays(&s.view);
        let mut hits = vec![Hit::MISS; rays.len()];
        let ctr = ctx.trace(Method::GridDda, &rays, &mut hits).expect("trace");
        let hit = hits.iter().filter(|h| h.is_hit()).count();
        let per_ray = |x: u64| x as f64 / rays.len() as f64;
        eprintln!(
            "{:<10} {n:>7} triangles, grid {}x{}x{}, {} refs, {bytes} bytes for Limits::for_triangles ({:.1} bytes/triangle), view hits {:.0} %, per ray {:.1} cells {:.1} macrocell skips {:.1} triangle tests",
            s.name,
            info.res[0],
            info.res[1],
            info.res[2],
            info.refs,
            bytes as f64 / n as f64,
            100.0 * hit as f64 / hits.len() as f64,
            per_ray(ctr.cells),
            per_ray(ctr.macro_skips),
            per_ray(ctr.tri_tests),
        );
        ctxs.push((ctx, rays, hits));
    }

    let mut g = c.benchmark_group("grid_build");
    for (s, (ctx, _, _)) in scenes.iter().zip(ctxs.iter_mut()) {
        let scene = s.scene();
        g.throughput(Throughput::Elements(s.triangles() as u64));
        g.bench_function(BenchmarkId::from_parameter(s.name), |b| {
            b.iter(|| {
                ctx.build_grid(black_box(&scene), &params)
                    .expect("grid build")
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("grid_trace_dda");
    for (s, (ctx, rays, hits)) in scenes.iter().zip(ctxs.iter_mut()) {
        g.throughput(Throughput::Elements(rays.len() as u64));
        g.bench_function(BenchmarkId::from_parameter(s.name), |b| {
            b.iter(|| {
                ctx.trace(Method::GridDda, black_box(rays), hits)
                    .expect("trace")
            })
        });
    }
    g.finish();

    // Coherent grid traversal of the same rays, one thread, n x n packets:
    // the ratio to grid_trace_dda is the packet speed-up (CGT paper 4.5).
    let mut g = c.benchmark_group("grid_trace_cgt");
    for (s, (ctx, rays, hits)) in scenes.iter().zip(ctxs.iter_mut()) {
        for n in [4u32, 8, 16] {
            let ordered = packet_order(rays, SIDE as usize, n as usize);
            let p = TraceParams::cgt(n);
            let ctr = ctx.trace_with(&p, &ordered, hits).expect("trace");
            eprintln!(
                "{:<10} cgt {n:>2}x{n:<2} per ray {:.2} cells {:.2} triangle tests {:.2} mailbox skips {:.2} culled, {} stray lanes",
                s.name,
                ctr.cells as f64 / ordered.len() as f64,
                ctr.tri_tests as f64 / ordered.len() as f64,
                ctr.mailbox_skips as f64 / ordered.len() as f64,
                ctr.culled as f64 / ordered.len() as f64,
                ctr.stray_lanes
            );
            g.throughput(Throughput::Elements(ordered.len() as u64));
            g.bench_function(BenchmarkId::new(s.name, format!("{n}x{n}")), |b| {
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
    targets = grid
}
criterion_main!(benches);
