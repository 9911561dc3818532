//! The colours of the recording: keypoints by use, map points by weight, P as an overlay.

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

/// Writes the RGBA overlay of the motion probability P = 1 − `w` into `out` (red, alpha
/// growing with P, transparent where P = 0).
pub fn overlay(weights: &[f32], out: &mut Vec<u8>) {
    out.clear();
    out.reserve(weights.len() * 4);
    for &w in weights {
        let p = (1.0 - w).clamp(0.0, 1.0);
        out.extend_from_slice(&[255, 30, 30, (p * 200.0) as u8]);
    }
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
        overlay(&[1.0, 0.0, 0.5], &mut o);
        assert_eq!(o.len(), 12);
        assert_eq!((o[3], o[7], o[11]), (0, 200, 100));
    }
}
