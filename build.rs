//! Build script: gives the shared library (cdylib) an ELF soname on Linux,
//! `libsheaf.so.<MAJOR>`, or `libsheaf.so.0.<MINOR>` while the major
//! version is 0 (`0.0.<PATCH>` for 0.0.x): cargo-c's rule, the soname
//! `cargo cinstall` would give.
//!
//! Rust's cdylib has no soname (rust-lang/cargo#5045), so a program linked
//! with `-lsheaf` would record the bare file path it was linked against.
//! With the soname it records `libsheaf.so.0.3`, which `scripts/install.sh`
//! installs as a symlink to the real file `libsheaf.so.MAJOR.MINOR.PATCH`.
//!
//! So that programs linked against the build tree still run (README's
//! `-Ltarget/release -lsheaf -Wl,-rpath,...`, `make -C examples-c shared`,
//! the shared-library C tests), this script also puts the symlink
//! `libsheaf.so.<soname version> -> libsheaf.so` next to the library in
//! `target/<profile>/` and `target/<profile>/deps/` (dangling until the
//! library is linked). These are the only files it writes outside OUT_DIR.
//!
//! Versioning (docs/c-api.md, "Upgrading"; pkg/README.md): within one
//! soname the C ABI only grows (new functions, new status codes never
//! renumbered, parameter structs grown at their end, which carry their
//! size); a release that breaks it raises the minor version while the
//! major is 0 (the major after), which changes the soname, and CI's
//! `abidiff` against `abi/libsheaf.abi` refuses a break that keeps it.
//! The static library and the no_std build are unaffected (the argument
//! applies to cdylib links only).

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    emulated_levels();
    let os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    let major =
        std::env::var("CARGO_PKG_VERSION_MAJOR").expect("cargo sets CARGO_PKG_VERSION_MAJOR");
    if os != "linux" {
        return;
    }
    let minor =
        std::env::var("CARGO_PKG_VERSION_MINOR").expect("cargo sets CARGO_PKG_VERSION_MINOR");
    let patch =
        std::env::var("CARGO_PKG_VERSION_PATCH").expect("cargo sets CARGO_PKG_VERSION_PATCH");
    // cargo-c's `sover`: 0.0.PATCH, 0.MINOR, or MAJOR.
    let soname = match (major.as_str(), minor.as_str()) {
        ("0", "0") => format!("libsheaf.so.0.0.{patch}"),
        ("0", _) => format!("libsheaf.so.0.{minor}"),
        _ => format!("libsheaf.so.{major}"),
    };
    println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,{soname}");
    soname_links(&soname);
}

/// The lane widths compiled for emulation (`isa::set_emulation`, tests
/// only: a level above the CPU's run in baseline code, so the exactness
/// suites check every width on any machine). A level the build machine
/// runs natively never runs emulated there, and its emulated copy of every
/// packet traversal was 45 % of the library's machine code (and of its
/// compile time), so it is left out: cfg `sheaf_emulate_avx2` /
/// `sheaf_emulate_avx512` are set only for levels the build machine lacks,
/// for every level when cross-compiling (or off x86), and for both with
/// `SHEAF_EMULATE=all`.
fn emulated_levels() {
    println!("cargo::rustc-check-cfg=cfg(sheaf_emulate_avx2)");
    println!("cargo::rustc-check-cfg=cfg(sheaf_emulate_avx512)");
    println!("cargo:rerun-if-env-changed=SHEAF_EMULATE");
    let all = std::env::var("SHEAF_EMULATE").is_ok_and(|v| v == "all");
    let native = std::env::var("TARGET").ok() == std::env::var("HOST").ok();
    let (mut avx2, mut avx512) = (false, false);
    #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
    if native && !all {
        avx2 = std::arch::is_x86_feature_detected!("avx2");
        avx512 = std::arch::is_x86_feature_detected!("avx512f");
    }
    let _ = (native, all);
    if !avx2 {
        println!("cargo:rustc-cfg=sheaf_emulate_avx2");
    }
    if !avx512 {
        println!("cargo:rustc-cfg=sheaf_emulate_avx512");
    }
}

/// `<profile dir>/{,deps/}libsheaf.so.<MAJOR> -> libsheaf.so`, best effort.
#[cfg(unix)]
fn soname_links(soname: &str) {
    // OUT_DIR is <target>/<profile>/build/sheaf-<hash>/out.
    let Some(out) = std::env::var_os("OUT_DIR") else {
        return;
    };
    let Some(profile) = std::path::Path::new(&out).ancestors().nth(3) else {
        return;
    };
    for dir in [profile.to_path_buf(), profile.join("deps")] {
        let link = dir.join(soname);
        if std::fs::read_link(&link).is_ok_and(|t| t == std::path::Path::new("libsheaf.so")) {
            continue;
        }
        let _ = std::fs::create_dir_all(&dir);
        let _ = std::fs::remove_file(&link);
        if let Err(e) = std::os::unix::fs::symlink("libsheaf.so", &link) {
            println!("cargo:warning=cannot create {}: {e}", link.display());
        }
    }
}

#[cfg(not(unix))]
fn soname_links(_soname: &str) {}
