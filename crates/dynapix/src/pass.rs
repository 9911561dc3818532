//! What a SLAM pass leaves (trajectory, per-frame status and timing, keyframes, closed
//! loops, counters) and the frames it skipped: plain data, so the errors of a pass can carry
//! a partial output without depending on the pass machinery.

use std::path::PathBuf;

use dynapix_io::{FrameStatus, StampedStatus, Trajectory};
use dynapix_slam::loop_closing::LoopEvent;
use serde::{Deserialize, Serialize};

/// A frame of a sequence whose files cannot be used: a missing, truncated or undecodable rgb
/// or depth image, rgb and depth of different sizes, or a size other than the camera's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BadFrame {
    /// Index of the frame in the sequence (0-based).
    pub index: usize,
    /// Frame time (s).
    pub timestamp: f64,
    /// The file at fault.
    pub file: PathBuf,
    /// What is wrong with it.
    pub reason: String,
}

impl std::fmt::Display for BadFrame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "frame {} (t = {:.6}): {}: {}",
            self.index,
            self.timestamp,
            self.file.display(),
            self.reason
        )
    }
}

/// Step times of one frame, in milliseconds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FrameTiming {
    /// Frame index.
    pub index: u64,
    /// Frame time (s).
    pub timestamp: f64,
    /// Feature extraction.
    pub extract_ms: f64,
    /// Tracking without extraction.
    pub track_ms: f64,
    /// Local mapping.
    pub mapping_ms: f64,
    /// Loop closing.
    pub loop_ms: f64,
    /// A keyframe was created.
    pub keyframe: bool,
    /// State after the frame.
    #[serde(serialize_with = "status_word")]
    pub status: FrameStatus,
}

fn status_word<S: serde::Serializer>(
    s: &FrameStatus,
    ser: S,
) -> std::result::Result<S::Ok, S::Error> {
    ser.serialize_str(s.as_str())
}

/// Counters of a pass.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PassStats {
    /// Frames processed.
    pub frames: usize,
    /// Frames tracked.
    pub tracked: usize,
    /// Keyframes in the final map.
    pub keyframes: usize,
    /// Map points in the final map.
    pub map_points: usize,
    /// Loops closed.
    pub loops_closed: usize,
    /// Wall-clock seconds of the pass.
    pub seconds: f64,
    /// Frames that ran unweighted because their probability map was missing.
    pub frames_without_prob_map: usize,
    /// Frames skipped because their files cannot be used (recorded lost).
    pub frames_skipped: usize,
}

/// What a pass leaves.
#[derive(Clone, Debug)]
pub struct PassOutput {
    /// Tracked frames with their current (BA-refined) camera-to-world pose.
    pub trajectory: Trajectory,
    /// Per frame: tracked / lost / not initialised.
    pub status: Vec<StampedStatus>,
    /// Keyframes in the final map, by creation.
    pub keyframes: Trajectory,
    /// Loops closed, in order.
    pub loops: Vec<LoopEvent>,
    /// Per-frame step times.
    pub timings: Vec<FrameTiming>,
    /// Counters.
    pub stats: PassStats,
    /// Frames skipped because their files cannot be used, in order.
    pub skipped: Vec<BadFrame>,
}

/// `traj` as it reads back from its TUM text (what a pass leaves in `trajectory.txt`).
pub(crate) fn as_written(traj: &Trajectory) -> Result<Trajectory, dynapix_io::IoError> {
    Trajectory::parse_tum(&traj.to_tum_string(), std::path::Path::new("<trajectory>"))
}

impl PassOutput {
    /// The trajectory as it reads back from its TUM text (what the pass leaves in
    /// `trajectory.txt`).
    pub fn written_trajectory(&self) -> Result<Trajectory, dynapix_io::IoError> {
        as_written(&self.trajectory)
    }
}

/// The first pass's trajectory (as its `trajectory.txt` reads back) and where it came from.
#[derive(Clone, Debug)]
pub struct FirstPassResult {
    /// The trajectory.
    pub trajectory: Trajectory,
    /// The full pass output when it was run now.
    pub output: Option<PassOutput>,
    /// Provenance (`computed`, `cache`, `given`) for the run record.
    pub record: serde_json::Value,
}
