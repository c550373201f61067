//! `sheaf render`: one image of an OBJ file or a built-in scene: plain
//! frames (Lambert, shadow rays), Whitted frames (reflections, refractions)
//! or deferred frames (perspective grid, light grids; their phase times).

use super::{grid_line, kd_line, mib, phases, primary_label, shadow_label, v3};
use crate::load::{self, Loaded};
use crate::run::{self, mrays, ms};
use crate::view::{self, INSIDE_FOV, OUTSIDE_FOV};
use crate::{MaterialsArg, PrimaryArg, RenderArgs, ShadowsArg};
use anyhow::{Context as _, Result, anyhow, bail};
use glam::Vec3;
use sheaf::render::material::{Material, Materials};
use sheaf::render::whitted::{WhittedJob, WhittedParams};
use sheaf::trace::RayKind;
use sheaf::{
    DeferredInfo, DeferredJob, Frame, GridInfo, Limits, PointLight, PrimaryPass, Shading,
    ShadowPass, TraceParams, required_bytes,
};
use std::fmt::Write as _;
use std::time::Instant;

fn excluded_line(l: &Loaded, info: &GridInfo) -> String {
    let mut s = format!(
        "{} ({} excluded: {} non-finite, {} zero-area)",
        info.triangles_in,
        info.excluded_non_finite + info.excluded_zero_area,
        info.excluded_non_finite,
        info.excluded_zero_area
    );
    if l.skipped > 0 {
        let _ = write!(
            s,
            "; {} triangles of the file's faces skipped by the OBJ loader",
            l.skipped
        );
    }
    s
}

/// `sheaf render`: one image of an OBJ file or a built-in scene.
pub fn render(a: &RenderArgs) -> Result<()> {
    let threads = run::threads(a.threads)?;
    let (w, h) = a.size;
    if let Some(f) = a.fov.filter(|f| !(*f > 0.0 && *f < 180.0)) {
        bail!("--fov {f}: must be in (0, 180)");
    }
    if a.up == Some([0.0; 3]) {
        bail!("--up must not be zero");
    }
    let t_load = Instant::now();
    let loaded = load::load(&a.scene)?;
    let load_ns = t_load.elapsed().as_nanos() as u64;
    let scene = loaded.scene()?;
    if scene.triangle_count() == 0 {
        bail!("{}: no triangles", loaded.label);
    }
    let params = a.grid.params();
    let (primary, shadow) = a.trace.params()?;
    // Deferred frames: --primary / --shadows.
    let deferred = a.primary.is_some() || a.shadows.is_some();
    if deferred && (a.reflect > 0 || a.refract > 0) {
        bail!(
            "--primary/--shadows render deferred frames, which have no reflections or refractions"
        );
    }
    if !deferred && a.pgrid.any() {
        bail!(
            "--pgrid-tile, --pgrid-group, --slices, --light-tiles, --light-slices and --chunk apply to deferred frames: add --primary pgrid or --shadows light-grid"
        );
    }
    let pgrid = a.pgrid.params(params.test).context("pgrid parameters")?;
    let (primary_pass, shadow_pass) = passes(a, &primary, &shadow, &pgrid)?;
    let traced: Vec<TraceParams> = [
        match primary_pass {
            PrimaryPass::Traced(p) => Some(p),
            PrimaryPass::Pgrid => None,
        },
        match shadow_pass {
            ShadowPass::Traced(p) => Some(p),
            ShadowPass::LightGrid => None,
        },
    ]
    .into_iter()
    .flatten()
    .collect();
    let uses = |s: sheaf::trace::Structure| traced.iter().any(|p| p.method.structure() == s);
    let setup = run::DeferredSetup {
        scene: &scene,
        grid: params,
        bvh: uses(sheaf::trace::Structure::Bvh),
        kd: uses(sheaf::trace::Structure::Kd),
        pgrid,
    };
    let (mut ctx, info) = if deferred {
        setup.context(run::limits(&scene, a.size, threads))?
    } else {
        run::context_for(&scene, run::limits(&scene, a.size, threads), &params, 1.0)?
    };
    if info.triangles == 0 {
        bail!(
            "{}: every triangle is degenerate or non-finite",
            loaded.label
        );
    }
    let whitted = a.reflect > 0 || a.refract > 0;
    let secondary = match a.secondary_method {
        Some(m) => sheaf::TraceParams {
            method: m.method(),
            ..primary
        },
        // The paper's recommendation for its own traversals; the frustum
        // walk's secondary packets beat Partition's (Whitted frames 1.05-1.29x
        // faster on four scenes, docs/studies/whitted.md).
        None if matches!(
            primary.method,
            sheaf::Method::BvhMasked | sheaf::Method::BvhRanged
        ) && primary.packet >= 16 =>
        {
            sheaf::TraceParams {
                method: sheaf::Method::BvhPartition,
                ..primary
            }
        }
        None => primary,
    };
    let (bvh, kd) = if deferred {
        (
            setup.bvh.then(|| ctx.stats().bvh),
            setup.kd.then(|| ctx.stats().kd),
        )
    } else {
        (
            run::build_bvh_if_used(
                &mut ctx,
                &scene,
                params.test,
                &[primary, shadow, secondary],
                threads,
            )?,
            run::build_kd_if_used(
                &mut ctx,
                &scene,
                params.test,
                &[primary, shadow, secondary],
                threads,
            )?,
        )
    };

    // Camera: the builtin's view or an automatic one, then the user's overrides.
    let (lo, hi) = (info.bounds.min, info.bounds.max);
    let scale = (hi - lo).length();
    let (mut v, how) = match &loaded.builtin {
        Some((views, _)) => {
            let i = a.view.unwrap_or(0);
            let v = *views.get(i).ok_or_else(|| {
                anyhow!(
                    "--view {i}: {} has views 0..={}",
                    loaded.label,
                    views.len() - 1
                )
            })?;
            (v, format!("builtin view {i}"))
        }
        None => {
            let up = a.up.map_or(Vec3::Y, Vec3::from);
            let tracer = ctx.tracer()?;
            let inside = view::inside(&tracer, lo, hi, up, a.fov.unwrap_or(INSIDE_FOV));
            let interior = view::is_interior(&tracer, inside.eye);
            let i = a.view.unwrap_or(interior as usize);
            let v = match i {
                0 => view::outside(
                    lo,
                    hi,
                    up,
                    a.fov.unwrap_or(OUTSIDE_FOV),
                    w as f32 / h as f32,
                ),
                1 => inside,
                _ => {
                    bail!("--view {i}: OBJ scenes have views 0 (outside) and 1 (inside)");
                }
            };
            let what = if i == 0 { "outside" } else { "inside" };
            let why = if a.view.is_some() {
                "chosen"
            } else if interior {
                "auto: the scene encloses it"
            } else {
                "auto"
            };
            (v, format!("{what} view ({why})"))
        }
    };
    let custom = a.eye.is_some() || a.look_at.is_some() || a.up.is_some() || a.fov.is_some();
    if let Some(e) = a.eye {
        v.eye = Vec3::from(e);
    }
    if let Some(l) = a.look_at {
        v.look_at = Vec3::from(l);
    }
    if let Some(u) = a.up {
        v.up = Vec3::from(u);
    }
    if let Some(f) = a.fov {
        v.fov_y_deg = f;
    }
    // Light: the user's, the builtin's, or one placed for the final eye
    // (kept inside the room when the eye is enclosed).
    let light = match (a.light, &loaded.builtin) {
        (Some(p), _) => PointLight {
            position: p,
            color: [1.0; 3],
            ..Default::default()
        },
        (None, Some((_, l))) => PointLight {
            position: l.to_array(),
            color: [1.0; 3],
            ..Default::default()
        },
        (None, None) => {
            let tracer = ctx.tracer()?;
            view::light_for(&tracer, &v, view::is_interior(&tracer, v.eye), scale)
        }
    };
    let frame = Frame {
        camera: view::camera(&v),
        light,
        shading: Shading {
            shadows: !a.no_shadows,
            ..Shading::default()
        },
        width: w,
        height: h,
    };
    let mut pixels = vec![0u8; w as usize * h as usize * 4];
    let forced = match a.materials {
        MaterialsArg::Scene => None,
        MaterialsArg::Mirror => Some(Material {
            reflect: 0.6,
            ..Material::diffuse(frame.shading.albedo)
        }),
        MaterialsArg::Glass => Some(Material {
            transmit: 0.7,
            ior: 1.5,
            ..Material::diffuse(frame.shading.albedo)
        }),
        MaterialsArg::Mixed => Some(Material {
            reflect: 0.3,
            transmit: 0.3,
            ior: 1.5,
            ..Material::diffuse(frame.shading.albedo)
        }),
    };
    let mut dfr: Option<(DeferredInfo, run::Threads, bool)> = None;
    let ctr = if deferred {
        let job = DeferredJob {
            frame: &frame,
            lights: &[],
            primary: primary_pass,
            shadow: shadow_pass,
        };
        let mut workers = run::Threads::new(threads);
        workers.keep_items = true;
        let (di, grown) = setup.render(&mut ctx, &job, &mut pixels, &mut workers)?;
        dfr = Some((di, workers, grown));
        ctx.stats().counters
    } else if whitted {
        let materials = match &forced {
            Some(m) => Materials::uniform(m),
            None => loaded.materials(),
        };
        let job = WhittedJob {
            frame: &frame,
            lights: &[],
            materials,
            params: WhittedParams {
                max_reflect: a.reflect,
                max_refract: a.refract,
            },
            primary: primary.with_kind(RayKind::Primary),
            shadow: shadow.with_kind(RayKind::Shadow),
            secondary: secondary.with_kind(RayKind::Secondary),
        };
        run::render_whitted_frame(&mut ctx, &job, &mut pixels, threads)?
    } else {
        run::render_frame(&mut ctx, &primary, &shadow, &frame, &mut pixels, threads)?
    };
    let st = *ctx.stats();
    run::write_png(&a.out, &pixels, w, h)?;

    let primary = w as u64 * h as u64;
    let bytes = required_bytes(ctx.limits())?;
    println!(
        "scene      {} (loaded in {:.0} ms)",
        loaded.label,
        ms(load_ns)
    );
    println!(
        "triangles  {}, {} vertices",
        excluded_line(&loaded, &info),
        loaded.vertex_count()
    );
    println!("grid       {}", grid_line(&info, &a.grid));
    println!(
        "memory     {bytes} bytes ({:.2} MiB) in one context",
        mib(bytes)
    );
    println!("build      grid {:.2} ms", ms(st.build_ns));
    if let Some(b) = bvh {
        println!(
            "bvh        {} nodes, {} leaves, depth {}, SAH cost {:.1}, build {:.2} ms = {:.2} M triangles/s",
            b.nodes,
            b.leaves,
            b.depth,
            b.sah_cost,
            ms(st.bvh_build_ns),
            b.triangles as f64 / (st.bvh_build_ns.max(1) as f64 * 1e-3)
        );
    }
    if let Some(k) = kd {
        println!("kd-tree    {}", kd_line(&k, st.kd_build_ns));
    }
    match &dfr {
        Some(_) => println!(
            "method     deferred: camera rays {} / shadows {}",
            primary_label(&primary_pass),
            shadow_label(&shadow_pass)
        ),
        None => println!("method     {}", a.trace.label()),
    }
    if whitted {
        println!(
            "whitted    up to {} reflections and {} refractions per path, materials {:?}, reflection/refraction rays {}",
            a.reflect,
            a.refract,
            a.materials,
            if secondary.method.is_packet() {
                format!(
                    "{} {}x{}",
                    secondary.method.name(),
                    secondary.packet,
                    secondary.packet
                )
            } else {
                secondary.method.name().to_string()
            }
        );
    }
    if let Some((di, workers, grown)) = &dfr {
        let rays = primary + di.shadow_rays;
        println!(
            "frame      {:.2} ms on {threads} threads, {:.2} Mrays/s: {primary} camera + {} shadow rays = {rays} rays, {} hits",
            ms(di.times.total()),
            mrays(rays, di.times.total()),
            di.shadow_rays,
            di.hits
        );
        deferred_lines(
            di,
            workers,
            &setup.pgrid,
            &shadow_pass,
            frame.shading.shadows,
            *grown,
            ctx.limits(),
        );
    } else {
        println!(
            "trace      {:.2} ms on {threads} threads, {:.2} Mrays/s: {primary} primary + {} shadow and secondary = {} rays",
            ms(st.trace_ns),
            mrays(ctr.rays, st.trace_ns),
            ctr.rays.saturating_sub(primary),
            ctr.rays
        );
    }
    println!(
        "camera     --eye {} --look-at {} --up {} --fov {}  [{how}{}]",
        v3(frame.camera.eye),
        v3(frame.camera.look_at),
        v3(frame.camera.up),
        v.fov_y_deg,
        if custom { ", with your overrides" } else { "" }
    );
    println!(
        "light      --light {}{}",
        v3(light.position),
        if a.no_shadows { " (no shadows)" } else { "" }
    );
    println!("wrote      {} ({w}x{h})", a.out.display());
    Ok(())
}

/// The deferred passes of `sheaf render`: --primary / --shadows, else the
/// traced methods of --method / --shadow-method. Shadow packets take the
/// side of the primary pass's tracing tiles (`deferred::tile_side`).
fn passes(
    a: &RenderArgs,
    primary: &TraceParams,
    shadow: &TraceParams,
    pgrid: &sheaf::PgridParams,
) -> Result<(PrimaryPass, ShadowPass)> {
    let p = match a.primary {
        Some(PrimaryArg::Pgrid) => PrimaryPass::Pgrid,
        Some(PrimaryArg::Method(m)) => PrimaryPass::Traced(TraceParams {
            method: m.method(),
            ..*primary
        }),
        None => PrimaryPass::Traced(*primary),
    };
    if let PrimaryPass::Traced(t) = &p {
        t.validate().context("--primary")?;
    }
    let side = sheaf::render::deferred::tile_side(&p, pgrid.tile, pgrid.group);
    let s = match a.shadows {
        Some(ShadowsArg::LightGrid) => ShadowPass::LightGrid,
        Some(ShadowsArg::Method(m)) => ShadowPass::Traced(TraceParams {
            method: m.method(),
            ..*shadow
        }),
        None => ShadowPass::Traced(*shadow),
    };
    let s = match s {
        ShadowPass::Traced(t) if t.method.is_packet() => {
            let t = TraceParams { packet: side, ..t };
            t.validate().with_context(|| {
                format!(
                    "shadow packets of a deferred frame take the tracing tile's side ({side}x{side})"
                )
            })?;
            ShadowPass::Traced(t)
        }
        s => s,
    };
    Ok((p, s))
}

/// `sheaf render`'s report of a deferred frame: the phase table (paper
/// Figure 10), the grids, the reordering and the chunks' load balance.
fn deferred_lines(
    di: &DeferredInfo,
    workers: &run::Threads,
    pp: &sheaf::PgridParams,
    shadow: &ShadowPass,
    shadows: bool,
    grown: bool,
    limits: &Limits,
) {
    let total = di.times.total();
    println!();
    println!("| phase | ms | % of frame |");
    println!("|---|--:|--:|");
    for (name, ns) in phases(&di.times) {
        println!(
            "| {name} | {:.2} | {:.1} |",
            ms(ns),
            100.0 * ns as f64 / total.max(1) as f64
        );
    }
    println!("| **frame** | **{:.2}** | 100.0 |", ms(total));
    println!();
    let c = &di.camera;
    if c.cells() > 0 {
        println!(
            "pgrid      {}x{} tiles of {} px x {} slices = {} cells, {} pairs ({:.2} per mapped triangle), {} triangles mapped, tracing tiles {}x{} px",
            c.tiles[0],
            c.tiles[1],
            pp.tile,
            c.depth.count,
            c.cells(),
            c.refs,
            c.refs as f64 / c.mapped.max(1) as f64,
            c.mapped,
            pp.tile * pp.group,
            pp.tile * pp.group
        );
    }
    if shadows && *shadow == ShadowPass::LightGrid {
        let l = &di.light;
        let r = &di.reorder;
        println!(
            "light grid {}x{} tiles x {} slices = {} cells, {} pairs, {} triangles mapped",
            l.tiles[0],
            l.tiles[1],
            l.depth.count,
            l.cells(),
            l.refs,
            l.mapped
        );
        println!(
            "reorder    {} shadow rays in {} light tiles, {} chunks of at most {} rays, {} rays in the most crowded tile",
            r.rays, r.tiles_used, r.chunks, pp.chunk, r.max_tile_rays
        );
        if let Some((t, _)) = workers.shadow_pass() {
            println!(
                "chunks     {} work items on {} threads: mean {:.3} ms, 99th percentile {:.3} ms, slowest {:.3} ms = {:.2}x the mean; threads busy {:.0} % of the pass",
                t.count,
                t.threads,
                t.mean_ns() * 1e-6,
                ms(t.p99_ns),
                ms(t.max_ns),
                t.imbalance(),
                100.0 * t.efficiency()
            );
        }
    }
    if grown {
        println!(
            "pools      grown after a capacity error: max_pgrid_cells {}, max_pgrid_refs {}",
            limits.pgrid_cells(),
            limits.pgrid_refs()
        );
    }
}
