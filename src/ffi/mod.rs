//! The C ABI: `include/sheaf.h` is generated from this module by cbindgen
//! (`cbindgen.toml`; `tests/header.rs` fails when the committed header is stale).
//!
//! One file per exported object, as in rustls-ffi:
//!
//! | file | C objects |
//! |---|---|
//! | `status.rs` | `sheaf_status` (numbered ranges, never renumbered), `sheaf_status_string` |
//! | `context.rs` | `sheaf_context` (opaque handle): required bytes, create / create_in / destroy, geometry, build, trace, occluded (method only or with trace params), render, the per-thread-slot calls (trace_slot, occluded_slot, render_rows), stats, last error |
//! | `limits.rs` | `sheaf_limits` (the crate's `Limits`), `sheaf_limits_default` |
//! | `grid.rs` | `sheaf_grid_params`, `sheaf_tri_test`, `sheaf_grid_params_default` |
//! | `bvh.rs` | `sheaf_bvh_params`, `sheaf_build_quality`, `sheaf_ray_kind`, `sheaf_bvh_params_default` |
//! | `kd.rs` | `sheaf_kd_params`, `sheaf_kd_params_default`, `sheaf_context_build_kd`, its joined forms |
//! | `method.rs` | `sheaf_method` |
//! | `trace_params.rs` | `sheaf_trace_params`, `sheaf_entry_search`, `sheaf_trace_params_default` |
//! | `ray.rs` | `sheaf_ray`, `sheaf_hit` (the C twins of `Ray`, `Hit`) |
//! | `pgrid.rs` | `sheaf_pgrid_params`, `sheaf_pgrid_params_default`, `sheaf_context_build_pgrid`, `sheaf_deferred_job`, `sheaf_context_render_deferred`, `sheaf_context_deferred_pixel`, `sheaf_context_deferred_shadow_ray` |
//! | `camera.rs` | `sheaf_pixel_rect`, `sheaf_context_trace_camera`, `sheaf_context_trace_scene_camera` (camera rays made in the kernel as packets, hits per pixel) |
//! | `filter.rs` | `sheaf_filter_fn`, `sheaf_candidate`, `sheaf_context_set_filter`, `sheaf_context_set_scene_geometry_filter` (any-hit filters) |
//! | `frame.rs` | `sheaf_frame` (camera, light, shading, size), `sheaf_shading_default`, `sheaf_frame_camera_ray` |
//! | `stats.rs` | `sheaf_stats` |
//! | `version.rs` | `sheaf_version_string` |
//! | `scene.rs` | `sheaf_mesh`, `sheaf_geometry_params`, `sheaf_update_mode`, `sheaf_scene_hit`, `sheaf_scene_info`: the two-level scene's geometries, instances, commit, trace and occluded, and its flattening for the grid, kd-tree and perspective grids (`sheaf_context_build_scene_*`, `sheaf_context_scene_prim`) |
//! | `stream.rs` | `sheaf_ray_stream`, `sheaf_hit_stream` (rays and hits as structures of arrays), `sheaf_context_trace_stream`, `sheaf_context_occluded_stream`, `sheaf_context_trace_scene_stream`, `sheaf_context_occluded_scene_stream` |
//! | `whitted.rs` | `sheaf_material`, `sheaf_material_range`, `sheaf_whitted_params`, `sheaf_context_render_whitted` |
//!
//! `sized.rs` exports nothing: it reads and writes the parameter structs
//! by their size (the versioning rule). The body every build call shares
//! (`build`, `build_joined`) lives in `context.rs`, beside the handle
//! boundary it wraps (`with_mut`, `joined`).
//!
//! # Conventions
//! - Every export is `#[unsafe(no_mangle)] pub extern "C" fn`, takes the
//!   handle first, then inputs, then outputs, and returns a `sheaf_status`
//!   (except the two functions returning static strings).
//! - Every pointer is checked: NULL gives `SHEAF_STATUS_NULL_POINTER` and is
//!   never dereferenced. An array pointer may be NULL only when its count is
//!   0. Single structs are read and written unaligned; arrays the core
//!   borrows as typed slices (indices, the context buffer) are checked and
//!   give `SHEAF_STATUS_MISALIGNED`.
//! - Sizes are multiplied with overflow checks.
//! - Outputs are written only when the call returns `SHEAF_STATUS_OK`
//!   (after a caught panic, output arrays may hold partial results).
//! - Every body runs inside `catch_unwind` (`guard`): no panic crosses the
//!   boundary; a caught panic returns `SHEAF_STATUS_PANIC`. Only the release
//!   profile unwinds (`Cargo.toml`), which is what C users link.
//! - Enum values coming from C are received as their raw integer ([`raw`])
//!   and checked, since a Rust enum holding an unknown value is undefined
//!   behaviour; the header still shows the enum types.
//! - No call allocates except `sheaf_context_create` (exactly once).
// Unsafe code is allowed only here, in mem/ and in isa/ (SIMD intrinsics);
// every block has a SAFETY comment.
#![allow(unsafe_code)]
// C names: sheaf_context, sheaf_status, ...
#![allow(non_camel_case_types)]
// Exports are safe `extern "C" fn`s taking raw pointers, as rustls-ffi's: their
// contract is the C header's (valid or NULL pointers), checked where possible.
#![allow(clippy::not_unsafe_ptr_arg_deref)]

pub mod bvh;
pub mod camera;
pub mod context;
pub mod filter;
pub mod frame;
pub mod grid;
pub mod kd;
pub mod limits;
pub mod method;
#[cfg(all(not(feature = "std"), feature = "panic-handler", not(test)))]
mod panic_handler;
pub mod pgrid;
pub mod ray;
pub mod scene;
pub(crate) mod sized;
pub mod stats;
pub mod status;
pub mod stream;
pub mod trace_params;
pub mod version;
pub mod whitted;

pub use bvh::{
    sheaf_build_quality, sheaf_bvh_params, sheaf_bvh_params_default, sheaf_ray_kind,
    sheaf_refit_info, sheaf_refit_params, sheaf_refit_params_default,
};
pub use camera::{sheaf_context_trace_camera, sheaf_context_trace_scene_camera};
#[cfg(feature = "std")]
pub use context::sheaf_context_create;
pub use context::{
    HEADER_BYTES, sheaf_context, sheaf_context_build_bvh, sheaf_context_build_grid,
    sheaf_context_clear_geometry, sheaf_context_create_in, sheaf_context_destroy,
    sheaf_context_last_error, sheaf_context_occluded, sheaf_context_occluded_slot,
    sheaf_context_occluded_with, sheaf_context_refit_bvh, sheaf_context_render,
    sheaf_context_render_rows, sheaf_context_set_geometry, sheaf_context_stats,
    sheaf_context_trace, sheaf_context_trace_slot, sheaf_context_trace_with, sheaf_required_bytes,
};
pub use filter::{
    sheaf_context_set_filter, sheaf_context_set_scene_geometry_filter, sheaf_filter_fn,
};
pub use frame::{sheaf_frame, sheaf_frame_camera_ray, sheaf_shading, sheaf_shading_default};
pub use grid::{sheaf_grid_params, sheaf_grid_params_default, sheaf_tri_test};
pub use kd::{
    sheaf_context_build_kd, sheaf_context_build_kd_joined, sheaf_context_build_scene_kd_joined,
    sheaf_kd_params, sheaf_kd_params_default,
};
pub use limits::{sheaf_limits, sheaf_limits_default};
pub use method::sheaf_method;
pub use pgrid::{
    sheaf_context_build_pgrid, sheaf_context_deferred_pixel, sheaf_context_deferred_shadow_ray,
    sheaf_context_render_deferred, sheaf_deferred_job, sheaf_pgrid_params,
    sheaf_pgrid_params_default,
};
pub use ray::{sheaf_hit, sheaf_ray};
pub use scene::{
    SHEAF_RAY_FLAG_CULL_BACK_FACING, SHEAF_RAY_FLAG_CULL_FRONT_FACING, SHEAF_RAY_FLAG_FORCE_OPAQUE,
    sheaf_context_build_scene_grid, sheaf_context_build_scene_kd, sheaf_context_build_scene_pgrid,
    sheaf_context_commit_scene, sheaf_context_occluded_scene, sheaf_context_remove_instance,
    sheaf_context_remove_scene_geometry, sheaf_context_scene_prim, sheaf_context_set_instance,
    sheaf_context_set_scene_geometry, sheaf_context_trace_scene,
    sheaf_context_update_scene_geometry, sheaf_geometry_params, sheaf_geometry_params_default,
    sheaf_mesh, sheaf_scene_hit, sheaf_scene_info, sheaf_update_mode,
};
pub use stats::sheaf_stats;
pub use status::{sheaf_status, sheaf_status_string};
pub use stream::{
    sheaf_context_occluded_scene_stream, sheaf_context_occluded_stream,
    sheaf_context_trace_scene_stream, sheaf_context_trace_stream, sheaf_hit_stream,
    sheaf_ray_stream,
};
pub use trace_params::{sheaf_entry_search, sheaf_trace_params, sheaf_trace_params_default};
pub use version::sheaf_version_string;
pub use whitted::{
    sheaf_context_render_whitted, sheaf_whitted_params, sheaf_whitted_params_default,
};

use crate::error::{Error, Result};
#[cfg(feature = "std")]
use core::panic::AssertUnwindSafe;

/// Alignment `sheaf_context_create_in` requires of its buffer
/// (C: `SHEAF_CONTEXT_ALIGN`).
pub const SHEAF_CONTEXT_ALIGN: usize = crate::CONTEXT_ALIGN;
/// Most lights of a deferred frame (C: `SHEAF_DEFERRED_MAX_LIGHTS`).
pub const SHEAF_DEFERRED_MAX_LIGHTS: usize = crate::render::deferred::MAX_LIGHTS;
/// `sheaf_hit.prim` of a miss (C: `SHEAF_INVALID_ID`).
pub const SHEAF_INVALID_ID: u32 = crate::geom::INVALID_ID;
/// A `sheaf_context_last_error` buffer of this many bytes always holds the
/// whole message (C: `SHEAF_ERROR_MESSAGE_MAX`).
pub const SHEAF_ERROR_MESSAGE_MAX: usize = 256;

/// Enum values as C passes them: plain integers, checked before use.
///
/// Each alias has the C name of its enum, so the header shows
/// `sheaf_method method` while Rust receives a `u32` (cbindgen skips these
/// aliases and resolves the name to the enum in `method.rs`, `grid.rs` or
/// `status.rs`).
pub mod raw {
    /// cbindgen:ignore
    pub type sheaf_status = u32;
    /// cbindgen:ignore
    pub type sheaf_method = u32;
    /// cbindgen:ignore
    pub type sheaf_tri_test = u32;
    /// cbindgen:ignore
    pub type sheaf_ray_kind = u32;
    /// cbindgen:ignore
    pub type sheaf_entry_search = u32;
    /// cbindgen:ignore
    pub type sheaf_isa = u32;
    /// cbindgen:ignore
    pub type sheaf_build_quality = u32;
    /// cbindgen:ignore
    pub type sheaf_update_mode = u32;
}

/// Return `Err(Error::NullPointer)` from the enclosing function when any
/// of the pointers is NULL.
macro_rules! check_non_null {
    ($($p:expr),+ $(,)?) => {
        $(
            if $p.is_null() {
                return Err($crate::error::Error::NullPointer);
            }
        )+
    };
}
pub(crate) use check_non_null;

/// Run `f`, turning a panic into `Err(Error::Panic)`. With std (and the
/// unwinding release profile C users link) the panic is caught here; the
/// no_std build has no unwinding (`panic = "abort"`, see Cargo.toml), so a
/// panic ends in the panic handler instead and never returns.
pub(crate) fn catch(f: impl FnOnce() -> Result<()>) -> Result<()> {
    #[cfg(feature = "std")]
    {
        std::panic::catch_unwind(AssertUnwindSafe(f)).unwrap_or(Err(Error::Panic))
    }
    #[cfg(not(feature = "std"))]
    {
        f()
    }
}

/// Run `f` behind the panic boundary and map its result to a status.
/// `on_error` sees every error (including a caught panic) before it is
/// mapped, to record it in a handle.
pub(crate) fn guard(f: impl FnOnce() -> Result<()>, on_error: impl FnOnce(Error)) -> sheaf_status {
    match catch(f) {
        Ok(()) => sheaf_status::Ok,
        Err(e) => {
            on_error(e);
            sheaf_status::from_error(&e)
        }
    }
}

/// [`guard`] for calls without a handle.
pub(crate) fn guard_free(f: impl FnOnce() -> Result<()>) -> sheaf_status {
    guard(f, |_| {})
}

/// Read a C struct (NULL checked, any alignment).
pub(crate) fn read_in<T: Copy>(p: *const T) -> Result<T> {
    check_non_null!(p);
    // SAFETY: non-NULL; the C contract is that a non-NULL argument points to
    // a readable, initialised `T`. read_unaligned puts no demand on alignment.
    Ok(unsafe { p.read_unaligned() })
}

/// Write one output value (any alignment). Call only after the pointer was
/// checked with `check_non_null!` and the call has succeeded.
pub(crate) fn write_out<T: Copy>(p: *mut T, v: T) {
    debug_assert!(!p.is_null());
    // SAFETY: the caller checked `p` for NULL; the C contract is that a
    // non-NULL output points to writable memory for one `T`.
    unsafe { p.write_unaligned(v) }
}

/// Write one output value the caller may decline with NULL (any
/// alignment); call only once the call has succeeded.
pub(crate) fn write_wanted<T: Copy>(p: *mut T, v: T) {
    if !p.is_null() {
        write_out(p, v);
    }
}

/// A boolean field of a C struct, received as its integer (a Rust `bool`
/// read from C memory holding 2 would be undefined behaviour): 0 is false,
/// 1 is true, anything else is `InvalidArgument` naming the field. The
/// header shows these fields as `uint8_t`, or `uint32_t` in the parameter
/// structs (no padding there); C's `true` and `false` convert to 1 and 0.
pub(crate) fn flag(b: impl Into<u32>, what: &'static str) -> Result<bool> {
    match b.into() {
        0 => Ok(false),
        1 => Ok(true),
        _ => Err(Error::InvalidArgument(what)),
    }
}

/// Byte length of `n` values of `T`, checked against `isize::MAX` (the
/// limit for any Rust slice).
pub(crate) fn array_bytes<T>(n: usize, what: &'static str) -> Result<usize> {
    n.checked_mul(core::mem::size_of::<T>())
        .filter(|&b| b <= isize::MAX as usize)
        .ok_or(Error::InvalidArgument(what))
}

/// Check an array argument: NULL only when `n == 0`, `n` values fit in
/// memory. Returns the byte length.
pub(crate) fn check_array<T>(p: *const T, n: usize, what: &'static str) -> Result<usize> {
    if n > 0 && p.is_null() {
        return Err(Error::NullPointer);
    }
    array_bytes::<T>(n, what)
}

/// Check the arrays of a call that traces `count` rays into `count`
/// results: each NULL only when `count` is 0 and within the address space,
/// and no byte of one in the other (`overlap` names that refusal).
pub(crate) fn check_rays_out<T>(
    rays: *const sheaf_ray,
    out: *const T,
    count: usize,
    overlap: &'static str,
) -> Result<()> {
    let rb = check_array(rays, count, "ray count too large")?;
    let ob = check_array(out, count, "ray count too large")?;
    if overlaps(rays.cast(), rb, out.cast(), ob) {
        return Err(Error::InvalidArgument(overlap));
    }
    Ok(())
}

/// Whether the byte ranges `[a, a + alen)` and `[b, b + blen)` overlap.
pub(crate) fn overlaps(a: *const u8, alen: usize, b: *const u8, blen: usize) -> bool {
    let (a, b) = (a as usize, b as usize);
    alen > 0 && blen > 0 && a < b.saturating_add(blen) && b < a.saturating_add(alen)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn guard_turns_a_panic_into_the_panic_status() {
        let mut seen = None;
        let s = guard(|| panic!("boom"), |e| seen = Some(e));
        assert_eq!(s, sheaf_status::Panic);
        assert_eq!(seen, Some(Error::Panic));
    }

    #[test]
    fn guard_maps_errors_and_success() {
        assert_eq!(guard_free(|| Ok(())), sheaf_status::Ok);
        assert_eq!(guard_free(|| Err(Error::NotBuilt)), sheaf_status::NotBuilt);
    }

    #[test]
    fn overlap_rules() {
        let p = 1000 as *const u8;
        let q = 1010 as *const u8;
        assert!(overlaps(p, 11, q, 1));
        assert!(!overlaps(p, 10, q, 1));
        assert!(!overlaps(p, 0, p, 10));
    }

    #[test]
    fn array_sizes_are_overflow_checked() {
        assert!(array_bytes::<u64>(usize::MAX / 4, "x").is_err());
        assert_eq!(array_bytes::<u64>(3, "x"), Ok(24));
    }
}
