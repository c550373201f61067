//! The C ABI from C and C++ (Debian's gcc and g++), and against the Rust API.
//!
//! 1. Finds the `libsheaf.a` and `libsheaf.so` built with this test binary
//!    (in `target/<profile>/deps/`, where `cargo test` writes every crate
//!    type of the library; see `lib_dir`).
//! 2. Compiles each C program in `ffi-tests/` twice, static
//!    (`-l:libsheaf.a -lm -lpthread -ldl`) and shared (`-lsheaf` with an
//!    rpath), with `gcc -std=c99 -Wall -Wextra -Werror -pedantic`, and the
//!    C++ one with `g++ -std=c++11 -Wall -Wextra -Werror -pedantic`, into
//!    `target/tmp/`; checks the header alone compiles as C99/C11/C++11/C++17.
//! 3. Runs them: each must exit 0 and end with "N passed, 0 failed".
//! 4. `ffi-tests/crosscheck.c` prints its scene, rays, hits, occlusion and
//!    image checksum as bit patterns; the same is computed here through the
//!    Rust API (`sheaf::OwnedContext`) and compared bit for bit.
//! 5. No call through the C ABI allocates after `sheaf_context_create`,
//!    which allocates exactly once (a counting global allocator).
//!
//! gcc and g++ are required: without them this test fails (CI installs
//! them). Only the release profile unwinds (Cargo.toml), which is what C
//! users link: run `cargo test --release`.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use sheaf::ffi::{
    self, sheaf_frame, sheaf_grid_params, sheaf_hit, sheaf_method, sheaf_ray, sheaf_stats,
    sheaf_status,
};
use sheaf::{
    Camera, Frame, GridParams, Hit, Limits, Method, OwnedContext, PointLight, Ray, Scene, Shading,
    TriTest,
};

// ---- where things are --------------------------------------------------------

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The directory holding the `libsheaf.a` and `libsheaf.so` built with this
/// test binary: `target/<profile>/deps` itself. `cargo test` writes every
/// crate type of [lib] there (unhashed names for staticlib and cdylib) but
/// copies them up to `target/<profile>/` only for `cargo build`, so the
/// copies there may be stale; they are used only when deps/ has none.
fn lib_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("current_exe");
    let deps = exe
        .parent()
        .expect("test binary lives in target/<profile>/deps")
        .to_path_buf();
    let has_libs = |d: &Path| d.join("libsheaf.a").is_file() && d.join("libsheaf.so").is_file();
    if has_libs(&deps) {
        return deps;
    }
    let profile = deps.parent().expect("target/<profile>").to_path_buf();
    assert!(
        has_libs(&profile),
        "libsheaf.a and libsheaf.so not found in {} or {}: `cargo test` builds every crate type of [lib]",
        deps.display(),
        profile.display()
    );
    profile
}

/// Where compiled test programs go (`target/tmp/ffi-tests-<profile>`).
fn out_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("current_exe");
    let profile = exe
        .parent()
        .and_then(Path::parent)
        .and_then(Path::file_name)
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("ffi-tests-{profile}"));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn require(tool: &str) {
    let ok = Command::new(tool)
        .arg("--version")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    assert!(
        ok,
        "`{tool}` not found: the C ABI tests need Debian's gcc and g++ (apt-get install gcc g++)"
    );
}

#[derive(Clone, Copy, Debug)]
enum Link {
    Static,
    Shared,
}

// ---- compile and run -----------------------------------------------------------

fn run_tool(cmd: &mut Command) {
    let shown = format!("{cmd:?}");
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {shown}: {e}"));
    assert!(
        out.status.success(),
        "compilation failed:\n{shown}\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Compile `ffi-tests/<src>` with `compiler` and `std_flags`, linked `link`.
fn compile(compiler: &str, std_flags: &[&str], src: &str, link: Link) -> PathBuf {
    require(compiler);
    let lib = lib_dir();
    let stem = Path::new(src)
        .file_stem()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let exe = out_dir().join(format!("{stem}-{}", format!("{link:?}").to_lowercase()));
    let mut cmd = Command::new(compiler);
    cmd.args(std_flags)
        .args(["-Wall", "-Wextra", "-Werror", "-pedantic", "-g"])
        .arg("-I")
        .arg(root().join("include"))
        .arg(root().join("ffi-tests").join(src))
        .arg("-o")
        .arg(&exe)
        .arg("-L")
        .arg(&lib);
    match link {
        Link::Static => cmd.args(["-l:libsheaf.a", "-lm", "-lpthread", "-ldl"]),
        // DT_RPATH (not RUNPATH): searched before any LD_LIBRARY_PATH.
        Link::Shared => cmd
            .arg("-lsheaf")
            .arg(format!("-Wl,-rpath,{}", lib.display()))
            .args(["-Wl,--disable-new-dtags", "-lm", "-lpthread"]),
    };
    run_tool(&mut cmd);
    if let Link::Shared = link {
        let bytes = std::fs::read(&exe).unwrap();
        assert!(
            bytes.windows(11).any(|w| w == b"libsheaf.so"),
            "{} does not link libsheaf.so",
            exe.display()
        );
    }
    exe
}

fn compile_c(src: &str, link: Link) -> PathBuf {
    compile("gcc", &["-std=c99"], src, link)
}

/// Run a test program; it must exit 0 and report "N passed, 0 failed".
/// Returns its stdout.
fn run(exe: &Path) -> String {
    check_layouts();
    // cargo puts target/<profile> (with possibly stale copies of the
    // libraries) on LD_LIBRARY_PATH, which would win over the rpath.
    let out = Command::new(exe)
        .env_remove("LD_LIBRARY_PATH")
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", exe.display()));
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let report: Vec<&str> = stdout.lines().filter(|l| !l.starts_with('@')).collect();
    println!("--- {} ---\n{}\n{stderr}", exe.display(), report.join("\n"));
    assert!(
        out.status.success(),
        "{} failed ({}):\n{}\n{stderr}",
        exe.display(),
        out.status,
        report.join("\n")
    );
    let last = report.last().copied().unwrap_or("");
    let (passed, failed) = last
        .strip_suffix(" failed")
        .and_then(|s| s.split_once(" passed, "))
        .unwrap_or_else(|| {
            panic!(
                "{}: last line {last:?} is not \"N passed, M failed\"",
                exe.display()
            )
        });
    assert_eq!(failed, "0", "{}: {last}", exe.display());
    assert!(
        passed.parse::<u32>().unwrap() > 0,
        "{}: no test ran",
        exe.display()
    );
    stdout
}

// ---- the header's layouts are the library's ---------------------------------------------

/// Size and alignment of every struct of the header as C sees it, against
/// the Rust types. Every program-running test checks this first: a stale
/// header (e.g. after a field was added to `Counters`) would otherwise let
/// the library write past the C structs and fail in confusing ways.
fn check_layouts() {
    static CHECKED: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    let r = CHECKED.get_or_init(|| {
        use std::mem::{align_of, size_of};
        let rust: &[(&str, usize, usize)] = &[
            ("sheaf_limits", size_of::<ffi::sheaf_limits>(), align_of::<ffi::sheaf_limits>()),
            ("sheaf_grid_params", size_of::<sheaf_grid_params>(), align_of::<sheaf_grid_params>()),
            ("sheaf_ray", size_of::<sheaf_ray>(), align_of::<sheaf_ray>()),
            ("sheaf_hit", size_of::<sheaf_hit>(), align_of::<sheaf_hit>()),
            ("sheaf_camera", size_of::<Camera>(), align_of::<Camera>()),
            ("sheaf_pixel_rect", size_of::<sheaf::PixelRect>(), align_of::<sheaf::PixelRect>()),
            ("sheaf_light", size_of::<PointLight>(), align_of::<PointLight>()),
            ("sheaf_shading", size_of::<ffi::sheaf_shading>(), align_of::<ffi::sheaf_shading>()),
            ("sheaf_frame", size_of::<sheaf_frame>(), align_of::<sheaf_frame>()),
            ("sheaf_counters", size_of::<sheaf::Counters>(), align_of::<sheaf::Counters>()),
            ("sheaf_stats", size_of::<sheaf_stats>(), align_of::<sheaf_stats>()),
            ("sheaf_status", size_of::<sheaf_status>(), align_of::<sheaf_status>()),
            ("sheaf_trace_params", size_of::<ffi::sheaf_trace_params>(), align_of::<ffi::sheaf_trace_params>()),
            ("sheaf_pgrid_params", size_of::<ffi::sheaf_pgrid_params>(), align_of::<ffi::sheaf_pgrid_params>()),
            ("sheaf_deferred_job", size_of::<ffi::sheaf_deferred_job>(), align_of::<ffi::sheaf_deferred_job>()),
            ("sheaf_refit_params", size_of::<ffi::sheaf_refit_params>(), align_of::<ffi::sheaf_refit_params>()),
            ("sheaf_bvh_params", size_of::<ffi::sheaf_bvh_params>(), align_of::<ffi::sheaf_bvh_params>()),
            ("sheaf_kd_params", size_of::<ffi::sheaf_kd_params>(), align_of::<ffi::sheaf_kd_params>()),
            ("sheaf_refit_info", size_of::<ffi::sheaf_refit_info>(), align_of::<ffi::sheaf_refit_info>()),
            ("sheaf_mesh", size_of::<ffi::sheaf_mesh>(), align_of::<ffi::sheaf_mesh>()),
            ("sheaf_geometry_params", size_of::<ffi::sheaf_geometry_params>(), align_of::<ffi::sheaf_geometry_params>()),
            ("sheaf_scene_hit", size_of::<ffi::sheaf_scene_hit>(), align_of::<ffi::sheaf_scene_hit>()),
            ("sheaf_scene_info", size_of::<ffi::sheaf_scene_info>(), align_of::<ffi::sheaf_scene_info>()),
            ("sheaf_ray_stream", size_of::<ffi::sheaf_ray_stream>(), align_of::<ffi::sheaf_ray_stream>()),
            ("sheaf_hit_stream", size_of::<ffi::sheaf_hit_stream>(), align_of::<ffi::sheaf_hit_stream>()),
        ];
        // Macros written by hand in cbindgen.toml that tests/header.rs does
        // not check, against the Rust values (printed after the layouts).
        let macros: &[(&str, u64)] = &[
            ("SHEAF_STRUCTURE_KD", Limits::KD as u64),
            ("SHEAF_STRUCTURE_PGRID", Limits::PGRID as u64),
            ("SHEAF_RENDERER_TILES", Limits::TILES as u64),
            ("SHEAF_RENDERER_WHITTED", Limits::WHITTED as u64),
            ("SHEAF_RENDERER_DEFERRED", Limits::DEFERRED as u64),
            ("SHEAF_DEFERRED_MAX_LIGHTS", ffi::SHEAF_DEFERRED_MAX_LIGHTS as u64),
        ];
        let mut c = String::from("#include \"sheaf.h\"\n#include <stdio.h>\n#include <stddef.h>\n");
        c += "#define SHOW(T) printf(\"%s %u %u\\n\", #T, (unsigned)sizeof(T), (unsigned)offsetof(struct { char c; T t; }, t))\n";
        c += "int main(void) {\n";
        for (name, _, _) in rust {
            c += &format!("    SHOW({name});\n");
        }
        for (name, _) in macros {
            c += &format!("    printf(\"%s %llu\\n\", \"{name}\", (unsigned long long)({name}));\n");
        }
        c += "    return 0;\n}\n";
        let src = out_dir().join("layout.c");
        std::fs::write(&src, c).unwrap();
        let exe = out_dir().join("layout");
        require("gcc");
        run_tool(
            Command::new("gcc")
                .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-I"])
                .arg(root().join("include"))
                .arg(&src)
                .arg("-o")
                .arg(&exe),
        );
        let out = Command::new(&exe).output().expect("run layout");
        let text = String::from_utf8_lossy(&out.stdout);
        let mut errors = Vec::new();
        for ((name, size, align), line) in rust.iter().zip(text.lines()) {
            let f: Vec<&str> = line.split_whitespace().collect();
            let (cs, ca): (usize, usize) = (f[1].parse().unwrap(), f[2].parse().unwrap());
            if f[0] != *name || cs != *size || ca != *align {
                errors.push(format!("  {name}: C sizeof {cs} align {ca}, Rust {size} align {align}"));
            }
        }
        for ((name, value), line) in macros.iter().zip(text.lines().skip(rust.len())) {
            if line != format!("{name} {value}") {
                errors.push(format!("  {line:?}: the crate's value of {name} is {value}"));
            }
        }
        if errors.is_empty() && text.lines().count() == rust.len() + macros.len() {
            Ok(())
        } else {
            Err(format!(
                "include/sheaf.h does not match the library's types:\n{}\nregenerate it: \
                 SHEAF_BLESS=1 cargo test --release --test header",
                errors.join("\n")
            ))
        }
    });
    if let Err(e) = r {
        panic!("{e}");
    }
}

#[test]
fn header_layouts_match_rust() {
    check_layouts();
}

// ---- the C and C++ programs ---------------------------------------------------------

#[test]
fn c_api_static() {
    run(&compile_c("test_api.c", Link::Static));
}

#[test]
fn c_api_shared() {
    run(&compile_c("test_api.c", Link::Shared));
}

#[test]
fn c_scene_static() {
    run(&compile_c("test_scene.c", Link::Static));
}

#[test]
fn c_scene_shared() {
    run(&compile_c("test_scene.c", Link::Shared));
}

/// `examples-c/engine.c`, the two-level frame loop, runs through the C
/// ABI: three frames, a table line each, the PPM written, most of the
/// 76,800 camera rays a hit (the rest see the sky), some of the hits lit,
/// some in shadow, and the grilles' filter asked every frame.
#[test]
fn c_engine_example_runs() {
    check_layouts();
    let exe = compile_c("../examples-c/engine.c", Link::Static);
    let ppm = out_dir().join("engine.ppm");
    let out = Command::new(&exe)
        .arg(&ppm)
        .arg("3")
        .env_remove("LD_LIBRARY_PATH")
        .output()
        .expect("run engine");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rows: Vec<Vec<&str>> = stdout
        .lines()
        .map(|l| l.split_whitespace().collect::<Vec<_>>())
        .filter(|f| f.len() == 8 && f.iter().all(|w| w.parse::<f64>().is_ok()))
        .collect();
    assert_eq!(rows.len(), 3, "{stdout}");
    for f in &rows {
        let (hits, lit): (u32, u32) = (f[5].parse().unwrap(), f[6].parse().unwrap());
        let calls: u64 = f[7].parse().unwrap();
        assert!(
            hits > 30_000 && lit > 0 && lit < hits && calls > 0,
            "{stdout}"
        );
    }
    assert!(stdout.contains("20 instances"), "{stdout}");
    assert!(std::fs::metadata(&ppm).map(|m| m.len()).unwrap_or(0) == 320 * 240 * 3 + 15);
}

#[test]
fn c_filters_static() {
    run(&compile_c("test_filter.c", Link::Static));
}

#[test]
fn c_filters_shared() {
    run(&compile_c("test_filter.c", Link::Shared));
}

#[test]
fn c_threads_static() {
    run(&compile_c("test_threads.c", Link::Static));
}

#[test]
fn c_threads_shared() {
    run(&compile_c("test_threads.c", Link::Shared));
}

/// One thread traces a committed two-level scene while another moves an
/// instance and commits: every trace OK (one committed state's hits, bit
/// for bit), CONTEXT_BUSY or NOT_BUILT.
#[test]
fn c_scene_threads_static() {
    run(&compile_c("test_scene_threads.c", Link::Static));
}

#[test]
fn c_scene_threads_shared() {
    run(&compile_c("test_scene_threads.c", Link::Shared));
}

/// The C ABI under misuse: the geometry borrow ends at clear_geometry, one
/// light check for every render, boolean bytes checked, overlaps refused,
/// render_rows touching its rows only, overflowing limits refused (memcheck
/// runs it too: `c_tests_under_valgrind`, where freed geometry read again
/// would fail the run).
#[test]
fn c_hardening_static() {
    run(&compile_c("test_hardening.c", Link::Static));
}

#[test]
fn c_hardening_shared() {
    run(&compile_c("test_hardening.c", Link::Shared));
}

/// `test_old_abi.c`: a program built against an older header (parameter
/// structs that end before the fields added since 0.2, declared without
/// sheaf.h) runs against this shared library: the defaults functions write
/// only its bytes, the missing fields take their defaults, every packet
/// method's hits equal the single ray's; a newer header's struct is read
/// while its unknown bytes are zero and refused once one is set
/// (docs/c-api.md, "Upgrading").
#[test]
fn c_old_abi_shared() {
    run(&compile_c("test_old_abi.c", Link::Shared));
}

/// `test_threads.c` under valgrind's helgrind (`SHEAF_TEST_QUICK=1`: fewer
/// rounds): no data race reported, and the only suppressions used are
/// valgrind's own defaults for glibc internals (`default.supp`, names
/// `helgrind-glibc*`; printed). sheaf's atomics tell helgrind their
/// happens-before edges (`sheaf::mem::hg`). Skipped with a message when
/// valgrind is not installed (CI installs it).
#[test]
fn c_threads_under_helgrind() {
    race_free(RaceTool::Helgrind, "test_threads.c");
}

/// `test_scene_threads.c` under helgrind, as `c_threads_under_helgrind`:
/// one thread traces the committed two-level scene while another moves an
/// instance and commits; 0 races, the same suppression rule.
#[test]
fn c_scene_threads_under_helgrind() {
    race_free(RaceTool::Helgrind, "test_scene_threads.c");
}

/// `test_threads.c` under valgrind's other race detector, DRD, which
/// honours the same client requests (`drd.h` gives its
/// `ANNOTATE_HAPPENS_BEFORE` / `_AFTER` helgrind's codes, the ones
/// `sheaf::mem::hg` sends): 0 errors, and only valgrind's own `drd-*`
/// defaults may be used (printed; none are now, see `RaceTool::Drd`).
#[test]
fn c_threads_under_drd() {
    race_free(RaceTool::Drd, "test_threads.c");
}

/// `test_scene_threads.c` under DRD, as `c_threads_under_drd`.
#[test]
fn c_scene_threads_under_drd() {
    race_free(RaceTool::Drd, "test_scene_threads.c");
}

#[derive(Clone, Copy, Debug)]
enum RaceTool {
    Helgrind,
    Drd,
}

impl RaceTool {
    fn name(self) -> &'static str {
        match self {
            RaceTool::Helgrind => "helgrind",
            RaceTool::Drd => "drd",
        }
    }

    /// The environment of the run.
    ///
    /// DRD: `LD_BIND_NOW=1`. Lazily bound, the first call of each libc
    /// function resolves its PLT slot in ld.so, whose
    /// `_dl_lookup_symbol_x` bumps a statistics counter (for
    /// `LD_DEBUG=statistics`) without a lock; a thread's first call
    /// after another thread's shows up as a conflicting load and store in
    /// ld.so's data section (6 in `test_threads.c`, 6 in
    /// `test_scene_threads.c`). Not sheaf's memory, and only a count that
    /// nothing reads here: valgrind's default `drd-ld` suppression would
    /// hide it, binding every symbol at startup (before any thread)
    /// removes it, so no suppression is needed.
    ///
    /// Helgrind: as it has always run. Its reports are on the test's own
    /// pthread mutexes, from inside glibc's `pthread_mutex_lock` /
    /// `_unlock` (the `__owner` and `__nusers` fields, written inside the
    /// lock before helgrind's wrapper records the acquisition), which
    /// valgrind's default `helgrind-glibc2X-005` (any race whose top frame
    /// is in libc) suppresses.
    fn env(self) -> &'static [(&'static str, &'static str)] {
        match self {
            RaceTool::Helgrind => &[],
            RaceTool::Drd => &[("LD_BIND_NOW", "1")],
        }
    }

    /// The only suppressions allowed: valgrind's own defaults for glibc
    /// and ld.so internals, never one for sheaf.
    fn allowed(self, used: &str) -> bool {
        let prefix = match self {
            RaceTool::Helgrind => "helgrind-glibc",
            RaceTool::Drd => "drd-",
        };
        used.contains(prefix) && used.contains("default.supp")
    }
}

/// `ffi-tests/<src>` (static) under `tool` (`--fair-sched=yes` so the
/// threads really interleave inside calls; `SHEAF_TEST_QUICK=1`, which
/// `test_threads.c` reads for fewer rounds): exit 0, "N passed, 0 failed",
/// `ERROR SUMMARY: 0 errors`, and only `tool.allowed` suppressions used
/// (printed, with the time taken). Skipped with a message when valgrind is
/// not installed (CI installs it).
fn race_free(tool: RaceTool, src: &str) {
    if !have_valgrind() {
        return;
    }
    check_layouts();
    let exe = compile_generated(
        &root().join("ffi-tests").join(src),
        Link::Static,
        &[],
        tool.name(),
    );
    let started = std::time::Instant::now();
    let out = Command::new("valgrind")
        .arg(format!("--tool={}", tool.name()))
        .args(["--fair-sched=yes", "--error-exitcode=99", "-v"])
        .arg(&exe)
        .env("SHEAF_TEST_QUICK", "1")
        .envs(tool.env().iter().copied())
        .env_remove("LD_LIBRARY_PATH")
        .output()
        .expect("run valgrind");
    let secs = started.elapsed().as_secs_f64();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let summary = stderr
        .lines()
        .find(|l| l.contains("ERROR SUMMARY"))
        .unwrap_or("no ERROR SUMMARY");
    let used: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("used_suppression:"))
        .collect();
    let name = tool.name();
    println!("{}\n{name} ({secs:.1} s): {summary}", stdout.trim_end());
    for u in &used {
        println!("{name} suppression: {}", u.trim());
    }
    assert!(
        out.status.success() && stdout.trim_end().ends_with(" passed, 0 failed"),
        "{src} under {name} failed ({}):\n{stdout}\n{stderr}",
        out.status
    );
    assert!(
        summary.contains("ERROR SUMMARY: 0 errors"),
        "{src} under {name}: {summary}"
    );
    for u in used {
        assert!(
            tool.allowed(u),
            "{src} under {name}: a suppression outside valgrind's glibc defaults was used: {u}"
        );
    }
}

/// `include/sheaf.hpp` as C++17 and C++20 (spans): its owners, both error
/// policies, owners released while an exception unwinds.
#[test]
fn hpp_owners_as_cpp17_and_cpp20() {
    for std in ["-std=c++17", "-std=c++20"] {
        for link in [Link::Static, Link::Shared] {
            run(&compile("g++", &[std], "test_hpp.cpp", link));
        }
    }
}

#[test]
fn cpp_static_and_shared() {
    for link in [Link::Static, Link::Shared] {
        run(&compile("g++", &["-std=c++11"], "test_cpp.cpp", link));
    }
}

/// The header alone, as several C and C++ standards.
#[test]
fn header_compiles_alone() {
    let header = root().join("include").join("sheaf.h");
    for (compiler, lang, std) in [
        ("gcc", "c", "-std=c99"),
        ("gcc", "c", "-std=c11"),
        ("g++", "c++", "-std=c++11"),
        ("g++", "c++", "-std=c++17"),
    ] {
        require(compiler);
        run_tool(
            Command::new(compiler)
                .args([
                    std,
                    "-Wall",
                    "-Wextra",
                    "-Werror",
                    "-pedantic",
                    "-fsyntax-only",
                    "-x",
                    lang,
                ])
                .arg(&header),
        );
    }
}

// ---- C results equal the Rust API's ------------------------------------------------------

fn hex_f32(s: &str) -> f32 {
    f32::from_bits(u32::from_str_radix(s, 16).unwrap_or_else(|_| panic!("bad float bits {s:?}")))
}

fn num(s: &str) -> u32 {
    s.parse().unwrap_or_else(|_| panic!("bad number {s:?}"))
}

#[derive(Default)]
struct Build {
    params: Option<GridParams>,
    stats: Vec<u32>,
    hits: BTreeMap<usize, Hit>,
    occluded: BTreeMap<usize, bool>,
    frame: Option<(Frame, usize)>,
    image: Option<u64>,
}

#[derive(Default)]
struct Emitted {
    limits: Option<Limits>,
    vertices: Vec<[f32; 3]>,
    indices: Vec<u32>,
    rays: Vec<Ray>,
    builds: BTreeMap<u32, Build>,
}

fn parse(stdout: &str) -> Emitted {
    let mut e = Emitted::default();
    for line in stdout.lines().filter(|l| l.starts_with('@')) {
        let f: Vec<&str> = line.split_whitespace().collect();
        let v3 = |at: usize| [hex_f32(f[at]), hex_f32(f[at + 1]), hex_f32(f[at + 2])];
        match f[0] {
            "@limits" => {
                let n: Vec<u32> = f[1..15].iter().map(|s| num(s)).collect();
                e.limits = Some(Limits {
                    max_triangles: n[0],
                    max_vertices: n[1],
                    max_image_width: n[2],
                    max_image_height: n[3],
                    max_tile: n[4],
                    max_threads: n[5],
                    max_grid_cells: n[6],
                    max_grid_refs: n[7],
                    projection_test: n[8] != 0,
                    structures: n[9],
                    max_kd_nodes: n[10],
                    max_kd_refs: n[11],
                    max_pgrid_cells: n[12],
                    max_pgrid_refs: n[13],
                    ..Limits::for_triangles(n[0])
                });
            }
            "@vertex" => {
                assert_eq!(num(f[1]) as usize, e.vertices.len());
                e.vertices.push(v3(2));
            }
            "@tri" => {
                assert_eq!(num(f[1]) as usize * 3, e.indices.len());
                e.indices.extend(f[2..5].iter().map(|s| num(s)));
            }
            "@ray" => {
                assert_eq!(num(f[1]) as usize, e.rays.len());
                e.rays.push(Ray {
                    org: v3(2),
                    tmin: hex_f32(f[5]),
                    dir: v3(6),
                    tmax: hex_f32(f[9]),
                });
            }
            "@build" => {
                let test = match num(f[2]) {
                    0 => TriTest::MollerTrumbore,
                    1 => TriTest::Watertight,
                    t => panic!("unknown test {t}"),
                };
                let p = GridParams {
                    lambda: hex_f32(f[3]),
                    macrocell: num(f[4]),
                    test,
                    fit: num(f[5]) != 0,
                };
                e.builds.entry(num(f[1])).or_default().params = Some(p);
            }
            "@stats" => {
                e.builds.entry(num(f[1])).or_default().stats =
                    f[2..].iter().map(|s| num(s)).collect()
            }
            "@hit" => {
                let h = Hit {
                    prim: num(f[3]),
                    t: hex_f32(f[4]),
                    u: hex_f32(f[5]),
                    v: hex_f32(f[6]),
                };
                e.builds
                    .entry(num(f[1]))
                    .or_default()
                    .hits
                    .insert(num(f[2]) as usize, h);
            }
            "@occ" => {
                e.builds
                    .entry(num(f[1]))
                    .or_default()
                    .occluded
                    .insert(num(f[2]) as usize, num(f[3]) != 0);
            }
            "@frame" => {
                let frame = Frame {
                    camera: Camera {
                        eye: v3(5),
                        look_at: v3(8),
                        up: v3(11),
                        fov_y_deg: hex_f32(f[14]),
                    },
                    light: PointLight {
                        position: v3(15),
                        color: v3(18),
                        ..Default::default()
                    },
                    shading: Shading {
                        albedo: v3(21),
                        ambient: hex_f32(f[24]),
                        background: v3(25),
                        shadows: num(f[28]) != 0,
                    },
                    width: num(f[2]),
                    height: num(f[3]),
                };
                e.builds.entry(num(f[1])).or_default().frame = Some((frame, num(f[4]) as usize));
            }
            "@image" => {
                let x = u64::from_str_radix(f[2], 16).expect("image checksum");
                e.builds.entry(num(f[1])).or_default().image = Some(x);
            }
            other => panic!("unknown line {other}"),
        }
    }
    e
}

fn fnv1a(pixels: &[u8], w: usize, h: usize, stride: usize) -> u64 {
    let mut x: u64 = 1469598103934665603;
    for r in 0..h {
        for &b in &pixels[r * stride..r * stride + 4 * w] {
            x ^= b as u64;
            x = x.wrapping_mul(1099511628211);
        }
    }
    x
}

fn same_hit(a: &Hit, b: &Hit) -> bool {
    a.prim == b.prim
        && a.t.to_bits() == b.t.to_bits()
        && a.u.to_bits() == b.u.to_bits()
        && a.v.to_bits() == b.v.to_bits()
}

fn crosscheck(link: Link) {
    let stdout = run(&compile_c("crosscheck.c", link));
    let e = parse(&stdout);
    let limits = e.limits.expect("@limits line");
    assert!(
        e.vertices.len() > 100 && e.indices.len() > 300 && e.rays.len() > 1000,
        "too little data emitted"
    );
    assert_eq!(
        e.builds.keys().copied().collect::<Vec<_>>(),
        [0, 1],
        "both grid configurations emitted"
    );

    // The same scene as in C: xyz plus one padding float per vertex (stride 16).
    let mut vbuf: Vec<f32> = Vec::new();
    for v in &e.vertices {
        vbuf.extend_from_slice(&[v[0], v[1], v[2], -1234.5]);
    }
    let bytes: Vec<u8> = vbuf.iter().flat_map(|x| x.to_ne_bytes()).collect();
    let scene = Scene::new(&bytes, 16, e.vertices.len() as u32, &e.indices).expect("scene");

    for (k, b) in &e.builds {
        let params = b.params.expect("@build line");
        let mut ctx = OwnedContext::new(&limits).expect("context");
        let info = ctx.build_grid(&scene, &params).expect("build");
        let want_stats = [
            info.triangles_in,
            info.triangles,
            info.excluded_non_finite,
            info.excluded_zero_area,
            info.res[0],
            info.res[1],
            info.res[2],
            info.refs,
        ];
        assert_eq!(b.stats, want_stats, "build {k}: C stats vs Rust GridInfo");

        let mut hits = vec![Hit::MISS; e.rays.len()];
        ctx.trace(Method::GridDda, &e.rays, &mut hits)
            .expect("trace");
        assert_eq!(b.hits.len(), e.rays.len(), "build {k}: one @hit per ray");
        let mut bad = Vec::new();
        for (i, want) in hits.iter().enumerate() {
            let got = &b.hits[&i];
            if !same_hit(got, want) {
                bad.push(format!(
                    "  ray {i} {:?}: C {got:?} vs Rust {want:?}",
                    e.rays[i]
                ));
            }
        }
        let n_hit = hits.iter().filter(|h| h.is_hit()).count();
        assert!(
            n_hit > e.rays.len() / 3,
            "build {k}: only {n_hit} hits: not a meaningful comparison"
        );
        assert!(
            bad.is_empty(),
            "build {k} ({params:?}): {} of {} hits differ:\n{}",
            bad.len(),
            hits.len(),
            bad[..bad.len().min(10)].join("\n")
        );

        let mut occ = vec![false; e.rays.len()];
        ctx.occluded(Method::GridDda, &e.rays, &mut occ)
            .expect("occluded");
        assert_eq!(
            b.occluded.len(),
            e.rays.len(),
            "build {k}: one @occ per ray"
        );
        let bad: Vec<usize> = (0..occ.len())
            .filter(|&i| b.occluded[&i] != occ[i])
            .collect();
        assert!(
            bad.is_empty(),
            "build {k}: occlusion differs for rays {bad:?}"
        );
        assert!(occ.iter().any(|&o| o) && occ.iter().any(|&o| !o));

        let (frame, stride) = b.frame.expect("@frame line");
        let (w, h) = (frame.width as usize, frame.height as usize);
        let mut pixels = vec![0u8; (h - 1) * stride + 4 * w];
        ctx.render(Method::GridDda, &frame, &mut pixels, stride)
            .expect("render");
        assert_eq!(
            b.image,
            Some(fnv1a(&pixels, w, h, stride)),
            "build {k}: rendered image differs"
        );
        println!(
            "build {k}: {} rays ({n_hit} hits), occlusion and a {w}x{h} image identical through C and Rust",
            hits.len()
        );
    }
}

#[test]
fn c_hits_equal_rust_api_static() {
    crosscheck(Link::Static);
}

#[test]
fn c_hits_equal_rust_api_shared() {
    crosscheck(Link::Shared);
}

// ---- no allocation after create ---------------------------------------------------------

/// Counts allocations made on threads that turned counting on.
struct CountingAlloc;

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

fn note_alloc() {
    let _ = COUNTING.try_with(|on| {
        if on.get() {
            let _ = ALLOCS.try_with(|n| n.set(n.get() + 1));
        }
    });
}

// SAFETY: forwards every call to the system allocator unchanged.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        note_alloc();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        note_alloc();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        note_alloc();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(p, l, new) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(p, l) }
    }
}

#[global_allocator]
static ALLOC: CountingAlloc = CountingAlloc;

/// Allocations made by `f` on this thread.
fn allocations<R>(f: impl FnOnce() -> R) -> (u64, R) {
    ALLOCS.with(|n| n.set(0));
    COUNTING.with(|c| c.set(true));
    let r = f();
    COUNTING.with(|c| c.set(false));
    (ALLOCS.with(|n| n.get()), r)
}

const OK: sheaf_status = sheaf_status::Ok;
const DDA: u32 = sheaf_method::GridDda as u32;

fn ground_and_box() -> (Vec<f32>, Vec<u32>) {
    let mut v = vec![
        -4.0, -4.0, 0.0, 4.0, -4.0, 0.0, 4.0, 4.0, 0.0, -4.0, 4.0, 0.0,
    ];
    let mut idx = vec![0, 1, 2, 0, 2, 3];
    for i in 0..8u32 {
        let c = |bit: u32, lo: f32, hi: f32| if i & bit != 0 { hi } else { lo };
        v.extend_from_slice(&[c(1, -0.5, 0.5), c(2, -0.5, 0.5), c(4, 0.0, 1.0)]);
    }
    for t in [
        [0, 2, 3],
        [0, 3, 1],
        [4, 5, 7],
        [4, 7, 6],
        [0, 1, 5],
        [0, 5, 4],
        [2, 6, 7],
        [2, 7, 3],
        [0, 4, 6],
        [0, 6, 2],
        [1, 3, 7],
        [1, 7, 5],
    ] {
        idx.extend(t.iter().map(|i| i + 4));
    }
    (v, idx)
}

/// Everything a session needs, allocated before counting starts.
struct Inputs {
    v: Vec<f32>,
    idx: Vec<u32>,
    bad_idx: Vec<u32>,
    rays: Vec<sheaf_ray>,
    hits: Vec<sheaf_hit>,
    occ: Vec<u8>,
    rgba: Vec<u8>,
    frame: sheaf_frame,
}

fn inputs() -> Inputs {
    let (v, idx) = ground_and_box();
    let mut bad_idx = idx.clone();
    bad_idx[4] = 99;
    let rays: Vec<sheaf_ray> = (0..64)
        .map(|i| {
            let x = -3.0 + 0.1 * i as f32;
            let tmax = if i % 2 == 0 { f32::INFINITY } else { 4.5 };
            sheaf_ray {
                org: [x, 0.3, 5.0],
                tmin: 0.0,
                dir: [0.1, 0.0, -1.0],
                tmax,
            }
        })
        .collect();
    let frame = sheaf_frame {
        camera: Camera {
            eye: [6.0, -8.0, 5.0],
            look_at: [0.0, 0.0, 0.5],
            up: [0.0, 0.0, 1.0],
            fov_y_deg: 40.0,
        },
        light: PointLight {
            position: [4.0, -3.0, 8.0],
            color: [1.0; 3],
            ..Default::default()
        },
        shading: ffi::sheaf_shading::of(&Shading::default()),
        width: 32,
        height: 24,
    };
    Inputs {
        v,
        idx,
        bad_idx,
        hits: vec![
            sheaf_hit {
                t: 0.0,
                prim: 0,
                u: 0.0,
                v: 0.0
            };
            rays.len()
        ],
        occ: vec![0; rays.len()],
        rays,
        rgba: vec![0; 32 * 24 * 4],
        frame,
    }
}

/// A whole session through the C ABI after creation, good and bad calls
/// (each error path formats into the last error). Returns how many calls
/// failed as expected.
fn session(ctx: *mut ffi::sheaf_context, x: &mut Inputs) -> u32 {
    let nt = (x.idx.len() / 3) as u32;
    let nv = (x.v.len() / 3) as u32;
    let mut failures = 0;
    let mut fail = |s: sheaf_status, want: sheaf_status| {
        assert_eq!(s, want);
        failures += 1;
    };
    let null = std::ptr::null_mut();
    // State errors, then geometry and build.
    fail(
        ffi::sheaf_context_build_grid(ctx, std::ptr::null()),
        sheaf_status::NoGeometry,
    );
    fail(
        ffi::sheaf_context_set_geometry(ctx, x.v.as_ptr(), 12, nv, x.bad_idx.as_ptr(), nt),
        sheaf_status::IndexOutOfRange,
    );
    fail(
        ffi::sheaf_context_set_geometry(ctx, std::ptr::null(), 12, 3, x.idx.as_ptr(), nt),
        sheaf_status::NullPointer,
    );
    assert_eq!(
        ffi::sheaf_context_set_geometry(ctx, x.v.as_ptr(), 12, nv, x.idx.as_ptr(), nt),
        OK
    );
    assert_eq!(ffi::sheaf_context_build_grid(ctx, std::ptr::null()), OK);
    let mut p = sheaf_grid_params {
        size: 0,
        lambda: 0.0,
        macrocell: 0,
        test: 0,
        fit: 0,
    };
    assert_eq!(ffi::sheaf_grid_params_default(&mut p, size_of_val(&p)), OK);
    p.test = 1;
    assert_eq!(ffi::sheaf_context_build_grid(ctx, &p), OK);
    p.lambda = f32::NAN;
    fail(
        ffi::sheaf_context_build_grid(ctx, &p),
        sheaf_status::InvalidArgument,
    );
    // Trace and occluded.
    let n = x.rays.len();
    assert_eq!(
        ffi::sheaf_context_trace(ctx, DDA, x.rays.as_ptr(), x.hits.as_mut_ptr(), n),
        OK
    );
    assert!(x.hits.iter().any(|h| h.prim != ffi::SHEAF_INVALID_ID));
    assert_eq!(
        ffi::sheaf_context_occluded(ctx, DDA, x.rays.as_ptr(), x.occ.as_mut_ptr(), n),
        OK
    );
    fail(
        ffi::sheaf_context_trace(ctx, 77, x.rays.as_ptr(), x.hits.as_mut_ptr(), n),
        sheaf_status::InvalidArgument,
    );
    fail(
        ffi::sheaf_context_trace(ctx, DDA, x.rays.as_ptr(), null, n),
        sheaf_status::NullPointer,
    );
    // Render and stats.
    assert_eq!(ffi::sheaf_shading_default(&mut x.frame.shading), OK);
    let len = x.rgba.len();
    assert_eq!(
        ffi::sheaf_context_render(ctx, DDA, &x.frame, x.rgba.as_mut_ptr(), 32 * 4, len),
        OK
    );
    fail(
        ffi::sheaf_context_render(ctx, DDA, &x.frame, x.rgba.as_mut_ptr(), 32 * 4, len - 1),
        sheaf_status::InvalidArgument,
    );
    let big = sheaf_frame {
        width: 5000,
        height: 1,
        ..x.frame
    };
    fail(
        ffi::sheaf_context_render(ctx, DDA, &big, x.rgba.as_mut_ptr(), 5000 * 4, len),
        sheaf_status::CapacityImage,
    );
    let mut stats = sheaf_stats::default();
    assert_eq!(ffi::sheaf_context_stats(ctx, &mut stats), OK);
    assert_eq!(stats.triangles, nt);
    // Last error (formatting with numbers), status strings, version.
    let mut msg = [0 as core::ffi::c_char; ffi::SHEAF_ERROR_MESSAGE_MAX];
    let mut written = 0usize;
    assert_eq!(
        ffi::sheaf_context_last_error(ctx, msg.as_mut_ptr(), msg.len(), &mut written),
        OK
    );
    assert!(written > 0);
    fail(
        ffi::sheaf_context_set_geometry(ctx, x.v.as_ptr(), 12, nv, x.bad_idx.as_ptr(), nt),
        sheaf_status::IndexOutOfRange,
    );
    assert_eq!(
        ffi::sheaf_context_last_error(ctx, msg.as_mut_ptr(), msg.len(), &mut written),
        OK
    );
    assert_eq!(
        ffi::sheaf_context_last_error(ctx, msg.as_mut_ptr(), 7, &mut written),
        OK
    );
    for s in sheaf_status::ALL {
        assert!(!ffi::sheaf_status_string(*s as u32).is_null());
    }
    assert!(!ffi::sheaf_status_string(4711).is_null());
    assert!(!ffi::sheaf_version_string().is_null());
    let mut limits = ffi::sheaf_limits::of(&Limits::for_triangles(1));
    assert_eq!(
        ffi::sheaf_limits_default(nt, &mut limits, size_of_val(&limits)),
        OK
    );
    let mut need = 0usize;
    assert_eq!(ffi::sheaf_required_bytes(&limits, &mut need), OK);
    failures
}

#[test]
fn no_allocation_after_create() {
    let mut x = inputs();
    let limits = Limits::for_triangles((x.idx.len() / 3) as u32);

    // sheaf_context_create: exactly one allocation; nothing afterwards.
    let mut ctx: *mut ffi::sheaf_context = std::ptr::null_mut();
    let (n, s) =
        allocations(|| ffi::sheaf_context_create(&ffi::sheaf_limits::of(&limits), &mut ctx));
    assert_eq!(s, OK);
    assert_eq!(n, 1, "sheaf_context_create must allocate exactly once");
    let (n, failures) = allocations(|| session(ctx, &mut x));
    assert!(failures >= 9, "{failures} error paths exercised");
    assert_eq!(
        n, 0,
        "a call through the C ABI allocated after sheaf_context_create"
    );
    ffi::sheaf_context_destroy(ctx);

    // sheaf_context_create_in: never.
    let mut x = inputs();
    let mut need = 0usize;
    assert_eq!(
        ffi::sheaf_required_bytes(&ffi::sheaf_limits::of(&limits), &mut need),
        OK
    );
    let mut buf = vec![0u64; need / 8 + 8];
    let off = buf.as_ptr().align_offset(ffi::SHEAF_CONTEXT_ALIGN);
    let base = buf[off..].as_mut_ptr().cast::<core::ffi::c_void>();
    let mut ctx: *mut ffi::sheaf_context = std::ptr::null_mut();
    let (n, s) = allocations(|| {
        let s = ffi::sheaf_context_create_in(base, need, &ffi::sheaf_limits::of(&limits), &mut ctx);
        assert_eq!(s, OK);
        session(ctx, &mut x);
        ffi::sheaf_context_destroy(ctx);
        s
    });
    assert_eq!(s, OK);
    assert_eq!(
        n, 0,
        "sheaf_context_create_in and the calls on its context must never allocate"
    );
}

/// The results through the C ABI equal the Rust API's, in process too (all
/// three tests and both structures' parameters).
#[test]
fn ffi_trace_equals_rust_trace_in_process() {
    let (v, idx) = ground_and_box();
    let nt = (idx.len() / 3) as u32;
    let limits = Limits::for_triangles(nt);
    let scene = Scene::from_f32(&v, &idx).unwrap();
    let rays: Vec<Ray> = (0..400)
        .map(|i| {
            let a = i as f32 * 0.37;
            Ray::new(
                glam::Vec3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.2 + (i % 9) as f32 * 0.3),
                glam::Vec3::new(-a.cos(), -a.sin(), -0.3),
                0.0,
                f32::INFINITY,
            )
        })
        .collect();
    let cray: Vec<sheaf_ray> = rays
        .iter()
        .map(|r| sheaf_ray {
            org: r.org,
            tmin: r.tmin,
            dir: r.dir,
            tmax: r.tmax,
        })
        .collect();
    for test in [TriTest::MollerTrumbore, TriTest::Watertight] {
        let params = GridParams {
            test,
            ..GridParams::default()
        };
        let mut rust = OwnedContext::new(&limits).unwrap();
        rust.build_grid(&scene, &params).unwrap();
        let mut want = vec![Hit::MISS; rays.len()];
        rust.trace(Method::GridDda, &rays, &mut want).unwrap();

        let mut ctx: *mut ffi::sheaf_context = std::ptr::null_mut();
        assert_eq!(
            ffi::sheaf_context_create(&ffi::sheaf_limits::of(&limits), &mut ctx),
            OK
        );
        assert_eq!(
            ffi::sheaf_context_set_geometry(
                ctx,
                v.as_ptr(),
                12,
                (v.len() / 3) as u32,
                idx.as_ptr(),
                nt
            ),
            OK
        );
        let cp = sheaf_grid_params::of(&params);
        assert_eq!(ffi::sheaf_context_build_grid(ctx, &cp), OK);
        let mut got = vec![
            sheaf_hit {
                t: 0.0,
                prim: 0,
                u: 0.0,
                v: 0.0
            };
            rays.len()
        ];
        assert_eq!(
            ffi::sheaf_context_trace(ctx, DDA, cray.as_ptr(), got.as_mut_ptr(), cray.len()),
            OK
        );
        ffi::sheaf_context_destroy(ctx);
        assert!(want.iter().filter(|h| h.is_hit()).count() > 100);
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            let g = Hit {
                t: g.t,
                prim: g.prim,
                u: g.u,
                v: g.v,
            };
            assert!(
                same_hit(&g, w),
                "{test:?} ray {i}: C ABI {g:?} vs Rust {w:?}"
            );
        }
    }
}

/// Deferred frames through the C ABI (perspective grid, light grids, two
/// lights one of them a spot): byte for byte the Rust API's
/// `render_deferred`, the same per-pixel hits and shadow bits, and no call
/// allocates, error paths included.
#[test]
fn deferred_frames_equal_rust_and_never_allocate() {
    use sheaf::{DeferredJob, OnCaller, PgridParams, PrimaryPass, ShadowPass, TraceParams};
    let x = inputs();
    let (w, h) = (x.frame.width, x.frame.height);
    let nt = (x.idx.len() / 3) as u32;
    let mut limits = Limits::for_triangles(nt);
    limits.max_image_width = w;
    limits.max_image_height = h;
    limits.structures = Limits::BVH | Limits::PGRID;
    let spot = PointLight {
        position: [-3.0, -2.0, 6.0],
        color: [0.6, 0.5, 0.3],
        spot_direction: [3.0, 2.0, -6.0],
        spot_angle_deg: 25.0,
        spot_soft_deg: 5.0,
    };
    let lights = [x.frame.light, spot];
    let nine = [x.frame.light; 9];
    let tp = ffi::sheaf_trace_params::of(&TraceParams::default());
    let job = ffi::sheaf_deferred_job {
        frame: x.frame,
        lights: lights.as_ptr(),
        light_count: lights.len(),
        primary_pgrid: 1,
        shadow_light_grid: 1,
        primary: &tp,
        shadow: &tp,
    };
    let too_many = ffi::sheaf_deferred_job {
        lights: nine.as_ptr(),
        light_count: nine.len(),
        ..job
    };
    let stride = w as usize * 4;
    let mut rgba = vec![0u8; stride * h as usize];
    let len = rgba.len();
    let mut pixels = vec![
        (
            sheaf_hit {
                t: 0.0,
                prim: 0,
                u: 0.0,
                v: 0.0
            },
            0u8
        );
        (w * h) as usize
    ];
    let mut st = sheaf_stats::default();
    let mut ctx: *mut ffi::sheaf_context = std::ptr::null_mut();
    assert_eq!(
        ffi::sheaf_context_create(&ffi::sheaf_limits::of(&limits), &mut ctx),
        OK
    );
    let (n, ()) = allocations(|| {
        let nv = (x.v.len() / 3) as u32;
        assert_eq!(
            ffi::sheaf_context_render_deferred(ctx, &job, rgba.as_mut_ptr(), stride, len),
            sheaf_status::NotBuilt
        );
        assert_eq!(
            ffi::sheaf_context_set_geometry(ctx, x.v.as_ptr(), 12, nv, x.idx.as_ptr(), nt),
            OK
        );
        assert_eq!(ffi::sheaf_context_build_pgrid(ctx, std::ptr::null()), OK);
        assert_eq!(
            ffi::sheaf_context_render_deferred(ctx, &job, rgba.as_mut_ptr(), stride, len),
            OK
        );
        for y in 0..h {
            for xx in 0..w {
                let p = &mut pixels[(y * w + xx) as usize];
                assert_eq!(
                    ffi::sheaf_context_deferred_pixel(ctx, xx, y, &mut p.0, &mut p.1),
                    OK
                );
            }
        }
        assert_eq!(ffi::sheaf_context_stats(ctx, &mut st), OK);
        let mut ray = x.rays[0];
        let mut has = false;
        assert_eq!(
            ffi::sheaf_context_deferred_shadow_ray(ctx, w / 2, h / 2, &spot, &mut ray, &mut has),
            OK
        );
        assert_eq!(ffi::sheaf_frame_camera_ray(&x.frame, 1, 2, &mut ray), OK);
        assert_eq!(
            ffi::sheaf_context_render_deferred(ctx, &too_many, rgba.as_mut_ptr(), stride, len),
            sheaf_status::InvalidArgument
        );
        assert_eq!(
            ffi::sheaf_context_render_deferred(
                ctx,
                std::ptr::null(),
                rgba.as_mut_ptr(),
                stride,
                len
            ),
            sheaf_status::NullPointer
        );
        assert_eq!(
            ffi::sheaf_context_deferred_pixel(ctx, w, 0, &mut pixels[0].0, &mut pixels[0].1),
            sheaf_status::InvalidArgument
        );
        let mut msg = [0 as core::ffi::c_char; ffi::SHEAF_ERROR_MESSAGE_MAX];
        let mut written = 0usize;
        assert_eq!(
            ffi::sheaf_context_last_error(ctx, msg.as_mut_ptr(), msg.len(), &mut written),
            OK
        );
    });
    ffi::sheaf_context_destroy(ctx);
    assert_eq!(n, 0, "a deferred call through the C ABI allocated");

    // The same frame through the Rust API.
    let scene = Scene::from_f32(&x.v, &x.idx).unwrap();
    let mut rust = OwnedContext::new(&limits).unwrap();
    rust.build_pgrid(&scene, &PgridParams::default()).unwrap();
    let frame = x.frame.to_core().unwrap();
    let rjob = DeferredJob {
        frame: &frame,
        lights: &lights,
        primary: PrimaryPass::Pgrid,
        shadow: ShadowPass::LightGrid,
    };
    let mut want = vec![0u8; len];
    let info = rust
        .render_deferred(&rjob, &mut want, stride, &mut OnCaller)
        .unwrap();
    assert!(
        rgba == want,
        "deferred image through C differs from the Rust API's"
    );
    assert_eq!(
        (
            st.hits,
            st.shadow_rays,
            st.reorder_chunks,
            st.camera_refs,
            st.light_refs
        ),
        (
            info.hits,
            info.shadow_rays,
            info.reorder.chunks,
            info.camera.refs,
            info.light.refs
        )
    );
    let mut shadowed = 0;
    for y in 0..h {
        for xx in 0..w {
            let (hit, bits) = rust.deferred_pixel(xx, y).unwrap();
            let (got, got_bits) = pixels[(y * w + xx) as usize];
            assert!(
                got.prim == hit.prim && got.t.to_bits() == hit.t.to_bits() && got_bits == bits,
                "pixel ({xx}, {y}): C {got:?} {got_bits:#x} vs Rust {hit:?} {bits:#x}"
            );
            shadowed += (bits != 0) as u32;
        }
    }
    assert!(st.hits > 100 && shadowed > 0, "not a meaningful comparison");
}

// ---- test_capacity.c: capacity errors keep the previous frame --------------------------

#[test]
fn c_capacity_static() {
    run(&compile_c("test_capacity.c", Link::Static));
}

#[test]
fn c_capacity_shared() {
    run(&compile_c("test_capacity.c", Link::Shared));
}

// ---- sheaf_version() from C equals the header's SHEAF_VERSION ----------------------------

#[test]
fn version_from_c_matches_header_and_crate() {
    let src = out_dir().join("version.c");
    std::fs::write(
        &src,
        "#include \"sheaf.h\"\n#include <stdio.h>\n#include <string.h>\n\
         int main(void) {\n\
         printf(\"%u %u %s\\n\", (unsigned)SHEAF_VERSION, (unsigned)sheaf_version(), sheaf_version_string());\n\
         return SHEAF_VERSION == sheaf_version() &&\n\
         SHEAF_VERSION == SHEAF_VERSION_MAJOR * 10000 + SHEAF_VERSION_MINOR * 100 + SHEAF_VERSION_PATCH ? 0 : 1;\n}\n",
    )
    .unwrap();
    let want = format!(
        "{v} {v} {}",
        env!("CARGO_PKG_VERSION"),
        v = sheaf::ffi::version::SHEAF_VERSION
    );
    for link in [Link::Static, Link::Shared] {
        let exe = compile_generated(&src, link, &[], "plain");
        let out = Command::new(&exe)
            .env_remove("LD_LIBRARY_PATH")
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "{}: {text}", exe.display());
        assert_eq!(
            text.trim(),
            want,
            "{link:?}: SHEAF_VERSION / sheaf_version() / string"
        );
    }
}

// ---- the C programs under AddressSanitizer + UBSan and valgrind -------------------------

/// Every C test program of ffi-tests/ (new ones are covered automatically).
fn c_programs() -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(root().join("ffi-tests"))
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".c"))
        .collect();
    v.sort();
    assert!(v.len() >= 3, "ffi-tests/*.c: {v:?}");
    v
}

/// Compile `src` (a path) like `compile`, with `extra` flags, into an exe
/// named after `tag`.
fn compile_generated(src: &Path, link: Link, extra: &[&str], tag: &str) -> PathBuf {
    require("gcc");
    let lib = lib_dir();
    let stem = src.file_stem().unwrap().to_string_lossy().into_owned();
    let exe = out_dir().join(format!(
        "{stem}-{}-{tag}",
        format!("{link:?}").to_lowercase()
    ));
    let mut cmd = Command::new("gcc");
    cmd.args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-g"])
        .args(extra)
        .arg("-I")
        .arg(root().join("include"))
        .arg(src)
        .arg("-o")
        .arg(&exe)
        .arg("-L")
        .arg(&lib);
    match link {
        Link::Static => cmd.args(["-l:libsheaf.a", "-lm", "-lpthread", "-ldl"]),
        Link::Shared => cmd
            .arg("-lsheaf")
            .arg(format!("-Wl,-rpath,{}", lib.display()))
            .args(["-Wl,--disable-new-dtags", "-lm", "-lpthread"]),
    };
    run_tool(&mut cmd);
    exe
}

/// Run `cmd` (a test program, possibly under a tool): exit 0 and a final
/// "N passed, 0 failed" line.
fn run_checked(mut cmd: Command, what: &str) {
    let out = cmd
        .env_remove("LD_LIBRARY_PATH")
        .output()
        .unwrap_or_else(|e| panic!("cannot run {what}: {e}"));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let report: Vec<&str> = stdout.lines().filter(|l| !l.starts_with('@')).collect();
    let last = report.last().copied().unwrap_or("");
    assert!(
        out.status.success() && last.ends_with(" passed, 0 failed"),
        "{what} failed ({}):\n{}\n{stderr}",
        out.status,
        report.join("\n")
    );
    println!("{what}: {last}");
}

const SANITIZE: &[&str] = &[
    "-fsanitize=address,undefined",
    "-fno-omit-frame-pointer",
    "-fno-sanitize-recover=all",
];

/// Whether gcc links a program with `flags` (libasan/libubsan installed).
fn gcc_supports(flags: &[&str]) -> bool {
    require("gcc");
    let src = out_dir().join("probe-sanitizer.c");
    std::fs::write(&src, "int main(void) { return 0; }\n").unwrap();
    Command::new("gcc")
        .args(flags)
        .arg(&src)
        .arg("-o")
        .arg(out_dir().join("probe-sanitizer"))
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

/// Every C test program, built with `-fsanitize=address,undefined` against
/// the static and the shared library (Rust code is not instrumented; ASan
/// sees the C side's accesses, every allocation and leak, UBSan the C
/// side's undefined behaviour). Any report fails the run.
#[test]
fn c_tests_under_asan_and_ubsan() {
    if !gcc_supports(SANITIZE) {
        println!("SKIPPED: gcc cannot link with {SANITIZE:?} (apt-get install libasan8 libubsan1)");
        return;
    }
    check_layouts();
    for src in c_programs() {
        for link in [Link::Static, Link::Shared] {
            let exe =
                compile_generated(&root().join("ffi-tests").join(&src), link, SANITIZE, "asan");
            let mut cmd = Command::new(&exe);
            cmd.env(
                "ASAN_OPTIONS",
                "detect_leaks=1:halt_on_error=1:detect_stack_use_after_return=1:strict_string_checks=1",
            )
            .env("UBSAN_OPTIONS", "print_stacktrace=1:halt_on_error=1");
            run_checked(cmd, &format!("{src} ({link:?}, ASan+UBSan)"));
        }
    }
}

/// Whether valgrind runs here; prints the skip message when not (CI
/// installs it).
fn have_valgrind() -> bool {
    let ok = Command::new("valgrind")
        .arg("--version")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok {
        println!("SKIPPED: valgrind not found (apt-get install valgrind)");
    }
    ok
}

/// Every C test program under valgrind's memcheck (uninitialised reads,
/// invalid accesses, leaks: `--error-exitcode=99 --leak-check=full`) linked
/// to the shared library (the same code as the static link, which runs
/// under ASan and UBSan above; memcheck of both links took 41 s, half of
/// it repeating the other's), except `test_threads.c`: valgrind runs threads one at a time,
/// which takes that program about a minute per link, and `test_stack.c`,
/// which paints the stack below the stack pointer to measure it (both run
/// under ASan above). Skipped with a message when valgrind is not installed (CI
/// installs it).
#[test]
fn c_tests_under_valgrind() {
    if !have_valgrind() {
        return;
    }
    check_layouts();
    let skip = ["test_threads.c", "test_stack.c"];
    for src in c_programs()
        .into_iter()
        .filter(|s| !skip.contains(&s.as_str()))
    {
        let link = Link::Shared;
        let exe = compile_generated(&root().join("ffi-tests").join(&src), link, &[], "valgrind");
        let mut cmd = Command::new("valgrind");
        cmd.args([
            "--error-exitcode=99",
            "--leak-check=full",
            "--errors-for-leak-kinds=definite,indirect",
            "--quiet",
        ])
        .arg(&exe);
        run_checked(cmd, &format!("{src} ({link:?}, valgrind)"));
    }
}
