//! Geometry: the 2x2 SIMD ray and its single-ray twin, boxes, triangle tests
//! and the borrowed scene input. Knows nothing about acceleration structures.
#![forbid(unsafe_code)]

pub mod aabb;
pub mod filter;
pub mod frustum;
pub mod lane;
pub mod ray;
pub mod scene;
pub mod triangle;
pub mod wide;
pub mod xform;

pub use aabb::Aabb;
pub use filter::{Accept, Candidate, Filter, FilterFn, Hook, OneFilter};
pub use lane::{F4, Lane, M4};
pub use ray::{Hit, Hit4, INVALID_ID, Ray, Ray4, closer};
pub use scene::{Excluded, Scene};
pub(crate) use triangle::with_test;
pub use triangle::{
    Cull, Mt, ProjTri, Pt, RayLanes, TriStore, TriTest, TriVerts, TriangleTest, Wt,
};
pub use wide::{F8, F16, Wide};
pub use xform::Affine;
