//! Wide lanes: `F8` (two 2x2 quads side by side, one AVX2 register) and
//! `F16` (four quads, one AVX-512 register), implementing the same `Lane`
//! vocabulary as `F4`, and `Wide`, which joins quads into a wide lane and
//! splits it again.
//!
//! The types are plain arrays with element-wise loops: compiled inside a
//! function with `avx2` (or `avx512f`) enabled (`crate::isa`) each loop is
//! one instruction on the whole register; compiled for baseline x86-64 or
//! another architecture they are two (four) 4-wide operations, so every ISA
//! level runs the same code. The 2x2 quad stays the API's SIMD ray: wide
//! lanes exist only inside packet traversals, joined from quads and split
//! back into them.
//!
//! # Exactness
//! Each lane performs the IEEE operation its scalar twin does (`+`, `-`,
//! `*`, `/`, ordered compares, bitwise selects): no reciprocal estimates,
//! and no FMA (Rust never contracts, and `crate::isa` enables `avx2` or
//! `avx512f`, never `fma`). Masks are all-ones or zero per lane.
#![forbid(unsafe_code)]

use super::lane::{Axis4, F4, Lane, M4, mask_from_bits};
use core::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// A lane type made of `G` quads side by side (`F4`: one; `F8`: two;
/// `F16`: four). Lanes `4k..4k+4` are quad `k`; mask bit `4k + i` is lane
/// `i` of quad `k`.
pub trait Wide: Lane {
    /// Quads per lane group.
    const G: usize;
    /// The group of quads `q(0) .. q(G - 1)`.
    fn join(q: impl Fn(usize) -> F4) -> Self;
    /// Quad `k` of the group.
    fn quad(self, k: usize) -> F4;
    /// The mask of bits `0 .. 4G` (bit `4k + i`: lane `i` of quad `k`).
    fn mask_from_bits(bits: u32) -> Self::Mask;
    fn mask_bits(m: Self::Mask) -> u32;
    /// Per-lane axes of the group's quads.
    fn join_axis(a: impl Fn(usize) -> Axis4) -> Self::Axis;
    /// Per lane `if o > self { o } else { self }`: the slab test's running
    /// entry (`select(o.gt(self), o, self)`, NaN in `o` never taken), one
    /// max instruction on wide lanes.
    fn raise(self, o: Self) -> Self;
    /// Per lane `if o < self { o } else { self }` (the running exit).
    fn lower(self, o: Self) -> Self;
    /// Bits of the lanes where `self <= o` (`mask_bits(self.le(o))`, one
    /// compare into a mask register on AVX-512).
    fn le_bits(self, o: Self) -> u32;
    /// The smallest lane, quad by quad then across the last quad (lanes
    /// must not be NaN: the extremes then are lane values, bit for bit).
    #[inline(always)]
    fn lane_min(self) -> f32 {
        let mut m = self.quad(0);
        for k in 1..Self::G {
            m = m.lower(self.quad(k));
        }
        m.min_element()
    }
    /// The largest lane (as `lane_min`).
    #[inline(always)]
    fn lane_max(self) -> f32 {
        let mut m = self.quad(0);
        for k in 1..Self::G {
            m = m.raise(self.quad(k));
        }
        m.max_element()
    }
    /// One level of `extremes_across`: `self`'s lanes in blocks of `2b`
    /// folded to blocks of `b` (the smaller, with `MAX` the larger, of
    /// lanes `2kb + j` and `2kb + b + j`) in the lower half of the result,
    /// `o`'s in the upper half.
    fn fold_pairs<const MAX: bool>(self, o: Self, b: usize) -> Self;
    /// Lane `g` of the result: the smallest (with `MAX` the largest) lane
    /// of `v[g]`, for `v` of `Self::WIDTH` vectors (overwritten): a
    /// transposing reduction of `WIDTH - 1` folds (two permutes and one
    /// min or max each), where `WIDTH` separate `lane_min`s, each blended
    /// into its lane, take about four times the instructions. Lanes must
    /// not be NaN; of two equal lanes (+0 and -0) either may come out.
    #[inline(always)]
    fn extremes_across<const MAX: bool>(v: &mut [Self]) -> Self {
        debug_assert_eq!(v.len(), Self::WIDTH);
        let (mut n, mut b) = (Self::WIDTH, Self::WIDTH / 2);
        while n > 1 {
            for i in 0..n / 2 {
                v[i] = v[2 * i].fold_pairs::<MAX>(v[2 * i + 1], b);
            }
            n /= 2;
            b /= 2;
        }
        v[0]
    }
}

/// The lanes `Wide::fold_pairs` folds at block size `b` (`second`: the
/// block's second half), as two-source indices: `i < N` lane `i` of
/// `self`, `N + i` lane `i` of `o` (the intrinsic lane types' permutes).
pub(crate) const fn fold_index<const N: usize>(b: usize, second: bool) -> [i32; N] {
    let mut r = [0i32; N];
    let mut i = 0;
    while i < N {
        let (from, ii) = if i < N / 2 { (0, i) } else { (N, i - N / 2) };
        let base = 2 * b * (ii / b) + ii % b + if second { b } else { 0 };
        r[i] = (from + base) as i32;
        i += 1;
    }
    r
}

/// `Wide::fold_pairs` on lane arrays.
#[inline(always)]
fn fold_lanes<const N: usize, const MAX: bool>(s: &[f32; N], o: &[f32; N], b: usize) -> [f32; N] {
    // The intrinsic types' permute tables, read here as array indices.
    let (ix, iy) = (fold_index::<N>(b, false), fold_index::<N>(b, true));
    let at = |k: i32| {
        let k = k as usize;
        if k < N { s[k] } else { o[k - N] }
    };
    let mut r = [0.0f32; N];
    for (i, ri) in r.iter_mut().enumerate() {
        let (x, y) = (at(ix[i]), at(iy[i]));
        *ri = if MAX {
            if y > x { y } else { x }
        } else if y < x {
            y
        } else {
            x
        };
    }
    r
}

/// `Lane::shear_axes` of a wide lane type, quad by quad with `F4`'s (whose
/// lanes run the scalar `shear1`): the same bits as lane by lane.
#[inline]
pub fn shear_by_quads<W: Wide>(d: [W; 3]) -> ([W::Axis; 3], [W; 3]) {
    let mut q = [(
        [Axis4 {
            is_x: M4::FALSE,
            is_y: M4::FALSE,
        }; 3],
        [F4::ZERO; 3],
    ); 4];
    for (k, qk) in q.iter_mut().enumerate().take(W::G) {
        *qk = F4::shear_axes([d[0].quad(k), d[1].quad(k), d[2].quad(k)]);
    }
    (
        core::array::from_fn(|j| W::join_axis(|k| q[k].0[j])),
        core::array::from_fn(|a| W::join(|k| q[k].1[a])),
    )
}

impl Wide for F4 {
    const G: usize = 1;
    #[inline(always)]
    fn join(q: impl Fn(usize) -> F4) -> F4 {
        q(0)
    }
    #[inline(always)]
    fn quad(self, _k: usize) -> F4 {
        self
    }
    #[inline(always)]
    fn mask_from_bits(bits: u32) -> M4 {
        mask_from_bits(bits)
    }
    #[inline(always)]
    fn mask_bits(m: M4) -> u32 {
        m.bitmask()
    }
    #[inline(always)]
    fn join_axis(a: impl Fn(usize) -> Axis4) -> Axis4 {
        a(0)
    }
    #[inline(always)]
    fn raise(self, o: F4) -> F4 {
        F4::select(o.cmpgt(self), o, self)
    }
    #[inline(always)]
    fn lower(self, o: F4) -> F4 {
        F4::select(o.cmplt(self), o, self)
    }
    #[inline(always)]
    fn le_bits(self, o: F4) -> u32 {
        self.cmple(o).bitmask()
    }
    #[inline(always)]
    fn fold_pairs<const MAX: bool>(self, o: F4, b: usize) -> F4 {
        F4::from_array(fold_lanes::<4, MAX>(&self.to_array(), &o.to_array(), b))
    }
}

macro_rules! wide_lane {
    ($(#[$doc:meta])* $F:ident, $M:ident, $A:ident, $N:literal, $G:literal, $align:literal) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, PartialEq)]
        #[repr(C, align($align))]
        pub struct $F(pub [f32; $N]);

        /// Per-lane masks of the same width: all ones (true) or zero.
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        #[repr(C, align($align))]
        pub struct $M(pub [u32; $N]);

        /// Per-lane axis (x = 0, y = 1, z = 2) as two masks, as `Axis4`.
        #[derive(Clone, Copy, Debug)]
        pub struct $A {
            pub is_x: $M,
            pub is_y: $M,
        }

        impl $F {
            #[inline(always)]
            fn map2(self, o: Self, f: impl Fn(f32, f32) -> f32) -> Self {
                let mut r = [0.0f32; $N];
                for i in 0..$N {
                    r[i] = f(self.0[i], o.0[i]);
                }
                $F(r)
            }
            #[inline(always)]
            fn cmp(self, o: Self, f: impl Fn(f32, f32) -> bool) -> $M {
                let mut r = [0u32; $N];
                for i in 0..$N {
                    r[i] = 0u32.wrapping_sub(f(self.0[i], o.0[i]) as u32);
                }
                $M(r)
            }
        }

        impl $M {
            #[inline(always)]
            fn map2(self, o: Self, f: impl Fn(u32, u32) -> u32) -> Self {
                let mut r = [0u32; $N];
                for i in 0..$N {
                    r[i] = f(self.0[i], o.0[i]);
                }
                $M(r)
            }
        }

        impl Add for $F {
            type Output = $F;
            #[inline(always)]
            fn add(self, o: $F) -> $F {
                self.map2(o, |a, b| a + b)
            }
        }
        impl Sub for $F {
            type Output = $F;
            #[inline(always)]
            fn sub(self, o: $F) -> $F {
                self.map2(o, |a, b| a - b)
            }
        }
        impl Mul for $F {
            type Output = $F;
            #[inline(always)]
            fn mul(self, o: $F) -> $F {
                self.map2(o, |a, b| a * b)
            }
        }
        impl Div for $F {
            type Output = $F;
            #[inline(always)]
            fn div(self, o: $F) -> $F {
                self.map2(o, |a, b| a / b)
            }
        }
        impl Neg for $F {
            type Output = $F;
            #[inline(always)]
            fn neg(self) -> $F {
                let mut r = self.0;
                for x in r.iter_mut() {
                    *x = -*x;
                }
                $F(r)
            }
        }
        impl BitAnd for $M {
            type Output = $M;
            #[inline(always)]
            fn bitand(self, o: $M) -> $M {
                self.map2(o, |a, b| a & b)
            }
        }
        impl BitOr for $M {
            type Output = $M;
            #[inline(always)]
            fn bitor(self, o: $M) -> $M {
                self.map2(o, |a, b| a | b)
            }
        }
        impl Not for $M {
            type Output = $M;
            #[inline(always)]
            fn not(self) -> $M {
                let mut r = self.0;
                for x in r.iter_mut() {
                    *x = !*x;
                }
                $M(r)
            }
        }

        impl Lane for $F {
            type Mask = $M;
            type Axis = $A;
            #[inline(always)]
            fn splat(x: f32) -> Self {
                $F([x; $N])
            }
            #[inline(always)]
            fn lt(self, o: Self) -> $M {
                self.cmp(o, |a, b| a < b)
            }
            #[inline(always)]
            fn le(self, o: Self) -> $M {
                self.cmp(o, |a, b| a <= b)
            }
            #[inline(always)]
            fn eq(self, o: Self) -> $M {
                self.cmp(o, |a, b| a == b)
            }
            #[inline(always)]
            fn select(m: $M, a: Self, b: Self) -> Self {
                // Bitwise, as the 4-wide select: the chosen lane's bits.
                let mut r = [0.0f32; $N];
                for i in 0..$N {
                    let (x, y) = (a.0[i].to_bits(), b.0[i].to_bits());
                    r[i] = f32::from_bits((x & m.0[i]) | (y & !m.0[i]));
                }
                $F(r)
            }
            #[inline(always)]
            fn any(m: $M) -> bool {
                let mut acc = 0u32;
                for x in m.0 {
                    acc |= x;
                }
                acc != 0
            }
            #[inline(always)]
            fn pick(v: [Self; 3], axis: $A) -> Self {
                Self::select(axis.is_x, v[0], Self::select(axis.is_y, v[1], v[2]))
            }
            #[inline(always)]
            fn get(self, i: usize) -> f32 {
                self.0[i]
            }
            #[inline(always)]
            fn set(&mut self, i: usize, x: f32) {
                self.0[i] = x
            }
            #[inline(always)]
            fn mask_get(m: $M, i: usize) -> bool {
                m.0[i] != 0
            }
            #[inline]
            fn shear_axes(d: [Self; 3]) -> ([$A; 3], [Self; 3]) {
                shear_by_quads(d)
            }
            const WIDTH: usize = $N;
        }

        impl Wide for $F {
            const G: usize = $G;
            #[inline(always)]
            fn join(q: impl Fn(usize) -> F4) -> Self {
                let mut r = [0.0f32; $N];
                for k in 0..$G {
                    r[4 * k..4 * k + 4].copy_from_slice(&q(k).to_array());
                }
                $F(r)
            }
            #[inline(always)]
            fn quad(self, k: usize) -> F4 {
                F4::from_slice(&self.0[4 * k..4 * k + 4])
            }
            #[inline(always)]
            fn mask_from_bits(bits: u32) -> $M {
                let mut r = [0u32; $N];
                for i in 0..$N {
                    r[i] = 0u32.wrapping_sub((bits >> i) & 1);
                }
                $M(r)
            }
            #[inline(always)]
            fn raise(self, o: Self) -> Self {
                let mut r = self.0;
                for i in 0..$N {
                    r[i] = if o.0[i] > r[i] { o.0[i] } else { r[i] };
                }
                $F(r)
            }
            #[inline(always)]
            fn lower(self, o: Self) -> Self {
                let mut r = self.0;
                for i in 0..$N {
                    r[i] = if o.0[i] < r[i] { o.0[i] } else { r[i] };
                }
                $F(r)
            }
            #[inline(always)]
            fn le_bits(self, o: Self) -> u32 {
                let mut b = 0u32;
                for i in 0..$N {
                    b |= u32::from(self.0[i] <= o.0[i]) << i;
                }
                b
            }
            #[inline(always)]
            fn fold_pairs<const MAX: bool>(self, o: Self, b: usize) -> Self {
                $F(fold_lanes::<$N, MAX>(&self.0, &o.0, b))
            }
            #[inline(always)]
            fn mask_bits(m: $M) -> u32 {
                // A sign test per lane (one compare into a mask register),
                // not a shift-and-or reduction.
                let mut b = 0u32;
                for i in 0..$N {
                    b |= u32::from((m.0[i] as i32) < 0) << i;
                }
                b
            }
            #[inline(always)]
            fn join_axis(a: impl Fn(usize) -> Axis4) -> $A {
                let mut bx = 0u32;
                let mut by = 0u32;
                for k in 0..$G {
                    let ak = a(k);
                    bx |= ak.is_x.bitmask() << (4 * k);
                    by |= ak.is_y.bitmask() << (4 * k);
                }
                $A {
                    is_x: Self::mask_from_bits(bx),
                    is_y: Self::mask_from_bits(by),
                }
            }
        }
    };
}

wide_lane!(
    /// Eight f32 lanes: two quads (one AVX2 register).
    F8, M8, Axis8, 8, 2, 32
);
wide_lane!(
    /// Sixteen f32 lanes: four quads (one AVX-512 register).
    F16, M16, Axis16, 16, 4, 64
);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::triangle::{
        ProjTri, RayLanes, Shear, TriVerts, moller_trumbore, projection, watertight,
    };

    fn quads(seed: u32, n: usize) -> [[F4; 8]; 4] {
        // Deterministic values with signs, zeros and wide magnitudes.
        let mut s = seed;
        let mut next = || {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let x = (s >> 8) as f32 / (1u32 << 24) as f32 - 0.5;
            if s.is_multiple_of(17) { 0.0 } else { x * 4.0 }
        };
        let mut q = [[F4::ZERO; 8]; 4];
        for qk in q.iter_mut().take(n) {
            for f in qk.iter_mut() {
                *f = F4::new(next(), next(), next(), next());
            }
        }
        q
    }

    fn rays<W: Wide>(q: &[[F4; 8]; 4]) -> RayLanes<W> {
        let j = |f: usize| W::join(|k| q[k][f]);
        RayLanes {
            org: [j(0), j(1), j(2)],
            dir: [j(3), j(4), j(5)],
            tmin: W::join(|k| q[k][6].abs() * F4::splat(0.01)),
            tmax: W::join(|k| q[k][7].abs() * F4::splat(100.0)),
        }
    }

    /// Every wide triangle test equals the 4-wide one quad by quad, bitwise.
    fn same_as_quads<W: Wide>() {
        let tris = [
            TriVerts {
                v0: [0.0, 0.0, 1.0],
                v1: [1.0, 0.0, 1.0],
                v2: [0.0, 1.0, 1.0],
            },
            TriVerts {
                v0: [-1.0, -1.0, 0.5],
                v1: [1.5, -0.2, 2.0],
                v2: [0.1, 1.7, -1.0],
            },
        ];
        for seed in 0..200 {
            let q = quads(seed, W::G);
            let wr = rays::<W>(&q);
            for tri in &tris {
                let proj = ProjTri::new(tri);
                let wsh = Shear::new(wr.dir);
                let wide = [
                    moller_trumbore(&wr, tri),
                    watertight(&wr, &wsh, tri),
                    projection(&wr, &proj),
                ];
                for (k, qk) in q.iter().enumerate().take(W::G) {
                    let one = [*qk, [F4::ZERO; 8], [F4::ZERO; 8], [F4::ZERO; 8]];
                    let r4 = rays::<F4>(&one);
                    let sh4 = Shear::new(r4.dir);
                    let four = [
                        moller_trumbore(&r4, tri),
                        watertight(&r4, &sh4, tri),
                        projection(&r4, &proj),
                    ];
                    for (w, f) in wide.iter().zip(&four) {
                        let bits = (W::mask_bits(w.mask) >> (4 * k)) & 15;
                        assert_eq!(bits, f.mask.bitmask(), "seed {seed} quad {k}");
                        for i in 0..4 {
                            if bits >> i & 1 == 1 {
                                for (a, b) in [(w.t, f.t), (w.u, f.u), (w.v, f.v)] {
                                    assert_eq!(a.quad(k)[i].to_bits(), b[i].to_bits());
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn f8_tests_equal_f4() {
        same_as_quads::<F8>();
    }

    #[test]
    fn f16_tests_equal_f4() {
        same_as_quads::<F16>();
    }

    /// `extremes_across` against each vector's own `lane_min`/`lane_max`.
    fn extremes_match<W: Wide>() {
        let mut seed = 7u32;
        let mut next = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            match seed >> 28 {
                0 => f32::INFINITY,
                1 => f32::NEG_INFINITY,
                2 => 0.0,
                _ => (seed >> 8) as f32 * 1e-3 - 8000.0,
            }
        };
        for _ in 0..50 {
            let v: Vec<W> = (0..W::WIDTH)
                .map(|_| {
                    let q: Vec<F4> = (0..W::G)
                        .map(|_| F4::new(next(), next(), next(), next()))
                        .collect();
                    W::join(|k| q[k])
                })
                .collect();
            let (mut a, mut b) = (v.clone(), v.clone());
            let (lo, hi) = (
                W::extremes_across::<false>(&mut a),
                W::extremes_across::<true>(&mut b),
            );
            for (g, x) in v.iter().enumerate() {
                assert_eq!(lo.get(g), x.lane_min());
                assert_eq!(hi.get(g), x.lane_max());
            }
        }
    }

    #[test]
    fn extremes_across_each_width() {
        extremes_match::<F4>();
        extremes_match::<F8>();
        extremes_match::<F16>();
    }

    #[test]
    fn masks_round_trip() {
        for bits in [0u32, 1, 0x80, 0xa5, 0xff] {
            assert_eq!(F8::mask_bits(F8::mask_from_bits(bits)), bits);
        }
        for bits in [0u32, 0x8001, 0xffff, 0x1234] {
            assert_eq!(F16::mask_bits(F16::mask_from_bits(bits)), bits);
        }
        let a = F8::join(|k| F4::splat(k as f32));
        assert_eq!(a.quad(1), F4::splat(1.0));
        assert!(F8::any(a.lt(F8::splat(0.5))));
        assert!(!F8::any(a.lt(F8::splat(0.0))));
    }
}
