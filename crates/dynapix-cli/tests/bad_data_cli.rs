//! Bad data gets a clear answer (issue 13), end to end on tiny generated sequences
//! (synth walking_xyz, 20 frames of 160×120): a broken frame stops `slam` and `run` naming it
//! and keeps what was computed, `--skip-bad-frames` records it lost and goes on, a run owns
//! its output folder (replaced as a whole, checked up front), every command decodes images by
//! content, an OS error is printed once, and closed sets list their valid values.
//! Run in release mode (`cargo test --release`).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dynapix"))
}

fn synth(dir: &Path) -> PathBuf {
    let seq = dir.join("seq");
    let o = bin()
        .args(["synth", "--preset", "walking_xyz", "--frames", "20"])
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

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// The rgb and depth files of frame `i` (association order).
fn frame_files(seq: &Path, i: usize) -> (PathBuf, PathBuf) {
    let text = std::fs::read_to_string(seq.join("association.txt")).unwrap();
    let line = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .nth(i)
        .unwrap();
    let f: Vec<&str> = line.split_whitespace().collect();
    (seq.join(f[1]), seq.join(f[3]))
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Data lines of a status or trajectory file.
fn lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(str::to_string)
        .collect()
}

/// A sequence whose frame 8 has a truncated rgb PNG and frame 12 a depth file that is no
/// image.
fn broken_sequence(dir: &Path) -> PathBuf {
    let seq = synth(dir);
    let (rgb8, _) = frame_files(&seq, 8);
    let bytes = std::fs::read(&rgb8).unwrap();
    std::fs::write(&rgb8, &bytes[..bytes.len() / 2]).unwrap();
    let (_, depth12) = frame_files(&seq, 12);
    std::fs::write(&depth12, b"not a depth image").unwrap();
    seq
}

/// `dynapix COMMAND SEQ --quiet --out OUT EXTRA…`.
fn command(name: &str, seq: &Path, out: &Path, extra: &[&str]) -> Output {
    bin()
        .arg(name)
        .arg(seq)
        .args(["--quiet", "--out"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

fn slam(seq: &Path, out: &Path, extra: &[&str]) -> Output {
    command("slam", seq, out, extra)
}

fn run(seq: &Path, out: &Path, extra: &[&str]) -> Output {
    command("run", seq, out, extra)
}

/// Checks a stopped run: the error names frame 8, its time and file; the trajectory and the
/// status hold the 8 frames before it; the record says incomplete and why.
fn assert_stopped_at_frame_8(o: &Output, out: &Path, record: &str, seq: &Path) {
    let err = stderr(o);
    let (rgb8, _) = frame_files(seq, 8);
    let name = rgb8.file_name().unwrap().to_string_lossy().into_owned();
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("frame 8") && err.contains("t = 0.266667") && err.contains(&name),
        "{err}"
    );
    let status = lines(&out.join("status.txt"));
    assert_eq!(status.len(), 8, "{status:?}");
    assert!(!lines(&out.join("trajectory.txt")).is_empty());
    let j = json(&out.join(record));
    assert_eq!(j["complete"], false, "{j}");
    assert!(j["error"].as_str().unwrap().contains("frame 8"), "{j}");
    assert_eq!(j["failed_frame"]["index"], 8);
    assert!(j["failed_frame"]["file"].as_str().unwrap().ends_with(&name));
}

/// Checks a run that skipped frames 8 and 12: 20 status lines with both lost, the record
/// complete and listing them, the summary counting them.
fn assert_skipped_8_and_12(o: &Output, out: &Path, record: &str) {
    assert!(o.status.success(), "{}", stderr(o));
    let status = lines(&out.join("status.txt"));
    assert_eq!(status.len(), 20);
    for i in [8, 12] {
        assert!(status[i].ends_with(" lost"), "{}", status[i]);
    }
    let j = json(&out.join(record));
    assert_eq!(j["complete"], true);
    let skipped: Vec<u64> = j["skipped_frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["index"].as_u64().unwrap())
        .collect();
    assert_eq!(skipped, vec![8, 12], "{j}");
    let summary = format!("{}{}", stdout(o), stderr(o));
    assert!(
        summary.contains("2 bad frame(s) skipped (frames 8, 12)"),
        "{summary}"
    );
}

#[test]
fn a_broken_frame_stops_the_run_by_default_and_is_skipped_on_request() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = broken_sequence(tmp.path());

    // slam: stops at frame 8, keeps the first 8 frames.
    let out = tmp.path().join("slam");
    let o = slam(&seq, &out, &[]);
    assert_stopped_at_frame_8(&o, &out, "slam.json", &seq);
    let o = slam(&seq, &out, &["--skip-bad-frames"]);
    assert_skipped_8_and_12(&o, &out, "slam.json");
    assert_eq!(json(&out.join("slam.json"))["stats"]["frames_skipped"], 2);

    // run (ORB-SLAM2): the same.
    let out = tmp.path().join("run");
    let o = run(&seq, &out, &["--method", "orbslam2"]);
    assert_stopped_at_frame_8(&o, &out, "run.json", &seq);
    let o = run(&seq, &out, &["--method", "orbslam2", "--skip-bad-frames"]);
    assert_skipped_8_and_12(&o, &out, "run.json");

    // run (DynaPix, with its maps): stops before any pass, or skips; the skipped frames get
    // no map and the maps' record names them; two runs give the same trajectory, the second
    // from the cache (kept apart from --out).
    let cache = tmp.path().join("cache");
    let dpx = |out: &Path, extra: &[&str]| {
        let mut args = vec![
            "--method",
            "dynapix",
            "--flow-preset",
            "ultrafast",
            "--cache",
        ];
        let c = cache.to_str().unwrap();
        args.push(c);
        args.extend_from_slice(extra);
        run(&seq, out, &args)
    };
    let a = tmp.path().join("dpx_a");
    let o = dpx(&a, &[]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("frame 8"), "{}", stderr(&o));
    assert_eq!(json(&a.join("run.json"))["complete"], false);
    let o = dpx(&a, &["--skip-bad-frames"]);
    assert_skipped_8_and_12(&o, &a, "run.json");
    let j = json(&a.join("run.json"));
    let maps = &j["passes"][0]["maps"];
    assert_eq!(
        maps["config"]["bad_frames_skipped"],
        serde_json::json!([8, 12])
    );
    let dir = PathBuf::from(maps["dir"].as_str().unwrap());
    let (rgb8, _) = frame_files(&seq, 8);
    assert!(!dir.join(rgb8.file_name().unwrap()).exists());
    let (rgb9, _) = frame_files(&seq, 9);
    assert!(dir.join(rgb9.file_name().unwrap()).is_file());
    let b = tmp.path().join("dpx_b");
    let o = dpx(&b, &["--skip-bad-frames"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        json(&b.join("run.json"))["passes"][0]["maps"]["source"],
        "cache (key matched)"
    );
    assert_eq!(
        std::fs::read(a.join("trajectory.txt")).unwrap(),
        std::fs::read(b.join("trajectory.txt")).unwrap()
    );
}

#[test]
fn a_run_owns_its_output_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path());
    let out = tmp.path().join("out");
    assert!(slam(&seq, &out, &[]).status.success());
    // Files of another command and leftovers of an interrupted run disappear.
    std::fs::write(out.join("run.json"), "{}").unwrap();
    std::fs::create_dir(tmp.path().join("out.tmp-999999")).unwrap();
    std::fs::create_dir(tmp.path().join("out.old-999998")).unwrap();
    let o = slam(&seq, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!out.join("run.json").exists());
    assert_eq!(json(&out.join("slam.json"))["complete"], true);
    let mut names: Vec<String> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["out", "seq"]);

    // A failed run leaves its own partial results, none of the earlier run.
    let (rgb8, _) = frame_files(&seq, 8);
    std::fs::remove_file(&rgb8).unwrap();
    std::fs::write(out.join("stale.txt"), "x").unwrap();
    let o = slam(&seq, &out, &[]);
    assert!(!o.status.success());
    assert!(!out.join("stale.txt").exists());
    assert_eq!(lines(&out.join("status.txt")).len(), 8);
    assert_eq!(json(&out.join("slam.json"))["complete"], false);
    let o = slam(&seq, &out, &["--skip-bad-frames"]);
    assert!(o.status.success(), "{}", stderr(&o));

    // Checked up front: a folder that is not a result set, an unwritable parent, a map
    // folder that cannot be written, the cache or a map to load inside --out.
    let photos = tmp.path().join("photos");
    std::fs::create_dir(&photos).unwrap();
    std::fs::write(photos.join("cat.jpg"), "x").unwrap();
    let o = slam(&seq, &photos, &[]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("photos"), "{}", stderr(&o));
    assert!(photos.join("cat.jpg").exists());
    let file = tmp.path().join("file.txt");
    std::fs::write(&file, "x").unwrap();
    let o = slam(&seq, &file.join("out"), &[]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("file.txt"), "{}", stderr(&o));
    let map = file.join("map.dpxmap");
    let o = slam(
        &seq,
        &tmp.path().join("m"),
        &["--save-map", map.to_str().unwrap()],
    );
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains("file.txt") && err.contains("map"), "{err}");
    assert!(!tmp.path().join("m").exists(), "refused before any work");
    let o = run(
        &seq,
        &out,
        &[
            "--method",
            "orbslam2",
            "--cache",
            out.join("c").to_str().unwrap(),
        ],
    );
    assert!(!o.status.success());
    assert!(stderr(&o).contains("the cache"), "{}", stderr(&o));
    let o = slam(
        &seq,
        &out,
        &["--localize", out.join("x.dpxmap").to_str().unwrap()],
    );
    assert!(!o.status.success());
    assert!(stderr(&o).contains("the map to load"), "{}", stderr(&o));
    assert!(
        out.join("slam.json").is_file(),
        "refused runs leave the folder alone"
    );
}

#[test]
fn every_command_decodes_images_by_content() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path());
    // Frame 5's rgb becomes JPEG bytes under its .png name.
    let (rgb5, _) = frame_files(&seq, 5);
    let img = image::open(&rgb5).unwrap().to_rgb8();
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
        .encode_image(&img)
        .unwrap();
    std::fs::write(&rgb5, &jpeg).unwrap();

    let o = slam(&seq, &tmp.path().join("slam"), &[]);
    assert!(o.status.success(), "slam: {}", stderr(&o));
    assert_eq!(lines(&tmp.path().join("slam/status.txt")).len(), 20);

    let o = bin()
        .arg("motion")
        .arg(&seq)
        .args(["--quiet", "--poses", "gt", "--flow-preset", "ultrafast"])
        .output()
        .unwrap();
    assert!(o.status.success(), "motion: {}", stderr(&o));
    assert!(seq.join("prob").join(rgb5.file_name().unwrap()).is_file());

    let (rgb6, _) = frame_files(&seq, 6);
    let o = bin()
        .arg("flow")
        .arg(&rgb5)
        .arg(&rgb6)
        .arg("--out")
        .arg(tmp.path().join("f.flo"))
        .output()
        .unwrap();
    assert!(o.status.success(), "flow: {}", stderr(&o));

    // A file that is no image fails the same way in every command.
    std::fs::write(&rgb5, b"# not an image").unwrap();
    let msgs: Vec<String> = [
        slam(&seq, &tmp.path().join("slam2"), &[]),
        bin()
            .arg("flow")
            .arg(&rgb5)
            .arg(&rgb6)
            .arg("--out")
            .arg(tmp.path().join("g.flo"))
            .output()
            .unwrap(),
    ]
    .iter()
    .map(|o| {
        assert!(!o.status.success());
        stderr(o)
    })
    .collect();
    for m in &msgs {
        assert!(m.contains("the content is neither PNG nor JPEG"), "{m}");
    }
}

#[test]
fn an_os_error_is_printed_once() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path());
    let (rgb3, _) = frame_files(&seq, 3);
    std::fs::remove_file(&rgb3).unwrap();
    let o = slam(&seq, &tmp.path().join("out"), &[]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert_eq!(err.matches("os error 2").count(), 1, "{err}");
    assert!(
        err.contains(rgb3.file_name().unwrap().to_str().unwrap()),
        "{err}"
    );
}

#[test]
fn closed_sets_list_their_valid_values() {
    let tmp = tempfile::tempdir().unwrap();
    let o = bin()
        .args([
            "experiment",
            "--methods",
            "foo",
            "--sequences",
            "x",
            "--out",
        ])
        .arg(tmp.path().join("e"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(
        err.contains("'foo'") && err.contains("orbslam2, dynapix, dynapix+, no-movable"),
        "{err}"
    );
    let o = bin()
        .args(["motion", "seq", "--poses", "bogus"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains("'bogus'") && err.contains("gt, own"), "{err}");
    for args in [
        &["run", "seq", "--method", "bogus", "--out", "o"][..],
        &["run", "seq", "--cues", "paper,nope", "--out", "o"],
        &["slam", "seq", "--camera", "tum9", "--out", "o"],
        &["synth", "--preset", "nope"],
    ] {
        let o = bin().args(args).output().unwrap();
        assert!(!o.status.success(), "{args:?}");
        let err = stderr(&o);
        assert!(
            err.contains("possible values") || err.contains("expected one of"),
            "{args:?}: {err}"
        );
    }
}

/// Depth pixels at the sensor's saturation value are counted in `run.json` (frames and
/// pixels read as missing), offline and online.
#[test]
fn run_json_counts_the_depth_read_as_missing() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path());
    for i in [4, 9] {
        let (_, depth) = frame_files(&seq, i);
        let mut d = image::open(&depth).unwrap().to_luma16();
        for y in 0..10 {
            for x in 0..(10 + i as u32) {
                d.put_pixel(x, y, image::Luma([u16::MAX]));
            }
        }
        d.save(&depth).unwrap();
    }
    for extra in [
        &["--method", "orbslam2"][..],
        &["--method", "orbslam2", "--online"],
    ] {
        let out = tmp.path().join("out");
        let o = run(&seq, &out, extra);
        assert!(o.status.success(), "{extra:?}: {}", stderr(&o));
        let rec = json(&out.join("run.json"));
        assert_eq!(rec["invalid_depth"]["frames"], 2, "{extra:?}");
        assert_eq!(
            rec["invalid_depth"]["pixels"],
            10 * (10 + 4) + 10 * (10 + 9),
            "{extra:?}"
        );
    }
}
