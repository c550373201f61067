//! `sheaf_version_string`: the library's version, to catch header/library skew.

use core::ffi::{CStr, c_char};

const VERSION: &CStr =
    match CStr::from_bytes_with_nul(concat!(env!("CARGO_PKG_VERSION"), "\0").as_bytes()) {
        Ok(v) => v,
        Err(_) => panic!("package version contains a NUL byte"),
    };

/// The library's version, "MAJOR.MINOR.PATCH" (compare with the header's
/// `SHEAF_VERSION_MAJOR/MINOR/PATCH` to detect a header/library mismatch).
///
/// Static string, never NULL, never free it. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_version_string() -> *const c_char {
    VERSION.as_ptr()
}

#[cfg(test)]
mod tests {
    #[test]
    fn version_is_the_package_version() {
        // SAFETY: a static NUL-terminated string.
        let v = unsafe { core::ffi::CStr::from_ptr(super::sheaf_version_string()) };
        assert_eq!(v.to_str(), Ok(env!("CARGO_PKG_VERSION")));
    }
}
