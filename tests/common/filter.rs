//! The filter of the filter suites: a cut-out that is a pure function of
//! the candidate (holes in a pattern of the barycentric coordinates,
//! shifted by the triangle, instance and geometry ids, so a hit checked
//! with wrong ids disagrees), counting its calls when given a counter.

use sheaf::{Candidate, Filter};
use std::ffi::c_void;
use std::sync::atomic::{AtomicU64, Ordering};

/// Whether the cut-out keeps a candidate: about two thirds of each
/// triangle's area.
pub fn keep(c: &Candidate) -> bool {
    let cell = ((c.u * 4.0) as u32 + (c.v * 4.0) as u32)
        .wrapping_add(c.prim)
        .wrapping_add(c.instance)
        .wrapping_add(2 * c.geometry);
    !cell.is_multiple_of(3)
}

/// `keep` as a filter; `user` is NULL or an `AtomicU64` counting calls.
pub extern "C" fn cutout(user: *mut c_void, c: &Candidate) -> bool {
    if !user.is_null() {
        // SAFETY: the suites pass NULL or a pointer to an AtomicU64 that
        // outlives every trace using the filter.
        unsafe { &*(user as *const AtomicU64) }.fetch_add(1, Ordering::Relaxed);
    }
    keep(c)
}

/// The cut-out counting into `calls`.
pub fn counted(calls: &AtomicU64) -> Filter {
    Filter::new(cutout, calls as *const AtomicU64 as *mut c_void)
}

/// The cut-out without a counter.
pub fn plain() -> Filter {
    Filter::new(cutout, std::ptr::null_mut())
}
