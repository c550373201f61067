//! Packaging for C users: `scripts/install.sh` into a temporary prefix,
//! then the C example built only from the installed files.
//!
//! 1. Installs the `libsheaf.a` and `libsheaf.so` built with this test
//!    binary (`SHEAF_LIB_DIR`, so no cargo runs inside `cargo test`) into
//!    `target/tmp/install-<profile>/prefix` and checks the layout: the
//!    header in `include/sheaf/`, `libsheaf.so.X.Y.Z` with the
//!    `libsheaf.so.X` and `libsheaf.so` symlinks, both pkg-config files and
//!    both CMake files.
//! 2. `readelf -d` shows the soname `libsheaf.so.0.<minor>` (0.x) or
//!    `libsheaf.so.<major>`.
//! 3. Builds `examples-c/render.c` with `make installed` (shared, through
//!    pkg-config) and `make installed-static` (static, sheaf-static.pc),
//!    and with CMake (`find_package(sheaf CONFIG REQUIRED)`, `sheaf::sheaf`
//!    and `sheaf::sheaf_static`) when cmake is present; runs each and
//!    checks the PPM it writes (size, header, not one flat colour), the
//!    same bytes from every build.
//! 4. A C program built through pkg-config prints the header's
//!    `SHEAF_VERSION` and `sheaf_version()`: equal, and the crate's.
//!
//! gcc, make, readelf and pkg-config are required (CI installs them); the
//! CMake part is skipped with a message when cmake is missing.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The directory holding the `libsheaf.a` and `libsheaf.so` built with
/// this test binary (as in tests/c_abi.rs: `target/<profile>/deps`).
fn lib_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("current_exe");
    let deps = exe.parent().expect("target/<profile>/deps").to_path_buf();
    let has_libs = |d: &Path| d.join("libsheaf.a").is_file() && d.join("libsheaf.so").is_file();
    if has_libs(&deps) {
        return deps;
    }
    let profile = deps.parent().expect("target/<profile>").to_path_buf();
    assert!(
        has_libs(&profile),
        "libsheaf.a and libsheaf.so not found in {} or {}",
        deps.display(),
        profile.display()
    );
    profile
}

/// A fresh work directory for this test under target/tmp.
fn work_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let profile = exe
        .parent()
        .and_then(Path::parent)
        .and_then(Path::file_name)
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("install-{profile}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn have(tool: &str) -> bool {
    Command::new(tool)
        .arg("--version")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

fn require(tool: &str, apt: &str) {
    assert!(
        have(tool),
        "`{tool}` not found: the install test needs it (apt-get install {apt})"
    );
}

/// Run `cmd`; it must succeed. Returns stdout.
fn run(cmd: &mut Command) -> String {
    let shown = format!("{cmd:?}");
    let out = cmd
        .env_remove("LD_LIBRARY_PATH")
        .output()
        .unwrap_or_else(|e| panic!("cannot run {shown}: {e}"));
    assert!(
        out.status.success(),
        "failed ({}):\n{shown}\n{}{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

const W: usize = 96;
const H: usize = 64;

/// Run the example `exe` into `dir/<name>.ppm` and check the image; returns
/// its bytes.
fn render(exe: &Path, dir: &Path, name: &str) -> Vec<u8> {
    let ppm = dir.join(format!("{name}.ppm"));
    let out = run(Command::new(exe)
        .arg(&ppm)
        .arg(W.to_string())
        .arg(H.to_string()));
    assert!(
        out.contains(env!("CARGO_PKG_VERSION")),
        "{name}: the example did not print the library version: {out}"
    );
    let bytes = std::fs::read(&ppm).unwrap_or_else(|e| panic!("{}: {e}", ppm.display()));
    let header = format!("P6\n{W} {H}\n255\n");
    assert!(
        bytes.starts_with(header.as_bytes()),
        "{name}: not a {W}x{H} binary PPM"
    );
    let pixels = &bytes[header.len()..];
    assert_eq!(pixels.len(), W * H * 3, "{name}: PPM size");
    let first = &pixels[..3];
    let distinct = pixels.chunks(3).filter(|p| *p != first).count();
    assert!(
        distinct > W * H / 10,
        "{name}: the image is (almost) one colour"
    );
    bytes
}

fn needed_libs(exe: &Path) -> String {
    run(Command::new("readelf").arg("-d").arg(exe))
        .lines()
        .filter(|l| l.contains("(NEEDED)"))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn install_then_build_the_example_against_it() {
    for (tool, apt) in [
        ("bash", "bash"),
        ("gcc", "gcc"),
        ("make", "make"),
        ("readelf", "binutils"),
        ("pkg-config", "pkg-config"),
    ] {
        require(tool, apt);
    }
    let work = work_dir();
    let prefix = work.join("prefix");
    let major = match env!("CARGO_PKG_VERSION_MAJOR") {
        "0" => concat!("0.", env!("CARGO_PKG_VERSION_MINOR")),
        m => m,
    };
    let version = env!("CARGO_PKG_VERSION");

    // 1. Install.
    let log = run(Command::new("bash")
        .arg(root().join("scripts/install.sh"))
        .arg(&prefix)
        .env("SHEAF_LIB_DIR", lib_dir())
        .env_remove("DESTDIR"));
    println!("{log}");
    let lib = prefix.join("lib");
    for f in [
        "include/sheaf/sheaf.h",
        "include/sheaf/sheaf.hpp",
        "lib/libsheaf.a",
        &format!("lib/libsheaf.so.{version}"),
        "lib/pkgconfig/sheaf.pc",
        "lib/pkgconfig/sheaf-static.pc",
        "lib/cmake/sheaf/sheafConfig.cmake",
        "lib/cmake/sheaf/sheafConfigVersion.cmake",
    ] {
        assert!(prefix.join(f).is_file(), "{f} not installed");
    }
    assert_eq!(
        std::fs::read(prefix.join("include/sheaf/sheaf.h")).unwrap(),
        std::fs::read(root().join("include/sheaf.h")).unwrap()
    );
    let link = |name: &str| std::fs::read_link(lib.join(name)).ok();
    assert_eq!(
        link(&format!("libsheaf.so.{major}")),
        Some(PathBuf::from(format!("libsheaf.so.{version}")))
    );
    assert_eq!(
        link("libsheaf.so"),
        Some(PathBuf::from(format!("libsheaf.so.{major}")))
    );

    // 2. The soname.
    let dynamic = run(Command::new("readelf")
        .arg("-d")
        .arg(lib.join(format!("libsheaf.so.{version}"))));
    assert!(
        dynamic.contains(&format!("Library soname: [libsheaf.so.{major}]")),
        "no soname libsheaf.so.{major} (build.rs):\n{dynamic}"
    );

    // pkg-config sees the installed package.
    let pc_path = lib.join("pkgconfig");
    let pkg = |args: &[&str]| {
        run(Command::new("pkg-config")
            .args(args)
            .env("PKG_CONFIG_PATH", &pc_path))
        .trim()
        .to_string()
    };
    assert_eq!(pkg(&["--modversion", "sheaf"]), version);
    let cflags = pkg(&["--cflags", "sheaf"]);
    assert!(
        cflags.contains(&format!("{}/include/sheaf", prefix.display())),
        "{cflags}"
    );
    let static_libs = pkg(&["--static", "--libs", "sheaf"]);
    assert!(
        static_libs.contains("-lsheaf") && static_libs.contains("-lpthread"),
        "Libs.private: {static_libs}"
    );
    assert!(pkg(&["--libs", "sheaf-static"]).contains("libsheaf.a"));

    // 3. The example through pkg-config, shared and static, from a copy of
    // examples-c (nothing is written into the source tree).
    let ex = work.join("examples-c");
    std::fs::create_dir_all(&ex).unwrap();
    for f in ["render.c", "Makefile", "CMakeLists.txt"] {
        std::fs::copy(root().join("examples-c").join(f), ex.join(f)).unwrap();
    }
    run(Command::new("make")
        .arg("-C")
        .arg(&ex)
        .arg("installed")
        .arg("installed-static")
        .arg(format!("PREFIX={}", prefix.display()))
        .env_remove("PKG_CONFIG_PATH"));
    let shared = ex.join("render-installed");
    let stat = ex.join("render-installed-static");
    let needed = needed_libs(&shared);
    assert!(
        needed.contains(&format!("[libsheaf.so.{major}]")),
        "render-installed does not need libsheaf.so.{major}:\n{needed}"
    );
    assert!(
        !needed_libs(&stat).contains("libsheaf"),
        "render-installed-static links libsheaf dynamically"
    );
    let want = render(&shared, &work, "pkg-config-shared");
    assert!(render(&stat, &work, "pkg-config-static") == want);

    // 4. sheaf_version() through the installed header and library.
    let src = work.join("version.c");
    std::fs::write(
        &src,
        "#include <sheaf.h>\n#include <stdio.h>\n\
         int main(void) { printf(\"%u %u\\n\", (unsigned)SHEAF_VERSION, (unsigned)sheaf_version()); \
         return SHEAF_VERSION == sheaf_version() ? 0 : 1; }\n",
    )
    .unwrap();
    let vexe = work.join("version");
    let flags = pkg(&["--cflags", "--libs", "sheaf"]);
    run(Command::new("gcc")
        .args(["-std=c99", "-Wall", "-Werror"])
        .arg(&src)
        .arg("-o")
        .arg(&vexe)
        .args(flags.split_whitespace())
        .arg(format!("-Wl,-rpath,{}", lib.display())));
    let v = sheaf::ffi::version::SHEAF_VERSION;
    assert_eq!(run(&mut Command::new(&vexe)).trim(), format!("{v} {v}"));

    // 5. CMake.
    if !have("cmake") {
        println!("SKIPPED: the CMake build (cmake not found; apt-get install cmake)");
        return;
    }
    let build = work.join("cmake-build");
    run(Command::new("cmake")
        .arg("-S")
        .arg(&ex)
        .arg("-B")
        .arg(&build)
        .arg(format!("-DCMAKE_PREFIX_PATH={}", prefix.display()))
        .env("CMAKE_BUILD_TYPE", "Release"));
    run(Command::new("cmake").arg("--build").arg(&build));
    let cm_shared = build.join("render");
    let cm_static = build.join("render_static");
    assert!(needed_libs(&cm_shared).contains(&format!("[libsheaf.so.{major}]")));
    assert!(!needed_libs(&cm_static).contains("libsheaf"));
    assert!(render(&cm_shared, &work, "cmake-shared") == want);
    assert!(render(&cm_static, &work, "cmake-static") == want);

    // The version file refuses an incompatible request.
    for (request, found) in [
        ("0.3", true),
        ("0.3.0", true),
        ("0.2", false),
        ("0.4", false),
        ("1.0", false),
    ] {
        let dir = work.join(format!("cmake-version-{request}"));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("CMakeLists.txt"),
            format!(
                "cmake_minimum_required(VERSION 3.13)\nproject(v NONE)\n\
                 find_package(sheaf {request} CONFIG QUIET)\n\
                 message(STATUS \"SHEAF_FOUND=${{sheaf_FOUND}}\")\n"
            ),
        )
        .unwrap();
        let out = run(Command::new("cmake")
            .arg("-S")
            .arg(&dir)
            .arg("-B")
            .arg(dir.join("b"))
            .arg(format!("-DCMAKE_PREFIX_PATH={}", prefix.display())));
        let found_now = out.contains("SHEAF_FOUND=1");
        assert_eq!(found_now, found, "find_package(sheaf {request}):\n{out}");
    }
}
