//! The parameters of the static depth and the geometric cue ([`StaticDepthParams`]).

use serde::{Deserialize, Serialize};

use crate::MotionError;

/// Parameters of the static depth and the geometric cue.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StaticDepthParams {
    /// Working image width in pixels (320): the input is subsampled by
    /// `round(width / working_width)` (at least 1).
    pub working_width: u32,
    /// Half width of the time window of neighbour views, in seconds (2.0).
    pub window_s: f64,
    /// Largest number of neighbour views, spread evenly over the window (24).
    pub max_views: usize,
    /// Depth agreement tolerance `tol(z) = tol_a + tol_b·z²`: constant part in metres (0.03).
    pub tol_a: f32,
    /// Depth agreement tolerance: quadratic part in 1/m (0.005; Kinect depth noise grows with
    /// the square of the distance).
    pub tol_b: f32,
    /// Views that must agree on a static surface, the one that sees it included (3).
    pub min_support: usize,
    /// Smallest valid depth in metres (0.1).
    pub min_depth: f32,
    /// Misalignment tolerance in working pixels (2): a pixel is near only when it is nearer
    /// than every static depth within this radius, so static depth edges that the poses
    /// misplace by a pixel or two are not taken for movers.
    pub align_radius: u32,
    /// Opening radius at working resolution (1: 3×3) that removes isolated detections.
    pub open_radius: u32,
    /// Dilation radius at working resolution (4: 9×9) that covers silhouettes, where depth is
    /// unreliable.
    pub dilate_radius: u32,
    /// Steps of 1 working pixel by which detections spread into pixels without depth (8):
    /// dark clothes and hair often have none.
    pub fill_steps: u32,
}

impl Default for StaticDepthParams {
    fn default() -> Self {
        Self {
            working_width: 320,
            window_s: 2.0,
            max_views: 24,
            tol_a: 0.03,
            tol_b: 0.005,
            min_support: 3,
            min_depth: 0.1,
            align_radius: 2,
            open_radius: 1,
            dilate_radius: 4,
            fill_steps: 8,
        }
    }
}

impl StaticDepthParams {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), MotionError> {
        let bad = |name: &'static str, message: &str| {
            Err(MotionError::InvalidParam {
                name,
                message: message.to_string(),
            })
        };
        if self.working_width == 0 {
            return bad("working_width", "must be at least 1");
        }
        if !(self.window_s.is_finite() && self.window_s > 0.0) {
            return bad("window_s", "must be a positive number of seconds");
        }
        if self.max_views == 0 {
            return bad("max_views", "must be at least 1");
        }
        if !(self.tol_a.is_finite() && self.tol_a >= 0.0 && self.tol_b.is_finite())
            || self.tol_b < 0.0
            || self.tol_a + self.tol_b <= 0.0
        {
            return bad("tol_a/tol_b", "must be finite, non-negative and not both 0");
        }
        if self.min_support == 0 {
            return bad("min_support", "must be at least 1");
        }
        if !(self.min_depth.is_finite() && self.min_depth > 0.0) {
            return bad("min_depth", "must be a positive depth in metres");
        }
        Ok(())
    }

    /// Subsampling factor for an image `width` pixels wide.
    pub fn factor(&self, width: u32) -> u32 {
        ((width as f64 / self.working_width.max(1) as f64).round() as u32).max(1)
    }

    /// Depth agreement tolerance at depth `z`.
    pub fn tol(&self, z: f32) -> f32 {
        self.tol_a + self.tol_b * z * z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_parameters_are_refused() {
        let p = StaticDepthParams {
            min_support: 0,
            ..Default::default()
        };
        assert!(p.validate().is_err());
        let p = StaticDepthParams {
            window_s: f64::NAN,
            ..Default::default()
        };
        assert!(p.validate().is_err());
    }
}
