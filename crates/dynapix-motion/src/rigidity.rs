//! A pose-free motion cue: how badly a pixel fits the dominant rigid motion between a frame
//! and its neighbours (new; not part of the paper or the reference code).
//!
//! The moving term of DynaPix needs camera poses, and the first SLAM pass on a crowded real
//! sequence (Bonn `crowd`) follows the people. This cue needs none:
//! 1. [`correspondences`]: on a grid, pixels of frame i with depth are matched to frame j by
//!    dense optical flow i → j and lifted to 3-D in both cameras (through the undistorted
//!    rays of [`PixelRays`], so lens distortion is handled). The target point sits on the
//!    ray of the rounded target pixel plus the linear sub-pixel offset, at the depth of the
//!    rounded target pixel.
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

use std::borrow::Borrow;
use std::sync::Arc;

use dynapix_flow::{DisFlow, DisParams, FlowField, FlowProvider, Preset};
use dynapix_geometry::align::align_se3;
use dynapix_geometry::{PinholeCamera, PixelRays, Se3};
use image::GrayImage;
use nalgebra::{Matrix3, Point3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::{FloatImage, MotionError, check_size};

/// Parameters of the rigidity cue. `Default` holds the values of the prototype.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RigidityParams {
    /// DIS preset of the flow from a frame to its neighbour (used by [`rigidity_probability`]).
    pub flow_preset: Preset,
    /// Width in pixels (160) below which the flow's finest computed pyramid level does not
    /// go: the flow is computed on the coarsest level at least this wide, unless the preset
    /// stops coarser, and upsampled to the image. With the medium preset a 320×240 image
    /// is computed at 160×120 either way, and a 640×480 image is now computed on the same
    /// 160×120 level instead of 320×240, so the cue costs and means the same at every
    /// resolution (its pixel constants already scale with the focal length). 0 keeps the
    /// preset's own finest level at every resolution (the behaviour before 2026-12-02).
    pub flow_working_width: u32,
    /// Grid step (pixels) of the correspondences fed to RANSAC.
    pub stride: u32,
    /// Depth (metres) a pixel must exceed, in both frames, to take part.
    pub min_depth: f64,
    /// Fewer correspondences than this give no fit (at least 3).
    pub min_correspondences: usize,
    /// Largest number of 3-point samples drawn by RANSAC (degenerate samples are drawn, then
    /// skipped).
    pub ransac_iterations: usize,
    /// RANSAC stops once, with this probability, at least one drawn sample was all inliers
    /// of the best motion so far (the standard adaptive count `ln(1 − p) / ln(1 − ŵ³)` for
    /// inlier fraction ŵ), checked after every batch of [`RANSAC_BATCH`] samples so the result
    /// does not depend on the thread count; 1 draws all `ransac_iterations` samples.
    pub ransac_confidence: f64,
    /// Seed of the sampling.
    pub seed: u64,
    /// A sample is degenerate when `|(a1 − a0) × (a2 − a0)|` (m²) is below this.
    pub min_sample_area: f64,
    /// A correspondence is an inlier when its normalised squared residual is below this
    /// (27 = (3σ)² on 3 degrees of freedom).
    pub chi2: f64,
    /// Rounds of refitting on the inliers after RANSAC.
    pub refine_rounds: usize,
    /// Standard deviation (pixels) of the flow end point at the focal length
    /// [`RigidityParams::reference_focal_px`]; scaled with the camera's focal length, so the
    /// cue means the same angle at every resolution.
    pub sigma_px: f64,
    /// Focal length (pixels) at which `sigma_px` and `stride` are given (525: a Kinect at
    /// 640×480).
    pub reference_focal_px: f64,
    /// Quadratic coefficient `a` (1/m) of the depth noise `σ_z = a·z² + b`.
    pub sigma_z_quadratic: f64,
    /// Constant part `b` (m) of the depth noise `σ_z = a·z² + b`.
    pub sigma_z_constant: f64,
    /// A moved point at or below this depth (m) is behind the camera: infinite residual.
    pub min_projected_depth: f64,
    /// Residual at and below which P = 0.
    pub r0: f64,
    /// Residual at and above which P = 1.
    pub r1: f64,
    /// Neighbour frame offsets a caller should pass (`[-4, -1, 1, 4]`: two baselines, so a
    /// slow mover shows at the longer one; a side whose best motion is ambiguous gives no
    /// evidence); the functions of this module take the neighbours themselves.
    pub offsets: Vec<i64>,
    /// Smallest inlier fraction of a pair's best motion (0.5): below it movers may be the
    /// majority and the pair is ambiguous, so it gives no evidence.
    pub min_inlier_fraction: f64,
    /// Each frame pair's flow and fit computed once, for both frames (true, the default
    /// since 2026-12-04), instead of each frame computing its own flow to each neighbour
    /// (false). The earlier frame `a` of a pair gets the residual of [`pair_residuals`]
    /// directly; the later frame `b` gets the residual of the flow a → b turned around
    /// ([`reverse_flow`]) under the inverse motion. Half the flows and fits: −9 to −13 % CPU
    /// of an offline run on the Bonn window and fr1_xyz, with ATE means over three RANSAC
    /// seeds within +2 % there and +0.7 % on synth walking_xyz 640×480 s0–s2 (BENCHMARKS.md,
    /// "Each frame pair's rigidity flow once"). Offline sequence runs honour it; the
    /// per-frame functions of this module and the online system, where a pair without
    /// lookahead serves one frame only, compute their own flows.
    pub shared_pairs: bool,
}

impl Default for RigidityParams {
    fn default() -> Self {
        Self {
            flow_preset: Preset::Medium,
            flow_working_width: 160,
            stride: 4,
            min_depth: 0.1,
            min_correspondences: 20,
            ransac_iterations: 500,
            ransac_confidence: 0.999,
            seed: 0,
            min_sample_area: 1e-3,
            chi2: 27.0,
            refine_rounds: 5,
            sigma_px: 1.0,
            reference_focal_px: 525.0,
            sigma_z_quadratic: 1.5e-3,
            sigma_z_constant: 0.003,
            min_projected_depth: 0.05,
            r0: 3.0,
            r1: 8.0,
            offsets: vec![-4, -1, 1, 4],
            min_inlier_fraction: 0.5,
            shared_pairs: true,
        }
    }
}

/// The finest pyramid level of a flow on images `width` pixels wide that stops at the
/// coarsest level at least `working_width` wide, never finer than `own` (the flow's own finest
/// level); `working_width` 0 keeps `own`.
pub fn finest_scale_at_working_width(own: usize, working_width: u32, width: u32) -> usize {
    if working_width == 0 {
        return own;
    }
    let mut level = 0;
    while (width >> (level + 1)) >= working_width {
        level += 1;
    }
    own.max(level)
}

fn invalid(name: &'static str, message: impl Into<String>) -> MotionError {
    MotionError::InvalidParam {
        name,
        message: message.into(),
    }
}

impl RigidityParams {
    /// Checks every value against its valid range.
    /// `sigma_px` at the focal length of `cam`.
    pub fn sigma_px_for(&self, cam: &PinholeCamera) -> f64 {
        self.sigma_px * cam.fx / self.reference_focal_px
    }

    /// The finest pyramid level of the flow for an image `width` pixels wide: the preset's,
    /// or the coarsest level at least [`RigidityParams::flow_working_width`] wide if that is
    /// coarser.
    pub fn flow_finest_scale(&self, width: u32) -> usize {
        finest_scale_at_working_width(
            DisParams::preset(self.flow_preset).finest_scale,
            self.flow_working_width,
            width,
        )
    }

    /// The DIS flow of the cue for an image `width` pixels wide: the preset with its finest
    /// level from [`RigidityParams::flow_finest_scale`].
    pub fn flow_for_width(&self, width: u32) -> DisFlow {
        let mut p = DisParams::preset(self.flow_preset);
        p.finest_scale = self.flow_finest_scale(width);
        DisFlow::new(p)
    }

    /// `stride` at the focal length of `cam` (at least 1).
    pub fn stride_for(&self, cam: &PinholeCamera) -> usize {
        ((self.stride as f64 * cam.fx / self.reference_focal_px).round() as usize).max(1)
    }

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), MotionError> {
        if !(0.0..=1.0).contains(&self.min_inlier_fraction) {
            return Err(invalid(
                "min_inlier_fraction",
                format!("must be in [0, 1], got {}", self.min_inlier_fraction),
            ));
        }
        let finite_nonneg = |name, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(invalid(name, format!("must be finite and ≥ 0, got {v}")))
            }
        };
        let positive = |name, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(invalid(name, format!("must be finite and > 0, got {v}")))
            }
        };
        if self.stride == 0 {
            return Err(invalid("stride", "must be at least 1"));
        }
        finite_nonneg("min_depth", self.min_depth)?;
        if self.min_correspondences < 3 {
            return Err(invalid(
                "min_correspondences",
                format!("must be at least 3, got {}", self.min_correspondences),
            ));
        }
        if self.ransac_iterations == 0 {
            return Err(invalid("ransac_iterations", "must be at least 1"));
        }
        if !(self.ransac_confidence > 0.0 && self.ransac_confidence <= 1.0) {
            return Err(invalid(
                "ransac_confidence",
                format!("must be in (0, 1], got {}", self.ransac_confidence),
            ));
        }
        finite_nonneg("min_sample_area", self.min_sample_area)?;
        positive("chi2", self.chi2)?;
        positive("sigma_px", self.sigma_px)?;
        positive("reference_focal_px", self.reference_focal_px)?;
        finite_nonneg("sigma_z_quadratic", self.sigma_z_quadratic)?;
        positive("sigma_z_constant", self.sigma_z_constant)?;
        if !self.min_projected_depth.is_finite() {
            return Err(invalid("min_projected_depth", "must be finite"));
        }
        finite_nonneg("r0", self.r0)?;
        if !(self.r1.is_finite() && self.r1 > self.r0) {
            return Err(invalid(
                "r1",
                format!("must be finite and exceed r0 ({} ≤ {})", self.r1, self.r0),
            ));
        }
        if self.offsets.is_empty() || self.offsets.contains(&0) {
            return Err(invalid(
                "offsets",
                format!("must be non-empty and non-zero, got {:?}", self.offsets),
            ));
        }
        Ok(())
    }
}

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

/// The normalised residual model of one parameter set and camera.
#[derive(Clone, Copy, Debug)]
struct Model {
    fx_over_sigma: f64,
    fy_over_sigma: f64,
    sz_a: f64,
    sz_b: f64,
    min_pz: f64,
}

impl Model {
    fn new(cam: &PinholeCamera, params: &RigidityParams) -> Self {
        Self {
            fx_over_sigma: cam.fx / params.sigma_px_for(cam),
            fy_over_sigma: cam.fy / params.sigma_px_for(cam),
            sz_a: params.sigma_z_quadratic,
            sz_b: params.sigma_z_constant,
            min_pz: params.min_projected_depth,
        }
    }

    /// `r²` of the moved point `p` against the target with normalised image coordinates `bn`
    /// and depth `bz`.
    #[inline]
    fn r2(&self, p: &Vector3<f64>, bn: [f64; 2], bz: f64) -> f64 {
        // A NaN depth counts as behind the camera.
        if p.z.is_nan() || p.z <= self.min_pz {
            return f64::INFINITY;
        }
        let ex = (p.x / p.z - bn[0]) * self.fx_over_sigma;
        let ey = (p.y / p.z - bn[1]) * self.fy_over_sigma;
        let ez = (p.z - bz) / (self.sz_a * bz * bz + self.sz_b);
        ex * ex + ey * ey + ez * ez
    }
}

/// Normalised squared residual of the pair `(a, b)` under `motion`: with `P = motion·a`,
/// `e_x = (P.x/P.z − b.x/b.z)·fx/σ_px`, `e_y` likewise with `fy`, `e_z = (P.z − b.z)/σ_z`,
/// `σ_z = a·b.z² + b`; `r² = e_x² + e_y² + e_z²`. Infinite when `P.z` is at or below
/// [`RigidityParams::min_projected_depth`] or `b` is not in front of the camera.
pub fn residual_squared(
    motion: &Se3,
    a: &Point3<f64>,
    b: &Point3<f64>,
    cam: &PinholeCamera,
    params: &RigidityParams,
) -> f64 {
    if b.z.is_nan() || b.z <= 0.0 {
        return f64::INFINITY;
    }
    let p = motion.transform_point(a).coords;
    Model::new(cam, params).r2(&p, [b.x / b.z, b.y / b.z], b.z)
}

/// Checks that `flow` has the image size `size` and one vector per pixel.
fn check_flow(flow: &FlowField, size: (u32, u32)) -> Result<(), MotionError> {
    check_size("flow", size, (flow.width, flow.height))?;
    if flow.data.len() != size.0 as usize * size.1 as usize {
        return Err(MotionError::SizeMismatch {
            what: "flow data".into(),
            expected: size,
            got: (flow.data.len() as u32, 1),
        });
    }
    Ok(())
}

/// One frame pair with its flow, for the per-pixel look-ups shared by the correspondences
/// and the dense residual.
struct Pair<'a> {
    depth_i: &'a FloatImage,
    depth_j: &'a FloatImage,
    flow: &'a FlowField,
    rays: &'a PixelRays,
    min_depth: f64,
}

/// A pixel of frame i lifted to 3-D and the normalised coordinates and depth of its target.
struct Lifted {
    a: Vector3<f64>,
    bn: [f64; 2],
    bz: f64,
}

impl<'a> Pair<'a> {
    fn new(
        depth_i: &'a FloatImage,
        depth_j: &'a FloatImage,
        flow: &'a FlowField,
        rays: &'a PixelRays,
        params: &RigidityParams,
    ) -> Result<Self, MotionError> {
        let cam = rays.camera();
        let size = (cam.width, cam.height);
        check_size("depth of frame i", size, depth_i.dimensions())?;
        check_size("depth of the neighbour", size, depth_j.dimensions())?;
        check_flow(flow, size)?;
        Ok(Self {
            depth_i,
            depth_j,
            flow,
            rays,
            min_depth: params.min_depth,
        })
    }

    /// The pixel `(x, y)` of frame i lifted, if it has depth, a ray, a flow target inside the
    /// image (within the span of pixel centres) and depth at the rounded target pixel.
    #[inline(always)]
    fn lift(&self, x: u32, y: u32) -> Option<Lifted> {
        let cam = self.rays.camera();
        let z = self.depth_i.get_pixel(x, y)[0] as f64;
        if z.is_nan() || z <= self.min_depth {
            return None;
        }
        let ri = self.rays.ray(x, y)?;
        let f = self.flow.get(x, y);
        let u2 = x as f64 + f[0] as f64;
        let v2 = y as f64 + f[1] as f64;
        let inside = (0.0..=(cam.width - 1) as f64).contains(&u2)
            && (0.0..=(cam.height - 1) as f64).contains(&v2);
        if !inside {
            return None;
        }
        let (ur, vr) = (u2.round(), v2.round());
        let (ui, vi) = (ur as u32, vr as u32);
        let z2 = self.depth_j.get_pixel(ui, vi)[0] as f64;
        if z2.is_nan() || z2 <= self.min_depth {
            return None;
        }
        let rj = self.rays.ray(ui, vi)?;
        Some(Lifted {
            a: Vector3::new(ri[0] * z, ri[1] * z, z),
            bn: [rj[0] + (u2 - ur) / cam.fx, rj[1] + (v2 - vr) / cam.fy],
            bz: z2,
        })
    }
}

/// Correspondences of frame i to its neighbour j on a grid of step
/// [`RigidityParams::stride`]: pixel `(x, y)` with depth `z_i > min_depth` whose flow target
/// `(u2, v2)` lies inside the image with depth `z_j > min_depth` at the rounded target gives
/// `A = z_i·ray(x, y)` and `B = z_j·(ray(round(u2), round(v2)) + ((u2 − round u2)/fx,
/// (v2 − round v2)/fy), 1)`. `flow` goes from i to j; `rays` fixes the camera and image size.
pub fn correspondences(
    depth_i: &FloatImage,
    depth_j: &FloatImage,
    flow: &FlowField,
    rays: &PixelRays,
    params: &RigidityParams,
) -> Result<Correspondences, MotionError> {
    params.validate()?;
    let pair = Pair::new(depth_i, depth_j, flow, rays, params)?;
    let stride = params.stride_for(rays.camera());
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        return Ok(unsafe { correspondences_avx2(avx2, &pair, stride) });
    }
    Ok(correspondences_body(&pair, stride))
}

/// [`correspondences_body`] compiled for AVX2, where `f64::round` is an instruction instead
/// of a library call; the same arithmetic, so the same correspondences (test
/// `correspondences_are_the_same_in_every_build`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn correspondences_avx2(_: dynapix_simd::Avx2, pair: &Pair<'_>, stride: usize) -> Correspondences {
    correspondences_body(pair, stride)
}

/// The correspondences of `pair` on the grid of step `stride`.
#[inline(always)]
fn correspondences_body(pair: &Pair<'_>, stride: usize) -> Correspondences {
    let cam = pair.rays.camera();
    let mut out = Correspondences::default();
    for y in (0..cam.height).step_by(stride) {
        for x in (0..cam.width).step_by(stride) {
            if let Some(l) = pair.lift(x, y) {
                out.source.push(Point3::from(l.a));
                out.target
                    .push(Point3::new(l.bn[0] * l.bz, l.bn[1] * l.bz, l.bz));
                out.pixels.push([x, y]);
            }
        }
    }
    out
}

/// Kabsch/Horn: the rigid motion minimising `Σ‖R·aₖ + t − bₖ‖²` (SVD with the reflection
/// guard); `None` for fewer than 3 pairs, non-finite input or an SVD failure.
fn kabsch(source: &[Point3<f64>], target: &[Point3<f64>]) -> Option<Se3> {
    align_se3(source, target).ok().map(|a| a.se3())
}

/// A correspondence's target in the form the residual needs.
#[derive(Clone, Copy)]
struct Target {
    bn: [f64; 2],
    bz: f64,
}

/// The correspondences as columns (structure of arrays) for [`count_inliers_soa`], with the
/// depth-noise denominator `σ_z = a·b_z² + b` of each target computed once.
struct Columns {
    ax: Vec<f64>,
    ay: Vec<f64>,
    az: Vec<f64>,
    bn0: Vec<f64>,
    bn1: Vec<f64>,
    bz: Vec<f64>,
    sigma_z: Vec<f64>,
}

impl Columns {
    fn new(source: &[Point3<f64>], targets: &[Target], model: &Model) -> Self {
        let n = source.len().min(targets.len());
        let (source, targets) = (&source[..n], &targets[..n]);
        Self {
            ax: source.iter().map(|a| a.x).collect(),
            ay: source.iter().map(|a| a.y).collect(),
            az: source.iter().map(|a| a.z).collect(),
            bn0: targets.iter().map(|b| b.bn[0]).collect(),
            bn1: targets.iter().map(|b| b.bn[1]).collect(),
            bz: targets.iter().map(|b| b.bz).collect(),
            sigma_z: targets
                .iter()
                .map(|b| model.sz_a * b.bz * b.bz + model.sz_b)
                .collect(),
        }
    }
}

/// [`count_inliers`] over [`Columns`], without branches so that the compiler vectorises it
/// (AVX2 when present). The same operations in the same order as [`Model::r2`], so the count
/// is identical (test `column_count_equals_the_point_by_point_count`).
fn count_inliers_soa(motion: &Se3, c: &Columns, model: &Model, chi2: f64) -> usize {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        return unsafe { count_inliers_avx2(avx2, motion, c, model, chi2) };
    }
    count_inliers_body(motion, c, model, chi2)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn count_inliers_avx2(
    _: dynapix_simd::Avx2,
    motion: &Se3,
    c: &Columns,
    model: &Model,
    chi2: f64,
) -> usize {
    count_inliers_body(motion, c, model, chi2)
}

#[inline(always)]
fn count_inliers_body(motion: &Se3, c: &Columns, model: &Model, chi2: f64) -> usize {
    let rt = crate::RigidRows::from_se3(motion);
    let (fxs, fys, min_pz) = (model.fx_over_sigma, model.fy_over_sigma, model.min_pz);
    let n = c.ax.len();
    let (ay, az, bn0, bn1, bz, sz) = (
        &c.ay[..n],
        &c.az[..n],
        &c.bn0[..n],
        &c.bn1[..n],
        &c.bz[..n],
        &c.sigma_z[..n],
    );
    let mut count = 0usize;
    for k in 0..n {
        let (px, py, pz) = rt.apply(c.ax[k], ay[k], az[k]);
        let ex = (px / pz - bn0[k]) * fxs;
        let ey = (py / pz - bn1[k]) * fys;
        let ez = (pz - bz[k]) / sz[k];
        let r2 = ex * ex + ey * ey + ez * ez;
        // A NaN depth counts as behind the camera, as in `Model::r2`.
        let ok = !(pz.is_nan() || pz <= min_pz) & (r2 < chi2);
        count += ok as usize;
    }
    count
}

#[cfg(test)]
fn count_inliers(
    motion: &Se3,
    source: &[Point3<f64>],
    targets: &[Target],
    model: &Model,
    chi2: f64,
) -> usize {
    let r: Matrix3<f64> = *motion.rotation.to_rotation_matrix().matrix();
    let t = motion.translation.vector;
    source
        .iter()
        .zip(targets)
        .filter(|(a, b)| model.r2(&(r * a.coords + t), b.bn, b.bz) < chi2)
        .count()
}

fn inlier_pairs(
    motion: &Se3,
    corr: &Correspondences,
    targets: &[Target],
    model: &Model,
    chi2: f64,
) -> (Vec<Point3<f64>>, Vec<Point3<f64>>) {
    let r: Matrix3<f64> = *motion.rotation.to_rotation_matrix().matrix();
    let t = motion.translation.vector;
    corr.source
        .iter()
        .zip(&corr.target)
        .zip(targets)
        .filter(|((a, _), b)| model.r2(&(r * a.coords + t), b.bn, b.bz) < chi2)
        .map(|((a, b), _)| (*a, *b))
        .unzip()
}

/// Samples drawn between two checks of RANSAC's adaptive stopping rule.
pub const RANSAC_BATCH: usize = 16;

/// Samples RANSAC needs so that, with probability `confidence`, one of them is all inliers
/// when a fraction `inlier_fraction` of the correspondences are inliers (3-point samples).
/// `usize::MAX` when that cannot be reached (no inliers, or confidence 1).
pub fn adaptive_samples(inlier_fraction: f64, confidence: f64) -> usize {
    let all_inliers = inlier_fraction.clamp(0.0, 1.0).powi(3);
    if confidence >= 1.0 || all_inliers <= 0.0 {
        return usize::MAX;
    }
    if all_inliers >= 1.0 {
        return 1;
    }
    let k = (1.0 - confidence).ln() / (1.0 - all_inliers).ln();
    if k.is_finite() && k >= 0.0 {
        (k.ceil() as usize).max(1)
    } else {
        usize::MAX
    }
}

/// RANSAC for the rigid motion `B ≈ R·A + t` of `corr` (see the module documentation):
/// up to [`RigidityParams::ransac_iterations`] seeded 3-point samples (fewer once
/// [`RigidityParams::ransac_confidence`] is reached), degenerate ones skipped,
/// each hypothesis scored by its number of inliers (`r² < chi2`, [`residual_squared`]; the
/// first best hypothesis wins ties), then [`RigidityParams::refine_rounds`] rounds of Kabsch
/// on the inliers. `cam` gives the focal lengths of the residual.
///
/// A pair that cannot be fitted gives [`MotionError::RigidFit`].
pub fn fit_rigid_motion(
    corr: &Correspondences,
    cam: &PinholeCamera,
    params: &RigidityParams,
) -> Result<RigidFit, MotionError> {
    params.validate()?;
    if corr.target.len() != corr.source.len() {
        return Err(invalid(
            "correspondences",
            format!(
                "{} source points but {} target points",
                corr.source.len(),
                corr.target.len()
            ),
        ));
    }
    let n = corr.len();
    if n < params.min_correspondences {
        return Err(RigidFitError::TooFewCorrespondences {
            got: n,
            needed: params.min_correspondences,
        }
        .into());
    }
    let model = Model::new(cam, params);
    let targets: Vec<Target> = corr
        .target
        .iter()
        .map(|b| Target {
            bn: [b.x / b.z, b.y / b.z],
            bz: b.z,
        })
        .collect();

    let columns = Columns::new(&corr.source, &targets, &model);
    // Samples are drawn in sequence from the seeded generator, in fixed batches; only the
    // scoring within a batch is parallel, and the first best sample wins ties, so the result
    // is the same on every thread count.
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
    let mut best: Option<(Se3, usize)> = None;
    let mut drawn = 0;
    let mut needed = params.ransac_iterations;
    while drawn < needed {
        let end = (drawn + RANSAC_BATCH).min(needed);
        let mut hypotheses = Vec::with_capacity(end - drawn);
        for _ in drawn..end {
            let idx = rand::seq::index::sample(&mut rng, n, 3);
            let a = [
                corr.source[idx.index(0)],
                corr.source[idx.index(1)],
                corr.source[idx.index(2)],
            ];
            let area = (a[1] - a[0]).cross(&(a[2] - a[0])).norm();
            // NaN areas (non-finite input) are degenerate too.
            if area.is_nan() || area < params.min_sample_area {
                continue;
            }
            let b = [
                corr.target[idx.index(0)],
                corr.target[idx.index(1)],
                corr.target[idx.index(2)],
            ];
            if let Some(m) = kabsch(&a, &b) {
                hypotheses.push(m);
            }
        }
        drawn = end;
        let scores: Vec<usize> = hypotheses
            .par_iter()
            .map(|m| count_inliers_soa(m, &columns, &model, params.chi2))
            .collect();
        for (m, s) in hypotheses.into_iter().zip(scores) {
            if best.as_ref().is_none_or(|(_, b)| s > *b) {
                best = Some((m, s));
            }
        }
        if let Some((_, s)) = &best {
            needed = adaptive_samples(*s as f64 / n as f64, params.ransac_confidence)
                .min(params.ransac_iterations);
        }
    }
    let Some((mut motion, _)) = best else {
        return Err(RigidFitError::NoHypothesis {
            samples: params.ransac_iterations,
        }
        .into());
    };
    for _ in 0..params.refine_rounds {
        let (a, b) = inlier_pairs(&motion, corr, &targets, &model, params.chi2);
        match kabsch(&a, &b) {
            Some(m) => motion = m,
            // Fewer than 3 inliers: keep the motion that has them.
            None => break,
        }
    }
    let inliers = count_inliers_soa(&motion, &columns, &model, params.chi2);
    Ok(RigidFit {
        motion,
        inliers,
        correspondences: n,
        samples: drawn,
    })
}

/// The normalised residual `r = √r²` ([`residual_squared`]) of every pixel of frame i under
/// `motion` (camera i → camera j) with the flow i → j; NaN where the pixel has no depth, its
/// flow target leaves the image or the rounded target has no depth (the same conditions as
/// [`correspondences`]).
pub fn dense_residual(
    depth_i: &FloatImage,
    depth_j: &FloatImage,
    flow: &FlowField,
    rays: &PixelRays,
    motion: &Se3,
    params: &RigidityParams,
) -> Result<FloatImage, MotionError> {
    params.validate()?;
    let pair = Pair::new(depth_i, depth_j, flow, rays, params)?;
    let cam = rays.camera();
    let model = Model::new(cam, params);
    let r: Matrix3<f64> = *motion.rotation.to_rotation_matrix().matrix();
    let t = motion.translation.vector;
    let w = cam.width as usize;
    let mut out = FloatImage::new(cam.width, cam.height);
    if w == 0 {
        return Ok(out);
    }
    out.par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| residual_row(&pair, &model, &r, &t, y, row));
    Ok(out)
}

/// One row of [`dense_residual`]: [`Pair::lift`] and [`Model::r2`] over slices of the row
/// instead of per-pixel look-ups, and compiled for AVX2 when present (where `f64::round` is
/// inlined instead of called). The same operations on the same values: bit-identical (test
/// `row_residual_equals_the_pixel_by_pixel_residual`).
fn residual_row(
    pair: &Pair<'_>,
    model: &Model,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    y: usize,
    row: &mut [f32],
) {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        unsafe { residual_row_avx2(avx2, pair, model, r, t, y, row) };
        return;
    }
    residual_row_body(pair, model, r, t, y, row);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn residual_row_avx2(
    _: dynapix_simd::Avx2,
    pair: &Pair<'_>,
    model: &Model,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    y: usize,
    row: &mut [f32],
) {
    residual_row_body(pair, model, r, t, y, row);
}

/// Pixels per block of [`residual_row_body`].
const RESIDUAL_BLOCK: usize = 64;

#[inline(always)]
fn residual_row_body(
    pair: &Pair<'_>,
    model: &Model,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    y: usize,
    row: &mut [f32],
) {
    let cam = pair.rays.camera();
    let (w, h) = (cam.width as usize, cam.height as usize);
    let (xmax, ymax) = ((cam.width - 1) as f64, (cam.height - 1) as f64);
    let (fx, fy) = (cam.fx, cam.fy);
    let zi = &pair.depth_i.as_raw()[y * w..][..w];
    let zj = pair.depth_j.as_raw();
    let flow = &pair.flow.data[y * w..][..w];
    let rays_i = pair.rays.row(y as u32);
    let rays = pair.rays.all();
    let min_depth = pair.min_depth;
    let rt = crate::RigidRows::new(r, t);
    let (fxs, fys) = (model.fx_over_sigma, model.fy_over_sigma);
    let (sz_a, sz_b, min_pz) = (model.sz_a, model.sz_b, model.min_pz);
    let mut ok = [false; RESIDUAL_BLOCK];
    let mut at = [0usize; RESIDUAL_BLOCK];
    let mut z2 = [0f64; RESIDUAL_BLOCK];
    let mut rj = [[0f64; 2]; RESIDUAL_BLOCK];
    let mut du = [0f64; RESIDUAL_BLOCK];
    let mut dv = [0f64; RESIDUAL_BLOCK];
    let row = &mut row[..w];
    for x0 in (0..w).step_by(RESIDUAL_BLOCK) {
        let n = RESIDUAL_BLOCK.min(w - x0);
        // The source pixel and its flow target, without branches.
        for j in 0..n {
            let x = x0 + j;
            let z = zi[x] as f64;
            let f = flow[x];
            let u2 = x as f64 + f[0] as f64;
            let v2 = y as f64 + f[1] as f64;
            let inside = (0.0..=xmax).contains(&u2) & (0.0..=ymax).contains(&v2);
            let (ur, vr) = (u2.round(), v2.round());
            let valid = !(z.is_nan() || z <= min_depth) & rays_i[x][0].is_finite() & inside;
            // Truncation of the clamped rounded target, which vectorises (`as` saturates, a
            // lane at a time): the same index wherever `inside`, where clamping changes
            // nothing; elsewhere the pixel is invalid anyway.
            let (uc, vc) = (ur.max(0.0).min(xmax), vr.max(0.0).min(ymax));
            // SAFETY: `max` turns NaN into 0, so uc and vc are finite, in [0, 2³²).
            let (ui, vi) = unsafe { (uc.to_int_unchecked::<u32>(), vc.to_int_unchecked::<u32>()) };
            let k = (vi as usize).wrapping_mul(w).wrapping_add(ui as usize);
            ok[j] = valid & (k < w * h);
            at[j] = if ok[j] { k } else { 0 };
            du[j] = u2 - ur;
            dv[j] = v2 - vr;
        }
        // The target's depth and ray (a gather).
        for j in 0..n {
            z2[j] = zj[at[j]] as f64;
            rj[j] = rays[at[j]];
        }
        // The residual, without branches; a pixel that failed a test gets NaN.
        for j in 0..n {
            let x = x0 + j;
            let z = zi[x] as f64;
            let ri = rays_i[x];
            let valid = ok[j] & !(z2[j].is_nan() || z2[j] <= min_depth) & rj[j][0].is_finite();
            let bn0 = rj[j][0] + du[j] / fx;
            let bn1 = rj[j][1] + dv[j] / fy;
            let bz = z2[j];
            let (px, py, pz) = rt.apply(ri[0] * z, ri[1] * z, z);
            // `Model::r2`: a NaN depth counts as behind the camera.
            let ex = (px / pz - bn0) * fxs;
            let ey = (py / pz - bn1) * fys;
            let ez = (pz - bz) / (sz_a * bz * bz + sz_b);
            let r2 = ex * ex + ey * ey + ez * ez;
            let r2 = if pz.is_nan() || pz <= min_pz {
                f64::INFINITY
            } else {
                r2
            };
            row[x] = if valid { r2.sqrt() as f32 } else { f32::NAN };
        }
    }
}

/// P of a frame from the dense residuals of its neighbours, each with its baseline
/// (|frame offset|). Per baseline, the residual is the minimum over the neighbours that give
/// a value (a pixel occluded or disoccluded on one side does not look moving); over
/// baselines, the maximum (a slow mover shows at the longer baseline, a fast one at the
/// shorter). Then P = clamp((r − r0)/(r1 − r0), 0, 1); pixels without any value get 0.
/// Returns (P, combined residual with NaN where none).
pub fn rigidity_from_residuals<R: Borrow<FloatImage>>(
    residuals: &[(u64, R)],
    params: &RigidityParams,
) -> Result<(FloatImage, FloatImage), MotionError> {
    params.validate()?;
    let Some((_, first)) = residuals.first() else {
        return Err(invalid("residuals", "need at least one neighbour"));
    };
    let size = first.borrow().dimensions();
    for (_, r) in residuals {
        check_size("residual of a neighbour", size, r.borrow().dimensions())?;
    }
    let mut baselines: Vec<u64> = residuals.iter().map(|(b, _)| *b).collect();
    baselines.sort_unstable();
    baselines.dedup();
    let mut combined = FloatImage::from_pixel(size.0, size.1, image::Luma([f32::NAN]));
    for b in baselines {
        let mut per = FloatImage::from_pixel(size.0, size.1, image::Luma([f32::NAN]));
        for (_, r) in residuals.iter().filter(|(rb, _)| *rb == b) {
            for (c, &v) in per.iter_mut().zip(r.borrow().iter()) {
                // f32::min returns the other operand when one is NaN.
                *c = c.min(v);
            }
        }
        for (c, &v) in combined.iter_mut().zip(per.iter()) {
            *c = c.max(v);
        }
    }
    let (r0, span) = (params.r0, params.r1 - params.r0);
    let mut p = FloatImage::new(size.0, size.1);
    for (o, &r) in p.iter_mut().zip(combined.iter()) {
        *o = if r.is_nan() {
            0.0
        } else {
            ((r as f64 - r0) / span).clamp(0.0, 1.0) as f32
        };
    }
    Ok((p, combined))
}

/// The undistorted ray table of `cam`, distorted or not, shared through the process-wide
/// cache of [`crate::splat::pixel_rays`] (built once per camera, not once per frame).
pub fn camera_rays(cam: &PinholeCamera) -> Arc<PixelRays> {
    crate::splat::cached_rays(cam)
}

/// The rigidity cue of `cur` from `neighbours` with DIS flow of preset
/// [`RigidityParams::flow_preset`] at [`RigidityParams::flow_working_width`] (see
/// [`rigidity_probability_with`]).
pub fn rigidity_probability(
    cur: &RigidFrame<'_>,
    neighbours: &[RigidFrame<'_>],
    cam: &PinholeCamera,
    params: &RigidityParams,
) -> Result<RigidityMaps, MotionError> {
    let dis = params.flow_for_width(cam.width);
    rigidity_probability_with(cur, neighbours, cam, &dis, params)
}

/// The rigidity cue of `cur` from `neighbours` with flows from `flow` (current → neighbour):
/// per neighbour [`correspondences`], [`fit_rigid_motion`] and [`dense_residual`], then
/// [`rigidity_from_residuals`]. A neighbour whose motion cannot be fitted gives no residual
/// (its error is in [`RigidityMaps::fits`]); without any residual P is 0 everywhere.
pub fn rigidity_probability_with(
    cur: &RigidFrame<'_>,
    neighbours: &[RigidFrame<'_>],
    cam: &PinholeCamera,
    flow: &dyn FlowProvider,
    params: &RigidityParams,
) -> Result<RigidityMaps, MotionError> {
    params.validate()?;
    let size = (cam.width, cam.height);
    check_size("grey image", size, cur.gray.dimensions())?;
    check_size("depth image", size, cur.depth.dimensions())?;
    for nb in neighbours {
        check_size("grey image of a neighbour", size, nb.gray.dimensions())?;
        check_size("depth image of a neighbour", size, nb.depth.dimensions())?;
    }
    let per_neighbour: Vec<Result<PairResiduals, MotionError>> = neighbours
        .par_iter()
        .map(|nb| pair_residuals(cur, nb, cam, flow, params, false))
        .collect();
    let mut pairs = Vec::with_capacity(neighbours.len());
    for (r, nb) in per_neighbour.into_iter().zip(neighbours) {
        let pair = r?;
        pairs.push((nb.offset, pair.fit, pair.forward));
    }
    rigidity_from_pairs(pairs, size, params)
}

/// What one frame pair (a, b) gives: the fit of a → b, the residual of a's pixels and, when
/// asked for, the residual of b's pixels.
#[derive(Clone, Debug)]
pub struct PairResiduals {
    /// The motion a → b, or why there is none (an ambiguous fit counts as none).
    pub fit: Result<RigidFit, RigidFitError>,
    /// [`dense_residual`] of a's pixels under the fit, with the flow a → b; `None` without a
    /// fit.
    pub forward: Option<FloatImage>,
    /// The residual of b's pixels: [`dense_residual`] of b against a with [`reverse_flow`]
    /// under the inverse fit; `None` without a fit or when not asked for.
    pub backward: Option<FloatImage>,
}

impl PairResiduals {
    /// The fit as b sees it: the motion b → a (the inverse of [`PairResiduals::fit`]).
    pub fn inverse_fit(&self) -> Result<RigidFit, RigidFitError> {
        self.fit.clone().map(|f| RigidFit {
            motion: f.motion.inverse(),
            ..f
        })
    }
}

/// The flow a → b, the rigid fit and the residuals of the pair: [`correspondences`],
/// [`fit_rigid_motion`] (a fit below [`RigidityParams::min_inlier_fraction`] is
/// [`RigidFitError::Ambiguous`]) and [`dense_residual`]; with `with_backward`, also the
/// residual of b's pixels through the flow a → b turned around ([`PairResiduals::backward`]).
pub fn pair_residuals(
    a: &RigidFrame<'_>,
    b: &RigidFrame<'_>,
    cam: &PinholeCamera,
    flow: &dyn FlowProvider,
    params: &RigidityParams,
    with_backward: bool,
) -> Result<PairResiduals, MotionError> {
    let rays = camera_rays(cam);
    let f = {
        let _stage = tracing::info_span!(target: "dynapix::stage", "rigidity: flow").entered();
        flow.flow(a.gray, b.gray)?
    };
    let fit_stage = tracing::info_span!(target: "dynapix::stage", "rigidity: fit").entered();
    let corr = correspondences(a.depth, b.depth, &f, &rays, params)?;
    let fit = match fit_rigid_motion(&corr, cam, params) {
        Ok(fit) if fit.inlier_fraction() < params.min_inlier_fraction => {
            Err(RigidFitError::Ambiguous {
                fraction: fit.inlier_fraction(),
                needed: params.min_inlier_fraction,
            })
        }
        Ok(fit) => Ok(fit),
        Err(MotionError::RigidFit(e)) => Err(e),
        Err(e) => return Err(e),
    };
    drop(fit_stage);
    let _stage = tracing::info_span!(target: "dynapix::stage", "rigidity: residual").entered();
    let Ok(good) = &fit else {
        return Ok(PairResiduals {
            fit,
            forward: None,
            backward: None,
        });
    };
    let forward = dense_residual(a.depth, b.depth, &f, &rays, &good.motion, params)?;
    let backward = if with_backward {
        let g = reverse_flow(&f, a.depth, &rays, &good.motion, params)?;
        let inverse = good.motion.inverse();
        Some(dense_residual(
            b.depth, a.depth, &g, &rays, &inverse, params,
        )?)
    } else {
        None
    };
    Ok(PairResiduals {
        fit,
        forward: Some(forward),
        backward,
    })
}

/// The rigidity maps of a frame of size `size` from its neighbours' fits and residuals (owned
/// or borrowed), each with its frame offset (see [`rigidity_from_residuals`]); P is 0
/// everywhere without any residual.
pub fn rigidity_from_pairs<R: Borrow<FloatImage>>(
    pairs: Vec<(i64, Result<RigidFit, RigidFitError>, Option<R>)>,
    size: (u32, u32),
    params: &RigidityParams,
) -> Result<RigidityMaps, MotionError> {
    let mut fits = Vec::with_capacity(pairs.len());
    let mut residuals = Vec::with_capacity(pairs.len());
    for (offset, fit, residual) in pairs {
        fits.push(fit);
        residuals.extend(residual.map(|r| (offset.unsigned_abs(), r)));
    }
    let (p, residual) = if residuals.is_empty() {
        (
            FloatImage::new(size.0, size.1),
            FloatImage::from_pixel(size.0, size.1, image::Luma([f32::NAN])),
        )
    } else {
        rigidity_from_residuals(&residuals, params)?
    };
    Ok(RigidityMaps { p, residual, fits })
}

/// The flow b → a on b's pixel grid from the flow a → b: each pixel x of frame a with depth
/// above [`RigidityParams::min_depth`] and a ray whose target `x + f(x)` lies inside the image
/// gives the flow `−f(x)` to the four pixels around its target (so a stretching flow leaves
/// no holes). Where several pixels of a reach one pixel of b, the one nearest camera b after
/// `motion` (a → b) wins, as in a depth buffer: depths compared in f32, those at or behind
/// camera b as 0, ties to the first pixel in row order. Pixels of b that no pixel of a
/// reaches get NaN flow, which [`dense_residual`] treats as no correspondence.
pub fn reverse_flow(
    flow: &FlowField,
    depth_a: &FloatImage,
    rays: &PixelRays,
    motion: &Se3,
    params: &RigidityParams,
) -> Result<FlowField, MotionError> {
    let cam = rays.camera();
    let size = (cam.width, cam.height);
    check_size("depth of frame a", size, depth_a.dimensions())?;
    check_flow(flow, size)?;
    let (w, h) = (cam.width as usize, cam.height as usize);
    // Only the depth after the motion matters: the third row of R·p + t.
    let rm = motion.rotation.to_rotation_matrix();
    let m = rm.matrix();
    let (r20, r21, r22, tz) = (m[(2, 0)], m[(2, 1)], m[(2, 2)], motion.translation.vector.z);
    let (xmax, ymax) = ((w.max(1) - 1) as f64, (h.max(1) - 1) as f64);
    // The depth buffer: per pixel of b, the depth (f32) and the index of the nearest pixel
    // of a so far in one key, `depth bits << 32 | index`, so the smallest key is the nearest
    // pixel and, among equal depths, the first. A depth at or below zero (behind camera b)
    // counts as 0: the bits of a non-negative f32 order like the numbers.
    let mut nearest = vec![u64::MAX; w * h];
    let min_depth = params.min_depth;
    for y in 0..h {
        let row = y * w..(y + 1) * w;
        let (za, ra, fa) = (
            &depth_a.as_raw()[row.clone()],
            &rays.all()[row.clone()],
            &flow.data[row],
        );
        for (x, ((&z, ray), f)) in za.iter().zip(ra).zip(fa).enumerate() {
            let z = z as f64;
            let (u2, v2) = (x as f64 + f[0] as f64, y as f64 + f[1] as f64);
            let valid = !(z.is_nan() || z <= min_depth)
                & ray[0].is_finite()
                & (0.0..=xmax).contains(&u2)
                & (0.0..=ymax).contains(&v2);
            if !valid {
                continue;
            }
            let zb = r20 * (ray[0] * z) + r21 * (ray[1] * z) + r22 * z + tz;
            let zb = if zb > 0.0 { zb as f32 } else { 0.0 };
            let key = ((zb.to_bits() as u64) << 32) | (y * w + x) as u64;
            // The four pixels around the target: a stretching flow leaves no holes.
            // SAFETY: 0 ≤ u2 ≤ xmax and 0 ≤ v2 ≤ ymax (checked above), so both truncate
            // into u32 (a single instruction, where `as` would add saturation checks).
            let (u0, v0) = unsafe {
                (
                    u2.to_int_unchecked::<u32>() as usize,
                    v2.to_int_unchecked::<u32>() as usize,
                )
            };
            let (u1, v1) = ((u0 + 1).min(w - 1), (v0 + 1).min(h - 1));
            for t in [v0 * w + u0, v0 * w + u1, v1 * w + u0, v1 * w + u1] {
                let n = &mut nearest[t];
                *n = (*n).min(key);
            }
        }
    }
    let data = nearest
        .iter()
        .map(|&key| match flow.data.get((key & 0xffff_ffff) as usize) {
            Some(f) if key != u64::MAX => [-f[0], -f[1]],
            _ => [f32::NAN; 2],
        })
        .collect();
    Ok(FlowField {
        width: cam.width,
        height: cam.height,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::RocAccumulator;
    use crate::testutil::{small_camera, small_distorted_camera};
    use nalgebra::{Translation3, UnitQuaternion};
    use proptest::prelude::*;
    use rand::Rng;
    use std::sync::OnceLock;

    fn se3(axis_angle: [f64; 3], t: [f64; 3]) -> Se3 {
        Se3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_scaled_axis(Vector3::from(axis_angle)),
        )
    }

    /// Rotation angle (rad) and translation distance between two motions.
    fn distance(a: &Se3, b: &Se3) -> (f64, f64) {
        let d = a.inverse() * b;
        (
            d.rotation.angle(),
            (a.translation.vector - b.translation.vector).norm(),
        )
    }

    /// A depth map with holes (0 and NaN) among depths of 0.05–4 m.
    fn random_depth(rng: &mut ChaCha8Rng, w: u32, h: u32) -> FloatImage {
        FloatImage::from_fn(w, h, |_, _| {
            image::Luma([match rng.random_range(0..10) {
                0 => 0.0,
                1 => f32::NAN,
                _ => rng.random_range(0.05f32..4.0),
            }])
        })
    }

    #[test]
    fn correspondences_are_the_same_in_every_build() {
        for cam in [small_camera(), small_distorted_camera()] {
            let (w, h) = (cam.width, cam.height);
            let params = RigidityParams::default();
            let mut rng = ChaCha8Rng::seed_from_u64(8);
            let (di, dj) = (random_depth(&mut rng, w, h), random_depth(&mut rng, w, h));
            let flow = FlowField {
                width: w,
                height: h,
                // Half-pixel flows too, where rounding matters.
                data: (0..w * h)
                    .map(|i| {
                        let f = rng.random_range(-6.0f32..6.0);
                        if i % 3 == 0 {
                            [f.round() + 0.5, -1.5]
                        } else {
                            [f, f * 0.5]
                        }
                    })
                    .collect(),
            };
            let rays = camera_rays(&cam);
            let got = correspondences(&di, &dj, &flow, &rays, &params).unwrap();
            let pair = Pair::new(&di, &dj, &flow, &rays, &params).unwrap();
            let want = correspondences_body(&pair, params.stride_for(&cam));
            assert!(got.len() > 10, "{}", got.len());
            assert_eq!(got.pixels, want.pixels);
            for (a, b) in [(&got.source, &want.source), (&got.target, &want.target)] {
                let bits = |p: &[Point3<f64>]| {
                    p.iter()
                        .flat_map(|q| q.coords.iter().map(|c| c.to_bits()).collect::<Vec<_>>())
                        .collect::<Vec<_>>()
                };
                assert_eq!(bits(a), bits(b));
            }
        }
    }

    #[test]
    fn row_residual_equals_the_pixel_by_pixel_residual() {
        for cam in [small_camera(), small_distorted_camera()] {
            let (w, h) = (cam.width, cam.height);
            let params = RigidityParams::default();
            let mut rng = ChaCha8Rng::seed_from_u64(4);
            let (di, dj) = (random_depth(&mut rng, w, h), random_depth(&mut rng, w, h));
            let flow = FlowField {
                width: w,
                height: h,
                data: (0..w * h)
                    .map(|_| {
                        [
                            rng.random_range(-6.0f32..6.0),
                            rng.random_range(-6.0f32..6.0),
                        ]
                    })
                    .collect(),
            };
            let rays = camera_rays(&cam);
            let motion = se3([0.02, -0.01, 0.005], [0.05, 0.01, -0.02]);
            let got = dense_residual(&di, &dj, &flow, &rays, &motion, &params).unwrap();
            let pair = Pair::new(&di, &dj, &flow, &rays, &params).unwrap();
            let model = Model::new(&cam, &params);
            let (r, t) = (
                *motion.rotation.to_rotation_matrix().matrix(),
                motion.translation.vector,
            );
            let mut finite = 0;
            for y in 0..h {
                for x in 0..w {
                    let want = match pair.lift(x, y) {
                        Some(l) => model.r2(&(r * l.a + t), l.bn, l.bz).sqrt() as f32,
                        None => f32::NAN,
                    };
                    let g = got.get_pixel(x, y).0[0];
                    assert_eq!(g.to_bits(), want.to_bits(), "({x}, {y}): {g} vs {want}");
                    finite += usize::from(want.is_finite());
                }
            }
            assert!(finite > (w * h / 4) as usize, "{finite}");
        }
    }

    #[test]
    fn column_count_equals_the_point_by_point_count() {
        let cam = small_camera();
        let params = RigidityParams::default();
        let model = Model::new(&cam, &params);
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let n = 1003;
        // Points near and behind the camera and targets with noise: every branch of r².
        let source: Vec<Point3<f64>> = (0..n)
            .map(|_| {
                Point3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-0.2..5.0),
                )
            })
            .collect();
        let truth = se3([0.05, -0.02, 0.01], [0.1, 0.0, -0.05]);
        let targets: Vec<Target> = source
            .iter()
            .map(|a| {
                let b = truth * a;
                let noise = rng.random_range(-0.01..0.01);
                Target {
                    bn: [b.x / b.z + noise, b.y / b.z],
                    bz: b.z + 3.0 * noise,
                }
            })
            .collect();
        let columns = Columns::new(&source, &targets, &model);
        let mut nonzero = 0;
        for k in 0..50 {
            let f = k as f64 / 50.0;
            let m = se3([0.05 * f, -0.02, 0.01 * f], [0.1 * f, 0.0, -0.05]);
            for chi2 in [1.0, 27.0, 1e4] {
                let want = count_inliers(&m, &source, &targets, &model, chi2);
                assert_eq!(count_inliers_soa(&m, &columns, &model, chi2), want);
                assert_eq!(count_inliers_body(&m, &columns, &model, chi2), want);
                nonzero += usize::from(want > 0 && want < n);
            }
        }
        assert!(nonzero > 50, "{nonzero}");
    }

    proptest! {
        #[test]
        fn prop_kabsch_recovers_a_rigid_transform(
            axis in prop::array::uniform3(-1.0f64..1.0),
            angle in 0.0f64..3.1,
            t in prop::array::uniform3(-5.0f64..5.0),
            seed in 0u64..10_000,
            n in 3usize..40,
        ) {
            let a = Vector3::from(axis);
            let w = if a.norm() > 1e-6 { a.normalize() * angle } else { Vector3::zeros() };
            let truth = se3(w.into(), t);
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let src: Vec<Point3<f64>> = (0..n)
                .map(|_| Point3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-2.0..2.0),
                    rng.random_range(0.5..5.0),
                ))
                .collect();
            // Minimal samples must not be degenerate, as RANSAC guarantees.
            prop_assume!((src[1] - src[0]).cross(&(src[2] - src[0])).norm() > 0.05);
            let dst: Vec<Point3<f64>> = src.iter().map(|p| truth * p).collect();
            let est = kabsch(&src, &dst);
            prop_assert!(est.is_some());
            if let Some(est) = est {
                let (dr, dt) = distance(&est, &truth);
                prop_assert!(dr < 1e-7 && dt < 1e-7, "{dr} {dt}");
                prop_assert!(est.rotation.to_rotation_matrix().matrix().determinant() > 0.0);
            }
        }
    }

    /// Points in front of the camera inside a 640×480 frustum, moved by `motion`
    /// and perturbed by at most half a pixel and one σ_z.
    fn scene_pairs(
        rng: &mut ChaCha8Rng,
        n: usize,
        motion: &Se3,
        cam: &PinholeCamera,
        params: &RigidityParams,
    ) -> (Vec<Point3<f64>>, Vec<Point3<f64>>) {
        let mut src = Vec::with_capacity(n);
        let mut dst = Vec::with_capacity(n);
        while src.len() < n {
            let z = rng.random_range(1.0..4.0);
            let a = Point3::new(
                rng.random_range(-0.55..0.55) * z,
                rng.random_range(-0.4..0.4) * z,
                z,
            );
            let b = motion * a;
            let sz = params.sigma_z_quadratic * b.z * b.z + params.sigma_z_constant;
            let bz = b.z + rng.random_range(-1.0..1.0) * sz;
            let bx = b.x / b.z + rng.random_range(-0.5..0.5) / cam.fx;
            let by = b.y / b.z + rng.random_range(-0.5..0.5) / cam.fy;
            src.push(a);
            dst.push(Point3::new(bx * bz, by * bz, bz));
        }
        (src, dst)
    }

    #[test]
    fn ransac_recovers_the_camera_motion_with_40_percent_rigid_outliers() {
        let cam = PinholeCamera::tum_fr3();
        let params = RigidityParams::default();
        let camera = se3([0.01, -0.02, 0.005], [0.03, -0.01, 0.02]);
        // The movers share one rigid motion of their own (a walker's 6-7 cm in one frame,
        // ≥ 8 px at 4 m), so they form a consistent second model that RANSAC must not prefer.
        let mover = se3([0.0; 3], [0.06, -0.03, 0.04]) * camera;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (mut src, mut dst) = scene_pairs(&mut rng, 600, &camera, &cam, &params);
        let (ms, md) = scene_pairs(&mut rng, 400, &mover, &cam, &params);
        // Interleave so the outliers are not a contiguous block.
        for (k, (a, b)) in ms.into_iter().zip(md).enumerate() {
            src.insert(2 * k + 1, a);
            dst.insert(2 * k + 1, b);
        }
        let corr = Correspondences {
            pixels: vec![[0, 0]; src.len()],
            source: src,
            target: dst,
        };
        let fit = fit_rigid_motion(&corr, &cam, &params).expect("fits");
        let (dr, dt) = distance(&fit.motion, &camera);
        assert!(dr.to_degrees() < 0.05 && dt < 0.003, "{dr} rad, {dt} m");
        assert_eq!(fit.correspondences, 1000);
        // Every static pair is an inlier (noise ≤ 0.5 px, 1 σ_z); no mover is.
        assert!((600..=610).contains(&fit.inliers), "{}", fit.inliers);
        assert!((fit.inlier_fraction() - 0.6).abs() < 0.011);
        // The same seed gives the same fit; a different seed the same motion.
        assert_eq!(fit_rigid_motion(&corr, &cam, &params).unwrap(), fit);
        let other = RigidityParams { seed: 99, ..params };
        let fit2 = fit_rigid_motion(&corr, &cam, &other).unwrap();
        let (dr2, dt2) = distance(&fit2.motion, &fit.motion);
        assert!(dr2 < 1e-9 && dt2 < 1e-9, "{dr2} {dt2}");
    }

    #[test]
    fn adaptive_sample_count_follows_the_ransac_formula() {
        // ln(0.001) / ln(1 − 0.5³) = 51.7 → 52 samples at half inliers.
        assert_eq!(adaptive_samples(0.5, 0.999), 52);
        // More inliers, fewer samples; more confidence, more samples.
        assert!(adaptive_samples(0.8, 0.999) < adaptive_samples(0.6, 0.999));
        assert!(adaptive_samples(0.6, 0.99) < adaptive_samples(0.6, 0.999));
        assert_eq!(adaptive_samples(1.0, 0.999), 1);
        assert_eq!(adaptive_samples(0.0, 0.999), usize::MAX);
        assert_eq!(adaptive_samples(0.7, 1.0), usize::MAX);
    }

    #[test]
    fn adaptive_ransac_stops_early_with_the_same_motion() {
        let cam = PinholeCamera::tum_fr3();
        let camera = se3([0.01, -0.02, 0.005], [0.03, -0.01, 0.02]);
        let mover = se3([0.0; 3], [0.06, -0.03, 0.04]) * camera;
        let all = RigidityParams {
            ransac_confidence: 1.0,
            ..Default::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (mut src, mut dst) = scene_pairs(&mut rng, 700, &camera, &cam, &all);
        let (ms, md) = scene_pairs(&mut rng, 300, &mover, &cam, &all);
        src.extend(ms);
        dst.extend(md);
        let corr = Correspondences {
            pixels: vec![[0, 0]; src.len()],
            source: src,
            target: dst,
        };
        let full = fit_rigid_motion(&corr, &cam, &all).unwrap();
        assert_eq!(full.samples, all.ransac_iterations);
        let adaptive = fit_rigid_motion(&corr, &cam, &RigidityParams::default()).unwrap();
        // 70 % inliers: ln(0.001) / ln(1 − 0.343) = 16.4 → the first batch (16) plus one.
        assert!(adaptive.samples <= 2 * RANSAC_BATCH, "{}", adaptive.samples);
        let (dr, dt) = distance(&adaptive.motion, &full.motion);
        assert!(dr.to_degrees() < 0.01 && dt < 5e-4, "{dr} rad, {dt} m");
        assert_eq!(adaptive.inliers, full.inliers);
        // Bad values are refused.
        for c in [0.0, 1.5, f64::NAN] {
            let p = RigidityParams {
                ransac_confidence: c,
                ..Default::default()
            };
            assert!(fit_rigid_motion(&corr, &cam, &p).is_err(), "{c}");
        }
    }

    #[test]
    fn residual_squared_follows_its_formula() {
        let cam = small_camera();
        // σ_px is given at the camera's own focal length here: 1 px.
        let params = RigidityParams {
            reference_focal_px: cam.fx,
            ..Default::default()
        };
        let id = Se3::identity();
        let a = Point3::new(0.2, -0.1, 2.0);
        assert_eq!(residual_squared(&id, &a, &a, &cam, &params), 0.0);
        // One pixel along x and one σ_z in depth: r² = 1 + 1 (the ray stays put when the
        // depth changes, so the pixel error is unchanged).
        let sz = 1.5e-3 * 4.0 + 0.003;
        let bz = 2.0 + sz;
        let b = Point3::new((0.1 + 1.0 / cam.fx) * bz, -0.05 * bz, bz);
        let r2 = residual_squared(&id, &a, &b, &cam, &params);
        // σ_z is taken at the target depth.
        let ez = (2.0 - bz) / (1.5e-3 * bz * bz + 0.003);
        assert!((r2 - (1.0 + ez * ez)).abs() < 1e-9, "{r2}");
        // Behind the camera, or a target without depth: infinite.
        let behind = se3([0.0; 3], [0.0, 0.0, -1.96]);
        assert_eq!(
            residual_squared(&behind, &a, &a, &cam, &params),
            f64::INFINITY
        );
        let no_depth = Point3::new(0.0, 0.0, 0.0);
        assert_eq!(
            residual_squared(&id, &a, &no_depth, &cam, &params),
            f64::INFINITY
        );
    }

    #[test]
    fn fits_fail_with_typed_errors() {
        let cam = small_camera();
        let params = RigidityParams::default();
        let pts: Vec<_> = (0..10).map(|k| Point3::new(k as f64, 0.0, 2.0)).collect();
        let few = Correspondences {
            source: pts.clone(),
            target: pts.clone(),
            pixels: vec![[0, 0]; 10],
        };
        assert!(matches!(
            fit_rigid_motion(&few, &cam, &params),
            Err(MotionError::RigidFit(
                RigidFitError::TooFewCorrespondences {
                    got: 10,
                    needed: 20
                }
            ))
        ));
        // Collinear points: every sample is degenerate.
        let line: Vec<_> = (0..50)
            .map(|k| Point3::new(0.01 * k as f64, 0.0, 2.0))
            .collect();
        let collinear = Correspondences {
            source: line.clone(),
            target: line,
            pixels: vec![[0, 0]; 50],
        };
        assert!(matches!(
            fit_rigid_motion(&collinear, &cam, &params),
            Err(MotionError::RigidFit(RigidFitError::NoHypothesis {
                samples: 500
            }))
        ));
        let mut bad = few.clone();
        bad.target.pop();
        let p3 = RigidityParams {
            min_correspondences: 3,
            ..params.clone()
        };
        assert!(matches!(
            fit_rigid_motion(&bad, &cam, &p3),
            Err(MotionError::InvalidParam { .. })
        ));
    }

    #[test]
    fn the_flow_runs_on_the_same_level_width_at_every_resolution() {
        let d = RigidityParams::default();
        // Medium stops at level 1 by itself; the working width of 160 px takes a 640-pixel
        // image to level 2 and a 1280-pixel one to level 3: 160 px across in every case.
        for (width, level) in [(160, 1), (320, 1), (480, 1), (640, 2), (1280, 3), (100, 1)] {
            assert_eq!(d.flow_finest_scale(width), level, "width {width}");
            assert_eq!(d.flow_for_width(width).params.finest_scale, level);
        }
        let own = RigidityParams {
            flow_working_width: 0,
            ..d.clone()
        };
        assert_eq!(own.flow_finest_scale(640), 1);
        // A preset that stops coarser keeps its own level.
        let fast = RigidityParams {
            flow_preset: Preset::Fast,
            ..d
        };
        assert_eq!(fast.flow_finest_scale(320), 2);
        assert_eq!(fast.flow_finest_scale(1280), 3);
        let p = fast.flow_for_width(640).params;
        assert_eq!((p.finest_scale, p.patch_stride), (2, 4));
    }

    #[test]
    fn params_default_validate_and_deserialise() {
        let d = RigidityParams::default();
        d.validate().unwrap();
        assert_eq!(
            (d.stride, d.ransac_iterations, d.chi2, d.r0, d.r1),
            (4, 500, 27.0, 3.0, 8.0)
        );
        assert_eq!((d.flow_preset, d.flow_working_width), (Preset::Medium, 160));
        let parsed: RigidityParams = serde_json::from_str("{}").unwrap();
        assert_eq!(parsed, d);
        let parsed: RigidityParams =
            serde_json::from_str(r#"{"stride": 2, "flow_preset": "fast"}"#).unwrap();
        assert_eq!((parsed.stride, parsed.flow_preset), (2, Preset::Fast));
        assert_eq!(parsed.chi2, 27.0);
        let cases: Vec<(&str, RigidityParams)> = vec![
            (
                "stride",
                RigidityParams {
                    stride: 0,
                    ..d.clone()
                },
            ),
            (
                "min_depth",
                RigidityParams {
                    min_depth: f64::NAN,
                    ..d.clone()
                },
            ),
            (
                "min_correspondences",
                RigidityParams {
                    min_correspondences: 2,
                    ..d.clone()
                },
            ),
            (
                "ransac_iterations",
                RigidityParams {
                    ransac_iterations: 0,
                    ..d.clone()
                },
            ),
            (
                "chi2",
                RigidityParams {
                    chi2: 0.0,
                    ..d.clone()
                },
            ),
            (
                "sigma_px",
                RigidityParams {
                    sigma_px: -1.0,
                    ..d.clone()
                },
            ),
            (
                "sigma_z_constant",
                RigidityParams {
                    sigma_z_constant: 0.0,
                    ..d.clone()
                },
            ),
            (
                "r1",
                RigidityParams {
                    r1: 3.0,
                    ..d.clone()
                },
            ),
            (
                "offsets",
                RigidityParams {
                    offsets: vec![-1, 0],
                    ..d.clone()
                },
            ),
            (
                "offsets",
                RigidityParams {
                    offsets: vec![],
                    ..d.clone()
                },
            ),
        ];
        for (name, p) in cases {
            match p.validate() {
                Err(MotionError::InvalidParam { name: got, .. }) => assert_eq!(got, name),
                other => panic!("{name}: {other:?}"),
            }
        }
    }

    #[test]
    fn correspondences_use_the_undistorted_rays_and_the_subpixel_offset() {
        let cam = small_distorted_camera();
        let rays = camera_rays(&cam);
        let (w, h) = (cam.width, cam.height);
        let depth = FloatImage::from_fn(w, h, |x, _| image::Luma([1.0 + 0.01 * x as f32]));
        let mut depth_j = depth.clone();
        depth_j.put_pixel(12, 0, image::Luma([0.05])); // no usable depth at one target
        let flow = FlowField::constant(w, h, [0.25, -0.375]);
        // The stride is given at the camera's own focal length here: 4 px.
        let params = RigidityParams {
            reference_focal_px: cam.fx,
            ..Default::default()
        };
        let c = correspondences(&depth, &depth_j, &flow, &rays, &params).unwrap();
        // Grid rows y = 0 lose their targets (v2 < 0); the last grid column stays inside.
        assert!(
            c.pixels
                .iter()
                .all(|p| p[1] > 0 && p[0] % 4 == 0 && p[1] % 4 == 0)
        );
        assert_eq!(c.len(), (w / 4) as usize * (h / 4 - 1) as usize);
        for ((a, b), px) in c.source.iter().zip(&c.target).zip(&c.pixels) {
            let und = cam.undistort_point(&nalgebra::Point2::new(px[0] as f64, px[1] as f64));
            let z = 1.0 + 0.01 * px[0] as f32;
            assert!((a.z - z as f64).abs() < 1e-12);
            assert!((a.x / a.z - (und.x - cam.cx) / cam.fx).abs() < 1e-12);
            // Target: x + 0.25 rounds to x and y − 0.375 to y, plus the sub-pixel offset.
            let r = rays.ray(px[0], px[1]).unwrap();
            assert!((b.x / b.z - (r[0] + 0.25 / cam.fx)).abs() < 1e-12);
            assert!((b.y / b.z - (r[1] - 0.375 / cam.fy)).abs() < 1e-12);
            assert!((b.z - z as f64).abs() < 1e-12);
        }
        // A target without depth drops the pair.
        let c2 = correspondences(
            &depth,
            &depth_j,
            &FlowField::constant(w, h, [0.0, 0.0]),
            &rays,
            &params,
        )
        .unwrap();
        assert!(!c2.pixels.contains(&[12, 0]) && c2.pixels.contains(&[16, 0]));
        // Sizes must agree.
        let small = FloatImage::new(w - 1, h);
        assert!(matches!(
            correspondences(&small, &depth_j, &flow, &rays, &params),
            Err(MotionError::SizeMismatch { .. })
        ));
    }

    /// A fronto-parallel plane at 2 m seen by a camera shifted by 5 cm along x: the camera,
    /// its rays, the depth of both frames, the constant flow `du` px and that flow.
    fn translating_plane() -> (PinholeCamera, Arc<PixelRays>, FloatImage, f32, FlowField) {
        let cam = small_camera();
        let rays = camera_rays(&cam);
        let depth = FloatImage::from_pixel(cam.width, cam.height, image::Luma([2.0]));
        let du = (cam.fx * 0.05 / 2.0) as f32;
        let flow = FlowField::constant(cam.width, cam.height, [du, 0.0]);
        (cam, rays, depth, du, flow)
    }

    #[test]
    fn a_translating_camera_over_a_plane_is_fitted_and_has_no_residual() {
        // Fronto-parallel plane at 2 m, camera j = camera i shifted: points move by
        // t = (0.05, 0, 0) in camera coordinates, i.e. a constant flow of fx·0.05/2 px.
        let (cam, rays, depth, du, flow) = translating_plane();
        let w = cam.width;
        let params = RigidityParams::default();
        let c = correspondences(&depth, &depth, &flow, &rays, &params).unwrap();
        let fit = fit_rigid_motion(&c, &cam, &params).unwrap();
        let truth = se3([0.0; 3], [0.05, 0.0, 0.0]);
        // A plane leaves rotations about in-plane axes nearly unobservable; the fit still
        // reproduces every correspondence.
        assert_eq!(fit.inliers, c.len());
        let (dr, dt) = distance(&fit.motion, &truth);
        assert!(dr < 1e-3 && dt < 1e-3, "{dr} {dt}");
        let r = dense_residual(&depth, &depth, &flow, &rays, &fit.motion, &params).unwrap();
        for (x, _, v) in r.enumerate_pixels() {
            let inside = x as f32 + du <= (w - 1) as f32;
            if inside {
                assert!(v[0] < 0.05, "{x}: {}", v[0]);
            } else {
                assert!(v[0].is_nan());
            }
        }
        // Under a wrong motion the residual is large everywhere it is defined.
        // (0.25 m of disagreement at 2 m: 10 px.)
        let wrong = se3([0.0; 3], [-0.2, 0.0, 0.0]);
        let r = dense_residual(&depth, &depth, &flow, &rays, &wrong, &params).unwrap();
        assert!(r.iter().filter(|v| !v.is_nan()).all(|&v| v > 8.0));
    }

    #[test]
    fn the_reversed_flow_of_a_translating_camera_has_no_residual() {
        // The plane of the test above, seen from camera j: the flow j → i is the constant
        // −du, so the reversed flow is −du wherever a pixel of i lands, and the inverse of the
        // fit explains it.
        let (cam, rays, depth, du, flow) = translating_plane();
        let (w, h) = (cam.width, cam.height);
        let params = RigidityParams::default();
        let motion = se3([0.0; 3], [0.05, 0.0, 0.0]);
        let narrow = FloatImage::new(w - 1, h);
        assert!(matches!(
            reverse_flow(&flow, &narrow, &rays, &motion, &params),
            Err(MotionError::SizeMismatch { .. })
        ));
        let g = reverse_flow(&flow, &depth, &rays, &motion, &params).unwrap();
        for y in 0..h {
            for x in 0..w {
                let v = g.get(x, y);
                // Pixel x of j is reached from x − du of i, rounded: from x ≥ round(du).
                if x as f32 >= du.round() {
                    assert_eq!(v, [-du, -0.0], "({x}, {y})");
                } else {
                    assert!(v[0].is_nan() && v[1].is_nan(), "({x}, {y}): {v:?}");
                }
            }
        }
        let r = dense_residual(&depth, &depth, &g, &rays, &motion.inverse(), &params).unwrap();
        let defined: Vec<f32> = r.iter().copied().filter(|v| !v.is_nan()).collect();
        assert!(
            defined.len() > (w as usize - 10) * h as usize,
            "{}",
            defined.len()
        );
        assert!(defined.iter().all(|&v| v < 0.05));
    }

    #[test]
    fn the_reversed_flow_keeps_the_nearer_of_two_pixels_landing_together() {
        let cam = small_camera();
        let rays = camera_rays(&cam);
        let (w, h) = (cam.width, cam.height);
        let params = RigidityParams::default();
        // Pixel (10, 5) moves right by one onto (11, 5), which stays put.
        let mut flow = FlowField::constant(w, h, [0.0, 0.0]);
        flow.data[5 * w as usize + 10] = [1.0, 0.0];
        let at = |near_moves: bool| {
            let mut depth = FloatImage::from_pixel(w, h, image::Luma([3.0]));
            let (mover, still) = if near_moves { (1.0, 2.0) } else { (2.0, 1.0) };
            depth.put_pixel(10, 5, image::Luma([mover]));
            depth.put_pixel(11, 5, image::Luma([still]));
            let g = reverse_flow(&flow, &depth, &rays, &Se3::identity(), &params).unwrap();
            (g.get(10, 5), g.get(11, 5))
        };
        // Each pixel covers the four pixels around its target, (11, 5) to (12, 6) for both;
        // the vacated (10, 5) is covered by its still neighbours (9, 5), (10, 4), (9, 4).
        let (left, right) = at(true);
        assert_eq!(left, [-0.0, -0.0]);
        assert_eq!(right, [-1.0, -0.0]);
        let (left, right) = at(false);
        assert_eq!(left, [-0.0, -0.0]);
        assert_eq!(right, [-0.0, -0.0]);
    }

    #[test]
    fn the_reversed_flow_of_a_stretching_flow_has_no_holes() {
        // Frame j sees the image of i stretched by 1.5 across: target x' = 1.5·x. Rounded
        // targets would skip every third pixel; the four-pixel footprint covers them all.
        let cam = small_camera();
        let rays = camera_rays(&cam);
        let (w, h) = (cam.width, cam.height);
        let params = RigidityParams::default();
        let depth = FloatImage::from_pixel(w, h, image::Luma([2.0]));
        let mut flow = FlowField::constant(w, h, [0.0, 0.0]);
        for (k, f) in flow.data.iter_mut().enumerate() {
            *f = [0.5 * (k % w as usize) as f32, 0.0];
        }
        let g = reverse_flow(&flow, &depth, &rays, &Se3::identity(), &params).unwrap();
        for y in 0..h {
            for x in 0..w {
                assert!(!g.get(x, y)[0].is_nan(), "hole at ({x}, {y})");
            }
        }
    }

    #[test]
    fn the_backward_residual_separates_walkers_like_the_frames_own_flow() {
        // The later frame b of a pair (a, b) three or four frames apart: its P from its own
        // flow b → a, and from the flow a → b turned around (shared pairs).
        let s = synth();
        let params = RigidityParams::default();
        let frame = |i: usize| RigidFrame {
            gray: &s.frames[i].0,
            depth: &s.frames[i].1,
            offset: 0,
        };
        let dis = params.flow_for_width(s.cam.width);
        let size = (s.cam.width, s.cam.height);
        let mut own = RocAccumulator::new(0.5);
        let mut shared = RocAccumulator::new(0.5);
        for (a, b) in [(0, 3), (0, 4), (1, 4)] {
            let mask = s.frames[b].2.as_raw();
            let add = |roc: &mut RocAccumulator, p: &FloatImage| add_fast_movers(roc, p, mask);
            let direct =
                pair_residuals(&frame(b), &frame(a), &s.cam, &dis, &params, false).unwrap();
            assert!(direct.backward.is_none());
            let maps = rigidity_from_pairs(vec![(-4, direct.fit, direct.forward)], size, &params);
            add(&mut own, &maps.unwrap().p);
            let pair = pair_residuals(&frame(a), &frame(b), &s.cam, &dis, &params, true).unwrap();
            let maps =
                rigidity_from_pairs(vec![(-4, pair.inverse_fit(), pair.backward)], size, &params);
            let maps = maps.unwrap();
            assert!(maps.fits.iter().all(|f| f.is_ok()));
            add(&mut shared, &maps.p);
        }
        let (a_own, a_shared) = (own.auc().unwrap(), shared.auc().unwrap());
        eprintln!(
            "walkers against the static scene: AUC {a_own:.3} own flow, {a_shared:.3} shared"
        );
        assert!(a_shared > 0.85, "{a_shared}");
        assert!(a_shared > a_own - 0.03, "{a_shared} against {a_own}");
    }

    #[test]
    fn pixel_constants_scale_with_the_focal_length() {
        let p = RigidityParams::default();
        let cam = |fx: f64| PinholeCamera::new(640, 480, fx, fx, 320.0, 240.0);
        assert_eq!(p.stride_for(&cam(525.0)), 4);
        assert_eq!(p.stride_for(&cam(262.5)), 2);
        assert_eq!(p.stride_for(&cam(60.0)), 1);
        assert!((p.sigma_px_for(&cam(262.5)) - 0.5).abs() < 1e-12);
    }

    #[test]
    fn residuals_combine_by_their_minimum_and_ramp() {
        let params = RigidityParams::default();
        let nan = f32::NAN;
        let a = FloatImage::from_raw(6, 1, vec![2.0, 5.5, 10.0, nan, nan, f32::INFINITY]).unwrap();
        let b = FloatImage::from_raw(6, 1, vec![9.0, 20.0, 4.0, 7.0, nan, nan]).unwrap();
        let (p, r) = rigidity_from_residuals(&[(1, a.clone()), (1, b.clone())], &params).unwrap();
        assert_eq!(&r.as_raw()[..4], &[2.0, 5.5, 4.0, 7.0]);
        assert!(r.as_raw()[4].is_nan());
        assert_eq!(r.as_raw()[5], f32::INFINITY);
        let want = [0.0, 0.5, 0.2, 0.8, 0.0, 1.0];
        for (got, want) in p.iter().zip(want) {
            assert!((got - want).abs() < 1e-6, "{got} {want}");
        }
        assert!(matches!(
            rigidity_from_residuals::<FloatImage>(&[], &params),
            Err(MotionError::InvalidParam { .. })
        ));
        // Over baselines the larger residual wins: a slow mover shows at the long baseline.
        let (_, r) = rigidity_from_residuals(&[(1, a.clone()), (4, b)], &params).unwrap();
        assert_eq!(&r.as_raw()[..4], &[9.0, 20.0, 10.0, 7.0]);
        let other = FloatImage::new(5, 1);
        assert!(matches!(
            rigidity_from_residuals(&[(1, a), (1, other)], &params),
            Err(MotionError::SizeMismatch { .. })
        ));
    }

    /// Frames 60-64 of a 320×240 `walking_xyz` synthetic sequence (a walker crosses the view
    /// while another sits down): grey image, depth (m) and motion mask, rendered once for all
    /// tests. The mask marks mover pixels that move more than 2 cm to the previous or next
    /// frame 255 and slower mover pixels 128: a one-frame cue at this resolution cannot be
    /// expected to see a few millimetres of motion (at 2 m, 2 cm are 2.7 px), so the slow ones
    /// are left out of the score.
    struct Synth {
        cam: PinholeCamera,
        frames: Vec<(GrayImage, FloatImage, GrayImage)>,
    }

    const SYNTH_FRAMES: usize = 5;

    fn synth() -> &'static Synth {
        static S: OnceLock<Synth> = OnceLock::new();
        S.get_or_init(|| {
            let full = PinholeCamera::tum_fr3();
            let s = 320.0 / full.width as f64;
            let cam =
                PinholeCamera::new(320, 240, full.fx * s, full.fy * s, full.cx * s, full.cy * s);
            let params = dynapix_synth::SynthParams {
                preset: dynapix_synth::Preset::WalkingXyz,
                frames: 100,
                seed: 0,
                scene: dynapix_synth::SceneParams::for_width(cam.width),
                camera: cam.clone(),
                moving_threshold: 0.02,
                ..dynapix_synth::SynthParams::default()
            };
            let seq = dynapix_synth::Sequence::new(params).expect("sequence");
            let frames = (60..60 + SYNTH_FRAMES)
                .into_par_iter()
                .map(|i| {
                    let (f, _) = seq.frame(i, None);
                    let depth = f.depth_metres();
                    (crate::moving::to_gray(&f.rgb), depth, f.mask)
                })
                .collect();
            Synth { cam, frames }
        })
    }

    fn synth_maps(k: usize, params: &RigidityParams) -> RigidityMaps {
        let s = synth();
        let frame = |i: usize| RigidFrame {
            gray: &s.frames[i].0,
            depth: &s.frames[i].1,
            offset: i as i64 - k as i64,
        };
        let nbs = [frame(k - 1), frame(k + 1)];
        rigidity_probability(&frame(k), &nbs, &s.cam, params).expect("maps")
    }

    #[test]
    fn rigidity_separates_walkers_from_the_static_scene() {
        let s = synth();
        let params = RigidityParams::default();
        // Fast movers (255) against the static scene (0); slow mover pixels (128) left out.
        let mut roc = RocAccumulator::new(0.5);
        // The same maps with the slow mover pixels counted as static.
        let mut roc_all = RocAccumulator::new(0.5);
        for k in 1..SYNTH_FRAMES - 1 {
            let maps = synth_maps(k, &params);
            for fit in &maps.fits {
                let fit = fit.as_ref().expect("fit");
                assert!(fit.inlier_fraction() > 0.5, "{}", fit.inlier_fraction());
            }
            let mask = s.frames[k].2.as_raw();
            add_fast_movers(&mut roc, &maps.p, mask);
            let fast: Vec<bool> = mask.iter().map(|&m| m == 255).collect();
            roc_all.add(maps.p.as_raw(), &fast);
            let slow: Vec<bool> = mask.iter().map(|&m| m == 128).collect();
            let still: Vec<bool> = mask.iter().map(|&m| m == 0).collect();
            eprintln!(
                "frame {k}: mean P fast movers {:.3}, slow movers {:.3}, static {:.3}",
                mean_where(&maps.p, &fast),
                mean_where(&maps.p, &slow),
                mean_where(&maps.p, &still),
            );
        }
        let auc = roc.auc().expect("both classes");
        eprintln!(
            "rigidity on walking_xyz 320×240: AUC {auc:.3} (slow movers counted static: {:?}), \
             IoU(P > 0.5) {:?}, fast mover px {}",
            roc_all.auc(),
            roc.iou(),
            roc.positives()
        );
        assert!(roc.positives() > 5000, "walkers in view");
        assert!(auc > 0.85, "AUC {auc}");
    }

    /// P of the fast movers (mask 255) against the static scene (0) into `roc`; slow mover
    /// pixels (128) left out.
    fn add_fast_movers(roc: &mut RocAccumulator, p: &FloatImage, mask: &[u8]) {
        let (p, pos): (Vec<f32>, Vec<bool>) = p
            .iter()
            .zip(mask)
            .filter(|(_, m)| **m != 128)
            .map(|(p, m)| (*p, *m == 255))
            .unzip();
        roc.add(&p, &pos);
    }

    fn mean_where(p: &FloatImage, mask: &[bool]) -> f64 {
        let (s, n) = p
            .iter()
            .zip(mask)
            .filter(|(_, m)| **m)
            .fold((0.0, 0usize), |(s, n), (v, _)| (s + *v as f64, n + 1));
        s / n.max(1) as f64
    }

    #[test]
    fn rigidity_is_deterministic_and_independent_of_the_thread_count() {
        let params = RigidityParams::default();
        let bits = |m: &RigidityMaps| -> (Vec<u32>, Vec<u32>) {
            (
                m.p.iter().map(|v| v.to_bits()).collect(),
                m.residual.iter().map(|v| v.to_bits()).collect(),
            )
        };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool")
                .install(|| synth_maps(2, &params))
        };
        let a = run(1);
        let b = run(2);
        let c = run(2);
        assert_eq!(bits(&a), bits(&b));
        assert_eq!(bits(&b), bits(&c));
        assert_eq!(a.fits, b.fits);
    }

    #[test]
    fn without_neighbours_or_fits_p_is_zero() {
        let cam = small_camera();
        let (w, h) = (cam.width, cam.height);
        let gray = GrayImage::new(w, h);
        let depth = FloatImage::new(w, h); // no depth anywhere: no correspondences
        let cur = RigidFrame {
            gray: &gray,
            depth: &depth,
            offset: 0,
        };
        let params = RigidityParams::default();
        let maps = rigidity_probability(&cur, &[cur], &cam, &params).unwrap();
        assert!(maps.p.iter().all(|&v| v == 0.0));
        assert!(maps.residual.iter().all(|v| v.is_nan()));
        assert!(matches!(
            maps.fits[0],
            Err(RigidFitError::TooFewCorrespondences { got: 0, .. })
        ));
        let maps = rigidity_probability(&cur, &[], &cam, &params).unwrap();
        assert!(maps.fits.is_empty() && maps.p.iter().all(|&v| v == 0.0));
        let small = GrayImage::new(w - 1, h);
        let nb = RigidFrame {
            gray: &small,
            depth: &depth,
            offset: 1,
        };
        assert!(matches!(
            rigidity_probability(&cur, &[nb], &cam, &params),
            Err(MotionError::SizeMismatch { .. })
        ));
    }
}
