//! Seeded pose perturbation, for measuring how the motion probability degrades with imperfect
//! poses (issue: "poses with 1 cm / 1° noise"). Each pose gets an independent left
//! perturbation whose translation and rotation-vector components are Gaussian with standard
//! deviations σ_t/√3 and σ_r/√3, so the RMS translation error is σ_t and the RMS angle σ_r.

use dynapix_geometry::Se3;
use nalgebra::{Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    // Box-Muller; 1 − u keeps the logarithm finite.
    let u: f64 = 1.0 - rng.random::<f64>();
    let v: f64 = rng.random::<f64>();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

/// Perturbs every pose: `T' = ΔT · T` with RMS translation `sigma_t` (metres) and RMS rotation
/// `sigma_r_deg` (degrees). Deterministic for a given `seed`.
pub fn perturb_poses(poses: &[Se3], sigma_t: f64, sigma_r_deg: f64, seed: u64) -> Vec<Se3> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let st = sigma_t / 3f64.sqrt();
    let sr = sigma_r_deg.to_radians() / 3f64.sqrt();
    poses
        .iter()
        .map(|t| {
            let dt = Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng)) * st;
            let dr = Vector3::new(gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng)) * sr;
            let delta =
                Se3::from_parts(Translation3::from(dt), UnitQuaternion::from_scaled_axis(dr));
            // Perturb the camera in its own frame so the centre moves by exactly dt.
            let mut out = *t;
            out.translation.vector += t.rotation * delta.translation.vector;
            out.rotation = t.rotation * delta.rotation;
            out
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_has_the_requested_size_and_is_seeded() {
        let poses = vec![Se3::translation(1.0, 2.0, 3.0); 4000];
        let a = perturb_poses(&poses, 0.01, 1.0, 7);
        let b = perturb_poses(&poses, 0.01, 1.0, 7);
        assert_eq!(a, b);
        let n = a.len() as f64;
        let rms_t = (a
            .iter()
            .map(|p| (p.translation.vector - poses[0].translation.vector).norm_squared())
            .sum::<f64>()
            / n)
            .sqrt();
        let rms_r = (a.iter().map(|p| p.rotation.angle().powi(2)).sum::<f64>() / n).sqrt();
        assert!((rms_t - 0.01).abs() < 0.0005, "{rms_t}");
        assert!(
            (rms_r.to_degrees() - 1.0).abs() < 0.05,
            "{}",
            rms_r.to_degrees()
        );
    }
}
