//! `sheaf demo`: the animated scene, the grid rebuilt and the frame rendered
//! every frame, one table line per frame.

use super::mib;
use crate::DemoArgs;
use crate::progress::Progress;
use crate::run::{self, mrays, ms, res};
use anyhow::{Context as _, Result, anyhow, bail};
use sheaf::scenes::ANIMATED_DETAIL;
use sheaf::scenes::animated::Animated;
use sheaf::{Frame, PointLight, Scene, Shading, required_bytes};

/// `sheaf demo`: the animated scene, one rebuild and one render per frame.
pub fn demo(a: &DemoArgs) -> Result<()> {
    let threads = run::threads(a.threads)?;
    let (w, h) = a.size;
    let dt = a.dt;
    if !dt.is_finite() {
        bail!("--dt {dt}: must be finite");
    }
    let mut anim = Animated::new(ANIMATED_DETAIL);
    let views = anim.views();
    let view = *views.get(a.view).ok_or_else(|| {
        anyhow!(
            "--view {}: the demo has views 0..={}",
            a.view,
            views.len() - 1
        )
    })?;
    let params = a.grid.params();
    let (primary, shadow) = a.trace.params()?;

    // The one context: sized on frame 0, grid pools with 25 % headroom if the
    // default rule is too small, so later frames fit too.
    let (mut ctx, _) = {
        let scene = Scene::from_f32(&anim.mesh.vertices, &anim.mesh.indices)?;
        run::context_for(&scene, run::limits(&scene, a.size, threads), &params, 1.25)?
    };
    let bytes = required_bytes(ctx.limits())?;
    std::fs::create_dir_all(&a.out_dir)
        .with_context(|| format!("cannot create {}", a.out_dir.display()))?;
    let frame = Frame {
        camera: crate::view::camera(&view),
        light: PointLight {
            position: anim.light().to_array(),
            color: [1.0; 3],
            ..Default::default()
        },
        shading: Shading::default(),
        width: w,
        height: h,
    };
    let mut pixels = vec![0u8; w as usize * h as usize * 4];
    // One step per frame (a bar with ETA on a terminal, for long runs).
    let prog = Progress::new("sheaf demo", a.frames as u64);
    prog.say(format_args!(
        "sheaf demo: animated scene, {} triangles, {w}x{h}, {}, {threads} threads, dt {dt} s, context {:.2} MiB, frames in {}",
        anim.mesh.triangle_count(),
        a.trace.label(),
        mib(bytes),
        a.out_dir.display()
    ));
    prog.say(format_args!(
        "{:>5} {:>9} {:>12} {:>9} {:>9} {:>9} {:>9} {:>8}",
        "frame", "triangles", "grid", "refs", "build ms", "trace ms", "rays", "Mrays/s"
    ));
    let (mut build_ns, mut trace_ns, mut rays) = (0u64, 0u64, 0u64);
    for f in 0..a.frames {
        anim.set_time(f as f32 * dt);
        let scene = Scene::from_f32(&anim.mesh.vertices, &anim.mesh.indices)?;
        let info = ctx
            .build_grid_with(&scene, &params, &run::Broadcast::of(threads))
            .with_context(|| format!("frame {f}: building the grid"))?;
        let bvh =
            run::build_bvh_if_used(&mut ctx, &scene, params.test, &[primary, shadow], threads)?;
        let kd = run::build_kd_if_used(&mut ctx, &scene, params.test, &[primary, shadow], threads)?;
        let b = ctx.stats().build_ns
            + if bvh.is_some() {
                ctx.stats().bvh_build_ns
            } else {
                0
            }
            + if kd.is_some() {
                ctx.stats().kd_build_ns
            } else {
                0
            };
        let ctr = run::render_frame(&mut ctx, &primary, &shadow, &frame, &mut pixels, threads)?;
        let t = ctx.stats().trace_ns;
        run::write_png(&a.out_dir.join(format!("frame_{f:03}.png")), &pixels, w, h)?;
        prog.say(format_args!(
            "{f:>5} {:>9} {:>12} {:>9} {:>9.2} {:>9.2} {:>9} {:>8.2}",
            info.triangles,
            res(&info),
            info.refs,
            ms(b),
            ms(t),
            ctr.rays,
            mrays(ctr.rays, t)
        ));
        prog.step();
        build_ns += b;
        trace_ns += t;
        rays += ctr.rays;
    }
    let n = a.frames as u64;
    prog.say(format_args!(
        "mean over {n} frames: build {:.2} ms, trace {:.2} ms, {:.2} Mrays/s (lambda {}, macrocell {}, {:?})",
        ms(build_ns / n),
        ms(trace_ns / n),
        mrays(rays, trace_ns),
        a.grid.lambda,
        a.grid.macrocell,
        params.test
    ));
    Ok(())
}
