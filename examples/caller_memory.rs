//! A context in the caller's memory: `required_bytes` says how much,
//! `Context::new_in` carves every pool from a `&mut [u8]` the caller owns,
//! and from then on nothing allocates: not the builds, not the traces, not
//! the renders.
//!
//! A counting global allocator shows it: the allocations made between the
//! end of setup and the end of the frame loop are counted and printed
//! (zero). The buffer here is a `Vec` for brevity; a static array, an
//! engine's arena or a memory-mapped region serve as well (the no_std
//! build has no allocator at all).
//!
//! Run it with `cargo run --release --example caller_memory`.

use sheaf::render::{Camera, Frame, PointLight, Shading};
use sheaf::{
    BvhParams, Context, GridParams, Hit, Limits, Method, Ray, Scene, TraceParams, required_bytes,
};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

/// The system allocator, counting allocations.
struct Counting;
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards every call to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller upholds `GlobalAlloc::alloc`'s contract.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: the caller upholds `GlobalAlloc::dealloc`'s contract.
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller upholds `GlobalAlloc::realloc`'s contract.
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> usize {
    ALLOCATIONS.load(Ordering::Relaxed)
}

const W: u32 = 128;
const H: u32 = 96;
const FRAMES: u32 = 5;

fn main() -> Result<(), sheaf::Error> {
    // Setup, allocations allowed: the scene, the caller's buffers.
    let s = sheaf::scenes::builtin("balls").expect("built-in scene");
    let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices)?;
    let mut limits = Limits::for_triangles(scene.triangle_count());
    limits.max_vertices = scene.vertex_count();
    limits.max_image_width = W;
    limits.max_image_height = H;
    limits.max_threads = 1;
    limits.structures = Limits::GRID | Limits::BVH;
    let need = required_bytes(&limits)?;
    println!(
        "{} triangles: required_bytes = {need} ({:.1} bytes per triangle) for a grid and a BVH",
        scene.triangle_count(),
        need as f64 / scene.triangle_count() as f64
    );
    // The buffer must start on a 64-byte boundary: over-allocate by 63 and
    // start at the first aligned byte.
    let mut storage = vec![0u8; need + 63];
    let at = storage.as_ptr().align_offset(64);
    let buf = &mut storage[at..at + need];

    let v = s.views[0];
    let frame = Frame {
        camera: Camera {
            eye: v.eye.to_array(),
            look_at: v.look_at.to_array(),
            up: v.up.to_array(),
            fov_y_deg: v.fov_y_deg,
        },
        light: PointLight::new(s.light.to_array(), [1.0; 3]),
        shading: Shading::default(),
        width: W,
        height: H,
    };
    let stride = 4 * W as usize;
    let mut rgba = vec![0u8; stride * H as usize];
    let primary = sheaf::render::PrimaryRays::new(&frame.camera, W, H)?;
    let rays: Vec<Ray> = (0..W * H).map(|i| primary.ray(i % W, i / W)).collect();
    let mut hits = vec![Hit::MISS; rays.len()];

    // From here on: nothing allocates.
    let before = allocations();
    {
        // A buffer one byte short is refused, with the size it needs.
        let short = Context::new_in(&mut buf[..need - 1], &limits).err();
        let mut ctx = Context::new_in(buf, &limits)?;
        let mut hit_sum = 0;
        for _ in 0..FRAMES {
            // Per frame: rebuild both structures, trace, render.
            ctx.build_grid(&scene, &GridParams::default())?;
            ctx.build_bvh(&scene, &BvhParams::default())?;
            ctx.trace(Method::GridDda, &rays, &mut hits)?;
            hit_sum += hits.iter().filter(|h| h.is_hit()).count();
            ctx.trace_with(&TraceParams::bvh(Method::BvhRanged, 8), &rays, &mut hits)?;
            ctx.render(Method::GridCgt, &frame, &mut rgba, stride)?;
        }
        let after = allocations();
        // Printing allocates (stdout's buffer), so it comes after counting.
        println!("new_in on a buffer one byte short: {short:?}");
        println!(
            "{FRAMES} frames (grid and BVH rebuilt, {} rays traced twice, a {W}x{H} frame rendered, {hit_sum} hits in all): {} allocations",
            rays.len(),
            after - before
        );
        assert_eq!(after, before, "the context allocated after setup");
    }
    // The context is gone; the caller's memory is the caller's again.
    storage.fill(0);
    Ok(())
}
