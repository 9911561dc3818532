//! `dynapix run`: one method end to end on a sequence folder (paper §3.2 and §4): motion
//! probabilities when needed (computed by `dynapix motion` into a cache next to the sequence,
//! never overwriting the sequence's own `prob/`), SLAM with the method's weighting, and the
//! evaluation when `groundtruth.txt` exists.
//!
//! Without `--oracle-poses` nothing at run time uses ground truth: the poses for splatting come
//! from the system's own ORB-SLAM2 first pass (untracked frames take the nearest tracked pose,
//! counted in `run.json`), the background from `background/` when present, else it is
//! reconstructed. `run.json` records every source.
//!
//! Outputs in `--out`: `trajectory.txt` (TUM, tracked frames, camera-to-world),
//! `status.txt`, `keyframes.txt`, `run.json`, and with ground truth `eval.json`. With
//! `--runs N > 1`, run k (seed + k) goes to `run_<k>/` and `trajectory.txt` is run 0's.

use std::path::{Path, PathBuf};
use std::sync::mpsc::sync_channel;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Parser;
use dynapix_io::StaticWeights;
use dynapix_io::images::{read_mask, read_prob_png_raw, read_rgbd};
use dynapix_io::tum::resolve_path;
use dynapix_io::{FrameStatus, StampedPose, StampedStatus, Trajectory};
use dynapix_slam::dynapix::{DynaPixParams, ProbUpdate, Weighting};
use dynapix_slam::orb::{OrbExtractor, rgb_to_gray_orbslam};
use dynapix_slam::system::{FrameInput, System, SystemParams};
use dynapix_slam::vocab::Vocabulary;
use image::GrayImage;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;

use super::slam;

/// Methods of the paper's tables (one binary, §4 and the supplementary ablations).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Plain ORB-SLAM2 RGB-D.
    Orbslam2,
    /// DynaPix: motion-probability weights, birth gate, per-point deletion.
    Dynapix,
    /// DynaPix+: DynaPix plus semantic masks that gate map-point creation.
    #[value(name = "dynapix+")]
    DynapixPlus,
    /// Ablation: motion probability without the movable term (D = 1).
    NoMovable,
    /// Ablation: motion probability without the moving term (M = 1).
    NoMoving,
    /// Ablation: keypoints with P > γ_add ignored, unweighted optimisation.
    Threshold,
}

impl Method {
    /// Name as on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Method::Orbslam2 => "orbslam2",
            Method::Dynapix => "dynapix",
            Method::DynapixPlus => "dynapix+",
            Method::NoMovable => "no-movable",
            Method::NoMoving => "no-moving",
            Method::Threshold => "threshold",
        }
    }

    /// Parses a command-line name.
    pub fn parse(s: &str) -> anyhow::Result<Self> {
        <Self as clap::ValueEnum>::from_str(s, true).map_err(|e| anyhow::anyhow!("{e}"))
    }

    /// Which motion terms the method's probability maps use (`None`: no maps).
    pub(crate) fn terms(self) -> Option<&'static str> {
        match self {
            Method::Orbslam2 => None,
            Method::NoMovable => Some("no-movable"),
            Method::NoMoving => Some("no-moving"),
            _ => Some("full"),
        }
    }
}

/// Weighting behaviour of the DynaPix methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum WeightingArg {
    /// The paper (design §5), default.
    Paper,
    /// The original code's behaviour (spec §2.9).
    Reference,
}

/// Per-map-point probability update rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum UpdateArg {
    /// Exponential moving average (`--ema-alpha`).
    Ema,
    /// Running maximum.
    Max,
}

/// Arguments of `dynapix run`.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Sequence folder (DynaPix/TUM layout).
    pub seq_dir: PathBuf,
    /// Method.
    #[arg(long, value_enum, default_value = "dynapix")]
    pub method: Method,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Use ground-truth poses for splatting (as the paper did) instead of the system's own
    /// first pass.
    #[arg(long)]
    pub oracle_poses: bool,
    /// Number of runs (seed, seed + 1, …).
    #[arg(long, default_value_t = 1)]
    pub runs: usize,
    /// Seed of the first run (relocalisation RANSAC).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// DynaPix+ semantic masks (8-bit, non-zero = dynamic class), named like the rgb images;
    /// default `SEQ_DIR/mask`.
    #[arg(long)]
    pub masks: Option<PathBuf>,
    /// Weighting behaviour.
    #[arg(long, value_enum, default_value = "paper")]
    pub weighting: WeightingArg,
    /// Per-map-point probability update.
    #[arg(long, value_enum, default_value = "ema")]
    pub update: UpdateArg,
    /// EMA weight of the newest observation.
    #[arg(long, default_value_t = 0.2)]
    pub ema_alpha: f32,
    /// γ_add: map points are born only where P ≤ γ_add.
    #[arg(long, default_value_t = 0.05)]
    pub gamma_add: f32,
    /// γ_del: map points are removed when their probability reaches γ_del.
    #[arg(long, default_value_t = 0.1)]
    pub gamma_del: f32,
    /// Motion-map cache (default `SEQ_DIR/dynapix_cache`).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Ignore `SEQ_DIR/prob` and compute the maps into the cache.
    #[arg(long)]
    pub recompute_prob: bool,
    /// DIS preset passed to `dynapix motion` (ultrafast, fast, medium).
    #[arg(long, default_value = "fast")]
    pub flow_preset: String,
    /// Process at most this many frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Camera settings YAML (default: `SEQ_DIR/camera.yaml` or the TUM preset by name).
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// Frames without a probability map run unweighted (counted in `run.json`) instead of
    /// stopping with an error (e.g. when `dynapix motion` associated rgb and depth differently).
    #[arg(long)]
    pub allow_missing_prob: bool,
    /// Turn loop closing off (ORB-SLAM2's loop closer runs by default).
    #[arg(long)]
    pub no_loop_closing: bool,
    /// Hide progress bars.
    #[arg(long)]
    pub quiet: bool,
}

#[derive(Parser)]
struct SlamWrap {
    #[command(flatten)]
    a: slam::Args,
}

/// What one `dynapix run` produced (used by `experiment` and `demo`).
#[derive(Clone, Debug)]
pub struct RunOutcome {
    /// Trajectory of run 0.
    pub trajectory: PathBuf,
    /// ATE RMSE (m) of each run, when ground truth exists and the ATE could be computed.
    pub ate: Vec<Option<f64>>,
    /// Tracking rate of each run, when ground truth exists.
    pub tracking_rate: Vec<Option<f64>>,
    /// Folder of the probability maps used (None for ORB-SLAM2).
    pub prob_dir: Option<PathBuf>,
}

fn slam_args(args: &Args, out: &Path) -> anyhow::Result<slam::Args> {
    let mut v: Vec<std::ffi::OsString> = vec![
        "slam".into(),
        args.seq_dir.clone().into(),
        "--out".into(),
        out.into(),
    ];
    if let Some(s) = &args.settings {
        v.push("--settings".into());
        v.push(s.into());
    }
    if let Some(m) = args.max_frames {
        v.push("--max-frames".into());
        v.push(m.to_string().into());
    }
    Ok(SlamWrap::try_parse_from(v)
        .context("building the SLAM arguments")?
        .a)
}

fn progress(len: u64, quiet: bool, prefix: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template(
            "{prefix:>22} {bar:30} {pos}/{len} {per_sec} {msg} [{elapsed_precise}]",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb.set_prefix(prefix.to_string());
    pb
}

/// One SLAM pass; writes trajectory, status and keyframes into `out`.
#[allow(clippy::too_many_arguments)]
fn slam_pass(
    args: &Args,
    params: SystemParams,
    prob_dir: Option<&Path>,
    threshold: Option<f32>,
    mask_dir: Option<&Path>,
    out: &Path,
    label: &str,
) -> anyhow::Result<serde_json::Value> {
    let sa = slam_args(args, out)?;
    let settings = slam::resolve_settings(&sa)?;
    let frames = slam::load_frames(&sa)?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let extractor = OrbExtractor::new(slam::orb_params(&settings)?).context("bad ORB settings")?;
    let mut system = System::new(slam::Orb(extractor), slam::rgbd_camera(&settings), params);
    if !sa.no_vocabulary {
        let vocab = match &sa.vocabulary {
            Some(p) => Vocabulary::load(p)
                .with_context(|| format!("cannot load vocabulary {}", p.display()))?,
            None => Vocabulary::embedded_default().context("embedded vocabulary")?,
        };
        system = system.with_vocabulary(vocab);
    }
    let (tx, rx) = sync_channel::<Loaded>(4);
    let dir = args.seq_dir.clone();
    let depth_factor = settings.depth_map_factor;
    let list = frames.clone();
    let prob_dir = prob_dir.map(Path::to_path_buf);
    let mask_dir = mask_dir.map(Path::to_path_buf);
    let allow_missing = args.allow_missing_prob;
    let loader = std::thread::spawn(move || {
        for a in list {
            let rgb_path = resolve_path(&dir, &a.rgb);
            let name = rgb_path
                .file_name()
                .map(|s| s.to_os_string())
                .unwrap_or_default();
            let rd = read_rgbd(&rgb_path, resolve_path(&dir, &a.depth), depth_factor)
                .map_err(anyhow::Error::from);
            let w = match &prob_dir {
                None => Ok(None),
                Some(d) => {
                    let p = d.join(&name);
                    if allow_missing && !p.exists() {
                        return_missing(&tx, a.t_rgb, rd);
                        continue;
                    }
                    read_prob_png_raw(&p)
                        .with_context(|| format!("probability map {}", p.display()))
                        .map(|raw| {
                            let w = StaticWeights::from_stored(&raw);
                            Some(match threshold {
                                Some(g) => w.thresholded(g),
                                None => w,
                            })
                        })
                }
            };
            let m = match &mask_dir {
                None => Ok(None),
                Some(d) => {
                    let p = d.join(&name);
                    read_mask(&p)
                        .with_context(|| format!("mask {}", p.display()))
                        .map(Some)
                }
            };
            if tx.send((a.t_rgb, rd, w, m, false)).is_err() {
                break;
            }
        }
    });
    let pb = progress(frames.len() as u64, args.quiet, label);
    let mut status = Vec::with_capacity(frames.len());
    let t0 = Instant::now();
    let mut missing = 0usize;
    for (t, rd, w, m, miss) in rx {
        missing += usize::from(miss);
        let (rgb, depth) = rd?;
        let (w, m) = (w?, m?);
        let gray = rgb_to_gray_orbslam(&rgb);
        let res = system.process(FrameInput {
            timestamp: t,
            gray: &gray,
            depth: &depth,
            weights: w.as_ref(),
            masks: m.as_ref(),
        })?;
        let st = slam::frame_status(res.state);
        status.push(StampedStatus { t, status: st });
        pb.set_message(format!(
            "{st} kf {} mp {}",
            system.map().num_keyframes(),
            system.map().num_points()
        ));
        pb.inc(1);
    }
    pb.finish_and_clear();
    loader
        .join()
        .map_err(|_| anyhow::anyhow!("image loader thread panicked"))?;
    let seconds = t0.elapsed().as_secs_f64();
    slam::write_outputs(&system, &status, out)?;
    let tracked = status
        .iter()
        .filter(|s| s.status == FrameStatus::Tracked)
        .count();
    Ok(json!({
        "loops_closed": system.loop_events().len(),
        "frames": status.len(),
        "tracked": tracked,
        "keyframes": system.map().num_keyframes(),
        "map_points": system.map().num_points(),
        "seconds": seconds,
        "frames_without_prob_map": missing,
    }))
}

/// Sends a frame without a probability map (it runs unweighted).
fn return_missing(
    tx: &std::sync::mpsc::SyncSender<Loaded>,
    t: f64,
    rd: anyhow::Result<(image::RgbImage, dynapix_io::DepthImage)>,
) {
    let _ = tx.send((t, rd, Ok(None), Ok(None), true));
}

/// One decoded frame: time, images, weight map, mask, "probability map missing".
type Loaded = (
    f64,
    anyhow::Result<(image::RgbImage, dynapix_io::DepthImage)>,
    anyhow::Result<Option<StaticWeights>>,
    anyhow::Result<Option<GrayImage>>,
    bool,
);

/// Writes a pose for every frame of the sequence from a (possibly incomplete) trajectory:
/// tracked frames keep theirs, the others take the nearest tracked pose. Returns how many
/// frames were filled in.
fn fill_poses(traj_path: &Path, stamps: &[f64], out: &Path) -> anyhow::Result<usize> {
    let traj = Trajectory::read_tum(traj_path)?;
    if traj.poses.is_empty() {
        bail!(
            "the first pass tracked no frame ({}): no poses for the motion maps",
            traj_path.display()
        );
    }
    let mut filled = 0;
    let mut poses = Vec::with_capacity(stamps.len());
    for &t in stamps {
        let k = traj.poses.partition_point(|p| p.t < t);
        let cands = [k.checked_sub(1), Some(k)];
        let best = cands
            .iter()
            .flatten()
            .filter_map(|&i| traj.poses.get(i))
            .min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs()));
        let Some(b) = best else { continue };
        if (b.t - t).abs() > 1e-4 {
            filled += 1;
        }
        poses.push(StampedPose::new(t, b.pose));
    }
    Trajectory::new(poses).write_tum(out)?;
    Ok(filled)
}

/// Shadow sequence folder: symlinks to everything of `seq` except `prob` and the cache, so
/// `dynapix motion` writes its `prob/` there.
fn shadow(seq: &Path, dir: &Path, cache: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let seq_abs = seq.canonicalize()?;
    let cache_abs = cache.canonicalize()?;
    for e in std::fs::read_dir(&seq_abs)? {
        let e = e?;
        let name = e.file_name();
        let src = e.path();
        if name == "prob" || src == cache_abs || cache_abs.starts_with(&src) {
            continue;
        }
        let dst = dir.join(&name);
        if dst.symlink_metadata().is_ok() {
            continue;
        }
        #[cfg(unix)]
        std::os::unix::fs::symlink(&src, &dst)
            .with_context(|| format!("cannot link {}", dst.display()))?;
        #[cfg(not(unix))]
        bail!("motion-map cache needs symbolic links (unix)");
    }
    Ok(())
}

/// Runs `dynapix motion` on `seq` (a shadow folder) as a child process of this binary.
fn motion(args: &Args, seq: &Path, poses: &str, terms: &str) -> anyhow::Result<()> {
    let exe = std::env::current_exe().context("cannot locate the dynapix binary")?;
    let mut cmd = std::process::Command::new(exe);
    cmd.arg("motion")
        .arg(seq)
        .args(["--poses", poses])
        .args(["--flow-preset", &args.flow_preset]);
    match terms {
        "no-movable" => {
            cmd.arg("--no-movable");
        }
        "no-moving" => {
            cmd.arg("--no-moving");
        }
        _ => {}
    }
    if let Some(m) = args.max_frames {
        cmd.args(["--max-frames", &m.to_string()]);
    }
    if let Some(s) = &args.settings {
        cmd.arg("--camera").arg(s);
    } else if !seq.join("camera.yaml").exists() {
        // The shadow folder's name no longer tells the camera (e.g. rgbd_dataset_freiburg1_*),
        // so hand `dynapix motion` the camera this run resolved from the original folder.
        let settings = slam::resolve_settings(&slam_args(args, &args.out)?)?;
        settings.write(seq.join("camera.yaml"))?;
    }
    tracing::info!("running {cmd:?}");
    let st = cmd.status().context("cannot start dynapix motion")?;
    if !st.success() {
        bail!("dynapix motion failed on {} ({st})", seq.display());
    }
    Ok(())
}

fn frame_stamps(args: &Args) -> anyhow::Result<Vec<f64>> {
    let sa = slam_args(args, &args.out)?;
    Ok(slam::load_frames(&sa)?.iter().map(|a| a.t_rgb).collect())
}

/// Makes sure the probability maps for `method` exist; returns their folder and a JSON
/// description of their sources.
fn ensure_prob(
    args: &Args,
    terms: &str,
    record: &mut serde_json::Value,
) -> anyhow::Result<PathBuf> {
    let own = args.seq_dir.join("prob");
    if terms == "full" && own.is_dir() && !args.recompute_prob {
        record["prob"] = json!({"source": "sequence prob/ folder", "dir": own});
        if let Ok(t) = std::fs::read_to_string(own.join("motion.json")) {
            record["prob"]["motion_json"] = serde_json::from_str(&t).unwrap_or(json!(t));
        }
        return Ok(own);
    }
    let cache = args
        .cache
        .clone()
        .unwrap_or_else(|| args.seq_dir.join("dynapix_cache"));
    std::fs::create_dir_all(&cache)
        .with_context(|| format!("cannot create {}", cache.display()))?;
    let poses_key = if args.oracle_poses { "gt" } else { "own" };
    let key = format!("{poses_key}-{terms}");
    let sh = cache.join(&key);
    let prob = sh.join("prob");
    let done = sh.join("done");
    let n = frame_stamps(args)?.len();
    let mut info = json!({
        "source": "computed by dynapix motion",
        "dir": prob,
        "poses": if args.oracle_poses { "ground truth (oracle)" } else { "own ORB-SLAM2 first pass" },
        "background": if args.seq_dir.join("background").is_dir() { "background/ folder" } else { "reconstructed from neighbouring frames" },
        "terms": terms,
        "flow_preset": args.flow_preset,
    });
    let complete = std::fs::read_to_string(&done)
        .ok()
        .and_then(|s| s.trim().parse::<usize>().ok())
        .is_some_and(|k| k >= n);
    if !complete {
        shadow(&args.seq_dir, &sh, &cache)?;
        let poses = if args.oracle_poses {
            "gt".to_string()
        } else {
            let fp = cache.join("first_pass");
            if !fp.join("trajectory.txt").exists() {
                let mut a = args.clone();
                a.method = Method::Orbslam2;
                let params =
                    SystemParams::default().with_dynapix(DynaPixParams::new(Weighting::Off));
                slam_pass(&a, params, None, None, None, &fp, "first pass (orbslam2)")?;
            }
            let filled_path = fp.join("poses_all_frames.txt");
            let filled = fill_poses(
                &fp.join("trajectory.txt"),
                &frame_stamps(args)?,
                &filled_path,
            )?;
            info["first_pass_filled_frames"] = json!(filled);
            filled_path.canonicalize()?.to_string_lossy().into_owned()
        };
        motion(args, &sh, &poses, terms)?;
        dynapix_io::write_atomic(&done, n.to_string().as_bytes())?;
    }
    if let Ok(t) = std::fs::read_to_string(prob.join("motion.json")) {
        info["motion_json"] = serde_json::from_str(&t).unwrap_or(json!(t));
    }
    record["prob"] = info;
    Ok(prob)
}

/// Computes (or finds) the probability maps `args.method` needs, without running SLAM.
pub fn prepare_prob(args: &Args) -> anyhow::Result<Option<PathBuf>> {
    let mut record = json!({});
    args.method
        .terms()
        .map(|t| ensure_prob(args, t, &mut record))
        .transpose()
}

fn dynapix_params(args: &Args) -> DynaPixParams {
    let mut p = DynaPixParams::new(match args.weighting {
        WeightingArg::Paper => Weighting::Paper,
        WeightingArg::Reference => Weighting::Reference,
    });
    p.gamma_add = args.gamma_add;
    p.gamma_del = args.gamma_del;
    if args.weighting == WeightingArg::Paper {
        p.update = match args.update {
            UpdateArg::Ema => ProbUpdate::Ema {
                alpha: args.ema_alpha,
            },
            UpdateArg::Max => ProbUpdate::Max,
        };
    }
    p
}

/// Evaluates `traj` against `SEQ_DIR/groundtruth.txt` (ATE RMSE, tracking rate over the
/// sequence's frames); `None` without ground truth.
pub fn evaluate(
    seq_dir: &Path,
    traj: &Path,
    stamps: &[f64],
) -> anyhow::Result<Option<dynapix_eval::RunResult>> {
    let gt_path = seq_dir.join("groundtruth.txt");
    if !gt_path.exists() {
        return Ok(None);
    }
    let gt = dynapix_eval::files::read_trajectory(&gt_path)?;
    let params = dynapix_eval::EvalParams::default();
    Ok(Some(dynapix_eval::files::evaluate_run_file(
        &gt,
        traj,
        Some(stamps),
        &params,
    )))
}

/// Writes the trajectory top view and the ATE over time of `traj` into `dir`.
fn plots(seq_dir: &Path, traj: &Path, dir: &Path) -> anyhow::Result<()> {
    let gt = dynapix_eval::files::read_trajectory(&seq_dir.join("groundtruth.txt"))?;
    let est = dynapix_eval::files::read_trajectory(traj)?;
    let ev = dynapix_eval::evaluate(&gt, &est, None, &dynapix_eval::EvalParams::default())?;
    dynapix_eval::plot::write_plots(dir, &ev.ate)?;
    Ok(())
}

/// Runs `args` and returns what it produced (shared by `experiment` and `demo`).
pub fn execute(args: &Args) -> anyhow::Result<RunOutcome> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let mut record = json!({
        "sequence": args.seq_dir,
        "method": args.method.name(),
        "oracle_poses": args.oracle_poses,
        "ground_truth_used_at_run_time": args.oracle_poses,
        "runs": args.runs,
        "seed": args.seed,
    });
    let prob_dir = match args.method.terms() {
        None => None,
        Some(terms) => Some(ensure_prob(args, terms, &mut record)?),
    };
    let mut params = SystemParams::default();
    let mut threshold = None;
    let dp = dynapix_params(args);
    params = match args.method {
        Method::Orbslam2 => params.with_dynapix(DynaPixParams::new(Weighting::Off)),
        Method::Threshold => {
            threshold = Some(args.gamma_add);
            params.with_dynapix(DynaPixParams::new(Weighting::Off))
        }
        _ => params.with_dynapix(dp.clone()),
    };
    params.loop_closing.enabled = !args.no_loop_closing;
    record["loop_closing"] = json!(!args.no_loop_closing);
    let mask_dir = if args.method == Method::DynapixPlus {
        let d = args
            .masks
            .clone()
            .unwrap_or_else(|| args.seq_dir.join("mask"));
        if !d.is_dir() {
            bail!(
                "dynapix+ needs semantic masks: {} is not a folder (pass --masks DIR)",
                d.display()
            );
        }
        record["masks"] = json!(d);
        Some(d)
    } else {
        None
    };
    record["dynapix"] = json!({
        "weighting": format!("{:?}", params.map.dynapix.weighting),
        "gamma_add": params.map.dynapix.gamma_add,
        "gamma_del": params.map.dynapix.gamma_del,
        "update": format!("{:?}", params.map.dynapix.update),
        "ba_weight_clamp": params.mapping.ba.weight_clamp,
        "threshold": threshold,
    });
    let stamps = frame_stamps(args)?;
    let mut outcome = RunOutcome {
        trajectory: args.out.join("trajectory.txt"),
        ate: Vec::new(),
        tracking_rate: Vec::new(),
        prob_dir: prob_dir.clone(),
    };
    let mut runs = Vec::new();
    for k in 0..args.runs {
        let dir = if args.runs == 1 {
            args.out.clone()
        } else {
            args.out.join(format!("run_{k}"))
        };
        let mut p = params.clone();
        p.tracking.reloc.seed = p.tracking.reloc.seed.wrapping_add(args.seed + k as u64);
        let label = format!("{} {}", args.method.name(), k);
        let mut stats = slam_pass(
            args,
            p,
            prob_dir.as_deref(),
            threshold,
            mask_dir.as_deref(),
            &dir,
            &label,
        )?;
        let traj = dir.join("trajectory.txt");
        if k == 0 && args.runs > 1 {
            std::fs::copy(&traj, &outcome.trajectory)?;
        }
        let ev = evaluate(&args.seq_dir, &traj, &stamps)?;
        if ev.as_ref().is_some_and(|r| r.ate_rmse_m.is_some())
            && let Err(e) = plots(&args.seq_dir, &traj, &dir)
        {
            tracing::warn!("plots of {}: {e:#}", dir.display());
        }
        if let Some(r) = &ev {
            stats["ate_rmse_m"] = json!(r.ate_rmse_m);
            stats["tracking_rate"] = json!(r.tracking_rate);
            if let Some(e) = &r.error {
                stats["eval_error"] = json!(e);
            }
            dynapix_io::write_atomic(
                dir.join("eval.json"),
                serde_json::to_string_pretty(r)?.as_bytes(),
            )?;
        }
        outcome.ate.push(ev.as_ref().and_then(|r| r.ate_rmse_m));
        outcome
            .tracking_rate
            .push(ev.as_ref().and_then(|r| r.tracking_rate));
        runs.push(stats);
    }
    record["results"] = json!(runs);
    dynapix_io::write_atomic(
        args.out.join("run.json"),
        serde_json::to_string_pretty(&record)?.as_bytes(),
    )?;
    Ok(outcome)
}

/// Runs `dynapix run`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let o = execute(&args)?;
    for (k, (a, t)) in o.ate.iter().zip(&o.tracking_rate).enumerate() {
        match (a, t) {
            (Some(a), Some(t)) => println!(
                "{} run {k}: ATE RMSE {:.4} m, tracking rate {:.1} %",
                args.method.name(),
                a,
                t * 100.0
            ),
            _ => println!(
                "{} run {k}: no ATE (no ground truth or no overlap)",
                args.method.name()
            ),
        }
    }
    println!("trajectory: {}", o.trajectory.display());
    Ok(())
}
