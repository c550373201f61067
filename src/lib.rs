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

/// A fault-injection point (feature `fault-injection`, tests only): panics
/// when a test armed it on this thread (`fault::arm`); compiles to nothing
/// otherwise.
macro_rules! fault_point {
    ($p:ident) => {
        #[cfg(feature = "fault-injection")]
        $crate::fault::point($crate::fault::Point::$p);
    };
}
pub(crate) use fault_point;

pub mod accel;
pub mod context;
pub mod counters;
pub mod error;
#[cfg(feature = "fault-injection")]
#[doc(hidden)]
pub mod fault;
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
