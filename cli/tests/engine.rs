//! Smoke test of `sheaf demo` (the engine loop, alias `sheaf engine`) on
//! the built-in gears environment, with each family: it runs to the end,
//! prints a table line per frame (and with the BVH the comparison with the
//! flattened frame), and writes every frame's PNG and the animated PNG. The
//! grid and the kd-tree trace the same flattened triangles with the same
//! test, so their frames are equal byte for byte; the two-level BVH meets
//! the triangles in object space instead, so its frame may differ where
//! transform rounding moves a hit across an edge (a check that the families
//! see the same scene, not an exactness claim: that is
//! `tests/exact/twolevel_exact.rs`'s). Timing is printed, never asserted.

use std::path::{Path, PathBuf};
use std::process::Command;

/// `sheaf demo --family FAMILY` for 3 frames into its own directory.
fn run(family: &str) -> (PathBuf, String) {
    let sheaf = env!("CARGO_BIN_EXE_sheaf");
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("engine-{family}"));
    let _ = std::fs::remove_dir_all(&dir);
    let out = Command::new(sheaf)
        .args(["demo", "--frames", "3", "--size", "64x48"])
        .args(["--env", "builtin:gears", "--family", family])
        .args(["--packet", "4", "--threads", "2", "--out-dir"])
        .arg(&dir)
        .output()
        .expect("run sheaf demo");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "sheaf demo --family {family} failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rows = stdout
        .lines()
        .filter(|l| {
            l.split_whitespace()
                .next()
                .is_some_and(|w| w.parse::<u32>().is_ok())
        })
        .count();
    assert_eq!(rows, 3, "{family}: one table line per frame:\n{stdout}");
    for f in ["frame_000.png", "frame_001.png", "frame_002.png"] {
        let len = std::fs::metadata(dir.join(f)).map(|m| m.len()).unwrap_or(0);
        assert!(len > 0, "{f} missing or empty in {}", dir.display());
    }
    let apng = std::fs::read(dir.join("engine.png")).expect("engine.png");
    assert!(
        apng.windows(4).any(|w| w == b"acTL"),
        "engine.png is an animated PNG"
    );
    (dir, stdout)
}

fn pixels(path: &Path) -> Vec<u8> {
    let dec = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(path).expect("frame"),
    ));
    let mut r = dec.read_info().expect("png");
    let mut buf = vec![0; r.output_buffer_size().expect("size")];
    let info = r.next_frame(&mut buf).expect("frame");
    buf.truncate(info.buffer_size());
    buf
}

#[test]
fn engine_loop_runs_and_writes_its_frames() {
    let (bvh, stdout) = run("bvh");
    assert!(
        stdout.contains("flattened"),
        "the flattened comparison:\n{stdout}"
    );
    let frame = |dir: &Path| pixels(&dir.join("frame_002.png"));
    let (grid, _) = run("grid");
    let (kd, _) = run("kd");
    assert!(frame(&grid) == frame(&kd), "grid and kd-tree frames differ");
    // The BVH's frame: the same scene, up to transform rounding at edges.
    let (a, b) = (frame(&bvh), frame(&grid));
    assert_eq!(a.len(), b.len());
    let differ = a.chunks(4).zip(b.chunks(4)).filter(|(x, y)| x != y).count();
    assert!(
        differ * 50 <= a.len() / 4,
        "{differ} of {} pixels of the two-level BVH's frame differ from the flattened grid's",
        a.len() / 4
    );
}
