//! `dynapix experiment`: every method × sequence × run, then the paper-style table (spec §4.4:
//! per sequence mean ± std over runs of ATE RMSE and tracking rate, Average row, ATR) as
//! Markdown, CSV and JSON. Motion maps are computed first (once per sequence and probability
//! variant, sequentially, into each sequence's cache); the SLAM runs then go in parallel
//! (`--jobs`). Resumable: a run whose `eval.json` (or, without ground truth, `trajectory.txt`)
//! exists is not repeated. Run k uses seed `seed + k`; each run folder holds its trajectory,
//! evaluation and plots (top view, ATE over time).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use dynapix_eval::{RunResult, SequenceSummary, paper_table};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

use super::run::{self, Method};

/// Arguments of `dynapix experiment`.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Sequence folders (comma separated or repeated).
    #[arg(long, value_delimiter = ',', num_args = 1.., required = true)]
    pub sequences: Vec<PathBuf>,
    /// Methods: orbslam2, dynapix, dynapix+, no-movable, no-moving, threshold.
    #[arg(long, value_delimiter = ',', default_value = "orbslam2,dynapix")]
    pub methods: Vec<String>,
    /// Runs per method and sequence.
    #[arg(long, default_value_t = 1)]
    pub runs: usize,
    /// Seed of run 0.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Ground-truth poses for the motion maps (the paper's setting).
    #[arg(long)]
    pub oracle_poses: bool,
    /// Runs in parallel.
    #[arg(long, default_value_t = 2)]
    pub jobs: usize,
    /// DIS preset of the motion maps.
    #[arg(long, default_value = "fast")]
    pub flow_preset: String,
    /// Weighting behaviour of the DynaPix methods.
    #[arg(long, value_enum, default_value = "paper")]
    pub weighting: run::WeightingArg,
    /// Per-map-point probability update.
    #[arg(long, value_enum, default_value = "ema")]
    pub update: run::UpdateArg,
    /// Motion-map cache root (default: `dynapix_cache` inside each sequence; needed for
    /// read-only sequence folders): maps go to `<cache>/<sequence name>/`.
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Process at most this many frames per sequence.
    #[arg(long)]
    pub max_frames: Option<usize>,
}

fn seq_name(p: &Path) -> String {
    p.canonicalize()
        .ok()
        .and_then(|c| c.file_name().map(|s| s.to_string_lossy().into_owned()))
        .unwrap_or_else(|| p.display().to_string())
}

fn run_args(a: &Args, seq: &Path, method: Method, out: PathBuf, k: usize) -> run::Args {
    run::Args {
        seq_dir: seq.to_path_buf(),
        method,
        out,
        oracle_poses: a.oracle_poses,
        runs: 1,
        seed: a.seed + k as u64,
        masks: None,
        weighting: a.weighting,
        update: a.update,
        ema_alpha: 0.2,
        gamma_add: 0.05,
        gamma_del: 0.1,
        cache: a.cache.as_ref().map(|c| c.join(seq_name(seq))),
        recompute_prob: false,
        flow_preset: a.flow_preset.clone(),
        max_frames: a.max_frames,
        settings: None,
        allow_missing_prob: false,
        no_loop_closing: false,
        quiet: true,
        static_features: None,
        predicted_frames: 0,
    }
}

fn read_result(dir: &Path) -> Option<RunResult> {
    let t = std::fs::read_to_string(dir.join("eval.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&t).ok()?;
    Some(RunResult {
        name: dir
            .file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        ate_rmse_m: v["ate_rmse_m"].as_f64(),
        pairs: v["pairs"].as_u64().unwrap_or(0) as usize,
        tracking_rate: v["tracking_rate"].as_f64(),
        missing_time_s: v["missing_time_s"].as_f64(),
        error: v["error"].as_str().map(str::to_string),
    })
}

/// Runs `dynapix experiment`.
pub fn run(args: Args) -> anyhow::Result<()> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let methods: Vec<Method> = args
        .methods
        .iter()
        .map(|m| Method::parse(m))
        .collect::<anyhow::Result<_>>()?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let names: Vec<String> = args.sequences.iter().map(|s| seq_name(s)).collect();
    // Phase 1: motion maps (and first passes), sequentially, one per probability variant.
    for (seq, name) in args.sequences.iter().zip(&names) {
        let mut seen = Vec::new();
        for &m in &methods {
            let Some(terms) = m.terms() else { continue };
            if seen.contains(&terms) {
                continue;
            }
            seen.push(terms);
            eprintln!("{name}: motion maps ({terms})");
            let ra = run_args(&args, seq, m, args.out.join("prep"), 0);
            run::prepare_prob(&ra)?;
        }
    }
    // Phase 2: SLAM runs in parallel.
    let mut jobs = Vec::new();
    for (seq, name) in args.sequences.iter().zip(&names) {
        for &m in &methods {
            for k in 0..args.runs {
                let dir = args
                    .out
                    .join("runs")
                    .join(name)
                    .join(m.name())
                    .join(format!("run_{k}"));
                let done = dir.join("eval.json").exists()
                    || (!seq.join("groundtruth.txt").exists()
                        && dir.join("trajectory.txt").exists());
                if !done {
                    jobs.push(run_args(&args, seq, m, dir, k));
                }
            }
        }
    }
    let pb = ProgressBar::new(jobs.len() as u64);
    pb.set_style(
        ProgressStyle::with_template("runs {bar:30} {pos}/{len} {msg} [{elapsed_precise}]")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.jobs.max(1))
        .build()?;
    let errors: Vec<String> = pool.install(|| {
        jobs.par_iter()
            .filter_map(|ra| {
                let r = run::execute(ra);
                pb.inc(1);
                pb.set_message(format!("{} {}", seq_name(&ra.seq_dir), ra.method.name()));
                r.err().map(|e| format!("{}: {e:#}", ra.out.display()))
            })
            .collect()
    });
    pb.finish_and_clear();
    for e in &errors {
        eprintln!("run failed: {e}");
    }
    // Table.
    let mut summaries = Vec::new();
    for (seq, name) in args.sequences.iter().zip(&names) {
        if !seq.join("groundtruth.txt").exists() {
            continue;
        }
        let mut ms = Vec::new();
        for &m in &methods {
            let runs: Vec<RunResult> = (0..args.runs)
                .filter_map(|k| {
                    read_result(
                        &args
                            .out
                            .join("runs")
                            .join(name)
                            .join(m.name())
                            .join(format!("run_{k}")),
                    )
                })
                .collect();
            ms.push(dynapix_eval::aggregate::summarize(m.name(), runs));
        }
        summaries.push(SequenceSummary {
            sequence: name.clone(),
            methods: ms,
        });
    }
    if summaries.is_empty() {
        println!(
            "no sequence has ground truth: trajectories in {}",
            args.out.display()
        );
        return Ok(());
    }
    let table = paper_table(summaries);
    let written = dynapix_eval::files::write_table(&args.out, &table)?;
    println!("{}", table.to_markdown());
    for w in written {
        println!("wrote {}", w.display());
    }
    if !errors.is_empty() {
        bail!("{} run(s) failed", errors.len());
    }
    Ok(())
}
