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
//! interrupted run resumes. The computation and the analysis outputs (pictures, float maps,
//! evaluation against masks) are the library's ([`dynapix::motion_maps`]); this module
//! parses, shows progress and prints.

use std::path::PathBuf;

use anyhow::bail;
use dynapix::{BackgroundSource, FlowPreset, Mode, MotionOptions, PoseSource};
use dynapix_motion::Variant;

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

/// Runs `dynapix motion`.
pub fn run(args: Args, bars: &Bars) -> anyhow::Result<()> {
    let config = config(&args)?;
    let input = args.seq.open(&config)?;
    let pose_noise = match &args.pose_noise {
        None => None,
        Some(v) if v.len() == 2 && v.iter().all(|x| *x >= 0.0) => Some((v[0], v[1], args.seed)),
        Some(v) => bail!("--pose-noise wants METRES,DEGREES, got {v:?}"),
    };
    let options = MotionOptions {
        // The sequence's default cache (first pass, rigidity maps).
        cache_dir: super::run::cache_for(&input, None, false),
        force: args.force,
        float_maps: args.float_maps,
        pictures: args.pictures,
        save_background: args.save_background,
        eval_masks: args.eval_masks,
        pose_noise,
    };
    let out = dynapix::motion_maps(&input, &config, &options, bars)?;
    if let Some(path) = &args.write_poses {
        out.poses.write_tum(path)?;
    }
    println!(
        "motion: {} frame(s) computed, {} skipped, {:.1} s ({:.0} ms/frame on {} threads) → {}",
        out.frames_computed,
        out.frames_skipped,
        out.wall_seconds,
        out.ms_per_frame,
        out.threads,
        out.dir.display()
    );
    if let Some(e) = &out.eval {
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
    }
    Ok(())
}
