//! Which raw depth values are measurements. An RGB-D sensor writes its largest value
//! (65535 in a 16-bit PNG) where a pixel saturates or its reading cannot be encoded, and
//! values far beyond its range where a reflection fooled it; neither is a depth. Every
//! consumer (SLAM, the rigidity cue, the static depth, the paper's terms) reads depth through
//! [`crate::Sequence`], which decodes it here, so such pixels reach all of them as missing
//! (0), like the sensor's own holes, and none has to know about them.

use image::ImageBuffer;
use serde::{Deserialize, Serialize};

use crate::images::{DepthImage, Gray16Image};

/// Largest plausible depth of an RGB-D sensor by default, in metres: Kinect-class sensors
/// measure to about 10 m, and TUM's 16-bit files (5000 units per metre) cannot hold more
/// than 13.1 m.
pub const DEFAULT_MAX_DEPTH: f32 = 20.0;

/// Which depth values are measurements (configurable per camera: the keys `depth_saturation`
/// and `depth_max_m` of its settings file, overridden by `sequence.depth_saturation` and
/// `sequence.max_depth` of a run's configuration; see [`DepthLimits`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DepthValidity {
    /// The raw value the sensor writes at saturation (65535); `None`: every raw value is a
    /// depth.
    pub saturation: Option<u16>,
    /// Depths beyond this (metres) are missing.
    pub max_depth: f32,
}

impl Default for DepthValidity {
    fn default() -> Self {
        Self {
            saturation: Some(u16::MAX),
            max_depth: DEFAULT_MAX_DEPTH,
        }
    }
}

impl DepthValidity {
    /// Every raw value is a depth (what files held before these rules).
    pub const ALL: DepthValidity = DepthValidity {
        saturation: None,
        max_depth: f32::INFINITY,
    };
}

/// The depth limits one source states (a camera's `camera.yaml`, a run's configuration),
/// each `None` where it states nothing: [`DepthLimits::or`] lets a source override another
/// key by key, [`DepthLimits::validity`] fills what no source stated with the defaults
/// ([`DepthValidity::default`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DepthLimits {
    /// The raw saturation value: `Some(Some(v))` the value `v`, `Some(None)` none (every raw
    /// value is a depth), `None` not stated.
    pub saturation: Option<Option<u16>>,
    /// The largest plausible depth in metres, `None` when not stated.
    pub max_depth: Option<f32>,
}

impl DepthLimits {
    /// True when the source states neither limit.
    pub fn is_empty(&self) -> bool {
        self.saturation.is_none() && self.max_depth.is_none()
    }

    /// These limits where stated, `under`'s for the rest.
    pub fn or(self, under: DepthLimits) -> DepthLimits {
        DepthLimits {
            saturation: self.saturation.or(under.saturation),
            max_depth: self.max_depth.or(under.max_depth),
        }
    }

    /// The validity rule: the stated limits, the defaults for the others.
    pub fn validity(self) -> DepthValidity {
        let d = DepthValidity::default();
        DepthValidity {
            saturation: self.saturation.unwrap_or(d.saturation),
            max_depth: self.max_depth.unwrap_or(d.max_depth),
        }
    }
}

/// Raw depth in metres like [`crate::images::depth_to_metres`] (`value · (1/depth_factor)`
/// in `f32`, so valid pixels have the same bits), with the values that are no measurement
/// ([`DepthValidity`]) set to 0 (missing). Also returns how many pixels were set to 0.
pub fn depth_to_metres_valid(
    raw: &Gray16Image,
    depth_factor: f64,
    validity: &DepthValidity,
) -> (DepthImage, usize) {
    let scale = 1.0f32 / depth_factor as f32;
    let mut invalid = 0usize;
    let metres: Vec<f32> = raw
        .as_raw()
        .iter()
        .map(|&v| {
            let m = v as f32 * scale;
            if Some(v) == validity.saturation || m > validity.max_depth {
                invalid += 1;
                0.0
            } else {
                m
            }
        })
        .collect();
    let img = ImageBuffer::from_raw(raw.width(), raw.height(), metres)
        .unwrap_or_else(|| ImageBuffer::new(raw.width(), raw.height()));
    (img, invalid)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::images::depth_to_metres;

    #[test]
    fn saturated_and_implausible_depths_are_missing_and_the_rest_keeps_its_bits() {
        let raw = Gray16Image::from_fn(6, 5, |x, y| {
            image::Luma([match (x, y) {
                (0, 0) => u16::MAX,
                (1, 0) => 0,
                (2, 0) => 60_000, // 12 m at 5000 units per metre
                _ => (x * 1000 + y * 97 + 1) as u16,
            }])
        });
        let plain = depth_to_metres(&raw, 5000.0);
        let (valid, n) = depth_to_metres_valid(&raw, 5000.0, &DepthValidity::default());
        assert_eq!(n, 1);
        assert_eq!(valid.get_pixel(0, 0)[0], 0.0);
        for (a, b) in plain.pixels().zip(valid.pixels()).skip(1) {
            assert_eq!(a[0].to_bits(), b[0].to_bits());
        }
        let close = DepthValidity {
            saturation: Some(u16::MAX),
            max_depth: 10.0,
        };
        let (d, n) = depth_to_metres_valid(&raw, 5000.0, &close);
        assert_eq!((n, d.get_pixel(2, 0)[0]), (2, 0.0));
        let (all, n) = depth_to_metres_valid(&raw, 5000.0, &DepthValidity::ALL);
        assert_eq!(n, 0);
        assert_eq!(all, plain);
    }

    #[test]
    fn limits_override_key_by_key_and_default_the_rest() {
        let camera = DepthLimits {
            saturation: Some(Some(4000)),
            max_depth: Some(4.5),
        };
        let config = DepthLimits {
            saturation: Some(None),
            max_depth: None,
        };
        assert!(DepthLimits::default().is_empty() && !config.is_empty());
        let v = config.or(camera).validity();
        assert_eq!((v.saturation, v.max_depth), (None, 4.5));
        assert_eq!(camera.validity().saturation, Some(4000));
        assert_eq!(DepthLimits::default().validity(), DepthValidity::default());
    }
}
