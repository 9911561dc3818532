//! `dynapix bench`: one measured run of a method on a sequence, from scratch (nothing read
//! from a cache), with a per-stage table of where the time went, frames per second, CPU and
//! wall time and peak memory (`dynapix::bench`), plus the ATE when ground truth exists.
//! Stage figures are busy time summed over worker threads; phases are wall time.

use std::path::{Path, PathBuf};

use dynapix::bench::StageProfiler;

use super::common::{Bars, SequenceArgs, write_text};
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
    /// Measure this many runs, each from scratch, one after the other: every run's speed is
    /// listed and the table is the median run's (by wall time). On a shared machine the
    /// spread between runs is part of the result.
    #[arg(long, value_name = "N", default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..))]
    pub repeat: u32,
    /// Write the report as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Write the report as a Markdown table to this file.
    #[arg(long, value_name = "FILE")]
    pub markdown: Option<PathBuf>,
    /// Log the measured run to Rerun, as `run` does (its cost is part of the measurement;
    /// with `--repeat` every run writes the recording anew).
    #[command(flatten)]
    pub viz: super::viz::VizArgs,
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
        no_cache: true,
        recompute_prob: true,
        allow_missing_prob: false,
        allow_untracked: true,
        skip_bad_frames: false,
        viz: Default::default(),
        online: args.online,
        lookahead: args.lookahead,
    };
    let config = super::run::config(&run_args)?;
    let input = args.seq.open(&config)?;
    let mut runs = Vec::with_capacity(args.repeat as usize);
    let name = format!("bench {} {}", config.method, args.seq.seq_dir.display());
    for _ in 0..args.repeat {
        let viz = args.viz.open(&name)?;
        let observer = viz.as_ref().map(super::viz::Viz::observer);
        runs.push(dynapix::bench::run(
            &config,
            &input,
            args.online,
            profiler,
            bars,
            observer,
        )?);
        if let Some(v) = viz {
            v.finish()?;
        }
    }
    let walls: Vec<f64> = runs.iter().map(|(r, _)| r.wall_seconds).collect();
    let (mut report, trajectory) = runs.swap_remove(median_index(&walls));
    let score = dynapix::evaluate::score_run(&input.sequence, &trajectory, Path::new("bench"))?;
    let ate = score.and_then(|s| Some((s.run.result.ate_rmse_m?, s.run.motionless_floor_m?)));
    report.ate_rmse_m = ate.map(|a| a.0);
    report.motionless_floor_m = ate.map(|a| a.1);
    report.repeat_wall_seconds = walls.clone();
    let mut text = report.to_markdown();
    if walls.len() > 1 {
        text.push_str(&repeat_lines(&walls, report.frames));
    }
    if let Some((a, floor)) = ate {
        text.push_str(&format!(
            "ATE RMSE {a:.4} m (motionless floor {floor:.4} m)\n"
        ));
    }
    print!("{text}");
    if let Some(p) = &args.markdown {
        write_text(p, &text)?;
    }
    if let Some(p) = &args.json {
        write_text(p, &serde_json::to_string_pretty(&report)?)?;
    }
    Ok(())
}

/// Index of the median of `values` (the lower one of the middle two).
fn median_index(values: &[f64]) -> usize {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    order[(order.len() - 1) / 2]
}

/// One line per run (wall time and frames/s), then the spread, for `--repeat`.
fn repeat_lines(walls: &[f64], frames: usize) -> String {
    let fps = |w: f64| frames as f64 / w.max(f64::MIN_POSITIVE);
    let mut text = String::from("\n| run | wall (s) | frames/s |\n|---:|---:|---:|\n");
    for (k, &w) in walls.iter().enumerate() {
        text.push_str(&format!("| {} | {w:.2} | {:.2} |\n", k + 1, fps(w)));
    }
    let lo = walls.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = walls.iter().copied().fold(0.0, f64::max);
    text.push_str(&format!(
        "\n{} runs: {:.2}–{:.2} frames/s (wall {lo:.2}–{hi:.2} s); the table above is the median run's\n",
        walls.len(),
        fps(hi),
        fps(lo),
    ));
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_median_run_and_the_spread_are_reported() {
        assert_eq!(median_index(&[3.0]), 0);
        assert_eq!(median_index(&[5.0, 1.0, 3.0]), 2);
        assert_eq!(median_index(&[4.0, 1.0, 3.0, 2.0]), 3);
        let text = repeat_lines(&[10.0, 12.5], 300);
        assert!(text.contains("| 1 | 10.00 | 30.00 |"), "{text}");
        assert!(text.contains("| 2 | 12.50 | 24.00 |"), "{text}");
        assert!(
            text.contains("2 runs: 24.00–30.00 frames/s (wall 10.00–12.50 s)"),
            "{text}"
        );
    }
}
