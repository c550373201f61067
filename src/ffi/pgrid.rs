//! Perspective grids for camera rays and spherical light grids for shadow
//! rays, from C: `sheaf_pgrid_params`, `sheaf_pgrid_params_default`,
//! `sheaf_context_build_pgrid`, and deferred frames (the perspective/light
//! grid paper's frame: camera rays into a hit buffer, then per light every
//! shadow ray at once, then shading): `sheaf_deferred_job`,
//! `sheaf_context_render_deferred`, `sheaf_context_deferred_pixel`,
//! `sheaf_context_deferred_shadow_ray`.

use super::context::{Handle, build, sheaf_context, with_mut, with_ref};
use super::frame::sheaf_frame;
use super::grid::sheaf_tri_test;
use super::sized::{self, versioned};
use super::trace_params::{sheaf_isa, sheaf_trace_params};
use super::{
    check_array, check_non_null, flag, raw, read_in, sheaf_hit, sheaf_ray, sheaf_status, write_out,
};
use crate::Hit;
use crate::PgridParams;
use crate::PointLight;
use crate::error::{Error, Result};
use crate::render::deferred::{
    DeferredJob, MAX_LIGHTS, OnCaller, OnPar, PrimaryPass, ShadowPass, Workers,
};

/// Tunables of the perspective grid (camera rays, section 3 of the
/// perspective/light grid paper) and of the spherical light grids (shadow
/// rays, section 4), the crate's `PgridParams`. Start from
/// `sheaf_pgrid_params_default`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_pgrid_params {
    /// `sizeof` the caller's struct, set by `sheaf_pgrid_params_default`
    /// (docs/c-api.md, "Upgrading").
    pub size: u32,
    /// Side of a sorting tile in pixels: 2, 4, 8, 16 or 32 (default 8).
    pub tile: u32,
    /// Sorting tiles per side of a tracing tile (indirect mapping): 1, 2
    /// or 4, with `tile * group` at most 64 and at most
    /// `sheaf_limits.max_tile` (default 2).
    pub group: u32,
    /// Depth slices of the camera frustum, 1..=1024 (default 32).
    pub slices: u32,
    /// Most light tiles per side of a light grid, 1..=256 (default 64;
    /// small frames get fewer).
    pub light_tiles: u32,
    /// Depth slices of a light grid, 1..=1024 (default 32).
    pub light_slices: u32,
    /// Most shadow rays per chunk, r (section 4.3, load balancing),
    /// 16..=4096 (default 256).
    pub chunk: u32,
    /// Ray-triangle test of both grids (a `sheaf_tri_test`; the projection
    /// test needs `sheaf_limits.projection_test`).
    pub test: raw::sheaf_tri_test,
    /// Leave out triangles facing away from the eye (default false). Changes
    /// results on open models: every other structure is two-sided. 0 or 1.
    pub cull_backfaces: u32,
    /// Lane width of both grids' triangle tests (a `sheaf_isa`, as
    /// `sheaf_trace_params.isa`): `AUTO` (0, default) or a forced level,
    /// `SHEAF_STATUS_INVALID_ARGUMENT` when the CPU lacks it.
    pub isa: raw::sheaf_isa,
}

impl sheaf_pgrid_params {
    pub fn of(p: &PgridParams) -> sheaf_pgrid_params {
        sheaf_pgrid_params {
            size: core::mem::size_of::<sheaf_pgrid_params>() as u32,
            tile: p.tile,
            group: p.group,
            slices: p.slices,
            light_tiles: p.light_tiles,
            light_slices: p.light_slices,
            chunk: p.chunk,
            test: sheaf_tri_test::of(p.test) as u32,
            cull_backfaces: p.cull_backfaces.into(),
            isa: sheaf_isa::of(p.isa) as u32,
        }
    }
    /// The checked crate value.
    pub fn to_core(&self) -> Result<PgridParams> {
        let p = PgridParams {
            tile: self.tile,
            group: self.group,
            slices: self.slices,
            light_tiles: self.light_tiles,
            light_slices: self.light_slices,
            chunk: self.chunk,
            cull_backfaces: flag(
                self.cull_backfaces,
                "sheaf_pgrid_params.cull_backfaces must be 0 or 1",
            )?,
            test: sheaf_tri_test::to_core(self.test)?,
            isa: sheaf_isa::to_core(self.isa)?,
        };
        p.validate()?;
        Ok(p)
    }
}

versioned!(
    sheaf_pgrid_params => PgridParams,
    [
        tile,
        group,
        slices,
        light_tiles,
        light_slices,
        chunk,
        test,
        cull_backfaces,
        isa
    ],
    sheaf_pgrid_params::of(&PgridParams::default())
);

/// Write the default perspective/light grid parameters (8-pixel sorting
/// tiles traced in 2 x 2 groups, 32 depth slices, up to 64 x 64 light tiles
/// of 32 slices, chunks of 256 shadow rays, no back-face culling,
/// Moller-Trumbore) to `*out`.
///
/// `*out` is a struct of `size` bytes (sheaf.h's macro passes `sizeof
/// *out`; see `sheaf_limits_default`).
///
/// `out` must not be NULL. Errors: `SHEAF_STATUS_INVALID_ARGUMENT` when
/// `size` is no size of this struct. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_pgrid_params_default(
    out: *mut sheaf_pgrid_params,
    size: usize,
) -> sheaf_status {
    sized::write_defaults(out, size)
}

/// Load the geometry for perspective and light grids with `*params`
/// (copied; NULL: the defaults of `sheaf_pgrid_params_default`). The grids
/// themselves depend on the camera and the lights: every
/// `sheaf_context_render_deferred` that uses them builds them for its
/// frame, so call this once per change of the geometry (or the
/// parameters). The grid, BVH and kd-tree, if built, are untouched.
///
/// Reads the geometry buffers (see `sheaf_context_set_geometry`) and keeps
/// a copy of the triangles; never allocates. On error the previous load
/// stays valid.
///
/// Errors: `SHEAF_STATUS_NO_GEOMETRY`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (params, or no pools: `SHEAF_STRUCTURE_PGRID` missing from
/// `sheaf_limits.structures`), `SHEAF_STATUS_INDEX_OUT_OF_RANGE`,
/// `SHEAF_STATUS_CAPACITY_TRIANGLES`.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_build_pgrid(
    ctx: *mut sheaf_context,
    params: *const sheaf_pgrid_params,
) -> sheaf_status {
    build(ctx, params, |c, scene, p| c.build_pgrid(scene, p))
}

/// A deferred frame (the crate's `DeferredJob`).
///
/// Camera rays go through the perspective grid (`primary_pgrid`) or are
/// traced with `primary`; shadow rays go through one spherical light grid
/// per light, sorted into light tiles and chunks (`shadow_light_grid`), or
/// are traced with `shadow` in packets from the light. With the grids, the
/// triangles are those of the last `sheaf_context_build_pgrid`; the other
/// methods need their structure built. The image does not depend on these
/// choices (with the same triangle test), and with one light it equals
/// `sheaf_context_render`'s.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct sheaf_deferred_job {
    /// Camera, shading and image size (`frame.light` is the light when
    /// `light_count` is 0).
    pub frame: sheaf_frame,
    /// `light_count` lights (point or spot lights), each with its own
    /// shadow rays (light `l` sets shadow bit `l`); NULL only when
    /// `light_count` is 0. Any alignment.
    pub lights: *const PointLight,
    /// At most `SHEAF_DEFERRED_MAX_LIGHTS` (8); 0: `frame.light` alone.
    pub light_count: usize,
    /// Camera rays through the perspective grid (built per frame); false:
    /// traced with `primary`. 0 or 1.
    pub primary_pgrid: u8,
    /// Shadow rays through light grids (built per frame and light); false:
    /// traced with `shadow`. 0 or 1.
    pub shadow_light_grid: u8,
    /// Method of camera rays when `primary_pgrid` is false (ignored, not
    /// checked, otherwise; NULL: `sheaf_trace_params_default`). Packet
    /// methods trace tiles of `primary->packet` pixels; single-ray methods
    /// tiles of 8. Read during the call only.
    pub primary: *const sheaf_trace_params,
    /// Method of shadow rays when `shadow_light_grid` is false (ignored,
    /// not checked, otherwise; NULL: the defaults).
    pub shadow: *const sheaf_trace_params,
}

/// Render a deferred frame into the caller's RGBA8 framebuffer (same
/// framebuffer rules as `sheaf_context_render`: row `y` at `rgba + y *
/// stride_bytes`, `rgba_len >= (height - 1) * stride_bytes + 4 * width`,
/// written only on success, bytes between rows untouched), on the calling
/// thread:
///
/// 1. the perspective grid is built for the frame's camera
///    (`job->primary_pgrid`);
/// 2. every camera ray is traced into a per-pixel hit buffer;
/// 3. per light, the shadow rays of all hit points are made, mapped to
///    light tiles, sorted and split into chunks (`job->shadow_light_grid`);
/// 4. per light, the light grid is built over those rays' (azimuth,
///    elevation) rectangle;
/// 5. per light, the shadow rays are traced, chunk by chunk;
/// 6. every pixel is shaded (Lambert, each light, spot cones).
///
/// `*job` and its lights are copied (any alignment). The
/// frame's per-pixel results stay in the context until the next
/// `sheaf_context_render_deferred` (`sheaf_context_deferred_pixel`).
/// Updates `sheaf_stats`: the phase times (paper Figure 10) and grid sizes,
/// the counters, and `trace_ns` (the sum of the phases).
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (more than 8 lights, a light, a method, the camera, sizes, stride, a
/// tracing tile above `sheaf_limits.max_tile`, or no pools:
/// `SHEAF_STRUCTURE_PGRID` missing from `sheaf_limits.structures`),
/// `SHEAF_STATUS_CAPACITY_IMAGE`, `SHEAF_STATUS_CAPACITY_PGRID_CELLS`,
/// `SHEAF_STATUS_CAPACITY_PGRID_REFS`,
/// `SHEAF_STATUS_NOT_BUILT` (a grid pass before `sheaf_context_build_pgrid`,
/// or a traced pass whose structure is not built). After an error the
/// framebuffer and `sheaf_stats` are unchanged; the previous frame's
/// per-pixel results may be gone (`sheaf_context_deferred_pixel` then
/// returns `SHEAF_STATUS_NOT_BUILT`).
///
/// Not thread-safe: needs exclusive access to `ctx` (no other call on the
/// same context may run at the same time; it writes the per-pixel buffers
/// and the stats).
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_render_deferred(
    ctx: *mut sheaf_context,
    job: *const sheaf_deferred_job,
    rgba: *mut u8,
    stride_bytes: usize,
    rgba_len: usize,
) -> sheaf_status {
    with_mut(ctx, |h: &mut Handle| {
        render_deferred(h, job, rgba, stride_bytes, rgba_len, &mut OnCaller)
    })
}

/// `sheaf_context_render_deferred` on `thread_count` caller threads that
/// each make this call with their own `thread_index` (0 to
/// `thread_count - 1`; at most 16), as in `sheaf_context_build_bvh_joined`:
/// thread 0 leads and returns the frame's status, the others help and
/// return the same status. Every phase runs on the joined threads: the
/// perspective and light grid builds, the light frustum, the map, the sort
/// and the chunking of the shadow rays split their data among the threads;
/// the camera rays, the shadow rays and the shading take work items from
/// one queue, each thread with its own thread slot (threads beyond
/// `sheaf_limits.max_threads` join the other phases only). The frame is the same as `sheaf_context_render_deferred`'s,
/// byte for byte, for any thread count.
///
/// Errors: as `sheaf_context_render_deferred`;
/// `SHEAF_STATUS_INVALID_ARGUMENT` for `thread_count` 0 or above 16 or
/// `thread_index >= thread_count`. Every thread must make the call; the
/// helpers' arguments other than `ctx`, `thread_index` and `thread_count`
/// are not read.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_render_deferred_joined(
    ctx: *mut sheaf_context,
    job: *const sheaf_deferred_job,
    rgba: *mut u8,
    stride_bytes: usize,
    rgba_len: usize,
    thread_index: u32,
    thread_count: u32,
) -> sheaf_status {
    super::context::joined(ctx, thread_index, thread_count, |h, par| {
        render_deferred(h, job, rgba, stride_bytes, rgba_len, &mut OnPar(par))
    })
}

/// The deferred frame of `*job` on `workers`: the body of the two calls.
fn render_deferred(
    h: &mut Handle,
    job: *const sheaf_deferred_job,
    rgba: *mut u8,
    stride_bytes: usize,
    rgba_len: usize,
    workers: &mut impl Workers,
) -> Result<()> {
    let j = read_in(job)?;
    if j.light_count > MAX_LIGHTS {
        return Err(Error::InvalidArgument(
            "a deferred frame takes at most 8 lights",
        ));
    }
    // Copied: any alignment, and no aliasing with the framebuffer.
    check_array(j.lights, j.light_count, "light count too large")?;
    let mut lights = [PointLight::default(); MAX_LIGHTS];
    for (i, l) in lights.iter_mut().enumerate().take(j.light_count) {
        // SAFETY: i < light_count <= MAX_LIGHTS; `lights` is non-NULL
        // when light_count > 0 (checked), and the C contract is that it
        // points to light_count readable values. Unaligned reads.
        *l = unsafe { j.lights.add(i).read_unaligned() };
    }
    let frame = j.frame.to_core()?;
    let job = DeferredJob {
        frame: &frame,
        lights: &lights[..j.light_count],
        primary: if flag(
            j.primary_pgrid,
            "sheaf_deferred_job.primary_pgrid must be 0 or 1",
        )? {
            PrimaryPass::Pgrid
        } else {
            PrimaryPass::Traced(sized::or_default(j.primary)?)
        },
        shadow: if flag(
            j.shadow_light_grid,
            "sheaf_deferred_job.shadow_light_grid must be 0 or 1",
        )? {
            ShadowPass::LightGrid
        } else {
            ShadowPass::Traced(sized::or_default(j.shadow)?)
        },
    };
    // `render_deferred` validates the job (once, before anything else).
    let pixels = super::context::pixels(h, &frame, rgba, stride_bytes, rgba_len)?;
    h.ctx.render_deferred(&job, pixels, stride_bytes, workers)?;
    Ok(())
}

/// Check that a deferred frame exists and contains pixel (x, y): its hit
/// and shadow bits.
fn deferred_pixel(h: &Handle, x: u32, y: u32) -> Result<(Hit, u8)> {
    // Every frame has pixel (0, 0): None there means no frame.
    h.ctx.deferred_pixel(0, 0).ok_or(Error::NotBuilt)?;
    h.ctx.deferred_pixel(x, y).ok_or(Error::InvalidArgument(
        "pixel outside the last deferred frame",
    ))
}

/// Pixel (x, y) of the last successful `sheaf_context_render_deferred`
/// (x to the right, y downwards): `*hit` the camera ray's nearest hit
/// (`prim`, and `t` along the camera ray of `sheaf_frame_camera_ray`; a
/// miss has `prim == SHEAF_INVALID_ID`, `t = INFINITY`; `u` and `v` are 0,
/// the frame does not keep them), and `*shadow_bits` bit `l` set when
/// light `l`'s shadow ray was occluded (0 for a miss, surfaces facing away
/// from a light or outside its spot cone, and frames with shadows off).
///
/// Thread-safe like `sheaf_context_trace` (shared access; not during a
/// call needing exclusive access).
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (pixel outside the frame), `SHEAF_STATUS_NOT_BUILT` (no deferred frame
/// yet, or the last one failed).
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_deferred_pixel(
    ctx: *const sheaf_context,
    x: u32,
    y: u32,
    hit: *mut sheaf_hit,
    shadow_bits: *mut u8,
) -> sheaf_status {
    with_ref(ctx, |h| {
        check_non_null!(hit, shadow_bits);
        let (hh, bits) = deferred_pixel(h, x, y)?;
        write_out(hit, hh.into());
        write_out(shadow_bits, bits);
        Ok(())
    })
}

/// The shadow ray towards `*light` of pixel (x, y) of the last successful
/// `sheaf_context_render_deferred`, bit for bit the ray that frame traced
/// for a light equal to `*light` (from the light's position, `tmax = 1`):
/// `*ray` and `*has_ray = true`, or `*has_ray = false` (`*ray` untouched)
/// when the pixel has no shadow ray (a miss, a surface facing away, outside
/// a spot cone). In a frame with shadows on, tracing it with
/// `sheaf_context_occluded` reproduces the pixel's shadow bit for that
/// light (with the same triangles and triangle test).
///
/// Thread-safe like `sheaf_context_deferred_pixel`.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (pixel outside the frame, a bad light), `SHEAF_STATUS_NOT_BUILT`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_deferred_shadow_ray(
    ctx: *const sheaf_context,
    x: u32,
    y: u32,
    light: *const PointLight,
    ray: *mut sheaf_ray,
    has_ray: *mut bool,
) -> sheaf_status {
    with_ref(ctx, |h| {
        let light = read_in(light)?;
        check_non_null!(ray, has_ray);
        light.validate()?;
        deferred_pixel(h, x, y)?;
        match h.ctx.deferred_shadow_ray(x, y, &light) {
            Some(r) => {
                write_out(ray, sheaf_ray::from(r));
                write_out(has_ray, true);
            }
            None => write_out(has_ray, false),
        }
        Ok(())
    })
}

// Ten u32: 40 bytes on every ABI (tests/c_abi.rs compares every header
// struct's size and alignment with C's).
const _: () = assert!(core::mem::size_of::<sheaf_pgrid_params>() == 40);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TriTest;

    #[test]
    fn params_round_trip() {
        let p = PgridParams {
            tile: 4,
            group: 4,
            slices: 7,
            light_tiles: 3,
            light_slices: 9,
            chunk: 64,
            cull_backfaces: true,
            test: TriTest::Watertight,
            isa: crate::isa::Isa::Sse2,
        };
        assert_eq!(sheaf_pgrid_params::of(&p).to_core(), Ok(p));
        assert_eq!(
            sheaf_pgrid_params::of(&PgridParams::default()).to_core(),
            Ok(PgridParams::default())
        );
        let c = sheaf_pgrid_params::of(&p);
        assert!(sheaf_pgrid_params { test: 9, ..c }.to_core().is_err());
        assert!(sheaf_pgrid_params { tile: 6, ..c }.to_core().is_err());
        assert!(sheaf_pgrid_params { chunk: 8, ..c }.to_core().is_err());
        assert!(
            sheaf_pgrid_params {
                light_tiles: 0,
                ..c
            }
            .to_core()
            .is_err()
        );
    }
}
