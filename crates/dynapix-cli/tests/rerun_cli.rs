//! `--rerun-save` on `run`, `slam` and `bench` (issue 35), on a tiny generated sequence (synth
//! walking_xyz, 24 frames of 160×120). With the `viz` feature the recording is written and
//! decodes back with the run's frames; without it the flags are refused with the command that
//! builds them, before any work. Run in release mode (`cargo test --release`, and
//! `cargo test --release -p dynapix-cli --features viz --test rerun_cli`).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const FRAMES: usize = 24;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dynapix"))
}

fn synth(dir: &Path) -> PathBuf {
    let seq = dir.join("seq");
    let o = bin()
        .args(["synth", "--preset", "walking_xyz", "--frames"])
        .arg(FRAMES.to_string())
        .args(["--width", "160", "--height", "120", "--out"])
        .arg(&seq)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    seq
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[cfg(feature = "viz")]
#[test]
fn run_and_slam_write_recordings_that_decode_back() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path());
    for (cmd, extra) in [
        ("slam", &[][..]),
        ("run", &["--method", "dynapix", "--no-cache"][..]),
    ] {
        let rrd = tmp.path().join(format!("{cmd}.rrd"));
        let out = tmp.path().join(format!("out-{cmd}"));
        let o = bin()
            .arg(cmd)
            .arg(&seq)
            .args(extra)
            .arg("--out")
            .arg(&out)
            .arg("--rerun-save")
            .arg(&rrd)
            .output()
            .unwrap();
        assert!(o.status.success(), "{cmd}: {}", stderr(&o));
        let c = dynapix_rerun::read::read_rrd(&rrd).unwrap();
        // One timeline per pass (`pass1`, …) beside Rerun's own `log_time`.
        let passes = c.timelines.keys().filter(|t| t.starts_with("pass")).count();
        assert!(passes >= 1, "{cmd}: {c:?}");
        assert_eq!(
            c.rows("world/camera/image/keypoints"),
            passes * FRAMES,
            "{cmd}"
        );
        let tracked = std::fs::read_to_string(out.join("trajectory.txt"))
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .count();
        // Every pass logs its tracked poses; the final pass is the trajectory written.
        assert!(c.rows("world/camera") >= tracked, "{cmd}: {c:?}");
        assert!(c.rows("world/map/points") >= passes, "{cmd}: {c:?}");
        // The images: in the last pass only.
        assert_eq!(c.rows("depth"), FRAMES, "{cmd}");
    }
    // `bench` logs the measured run the same way, every 2nd frame's images here.
    let rrd = tmp.path().join("bench.rrd");
    let o = bin()
        .arg("bench")
        .arg(&seq)
        .args([
            "--method",
            "dynapix",
            "--rerun-images-every",
            "2",
            "--rerun-save",
        ])
        .arg(&rrd)
        .output()
        .unwrap();
    assert!(o.status.success(), "bench: {}", stderr(&o));
    let c = dynapix_rerun::read::read_rrd(&rrd).unwrap();
    assert_eq!(c.rows("depth"), FRAMES.div_ceil(2), "bench: {c:?}");
    let passes = c.timelines.keys().filter(|t| t.starts_with("pass")).count();
    assert_eq!(c.rows("world/camera/image/keypoints"), passes * FRAMES);
}

#[cfg(not(feature = "viz"))]
#[test]
fn without_the_viz_feature_the_flags_say_how_to_get_them() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path());
    for (cmd, flag) in [("slam", "--rerun-save"), ("run", "--rerun")] {
        let out = tmp.path().join(format!("out-{cmd}"));
        let mut c = bin();
        c.arg(cmd).arg(&seq).arg("--out").arg(&out).arg(flag);
        if flag == "--rerun-save" {
            c.arg(tmp.path().join("x.rrd"));
        }
        let o = c.output().unwrap();
        assert!(!o.status.success(), "{cmd} {flag} ran without the feature");
        let e = stderr(&o);
        assert!(e.contains(flag) && e.contains("--features viz"), "{e}");
        assert!(
            !out.exists(),
            "{cmd} {flag}: wrote {} before refusing",
            out.display()
        );
        assert!(!tmp.path().join("x.rrd").exists());
    }
}
