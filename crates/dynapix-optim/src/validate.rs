//! The ranges of the solver parameters ([`dynapix_params::Validate`]): iteration and round
//! counts bounded so a run ends (at most 1000), χ² thresholds positive and finite.

use dynapix_params::{Checked, Validate, above, below, range};

use crate::{BaParams, PoseGraphParams, PoseOnlyParams};

/// Largest iteration or round count of a solver.
pub const MAX_ITERATIONS: usize = 1000;
/// Largest χ² threshold.
pub const MAX_CHI2: f64 = 1e6;

impl Validate for PoseOnlyParams {
    fn validate(&self) -> Checked {
        range("rounds", self.rounds, 1, 100)?;
        range("iterations", self.iterations, 1, MAX_ITERATIONS)?;
        above("chi2_mono", self.chi2_mono, 0.0, MAX_CHI2)?;
        above("chi2_stereo", self.chi2_stereo, 0.0, MAX_CHI2)?;
        range("robust_rounds", self.robust_rounds, 0, 100)?;
        range(
            "min_edges_for_rounds",
            self.min_edges_for_rounds,
            0,
            1_000_000,
        )
    }
}

impl Validate for BaParams {
    fn validate(&self) -> Checked {
        range(
            "iterations_robust",
            self.iterations_robust,
            0,
            MAX_ITERATIONS,
        )?;
        range(
            "iterations_refine",
            self.iterations_refine,
            0,
            MAX_ITERATIONS,
        )?;
        below(
            "min_relative_decrease",
            self.min_relative_decrease,
            0.0,
            1.0,
        )?;
        above("chi2_mono", self.chi2_mono, 0.0, MAX_CHI2)?;
        above("chi2_stereo", self.chi2_stereo, 0.0, MAX_CHI2)
    }
}

impl Validate for PoseGraphParams {
    fn validate(&self) -> Checked {
        range("iterations", self.iterations, 0, MAX_ITERATIONS)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_pass_and_absurd_values_are_named() {
        PoseOnlyParams::default().validate().unwrap();
        BaParams::default().validate().unwrap();
        PoseGraphParams::default().validate().unwrap();
        let p = PoseOnlyParams {
            rounds: 1_000_000_000_000,
            ..Default::default()
        };
        let e = p.validate().unwrap_err();
        assert_eq!(e.key, "rounds");
        assert!(e.to_string().contains("[1, 100]"), "{e}");
        let b = BaParams {
            chi2_stereo: -1.0,
            ..Default::default()
        };
        assert_eq!(b.validate().unwrap_err().key, "chi2_stereo");
        let b = BaParams {
            min_relative_decrease: 1.0,
            ..Default::default()
        };
        assert_eq!(b.validate().unwrap_err().key, "min_relative_decrease");
    }
}
