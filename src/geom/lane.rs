//! The one SIMD vocabulary: `F4` (four f32 lanes) and `M4` (four lane masks),
//! and the `Lane` trait that lets one triangle test serve both a single ray
//! (`f32`) and the 2x2 SIMD ray (`F4`).
//!
//! Writing the test once, generically, is what makes packet results bitwise
//! equal to single-ray results: both execute the same IEEE operations in the
//! same order (Rust never contracts `a * b + c` into an FMA on its own).

use core::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// Four f32 lanes (SSE2 on x86-64, scalar fallback of identical layout elsewhere).
pub type F4 = glam::Vec4;
/// Four lane masks matching `F4` (glam's `scalar-math` fallback uses `BVec4`).
#[cfg(not(feature = "scalar-math"))]
pub type M4 = glam::BVec4A;
#[cfg(feature = "scalar-math")]
pub type M4 = glam::BVec4;

/// An arithmetic lane: `f32` for one ray, `F4` for four.
pub trait Lane:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// Per-lane boolean.
    type Mask: Copy
        + BitAnd<Output = Self::Mask>
        + BitOr<Output = Self::Mask>
        + Not<Output = Self::Mask>;
    /// Per-lane choice of one of the three axes (x = 0, y = 1, z = 2).
    type Axis: Copy;
    fn splat(x: f32) -> Self;
    fn lt(self, o: Self) -> Self::Mask;
    fn le(self, o: Self) -> Self::Mask;
    fn eq(self, o: Self) -> Self::Mask;
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
    fn any(m: Self::Mask) -> bool;
    /// The component of `v` on `axis`, per lane.
    fn pick(v: [Self; 3], axis: Self::Axis) -> Self;
    /// Lane `i` as f32 (i < 1 for f32, < 4 for F4).
    fn get(self, i: usize) -> f32;
    fn set(&mut self, i: usize, x: f32);
    fn mask_get(m: Self::Mask, i: usize) -> bool;
    /// Watertight-test shear of direction `d`: axes (kx, ky, kz) and
    /// (dx/dz, dy/dz, 1/dz), computed lane by lane with scalar code so every
    /// lane type yields the same bits.
    fn shear_axes(d: [Self; 3]) -> ([Self::Axis; 3], [Self; 3]);
    const WIDTH: usize;
}

impl Lane for f32 {
    type Mask = bool;
    type Axis = usize;
    #[inline(always)]
    fn splat(x: f32) -> Self {
        x
    }
    #[inline(always)]
    fn lt(self, o: Self) -> bool {
        self < o
    }
    #[inline(always)]
    fn le(self, o: Self) -> bool {
        self <= o
    }
    #[inline(always)]
    fn eq(self, o: Self) -> bool {
        self == o
    }
    #[inline(always)]
    fn select(m: bool, a: Self, b: Self) -> Self {
        if m { a } else { b }
    }
    #[inline(always)]
    fn any(m: bool) -> bool {
        m
    }
    #[inline(always)]
    fn pick(v: [Self; 3], axis: usize) -> Self {
        v[axis]
    }
    #[inline(always)]
    fn get(self, _i: usize) -> f32 {
        self
    }
    #[inline(always)]
    fn set(&mut self, _i: usize, x: f32) {
        *self = x
    }
    #[inline(always)]
    fn mask_get(m: bool, _i: usize) -> bool {
        m
    }
    #[inline]
    fn shear_axes(d: [f32; 3]) -> ([usize; 3], [f32; 3]) {
        shear1(d)
    }
    const WIDTH: usize = 1;
}

/// Per-lane axis for `F4`: two masks, `is_x` and `is_y` (neither: z).
#[derive(Clone, Copy, Debug)]
pub struct Axis4 {
    pub is_x: M4,
    pub is_y: M4,
}

impl Axis4 {
    /// Build from four axis indices (each 0, 1 or 2).
    #[inline]
    pub fn new(a: [usize; 4]) -> Self {
        Axis4 {
            is_x: M4::new(a[0] == 0, a[1] == 0, a[2] == 0, a[3] == 0),
            is_y: M4::new(a[0] == 1, a[1] == 1, a[2] == 1, a[3] == 1),
        }
    }
}

impl Lane for F4 {
    type Mask = M4;
    type Axis = Axis4;
    #[inline(always)]
    fn splat(x: f32) -> Self {
        F4::splat(x)
    }
    #[inline(always)]
    fn lt(self, o: Self) -> M4 {
        self.cmplt(o)
    }
    #[inline(always)]
    fn le(self, o: Self) -> M4 {
        self.cmple(o)
    }
    #[inline(always)]
    fn eq(self, o: Self) -> M4 {
        self.cmpeq(o)
    }
    #[inline(always)]
    fn select(m: M4, a: Self, b: Self) -> Self {
        F4::select(m, a, b)
    }
    #[inline(always)]
    fn any(m: M4) -> bool {
        m.any()
    }
    #[inline(always)]
    fn pick(v: [Self; 3], axis: Axis4) -> Self {
        F4::select(axis.is_x, v[0], F4::select(axis.is_y, v[1], v[2]))
    }
    #[inline(always)]
    fn get(self, i: usize) -> f32 {
        self[i]
    }
    #[inline(always)]
    fn set(&mut self, i: usize, x: f32) {
        self[i] = x
    }
    #[inline(always)]
    fn mask_get(m: M4, i: usize) -> bool {
        m.test(i)
    }
    #[inline]
    fn shear_axes(d: [F4; 3]) -> ([Axis4; 3], [F4; 3]) {
        let mut k = [[0usize; 3]; 4];
        let mut s = [F4::ZERO; 3];
        for i in 0..4 {
            let (ki, si) = shear1([d[0][i], d[1][i], d[2][i]]);
            k[i] = ki;
            for a in 0..3 {
                s[a][i] = si[a];
            }
        }
        let axis = |j: usize| Axis4::new([k[0][j], k[1][j], k[2][j], k[3][j]]);
        ([axis(0), axis(1), axis(2)], s)
    }
    const WIDTH: usize = 4;
}

/// Lane mask from a 4-bit integer (bit i = lane i).
#[inline]
pub fn mask_from_bits(bits: u32) -> M4 {
    M4::new(bits & 1 != 0, bits & 2 != 0, bits & 4 != 0, bits & 8 != 0)
}

/// Scalar shear of one direction: ([kx, ky, kz], [sx, sy, sz]).
#[inline]
pub(crate) fn shear1(d: [f32; 3]) -> ([usize; 3], [f32; 3]) {
    let a = [d[0].abs(), d[1].abs(), d[2].abs()];
    let kz = if a[0] >= a[1] && a[0] >= a[2] {
        0
    } else if a[1] >= a[2] {
        1
    } else {
        2
    };
    let mut kx = (kz + 1) % 3;
    let mut ky = (kx + 1) % 3;
    if d[kz] < 0.0 {
        core::mem::swap(&mut kx, &mut ky);
    }
    ([kx, ky, kz], [d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]])
}
