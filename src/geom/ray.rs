//! Rays and hits: the single ray (`Ray`, `Hit`, also the C layout) and the
//! 2x2 SIMD ray (`Ray4`, `Hit4`).
//!
//! # Semantics
//! A ray is `org + t * dir` for `t` in `[tmin, tmax)`. `dir` need not be
//! normalised (t is in units of `dir`). Zero direction components are allowed
//! and exact. A hit at exactly `tmax` is not reported, so a shadow ray with
//! `dir = light - p`, `tmax = 1` never reports the light's own position.
//! Of two hits at the same t, the lower triangle id wins: results do not depend
//! on traversal order, which is what lets packet methods match single-ray ones
//! bit for bit.

use crate::geom::lane::{F4, M4};
use bytemuck::{Pod, Zeroable};

/// Triangle id of a miss.
pub const INVALID_ID: u32 = u32::MAX;

/// One ray (32 bytes, C layout `sheaf_ray`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Ray {
    pub org: [f32; 3],
    pub tmin: f32,
    pub dir: [f32; 3],
    pub tmax: f32,
}

/// One hit (16 bytes, C layout `sheaf_hit`). On a miss `prim == INVALID_ID`,
/// `t == +inf`, `u == v == 0`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Hit {
    /// Ray parameter of the hit.
    pub t: f32,
    /// Triangle index in the caller's index buffer (`INVALID_ID`: miss).
    pub prim: u32,
    /// Barycentric weight of the triangle's second vertex.
    pub u: f32,
    /// Barycentric weight of the triangle's third vertex.
    pub v: f32,
}

impl Hit {
    pub const MISS: Hit = Hit {
        t: f32::INFINITY,
        prim: INVALID_ID,
        u: 0.0,
        v: 0.0,
    };
    /// An occluded lane of a packet method that knows no occluder's id
    /// (`prim` = `INVALID_ID - 1`, never a triangle's).
    pub const OCCLUDED: Hit = Hit {
        t: 0.0,
        prim: INVALID_ID - 1,
        u: 0.0,
        v: 0.0,
    };
    #[inline]
    pub fn is_hit(&self) -> bool {
        self.prim != INVALID_ID
    }
}

impl Ray {
    #[inline]
    pub fn new(org: glam::Vec3, dir: glam::Vec3, tmin: f32, tmax: f32) -> Ray {
        Ray {
            org: org.to_array(),
            tmin,
            dir: dir.to_array(),
            tmax,
        }
    }
    /// `true` when every field is usable: finite origin and direction, a
    /// non-zero direction, `tmin >= 0` and `tmin <= tmax` (tmax may be +inf).
    /// Other rays are reported as misses without being traced.
    #[inline]
    pub fn is_valid(&self) -> bool {
        let finite = self
            .org
            .iter()
            .chain(self.dir.iter())
            .all(|x| x.is_finite());
        let nonzero = self.dir.iter().any(|&x| x != 0.0);
        finite && nonzero && self.tmin >= 0.0 && self.tmin <= self.tmax
    }
}

/// Four rays in structure-of-arrays form, one per lane.
///
/// Lane order is the 2x2 pixel quad: lane 0 = (x, y), 1 = (x+1, y),
/// 2 = (x, y+1), 3 = (x+1, y+1). The reciprocals are not stored: each
/// traversal computes the ones it reads (a frustum walk per lane group, a
/// slab test per quad), so packing a packet divides nothing. Inactive
/// lanes carry whatever the caller left; callers use the `active` mask of
/// the packet instead; the struct holds no mask.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug)]
pub struct Ray4 {
    pub org: [F4; 3],
    pub dir: [F4; 3],
    pub tmin: F4,
    pub tmax: F4,
}

/// Four hits, structure of arrays, lanes as in `Ray4`.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug)]
pub struct Hit4 {
    pub t: F4,
    pub prim: [u32; 4],
    pub u: F4,
    pub v: F4,
}

const _: () = assert!(core::mem::size_of::<Ray>() == 32);
const _: () = assert!(core::mem::size_of::<Hit>() == 16);
const _: () = assert!(core::mem::size_of::<Ray4>() == 8 * 16);
const _: () = assert!(core::mem::align_of::<Ray4>() == 16);
const _: () = assert!(core::mem::size_of::<Hit4>() == 4 * 16);

impl Hit4 {
    pub const MISS: Hit4 = Hit4 {
        t: F4::splat(f32::INFINITY),
        prim: [INVALID_ID; 4],
        u: F4::ZERO,
        v: F4::ZERO,
    };
    /// `Hit::MISS` in the lanes of `m`, the others unchanged.
    #[inline(always)]
    pub fn miss(&mut self, m: M4) {
        self.t = F4::select(m, F4::INFINITY, self.t);
        self.u = F4::select(m, F4::ZERO, self.u);
        self.v = F4::select(m, F4::ZERO, self.v);
        for i in 0..4 {
            if m.test(i) {
                self.prim[i] = INVALID_ID;
            }
        }
    }
    /// Lane `i` as a `Hit`.
    #[inline]
    pub fn lane(&self, i: usize) -> Hit {
        Hit {
            t: self.t[i],
            prim: self.prim[i],
            u: self.u[i],
            v: self.v[i],
        }
    }
    /// The four lanes as `Hit`s: `Hit4`'s rows (t, prim, u, v) are the
    /// fields of `Hit` in its order, so this is a 4x4 transpose (shuffles,
    /// which move bits unchanged) instead of sixteen lane picks.
    #[inline(always)]
    pub fn hits(&self) -> [Hit; 4] {
        let prim = F4::from_array(self.prim.map(f32::from_bits));
        let m = glam::Mat4::from_cols(self.t, prim, self.u, self.v).transpose();
        [m.x_axis, m.y_axis, m.z_axis, m.w_axis].map(|c| bytemuck::cast(c.to_array()))
    }
    #[inline]
    pub fn set_lane(&mut self, i: usize, h: Hit) {
        self.t[i] = h.t;
        self.prim[i] = h.prim;
        self.u[i] = h.u;
        self.v[i] = h.v;
    }
    /// Lanes where a hit at `t` on triangle `prim` beats the current one:
    /// nearer, or as near with a smaller triangle id (the tie rule of every
    /// nearest-hit traversal, so results do not depend on visiting order).
    #[inline(always)]
    pub fn closer(&self, t: F4, prim: u32) -> M4 {
        let lt = t.cmplt(self.t);
        let eq = t.cmpeq(self.t);
        if !eq.any() {
            return lt;
        }
        let b = self.prim;
        lt | (eq & M4::new(prim < b[0], prim < b[1], prim < b[2], prim < b[3]))
    }
    /// Lanes that hit something.
    #[inline]
    pub fn hit_mask(&self) -> M4 {
        M4::new(
            self.prim[0] != INVALID_ID,
            self.prim[1] != INVALID_ID,
            self.prim[2] != INVALID_ID,
            self.prim[3] != INVALID_ID,
        )
    }
}

impl Ray4 {
    /// Pack four rays.
    #[inline]
    pub fn from_rays(r: &[Ray; 4]) -> Ray4 {
        // Plain loads per lane (a 4x8 transpose the compiler can schedule).
        let org =
            core::array::from_fn(|a| F4::new(r[0].org[a], r[1].org[a], r[2].org[a], r[3].org[a]));
        let dir: [F4; 3] =
            core::array::from_fn(|a| F4::new(r[0].dir[a], r[1].dir[a], r[2].dir[a], r[3].dir[a]));
        Ray4 {
            org,
            dir,
            tmin: F4::new(r[0].tmin, r[1].tmin, r[2].tmin, r[3].tmin),
            tmax: F4::new(r[0].tmax, r[1].tmax, r[2].tmax, r[3].tmax),
        }
    }
    /// `Ray::is_valid`, lane by lane: finite origin and direction, a
    /// non-zero direction, `0 <= tmin <= tmax`.
    #[inline(always)]
    pub fn valid(&self) -> M4 {
        let fin = |x: F4| x.abs().cmplt(F4::INFINITY);
        let d = &self.dir;
        fin(self.org[0])
            & fin(self.org[1])
            & fin(self.org[2])
            & fin(d[0])
            & fin(d[1])
            & fin(d[2])
            & (d[0].cmpne(F4::ZERO) | d[1].cmpne(F4::ZERO) | d[2].cmpne(F4::ZERO))
            & self.tmin.cmpge(F4::ZERO)
            & self.tmin.cmple(self.tmax)
    }
    /// Lane `i` as a `Ray`.
    #[inline]
    pub fn lane(&self, i: usize) -> Ray {
        Ray {
            org: [self.org[0][i], self.org[1][i], self.org[2][i]],
            tmin: self.tmin[i],
            dir: [self.dir[0][i], self.dir[1][i], self.dir[2][i]],
            tmax: self.tmax[i],
        }
    }
}

/// The tie rule shared by every traversal: nearer t wins; equal t, lower id.
#[inline(always)]
pub fn closer(t: f32, prim: u32, best: &Hit) -> bool {
    t < best.t || (t == best.t && prim < best.prim)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hits_are_the_lanes_bit_for_bit() {
        let h = Hit4 {
            t: F4::new(1.5, f32::INFINITY, -0.0, 3.0e-39),
            // Ids whose bits are NaNs (a miss, a signalling pattern).
            prim: [7, INVALID_ID, 0x7f80_0001, 0xffc0_0000],
            u: F4::new(0.25, 0.0, 1.0, f32::MIN_POSITIVE),
            v: F4::new(0.5, 0.0, f32::EPSILON, 1.0),
        };
        let bits = |x: &Hit| (x.t.to_bits(), x.prim, x.u.to_bits(), x.v.to_bits());
        for (l, got) in h.hits().iter().enumerate() {
            assert_eq!(bits(got), bits(&h.lane(l)), "lane {l}");
        }
    }
}
