//! # sheaf
//!
//! An embeddable ray-tracing kernel: coherent packets of rays through
//! acceleration structures rebuilt every frame, in memory fixed at setup.
//! The core is `no_std` (feature `std` off) and never allocates after a
//! `Context` is created; `ffi` exposes it to C and C++ (`include/sheaf.h`).
//!
//! Layers, data flowing down only: `ffi` / CLI -> `render` -> `trace` ->
//! `accel::*` -> `geom` -> `mem`. See `DESIGN.md` in the project notes.
#![cfg_attr(not(feature = "std"), no_std)]
#![deny(unsafe_code)]

pub mod accel;
pub mod context;
pub mod error;
#[cfg(feature = "std")]
pub mod ffi;
pub mod geom;
pub mod math;
pub mod mem;
pub mod reference;
pub mod render;
pub mod trace;

#[cfg(feature = "std")]
pub mod scenes;

pub use accel::bvh::{BvhInfo, BvhParams};
pub use accel::grid::{GridInfo, GridParams};
pub use accel::pgrid::PgridParams;
#[cfg(feature = "std")]
pub use context::OwnedContext;
pub use context::{Context, Stats, required_bytes};
pub use error::{Error, Pool, Result};
pub use geom::{Hit, Ray, Scene, TriTest};
pub use mem::Limits;
pub use render::deferred::{DeferredInfo, DeferredJob, OnCaller, PrimaryPass, ShadowPass};
pub use render::{Camera, Frame, PointLight, Shading};
pub use trace::{CgtOptions, Counters, Method, TraceParams};

/// Without std a staticlib/cdylib needs a panic handler; sheaf's spins (no
/// panic is reachable from caller input, see STYLE.md rule 8).
#[cfg(all(not(feature = "std"), not(feature = "no-panic-handler"), not(test)))]
#[panic_handler]
fn panic(_: &core::panic::PanicInfo<'_>) -> ! {
    loop {
        core::hint::spin_loop();
    }
}
