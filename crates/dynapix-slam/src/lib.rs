//! ORB-SLAM2-class RGB-D SLAM with DynaPix per-keypoint weights: frames, the map, matching,
//! tracking, local mapping, loop closing and the [`System`] that runs them. ORB extraction and
//! the bag-of-words vocabulary come from `dynapix-features` (re-exported as [`orb`] and
//! [`vocab`]). No file access: inputs are images and parameters, outputs are poses and the map.
//!
//! Layers, each importing only from the ones above it (`python3 scripts/check-cycles.py`
//! finds no cycle):
//! 1. leaves: [`ids`], [`pose`], [`camera`], [`features`], [`weighting::params`];
//! 2. [`frame`], [`feature_stage`]; 3. [`map`]; 4. [`weighting::apply`], [`matcher`];
//! 5. the stages: [`tracking`], [`local_mapping`], [`loop_closing`]; [`persist`];
//! 6. [`system`].

pub mod camera;
pub mod feature_stage;
pub mod features;
pub mod frame;
pub mod ids;
pub mod local_mapping;
pub mod loop_closing;
pub mod map;
pub mod matcher;
pub mod persist;
pub mod pose;
pub mod system;
pub mod tracking;
pub mod weighting;

pub use dynapix_features::{orb, vocab};

pub use camera::RgbdCamera;
pub use feature_stage::{FeatureStage, Features};
pub use features::{Descriptor, FeatureExtractor, KeyPoint, ScalePyramid};
pub use frame::{DepthImage, Frame};
pub use ids::{KeyFrameId, MapPointId};
pub use loop_closing::LoopEvent;
pub use map::{Map, MapParams};
pub use system::{FrameInput, FrameResult, ProcessError, System, SystemParams};
pub use tracking::TrackingState;
pub use weighting::{DynaPixParams, ProbUpdate, Weighting};

mod validate;
