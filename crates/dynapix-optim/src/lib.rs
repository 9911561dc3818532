//! Solvers for dynapix SLAM: weighted pose-only optimisation (tracking) and weighted bundle
//! adjustment with a Schur complement (local and global BA), on flat problems that know
//! nothing of the map. Every observation carries a DynaPix weight w = 1 − P. An SE3 pose graph
//! serves loop closing.
//!
//! Residuals follow ORB-SLAM2's RGB-D "virtual stereo" model: an observation with depth has a
//! 3-vector residual `(u, v, uR) − (fx·X/Z + cx, fy·Y/Z + cy, fx·X/Z + cx − bf/Z)`, one
//! without depth a 2-vector residual (mono edge). Poses are `T_cw` (world → camera).

// Index loops over CSR ranges (edges of a point) read clearer than zipped iterators here.
#![allow(clippy::needless_range_loop)]

pub mod ba;
mod edge;
pub mod pose;
pub mod pose_graph;
pub mod problem;
mod validate;

pub use ba::bundle_adjust;
pub use pose::optimize_pose;
pub use pose_graph::{PoseGraphEdge, PoseGraphParams, PoseGraphResult, optimize_pose_graph};
pub use problem::*;
