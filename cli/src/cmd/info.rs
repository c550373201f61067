//! `sheaf info`: a scene's size, bounds and the memory a context for it needs.

use super::{grid_line, kd_line, mib, v3};
use crate::InfoArgs;
use crate::load;
use crate::run::{self, ms};
use anyhow::Result;
use sheaf::{Limits, required_bytes};
use std::fmt::Write as _;

/// `sheaf info`: sizes, bounds and memory.
pub fn info(a: &InfoArgs) -> Result<()> {
    let loaded = load::load(&a.scene)?;
    let scene = loaded.scene()?;
    let n = scene.triangle_count();
    println!("scene      {}", loaded.label);
    let mut tri = format!("{n}");
    if loaded.skipped > 0 {
        let _ = write!(
            tri,
            " ({} triangles of the file's faces skipped by the OBJ loader)",
            loaded.skipped
        );
    }
    println!("triangles  {tri}");
    println!("vertices   {}", loaded.vertex_count());
    match loaded.bounds() {
        Some((lo, hi)) => println!(
            "bounds     min ({}) max ({}) extent ({})",
            v3(lo.to_array()),
            v3(hi.to_array()),
            v3((hi - lo).to_array())
        ),
        None => println!("bounds     none (no finite vertex in a triangle)"),
    }
    let mut limits = Limits::for_triangles(n);
    limits.max_vertices = scene.vertex_count();
    let bytes = required_bytes(&limits)?;
    let per_tri = if n > 0 {
        format!(", {:.1} bytes/triangle", bytes as f64 / n as f64)
    } else {
        String::new()
    };
    println!(
        "memory     {bytes} bytes ({:.2} MiB{per_tri}) for Limits::for_triangles({n}) (grid pools: {} cells, {} refs)",
        mib(bytes),
        limits.grid_cells(),
        limits.grid_refs()
    );
    if n > 0 {
        let (mut ctx, info) = run::context_for(&scene, limits, &a.grid.params(), 1.0)?;
        let mut tight = *ctx.limits();
        tight.max_grid_cells = info.cells().max(1) as u32;
        tight.max_grid_refs = info.refs.max(1);
        let tight_bytes = required_bytes(&tight)?;
        println!("grid       {}", grid_line(&info, &a.grid));
        println!(
            "excluded   {} non-finite, {} zero-area",
            info.excluded_non_finite, info.excluded_zero_area
        );
        println!("build      {:.2} ms", ms(ctx.stats().build_ns));
        println!(
            "tight      {tight_bytes} bytes ({:.2} MiB, {:.1} bytes/triangle) with the grid pools cut to this grid's cells and refs",
            mib(tight_bytes),
            tight_bytes as f64 / n as f64
        );
        let b = ctx.build_bvh(
            &scene,
            &sheaf::BvhParams {
                test: info.test,
                ..Default::default()
            },
        )?;
        let bvh_only = Limits {
            structures: Limits::BVH,
            ..limits
        };
        println!(
            "bvh        {} nodes, {} leaves, depth {}, SAH cost {:.1} (leaves of up to 4, 16 bins), build {:.2} ms = {:.2} M triangles/s",
            b.nodes,
            b.leaves,
            b.depth,
            b.sah_cost,
            ms(ctx.stats().bvh_build_ns),
            b.triangles as f64 / (ctx.stats().bvh_build_ns.max(1) as f64 * 1e-3)
        );
        println!(
            "bvh only   {} bytes ({:.2} MiB, {:.1} bytes/triangle) with Limits::structures = BVH",
            required_bytes(&bvh_only)?,
            mib(required_bytes(&bvh_only)?),
            required_bytes(&bvh_only)? as f64 / n as f64
        );
        let k = ctx.build_kd(
            &scene,
            &sheaf::accel::kd::KdParams {
                test: info.test,
                ..Default::default()
            },
        )?;
        println!("kd-tree    {}", kd_line(&k, ctx.stats().kd_build_ns));
        let kd_only = Limits {
            structures: Limits::KD,
            ..*ctx.limits()
        };
        let kd_bytes = required_bytes(&kd_only)?;
        println!(
            "kd only    {kd_bytes} bytes ({:.2} MiB, {:.1} bytes/triangle) with Limits::structures = KD (pools: {} nodes, {} refs, {} build events; this tree uses {} nodes, {} refs, {} events)",
            mib(kd_bytes),
            kd_bytes as f64 / n as f64,
            kd_only.kd_nodes(),
            kd_only.kd_refs(),
            kd_only.kd_events(),
            k.nodes,
            k.refs,
            k.events_peak
        );
        if k.forced_leaves > 0 {
            let (grown, g) = run::kd_limits(
                &scene,
                kd_only,
                &sheaf::accel::kd::KdParams {
                    test: info.test,
                    ..Default::default()
                },
            )?;
            let b = required_bytes(&grown)?;
            println!(
                "kd grown   {b} bytes ({:.2} MiB, {:.1} bytes/triangle) with max_kd_nodes {} and max_kd_refs {}: {}",
                mib(b),
                b as f64 / n as f64,
                grown.kd_nodes(),
                grown.kd_refs(),
                kd_line(&g, 0).split(", build").next().unwrap_or_default()
            );
        }
    }
    // Perspective/light grid pools: they scale with the image.
    let (w, h) = a.size;
    let pg = Limits {
        structures: Limits::PGRID,
        max_image_width: w,
        max_image_height: h,
        ..limits
    };
    let pg_bytes = required_bytes(&pg)?;
    println!(
        "pgrid only {pg_bytes} bytes ({:.2} MiB, {:.1} bytes/pixel) with Limits::structures = PGRID at {w}x{h} (pools: {} cells and {} pairs per grid, {} frame pixels with {}-pixel tile padding)",
        mib(pg_bytes),
        pg_bytes as f64 / (w as f64 * h as f64),
        pg.pgrid_cells(),
        pg.pgrid_refs(),
        pg.frame_pixels(),
        pg.max_tile
    );
    Ok(())
}
