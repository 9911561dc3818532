//! RANSAC with Kabsch/Horn hypotheses for the dominant rigid motion of a frame pair
//! ([`fit_rigid_motion`], step 2 of the cue) and the inlier counting it scores with.

use dynapix_geometry::align::align_se3;
use dynapix_geometry::{PinholeCamera, Se3};
use nalgebra::{Matrix3, Point3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::pair::Model;
use super::params::{RigidityParams, invalid};
use super::{Correspondences, RigidFit, RigidFitError};
use crate::MotionError;

/// Kabsch/Horn: the rigid motion minimising `Σ‖R·aₖ + t − bₖ‖²` (SVD with the reflection
/// guard); `None` for fewer than 3 pairs, non-finite input or an SVD failure.
fn kabsch(source: &[Point3<f64>], target: &[Point3<f64>]) -> Option<Se3> {
    align_se3(source, target).ok().map(|a| a.se3())
}

/// A correspondence's target in the form the residual needs.
#[derive(Clone, Copy)]
pub(super) struct Target {
    bn: [f64; 2],
    bz: f64,
}

/// The correspondences as columns (structure of arrays) for [`count_inliers_soa`], with the
/// depth-noise denominator `σ_z = a·b_z² + b` of each target computed once.
struct Columns {
    ax: Vec<f64>,
    ay: Vec<f64>,
    az: Vec<f64>,
    bn0: Vec<f64>,
    bn1: Vec<f64>,
    bz: Vec<f64>,
    sigma_z: Vec<f64>,
}

impl Columns {
    fn new(source: &[Point3<f64>], targets: &[Target], model: &Model) -> Self {
        let n = source.len().min(targets.len());
        let (source, targets) = (&source[..n], &targets[..n]);
        Self {
            ax: source.iter().map(|a| a.x).collect(),
            ay: source.iter().map(|a| a.y).collect(),
            az: source.iter().map(|a| a.z).collect(),
            bn0: targets.iter().map(|b| b.bn[0]).collect(),
            bn1: targets.iter().map(|b| b.bn[1]).collect(),
            bz: targets.iter().map(|b| b.bz).collect(),
            sigma_z: targets
                .iter()
                .map(|b| model.sz_a * b.bz * b.bz + model.sz_b)
                .collect(),
        }
    }
}

/// [`count_inliers`] over [`Columns`], without branches so that the compiler vectorises it
/// (AVX2 when present). The same operations in the same order as [`Model::r2`], so the count
/// is identical (test `column_count_equals_the_point_by_point_count`).
fn count_inliers_soa(motion: &Se3, c: &Columns, model: &Model, chi2: f64) -> usize {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        return unsafe { count_inliers_avx2(avx2, motion, c, model, chi2) };
    }
    count_inliers_body(motion, c, model, chi2)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn count_inliers_avx2(
    _: dynapix_simd::Avx2,
    motion: &Se3,
    c: &Columns,
    model: &Model,
    chi2: f64,
) -> usize {
    count_inliers_body(motion, c, model, chi2)
}

#[inline(always)]
fn count_inliers_body(motion: &Se3, c: &Columns, model: &Model, chi2: f64) -> usize {
    let rt = crate::RigidRows::from_se3(motion);
    let (fxs, fys, min_pz) = (model.fx_over_sigma, model.fy_over_sigma, model.min_pz);
    let n = c.ax.len();
    let (ay, az, bn0, bn1, bz, sz) = (
        &c.ay[..n],
        &c.az[..n],
        &c.bn0[..n],
        &c.bn1[..n],
        &c.bz[..n],
        &c.sigma_z[..n],
    );
    let mut count = 0usize;
    for k in 0..n {
        let (px, py, pz) = rt.apply(c.ax[k], ay[k], az[k]);
        let ex = (px / pz - bn0[k]) * fxs;
        let ey = (py / pz - bn1[k]) * fys;
        let ez = (pz - bz[k]) / sz[k];
        let r2 = ex * ex + ey * ey + ez * ez;
        // A NaN depth counts as behind the camera, as in `Model::r2`.
        let ok = !(pz.is_nan() || pz <= min_pz) & (r2 < chi2);
        count += ok as usize;
    }
    count
}

#[cfg(test)]
fn count_inliers(
    motion: &Se3,
    source: &[Point3<f64>],
    targets: &[Target],
    model: &Model,
    chi2: f64,
) -> usize {
    let r: Matrix3<f64> = *motion.rotation.to_rotation_matrix().matrix();
    let t = motion.translation.vector;
    source
        .iter()
        .zip(targets)
        .filter(|(a, b)| model.r2(&(r * a.coords + t), b.bn, b.bz) < chi2)
        .count()
}

/// The targets of `corr` in the form the residual needs.
pub(super) fn targets_of(corr: &Correspondences) -> Vec<Target> {
    corr.target
        .iter()
        .map(|b| Target {
            bn: [b.x / b.z, b.y / b.z],
            bz: b.z,
        })
        .collect()
}

/// `rounds` rounds of Kabsch on the inliers of `motion` (stops when fewer than 3 remain).
pub(super) fn refine(
    mut motion: Se3,
    corr: &Correspondences,
    targets: &[Target],
    model: &Model,
    params: &RigidityParams,
) -> Se3 {
    for _ in 0..params.refine_rounds {
        let (a, b) = inlier_pairs(&motion, corr, targets, model, params.chi2);
        match kabsch(&a, &b) {
            Some(m) => motion = m,
            // Fewer than 3 inliers: keep the motion that has them.
            None => break,
        }
    }
    motion
}

/// The number of correspondences of `corr` that are inliers of `motion`.
pub(super) fn inliers_of(
    motion: &Se3,
    corr: &Correspondences,
    targets: &[Target],
    model: &Model,
    chi2: f64,
) -> usize {
    let columns = Columns::new(&corr.source, targets, model);
    count_inliers_soa(motion, &columns, model, chi2)
}

fn inlier_pairs(
    motion: &Se3,
    corr: &Correspondences,
    targets: &[Target],
    model: &Model,
    chi2: f64,
) -> (Vec<Point3<f64>>, Vec<Point3<f64>>) {
    let r: Matrix3<f64> = *motion.rotation.to_rotation_matrix().matrix();
    let t = motion.translation.vector;
    corr.source
        .iter()
        .zip(&corr.target)
        .zip(targets)
        .filter(|((a, _), b)| model.r2(&(r * a.coords + t), b.bn, b.bz) < chi2)
        .map(|((a, b), _)| (*a, *b))
        .unzip()
}

/// Samples drawn between two checks of RANSAC's adaptive stopping rule.
pub const RANSAC_BATCH: usize = 16;

/// Samples RANSAC needs so that, with probability `confidence`, one of them is all inliers
/// when a fraction `inlier_fraction` of the correspondences are inliers (3-point samples).
/// `usize::MAX` when that cannot be reached (no inliers, or confidence 1).
pub fn adaptive_samples(inlier_fraction: f64, confidence: f64) -> usize {
    let all_inliers = inlier_fraction.clamp(0.0, 1.0).powi(3);
    if confidence >= 1.0 || all_inliers <= 0.0 {
        return usize::MAX;
    }
    if all_inliers >= 1.0 {
        return 1;
    }
    let k = (1.0 - confidence).ln() / (1.0 - all_inliers).ln();
    if k.is_finite() && k >= 0.0 {
        (k.ceil() as usize).max(1)
    } else {
        usize::MAX
    }
}

/// RANSAC for the rigid motion `B ≈ R·A + t` of `corr` (see the module documentation):
/// up to [`RigidityParams::ransac_iterations`] seeded 3-point samples (fewer once
/// [`RigidityParams::ransac_confidence`] is reached), degenerate ones skipped,
/// each hypothesis scored by its number of inliers (`r² < chi2`,
/// [`residual_squared`](super::residual_squared); the
/// first best hypothesis wins ties), then [`RigidityParams::refine_rounds`] rounds of Kabsch
/// on the inliers. `cam` gives the focal lengths of the residual.
///
/// A pair that cannot be fitted gives [`MotionError::RigidFit`].
pub fn fit_rigid_motion(
    corr: &Correspondences,
    cam: &PinholeCamera,
    params: &RigidityParams,
) -> Result<RigidFit, MotionError> {
    params.validate()?;
    if corr.target.len() != corr.source.len() {
        return Err(invalid(
            "correspondences",
            format!(
                "{} source points but {} target points",
                corr.source.len(),
                corr.target.len()
            ),
        ));
    }
    let n = corr.len();
    if n < params.min_correspondences {
        return Err(RigidFitError::TooFewCorrespondences {
            got: n,
            needed: params.min_correspondences,
        }
        .into());
    }
    let model = Model::new(cam, params);
    let targets = targets_of(corr);

    let columns = Columns::new(&corr.source, &targets, &model);
    // Samples are drawn in sequence from the seeded generator, in fixed batches; only the
    // scoring within a batch is parallel, and the first best sample wins ties, so the result
    // is the same on every thread count.
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
    let mut best: Option<(Se3, usize)> = None;
    let mut drawn = 0;
    let mut needed = params.ransac_iterations;
    while drawn < needed {
        let end = (drawn + RANSAC_BATCH).min(needed);
        let mut hypotheses = Vec::with_capacity(end - drawn);
        for _ in drawn..end {
            let idx = rand::seq::index::sample(&mut rng, n, 3);
            let a = [
                corr.source[idx.index(0)],
                corr.source[idx.index(1)],
                corr.source[idx.index(2)],
            ];
            let area = (a[1] - a[0]).cross(&(a[2] - a[0])).norm();
            // NaN areas (non-finite input) are degenerate too.
            if area.is_nan() || area < params.min_sample_area {
                continue;
            }
            let b = [
                corr.target[idx.index(0)],
                corr.target[idx.index(1)],
                corr.target[idx.index(2)],
            ];
            if let Some(m) = kabsch(&a, &b) {
                hypotheses.push(m);
            }
        }
        drawn = end;
        let scores: Vec<usize> = hypotheses
            .par_iter()
            .map(|m| count_inliers_soa(m, &columns, &model, params.chi2))
            .collect();
        for (m, s) in hypotheses.into_iter().zip(scores) {
            if best.as_ref().is_none_or(|(_, b)| s > *b) {
                best = Some((m, s));
            }
        }
        if let Some((_, s)) = &best {
            needed = adaptive_samples(*s as f64 / n as f64, params.ransac_confidence)
                .min(params.ransac_iterations);
        }
    }
    let Some((motion, _)) = best else {
        return Err(RigidFitError::NoHypothesis {
            samples: params.ransac_iterations,
        }
        .into());
    };
    let motion = refine(motion, corr, &targets, &model, params);
    let inliers = count_inliers_soa(&motion, &columns, &model, params.chi2);
    Ok(RigidFit {
        motion,
        inliers,
        correspondences: n,
        samples: drawn,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rigidity::{fixtures::*, *};
    use crate::testutil::small_camera;
    use nalgebra::Vector3;
    use proptest::prelude::*;
    use rand::Rng;

    #[test]
    fn column_count_equals_the_point_by_point_count() {
        let cam = small_camera();
        let params = RigidityParams::default();
        let model = Model::new(&cam, &params);
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let n = 1003;
        // Points near and behind the camera and targets with noise: every branch of r².
        let source: Vec<Point3<f64>> = (0..n)
            .map(|_| {
                Point3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-0.2..5.0),
                )
            })
            .collect();
        let truth = se3([0.05, -0.02, 0.01], [0.1, 0.0, -0.05]);
        let targets: Vec<Target> = source
            .iter()
            .map(|a| {
                let b = truth * a;
                let noise = rng.random_range(-0.01..0.01);
                Target {
                    bn: [b.x / b.z + noise, b.y / b.z],
                    bz: b.z + 3.0 * noise,
                }
            })
            .collect();
        let columns = Columns::new(&source, &targets, &model);
        let mut nonzero = 0;
        for k in 0..50 {
            let f = k as f64 / 50.0;
            let m = se3([0.05 * f, -0.02, 0.01 * f], [0.1 * f, 0.0, -0.05]);
            for chi2 in [1.0, 27.0, 1e4] {
                let want = count_inliers(&m, &source, &targets, &model, chi2);
                assert_eq!(count_inliers_soa(&m, &columns, &model, chi2), want);
                assert_eq!(count_inliers_body(&m, &columns, &model, chi2), want);
                nonzero += usize::from(want > 0 && want < n);
            }
        }
        assert!(nonzero > 50, "{nonzero}");
    }

    proptest! {
        #[test]
        fn prop_kabsch_recovers_a_rigid_transform(
            axis in prop::array::uniform3(-1.0f64..1.0),
            angle in 0.0f64..3.1,
            t in prop::array::uniform3(-5.0f64..5.0),
            seed in 0u64..10_000,
            n in 3usize..40,
        ) {
            let a = Vector3::from(axis);
            let w = if a.norm() > 1e-6 { a.normalize() * angle } else { Vector3::zeros() };
            let truth = se3(w.into(), t);
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let src: Vec<Point3<f64>> = (0..n)
                .map(|_| Point3::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-2.0..2.0),
                    rng.random_range(0.5..5.0),
                ))
                .collect();
            // Minimal samples must not be degenerate, as RANSAC guarantees.
            prop_assume!((src[1] - src[0]).cross(&(src[2] - src[0])).norm() > 0.05);
            let dst: Vec<Point3<f64>> = src.iter().map(|p| truth * p).collect();
            let est = kabsch(&src, &dst);
            prop_assert!(est.is_some());
            if let Some(est) = est {
                let (dr, dt) = distance(&est, &truth);
                prop_assert!(dr < 1e-7 && dt < 1e-7, "{dr} {dt}");
                prop_assert!(est.rotation.to_rotation_matrix().matrix().determinant() > 0.0);
            }
        }
    }

    #[test]
    fn ransac_recovers_the_camera_motion_with_40_percent_rigid_outliers() {
        let cam = PinholeCamera::tum_fr3();
        let params = RigidityParams::default();
        let camera = se3([0.01, -0.02, 0.005], [0.03, -0.01, 0.02]);
        // The movers share one rigid motion of their own (a walker's 6-7 cm in one frame,
        // ≥ 8 px at 4 m), so they form a consistent second model that RANSAC must not prefer.
        let mover = se3([0.0; 3], [0.06, -0.03, 0.04]) * camera;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (mut src, mut dst) = scene_pairs(&mut rng, 600, &camera, &cam, &params);
        let (ms, md) = scene_pairs(&mut rng, 400, &mover, &cam, &params);
        // Interleave so the outliers are not a contiguous block.
        for (k, (a, b)) in ms.into_iter().zip(md).enumerate() {
            src.insert(2 * k + 1, a);
            dst.insert(2 * k + 1, b);
        }
        let corr = Correspondences {
            pixels: vec![[0, 0]; src.len()],
            source: src,
            target: dst,
        };
        let fit = fit_rigid_motion(&corr, &cam, &params).expect("fits");
        let (dr, dt) = distance(&fit.motion, &camera);
        assert!(dr.to_degrees() < 0.05 && dt < 0.003, "{dr} rad, {dt} m");
        assert_eq!(fit.correspondences, 1000);
        // Every static pair is an inlier (noise ≤ 0.5 px, 1 σ_z); no mover is.
        assert!((600..=610).contains(&fit.inliers), "{}", fit.inliers);
        assert!((fit.inlier_fraction() - 0.6).abs() < 0.011);
        // The same seed gives the same fit; a different seed the same motion.
        assert_eq!(fit_rigid_motion(&corr, &cam, &params).unwrap(), fit);
        let other = RigidityParams { seed: 99, ..params };
        let fit2 = fit_rigid_motion(&corr, &cam, &other).unwrap();
        let (dr2, dt2) = distance(&fit2.motion, &fit.motion);
        assert!(dr2 < 1e-9 && dt2 < 1e-9, "{dr2} {dt2}");
    }

    #[test]
    fn adaptive_sample_count_follows_the_ransac_formula() {
        // ln(0.001) / ln(1 − 0.5³) = 51.7 → 52 samples at half inliers.
        assert_eq!(adaptive_samples(0.5, 0.999), 52);
        // More inliers, fewer samples; more confidence, more samples.
        assert!(adaptive_samples(0.8, 0.999) < adaptive_samples(0.6, 0.999));
        assert!(adaptive_samples(0.6, 0.99) < adaptive_samples(0.6, 0.999));
        assert_eq!(adaptive_samples(1.0, 0.999), 1);
        assert_eq!(adaptive_samples(0.0, 0.999), usize::MAX);
        assert_eq!(adaptive_samples(0.7, 1.0), usize::MAX);
    }

    #[test]
    fn adaptive_ransac_stops_early_with_the_same_motion() {
        let cam = PinholeCamera::tum_fr3();
        let camera = se3([0.01, -0.02, 0.005], [0.03, -0.01, 0.02]);
        let mover = se3([0.0; 3], [0.06, -0.03, 0.04]) * camera;
        let all = RigidityParams {
            ransac_confidence: 1.0,
            ..Default::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (mut src, mut dst) = scene_pairs(&mut rng, 700, &camera, &cam, &all);
        let (ms, md) = scene_pairs(&mut rng, 300, &mover, &cam, &all);
        src.extend(ms);
        dst.extend(md);
        let corr = Correspondences {
            pixels: vec![[0, 0]; src.len()],
            source: src,
            target: dst,
        };
        let full = fit_rigid_motion(&corr, &cam, &all).unwrap();
        assert_eq!(full.samples, all.ransac_iterations);
        let adaptive = fit_rigid_motion(&corr, &cam, &RigidityParams::default()).unwrap();
        // 70 % inliers: ln(0.001) / ln(1 − 0.343) = 16.4 → the first batch (16) plus one.
        assert!(adaptive.samples <= 2 * RANSAC_BATCH, "{}", adaptive.samples);
        let (dr, dt) = distance(&adaptive.motion, &full.motion);
        assert!(dr.to_degrees() < 0.01 && dt < 5e-4, "{dr} rad, {dt} m");
        assert_eq!(adaptive.inliers, full.inliers);
        // Bad values are refused.
        for c in [0.0, 1.5, f64::NAN] {
            let p = RigidityParams {
                ransac_confidence: c,
                ..Default::default()
            };
            assert!(fit_rigid_motion(&corr, &cam, &p).is_err(), "{c}");
        }
    }

    #[test]
    fn fits_fail_with_typed_errors() {
        let cam = small_camera();
        let params = RigidityParams::default();
        let pts: Vec<_> = (0..10).map(|k| Point3::new(k as f64, 0.0, 2.0)).collect();
        let few = Correspondences {
            source: pts.clone(),
            target: pts.clone(),
            pixels: vec![[0, 0]; 10],
        };
        assert!(matches!(
            fit_rigid_motion(&few, &cam, &params),
            Err(MotionError::RigidFit(
                RigidFitError::TooFewCorrespondences {
                    got: 10,
                    needed: 20
                }
            ))
        ));
        // Collinear points: every sample is degenerate.
        let line: Vec<_> = (0..50)
            .map(|k| Point3::new(0.01 * k as f64, 0.0, 2.0))
            .collect();
        let collinear = Correspondences {
            source: line.clone(),
            target: line,
            pixels: vec![[0, 0]; 50],
        };
        assert!(matches!(
            fit_rigid_motion(&collinear, &cam, &params),
            Err(MotionError::RigidFit(RigidFitError::NoHypothesis {
                samples: 500
            }))
        ));
        let mut bad = few.clone();
        bad.target.pop();
        let p3 = RigidityParams {
            min_correspondences: 3,
            ..params.clone()
        };
        assert!(matches!(
            fit_rigid_motion(&bad, &cam, &p3),
            Err(MotionError::InvalidParam { .. })
        ));
    }
}
