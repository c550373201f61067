//! Trace a handful of rays through a BVH: the smallest complete use of the
//! Rust API.
//!
//! A hand-made scene (a floor and a pyramid, 6 triangles) gets a context
//! sized for it, a BVH is built over it, and one 4x4 packet of camera rays
//! is traced with the BVH's Ranged packet traversal (Overbeck et al. 2008,
//! section 3.2). The hits are printed, and shadow rays from a point light
//! to the hit points are tested for occlusion with the same traversal.
//!
//! Run it with `cargo run --release --example trace_rays`.

use glam::Vec3;
use sheaf::render::{Camera, PrimaryRays};
use sheaf::trace::RayKind;
use sheaf::{BvhParams, Hit, Limits, Method, OwnedContext, Ray, Scene, TraceParams};

/// Packet side: 4x4 rays.
const N: u32 = 4;

fn main() -> Result<(), sheaf::Error> {
    // Vertices (x, y, z; +y up) and triangles (three indices each): a 4 x 4
    // floor at y = 0 and a pyramid of height 1 standing on it.
    #[rustfmt::skip]
    let vertices: [f32; 3 * 9] = [
        -2.0, 0.0, -2.0,   2.0, 0.0, -2.0,   2.0, 0.0, 2.0,   -2.0, 0.0, 2.0,
        -0.5, 0.0, -0.5,   0.5, 0.0, -0.5,   0.5, 0.0, 0.5,   -0.5, 0.0, 0.5,
         0.0, 1.0,  0.0,
    ];
    #[rustfmt::skip]
    let indices: [u32; 3 * 6] = [
        0, 2, 1,  0, 3, 2,                        // floor
        4, 8, 5,  5, 8, 6,  6, 8, 7,  7, 8, 4,    // pyramid sides
    ];
    let scene = Scene::from_f32(&vertices, &indices)?;

    // A context sized for this scene with BVH pools only. `OwnedContext`
    // makes its one allocation here; nothing below allocates.
    let mut limits = Limits::for_triangles(scene.triangle_count());
    limits.max_vertices = scene.vertex_count();
    limits.structures = Limits::BVH;
    let mut ctx = OwnedContext::new(&limits)?;
    let info = ctx.build_bvh(&scene, &BvhParams::default())?;
    println!(
        "BVH over {} triangles: {} nodes, {} leaves, depth {}",
        info.triangles, info.nodes, info.leaves, info.depth
    );

    // Camera rays through the centres of a 4x4 "image", in the order packet
    // methods take them: 2x2 quads in row-major quad order, each quad's
    // lanes (x, y), (x+1, y), (x, y+1), (x+1, y+1).
    let cam = Camera {
        eye: [0.0, 1.6, 3.0],
        look_at: [0.0, 0.2, 0.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 45.0,
    };
    let primary = PrimaryRays::new(&cam, N, N)?;
    let mut pixels = Vec::new();
    for qy in (0..N).step_by(2) {
        for qx in (0..N).step_by(2) {
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                pixels.push((qx + dx, qy + dy));
            }
        }
    }
    let rays: Vec<Ray> = pixels.iter().map(|&(x, y)| primary.ray(x, y)).collect();

    // One 4x4 packet, Ranged traversal, camera-ray frustum.
    let p = TraceParams::bvh(Method::BvhRanged, N).with_kind(RayKind::Primary);
    let mut hits = vec![Hit::MISS; rays.len()];
    let ctr = ctx.trace_with(&p, &rays, &mut hits)?;

    // Shadow rays from the light to just above each hit point (tmax = 1:
    // the end point itself is not tested); misses get an empty ray.
    let light = Vec3::new(-2.0, 1.5, -1.0);
    let mut ends = Vec::new();
    let shadow: Vec<Ray> = rays
        .iter()
        .zip(&hits)
        .map(|(r, h)| {
            let end = Vec3::from(r.org) + Vec3::from(r.dir) * h.t.min(1e3) + Vec3::Y * 1e-3;
            ends.push(end);
            let tmax = if h.is_hit() { 1.0 } else { 0.0 };
            Ray::new(light, end - light, 0.0, tmax)
        })
        .collect();
    let mut occluded = vec![false; shadow.len()];
    let ps = p.with_kind(RayKind::Shadow);
    ctx.occluded_with(&ps, &shadow, &mut occluded)?;

    println!(
        "{} rays in {} packet(s), {} box tests, {} triangle tests:",
        ctr.rays, ctr.packets, ctr.aabb_tests, ctr.tri_tests
    );
    for (i, &(x, y)) in pixels.iter().enumerate() {
        let h = &hits[i];
        if h.is_hit() {
            let what = if h.prim < 2 { "floor" } else { "pyramid" };
            let p = ends[i];
            println!(
                "  pixel ({x}, {y}): triangle {} ({what}) at t = {:.3}, point ({:.2}, {:.2}, {:.2}), {}",
                h.prim,
                h.t,
                p.x,
                p.y,
                p.z,
                if occluded[i] { "in shadow" } else { "lit" }
            );
        } else {
            println!("  pixel ({x}, {y}): miss");
        }
    }
    Ok(())
}
