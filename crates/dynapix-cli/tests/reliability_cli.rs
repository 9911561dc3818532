//! Nothing lost, nothing silently wrong (issue 36), end to end on tiny generated sequences
//! (synth walking_xyz, 20 frames of 160×120): two runs never share an output folder, a cache
//! fault never replaces an earlier result, offline DynaPix that tracks nothing writes its
//! status and honours `--allow-untracked`, an unwritable cache stops a run before it starts,
//! `motion` leaves a read-only sequence alone, `run.json` names the ground-truth convention,
//! WARN lines carry no colour codes in a file, and a two-frame run says why it has no ATE.
//! Run in release mode (`cargo test --release`).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dynapix"))
}

fn synth(dir: &Path, name: &str) -> PathBuf {
    let seq = dir.join(name);
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

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// `dynapix run SEQ --quiet --out OUT EXTRA…` as a command.
fn run_cmd(seq: &Path, out: &Path, extra: &[&str]) -> Command {
    let mut c = bin();
    c.arg("run")
        .arg(seq)
        .args(["--quiet", "--out"])
        .arg(out)
        .args(extra);
    c
}

fn run(seq: &Path, out: &Path, extra: &[&str]) -> Output {
    run_cmd(seq, out, extra).output().unwrap()
}

/// A complete result set of `run`.
fn assert_complete(out: &Path) {
    for f in ["trajectory.txt", "status.txt", "run.json"] {
        assert!(out.join(f).is_file(), "{} has no {f}", out.display());
    }
    assert_eq!(json(&out.join("run.json"))["complete"], true);
}

#[test]
fn two_runs_into_one_out_never_mix() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), "seq");
    let fast = ["--method", "orbslam2"];

    // Deterministic: the folder is taken (by this process); the run is refused, naming it.
    let out = tmp.path().join("out");
    let held = dynapix_io::OutputFolder::begin(&out, &["run.json"]).unwrap();
    std::fs::write(held.path().join("run.json"), "{\"complete\": true}").unwrap();
    let o = run(&seq, &out, &fast);
    assert!(!o.status.success());
    let err = stderr(&o);
    let pid = std::process::id().to_string();
    assert!(
        err.contains(&format!("pid {pid}")) && err.contains("out.lock") && err.contains("--out"),
        "{err}"
    );
    assert!(
        held.path().join("run.json").is_file(),
        "the live run's files stay"
    );
    held.commit().unwrap();
    assert_eq!(json(&out.join("run.json"))["complete"], true);
    let o = run(&seq, &out, &fast);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_complete(&out);

    // Two processes: while the first holds the folder, the second is refused naming it; the
    // first's result is complete.
    let out = tmp.path().join("out2");
    let lock = tmp.path().join("out2.lock");
    let mut first = run_cmd(&seq, &out, &["--flow-preset", "ultrafast"])
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !lock.exists() && start.elapsed() < Duration::from_secs(120) {
        if first.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let second = run(&seq, &out, &fast);
    let first_running = first.try_wait().unwrap().is_none();
    if !second.status.success() {
        let err = stderr(&second);
        assert!(
            err.contains(&format!("pid {}", first.id())),
            "refused, naming the first run: {err}"
        );
    } else {
        assert!(
            !first_running,
            "the second run succeeded while the first was still running"
        );
    }
    assert!(first.wait().unwrap().success());
    assert_complete(&out);
    assert!(!lock.exists(), "the lock file goes with the lock");
}

/// Offline DynaPix on frames where nothing can be tracked (black images): the first pass is
/// the result, with `status.txt`, exit 1, and exit 0 with `--allow-untracked`.
#[test]
fn offline_dynapix_that_tracks_nothing_writes_its_status() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), "seq");
    for e in std::fs::read_dir(seq.join("rgb")).unwrap() {
        let p = e.unwrap().path();
        image::RgbImage::new(160, 120).save(&p).unwrap();
    }
    let out = tmp.path().join("out");
    let o = run(&seq, &out, &[]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(
        err.contains("nothing tracked") && err.contains("--allow-untracked"),
        "{err}"
    );
    let status = std::fs::read_to_string(out.join("status.txt")).unwrap();
    assert_eq!(
        status.lines().filter(|l| !l.starts_with('#')).count(),
        20,
        "{status}"
    );
    assert!(!status.contains(" tracked"), "{status}");
    let j = json(&out.join("run.json"));
    assert_eq!(j["complete"], true);
    assert!(j["nothing_tracked"].is_string(), "{j}");
    let o = run(&seq, &out, &["--allow-untracked"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("status.txt").is_file());
}

/// The cache: unwritable fails up front; a damaged item is recomputed with a plain WARN line
/// (no colour codes in a file); a cache that cannot be repaired stops the run without
/// replacing the earlier result.
#[test]
fn cache_faults_cost_no_earlier_result() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), "seq");
    let cache = tmp.path().join("cache");
    let out = tmp.path().join("out");
    let dpx = |extra: &[&str]| {
        let mut args = vec!["--flow-preset", "ultrafast", "--cache"];
        args.push(cache.to_str().unwrap());
        args.extend_from_slice(extra);
        run(&seq, &out, &args)
    };

    // Unwritable: refused before any work (a file where the folder should be).
    let file = tmp.path().join("file.txt");
    std::fs::write(&file, "x").unwrap();
    let bad_cache = file.join("c");
    let started = Instant::now();
    let o = run(
        &seq,
        &out,
        &[
            "--cache",
            bad_cache.to_str().unwrap(),
            "--flow-preset",
            "ultrafast",
        ],
    );
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(
        err.contains("the cache") && err.contains("file.txt") && err.contains("--cache"),
        "{err}"
    );
    assert!(!out.exists(), "refused before any work");
    assert!(started.elapsed() < Duration::from_secs(30));

    let o = dpx(&[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_complete(&out);
    let good = std::fs::read(out.join("trajectory.txt")).unwrap();
    let maps = PathBuf::from(json(&out.join("run.json"))["prob"]["dir"].as_str().unwrap());
    let map = std::fs::read_dir(&maps)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "png"))
        .min()
        .unwrap();

    // A truncated map: recomputed, a plain WARN line naming it, the same result.
    let bytes = std::fs::read(&map).unwrap();
    std::fs::write(&map, &bytes[..bytes.len() / 3]).unwrap();
    let o = run(
        &seq,
        &out,
        &[
            "--flow-preset",
            "ultrafast",
            "--cache",
            cache.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    let name = map.file_name().unwrap().to_string_lossy().into_owned();
    assert!(err.contains("WARN") && err.contains(&name), "{err}");
    assert!(!err.contains('\u{1b}'), "colour codes in a file: {err:?}");
    assert_eq!(std::fs::read(out.join("trajectory.txt")).unwrap(), good);
    assert_eq!(std::fs::read(&map).unwrap(), bytes);

    // A cache that cannot be repaired (a folder where a map should be): the run stops and
    // --out keeps the earlier complete result.
    std::fs::remove_file(&map).unwrap();
    std::fs::create_dir(&map).unwrap();
    let o = dpx(&[]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains("cache") && err.contains(&name), "{err}");
    assert_complete(&out);
    assert_eq!(std::fs::read(out.join("trajectory.txt")).unwrap(), good);
}

/// `motion` refuses a sequence marked read-only; `run.json` names the ground-truth
/// convention (camera poses for a synthetic sequence, marker poses for a Bonn folder); a
/// two-frame run says why it has no ATE.
#[test]
fn read_only_sequences_conventions_and_short_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), "seq");
    let listing = |d: &Path| {
        let mut v: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    let before = listing(&seq);
    let mut perms = std::fs::metadata(&seq).unwrap().permissions();
    perms.set_readonly(true);
    std::fs::set_permissions(&seq, perms.clone()).unwrap();
    let o = bin()
        .args(["motion", "--quiet"])
        .arg(&seq)
        .args(["--flow-preset", "ultrafast"])
        .output()
        .unwrap();
    #[allow(clippy::permissions_set_readonly_false)]
    perms.set_readonly(false);
    std::fs::set_permissions(&seq, perms).unwrap();
    assert!(!o.status.success());
    assert!(stderr(&o).contains("read-only"), "{}", stderr(&o));
    assert_eq!(listing(&seq), before, "nothing written into the sequence");

    let out = tmp.path().join("out");
    let o = run(&seq, &out, &["--method", "orbslam2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let gt = &json(&out.join("run.json"))["sequence"]["groundtruth_convention"];
    assert_eq!(gt["file_holds"], "camera", "{gt}");
    assert!(gt["rule"].as_str().unwrap().contains("rgbd_bonn_"), "{gt}");
    // The same files in a folder named like a Bonn sequence: marker poses, converted.
    let bonn = tmp.path().join("rgbd_bonn_test");
    std::fs::rename(&seq, &bonn).unwrap();
    let o = run(&bonn, &out, &["--method", "orbslam2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let gt = &json(&out.join("run.json"))["sequence"]["groundtruth_convention"];
    assert_eq!(gt["file_holds"], "bonn-marker", "{gt}");
    assert!(
        gt["used_as"].as_str().unwrap().contains("converted"),
        "{gt}"
    );

    let o = run(
        &bonn,
        &out,
        &[
            "--method",
            "orbslam2",
            "--max-frames",
            "2",
            "--allow-untracked",
        ],
    );
    let said = format!("{}{}", stdout(&o), stderr(&o));
    assert!(
        said.contains("an ATE needs at least 3") || said.contains("no poses"),
        "{said}"
    );
    assert!(!said.contains("no overlap"), "{said}");
}

/// A weighted pass that tracks nothing (here the first one, weighted by the sequence's own
/// maps that call every pixel dynamic) leaves the next pass without poses: the run ends with
/// it as its result, like a first pass that tracked nothing (exit 1 with the outputs written,
/// exit 0 with `--allow-untracked`).
#[test]
fn a_weighted_pass_that_tracks_nothing_ends_the_run_like_an_untracked_first_pass() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = synth(tmp.path(), "seq");
    let prob = seq.join("prob");
    std::fs::create_dir_all(&prob).unwrap();
    for e in std::fs::read_dir(seq.join("rgb")).unwrap() {
        let p = e.unwrap().path();
        // Stored 0 = weight 0 = P 1 everywhere.
        let name = p.with_extension("png");
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(160, 120)
            .save(prob.join(name.file_name().unwrap()))
            .unwrap();
    }
    let out = tmp.path().join("out");
    let o = run(&seq, &out, &["--flow-preset", "ultrafast", "--no-cache"]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(
        err.contains("nothing tracked") && err.contains("--allow-untracked"),
        "{err}"
    );
    let status = std::fs::read_to_string(out.join("status.txt")).unwrap();
    assert_eq!(
        status.lines().filter(|l| !l.starts_with('#')).count(),
        20,
        "{status}"
    );
    assert!(!status.contains(" tracked"), "{status}");
    let j = json(&out.join("run.json"));
    assert_eq!(j["complete"], true);
    let why = j["nothing_tracked"].as_str().unwrap_or_default();
    assert!(why.contains("weighted pass 1 tracked no frame"), "{j}");
    assert_eq!(j["passes"].as_array().map(Vec::len), Some(1), "{j}");
    let o = run(
        &seq,
        &out,
        &[
            "--flow-preset",
            "ultrafast",
            "--no-cache",
            "--allow-untracked",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
}
