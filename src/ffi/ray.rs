//! `sheaf_ray` and `sheaf_hit`: the C twins of the crate's `Ray` and `Hit`
//! (same fields; own types so that the header documents the C semantics and
//! carries none of the Rust-only associated items such as `Hit::MISS`, which
//! cbindgen would emit as a macro that does not compile in C).

use crate::{Hit, Ray};

/// One ray: the points `org + t * dir` for `t` in `[tmin, tmax)` (32 bytes).
///
/// `dir` need not be normalised (`t` is in units of `dir`); zero components
/// are allowed and exact. A hit at exactly `tmax` is not reported, so a
/// shadow ray with `dir = light - p`, `tmax = 1` never reports the light's
/// own position. Rays with non-finite fields, a zero direction, `tmin < 0`
/// or `tmin > tmax` are misses (`tmax` may be `INFINITY`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_ray {
    pub org: [f32; 3],
    pub tmin: f32,
    pub dir: [f32; 3],
    pub tmax: f32,
}

/// Nearest hit of a ray (16 bytes). A miss has `prim == SHEAF_INVALID_ID`,
/// `t == INFINITY`, `u == v == 0`. Of two hits at the same `t` the lower
/// triangle index wins, so results never depend on traversal order.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_hit {
    /// Ray parameter of the hit.
    pub t: f32,
    /// Index of the triangle in the index buffer (`SHEAF_INVALID_ID`: miss).
    pub prim: u32,
    /// Barycentric weight of the triangle's second vertex.
    pub u: f32,
    /// Barycentric weight of the triangle's third vertex.
    pub v: f32,
}

impl From<sheaf_ray> for Ray {
    #[inline]
    fn from(r: sheaf_ray) -> Ray {
        Ray::new(
            glam::Vec3::from(r.org),
            glam::Vec3::from(r.dir),
            r.tmin,
            r.tmax,
        )
    }
}

impl From<Ray> for sheaf_ray {
    #[inline]
    fn from(r: Ray) -> sheaf_ray {
        sheaf_ray {
            org: r.org,
            tmin: r.tmin,
            dir: r.dir,
            tmax: r.tmax,
        }
    }
}

impl From<sheaf_hit> for Hit {
    #[inline]
    fn from(h: sheaf_hit) -> Hit {
        Hit {
            t: h.t,
            prim: h.prim,
            u: h.u,
            v: h.v,
        }
    }
}

impl From<Hit> for sheaf_hit {
    #[inline]
    fn from(h: Hit) -> sheaf_hit {
        sheaf_hit {
            t: h.t,
            prim: h.prim,
            u: h.u,
            v: h.v,
        }
    }
}

// The C layout of these two is part of the ABI: 32 and 16 bytes, no padding.
const _: () =
    assert!(core::mem::size_of::<sheaf_ray>() == 32 && core::mem::size_of::<sheaf_hit>() == 16);
