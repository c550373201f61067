//! Render a frame into an RGBA8 buffer: a built-in scene, a BVH built for
//! the frame, camera rays and shadow rays traced as 8x8 packets.
//!
//! The frame is printed as ASCII art with a checksum of its bytes; given a
//! path it is also written as a binary PPM (the kernel has no image
//! dependency: PPM is a short header and the RGB bytes).
//!
//! Run it with `cargo run --release --example render_frame`, or
//! `cargo run --release --example render_frame -- gears out.ppm` for another
//! built-in scene (`tetra`, `balls`, `gears`, `animated`) and a PPM file.

use sheaf::render::{Camera, Frame, PointLight, Shading};
use sheaf::trace::RayKind;
use sheaf::{BvhParams, Limits, Method, OwnedContext, TraceParams};
use std::io::Write;

const WIDTH: u32 = 320;
const HEIGHT: u32 = 240;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let name = args.next().unwrap_or_else(|| "animated".into());
    let out = args.next();
    let s = sheaf::scenes::builtin(&name).ok_or("unknown built-in scene")?;
    let scene = sheaf::Scene::from_f32(&s.mesh.vertices, &s.mesh.indices)?;

    // Pools for this scene's size and images up to WIDTH x HEIGHT, BVH only.
    let mut limits = Limits::for_triangles(scene.triangle_count());
    limits.max_vertices = scene.vertex_count();
    limits.max_image_width = WIDTH;
    limits.max_image_height = HEIGHT;
    limits.structures = Limits::BVH;
    let mut ctx = OwnedContext::new(&limits)?;
    ctx.build_bvh(&scene, &BvhParams::default())?;

    let v = s.views[0];
    let frame = Frame {
        camera: Camera {
            eye: v.eye.to_array(),
            look_at: v.look_at.to_array(),
            up: v.up.to_array(),
            fov_y_deg: v.fov_y_deg,
        },
        light: PointLight::new(s.light.to_array(), [1.0, 1.0, 1.0]),
        shading: Shading::default(),
        width: WIDTH,
        height: HEIGHT,
    };
    // Camera rays and shadow rays as 8x8 Ranged packets, each with its
    // frustum (BVH paper sections 3.2 and 4).
    let p = TraceParams::bvh(Method::BvhRanged, 8);
    let stride = 4 * WIDTH as usize;
    let mut rgba = vec![0u8; stride * HEIGHT as usize];
    let ctr = ctx.render_with(
        &p.with_kind(RayKind::Primary),
        &p.with_kind(RayKind::Shadow),
        &frame,
        &mut rgba,
        stride,
    )?;
    println!(
        "{name}: {} triangles, {WIDTH}x{HEIGHT}, {} rays in {} packets, {:.1} ms",
        scene.triangle_count(),
        ctr.rays,
        ctr.packets,
        ctx.stats().trace_ns as f64 * 1e-6
    );

    // ASCII art: one character per 5 x 10 pixels, by luma.
    const RAMP: &[u8] = b" .:-=+*#%@";
    for y in (0..HEIGHT).step_by(10) {
        let line: String = (0..WIDTH)
            .step_by(5)
            .map(|x| {
                let i = y as usize * stride + 4 * x as usize;
                let [r, g, b] = [rgba[i], rgba[i + 1], rgba[i + 2]].map(u32::from);
                let luma = (299 * r + 587 * g + 114 * b) / 1000;
                RAMP[luma as usize * (RAMP.len() - 1) / 255] as char
            })
            .collect();
        println!("{line}");
    }
    // FNV-1a over the RGBA bytes: equal on every machine for the same
    // scene, view, size and triangle test.
    let sum = rgba.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    });
    println!("checksum (FNV-1a of the RGBA bytes): {sum:016x}");

    if let Some(path) = out {
        let mut f = std::io::BufWriter::new(std::fs::File::create(&path)?);
        write!(f, "P6\n{WIDTH} {HEIGHT}\n255\n")?;
        for px in rgba.chunks_exact(4) {
            f.write_all(&px[..3])?;
        }
        f.flush()?;
        println!("wrote {path}");
    }
    Ok(())
}
