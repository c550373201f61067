//! `Z16`: the AVX-512 level's lane type, sixteen f32 lanes in one `__m512`
//! register with masks in a mask register (`__mmask16`), so a compare
//! yields its lane bits directly and a select is one blend.
//!
//! `geom::wide::F16` states the same lanes as plain arrays. LLVM turns its
//! arithmetic into zmm instructions, but not its mask-to-bits reductions:
//! each `mask_bits` / `le_bits` became a chain of about ten shuffles and
//! ors (8% of the frustum walk's samples on crytek sponza;
//! docs/studies/lane-widths.md, "Lanes in registers"), and it split some slab tests into scalar lanes to
//! feed them. `Z16` is what `isa::Chosen` instantiates inside its `avx512f`
//! function; `F16` stays for the emulated level (`set_emulation`) on
//! machines without AVX-512.
//!
//! # Exactness
//! Every operation is the IEEE operation of `F16`'s lane loop: `vaddps`,
//! `vsubps`, `vmulps`, `vdivps` (round to nearest, no FMA), ordered
//! compares, `vmaxps`/`vminps` for `raise`/`lower` (`o > x ? o : x`, which is
//! `maxps(o, x)` exactly, NaN in `o` not taken), a sign-bit xor for `-x`.
//! `same_as_f16` (`isa::same_ops`) checks each against `F16` bitwise.
//!
//! # Safety
//! This module's `unsafe` blocks call AVX-512F intrinsics (and bit casts).
//! They are sound because the only way to obtain a `Z16` is to be handed
//! one inside `x86::avx512` (the type is private to `isa`; a `Kernel` sees
//! it only as its generic lane type), which `run` calls only after
//! `detected()` reported AVX-512F usable (CPUID and XGETBV); CPU features
//! do not change within a process, so a value that escaped the call would
//! still run on a CPU that has them. The emulated level uses `F16`. The
//! methods are `#[inline(always)]`: inlined into the `avx512f` function,
//! the intrinsics become single instructions (a kernel helper that is not
//! inlined there would call them out of line: slower, still correct).
#![allow(unsafe_code)] // AVX-512F intrinsics; see the module's Safety section

use crate::geom::lane::{Axis4, F4, Lane};
use crate::geom::wide::{Wide, fold_index, shear_by_quads};
use core::arch::x86_64::*;
use core::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// Sixteen f32 lanes: four 2x2 quads, lanes `4k..4k+4` quad `k`.
#[derive(Clone, Copy)]
#[repr(transparent)]
pub(super) struct Z16(__m512);

/// Sixteen lane masks, bit `i` lane `i`.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) struct K16(u16);

/// Per-lane axis (x = 0, y = 1, z = 2) as two masks, as `Axis4`.
#[derive(Clone, Copy)]
pub(super) struct AxisZ {
    is_x: K16,
    is_y: K16,
}

impl Z16 {
    // Bit casts, no instruction of their own: a kernel reads lanes of
    // values in memory (a group's first ray), so these must not depend on
    // being inlined into the `avx512f` function.
    #[inline(always)]
    fn from_array(a: [f32; 16]) -> Z16 {
        // SAFETY: `[f32; 16]` and `__m512` are 64 plain bytes, every bit
        // pattern valid in both.
        Z16(unsafe { core::mem::transmute::<[f32; 16], __m512>(a) })
    }
    #[inline(always)]
    fn to_array(self) -> [f32; 16] {
        // SAFETY: as `from_array`.
        unsafe { core::mem::transmute::<__m512, [f32; 16]>(self.0) }
    }
}

macro_rules! arith {
    ($Tr:ident, $f:ident, $op:ident) => {
        impl $Tr for Z16 {
            type Output = Z16;
            #[inline(always)]
            fn $f(self, o: Z16) -> Z16 {
                // SAFETY: AVX-512F is usable wherever a Z16 exists (module docs).
                Z16(unsafe { $op(self.0, o.0) })
            }
        }
    };
}
arith!(Add, add, _mm512_add_ps);
arith!(Sub, sub, _mm512_sub_ps);
arith!(Mul, mul, _mm512_mul_ps);
arith!(Div, div, _mm512_div_ps);

impl Neg for Z16 {
    type Output = Z16;
    #[inline(always)]
    fn neg(self) -> Z16 {
        // SAFETY: AVX-512F is usable wherever a Z16 exists (module docs).
        // Flipping the sign bit is what scalar `-x` does, NaN included.
        Z16(unsafe {
            _mm512_castsi512_ps(_mm512_xor_si512(
                _mm512_castps_si512(self.0),
                _mm512_set1_epi32(i32::MIN),
            ))
        })
    }
}

impl BitAnd for K16 {
    type Output = K16;
    #[inline(always)]
    fn bitand(self, o: K16) -> K16 {
        K16(self.0 & o.0)
    }
}
impl BitOr for K16 {
    type Output = K16;
    #[inline(always)]
    fn bitor(self, o: K16) -> K16 {
        K16(self.0 | o.0)
    }
}
impl Not for K16 {
    type Output = K16;
    #[inline(always)]
    fn not(self) -> K16 {
        K16(!self.0)
    }
}

impl Lane for Z16 {
    type Mask = K16;
    type Axis = AxisZ;
    #[inline(always)]
    fn splat(x: f32) -> Z16 {
        // SAFETY: AVX-512F is usable wherever a Z16 exists (module docs).
        Z16(unsafe { _mm512_set1_ps(x) })
    }
    #[inline(always)]
    fn lt(self, o: Z16) -> K16 {
        // SAFETY: as `splat`. Ordered, quiet: false on NaN, as `<`.
        K16(unsafe { _mm512_cmp_ps_mask::<_CMP_LT_OQ>(self.0, o.0) })
    }
    #[inline(always)]
    fn le(self, o: Z16) -> K16 {
        // SAFETY: as `splat`.
        K16(unsafe { _mm512_cmp_ps_mask::<_CMP_LE_OQ>(self.0, o.0) })
    }
    #[inline(always)]
    fn eq(self, o: Z16) -> K16 {
        // SAFETY: as `splat`.
        K16(unsafe { _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(self.0, o.0) })
    }
    #[inline(always)]
    fn select(m: K16, a: Z16, b: Z16) -> Z16 {
        // SAFETY: as `splat`. The blend takes its second operand where the
        // mask is set.
        Z16(unsafe { _mm512_mask_blend_ps(m.0, b.0, a.0) })
    }
    #[inline(always)]
    fn any(m: K16) -> bool {
        m.0 != 0
    }
    #[inline(always)]
    fn pick(v: [Z16; 3], axis: AxisZ) -> Z16 {
        Z16::select(axis.is_x, v[0], Z16::select(axis.is_y, v[1], v[2]))
    }
    #[inline(always)]
    fn get(self, i: usize) -> f32 {
        debug_assert!(i < 16);
        // A lane move, not a store and a reload: a 64-byte store read back
        // in pieces misses store forwarding.
        // SAFETY: as `splat`. The index is taken mod 16 by the permute.
        unsafe { _mm512_cvtss_f32(_mm512_permutexvar_ps(_mm512_set1_epi32(i as i32), self.0)) }
    }
    #[inline(always)]
    fn set(&mut self, i: usize, x: f32) {
        let mut a = self.to_array();
        a[i] = x;
        *self = Z16::from_array(a);
    }
    #[inline(always)]
    fn mask_get(m: K16, i: usize) -> bool {
        debug_assert!(i < 16);
        m.0 >> i & 1 != 0
    }
    #[inline]
    fn shear_axes(d: [Z16; 3]) -> ([AxisZ; 3], [Z16; 3]) {
        shear_by_quads(d)
    }
    const WIDTH: usize = 16;
}

impl Wide for Z16 {
    const G: usize = 4;
    #[inline(always)]
    fn join(q: impl Fn(usize) -> F4) -> Z16 {
        // Register inserts, not four 16-byte stores read back as one
        // 64-byte load (which misses store forwarding: the setup's
        // joins of a camera packet cost 10% of its samples that way).
        let q = |k: usize| super::f4_to_m128(q(k));
        // SAFETY: as `splat`; a cast and three 128-bit inserts.
        Z16(unsafe {
            let v = _mm512_castps128_ps512(q(0));
            let v = _mm512_insertf32x4::<1>(v, q(1));
            let v = _mm512_insertf32x4::<2>(v, q(2));
            _mm512_insertf32x4::<3>(v, q(3))
        })
    }
    #[inline(always)]
    fn quad(self, k: usize) -> F4 {
        debug_assert!(k < 4);
        // SAFETY: as `splat`; one 128-bit extract (see `get`).
        super::m128_to_f4(unsafe {
            match k {
                0 => _mm512_castps512_ps128(self.0),
                1 => _mm512_extractf32x4_ps::<1>(self.0),
                2 => _mm512_extractf32x4_ps::<2>(self.0),
                _ => _mm512_extractf32x4_ps::<3>(self.0),
            }
        })
    }
    #[inline(always)]
    fn mask_from_bits(bits: u32) -> K16 {
        K16(bits as u16)
    }
    #[inline(always)]
    fn mask_bits(m: K16) -> u32 {
        u32::from(m.0)
    }
    #[inline(always)]
    fn join_axis(a: impl Fn(usize) -> Axis4) -> AxisZ {
        let (mut bx, mut by) = (0u32, 0u32);
        for k in 0..4 {
            let ak = a(k);
            bx |= ak.is_x.bitmask() << (4 * k);
            by |= ak.is_y.bitmask() << (4 * k);
        }
        AxisZ {
            is_x: K16(bx as u16),
            is_y: K16(by as u16),
        }
    }
    #[inline(always)]
    fn raise(self, o: Z16) -> Z16 {
        // SAFETY: as `splat`. `maxps(o, x)` is `o > x ? o : x` lane by lane.
        Z16(unsafe { _mm512_max_ps(o.0, self.0) })
    }
    #[inline(always)]
    fn lower(self, o: Z16) -> Z16 {
        // SAFETY: as `splat`. `minps(o, x)` is `o < x ? o : x` lane by lane.
        Z16(unsafe { _mm512_min_ps(o.0, self.0) })
    }
    #[inline(always)]
    fn le_bits(self, o: Z16) -> u32 {
        Z16::mask_bits(self.le(o))
    }
    #[inline(always)]
    fn fold_pairs<const MAX: bool>(self, o: Z16, b: usize) -> Z16 {
        let k = b.trailing_zeros() as usize;
        // SAFETY: as `splat`; the index tables are 16 i32 each, read
        // unaligned. `permutex2var` picks lanes of `self` (0..16) and `o`
        // (16..32); min/max as `lower`/`raise` (`y < x ? y : x`).
        Z16(unsafe {
            let ix = _mm512_loadu_si512(FOLD16[k][0].as_ptr().cast());
            let iy = _mm512_loadu_si512(FOLD16[k][1].as_ptr().cast());
            let x = _mm512_permutex2var_ps(self.0, ix, o.0);
            let y = _mm512_permutex2var_ps(self.0, iy, o.0);
            if MAX {
                _mm512_max_ps(y, x)
            } else {
                _mm512_min_ps(y, x)
            }
        })
    }
}

/// `fold_index` at block sizes 1, 2, 4 and 8 (first and second halves).
const FOLD16: [[[i32; 16]; 2]; 4] = {
    let mut t = [[[0; 16]; 2]; 4];
    let mut k = 0;
    while k < 4 {
        t[k] = [
            fold_index::<16>(1 << k, false),
            fold_index::<16>(1 << k, true),
        ];
        k += 1;
    }
    t
};

// The scratch budgets are sized with `F16`: a `Z16` must fit its slots.
const _: () = {
    assert!(core::mem::size_of::<Z16>() == core::mem::size_of::<crate::geom::F16>());
    assert!(core::mem::align_of::<Z16>() == core::mem::align_of::<crate::geom::F16>());
};

#[cfg(test)]
mod tests {
    /// Every `Lane` and `Wide` operation of `Z16` gives `F16`'s bits.
    #[test]
    fn same_as_f16() {
        if !super::super::cpu_avx512::get() {
            eprintln!("no AVX-512F on this CPU: Z16 not checked here");
            return;
        }
        super::super::same_ops::check::<super::Z16, crate::geom::F16>();
    }
}
