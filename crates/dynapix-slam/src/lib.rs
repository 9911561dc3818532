//! ORB-SLAM2-class RGB-D SLAM with DynaPix per-keypoint weights: ORB features, matching,
//! bag-of-words vocabulary, frames, the map, tracking and local mapping.
//! No file access: inputs are images and parameters, outputs are poses and the map.

pub mod dynapix;
pub mod features;
pub mod frame;
pub mod local_mapping;
pub mod loop_closing;
pub mod map;
pub mod matcher;
pub mod orb;
pub mod persist;
pub mod system;
pub mod tracking;
mod validate;
pub mod vocab;
