//! The methods of the paper's tables and the one paper/reference switch (paper §4 and the
//! supplementary ablations; design §5).

use std::fmt;
use std::str::FromStr;

use dynapix_slam::weighting::Weighting;
use serde::{Deserialize, Serialize};

/// A method of the paper's tables: the baseline, DynaPix, DynaPix+ and the ablations. All run
/// from the same code; they differ in which motion terms the maps use and how the SLAM
/// backend weights keypoints.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Method {
    /// Plain ORB-SLAM2 RGB-D (no motion probabilities).
    #[serde(rename = "orbslam2")]
    Orbslam2,
    /// DynaPix: motion-probability weights, birth gate, per-point deletion.
    #[default]
    #[serde(rename = "dynapix")]
    Dynapix,
    /// DynaPix+: DynaPix plus semantic masks that gate map-point creation.
    #[serde(rename = "dynapix+")]
    #[cfg_attr(feature = "clap", value(name = "dynapix+"))]
    DynapixPlus,
    /// Ablation: motion probability without the movable term (D = 1).
    #[serde(rename = "no-movable")]
    NoMovable,
    /// Ablation: motion probability without the moving term (M = 1).
    #[serde(rename = "no-moving")]
    NoMoving,
    /// Ablation: keypoints with P > γ_add ignored, unweighted optimisation.
    #[serde(rename = "threshold")]
    Threshold,
}

/// Which terms a method's motion maps use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub(crate) enum Terms {
    /// P = D·M.
    Full,
    /// P = M (no movable term).
    NoMovable,
    /// P = D (no moving term).
    NoMoving,
}

impl Method {
    /// Every method, in the order of the paper's tables.
    pub const ALL: [Method; 6] = [
        Method::Orbslam2,
        Method::Dynapix,
        Method::DynapixPlus,
        Method::NoMovable,
        Method::NoMoving,
        Method::Threshold,
    ];

    /// The name used on command lines, in configuration files and in outputs.
    pub fn name(self) -> &'static str {
        match self {
            Method::Orbslam2 => "orbslam2",
            Method::Dynapix => "dynapix",
            Method::DynapixPlus => "dynapix+",
            Method::NoMovable => "no-movable",
            Method::NoMoving => "no-moving",
            Method::Threshold => "threshold",
        }
    }

    /// The motion terms of the method's maps: methods with the same terms share their maps
    /// (`full`, `no-movable` or `no-moving`); `None` for ORB-SLAM2 (no maps).
    pub fn map_terms(self) -> Option<&'static str> {
        self.terms().map(|t| match t {
            Terms::Full => "full",
            Terms::NoMovable => "no-movable",
            Terms::NoMoving => "no-moving",
        })
    }

    /// The motion terms of the method's maps; `None` for ORB-SLAM2 (no maps).
    pub(crate) fn terms(self) -> Option<Terms> {
        match self {
            Method::Orbslam2 => None,
            Method::NoMovable => Some(Terms::NoMovable),
            Method::NoMoving => Some(Terms::NoMoving),
            Method::Dynapix | Method::DynapixPlus | Method::Threshold => Some(Terms::Full),
        }
    }

    /// True when the method needs semantic masks (DynaPix+).
    pub fn needs_masks(self) -> bool {
        self == Method::DynapixPlus
    }

    /// True for the threshold ablation: P > γ_add drops a keypoint, the rest is unweighted.
    pub fn thresholds(self) -> bool {
        self == Method::Threshold
    }

    /// The SLAM backend's behaviour for this method in `mode`: off for ORB-SLAM2 and the
    /// threshold ablation (which only drops keypoints), else the mode's weighting.
    pub fn weighting(self, mode: Mode) -> Weighting {
        match self {
            Method::Orbslam2 | Method::Threshold => Weighting::Off,
            _ => mode.weighting(),
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Method::ALL
            .into_iter()
            .find(|m| m.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| {
                let names: Vec<&str> = Method::ALL.iter().map(|m| m.name()).collect();
                format!(
                    "unknown method {s:?} (expected one of {})",
                    names.join(", ")
                )
            })
    }
}

/// Paper or reference behaviour: the one switch for both the motion maps and the SLAM
/// weighting (design §5). Every mode-dependent default of [`crate::Config`] follows it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Mode {
    /// The paper's method with the reference code's defects fixed (default).
    #[default]
    Paper,
    /// What the reference code does, constant by constant.
    Reference,
}

impl Mode {
    /// The motion crate's behaviour switch.
    pub fn motion(self) -> dynapix_motion::Mode {
        match self {
            Mode::Paper => dynapix_motion::Mode::Paper,
            Mode::Reference => dynapix_motion::Mode::Reference,
        }
    }

    /// The SLAM backend's weighting in this mode (for a method that weights).
    pub fn weighting(self) -> Weighting {
        match self {
            Mode::Paper => Weighting::Paper,
            Mode::Reference => Weighting::Reference,
        }
    }

    /// The name used in configuration files.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Paper => "paper",
            Mode::Reference => "reference",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_decide_terms_and_weighting() {
        for m in Method::ALL {
            assert_eq!(m.name().parse::<Method>().unwrap(), m);
            let json = serde_json::to_string(&m).unwrap();
            assert_eq!(json, format!("\"{}\"", m.name()));
        }
        assert!("bogus".parse::<Method>().unwrap_err().contains("dynapix+"));
        assert_eq!(Method::Orbslam2.terms(), None);
        assert_eq!(Method::NoMovable.terms(), Some(Terms::NoMovable));
        assert_eq!(Method::Threshold.weighting(Mode::Paper), Weighting::Off);
        assert_eq!(
            Method::Dynapix.weighting(Mode::Reference),
            Weighting::Reference
        );
    }
}
