//! `dynapix eval`: trajectory evaluation (spec §4) — ATE, RPE, tracking rate, multi-run and
//! multi-sequence tables, plots. All maths lives in `dynapix-eval`; this module parses
//! arguments, reads files and prints.

use anyhow::{Context, bail};
use dynapix_eval::files::{evaluate_runs_dir, read_reference_stamps, read_trajectory, write_table};
use dynapix_eval::{
    AssocParams, AteParams, EvalParams, Evaluation, RpeDelta, RpeParams, SequenceSummary,
    TrackingParams, evaluate, paper_table,
};
use dynapix_io::{GroundTruth, GtFrame};
use std::path::{Path, PathBuf};

/// How the three modes of `dynapix eval` are called (shown after the options in `--help`).
const MODES: &str = "\
Modes:
  One trajectory:
    dynapix eval --gt groundtruth.txt --est CameraTrajectory.txt [--reference associations.txt]
                 [--json] [--plot DIR] [--rpe | --rpe-delta S | --rpe-frames N]
  Many runs on one sequence (RUNS/<method>/<run>.txt, like the reference eval.py):
    dynapix eval --gt groundtruth.txt --runs RUNS [--reference associations.txt] [--out DIR]
    -> per method mean ± std of ATE RMSE and tracking rate
  Several sequences (paper-style table with Average and ATR rows):
    dynapix eval --sequence walking_xyz=GT:RUNS[:REFERENCE] --sequence ... [--out DIR]
    (one --sequence per sequence; paths must not contain ':')

--out DIR writes DIR/table.md, table.csv and table.json. With --json, one trajectory prints
one JSON object (at least ate_rmse_m, pairs, motionless_floor_m and gt_frame; with
--reference also tracking_rate and missing_time_s); the table modes print the table as JSON.

Every evaluation also reports the motionless floor: the ATE RMSE of a camera that never moves
(one constant pose) on the same pairs after the same alignment. An ATE at or above it is no
better than standing still.

Ground truth: the groundtruth.txt of a Bonn RGB-D Dynamic folder (rgbd_bonn_*) holds poses of
the motion-capture marker, not of the camera; --gt-frame camera (default) converts them
(T_ros·T·T_ros·T_m, as the dataset's tools do), --gt-frame raw scores against the file as it
is, as published Bonn results do. Other ground-truth files hold camera poses either way.";

/// Which ground-truth poses to score against.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum GtFrameArg {
    /// Camera poses (Bonn marker poses converted).
    Camera,
    /// The file as it is (Bonn: marker poses, what published Bonn numbers use).
    Raw,
}

impl From<GtFrameArg> for GtFrame {
    fn from(a: GtFrameArg) -> Self {
        match a {
            GtFrameArg::Camera => GtFrame::Camera,
            GtFrameArg::Raw => GtFrame::Raw,
        }
    }
}

/// The ground truth of one sequence and how it was read.
struct LoadedGt {
    poses: Vec<(f64, dynapix_geometry::Se3)>,
    info: GroundTruth,
}

impl LoadedGt {
    fn read(path: &Path, frame: GtFrame) -> anyhow::Result<Self> {
        let (poses, info) = dynapix_eval::files::read_ground_truth(path, frame)
            .with_context(|| format!("reading ground truth {}", path.display()))?;
        Ok(Self { poses, info })
    }

    /// The JSON fields that say which poses were scored against.
    fn json(&self, sequence: Option<&str>) -> GtJson {
        GtJson {
            sequence: sequence.map(str::to_string),
            gt_frame: self.info.frame.as_str(),
            gt_file_holds: self.info.convention.as_str(),
            gt_converted: self.info.converted(),
            gt_description: self.info.description(),
        }
    }
}

/// Which ground-truth poses an evaluation scored against (JSON output).
#[derive(serde::Serialize)]
struct GtJson {
    /// Sequence name (table modes).
    #[serde(skip_serializing_if = "Option::is_none")]
    sequence: Option<String>,
    /// `camera` or `raw` (`--gt-frame`).
    gt_frame: &'static str,
    /// What the file holds: `camera` or `bonn-marker`.
    gt_file_holds: &'static str,
    /// True when marker poses were converted to camera poses.
    gt_converted: bool,
    /// One line for people.
    gt_description: &'static str,
}

/// `--json` of one trajectory: the report, then the ground-truth fields.
#[derive(serde::Serialize)]
struct SingleJson {
    #[serde(flatten)]
    report: dynapix_eval::Report,
    #[serde(flatten)]
    gt: GtJson,
}

/// `--json` of the table modes: the table, then the ground truth of every sequence.
#[derive(serde::Serialize)]
struct TableJson<'a> {
    #[serde(flatten)]
    table: &'a dynapix_eval::PaperTable,
    ground_truth: Vec<GtJson>,
}

/// Arguments of `dynapix eval` (see [`MODES`]).
#[derive(clap::Args, Debug)]
#[command(after_help = MODES)]
pub struct Args {
    /// Ground-truth trajectory (TUM format: timestamp tx ty tz qx qy qz qw).
    #[arg(long, value_name = "FILE")]
    pub gt: Option<PathBuf>,
    /// Ground-truth poses to score against: `camera` converts the marker poses of a Bonn
    /// `rgbd_bonn_*/groundtruth.txt` to camera poses; `raw` takes the file as it is (what
    /// published Bonn results use). Other files hold camera poses either way.
    #[arg(long, value_enum, default_value = "camera", value_name = "FRAME")]
    pub gt_frame: GtFrameArg,
    /// Estimated trajectory (TUM format). Single-trajectory mode.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["runs", "sequence"])]
    pub est: Option<PathBuf>,
    /// Folder with one sub-folder per method, each holding one trajectory .txt per run.
    #[arg(long, value_name = "DIR", conflicts_with = "sequence")]
    pub runs: Option<PathBuf>,
    /// A sequence of a multi-sequence table: `NAME=GT:RUNS[:REFERENCE]`. Repeatable.
    #[arg(long, value_name = "NAME=GT:RUNS[:REF]", conflicts_with = "gt")]
    pub sequence: Vec<String>,
    /// Reference frame list for the tracking rate: rgb.txt or an association file (first
    /// column = frame timestamps). Restricted to the ground-truth time span.
    #[arg(long, value_name = "FILE")]
    pub reference: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Align with scale (Umeyama Sim3) instead of rotation + translation (Horn SE3).
    #[arg(long)]
    pub sim3: bool,
    /// Maximum timestamp difference for association, seconds.
    #[arg(long, default_value_t = 0.02, value_name = "S")]
    pub max_diff: f64,
    /// Time offset added to the estimate's timestamps, seconds.
    #[arg(
        long,
        default_value_t = 0.0,
        value_name = "S",
        allow_hyphen_values = true
    )]
    pub offset: f64,
    /// Start of the evaluation window (pairs outside [start − 1 s, end + 1 s] are skipped;
    /// the tracking rate uses [start, end] ∩ ground-truth span).
    #[arg(long, value_name = "T", allow_hyphen_values = true)]
    pub start: Option<f64>,
    /// End of the evaluation window (see --start).
    #[arg(long, value_name = "T", allow_hyphen_values = true)]
    pub end: Option<f64>,
    /// Also compute the RPE with a 1 s delta (implied by --rpe-delta / --rpe-frames).
    #[arg(long)]
    pub rpe: bool,
    /// RPE delta in seconds.
    #[arg(long, value_name = "S", conflicts_with = "rpe_frames")]
    pub rpe_delta: Option<f64>,
    /// RPE delta in frames of the estimate.
    #[arg(long, value_name = "N")]
    pub rpe_frames: Option<usize>,
    /// Write plots (trajectory top view and ATE over time, SVG and PNG) into this folder.
    #[arg(long, value_name = "DIR")]
    pub plot: Option<PathBuf>,
    /// Write table.md, table.csv and table.json into this folder (multi-run modes).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

fn params(args: &Args) -> anyhow::Result<EvalParams> {
    if !(args.max_diff.is_finite() && args.max_diff > 0.0) {
        bail!("--max-diff must be positive, got {}", args.max_diff);
    }
    let window = match (args.start, args.end) {
        (None, None) => None,
        (s, e) => {
            let w = (s.unwrap_or(f64::NEG_INFINITY), e.unwrap_or(f64::INFINITY));
            if w.0 > w.1 {
                bail!("--start {} is after --end {}", w.0, w.1);
            }
            Some(w)
        }
    };
    let rpe = match (args.rpe_delta, args.rpe_frames, args.rpe) {
        (Some(d), _, _) => Some(RpeDelta::Seconds(d)),
        (None, Some(n), _) => Some(RpeDelta::Frames(n)),
        (None, None, true) => Some(RpeDelta::Seconds(1.0)),
        (None, None, false) => None,
    };
    Ok(EvalParams {
        ate: AteParams {
            assoc: AssocParams {
                max_diff: args.max_diff,
                offset: args.offset,
                window,
                ..AssocParams::default()
            },
            sim3: args.sim3,
            ..AteParams::default()
        },
        rpe: rpe.map(|delta| RpeParams {
            delta,
            offset: args.offset,
            ..RpeParams::default()
        }),
        tracking: TrackingParams::default(),
    })
}

fn read_reference(path: Option<&Path>) -> anyhow::Result<Option<Vec<f64>>> {
    path.map(|p| {
        read_reference_stamps(p).with_context(|| format!("reading reference {}", p.display()))
    })
    .transpose()
}

/// Runs `dynapix eval`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let p = params(&args)?;
    if !args.sequence.is_empty() {
        return run_sequences(&args, &p);
    }
    let Some(gt_path) = args.gt.as_deref() else {
        bail!("give --gt with --est or --runs, or one --sequence per sequence (see --help)");
    };
    let gt = LoadedGt::read(gt_path, args.gt_frame.into())?;
    let reference = read_reference(args.reference.as_deref())?;
    if let Some(est_path) = args.est.as_deref() {
        let est = read_trajectory(est_path)
            .with_context(|| format!("reading estimate {}", est_path.display()))?;
        let ev = evaluate(&gt.poses, &est, reference.as_deref(), &p)
            .with_context(|| format!("evaluating {}", est_path.display()))?;
        if let Some(dir) = args.plot.as_deref() {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("creating plot folder {}", dir.display()))?;
            let files = dynapix_eval::plot::write_plots(dir, &ev.ate)?;
            for f in files {
                tracing::info!("wrote {}", f.display());
            }
        }
        if args.json {
            let out = SingleJson {
                report: ev.report(),
                gt: gt.json(None),
            };
            println!("{}", serde_json::to_string(&out)?);
        } else {
            println!("Ground truth: {}", gt.info.description());
            print_single(&ev, &p);
        }
        return Ok(());
    }
    if let Some(runs) = args.runs.as_deref() {
        let name = sequence_name(gt_path);
        let seq = evaluate_sequence(&name, &gt.poses, runs, reference.as_deref(), &p)?;
        return output_table(&args, vec![seq], vec![(name, gt)]);
    }
    bail!("give --est (one trajectory) or --runs (a folder of runs); see --help")
}

/// Name of a sequence from its ground-truth path: the parent folder name, else the stem.
fn sequence_name(gt: &Path) -> String {
    gt.parent()
        .and_then(|p| p.file_name())
        .or_else(|| gt.file_stem())
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "sequence".into())
}

fn evaluate_sequence(
    name: &str,
    gt: &[(f64, dynapix_geometry::Se3)],
    runs: &Path,
    reference: Option<&[f64]>,
    p: &EvalParams,
) -> anyhow::Result<SequenceSummary> {
    let bar = indicatif::ProgressBar::new_spinner();
    let methods = evaluate_runs_dir(gt, runs, reference, p, |f| {
        bar.set_message(format!("{name}: {}", f.display()));
        bar.tick();
    })
    .with_context(|| format!("evaluating runs in {}", runs.display()))?;
    bar.finish_and_clear();
    for m in &methods {
        for r in &m.runs {
            if let Some(e) = &r.error {
                tracing::warn!("{name}/{}/{}: {e}", m.method, r.name);
            }
        }
    }
    Ok(SequenceSummary {
        sequence: name.to_string(),
        methods,
    })
}

fn run_sequences(args: &Args, p: &EvalParams) -> anyhow::Result<()> {
    let mut seqs = Vec::new();
    let mut gts = Vec::new();
    for spec in &args.sequence {
        let (name, rest) = spec
            .split_once('=')
            .with_context(|| format!("--sequence {spec:?}: expected NAME=GT:RUNS[:REFERENCE]"))?;
        let parts: Vec<&str> = rest.split(':').collect();
        let (gt_path, runs, reference) = match parts.as_slice() {
            [g, r] => (*g, *r, None),
            [g, r, f] => (*g, *r, Some(Path::new(*f))),
            _ => bail!("--sequence {spec:?}: expected NAME=GT:RUNS[:REFERENCE]"),
        };
        let gt = LoadedGt::read(Path::new(gt_path), args.gt_frame.into())?;
        let reference = read_reference(reference.or(args.reference.as_deref()))?;
        seqs.push(evaluate_sequence(
            name,
            &gt.poses,
            Path::new(runs),
            reference.as_deref(),
            p,
        )?);
        gts.push((name.to_string(), gt));
    }
    output_table(args, seqs, gts)
}

fn output_table(
    args: &Args,
    seqs: Vec<SequenceSummary>,
    gts: Vec<(String, LoadedGt)>,
) -> anyhow::Result<()> {
    let table = paper_table(seqs);
    // Runs that could not be evaluated: named, counted in every mean's n, and an error exit.
    let mut counts = Vec::new();
    let mut failed = Vec::new();
    for s in &table.sequences {
        for m in &s.methods {
            let bad: Vec<&str> = m
                .runs
                .iter()
                .filter(|r| r.ate_rmse_m.is_none())
                .map(|r| r.name.as_str())
                .collect();
            let given = m.runs.len();
            counts.push(format!(
                "{} / {}: {} of {given} runs used",
                s.sequence,
                m.method,
                given - bad.len()
            ));
            if !bad.is_empty() {
                failed.push(format!("{} / {}: {}", s.sequence, m.method, bad.join(", ")));
            }
        }
    }
    let verdict = || {
        if failed.is_empty() {
            Ok(())
        } else {
            Err(anyhow::anyhow!(
                "{} method(s) with runs that could not be evaluated (left out of mean ± std): {}",
                failed.len(),
                failed.join("; ")
            ))
        }
    };
    if let Some(dir) = args.out.as_deref() {
        for f in write_table(dir, &table)? {
            tracing::info!("wrote {}", f.display());
        }
    }
    if args.json {
        let out = TableJson {
            table: &table,
            ground_truth: gts.iter().map(|(name, gt)| gt.json(Some(name))).collect(),
        };
        println!("{}", serde_json::to_string_pretty(&out)?);
        return verdict();
    }
    for (name, gt) in &gts {
        println!("Ground truth of {name}: {}", gt.info.description());
    }
    println!();
    for (k, s) in table.sequences.iter().enumerate() {
        println!("## {}\n", s.sequence);
        if let Some(f) = table.floors_m.get(k).copied().flatten() {
            println!(
                "Motionless floor (a camera that never moves, same pairs): {f:.6} m (mean over runs)\n"
            );
        }
        println!(
            "| method | run | ATE RMSE [m] | motionless floor [m] | pairs | TR | missing [s] |"
        );
        println!("|---|---|---:|---:|---:|---:|---:|");
        for m in &s.methods {
            for (r, floor) in m.runs.iter().zip(&m.run_floors_m) {
                let ate = r
                    .ate_rmse_m
                    .map_or_else(|| "failed".to_string(), |v| format!("{v:.6}"));
                let tr = r
                    .tracking_rate
                    .map_or_else(|| "—".to_string(), |v| format!("{v:.4}"));
                let miss = r
                    .missing_time_s
                    .map_or_else(|| "—".to_string(), |v| format!("{v:.3}"));
                let floor = floor.map_or_else(|| "—".to_string(), |v| format!("{v:.6}"));
                println!(
                    "| {} | {} | {ate} | {floor} | {} | {tr} | {miss} |",
                    m.method, r.name, r.pairs
                );
            }
        }
        println!();
    }
    println!("{}", table.to_markdown());
    println!("Runs per mean: {}", counts.join("; "));
    verdict()
}

fn print_single(ev: &Evaluation, p: &EvalParams) {
    let s = &ev.ate.stats;
    let kind = if p.ate.sim3 {
        format!(
            "Sim3 Umeyama alignment, scale {:.6}",
            ev.ate.alignment.scale()
        )
    } else {
        "SE3 Horn alignment".to_string()
    };
    println!(
        "ATE ({kind}; {} pairs within {} s)",
        s.count, p.ate.assoc.max_diff
    );
    println!("  rmse    {:.6} m", s.rmse);
    println!("  mean    {:.6} m", s.mean);
    println!("  median  {:.6} m", s.median);
    println!("  std     {:.6} m", s.std);
    println!("  min     {:.6} m", s.min);
    println!("  max     {:.6} m", s.max);
    let floor = ev.motionless_floor();
    let ratio = if floor > 0.0 {
        format!("; ATE/floor {:.3}", s.rmse / floor)
    } else {
        String::new()
    };
    println!(
        "  motionless floor {floor:.6} m (a camera that never moves, same pairs and alignment{ratio})"
    );
    if let Some(r) = &ev.rpe {
        println!("RPE ({} pairs)", r.pairs);
        println!(
            "  translation rmse {:.6} m, mean {:.6} m, max {:.6} m",
            r.translation.rmse, r.translation.mean, r.translation.max
        );
        println!(
            "  rotation    rmse {:.6} deg, mean {:.6} deg, max {:.6} deg",
            r.rotation_deg.rmse, r.rotation_deg.mean, r.rotation_deg.max
        );
    }
    if let Some(t) = &ev.tracking {
        println!(
            "Tracking rate {:.4} (missing {:.3} s of {:.3} s; {} of {} reference frames without pose)",
            t.tracking_rate, t.missing_time_s, t.duration_s, t.missing_frames, t.frames
        );
    }
}
