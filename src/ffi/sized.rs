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
//!
//! The calls share three readers: [`to_core`] for a struct the call
//! needs, [`or_default`] for one NULL leaves at the crate's defaults, and
//! [`optional`] for one whose NULL means something else; the `*_default`
//! functions are [`write_defaults`].

use super::{check_non_null, guard_free, sheaf_status};
use crate::error::{Error, Result};

/// Largest size a newer header's struct may declare.
const MAX_BYTES: usize = 4096;

/// A parameter struct that begins with its `u32` size (declared with
/// [`versioned!`]).
pub(crate) trait Versioned: Copy {
    /// The crate value the struct stands for.
    type Core;
    /// The checked crate value (the struct's own `to_core`).
    fn core(&self) -> Result<Self::Core>;
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

/// The checked crate value of a parameter struct from C (NULL refused).
pub(crate) fn to_core<T: Versioned>(p: *const T) -> Result<T::Core> {
    read(p)?.core()
}

/// The checked crate value of a parameter struct from C, `None` for NULL.
pub(crate) fn optional<T: Versioned>(p: *const T) -> Result<Option<T::Core>> {
    if p.is_null() {
        return Ok(None);
    }
    to_core(p).map(Some)
}

/// The checked crate value of a parameter struct from C, the crate's
/// defaults for NULL (the documented meaning of a NULL parameter struct).
pub(crate) fn or_default<T: Versioned>(p: *const T) -> Result<T::Core>
where
    T::Core: Default,
{
    Ok(optional(p)?.unwrap_or_default())
}

/// The body of a `*_default` function: this library's defaults written to
/// the caller's struct of `size` bytes, as [`write`] writes them.
pub(crate) fn write_defaults<T: Versioned>(out: *mut T, size: usize) -> sheaf_status {
    guard_free(|| write(out, size, T::defaults()))
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

/// Declare a parameter struct [`Versioned`]: its name and the crate type
/// its `to_core` returns, the fields after `size` in declaration order (the
/// first is in every layout), and its defaults. Asserts at compile time
/// that `size` comes first, that the list is every other field in
/// declaration order, and that the fields leave no padding.
macro_rules! versioned {
    ($t:ident => $core:ty, [$first:ident $(, $f:ident)* $(,)?], $defaults:expr) => {
        impl $crate::ffi::sized::Versioned for $t {
            type Core = $core;
            fn core(&self) -> $crate::error::Result<$core> {
                $t::to_core(self)
            }
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
            // In declaration order from the first after `size`, so that
            // `PREFIXES` are the older layouts' sizes.
            let offsets = [
                core::mem::offset_of!($t, $first)
                $(, core::mem::offset_of!($t, $f))*
            ];
            assert!(
                offsets[0] == core::mem::size_of_val(&v.size),
                concat!(stringify!($t), ": versioned! must start at the field after size")
            );
            let mut i = 1;
            while i < offsets.len() {
                assert!(
                    offsets[i - 1] < offsets[i],
                    concat!(stringify!($t), ": versioned! lists fields out of order")
                );
                i += 1;
            }
        };
    };
}
pub(crate) use versioned;
