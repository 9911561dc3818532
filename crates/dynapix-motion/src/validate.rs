//! The ranges of the motion-map parameters ([`dynapix_params::Validate`]), checked before a
//! run starts: sizes and counts bounded so memory and time stay finite (a low-pass of at most
//! σ = 100 px, at most 100 refinement rounds, neighbour offsets within ±60 frames), fractions
//! and probabilities in [0, 1], thresholds and scales positive, and the pairs that must be
//! ordered ordered (`clip_lo < clip_hi`, `r0 < r1`). [`StaticDepthParams`] and
//! [`RigidityParams`] keep their own `validate` (the motion error type); their
//! [`Validate`] implementation checks each field's range first, so the error names the field
//! that is out of range, then runs it for the rules between fields.

use dynapix_params::{
    Checked, InvalidParam, Validate, above, each, nested, optional, probability, range,
};

use crate::MotionError;
use crate::background::{ReconstructParams, Statistic};
use crate::movable::{MinExclusion, MovableParams};
use crate::moving::MovingParams;
use crate::pipeline::MotionParams;
use crate::rigidity::RigidityParams;
use crate::splat::SplatParams;
use crate::static_depth::StaticDepthParams;

/// Largest neighbour frame offset (2 s at 30 frames/s).
pub const MAX_OFFSET: i64 = 60;
/// Most neighbour offsets of one cue.
const MAX_OFFSETS: usize = 16;
/// Largest image width of a working resolution.
const MAX_WIDTH: u32 = 16_384;
/// Largest morphology radius (working pixels).
const MAX_RADIUS: u32 = 64;
/// Largest grey-level value (8-bit images).
const GREY: f32 = 255.0;

/// Offsets: 1 to 16 of them, each non-zero and within ±[`MAX_OFFSET`].
fn offsets(key: &str, v: &[i64]) -> Checked {
    each(key, v, (1, MAX_OFFSETS), -MAX_OFFSET, MAX_OFFSET)?;
    if let Some(i) = v.iter().position(|&o| o == 0) {
        return Err(InvalidParam::new(
            format!("{key}[{i}]"),
            "must not be 0 (a frame is not its own neighbour)",
        ));
    }
    Ok(())
}

/// The motion crate's own range error as a keyed one.
fn keyed(e: MotionError) -> InvalidParam {
    match e {
        MotionError::InvalidParam { name, message } => InvalidParam::new(name, message),
        other => InvalidParam::new("", other.to_string()),
    }
}

impl Validate for MovableParams {
    fn validate(&self) -> Checked {
        range("clip_lo", self.clip_lo, 0.0, GREY)?;
        range("clip_hi", self.clip_hi, 0.0, GREY)?;
        if self.clip_hi <= self.clip_lo {
            return Err(InvalidParam::new(
                "clip_hi",
                format!("must exceed clip_lo ({} ≤ {})", self.clip_hi, self.clip_lo),
            ));
        }
        above("max_depth", self.max_depth, 0.0, 1000.0)?;
        above("robust_max_fraction", self.robust_max_fraction, 0.0, 1.0)?;
        above("robust_min_fraction", self.robust_min_fraction, 0.0, 1.0)?;
        if let MinExclusion::AtMost(v) = self.min_exclusion {
            range("min_exclusion.at_most", v, 0.0, GREY)?;
        }
        range("exclusion_substitute", self.exclusion_substitute, 0.0, 1e4)?;
        range("lambda_slope", self.lambda_slope, 0.0, 100.0)?;
        above("denominator_eps", self.denominator_eps, 0.0, 1.0)?;
        optional("range_guard", self.range_guard, 0.0, GREY)
    }
}

impl Validate for SplatParams {
    fn validate(&self) -> Checked {
        above("depth_clamp", self.depth_clamp, 0.0, 1e4)?;
        // exp(sharpness) must stay finite in f64.
        range("sharpness", self.sharpness, 0.0, 500.0)?;
        above("z_temperature", self.z_temperature, 0.0, 100.0)?;
        above("z_cutoff", self.z_cutoff, 0.0, 80.0)?;
        range("min_weight", self.min_weight, 0.0, 100.0)?;
        range("min_depth", self.min_depth, 0.0, 100.0)
    }
}

impl Validate for MovingParams {
    fn validate(&self) -> Checked {
        range("clip[0]", self.clip[0], 0.0, 1e4)?;
        range("clip[1]", self.clip[1], 0.0, 1e4)?;
        if self.clip[1] <= self.clip[0] {
            return Err(InvalidParam::new(
                "clip",
                format!("must be increasing, got {:?}", self.clip),
            ));
        }
        // The blur kernel has 6σ + 1 taps.
        range("lowpass_sigma", self.lowpass_sigma, 0.0, 100.0)?;
        above("norm_fraction", self.norm_fraction, 0.0, 1.0)?;
        range("min_range", self.min_range, 0.0, 1e4)?;
        range("refine_iterations", self.refine_iterations, 0, 100)
    }
}

impl Validate for MotionParams {
    fn validate(&self) -> Checked {
        offsets("offsets", &self.offsets)?;
        nested("movable", &self.movable)?;
        nested("splat", &self.splat)?;
        nested("moving", &self.moving)
    }
}

impl Validate for ReconstructParams {
    fn validate(&self) -> Checked {
        range("radius", self.radius, 0, 300)?;
        range("step", self.step, 1, 300)?;
        nested("splat", &self.splat)?;
        if let Statistic::FarMedian {
            quantile,
            tolerance,
        } = self.statistic
        {
            probability("statistic.far_median.quantile", quantile)?;
            range("statistic.far_median.tolerance", tolerance, 0.0, 10.0)?;
        }
        range("refine_iterations", self.refine_iterations, 0, 100)
    }
}

impl Validate for StaticDepthParams {
    fn validate(&self) -> Checked {
        range("working_width", self.working_width, 1, MAX_WIDTH)?;
        range("window_s", self.window_s, 0.0, 3600.0)?;
        range("max_views", self.max_views, 1, 1000)?;
        range("tol_a", self.tol_a, 0.0, 10.0)?;
        range("tol_b", self.tol_b, 0.0, 10.0)?;
        range("min_support", self.min_support, 1, 1000)?;
        range("min_depth", self.min_depth, 0.0, 100.0)?;
        range("align_radius", self.align_radius, 0, MAX_RADIUS)?;
        range("open_radius", self.open_radius, 0, MAX_RADIUS)?;
        range("dilate_radius", self.dilate_radius, 0, MAX_RADIUS)?;
        range("fill_steps", self.fill_steps, 0, 256)?;
        StaticDepthParams::validate(self).map_err(keyed)
    }
}

impl Validate for RigidityParams {
    fn validate(&self) -> Checked {
        range("flow_working_width", self.flow_working_width, 0, MAX_WIDTH)?;
        range("stride", self.stride, 1, 256)?;
        range("min_depth", self.min_depth, 0.0, 100.0)?;
        range(
            "min_correspondences",
            self.min_correspondences,
            3,
            10_000_000,
        )?;
        range("ransac_iterations", self.ransac_iterations, 1, 100_000)?;
        range("min_sample_area", self.min_sample_area, 0.0, 100.0)?;
        range("chi2", self.chi2, 0.0, 1e6)?;
        range("refine_rounds", self.refine_rounds, 0, 100)?;
        range("sigma_px", self.sigma_px, 0.0, 1000.0)?;
        range("reference_focal_px", self.reference_focal_px, 0.0, 1e5)?;
        range("sigma_z_quadratic", self.sigma_z_quadratic, 0.0, 10.0)?;
        range("sigma_z_constant", self.sigma_z_constant, 0.0, 10.0)?;
        range("min_projected_depth", self.min_projected_depth, 0.0, 100.0)?;
        range("r0", self.r0, 0.0, 1e6)?;
        range("r1", self.r1, 0.0, 1e6)?;
        offsets("offsets", &self.offsets)?;
        RigidityParams::validate(self).map_err(keyed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Mode, Variant};

    #[test]
    fn defaults_pass_and_absurd_values_are_named_up_front() {
        for mode in [Mode::Paper, Mode::Reference] {
            for variant in [Variant::Tum, Variant::Grade] {
                Validate::validate(&MotionParams::new(variant, mode)).unwrap();
            }
        }
        Validate::validate(&ReconstructParams::default()).unwrap();
        Validate::validate(&StaticDepthParams::default()).unwrap();
        Validate::validate(&RigidityParams::default()).unwrap();
        let mut p = MotionParams::default();
        p.moving.lowpass_sigma = 1e12;
        assert_eq!(
            p.validate().unwrap_err().to_string(),
            "moving.lowpass_sigma must lie in [0, 100], got 1000000000000"
        );
        let mut p = MotionParams::default();
        p.movable.clip_hi = 10.0;
        let e = p.validate().unwrap_err().to_string();
        assert!(e.starts_with("movable.clip_hi must exceed clip_lo"), "{e}");
        let r = RigidityParams {
            refine_rounds: 1_000_000_000_000,
            ..Default::default()
        };
        assert_eq!(Validate::validate(&r).unwrap_err().key, "refine_rounds");
        let r = RigidityParams {
            ransac_confidence: -1.0,
            ..Default::default()
        };
        assert_eq!(Validate::validate(&r).unwrap_err().key, "ransac_confidence");
        let p = MotionParams {
            offsets: vec![-1, 0],
            ..Default::default()
        };
        assert_eq!(p.validate().unwrap_err().key, "offsets[1]");
    }
}
