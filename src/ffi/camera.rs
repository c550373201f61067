//! `PixelRect` and the camera calls: the camera rays of a pixel
//! rectangle made in the kernel as packets (`render::CameraRays`) and
//! traced, hits written per pixel, for the context's single mesh and for
//! its two-level scene. No ray array and no conversion: a caller's threads
//! each trace their tiles or row bands of one image into one hit buffer.

use super::context::{Handle, sheaf_context, with_ref};
use super::ray::sheaf_hit;
use super::scene::{controls, sheaf_scene_hit};
use super::sized;
use super::trace_params::sheaf_trace_params;
use super::{check_array, read_in};
use crate::error::Result;
use crate::render::{Camera, CameraRays, PixelRect, PrimaryRays};

/// The checked inputs of a camera call: the camera's rays and the
/// rectangle, after checking `hits` spans the rectangle's pixels
/// `hits_per_row` apart (NULL, overflow).
fn camera_of<T>(
    camera: *const Camera,
    width: u32,
    height: u32,
    rect: *const PixelRect,
    hits: *const T,
    hits_per_row: usize,
) -> Result<(PrimaryRays, PixelRect)> {
    let cam = read_in(camera)?;
    let r = read_in(rect)?;
    r.check(width, height)?;
    check_array(hits, r.results(hits_per_row)?, "hit buffer too large")?;
    Ok((PrimaryRays::new(&cam, width, height)?, r))
}

/// Nearest hits of the camera rays through the pixels of `*rect` of a
/// `width` x `height` image seen by `*camera`, made by the kernel as
/// packets of `params->packet`^2 pixels (2x2 quads in Morton order, tiles
/// row by row over the rectangle) and traced with `params->method`:
/// pixel (x, y)'s hit into `hits[(y - rect->y0) * hits_per_row + (x -
/// rect->x0)]`; other elements are left alone. Each ray is bit for bit
/// `sheaf_frame_camera_ray`'s for that pixel and each hit
/// `sheaf_context_trace_with`'s for that ray. Takes a free thread slot as
/// `sheaf_context_trace_with` does and is thread-safe like it: threads may
/// trace disjoint rectangles (tiles, row bands) of one image into one
/// `hits` buffer at once.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (bad params; a camera with a NaN or infinite field, `eye == look_at`,
/// `up` zero or within 1e-6 radians of the view or a field of view outside (0, 180):
/// vectors of any finite length are normalised first; a
/// rectangle empty or outside the image; `hits_per_row` below the
/// rectangle's width or a buffer past the address space),
/// `SHEAF_STATUS_NOT_BUILT`, `SHEAF_STATUS_CAPACITY_THREADS`. `hits` is
/// written only on success.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_trace_camera(
    ctx: *const sheaf_context,
    params: *const sheaf_trace_params,
    camera: *const Camera,
    width: u32,
    height: u32,
    rect: *const PixelRect,
    hits: *mut sheaf_hit,
    hits_per_row: usize,
) -> super::sheaf_status {
    with_ref(ctx, |h: &Handle| {
        let p = sized::to_core(params)?;
        let (pr, r) = camera_of(camera, width, height, rect, hits.cast_const(), hits_per_row)?;
        let rays = CameraRays::new(&pr, r, Some(&p))?;
        let mut at = rays.index(hits_per_row);
        let out = |i: usize, h4: &crate::geom::Hit4, _: usize| {
            for (k, hit) in at.quad(i).into_iter().zip(h4.hits()) {
                if let Some(k) = k {
                    // SAFETY: k is a pixel of the rectangle, `(y - y0) *
                    // hits_per_row + (x - x0)` with x, y inside it, so below
                    // `r.results(hits_per_row)`, which `check_array` checked `hits` spans (C
                    // contract: writable for the call; unaligned writes
                    // allowed).
                    unsafe { hits.add(k).write_unaligned(hit.into()) }
                }
            }
        };
        h.ctx
            .trace_quads(None, &p, rays.count(), rays, out, false)?;
        Ok(())
    })
}

/// `sheaf_context_trace_camera` in the committed two-level scene: `params`
/// (NULL: single rays), `mask` and `flags` as in
/// `sheaf_context_trace_scene`, and its hits for those rays, bit for bit,
/// into `hits` laid out as in `sheaf_context_trace_camera`. Thread-safe
/// as `sheaf_context_trace_scene`. Errors: those of
/// `sheaf_context_trace_scene` and the camera checks of
/// `sheaf_context_trace_camera`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_trace_scene_camera(
    ctx: *const sheaf_context,
    params: *const sheaf_trace_params,
    camera: *const Camera,
    width: u32,
    height: u32,
    rect: *const PixelRect,
    hits: *mut sheaf_scene_hit,
    hits_per_row: usize,
    mask: u32,
    flags: u32,
) -> super::sheaf_status {
    with_ref(ctx, |h: &Handle| {
        let ctl = controls(mask, flags)?;
        let p = sized::optional(params)?; // NULL: single rays
        let (pr, r) = camera_of(camera, width, height, rect, hits.cast_const(), hits_per_row)?;
        let rays = CameraRays::new(&pr, r, p.as_ref())?;
        let mut at = rays.index(hits_per_row);
        let out = |i: usize, hit: crate::SceneHit| {
            if let Some(k) = at.of(i) {
                // SAFETY: as in `sheaf_context_trace_camera`.
                unsafe { hits.add(k).write_unaligned(hit.into()) }
            }
        };
        // `trace_scene_each` checks the scene (pools, commit) before any write.
        h.ctx
            .trace_scene_each(p.as_ref(), None, rays.count(), ctl, false, rays, out)?;
        Ok(())
    })
}
