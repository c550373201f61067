//! `sheaf_version_string` and `sheaf_version`: the library's version, to
//! catch header/library skew (the Embree model: `RTC_VERSION` in the header,
//! the device's version at run time).

use core::ffi::{CStr, c_char};

const VERSION: &CStr =
    match CStr::from_bytes_with_nul(concat!(env!("CARGO_PKG_VERSION"), "\0").as_bytes()) {
        Ok(v) => v,
        Err(_) => panic!("package version contains a NUL byte"),
    };

/// A decimal version component (Cargo guarantees digits only).
const fn component(s: &str) -> u32 {
    let b = s.as_bytes();
    let mut i = 0;
    let mut n = 0u32;
    while i < b.len() {
        assert!(b[i].is_ascii_digit(), "version component is not a number");
        n = n * 10 + (b[i] - b'0') as u32;
        i += 1;
    }
    n
}

const MAJOR: u32 = component(env!("CARGO_PKG_VERSION_MAJOR"));
const MINOR: u32 = component(env!("CARGO_PKG_VERSION_MINOR"));
const PATCH: u32 = component(env!("CARGO_PKG_VERSION_PATCH"));
// Two decimal digits each for minor and patch, as in the numeric version.
const _: () = assert!(MINOR < 100 && PATCH < 100 && MAJOR < 42949);

/// The numeric version `MAJOR * 10000 + MINOR * 100 + PATCH` (0.1.0 is
/// 100, 1.2.3 would be 10203), what the header's `SHEAF_VERSION` says
/// (cbindgen.toml writes it; `tests/c_abi.rs` and this module's tests
/// check both against Cargo.toml).
pub const SHEAF_VERSION: u32 = MAJOR * 10000 + MINOR * 100 + PATCH;

/// The library's version, "MAJOR.MINOR.PATCH" (compare with the header's
/// `SHEAF_VERSION_MAJOR/MINOR/PATCH` to detect a header/library mismatch).
///
/// Static string, never NULL, never free it. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_version_string() -> *const c_char {
    VERSION.as_ptr()
}

/// The library's numeric version, `MAJOR * 10000 + MINOR * 100 + PATCH`
/// (100 for 0.1.0): equal to the header's `SHEAF_VERSION` when the program
/// runs with the library it was compiled against. A program can refuse to
/// run with an older library:
///
/// ```c
/// if (sheaf_version() < SHEAF_VERSION) return 1; // libsheaf older than sheaf.h
/// ```
///
/// The shared library's soname carries the major version
/// (`libsheaf.so.0` for 0.x). Never fails. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_version() -> u32 {
    SHEAF_VERSION
}

#[cfg(test)]
mod tests {
    #[test]
    fn version_is_the_package_version() {
        // SAFETY: a static NUL-terminated string.
        let v = unsafe { core::ffi::CStr::from_ptr(super::sheaf_version_string()) };
        assert_eq!(v.to_str(), Ok(env!("CARGO_PKG_VERSION")));
    }

    #[test]
    fn numeric_version_matches_the_string_and_the_header() {
        let parts: Vec<u32> = env!("CARGO_PKG_VERSION")
            .split(['.', '-', '+'])
            .take(3)
            .map(|p| p.parse().unwrap())
            .collect();
        let want = parts[0] * 10000 + parts[1] * 100 + parts[2];
        assert_eq!(super::sheaf_version(), want);
        // The header's macro (cbindgen.toml after_includes) says the same.
        let header = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("include/sheaf.h"),
        )
        .expect("include/sheaf.h");
        let line = header
            .lines()
            .find(|l| l.starts_with("#define SHEAF_VERSION "))
            .expect("include/sheaf.h has no `#define SHEAF_VERSION`: edit cbindgen.toml");
        assert_eq!(
            line["#define SHEAF_VERSION ".len()..].trim(),
            want.to_string(),
            "SHEAF_VERSION in cbindgen.toml vs Cargo.toml"
        );
    }
}
