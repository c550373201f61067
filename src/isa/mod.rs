//! Instruction-set levels and runtime dispatch: which lane width a packet
//! traversal runs at (`F4`: one 2x2 quad per operation, SSE2 on x86-64;
//! `F8`: two quads, AVX2; `F16`: four quads, AVX-512), chosen once per
//! call from what the CPU supports (CPUID and XGETBV through the
//! `cpufeatures` crate, which works without std), what the caller asks for
//! (`TraceParams::isa`, as Embree's `isa=` device setting) and, for
//! `Isa::Auto`, the `SHEAF_ISA` environment variable (std builds; read once,
//! when the first context is created, like Embree's `max_isa=`).
//!
//! A packet traversal implements `LaneFn` (generic over the lane type,
//! `#[inline(always)]`); `Chosen::new` picks its instance inside a function
//! compiled with `avx2` or `avx512f` enabled, so the whole traversal is
//! compiled for that level and each wide-lane loop becomes one
//! instruction. A trace call chooses once (`accel::packet::Kernel`) and
//! calls the chosen pointer per packet. `fma` is never
//! enabled: results are bitwise equal at every level (`geom::wide`).
//!
//! On x86-64 the AVX-512 level runs on `Z16` (`z16`: one `__m512` register
//! per lane group, compares into mask registers) and the AVX2 level on `Y8`
//! (`y8`); the emulated levels and 32-bit x86 on the portable `F16`, `F8`.
//!
//! This is one of the crate's small unsafe modules: calling a
//! `#[target_feature]` function needs `unsafe`, and the one obligation (the
//! CPU has the feature) is checked when `Chosen::new` takes its pointer;
//! `y8`'s and `z16`'s intrinsics rest on the same check.
#![allow(unsafe_code)] // the pointer call in `Chosen::call`, `y8` and `z16`, each block with a SAFETY comment

use crate::error::{Error, Result};
use crate::geom::F4;
use crate::geom::wide::Wide;
use core::sync::atomic::{AtomicBool, AtomicU8, Ordering};

/// Lane width of packet traversals (C: `sheaf_isa`). Ordered: a higher
/// level is wider.
#[repr(u32)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Isa {
    /// The widest level the CPU supports, capped by `SHEAF_ISA` when set.
    #[default]
    Auto = 0,
    /// 4 lanes (one 2x2 quad): SSE2 on x86-64; glam's backend (NEON,
    /// scalar) on other architectures.
    Sse2 = 1,
    /// 8 lanes (two quads), x86 with AVX2.
    Avx2 = 2,
    /// 16 lanes (four quads), x86 with AVX-512F.
    Avx512 = 3,
}

impl Isa {
    pub const ALL: &'static [Isa] = &[Isa::Auto, Isa::Sse2, Isa::Avx2, Isa::Avx512];

    /// The name `SHEAF_ISA` and the CLI use.
    pub const fn name(self) -> &'static str {
        match self {
            Isa::Auto => "auto",
            Isa::Sse2 => "sse2",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }

    /// Parse a name (`auto`, `sse2`, `avx2`, `avx512`; case-insensitive).
    pub fn parse(s: &str) -> Option<Isa> {
        Isa::ALL
            .iter()
            .copied()
            .find(|i| s.trim().eq_ignore_ascii_case(i.name()))
            .or_else(|| {
                s.trim()
                    .eq_ignore_ascii_case("avx512f")
                    .then_some(Isa::Avx512)
            })
    }

    /// Lanes per operation of packet traversals at this level (`Auto`: the
    /// level `resolve` picks).
    pub fn lanes(self) -> usize {
        match effective(self) {
            Isa::Avx512 => 16,
            Isa::Avx2 => 8,
            _ => 4,
        }
    }
}

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
cpufeatures::new!(cpu_avx2, "avx2");
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
cpufeatures::new!(cpu_avx512, "avx512f");

/// The widest level this CPU (and its OS) supports.
pub fn detected() -> Isa {
    #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
    {
        if cpu_avx512::get() {
            return Isa::Avx512;
        }
        if cpu_avx2::get() {
            return Isa::Avx2;
        }
    }
    Isa::Sse2
}

/// `SHEAF_ISA`'s cap on `Auto` (0: not read yet).
static ENV_CAP: AtomicU8 = AtomicU8::new(0);

/// Read `SHEAF_ISA` (once per process; std builds). Contexts call this at
/// creation, so no trace call pays for reading the environment (which
/// allocates the value's copy when the variable is set). An unset, empty,
/// `auto` or unknown value leaves `Auto` at the CPU's widest level.
pub fn read_env() {
    if ENV_CAP.load(Ordering::Relaxed) != 0 {
        return;
    }
    #[cfg(feature = "std")]
    let cap = std::env::var("SHEAF_ISA")
        .ok()
        .and_then(|v| Isa::parse(&v))
        .filter(|&i| i != Isa::Auto)
        .unwrap_or(Isa::Avx512);
    #[cfg(not(feature = "std"))]
    let cap = Isa::Avx512;
    ENV_CAP.store(cap as u8, Ordering::Relaxed);
}

/// `SHEAF_ISA`'s cap (the widest level when unset; without std, always).
/// Read here when no context has read it yet (callers of the traversals
/// that never create a context: tests, studies).
pub fn env_cap() -> Isa {
    read_env();
    match ENV_CAP.load(Ordering::Relaxed) {
        1 => Isa::Sse2,
        2 => Isa::Avx2,
        _ => Isa::Avx512,
    }
}

/// The level a call asking for `req` runs at: `Auto` is the CPU's widest
/// capped by `SHEAF_ISA`; a forced level must be supported
/// (`Error::InvalidArgument` otherwise).
pub fn resolve(req: Isa) -> Result<Isa> {
    match req {
        Isa::Auto => Ok(detected().min(env_cap())),
        r if r <= detected() || (EMULATE.load(Ordering::Relaxed) && emulated(r)) => Ok(r),
        _ => Err(Error::InvalidArgument(
            "TraceParams::isa: this CPU does not support that instruction set",
        )),
    }
}

/// `resolve` without the error, for the traversals: never above what the
/// CPU supports.
#[inline]
pub fn effective(req: Isa) -> Isa {
    match req {
        Isa::Auto => detected().min(env_cap()),
        r => r.min(detected()),
    }
}

/// Tests only: forced levels above the CPU's run their lane width in
/// baseline code (each wide operation as 4-wide ones) instead of being
/// rejected, so the exactness suites run every width's traversal logic on
/// any machine. Process-wide. Only the levels the build machine lacks are
/// compiled for emulation (`emulated`; the build script).
#[doc(hidden)]
pub fn set_emulation(on: bool) {
    EMULATE.store(on, Ordering::Relaxed);
}

static EMULATE: AtomicBool = AtomicBool::new(false);

/// Whether `level` can run emulated (`set_emulation`): compiled only for
/// the levels the build machine does not run natively, all of them when
/// cross-compiling or with `SHEAF_EMULATE=all` (the build script's cfgs),
/// since a level the machine has never runs emulated on it.
pub const fn emulated(level: Isa) -> bool {
    match level {
        Isa::Avx2 => cfg!(sheaf_emulate_avx2),
        Isa::Avx512 => cfg!(sheaf_emulate_avx512),
        _ => false,
    }
}

/// The signature of a family of lane functions (`LaneFn`): their
/// arguments, one tuple, and their result. What a `Chosen` stores.
pub trait Sig {
    type Args<'a>
    where
        Self: 'a;
    type Out;
}

/// A lane-generic function of signature `S`: `call::<W>(args)`, a
/// traversal at one lane width. A marker type per traversal implements it
/// (mark `call` `#[inline(always)]`, and everything it calls down to the
/// hot loop, so all of it is compiled inside the level's function).
pub trait LaneFn<S: Sig> {
    fn call<W: Wide>(args: S::Args<'_>) -> S::Out;
}

/// `S::Args<'a>` with its lifetime in plain sight, so a function taking
/// it has a late-bound lifetime and coerces to `Chosen`'s pointer type.
pub struct ArgsOf<'a, S: Sig + 'a>(S::Args<'a>);

/// A `LaneFn` at a lane width chosen once (`new`), called many times
/// (`call`): a pointer to its instance inside the level's function.
/// Calls choose their traversal and width with it once, then call it
/// per packet.
pub struct Chosen<S: Sig> {
    f: for<'a> unsafe fn(ArgsOf<'a, S>) -> S::Out,
}

impl<S: Sig> Clone for Chosen<S> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<S: Sig> Copy for Chosen<S> {}

impl<S: Sig> Chosen<S> {
    /// `F` at level `effective(isa)`: on `Z16` lanes in a function
    /// compiled for AVX-512F, `Y8` in one for AVX2 (`F16`, `F8` on 32-bit
    /// x86), else `F4`; emulated levels on `F16`, `F8` in baseline code.
    ///
    /// The crate's own unit tests (`cfg(test)`) compile every traversal on
    /// `F4` only, whatever `isa` says: the library is compiled twice by
    /// `cargo test`, and its wide instances were half the unit tests'
    /// compile time. Every width is checked bitwise against the single ray
    /// by the integration suites (`tests/exact`, `cli/stress`), which link
    /// the library as it ships.
    pub fn new<F: LaneFn<S>>(isa: Isa) -> Self {
        #[cfg(test)]
        {
            let _ = isa;
            Self::baseline::<F>()
        }
        #[cfg(not(test))]
        Self::widest::<F>(isa)
    }

    #[cfg(not(test))]
    fn widest<F: LaneFn<S>>(isa: Isa) -> Self {
        if isa > detected() && EMULATE.load(Ordering::Relaxed) {
            match isa {
                #[cfg(sheaf_emulate_avx512)]
                Isa::Avx512 => {
                    return Chosen {
                        f: baseline::<S, F, crate::geom::F16>,
                    };
                }
                #[cfg(sheaf_emulate_avx2)]
                Isa::Avx2 => {
                    return Chosen {
                        f: baseline::<S, F, crate::geom::F8>,
                    };
                }
                // Not compiled for emulation (`emulated`): `resolve` refuses
                // it, and the traversals run the CPU's widest level.
                _ => {}
            }
        }
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        match effective(isa) {
            Isa::Avx512 => {
                return Chosen {
                    f: x86::avx512::<S, F>,
                };
            }
            Isa::Avx2 => {
                return Chosen {
                    f: x86::avx2::<S, F>,
                };
            }
            _ => {}
        }
        #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
        let _ = isa;
        Self::baseline::<F>()
    }

    /// `F` on `F4` lanes in baseline code: for traversals without wide
    /// lanes (single rays lane by lane, the 2x2 SIMD ray).
    pub fn baseline<F: LaneFn<S>>() -> Self {
        Chosen {
            f: baseline::<S, F, F4>,
        }
    }

    /// Call the chosen function.
    #[inline(always)]
    pub fn call(&self, args: S::Args<'_>) -> S::Out {
        // SAFETY: `new` stores a function compiled for AVX2 or AVX-512F
        // only when `effective` returns that level, i.e. when CPUID and
        // XGETBV report it usable; every other pointer is baseline code.
        unsafe { (self.f)(ArgsOf(args)) }
    }
}

/// `F` on `W` lanes in baseline code (`Chosen`).
///
/// # Safety
/// None: `unsafe` only for the pointer type `Chosen` stores.
unsafe fn baseline<S: Sig, F: LaneFn<S>, W: Wide>(a: ArgsOf<'_, S>) -> S::Out {
    F::call::<W>(a.0)
}

/// `F::call(args)` at level `effective(isa)` (`Chosen`), for a call that
/// runs one traversal once.
#[inline]
pub fn run_fn<S: Sig, F: LaneFn<S>>(isa: Isa, args: S::Args<'_>) -> S::Out {
    Chosen::<S>::new::<F>(isa).call(args)
}

#[cfg(target_arch = "x86_64")]
mod y8;

/// A 128-bit register as glam's `Vec4` (by value, so also with glam's
/// scalar backend, whose `Vec4` is not an `__m128`): `y8`'s and `z16`'s
/// quad extracts.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn m128_to_f4(x: core::arch::x86_64::__m128) -> F4 {
    // SAFETY: `__m128` and `[f32; 4]` are 16 plain bytes, every bit
    // pattern valid in both.
    F4::from_array(unsafe { core::mem::transmute::<core::arch::x86_64::__m128, [f32; 4]>(x) })
}
/// `F4` as `__m128` (the inverse of `m128_to_f4`; no instruction when
/// `F4` is an SSE register).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn f4_to_m128(x: F4) -> core::arch::x86_64::__m128 {
    // SAFETY: as `m128_to_f4`.
    unsafe { core::mem::transmute::<[f32; 4], core::arch::x86_64::__m128>(x.to_array()) }
}
#[cfg(target_arch = "x86_64")]
mod z16;

// Not in the unit tests: they run every traversal on `F4` (`Chosen::new`).
#[cfg(all(any(target_arch = "x86", target_arch = "x86_64"), not(test)))]
mod x86 {
    use super::{ArgsOf, LaneFn, Sig};

    /// `F` on `Y8` lanes (intrinsics; `y8` module docs), the only place a
    /// `Y8` is created.
    ///
    /// # Safety
    /// The CPU supports AVX2 (`Chosen::new`).
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn avx2<S: Sig, F: LaneFn<S>>(a: ArgsOf<'_, S>) -> S::Out {
        #[cfg(target_arch = "x86_64")]
        return F::call::<super::y8::Y8>(a.0);
        #[cfg(not(target_arch = "x86_64"))]
        return F::call::<crate::geom::F8>(a.0);
    }

    /// `F` on `Z16` lanes (intrinsics; `z16` module docs), the only place
    /// a `Z16` is created.
    ///
    /// # Safety
    /// The CPU supports AVX-512F (`Chosen::new`).
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn avx512<S: Sig, F: LaneFn<S>>(a: ArgsOf<'_, S>) -> S::Out {
        #[cfg(target_arch = "x86_64")]
        return F::call::<super::z16::Z16>(a.0);
        #[cfg(not(target_arch = "x86_64"))]
        return F::call::<crate::geom::F16>(a.0);
    }
}

/// Tests of `y8` and `z16`: a register lane type against its portable
/// twin, operation by operation.
#[cfg(all(test, target_arch = "x86_64"))]
mod same_ops {
    use crate::geom::lane::F4;
    use crate::geom::wide::Wide;

    /// Deterministic lanes with signs, zeros, infinities and NaN.
    fn lanes(seed: u32, n: usize) -> [f32; 16] {
        let mut s = seed;
        core::array::from_fn(|i| {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            match s % 23 {
                _ if i >= n => 0.0,
                0 => 0.0,
                1 => -0.0,
                2 => f32::INFINITY,
                3 => f32::NEG_INFINITY,
                4 => f32::NAN,
                5 => -f32::NAN,
                6 => f32::from_bits(s >> 9), // subnormals and small normals
                7 => f32::MAX,
                _ => ((s >> 8) as f32 / (1u32 << 24) as f32 - 0.5) * 8.0,
            }
        })
    }

    fn join<W: Wide>(v: &[f32; 16]) -> W {
        W::join(|k| F4::from_slice(&v[4 * k..4 * k + 4]))
    }

    /// Every `Lane` and `Wide` operation of `A` gives `B`'s bits (`A` and
    /// `B` of one width).
    pub(super) fn check<A: Wide, B: Wide>() {
        assert_eq!(A::WIDTH, B::WIDTH);
        let n = A::WIDTH;
        let full = (1u32 << n) - 1;
        for seed in 0..500 {
            let (a, b) = (lanes(seed, n), lanes(seed ^ 0x9e37_79b9, n));
            let (xa, ya): (A, A) = (join(&a), join(&b));
            let (xb, yb): (B, B) = (join(&a), join(&b));
            let same = |x: A, y: B| {
                for i in 0..n {
                    assert_eq!(
                        x.get(i).to_bits(),
                        y.get(i).to_bits(),
                        "seed {seed} lane {i}"
                    );
                }
            };
            same(xa, xb);
            same(xa + ya, xb + yb);
            same(xa - ya, xb - yb);
            same(xa * ya, xb * yb);
            same(xa / ya, xb / yb);
            same(-xa, -xb);
            same(xa.raise(ya), xb.raise(yb));
            same(xa.lower(ya), xb.lower(yb));
            let mut b_ = 1;
            while b_ < n {
                same(
                    xa.fold_pairs::<false>(ya, b_),
                    xb.fold_pairs::<false>(yb, b_),
                );
                same(xa.fold_pairs::<true>(ya, b_), xb.fold_pairs::<true>(yb, b_));
                b_ *= 2;
            }
            let ma = [xa.lt(ya), xa.le(ya), xa.eq(ya)];
            let mb = [xb.lt(yb), xb.le(yb), xb.eq(yb)];
            for (p, q) in ma.iter().zip(&mb) {
                let bits = |m: A::Mask| A::mask_bits(m) & full;
                assert_eq!(bits(*p), B::mask_bits(*q) & full, "seed {seed}");
                assert_eq!(bits(!*p), B::mask_bits(!*q) & full);
                assert_eq!(bits(*p & ma[0]), B::mask_bits(*q & mb[0]) & full);
                assert_eq!(bits(*p | ma[2]), B::mask_bits(*q | mb[2]) & full);
                assert_eq!(A::any(*p), B::any(*q));
                same(A::select(*p, xa, ya), B::select(*q, xb, yb));
                for i in 0..n {
                    assert_eq!(A::mask_get(*p, i), B::mask_get(*q, i));
                }
            }
            assert_eq!(xa.le_bits(ya), xb.le_bits(yb));
            // Masks made from bits (bits above the width ignored).
            let m = seed.wrapping_mul(2_654_435_761);
            let (pa, pb) = (A::mask_from_bits(m), B::mask_from_bits(m));
            assert_eq!(A::mask_bits(pa), m & full);
            assert_eq!(A::mask_bits(pa), B::mask_bits(pb));
            assert_eq!(A::mask_bits(!pa) & full, B::mask_bits(!pb) & full);
            assert_eq!(A::any(pa), B::any(pb));
            same(A::select(pa, xa, ya), B::select(pb, xb, yb));
            same(A::select(!pa, xa, ya), B::select(!pb, xb, yb));
            let i = seed as usize % n;
            assert_eq!(A::mask_get(pa, i), B::mask_get(pb, i));
            same(A::splat(a[i]), B::splat(a[i]));
            let (mut xs, mut ys) = (xa, xb);
            xs.set(i, b[i]);
            ys.set(i, b[i]);
            same(xs, ys);
            let axis = |k: usize| {
                let c =
                    |v: u32| crate::geom::lane::mask_from_bits(m.rotate_right(v + 4 * k as u32));
                crate::geom::lane::Axis4 {
                    is_x: c(0),
                    is_y: c(7) & !c(0),
                }
            };
            same(
                A::pick([xa, ya, -xa], A::join_axis(axis)),
                B::pick([xb, yb, -xb], B::join_axis(axis)),
            );
            for k in 0..A::G {
                let q = |x: F4| x.to_array().map(f32::to_bits);
                assert_eq!(q(xa.quad(k)), q(xb.quad(k)));
            }
            let (ka, sa) = A::shear_axes([xa, ya, xa * ya]);
            let (kb, sb) = B::shear_axes([xb, yb, xb * yb]);
            for j in 0..3 {
                same(sa[j], sb[j]);
                same(A::pick([xa, ya, -xa], ka[j]), B::pick([xb, yb, -xb], kb[j]));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for &i in Isa::ALL {
            assert_eq!(Isa::parse(i.name()), Some(i));
        }
        assert_eq!(Isa::parse(" AVX512F "), Some(Isa::Avx512));
        assert_eq!(Isa::parse("neon"), None);
    }

    #[test]
    fn forced_levels_are_checked() {
        assert_eq!(resolve(Isa::Sse2), Ok(Isa::Sse2));
        assert!(resolve(Isa::Auto).unwrap() <= detected());
        for &i in &Isa::ALL[1..] {
            assert_eq!(resolve(i).is_ok(), i <= detected());
            assert!(effective(i) <= detected());
        }
    }
}
