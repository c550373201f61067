//! No allocation after setup (every pool is carved then), proved
//! with a counting global allocator over 10 frames of the animated scene:
//! set geometry, rebuild the grid, trace, occlude and render every frame,
//! with the 3DDDA and with coherent grid traversal, the BVH and kd-tree
//! methods, and deferred frames (perspective grid and light grids, loaded
//! by `build_pgrid` every frame, with traced passes mixed in, two lights
//! one of them a spot), and a two-level scene (a static geometry, a
//! refit one and a rebuilt one, instances moved, added and removed, the
//! top level committed and traced every frame).
//! Its own test binary with one test; allocations are counted per thread
//! (the test's), so the harness's own (its main thread reporting while the
//! test runs) are not counted: the context runs on the calling thread.

#[path = "common/ray_stream.rs"]
mod ray_stream;

use sheaf::accel::bvh::BvhParams;
use sheaf::accel::kd::KdParams;
use sheaf::render::{Camera, Frame, PointLight, Shading};
use sheaf::scenes::animated::Animated;
use sheaf::trace::EntrySearch;
use sheaf::{Affine, GeometryParams, SceneHit, UpdateMode};
use sheaf::{
    Context, DeferredJob, GridParams, Hit, Limits, Method, OnCaller, OwnedContext, PgridParams,
    PrimaryPass, Ray, Scene, ShadowPass, TraceParams, TriTest, required_bytes,
};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;
thread_local! {
    // Const-initialised without a destructor: reading it never allocates.
    static ALLOCS: Cell<usize> = const { Cell::new(0) };
}

fn bump() {
    // `try_with`: a thread being torn down has no slot left; not ours.
    let _ = ALLOCS.try_with(|a| a.set(a.get() + 1));
}

// SAFETY: forwards to the system allocator; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        bump();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        bump();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocs() -> usize {
    ALLOCS.with(Cell::get)
}

fn frame_of(anim: &Animated) -> Frame {
    let v = anim.views()[0];
    Frame {
        camera: Camera {
            eye: v.eye.to_array(),
            look_at: v.look_at.to_array(),
            up: v.up.to_array(),
            fov_y_deg: v.fov_y_deg,
        },
        light: PointLight {
            position: anim.light().to_array(),
            color: [1.0; 3],
            ..Default::default()
        },
        shading: Shading::default(),
        width: 96,
        height: 64,
    }
}

#[test]
fn ten_animated_frames_allocate_nothing() {
    let mut anim = Animated::new(1);
    let frame = frame_of(&anim);
    let tris = anim.mesh.triangle_count() as u32;
    let tetra = sheaf::scenes::builtin("tetra").unwrap();
    // Room for the flattened two-level scene seen by mask 2 (the tetra
    // and one animated instance) in the grid and kd-tree pools.
    let mut limits = Limits::for_triangles(tris + tetra.mesh.triangle_count() as u32);
    limits.max_vertices = anim.mesh.vertex_count() as u32;
    // The perspective and light grids' pools scale with the image.
    limits.structures |= Limits::PGRID;
    limits.max_image_width = frame.width;
    limits.max_image_height = frame.height;
    // The two-level scene: three geometries (the animated mesh twice, one
    // of them rebuilt, and a static tetra), up to 6 instances.
    limits.max_geometries = 3;
    limits.max_instances = 6;
    limits.max_scene_triangles = 2 * tris + tetra.mesh.triangle_count() as u32;

    // Creation: exactly one allocation for the owned context...
    let a0 = allocs();
    let mut owned = OwnedContext::new(&limits).unwrap();
    assert_eq!(
        allocs() - a0,
        1,
        "OwnedContext::new must allocate exactly once"
    );
    // ...and none over a caller buffer.
    let need = required_bytes(&limits).unwrap();
    let mut backing = vec![0u8; need + 64];
    let off = backing.as_ptr().align_offset(64);
    let a1 = allocs();
    let mut borrowed = Context::new_in(&mut backing[off..off + need], &limits).unwrap();
    assert_eq!(allocs(), a1, "Context::new_in must not allocate");

    // Caller-side buffers, made before the measured loop.
    let rays: Vec<Ray> = (0..256)
        .map(|k| {
            let (x, y) = ((k % 16) as f32 / 16.0 - 0.5, (k / 16) as f32 / 16.0 - 0.5);
            let cam = &frame.camera;
            let d = [
                cam.look_at[0] - cam.eye[0] + x,
                cam.look_at[1] - cam.eye[1] + y,
                cam.look_at[2] - cam.eye[2],
            ];
            Ray {
                org: cam.eye,
                tmin: 0.0,
                dir: d,
                tmax: f32::INFINITY,
            }
        })
        .collect();
    let mut hits = vec![Hit::MISS; rays.len()];
    let mut occ = vec![false; rays.len()];
    let stride = frame.width as usize * 4;
    let mut pixels = vec![0u8; stride * frame.height as usize];
    let mut hit_total = 0usize;
    let mut deferred = Deferred::default();
    // Two lights: the scene's, and a spot from above the camera aimed at
    // what it looks at.
    let view = anim.views()[0];
    let (spot_at, spot_from) = (view.look_at, view.eye + glam::Vec3::new(0.0, 0.0, 3.0));

    let tetra_scene = Scene::from_f32(&tetra.mesh.vertices, &tetra.mesh.indices).unwrap();
    let mut scene_hits = vec![SceneHit::MISS; rays.len()];
    let mut scene_hit_total = 0usize;
    // The same rays as a ray stream, and a hit stream for them.
    let cols = ray_stream::Columns::of(&rays);
    let stream = cols.stream();
    let n = rays.len();
    let (mut st, mut su, mut sv) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    let (mut sp, mut sg, mut si) = (vec![0; n], vec![0; n], vec![0; n]);
    let cam = sheaf::PrimaryRays::new(&frame.camera, frame.width, frame.height).unwrap();
    for ctx in [&mut owned, &mut borrowed] {
        let scene = Scene::from_f32(&anim.mesh.vertices, &anim.mesh.indices).unwrap();
        let at = |mode| GeometryParams {
            mode,
            ..GeometryParams::default()
        };
        ctx.set_geometry(0, &tetra_scene, &at(UpdateMode::Static))
            .unwrap();
        ctx.set_geometry(1, &scene, &at(UpdateMode::Refit)).unwrap();
        ctx.set_geometry(2, &scene, &at(UpdateMode::Rebuild))
            .unwrap();
        for (i, g) in [0u32, 1, 2, 1].iter().enumerate() {
            let at = Affine::translation([i as f32 * 0.25, 0.0, 0.0]);
            let mask = if i < 2 { !0 } else { 1 };
            ctx.set_instance(i as u32, *g, &at, mask).unwrap();
        }
    }

    let start = allocs();
    for f in 0..10 {
        anim.set_time(f as f32 * 0.37);
        let scene = Scene::from_f32(&anim.mesh.vertices, &anim.mesh.indices).unwrap();
        let test = if f % 2 == 0 {
            TriTest::MollerTrumbore
        } else {
            TriTest::Watertight
        };
        let params = GridParams {
            test,
            ..GridParams::default()
        };
        let lights = [
            PointLight {
                position: anim.light().to_array(),
                color: [0.7; 3],
                ..Default::default()
            },
            PointLight {
                position: spot_from.to_array(),
                color: [0.5; 3],
                spot_direction: (spot_at - spot_from).to_array(),
                spot_angle_deg: 25.0,
                spot_soft_deg: 5.0,
            },
        ];
        for ctx in [&mut owned, &mut borrowed] {
            ctx.update_geometry(1, &scene).unwrap();
            ctx.update_geometry(2, &scene).unwrap();
            let moved = Affine::translation([0.1 * f as f32, 0.0, -0.05 * f as f32]);
            ctx.set_instance(1, 1, &moved, !0).unwrap();
            if f % 2 == 0 {
                ctx.set_instance(4, 2, &moved, 1).unwrap();
            } else {
                ctx.remove_instance(4).unwrap();
            }
            ctx.commit_scene().unwrap();
            ctx.trace_scene(&rays, !0, &mut scene_hits).unwrap();
            scene_hit_total += scene_hits.iter().filter(|h| h.is_hit()).count();
            // The grid and kd-tree over the flattened scene.
            ctx.build_grid_scene(&params, 2).unwrap();
            ctx.build_kd_scene(&sheaf::KdParams::default(), 2).unwrap();
            for m in [Method::GridCgt, Method::KdPacket] {
                let p = TraceParams {
                    method: m,
                    ..TraceParams::default()
                };
                ctx.trace_scene_with(&p, &rays, 2, &mut scene_hits).unwrap();
                scene_hit_total += scene_hits.iter().filter(|h| h.is_hit()).count();
            }
            ctx.occluded_scene(&rays, 1, &mut occ).unwrap();
            // Ray streams: the frustum packets and single rays.
            let p = TraceParams {
                method: Method::BvhFrustum,
                packet: 16,
                ..TraceParams::default()
            };
            let mut out = sheaf::SceneHitStream {
                t: &mut st,
                u: &mut su,
                v: &mut sv,
                prim: &mut sp,
                geometry: &mut sg,
                instance: &mut si,
            };
            ctx.trace_scene_stream(Some(&p), None, &stream, !0, &mut out)
                .unwrap();
            scene_hit_total += sp.iter().filter(|&&k| k != sheaf::geom::INVALID_ID).count();
            ctx.occluded_scene_stream(None, None, &stream, 1, &mut occ)
                .unwrap();
            // Camera packets made in the kernel, a 16 x 16 tile.
            let tile = sheaf::PixelRect {
                x0: 0,
                y0: 0,
                x1: 16,
                y1: 16,
            };
            ctx.trace_scene_camera(Some(&p), None, &cam, tile, !0, &mut scene_hits, 16)
                .unwrap();
            scene_hit_total += scene_hits.iter().filter(|h| h.is_hit()).count();
        }
        for ctx in [
            &mut owned as &mut dyn Frames,
            &mut borrowed as &mut dyn Frames,
        ] {
            let traced = Traced {
                rays: &rays,
                hits: &mut hits,
                occluded: &mut occ,
            };
            let image = Image {
                frame: &frame,
                lights: &lights,
                pixels: &mut pixels,
                stride,
            };
            ctx.frame(&scene, &params, traced, image, &mut deferred);
            hit_total += hits.iter().filter(|h| h.is_hit()).count();
        }
        // Single-mesh ray streams on the frame's last structures.
        for ctx in [&mut owned, &mut borrowed] {
            let p = TraceParams {
                method: Method::BvhFrustum,
                packet: 16,
                ..TraceParams::default()
            };
            let mut out = sheaf::HitStream {
                t: &mut st,
                u: &mut su,
                v: &mut sv,
                prim: &mut sp,
            };
            ctx.trace_stream(None, &p, &stream, &mut out).unwrap();
            hit_total += sp.iter().filter(|&&k| k != sheaf::geom::INVALID_ID).count();
            ctx.occluded_stream(Some(0), &p, &stream, &mut occ).unwrap();
        }
    }
    let during = allocs() - start;
    assert_eq!(
        during, 0,
        "10 frames of grid, BVH and kd-tree builds + trace + occluded + render + deferred frames allocated {during} times"
    );
    assert!(hit_total > 0, "the frames must trace something");
    assert!(scene_hit_total > 0, "the two-level scene must be hit");
    assert!(pixels.iter().any(|&p| p != 0));
    assert_eq!(
        deferred.frames,
        10 * 2 * 4,
        "every deferred frame must render"
    );
    assert!(
        deferred.hits > 0 && deferred.shadow_rays > 0 && deferred.chunks > 0,
        "the deferred frames must trace camera and shadow rays: {deferred:?}"
    );
}

/// What the deferred frames did (summed), so the test knows they ran.
#[derive(Debug, Default)]
struct Deferred {
    frames: u32,
    hits: u64,
    shadow_rays: u64,
    chunks: u64,
}

/// The rays a frame traces, and their hits and occlusion.
struct Traced<'a> {
    rays: &'a [Ray],
    hits: &'a mut [Hit],
    occluded: &'a mut [bool],
}

/// The image a frame renders: its frame and lights, and its pixels
/// (`stride` bytes per row).
struct Image<'a> {
    frame: &'a Frame,
    lights: &'a [PointLight],
    pixels: &'a mut [u8],
    stride: usize,
}

/// One frame on either kind of context.
trait Frames {
    fn frame(
        &mut self,
        s: &Scene,
        p: &GridParams,
        traced: Traced<'_>,
        image: Image<'_>,
        d: &mut Deferred,
    );
}
macro_rules! impl_frames {
    ($($t:ty),*) => {$(
        impl Frames for $t {
            fn frame(&mut self, s: &Scene, p: &GridParams, traced: Traced<'_>, image: Image<'_>, d: &mut Deferred) {
                let Traced { rays: r, hits: h, occluded: o } = traced;
                let Image { frame: f, lights, pixels: px, stride } = image;
                self.build_grid(s, p).unwrap();
                self.trace(Method::GridDda, r, h).unwrap();
                self.occluded(Method::GridDda, r, o).unwrap();
                self.render(Method::GridDda, f, px, stride).unwrap();
                // The packet method: CGT at two packet sizes, shadow splitting on.
                for n in [4, 16] {
                    let cgt = TraceParams::cgt(n);
                    self.trace_with(&cgt, r, h).unwrap();
                    self.occluded_with(&cgt, r, o).unwrap();
                    self.render_with(&cgt, &cgt, f, px, stride).unwrap();
                }
                // The BVH beside the grid: build, then every BVH method.
                self.build_bvh(s, &BvhParams { test: p.test, ..BvhParams::default() }).unwrap();
                for m in [Method::BvhSingle, Method::BvhWide, Method::BvhSimd, Method::BvhMasked, Method::BvhRanged, Method::BvhPartition, Method::BvhWideRanged, Method::BvhFrustum] {
                    let bp = TraceParams::bvh(m, 16);
                    self.trace_with(&bp, r, h).unwrap();
                    self.occluded_with(&bp, r, o).unwrap();
                    self.render_with(&bp, &bp, f, px, stride).unwrap();
                    // Camera packets made in the kernel: a 16 x 16 tile.
                    let cam = sheaf::PrimaryRays::new(&f.camera, f.width, f.height).unwrap();
                    let tile = sheaf::PixelRect { x0: 0, y0: 0, x1: 16, y1: 16 };
                    self.trace_camera(None, &bp, &cam, tile, h, 16).unwrap();
                }
                // BVH packets from AEPSA entry points.
                let bp = TraceParams::bvh(Method::BvhRanged, 16).with_entry(EntrySearch::Aepsa);
                self.trace_with(&bp, r, h).unwrap();
                // A refit (to the same vertices), and one with a rebuild threshold.
                self.refit_bvh(s, &sheaf::RefitParams::default()).unwrap();
                self.refit_bvh(s, &sheaf::RefitParams { rebuild_above: 1.0 }).unwrap();
                self.trace_with(&bp, r, h).unwrap();
                // The fast (Morton) build, on the calling thread and on a
                // worker set that runs every task here (as a caller's pool
                // would on its threads; the threads are the caller's).
                let low = BvhParams { test: p.test, quality: sheaf::BuildQuality::Low, ..BvhParams::default() };
                self.build_bvh(s, &low).unwrap();
                struct Inline(usize);
                impl sheaf::mem::par::Par for Inline {
                    fn workers(&self) -> usize {
                        self.0
                    }
                    fn run(&self, task: &(dyn Fn(usize) + Sync)) {
                        (0..self.0).for_each(task)
                    }
                }
                self.build_bvh_with(s, &low, &Inline(3)).unwrap();
                self.refit_bvh_with(s, &sheaf::RefitParams::default(), &Inline(3)).unwrap();
                let gp = GridParams { test: p.test, ..GridParams::default() };
                self.build_grid_with(s, &gp, &Inline(3)).unwrap();
                self.trace_with(&TraceParams::cgt(8), r, h).unwrap();
                self.trace_with(&bp, r, h).unwrap();
                // The kd-tree beside both: build, every kd method and entry search.
                self.build_kd(s, &KdParams { test: p.test, ..KdParams::default() }).unwrap();
                for m in [Method::KdSingle, Method::KdSimd, Method::KdPacket] {
                    for &e in EntrySearch::ALL {
                        let kp = TraceParams::bvh(m, 16).with_entry(e);
                        self.trace_with(&kp, r, h).unwrap();
                        self.occluded_with(&kp, r, o).unwrap();
                        self.render_with(&kp, &kp, f, px, stride).unwrap();
                    }
                }
                // Deferred frames: the scene loaded for the perspective and
                // light grids (rebuilt inside every frame), then the grid
                // passes and traced passes mixed, with both lights and with
                // the frame's light alone.
                self.build_pgrid(s, &PgridParams { test: p.test, chunk: 64, ..PgridParams::default() }).unwrap();
                let bvh16 = TraceParams::bvh(Method::BvhRanged, 16);
                for (primary, shadow, ls) in [
                    (PrimaryPass::Pgrid, ShadowPass::LightGrid, lights),
                    (PrimaryPass::Traced(bvh16), ShadowPass::LightGrid, lights),
                    (PrimaryPass::Pgrid, ShadowPass::Traced(TraceParams::cgt(8)), lights),
                    (PrimaryPass::Pgrid, ShadowPass::LightGrid, &[][..]),
                ] {
                    let job = DeferredJob { frame: f, lights: ls, primary, shadow };
                    let info = self.render_deferred(&job, px, stride, &mut OnCaller).unwrap();
                    // The same frame with its phases joined by three workers.
                    let joined = self.render_deferred(&job, px, stride, &mut sheaf::OnPar(&Inline(3))).unwrap();
                    assert_eq!(joined.reorder, info.reorder);
                    d.frames += 1;
                    d.hits += info.hits;
                    d.shadow_rays += info.shadow_rays;
                    d.chunks += info.reorder.chunks as u64;
                    let _ = self.deferred_pixel(f.width / 2, f.height / 2);
                    let _ = self.deferred_shadow_ray(f.width / 2, f.height / 2, &f.light);
                }
            }
        }
    )*};
}
// `OwnedContext` is `Context<'static>`: one impl covers both.
impl_frames!(Context<'_>);
