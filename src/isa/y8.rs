//! `Y8`: the AVX2 level's lane type, eight f32 lanes in one `__m256`
//! register, masks as all-ones or zero lanes of another (`vcmpps`,
//! `vblendvps`, `vmovmskps`), the twin of `z16` for machines without
//! AVX-512.
//!
//! `geom::wide::F8` states the same lanes as plain arrays; LLVM compiles
//! its lane-to-bits reductions into shuffle chains (`z16` module docs).
//! `Y8` is what `isa::Chosen` instantiates inside its `avx2` function; `F8`
//! stays for the emulated level.
//!
//! # Exactness
//! Every operation is the IEEE operation of `F8`'s lane loop (no FMA),
//! `vmaxps`/`vminps` for `raise`/`lower` as in `z16`; `same_as_f8` (`isa::same_ops`) checks
//! each against `F8` bitwise.
//!
//! # Safety
//! As `z16`: the only way to obtain a `Y8` is to be handed one inside
//! `x86::avx2`, which `run` calls only after `detected()` reported AVX2
//! usable; the emulated level uses `F8`.
#![allow(unsafe_code)] // AVX2 intrinsics; see the module's Safety section

use crate::geom::lane::{Axis4, F4, Lane};
use crate::geom::wide::{Wide, fold_index, shear_by_quads};
use core::arch::x86_64::*;
use core::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// Eight f32 lanes: two 2x2 quads, lanes `4k..4k+4` quad `k`.
#[derive(Clone, Copy)]
#[repr(transparent)]
pub(super) struct Y8(__m256);

/// Eight lane masks: all ones (true) or zero per lane.
#[derive(Clone, Copy)]
#[repr(transparent)]
pub(super) struct YM8(__m256);

/// Per-lane axis (x = 0, y = 1, z = 2) as two masks, as `Axis4`.
#[derive(Clone, Copy)]
pub(super) struct AxisY {
    is_x: YM8,
    is_y: YM8,
}

impl Y8 {
    // Bit casts (see `z16`).
    #[inline(always)]
    fn from_array(a: [f32; 8]) -> Y8 {
        // SAFETY: `[f32; 8]` and `__m256` are 32 plain bytes, every bit
        // pattern valid in both.
        Y8(unsafe { core::mem::transmute::<[f32; 8], __m256>(a) })
    }
    #[inline(always)]
    fn to_array(self) -> [f32; 8] {
        // SAFETY: as `from_array`.
        unsafe { core::mem::transmute::<__m256, [f32; 8]>(self.0) }
    }
}

macro_rules! arith {
    ($Tr:ident, $f:ident, $op:ident) => {
        impl $Tr for Y8 {
            type Output = Y8;
            #[inline(always)]
            fn $f(self, o: Y8) -> Y8 {
                // SAFETY: AVX2 is usable wherever a Y8 exists (module docs).
                Y8(unsafe { $op(self.0, o.0) })
            }
        }
    };
}
arith!(Add, add, _mm256_add_ps);
arith!(Sub, sub, _mm256_sub_ps);
arith!(Mul, mul, _mm256_mul_ps);
arith!(Div, div, _mm256_div_ps);

impl Neg for Y8 {
    type Output = Y8;
    #[inline(always)]
    fn neg(self) -> Y8 {
        // SAFETY: as above. Flipping the sign bit is scalar `-x`.
        Y8(unsafe { _mm256_xor_ps(self.0, _mm256_set1_ps(-0.0)) })
    }
}

impl BitAnd for YM8 {
    type Output = YM8;
    #[inline(always)]
    fn bitand(self, o: YM8) -> YM8 {
        // SAFETY: AVX2 is usable wherever a mask exists (module docs).
        YM8(unsafe { _mm256_and_ps(self.0, o.0) })
    }
}
impl BitOr for YM8 {
    type Output = YM8;
    #[inline(always)]
    fn bitor(self, o: YM8) -> YM8 {
        // SAFETY: as `bitand`.
        YM8(unsafe { _mm256_or_ps(self.0, o.0) })
    }
}
impl Not for YM8 {
    type Output = YM8;
    #[inline(always)]
    fn not(self) -> YM8 {
        // SAFETY: as `bitand`. All-ones xor: the complement of each lane.
        YM8(unsafe { _mm256_xor_ps(self.0, _mm256_castsi256_ps(_mm256_set1_epi32(-1))) })
    }
}

impl Lane for Y8 {
    type Mask = YM8;
    type Axis = AxisY;
    #[inline(always)]
    fn splat(x: f32) -> Y8 {
        // SAFETY: AVX2 is usable wherever a Y8 exists (module docs).
        Y8(unsafe { _mm256_set1_ps(x) })
    }
    #[inline(always)]
    fn lt(self, o: Y8) -> YM8 {
        // SAFETY: as `splat`. Ordered, quiet: false on NaN, as `<`.
        YM8(unsafe { _mm256_cmp_ps::<_CMP_LT_OQ>(self.0, o.0) })
    }
    #[inline(always)]
    fn le(self, o: Y8) -> YM8 {
        // SAFETY: as `splat`.
        YM8(unsafe { _mm256_cmp_ps::<_CMP_LE_OQ>(self.0, o.0) })
    }
    #[inline(always)]
    fn eq(self, o: Y8) -> YM8 {
        // SAFETY: as `splat`.
        YM8(unsafe { _mm256_cmp_ps::<_CMP_EQ_OQ>(self.0, o.0) })
    }
    #[inline(always)]
    fn select(m: YM8, a: Y8, b: Y8) -> Y8 {
        // SAFETY: as `splat`. The blend takes its second operand where the
        // mask lane's sign bit is set (every bit, for these masks).
        Y8(unsafe { _mm256_blendv_ps(b.0, a.0, m.0) })
    }
    #[inline(always)]
    fn any(m: YM8) -> bool {
        Y8::mask_bits(m) != 0
    }
    #[inline(always)]
    fn pick(v: [Y8; 3], axis: AxisY) -> Y8 {
        Y8::select(axis.is_x, v[0], Y8::select(axis.is_y, v[1], v[2]))
    }
    #[inline(always)]
    fn get(self, i: usize) -> f32 {
        debug_assert!(i < 8);
        // SAFETY: as `splat`; a lane move (see `z16::Z16::get`), index mod 8.
        unsafe {
            _mm256_cvtss_f32(_mm256_permutevar8x32_ps(
                self.0,
                _mm256_set1_epi32(i as i32),
            ))
        }
    }
    #[inline(always)]
    fn set(&mut self, i: usize, x: f32) {
        let mut a = self.to_array();
        a[i] = x;
        *self = Y8::from_array(a);
    }
    #[inline(always)]
    fn mask_get(m: YM8, i: usize) -> bool {
        Y8::mask_bits(m) >> i & 1 != 0
    }
    #[inline]
    fn shear_axes(d: [Y8; 3]) -> ([AxisY; 3], [Y8; 3]) {
        shear_by_quads(d)
    }
    const WIDTH: usize = 8;
}

/// `fold_index` at block sizes 1, 2 and 4 (first and second halves),
/// modulo 8: each half of the result is permuted out of one source.
const FOLD8: [[[i32; 8]; 2]; 3] = {
    let mut t = [[[0; 8]; 2]; 3];
    let mut k = 0;
    while k < 3 {
        let (x, y) = (
            fold_index::<8>(1 << k, false),
            fold_index::<8>(1 << k, true),
        );
        let mut i = 0;
        while i < 8 {
            t[k][0][i] = x[i] % 8;
            t[k][1][i] = y[i] % 8;
            i += 1;
        }
        k += 1;
    }
    t
};

impl Wide for Y8 {
    const G: usize = 2;
    #[inline(always)]
    fn join(q: impl Fn(usize) -> F4) -> Y8 {
        // Register inserts, not two 16-byte stores read back as one
        // 32-byte load (`Z16::join`).
        // SAFETY: as `splat`; one 128-bit pair made one register.
        Y8(unsafe { _mm256_set_m128(super::f4_to_m128(q(1)), super::f4_to_m128(q(0))) })
    }
    #[inline(always)]
    fn quad(self, k: usize) -> F4 {
        debug_assert!(k < 2);
        // SAFETY: as `splat`; one 128-bit extract.
        super::m128_to_f4(unsafe {
            if k == 0 {
                _mm256_castps256_ps128(self.0)
            } else {
                _mm256_extractf128_ps::<1>(self.0)
            }
        })
    }
    #[inline(always)]
    fn mask_from_bits(bits: u32) -> YM8 {
        // SAFETY: as `splat`. Lane i: all ones when bit i is set.
        YM8(unsafe {
            let lane = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
            let b = _mm256_and_si256(_mm256_set1_epi32(bits as i32), lane);
            _mm256_castsi256_ps(_mm256_cmpeq_epi32(b, lane))
        })
    }
    #[inline(always)]
    fn mask_bits(m: YM8) -> u32 {
        // SAFETY: as `splat`.
        unsafe { _mm256_movemask_ps(m.0) as u32 }
    }
    #[inline(always)]
    fn join_axis(a: impl Fn(usize) -> Axis4) -> AxisY {
        let (mut bx, mut by) = (0u32, 0u32);
        for k in 0..2 {
            let ak = a(k);
            bx |= ak.is_x.bitmask() << (4 * k);
            by |= ak.is_y.bitmask() << (4 * k);
        }
        AxisY {
            is_x: Y8::mask_from_bits(bx),
            is_y: Y8::mask_from_bits(by),
        }
    }
    #[inline(always)]
    fn raise(self, o: Y8) -> Y8 {
        // SAFETY: as `splat`. `maxps(o, x)` is `o > x ? o : x` lane by lane.
        Y8(unsafe { _mm256_max_ps(o.0, self.0) })
    }
    #[inline(always)]
    fn lower(self, o: Y8) -> Y8 {
        // SAFETY: as `splat`. `minps(o, x)` is `o < x ? o : x` lane by lane.
        Y8(unsafe { _mm256_min_ps(o.0, self.0) })
    }
    #[inline(always)]
    fn fold_pairs<const MAX: bool>(self, o: Y8, b: usize) -> Y8 {
        let k = b.trailing_zeros() as usize;
        // SAFETY: as `splat`; the index tables are 8 i32 each, read
        // unaligned. Lanes 0..4 come from `self`, 4..8 from `o` (the
        // tables' indices modulo 8 within each); min/max as `lower`/`raise`.
        Y8(unsafe {
            let ix = _mm256_loadu_si256(FOLD8[k][0].as_ptr().cast());
            let iy = _mm256_loadu_si256(FOLD8[k][1].as_ptr().cast());
            let x = _mm256_blend_ps::<0xf0>(
                _mm256_permutevar8x32_ps(self.0, ix),
                _mm256_permutevar8x32_ps(o.0, ix),
            );
            let y = _mm256_blend_ps::<0xf0>(
                _mm256_permutevar8x32_ps(self.0, iy),
                _mm256_permutevar8x32_ps(o.0, iy),
            );
            if MAX {
                _mm256_max_ps(y, x)
            } else {
                _mm256_min_ps(y, x)
            }
        })
    }
    #[inline(always)]
    fn le_bits(self, o: Y8) -> u32 {
        Y8::mask_bits(self.le(o))
    }
}

// The scratch budgets are sized with `F8`: a `Y8` must fit its slots.
const _: () = {
    assert!(core::mem::size_of::<Y8>() == core::mem::size_of::<crate::geom::F8>());
    assert!(core::mem::align_of::<Y8>() == core::mem::align_of::<crate::geom::F8>());
    assert!(core::mem::size_of::<YM8>() <= core::mem::size_of::<[u32; 8]>());
};

#[cfg(test)]
mod tests {
    /// Every `Lane` and `Wide` operation of `Y8` gives `F8`'s bits.
    #[test]
    fn same_as_f8() {
        if !super::super::cpu_avx2::get() {
            eprintln!("no AVX2 on this CPU: Y8 not checked here");
            return;
        }
        super::super::same_ops::check::<super::Y8, crate::geom::F8>();
    }
}
