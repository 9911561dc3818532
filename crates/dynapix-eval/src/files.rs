//! The thin file layer of the evaluation: reading trajectories (through
//! `dynapix_io::trajectory`) and ground truth (camera poses, or the raw file), reading reference frame stamps (first column of `rgb.txt` or an
//! association file), walking a runs folder (one sub-folder per method, one trajectory `.txt`
//! per run, like the reference `eval.py` RESULT_DIR), and writing tables atomically.

use crate::aggregate::{MethodSummary, PaperTable, RunResult, summarize_with_floors};
use crate::error::{EvalError, Result};
use crate::report::EvalParams;
use dynapix_geometry::Se3;
use dynapix_io::{GroundTruth, GtFrame};
use std::path::{Path, PathBuf};

pub use crate::run::RunEvaluation;

/// Reads a TUM trajectory (`timestamp tx ty tz qx qy qz qw`, `#` comments, commas/tabs).
/// A timestamp given twice with different poses is an error naming both lines, an empty file
/// is an error saying so ([`check_trajectory_file`]).
pub fn read_trajectory(path: &Path) -> Result<Vec<(f64, Se3)>> {
    let t = check_trajectory_file(path)?;
    Ok(t.pairs())
}

/// Reads a trajectory file for scoring: refuses a timestamp given twice with different poses
/// (naming the file and both lines) and a file without any pose.
pub fn check_trajectory_file(path: &Path) -> Result<dynapix_io::Trajectory> {
    let t = dynapix_io::Trajectory::read_tum_strict(path)?;
    if t.is_empty() {
        return Err(EvalError::Empty {
            path: path.to_path_buf(),
        });
    }
    Ok(t)
}

/// Reads a ground-truth file in `frame` ([`dynapix_io::read_ground_truth`], the one reader:
/// duplicate timestamps refused unless within one sample's noise, the marker poses of a Bonn
/// `groundtruth.txt` converted to camera poses for [`GtFrame::Camera`]); a file without any
/// pose is an error. Returns the poses and how they were read.
pub fn read_ground_truth(path: &Path, frame: GtFrame) -> Result<(Vec<(f64, Se3)>, GroundTruth)> {
    let gt = dynapix_io::read_ground_truth(path, frame)?;
    if gt.trajectory.is_empty() {
        return Err(EvalError::Empty {
            path: path.to_path_buf(),
        });
    }
    Ok((gt.trajectory.pairs(), gt))
}

/// Reads a ground-truth file as camera poses: use this, not [`read_trajectory`], for the
/// ground truth of a sequence, so that Bonn marker poses are converted.
pub fn read_camera_ground_truth(path: &Path) -> Result<Vec<(f64, Se3)>> {
    Ok(read_ground_truth(path, GtFrame::Camera)?.0)
}

/// Reads reference frame stamps: the first field of every non-empty, non-`#` line
/// (`rgb.txt`, `depth.txt`, a 4-column association file, or a trajectory).
pub fn read_reference_stamps(path: &Path) -> Result<Vec<f64>> {
    let text = std::fs::read_to_string(path).map_err(|source| EvalError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_reference_stamps(&text, path)
}

/// Parses reference stamps from text; `path` is used in error messages only.
pub fn parse_reference_stamps(text: &str, path: &Path) -> Result<Vec<f64>> {
    let mut out = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let first = line
            .split(|c: char| c.is_whitespace() || c == ',')
            .find(|s| !s.is_empty())
            .unwrap_or("");
        let t: f64 = first.parse().map_err(|_| EvalError::Parse {
            path: path.to_path_buf(),
            line: k + 1,
            reason: format!("expected a timestamp in the first column, got {first:?}"),
        })?;
        if !t.is_finite() {
            return Err(EvalError::Parse {
                path: path.to_path_buf(),
                line: k + 1,
                reason: format!("timestamp {first:?} is not finite"),
            });
        }
        out.push(t);
    }
    Ok(out)
}

fn list_dir(dir: &Path) -> Result<Vec<PathBuf>> {
    let rd = std::fs::read_dir(dir).map_err(|source| EvalError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut v = Vec::new();
    for e in rd {
        let e = e.map_err(|source| EvalError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        v.push(e.path());
    }
    // Sorted by name, so the run order (and every table) is reproducible.
    v.sort();
    Ok(v)
}

fn txt_files(dir: &Path) -> Result<Vec<PathBuf>> {
    Ok(list_dir(dir)?
        .into_iter()
        .filter(|p| p.is_file() && p.extension().is_some_and(|e| e == "txt"))
        .collect())
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Evaluates one trajectory file into a [`RunEvaluation`] (its [`RunResult`] and the
/// motionless floor of the run, [`crate::run::evaluate_run_poses`]); errors, a file that
/// cannot be read included, are recorded, not returned.
pub fn evaluate_run(
    gt: &[(f64, Se3)],
    est_path: &Path,
    reference: Option<&[f64]>,
    params: &EvalParams,
) -> RunEvaluation {
    match read_trajectory(est_path) {
        Ok(est) => crate::run::evaluate_run_poses(gt, &est, est_path, reference, params),
        Err(e) => RunEvaluation {
            result: RunResult {
                name: file_name(est_path),
                ate_rmse_m: None,
                pairs: 0,
                tracking_rate: None,
                missing_time_s: None,
                error: Some(e.to_string()),
            },
            motionless_floor_m: None,
        },
    }
}

/// Evaluates a runs folder: each sub-folder is a method and each `.txt` in it one run. A
/// folder that holds `.txt` files directly (no sub-folders) is one method named after it.
/// Methods and runs are taken in name order.
pub fn evaluate_runs_dir(
    gt: &[(f64, Se3)],
    runs_dir: &Path,
    reference: Option<&[f64]>,
    params: &EvalParams,
    mut progress: impl FnMut(&Path),
) -> Result<Vec<MethodSummary>> {
    let entries = list_dir(runs_dir)?;
    let subdirs: Vec<PathBuf> = entries.iter().filter(|p| p.is_dir()).cloned().collect();
    let methods: Vec<(String, PathBuf)> = if subdirs.is_empty() {
        vec![(file_name(runs_dir), runs_dir.to_path_buf())]
    } else {
        subdirs.into_iter().map(|p| (file_name(&p), p)).collect()
    };
    let mut out = Vec::new();
    for (name, dir) in methods {
        let files = txt_files(&dir)?;
        if files.is_empty() {
            continue;
        }
        let (runs, floors) = files
            .iter()
            .map(|f| {
                progress(f);
                let r = evaluate_run(gt, f, reference, params);
                (r.result, r.motionless_floor_m)
            })
            .unzip();
        out.push(summarize_with_floors(&name, runs, floors));
    }
    if out.is_empty() {
        return Err(EvalError::Layout {
            path: runs_dir.to_path_buf(),
            reason: "no trajectories found: expected <method>/<run>.txt files".into(),
        });
    }
    Ok(out)
}

/// Writes `table.md`, `table.csv` and `table.json` into `dir` (created if needed),
/// atomically. Returns the written paths.
pub fn write_table(dir: &Path, table: &PaperTable) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|source| EvalError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut written = Vec::new();
    for (name, text) in [
        ("table.md", table.to_markdown()),
        ("table.csv", table.to_csv()),
        ("table.json", table.to_json()),
    ] {
        let p = dir.join(name);
        dynapix_io::write_atomic(&p, text.as_bytes())?;
        written.push(p);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(256))]

        /// Reference stamps of any text are stamps or an error naming the file.
        #[test]
        fn reference_stamps_never_panic(text in proptest::prelude::any::<String>()) {
            if let Err(e) = parse_reference_stamps(&text, Path::new("rgb.txt")) {
                proptest::prop_assert!(e.to_string().contains("rgb.txt"), "{}", e);
            }
        }
    }

    #[test]
    fn a_run_reports_its_floor_and_serialises_flat() {
        let dir = tempfile::tempdir().expect("tmp");
        // Ground truth along x at 1 m/s for 2 s; a motionless estimate at 10 Hz.
        let gt: Vec<(f64, Se3)> = (0..=200)
            .map(|k| {
                let t = k as f64 * 0.01;
                (t, Se3::translation(t, 0.0, 0.0))
            })
            .collect();
        let est = dir.path().join("still.txt");
        let lines: String = (0..=20)
            .map(|k| format!("{:.6} 0 0 0 0 0 0 1\n", k as f64 * 0.1))
            .collect();
        std::fs::write(&est, lines).expect("write");
        let r = evaluate_run(&gt, &est, None, &EvalParams::default());
        // Positions 0, 0.1, …, 2.0: RMS distance from 1.0 is √(Σ(0.1k − 1)²/21) = √0.3667.
        let floor = r.motionless_floor_m.expect("floor");
        assert!(
            (floor - (0.11f64 * 10.0 / 3.0).sqrt()).abs() < 1e-9,
            "{floor}"
        );
        assert!((r.result.ate_rmse_m.expect("ate") - floor).abs() < 1e-9);
        let v = serde_json::to_value(&r).expect("json");
        assert_eq!(v["pairs"], 21);
        assert!(v["motionless_floor_m"].as_f64().is_some() && v.get("result").is_none());
        let missing = evaluate_run(
            &gt,
            &dir.path().join("none.txt"),
            None,
            &EvalParams::default(),
        );
        assert!(missing.motionless_floor_m.is_none() && missing.result.error.is_some());
    }

    #[test]
    fn reference_stamps_from_association_and_bad_line() {
        let text = "# comment\n1305031102.175304 rgb/1305031102.175304.png 1305031102.160407 depth/x.png\n\n1305031102.211214,rgb/a.png\n";
        let v = parse_reference_stamps(text, Path::new("assoc.txt")).expect("parses");
        assert_eq!(v, vec![1305031102.175304, 1305031102.211214]);
        let err = parse_reference_stamps("1.0 a\nrgb/2.png 2.0\n", Path::new("assoc.txt"))
            .expect_err("bad line");
        let msg = err.to_string();
        assert!(msg.contains("assoc.txt:2"), "{msg}");
    }
}
