//! `dynapix motion` as one library call ([`motion_maps`]): a sequence's motion maps computed
//! into its `prob/` folder with their record (`motion.json`), resumable (frames whose map
//! exists are kept unless forced), with the analysis outputs asked for (float maps,
//! pictures, reconstructed backgrounds, scores against the sequence's masks).

use std::path::{Path, PathBuf};
use std::time::Instant;

use dynapix_io::{MotionProbability, StampedPose, Trajectory};
use dynapix_motion::FloatImage;
use dynapix_motion::metrics::{MaskEvaluation, MaskScores};
use image::{Rgb, RgbImage};
use serde::Serialize;

use crate::config::Config;
use crate::error::{Error, Result};
use crate::input::Input;
use crate::maps::MapJob;
use crate::offline::{OfflineRunner, RunOptions, folder_writable};
use crate::poses::{FramePoses, from_source};
use crate::progress::{Progress, Task};
use crate::record::{MapsStatus, MotionRecord};
use crate::store::MapFolder;

/// What [`motion_maps`] does besides computing the maps.
#[derive(Clone, Debug, Default)]
pub struct MotionOptions {
    /// Cache folder of the first pass (`--poses own`) and of the rigidity maps; `None`
    /// computes them without writing them anywhere.
    pub cache_dir: Option<PathBuf>,
    /// Recompute frames whose map already exists (and accept a record made with other
    /// settings).
    pub force: bool,
    /// Also write P losslessly as `prob/<stem>.pfm`.
    pub float_maps: bool,
    /// Also write pictures (moving regions in red over the frame) to `SEQ/prob_vis/`.
    pub pictures: bool,
    /// Also write reconstructed backgrounds to `SEQ/background_rec/`.
    pub save_background: bool,
    /// Score the maps against `mask/` (255 = moving), and a reconstructed background
    /// against `background/` inside the movers.
    pub eval_masks: bool,
    /// Perturb every pose: RMS translation (m) and rotation (degrees), with its seed.
    pub pose_noise: Option<(f64, f64, u64)>,
}

/// What [`motion_maps`] did: the `results` of the folder's `motion.json` (the serialized
/// fields), the folder and the poses the maps were made with.
#[derive(Clone, Debug, Serialize)]
pub struct MotionOutput {
    /// The map folder (`SEQ/prob`).
    #[serde(skip)]
    pub dir: PathBuf,
    /// The poses of the frames as used (after any noise); identity when the maps use none.
    #[serde(skip)]
    pub poses: Trajectory,
    /// Frames computed now.
    pub frames_computed: usize,
    /// Frames kept from an earlier, interrupted run.
    pub frames_skipped: usize,
    /// Wall-clock seconds of the whole call.
    pub wall_seconds: f64,
    /// Seconds of the map computation.
    pub compute_seconds: f64,
    /// Milliseconds of computation per computed frame.
    pub ms_per_frame: f64,
    /// Worker threads.
    pub threads: usize,
    /// Scores against the masks, when asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub eval: Option<MaskScores>,
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

/// The maps go into the sequence (`prob/`, `prob_vis/`, `background_rec/`): a sequence
/// folder (or its `prob/`) that is read-only, or marked so, is refused before any work.
fn refuse_read_only(seq_dir: &Path, prob_dir: &Path) -> Result<()> {
    for dir in [seq_dir, prob_dir] {
        if dir.exists() && !folder_writable(dir) {
            return Err(Error::Input(format!(
                "{} is read-only (or marked so); `motion` writes its maps into the sequence \
                 folder, so it leaves this one alone: copy the sequence to a writable place, \
                 or use `dynapix run`, which caches its maps elsewhere",
                dir.display()
            )));
        }
    }
    Ok(())
}

/// One error listing the first 30 of `problems`.
fn problems_error(dir: &Path, mut problems: Vec<String>) -> Error {
    let total = problems.len();
    problems.truncate(30);
    let more = if total > 30 {
        format!("\n  … and {} more", total - 30)
    } else {
        String::new()
    };
    Error::Input(format!(
        "{total} problem(s) in {}:\n  {}{more}",
        dir.display(),
        problems.join("\n  ")
    ))
}

/// Computes the motion maps of `config` on `input` into the sequence's `prob/` folder
/// (16-bit, `trunc((1 − P)·1000)`, named like the rgb images) with its `motion.json`, the
/// poses from `config.motion.poses` (ground truth, a trajectory file, or the system's own
/// ORB-SLAM2 pass). Every frame is checked before anything is written; each map is written
/// atomically and frames whose map exists are kept unless `options.force`, so an interrupted
/// call resumes; a record made with other settings is refused unless forced.
pub fn motion_maps(
    input: &Input,
    config: &Config,
    options: &MotionOptions,
    progress: &dyn Progress,
) -> Result<MotionOutput> {
    let started = Instant::now();
    let seq = &input.sequence;
    refuse_read_only(&seq.dir, &seq.prob_dir)?;
    let n = input.len();
    let stamps = input.timestamps();
    let runner = || OfflineRunner::new(config, input, run_options(options));
    // Poses (frames without one are reported with the other input problems).
    let (mut poses, missing) = if !MapJob::needs_poses(input, config) {
        (FramePoses::unused(n), Vec::new())
    } else {
        from_source(
            &config.motion.poses,
            seq,
            &stamps,
            config.motion.max_pose_gap,
            || Ok((0, runner()?.first_pass(progress)?.trajectory)),
        )?
    };
    let poses_from = poses.origin.describe();
    let problems =
        MapJob::new(input, config, &poses).check_inputs(options.eval_masks, &missing, &poses_from);
    if !problems.is_empty() {
        return Err(problems_error(&seq.dir, problems));
    }
    if let Some((st, sr, seed)) = options.pose_noise {
        poses.poses = dynapix_motion::noise::perturb_poses(&poses.poses, st, sr, seed);
    }
    let notes = serde_json::json!({
        "noise": options.pose_noise.map(|(t, r, seed)| serde_json::json!({
            "rms_translation_m": t, "rms_rotation_deg": r, "seed": seed,
        })),
    });
    let rigidity = runner()?.rigidity_maps(progress)?;
    let job = MapJob {
        pose_notes: notes,
        ..MapJob::new(input, config, &poses)
    }
    .with_rigidity(rigidity);

    // The record; a resumed run must use the same one.
    let folder = MapFolder::new(seq.prob_dir.clone());
    let record = job.record();
    if let Some(old) = folder.read_record()
        && !options.force
        && !old?.describes(&record)
    {
        return Err(Error::Input(format!(
            "{} was written with other settings; use --force to recompute all frames",
            folder.dir.join(MotionRecord::FILE).display()
        )));
    }
    let vis_dir = seq.dir.join("prob_vis");
    let bgrec_dir = seq.dir.join("background_rec");
    let reconstructs = job.backgrounds.reconstructs();
    let save_background = options.save_background && reconstructs;
    for (on, dir) in [(options.pictures, &vis_dir), (save_background, &bgrec_dir)] {
        if on {
            std::fs::create_dir_all(dir).map_err(|e| dynapix_io::IoError::io(dir, e))?;
        }
    }
    folder.write_record(input, &record, MapsStatus::Running, serde_json::Value::Null)?;

    let map_path = |i: usize| folder.map_path(input, i);
    let todo: Vec<usize> = (0..n)
        .filter(|&i| options.force || !map_path(i).is_some_and(|p| p.exists()))
        .collect();
    let skipped: Vec<usize> = (0..n).filter(|i| todo.binary_search(i).is_err()).collect();
    if !skipped.is_empty() {
        tracing::info!("{} frame(s) already done, skipping", skipped.len());
    }
    let mut scores = MaskEvaluation::new();
    let task = Task::begin(progress, "motion maps", todo.len());
    let stats = job.run(
        &todo,
        |m| -> std::result::Result<MaskEvaluation, dynapix_motion::BoxError> {
            let i = m.index;
            let name = input.map_name(i).ok_or("no file name")?;
            let p = MotionProbability::new(m.p);
            folder.write_map(input, i, &p)?;
            if options.float_maps {
                p.write_pfm(folder.dir.join(&name).with_extension("pfm"))?;
            }
            if options.pictures {
                let rgb = match &m.paper {
                    Some(paper) => paper.images.rgb.clone(),
                    None => input.load_rgbd(i)?.0,
                };
                dynapix_io::images::write_rgb(vis_dir.join(&name), &overlay(&rgb, p.as_image()))?;
            }
            if save_background && let Some(paper) = &m.paper {
                dynapix_io::images::write_rgb(bgrec_dir.join(&name), &paper.background.rgb)?;
            }
            let mut frame_scores = MaskEvaluation::new();
            if options.eval_masks {
                let f = &seq.frames[i];
                let mask = dynapix_io::images::read_mask(f.mask.as_ref().ok_or("no mask")?)?;
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
            task.step("");
        },
    );
    drop(task);
    let stats = stats?;
    if options.eval_masks {
        for &i in &skipped {
            let p = map_path(i).ok_or_else(|| Error::Input(format!("frame {i}: no file name")))?;
            let p = MotionProbability::read(p)?;
            let mask_path = seq.frames[i]
                .mask
                .as_ref()
                .ok_or_else(|| Error::Input(format!("frame {i}: no mask")))?;
            let mask = dynapix_io::images::read_mask(mask_path)?;
            scores.add_map(p.as_image().as_raw(), mask.as_raw());
        }
    }
    let ms_per_frame = if todo.is_empty() {
        0.0
    } else {
        1000.0 * stats.compute_seconds / todo.len() as f64
    };
    let out = MotionOutput {
        dir: folder.dir.clone(),
        poses: Trajectory::new(
            stamps
                .iter()
                .zip(&poses.poses)
                .map(|(t, p)| StampedPose::new(*t, *p))
                .collect(),
        ),
        frames_computed: todo.len(),
        frames_skipped: skipped.len(),
        wall_seconds: started.elapsed().as_secs_f64(),
        compute_seconds: stats.compute_seconds,
        ms_per_frame,
        threads: rayon::current_num_threads(),
        eval: options.eval_masks.then(|| scores.scores()),
    };
    let results =
        serde_json::to_value(&out).map_err(|e| Error::Input(format!("motion results: {e}")))?;
    folder.write_record(input, &record, MapsStatus::Complete, results)?;
    Ok(out)
}

/// The runner options of the first pass and the rigidity maps: the cache folder only.
fn run_options(options: &MotionOptions) -> RunOptions {
    RunOptions {
        cache_dir: options.cache_dir.clone(),
        ..RunOptions::default()
    }
}
