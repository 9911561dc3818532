//! A pose-free motion cue: how badly a pixel fits the dominant rigid motion between a frame
//! and its neighbours (new; not part of the paper or the reference code).
//!
//! The moving term of DynaPix needs camera poses, and the first SLAM pass on a crowded real
//! sequence (Bonn `crowd`) follows the people. This cue needs none:
//! 1. [`correspondences`]: on a grid, pixels of frame i with depth are matched to frame j by
//!    dense optical flow i → j and lifted to 3-D in both cameras (through the undistorted
//!    rays of [`PixelRays`](dynapix_geometry::PixelRays), so lens distortion is handled).
//!    The target point sits on the ray of the rounded target pixel plus the linear sub-pixel
//!    offset, at the depth of the rounded target pixel.
//! 2. [`fit_rigid_motion`]: RANSAC (seeded 3-point samples, Kabsch/Horn hypotheses) for the
//!    rigid motion `B ≈ R·A + t` with the most correspondences whose normalised squared
//!    residual ([`residual_squared`]: re-projection error in pixels over `σ_px`, depth error
//!    over the Kinect-like `σ_z = a·z² + b`) is below `chi2`, then a few rounds of refitting
//!    on the inliers.
//! 3. [`dense_residual`]: the residual `r` of every pixel under the fitted motion.
//! 4. [`rigidity_from_residuals`]: per pixel the smallest residual over the neighbours that
//!    see it (an occlusion in one neighbour does not make a pixel look moving), mapped to
//!    `P = clamp((r − r0)/(r1 − r0), 0, 1)`; pixels without a residual get P = 0.
//!
//! [`rigidity_probability`] runs all four steps for one frame with DIS flow.
//!
//! Limits: the dominant motion is the one with the most correspondences, so where movers
//! cover more of the pixels with depth than the static scene does, it can be a mover's and
//! the map then marks the static scene as moving. The defaults (σ_px = 1 px, r0 = 3, r1 = 8)
//! are meant for 640×480: at half that resolution a one-frame motion gives half the pixel
//! residual. Motion along the viewing direction only counts through `σ_z`, which grows with
//! the squared depth.
//!
//! Everything is deterministic: the samples come from a seeded ChaCha8 generator, and the
//! parallel parts (hypothesis scoring, rows of the dense residual, neighbours) are reduced in
//! a fixed order.

mod fit;
#[cfg(test)]
mod fixtures;
mod pair;
mod params;
mod prior;
mod probability;
mod residual;
mod reverse;

pub use fit::{RANSAC_BATCH, adaptive_samples, fit_rigid_motion};
pub use pair::{correspondences, residual_squared};
pub use params::{RigidityParams, finest_scale_at_working_width};
pub use prior::{PriorChoice, choose_with_prior, fit_from_prior, motions_agree};
pub use probability::{
    PairResiduals, camera_rays, pair_residuals, pair_residuals_with_prior, rigidity_from_pairs,
    rigidity_from_residuals, rigidity_probability, rigidity_probability_with,
    rigidity_probability_with_priors,
};
pub use residual::dense_residual;
pub use reverse::reverse_flow;

use dynapix_geometry::Se3;
use image::GrayImage;
use nalgebra::Point3;

use crate::FloatImage;

/// Why no rigid motion could be fitted between two frames.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RigidFitError {
    /// Too few pixels have depth and a flow target with depth.
    #[error("too few correspondences: {got} (need {needed})")]
    TooFewCorrespondences {
        /// Correspondences found.
        got: usize,
        /// Correspondences needed ([`RigidityParams::min_correspondences`]).
        needed: usize,
    },
    /// Every sample was degenerate (points nearly collinear), so there was no hypothesis.
    #[error("no non-degenerate sample among {samples} RANSAC samples")]
    NoHypothesis {
        /// Samples drawn.
        samples: usize,
    },
    /// The best motion explains too few correspondences to be the static scene's: movers
    /// may dominate the view, so the pair gives no evidence.
    #[error(
        "ambiguous dominant motion: {fraction:.2} of the correspondences are inliers (need {needed:.2})"
    )]
    Ambiguous {
        /// Inlier fraction of the best motion.
        fraction: f64,
        /// [`RigidityParams::min_inlier_fraction`].
        needed: f64,
    },
}

/// Matched 3-D points of frame i and its neighbour j, each in its own camera frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Correspondences {
    /// Points `A` in camera i.
    pub source: Vec<Point3<f64>>,
    /// Points `B` in camera j.
    pub target: Vec<Point3<f64>>,
    /// Pixel `(x, y)` of frame i of each pair.
    pub pixels: Vec<[u32; 2]>,
}

impl Correspondences {
    /// Number of pairs.
    pub fn len(&self) -> usize {
        self.source.len()
    }

    /// True when there is no pair.
    pub fn is_empty(&self) -> bool {
        self.source.is_empty()
    }
}

/// The rigid motion fitted between frame i and its neighbour j.
#[derive(Clone, Debug, PartialEq)]
pub struct RigidFit {
    /// Maps camera-i points into camera j (`B ≈ motion · A`, i.e. `T_ji`).
    pub motion: Se3,
    /// Correspondences that are inliers of the final motion.
    pub inliers: usize,
    /// Correspondences the fit saw.
    pub correspondences: usize,
    /// RANSAC samples drawn (degenerate ones included).
    pub samples: usize,
}

impl RigidFit {
    /// Fraction of the correspondences that are inliers of the final motion.
    pub fn inlier_fraction(&self) -> f64 {
        if self.correspondences == 0 {
            0.0
        } else {
            self.inliers as f64 / self.correspondences as f64
        }
    }
}

/// The two images of a frame the rigidity cue needs.
#[derive(Clone, Copy, Debug)]
pub struct RigidFrame<'a> {
    /// Grey image for the optical flow (e.g. [`crate::moving::to_gray`] of the colour image).
    pub gray: &'a GrayImage,
    /// Depth in metres (0 = invalid).
    pub depth: &'a FloatImage,
    /// Frame offset from the current frame (0 for the current frame itself): neighbours at
    /// the same distance |offset| form one baseline (see [`rigidity_from_residuals`]).
    pub offset: i64,
}

/// The rigidity cue of one frame.
#[derive(Clone, Debug)]
pub struct RigidityMaps {
    /// Motion probability P ∈ [0, 1] (0 where no neighbour gives a residual).
    pub p: FloatImage,
    /// Smallest normalised residual over the neighbours (NaN where none gives one; infinite
    /// where the fitted motion puts the point behind the camera).
    pub residual: FloatImage,
    /// The fit of each neighbour, in the order given.
    pub fits: Vec<Result<RigidFit, RigidFitError>>,
}
