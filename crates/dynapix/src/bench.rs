//! One measured run of a method on a sequence (`dynapix bench`): wall and CPU time, frames
//! per second, peak memory and where the time went, stage by stage ([`StageProfiler`]).
//!
//! An offline bench computes everything (first pass, rigidity maps, motion maps, every pass)
//! in memory without a cache, so nothing is reused from an earlier run; an online bench
//! pushes the frames through [`crate::OnlineDynaPix`] one by one and also reports per-frame latency.

use std::path::PathBuf;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::config::Config;
use crate::error::{Error, Result};
use crate::input::Input;
use crate::offline::{OfflineRunner, RunOptions};
use crate::profile::process_usage;
pub use crate::profile::{Profile, StageProfiler, StageTime, retain_freed_memory};
use crate::progress::Progress;
use crate::stream::run_online;

/// Per-frame latency of an online bench: milliseconds spent in each `push` (the processing of
/// the frame it releases: the pushed one, or with a lookahead the one pushed K frames before).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Latency {
    /// Mean.
    pub mean_ms: f64,
    /// Median.
    pub p50_ms: f64,
    /// 95th percentile.
    pub p95_ms: f64,
    /// Largest.
    pub max_ms: f64,
}

impl Latency {
    /// Statistics of `ms` (`None` when empty).
    pub fn of(ms: &[f64]) -> Option<Self> {
        if ms.is_empty() {
            return None;
        }
        let mut s = ms.to_vec();
        s.sort_by(f64::total_cmp);
        let q = |f: f64| s[((s.len() - 1) as f64 * f).round() as usize];
        Some(Self {
            mean_ms: s.iter().sum::<f64>() / s.len() as f64,
            p50_ms: q(0.5),
            p95_ms: q(0.95),
            max_ms: s[s.len() - 1],
        })
    }
}

/// What a bench measured: also the record `dynapix bench --json` writes (the ATE, the wall
/// times of repeated runs and the build are filled in by the caller).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BenchReport {
    /// The sequence folder.
    pub sequence: PathBuf,
    /// Method name.
    pub method: String,
    /// `offline` or `online`.
    pub schedule: String,
    /// Frames processed.
    pub frames: usize,
    /// Frames tracked by the final pass.
    pub tracked: usize,
    /// Image size.
    pub width: u32,
    /// Image size.
    pub height: u32,
    /// Worker threads (rayon).
    pub threads: usize,
    /// Wall-clock seconds of the whole run.
    pub wall_seconds: f64,
    /// CPU seconds (user + system, all threads) of the run (`None` where unknown).
    pub cpu_seconds: Option<f64>,
    /// Peak resident memory of the process (MiB) at the end of the run.
    pub peak_rss_mib: Option<f64>,
    /// Frames per wall-clock second.
    pub fps: f64,
    /// Per-frame latency (online only).
    pub latency: Option<Latency>,
    /// Phases and stages (empty unless the profiler is installed as a subscriber layer).
    pub profile: Profile,
    /// ATE RMSE (m) of the final trajectory, when ground truth exists.
    pub ate_rmse_m: Option<f64>,
    /// The motionless floor (m) of that ATE.
    pub motionless_floor_m: Option<f64>,
    /// The whole resolved configuration.
    pub config: serde_json::Value,
    /// Wall-clock seconds of every measured run, in order (the report is the median one's).
    pub repeat_wall_seconds: Vec<f64>,
    /// `release` or `debug`.
    pub build: String,
}

impl BenchReport {
    /// The report as a Markdown table: one line per phase and stage with seconds, calls and
    /// milliseconds per frame, then the totals.
    pub fn to_markdown(&self) -> String {
        let n = self.frames.max(1) as f64;
        let mut s = format!(
            "{} {} on {} ({} frames, {}×{}, {} threads)\n\n| | seconds | calls | ms/frame | share |\n|---|---:|---:|---:|---:|\n",
            self.method,
            self.schedule,
            self.sequence.display(),
            self.frames,
            self.width,
            self.height,
            self.threads
        );
        for (kind, rows) in [
            ("phases (wall)", &self.profile.phases),
            ("stages (summed over threads)", &self.profile.stages),
        ] {
            if rows.is_empty() {
                continue;
            }
            s.push_str(&format!("| **{kind}** | | | | |\n"));
            for r in rows {
                s.push_str(&format!(
                    "| {} | {:.2} | {} | {:.1} | {:.0} % |\n",
                    r.name,
                    r.seconds,
                    r.calls,
                    r.seconds * 1e3 / n,
                    100.0 * r.seconds / self.wall_seconds.max(1e-9)
                ));
            }
        }
        s.push_str(&format!(
            "| **wall** | {:.2} | | {:.1} | 100 % |\n",
            self.wall_seconds,
            self.wall_seconds * 1e3 / n
        ));
        if let Some(c) = self.cpu_seconds {
            s.push_str(&format!(
                "| **CPU (process, all threads)** | {c:.2} | | {:.1} | |\n",
                c * 1e3 / n
            ));
        }
        s.push_str(&format!(
            "\n{:.2} frames/s ({:.1} ms/frame wall), {} of {} frames tracked",
            self.fps,
            self.wall_seconds * 1e3 / n,
            self.tracked,
            self.frames
        ));
        if let Some(m) = self.peak_rss_mib {
            s.push_str(&format!(", peak memory {m:.0} MiB"));
        }
        if let Some(l) = &self.latency {
            s.push_str(&format!(
                "\nlatency per frame: mean {:.1} ms, median {:.1}, p95 {:.1}, max {:.1}",
                l.mean_ms, l.p50_ms, l.p95_ms, l.max_ms
            ));
        }
        s.push('\n');
        s
    }
}

struct Clock {
    wall: Instant,
    cpu: Option<f64>,
}

impl Clock {
    fn start(profiler: &StageProfiler) -> Self {
        profiler.start();
        Self {
            wall: Instant::now(),
            cpu: process_usage().map(|u| u.cpu_seconds),
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn report(
        self,
        profiler: &StageProfiler,
        input: &Input,
        config: &Config,
        schedule: &'static str,
        tracked: usize,
        latency: Option<Latency>,
    ) -> BenchReport {
        let wall = self.wall.elapsed().as_secs_f64();
        let profile = profiler.stop();
        let usage = process_usage();
        let frames = input.len();
        let cam = input.camera.pinhole();
        BenchReport {
            sequence: input.sequence.dir.clone(),
            method: config.method.name().to_string(),
            schedule: schedule.to_string(),
            frames,
            tracked,
            width: cam.width,
            height: cam.height,
            threads: rayon::current_num_threads(),
            wall_seconds: wall,
            cpu_seconds: match (self.cpu, usage) {
                (Some(a), Some(b)) => Some(b.cpu_seconds - a),
                _ => None,
            },
            peak_rss_mib: usage.map(|u| u.peak_rss_mib),
            fps: frames as f64 / wall.max(1e-9),
            latency,
            profile,
            ate_rmse_m: None,
            motionless_floor_m: None,
            config: config.to_json_value(),
            repeat_wall_seconds: vec![wall],
            build: if cfg!(debug_assertions) {
                "debug"
            } else {
                "release"
            }
            .to_string(),
        }
    }
}

/// Runs `config` on `input` once and measures it, stage by stage: `online` pushes every
/// frame through [`OnlineDynaPix`](crate::OnlineDynaPix) ([`crate::run_online`]: decoding
/// included, on a reader thread that stays up to two frames ahead; DynaPix+ with the
/// sequence's `mask/`), else the offline schedule runs from scratch (no cache: nothing is read
/// from or written to disk but the sequence's frames). The run is shown to `observer` when
/// given (a viewer's cost is then part of the measured time). `profiler` must be a layer of
/// the process's `tracing` subscriber for the stage times.
///
/// Returns the report and the camera-to-world pose of every tracked frame (online: as
/// reported when each frame was processed; offline: the final pass).
pub fn run(
    config: &Config,
    input: &Input,
    online: bool,
    profiler: &StageProfiler,
    progress: &dyn Progress,
    observer: Option<std::sync::Arc<dyn crate::RunObserver>>,
) -> Result<(BenchReport, dynapix_io::Trajectory)> {
    if online {
        bench_online(config, input, profiler, progress, observer)
    } else {
        bench_offline(config, input, profiler, progress, observer)
    }
}

/// Runs `config` offline on `input` from scratch (no cache: nothing is read from or written
/// to disk but the sequence's frames) and measures it, shown to `observer` when given (a
/// viewer's cost is then part of the measured time).
/// Returns the report and the final pass's trajectory.
fn bench_offline(
    config: &Config,
    input: &Input,
    profiler: &StageProfiler,
    progress: &dyn Progress,
    observer: Option<std::sync::Arc<dyn crate::RunObserver>>,
) -> Result<(BenchReport, dynapix_io::Trajectory)> {
    // No cache: everything is computed and kept in memory, nothing is written or read back.
    let mut runner = OfflineRunner::new(
        config,
        input,
        RunOptions {
            cache_dir: None,
            recompute_maps: true,
            ..RunOptions::default()
        },
    )?;
    if let Some(o) = observer {
        runner = runner.with_observer(o);
    }
    let clock = Clock::start(profiler);
    let out = runner.run(progress);
    let tracked = out
        .as_ref()
        .ok()
        .and_then(|o| o.final_pass())
        .map_or(0, |p| p.stats.tracked);
    let report = clock.report(profiler, input, config, "offline", tracked, None);
    let trajectory = out?
        .final_pass()
        .map(|p| p.trajectory.clone())
        .unwrap_or_default();
    Ok((report, trajectory))
}

/// Pushes every frame of `input` through [`OnlineDynaPix`](crate::OnlineDynaPix) with
/// `config` ([`crate::run_online`]: decoding included, on a reader thread that stays up to two
/// frames ahead; DynaPix+ with the sequence's `mask/`) and measures it, shown to `observer`
/// when given. Returns the report and the camera-to-world pose of every tracked frame.
fn bench_online(
    config: &Config,
    input: &Input,
    profiler: &StageProfiler,
    progress: &dyn Progress,
    observer: Option<std::sync::Arc<dyn crate::RunObserver>>,
) -> Result<(BenchReport, dynapix_io::Trajectory)> {
    // Checked before the clock starts, like the offline runner checks its inputs.
    input.mask_folder(config, None)?;
    let clock = Clock::start(profiler);
    let (run, fed) = run_online(input, config, None, progress, &mut |_| {}, observer);
    if let Err(e) = fed {
        profiler.stop();
        return Err(e);
    }
    let report = clock.report(
        profiler,
        input,
        config,
        "online",
        run.tracked(),
        Latency::of(&run.push_ms),
    );
    if run.results.len() + run.skipped.len() != input.len() {
        return Err(Error::Input(format!(
            "online bench: {} results for {} frames",
            run.results.len(),
            input.len()
        )));
    }
    Ok((report, run.reported()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latency_quantiles() {
        let l = Latency::of(&[4.0, 1.0, 3.0, 2.0, 100.0]).unwrap();
        assert_eq!(l.p50_ms, 3.0);
        assert_eq!(l.max_ms, 100.0);
        assert_eq!(l.p95_ms, 100.0);
        assert!((l.mean_ms - 22.0).abs() < 1e-12);
        assert!(Latency::of(&[]).is_none());
    }

    #[test]
    fn the_bench_record_round_trips_through_its_json() {
        let stage = |name: &str, seconds, calls| StageTime {
            name: name.into(),
            seconds,
            calls,
        };
        let report = BenchReport {
            sequence: PathBuf::from("seq"),
            method: "dynapix".into(),
            schedule: "online".into(),
            frames: 30,
            tracked: 29,
            width: 640,
            height: 480,
            threads: 2,
            wall_seconds: 12.5,
            cpu_seconds: Some(24.25),
            peak_rss_mib: None,
            fps: 2.4,
            latency: Latency::of(&[1.0, 2.0, 30.0]),
            profile: Profile {
                phases: vec![stage("slam pass", 3.5, 1)],
                stages: vec![stage("flow", 1.25, 60), stage("orb", 0.5, 30)],
            },
            ate_rmse_m: Some(0.0125),
            motionless_floor_m: None,
            config: serde_json::json!({"method": "dynapix", "passes": {"weighted": 1}}),
            repeat_wall_seconds: vec![12.5, 13.0],
            build: "release".into(),
        };
        let text = serde_json::to_string_pretty(&report).unwrap();
        let back: BenchReport = serde_json::from_str(&text).unwrap();
        assert_eq!(back, report);
        // An absent value is written as `null`, as the report always had it.
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert!(v["motionless_floor_m"].is_null());
        assert!(v["peak_rss_mib"].is_null());
        assert_eq!(v["profile"]["stages"][0]["calls"], 60);
    }
}
