//! The ranges of the DIS parameters ([`dynapix_params::Validate`]): pyramid levels,
//! patches and iteration counts bounded so a flow ends, weights finite and non-negative, the
//! SOR relaxation factor in (0, 2). [`DisParams`] keeps its own `validate` (the flow error
//! type, what a flow cannot run without); the [`Validate`] implementation adds the rest.

use dynapix_params::{Checked, InvalidParam, Validate, above, nested, optional, range};

use crate::dis::DisParams;
use crate::variational::VariationalParams;

/// Deepest pyramid level (an image 65,536 pixels wide has 16 halvings).
const MAX_SCALE: usize = 16;
/// Largest iteration count of one level.
const MAX_ITERATIONS: usize = 1000;

impl Validate for VariationalParams {
    fn validate(&self) -> Checked {
        range(
            "fixed_point_iterations",
            self.fixed_point_iterations,
            0,
            100,
        )?;
        range("sor_iterations", self.sor_iterations, 0, 100)?;
        if !(self.omega > 0.0 && self.omega < 2.0) {
            return Err(InvalidParam::new(
                "omega",
                format!("must lie in (0, 2), got {}", self.omega),
            ));
        }
        range("alpha", self.alpha, 0.0, 1e4)?;
        range("delta", self.delta, 0.0, 1e4)?;
        range("gamma", self.gamma, 0.0, 1e4)?;
        above("zeta", self.zeta, 0.0, 1e3)?;
        above("epsilon", self.epsilon, 0.0, 1.0)
    }
}

impl Validate for DisParams {
    fn validate(&self) -> Checked {
        range("finest_scale", self.finest_scale, 0, MAX_SCALE)?;
        optional("coarsest_scale", self.coarsest_scale, 0, MAX_SCALE)?;
        range("patch_size", self.patch_size, 1, 64)?;
        range("patch_stride", self.patch_stride, 1, 64)?;
        range(
            "grad_descent_iterations",
            self.grad_descent_iterations,
            0,
            MAX_ITERATIONS,
        )?;
        above("descent_step", self.descent_step, 0.0, 10.0)?;
        range("propagation_bands", self.propagation_bands, 1, 1024)?;
        nested("variational", &self.variational)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Preset;

    #[test]
    fn presets_pass_and_absurd_values_are_named() {
        for p in [Preset::Ultrafast, Preset::Fast, Preset::Medium] {
            Validate::validate(&DisParams::preset(p)).unwrap();
        }
        let mut p = DisParams::default();
        p.variational.sor_iterations = 1_000_000_000_000;
        assert_eq!(
            Validate::validate(&p).unwrap_err().key,
            "variational.sor_iterations"
        );
        let p = DisParams {
            patch_size: 0,
            ..Default::default()
        };
        assert_eq!(Validate::validate(&p).unwrap_err().key, "patch_size");
    }
}
