//! Ray streams: rays and hits as structures of arrays (Embree's
//! `RTCRayHitNp` layout), traced by every method without the
//! array-of-structs round trip.
//!
//! A packet method reads its rays as 2x2 quads (`Ray4`: each field four
//! lanes side by side). From the array-of-structs `Ray` every quad is a
//! 4x8 transpose; from a stream, whose component arrays already hold
//! consecutive rays side by side, every field of a quad is one 16-byte
//! load (`RaySource::pack`). Hits go back as plain stores into their
//! arrays.
//!
//! # Exactness
//! A stream's ray `i` is the `Ray` made of each array's element `i`, and
//! its quads hold the same bits `pack_quads` gives for those rays (the
//! last quad's unused lanes repeat the last ray, as there), so every
//! method's answers equal the array-of-structs call's, bit for bit (the
//! unit test below for the quads; `tests/context.rs` and
//! `tests/exact/twolevel_exact.rs` for every method's answers).
//!
//! # Deviations
//! Embree's `RTCRayNp` carries a mask, an id and flags per ray; a stream
//! here carries the fields `Ray` has (the mask and culling are per call,
//! `RayControls`).

use crate::error::{Error, Result};
use crate::geom::{F4, Hit4, M4, Ray, Ray4};

/// Where a batch's rays come from: one ray by index, or a packet's quads
/// at once (`trace::batch_on`, `Context::trace_scene_each`).
pub trait RaySource {
    /// Ray `i`.
    fn ray(&self, i: usize) -> Ray;
    /// Rays `start .. start + n` as quads into `quads`, `active` their
    /// lanes: `pack_quads`'s result. Returns the quads used.
    #[inline(always)]
    fn pack(&self, start: usize, n: usize, quads: &mut [Ray4], active: &mut [M4]) -> usize {
        super::pack_quads(n, |k| self.ray(start + k), quads, active)
    }
}

/// Any `RaySource` behind one type: the non-generic bodies of the scene
/// calls (`Context::trace_scene_each`) take their rays so, and are then
/// compiled once, in this crate, whoever calls them. One indirect call per
/// packet (`pack`) or single ray (`ray`).
#[derive(Clone, Copy)]
pub struct DynRays<'a>(pub &'a dyn RaySource);

impl RaySource for DynRays<'_> {
    #[inline(always)]
    fn ray(&self, i: usize) -> Ray {
        self.0.ray(i)
    }
    #[inline(always)]
    fn pack(&self, start: usize, n: usize, quads: &mut [Ray4], active: &mut [M4]) -> usize {
        self.0.pack(start, n, quads, active)
    }
}

/// A ray by index (the array-of-structs calls read `rays[i]`).
impl<F: Fn(usize) -> Ray> RaySource for F {
    #[inline(always)]
    fn ray(&self, i: usize) -> Ray {
        self(i)
    }
}

/// Rays as structures of arrays: ray `i` is `org[a][i]`, `dir[a][i]`,
/// `tmin[i]`, `tmax[i]`. Every array has the stream's length.
#[derive(Clone, Copy, Debug)]
pub struct RayStream<'a> {
    pub org: [&'a [f32]; 3],
    pub dir: [&'a [f32]; 3],
    pub tmin: &'a [f32],
    pub tmax: &'a [f32],
}

impl RayStream<'_> {
    /// The number of rays, when every array has it.
    pub fn count(&self) -> Result<usize> {
        let n = self.tmin.len();
        let lens = [self.org, self.dir].into_iter().flatten().map(|s| s.len());
        if lens.chain([self.tmax.len()]).all(|l| l == n) {
            Ok(n)
        } else {
            Err(Error::InvalidArgument("ray stream arrays differ in length"))
        }
    }
}

impl RaySource for RayStream<'_> {
    #[inline(always)]
    fn ray(&self, i: usize) -> Ray {
        Ray {
            org: self.org.map(|s| s[i]),
            tmin: self.tmin[i],
            dir: self.dir.map(|s| s[i]),
            tmax: self.tmax[i],
        }
    }

    #[inline(always)]
    fn pack(&self, start: usize, n: usize, quads: &mut [Ray4], active: &mut [M4]) -> usize {
        let full = n / 4;
        // One bounds check per array and packet, not per quad.
        let end = start + 4 * full;
        let (org, dir) = (
            self.org.map(|s| &s[start..end]),
            self.dir.map(|s| &s[start..end]),
        );
        let (tmin, tmax) = (&self.tmin[start..end], &self.tmax[start..end]);
        for (q, (quad, act)) in quads[..full]
            .iter_mut()
            .zip(&mut active[..full])
            .enumerate()
        {
            let at = |s: &[f32]| F4::from_slice(&s[4 * q..4 * q + 4]);
            *quad = Ray4 {
                org: org.map(at),
                dir: dir.map(at),
                tmin: at(tmin),
                tmax: at(tmax),
            };
            *act = M4::TRUE;
        }
        if n.is_multiple_of(4) {
            return full;
        }
        // The last, partial quad as `pack_quads` fills it.
        let b = start + 4 * full;
        let tail = super::pack_quads(
            n - 4 * full,
            |k| self.ray(b + k),
            &mut quads[full..full + 1],
            &mut active[full..full + 1],
        );
        full + tail
    }
}

/// `Error::InvalidArgument` unless every result array of `lens` holds
/// one result for each of `n` rays.
pub fn one_per_ray(lens: &[usize], n: usize) -> Result<()> {
    if lens.iter().all(|&l| l == n) {
        Ok(())
    } else {
        Err(Error::InvalidArgument(
            "result arrays must hold one result per ray",
        ))
    }
}

/// Nearest hits as structures of arrays: hit `i` is `t[i]`, `u[i]`,
/// `v[i]`, `prim[i]` (`Hit`'s fields; a miss has `prim == INVALID_ID`,
/// `t == +inf`, `u == v == 0`).
#[derive(Debug)]
pub struct HitStream<'a> {
    pub t: &'a mut [f32],
    pub u: &'a mut [f32],
    pub v: &'a mut [f32],
    pub prim: &'a mut [u32],
}

impl HitStream<'_> {
    /// `Error::InvalidArgument` unless every array holds `n` hits.
    pub fn check(&self, n: usize) -> Result<()> {
        one_per_ray(
            &[self.t.len(), self.u.len(), self.v.len(), self.prim.len()],
            n,
        )
    }

    /// Lanes `0 .. n` of `h` as hits `i .. i + n` (a whole quad as four
    /// stores per field).
    #[inline(always)]
    pub fn put_quad(&mut self, i: usize, h: &Hit4, n: usize) {
        if n == 4 {
            h.t.write_to_slice(&mut self.t[i..i + 4]);
            h.u.write_to_slice(&mut self.u[i..i + 4]);
            h.v.write_to_slice(&mut self.v[i..i + 4]);
            self.prim[i..i + 4].copy_from_slice(&h.prim);
        } else {
            for l in 0..n {
                self.put(i + l, h, l);
            }
        }
    }

    /// Lane `lane` of `h` as hit `i`.
    #[inline(always)]
    pub fn put(&mut self, i: usize, h: &Hit4, lane: usize) {
        self.t[i] = h.t[lane];
        self.u[i] = h.u[lane];
        self.v[i] = h.v[lane];
        self.prim[i] = h.prim[lane];
    }
}

/// A two-level scene's nearest hits as structures of arrays (`SceneHit`'s
/// fields).
#[derive(Debug)]
pub struct SceneHitStream<'a> {
    pub t: &'a mut [f32],
    pub u: &'a mut [f32],
    pub v: &'a mut [f32],
    pub prim: &'a mut [u32],
    pub geometry: &'a mut [u32],
    pub instance: &'a mut [u32],
}

impl SceneHitStream<'_> {
    /// `Error::InvalidArgument` unless every array holds `n` hits.
    pub fn check(&self, n: usize) -> Result<()> {
        let ids = [self.geometry.len(), self.instance.len()];
        one_per_ray(
            &[self.t.len(), self.u.len(), self.v.len(), self.prim.len()],
            n,
        )
        .and_then(|()| one_per_ray(&ids, n))
    }

    /// `h` as hit `i`.
    #[inline(always)]
    pub fn put(&mut self, i: usize, h: &crate::SceneHit) {
        self.t[i] = h.t;
        self.u[i] = h.u;
        self.v[i] = h.v;
        self.prim[i] = h.prim;
        self.geometry[i] = h.geometry;
        self.instance[i] = h.instance;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stream and the same rays as structs: every ray and every packing
    /// (counts around the quad size, offsets) give the same bits.
    #[test]
    fn stream_packs_as_the_rays_do() {
        let n = 23;
        let f = |i: usize, k: usize| (i * 7 + k * 3) as f32 * 0.37 - 2.0;
        let cols: [Vec<f32>; 8] = core::array::from_fn(|k| (0..n).map(|i| f(i, k)).collect());
        let s = RayStream {
            org: [&cols[0], &cols[1], &cols[2]],
            dir: [&cols[3], &cols[4], &cols[5]],
            tmin: &cols[6],
            tmax: &cols[7],
        };
        assert_eq!(s.count().unwrap(), n);
        let rays: Vec<Ray> = (0..n).map(|i| s.ray(i)).collect();
        let blank = Ray4::from_rays(&[Ray::new(glam::Vec3::ZERO, glam::Vec3::X, 0.0, 0.0); 4]);
        for start in [0, 1, 4, 5] {
            for len in 0..=n - start {
                let (mut qa, mut aa) = ([blank; 6], [M4::FALSE; 6]);
                let (mut qb, mut ab) = ([blank; 6], [M4::FALSE; 6]);
                let na = s.pack(start, len, &mut qa, &mut aa);
                let nb = (|i: usize| rays[i]).pack(start, len, &mut qb, &mut ab);
                assert_eq!(na, nb);
                for q in 0..na {
                    assert_eq!(aa[q].bitmask(), ab[q].bitmask(), "start {start} len {len}");
                    for l in 0..4 {
                        let (x, y) = (qa[q].lane(l), qb[q].lane(l));
                        assert_eq!(bytemuck::bytes_of(&x), bytemuck::bytes_of(&y));
                    }
                }
            }
        }
        let short = RayStream {
            tmax: &cols[7][1..],
            ..s
        };
        assert!(short.count().is_err());
    }
}
