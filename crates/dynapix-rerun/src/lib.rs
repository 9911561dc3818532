//! Watch a dynapix run in the [Rerun](https://rerun.io) viewer: [`RerunObserver`] implements
//! the library's [`dynapix::RunObserver`] with the `rerun` crate and logs, on one timeline per
//! pass (`pass1`, `pass2`, …, the frame index):
//!
//! - `world/camera` (pose) and `world/camera/image` (pinhole frustum with the colour image),
//!   `world/camera/image/motion` (P as a segmentation image of 9 levels of P, drawn as a red
//!   layer whose opacity grows with P, transparent at P ≈ 0) and
//!   `world/camera/image/keypoints` (green: used, orange: down-weighted, red: refused);
//! - `world/trajectory/estimate` and, when the sequence has ground truth,
//!   `world/trajectory/ground_truth` aligned to the estimate so far (rigid, like the ATE);
//! - `world/map/points` (static map points, green → red as their weight falls),
//!   `world/map/removed` (points removed as moving), `world/map/keyframes`;
//! - `depth` (the depth image), `plots/*` (tracking state, tracked map points, map size,
//!   ATE so far, mean P) and `timings/*` (stage milliseconds), `events` (keyframes, loops,
//!   losses, passes).
//!
//! The images (colour JPEG, P, depth) are logged in the run's last pass only, whose
//! trajectory is the result ([`dynapix::PassInfo::last`]); the earlier passes of an offline
//! DynaPix run log everything else. [`RerunParams`] can log them in every pass, or every k-th
//! frame only. Map points, removed points and trajectories are logged every few frames and
//! at keyframes. What a recording costs a 640×480 run is measured in BENCHMARKS.md.
//!
//! A layout (3D view, image with P and keypoints, depth, plots, events) is sent with the
//! recording ([`layout`]).
//!
//! ## No usage analytics
//!
//! The crate is built without Rerun's `analytics` feature (`default-features = false`,
//! features `sdk` and `rrd`): the SDK records no usage event, and nothing leaves the machine
//! except to the viewer or file the caller names. The crate `re_analytics` is still in the
//! dependency tree (`cargo tree -p dynapix-rerun -i re_analytics`): `rerun` always depends on
//! `re_redap_client` (the data-platform client), which depends on `re_auth` with its `oauth`
//! feature, which depends on `re_analytics`; no feature of `rerun` 0.36.3 removes that edge.
//! It is inert here: its only callers in this tree are `re_auth`'s log-in and credential
//! functions, called only by the `rerun` crate's command-line commands (feature `run`, not
//! enabled); neither the SDK's logging nor saving nor `re_grpc_client` calls them, so the
//! linker drops the code (the built `dynapix` binary does not contain the analytics
//! endpoint's address). The viewer is another program: scripts run `rerun analytics
//! disable` before starting it (`scripts/rerun-screenshot.sh`), and `--rerun`'s help says to.
//!
//! [`read::read_rrd`] decodes a saved `.rrd` back (entity path → rows), for tests and
//! checks.

#![deny(missing_docs)]
#![forbid(unsafe_code)]

mod colors;
mod encode;
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
