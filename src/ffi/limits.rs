//! `sheaf_limits` (the crate's `Limits`, `#[repr(C)]`): every pool size of a
//! context. The struct itself is exported from `mem/limits.rs` under its C
//! name (cbindgen.toml `[export.rename]`).

use super::{check_non_null, guard_free, write_out};
use crate::mem::Limits;

/// Write limits for scenes of up to `max_triangles` triangles to `*out`:
/// `3 * max_triangles` vertices, 4096 x 4096 images, 64-pixel tiles, 8
/// threads, grid pools derived from the triangle count (0 in
/// `max_grid_cells` / `max_grid_refs`). Adjust fields afterwards as needed.
///
/// `out` must not be NULL. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_limits_default(
    max_triangles: u32,
    out: *mut Limits,
) -> super::sheaf_status {
    guard_free(|| {
        check_non_null!(out);
        write_out(out, Limits::for_triangles(max_triangles));
        Ok(())
    })
}
