//! Parameter structs that carry their size (docs/c-api.md, "Upgrading"):
//! the versioning rule of the C ABI.
//!
//! Each of the nine parameter structs (`sheaf_limits` and the `*_params`)
//! begins with `uint32_t size`, which its `*_default` function sets to the
//! size of the struct the caller was compiled with (the header's macro
//! passes `sizeof`). A call reads the struct through [`read`]:
//! - the size of this library's struct: read as is;
//! - a smaller size at a field boundary (a program built against an older
//!   header, whose struct ends there): the fields it covers are read, the
//!   others take their defaults;
//! - a larger size (a newer header): read when every byte this library does
//!   not know is zero (a newer field left at its zero default), else
//!   refused, as is any other size.
//!
//! Fields are only ever appended, and no layout may have padding (a const
//! assertion per struct), so every older layout is a prefix of this one
//! and no byte of it is left undefined by a `*_default` function.

use super::check_non_null;
use crate::error::{Error, Result};

/// Largest size a newer header's struct may declare.
const MAX_BYTES: usize = 4096;

/// A parameter struct that begins with its `u32` size (declared with
/// [`versioned!`]).
pub(crate) trait Versioned: Copy {
    /// This library's defaults, `size` set to this struct's size.
    fn defaults() -> Self;
    /// The sizes of this struct's older layouts: the offset of each field
    /// after the first one following `size`.
    const PREFIXES: &'static [usize];
    /// The refusal of a size this library cannot read.
    const BAD_SIZE: &'static str;
    /// The refusal of a newer struct with fields this library does not know.
    const UNKNOWN_FIELDS: &'static str;
}

/// `size` of a struct as the caller declared it: its own `sizeof` (any
/// field boundary of this layout, or more) or refused.
fn check_size<T: Versioned>(size: usize) -> Result<()> {
    let full = core::mem::size_of::<T>();
    if size == full || T::PREFIXES.contains(&size) || (size > full && size <= MAX_BYTES) {
        Ok(())
    } else {
        Err(Error::InvalidArgument(T::BAD_SIZE))
    }
}

/// Read a parameter struct from C (NULL checked, any alignment): see the
/// module docs for the sizes it accepts.
pub(crate) fn read<T: Versioned>(p: *const T) -> Result<T> {
    check_non_null!(p);
    // SAFETY: non-NULL; the C contract is that a parameter struct begins
    // with its `uint32_t size`, readable whatever the struct's version.
    let size = unsafe { p.cast::<u32>().read_unaligned() } as usize;
    check_size::<T>(size)?;
    let full = core::mem::size_of::<T>();
    let mut v = T::defaults();
    let bytes = p.cast::<u8>();
    if size > full {
        // SAFETY: the caller's struct is `size` bytes long (its own
        // `sizeof`, set by its `*_default`), so `full..size` is readable.
        let tail = unsafe { core::slice::from_raw_parts(bytes.add(full), size - full) };
        if tail.iter().any(|&b| b != 0) {
            return Err(Error::InvalidArgument(T::UNKNOWN_FIELDS));
        }
    }
    // SAFETY: `min(size, full)` bytes are readable at `p` (the caller's
    // struct is `size` long) and fit in `v`; every prefix of `T` ends at a
    // field boundary with no padding, so the bytes copied make whole
    // fields, each valid for its type (the types of these structs accept
    // any bits but for the function pointer, an `Option` whose NULL is
    // `None`).
    unsafe {
        core::ptr::copy_nonoverlapping(bytes, (&mut v as *mut T).cast::<u8>(), size.min(full));
    }
    Ok(v)
}

/// Write `v` (its `size` replaced) to a caller's struct of `size` bytes:
/// the fields an older layout has, or this whole struct and zeros after it
/// for a newer one. Refuses sizes [`read`] would refuse.
pub(crate) fn write<T: Versioned>(out: *mut T, size: usize, v: T) -> Result<()> {
    check_non_null!(out);
    check_size::<T>(size)?;
    let full = core::mem::size_of::<T>();
    let mut v = v;
    // SAFETY: every parameter struct begins with its `u32` size (the
    // const assertion of `versioned!`).
    unsafe { (&mut v as *mut T).cast::<u32>().write(size as u32) };
    let bytes = out.cast::<u8>();
    // SAFETY: the caller's struct is `size` bytes long (the header's macro
    // passes its `sizeof`): `min(size, full)` bytes of `v` fit, and
    // `full..size` of a larger struct is writable; `v` has no padding, so
    // every byte copied is initialised.
    unsafe {
        core::ptr::copy_nonoverlapping((&v as *const T).cast::<u8>(), bytes, size.min(full));
        if size > full {
            core::ptr::write_bytes(bytes.add(full), 0, size - full);
        }
    }
    Ok(())
}

/// Declare a parameter struct [`Versioned`]: its name, the fields after
/// `size` in declaration order (the first is in every layout), and its
/// defaults. Asserts at compile time that `size` comes first and that the
/// fields leave no padding.
macro_rules! versioned {
    ($t:ident, [$first:ident $(, $f:ident)* $(,)?], $defaults:expr) => {
        impl $crate::ffi::sized::Versioned for $t {
            fn defaults() -> Self {
                let mut v: $t = $defaults;
                v.size = core::mem::size_of::<$t>() as u32;
                v
            }
            const PREFIXES: &'static [usize] = &[$(core::mem::offset_of!($t, $f)),*];
            const BAD_SIZE: &'static str = concat!(
                stringify!($t),
                ".size is not the size of any version of the struct: start from ",
                stringify!($t),
                "_default (sheaf.h's macro passes the size)"
            );
            const UNKNOWN_FIELDS: &'static str = concat!(
                stringify!($t),
                " sets fields this library does not know (a newer header): \
                 leave them at their defaults or link the newer library"
            );
        }
        const _: () = {
            assert!(core::mem::offset_of!($t, size) == 0);
            // SAFETY: all-zero bits are a valid value of every field type
            // of a parameter struct (integers, floats, raw pointers and
            // `Option` of a function pointer).
            let v: $t = unsafe { core::mem::MaybeUninit::zeroed().assume_init() };
            let fields = core::mem::size_of_val(&v.size)
                + core::mem::size_of_val(&v.$first)
                $(+ core::mem::size_of_val(&v.$f))*;
            assert!(
                fields == core::mem::size_of::<$t>(),
                concat!(stringify!($t), ": fields missing from versioned! or padding")
            );
        };
    };
}
pub(crate) use versioned;
