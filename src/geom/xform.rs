//! Affine transforms of instances (3x4, row-major, as Embree's
//! `RTC_FORMAT_FLOAT3X4_ROW_MAJOR` and DXR's instance transform): a point
//! `p` maps to `M[.][0..3] . p + M[.][3]`, a direction to `M[.][0..3] . d`.
//!
//! Rays enter an instance by the inverse transform, computed once when the
//! instance is set (in f64, rounded to f32), never per ray. Every ray that
//! visits an instance is mapped with the same f32 operations in the same
//! order (`point`, `vector`), so every traversal of a two-level scene sees
//! the same object-space ray, bit for bit, and the object-space t is the
//! world-space t (the direction is mapped, not normalised).

use crate::error::{Error, Result};
use crate::geom::{Aabb, F4};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// A 3x4 affine transform, row-major.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Affine {
    pub m: [[f32; 4]; 3],
}

impl Affine {
    pub const IDENTITY: Affine = Affine {
        m: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ],
    };

    /// `m` (column-major, as glam's) followed by a translation by `t`.
    pub fn from_mat3(m: glam::Mat3, t: Vec3) -> Affine {
        let r = |k: usize| m.row(k);
        Affine {
            m: [0, 1, 2].map(|k| [r(k).x, r(k).y, r(k).z, t[k]]),
        }
    }

    /// Rotation by `deg` degrees about axis `axis` (0 x, 1 y, 2 z) of the
    /// per-axis scale `s`, then a translation by `t` (tests and examples).
    pub fn rotated(deg: f32, axis: usize, s: [f32; 3], t: [f32; 3]) -> Affine {
        let r = glam::Mat3::from_axis_angle(Vec3::AXES[axis], deg.to_radians());
        Affine::from_mat3(r * glam::Mat3::from_diagonal(Vec3::from(s)), Vec3::from(t))
    }

    /// A translation by `t`.
    pub fn translation(t: [f32; 3]) -> Affine {
        let mut a = Affine::IDENTITY;
        for (r, &x) in a.m.iter_mut().zip(&t) {
            r[3] = x;
        }
        a
    }

    /// `p` mapped: `((m0 x + m1 y) + m2 z) + m3` per row, in f32.
    #[inline(always)]
    pub fn point(&self, p: [f32; 3]) -> [f32; 3] {
        self.m
            .map(|r| ((r[0] * p[0] + r[1] * p[1]) + r[2] * p[2]) + r[3])
    }

    /// `d` mapped without the translation, in f32.
    #[inline(always)]
    pub fn vector(&self, d: [f32; 3]) -> [f32; 3] {
        self.m.map(|r| (r[0] * d[0] + r[1] * d[1]) + r[2] * d[2])
    }

    /// Four points mapped (`point` lane by lane, the same f32 operations
    /// in the same order, so each lane is bitwise `point`'s).
    #[inline(always)]
    pub fn point4(&self, p: &[F4; 3]) -> [F4; 3] {
        let mut o = self.vector4(p);
        for (o, r) in o.iter_mut().zip(&self.m) {
            *o += F4::splat(r[3]);
        }
        o
    }

    /// Four vectors mapped (`vector` lane by lane, bitwise).
    #[inline(always)]
    pub fn vector4(&self, d: &[F4; 3]) -> [F4; 3] {
        let mut o = [F4::ZERO; 3];
        for (o, r) in o.iter_mut().zip(&self.m) {
            *o = (F4::splat(r[0]) * d[0] + F4::splat(r[1]) * d[1]) + F4::splat(r[2]) * d[2];
        }
        o
    }

    fn f64(&self) -> [[f64; 4]; 3] {
        self.m.map(|r| r.map(f64::from))
    }

    /// The inverse, computed in f64 and rounded to f32.
    ///
    /// Errors: `InvalidArgument` when an entry is NaN or infinite, the
    /// linear part is singular (determinant exactly zero in f64), or the
    /// inverse does not fit f32 (an entry rounds to infinity or the
    /// determinant underflows).
    pub fn inverse(&self) -> Result<Affine> {
        if !self.m.iter().flatten().all(|x| x.is_finite()) {
            return Err(Error::InvalidArgument(
                "instance transform has a NaN or infinite entry",
            ));
        }
        let a = self.f64();
        let c = |r: usize, k: usize| a[r][k];
        // Cofactors of the 3x3 linear part.
        let cof = [
            [
                c(1, 1) * c(2, 2) - c(1, 2) * c(2, 1),
                c(1, 2) * c(2, 0) - c(1, 0) * c(2, 2),
                c(1, 0) * c(2, 1) - c(1, 1) * c(2, 0),
            ],
            [
                c(0, 2) * c(2, 1) - c(0, 1) * c(2, 2),
                c(0, 0) * c(2, 2) - c(0, 2) * c(2, 0),
                c(0, 1) * c(2, 0) - c(0, 0) * c(2, 1),
            ],
            [
                c(0, 1) * c(1, 2) - c(0, 2) * c(1, 1),
                c(0, 2) * c(1, 0) - c(0, 0) * c(1, 2),
                c(0, 0) * c(1, 1) - c(0, 1) * c(1, 0),
            ],
        ];
        let det = c(0, 0) * cof[0][0] + c(0, 1) * cof[0][1] + c(0, 2) * cof[0][2];
        if det == 0.0 || !det.is_finite() {
            return Err(Error::InvalidArgument(
                "instance transform is singular (zero determinant)",
            ));
        }
        // inv[r][k] = cof[k][r] / det; translation -inv . t.
        let mut inv = [[0.0f64; 4]; 3];
        for (r, row) in inv.iter_mut().enumerate() {
            for (k, x) in row.iter_mut().take(3).enumerate() {
                *x = cof[k][r] / det;
            }
            row[3] = -(row[0] * c(0, 3) + row[1] * c(1, 3) + row[2] * c(2, 3));
        }
        let out = Affine {
            m: inv.map(|r| r.map(|x| x as f32)),
        };
        if !out.m.iter().flatten().all(|x| x.is_finite())
            || out.m.iter().any(|r| r[..3] == [0.0; 3])
        {
            return Err(Error::InvalidArgument(
                "instance transform's inverse does not fit f32",
            ));
        }
        Ok(out)
    }

    /// How much f32 rounding of a mapped ray can stretch (`|M| |M^-1|` in
    /// the infinity norm, at least 1): the world boxes of instances are
    /// padded by this factor.
    pub fn condition(&self, inv: &Affine) -> f32 {
        let norm = |a: &Affine| {
            a.m.iter()
                .map(|r| r[0].abs() + r[1].abs() + r[2].abs())
                .fold(0.0f32, f32::max)
        };
        (norm(self) * norm(inv)).max(1.0)
    }

    /// The box of `b`'s eight corners mapped (in f64, so no corner is
    /// rounded inward), rounded outward to f32; empty for an empty `b`.
    pub fn bounds(&self, b: &Aabb) -> Aabb {
        if b.is_empty() {
            return Aabb::EMPTY;
        }
        let a = self.f64();
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for corner in 0..8 {
            let p = [
                if corner & 1 == 0 { b.min.x } else { b.max.x },
                if corner & 2 == 0 { b.min.y } else { b.max.y },
                if corner & 4 == 0 { b.min.z } else { b.max.z },
            ]
            .map(f64::from);
            for r in 0..3 {
                let x = a[r][0] * p[0] + a[r][1] * p[1] + a[r][2] * p[2] + a[r][3];
                lo[r] = lo[r].min(x);
                hi[r] = hi[r].max(x);
            }
        }
        let down = |x: f64| {
            let f = x as f32;
            if f64::from(f) > x { f.next_down() } else { f }
        };
        let up = |x: f64| {
            let f = x as f32;
            if f64::from(f) < x { f.next_up() } else { f }
        };
        Aabb {
            min: Vec3::from_array(lo.map(down)),
            max: Vec3::from_array(hi.map(up)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rot(deg: f32, s: f32) -> Affine {
        Affine::rotated(deg, 2, [s; 3], [1.5, -2.0, 0.25])
    }

    #[test]
    fn inverse_round_trips() {
        for a in [
            Affine::IDENTITY,
            rot(30.0, 2.0),
            rot(-75.0, 0.1),
            Affine::translation([1.0, 2.0, 3.0]),
        ] {
            let inv = a.inverse().unwrap();
            for p in [[0.0, 0.0, 0.0], [1.0, -2.0, 3.5], [100.0, 0.5, -7.0]] {
                let q = inv.point(a.point(p));
                for k in 0..3 {
                    assert!(
                        (q[k] - p[k]).abs() <= 1e-4 * (1.0 + p[k].abs()),
                        "{a:?} {p:?} {q:?}"
                    );
                }
            }
            assert!(a.condition(&inv) >= 1.0);
        }
    }

    #[test]
    fn four_lanes_map_as_one() {
        let pts = [
            [0.0, -0.0, 3.5],
            [1.0e-30, -2.0, 7.25e20],
            [100.0, 0.5, -7.0],
            [-3.0e-7, 1.0e6, 0.1],
        ];
        let four = |k: usize| F4::from_array(core::array::from_fn(|i| pts[i][k]));
        let p4 = [four(0), four(1), four(2)];
        for a in [Affine::IDENTITY, rot(30.0, 2.0), rot(-75.0, 0.1)] {
            let (q4, v4) = (a.point4(&p4), a.vector4(&p4));
            for (i, p) in pts.iter().enumerate() {
                let (q, v) = (a.point(*p), a.vector(*p));
                for k in 0..3 {
                    assert_eq!(q4[k][i].to_bits(), q[k].to_bits(), "{a:?} {p:?}");
                    assert_eq!(v4[k][i].to_bits(), v[k].to_bits(), "{a:?} {p:?}");
                }
            }
        }
    }

    #[test]
    fn bad_transforms_are_refused() {
        let mut a = Affine::IDENTITY;
        a.m[1][2] = f32::NAN;
        assert!(a.inverse().is_err());
        a.m[1][2] = f32::INFINITY;
        assert!(a.inverse().is_err());
        let flat = Affine {
            m: [
                [1.0, 0.0, 0.0, 0.0],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
        };
        assert!(flat.inverse().is_err(), "zero determinant");
        let tiny = Affine {
            m: [
                [1e-39, 0.0, 0.0, 0.0],
                [0.0, 1e-39, 0.0, 0.0],
                [0.0, 0.0, 1e-39, 0.0],
            ],
        };
        assert!(tiny.inverse().is_err(), "inverse overflows f32");
    }

    #[test]
    fn bounds_hold_every_mapped_point() {
        let b = Aabb {
            min: Vec3::new(-1.0, 0.0, 2.0),
            max: Vec3::new(3.0, 0.5, 2.25),
        };
        let a = rot(33.0, 1.7);
        let w = a.bounds(&b);
        for i in 0..=10 {
            for j in 0..=10 {
                for k in 0..=10 {
                    let f = |t: i32, lo: f32, hi: f32| lo + (hi - lo) * t as f32 / 10.0;
                    let p = [
                        f(i, b.min.x, b.max.x),
                        f(j, b.min.y, b.max.y),
                        f(k, b.min.z, b.max.z),
                    ];
                    let q = Vec3::from_array(a.point(p));
                    // The f32 mapping may round past the exact box by an ulp
                    // or two; the instance boxes are padded for that.
                    let pad = Vec3::splat(1e-5 * (1.0 + q.abs().max_element()));
                    assert!(q.cmpge(w.min - pad).all() && q.cmple(w.max + pad).all());
                }
            }
        }
        assert!(a.bounds(&Aabb::EMPTY).is_empty());
    }
}
