//! `sheaf_filter_fn` and `sheaf_candidate` (the crate's `geom::filter`):
//! any-hit filters on the single mesh (`sheaf_context_set_filter`) and on
//! the two-level scene's geometries (`sheaf_geometry_params.filter`,
//! `sheaf_context_set_scene_geometry_filter`).

use super::context::{sheaf_context, with_mut};
use crate::error::{Error, Result};
use crate::geom::{Candidate, Filter};
use core::ffi::c_void;

/// An any-hit filter: called with the caller's `user` pointer and a
/// candidate hit before a trace accepts it; returns true to accept it,
/// false to reject it (the ray goes on as if the triangle were not there).
/// The return type is C's `bool`, whose only values are 0 and 1 (C and C++
/// convert any other value on return): a function of another type cast to
/// this one that returns another byte is undefined behaviour, in sheaf as
/// in C, and is not checked (unlike the `uint8_t` flags of the parameter
/// structs, which are refused unless 0 or 1).
/// Nearest-hit traces keep the nearest accepted candidate; occlusion
/// stops at the first accepted one.
///
/// When: only for candidates a trace would take (nearer than its best so
/// far, or any hit for occlusion), so most hits behind the nearest are
/// never asked about; possibly more than once for one candidate (a
/// triangle in several cells or leaves, a lane traced again by a
/// fallback), lanes of a packet in any order, on the threads of the call
/// (concurrently when several threads trace).
///
/// What it must be: a pure function of its arguments (then every method
/// returns its single ray's hits bit for bit, with the same filter), and
/// thread-safe; it must return (no longjmp, no C++ exception through
/// sheaf) and make no sheaf call: a call on a context from inside a filter
/// returns `SHEAF_STATUS_REENTRANT` and changes nothing.
pub type sheaf_filter_fn = Option<extern "C" fn(user: *mut c_void, candidate: &Candidate) -> bool>;

/// A C filter and its pointer as the crate's (`None`: no filter).
/// `InvalidArgument` for a pointer without a function.
pub(super) fn filter_of(f: sheaf_filter_fn, user: *mut c_void) -> Result<Option<Filter>> {
    match f {
        Some(f) => Ok(Some(Filter::new(f, user))),
        None if user.is_null() => Ok(None),
        None => Err(Error::InvalidArgument(
            "a filter's user pointer without a filter function",
        )),
    }
}

/// Candidate hits on the single mesh (`sheaf_context_set_geometry`) go to
/// `filter` with `user` from now on (NULL: every candidate is accepted), in
/// every structure built from the mesh and every method, with geometry 0
/// and instance `SHEAF_INVALID_ID`; calls with
/// `sheaf_trace_params.force_opaque` skip it. Takes effect at once (no
/// rebuild). See `sheaf_filter_fn` for when it is called.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER` (`ctx`),
/// `SHEAF_STATUS_INVALID_ARGUMENT` (a NULL `filter` with a non-NULL
/// `user`), `SHEAF_STATUS_REENTRANT`. On error nothing changes.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_set_filter(
    ctx: *mut sheaf_context,
    filter: sheaf_filter_fn,
    user: *mut c_void,
) -> super::sheaf_status {
    with_mut(ctx, |h| {
        h.ctx.set_filter(filter_of(filter, user)?);
        Ok(())
    })
}

/// Candidate hits on geometry `id` of the two-level scene go to `filter`
/// with `user` from now on (NULL: every candidate is accepted), in every
/// instance of it, through every method, and in the grid, kd-tree and
/// perspective grids built over the scene (the candidate then carries the
/// geometry's own triangle id and the instance's); a geometry set
/// `opaque` (`sheaf_geometry_params.opaque`) and calls with
/// `SHEAF_RAY_FLAG_FORCE_OPAQUE` or `sheaf_trace_params.force_opaque`
/// skip it. Takes effect at once (no commit). The same as
/// `sheaf_geometry_params.filter` at `sheaf_context_set_scene_geometry`.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER` (`ctx`),
/// `SHEAF_STATUS_INVALID_ARGUMENT` (no two-level scene, geometry `id` not
/// set, a NULL `filter` with a non-NULL `user`), `SHEAF_STATUS_REENTRANT`.
/// On error nothing changes.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_set_scene_geometry_filter(
    ctx: *mut sheaf_context,
    id: u32,
    filter: sheaf_filter_fn,
    user: *mut c_void,
) -> super::sheaf_status {
    with_mut(ctx, |h| {
        h.ctx.set_geometry_filter(id, filter_of(filter, user)?)
    })
}
