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
use glam::Vec3;
use sheaf::scenes::{self, View};
use sheaf::{TraceParams, GridParams, Hit, Limits, Method, OwnedContext, Ray, Scene, required_bytes};
use std::hint::black_box;
use std::time::Duration;

/// Shared with the tests: OBJ loading (tobj) and the scenes folder.
#[path = "../tests/common/mod.rs"]
mod common;
use common::{load_obj, scenes_dir};

/// Image side of the traced view (rays per iteration: `SIDE * SIDE`).
const SIDE: u32 = 256;

/// A scene with its fixed view.
struct BenchScene {
    name: &'static str,
    vertices: Vec<f32>,
    indices: Vec<u32>,
    view: View,
}

impl BenchScene {
    fn scene(&self) -> Scene<'_> {
        Scene::from_f32(&self.vertices, &self.indices).expect("valid bench scene")
    }
    fn triangles(&self) -> u32 {
        (self.indices.len() / 3) as u32
    }
}

/// OBJ scenes: file under `../shared/scenes`, name, fixed view (+Y up).
/// bunny: outside, framing the bounding sphere from (0.6, 0.45, 1.0) like
/// `sheaf render`'s automatic view; sponza: down the atrium from its west
/// end under the first arch; conference: from a corner above the chairs
/// towards the table.
fn obj_specs() -> [(&'static str, &'static str, View); 3] {
    let y_up = |eye: [f32; 3], look_at: [f32; 3], fov_y_deg: f32| View {
        eye: Vec3::from(eye),
        look_at: Vec3::from(look_at),
        up: Vec3::Y,
        fov_y_deg,
    };
    [
        ("bunny/bunny_tinybvh.obj", "bunny", y_up([9.0, 11.42, 16.70], [-1.08, 3.86, -0.10], 45.0)),
        ("crytek_sponza/crytek_sponza.obj", "sponza", y_up([-120.0, 20.0, -4.0], [100.0, 45.0, -4.0], 60.0)),
        ("conference/conference.obj", "conference", y_up([-500.0, 400.0, 300.0], [333.0, 80.0, -194.0], 60.0)),
    ]
}

fn bench_scenes() -> Vec<BenchScene> {
    let mut out = Vec::new();
    for name in ["animated", "balls"] {
        let s = scenes::builtin(name).expect("builtin scene");
        out.push(BenchScene { name: s.name, vertices: s.mesh.vertices, indices: s.mesh.indices, view: s.views[0] });
    }
    if let Some(dir) = scenes_dir() {
        for (file, name, view) in obj_specs() {
            let path = dir.join(file);
            if !path.is_file() {
                eprintln!("note: {} not found: {name} skipped", path.display());
                continue;
            }
            if let Some((vertices, indices)) = load_obj(&path) {
                out.push(BenchScene { name, vertices, indices, view });
            }
        }
    }
    out
}

/// Limits for `s`, as an embedder would size them: `for_triangles(n)` with
/// the scene's vertex count, one thread.
fn limits(s: &BenchScene) -> Limits {
    let mut l = Limits::for_triangles(s.triangles());
    l.max_vertices = s.scene().vertex_count();
    l.max_threads = 1;
    l
}

fn primary_rays(view: &View) -> Vec<Ray> {
    common::view_rays(view, SIDE, SIDE)
}

/// Row-major rays reordered for `Context::trace_with`'s packet layout:
/// consecutive n x n tiles, each as 2x2 quads in row-major quad order.
fn packet_order(rays: &[Ray], side: usize, n: usize) -> Vec<Ray> {
    let mut out = Vec::with_capacity(rays.len());
    for ty in (0..side).step_by(n) {
        for tx in (0..side).step_by(n) {
            for qy in (ty..ty + n).step_by(2) {
                for qx in (tx..tx + n).step_by(2) {
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        out.push(rays[(qy + dy) * side + qx + dx]);
                    }
                }
            }
        }
    }
    out
}

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
            b.iter(|| ctx.build_grid(black_box(&scene), &params).expect("grid build"))
        });
    }
    g.finish();

    let mut g = c.benchmark_group("grid_trace_dda");
    for (s, (ctx, rays, hits)) in scenes.iter().zip(ctxs.iter_mut()) {
        g.throughput(Throughput::Elements(rays.len() as u64));
        g.bench_function(BenchmarkId::from_parameter(s.name), |b| {
            b.iter(|| ctx.trace(Method::GridDda, black_box(rays), hits).expect("trace"))
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
                b.iter(|| ctx.trace_with(&p, black_box(&ordered), hits).expect("trace"))
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
