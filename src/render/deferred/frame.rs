//! The deferred frame of the perspective/light grid paper, its Figure 10:
//! (1) the perspective grid, (2) camera rays, (3) shadow rays mapped and
//! sorted into light tiles, (4) the light grid over the tiles and slices
//! they reach, (5) chunks of shadow rays through the light grid, (6)
//! shading. The context checks the job and keeps the frame; this file runs
//! the phases in order over the context's pools.
#![forbid(unsafe_code)]

use super as deferred;
use super::{
    Crew, DeferredInfo, DeferredJob, FrameBuffers, Nearest, PrimaryPass, ShadowBits, ShadowPass,
    SortedRays, Surfaces, TileLayout, Workers,
};
use crate::accel::pgrid::reorder::{self, Pairs};
use crate::accel::pgrid::{self, CamView, LightView, Pgrid, PgridParams};
use crate::counters::{Counters, elapsed_ns, now};
use crate::error::{Error, Result};
use crate::geom::TriVerts;
use crate::mem::Slots;
use crate::mem::sort::SortScratch;
use crate::render::{PrimaryRays, Tracer};
use crate::trace::SceneTracer;

/// The context's pools a deferred frame writes.
pub(crate) struct Parts<'c, 'a> {
    pub pg: &'c mut Pgrid<'a>,
    pub buf: &'c mut FrameBuffers<'a>,
    pub slots: &'c mut Slots<'a>,
}

/// Run the six phases of `job` (checked by the caller) into `pixels`:
/// the frame's statistics, its counters and the shadow-ray offset used.
// `Context::render_deferred` (context/render.rs) calls it with these
// arguments: the context's pools, the checked job and its layout.
#[allow(clippy::too_many_arguments)]
pub(crate) fn run<W: Workers>(
    parts: Parts<'_, '_>,
    tr: &SceneTracer<'_>,
    job: &DeferredJob<'_>,
    rays: &PrimaryRays,
    lay: &TileLayout,
    pp: &PgridParams,
    pixels: &mut [u8],
    stride: usize,
    workers: &mut W,
) -> Result<(DeferredInfo, Counters, f32)> {
    let (lay, pp, rays, tr) = (*lay, *pp, *rays, *tr);
    let mut info = DeferredInfo::default();
    let mut ctr = Counters::default();
    // Phase 1: the perspective grid.
    if job.primary == PrimaryPass::Pgrid {
        let t = now();
        info.camera = pgrid::build::build_camera(parts.pg, &rays.pinhole(), workers.par())?;
        info.times.primary_build = elapsed_ns(t);
    }
    let Parts { pg, buf, slots } = parts;
    let mut crew = Crew { workers, slots };
    // Phase 2: camera rays.
    let t = now();
    let cam = pg.camera().map(|c| CamView {
        filter: tr.pgrid_filter,
        ..c
    });
    let hits = Nearest {
        prim: buf.prim,
        t: buf.t,
    };
    ctr.add(&deferred::primary_pass(
        &tr,
        cam.as_ref(),
        &job.primary,
        &rays,
        &lay,
        hits,
        &mut crew,
    ));
    info.times.primary_trace = elapsed_ns(t);
    let from_pgrid = job.primary == PrimaryPass::Pgrid;
    let scale = if from_pgrid {
        crate::trace::scene::scale_of(&pg.scene.bounds)
    } else {
        tr.scene_scale()
    };
    let eps = deferred::shadow_eps(scale);
    // Hits are looked up where the primary pass found them (anew for each
    // phase: the light grid builds in between borrow the grid's pools).
    macro_rules! surfaces {
        () => {
            Surfaces {
                tri_of: &{
                    let pg_tris = pg.triangles();
                    let pg_ok = &*pg.pools.ok;
                    move |id: u32| -> Option<TriVerts> {
                        if from_pgrid {
                            let t = pg_tris?;
                            (pg_ok.get(id as usize) == Some(&1)).then(|| t.tris[id as usize])
                        } else {
                            tr.triangle(id)
                        }
                    }
                },
                rays: &rays,
                lay: &lay,
                eps,
                prim: buf.prim,
                t: buf.t,
            }
        };
    }
    info.hits = buf.prim[..lay.len()]
        .iter()
        .filter(|&&p| p != crate::geom::INVALID_ID)
        .count() as u64;
    let lights = job.lights();
    buf.shadow[..lay.len()].fill(0);
    if job.frame.shading.shadows {
        for (l, light) in lights.iter().enumerate() {
            // Phase 3: shadow rays, mapped and sorted into light tiles.
            let t = now();
            let s = deferred::make_shadow_rays(&surfaces!(), light, buf.dirs, &mut crew);
            info.shadow_rays += s.count as u64;
            match job.shadow {
                ShadowPass::Traced(p) => {
                    info.times.rearrange += elapsed_ns(t);
                    let t = now();
                    let bits = ShadowBits {
                        shadow: buf.shadow,
                        bit: l as u8,
                    };
                    ctr.add(&deferred::traced_shadow_pass(
                        &tr, &p, light, &lay, buf.dirs, bits, &mut crew,
                    ));
                    info.times.shadow_trace += elapsed_ns(t);
                }
                ShadowPass::LightGrid => {
                    macro_rules! pairs {
                        () => {
                            Pairs {
                                tiles: buf.ray_tiles,
                                ids: buf.ray_ids,
                            }
                        };
                    }
                    let f = deferred::light_frame(
                        light,
                        &s,
                        deferred::light_tiles(pp.light_tiles, s.count),
                        &lay,
                        buf.dirs,
                        pairs!(),
                        crew.par(),
                    );
                    let depth =
                        pgrid::Slices::new(s.near, s.far, pp.light_slices, pgrid::LIGHT_DEPTH_PAD);
                    let mapped = deferred::map_to_tiles(
                        &f,
                        &depth,
                        &lay,
                        buf.dirs,
                        pairs!(),
                        buf.reach,
                        crew.par(),
                    );
                    info.times.rearrange += elapsed_ns(t);
                    // Phase 4: the light grid, over the tiles and
                    // slices the rays reach.
                    let t = now();
                    info.light = pgrid::build::build_light(
                        pg,
                        &f,
                        s.near,
                        s.far,
                        pp.light_slices,
                        buf.reach,
                        crew.par(),
                    )?;
                    info.times.shadow_build += elapsed_ns(t);
                    // Phase 3d: the pairs sorted by light tile and chunked.
                    let t = now();
                    let par = crew.par();
                    let scratch = SortScratch {
                        tmp_keys: pg.pools.tmp_keys,
                        tmp_vals: pg.pools.tmp_vals,
                        counts: pg.pools.counts,
                    };
                    let r = reorder::reorder(
                        pairs!(),
                        &mapped[..par.workers()],
                        scratch,
                        f.tiles[0] * f.tiles[1],
                        pp.chunk,
                        buf.chunks,
                        par,
                    );
                    // Saturating: up to 8 lights of 2^30 pixels each.
                    info.reorder.rays = info.reorder.rays.saturating_add(r.rays);
                    info.reorder.tiles_used += r.tiles_used;
                    info.reorder.chunks += r.chunks;
                    info.reorder.max_tile_rays = info.reorder.max_tile_rays.max(r.max_tile_rays);
                    info.times.rearrange += elapsed_ns(t);
                    // Phase 5: chunks.
                    let t = now();
                    let g = pg.light_view().ok_or(Error::NotBuilt)?;
                    let g = LightView {
                        filter: tr.pgrid_filter,
                        ..g
                    };
                    let sorted = SortedRays {
                        chunks: &buf.chunks[..r.chunks as usize],
                        ids: buf.ray_ids,
                        dirs: buf.dirs,
                    };
                    let bits = ShadowBits {
                        shadow: buf.shadow,
                        bit: l as u8,
                    };
                    ctr.add(&deferred::light_grid_pass(
                        &g, &sorted, buf.occ, bits, pp.chunk, &mut crew,
                    ));
                    info.times.shadow_trace += elapsed_ns(t);
                }
            }
        }
    }
    // Phase 6: shading.
    let t = now();
    deferred::shade(
        &surfaces!(),
        job.frame,
        lights,
        buf.shadow,
        pixels,
        stride,
        &mut crew,
    );
    info.times.shade = elapsed_ns(t);
    Ok((info, ctr, eps))
}
