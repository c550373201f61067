//! Perspective grids for camera rays and spherical light grids for shadow
//! rays, in deferred frames (perspective/light grid paper: section 3 for
//! the camera grid, section 4 and Algorithm 1 for light tiles and chunks).
//!
//! The grids are built inside `Context::render_deferred`, per frame, so
//! every iteration renders a whole 256 x 256 frame on one thread
//! (`OnCaller`) and reports only the phases a bench is about, from the
//! frame's own phase times (`DeferredInfo::times`, the paper's Figure 10;
//! `Bencher::iter_custom`). A bench therefore runs longer than its
//! measured time: the rest of the frame is not counted.
//!
//! Groups, each over the scenes of `bench_scenes.rs`:
//! - `pgrid_camera_build`: the perspective grid build (phase 1),
//!   `Throughput::Elements` = triangles.
//! - `pgrid_camera`: camera rays, grid build plus traversal (phases 1-2),
//!   `Throughput::Elements` = rays (pixels); beside it the same rays as
//!   BVH Ranged 16x16 packets (phase 2 only: the BVH is built once).
//! - `pgrid_light_build`: the light grid build (phase 4),
//!   `Throughput::Elements` = triangles.
//! - `pgrid_light`: shadow rays towards the scene's light, from making and
//!   sorting them into light tiles and chunks through the light grid build
//!   to the chunks' traversal (phases 3-5), `Throughput::Elements` =
//!   shadow rays: light tiles 16, 64 (the default) and 128 per side at
//!   chunk size r = 256, and r = 32 and 4096 at 64 tiles (on one thread
//!   chunks only cost: r balances the load of several threads); beside it
//!   the same shadow rays as BVH Ranged 16x16 shadow packets (phases 3 and
//!   5).
//!
//! Setup prints each scene's phase breakdown for the default settings.
//!
//! `cargo bench --bench pgrid` (about five minutes on two cores);
//! `cargo bench --bench pgrid -- sponza` for one scene.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use sheaf::accel::bvh::BvhParams;
use sheaf::render::deferred::PhaseTimes;
use sheaf::trace::RayKind;
use sheaf::{
    Camera, DeferredInfo, DeferredJob, Frame, Limits, Method, OnCaller, OwnedContext, PgridParams,
    PointLight, PrimaryPass, Shading, ShadowPass, TraceParams,
};
use std::time::Duration;

#[path = "bench_scenes.rs"]
mod bench_scenes;
use bench_scenes::{BenchScene, SIDE, bench_scenes, limits};

/// A context with BVH and perspective grid pools for `SIDE x SIDE` frames.
fn context(s: &BenchScene) -> OwnedContext {
    let mut l = limits(s);
    l.structures = Limits::BVH | Limits::PGRID;
    l.max_image_width = SIDE;
    l.max_image_height = SIDE;
    // As tests/exact/pgrid_exact.rs: room for lights close to surfaces, whose
    // nearby triangles span many light tiles.
    l.max_pgrid_refs = 8 * s.triangles() + (1 << 21);
    // Light grids of up to 128 x 128 tiles of the default 32 slices.
    l.max_pgrid_cells = 128 * 128 * 32;
    OwnedContext::new(&l).expect("context")
}

fn frame(s: &BenchScene, shadows: bool) -> Frame {
    let v = &s.view;
    Frame {
        camera: Camera {
            eye: v.eye.to_array(),
            look_at: v.look_at.to_array(),
            up: v.up.to_array(),
            fov_y_deg: v.fov_y_deg,
        },
        light: PointLight::new(s.light.to_array(), [1.0; 3]),
        shading: Shading {
            shadows,
            ..Shading::default()
        },
        width: SIDE,
        height: SIDE,
    }
}

/// One deferred frame into `px`.
fn render(
    ctx: &mut OwnedContext,
    f: &Frame,
    primary: PrimaryPass,
    shadow: ShadowPass,
    px: &mut [u8],
) -> DeferredInfo {
    let job = DeferredJob {
        frame: f,
        lights: &[],
        primary,
        shadow,
    };
    ctx.render_deferred(&job, px, 4 * f.width as usize, &mut OnCaller)
        .expect("deferred frame")
}

/// Criterion's `iter_custom` body: `iters` frames, the sum of `phases`.
fn phases_of(
    iters: u64,
    mut frame: impl FnMut() -> DeferredInfo,
    phases: impl Fn(&PhaseTimes) -> u64,
) -> Duration {
    (0..iters)
        .map(|_| Duration::from_nanos(phases(&frame().times)))
        .sum()
}

fn ms(ns: u64) -> f64 {
    ns as f64 * 1e-6
}

fn pgrid(c: &mut Criterion) {
    let scenes = bench_scenes();
    let ranged = |kind| TraceParams::bvh(Method::BvhRanged, 16).with_kind(kind);
    let mut ctxs = Vec::with_capacity(scenes.len());
    for s in &scenes {
        let mut ctx = context(s);
        ctx.build_bvh(&s.scene(), &BvhParams::default())
            .expect("bvh build");
        let pp = PgridParams::default();
        ctx.build_pgrid(&s.scene(), &pp).expect("pgrid load");
        let f = frame(s, true);
        let mut px = vec![0u8; 4 * (SIDE * SIDE) as usize];
        let i = render(
            &mut ctx,
            &f,
            PrimaryPass::Pgrid,
            ShadowPass::LightGrid,
            &mut px,
        );
        let t = &i.times;
        eprintln!(
            "{:<10} {:>7} triangles, {} hits, {} shadow rays; camera grid {} pairs, light grid {} pairs, {} light tiles used, {} chunks, most rays in a tile {}; ms: camera build {:.2} trace {:.2}, rearrange {:.2}, light build {:.2} trace {:.2}, shade {:.2}",
            s.name,
            s.triangles(),
            i.hits,
            i.shadow_rays,
            i.camera.refs,
            i.light.refs,
            i.reorder.tiles_used,
            i.reorder.chunks,
            i.reorder.max_tile_rays,
            ms(t.primary_build),
            ms(t.primary_trace),
            ms(t.rearrange),
            ms(t.shadow_build),
            ms(t.shadow_trace),
            ms(t.shade),
        );
        ctxs.push((ctx, px, i.shadow_rays));
    }

    // Camera rays: frames without shadows (phases 1, 2 and 6).
    let camera = |s: &BenchScene| frame(s, false);
    let mut g = c.benchmark_group("pgrid_camera_build");
    g.measurement_time(Duration::from_secs(1));
    for (s, (ctx, px, _)) in scenes.iter().zip(ctxs.iter_mut()) {
        let f = camera(s);
        g.throughput(Throughput::Elements(s.triangles() as u64));
        g.bench_function(BenchmarkId::from_parameter(s.name), |b| {
            b.iter_custom(|iters| {
                phases_of(
                    iters,
                    || render(ctx, &f, PrimaryPass::Pgrid, ShadowPass::LightGrid, px),
                    |t| t.primary_build,
                )
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("pgrid_camera");
    for (s, (ctx, px, _)) in scenes.iter().zip(ctxs.iter_mut()) {
        let f = camera(s);
        g.throughput(Throughput::Elements((SIDE * SIDE) as u64));
        g.bench_function(BenchmarkId::new(s.name, "pgrid"), |b| {
            b.iter_custom(|iters| {
                phases_of(
                    iters,
                    || render(ctx, &f, PrimaryPass::Pgrid, ShadowPass::LightGrid, px),
                    |t| t.primary_build + t.primary_trace,
                )
            })
        });
        let p = PrimaryPass::Traced(ranged(RayKind::Primary));
        g.bench_function(BenchmarkId::new(s.name, "bvh-ranged 16x16"), |b| {
            b.iter_custom(|iters| {
                phases_of(
                    iters,
                    || render(ctx, &f, p, ShadowPass::LightGrid, px),
                    |t| t.primary_trace,
                )
            })
        });
    }
    g.finish();

    // Shadow rays: camera rays through the perspective grid in every frame
    // (the hit points), then the light's shadow rays (phases 3-5).
    let mut g = c.benchmark_group("pgrid_light_build");
    g.measurement_time(Duration::from_secs(1));
    for (s, (ctx, px, _)) in scenes.iter().zip(ctxs.iter_mut()) {
        let f = frame(s, true);
        g.throughput(Throughput::Elements(s.triangles() as u64));
        g.bench_function(BenchmarkId::from_parameter(s.name), |b| {
            b.iter_custom(|iters| {
                phases_of(
                    iters,
                    || render(ctx, &f, PrimaryPass::Pgrid, ShadowPass::LightGrid, px),
                    |t| t.shadow_build,
                )
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("pgrid_light");
    let configs = [(16u32, 256u32), (64, 256), (128, 256), (64, 32), (64, 4096)];
    for (s, (ctx, px, rays)) in scenes.iter().zip(ctxs.iter_mut()) {
        let f = frame(s, true);
        g.throughput(Throughput::Elements(*rays));
        for (light_tiles, chunk) in configs {
            let pp = PgridParams {
                light_tiles,
                chunk,
                ..PgridParams::default()
            };
            ctx.build_pgrid(&s.scene(), &pp).expect("pgrid load");
            let label = format!("light grid {light_tiles}^2 tiles r={chunk}");
            g.bench_function(BenchmarkId::new(s.name, label), |b| {
                b.iter_custom(|iters| {
                    phases_of(
                        iters,
                        || render(ctx, &f, PrimaryPass::Pgrid, ShadowPass::LightGrid, px),
                        |t| t.rearrange + t.shadow_build + t.shadow_trace,
                    )
                })
            });
        }
        ctx.build_pgrid(&s.scene(), &PgridParams::default())
            .expect("pgrid load");
        let sp = ShadowPass::Traced(ranged(RayKind::Shadow));
        g.bench_function(BenchmarkId::new(s.name, "bvh-ranged 16x16"), |b| {
            b.iter_custom(|iters| {
                phases_of(
                    iters,
                    || render(ctx, &f, PrimaryPass::Pgrid, sp, px),
                    |t| t.rearrange + t.shadow_trace,
                )
            })
        });
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(2));
    targets = pgrid
}
criterion_main!(benches);
