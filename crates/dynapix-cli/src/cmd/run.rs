//! `dynapix run`: one method end to end on a sequence folder (paper §3.2 and §4), in this
//! process through the library: offline (`dynapix::OfflineRunner`: first pass, motion maps
//! cached next to the sequence or in `--cache`, weighted pass) or online (`--online`,
//! `dynapix::OnlineDynaPix`: frames pushed one at a time, optional `--lookahead`), then the
//! evaluation when `groundtruth.txt` exists.
//!
//! Without `--oracle-poses` nothing at run time uses ground truth: the poses for splatting come
//! from the system's own ORB-SLAM2 first pass, the background from `background/` when present,
//! else it is reconstructed. A sequence's own `prob/` is used when present, and `run.json` says
//! what made it (its `motion.json`). `run.json` records the whole configuration and the
//! provenance of every input.
//!
//! Outputs in `--out`: `trajectory.txt` (TUM, tracked frames, camera-to-world), `status.txt`,
//! `keyframes.txt`, `loops.txt`, `run.json`, and with ground truth `eval.json` and plots. With
//! `--runs N > 1`, run k (seed + k) goes to `run_<k>/` and `trajectory.txt` is run 0's. The
//! result set is written beside `--out` and replaces it as a whole at the end
//! ([`dynapix::OutputFolder`]), also when the run stops at a frame it cannot read: then with
//! what it had computed and `"complete": false` in `run.json` (`--skip-bad-frames` skips such
//! frames instead and lists them).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use dynapix::evaluate::{RunEvaluation, score_run};
use dynapix::{
    Config, Cue, Cues, FirstPass, FlowPreset, FrameStatus, Input, Method, Mode, OfflineRunner,
    OnlineRun, OutputFolder, PoseSource, ProbUpdate, RunOptions, RunRecord, StampedStatus,
    Trajectory,
};
use serde_json::{Value, json};

use super::common::{
    Bars, RESULT_MARKERS, SequenceArgs, check_out, skipped_note, stop_reason, write_json,
    write_pass,
};

/// Per-map-point probability update rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum UpdateArg {
    /// Exponential moving average (`--ema-alpha`).
    Ema,
    /// Running maximum.
    Max,
}

/// The method flags shared by `run` and `experiment`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct MethodArgs {
    /// Paper or reference behaviour of the motion maps and the SLAM weighting (`--weighting`
    /// is the older spelling).
    #[arg(long, value_enum, alias = "weighting")]
    pub mode: Option<Mode>,
    /// Use ground-truth poses for splatting (as the paper did) instead of the system's own
    /// first pass.
    #[arg(long)]
    pub oracle_poses: bool,
    /// Per-map-point probability update (default: EMA in paper mode, latest in reference).
    #[arg(long, value_enum)]
    pub update: Option<UpdateArg>,
    /// EMA weight of the newest observation (0.2).
    #[arg(long)]
    pub ema_alpha: Option<f32>,
    /// γ_add: map points are born only where P ≤ γ_add (0.05).
    #[arg(long)]
    pub gamma_add: Option<f32>,
    /// γ_del: map points are removed when their probability reaches γ_del (0.1).
    #[arg(long)]
    pub gamma_del: Option<f32>,
    /// DIS preset of the motion maps (fast).
    #[arg(long, value_enum)]
    pub flow_preset: Option<FlowPreset>,
    /// Weighted passes; the maps of pass k + 1 use the trajectory of pass k (paper mode 2,
    /// reference 1).
    #[arg(long)]
    pub passes: Option<usize>,
    /// The cues of P, comma separated, combined by noisy-or (paper mode:
    /// paper,geometric,rigidity; reference: paper).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub cues: Option<Vec<Cue>>,
    /// The pass whose poses make the first maps (paper mode: rigidity; reference: orbslam2).
    #[arg(long, value_enum)]
    pub first_pass: Option<FirstPass>,
    /// Turn loop closing off (ORB-SLAM2's loop closer runs by default).
    #[arg(long)]
    pub no_loop_closing: bool,
}

impl MethodArgs {
    /// Applies the flags to `c`.
    pub fn apply(&self, c: &mut Config) -> anyhow::Result<()> {
        if self.oracle_poses {
            c.motion.poses = PoseSource::GroundTruth;
        }
        let d = &mut c.dynapix;
        match (self.update, self.ema_alpha) {
            (Some(UpdateArg::Max), _) => d.update = ProbUpdate::Max,
            (Some(UpdateArg::Ema), a) => {
                d.update = ProbUpdate::Ema {
                    alpha: a.unwrap_or(0.2),
                }
            }
            (None, Some(a)) => d.update = ProbUpdate::Ema { alpha: a },
            (None, None) => {}
        }
        if let Some(g) = self.gamma_add {
            d.gamma_add = g;
        }
        if let Some(g) = self.gamma_del {
            d.gamma_del = g;
        }
        if let Some(f) = self.flow_preset {
            c.motion.flow = f;
        }
        if let Some(p) = self.passes {
            c.passes.weighted = p;
        }
        if let Some(list) = &self.cues {
            c.motion.cues = Cues::only(list);
        }
        if let Some(f) = self.first_pass {
            c.passes.first = f;
        }
        if self.no_loop_closing {
            c.slam.params.loop_closing.enabled = false;
        }
        c.validate()?;
        Ok(())
    }
}

/// Arguments of `dynapix run`.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// The sequence.
    #[command(flatten)]
    pub seq: SequenceArgs,
    /// Method (default: the configuration's, dynapix).
    #[arg(long, value_enum)]
    pub method: Option<Method>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Method flags.
    #[command(flatten)]
    pub m: MethodArgs,
    /// Number of runs (seed, seed + 1, …).
    #[arg(long, default_value_t = 1)]
    pub runs: usize,
    /// Seed of the first run (relocalisation RANSAC).
    #[arg(long)]
    pub seed: Option<u64>,
    /// DynaPix+ semantic masks (8-bit, non-zero = dynamic class), named like the rgb images;
    /// default `SEQ_DIR/mask`.
    #[arg(long)]
    pub masks: Option<PathBuf>,
    /// Motion-map and first-pass cache (default `SEQ_DIR/dynapix_cache`, or `dynapix/NAME-HASH` under the user cache directory when SEQ_DIR is not writable).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// No cache: compute the first pass and the motion maps in memory, read nothing from a
    /// cache and write nothing but `--out`.
    #[arg(long, conflicts_with = "cache")]
    pub no_cache: bool,
    /// Ignore `SEQ_DIR/prob` and compute the maps into the cache.
    #[arg(long)]
    pub recompute_prob: bool,
    /// Frames without a probability map run unweighted (counted in `run.json`) instead of
    /// stopping with an error.
    #[arg(long)]
    pub allow_missing_prob: bool,
    /// Exit 0 even when no frame was tracked (otherwise a warning and exit code 1; the
    /// outputs are written either way).
    #[arg(long)]
    pub allow_untracked: bool,
    /// Online: push frames one at a time; motion from past frames only (plus `--lookahead`),
    /// poses reported as they are known (written to `trajectory.txt`).
    #[arg(long)]
    pub online: bool,
    /// Online: frames of latency allowed; the background of a frame may use this many later
    /// frames.
    #[arg(long, requires = "online")]
    pub lookahead: Option<usize>,
    /// A frame whose rgb or depth file cannot be used (missing, truncated, undecodable, of
    /// another size) is recorded lost, gets no motion map (its neighbours' maps do without
    /// it) and SLAM goes on with the next one; the skipped frames are listed in `run.json`.
    /// Without it the run stops at such a frame with an error naming it, keeping the
    /// trajectory and status up to it (`"complete": false`).
    #[arg(long)]
    pub skip_bad_frames: bool,
    /// The Rerun viewer.
    #[command(flatten)]
    pub viz: super::viz::VizArgs,
}

/// What one run produced (used by `experiment` and `demo`).
#[derive(Clone, Debug)]
pub struct RunOutcome {
    /// Trajectory of run 0.
    pub trajectory: PathBuf,
    /// ATE RMSE (m) of each run, when ground truth exists and the ATE could be computed.
    pub ate: Vec<Option<f64>>,
    /// Tracking rate of each run, when ground truth exists.
    pub tracking_rate: Vec<Option<f64>>,
    /// Why each run has no ATE, when it has none (no ground truth, too few frames, …).
    pub no_ate: Vec<String>,
    /// Folder of the probability maps of the final pass (None for ORB-SLAM2 and online).
    pub prob_dir: Option<PathBuf>,
    /// The final pass's trajectory as written (a first pass for a later DynaPix run).
    pub written_trajectory: Option<Trajectory>,
    /// The motionless floor (ATE of a camera that never moves on the same pairs).
    pub floor: Option<f64>,
    /// Evaluations of the passes before the final one (first pass, weighted pass 1, …).
    pub earlier_passes: Vec<Value>,
    /// Frames tracked in each run's final pass.
    pub tracked: Vec<usize>,
    /// Frames skipped as unusable in each run's final pass.
    pub skipped: Vec<Vec<dynapix::BadFrame>>,
}

/// One run to execute: a configuration on an opened sequence.
pub struct RunSpec<'a> {
    /// The sequence.
    pub input: &'a Input,
    /// The configuration.
    pub config: Config,
    /// File options.
    pub options: RunOptions,
    /// Output folder.
    pub out: PathBuf,
    /// Runs: run k's weighted pass uses relocalisation seed `config.slam.seed + first_run + k`
    /// (the first pass and the maps use `config.slam.seed`, so runs share them).
    pub runs: usize,
    /// Index of the first run (an experiment runs run k alone).
    pub first_run: u64,
    /// Who watches the passes (`--rerun`).
    pub observer: Option<std::sync::Arc<dyn dynapix::RunObserver>>,
}

/// Evaluates `trajectory`, written to `dir/trajectory.txt`, from memory against the
/// sequence's ground truth into `dir` (eval.json, plots); returns the result.
fn evaluate_into(
    input: &Input,
    trajectory: &Trajectory,
    dir: &Path,
    stats: &mut Value,
    with_plots: bool,
) -> anyhow::Result<Option<RunEvaluation>> {
    let score = score_run(&input.sequence, trajectory, &dir.join("trajectory.txt"))?;
    if with_plots
        && let Some(ev) = score.as_ref().and_then(|s| s.evaluation.as_ref())
        && let Err(e) = dynapix_eval::plot::write_plots(dir, &ev.ate)
    {
        tracing::warn!("plots of {}: {e}", dir.display());
    }
    let ev = score.map(|s| s.run);
    if let Some(r) = &ev {
        stats["ate_rmse_m"] = json!(r.result.ate_rmse_m);
        stats["tracking_rate"] = json!(r.result.tracking_rate);
        stats["motionless_floor_m"] = json!(r.motionless_floor_m);
        if let Some(e) = &r.result.error {
            stats["eval_error"] = json!(e);
        }
        write_json(&dir.join("eval.json"), &serde_json::to_value(r)?)?;
    }
    Ok(ev)
}

/// Writes the trajectories of the passes before the final one (`passes/first`,
/// `passes/pass_K`) into `out` and evaluates them: how the alternation of SLAM and motion
/// converges. The rows name the folders as they will be once `out` is moved to `shown`.
fn write_earlier_passes(
    input: &Input,
    out: &Path,
    shown: &Path,
    run: &dynapix::OfflineOutput,
) -> anyhow::Result<Vec<Value>> {
    let mut dirs: Vec<(String, PathBuf, &Trajectory)> = Vec::new();
    if let Some(f) = &run.first_pass {
        let rel = Path::new("passes").join("first");
        let d = out.join(&rel);
        std::fs::create_dir_all(&d).with_context(|| format!("cannot create {}", d.display()))?;
        f.trajectory.write_tum(d.join("trajectory.txt"))?;
        dirs.push(("first".into(), rel, &f.trajectory));
    }
    let n = run.passes.len();
    for (j, p) in run.passes.iter().enumerate().take(n.saturating_sub(1)) {
        let rel = Path::new("passes").join(format!("pass_{}", j + 1));
        write_pass(&out.join(&rel), p)?;
        dirs.push((format!("{}", j + 1), rel, &p.trajectory));
    }
    let mut rows = Vec::new();
    for (name, rel, trajectory) in dirs {
        let mut stats = json!({"pass": name, "dir": shown.join(&rel)});
        evaluate_into(input, trajectory, &out.join(&rel), &mut stats, false)?;
        rows.push(stats);
    }
    Ok(rows)
}

/// The folders and files a run must not replace: the sequence, the cache, DynaPix+ masks.
fn kept_paths(input: &Input, runner: &OfflineRunner<'_>) -> Vec<(&'static str, PathBuf)> {
    let mut keep = vec![("the sequence", input.sequence.dir.clone())];
    if let Some(c) = runner.cache_dir() {
        keep.push(("the cache", c.to_path_buf()));
    }
    if runner.config().method.needs_masks() {
        keep.push(("the masks", runner.masks_dir()));
    }
    keep
}

/// Runs `spec` offline and writes its outputs: into a folder beside `spec.out` that replaces
/// it at the end, also when the run stops part-way (then with what it had computed and
/// `"complete": false` in `run.json`).
pub fn execute(spec: RunSpec<'_>, bars: &Bars) -> anyhow::Result<RunOutcome> {
    if spec.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let mut runner = OfflineRunner::new(&spec.config, spec.input, spec.options.clone())?;
    if let Some(o) = &spec.observer {
        runner = runner.with_observer(o.clone());
    }
    let keep = kept_paths(spec.input, &runner);
    let keep: Vec<(&str, &Path)> = keep.iter().map(|(w, p)| (*w, p.as_path())).collect();
    check_out(&spec.out, &keep)?;
    let staged = OutputFolder::begin(&spec.out, RESULT_MARKERS)?;
    let mut record = runner.record();
    match execute_into(&spec, &runner, staged.path(), &mut record, bars) {
        Ok(outcome) => {
            record.mark_complete();
            record.invalid_depth = Some(spec.input.sequence.invalid_depth());
            record.write(staged.path().join("run.json"))?;
            staged.commit()?;
            Ok(outcome)
        }
        Err(e) => {
            if let Some(cache) = runner.cache_dir()
                && let Some(file) = super::common::cache_fault(&e, cache)
            {
                // A cache fault is no result: the earlier one stays (issue 36).
                drop(staged);
                eprintln!(
                    "the run stopped on its cache ({}); {} keeps its earlier content. Remove \
                     the cache folder {} (or pass another --cache) and run again",
                    file.display(),
                    spec.out.display(),
                    cache.display()
                );
                return Err(e);
            }
            let (why, frame) = stop_reason(&e);
            record.mark_incomplete(why, frame);
            record.invalid_depth = Some(spec.input.sequence.invalid_depth());
            record.write(staged.path().join("run.json"))?;
            let out = staged.commit()?;
            eprintln!(
                "the run stopped; {} keeps what it computed (marked incomplete)",
                out.display()
            );
            Err(e)
        }
    }
}

/// The runs of `spec` written into `out` (the staging folder of `spec.out`), their facts
/// added to `record`. A pass that stops leaves its files up to the frame that stopped it.
fn execute_into(
    spec: &RunSpec<'_>,
    runner: &OfflineRunner<'_>,
    out: &Path,
    record: &mut RunRecord,
    bars: &Bars,
) -> anyhow::Result<RunOutcome> {
    let mut outcome = RunOutcome {
        trajectory: spec.out.join("trajectory.txt"),
        ate: Vec::new(),
        tracking_rate: Vec::new(),
        no_ate: Vec::new(),
        prob_dir: None,
        written_trajectory: None,
        floor: None,
        earlier_passes: Vec::new(),
        tracked: Vec::new(),
        skipped: Vec::new(),
    };
    let mut runs = Vec::new();
    record.runs = Some(spec.runs);
    record.seed = Some(spec.config.slam.seed + spec.first_run);
    for k in 0..spec.runs {
        let dir = if spec.runs == 1 {
            out.to_path_buf()
        } else {
            out.join(format!("run_{k}"))
        };
        let seed = spec.config.slam.seed + spec.first_run + k as u64;
        let run = match runner.run_with_seed(seed, bars) {
            Ok(run) => run,
            Err(e) => {
                // Keep what was computed: the pass that stopped, up to its last good frame.
                if let Some(p) = e.partial_pass() {
                    write_pass(&dir, p)?;
                    runs.push(json!(p.stats));
                    record.skipped_frames = Some(p.skipped.clone());
                }
                record.results = Some(runs);
                return Err(e.into());
            }
        };
        let pass = run.final_pass().context("the run produced no pass")?;
        write_pass(&dir, pass)?;
        if k == 0 {
            if spec.runs > 1 {
                std::fs::copy(dir.join("trajectory.txt"), out.join("trajectory.txt"))?;
            }
            outcome.prob_dir = run
                .final_maps()
                .and_then(|m| m.dir().map(Path::to_path_buf));
            outcome.written_trajectory = Some(pass.written_trajectory()?);
            // The run's record replaces the record before the run (the runner's own fields).
            let (runs, seed) = (record.runs, record.seed);
            *record = run.record.clone();
            record.runs = runs;
            record.seed = seed;
            let earlier = write_earlier_passes(spec.input, out, &spec.out, &run)?;
            if !earlier.is_empty() {
                record.earlier_passes = Some(earlier.clone());
            }
            record.skipped_frames = Some(pass.skipped.clone());
            outcome.earlier_passes = earlier;
        }
        outcome.tracked.push(pass.stats.tracked);
        outcome.skipped.push(pass.skipped.clone());
        let mut stats = serde_json::to_value(pass.stats)?;
        let ev = evaluate_into(spec.input, &pass.trajectory, &dir, &mut stats, true)?;
        outcome
            .ate
            .push(ev.as_ref().and_then(|r| r.result.ate_rmse_m));
        outcome
            .tracking_rate
            .push(ev.as_ref().and_then(|r| r.result.tracking_rate));
        outcome.no_ate.push(no_ate_reason(ev.as_ref()));
        outcome.floor = ev.as_ref().and_then(|r| r.motionless_floor_m);
        runs.push(stats);
    }
    record.results = Some(runs);
    Ok(outcome)
}

/// Why a run has no ATE: no ground truth, or the evaluation's error (a sequence of one or two
/// frames, no overlap in time, …).
fn no_ate_reason(ev: Option<&RunEvaluation>) -> String {
    match ev {
        None => "no ground truth".into(),
        Some(r) => r
            .result
            .error
            .clone()
            .unwrap_or_else(|| "no ATE computed".into()),
    }
}

/// Runs `config` online over `input` and writes its outputs into `out`, replaced as a whole
/// at the end (like [`execute`]).
pub fn execute_online(
    input: &Input,
    config: &Config,
    masks: Option<&Path>,
    out: &Path,
    bars: &Bars,
    observer: Option<std::sync::Arc<dyn dynapix::RunObserver>>,
) -> anyhow::Result<RunOutcome> {
    check_out(out, &[("the sequence", input.sequence.dir.as_path())])?;
    // DynaPix+ masks (`--masks`, else the sequence's `mask/`), checked before anything is
    // written.
    let masks = input.mask_folder(config, masks)?;
    let masks = masks.as_deref();
    let staged = OutputFolder::begin(out, RESULT_MARKERS)?;
    let mut record = RunRecord::online(input, config, masks);
    let result = online_into(
        input,
        config,
        masks,
        staged.path(),
        &mut record,
        bars,
        observer,
    );
    if let Err(e) = &result {
        let (why, frame) = stop_reason(e);
        record.mark_incomplete(why, frame);
    } else {
        record.mark_complete();
    }
    record.invalid_depth = Some(input.sequence.invalid_depth());
    record.write(staged.path().join("run.json"))?;
    let written = staged.commit()?;
    if result.is_err() {
        eprintln!(
            "the run stopped; {} keeps what it computed (marked incomplete)",
            written.display()
        );
    }
    let mut o = result?;
    o.trajectory = out.join("trajectory.txt");
    Ok(o)
}

/// Writes the poses reported so far and every frame's status (skipped frames lost) into `dir`.
/// Returns the reported poses and the statuses.
fn write_online_poses(
    dir: &Path,
    run: &OnlineRun,
) -> anyhow::Result<(Trajectory, Vec<StampedStatus>)> {
    Ok(run.write_poses(dir)?)
}

/// The online run of [`execute_online`] into the folder `dir`.
fn online_into(
    input: &Input,
    config: &Config,
    masks: Option<&Path>,
    dir: &Path,
    record: &mut RunRecord,
    bars: &Bars,
    observer: Option<std::sync::Arc<dyn dynapix::RunObserver>>,
) -> anyhow::Result<RunOutcome> {
    let (run, result) = dynapix::run_online(input, config, masks, bars, &mut |_| {}, observer);
    if let Err(e) = result {
        // Keep what was reported up to the frame that stopped the run.
        write_online_poses(dir, &run)?;
        record.skipped_frames = Some(run.skipped.clone());
        return Err(e.into());
    }
    let n = input.len();
    let results = &run.results;
    let (reported, status) = write_online_poses(dir, &run)?;
    run.refined.write_tum(dir.join("trajectory_refined.txt"))?;
    let per = |f: &dyn Fn(&dynapix::FrameResult) -> f64| {
        let mut v: Vec<f64> = results.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
        let p95 = v
            .get(((v.len().max(1) - 1) as f64 * 0.95).round() as usize)
            .copied()
            .unwrap_or(0.0);
        json!({"mean": mean, "median": v.get(v.len() / 2).copied().unwrap_or(0.0), "p95": p95})
    };
    let tracked = status
        .iter()
        .filter(|s| s.status == FrameStatus::Tracked)
        .count();
    let mut stats = json!({
        "frames": n,
        "tracked": tracked,
        "frames_skipped": run.skipped.len(),
        "keyframes": run.keyframes,
        "map_points": run.map_points,
        "lookahead_frames": run.lookahead,
        "motion_ms": per(&|r| r.motion_ms),
        "background_ms": per(&|r| r.background_ms),
        "slam_ms": per(&|r| r.slam_ms),
        "mapping_ms": per(&|r| r.mapping_ms),
        "frame_ms": per(&|r| r.motion_ms + r.slam_ms),
        "next_rigidity_ms": per(&|r| r.next_rigidity_ms),
        "rigidity_ahead_frames": results.iter().filter(|r| r.rigidity_ahead).count(),
        "image_loading_ms_mean": run.load_ms.iter().sum::<f64>() / n.max(1) as f64,
        "wall_seconds": run.wall_seconds,
        "masks": masks,
    });
    let ev = evaluate_into(input, &reported, dir, &mut stats, true)?;
    record.skipped_frames = Some(run.skipped.clone());
    record.results = Some(vec![stats]);
    Ok(RunOutcome {
        trajectory: dir.join("trajectory.txt"),
        ate: vec![ev.as_ref().and_then(|r| r.result.ate_rmse_m)],
        tracking_rate: vec![ev.as_ref().and_then(|r| r.result.tracking_rate)],
        no_ate: vec![no_ate_reason(ev.as_ref())],
        floor: ev.as_ref().and_then(|r| r.motionless_floor_m),
        earlier_passes: Vec::new(),
        tracked: vec![tracked],
        skipped: vec![run.skipped.clone()],
        prob_dir: None,
        written_trajectory: None,
    })
}

/// The cache folder of a run on `input`: `given`, else none with `no_cache`, else the
/// default one ([`dynapix::RunOptions::default_cache_dir`]).
pub fn cache_for(input: &Input, given: Option<PathBuf>, no_cache: bool) -> Option<PathBuf> {
    if no_cache {
        return None;
    }
    Some(given.unwrap_or_else(|| {
        let dir = dynapix::RunOptions::default_cache_dir(&input.sequence.dir);
        if !dir.starts_with(&input.sequence.dir) {
            if dynapix::RunOptions::user_cache_is_temporary() {
                tracing::warn!(
                    "{} is not writable and neither HOME nor XDG_CACHE_HOME is set: caching \
                     in {} (pass --cache DIR to keep the cache elsewhere)",
                    input.sequence.dir.display(),
                    dir.display()
                );
            } else {
                tracing::info!(
                    "{} is not writable: caching in {}",
                    input.sequence.dir.display(),
                    dir.display()
                );
            }
        }
        dir
    }))
}

/// The configuration of `run`'s flags over the `--config` file.
pub fn config(args: &Args) -> anyhow::Result<Config> {
    let mut c = args.seq.base_config(args.m.mode)?;
    if let Some(m) = args.method {
        c.method = m;
    }
    if let Some(s) = args.seed {
        c.slam.seed = s;
    }
    if let Some(k) = args.lookahead {
        c.online.lookahead = k;
    }
    if args.skip_bad_frames {
        c.sequence.skip_bad_frames = true;
    }
    args.m.apply(&mut c)?;
    Ok(c)
}

/// Runs `dynapix run`.
pub fn run(args: Args, bars: &Bars) -> anyhow::Result<()> {
    let config = config(&args)?;
    // Where the results go, before any work.
    let mut keep = vec![("the sequence", args.seq.seq_dir.as_path())];
    if let Some(c) = &args.cache {
        keep.push(("the cache", c.as_path()));
    }
    if let Some(m) = &args.masks {
        keep.push(("the masks", m.as_path()));
    }
    check_out(&args.out, &keep)?;
    let input = args.seq.open(&config)?;
    let method = config.method;
    let viz = args
        .viz
        .open(&format!("{method} {}", args.seq.seq_dir.display()))?;
    let observer = viz.as_ref().map(super::viz::Viz::observer);
    let o = if args.online {
        if args.runs != 1 {
            bail!("--online runs once (the system is deterministic); drop --runs");
        }
        execute_online(
            &input,
            &config,
            args.masks.as_deref(),
            &args.out,
            bars,
            observer,
        )?
    } else {
        let options = RunOptions {
            cache_dir: cache_for(&input, args.cache.clone(), args.no_cache),
            recompute_maps: args.recompute_prob,
            masks_dir: args.masks.clone(),
            allow_missing_maps: args.allow_missing_prob,
            first_pass: None,
        };
        execute(
            RunSpec {
                input: &input,
                config,
                options,
                out: args.out.clone(),
                runs: args.runs,
                first_run: 0,
                observer,
            },
            bars,
        )?
    };
    if let Some(v) = viz {
        v.finish()?;
    }
    let ate = |a: Option<f64>| a.map_or_else(|| "n/a".to_string(), |a| format!("{a:.4} m"));
    for p in &o.earlier_passes {
        println!(
            "  pass {}: ATE RMSE {}, tracking rate {}",
            p["pass"].as_str().unwrap_or("?"),
            ate(p["ate_rmse_m"].as_f64()),
            p["tracking_rate"]
                .as_f64()
                .map_or_else(|| "n/a".to_string(), |t| format!("{:.1} %", t * 100.0))
        );
    }
    let floor = o
        .floor
        .map(|f| format!(" (motionless floor {f:.4} m)"))
        .unwrap_or_default();
    for (k, (a, t)) in o.ate.iter().zip(&o.tracking_rate).enumerate() {
        let skipped = skipped_note(
            o.skipped.get(k).map_or(&[][..], Vec::as_slice),
            args.skip_bad_frames,
        );
        match (a, t) {
            (Some(a), Some(t)) => println!(
                "{method} run {k}: ATE RMSE {a:.4} m, tracking rate {:.1} %{floor}{skipped}",
                t * 100.0
            ),
            _ => println!(
                "{method} run {k}: no ATE ({}){skipped}",
                o.no_ate.get(k).map_or("no ground truth", String::as_str)
            ),
        }
    }
    println!("trajectory: {}", o.trajectory.display());
    let least = o.tracked.iter().copied().min().unwrap_or(0);
    super::common::check_tracked(&args.seq.seq_dir, least, args.allow_untracked)
}
