//! The C ABI's overhead: the same rays traced through the `extern "C"`
//! functions of `sheaf::ffi` (what a C engine calls) and through the Rust
//! API, on the same built BVH, for batches of 1, 4, 64 (one 8x8 packet)
//! and 65,536 rays (the whole 256 x 256 view), so the per-call cost shows
//! in the small batches and the per-ray cost in the big one.
//!
//! Group `ffi_trace`, on the built-in `animated` scene (always present;
//! the call cost does not depend on the scene), for `bvh-single` (ray by
//! ray) and `bvh-ranged 8x8` (packets), `Throughput::Elements` = rays:
//! - `rust trace_with`: `Context::trace_with` (`&mut self`: slot 0's
//!   scratch, records `stats`, two clock reads per call);
//! - `ffi trace_with`: `sheaf_context_trace_with` (panic boundary, state
//!   word, pointer checks, params copied and checked, no slot, no stats);
//! - `rust trace_in_slot`: `Context::trace_in_slot(0, ..)` (`&self`, slot
//!   claimed per call);
//! - `ffi trace_slot`: `sheaf_context_trace_slot(.., 0, ..)`, the same
//!   core path as `rust trace_in_slot`: the difference between the two is
//!   the C boundary alone.
//!
//! The functions are called from Rust, so no dynamic-linker stub is in the
//! path (a C program linking the cdylib adds one indirect jump per call);
//! without LTO they are not inlined into the bench either. Setup checks
//! that both sides return the same hits, bit for bit.
//!
//! `cargo bench --bench ffi` (about two minutes on two cores).

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use sheaf::ffi::{
    sheaf_context, sheaf_context_build_bvh, sheaf_context_create, sheaf_context_destroy,
    sheaf_context_set_geometry, sheaf_context_trace_slot, sheaf_context_trace_with, sheaf_hit,
    sheaf_limits, sheaf_ray, sheaf_status, sheaf_trace_params,
};
use sheaf::{Hit, Limits, Method, OwnedContext, Ray, TraceParams};
use std::hint::black_box;
use std::ptr;
use std::time::Duration;

#[path = "bench_scenes.rs"]
mod bench_scenes;
use bench_scenes::{BenchScene, SIDE, builtin, limits, packet_order, primary_rays};

/// Batch sizes: a single ray, one 2x2 quad, one 8x8 packet, the whole view.
const BATCHES: [usize; 4] = [1, 4, 64, (SIDE * SIDE) as usize];

/// A C-ABI context over `s`'s buffers (which must outlive it), BVH built.
fn c_context(s: &BenchScene, l: &Limits) -> *mut sheaf_context {
    let mut ctx = ptr::null_mut();
    let ok = |st: sheaf_status, what: &str| assert_eq!(st, sheaf_status::Ok, "{what}");
    ok(
        sheaf_context_create(&sheaf_limits::of(l), &mut ctx),
        "sheaf_context_create",
    );
    ok(
        sheaf_context_set_geometry(
            ctx,
            s.vertices.as_ptr(),
            12,
            (s.vertices.len() / 3) as u32,
            s.indices.as_ptr(),
            s.triangles(),
        ),
        "sheaf_context_set_geometry",
    );
    ok(
        sheaf_context_build_bvh(ctx, ptr::null()),
        "sheaf_context_build_bvh",
    );
    ctx
}

fn ffi(c: &mut Criterion) {
    let s = &builtin("animated");
    let mut l = limits(s);
    l.structures = Limits::BVH;
    let mut rust = OwnedContext::new(&l).expect("context");
    rust.build_bvh(&s.scene(), &Default::default())
        .expect("bvh build");
    let cctx = c_context(s, &l);

    // 8x8 packets in order: every batch is whole packets (or a prefix of one).
    let rays: Vec<Ray> = packet_order(&primary_rays(&s.view), SIDE as usize, 8);
    let c_rays: Vec<sheaf_ray> = rays.iter().map(|&r| r.into()).collect();
    let methods = [
        ("bvh-single", TraceParams::bvh(Method::BvhSingle, 0)),
        ("bvh-ranged 8x8", TraceParams::bvh(Method::BvhRanged, 8)),
    ];

    let mut hits = vec![Hit::MISS; rays.len()];
    let miss = sheaf_hit {
        t: f32::INFINITY,
        prim: sheaf::ffi::SHEAF_INVALID_ID,
        u: 0.0,
        v: 0.0,
    };
    let mut c_hits = vec![miss; rays.len()];
    for (name, p) in &methods {
        let cp = sheaf_trace_params::of(p);
        rust.trace_with(p, &rays, &mut hits).expect("trace");
        for slot in [None, Some(0)] {
            c_hits.fill(miss);
            let (r, h, n) = (c_rays.as_ptr(), c_hits.as_mut_ptr(), c_rays.len());
            let st = match slot {
                None => sheaf_context_trace_with(cctx, &cp, r, h, n),
                Some(k) => sheaf_context_trace_slot(cctx, k, &cp, r, h, n),
            };
            assert_eq!(st, sheaf_status::Ok, "{name} slot {slot:?}");
            let same = hits.iter().zip(&c_hits).all(|(h, c)| {
                h.prim == c.prim
                    && h.t.to_bits() == c.t.to_bits()
                    && h.u.to_bits() == c.u.to_bits()
                    && h.v.to_bits() == c.v.to_bits()
            });
            assert!(
                same,
                "{name} slot {slot:?}: the C ABI's hits differ from the Rust API's"
            );
        }
    }
    eprintln!(
        "{}: {} triangles, {} rays; sheaf_context_trace_with and _trace_slot return the Rust API's hits for every method",
        s.name,
        s.triangles(),
        rays.len()
    );

    let mut g = c.benchmark_group("ffi_trace");
    for (name, p) in &methods {
        let cp = sheaf_trace_params::of(p);
        for n in BATCHES {
            let (r, cr) = (&rays[..n], &c_rays[..n]);
            g.throughput(Throughput::Elements(n as u64));
            g.bench_function(
                BenchmarkId::new(format!("{name}/rust trace_with"), n),
                |b| {
                    b.iter(|| {
                        rust.trace_with(p, black_box(r), &mut hits[..n])
                            .expect("trace")
                    })
                },
            );
            g.bench_function(BenchmarkId::new(format!("{name}/ffi trace_with"), n), |b| {
                b.iter(|| {
                    sheaf_context_trace_with(
                        cctx,
                        &cp,
                        black_box(cr.as_ptr()),
                        c_hits.as_mut_ptr(),
                        n,
                    )
                })
            });
            g.bench_function(
                BenchmarkId::new(format!("{name}/rust trace_in_slot"), n),
                |b| {
                    b.iter(|| {
                        rust.trace_in_slot(0, p, black_box(r), &mut hits[..n])
                            .expect("trace")
                    })
                },
            );
            g.bench_function(BenchmarkId::new(format!("{name}/ffi trace_slot"), n), |b| {
                b.iter(|| {
                    sheaf_context_trace_slot(
                        cctx,
                        0,
                        &cp,
                        black_box(cr.as_ptr()),
                        c_hits.as_mut_ptr(),
                        n,
                    )
                })
            });
        }
    }
    g.finish();
    sheaf_context_destroy(cctx);
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(2));
    targets = ffi
}
criterion_main!(benches);
