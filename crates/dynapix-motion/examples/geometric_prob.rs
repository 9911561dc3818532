//! Geometric motion maps of a sequence from a trajectory (development tool).
//!
//! `cargo run --release -p dynapix-motion --example geometric_prob -- SEQ TRAJ OUT [COMBINE]`
//! reads the sequence folder `SEQ` with `dynapix_io::Sequence`, takes the camera poses from
//! the TUM trajectory `TRAJ` (nearest pose within 0.05 s), computes the geometric cue of every
//! frame from its neighbours' depth (`dynapix_motion::static_depth`) and writes the 16-bit
//! probability maps `OUT/<rgb name>.png`. With a fourth argument, each map is combined
//! (noisy-or) with the map of the same name in `COMBINE`.

use std::path::PathBuf;

use dynapix_io::images::read_depth;
use dynapix_io::weights::{read_prob_png, write_prob_png};
use dynapix_io::{Sequence, Trajectory};
use dynapix_motion::{
    DepthView, StaticDepthParams, WorkingDepth, geometric_term, select_views, static_depth,
};
use image::Luma;
use rayon::prelude::*;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        eprintln!("usage: geometric_prob SEQ TRAJ OUT [COMBINE]");
        std::process::exit(2);
    }
    let seq = Sequence::open(&args[0])?;
    let traj = Trajectory::read_tum(&args[1])?;
    let out = PathBuf::from(&args[2]);
    let combine: Vec<PathBuf> = args
        .get(3)
        .map(|a| a.split(',').map(PathBuf::from).collect())
        .unwrap_or_default();
    let no_geo = std::env::var("DPX_NO_GEO").is_ok();
    std::fs::create_dir_all(&out)?;
    let cam = seq.settings()?.camera();
    let mut params = StaticDepthParams::default();
    if let Ok(v) = std::env::var("DPX_STATIC_DEPTH") {
        // JSON overrides, e.g. DPX_STATIC_DEPTH='{"window_s": 4.0}'.
        params = serde_json::from_str(&v)?;
    }
    let stamps: Vec<f64> = seq.frames.iter().map(|f| f.t).collect();
    let poses: Vec<Option<dynapix_geometry::se3::Se3>> = stamps
        .iter()
        .map(|&t| {
            traj.poses
                .iter()
                .min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs()))
                .filter(|p| (p.t - t).abs() <= 0.05)
                .map(|p| p.pose)
        })
        .collect();
    let t0 = std::time::Instant::now();
    let depths: Vec<WorkingDepth> = seq
        .frames
        .par_iter()
        .map(|f| read_depth(&f.depth, seq.depth_factor).map(|d| WorkingDepth::new(&d, &params)))
        .collect::<Result<_, _>>()?;
    eprintln!(
        "loaded {} depth maps in {:.1} s",
        depths.len(),
        t0.elapsed().as_secs_f64()
    );
    let results: Vec<Result<f64, String>> = (0..seq.frames.len())
        .into_par_iter()
        .map(|t| {
            let name = seq.frames[t].rgb.file_name().ok_or("no file name")?;
            let mut p = match poses[t].filter(|_| !no_geo) {
                None => dynapix_motion::FloatImage::new(cam.width, cam.height),
                Some(twc) => {
                    let idx = select_views(&stamps, t, |s| poses[s].is_some(), &params);
                    let views: Vec<DepthView> = idx
                        .iter()
                        .filter_map(|&s| {
                            let tws = poses[s]?;
                            Some(DepthView {
                                depth: &depths[s],
                                t_cs: twc.inverse() * tws,
                            })
                        })
                        .collect();
                    if views.is_empty() {
                        dynapix_motion::FloatImage::new(cam.width, cam.height)
                    } else {
                        let sd = static_depth(&cam, &views, &params).map_err(|e| e.to_string())?;
                        geometric_term(&depths[t], &sd, &params).map_err(|e| e.to_string())?
                    }
                }
            };
            for c in &combine {
                let q = read_prob_png(c.join(name)).map_err(|e| e.to_string())?;
                for (a, b) in p.pixels_mut().zip(q.pixels()) {
                    *a = Luma([1.0 - (1.0 - a.0[0]) * (1.0 - b.0[0])]);
                }
            }
            let mean = p.as_raw().iter().map(|&v| v as f64).sum::<f64>() / p.len() as f64;
            write_prob_png(out.join(name), &p).map_err(|e| e.to_string())?;
            Ok(mean)
        })
        .collect();
    let mut sum = 0.0;
    for r in &results {
        sum += r.as_ref().map_err(|e| e.clone())?;
    }
    eprintln!(
        "{} maps, mean P {:.3}, {:.1} s",
        results.len(),
        sum / results.len().max(1) as f64,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
