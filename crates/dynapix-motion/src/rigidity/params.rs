//! The parameters of the rigidity cue ([`RigidityParams`]) and their validation.

use dynapix_flow::{DisFlow, DisParams, Preset};
use dynapix_geometry::PinholeCamera;
use serde::{Deserialize, Serialize};

use crate::MotionError;

/// Parameters of the rigidity cue. `Default` holds the values of the prototype.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RigidityParams {
    /// DIS preset of the flow from a frame to its neighbour (used by
    /// [`rigidity_probability`](super::rigidity_probability)).
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
    /// inlier fraction ŵ), checked after every batch of [`RANSAC_BATCH`](super::RANSAC_BATCH)
    /// samples so the result
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
    /// (false). The earlier frame `a` of a pair gets the residual of
    /// [`pair_residuals`](super::pair_residuals)
    /// directly; the later frame `b` gets the residual of the flow a → b turned around
    /// ([`reverse_flow`](super::reverse_flow)) under the inverse motion. Half the flows and fits:
    /// −9 to −13 % CPU
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

pub(super) fn invalid(name: &'static str, message: impl Into<String>) -> MotionError {
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

#[cfg(test)]
mod tests {
    use super::*;

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
    fn pixel_constants_scale_with_the_focal_length() {
        let p = RigidityParams::default();
        let cam = |fx: f64| PinholeCamera::new(640, 480, fx, fx, 320.0, 240.0);
        assert_eq!(p.stride_for(&cam(525.0)), 4);
        assert_eq!(p.stride_for(&cam(262.5)), 2);
        assert_eq!(p.stride_for(&cam(60.0)), 1);
        assert!((p.sigma_px_for(&cam(262.5)) - 0.5).abs() < 1e-12);
    }
}
