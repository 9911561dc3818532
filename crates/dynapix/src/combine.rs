//! The one place where the cues of a frame become its motion probability P, offline and
//! online alike: the enabled cues ([`crate::Cues`]) combined by noisy-or,
//! `P = 1 − Π(1 − P_cue)`, in the fixed order paper terms, geometric, rigidity (P starts as
//! the paper's terms when that cue is on, else 0, and each further cue is noisy-or'ed into
//! it).
//! The order is fixed because floating-point noisy-or is not exactly associative: the same
//! cues always give the same bytes.

use dynapix_motion::{FloatImage, MotionError, noisy_or};

/// The cues of one frame, each present when enabled.
#[derive(Debug, Default)]
pub struct FrameCues {
    /// The paper's terms, P = D·M.
    pub paper: Option<FloatImage>,
    /// The geometric cue (static depth).
    pub geometric: Option<FloatImage>,
    /// The rigidity cue.
    pub rigidity: Option<FloatImage>,
}

impl FrameCues {
    /// P of the frame, `width`×`height` (the size of every cue; another size is an error).
    pub fn combine(self, width: u32, height: u32) -> Result<FloatImage, MotionError> {
        let mut p = match self.paper {
            Some(paper) => {
                if paper.dimensions() != (width, height) {
                    // Refused by the size check of the combination itself.
                    noisy_or(&mut FloatImage::new(width, height), &paper)?;
                }
                paper
            }
            None => FloatImage::new(width, height),
        };
        for cue in [self.geometric, self.rigidity].iter().flatten() {
            noisy_or(&mut p, cue)?;
        }
        Ok(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Luma;

    #[test]
    fn cues_combine_in_one_order_by_noisy_or() {
        let px = |v: f32| FloatImage::from_pixel(2, 1, Luma([v]));
        // No cue: nothing moves.
        let none = FrameCues::default().combine(2, 1).unwrap();
        assert_eq!(none.as_raw(), &vec![0.0; 2]);
        // The paper's terms are taken as they are (bit for bit, not 1 − (1 − P)); any other
        // cue is noisy-or'ed into P = 0.
        let paper = FrameCues {
            paper: Some(px(0.1)),
            ..Default::default()
        };
        assert_eq!(
            paper.combine(2, 1).unwrap().as_raw()[0].to_bits(),
            0.1f32.to_bits()
        );
        let geometric = FrameCues {
            geometric: Some(px(0.1)),
            ..Default::default()
        };
        let mut zero = FloatImage::new(2, 1);
        noisy_or(&mut zero, &px(0.1)).unwrap();
        assert_eq!(geometric.combine(2, 1).unwrap(), zero);
        // Three cues: paper, then geometric, then rigidity.
        let all = FrameCues {
            paper: Some(px(0.5)),
            geometric: Some(px(0.2)),
            rigidity: Some(px(0.1)),
        }
        .combine(2, 1)
        .unwrap();
        let mut expected = px(0.5);
        noisy_or(&mut expected, &px(0.2)).unwrap();
        noisy_or(&mut expected, &px(0.1)).unwrap();
        assert_eq!(all, expected);
        assert!((all.as_raw()[0] - (1.0 - 0.5 * 0.8 * 0.9)).abs() < 1e-6);
        // A cue of another size is refused, also when it comes first.
        let bad = FrameCues {
            paper: Some(FloatImage::new(3, 1)),
            ..Default::default()
        };
        assert!(bad.combine(2, 1).is_err());
    }
}
