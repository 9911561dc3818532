//! Writes the pose-free rigidity cue ([`dynapix_motion::rigidity`]) of every frame of a
//! TUM-layout sequence folder as probability maps `OUT/<rgb file name>` in the project's
//! 16-bit format (`dynapix_io::weights::write_prob_png`), and prints per frame the mean P, the
//! time the frame took and, per neighbour, the fit (inlier fraction, translation) and, when
//! the sequence has ground truth, how far the fit is from the ground-truth camera motion.
//!
//! `cargo run --release -p dynapix-motion --example rigidity_prob -- SEQUENCE OUT
//! [--max-frames N] [--preset ultrafast|fast|medium]`
//!
//! The camera comes from the sequence (`camera.yaml`, or the dataset of the folder name, e.g.
//! `rgbd_bonn_*`). Frames run in parallel (rayon; `RAYON_NUM_THREADS` limits the threads),
//! in chunks so that only a chunk and its neighbours are in memory.

use std::path::PathBuf;
use std::time::Instant;

use dynapix_io::Sequence;
use dynapix_motion::moving::to_gray;
use dynapix_motion::{FloatImage, RigidFrame, RigidityParams, rigidity_probability};
use image::GrayImage;
use rayon::prelude::*;

type Error = Box<dyn std::error::Error + Send + Sync>;

struct Args {
    seq: PathBuf,
    out: PathBuf,
    max_frames: Option<usize>,
    params: RigidityParams,
}

fn parse_args() -> Result<Args, Error> {
    let mut pos = Vec::new();
    let mut max_frames = None;
    let mut params = RigidityParams::default();
    if let Ok(v) = std::env::var("DPX_RIGIDITY") {
        // JSON overrides, e.g. DPX_RIGIDITY='{"sigma_px": 0.5}'.
        params = serde_json::from_str(&v)?;
    }
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        match a.as_str() {
            "--max-frames" => {
                max_frames = Some(it.next().ok_or("--max-frames needs a value")?.parse()?);
            }
            "--preset" => {
                params.flow_preset = it.next().ok_or("--preset needs a value")?.parse()?;
            }
            "-h" | "--help" => {
                return Err("usage: rigidity_prob SEQUENCE OUT [--max-frames N] \
                            [--preset ultrafast|fast|medium]"
                    .into());
            }
            _ => pos.push(PathBuf::from(a)),
        }
    }
    let [seq, out] = <[PathBuf; 2]>::try_from(pos)
        .map_err(|_| "expected two paths: SEQUENCE OUT (see --help)")?;
    Ok(Args {
        seq,
        out,
        max_frames,
        params,
    })
}

/// What one frame's computation reports.
struct FrameReport {
    mean_p: f64,
    fits: Vec<String>,
    secs: f64,
}

fn main() -> Result<(), Error> {
    let args = parse_args()?;
    args.params.validate()?;
    let seq = Sequence::open(&args.seq)?;
    let cam = seq.settings()?.camera();
    let n = args.max_frames.map_or(seq.len(), |m| m.min(seq.len()));
    std::fs::create_dir_all(&args.out)?;
    let offsets = &args.params.offsets;
    let reach = offsets
        .iter()
        .map(|o| o.unsigned_abs() as usize)
        .max()
        .unwrap_or(0);
    println!(
        "{}: {n} frames, camera {}×{} fx {:.3}, DIS {:?}, offsets {offsets:?}, {} threads",
        seq.dir.display(),
        cam.width,
        cam.height,
        cam.fx,
        args.params.flow_preset,
        rayon::current_num_threads()
    );

    let load = |i: usize| -> Result<(GrayImage, FloatImage), Error> {
        let info = &seq.frames[i];
        let rgb = dynapix_io::images::read_rgb(&info.rgb)?;
        let depth = dynapix_io::images::read_depth(&info.depth, seq.depth_factor)?;
        Ok((to_gray(&rgb), depth))
    };
    let start = Instant::now();
    let mut sum_secs = 0.0;
    let chunk = 4 * rayon::current_num_threads().max(1);
    for first in (0..n).step_by(chunk) {
        let last = (first + chunk).min(n);
        // Frames this chunk reads: its own and their neighbours.
        let lo = first.saturating_sub(reach);
        let hi = (last + reach).min(n);
        let loaded: Vec<(GrayImage, FloatImage)> = (lo..hi)
            .into_par_iter()
            .map(load)
            .collect::<Result<_, _>>()?;
        let frame = |i: usize, o: i64| RigidFrame {
            gray: &loaded[i - lo].0,
            depth: &loaded[i - lo].1,
            offset: o,
        };
        let reports: Vec<FrameReport> = (first..last)
            .into_par_iter()
            .map(|i| -> Result<FrameReport, Error> {
                let t0 = Instant::now();
                let neighbours_idx: Vec<usize> = offsets
                    .iter()
                    .filter_map(|&o| usize::try_from(i as i64 + o).ok())
                    .filter(|&j| j < n)
                    .collect();
                let neighbours: Vec<RigidFrame> = neighbours_idx
                    .iter()
                    .map(|&j| frame(j, j as i64 - i as i64))
                    .collect();
                let maps = rigidity_probability(&frame(i, 0), &neighbours, &cam, &args.params)?;
                let name = seq.frames[i]
                    .rgb
                    .file_name()
                    .ok_or("rgb path without a file name")?;
                dynapix_io::weights::write_prob_png(args.out.join(name), &maps.p)?;
                let mean_p =
                    maps.p.iter().map(|&v| v as f64).sum::<f64>() / maps.p.len().max(1) as f64;
                let fits = maps
                    .fits
                    .iter()
                    .zip(&neighbours_idx)
                    .map(|(f, &j)| match f {
                        Ok(f) => {
                            let t = f.motion.translation.vector * 1e3;
                            let mut s = format!(
                                "{j}: inl {:.2} of {} t ({:.1} {:.1} {:.1}) mm",
                                f.inlier_fraction(),
                                f.correspondences,
                                t.x,
                                t.y,
                                t.z
                            );
                            // With ground truth: how far the fit is from the camera motion.
                            let gt = |k: usize| seq.gt_pose_at(seq.frames[k].t);
                            if let (Some(wi), Some(wj)) = (gt(i), gt(j)) {
                                let t_ji = wj.inverse() * wi;
                                let d = f.motion.inverse() * t_ji;
                                let dt =
                                    (f.motion.translation.vector - t_ji.translation.vector).norm();
                                s += &format!(
                                    " vs GT {:.1} mm {:.2}°",
                                    dt * 1e3,
                                    d.rotation.angle().to_degrees()
                                );
                            }
                            s
                        }
                        Err(e) => format!("{j}: no fit ({e})"),
                    })
                    .collect();
                Ok(FrameReport {
                    mean_p,
                    fits,
                    secs: t0.elapsed().as_secs_f64(),
                })
            })
            .collect::<Result<_, _>>()?;
        for (k, r) in reports.iter().enumerate() {
            let i = first + k;
            sum_secs += r.secs;
            println!(
                "frame {i:4} {}: mean P {:.3}, {:.0} ms, fits [{}]",
                seq.frames[i]
                    .rgb
                    .file_name()
                    .unwrap_or_default()
                    .to_string_lossy(),
                r.mean_p,
                r.secs * 1e3,
                r.fits.join("; "),
            );
        }
    }
    let wall = start.elapsed().as_secs_f64();
    println!(
        "{n} frames in {wall:.1} s wall ({:.0} ms per frame including reading and writing); \
         mean time inside one frame's computation {:.0} ms",
        wall * 1e3 / n.max(1) as f64,
        sum_secs * 1e3 / n.max(1) as f64
    );
    Ok(())
}
