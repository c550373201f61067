//! Finds Debian's Embree 3 (libembree-dev) for `sheaf bench`'s reference
//! points: with its header and library present (and the instance-level
//! layout `studies::embree` declares), the CLI links libembree3 and is
//! compiled with `--cfg embree`; otherwise the bench runs without Embree.
//! `SHEAF_NO_EMBREE=1` leaves it out.
use std::path::Path;

fn main() {
    println!("cargo::rustc-check-cfg=cfg(embree)");
    println!("cargo::rerun-if-env-changed=SHEAF_NO_EMBREE");
    let config = Path::new("/usr/include/embree3/rtcore_config.h");
    println!("cargo::rerun-if-changed={}", config.display());
    if std::env::var_os("SHEAF_NO_EMBREE").is_some_and(|v| v == "1") {
        return;
    }
    let Ok(text) = std::fs::read_to_string(config) else {
        return;
    };
    // The FFI declares RTCIntersectContext for one instance level and no
    // minimum curve width (Debian's build): anything else is left out.
    let one_level = text.contains("#define RTC_MAX_INSTANCE_LEVEL_COUNT 1\n");
    let no_min_width = text.contains("#define EMBREE_MIN_WIDTH 0\n");
    let lib = [
        "/usr/lib/x86_64-linux-gnu",
        "/usr/lib/aarch64-linux-gnu",
        "/usr/lib",
    ]
    .iter()
    .find(|d| Path::new(d).join("libembree3.so").exists());
    if let (true, true, Some(dir)) = (one_level, no_min_width, lib) {
        println!("cargo::rustc-link-search=native={dir}");
        println!("cargo::rustc-link-lib=dylib=embree3");
        println!("cargo::rustc-cfg=embree");
    }
}
