//! Smoke test of the Embree 3 comparison (`benches/embree`): when Debian's
//! libembree-dev is installed, export two small built-in scenes with
//! `sheaf export`, build `benches/embree/embree_bench.c` against the
//! `libsheaf.a` built with this test, run it in its quick configuration
//! (small images, one timed run) with `--check`, and assert on its
//! agreement summary:
//!
//! - every sheaf method returned the reference's answers (BVH single ray)
//!   and the C program's camera and shadow rays are bit for bit those of a
//!   sheaf deferred frame;
//! - sheaf and Embree disagree on no camera ray and no shadow ray that
//!   the f64 check cannot explain as a tie or an edge (or, for shadow rays,
//!   an occluder at the ray's end): `MAX_UNEXPLAINED`;
//! - the explained disagreements stay small: at most `MAX_EDGE_TIE_RAYS`
//!   rays per scene, and the hit (occlusion) counts differ by no more.
//!
//! Without Embree (no `/usr/include/embree3/rtcore.h`) or without gcc it
//! prints why and passes. No timing is asserted.
//!
//! It lives in the CLI's crate for `CARGO_BIN_EXE_sheaf`; the kernel's
//! `libsheaf.a` is the one cargo built for this crate (a dependency's
//! library is built with every crate type of its `[lib]`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Disagreements neither a tie nor an edge explains (per scene and Embree
/// build quality): none.
const MAX_UNEXPLAINED: f64 = 0.0;
/// Rays (camera or shadow) on which the libraries may disagree per scene
/// and quality, each explained as a tie between two triangles at the same
/// depth or a ray grazing an edge: watertightness and tie rules differ
/// (sheaf takes the lower triangle id at equal t, Embree either).
const MAX_EDGE_TIE_RAYS: f64 = 8.0;
/// The scenes and image sizes of the smoke test.
const SCENES: &[(&str, &str)] = &[
    ("builtin:tetra", "256x256"),
    ("builtin:animated", "128x128"),
];

/// The workspace root: the kernel's package, with include/ and benches/.
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The directory holding the `libsheaf.a` built with this test binary
/// (`target/<profile>/deps`, where `cargo test` writes every crate type of
/// [lib]; else `target/<profile>`), as `tests/c_abi.rs` finds it.
fn lib_dir() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    let deps = exe.parent()?.to_path_buf();
    if deps.join("libsheaf.a").is_file() {
        return Some(deps);
    }
    let profile = deps.parent()?.to_path_buf();
    profile.join("libsheaf.a").is_file().then_some(profile)
}

fn skip(why: &str) {
    println!("embree_bench: skipped: {why}");
}

/// The program built into its own directory `name` under the test's
/// temporary directory (`None`, with the reason printed, without Embree or
/// gcc).
fn program(name: &str) -> Option<(PathBuf, PathBuf)> {
    if !Path::new("/usr/include/embree3/rtcore.h").is_file() {
        skip("Embree 3 not installed (apt-get install libembree-dev)");
        return None;
    }
    if Command::new("gcc").arg("--version").output().is_err() {
        skip("gcc not found");
        return None;
    }
    let lib = lib_dir().expect(
        "libsheaf.a next to the test binary: cargo builds every crate type of the kernel's [lib]",
    );
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    std::fs::create_dir_all(&dir).unwrap();
    // Link a copy: another cargo build in the same target directory may be
    // replacing the library while this test runs.
    let copy = dir.join("libsheaf.a");
    let copied = (0..10).any(|i| {
        if i > 0 {
            std::thread::sleep(std::time::Duration::from_millis(500));
        }
        std::fs::copy(lib.join("libsheaf.a"), &copy).is_ok()
    });
    assert!(copied, "cannot copy {}/libsheaf.a", lib.display());

    // The program, as benches/embree/Makefile builds it.
    let exe = dir.join("embree_bench");
    let out = Command::new("gcc")
        .args([
            "-std=c99",
            "-O2",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-pedantic",
            "-ffp-contract=off",
        ])
        .arg("-I")
        .arg(root().join("include"))
        .arg(root().join("benches/embree/embree_bench.c"))
        .arg("-o")
        .arg(&exe)
        .arg(format!("-L{}", dir.display()))
        .args(["-l:libsheaf.a", "-lembree3", "-lm", "-lpthread", "-ldl"])
        .output()
        .expect("running gcc");
    assert!(
        out.status.success(),
        "gcc failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some((exe, dir))
}

/// `sheaf export SCENE --size SIZE [extra]` into `dir`.
fn export(dir: &Path, scene: &str, size: &str, extra: &[&str]) -> PathBuf {
    let f = dir.join(format!("{}.scene", scene.trim_start_matches("builtin:")));
    let out = Command::new(env!("CARGO_BIN_EXE_sheaf"))
        .args(["export", scene, "--size", size])
        .args(extra)
        .arg("--out")
        .arg(&f)
        .output()
        .expect("running sheaf export");
    assert!(
        out.status.success(),
        "sheaf export {scene} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    f
}

/// `scene key=value` lines of a summary file: scene -> key -> value.
fn read_summary(path: &Path) -> BTreeMap<String, BTreeMap<String, f64>> {
    let mut sum: BTreeMap<String, BTreeMap<String, f64>> = BTreeMap::new();
    for line in std::fs::read_to_string(path).unwrap().lines() {
        let (scene, kv) = line.split_once(' ').expect("scene key=value");
        let (k, v) = kv.split_once('=').expect("key=value");
        sum.entry(scene.into())
            .or_default()
            .insert(k.into(), v.parse().expect("a number"));
    }
    sum
}

#[test]
fn sheaf_and_embree_agree_on_the_quick_scenes() {
    let Some((exe, dir)) = program("embree-bench") else {
        return;
    };
    let files: Vec<PathBuf> = SCENES
        .iter()
        .map(|(scene, size)| export(&dir, scene, size, &[]))
        .collect();

    let summary = dir.join("summary.txt");
    let out = Command::new(&exe)
        .args(["--reps", "1", "--check", "--summary"])
        .arg(&summary)
        .args(&files)
        .output()
        .expect("running embree_bench");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "embree_bench --check failed ({}):\n{stderr}\n{stdout}",
        out.status
    );
    assert!(
        stdout.contains("### tetra") && stdout.contains("**Agreement**"),
        "{stdout}"
    );

    let sum = read_summary(&summary);
    assert_eq!(sum.len(), SCENES.len(), "one summary per scene: {sum:?}");
    for (scene, m) in &sum {
        let get = |k: &str| {
            *m.get(k)
                .unwrap_or_else(|| panic!("{scene}: no {k} in the summary"))
        };
        assert!(
            get("primary_rays") > 0.0 && get("sheaf_hits") > 0.0,
            "{scene}: no hits"
        );
        assert!(get("shadow_rays") > 0.0, "{scene}: no shadow rays");
        assert_eq!(
            get("sheaf_internal_mismatch"),
            0.0,
            "{scene}: a sheaf method differs from the reference"
        );
        assert_eq!(
            get("ray_check_mismatch"),
            0.0,
            "{scene}: rays differ from sheaf's deferred frame"
        );
        for q in ["LOW", "MEDIUM", "HIGH"] {
            for kind in ["primary", "shadow"] {
                let other = get(&format!("{kind}_{q}_other"));
                let differ = get(&format!("{kind}_{q}_differ"));
                let embree = get(&format!("{kind}_{q}_hits_embree"));
                let sheaf_count = get(if kind == "primary" {
                    "sheaf_hits"
                } else {
                    "sheaf_occluded"
                });
                assert!(
                    other <= MAX_UNEXPLAINED,
                    "{scene} {kind} {q}: {other} unexplained disagreements"
                );
                assert!(
                    differ <= MAX_EDGE_TIE_RAYS,
                    "{scene} {kind} {q}: {differ} rays differ (ties and edges), more than {MAX_EDGE_TIE_RAYS}"
                );
                assert!(
                    (embree - sheaf_count).abs() <= MAX_EDGE_TIE_RAYS,
                    "{scene} {kind} {q}: sheaf {sheaf_count} hits, Embree {embree}"
                );
            }
        }
        println!(
            "embree_bench: {scene}: {} camera rays, {} hits, {} shadow rays: sheaf and Embree agree \
             (differing rays LOW/MEDIUM/HIGH: primary {}/{}/{}, shadow {}/{}/{})",
            get("primary_rays"),
            get("sheaf_hits"),
            get("shadow_rays"),
            get("primary_LOW_differ"),
            get("primary_MEDIUM_differ"),
            get("primary_HIGH_differ"),
            get("shadow_LOW_differ"),
            get("shadow_MEDIUM_differ"),
            get("shadow_HIGH_differ"),
        );
    }
}

/// The two-level scene: gears as the environment, the animated mesh refit
/// in 4 instances, a ring of 16 tetrahedra; both libraries trace the same
/// camera and shadow rays through their instances, and agree on all but the
/// rays `--check` allows (`TL_MAX_DIFF_FRACTION`, 1e-4 of the rays; not
/// classified as ties or edges).
#[test]
fn sheaf_and_embree_agree_on_the_two_level_scene() {
    let Some((exe, dir)) = program("embree-bench-twolevel") else {
        return;
    };
    let env = export(&dir, "builtin:gears", "128x128", &[]);
    let anim = export(&dir, "builtin:animated", "128x128", &["--frames", "3"]);
    let obj = export(&dir, "builtin:tetra", "128x128", &[]);
    // Plain, then with the animated mesh cut out by filters in both
    // libraries (the same pure function of the candidate).
    for filter in [false, true] {
        let summary = dir.join(format!("summary-{filter}.txt"));
        let out = Command::new(&exe)
            .arg("--twolevel")
            .args([&env, &anim, &obj])
            .args(["--frames", "2", "--reps", "1", "--threads", "1", "--check"])
            .args(filter.then_some("--filter"))
            .arg("--summary")
            .arg(&summary)
            .output()
            .expect("running embree_bench --twolevel");
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "embree_bench --twolevel --check (filter {filter}) failed ({}):\n{}\n{stdout}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        );
        let sum = read_summary(&summary);
        let m = &sum["twolevel"];
        let get = |k: &str| *m.get(k).unwrap_or_else(|| panic!("no {k} in the summary"));
        // The agreement bound is `--check`'s exit status, asserted above.
        assert!(get("camera_rays") > 0.0 && get("shadow_rays") > 0.0);
        println!(
            "embree_bench: two-level (filter {filter}): {} of {} camera rays and {} of {} shadow rays differ",
            get("camera_differ"),
            get("camera_rays"),
            get("shadow_differ"),
            get("shadow_rays")
        );
    }
}
