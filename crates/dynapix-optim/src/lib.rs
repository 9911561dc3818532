//! Solvers for dynapix SLAM: weighted pose-only optimisation (tracking) and weighted bundle
//! adjustment with a Schur complement (local and global BA), on flat problems that know
//! nothing of the map. Every observation carries a DynaPix weight w = 1 − P.
//!
//! Residuals follow ORB-SLAM2's RGB-D "virtual stereo" model: an observation with depth has a
//! 3-vector residual `(u, v, uR) − (fx·X/Z + cx, fy·Y/Z + cy, fx·X/Z + cx − bf/Z)`, one
//! without depth a 2-vector residual (mono edge). Poses are `T_cw` (world → camera).

pub mod ba;
mod edge;
pub mod pose;
pub mod problem;

pub use ba::bundle_adjust;
pub use pose::optimize_pose;
pub use problem::*;
