//! Online DynaPix on a sequence folder, watched in the Rerun viewer (the `online_rgbd`
//! example of the `dynapix` crate with a viewer):
//!
//! ```sh
//! cargo run --release -p dynapix-rerun --example online_rgbd_rerun -- SEQ_DIR --rerun
//! cargo run --release -p dynapix-rerun --example online_rgbd_rerun -- SEQ_DIR --rerun-save run.rrd
//! ```
//!
//! `--rerun` connects to a viewer on 127.0.0.1:9876 or starts `rerun` (from
//! `pip install rerun-sdk==0.36.*`; run `rerun analytics disable` once). Prints one TUM line
//! per tracked frame on stdout as soon as its pose is known.

use std::process::ExitCode;
use std::sync::Arc;

use dynapix::{CameraChoice, Config, FrameResult, Input, run_online};
use dynapix_rerun::{RerunObserver, RerunParams, Target};

fn usage() -> ExitCode {
    eprintln!("usage: online_rgbd_rerun SEQ_DIR (--rerun | --rerun-save FILE.rrd) [--lookahead K]");
    ExitCode::FAILURE
}

fn print(r: &FrameResult) {
    if let Some(p) = r.pose_wc {
        let (t, q) = (p.translation.vector, p.rotation);
        println!(
            "{:.6} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
            r.t, t.x, t.y, t.z, q.i, q.j, q.k, q.w
        );
    }
}

fn run(dir: &str, config: &Config, target: &Target) -> Result<(), Box<dyn std::error::Error>> {
    let input = Input::open(dir, &config.sequence, &CameraChoice::Sequence)?;
    let observer = Arc::new(RerunObserver::open(target, dir, RerunParams::default())?);
    let (run, result) = run_online(
        &input,
        config,
        None,
        &(),
        &mut print,
        Some(observer.clone()),
    );
    observer.finish()?;
    result?;
    eprintln!(
        "{} frames, {} tracked; recording sent to {target}",
        input.len(),
        run.tracked()
    );
    Ok(())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(dir) = args.first() else {
        return usage();
    };
    let mut config = Config::default();
    let mut target = None;
    let mut it = args[1..].iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--rerun" => target = Some(Target::Spawn),
            "--rerun-save" => match it.next() {
                Some(f) => target = Some(Target::Save(f.into())),
                None => return usage(),
            },
            "--lookahead" => match it.next().and_then(|k| k.parse().ok()) {
                Some(k) => config.online.lookahead = k,
                None => return usage(),
            },
            _ => return usage(),
        }
    }
    let Some(target) = target else {
        return usage();
    };
    match run(dir, &config, &target) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
