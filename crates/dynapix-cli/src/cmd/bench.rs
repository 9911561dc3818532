//! `dynapix bench`: one measured run of a method on a sequence, from scratch (nothing read
//! from a cache), with a per-stage table of where the time went, frames per second, CPU and
//! wall time and peak memory (`dynapix::bench`), plus the ATE when ground truth exists.
//! Stage figures are busy time summed over worker threads; phases are wall time.

use std::path::PathBuf;

use anyhow::Context;
use dynapix::profile::StageProfiler;
use serde_json::json;

use super::common::{Bars, SequenceArgs, write_json};
use super::run::MethodArgs;

/// Arguments of `dynapix bench`.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// The sequence.
    #[command(flatten)]
    pub seq: SequenceArgs,
    /// Method (default: the configuration's, dynapix).
    #[arg(long, value_enum)]
    pub method: Option<dynapix::Method>,
    /// Method flags (as in `run`).
    #[command(flatten)]
    pub m: MethodArgs,
    /// Push frames one at a time through the online mode (reports per-frame latency).
    #[arg(long)]
    pub online: bool,
    /// Online: frames of latency allowed (as in `run`).
    #[arg(long, requires = "online")]
    pub lookahead: Option<usize>,
    /// Write the report as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Write the report as a Markdown table to this file.
    #[arg(long, value_name = "FILE")]
    pub markdown: Option<PathBuf>,
}

/// Runs `dynapix bench`.
pub fn run(args: Args, bars: &Bars, profiler: &StageProfiler) -> anyhow::Result<()> {
    let run_args = super::run::Args {
        seq: args.seq.clone(),
        method: args.method,
        out: PathBuf::new(),
        m: args.m.clone(),
        runs: 1,
        seed: None,
        masks: None,
        cache: None,
        recompute_prob: true,
        allow_missing_prob: false,
        allow_untracked: true,
        skip_bad_frames: false,
        online: args.online,
        lookahead: args.lookahead,
    };
    let config = super::run::config(&run_args)?;
    let input = args.seq.open(&config)?;
    let (report, trajectory) = if args.online {
        dynapix::bench_online(&config, &input, profiler, bars)?
    } else {
        let (r, out) = dynapix::bench_offline(&config, &input, profiler, bars)?;
        let t = out
            .final_pass()
            .map(|p| p.trajectory.clone())
            .unwrap_or_default();
        (r, t)
    };
    let ate = ate(&args.seq.seq_dir, &trajectory, &input.timestamps())?;
    let mut text = report.to_markdown();
    if let Some((a, floor)) = ate {
        text.push_str(&format!(
            "ATE RMSE {a:.4} m (motionless floor {floor:.4} m)\n"
        ));
    }
    print!("{text}");
    if let Some(p) = &args.markdown {
        dynapix_io::write_atomic(p, text.as_bytes())
            .with_context(|| format!("cannot write {}", p.display()))?;
    }
    if let Some(p) = &args.json {
        let mut v = serde_json::to_value(&report)?;
        v["ate_rmse_m"] = json!(ate.map(|a| a.0));
        v["motionless_floor_m"] = json!(ate.map(|a| a.1));
        v["config"] = config.to_json_value();
        v["build"] = json!(if cfg!(debug_assertions) {
            "debug"
        } else {
            "release"
        });
        write_json(p, &v)?;
    }
    Ok(())
}

/// ATE RMSE and motionless floor of `trajectory` against the sequence's ground truth.
fn ate(
    seq_dir: &std::path::Path,
    trajectory: &dynapix_io::Trajectory,
    stamps: &[f64],
) -> anyhow::Result<Option<(f64, f64)>> {
    let gt_path = seq_dir.join("groundtruth.txt");
    if !gt_path.exists() || trajectory.poses.is_empty() {
        return Ok(None);
    }
    let gt = dynapix_eval::files::read_camera_ground_truth(&gt_path)?;
    let est: Vec<_> = trajectory.poses.iter().map(|p| (p.t, p.pose)).collect();
    let ev = dynapix_eval::evaluate(
        &gt,
        &est,
        Some(stamps),
        &dynapix_eval::EvalParams::default(),
    )?;
    Ok(Some((ev.ate.stats.rmse, ev.motionless_floor())))
}
