//! Smoke test of `sheaf engine` (issue 19's engine loop) on the built-in
//! gears environment: it runs to the end, prints a table line per frame
//! and the comparison with the flattened frame, and writes every frame's
//! PNG and the animated PNG. Timing is printed, never asserted.

use std::path::Path;
use std::process::Command;

#[test]
fn engine_loop_runs_and_writes_its_frames() {
    let sheaf = env!("CARGO_BIN_EXE_sheaf");
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("engine");
    let _ = std::fs::remove_dir_all(&dir);
    let out = Command::new(sheaf)
        .args([
            "engine",
            "--frames",
            "3",
            "--size",
            "64x48",
            "--env",
            "builtin:gears",
        ])
        .args(["--packet", "4", "--threads", "2", "--out-dir"])
        .arg(&dir)
        .output()
        .expect("run sheaf engine");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "sheaf engine failed:\n{stdout}\n{}",
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
    assert_eq!(rows, 3, "one table line per frame:\n{stdout}");
    assert!(
        stdout.contains("flattened"),
        "the flattened comparison:\n{stdout}"
    );
    for f in ["frame_000.png", "frame_001.png", "frame_002.png"] {
        let len = std::fs::metadata(dir.join(f)).map(|m| m.len()).unwrap_or(0);
        assert!(len > 0, "{f} missing or empty in {}", dir.display());
    }
    let apng = std::fs::read(dir.join("engine.png")).expect("engine.png");
    assert!(
        apng.windows(4).any(|w| w == b"acTL"),
        "engine.png is an animated PNG"
    );
}
