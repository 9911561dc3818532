//! `dynapix eval` end to end: the JSON contract used by automated checks, the human-readable
//! output, multi-run tables, plots and clean errors on bad input.

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dynapix"))
}

fn repo() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
}

fn small_gt() -> PathBuf {
    repo().join("tests/data/fr1_xyz/groundtruth.txt")
}

fn small_est() -> PathBuf {
    repo().join("tests/data/fr1_xyz/rgbdslam_first300.txt")
}

fn json_of(out: &std::process::Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        text.trim().lines().count(),
        1,
        "one JSON object on one line: {text}"
    );
    serde_json::from_str(text.trim()).expect("valid JSON")
}

/// Writes the stamps of a trajectory file, minus some, as a reference list, and returns the
/// expected missing time (every stamp is a reference frame; the estimate lacks frames 10..15).
fn write_reference_with_extra_frames(est: &Path, dir: &Path) -> (PathBuf, f64) {
    let text = std::fs::read_to_string(est).expect("est");
    let stamps: Vec<f64> = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            l.split_whitespace()
                .next()
                .expect("field")
                .parse()
                .expect("num")
        })
        .collect();
    let reference = dir.join("rgb.txt");
    let body: String = stamps
        .iter()
        .map(|t| format!("{t:.6} rgb/{t:.6}.png\n"))
        .collect();
    std::fs::write(&reference, format!("# timestamp filename\n{body}")).expect("write");
    let kept: String = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .enumerate()
        .filter(|(k, _)| !(10..15).contains(k))
        .map(|(_, l)| format!("{l}\n"))
        .collect();
    std::fs::write(dir.join("est.txt"), kept).expect("write");
    (reference, stamps[15] - stamps[9])
}

#[test]
fn json_contract_without_and_with_reference() {
    let out = bin()
        .args(["eval", "--json", "--gt"])
        .arg(small_gt())
        .arg("--est")
        .arg(small_est())
        .output()
        .expect("runs");
    let v = json_of(&out);
    let rmse = v["ate_rmse_m"].as_f64().expect("ate_rmse_m");
    assert!(rmse > 0.001 && rmse < 0.1, "{rmse}");
    assert_eq!(v["pairs"].as_u64(), Some(298));
    assert!(v.get("tracking_rate").is_none());

    let dir = tempfile::tempdir().expect("tmp");
    let (reference, missing) = write_reference_with_extra_frames(&small_est(), dir.path());
    let out = bin()
        .args(["eval", "--json", "--gt"])
        .arg(small_gt())
        .arg("--est")
        .arg(dir.path().join("est.txt"))
        .arg("--reference")
        .arg(&reference)
        .output()
        .expect("runs");
    let v = json_of(&out);
    assert!(v["ate_rmse_m"].as_f64().is_some());
    assert_eq!(v["pairs"].as_u64(), Some(293));
    let got = v["missing_time_s"].as_f64().expect("missing_time_s");
    assert!((got - missing).abs() < 1e-9, "{got} vs {missing}");
    let tr = v["tracking_rate"].as_f64().expect("tracking_rate");
    assert!(tr > 0.9 && tr < 1.0, "{tr}");
}

#[test]
fn human_output_rpe_and_plots() {
    let dir = tempfile::tempdir().expect("tmp");
    let plots = dir.path().join("plots");
    let out = bin()
        .args(["eval", "--rpe-frames", "5", "--gt"])
        .arg(small_gt())
        .arg("--est")
        .arg(small_est())
        .arg("--plot")
        .arg(&plots)
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("rmse    0.0"), "{text}");
    assert!(text.contains("RPE ("), "{text}");
    for f in ["trajectory_xy", "ate_over_time"] {
        let svg = std::fs::read_to_string(plots.join(format!("{f}.svg"))).expect("svg");
        assert!(
            svg.starts_with("<svg") && svg.contains("<polyline"),
            "{f}.svg"
        );
        let png = std::fs::read(plots.join(format!("{f}.png"))).expect("png");
        assert_eq!(&png[1..4], b"PNG");
    }
}

#[test]
fn runs_folder_gives_per_method_table() {
    let dir = tempfile::tempdir().expect("tmp");
    let runs = dir.path().join("runs");
    let est = std::fs::read_to_string(small_est()).expect("est");
    for (method, n) in [("A", 2), ("B", 1)] {
        std::fs::create_dir_all(runs.join(method)).expect("mkdir");
        for k in 0..n {
            std::fs::write(runs.join(method).join(format!("run{k}.txt")), &est).expect("write");
        }
    }
    let out_dir = dir.path().join("table");
    let seq = format!("fr1={}:{}", small_gt().display(), runs.display());
    let out = bin()
        .args(["eval", "--sequence", &seq, "--out"])
        .arg(&out_dir)
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let md = std::fs::read_to_string(out_dir.join("table.md")).expect("md");
    assert!(md.contains("A ATE [m]") && md.contains("B ATE [m]"), "{md}");
    // Identical runs: std 0. The motionless floor of fr1_xyz's first 10 s is 0.185 m.
    assert!(
        md.contains("| fr1 | 0.185 | 0.015 ± 0.000 | 0.015 ± 0.000 |"),
        "{md}"
    );
    let csv = std::fs::read_to_string(out_dir.join("table.csv")).expect("csv");
    assert!(
        csv.contains("fr1,A,0.014980,0.000000,,,2,0,0.184938"),
        "{csv}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("table.json")).expect("json"))
            .expect("json");
    assert_eq!(json["methods"][1], "B");
    let floor = json["floors_m"][0].as_f64().expect("floor");
    assert!((floor - 0.184938).abs() < 1e-6, "{floor}");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("| A | run0.txt | 0.014980 | 0.184938 | 298 |"),
        "{text}"
    );
    assert!(text.contains("Ground truth of fr1: camera poses"), "{text}");

    let out = bin()
        .args(["eval", "--json", "--gt"])
        .arg(small_gt())
        .arg("--runs")
        .arg(&runs)
        .output()
        .expect("runs");
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    assert_eq!(
        v["sequences"][0]["methods"][0]["runs"]
            .as_array()
            .map(Vec::len),
        Some(2)
    );
    assert_eq!(v["ground_truth"][0]["gt_frame"], "camera");
    assert_eq!(v["ground_truth"][0]["sequence"], "fr1_xyz");
    assert!(
        v["sequences"][0]["methods"][0]["run_floors_m"][1]
            .as_f64()
            .is_some()
    );
}

fn bonn_dir() -> Option<PathBuf> {
    let d = repo().join("../shared/data/bonn/rgbd_bonn_crowd");
    if d.is_dir() {
        Some(d)
    } else {
        eprintln!("skipped: {} not found", d.display());
        None
    }
}

/// A camera that never moves, at every frame of the Bonn window, scores exactly the floor:
/// 0.074 m against camera-frame ground truth (the marker poses converted), and the output
/// says which ground truth it used.
#[test]
fn bonn_window_floor_and_ground_truth_frame() {
    let Some(seq) = bonn_dir() else { return };
    let dir = tempfile::tempdir().expect("tmp");
    let rgb = std::fs::read_to_string(seq.join("rgb.txt")).expect("rgb.txt");
    let still: String = rgb
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            format!(
                "{} 0 0 0 0 0 0 1\n",
                l.split_whitespace().next().expect("stamp")
            )
        })
        .collect();
    let est = dir.path().join("still.txt");
    std::fs::write(&est, still).expect("write");
    let eval = |frame: &str| {
        let out = bin()
            .args(["eval", "--json", "--gt-frame", frame, "--gt"])
            .arg(seq.join("groundtruth.txt"))
            .arg("--est")
            .arg(&est)
            .output()
            .expect("runs");
        json_of(&out)
    };
    let cam = eval("camera");
    assert_eq!(cam["pairs"].as_u64(), Some(150));
    assert_eq!(cam["gt_frame"], "camera");
    assert_eq!(cam["gt_file_holds"], "bonn-marker");
    assert_eq!(cam["gt_converted"], true);
    let floor = cam["motionless_floor_m"].as_f64().expect("floor");
    let ate = cam["ate_rmse_m"].as_f64().expect("ate");
    assert!((floor - 0.074).abs() < 0.001, "{floor}");
    assert!((ate - floor).abs() < 1e-9, "{ate} vs {floor}");
    let raw = eval("raw");
    assert_eq!(
        (&raw["gt_frame"], &raw["gt_converted"]),
        (&"raw".into(), &false.into())
    );
    // The marker is not the camera: the aligned ground truth sits elsewhere.
    assert_ne!(
        raw["alignment_translation_m"],
        cam["alignment_translation_m"]
    );
    let out = bin()
        .args(["eval", "--gt"])
        .arg(seq.join("groundtruth.txt"))
        .arg("--est")
        .arg(&est)
        .output()
        .expect("runs");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.starts_with("Ground truth: camera poses (Bonn marker poses converted"),
        "{text}"
    );
    assert!(text.contains("motionless floor 0.07"), "{text}");
}

#[test]
fn bad_input_fails_with_file_and_line() {
    let dir = tempfile::tempdir().expect("tmp");
    let bad = dir.path().join("bad.txt");
    std::fs::write(&bad, "1.0 0 0 0 0 0 0 1\n2.0 0 0 zero 0 0 0 1\n").expect("write");
    let out = bin()
        .args(["eval", "--gt"])
        .arg(small_gt())
        .arg("--est")
        .arg(&bad)
        .output()
        .expect("runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.txt") && err.contains(":2"), "{err}");
    assert!(!err.contains("panicked"), "{err}");

    // No overlap in time: a clear message, no panic.
    let shifted = dir.path().join("shifted.txt");
    std::fs::write(
        &shifted,
        "5.0 0 0 0 0 0 0 1\n6.0 1 0 0 0 0 0 1\n7.0 0 1 0 0 0 0 1\n",
    )
    .expect("write");
    let out = bin()
        .args(["eval", "--gt"])
        .arg(small_gt())
        .arg("--est")
        .arg(&shifted)
        .output()
        .expect("runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("timestamp pairs"), "{err}");
}

/// A run that cannot be evaluated (a pose too large to square) is named, the means say how
/// many runs they use, and the exit code is non-zero; `eval --est` on it is an error too.
#[test]
fn failed_runs_are_counted_named_and_fail_the_command() {
    let tmp = tempfile::tempdir().unwrap();
    let m = tmp.path().join("runs").join("m");
    std::fs::create_dir_all(&m).unwrap();
    let good = std::fs::read_to_string(small_est()).unwrap();
    std::fs::write(m.join("a.txt"), &good).unwrap();
    let mut lines: Vec<String> = good.lines().map(str::to_string).collect();
    let k = lines
        .iter()
        .position(|l| !l.starts_with('#') && !l.trim().is_empty())
        .unwrap()
        + 5;
    let mut f: Vec<String> = lines[k].split_whitespace().map(str::to_string).collect();
    f[1] = "1e200".into();
    lines[k] = f.join(" ");
    std::fs::write(m.join("b.txt"), lines.join("\n") + "\n").unwrap();
    let out = bin()
        .args(["eval", "--gt"])
        .arg(small_gt())
        .arg("--runs")
        .arg(tmp.path().join("runs"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stdout.contains("1 of 2 runs used"), "{stdout}");
    assert!(stderr.contains("b.txt"), "{stderr}");
    let out = bin()
        .args(["eval", "--gt"])
        .arg(small_gt())
        .arg("--est")
        .arg(m.join("b.txt"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("not finite"));
}

/// Issue 36 item 5: a timestamp given twice with different poses (ground truth or estimate)
/// is refused naming the file and both lines; an empty file is called empty (not a clock
/// problem); a one- or two-frame estimate is called too short.
#[test]
fn duplicated_stamps_empty_files_and_short_estimates_are_explained() {
    let dir = tempfile::tempdir().expect("tmp");
    let eval = |gt: &Path, est: &Path| {
        let out = bin()
            .args(["eval", "--gt"])
            .arg(gt)
            .arg("--est")
            .arg(est)
            .output()
            .expect("runs");
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(!err.contains("panicked"), "{err}");
        err
    };
    // Line 5 repeats the stamp of line 4 (comment lines counted) with another pose.
    let with_duplicate = |src: &Path, name: &str| {
        let text = std::fs::read_to_string(src).expect("read");
        let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
        let data = lines
            .iter()
            .position(|l| !l.starts_with('#'))
            .expect("data");
        let mut f: Vec<String> = lines[data + 1]
            .split_whitespace()
            .map(str::to_string)
            .collect();
        f[1] = "9.5".into();
        lines.insert(data + 2, f.join(" "));
        let p = dir.path().join(name);
        std::fs::write(&p, lines.join("\n") + "\n").expect("write");
        (p, data + 2, data + 3)
    };
    let (est, first, second) = with_duplicate(&small_est(), "est_dup.txt");
    let err = eval(&small_gt(), &est);
    assert!(
        err.contains(&format!("est_dup.txt:{second}")) && err.contains(&format!("line {first}")),
        "{err}"
    );
    let (gt, first, second) = with_duplicate(&small_gt(), "gt_dup.txt");
    let err = eval(&gt, &small_est());
    assert!(
        err.contains(&format!("gt_dup.txt:{second}")) && err.contains(&format!("line {first}")),
        "{err}"
    );

    let empty = dir.path().join("empty.txt");
    std::fs::write(&empty, "# nothing yet\n").expect("write");
    for err in [eval(&small_gt(), &empty), eval(&empty, &small_est())] {
        assert!(
            err.contains("empty.txt") && err.contains("no poses") && !err.contains("clock"),
            "{err}"
        );
    }

    let est_text = std::fs::read_to_string(small_est()).expect("read");
    let data: Vec<&str> = est_text.lines().filter(|l| !l.starts_with('#')).collect();
    for n in [1, 2] {
        let short = dir.path().join(format!("short{n}.txt"));
        std::fs::write(&short, data[..n].join("\n") + "\n").expect("write");
        let err = eval(&small_gt(), &short);
        assert!(
            err.contains(&format!("holds {n} pose(s)")) && !err.contains("clock"),
            "{err}"
        );
    }
}
