//! Memory fixed at setup: `Limits`, the `Arena` that carves typed pools out of
//! one caller buffer, and (with `std`) the one-allocation owned buffer.
//!
//! Nothing in sheaf allocates after a context is created: the pools carved
//! here are all the memory that build, trace and render ever touch.
#![allow(unsafe_code)] // only owned.rs, slots.rs, scratch.rs, par.rs, gate.rs, hg.rs and prefetch.rs, each block with a SAFETY comment

pub mod arena;
pub mod gate;
#[doc(hidden)]
pub mod hg;
pub mod limits;
#[cfg(feature = "std")]
pub mod owned;
pub mod par;
pub(crate) mod prefetch;
pub mod regions;
pub mod scratch;
pub mod slots;
pub mod sort;

pub use arena::{
    ARENA_ALIGN, Arena, Carve, Sizer, TOO_BIG, entries, pool_bytes, pool_bytes_checked, when,
};
pub use limits::Limits;
pub use scratch::Scratch;
pub use slots::{SlotGuard, SlotParts, Slots};
