//! The one online driver of a sequence folder: frames read on a reader thread (as a camera
//! driver delivers them) and pushed one at a time through [`OnlineDynaPix`], with the
//! DynaPix+ masks, bad frames skipped when the input skips them, and the statistics of the
//! run. `dynapix run --online`, `dynapix bench --online` and the `online_rgbd` example all
//! use it.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use dynapix_io::{FrameStatus, StampedPose, StampedStatus, Trajectory};

use crate::config::Config;
use crate::error::{BadFrame, Error, Result};
use crate::input::Input;
use crate::observe::{PassInfo, RunObserver};
use crate::online::{FrameResult, OnlineDynaPix, RgbdFrame};
use crate::progress::{Progress, Task};
use crate::record::RunRecord;

/// Frames decoded ahead of the online system by [`run_online`].
pub const FRAMES_AHEAD: usize = 2;

/// What an online run over a sequence produced (also when it stopped part-way: what was
/// reported up to the frame that stopped it).
#[derive(Clone, Debug, Default)]
pub struct OnlineRun {
    /// Every processed frame's result, in frame order.
    pub results: Vec<FrameResult>,
    /// Frames skipped because their files cannot be used, in order.
    pub skipped: Vec<BadFrame>,
    /// The system's final estimate of every tracked frame (after the last local mapping).
    pub refined: Trajectory,
    /// Keyframes in the final map.
    pub keyframes: usize,
    /// Map points in the final map.
    pub map_points: usize,
    /// The latency in frames.
    pub lookahead: usize,
    /// Milliseconds spent in each push (the processing of the frame it releases).
    pub push_ms: Vec<f64>,
    /// Milliseconds spent reading each frame (on the reader thread).
    pub load_ms: Vec<f64>,
    /// Wall-clock seconds of the run.
    pub wall_seconds: f64,
}

impl OnlineRun {
    /// The poses as reported when each frame was processed (tracked frames).
    pub fn reported(&self) -> Trajectory {
        Trajectory::new(
            self.results
                .iter()
                .filter_map(|r| r.pose_wc.map(|p| StampedPose::new(r.t, p)))
                .collect(),
        )
    }

    /// Every frame's status, skipped frames lost, in time order.
    pub fn status(&self) -> Vec<StampedStatus> {
        let mut status: Vec<StampedStatus> = self
            .results
            .iter()
            .map(|r| StampedStatus {
                t: r.t,
                status: r.status,
            })
            .chain(self.skipped.iter().map(|b| StampedStatus {
                t: b.timestamp,
                status: FrameStatus::Lost,
            }))
            .collect();
        status.sort_by(|a, b| a.t.total_cmp(&b.t));
        status
    }

    /// Writes the poses reported so far (`trajectory.txt`, TUM) and every frame's status
    /// (`status.txt`, skipped frames lost) into `dir`; returns both.
    pub fn write_poses(&self, dir: &Path) -> Result<(Trajectory, Vec<StampedStatus>)> {
        let reported = self.reported();
        reported.write_tum(dir.join("trajectory.txt"))?;
        let status = self.status();
        dynapix_io::trajectory::write_status(dir.join("status.txt"), &status)?;
        Ok((reported, status))
    }

    /// Frames tracked.
    pub fn tracked(&self) -> usize {
        self.results
            .iter()
            .filter(|r| r.status == FrameStatus::Tracked)
            .count()
    }
}

impl Input {
    /// The DynaPix+ mask folder of an online run of `config` on this input: `masks`, else
    /// `<sequence>/mask`; `None` when the method uses no masks. A folder that does not exist
    /// is an error naming it.
    pub fn mask_folder(&self, config: &Config, masks: Option<&Path>) -> Result<Option<PathBuf>> {
        if !config.method.needs_masks() {
            return Ok(None);
        }
        let d = masks.map_or_else(|| self.sequence.dir.join("mask"), Path::to_path_buf);
        if !d.is_dir() {
            return Err(Error::Input(format!(
                "dynapix+ needs semantic masks: {} is not a folder (pass --masks DIR)",
                d.display()
            )));
        }
        Ok(Some(d))
    }
}

/// Frame `i` of `input` as it arrives, with its mask from `masks` (named like the rgb image).
fn load_frame(input: &Input, i: usize, masks: Option<&Path>) -> Result<RgbdFrame> {
    let (rgb, depth) = input.load_rgbd(i)?;
    let mask = match masks {
        None => None,
        Some(d) => {
            let name = input
                .sequence
                .rgb_name(i)
                .ok_or_else(|| Error::Input(format!("frame {i}: no file name")))?;
            Some(dynapix_io::images::read_mask(d.join(name))?)
        }
    };
    Ok(RgbdFrame {
        t: input.sequence.frames[i].t,
        rgb,
        depth,
        mask,
    })
}

/// Pushes every frame of `input` through a new [`OnlineDynaPix`] of `config`, reading them
/// on a reader thread up to `FRAMES_AHEAD` (2) frames ahead; a frame already read is shown to
/// the push before it ([`OnlineDynaPix::push_before`], the same results). DynaPix+ reads its
/// masks from `masks` ([`Input::mask_folder`]). A frame whose files cannot be used is skipped
/// (listed in [`OnlineRun::skipped`]) when `input` skips bad frames, else it stops the run.
/// `each` gets every frame's result as soon as it is known. An `observer` is shown the run's
/// start ([`RunObserver::pass_begins`], pass 1), every frame and its end
/// ([`RunObserver::online_ends`]); the results are the same with and without one.
///
/// Returns what was produced and, when the run stopped part-way, why (what was produced is
/// then up to the frame before).
pub fn run_online(
    input: &Input,
    config: &Config,
    masks: Option<&Path>,
    progress: &dyn Progress,
    each: &mut dyn FnMut(&FrameResult),
    observer: Option<Arc<dyn RunObserver>>,
) -> (OnlineRun, Result<()>) {
    let mut run = OnlineRun::default();
    let masks = match input.mask_folder(config, masks) {
        Ok(m) => m,
        Err(e) => return (run, Err(e)),
    };
    let mut online = match OnlineDynaPix::new(&input.camera, config) {
        Ok(o) => o,
        Err(e) => return (run, Err(e)),
    };
    run.lookahead = online.lookahead();
    let label = format!("{} online", config.method);
    let pinhole = input.camera.pinhole();
    let info = PassInfo {
        number: 1,
        label: &label,
        frames: input.len(),
        camera: &pinhole,
        ground_truth: input.sequence.groundtruth.as_ref(),
        weighted: config.method.terms().is_some(),
        last: true,
    };
    if let Some(o) = &observer {
        online.set_observer(o.clone());
        o.pass_begins(&info);
    }
    let task = Task::begin(progress, &label, input.len());
    let started = Instant::now();
    let load = |i: usize| {
        let t0 = Instant::now();
        let frame = load_frame(input, i, masks.as_deref());
        (frame, t0.elapsed().as_secs_f64() * 1e3)
    };
    let streamed = input.stream_with_next(FRAMES_AHEAD, load, |_, (frame, ms), next| {
        run.load_ms.push(ms);
        let next = next.and_then(|(n, _)| n.as_ref().ok());
        let frame = match frame {
            Ok(frame) => frame,
            Err(Error::Frame(bad)) if input.skip_bad_frames => {
                tracing::warn!("skipped {bad}");
                run.skipped.push(bad);
                task.step("");
                return Ok(());
            }
            Err(e) => return Err(e),
        };
        let t0 = Instant::now();
        let pushed = online.push_before(frame, next)?;
        run.push_ms.push(t0.elapsed().as_secs_f64() * 1e3);
        if let Some(r) = pushed {
            each(&r);
            run.results.push(r);
        }
        task.step("");
        Ok(())
    });
    let finished = streamed.and_then(|()| {
        for r in online.finish()? {
            each(&r);
            run.results.push(r);
        }
        Ok(())
    });
    drop(task);
    run.wall_seconds = started.elapsed().as_secs_f64();
    let system = online.system();
    run.refined = Trajectory::new(
        system
            .trajectory()
            .into_iter()
            .filter_map(|e| e.pose_wc.map(|p| StampedPose::new(e.timestamp, p)))
            .collect(),
    );
    run.keyframes = system.map().num_keyframes();
    run.map_points = system.map().num_points();
    if let Some(o) = &observer {
        o.online_ends(&info, &run.refined);
    }
    (run, finished)
}

impl RunRecord {
    /// The record of an online run of `config` over `input` (with DynaPix+ `masks`), before
    /// any frame.
    pub fn online(input: &Input, config: &Config, masks: Option<&Path>) -> Self {
        let outputs = [
            (
                "trajectory.txt",
                "poses as reported when each frame was processed",
            ),
            (
                "trajectory_refined.txt",
                "the system's final estimate of every tracked frame",
            ),
        ];
        Self {
            schedule: Some("online".into()),
            masks: masks.map(Path::to_path_buf),
            outputs: Some(
                outputs
                    .iter()
                    .map(|(k, v)| (k.to_string(), v.to_string()))
                    .collect(),
            ),
            ..RunRecord::new(input.record(), config)
        }
    }
}
