//! File formats and dataset layouts for dynapix: TUM RGB-D lists and association, the
//! DynaPix and GRADE folder layouts, ORB-SLAM2 settings, trajectories and probability maps.
//! Every parser reports errors with the file and line; every writer is atomic.
//!
//! Map of the crate:
//! - [`trajectory`]: [`Trajectory`] (TUM and KITTI read/write, SLERP interpolation) and the
//!   per-frame status file ([`FrameStatus`]).
//! - [`tum`]: `rgb.txt`/`depth.txt` lists, [`associate`] (exactly like `associate.py`),
//!   4-column association files.
//! - [`images`]: rgb, depth (metres), masks, probability maps (reference 16-bit PNG and
//!   lossless PFM).
//! - [`settings`]: ORB-SLAM2 settings YAML, presets `tum1 tum2 tum3 grade`, the camera of a
//!   sequence folder.
//! - [`sequence`]: [`Sequence`] over the TUM, DynaPix and GRADE layouts, [`FrameData`],
//!   and [`SequenceWriter`] for the DynaPix layout.
//! - [`weights`]: [`MotionProbability`] P and [`StaticWeights`] w = 1 − P as distinct types,
//!   with the one 16-bit codec of the reference `prob/*.png` files.
//! - [`atomic`]: [`write_atomic`] (temporary file + rename) for any other writer.

#![warn(missing_docs)]

pub mod atomic;
pub mod error;
pub mod images;
pub mod sequence;
pub mod settings;
mod text;
pub mod trajectory;
pub mod tum;
pub mod weights;

pub use atomic::write_atomic;
pub use error::{IoError, Result};
pub use images::{DepthImage, Gray16Image, ProbMap};
pub use sequence::{
    FrameData, FrameInfo, FrameList, Layout, Pairing, Sequence, SequenceOptions, SequenceWriter,
};
pub use settings::{OrbSettings, Settings};
pub use trajectory::{FrameStatus, StampedPose, StampedStatus, Trajectory};
pub use tum::{Association, ListEntry, associate};
pub use weights::{MotionProbability, StaticWeights, WeightImage};
