//! `dynapix demo` end to end on one short preset: the table (Markdown, CSV, JSON), the report
//! with its plots and the probability overlay strip are written, and the table holds both
//! methods with finite ATE. Needs `dynapix motion` (skips with a message when this build has
//! none). Run in release mode.

use std::process::Command;

#[test]
fn demo_writes_table_report_and_pictures() {
    let bin = env!("CARGO_BIN_EXE_dynapix");
    let help = Command::new(bin)
        .args(["motion", "--help"])
        .output()
        .unwrap();
    if !String::from_utf8_lossy(&help.stdout).contains("--poses") {
        eprintln!("skipping: this build has no `dynapix motion --poses`");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("demo");
    let o = Command::new(bin)
        .args(["demo", "--frames", "40", "--presets", "walking_xyz"])
        .args(["--flow-preset", "ultrafast", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in [
        "report.md",
        "table.md",
        "table.csv",
        "table.json",
        "overlays.png",
    ] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("walking_xyz") && report.contains("overlays.png"));
    for m in ["orbslam2", "dynapix"] {
        let p = out.join("runs/walking_xyz").join(m);
        assert!(p.join("trajectory.txt").exists());
        assert!(p.join("trajectory_xy.png").exists());
    }
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("table.json")).unwrap()).unwrap();
    let avg = t["average"].as_array().unwrap();
    assert_eq!(avg.len(), 2);
    for a in avg {
        let ate = a["ate_m"].as_f64().unwrap();
        assert!(ate.is_finite() && ate < 0.2, "{a}");
    }
    let strip = image::open(out.join("overlays.png")).unwrap();
    assert_eq!(strip.height(), 2 * 240, "frames above, overlays below");
}
