//! Whitted frames from C: `sheaf_material`, `sheaf_material_range`,
//! `sheaf_whitted_params` (the crate's `Material`, `MaterialRange`,
//! `WhittedParams`) and `sheaf_context_render_whitted`.

use super::context::{Handle, sheaf_context, with_mut};
use super::frame::sheaf_frame;
use super::sized::{self, versioned};
use super::trace_params::sheaf_trace_params;
use super::{check_array, overlaps, read_in};
use crate::PointLight;
use crate::error::{Error, Result};
use crate::{Material, MaterialRange, Materials};
use crate::{WhittedJob, WhittedParams};

/// Bounce limits of a Whitted frame (the crate's `WhittedParams`). Start
/// from `sheaf_whitted_params_default`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct sheaf_whitted_params {
    /// `sizeof` the caller's struct, set by `sheaf_whitted_params_default`
    /// (docs/c-api.md, "Upgrading").
    pub size: u32,
    /// Most mirror reflections on a path (default 2).
    pub max_reflect: u32,
    /// Most refractions on a path (default 2).
    pub max_refract: u32,
}

impl sheaf_whitted_params {
    pub fn of(p: &WhittedParams) -> Self {
        sheaf_whitted_params {
            size: core::mem::size_of::<sheaf_whitted_params>() as u32,
            max_reflect: p.max_reflect,
            max_refract: p.max_refract,
        }
    }
    pub fn to_core(&self) -> Result<WhittedParams> {
        let p = WhittedParams {
            max_reflect: self.max_reflect,
            max_refract: self.max_refract,
        };
        p.validate()?;
        Ok(p)
    }
}

versioned!(
    sheaf_whitted_params => WhittedParams,
    [max_reflect, max_refract],
    sheaf_whitted_params::of(&WhittedParams::default())
);

/// Write the default bounce limits (2 reflections, 2 refractions) to
/// `*out`, a struct of `size` bytes (sheaf.h's macro passes `sizeof *out`;
/// see `sheaf_limits_default`).
///
/// `out` must not be NULL. Errors: `SHEAF_STATUS_INVALID_ARGUMENT` when
/// `size` is no size of this struct. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_whitted_params_default(
    out: *mut sheaf_whitted_params,
    size: usize,
) -> super::sheaf_status {
    sized::write_defaults(out, size)
}

/// Borrow a C array as a slice: NULL only when `n == 0`, naturally aligned.
fn borrow<'a, T>(p: *const T, n: usize, what: &'static str) -> Result<&'a [T]> {
    check_array(p, n, what)?;
    if n == 0 {
        return Ok(&[]);
    }
    if !(p as usize).is_multiple_of(core::mem::align_of::<T>()) {
        return Err(Error::Misaligned {
            required: core::mem::align_of::<T>() as u32,
        });
    }
    // SAFETY: non-NULL (n > 0, checked), aligned (checked), and the C
    // contract is that `p` points to `n` initialised values that stay
    // unchanged for the call; `n * size_of::<T>() <= isize::MAX` (checked).
    Ok(unsafe { core::slice::from_raw_parts(p, n) })
}

/// Render a Whitted frame into the caller's RGBA8 framebuffer (same
/// framebuffer rules as `sheaf_context_render`): point-light shadows from
/// every light of `lights` (`light_count` of them; 0: `frame->light`),
/// mirror reflections and refractions from the materials, up to
/// `params->max_reflect` reflections and `params->max_refract` refractions
/// per path (NULL: `sheaf_whitted_params_default`). BVH paper sections 2.4
/// and 6: secondary packets are the surviving lanes of their parent packet.
///
/// Materials: triangles `ranges[i].first` up to the next range's `first`
/// use `materials[ranges[i].material]`; triangles before the first range
/// (or all, when `range_count` is 0) are diffuse with
/// `frame->shading.albedo`. Ranges sorted by `first`.
///
/// `primary`, `shadow` and `secondary` (copied) choose the method of camera,
/// shadow, and reflection/refraction rays; their structures must be built.
/// Packet methods render n x n tiles, n the largest tile side of the three
/// (camera packets take that side). The image does not depend on these
/// choices.
///
/// Stack: packets and bounce levels live in thread slot 0's scratch (sized
/// at creation for 32x32 tiles and 8 bounces); the call uses at most 16 KiB
/// of the caller's stack.
///
/// Updates `sheaf_stats` (counters, trace time). All arrays are only read
/// and must be naturally aligned.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (methods, bounce limits above 8 in total, materials, ranges, lights,
/// camera, sizes, a framebuffer overlapping an input array), `SHEAF_STATUS_MISALIGNED`, `SHEAF_STATUS_CAPACITY_IMAGE`,
/// `SHEAF_STATUS_NOT_BUILT`.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_render_whitted(
    ctx: *mut sheaf_context,
    primary: *const sheaf_trace_params,
    shadow: *const sheaf_trace_params,
    secondary: *const sheaf_trace_params,
    params: *const sheaf_whitted_params,
    frame: *const sheaf_frame,
    lights: *const PointLight,
    light_count: usize,
    materials: *const Material,
    material_count: usize,
    ranges: *const MaterialRange,
    range_count: usize,
    rgba: *mut u8,
    stride_bytes: usize,
    rgba_len: usize,
) -> super::sheaf_status {
    with_mut(ctx, |h: &mut Handle| {
        let frame = read_in(frame)?.to_core()?;
        let params = sized::or_default(params)?;
        let job = WhittedJob {
            frame: &frame,
            lights: borrow(lights, light_count, "light count too large")?,
            materials: Materials {
                materials: borrow(materials, material_count, "material count too large")?,
                ranges: borrow(ranges, range_count, "range count too large")?,
            },
            params,
            primary: sized::to_core(primary)?,
            shadow: sized::to_core(shadow)?,
            secondary: sized::to_core(secondary)?,
        };
        // The framebuffer is written while the arrays are read: they must
        // not share a byte (checked before the framebuffer is borrowed).
        let fb_len = super::context::band_bytes(frame.height.max(1), frame.width, stride_bytes)?
            .min(rgba_len);
        let arrays = [
            (lights.cast::<u8>(), core::mem::size_of_val(job.lights)),
            (
                materials.cast::<u8>(),
                core::mem::size_of_val(job.materials.materials),
            ),
            (
                ranges.cast::<u8>(),
                core::mem::size_of_val(job.materials.ranges),
            ),
        ];
        if arrays
            .iter()
            .any(|&(p, n)| overlaps(p, n, rgba.cast_const(), fb_len))
        {
            return Err(Error::InvalidArgument(
                "the framebuffer overlaps the lights, materials or ranges",
            ));
        }
        let pixels = super::context::framebuffer(h, &frame, rgba, stride_bytes, rgba_len)?;
        h.ctx.render_whitted(&job, pixels, stride_bytes)?;
        Ok(())
    })
}
