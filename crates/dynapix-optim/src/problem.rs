//! Problem and parameter types shared by the solvers (the interface `dynapix-slam` builds).

use dynapix_geometry::Se3;
use nalgebra::Vector3;

/// Intrinsics the residuals need (undistorted pinhole plus stereo baseline × fx).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StereoCamera {
    /// Focal length x.
    pub fx: f64,
    /// Focal length y.
    pub fy: f64,
    /// Principal point x.
    pub cx: f64,
    /// Principal point y.
    pub cy: f64,
    /// Baseline times fx (ORB-SLAM2 `Camera.bf`).
    pub bf: f64,
}

/// One measurement of a 3-D point in one image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Undistorted pixel (u, v).
    pub uv: [f64; 2],
    /// Virtual right coordinate uR = u − bf/d when the keypoint has depth; `None` = mono edge.
    pub u_right: Option<f64>,
    /// 1/σ² of the keypoint's pyramid level (information = I/σ²).
    pub inv_sigma2: f64,
    /// DynaPix weight w = 1 − P in [0, 1] (1 for ORB-SLAM2).
    pub weight: f64,
}

/// How the DynaPix weight enters the cost.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WeightMode {
    /// Paper: cost Σ w·ρ(rᵀΩr); outlier tests on the unweighted χ².
    #[default]
    Paper,
    /// Reference code: residual scaled by w, i.e. ρ(w²·rᵀΩr); outlier tests on the weighted χ².
    Reference,
}

/// Parameters of pose-only optimisation (ORB-SLAM2 `PoseOptimization` defaults). Missing
/// fields of a serialised form take the defaults; `weight_mode` is not serialised (callers
/// derive it from their weighting behaviour, see `dynapix-slam`'s `DynaPixParams`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct PoseOnlyParams {
    /// Outlier-classification rounds (4).
    pub rounds: usize,
    /// Levenberg-Marquardt iterations per round (10).
    pub iterations: usize,
    /// χ² threshold of mono edges (5.991, 2 dof 95 %).
    pub chi2_mono: f64,
    /// χ² threshold of stereo edges (7.815, 3 dof 95 %).
    pub chi2_stereo: f64,
    /// Rounds that use the Huber kernel (the first 3; the last round is non-robust).
    pub robust_rounds: usize,
    /// Weight handling (set by the caller from its weighting behaviour; not serialised).
    #[serde(skip)]
    pub weight_mode: WeightMode,
    /// Include observations without depth as mono edges (true in ORB-SLAM2 and paper mode).
    pub use_mono: bool,
    /// With fewer edges than this, stop after the first round (ORB-SLAM2:
    /// `if (optimizer.edges().size() < 10) break;`, 10).
    pub min_edges_for_rounds: usize,
}

impl Default for PoseOnlyParams {
    fn default() -> Self {
        Self {
            rounds: 4,
            iterations: 10,
            chi2_mono: 5.991,
            chi2_stereo: 7.815,
            robust_rounds: 3,
            weight_mode: WeightMode::Paper,
            use_mono: true,
            min_edges_for_rounds: 10,
        }
    }
}

/// Pose-only problem: a camera pose seen through fixed 3-D points.
#[derive(Clone, Debug)]
pub struct PoseOnlyProblem {
    /// Camera intrinsics.
    pub camera: StereoCamera,
    /// Initial guess of `T_cw`.
    pub pose: Se3,
    /// World points, one per observation.
    pub points: Vec<Vector3<f64>>,
    /// Observations, `observations[i]` measures `points[i]`.
    pub observations: Vec<Observation>,
}

/// Result of pose-only optimisation.
#[derive(Clone, Debug)]
pub struct PoseOnlyResult {
    /// Optimised `T_cw`.
    pub pose: Se3,
    /// Per observation: true when classified as an inlier in the last round.
    pub inlier: Vec<bool>,
    /// Number of inliers.
    pub num_inliers: usize,
}

/// One BA edge: observation of `point` from keyframe `pose`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BaEdge {
    /// Index into [`BaProblem::poses`].
    pub pose: usize,
    /// Index into [`BaProblem::points`].
    pub point: usize,
    /// The measurement.
    pub obs: Observation,
}

/// Bundle-adjustment problem (local or global).
#[derive(Clone, Debug)]
pub struct BaProblem {
    /// Camera intrinsics (one camera for all keyframes).
    pub camera: StereoCamera,
    /// Keyframe poses `T_cw`.
    pub poses: Vec<Se3>,
    /// Per pose: held fixed (e.g. keyframe 0, or keyframes outside the local window).
    pub pose_fixed: Vec<bool>,
    /// 3-D points (world).
    pub points: Vec<Vector3<f64>>,
    /// Observations.
    pub edges: Vec<BaEdge>,
}

/// Parameters of bundle adjustment (ORB-SLAM2 `LocalBundleAdjustment` defaults). Missing
/// fields of a serialised form take the defaults; `weight_mode` and `weight_clamp` are not
/// serialised (callers derive them from their weighting behaviour).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct BaParams {
    /// LM iterations with the Huber kernel (5).
    pub iterations_robust: usize,
    /// LM iterations after removing outliers and the kernel (10); 0 skips the second stage.
    pub iterations_refine: usize,
    /// Use the Huber kernel in the first stage (false for ORB-SLAM2's global BA).
    pub robust: bool,
    /// A stage stops early once an accepted step lowers the cost by less than this fraction
    /// of it (converged); 0, the default, runs every iteration, as ORB-SLAM2's g2o does.
    /// 10⁻⁴ cuts ORB-SLAM2 mode's wall time on synth walking_xyz 640×480 by about a quarter,
    /// at mixed accuracy (BENCHMARKS.md, "Local BA that stops when converged").
    pub min_relative_decrease: f64,
    /// χ² threshold of mono edges (5.991).
    pub chi2_mono: f64,
    /// χ² threshold of stereo edges (7.815).
    pub chi2_stereo: f64,
    /// Weight handling (set by the caller from its weighting behaviour; not serialised).
    #[serde(skip)]
    pub weight_mode: WeightMode,
    /// Clamp of weights before use, e.g. `Some((0.9, 1.0))` (paper: [1 − γ_del, 1]); set by
    /// the caller from its weighting behaviour, not serialised.
    #[serde(skip)]
    pub weight_clamp: Option<(f64, f64)>,
}

impl Default for BaParams {
    fn default() -> Self {
        Self {
            iterations_robust: 5,
            iterations_refine: 10,
            robust: true,
            min_relative_decrease: 0.0,
            chi2_mono: 5.991,
            chi2_stereo: 7.815,
            weight_mode: WeightMode::Paper,
            weight_clamp: None,
        }
    }
}

/// Result of bundle adjustment.
#[derive(Clone, Debug)]
pub struct BaResult {
    /// Optimised poses (fixed ones unchanged).
    pub poses: Vec<Se3>,
    /// Optimised points.
    pub points: Vec<Vector3<f64>>,
    /// Per edge: false when classified as an outlier (χ² over threshold or negative depth).
    pub inlier: Vec<bool>,
    /// Levenberg–Marquardt iterations run, both stages together.
    pub iterations: usize,
}
