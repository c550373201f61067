//! Tracing front end: which method traces which rays, and the counters every
//! method fills. Structures know nothing of each other; this layer picks one.
//! `fallback` holds what every packet traversal does with incoherent packets.
#![forbid(unsafe_code)]

pub use crate::accel::fallback;

pub mod scene;
pub mod stream;
pub use scene::{Packets, SceneTracer, Tracer, batch_on, per_ray};
pub use stream::{DynRays, HitStream, RaySource, RayStream, SceneHitStream};

pub use crate::counters::{Counters, DEPTH_BINS};

pub use crate::accel::bvh::{BvhOptions, RayKind};
pub use crate::accel::entry::EntrySearch;
pub use crate::accel::grid::traverse_cgt::CgtOptions;
pub use crate::accel::method::{Method, Structure, TraceParams};

use crate::geom::{M4, Ray, Ray4};

/// Pack `n` consecutive rays (`ray(k)` for `k < n`, at most `4 * quads.len()`)
/// into 2x2 quads in `Ray4` lane order; lanes past `n` are inactive (they
/// repeat the last ray so every lane holds finite data). Returns the quads used.
#[inline]
pub fn pack_quads(
    n: usize,
    ray: impl Fn(usize) -> Ray,
    quads: &mut [Ray4],
    active: &mut [M4],
) -> usize {
    let nq = n.div_ceil(4);
    for q in 0..nq {
        let b = q * 4;
        if b + 4 <= n {
            quads[q] = Ray4::from_rays(&[ray(b), ray(b + 1), ray(b + 2), ray(b + 3)]);
            active[q] = M4::TRUE;
            continue;
        }
        let last = ray(n - 1);
        let mut lanes = [last; 4];
        let mut m = [false; 4];
        for i in 0..n - b {
            lanes[i] = ray(b + i);
            m[i] = true;
        }
        quads[q] = Ray4::from_rays(&lanes);
        active[q] = M4::new(m[0], m[1], m[2], m[3]);
    }
    nq
}
