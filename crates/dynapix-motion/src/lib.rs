//! Per-pixel motion probability of DynaPix (paper §3.1; reference behaviour in spec §1, its
//! defects and fixes in spec §7).
//!
//! The probability of a pixel being on something that currently moves is `P = D ⊙ M`:
//! - [`movable`](mod@movable): the movable term D from the difference between the frame and its static
//!   background (spec §1.3);
//! - [`splat`](mod@splat): forward-splatting view synthesis of a neighbour frame into the current view,
//!   through the lens distortion of the camera when it has one
//!   (spec §1.5);
//! - [`moving`]: the moving term M from static/dynamic flow differencing (spec §1.7);
//! - [`background`]: a static background reconstructed from neighbouring frames (new; replaces
//!   the external inpainting the reference needs, spec §7.2);
//! - [`pipeline`]: one frame end to end and the ablations;
//! - [`static_depth`](mod@static_depth): the static depth of a view from a wide window of frames and the
//!   geometric cue (nearer than the static scene ⇒ not static; new, see the module);
//! - [`rigidity`]: a pose-free motion cue, the residual of each pixel against the dominant
//!   rigid motion to the neighbours found by RANSAC on depth-backed optical flow (new);
//! - [`sequence`]: every frame of a sequence, frames from a [`FrameLoader`], in parallel chunks;
//! - [`metrics`]: ROC-AUC, IoU and PSNR used to measure the maps against synthetic ground truth;
//! - [`noise`]: seeded pose perturbation for robustness experiments.
//!
//! Everything here is pure computation on in-memory images; reading and writing files is the
//! job of `dynapix-io` and the CLI.

pub mod align;
pub mod background;
pub mod combine;
mod gray;
pub mod metrics;
pub mod movable;
pub mod moving;
pub mod noise;
pub mod pipeline;
pub mod rigidity;
pub mod sequence;
pub mod splat;
pub mod static_depth;
mod validate;

#[cfg(test)]
pub(crate) mod testutil;

use image::{ImageBuffer, Luma};
use serde::{Deserialize, Serialize};

pub use background::{Background, ReconstructParams, Source, Statistic, reconstruct_background};
pub use movable::{Movable, MovableParams, movable};

pub use combine::noisy_or;
pub use moving::{FrameImages, MovingParams, Neighbour, moving_term};
pub use pipeline::{MotionMaps, MotionParams, motion_probability};
pub use rigidity::{
    Correspondences, PairResiduals, PriorChoice, RigidFit, RigidFitError, RigidFrame, RigidityMaps,
    RigidityParams, pair_residuals, pair_residuals_with_prior, reverse_flow, rigidity_from_pairs,
    rigidity_probability, rigidity_probability_with, rigidity_probability_with_priors,
};
pub use sequence::{
    Backgrounds, BoxError, FrameLoader, FrameMotion, RgbdImages, SequenceError, SequenceMotion,
    SequenceStats, StaticBackground,
};
pub use splat::{SplatParams, Warped, pixel_rays, splat};
pub use static_depth::{
    DepthView, StaticDepth, StaticDepthParams, WorkingDepth, geometric_frame, geometric_term,
    select_views, static_depth,
};

/// A single-channel `f32` image: depth in metres (0 = invalid) or a probability map.
pub type FloatImage = ImageBuffer<Luma<f32>, Vec<f32>>;

/// Which behaviour to follow where the paper and the reference code disagree.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// The paper's description with the reference's defects fixed (spec §7): guarded robust
    /// min-max, invalid depth skipped in splatting, soft z-buffer, holes masked, low-pass
    /// filter and min-max normalisation of the moving term.
    #[default]
    Paper,
    /// What the reference code does, constant by constant (spec §1).
    Reference,
}

/// Which of the two reference scripts' constants to use (spec §1.9).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Variant {
    /// `motion_tum.py`: neighbours ±1, robust-min excludes values ≤ 5, flow clip [1, 4] px.
    #[default]
    Tum,
    /// `motion_grade.py`: neighbours ±2, robust-min excludes zeros, flow clip [0.5, 2.5] px.
    Grade,
}

/// Errors of the motion-probability computation.
#[derive(Debug, thiserror::Error)]
pub enum MotionError {
    /// Two inputs that must have the same size do not.
    #[error("size mismatch for {what}: expected {expected:?}, got {got:?}")]
    SizeMismatch {
        /// Which input is wrong.
        what: String,
        /// Expected `(width, height)`.
        expected: (u32, u32),
        /// Actual `(width, height)`.
        got: (u32, u32),
    },
    /// A parameter is out of its valid range.
    #[error("invalid parameter {name}: {message}")]
    InvalidParam {
        /// Parameter name.
        name: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The optical flow failed.
    #[error("optical flow: {0}")]
    Flow(#[from] dynapix_flow::FlowError),
    /// No rigid motion could be fitted between two frames ([`rigidity::fit_rigid_motion`]).
    #[error("rigid motion fit: {0}")]
    RigidFit(#[from] rigidity::RigidFitError),
}

/// A rigid motion unpacked into plain numbers for the branch-free kernels (static-depth
/// splat, RANSAC count, dense residual): [`RigidRows::apply`] computes `R·p + t` with the
/// same operations in the same order as nalgebra's matrix product (column by column, then
/// `+ t`), so the kernels give the bits of the code they replaced.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RigidRows {
    r: [[f64; 3]; 3],
    t: [f64; 3],
}

impl RigidRows {
    /// From a rotation matrix and a translation.
    pub(crate) fn new(r: &nalgebra::Matrix3<f64>, t: &nalgebra::Vector3<f64>) -> Self {
        Self {
            r: std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)])),
            t: [t.x, t.y, t.z],
        }
    }

    /// From an `Se3`.
    pub(crate) fn from_se3(m: &dynapix_geometry::Se3) -> Self {
        Self::new(
            m.rotation.to_rotation_matrix().matrix(),
            &m.translation.vector,
        )
    }

    /// `R·(x, y, z) + t`.
    #[inline(always)]
    pub(crate) fn apply(&self, x: f64, y: f64, z: f64) -> (f64, f64, f64) {
        let [[r00, r01, r02], [r10, r11, r12], [r20, r21, r22]] = self.r;
        let [t0, t1, t2] = self.t;
        (
            r00 * x + r01 * y + r02 * z + t0,
            r10 * x + r11 * y + r12 * z + t1,
            r20 * x + r21 * y + r22 * z + t2,
        )
    }
}

/// Checks that an image has the expected size.
pub(crate) fn check_size(
    what: &str,
    expected: (u32, u32),
    got: (u32, u32),
) -> Result<(), MotionError> {
    if expected == got {
        Ok(())
    } else {
        Err(MotionError::SizeMismatch {
            what: what.to_string(),
            expected,
            got,
        })
    }
}
