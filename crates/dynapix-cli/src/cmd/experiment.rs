//! `dynapix experiment`: every method × sequence × run, then the paper-style table (spec §4.4:
//! per sequence mean ± std over runs of ATE RMSE and tracking rate, Average row, ATR) as
//! Markdown, CSV and JSON. First passes and motion maps are prepared first (once per sequence
//! and probability variant, sequentially, into each sequence's cache); the SLAM runs then go
//! in parallel (`--jobs`), all in this process. Resumable: a run whose `run.json` does not say
//! it stopped and whose `eval.json` (or, without ground truth, `trajectory.txt`) exists is not
//! repeated. Run k uses seed `seed + k`;
//! each run folder holds its trajectory, evaluation, plots and `run.json`.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use dynapix::{CameraChoice, Config, Input, Method, Progress, ProgressEvent};
use dynapix::{OfflineRunner, RunOptions};
use dynapix_eval::{RunResult, SequenceSummary, paper_table};
use rayon::prelude::*;

use super::common::Bars;
use super::run::{MethodArgs, RunSpec, execute};

/// Arguments of `dynapix experiment`.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Sequence folders (comma separated or repeated).
    #[arg(long, value_delimiter = ',', num_args = 1.., required = true)]
    pub sequences: Vec<PathBuf>,
    /// Methods (comma separated).
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "orbslam2,dynapix"
    )]
    pub methods: Vec<Method>,
    /// Runs per method and sequence.
    #[arg(long, default_value_t = 1)]
    pub runs: usize,
    /// Seed of run 0.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Method flags (applied to every method).
    #[command(flatten)]
    pub m: MethodArgs,
    /// Runs in parallel.
    #[arg(long, default_value_t = 2)]
    pub jobs: usize,
    /// Motion-map cache root (default: `dynapix_cache` inside each sequence; needed for
    /// read-only sequence folders): maps go to `<cache>/<sequence name>/`.
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Process at most this many frames per sequence.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Configuration file (JSON or YAML); flags override its values.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

fn seq_name(p: &Path) -> String {
    p.canonicalize()
        .ok()
        .and_then(|c| c.file_name().map(|s| s.to_string_lossy().into_owned()))
        .unwrap_or_else(|| p.display().to_string())
}

fn read_result(dir: &Path) -> Option<(RunResult, Option<f64>)> {
    let t = std::fs::read_to_string(dir.join("eval.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&t).ok()?;
    let floor = v["motionless_floor_m"].as_f64();
    Some((
        RunResult {
            name: dir
                .file_name()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            ate_rmse_m: v["ate_rmse_m"].as_f64(),
            pairs: v["pairs"].as_u64().unwrap_or(0) as usize,
            tracking_rate: v["tracking_rate"].as_f64(),
            missing_time_s: v["missing_time_s"].as_f64(),
            error: v["error"].as_str().map(str::to_string),
        },
        floor,
    ))
}

/// True when the run folder's `run.json` is a run record that does not say the run stopped
/// (`"complete": false`); a record of a version without the field counts as complete.
fn completed(dir: &Path) -> bool {
    dynapix::RunRecord::read(dir.join("run.json")).is_ok_and(|r| r.complete != Some(false))
}

/// Runs `dynapix experiment`.
pub fn run(args: Args, bars: &Bars) -> anyhow::Result<()> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let mut base = Config::load_with(args.config.as_deref(), args.m.mode)?;
    if let Some(n) = args.max_frames {
        anyhow::ensure!(n > 0, "--max-frames must be at least 1");
        base.sequence.max_frames = Some(n);
    }
    base.slam.seed = args.seed;
    args.m.apply(&mut base)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let names: Vec<String> = args.sequences.iter().map(|s| seq_name(s)).collect();
    let inputs: Vec<Input> = args
        .sequences
        .iter()
        .map(|s| {
            Input::open(s, &base.sequence, &CameraChoice::Sequence)
                .with_context(|| format!("cannot read the sequence {}", s.display()))
        })
        .collect::<anyhow::Result<_>>()?;
    let options = |input: &Input, name: &str| RunOptions {
        cache_dir: super::run::cache_for(input, args.cache.as_ref().map(|c| c.join(name)), false),
        ..Default::default()
    };
    // Phase 1: first passes and motion maps, sequentially, once per probability variant.
    for (input, name) in inputs.iter().zip(&names) {
        let mut seen = Vec::new();
        for &m in &args.methods {
            let Some(terms) = m.map_terms() else { continue };
            if seen.contains(&terms) {
                continue;
            }
            seen.push(terms);
            eprintln!("{name}: motion maps ({terms})");
            let config = base.clone().with_method(m);
            OfflineRunner::new(&config, input, options(input, name))?.prepare(bars)?;
        }
    }
    // Phase 2: SLAM runs in parallel.
    let mut jobs = Vec::new();
    for ((input, seq), name) in inputs.iter().zip(&args.sequences).zip(&names) {
        for &m in &args.methods {
            for k in 0..args.runs {
                let dir = args
                    .out
                    .join("runs")
                    .join(name)
                    .join(m.name())
                    .join(format!("run_{k}"));
                let done = completed(&dir)
                    && (dir.join("eval.json").exists()
                        || (!seq.join("groundtruth.txt").exists()
                            && dir.join("trajectory.txt").exists()));
                if !done {
                    jobs.push((input, name, base.clone().with_method(m), dir, k as u64));
                }
            }
        }
    }
    bars.event(ProgressEvent::Begin {
        task: "runs",
        total: jobs.len() as u64,
    });
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.jobs.max(1))
        .build()?;
    let hidden = Bars::new(true);
    let errors: Vec<String> = pool.install(|| {
        jobs.par_iter()
            .filter_map(|(input, name, config, dir, k)| {
                let spec = RunSpec {
                    input,
                    config: config.clone(),
                    options: options(input, name),
                    out: dir.clone(),
                    runs: 1,
                    first_run: *k,
                    observer: None,
                };
                let r = execute(spec, &hidden);
                let msg = format!("{name} {}", config.method);
                bars.event(ProgressEvent::Step {
                    task: "runs",
                    message: &msg,
                });
                r.err()
                    .map(|e| format!("{}: {}", dir.display(), super::common::report(&e)))
            })
            .collect()
    });
    bars.event(ProgressEvent::End { task: "runs" });
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
        for &m in &args.methods {
            let (runs, floors): (Vec<RunResult>, Vec<Option<f64>>) = (0..args.runs)
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
                .unzip();
            ms.push(dynapix_eval::aggregate::summarize_with_floors(
                m.name(),
                runs,
                floors,
            ));
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
