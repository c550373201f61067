//! `sheaf_status`: what every C call returns, and its text.

use crate::error::{Error, Pool};
use core::ffi::{CStr, c_char};

/// Result of a sheaf call.
///
/// Codes are grouped in numbered ranges and are never renumbered; new codes
/// are only ever added:
/// - 0: success;
/// - 100-199: an argument is wrong (the call changed nothing);
/// - 200-299: a fixed pool (chosen by `sheaf_limits`) is too small for the
///   input; `sheaf_context_last_error` names the pool, what was needed and
///   what is available. The context keeps its previous state;
/// - 300-399: the call came in the wrong state (no geometry, nothing built);
/// - 900-999: internal error (a bug in sheaf, please report it).
///
/// `sheaf_status_string` gives a fixed text per code; the context's last
/// error (`sheaf_context_last_error`) gives the details of its last failure.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sheaf_status {
    /// Success: outputs have been written.
    Ok = 0,
    /// A required pointer argument is NULL.
    NullPointer = 100,
    /// An argument is outside its documented domain (an unknown enum value,
    /// a zero size, a stride, overlapping arrays, a camera...).
    InvalidArgument = 101,
    /// A triangle references a vertex index `>= vertex_count`.
    IndexOutOfRange = 102,
    /// A buffer is not aligned as required (`sheaf_context_create_in`:
    /// `SHEAF_CONTEXT_ALIGN` bytes; index buffers: 4 bytes).
    Misaligned = 103,
    /// The buffer given to `sheaf_context_create_in` is smaller than
    /// `sheaf_required_bytes`.
    BufferTooSmall = 104,
    /// More triangles than `sheaf_limits.max_triangles`.
    CapacityTriangles = 200,
    /// More vertices than `sheaf_limits.max_vertices`.
    CapacityVertices = 201,
    /// The grid resolution needs more cells than `sheaf_limits.max_grid_cells`
    /// (lower `lambda`, or set `sheaf_grid_params.fit`).
    CapacityGridCells = 202,
    /// The grid needs more triangle references than `sheaf_limits.max_grid_refs`.
    CapacityGridRefs = 203,
    /// The image is larger than `sheaf_limits.max_image_width/height`.
    CapacityImage = 204,
    /// More threads than `sheaf_limits.max_threads`.
    CapacityThreads = 205,
    /// A perspective or light grid needs more cells than
    /// `sheaf_limits.max_pgrid_cells` (fewer tiles or depth slices).
    CapacityPgridCells = 206,
    /// A perspective or light grid needs more (triangle, cell) pairs than
    /// `sheaf_limits.max_pgrid_refs`.
    CapacityPgridRefs = 207,
    /// A packet side larger than `sheaf_limits.max_packet_side`.
    CapacityPacketSide = 208,
    /// More Whitted bounces than `sheaf_limits.max_bounces`.
    CapacityBounces = 209,
    /// `sheaf_context_create` could not allocate its memory.
    OutOfMemory = 299,
    /// `sheaf_context_build_grid` before any successful `sheaf_context_set_geometry`.
    NoGeometry = 300,
    /// A trace, occluded or render call before the first successful build.
    NotBuilt = 301,
    /// The thread slot passed to a `_slot` / `_rows` call is in use by
    /// another call right now (give each concurrent thread its own slot).
    SlotBusy = 302,
    /// Another call on the context is running and this call cannot run
    /// beside it (an exclusive call while any other call is inside, or any
    /// call while an exclusive one runs; see `sheaf_context`). Nothing was
    /// changed and the last error is not touched: retry after the other
    /// call returns. Seeing it means the threads are not coordinated.
    ContextBusy = 303,
    /// An earlier call on this context caught a panic (returned
    /// `SHEAF_STATUS_PANIC`), so its structures may be half-built: every
    /// call but `sheaf_context_last_error` and `sheaf_context_destroy`
    /// returns this until the context is destroyed.
    Poisoned = 304,
    /// A filter function (`sheaf_filter_fn`) called into sheaf: every call
    /// on a context made from inside a filter is refused and changes
    /// nothing (the last error is not touched).
    Reentrant = 305,
    /// A panic was caught at the C boundary (a bug in sheaf: please report).
    Panic = 900,
}

impl sheaf_status {
    /// Every code, in numeric order.
    pub const ALL: &'static [sheaf_status] = &[
        sheaf_status::Ok,
        sheaf_status::NullPointer,
        sheaf_status::InvalidArgument,
        sheaf_status::IndexOutOfRange,
        sheaf_status::Misaligned,
        sheaf_status::BufferTooSmall,
        sheaf_status::CapacityTriangles,
        sheaf_status::CapacityVertices,
        sheaf_status::CapacityGridCells,
        sheaf_status::CapacityGridRefs,
        sheaf_status::CapacityImage,
        sheaf_status::CapacityThreads,
        sheaf_status::CapacityPgridCells,
        sheaf_status::CapacityPgridRefs,
        sheaf_status::CapacityPacketSide,
        sheaf_status::CapacityBounces,
        sheaf_status::OutOfMemory,
        sheaf_status::NoGeometry,
        sheaf_status::NotBuilt,
        sheaf_status::SlotBusy,
        sheaf_status::ContextBusy,
        sheaf_status::Poisoned,
        sheaf_status::Reentrant,
        sheaf_status::Panic,
    ];

    /// The one mapping from the crate's error to a C status.
    pub const fn from_error(e: &Error) -> sheaf_status {
        match *e {
            Error::NullPointer => sheaf_status::NullPointer,
            Error::InvalidArgument(_) => sheaf_status::InvalidArgument,
            Error::IndexOutOfRange { .. } => sheaf_status::IndexOutOfRange,
            Error::Capacity { pool, .. } => match pool {
                Pool::Triangles => sheaf_status::CapacityTriangles,
                Pool::Vertices => sheaf_status::CapacityVertices,
                Pool::GridCells => sheaf_status::CapacityGridCells,
                Pool::GridRefs => sheaf_status::CapacityGridRefs,
                Pool::Image => sheaf_status::CapacityImage,
                Pool::Threads => sheaf_status::CapacityThreads,
                Pool::PgridCells => sheaf_status::CapacityPgridCells,
                Pool::PgridRefs => sheaf_status::CapacityPgridRefs,
                Pool::PacketSide => sheaf_status::CapacityPacketSide,
                Pool::Bounces => sheaf_status::CapacityBounces,
            },
            Error::BufferTooSmall { .. } => sheaf_status::BufferTooSmall,
            Error::Misaligned { .. } => sheaf_status::Misaligned,
            Error::NoGeometry => sheaf_status::NoGeometry,
            Error::NotBuilt => sheaf_status::NotBuilt,
            Error::SlotBusy { .. } => sheaf_status::SlotBusy,
            Error::ContextBusy => sheaf_status::ContextBusy,
            Error::Poisoned => sheaf_status::Poisoned,
            Error::Reentrant => sheaf_status::Reentrant,
            Error::Panic => sheaf_status::Panic,
        }
    }

    /// The status with code `raw`, if any.
    pub fn from_raw(raw: u32) -> Option<sheaf_status> {
        sheaf_status::ALL.iter().copied().find(|s| *s as u32 == raw)
    }

    /// Fixed text of the status (what `sheaf_status_string` returns).
    pub const fn text(self) -> &'static CStr {
        match self {
            sheaf_status::Ok => c"ok",
            sheaf_status::NullPointer => c"a required pointer argument is NULL",
            sheaf_status::InvalidArgument => c"invalid argument",
            sheaf_status::IndexOutOfRange => c"a vertex index is out of range",
            sheaf_status::Misaligned => c"buffer is not aligned as required",
            sheaf_status::BufferTooSmall => c"buffer is smaller than sheaf_required_bytes",
            sheaf_status::CapacityTriangles => {
                c"capacity exceeded: triangles (sheaf_limits.max_triangles)"
            }
            sheaf_status::CapacityVertices => {
                c"capacity exceeded: vertices (sheaf_limits.max_vertices)"
            }
            sheaf_status::CapacityGridCells => {
                c"capacity exceeded: grid cells (sheaf_limits.max_grid_cells)"
            }
            sheaf_status::CapacityGridRefs => {
                c"capacity exceeded: grid references (sheaf_limits.max_grid_refs)"
            }
            sheaf_status::CapacityImage => {
                c"capacity exceeded: image size (sheaf_limits.max_image_width/height)"
            }
            sheaf_status::CapacityThreads => {
                c"capacity exceeded: threads (sheaf_limits.max_threads)"
            }
            sheaf_status::CapacityPgridCells => {
                c"capacity exceeded: perspective/light grid cells (sheaf_limits.max_pgrid_cells)"
            }
            sheaf_status::CapacityPgridRefs => {
                c"capacity exceeded: perspective/light grid pairs (sheaf_limits.max_pgrid_refs)"
            }
            sheaf_status::CapacityPacketSide => {
                c"capacity exceeded: packet side (sheaf_limits.max_packet_side)"
            }
            sheaf_status::CapacityBounces => {
                c"capacity exceeded: Whitted bounces (sheaf_limits.max_bounces)"
            }
            sheaf_status::OutOfMemory => c"out of memory",
            sheaf_status::NoGeometry => c"no geometry set",
            sheaf_status::NotBuilt => c"no acceleration structure built yet",
            sheaf_status::SlotBusy => c"thread slot in use by another call",
            sheaf_status::ContextBusy => c"context busy: another call on it is running",
            sheaf_status::Poisoned => c"context poisoned by an earlier panic: destroy it",
            sheaf_status::Reentrant => c"called from inside a filter function: refused",
            sheaf_status::Panic => c"internal error (panic caught at the C boundary)",
        }
    }
}

impl From<Error> for sheaf_status {
    fn from(e: Error) -> Self {
        sheaf_status::from_error(&e)
    }
}

const UNKNOWN: &CStr = c"unknown sheaf_status code";

/// Fixed, NUL-terminated English text for `status`.
///
/// Never returns NULL: unknown codes give "unknown sheaf_status code". The
/// string is static (never free it). Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_status_string(status: super::raw::sheaf_status) -> *const c_char {
    // Cannot panic (a search in a constant table): no unwind guard needed.
    sheaf_status::from_raw(status)
        .map_or(UNKNOWN, sheaf_status::text)
        .as_ptr()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_stay_in_their_ranges() {
        for s in sheaf_status::ALL {
            let c = *s as u32;
            let range = match s {
                sheaf_status::Ok => 0..1,
                sheaf_status::NullPointer
                | sheaf_status::InvalidArgument
                | sheaf_status::IndexOutOfRange
                | sheaf_status::Misaligned
                | sheaf_status::BufferTooSmall => 100..200,
                sheaf_status::CapacityTriangles
                | sheaf_status::CapacityVertices
                | sheaf_status::CapacityGridCells
                | sheaf_status::CapacityGridRefs
                | sheaf_status::CapacityImage
                | sheaf_status::CapacityThreads
                | sheaf_status::CapacityPgridCells
                | sheaf_status::CapacityPgridRefs
                | sheaf_status::CapacityPacketSide
                | sheaf_status::CapacityBounces
                | sheaf_status::OutOfMemory => 200..300,
                sheaf_status::NoGeometry
                | sheaf_status::NotBuilt
                | sheaf_status::SlotBusy
                | sheaf_status::ContextBusy
                | sheaf_status::Poisoned
                | sheaf_status::Reentrant => 300..400,
                sheaf_status::Panic => 900..1000,
            };
            assert!(range.contains(&c), "{s:?} = {c}");
        }
        assert!(
            sheaf_status::ALL
                .windows(2)
                .all(|w| (w[0] as u32) < (w[1] as u32))
        );
    }

    #[test]
    fn every_string_is_distinct_and_unknown_codes_get_one() {
        let texts: Vec<&CStr> = sheaf_status::ALL.iter().map(|s| s.text()).collect();
        for (i, a) in texts.iter().enumerate() {
            assert!(!a.is_empty());
            assert!(texts[i + 1..].iter().all(|b| a != b));
        }
        assert!(!sheaf_status_string(12345).is_null());
        assert!(!sheaf_status_string(u32::MAX).is_null());
    }
}
