//! Online DynaPix on a sequence folder, one frame at a time, as a robot would feed it:
//!
//! ```sh
//! cargo run --release -p dynapix --example online_rgbd -- SEQ_DIR [--lookahead K] [--config FILE]
//! ```
//!
//! Prints one TUM line (`t tx ty tz qx qy qz qw`, camera-to-world) per tracked frame on
//! stdout, as soon as the frame's pose is known, and a summary on stderr. The folder is read
//! with the library's sequence reader (`camera.yaml` or a TUM folder name gives the camera).
//!
//! To watch it in the Rerun viewer (`--rerun`, `--rerun-save FILE.rrd`) run the same loop
//! from the `dynapix-rerun` crate, which compiles `rerun`:
//! `cargo run --release -p dynapix-rerun --example online_rgbd_rerun -- SEQ_DIR --rerun-save run.rrd`.

use std::process::ExitCode;

use dynapix::run_online;
use dynapix::{CameraChoice, Config, FrameResult, Input};

fn usage() -> ExitCode {
    eprintln!("usage: online_rgbd SEQ_DIR [--lookahead K] [--config FILE]");
    ExitCode::FAILURE
}

fn print(r: &FrameResult) {
    if let Some(p) = r.pose_wc {
        let t = p.translation.vector;
        let q = p.rotation;
        println!(
            "{:.6} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
            r.t, t.x, t.y, t.z, q.i, q.j, q.k, q.w
        );
    }
}

fn run(dir: &str, config: &Config) -> dynapix::Result<()> {
    let input = Input::open(dir, &config.sequence, &CameraChoice::Sequence)?;
    // The library's online driver: frames read ahead on a reader thread, DynaPix+ masks from
    // the folder's `mask/`, each result printed as soon as it is known.
    let (run, result) = run_online(&input, config, None, &(), &mut print, None);
    result?;
    let n = input.len().max(1) as f64;
    let sum = |f: fn(&FrameResult) -> f64| run.results.iter().map(f).sum::<f64>();
    eprintln!(
        "{} frames, {} tracked, lookahead {} frames; per frame: motion {:.1} ms, SLAM {:.1} ms; {:.1} s wall (with image decoding)",
        input.len(),
        run.tracked(),
        run.lookahead,
        sum(|r| r.motion_ms) / n,
        sum(|r| r.slam_ms) / n,
        run.wall_seconds
    );
    Ok(())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(dir) = args.first() else {
        return usage();
    };
    let mut config = Config::default();
    let mut lookahead = None;
    let mut it = args[1..].iter();
    while let Some(a) = it.next() {
        if a == "--rerun" || a == "--rerun-save" {
            eprintln!(
                "error: {a} needs the Rerun viewer, which this example does not compile: run \
                 `cargo run --release -p dynapix-rerun --example online_rgbd_rerun -- SEQ_DIR {a} …`"
            );
            return ExitCode::FAILURE;
        }
        match (a.as_str(), it.next()) {
            ("--lookahead", Some(k)) => match k.parse() {
                Ok(k) => lookahead = Some(k),
                Err(_) => return usage(),
            },
            ("--config", Some(f)) => match Config::load(f) {
                Ok(c) => config = c,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            },
            _ => return usage(),
        }
    }
    if let Some(k) = lookahead {
        config.online.lookahead = k;
    }
    match run(dir, &config) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
