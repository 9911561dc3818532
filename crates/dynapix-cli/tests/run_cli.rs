//! `dynapix run` contract on a small generated sequence (synth walking_xyz, 320×240):
//! `--method orbslam2|dynapix --out OUT` writes `OUT/trajectory.txt`, `run.json` records the
//! sources (no ground truth at run time by default) and the evaluation. DynaPix runs on a
//! `prob/` folder made from the synth motion masks (so the SLAM weighting is tested on its
//! own), and, when `dynapix motion` is available, on maps it computes itself.
//! Run in release mode (`cargo test --release`).

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
        .args(["--width", "320", "--height", "240", "--out"])
        .arg(&seq)
        .status()
        .unwrap();
    assert!(st.success());
    seq
}

fn tracked_lines(p: &Path) -> usize {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .count()
}

/// The `run.json` of `out`, checked to round-trip through its record type: it deserialises
/// into `dynapix::RunRecord` and serialises back to the same JSON value.
fn run_json(out: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(out.join("run.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let rec: dynapix::RunRecord = serde_json::from_str(&text)
        .unwrap_or_else(|e| panic!("{}/run.json is no RunRecord: {e}", out.display()));
    assert_eq!(
        serde_json::to_value(&rec).unwrap(),
        v,
        "{}/run.json does not round-trip",
        out.display()
    );
    v
}

/// Writes `prob/<name>` from the synth masks: P = 1 where the mask marks a mover.
fn prob_from_masks(seq: &Path) {
    let prob = seq.join("prob");
    std::fs::create_dir_all(&prob).unwrap();
    for e in std::fs::read_dir(seq.join("mask")).unwrap() {
        let p = e.unwrap().path();
        let m = image::open(&p).unwrap().to_luma8();
        let w = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(
            m.width(),
            m.height(),
            |x, y| image::Luma([if m.get_pixel(x, y).0[0] > 0 { 0 } else { 1000 }]),
        );
        w.save(prob.join(p.file_name().unwrap())).unwrap();
    }
}

#[test]
fn run_contract_orbslam2_and_dynapix() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), 60);
    prob_from_masks(&seq);
    for method in ["orbslam2", "dynapix", "threshold"] {
        let out = tmp.path().join(method);
        let o = Command::new(bin())
            .arg("run")
            .arg(&seq)
            .args(["--method", method, "--quiet", "--out"])
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{method}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let n = tracked_lines(&out.join("trajectory.txt"));
        assert!(n >= 50, "{method}: only {n} of 60 frames tracked");
        let j = run_json(&out);
        assert_eq!(j["method"], method);
        if method == "orbslam2" {
            assert_eq!(j["ground_truth_used_at_run_time"], false);
        } else {
            // Maps without a motion.json beside them: where their poses came from is unknown.
            assert!(j["ground_truth_used_at_run_time"].is_null(), "{method}");
            assert!(
                j["prob"]["provenance"]
                    .as_str()
                    .unwrap()
                    .contains("unknown")
            );
        }
        let ate = j["results"][0]["ate_rmse_m"].as_f64().unwrap();
        assert!(ate.is_finite() && ate < 0.2, "{method}: ATE {ate}");
        if method != "orbslam2" {
            assert_eq!(j["prob"]["source"], "sequence prob/ folder");
        } else {
            assert!(j.get("prob").is_none());
        }
        assert!(out.join("eval.json").exists());
        assert!(out.join("status.txt").exists());
    }
    // The DynaPix methods read the masks' maps; paper weighting records its clamp.
    let j = run_json(&tmp.path().join("dynapix"));
    assert_eq!(j["dynapix"]["weighting"], "Paper");
    assert!(j["dynapix"]["ba_weight_clamp"].is_array());
    let j = run_json(&tmp.path().join("threshold"));
    assert_eq!(j["dynapix"]["weighting"], "Off");
}

#[test]
fn dynapix_plus_needs_masks_and_bad_method_fails() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), 20);
    let o = Command::new(bin())
        .arg("run")
        .arg(&seq)
        .args(["--method", "dynapix+", "--quiet", "--masks"])
        .arg(tmp.path().join("nope"))
        .arg("--out")
        .arg(tmp.path().join("o"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let o = Command::new(bin())
        .arg("run")
        .arg(&seq)
        .args(["--method", "bogus", "--out"])
        .arg(tmp.path().join("o2"))
        .output()
        .unwrap();
    assert!(!o.status.success());
}

#[test]
fn dynapix_computes_missing_maps_without_ground_truth() {
    let help = Command::new(bin())
        .args(["motion", "--help"])
        .output()
        .unwrap();
    if !String::from_utf8_lossy(&help.stdout).contains("--poses") {
        eprintln!("skipping: this build has no `dynapix motion --poses`");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), 30);
    let out = tmp.path().join("dpx");
    let o = Command::new(bin())
        .arg("run")
        .arg(&seq)
        .args([
            "--method",
            "dynapix",
            "--quiet",
            "--flow-preset",
            "ultrafast",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(tracked_lines(&out.join("trajectory.txt")) >= 20);
    let j = run_json(&out);
    assert_eq!(j["ground_truth_used_at_run_time"], false);
    assert_eq!(j["prob"]["source"], "computed");
    assert_eq!(j["prob"]["poses"]["source"], "pass");
    assert_eq!(j["prob"]["poses"]["pass"], 0);
    assert_eq!(j["first_pass"]["source"], "computed");
    let prob = PathBuf::from(j["prob"]["dir"].as_str().unwrap());
    let n = std::fs::read_dir(&prob)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .is_ok_and(|e| e.path().extension().is_some_and(|x| x == "png"))
        })
        .count();
    assert_eq!(n, 30, "one map per frame in {}", prob.display());
    // The cache's motion.json round-trips through its record type, complete, every map listed.
    let text = std::fs::read_to_string(prob.join("motion.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let rec: dynapix::MotionRecord = serde_json::from_str(&text).unwrap();
    assert_eq!(serde_json::to_value(&rec).unwrap(), v);
    assert_eq!(rec.status, dynapix::MapsStatus::Complete);
    assert_eq!(rec.files.as_ref().map(|f| f.len()), Some(30));
    assert_eq!(rec.uses_ground_truth(), Some(false));
    assert!(
        !seq.join("prob").exists(),
        "the sequence's own prob/ is untouched"
    );
}

#[test]
fn online_run_config_file_and_flags_shared_by_every_command() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), 30);
    let out = tmp.path().join("online");
    let o = Command::new(bin())
        .arg("run")
        .arg(&seq)
        .args([
            "--method",
            "dynapix",
            "--online",
            "--lookahead",
            "1",
            "--quiet",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(tracked_lines(&out.join("trajectory.txt")) >= 25);
    assert!(out.join("trajectory_refined.txt").is_file());
    let j = run_json(&out);
    assert_eq!(j["schedule"], "online");
    assert_eq!(j["results"][0]["lookahead_frames"], 1);
    assert_eq!(j["config"]["online"]["lookahead"], 1);
    assert!(j["results"][0]["ate_rmse_m"].as_f64().unwrap() < 0.2);

    // A configuration file; flags override it.
    let cfg = tmp.path().join("c.yaml");
    std::fs::write(&cfg, "method: no-moving\nmotion:\n  flow: ultrafast\n").unwrap();
    let out = tmp.path().join("cfg");
    let o = Command::new(bin())
        .arg("run")
        .arg(&seq)
        .arg("--config")
        .arg(&cfg)
        .args(["--max-frames", "20", "--quiet", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = run_json(&out);
    assert_eq!(j["method"], "no-moving");
    assert_eq!(j["config"]["motion"]["flow"], "ultrafast");
    assert_eq!(j["config"]["sequence"]["max_frames"], 20);
    assert_eq!(j["sequence"]["frames"], 20);
    assert_eq!(j["sequence"]["frame_list"]["source"], "association_file");
    let bad = tmp.path().join("bad.yaml");
    std::fs::write(&bad, "motion:\n  flw: fast\n").unwrap();
    let o = Command::new(bin())
        .arg("run")
        .arg(&seq)
        .arg("--config")
        .arg(&bad)
        .arg("--out")
        .arg(tmp.path().join("x"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("unknown key motion.flw") && err.contains("bad.yaml"),
        "{err}"
    );

    // `--camera` is a preset everywhere; the old `motion --camera FILE` names `--settings`.
    let yaml = seq.join("camera.yaml");
    for cmd in ["motion", "slam", "run"] {
        let mut c = Command::new(bin());
        c.arg(cmd).arg(&seq).arg("--camera").arg(&yaml);
        if cmd != "motion" {
            c.arg("--out").arg(tmp.path().join("y"));
        }
        let o = c.output().unwrap();
        assert!(!o.status.success(), "{cmd}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("--settings"), "{cmd}: {err}");
    }
    // `--quiet` and `--settings` are accepted by every command that reads a sequence.
    let out = tmp.path().join("slam");
    let o = Command::new(bin())
        .arg("slam")
        .arg(&seq)
        .arg("--settings")
        .arg(&yaml)
        .args(["--max-frames", "10", "--quiet", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(tracked_lines(&out.join("status.txt")), 10);
}

/// `run` prints and records the motionless floor and the earlier passes; `experiment`'s
/// table carries the floor too.
#[test]
fn run_and_experiment_report_the_motionless_floor_and_every_pass() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), 40);
    for d in ["background", "depth_bg", "prob"] {
        let _ = std::fs::remove_dir_all(seq.join(d));
    }
    let out = tmp.path().join("run");
    let o = Command::new(bin())
        .arg("run")
        .arg(&seq)
        .args(["--method", "dynapix", "--quiet", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("motionless floor"), "{stdout}");
    assert!(
        stdout.contains("pass first:") && stdout.contains("pass 1:"),
        "{stdout}"
    );
    let j = run_json(&out);
    assert!(j["results"][0]["motionless_floor_m"].as_f64().unwrap() > 0.0);
    assert_eq!(j["cues"], "geometric+rigidity");
    assert_eq!(j["first_pass_kind"], "rigidity");
    let earlier = j["earlier_passes"].as_array().unwrap();
    assert_eq!(earlier.len(), 2, "{earlier:?}");
    assert!(out.join("passes/first/trajectory.txt").is_file());
    assert!(out.join("passes/pass_1/trajectory.txt").is_file());
    // The maps' record names every cue.
    let maps = j["passes"][0]["maps"]["config"]["cues"].clone();
    assert_eq!(maps["paper"], false);
    assert!(
        maps["geometric"].is_object() && maps["rigidity"].is_object(),
        "{maps}"
    );

    let exp = tmp.path().join("exp");
    let o = Command::new(bin())
        .args([
            "experiment",
            "--methods",
            "orbslam2",
            "--quiet",
            "--sequences",
        ])
        .arg(&seq)
        .arg("--out")
        .arg(&exp)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let table = std::fs::read_to_string(exp.join("table.md")).unwrap();
    assert!(table.contains("motionless floor"), "{table}");
}

/// A sequence where nothing can be tracked (all-zero depth) is a warning and exit code 1,
/// with the outputs written; `--allow-untracked` accepts it.
#[test]
fn nothing_tracked_is_not_a_silent_success() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), 8);
    for e in std::fs::read_dir(seq.join("depth")).unwrap() {
        let p = e.unwrap().path();
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(320, 240)
            .save(&p)
            .unwrap();
    }
    let out = tmp.path().join("slam");
    let run = |extra: &[&str]| {
        Command::new(bin())
            .arg("slam")
            .arg(&seq)
            .args(["--quiet", "--out"])
            .arg(&out)
            .args(extra)
            .output()
            .unwrap()
    };
    let o = run(&[]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("nothing tracked") && err.contains("--allow-untracked"),
        "{err}"
    );
    assert!(out.join("status.txt").is_file());
    assert!(run(&["--allow-untracked"]).status.success());
}

/// A folder of DynaPix+ masks named like the rgb images of `seq`, every pixel `value`.
fn constant_masks(seq: &Path, dir: &Path, value: u8) {
    std::fs::create_dir_all(dir).unwrap();
    for e in std::fs::read_dir(seq.join("mask")).unwrap() {
        let p = e.unwrap().path();
        let (w, h) = image::image_dimensions(&p).unwrap();
        image::GrayImage::from_pixel(w, h, image::Luma([value]))
            .save(dir.join(p.file_name().unwrap()))
            .unwrap();
    }
}

#[test]
fn online_dynapix_plus_uses_the_masks_it_is_given() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), 20);
    let run = |masks: &Path, out: &str, extra: &[&str]| {
        Command::new(bin())
            .arg("run")
            .arg(&seq)
            .args([
                "--method",
                "dynapix+",
                "--online",
                "--allow-untracked",
                "--quiet",
            ])
            .args(extra)
            .arg("--masks")
            .arg(masks)
            .arg("--out")
            .arg(tmp.path().join(out))
            .output()
            .unwrap()
    };
    // A mask folder that does not exist is refused, naming it (it was ignored online).
    let o = run(&tmp.path().join("nope"), "o0", &[]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("nope"));
    // Everything dynamic: no map point is born, nothing is tracked; nothing dynamic: the
    // frames are tracked. Both read the masks given, not the sequence's `mask/`.
    let (all, none) = (tmp.path().join("all"), tmp.path().join("none"));
    constant_masks(&seq, &all, 255);
    constant_masks(&seq, &none, 0);
    assert!(run(&all, "o_all", &[]).status.success());
    assert!(run(&none, "o_none", &[]).status.success());
    let tracked = |out: &str| run_json(&tmp.path().join(out))["results"][0]["tracked"].as_u64();
    let (t_all, t_none) = (tracked("o_all").unwrap(), tracked("o_none").unwrap());
    assert!(t_all < t_none, "all dynamic {t_all}, none {t_none}");
    assert_eq!(
        run_json(&tmp.path().join("o_all"))["masks"],
        serde_json::json!(all)
    );
}
