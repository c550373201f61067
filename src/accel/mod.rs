//! Acceleration structures, one folder per family, and the contract every
//! family implements (`Accel`). A family never calls another (the two-level
//! scene, below, is built on `bvh`); the trace layer picks one by `Method`
//! and the triangle test once (`trace::scene`).
//!
//! | family | paper | build | single ray | 2x2 SIMD ray | n x n packets |
//! |---|---|---|---|---|---|
//! | `grid/` | Wald, Ize, Kensler, Knoll, Parker 2006, "Ray Tracing Animated Scenes using Coherent Grid Traversal" | `build.rs` (section 3) | `traverse_single.rs` (3DDDA) | lane by lane | `traverse_cgt.rs` (section 2) |
//! | `bvh/` | Overbeck, Ramamoorthi, Mark 2008, "Large Ray Packets for Real-time Whitted Ray Tracing"; the 4-wide tree and its walks after later papers (see `bvh/mod.rs`) | `build.rs` (binned SAH), `build_morton.rs` (Morton codes), `refit.rs`, `wide.rs` (the 4-wide tree) | `traverse_single.rs`, `traverse_wide.rs` (4-wide tree) | `traverse_simd.rs` | `traverse_masked.rs`, `traverse_ranged.rs`, `traverse_partition.rs` (section 3); `traverse_wide_ranged.rs`, `traverse_frustum.rs` (4-wide tree) |
//! | `kd/` | the AEPSA paper, on Wald 2004 | `build.rs` (section 5.1) | `traverse_single.rs` | `traverse_simd.rs` | `traverse_packet.rs`, from `entry/` (MLRTA, AEPSA) |
//! | `pgrid/` | "Fast ray tracing of dynamic scenes with primary and shadow rays on grids" (2010) | `build.rs`, `reorder.rs` (shadow rays into light tiles and chunks), both sorting with `mem::sort` | through a grid, BVH or kd-tree | - | `traverse_primary.rs`, `traverse_shadow.rs` (a deferred frame, `render::deferred`) |
//! | `twolevel/` | Wald, Benthin, Slusallek 2003, "Distributed Interactive Ray Tracing of Dynamic Scenes", section 3 | a BVH per geometry (`bvh/`); `build.rs` (the top level, per commit), `flatten.rs` (world triangles for the other families) | `traverse_single.rs` | `traverse_packet.rs` | `traverse_packet.rs` (every BVH packet method, instance by instance) |
//!
//! The perspective and light grids answer camera rays and shadow rays of
//! a deferred frame, tile by tile, not arbitrary rays: they are driven by
//! `render::deferred` and do not implement `Accel`.
//!
//! A two-level scene (`twolevel`) places many geometries, each with its own
//! BVH, by instances: it is made of `bvh`'s trees and walks, is traced by
//! the context (`context::scene`), and does not implement `Accel` either.
//!
//! Shared by the families: `packet` (the packet contract `PacketSig` and
//! the chosen `Kernel`; lane-by-lane fallbacks, the tiny-lane split,
//! all-miss packets, where a tree packet starts), `fallback` (the
//! coherence test and the tiny-direction lanes), `group` (leaf tests on
//! wide lanes), `entry` (entry-point search for both trees), `mailbox` (CGT
//! section 2.3), `slot` (what a thread slot lends a call: its mailbox and
//! scratch), `method` (what a trace call asks for); `testkit` holds the
//! unit tests' fixtures.
#![forbid(unsafe_code)]

pub mod bvh;
pub mod entry;
pub mod fallback;
pub mod grid;
pub(crate) mod group;
pub mod kd;
pub mod mailbox;
pub mod method;
pub mod packet;
pub mod pgrid;
pub mod slot;
#[cfg(test)]
pub(crate) mod testkit;
pub mod twolevel;

use crate::counters::Counters;
use crate::geom::{Aabb, Hit, Ray, TriTest, TriVerts, TriangleTest};

/// The family contract: a built structure, shared across threads, as the
/// trace layer sees it. Every query is generic over the triangle test the
/// structure was built for (`test`), so traversals are monomorphised per
/// test; `trace::scene` matches on `test` and picks the `kernel` once per
/// call.
///
/// # Exactness
/// Every packet traversal returns, lane by lane, the single ray's
/// (`intersect`) triangle and bitwise t; occlusion agrees with `occluded`.
pub trait Accel: Sync {
    /// The triangle test the structure was built for.
    fn test(&self) -> TriTest;
    /// Bounds of the stored (unpadded) triangles: the scene's scale.
    fn bounds(&self) -> Aabb;
    /// Vertices of the triangle with caller id `prim`, if stored.
    fn triangle(&self, prim: u32) -> Option<TriVerts>;
    /// The single ray: nearest hit in `[tmin, tmax)`.
    fn intersect<T: TriangleTest>(&self, ray: &Ray, ctr: &mut Counters) -> Hit;
    /// The single ray: whether anything is hit in `[tmin, tmax)`.
    fn occluded<T: TriangleTest>(&self, ray: &Ray, ctr: &mut Counters) -> bool;
    /// The single ray: some hit (the first found) or a miss.
    fn any_hit<T: TriangleTest>(&self, ray: &Ray, ctr: &mut Counters) -> Hit;
    /// The family's fastest single ray, which the packet fallbacks trace
    /// lanes with (`packet::alone`): nearest hit, or with `ANY` some hit.
    /// The same answers as `intersect` / `any_hit`, which it defaults to.
    #[inline(always)]
    fn fastest<T: TriangleTest, const ANY: bool>(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
        if ANY {
            self.any_hit::<T>(ray, ctr)
        } else {
            self.intersect::<T>(ray, ctr)
        }
    }
}
