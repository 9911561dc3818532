//! `dynapix bench` on a small generated sequence: the report names every stage of the method
//! that ran (and none that did not), counts its passes and frames, and scores the run like
//! `run` does. Run in release mode (`cargo test --release`).

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_dynapix")
}

fn synth(dir: &Path, frames: usize) -> PathBuf {
    let seq = dir.join("seq");
    let st = Command::new(bin())
        .args(["synth", "--preset", "walking_xyz", "--frames"])
        .arg(frames.to_string())
        .args(["--width", "160", "--height", "120", "-q", "--out"])
        .arg(&seq)
        .status()
        .unwrap();
    assert!(st.success());
    for d in ["background", "depth_bg", "mask", "instance"] {
        let _ = std::fs::remove_dir_all(seq.join(d));
    }
    seq
}

fn bench(seq: &Path, json: &Path, extra: &[&str]) -> (serde_json::Value, String) {
    let out = Command::new(bin())
        .arg("bench")
        .arg(seq)
        .args(extra)
        .arg("--json")
        .arg(json)
        .arg("-q")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v = serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    (v, stdout)
}

fn names(v: &serde_json::Value, kind: &str) -> Vec<String> {
    v["profile"][kind]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["name"].as_str().unwrap().to_string())
        .collect()
}

fn calls(v: &serde_json::Value, kind: &str, name: &str) -> u64 {
    v["profile"][kind]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == name)
        .and_then(|s| s["calls"].as_u64())
        .unwrap_or(0)
}

#[test]
fn bench_reports_each_stage_of_the_method_that_ran() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), 24);

    let (orb, text) = bench(
        &seq,
        &tmp.path().join("orb.json"),
        &["--method", "orbslam2"],
    );
    assert_eq!(orb["frames"], 24);
    assert_eq!(orb["schedule"], "offline");
    assert!(orb["ate_rmse_m"].as_f64().is_some(), "{orb}");
    assert!(orb["wall_seconds"].as_f64().unwrap() > 0.0);
    assert!(orb["fps"].as_f64().unwrap() > 0.0);
    let stages = names(&orb, "stages");
    for s in [
        "decode images",
        "orb extraction",
        "tracking",
        "local mapping",
    ] {
        assert!(stages.contains(&s.to_string()), "{s} missing: {stages:?}");
    }
    // ORB-SLAM2 computes no motion maps.
    assert!(
        !stages
            .iter()
            .any(|s| s.contains("rigidity") || s.contains("geometric"))
    );
    assert_eq!(calls(&orb, "stages", "orb extraction"), 24);
    assert_eq!(calls(&orb, "phases", "SLAM passes"), 1);
    assert!(
        text.contains("frames/s") && text.contains("orb extraction"),
        "{text}"
    );

    // Repeated runs: each from scratch, all listed, the table from the median one.
    let (rep, text) = bench(
        &seq,
        &tmp.path().join("rep.json"),
        &["--method", "orbslam2", "--repeat", "3"],
    );
    let walls = rep["repeat_wall_seconds"].as_array().unwrap();
    assert_eq!(walls.len(), 3, "{rep}");
    let mut w: Vec<f64> = walls.iter().map(|x| x.as_f64().unwrap()).collect();
    w.sort_by(f64::total_cmp);
    assert_eq!(rep["wall_seconds"].as_f64().unwrap(), w[1]);
    assert_eq!(calls(&rep, "stages", "orb extraction"), 24);
    assert_eq!(rep["ate_rmse_m"], orb["ate_rmse_m"]);
    assert!(text.contains("3 runs:"), "{text}");

    let (dp, _) = bench(&seq, &tmp.path().join("dp.json"), &["--method", "dynapix"]);
    let stages = names(&dp, "stages");
    for s in ["rigidity: flow", "rigidity: fit", "geometric: static depth"] {
        assert!(stages.contains(&s.to_string()), "{s} missing: {stages:?}");
    }
    // A cold bench keeps its maps in a temporary file: no map file written or read back.
    for s in ["write maps", "read maps"] {
        assert!(!stages.contains(&s.to_string()), "{s} ran: {stages:?}");
    }
    // The paper's terms are off by default: no paper stage ran.
    assert!(!stages.iter().any(|s| s.starts_with("paper")), "{stages:?}");
    // First pass + two weighted passes, each extracting every frame once.
    assert_eq!(calls(&dp, "phases", "SLAM passes"), 3);
    assert_eq!(calls(&dp, "stages", "orb extraction"), 3 * 24);
    // Rigidity maps once per sequence (computed from scratch: the bench uses no cache).
    assert_eq!(calls(&dp, "phases", "rigidity maps"), 1);
    assert_eq!(calls(&dp, "phases", "motion maps"), 2);
    assert!(dp["cpu_seconds"].as_f64().unwrap() > orb["cpu_seconds"].as_f64().unwrap());

    let (on, text) = bench(
        &seq,
        &tmp.path().join("on.json"),
        &["--method", "dynapix", "--online"],
    );
    assert_eq!(on["schedule"], "online");
    assert!(on["latency"]["p95_ms"].as_f64().unwrap() > 0.0, "{on}");
    assert!(text.contains("latency per frame"), "{text}");
}

#[test]
fn online_bench_of_dynapix_plus_uses_the_masks() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), 12);
    let json = tmp.path().join("b.json");
    let args = ["--method", "dynapix+", "--online"];
    // Without `mask/` the bench refuses to run (it ran unmasked before).
    let o = Command::new(bin())
        .arg("bench")
        .arg(&seq)
        .args(args)
        .arg("-q")
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("mask"));
    // Every pixel dynamic: no map point is born, no frame tracked.
    let masks = seq.join("mask");
    std::fs::create_dir_all(&masks).unwrap();
    for e in std::fs::read_dir(seq.join("rgb")).unwrap() {
        let p = e.unwrap().path();
        let (w, h) = image::image_dimensions(&p).unwrap();
        let name = p.with_extension("png");
        image::GrayImage::from_pixel(w, h, image::Luma([255]))
            .save(masks.join(name.file_name().unwrap()))
            .unwrap();
    }
    let (all, _) = bench(&seq, &json, &args);
    for e in std::fs::read_dir(&masks).unwrap() {
        let p = e.unwrap().path();
        let (w, h) = image::image_dimensions(&p).unwrap();
        image::GrayImage::new(w, h).save(&p).unwrap();
    }
    let (none, _) = bench(&seq, &json, &args);
    let (t_all, t_none) = (
        all["tracked"].as_u64().unwrap(),
        none["tracked"].as_u64().unwrap(),
    );
    assert!(t_all < t_none, "all dynamic {t_all}, none dynamic {t_none}");
}
