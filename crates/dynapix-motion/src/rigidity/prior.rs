//! The static motion with the map's help (issue 33, crowds that fill the view): when a pose
//! prior for a frame pair is known (the relative pose of the two frames in the trajectory of
//! a previous SLAM pass), the pair's motion is chosen with it instead of by majority alone.
//!
//! - [`fit_from_prior`]: the fit seeded by the prior, i.e. [`RigidityParams::refine_rounds`]
//!   rounds of Kabsch on the inliers of the prior motion, as RANSAC's refinement does on the
//!   inliers of its best sample. It finds the static scene's motion whatever share of the
//!   correspondences the static scene has, as long as the prior lies within the inlier
//!   tolerance of it.
//! - [`choose_with_prior`]: the dominant motion is kept, unchanged, when it agrees with the
//!   seeded fit ([`motions_agree`]: the two move the correspondences to within the inlier
//!   tolerance of each other, in the median); when it disagrees (movers dominate) or when
//!   there is no dominant motion ([`RigidFitError::Ambiguous`]), the seeded fit replaces it,
//!   provided it has at least [`RigidityParams::min_correspondences`] inliers.

use dynapix_geometry::{PinholeCamera, Se3};
use serde::Serialize;

use super::fit::{inliers_of, refine, targets_of};
use super::pair::Model;
use super::params::RigidityParams;
use super::{Correspondences, RigidFit, RigidFitError};
use crate::MotionError;

/// How the motion of a frame pair was chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PriorChoice {
    /// No prior was given: the dominant motion (the pose-free cue).
    #[default]
    NoPrior,
    /// The dominant motion agrees with the fit seeded by the prior: kept unchanged.
    Agrees,
    /// The dominant motion disagrees with the prior: the fit seeded by it replaces it.
    Disagrees,
    /// There was no dominant motion (ambiguous pair): the fit seeded by the prior is used.
    Ambiguous,
    /// The fit seeded by the prior has too few inliers: the pose-free outcome is kept.
    Unsupported,
    /// The pair could not be fitted at all (too few correspondences, degenerate).
    Failed,
}

/// The rigid motion of `corr` seeded by `prior`: [`RigidityParams::refine_rounds`] rounds of
/// Kabsch on the inliers of the current motion, starting from `prior` (the motion stays the
/// prior when fewer than 3 correspondences are its inliers).
pub fn fit_from_prior(
    corr: &Correspondences,
    cam: &PinholeCamera,
    params: &RigidityParams,
    prior: &Se3,
) -> Result<RigidFit, MotionError> {
    params.validate()?;
    if corr.target.len() != corr.source.len() {
        return Err(super::params::invalid(
            "correspondences",
            format!(
                "{} source points but {} target points",
                corr.source.len(),
                corr.target.len()
            ),
        ));
    }
    let model = Model::new(cam, params);
    let targets = targets_of(corr);
    let motion = refine(*prior, corr, &targets, &model, params);
    let inliers = inliers_of(&motion, corr, &targets, &model, params.chi2);
    Ok(RigidFit {
        motion,
        inliers,
        correspondences: corr.len(),
        samples: 0,
    })
}

/// True when `a` and `b` move the source points of `corr` to within the inlier tolerance of
/// each other in the median: the median over the points of the normalised squared residual
/// of `a·p` against `b·p` (the residual of [`residual_squared`](super::residual_squared)) is
/// below [`RigidityParams::chi2`]. False without points.
pub fn motions_agree(
    a: &Se3,
    b: &Se3,
    corr: &Correspondences,
    cam: &PinholeCamera,
    params: &RigidityParams,
) -> bool {
    let model = Model::new(cam, params);
    let mut r2: Vec<f64> = corr
        .source
        .iter()
        .map(|p| {
            let pa = a * p;
            let pb = b * p;
            if pb.z.is_nan() || pb.z <= params.min_projected_depth {
                return f64::INFINITY;
            }
            model.r2(&pa.coords, [pb.x / pb.z, pb.y / pb.z], pb.z)
        })
        .collect();
    if r2.is_empty() {
        return false;
    }
    let mid = r2.len() / 2;
    let (_, median, _) = r2.select_nth_unstable_by(mid, |x, y| x.total_cmp(y));
    *median < params.chi2
}

/// The motion of a pair given its pose-free outcome `dominant` (RANSAC, with an ambiguous
/// fit as [`RigidFitError::Ambiguous`]) and a pose prior (see the module documentation).
/// Without a prior, or when the pair has no fit at all, `dominant` is returned as it is.
pub fn choose_with_prior(
    dominant: Result<RigidFit, RigidFitError>,
    corr: &Correspondences,
    cam: &PinholeCamera,
    params: &RigidityParams,
    prior: Option<&Se3>,
) -> Result<(Result<RigidFit, RigidFitError>, PriorChoice), MotionError> {
    let Some(prior) = prior else {
        return Ok((dominant, PriorChoice::NoPrior));
    };
    let ambiguous = match &dominant {
        Ok(_) => false,
        Err(RigidFitError::Ambiguous { .. }) => true,
        Err(_) => return Ok((dominant, PriorChoice::Failed)),
    };
    let seeded = fit_from_prior(corr, cam, params, prior)?;
    if let Ok(d) = &dominant
        && motions_agree(&d.motion, &seeded.motion, corr, cam, params)
    {
        return Ok((dominant, PriorChoice::Agrees));
    }
    if seeded.inliers < params.min_correspondences {
        return Ok((dominant, PriorChoice::Unsupported));
    }
    let choice = if ambiguous {
        PriorChoice::Ambiguous
    } else {
        PriorChoice::Disagrees
    };
    Ok((Ok(seeded), choice))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rigidity::fixtures::*;
    use crate::rigidity::{fit_rigid_motion, residual_squared};
    use nalgebra::Point3;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// 300 static pairs under `camera`, 700 pairs of a crowd that moves rigidly with the
    /// camera (a mover that keeps its place in the image), interleaved.
    fn crowd_pairs(camera: &Se3, seed: u64) -> (Correspondences, Vec<bool>) {
        let cam = PinholeCamera::tum_fr3();
        let params = RigidityParams::default();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (src, dst) = scene_pairs(&mut rng, 300, camera, &cam, &params);
        let (ms, md) = scene_pairs(&mut rng, 700, &Se3::identity(), &cam, &params);
        let mut corr = Correspondences::default();
        let mut is_static = Vec::new();
        let (mut s, mut m) = (src.into_iter().zip(dst), ms.into_iter().zip(md));
        for k in 0..1000 {
            let still = k % 10 < 3;
            is_static.push(still);
            let next = if still { s.next() } else { m.next() };
            let (a, b) = next.expect("enough pairs");
            corr.source.push(a);
            corr.target.push(b);
            corr.pixels.push([0, 0]);
        }
        (corr, is_static)
    }

    fn mean_r2(fit: &RigidFit, corr: &Correspondences, pick: &[bool], want: bool) -> f64 {
        let cam = PinholeCamera::tum_fr3();
        let params = RigidityParams::default();
        let r: Vec<f64> = (corr.source.iter().zip(&corr.target).zip(pick))
            .filter(|(_, p)| **p == want)
            .map(|((a, b), _)| residual_squared(&fit.motion, a, b, &cam, &params).min(1e6))
            .collect();
        r.iter().sum::<f64>() / r.len() as f64
    }

    #[test]
    fn movers_dominate_and_the_prior_gives_the_static_residual() {
        let cam = PinholeCamera::tum_fr3();
        let params = RigidityParams::default();
        let camera = se3([0.01, -0.03, 0.005], [0.05, -0.01, 0.02]);
        let (corr, is_static) = crowd_pairs(&camera, 4);
        let dominant = fit_rigid_motion(&corr, &cam, &params).expect("fits");
        // The crowd (70 %) wins the vote: its motion is the identity, the static scene's
        // residual is large and the crowd's small.
        let (dr, dt) = distance(&dominant.motion, &Se3::identity());
        assert!(dr < 1e-3 && dt < 3e-3, "{dr} {dt}");
        assert!(mean_r2(&dominant, &corr, &is_static, true) > 100.0);
        // The prior, 5 mm and 0.2° off the true motion, picks the static scene's motion.
        let prior = se3([0.0, 0.0035, 0.0], [0.003, 0.0, 0.004]) * camera;
        let (chosen, choice) =
            choose_with_prior(Ok(dominant.clone()), &corr, &cam, &params, Some(&prior)).unwrap();
        assert_eq!(choice, PriorChoice::Disagrees);
        let chosen = chosen.expect("a fit");
        let (dr, dt) = distance(&chosen.motion, &camera);
        assert!(dr.to_degrees() < 0.05 && dt < 0.003, "{dr} rad, {dt} m");
        assert!((295..=310).contains(&chosen.inliers), "{}", chosen.inliers);
        // Now the static pixels fit (residual below r0 = 3, squared 9) and the crowd does not.
        assert!(mean_r2(&chosen, &corr, &is_static, true) < 9.0);
        assert!(mean_r2(&chosen, &corr, &is_static, false) > 100.0);
        // Without a prior nothing changes.
        let (same, choice) =
            choose_with_prior(Ok(dominant.clone()), &corr, &cam, &params, None).unwrap();
        assert_eq!(choice, PriorChoice::NoPrior);
        assert_eq!(same, Ok(dominant));
    }

    #[test]
    fn an_agreeing_dominant_motion_is_kept_unchanged() {
        let cam = PinholeCamera::tum_fr3();
        let params = RigidityParams::default();
        let camera = se3([0.01, -0.02, 0.005], [0.03, -0.01, 0.02]);
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let (source, target) = scene_pairs(&mut rng, 800, &camera, &cam, &params);
        let corr = Correspondences {
            pixels: vec![[0, 0]; source.len()],
            source,
            target,
        };
        let dominant = fit_rigid_motion(&corr, &cam, &params).unwrap();
        let prior = se3([0.002, 0.0, 0.0], [0.0, 0.004, 0.0]) * camera;
        let (kept, choice) =
            choose_with_prior(Ok(dominant.clone()), &corr, &cam, &params, Some(&prior)).unwrap();
        assert_eq!(choice, PriorChoice::Agrees);
        // Bit for bit the pose-free fit.
        assert_eq!(kept, Ok(dominant));
    }

    #[test]
    fn an_ambiguous_pair_takes_the_prior_fit_and_an_unsupported_prior_changes_nothing() {
        let cam = PinholeCamera::tum_fr3();
        let params = RigidityParams::default();
        let camera = se3([0.0, 0.02, 0.0], [0.04, 0.0, 0.01]);
        let (corr, _) = crowd_pairs(&camera, 11);
        let amb = Err(RigidFitError::Ambiguous {
            fraction: 0.4,
            needed: 0.5,
        });
        let (fit, choice) =
            choose_with_prior(amb.clone(), &corr, &cam, &params, Some(&camera)).unwrap();
        assert_eq!(choice, PriorChoice::Ambiguous);
        let (dr, dt) = distance(&fit.expect("fit").motion, &camera);
        assert!(dr.to_degrees() < 0.05 && dt < 0.003, "{dr} rad, {dt} m");
        // A prior far from every motion of the pair (30 cm off) finds no inliers: no evidence.
        let far = se3([0.0; 3], [0.3, 0.0, 0.0]) * camera;
        let (fit, choice) =
            choose_with_prior(amb.clone(), &corr, &cam, &params, Some(&far)).unwrap();
        assert_eq!(choice, PriorChoice::Unsupported);
        assert_eq!(fit, amb);
        // A pair without any fit stays without one.
        let failed = Err(RigidFitError::NoHypothesis { samples: 500 });
        let (fit, choice) =
            choose_with_prior(failed.clone(), &corr, &cam, &params, Some(&camera)).unwrap();
        assert_eq!((fit, choice), (failed, PriorChoice::Failed));
    }

    #[test]
    fn motions_agree_within_the_inlier_tolerance() {
        let cam = PinholeCamera::tum_fr3();
        let params = RigidityParams::default();
        let pts: Vec<Point3<f64>> = (0..100)
            .map(|k| Point3::new(0.01 * k as f64 - 0.5, 0.2, 2.0))
            .collect();
        let corr = Correspondences {
            pixels: vec![[0, 0]; pts.len()],
            source: pts.clone(),
            target: pts,
        };
        let a = Se3::identity();
        // 1 mm at 2 m is 0.26 px: agree; 5 cm is 13 px: disagree.
        let near = se3([0.0; 3], [0.001, 0.0, 0.0]);
        let far = se3([0.0; 3], [0.05, 0.0, 0.0]);
        assert!(motions_agree(&a, &near, &corr, &cam, &params));
        assert!(!motions_agree(&a, &far, &corr, &cam, &params));
        assert!(!motions_agree(
            &a,
            &a,
            &Correspondences::default(),
            &cam,
            &params
        ));
    }
}
