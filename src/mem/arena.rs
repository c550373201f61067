//! The arena: typed pools carved, once, out of one caller-provided byte buffer.
//!
//! Every pool starts on a 64-byte boundary (a cache line) and its size is
//! rounded up to 64 bytes, so the bytes a layout needs depend only on the
//! pool sizes, never on addresses: `required_bytes` is exact.
//! Casting bytes to typed slices goes through `bytemuck` (checked, safe).

use crate::error::{Error, Result};
use bytemuck::Pod;

/// Alignment of the buffer and of every pool.
pub const ARENA_ALIGN: usize = 64;

/// Bytes a pool of `n` values of `T` occupies in an arena.
pub const fn pool_bytes<T>(n: usize) -> usize {
    (n * core::mem::size_of::<T>()).div_ceil(ARENA_ALIGN) * ARENA_ALIGN
}

/// [`pool_bytes`] with every operation checked: None when the bytes of `n`
/// values, rounded up to 64, do not fit a `usize`.
#[deny(clippy::arithmetic_side_effects)]
pub const fn pool_bytes_checked<T>(n: usize) -> Option<usize> {
    match n.checked_mul(core::mem::size_of::<T>()) {
        Some(b) => match b.checked_next_multiple_of(ARENA_ALIGN) {
            Some(r) => Some(r),
            None => None,
        },
        None => None,
    }
}

/// The error of limits whose pools do not fit the address space.
pub const TOO_BIG: Error = Error::InvalidArgument("limits need more memory than can be addressed");

/// A pool size from a `Limits` rule (u64), `TOO_BIG` when it does not fit
/// a `usize` (32-bit targets).
pub fn entries(v: u64) -> Result<usize> {
    usize::try_from(v).map_err(|_| TOO_BIG)
}

/// `n`, or 0 when the pool's structure is left out of the limits.
#[inline]
pub const fn when(on: bool, n: usize) -> usize {
    if on { n } else { 0 }
}

/// Hands out disjoint, aligned, zeroed pools from one buffer.
pub struct Arena<'a> {
    rest: &'a mut [u8],
    used: usize,
}

impl<'a> Arena<'a> {
    /// Wrap `buf`, which must start on a 64-byte boundary.
    pub fn new(buf: &'a mut [u8]) -> Result<Self> {
        if !(buf.as_ptr() as usize).is_multiple_of(ARENA_ALIGN) {
            return Err(Error::Misaligned {
                required: ARENA_ALIGN as u32,
            });
        }
        Ok(Arena { rest: buf, used: 0 })
    }

    /// Bytes handed out so far (including padding).
    pub fn used(&self) -> usize {
        self.used
    }

    /// Bytes still available.
    pub fn remaining(&self) -> usize {
        self.rest.len()
    }

    /// A zeroed pool of `n` values. Fails (changing nothing) when the buffer
    /// is too small; `needed` counts this pool only.
    pub fn take<T: Pod>(&mut self, n: usize) -> Result<&'a mut [T]> {
        let bytes = pool_bytes_checked::<T>(n).unwrap_or(usize::MAX);
        if bytes > self.rest.len() {
            return Err(Error::BufferTooSmall {
                needed: (self.used as u64).saturating_add(bytes as u64),
                available: (self.used + self.rest.len()) as u64,
            });
        }
        let rest = core::mem::take(&mut self.rest);
        let (pool, rest) = rest.split_at_mut(bytes);
        self.rest = rest;
        self.used += bytes;
        pool.fill(0);
        let pool = &mut pool[..n * core::mem::size_of::<T>()];
        // Alignment holds by construction (64-aligned start, 64-multiple sizes,
        // align_of::<T>() <= 64): a failure here is a sheaf bug, reported as such.
        bytemuck::try_cast_slice_mut(pool).map_err(|_| Error::Misaligned {
            required: ARENA_ALIGN as u32,
        })
    }
}

/// Something pools are carved from: the `Arena` over a real buffer, or a
/// `Sizer` that only adds up their bytes. A context's layout is one
/// function over `Carve`, so the bytes it asks for (`required_bytes`) and
/// the pools it gets can never disagree.
pub trait Carve<'a> {
    /// A zeroed pool of `n` values (empty from a `Sizer`).
    fn take<T: Pod>(&mut self, n: usize) -> Result<&'a mut [T]>;
}

impl<'a> Carve<'a> for Arena<'a> {
    #[inline]
    fn take<T: Pod>(&mut self, n: usize) -> Result<&'a mut [T]> {
        Arena::take(self, n)
    }
}

/// Adds up the bytes of the pools a layout takes, with checked arithmetic:
/// `InvalidArgument` once the sum leaves `isize::MAX` (32-bit targets,
/// absurd limits).
#[derive(Clone, Copy, Debug, Default)]
pub struct Sizer {
    bytes: usize,
}

impl Sizer {
    /// Bytes of the pools taken so far (each rounded up to 64).
    pub fn bytes(&self) -> usize {
        self.bytes
    }
}

impl<'a> Carve<'a> for Sizer {
    #[deny(clippy::arithmetic_side_effects)]
    fn take<T: Pod>(&mut self, n: usize) -> Result<&'a mut [T]> {
        pool_bytes_checked::<T>(n)
            .and_then(|b| self.bytes.checked_add(b))
            .filter(|&b| b <= isize::MAX as usize)
            .map(|b| self.bytes = b)
            .ok_or(TOO_BIG)?;
        Ok(&mut [])
    }
}
