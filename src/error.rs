//! The one error type: small, `Copy`, with data, no `String` (the core never allocates).

use core::fmt;

/// A fixed-memory pool, named in capacity errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pool {
    /// Triangles accepted by `Limits::max_triangles`.
    Triangles,
    /// Vertices accepted by `Limits::max_vertices`.
    Vertices,
    /// Grid cells (`Limits::max_grid_cells`): the resolution chosen from lambda x triangles.
    GridCells,
    /// Triangle references stored in grid cells (`Limits::max_grid_refs`).
    GridRefs,
    /// Image width x height (`Limits::max_image_width/height`).
    Image,
    /// Per-thread slots (`Limits::max_threads`).
    Threads,
    /// Cells of a perspective or light grid (`Limits::max_pgrid_cells`):
    /// tiles x depth slices.
    PgridCells,
    /// (triangle, cell) pairs of a perspective or light grid
    /// (`Limits::max_pgrid_refs`).
    PgridRefs,
    /// The side of a packet a call asks for (`Limits::max_packet_side`).
    PacketSide,
    /// Bounces of a Whitted frame (`Limits::max_bounces`).
    Bounces,
}

impl Pool {
    /// Stable lower-case name used in messages.
    pub const fn name(self) -> &'static str {
        match self {
            Pool::Triangles => "triangles",
            Pool::Vertices => "vertices",
            Pool::GridCells => "grid_cells",
            Pool::GridRefs => "grid_refs",
            Pool::Image => "image",
            Pool::Threads => "threads",
            Pool::PgridCells => "pgrid_cells",
            Pool::PgridRefs => "pgrid_refs",
            Pool::PacketSide => "packet_side",
            Pool::Bounces => "bounces",
        }
    }
}

/// Everything that can go wrong in sheaf. Every failing call leaves the
/// context as it was before the call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error {
    /// A required pointer was NULL (C ABI only).
    NullPointer,
    /// An argument is out of its documented domain; the text names it.
    InvalidArgument(&'static str),
    /// Triangle `triangle` references vertex `index`, but only `vertex_count` exist.
    IndexOutOfRange {
        triangle: u32,
        index: u32,
        vertex_count: u32,
    },
    /// A fixed pool is too small for this input.
    Capacity {
        pool: Pool,
        needed: u64,
        available: u64,
    },
    /// The memory handed to `create` is smaller than `required_bytes`.
    BufferTooSmall { needed: u64, available: u64 },
    /// The memory handed to `create` is not aligned to `required` bytes.
    Misaligned { required: u32 },
    /// `build` was called before any geometry was set (C ABI only).
    NoGeometry,
    /// A trace or render call came before the first successful `build`.
    NotBuilt,
    /// Thread slot `slot` is in use by another call (each thread that
    /// traces or renders concurrently on one context needs its own slot).
    SlotBusy { slot: u32 },
    /// Another call is inside the context in a way this call may not join
    /// (C ABI: an exclusive call while others run, or any call during an
    /// exclusive one). Nothing was changed; retry when the other call is done.
    ContextBusy,
    /// A panic was caught inside an earlier call on this context (C ABI):
    /// its structures may be half-built, so every call but last_error and
    /// destroy is refused until destroy.
    Poisoned,
    /// A filter (`geom::filter`) called into sheaf: refused, nothing
    /// changed (C ABI, with `std`).
    Reentrant,
    /// A panic was caught at the C boundary (a bug in sheaf: please report).
    Panic,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Error::NullPointer => write!(f, "a required pointer is NULL"),
            Error::InvalidArgument(what) => write!(f, "invalid argument: {what}"),
            Error::IndexOutOfRange {
                triangle,
                index,
                vertex_count,
            } => write!(
                f,
                "triangle {triangle} references vertex {index} but the vertex buffer holds {vertex_count}"
            ),
            Error::Capacity {
                pool,
                needed,
                available,
            } => write!(
                f,
                "capacity exceeded in pool '{}': needed {needed}, available {available}",
                pool.name()
            ),
            Error::BufferTooSmall { needed, available } => {
                write!(
                    f,
                    "memory buffer too small: needed {needed} bytes, got {available}"
                )
            }
            Error::Misaligned { required } => {
                write!(f, "memory buffer must be aligned to {required} bytes")
            }
            Error::NoGeometry => write!(f, "no geometry set"),
            Error::NotBuilt => write!(f, "no acceleration structure built yet"),
            Error::SlotBusy { slot } => {
                write!(f, "thread slot {slot} is in use by another call")
            }
            Error::ContextBusy => write!(
                f,
                "context busy: another call on this context is running (exclusive calls need the context alone)"
            ),
            Error::Poisoned => write!(
                f,
                "context poisoned by an earlier internal error (panic): destroy it and create a new one"
            ),
            Error::Reentrant => write!(
                f,
                "called from inside a filter: sheaf calls are refused there"
            ),
            Error::Panic => write!(f, "internal error (panic caught at the C boundary)"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for Error {}

/// Result alias used throughout sheaf.
pub type Result<T> = core::result::Result<T, Error>;
