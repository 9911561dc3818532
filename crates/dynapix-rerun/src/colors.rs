//! The colours of the recording: keypoints by use, map points by weight, P as an overlay
//! (classes of P with their colours).

use dynapix::KeypointUse;

/// Green: a keypoint used at full weight.
pub const USED: [u8; 4] = [40, 220, 60, 255];
/// Orange: a down-weighted keypoint.
pub const DOWN_WEIGHTED: [u8; 4] = [255, 170, 0, 255];
/// Red: a refused keypoint.
pub const REFUSED: [u8; 4] = [235, 30, 30, 255];
/// Magenta: map points removed as moving.
pub const REMOVED: [u8; 4] = [230, 40, 200, 255];
/// Blue: keyframes.
pub const KEYFRAME: [u8; 4] = [60, 140, 255, 255];
/// Cyan: the estimated trajectory.
pub const ESTIMATE: [u8; 4] = [0, 200, 230, 255];
/// Grey: the ground truth.
pub const GROUND_TRUTH: [u8; 4] = [200, 200, 200, 255];

/// The colour of a keypoint by its use.
pub fn keypoint(usage: KeypointUse) -> [u8; 4] {
    match usage {
        KeypointUse::Used => USED,
        KeypointUse::DownWeighted => DOWN_WEIGHTED,
        KeypointUse::Refused => REFUSED,
    }
}

/// The colour of a map point of static weight `w` ∈ [0, 1]: green at 1, through yellow, to
/// red at 0.
pub fn weight(w: f32) -> [u8; 4] {
    let w = w.clamp(0.0, 1.0);
    let r = (255.0 * (2.0 * (1.0 - w)).min(1.0)) as u8;
    let g = (220.0 * (2.0 * w).min(1.0)) as u8;
    [r, g, 40, 255]
}

/// Levels of the motion probability in the P overlay: class k ∈ 0..=`P_LEVELS` stands for
/// P ≈ k / `P_LEVELS`.
pub const P_LEVELS: u8 = 8;

/// Writes the P overlay's class of every pixel of the static weights `weights` (P = 1 − w)
/// into `out`: `round(P · P_LEVELS)`, one byte per pixel (a Rerun segmentation image).
pub fn motion_classes(weights: &[f32], out: &mut Vec<u8>) {
    out.clear();
    out.extend(weights.iter().map(|&w| {
        let p = (1.0 - w).clamp(0.0, 1.0);
        // Rounded to the nearest class (p ≥ 0, so + 0.5 and truncation round).
        (p * f32::from(P_LEVELS) + 0.5) as u8
    }));
}

/// The colour of P overlay class `k` (see [`motion_classes`]): transparent at P ≈ 0, then
/// red with an opacity growing with P (at most 220 of 255, so the image stays visible).
/// The colour is premultiplied by its opacity, so that class 0 is (0, 0, 0, 0) whether the
/// viewer blends premultiplied or straight colours (with straight blending the red of a
/// class only looks darker).
pub fn motion_class(k: u8) -> [u8; 4] {
    let k = k.min(P_LEVELS);
    let alpha = 220 * u32::from(k) / u32::from(P_LEVELS);
    let premultiplied = |c: u32| (c * alpha / 255) as u8;
    [
        premultiplied(255),
        premultiplied(30),
        premultiplied(30),
        alpha as u8,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_run_from_green_to_red() {
        assert_eq!(weight(1.0), [0, 220, 40, 255]);
        assert_eq!(weight(0.0), [255, 0, 40, 255]);
        let mid = weight(0.5);
        assert_eq!((mid[0], mid[1]), (255, 220));
        let mut o = Vec::new();
        motion_classes(&[1.0, 0.0, 0.5, 0.96, 1.5], &mut o);
        assert_eq!(o, [0, P_LEVELS, P_LEVELS / 2, 0, 0]);
        assert_eq!(motion_class(0), [0; 4], "P = 0 leaves the image as it is");
        assert_eq!(motion_class(P_LEVELS), [220, 25, 25, 220]);
        assert_eq!(motion_class(P_LEVELS / 2)[3], 110);
    }
}
