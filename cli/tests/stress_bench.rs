//! Smoke test of `sheaf bench --stress --quick` (the report on stability
//! where methods fail): it runs to the end, writes its four files, and its
//! CSV shows for every packet configuration with the fallbacks on no ray
//! that differs from the structure's single ray and no panicked call.
//! Timing is printed by the bench, never asserted.

use std::path::Path;
use std::process::Command;

#[test]
fn quick_stress_bench_runs_and_fallbacks_keep_every_ray() {
    let sheaf = env!("CARGO_BIN_EXE_sheaf");
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("stress-bench");
    let _ = std::fs::remove_dir_all(&dir);
    let out = Command::new(sheaf)
        .args(["bench", "--stress", "--quick", "--out-dir"])
        .arg(&dir)
        // The workspace root, where `sheaf bench` finds ../shared/scenes.
        .current_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join(".."))
        .output()
        .expect("run sheaf bench --stress --quick");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "sheaf bench --stress --quick failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for f in ["README.md", "stress.csv", "stress.svg", "stress.png"] {
        let len = std::fs::metadata(dir.join(f)).map(|m| m.len()).unwrap_or(0);
        assert!(len > 0, "{f} missing or empty in {}", dir.display());
    }
    let csv = std::fs::read_to_string(dir.join("stress.csv")).unwrap();
    let mut lines = csv.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| {
        head.iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("column {name} in stress.csv"))
    };
    let (fallback, diff, panicked, method) = (
        col("fallback"),
        col("diff_vs_baseline"),
        col("panicked"),
        col("method"),
    );
    let (mut on, mut off) = (0, 0);
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f[panicked], "false", "a call panicked: {line}");
        match f[fallback] {
            "on" => {
                on += 1;
                assert_eq!(
                    f[diff], "0",
                    "{} differs from its single ray with the fallbacks on: {line}",
                    f[method]
                );
            }
            "off" => off += 1,
            _ => {}
        }
    }
    assert!(
        on > 0 && on == off,
        "{on} rows with fallbacks on, {off} off"
    );
    println!(
        "stress_bench: {on} configurations with the fallbacks on, every ray equal to its single ray"
    );
}
