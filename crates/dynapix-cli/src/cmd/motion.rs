//! `dynapix motion`: per-pixel motion probability maps for a sequence (paper §3.1, spec §1).
//!
//! Reads the sequence with the library's reader, the camera (`--camera`, `--settings`,
//! `camera.yaml`, or the preset of `rgbd_dataset_freiburgN_*` and `rgbd_bonn_*` folders),
//! poses (ground truth as camera poses with SLERP, the system's own ORB-SLAM2 pass, or any TUM trajectory) and a background
//! source (`background/` + `depth_bg/` folders, or a reconstruction from neighbouring frames),
//! and writes `SEQ_DIR/prob/<rgb file name>` (16-bit, `trunc((1 − P)·1000)`, the reference
//! format) plus `prob/motion.json` recording every source and parameter (read back by `run`).
//! All frames are checked before anything is written; each output file is written
//! atomically, and frames whose output exists are skipped unless `--force`, so an
//! interrupted run resumes. The computation is the library's (`dynapix::maps`); this module
//! adds the analysis outputs (pictures, float maps, evaluation against masks).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use dynapix::stages::{FramePoses, MapFolder, MapJob};
use dynapix::{BackgroundSource, FlowPreset, Mode, PoseSource};
use dynapix::{OfflineRunner, RunOptions};
use dynapix_io::{MotionProbability, StampedPose, Trajectory};
use dynapix_motion::metrics::MaskEvaluation;
use dynapix_motion::{FloatImage, Variant};
use image::{Rgb, RgbImage};
use serde_json::json;

use super::common::{Bars, SequenceArgs};

/// Reference constant set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum VariantArg {
    /// TUM script constants (neighbours ±1, flow clip [1, 4] px).
    Tum,
    /// GRADE script constants (neighbours ±2, flow clip [0.5, 2.5] px).
    Grade,
}

/// Arguments of `dynapix motion`.
#[derive(clap::Args)]
pub struct Args {
    /// The sequence.
    #[command(flatten)]
    pub seq: SequenceArgs,
    /// Poses for splatting: `gt` (SEQ_DIR/groundtruth.txt, SLERP at frame time), `own` (the
    /// system's own ORB-SLAM2 pass, cached in SEQ_DIR/dynapix_cache, or under the user cache
    /// directory when SEQ_DIR is not writable) or a TUM trajectory file.
    #[arg(long, default_value = "gt", value_name = "gt|own|FILE", value_parser = parse_poses)]
    pub poses: PoseSource,
    /// Largest allowed distance (s) from a frame to the nearest pose.
    #[arg(long)]
    pub max_pose_gap: Option<f64>,
    /// Static background source.
    #[arg(long, value_enum)]
    pub background: Option<BackgroundSource>,
    /// Paper method (default) or reference behaviour.
    #[arg(long, value_enum)]
    pub mode: Option<Mode>,
    /// Reference constant set.
    #[arg(long, value_enum)]
    pub variant: Option<VariantArg>,
    /// Neighbour offsets J, comma separated (default ±1 for tum, ±2 for grade).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub offsets: Option<Vec<i64>>,
    /// Ablation: no movable term (D = 1).
    #[arg(long)]
    pub no_movable: bool,
    /// Ablation: no moving term (M = 1).
    #[arg(long)]
    pub no_moving: bool,
    /// DIS preset.
    #[arg(long, value_enum)]
    pub flow_preset: Option<FlowPreset>,
    /// The cues of P, comma separated, combined by noisy-or (paper mode:
    /// paper,geometric,rigidity; reference: paper).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub cues: Option<Vec<dynapix::Cue>>,
    /// Background reconstruction: largest frame offset.
    #[arg(long)]
    pub bg_radius: Option<usize>,
    /// Refine the rotation of every relative pose by this many image-alignment iterations
    /// before splatting (for noisy poses, e.g. from a SLAM run); 0 trusts the poses.
    #[arg(long)]
    pub refine_rotation: Option<usize>,
    /// Background reconstruction: offset step.
    #[arg(long)]
    pub bg_step: Option<usize>,
    /// Recompute frames whose output already exists.
    #[arg(long)]
    pub force: bool,
    /// Also write P losslessly as `prob/<stem>.pfm`.
    #[arg(long)]
    pub float_maps: bool,
    /// Also write pictures (moving regions in red over the frame) to `SEQ_DIR/prob_vis/`.
    #[arg(long)]
    pub pictures: bool,
    /// Also write reconstructed backgrounds to `SEQ_DIR/background_rec/`.
    #[arg(long)]
    pub save_background: bool,
    /// Measure the maps against `mask/` (255 = moving): ROC-AUC and IoU at P > 0.5; with a
    /// reconstructed background and a `background/` folder, also its PSNR inside the movers.
    #[arg(long)]
    pub eval_masks: bool,
    /// Perturb every pose: RMS translation (m) and rotation (degrees), e.g. `0.01,1`.
    #[arg(long, value_delimiter = ',', num_args = 1)]
    pub pose_noise: Option<Vec<f64>>,
    /// Seed of `--pose-noise`.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Write the poses used (after noise) as a TUM trajectory.
    #[arg(long)]
    pub write_poses: Option<PathBuf>,
}

/// `--poses`: one of the two names, or a trajectory file that exists; anything else lists
/// the valid values.
fn parse_poses(s: &str) -> Result<PoseSource, String> {
    match s {
        "gt" => Ok(PoseSource::GroundTruth),
        "own" => Ok(PoseSource::Own),
        f if std::path::Path::new(f).is_file() => Ok(PoseSource::File(PathBuf::from(f))),
        f => Err(format!(
            "expected gt, own or a TUM trajectory file; {f:?} is neither name and no file"
        )),
    }
}

/// Fig.-1-style picture: the frame with moving regions tinted red in proportion to P.
fn overlay(rgb: &RgbImage, p: &FloatImage) -> RgbImage {
    let mut out = rgb.clone();
    for (o, v) in out.pixels_mut().zip(p.iter()) {
        let a = 0.7 * v.clamp(0.0, 1.0);
        let mix = |c: u8, t: f32| ((1.0 - a) * c as f32 + a * t).round() as u8;
        *o = Rgb([mix(o.0[0], 255.0), mix(o.0[1], 0.0), mix(o.0[2], 0.0)]);
    }
    out
}

/// The configuration of this command's flags over the `--config` file.
fn config(args: &Args) -> anyhow::Result<dynapix::Config> {
    let mut c = args.seq.base_config(args.mode)?;
    if let Some(v) = args.variant {
        let variant = match v {
            VariantArg::Tum => Variant::Tum,
            VariantArg::Grade => Variant::Grade,
        };
        if variant != c.motion.params.variant {
            c.motion.params = dynapix_motion::MotionParams::new(variant, c.mode.motion());
        }
    }
    let p = &mut c.motion.params;
    if let Some(o) = &args.offsets {
        if o.contains(&0) {
            bail!("--offsets must not contain 0");
        }
        p.offsets = o.clone();
    }
    if let Some(list) = &args.cues {
        c.motion.cues = dynapix::Cues::only(list);
    }
    let p = &mut c.motion.params;
    p.use_movable &= !args.no_movable;
    p.use_moving &= !args.no_moving;
    if let Some(r) = args.refine_rotation {
        p.moving.refine_iterations = r;
        c.motion.reconstruct.refine_iterations = r;
    }
    if let Some(r) = args.bg_radius {
        c.motion.reconstruct.radius = r;
    }
    if let Some(s) = args.bg_step {
        c.motion.reconstruct.step = s;
    }
    if let Some(b) = args.background {
        c.motion.background = b;
    }
    if let Some(f) = args.flow_preset {
        c.motion.flow = f;
    }
    if let Some(g) = args.max_pose_gap {
        c.motion.max_pose_gap = g;
    }
    c.motion.poses = args.poses.clone();
    c.validate()?;
    Ok(c)
}

/// `motion` writes its maps into the sequence (`prob/`, `prob_vis/`, `background_rec/`):
/// a sequence folder (or its `prob/`) that is read-only, or marked so, is refused before any
/// work, even for a user who could write there anyway.
fn refuse_read_only(seq_dir: &std::path::Path, prob_dir: &std::path::Path) -> anyhow::Result<()> {
    for dir in [seq_dir, prob_dir] {
        if dir.exists() && !dynapix::stages::folder_writable(dir) {
            bail!(
                "{} is read-only (or marked so); `motion` writes its maps into the sequence \
                 folder, so it leaves this one alone: copy the sequence to a writable place, \
                 or use `dynapix run`, which caches its maps elsewhere",
                dir.display()
            );
        }
    }
    Ok(())
}

/// Runs `dynapix motion`.
pub fn run(args: Args, bars: &Bars) -> anyhow::Result<()> {
    let started = Instant::now();
    let config = config(&args)?;
    let input = args.seq.open(&config)?;
    let seq = &input.sequence;
    refuse_read_only(&seq.dir, &seq.prob_dir)?;
    let n = input.len();
    let noise = match &args.pose_noise {
        None => None,
        Some(v) if v.len() == 2 && v.iter().all(|x| *x >= 0.0) => Some((v[0], v[1])),
        Some(v) => bail!("--pose-noise wants METRES,DEGREES, got {v:?}"),
    };

    // Poses (frames without one are reported with the other input problems).
    let stamps = input.timestamps();
    let gap = config.motion.max_pose_gap;
    let needs_poses = MapJob::needs_poses(&input, &config);
    let (mut poses, missing) = if !needs_poses {
        (FramePoses::unused(n), Vec::new())
    } else {
        dynapix::stages::poses_from_source(&config.motion.poses, seq, &stamps, gap, || {
            let runner = OfflineRunner::new(&config, &input, motion_cache(&input))?;
            Ok((0, runner.first_pass(bars)?.trajectory))
        })?
    };
    let poses_from = poses.origin.describe();

    // Validate every frame before writing anything.
    let mut problems =
        MapJob::new(&input, &config, &poses).check_inputs(args.eval_masks, &missing, &poses_from);
    if !problems.is_empty() {
        let total = problems.len();
        problems.truncate(30);
        let more = if total > 30 {
            format!("\n  … and {} more", total - 30)
        } else {
            String::new()
        };
        bail!(
            "{total} problem(s) in {}:\n  {}{more}",
            seq.dir.display(),
            problems.join("\n  ")
        );
    }
    if let Some((st, sr)) = noise {
        poses.poses = dynapix_motion::noise::perturb_poses(&poses.poses, st, sr, args.seed);
    }
    let notes = json!({
        "noise": noise.map(|(t, r)| json!({"rms_translation_m": t, "rms_rotation_deg": r, "seed": args.seed})),
    });
    if let Some(path) = &args.write_poses {
        let traj = Trajectory::new(
            stamps
                .iter()
                .zip(&poses.poses)
                .map(|(t, p)| StampedPose::new(*t, *p))
                .collect(),
        );
        traj.write_tum(path)?;
    }
    let rigidity =
        OfflineRunner::new(&config, &input, motion_cache(&input))?.rigidity_maps(bars)?;
    let job = MapJob {
        pose_notes: notes,
        ..MapJob::new(&input, &config, &poses)
    }
    .with_rigidity(rigidity);

    // Configuration record; a resumed run must use the same one.
    let folder = MapFolder::new(seq.prob_dir.clone());
    let record = job.record();
    if let Some(old) = folder.read_record()
        && !args.force
    {
        let old = old?;
        if !old.describes(&record) {
            bail!(
                "{} was written with other settings; use --force to recompute all frames",
                folder.dir.join(dynapix::MotionRecord::FILE).display()
            );
        }
    }
    let vis_dir = seq.dir.join("prob_vis");
    let bgrec_dir = seq.dir.join("background_rec");
    if args.pictures {
        std::fs::create_dir_all(&vis_dir)?;
    }
    let reconstructs = job.backgrounds.reconstructs();
    if args.save_background && reconstructs {
        std::fs::create_dir_all(&bgrec_dir)?;
    }
    folder.write_record(
        &input,
        &record,
        dynapix::MapsStatus::Running,
        serde_json::Value::Null,
    )?;

    let map_path = |i: usize| folder.map_path(&input, i);
    let todo: Vec<usize> = (0..n)
        .filter(|&i| args.force || !map_path(i).is_some_and(|p| p.exists()))
        .collect();
    let skipped: Vec<usize> = (0..n).filter(|i| todo.binary_search(i).is_err()).collect();
    if !skipped.is_empty() {
        tracing::info!("{} frame(s) already done, skipping", skipped.len());
    }

    let mut scores = MaskEvaluation::new();
    let task = dynapix::ProgressEvent::Begin {
        task: "motion maps",
        total: todo.len() as u64,
    };
    use dynapix::Progress;
    bars.event(task);
    let stats = job.run(
        &todo,
        |m| -> Result<MaskEvaluation, dynapix_motion::BoxError> {
            let i = m.index;
            let name = input.map_name(i).ok_or("no file name")?;
            let p = MotionProbability::new(m.p);
            folder.write_map(&input, i, &p)?;
            if args.float_maps {
                dynapix_io::weights::write_prob_pfm(
                    folder.dir.join(&name).with_extension("pfm"),
                    p.as_image(),
                )?;
            }
            if args.pictures {
                let rgb = match &m.paper {
                    Some(paper) => paper.images.rgb.clone(),
                    None => input.load_rgbd(i)?.0,
                };
                dynapix_io::images::write_rgb(vis_dir.join(&name), &overlay(&rgb, p.as_image()))?;
            }
            if args.save_background
                && reconstructs
                && let Some(paper) = &m.paper
            {
                dynapix_io::images::write_rgb(bgrec_dir.join(&name), &paper.background.rgb)?;
            }
            let mut frame_scores = MaskEvaluation::new();
            if args.eval_masks {
                let f = &seq.frames[i];
                let mask_path = f.mask.as_ref().ok_or("no mask")?;
                let mask = dynapix_io::images::read_mask(mask_path)?;
                frame_scores.add_map(p.as_image().as_raw(), mask.as_raw());
                if reconstructs
                    && let Some(bg) = &f.background
                    && let Some(paper) = &m.paper
                {
                    let truth = dynapix_io::images::read_rgb(bg)?;
                    frame_scores.add_background(
                        mask.as_raw(),
                        &paper.background.rgb,
                        &paper.images.rgb,
                        &truth,
                    );
                }
            }
            Ok(frame_scores)
        },
        |_, frame_scores| {
            scores.merge(&frame_scores);
            bars.event(dynapix::ProgressEvent::Step {
                task: "motion maps",
                message: "",
            });
        },
    );
    bars.event(dynapix::ProgressEvent::End {
        task: "motion maps",
    });
    let stats = stats?;
    if args.eval_masks {
        for &i in &skipped {
            let p = map_path(i).context("no file name")?;
            let p = dynapix_io::weights::read_prob_png(p)?;
            let mask_path = seq.frames[i].mask.as_ref().context("no mask")?;
            let mask = dynapix_io::images::read_mask(mask_path)?;
            scores.add_map(p.as_raw(), mask.as_raw());
        }
    }
    let wall = started.elapsed().as_secs_f64();
    let ms_per_frame = if todo.is_empty() {
        0.0
    } else {
        1000.0 * stats.compute_seconds / todo.len() as f64
    };
    let mut results = json!({
        "frames_computed": todo.len(),
        "frames_skipped": skipped.len(),
        "wall_seconds": wall,
        "compute_seconds": stats.compute_seconds,
        "ms_per_frame": ms_per_frame,
        "threads": rayon::current_num_threads(),
    });
    println!(
        "motion: {} frame(s) computed, {} skipped, {:.1} s ({:.0} ms/frame on {} threads) → {}",
        todo.len(),
        skipped.len(),
        wall,
        ms_per_frame,
        rayon::current_num_threads(),
        folder.dir.display()
    );
    if args.eval_masks {
        let e = scores.scores();
        let f4 = |v: Option<f64>| v.map_or("n/a".into(), |v| format!("{v:.4}"));
        println!(
            "eval: ROC-AUC {} IoU(P>0.5) {} best IoU {} over {} moving / {} other pixels",
            f4(e.roc_auc),
            f4(e.iou_p_gt_0_5),
            match (e.best_iou, e.best_iou_threshold) {
                (Some(v), Some(t)) => format!("{v:.4} (P>{t:.3})"),
                _ => "n/a".into(),
            },
            e.moving_pixels,
            e.other_pixels
        );
        if let (Some(b), Some(r)) = (e.background_psnr_in_movers_db, e.frame_psnr_in_movers_db) {
            println!(
                "eval: reconstructed background PSNR inside all movers {b:.2} dB (frame itself: {r:.2} dB)"
            );
        }
        if let (Some(b), Some(r)) = (e.background_psnr_in_moving_db, e.frame_psnr_in_moving_db) {
            println!(
                "eval: reconstructed background PSNR inside moving movers {b:.2} dB (frame itself: {r:.2} dB)"
            );
        }
        results["eval"] = serde_json::to_value(e)?;
    }
    folder.write_record(&input, &record, dynapix::MapsStatus::Complete, results)?;
    Ok(())
}

/// The runner options of `motion`: the sequence's default cache (first pass, rigidity maps).
fn motion_cache(input: &dynapix::Input) -> RunOptions {
    RunOptions {
        cache_dir: super::run::cache_for(input, None, false),
        ..RunOptions::default()
    }
}
