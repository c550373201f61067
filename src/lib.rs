//! # sheaf
//!
//! An embeddable ray-tracing kernel: coherent packets of rays through
//! acceleration structures rebuilt every frame, in memory fixed at setup.
//! The core is `no_std` (feature `std` off) and never allocates after a
//! `Context` is created; `ffi` exposes it to C and C++ (`include/sheaf.h`).
//!
//! Layers, data flowing down only: `ffi` / CLI -> `render` -> `trace` ->
//! `accel::*` -> `geom` -> `mem`. `docs/design.md` in the repository
//! describes the design.
//!
//! # The API
//!
//! The items at the crate root are the API: a [`Context`] (or an
//! [`OwnedContext`]) sized by [`Limits`], a [`Scene`] borrowed from the
//! caller's buffers, per-frame builds ([`GridParams`], [`BvhParams`],
//! [`KdParams`], [`PgridParams`]), traces ([`TraceParams`], [`Ray`], [`Hit`])
//! and frames ([`Frame`], deferred frames run by your [`Workers`]). C and
//! C++ callers use the C ABI of `include/sheaf.h` instead.
//!
//! The modules behind it (`accel`, `geom`, `trace`, `render`, `context`,
//! `mem`, ...) stay public for the `sheaf` CLI's paper studies and the
//! integration tests, which measure the algorithms one by one; they are
//! hidden from these docs unless the internal `study` feature is on, and
//! carry no stability promise.
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

// Internal layers: public for the CLI's studies and the tests, documented
// only with the `study` feature (the curated API is the re-exports below).
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod accel;
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod context;
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod counters;
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod error;
#[cfg(feature = "fault-injection")]
#[doc(hidden)]
pub mod fault;
// The C ABI (`sheaf_*` functions): `include/sheaf.h` documents it.
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod ffi;
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod geom;
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod isa;
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod math;
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod mem;
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod reference;
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod render;
#[cfg_attr(not(feature = "study"), doc(hidden))]
pub mod trace;

#[cfg(feature = "std")]
pub mod scenes;

pub use accel::bvh::refit::{RefitInfo, RefitParams};
pub use accel::bvh::{BuildQuality, BvhInfo, BvhParams};
pub use accel::grid::{GridInfo, GridParams};
pub use accel::kd::{KdInfo, KdParams};
pub use accel::mailbox::Mailbox;
pub use accel::pgrid::PgridParams;
pub use accel::slot::Slot;
pub use accel::twolevel::traverse_single::SceneHit;
pub use accel::twolevel::{GeometryParams, RayControls, TwoLevelInfo, UpdateInfo, UpdateMode};
#[cfg(feature = "std")]
pub use context::OwnedContext;
pub use context::{Context, Stats, required_bytes, slot_scratch_bytes};
pub use error::{Error, Pool, Result};
pub use geom::{Affine, Candidate, Cull, Filter, FilterFn, Hit, Ray, Scene, TriTest};
pub use isa::Isa;
pub use mem::Limits;
// The caller's threads joining a build or a frame (`Context::build_bvh_with`,
// `OnPar`): the `Par` a caller implements or takes (`Serial`, `Join`).
pub use mem::par::{Helped, Join, MAX_WORKERS, Par, Serial};
// Misuse detection for bindings that share a context between threads
// without the borrow rules (the C ABI's state word and last-error lock).
pub use mem::gate::{CallGate, ExclusiveGuard, Locked, SharedGuard};

/// Alignment in bytes of the buffer `Context::new_in` takes (C:
/// `SHEAF_CONTEXT_ALIGN`).
pub const CONTEXT_ALIGN: usize = mem::ARENA_ALIGN;
pub use render::deferred::{
    DeferredInfo, DeferredJob, OnCaller, OnPar, PhaseTimes, PrimaryPass, ShadowPass, Workers,
};
pub use render::material::{Material, MaterialRange, Materials};
pub use render::whitted::{WhittedJob, WhittedParams};
pub use render::{Band, Camera, Frame, PixelRect, PointLight, PrimaryRays, Shading};
pub use trace::{
    BvhOptions, CgtOptions, Counters, EntrySearch, HitStream, Method, RayKind, RayStream,
    SceneHitStream, TraceParams,
};
