//! Relative pose between two RGB-D keyframes from matched 3-D points: a seeded RANSAC over
//! 3-point subsets with Horn's closed-form alignment (ORB-SLAM2 `Sim3Solver` with the scale
//! fixed to 1, spec §6.6 `ComputeSim3`). A hypothesis `T₁₂` (camera 2 → camera 1) is scored by
//! reprojecting every pair into both images (`Sim3Solver::CheckInliers`): a pair is an inlier
//! when both squared pixel errors are below χ²·σ² of their keypoint's pyramid level.
//!
//! The solver runs a few iterations at a time so the detector can alternate between loop
//! candidates as ORB-SLAM2 does; the random draws come from a `ChaCha8Rng` owned by the
//! solver, so a given seed always gives the same hypotheses.

use dynapix_geometry::{PinholeCamera, Se3, align::align_se3};
use nalgebra::{Point3, Vector2, Vector3};
use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// One matched pair of map points seen by keyframe 1 and keyframe 2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PointPair {
    /// Point of keyframe 1 in camera-1 coordinates.
    pub p1: Vector3<f64>,
    /// Point of keyframe 2 in camera-2 coordinates.
    pub p2: Vector3<f64>,
    /// Squared-pixel error bound in image 1 (χ² · σ² of the keypoint level).
    pub max_err1: f64,
    /// Squared-pixel error bound in image 2.
    pub max_err2: f64,
}

/// RANSAC settings (ORB-SLAM2 `SetRansacParameters(0.99, 20, 300)`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct RansacSettings {
    /// Probability of drawing one outlier-free minimal set.
    pub probability: f64,
    /// A hypothesis is returned once it has more than this many inliers.
    pub min_inliers: usize,
    /// Upper bound on the iterations.
    pub max_iterations: usize,
}

/// Outcome of [`Se3Ransac::iterate`].
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum RansacStep {
    /// A hypothesis with more than `min_inliers` inliers: `T₁₂` and the inlier flags.
    Found(Se3, Vec<bool>),
    /// Nothing yet; more iterations remain.
    Continue,
    /// The iteration budget is spent (or there are too few pairs).
    Exhausted,
}

/// The seeded SE3 RANSAC over 3-point subsets.
pub(crate) struct Se3Ransac {
    pairs: Vec<PointPair>,
    /// Projection of each `p1` in image 1 and `p2` in image 2 (the reference positions the
    /// transferred points are compared with, as in `Sim3Solver`).
    uv1: Vec<Option<Vector2<f64>>>,
    uv2: Vec<Option<Vector2<f64>>>,
    camera: PinholeCamera,
    min_inliers: usize,
    max_iterations: usize,
    iterations: usize,
    rng: ChaCha8Rng,
}

/// Pinhole projection without distortion (keypoints are undistorted); None behind the camera.
pub(crate) fn project(cam: &PinholeCamera, p: &Vector3<f64>) -> Option<Vector2<f64>> {
    if p.z <= 0.0 || !p.z.is_finite() {
        return None;
    }
    Some(Vector2::new(
        cam.fx * p.x / p.z + cam.cx,
        cam.fy * p.y / p.z + cam.cy,
    ))
}

impl Se3Ransac {
    /// A solver for `pairs`; `seed` fixes the sample sequence.
    pub fn new(
        pairs: Vec<PointPair>,
        camera: &PinholeCamera,
        settings: &RansacSettings,
        seed: u64,
    ) -> Self {
        let n = pairs.len();
        let uv1 = pairs.iter().map(|p| project(camera, &p.p1)).collect();
        let uv2 = pairs.iter().map(|p| project(camera, &p.p2)).collect();
        // Iterations for `probability` of one clean 3-point draw at inlier ratio
        // min_inliers / n (ORB-SLAM2's choice of ε).
        let max_iterations = if n == 0 || settings.min_inliers >= n {
            1
        } else {
            let eps = settings.min_inliers as f64 / n as f64;
            let its = ((1.0 - settings.probability).ln() / (1.0 - eps.powi(3)).ln()).ceil();
            if its.is_finite() && its > 0.0 {
                (its as usize).min(settings.max_iterations)
            } else {
                settings.max_iterations
            }
        }
        .max(1);
        Self {
            pairs,
            uv1,
            uv2,
            camera: camera.clone(),
            min_inliers: settings.min_inliers,
            max_iterations,
            iterations: 0,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// Number of pairs.
    #[cfg(test)]
    pub fn len(&self) -> usize {
        self.pairs.len()
    }

    /// Runs up to `n` more iterations.
    pub fn iterate(&mut self, n: usize) -> RansacStep {
        let total = self.pairs.len();
        if total < self.min_inliers.max(3) {
            return RansacStep::Exhausted;
        }
        let mut done = 0;
        while self.iterations < self.max_iterations && done < n {
            self.iterations += 1;
            done += 1;
            let sample = self.draw3(total);
            let src: Vec<Point3<f64>> = sample
                .iter()
                .map(|&i| Point3::from(self.pairs[i].p2))
                .collect();
            let dst: Vec<Point3<f64>> = sample
                .iter()
                .map(|&i| Point3::from(self.pairs[i].p1))
                .collect();
            let Ok(al) = align_se3(&src, &dst) else {
                continue;
            };
            let t12 = al.se3();
            let inliers = self.check_inliers(&t12);
            let count = inliers.iter().filter(|&&b| b).count();
            if count > self.min_inliers {
                return RansacStep::Found(t12, inliers);
            }
        }
        if self.iterations >= self.max_iterations {
            RansacStep::Exhausted
        } else {
            RansacStep::Continue
        }
    }

    /// Three distinct indices below `total` (`total ≥ 3`).
    fn draw3(&mut self, total: usize) -> [usize; 3] {
        let a = self.rng.random_range(0..total);
        let mut b = self.rng.random_range(0..total - 1);
        if b >= a {
            b += 1;
        }
        let (lo, hi) = if a < b { (a, b) } else { (b, a) };
        let mut c = self.rng.random_range(0..total - 2);
        if c >= lo {
            c += 1;
        }
        if c >= hi {
            c += 1;
        }
        [a, b, c]
    }

    /// Inlier flags of hypothesis `t12`: both transfers land within their error bound.
    pub fn check_inliers(&self, t12: &Se3) -> Vec<bool> {
        let t21 = t12.inverse();
        self.pairs
            .iter()
            .zip(self.uv1.iter().zip(&self.uv2))
            .map(|(p, (uv1, uv2))| {
                let (Some(uv1), Some(uv2)) = (uv1, uv2) else {
                    return false;
                };
                let q1 = t12.transform_point(&Point3::from(p.p2)).coords;
                let q2 = t21.transform_point(&Point3::from(p.p1)).coords;
                match (project(&self.camera, &q1), project(&self.camera, &q2)) {
                    (Some(a), Some(b)) => {
                        (a - uv1).norm_squared() < p.max_err1
                            && (b - uv2).norm_squared() < p.max_err2
                    }
                    _ => false,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use rand::Rng;

    fn camera() -> PinholeCamera {
        PinholeCamera::new(320, 240, 260.0, 260.0, 160.0, 120.0)
    }

    /// `n` points in front of camera 2, seen by camera 1 through `t12`; a fraction
    /// `outliers` of the camera-1 points is replaced by random points.
    fn scene(t12: &Se3, n: usize, outliers: f64, seed: u64) -> (Vec<PointPair>, Vec<bool>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut pairs = Vec::new();
        let mut truth = Vec::new();
        for i in 0..n {
            let p2 = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.8..0.8),
                rng.random_range(1.5..4.0),
            );
            let mut p1 = t12.transform_point(&Point3::from(p2)).coords;
            let bad = (i as f64) < outliers * n as f64;
            if bad {
                p1 = Vector3::new(
                    rng.random_range(-1.5..1.5),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(1.0..4.0),
                );
            } else {
                // Depth noise of a few millimetres.
                p1 += Vector3::new(
                    rng.random_range(-0.003..0.003),
                    rng.random_range(-0.003..0.003),
                    rng.random_range(-0.003..0.003),
                );
            }
            pairs.push(PointPair {
                p1,
                p2,
                max_err1: 9.21,
                max_err2: 9.21,
            });
            truth.push(!bad);
        }
        (pairs, truth)
    }

    fn settings() -> RansacSettings {
        RansacSettings {
            probability: 0.99,
            min_inliers: 20,
            max_iterations: 300,
        }
    }

    fn run(solver: &mut Se3Ransac) -> Option<(Se3, Vec<bool>)> {
        loop {
            match solver.iterate(5) {
                RansacStep::Found(t, inl) => return Some((t, inl)),
                RansacStep::Continue => {}
                RansacStep::Exhausted => return None,
            }
        }
    }

    #[test]
    fn recovers_a_known_transform_with_40_percent_outliers() {
        let t12 = Se3::from_parts(
            Translation3::new(0.3, -0.1, 0.25),
            UnitQuaternion::from_euler_angles(0.1, -0.35, 0.05),
        );
        let (pairs, truth) = scene(&t12, 100, 0.4, 7);
        let mut solver = Se3Ransac::new(pairs.clone(), &camera(), &settings(), 1);
        let (est, inliers) = run(&mut solver).expect("a hypothesis");
        // The first accepted hypothesis comes from 3 noisy points: a few mm / tenths of a
        // degree off; the refinement stage polishes it.
        let d = est.inverse() * t12;
        assert!(d.translation.vector.norm() < 0.03, "{d:?}");
        assert!(d.rotation.angle() < 0.02, "{d:?}");
        let found_outliers = inliers
            .iter()
            .zip(&truth)
            .filter(|(i, t)| **i && !**t)
            .count();
        assert_eq!(found_outliers, 0, "outliers accepted as inliers");
        assert!(inliers.iter().filter(|&&b| b).count() > 20);
        // Same seed, same answer.
        let mut again = Se3Ransac::new(pairs, &camera(), &settings(), 1);
        assert_eq!(run(&mut again), Some((est, inliers)));
    }

    #[test]
    fn rejects_pure_noise() {
        let t12 = Se3::identity();
        let (pairs, _) = scene(&t12, 80, 1.0, 3);
        let mut solver = Se3Ransac::new(pairs, &camera(), &settings(), 5);
        assert_eq!(run(&mut solver), None);
        assert!(solver.iterations <= 300);
    }

    #[test]
    fn too_few_pairs_are_exhausted_at_once() {
        let (pairs, _) = scene(&Se3::identity(), 10, 0.0, 1);
        let mut solver = Se3Ransac::new(pairs, &camera(), &settings(), 0);
        assert_eq!(solver.len(), 10);
        assert_eq!(solver.iterate(5), RansacStep::Exhausted);
    }
}
