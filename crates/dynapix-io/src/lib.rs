//! File formats and dataset layouts for dynapix: TUM RGB-D lists and association, the
//! DynaPix and GRADE folder layouts, ORB-SLAM2 settings, trajectories and probability maps.
//! Every parser reports errors with the file and line; every writer is atomic.

pub mod atomic;
pub mod error;
pub mod images;
pub mod sequence;
pub mod settings;
mod text;
pub mod trajectory;
pub mod tum;

pub use atomic::write_atomic;
pub use error::{IoError, Result};
pub use images::{DepthImage, Gray16Image, ProbMap};
pub use sequence::{FrameData, FrameInfo, Layout, Sequence, SequenceOptions};
pub use settings::{OrbSettings, Settings};
pub use trajectory::{FrameStatus, StampedPose, StampedStatus, Trajectory};
pub use tum::{Association, ListEntry, associate};
