//! Fault injection (feature `fault-injection`, off by default; tests only):
//! named points inside each build and frame that panic when a test armed
//! them, so tests can show what a caught panic leaves behind (the C ABI
//! poisons the context: `tests/fault_injection.rs`).
//!
//! Arming is per thread and used once, so tests running in parallel do not
//! trip each other's points.

use std::cell::Cell;

/// Where a fault can be injected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Point {
    /// `set_geometry` (C ABI) after the new geometry was validated.
    SetGeometry,
    /// The grid build after its cell counts were cleared (commit phase).
    GridBuild,
    /// The BVH build after the references were written, before the nodes.
    BvhBuild,
    /// The kd-tree build after every capacity check, before writing.
    KdBuild,
    /// The perspective/light grid scene load after the triangles were copied.
    PgridLoad,
    /// A deferred frame's perspective grid build, before it is marked built.
    PgridCamera,
    /// `render_with` after the pixels were written, before the stats.
    Render,
    /// `render_whitted` after the pixels were written, before the stats.
    Whitted,
}

impl Point {
    /// Every point.
    pub const ALL: [Point; 8] = [
        Point::SetGeometry,
        Point::GridBuild,
        Point::BvhBuild,
        Point::KdBuild,
        Point::PgridLoad,
        Point::PgridCamera,
        Point::Render,
        Point::Whitted,
    ];
}

std::thread_local! {
    static ARMED: Cell<Option<Point>> = const { Cell::new(None) };
}

/// Make the next pass through `p` on this thread panic.
pub fn arm(p: Point) {
    ARMED.set(Some(p));
}

/// Disarm this thread's point, returning it if it was never reached.
pub fn disarm() -> Option<Point> {
    ARMED.replace(None)
}

/// Panic when `p` is armed on this thread (the arming is used up).
pub fn point(p: Point) {
    if ARMED.get() == Some(p) {
        ARMED.set(None);
        panic!("sheaf fault injection at {p:?}");
    }
}
