//! `dynapix slam --save-map` / `--localize`: a mapping run saves its map, a localisation run on
//! the same sequence tracks every frame against it (no new keyframes) with an ATE no worse than
//! the mapping run; damaged, foreign, missing or incompatible map files fail with a message
//! naming the file. The fr1_xyz test skips with a message when the real data is missing; the
//! error tests run on a small generated sequence. Run in release mode.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn dynapix(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dynapix"))
        .args(args)
        .output()
        .expect("run dynapix")
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn fr1_xyz() -> Option<PathBuf> {
    let d = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz"
    ));
    if d.join("rgb.txt").exists() {
        Some(d)
    } else {
        eprintln!("skipping: {} not found", d.display());
        None
    }
}

/// `(tracked, total)` frames of a `status.txt`.
fn tracking(out: &Path) -> (usize, usize) {
    let text = std::fs::read_to_string(out.join("status.txt")).expect("status.txt");
    let rows: Vec<&str> = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .collect();
    let tracked = rows.iter().filter(|l| l.ends_with(" tracked")).count();
    (tracked, rows.len())
}

fn lines(path: &Path) -> usize {
    std::fs::read_to_string(path)
        .expect("read")
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .count()
}

/// ATE RMSE (SE3 alignment) of `out/trajectory.txt` with `dynapix eval --json`.
fn ate(gt: &Path, out: &Path) -> f64 {
    let o = dynapix(&[
        "eval",
        "--gt",
        s(gt),
        "--est",
        s(&out.join("trajectory.txt")),
        "--json",
    ]);
    assert!(o.status.success(), "eval failed: {}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("eval json");
    v["ate_rmse_m"].as_f64().expect("ate_rmse_m")
}

/// Relative ATE tolerance of the localisation run against the mapping run: localisation
/// tracks the final, bundle-adjusted map frame by frame while the mapping trajectory is
/// recomposed from refined keyframes, so the two differ by float-level amounts either way
/// (measured on fr1_xyz: 0.011862 m vs 0.011825 m, +0.3 %).
const ATE_TOLERANCE: f64 = 0.02;

#[test]
fn fr1_xyz_save_map_then_localize_tracks_every_frame() {
    let Some(seq) = fr1_xyz() else { return };
    let tmp = tempfile::tempdir().expect("tempdir");
    let map_out = tmp.path().join("mapping");
    let loc_out = tmp.path().join("localisation");
    let map = map_out.join("map.dpxmap");
    let o = dynapix(&[
        "slam",
        s(&seq),
        "--camera",
        "tum1",
        "--out",
        s(&map_out),
        "--save-map",
        s(&map),
    ]);
    assert!(o.status.success(), "mapping run failed: {}", stderr(&o));
    let bytes = std::fs::read(&map).expect("map file written");
    assert!(bytes.starts_with(b"DPXMAP\0\0"));
    assert!(stderr(&o).contains("map saved to"), "{}", stderr(&o));

    let o = dynapix(&[
        "slam",
        s(&seq),
        "--camera",
        "tum1",
        "--out",
        s(&loc_out),
        "--localize",
        s(&map),
    ]);
    let err = stderr(&o);
    assert!(o.status.success(), "localisation run failed: {err}");
    let n_kf = lines(&map_out.join("keyframes.txt"));
    assert!(
        err.contains(&format!(
            "localisation mode, map {} ({n_kf} keyframes,",
            map.display()
        )),
        "{err}"
    );
    // No keyframe was added: the localisation run reports the loaded map's keyframes.
    assert_eq!(lines(&loc_out.join("keyframes.txt")), n_kf);
    let (tracked, total) = tracking(&loc_out);
    assert_eq!(tracked, total, "localisation lost frames");
    assert_eq!(total, tracking(&map_out).1);

    let gt = seq.join("groundtruth.txt");
    let (ate_map, ate_loc) = (ate(&gt, &map_out), ate(&gt, &loc_out));
    eprintln!("fr1_xyz ATE RMSE: mapping {ate_map:.6} m, localisation {ate_loc:.6} m");
    assert!(
        ate_loc <= ate_map * (1.0 + ATE_TOLERANCE),
        "localisation ATE {ate_loc} m worse than mapping {ate_map} m"
    );
}

/// A small generated sequence and the map of a mapping run on it.
fn synth_map(dir: &Path) -> (PathBuf, PathBuf) {
    let seq = dir.join("seq");
    let o = dynapix(&[
        "synth",
        "--preset",
        "loop",
        "--frames",
        "20",
        "--seed",
        "0",
        "--width",
        "320",
        "--height",
        "240",
        "--out",
        s(&seq),
    ]);
    assert!(o.status.success(), "synth failed: {}", stderr(&o));
    let out = dir.join("mapping");
    let map = out.join("map.dpxmap");
    let o = dynapix(&["slam", s(&seq), "--out", s(&out), "--save-map", s(&map)]);
    assert!(o.status.success(), "mapping failed: {}", stderr(&o));
    (seq, map)
}

fn localize(seq: &Path, out: &Path, map: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["slam", s(seq), "--out", s(out), "--localize", s(map)];
    args.extend_from_slice(extra);
    dynapix(&args)
}

#[test]
fn damaged_foreign_missing_and_incompatible_maps_are_clear_errors() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (seq, map) = synth_map(tmp.path());
    let out = tmp.path().join("loc");

    // Sanity: the intact map localises the sequence.
    let o = localize(&seq, &out, &map, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (tracked, total) = tracking(&out);
    assert_eq!(tracked, total);

    let bytes = std::fs::read(&map).expect("map");
    let cases: [(&str, Vec<u8>, &str); 3] = [
        (
            "truncated.dpxmap",
            bytes[..bytes.len() / 2].to_vec(),
            "truncated",
        ),
        (
            "foreign.dpxmap",
            b"# timestamp filename\n".to_vec(),
            "bad magic",
        ),
        ("empty.dpxmap", Vec::new(), "truncated"),
    ];
    for (name, content, why) in cases {
        let bad = tmp.path().join(name);
        std::fs::write(&bad, content).expect("write");
        let o = localize(&seq, &out, &bad, &[]);
        let err = stderr(&o);
        assert!(!o.status.success(), "{name} was accepted");
        assert!(err.contains(s(&bad)) && err.contains(why), "{name}: {err}");
    }

    let missing = tmp.path().join("missing.dpxmap");
    let o = localize(&seq, &out, &missing, &[]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains(s(&missing)), "{}", stderr(&o));

    // Another camera or no vocabulary: refused, naming the file and the difference.
    let o = localize(&seq, &out, &map, &["--camera", "tum3"]);
    let err = stderr(&o);
    assert!(!o.status.success());
    assert!(err.contains(s(&map)) && err.contains("camera"), "{err}");
    let o = localize(&seq, &out, &map, &["--no-vocabulary"]);
    let err = stderr(&o);
    assert!(!o.status.success());
    assert!(
        err.contains("vocabulary") && err.contains("got none"),
        "{err}"
    );

    // Saving and localising at once is refused by the argument parser.
    let o = localize(&seq, &out, &map, &["--save-map", s(&tmp.path().join("x"))]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("cannot be used with"), "{}", stderr(&o));
}
