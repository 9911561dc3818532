//! DynaPix dynamic RGB-D SLAM (Xu, Bonetto, Ahmad, GCPR 2024) as a library: the facade over
//! `dynapix-io` (sequences, files), `dynapix-motion` (per-pixel motion probability) and
//! `dynapix-slam` (the ORB-SLAM2-class backend weighted by w = 1 − P).
//!
//! - [`Config`]: the one configuration (method, paper/reference [`Mode`], sequence reading,
//!   motion maps and their [`Cues`], SLAM, passes, online schedule), serde with the paper's
//!   defaults, loadable from JSON or YAML.
//! - the cues beyond the paper's terms on a sequence (pose-free rigidity maps, cached once per
//!   sequence; the geometric cue's inputs), switched by [`Cues`].
//! - [`OfflineRunner`]: sequence → first pass → motion maps → weighted pass(es), in process
//!   and in memory (the maps in their stored 16-bit form), with an optional cache
//!   keyed by everything that determines the maps (written as a side effect, reused when the
//!   key matches; without one nothing is written) and a provenance record of every input
//!   ([`RunRecord`], `run.json`; a map folder's [`MotionRecord`], `motion.json`).
//! - one combiner turns a frame's cues into P (offline and online).
//! - [`run_online`]: the one online driver of a sequence folder (frames read ahead, DynaPix+
//!   masks, bad frames, statistics), used by `dynapix run --online` and `dynapix bench`.
//! - [`OnlineDynaPix`]: `push(frame) → FrameResult`, motion from past frames (and an optional
//!   fixed lookahead), a background kept from past keyframes, memory bounded by a window.
//! - [`bench`](mod@bench): one measured run, stage by stage (`dynapix bench`).
//! - [`motion_maps`] and [`SlamPass`]: the single stages the `motion` and `slam` tools run
//!   alone (a sequence's maps into its `prob/` folder; one ORB-SLAM2 pass with map load/save).
//! - [`evaluate`] and [`synthetic`]: ATE/RPE of trajectories; synthetic sequences.
//! - [`MotionProbability`] and [`StaticWeights`]: P and w = 1 − P as distinct types.
//!
//! Streaming a sequence folder through the online mode:
//!
//! ```no_run
//! use dynapix::{CameraChoice, Config, Input, OnlineDynaPix, RgbdFrame};
//!
//! # fn main() -> dynapix::Result<()> {
//! let config = Config::default(); // DynaPix, paper mode
//! let input = Input::open("walking_xyz", &config.sequence, &CameraChoice::Sequence)?;
//! let mut online = OnlineDynaPix::new(&input.camera, &config)?;
//! for i in 0..input.len() {
//!     let (rgb, depth) = input.load_rgbd(i)?;
//!     let t = input.sequence.frames[i].t;
//!     if let Some(r) = online.push(RgbdFrame::new(t, rgb, depth))? {
//!         if let Some(p) = r.pose_wc {
//!             println!("{:.6} {:?}", r.t, p.translation.vector);
//!         }
//!     }
//! }
//! online.finish()?;
//! # Ok(())
//! # }
//! ```

//! P and w are different types, so one cannot stand in for the other:
//!
//! ```compile_fail
//! fn track(weights: &dynapix::StaticWeights) {}
//! let p = dynapix::MotionProbability::new(image::ImageBuffer::new(4, 4));
//! track(&p); // a probability is not a weight: convert with `p.static_weights()`
//! ```
//!
//! ```
//! let p = dynapix::MotionProbability::new(image::ImageBuffer::from_pixel(4, 4, image::Luma([0.25])));
//! let w = p.static_weights(); // w = 1 − P, quantised like the map files
//! assert_eq!(w.as_image().get_pixel(0, 0)[0], 0.75);
//! ```

#![deny(missing_docs)]

pub mod bench;
pub mod evaluate;
pub mod synthetic;

mod combine;
mod config;
mod cues;
mod error;
mod hash;
mod input;
mod maps;
mod method;
mod motion_tool;
mod observe;
mod offline;
mod online;
mod pass;
mod poses;
mod profile;
mod progress;
mod record;
mod slam;
mod slam_tool;
mod spill;
mod store;
mod stream;
#[cfg(test)]
mod tests;

pub use config::{
    BackgroundSource, Config, Cue, Cues, DynaPixConfig, FirstPass, FlowPreset, MotionConfig,
    OnlineConfig, PassConfig, PoseSource, SequenceConfig, SlamConfig, VocabularyChoice,
};
pub use dynapix_io::{
    FrameList, FrameStatus, IoError, MotionProbability, OutputFolder, Pairing, Sequence, Settings,
    StampedPose, StampedStatus, StaticWeights, Trajectory,
};
/// The per-map-point probability update rule of the SLAM weighting (EMA, max, latest).
pub use dynapix_slam::weighting::ProbUpdate;
pub use error::{BadFrame, Error, Result};
pub use input::{Camera, CameraChoice, CameraPreset, CameraSource, Input};
pub use method::{Method, Mode};
pub use motion_tool::{MotionOptions, MotionOutput, motion_maps};
pub use observe::{
    FrameView, KeypointUse, KeypointView, MapPointView, PassInfo, RunObserver, StageTimes,
};
pub use offline::{FirstPassResult, OfflineOutput, OfflineRunner, RunOptions};
pub use online::{FrameResult, OnlineDynaPix, RgbdFrame};
pub use pass::{FrameTiming, PassOutput, PassStats};
pub use progress::{Progress, ProgressEvent};
pub use record::{
    CameraRecord, FileFingerprint, GroundTruthRecord, MapsStatus, MotionRecord, OrbRecord,
    PassRecord, RunRecord, SequenceRecord, SlamRecord, WeightingRecord,
};
pub use slam::MapFileStats;
pub use slam_tool::SlamPass;
pub use store::MapSet;
pub use stream::{OnlineRun, run_online};
