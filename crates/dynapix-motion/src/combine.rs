//! Combining motion cues. Cues are evidence of motion from different physics (appearance
//! against a background, flow against the splatted neighbours, depth against the static
//! scene, rigidity against the dominant motion); a pixel is static only when no cue says it
//! moves, so they combine by noisy-or: `P = 1 − Π(1 − P_cue)`.

use crate::{FloatImage, MotionError, check_size};

/// `acc ← 1 − (1 − acc)(1 − other)` pixel by pixel (values clamped to [0, 1]; NaN counts as
/// no evidence, 0).
pub fn noisy_or(acc: &mut FloatImage, other: &FloatImage) -> Result<(), MotionError> {
    check_size("cue", acc.dimensions(), other.dimensions())?;
    let clean = |v: f32| if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    for (a, &b) in acc.iter_mut().zip(other.iter()) {
        *a = 1.0 - (1.0 - clean(*a)) * (1.0 - clean(b));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Luma;
    use proptest::prelude::*;

    #[test]
    fn refuses_other_sizes_and_treats_nan_as_no_evidence() {
        let mut a = FloatImage::from_pixel(2, 2, Luma([0.5]));
        assert!(noisy_or(&mut a, &FloatImage::new(3, 2)).is_err());
        noisy_or(&mut a, &FloatImage::from_pixel(2, 2, Luma([f32::NAN]))).unwrap();
        assert_eq!(a.get_pixel(0, 0)[0], 0.5);
    }

    proptest! {
        /// Laws: 0 is the identity, 1 absorbs, the result is symmetric, in [0, 1] and never
        /// below either input.
        #[test]
        fn noisy_or_laws(x in 0.0f32..=1.0, y in 0.0f32..=1.0) {
            let one = |v: f32| FloatImage::from_pixel(1, 1, Luma([v]));
            let run = |a: f32, b: f32| {
                let mut acc = one(a);
                noisy_or(&mut acc, &one(b)).unwrap();
                acc.get_pixel(0, 0)[0]
            };
            prop_assert!((run(x, 0.0) - x).abs() < 1e-6);
            prop_assert_eq!(run(x, 1.0), 1.0);
            prop_assert!((run(x, y) - run(y, x)).abs() < 1e-6);
            let r = run(x, y);
            prop_assert!((0.0..=1.0).contains(&r) && r >= x.max(y) - 1e-6);
        }
    }
}
