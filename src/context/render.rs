//! The context's renderers: whole frames and row bands in 2x2 or n x n
//! tiles (`render`), Whitted frames (`render::whitted`) and deferred frames
//! (`render::deferred`), each checked against the limits and its buffer
//! before it writes a pixel.
#![forbid(unsafe_code)]

use super::Context;
use crate::accel::pgrid::PgridParams;
use crate::accel::slot::Slot;
use crate::counters::{elapsed_ns, now};
use crate::error::{Error, Pool, Result};
use crate::geom::{Hit, Ray};
use crate::mem::Limits;
use crate::render::deferred::{
    self, DeferredInfo, DeferredJob, PrimaryPass, ShadowPass, TileLayout, Workers,
};
use crate::render::whitted::{self, WhittedJob};
use crate::render::{self, Band, Frame, PointLight, PrimaryRays, TileParams, Tracer};
use crate::trace::{Counters, Method, SceneTracer, TraceParams};

impl Context<'_> {
    /// Render a deferred frame (`render::deferred`): camera rays, then per
    /// light every shadow ray, then shading, each phase's work items run
    /// by `workers` (`OnCaller`: the calling thread, slot 0's mailbox;
    /// `OnPar`: the workers of a `Par`). The perspective grid and the light
    /// grids are built here, per frame, on `workers.par()` as joined builds,
    /// as are the light frustum, the map and the sort of the shadow rays;
    /// the frame is the same for any worker count. A `par()` of more than
    /// `MAX_WORKERS` workers is refused before anything is written. The
    /// phase times land in `stats().deferred`.
    pub fn render_deferred<W: Workers>(
        &mut self,
        job: &DeferredJob<'_>,
        pixels: &mut [u8],
        stride: usize,
        workers: &mut W,
    ) -> Result<DeferredInfo> {
        job.validate(&self.limits)?;
        // The joined phases take 1 to MAX_WORKERS workers.
        crate::mem::par::workers_of(workers.par())?;
        let rays = self.check_frame(job.frame, pixels.len(), stride)?;
        if !self.limits.has(Limits::PGRID) {
            return Err(Error::InvalidArgument(
                "deferred frames need Limits::PGRID (their per-pixel buffers)",
            ));
        }
        let grids = job.primary == PrimaryPass::Pgrid || job.shadow == ShadowPass::LightGrid;
        let pp = match self.pgrid.scene.params {
            Some(p) => p,
            None if grids => return Err(Error::NotBuilt),
            None => PgridParams::default(),
        };
        let side = deferred::tile_side(&job.primary, pp.tile, pp.group);
        if side > self.limits.max_tile {
            return Err(Error::InvalidArgument(
                "the tracing tile (pgrid tile * group, or the packet side) exceeds Limits::max_tile",
            ));
        }
        if matches!(job.shadow, ShadowPass::Traced(p) if p.tile_side() > 0) && side > 32 {
            return Err(Error::InvalidArgument(
                "traced shadow packets take the tracing tile's side, at most 32 (pgrid tile * group)",
            ));
        }
        let lay = TileLayout::new(side, job.frame.width, job.frame.height);
        let tr = super::structures!(self);
        let tr = match (&job.primary, &job.shadow) {
            (PrimaryPass::Traced(p), ShadowPass::Traced(s)) => {
                tr.check(s.method)?;
                tr.with_single(p.method)?
            }
            (PrimaryPass::Traced(p), _) => tr.with_single(p.method)?,
            (_, ShadowPass::Traced(s)) => tr.with_single(s.method)?,
            _ => tr,
        };
        // From here on the frame buffers are overwritten: the last frame's
        // pixels are gone, even if a grid build below fails.
        self.frame_layout = None;
        let parts = deferred::frame::Parts {
            pg: &mut self.pgrid,
            buf: &mut self.frame,
            slots: &mut self.slots,
        };
        let (info, ctr, eps) =
            deferred::frame::run(parts, &tr, job, &rays, &lay, &pp, pixels, stride, workers)?;
        self.stats.counters = ctr;
        self.stats.trace_ns = info.times.total();
        self.stats.deferred = info;
        self.frame_layout = Some(lay);
        self.frame_rays = Some((rays, eps));
        Ok(info)
    }

    /// Pixel (x, y) of the last deferred frame: the camera ray's nearest
    /// triangle and t (`INVALID_ID`, infinity: a miss) and the shadow bits
    /// (bit l: light l's shadow ray was occluded). None outside the frame
    /// or before the first successful `render_deferred`.
    pub fn deferred_pixel(&self, x: u32, y: u32) -> Option<(Hit, u8)> {
        let lay = self.frame_layout?;
        if x >= lay.width || y >= lay.height {
            return None;
        }
        let i = lay.index(x, y);
        let prim = self.frame.prim[i];
        let hit = Hit {
            t: if prim == crate::geom::INVALID_ID {
                f32::INFINITY
            } else {
                self.frame.t[i]
            },
            prim,
            u: 0.0,
            v: 0.0,
        };
        Some((hit, self.frame.shadow[i]))
    }

    /// The shadow ray towards `light` of pixel (x, y) of the last deferred
    /// frame (None: a miss, or no shadow ray), bit for bit the ray the
    /// frame traced, for checking its shadow bits against a reference.
    pub fn deferred_shadow_ray(&self, x: u32, y: u32, light: &PointLight) -> Option<Ray> {
        let (hit, _) = self.deferred_pixel(x, y)?;
        let (rays, eps) = self.frame_rays?;
        if !hit.is_hit() {
            return None;
        }
        let tri = match self.pgrid.triangles() {
            Some(t) => *t.tris.get(hit.prim as usize)?,
            None => self.scene_tracer().ok()?.triangle(hit.prim)?,
        };
        deferred::shadow_ray(&rays.ray(x, y), hit.t, &tri, light, eps)
    }

    /// Check a frame against the limits and the framebuffer size.
    pub fn check_frame(
        &self,
        frame: &Frame,
        pixels_len: usize,
        stride: usize,
    ) -> Result<PrimaryRays> {
        self.check_rows(frame, 0, frame.height, pixels_len, stride)
    }

    /// Check a frame against the limits, and a band of its rows
    /// `[y0, y1)` against the band's buffer (`Frame::check_rows`).
    pub fn check_rows(
        &self,
        frame: &Frame,
        y0: u32,
        y1: u32,
        pixels_len: usize,
        stride: usize,
    ) -> Result<PrimaryRays> {
        frame.check_rows(&self.limits, y0, y1, pixels_len, stride)
    }

    /// Render a whole frame on the calling thread with `method` for every
    /// ray (default packet settings).
    pub fn render(
        &mut self,
        method: Method,
        frame: &Frame,
        pixels: &mut [u8],
        stride: usize,
    ) -> Result<Counters> {
        let p = TraceParams {
            method,
            ..TraceParams::default()
        };
        self.render_with(&p, &p, frame, pixels, stride)
    }

    /// Render a whole frame on the calling thread: `primary` for camera
    /// rays, `shadow` for shadow rays.
    pub fn render_with(
        &mut self,
        primary: &TraceParams,
        shadow: &TraceParams,
        frame: &Frame,
        pixels: &mut [u8],
        stride: usize,
    ) -> Result<Counters> {
        // The whole frame as one band, on slot 0: `render_rows_in_slot`'s
        // checks and image, its counters and time recorded.
        let band = Band {
            y0: 0,
            y1: frame.height,
            pixels,
            stride,
        };
        self.timed(|c| {
            let ctr = c.render_rows_in_slot(0, primary, shadow, frame, band)?;
            crate::fault_point!(Render);
            Ok(ctr)
        })
    }

    /// Render rows `[band.y0, band.y1)` of `*frame` from any thread sharing
    /// `&self`, with thread slot `slot`'s mailbox (claimed for the call:
    /// `Error::SlotBusy` while another call holds it). `band.pixels` holds
    /// only those rows, row `y0` first, `band.stride` bytes apart. Threads
    /// rendering disjoint bands with distinct slots make the image
    /// `render_with` makes, byte for byte. Does not update `stats`.
    pub fn render_rows_in_slot(
        &self,
        slot: u32,
        primary: &TraceParams,
        shadow: &TraceParams,
        frame: &Frame,
        band: Band<'_>,
    ) -> Result<Counters> {
        self.limits.check_renderer(Limits::TILES)?;
        primary.validate_for(&self.limits)?;
        shadow.validate_for(&self.limits)?;
        frame.light.validate()?;
        let rays = self.check_rows(frame, band.y0, band.y1, band.pixels.len(), band.stride)?;
        let tr = self.scene_tracer()?;
        tr.check(shadow.method)?;
        let tr = tr.with_single(primary.method)?;
        let shot = Shot { frame, rays: &rays };
        self.with_slot(Some(slot), |slot| {
            let mut ctr = Counters::default();
            shot.render(&tr, primary, shadow, band, slot, &mut ctr);
            ctr
        })
    }

    /// Render a Whitted frame (shadows, reflections, refractions; BVH paper
    /// sections 2.4 and 6) on the calling thread: `job.primary`,
    /// `job.shadow` and `job.secondary` choose the method per ray class.
    /// Packet methods render n x n tiles, n the largest tile side of the
    /// three (`TraceParams::tile_side`), and camera packets take that side;
    /// single-ray methods alone render ray tree by ray tree. Hit triangles
    /// are looked up in the primary method's structure. The image does not
    /// depend on these choices.
    pub fn render_whitted(
        &mut self,
        job: &WhittedJob<'_>,
        pixels: &mut [u8],
        stride: usize,
    ) -> Result<Counters> {
        job.validate(&self.limits)?;
        let rays = self.check_frame(job.frame, pixels.len(), stride)?;
        let t = now();
        let mut ctr = Counters::default();
        {
            let (tr, mut mbs) = self.parts()?;
            tr.check(job.shadow.method)?;
            tr.check(job.secondary.method)?;
            let tr = tr.with_single(job.primary.method)?;
            let mut slot = mbs.next().ok_or(Error::Capacity {
                pool: Pool::Threads,
                needed: 1,
                available: 0,
            })?;
            let band = Band {
                y0: 0,
                y1: job.frame.height,
                pixels,
                stride,
            };
            match job
                .primary
                .tile_side()
                .max(job.shadow.tile_side())
                .max(job.secondary.tile_side())
            {
                0 => whitted::render_whitted_rows(&tr, job, &rays, band, &mut ctr),
                side => {
                    let job = WhittedJob {
                        primary: TraceParams {
                            packet: side,
                            ..job.primary
                        },
                        ..*job
                    };
                    whitted::render_whitted_tiles(&tr, &job, &rays, band, &mut slot, &mut ctr)
                }
            }
        }
        crate::fault_point!(Whitted);
        self.stats.trace_ns = elapsed_ns(t);
        self.stats.counters = ctr;
        Ok(ctr)
    }
}

/// A frame and its camera rays, rendered band by band.
struct Shot<'f> {
    frame: &'f Frame,
    rays: &'f PrimaryRays,
}

impl Shot<'_> {
    /// Packet methods render n x n tiles (n the larger tile side of the two
    /// classes), single-ray methods row by row.
    fn render(
        &self,
        tr: &SceneTracer<'_>,
        primary: &TraceParams,
        shadow: &TraceParams,
        band: Band<'_>,
        slot: &mut Slot<'_>,
        ctr: &mut Counters,
    ) {
        let (frame, rays) = (self.frame, self.rays);
        match primary.tile_side().max(shadow.tile_side()) {
            0 => render::render_rows(tr, frame, rays, band, ctr),
            side => {
                let params = TileParams {
                    primary: TraceParams {
                        packet: side,
                        ..*primary
                    },
                    shadow: *shadow,
                };
                render::render_tiles(tr, &params, frame, rays, band, slot, ctr);
            }
        }
    }
}
