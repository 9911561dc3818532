//! Watch a dynapix run in the [Rerun](https://rerun.io) viewer: [`RerunObserver`] implements
//! the library's [`dynapix::RunObserver`] with the `rerun` crate and logs, on one timeline per
//! pass (`pass1`, `pass2`, …, the frame index):
//!
//! - `world/camera` (pose) and `world/camera/image` (pinhole frustum with the colour image),
//!   `world/camera/image/motion` (P as a red overlay, alpha ∝ P) and
//!   `world/camera/image/keypoints` (green: used, orange: down-weighted, red: refused);
//! - `world/trajectory/estimate` and, when the sequence has ground truth,
//!   `world/trajectory/ground_truth` aligned to the estimate so far (rigid, like the ATE);
//! - `world/map/points` (static map points, green → red as their weight falls),
//!   `world/map/removed` (points removed as moving), `world/map/keyframes`;
//! - `depth` (the depth image), `plots/*` (tracking state, tracked map points, map size,
//!   ATE so far, mean P) and `timings/*` (stage milliseconds), `events` (keyframes, loops,
//!   losses, passes).
//!
//! A layout (3D view, image with P and keypoints, depth, plots, events) is sent with the
//! recording ([`layout`]). The crate is built without Rerun's `analytics` feature: nothing
//! leaves the machine except to the viewer the caller names.
//!
//! [`read::read_rrd`] decodes a saved `.rrd` back (entity path → rows), for tests and
//! checks.

#![deny(missing_docs)]
#![forbid(unsafe_code)]

mod colors;
pub mod layout;
mod observer;
pub mod read;

pub use observer::{RerunObserver, RerunParams, Target};
/// The `rerun` crate this one logs with (=0.36.3), for callers that add their own data.
pub use rerun;

/// What can go wrong when opening or closing a recording.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The recording stream could not be made (file not writable, no viewer to spawn).
    #[error("cannot open the Rerun recording ({target}): {source}")]
    Open {
        /// Where the recording was to go.
        target: String,
        /// Rerun's error.
        #[source]
        source: rerun::RecordingStreamError,
    },
    /// The recording could not be flushed to its sink.
    #[error("cannot finish the Rerun recording ({target}): {reason}")]
    Flush {
        /// Where the recording goes.
        target: String,
        /// Rerun's error.
        reason: String,
    },
    /// A recording file could not be read back.
    #[error("cannot read the Rerun recording {path}: {reason}")]
    Read {
        /// The file.
        path: std::path::PathBuf,
        /// Why.
        reason: String,
    },
}

/// This crate's results.
pub type Result<T> = std::result::Result<T, Error>;
