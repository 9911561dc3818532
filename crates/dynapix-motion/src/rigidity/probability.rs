//! From residuals to the motion probability P ([`rigidity_from_residuals`], step 4), and
//! the cue of one frame end to end ([`rigidity_probability`], [`pair_residuals`],
//! [`rigidity_from_pairs`]).

use std::borrow::Borrow;
use std::sync::Arc;

use dynapix_flow::FlowProvider;
use dynapix_geometry::{PinholeCamera, PixelRays, Se3};
use rayon::prelude::*;

use super::fit::fit_rigid_motion;
use super::pair::correspondences;
use super::params::{RigidityParams, invalid};
use super::prior::{PriorChoice, choose_with_prior};
use super::residual::dense_residual;
use super::reverse::reverse_flow;
use super::{RigidFit, RigidFitError, RigidFrame, RigidityMaps};
use crate::{FloatImage, MotionError, check_size};

/// P of a frame from the dense residuals of its neighbours, each with its baseline
/// (|frame offset|). Per baseline, the residual is the minimum over the neighbours that give
/// a value (a pixel occluded or disoccluded on one side does not look moving); over
/// baselines, the maximum (a slow mover shows at the longer baseline, a fast one at the
/// shorter). Then P = clamp((r − r0)/(r1 − r0), 0, 1); pixels without any value get 0.
/// Returns (P, combined residual with NaN where none).
pub fn rigidity_from_residuals<R: Borrow<FloatImage>>(
    residuals: &[(u64, R)],
    params: &RigidityParams,
) -> Result<(FloatImage, FloatImage), MotionError> {
    params.validate()?;
    let Some((_, first)) = residuals.first() else {
        return Err(invalid("residuals", "need at least one neighbour"));
    };
    let size = first.borrow().dimensions();
    for (_, r) in residuals {
        check_size("residual of a neighbour", size, r.borrow().dimensions())?;
    }
    let mut baselines: Vec<u64> = residuals.iter().map(|(b, _)| *b).collect();
    baselines.sort_unstable();
    baselines.dedup();
    let mut combined = FloatImage::from_pixel(size.0, size.1, image::Luma([f32::NAN]));
    for b in baselines {
        let mut per = FloatImage::from_pixel(size.0, size.1, image::Luma([f32::NAN]));
        for (_, r) in residuals.iter().filter(|(rb, _)| *rb == b) {
            for (c, &v) in per.iter_mut().zip(r.borrow().iter()) {
                // f32::min returns the other operand when one is NaN.
                *c = c.min(v);
            }
        }
        for (c, &v) in combined.iter_mut().zip(per.iter()) {
            *c = c.max(v);
        }
    }
    let (r0, span) = (params.r0, params.r1 - params.r0);
    let mut p = FloatImage::new(size.0, size.1);
    for (o, &r) in p.iter_mut().zip(combined.iter()) {
        *o = if r.is_nan() {
            0.0
        } else {
            ((r as f64 - r0) / span).clamp(0.0, 1.0) as f32
        };
    }
    Ok((p, combined))
}

/// The undistorted ray table of `cam`, distorted or not, shared through the process-wide
/// cache of [`crate::splat::pixel_rays`] (built once per camera, not once per frame).
pub fn camera_rays(cam: &PinholeCamera) -> Arc<PixelRays> {
    crate::splat::cached_rays(cam)
}

/// The rigidity cue of `cur` from `neighbours` with DIS flow of preset
/// [`RigidityParams::flow_preset`] at [`RigidityParams::flow_working_width`] (see
/// [`rigidity_probability_with`]).
pub fn rigidity_probability(
    cur: &RigidFrame<'_>,
    neighbours: &[RigidFrame<'_>],
    cam: &PinholeCamera,
    params: &RigidityParams,
) -> Result<RigidityMaps, MotionError> {
    let dis = params.flow_for_width(cam.width);
    rigidity_probability_with(cur, neighbours, cam, &dis, params)
}

/// The rigidity cue of `cur` from `neighbours` with flows from `flow` (current → neighbour):
/// per neighbour [`correspondences`], [`fit_rigid_motion`] and [`dense_residual`], then
/// [`rigidity_from_residuals`]. A neighbour whose motion cannot be fitted gives no residual
/// (its error is in [`RigidityMaps::fits`]); without any residual P is 0 everywhere.
pub fn rigidity_probability_with(
    cur: &RigidFrame<'_>,
    neighbours: &[RigidFrame<'_>],
    cam: &PinholeCamera,
    flow: &dyn FlowProvider,
    params: &RigidityParams,
) -> Result<RigidityMaps, MotionError> {
    rigidity_probability_with_priors(cur, neighbours, &[], cam, flow, params)
}

/// [`rigidity_probability_with`] with a pose prior of the motion current → neighbour for
/// each neighbour (`priors[k]` for `neighbours[k]`; a missing or `None` entry is no prior),
/// see [`pair_residuals_with_prior`].
pub fn rigidity_probability_with_priors(
    cur: &RigidFrame<'_>,
    neighbours: &[RigidFrame<'_>],
    priors: &[Option<Se3>],
    cam: &PinholeCamera,
    flow: &dyn FlowProvider,
    params: &RigidityParams,
) -> Result<RigidityMaps, MotionError> {
    params.validate()?;
    let size = (cam.width, cam.height);
    check_size("grey image", size, cur.gray.dimensions())?;
    check_size("depth image", size, cur.depth.dimensions())?;
    for nb in neighbours {
        check_size("grey image of a neighbour", size, nb.gray.dimensions())?;
        check_size("depth image of a neighbour", size, nb.depth.dimensions())?;
    }
    let per_neighbour: Vec<Result<PairResiduals, MotionError>> = neighbours
        .par_iter()
        .enumerate()
        .map(|(k, nb)| {
            let prior = priors.get(k).and_then(Option::as_ref);
            pair_residuals_with_prior(cur, nb, cam, flow, params, false, prior)
        })
        .collect();
    let mut pairs = Vec::with_capacity(neighbours.len());
    for (r, nb) in per_neighbour.into_iter().zip(neighbours) {
        let pair = r?;
        pairs.push((nb.offset, pair.fit, pair.forward));
    }
    rigidity_from_pairs(pairs, size, params)
}

/// What one frame pair (a, b) gives: the fit of a → b, the residual of a's pixels and, when
/// asked for, the residual of b's pixels.
#[derive(Clone, Debug)]
pub struct PairResiduals {
    /// The motion a → b, or why there is none (an ambiguous fit counts as none).
    pub fit: Result<RigidFit, RigidFitError>,
    /// [`dense_residual`] of a's pixels under the fit, with the flow a → b; `None` without a
    /// fit.
    pub forward: Option<FloatImage>,
    /// The residual of b's pixels: [`dense_residual`] of b against a with [`reverse_flow`]
    /// under the inverse fit; `None` without a fit or when not asked for.
    pub backward: Option<FloatImage>,
    /// How the motion was chosen ([`PriorChoice::NoPrior`] for the pose-free cue).
    pub choice: PriorChoice,
}

impl PairResiduals {
    /// The fit as b sees it: the motion b → a (the inverse of [`PairResiduals::fit`]).
    pub fn inverse_fit(&self) -> Result<RigidFit, RigidFitError> {
        self.fit.clone().map(|f| RigidFit {
            motion: f.motion.inverse(),
            ..f
        })
    }
}

/// The flow a → b, the rigid fit and the residuals of the pair: [`correspondences`],
/// [`fit_rigid_motion`] (a fit below [`RigidityParams::min_inlier_fraction`] is
/// [`RigidFitError::Ambiguous`]) and [`dense_residual`]; with `with_backward`, also the
/// residual of b's pixels through the flow a → b turned around ([`PairResiduals::backward`]).
pub fn pair_residuals(
    a: &RigidFrame<'_>,
    b: &RigidFrame<'_>,
    cam: &PinholeCamera,
    flow: &dyn FlowProvider,
    params: &RigidityParams,
    with_backward: bool,
) -> Result<PairResiduals, MotionError> {
    pair_residuals_with_prior(a, b, cam, flow, params, with_backward, None)
}

/// [`pair_residuals`] with the pose prior `prior` of the motion a → b (camera-a points into
/// camera b): the motion of the pair is chosen by [`choose_with_prior`] (the dominant motion
/// when it agrees with the prior, else the fit seeded by the prior); `None` is
/// [`pair_residuals`].
pub fn pair_residuals_with_prior(
    a: &RigidFrame<'_>,
    b: &RigidFrame<'_>,
    cam: &PinholeCamera,
    flow: &dyn FlowProvider,
    params: &RigidityParams,
    with_backward: bool,
    prior: Option<&Se3>,
) -> Result<PairResiduals, MotionError> {
    let rays = camera_rays(cam);
    let f = {
        let _stage = tracing::info_span!(target: "dynapix::stage", "rigidity: flow").entered();
        flow.flow(a.gray, b.gray)?
    };
    let fit_stage = tracing::info_span!(target: "dynapix::stage", "rigidity: fit").entered();
    let corr = correspondences(a.depth, b.depth, &f, &rays, params)?;
    let fit = match fit_rigid_motion(&corr, cam, params) {
        Ok(fit) if fit.inlier_fraction() < params.min_inlier_fraction => {
            Err(RigidFitError::Ambiguous {
                fraction: fit.inlier_fraction(),
                needed: params.min_inlier_fraction,
            })
        }
        Ok(fit) => Ok(fit),
        Err(MotionError::RigidFit(e)) => Err(e),
        Err(e) => return Err(e),
    };
    let (fit, choice) = choose_with_prior(fit, &corr, cam, params, prior)?;
    drop(fit_stage);
    let _stage = tracing::info_span!(target: "dynapix::stage", "rigidity: residual").entered();
    let Ok(good) = &fit else {
        return Ok(PairResiduals {
            fit,
            forward: None,
            backward: None,
            choice,
        });
    };
    let forward = dense_residual(a.depth, b.depth, &f, &rays, &good.motion, params)?;
    let backward = if with_backward {
        let g = reverse_flow(&f, a.depth, &rays, &good.motion, params)?;
        let inverse = good.motion.inverse();
        Some(dense_residual(
            b.depth, a.depth, &g, &rays, &inverse, params,
        )?)
    } else {
        None
    };
    Ok(PairResiduals {
        fit,
        forward: Some(forward),
        backward,
        choice,
    })
}

/// The rigidity maps of a frame of size `size` from its neighbours' fits and residuals (owned
/// or borrowed), each with its frame offset (see [`rigidity_from_residuals`]); P is 0
/// everywhere without any residual.
pub fn rigidity_from_pairs<R: Borrow<FloatImage>>(
    pairs: Vec<(i64, Result<RigidFit, RigidFitError>, Option<R>)>,
    size: (u32, u32),
    params: &RigidityParams,
) -> Result<RigidityMaps, MotionError> {
    let mut fits = Vec::with_capacity(pairs.len());
    let mut residuals = Vec::with_capacity(pairs.len());
    for (offset, fit, residual) in pairs {
        fits.push(fit);
        residuals.extend(residual.map(|r| (offset.unsigned_abs(), r)));
    }
    let (p, residual) = if residuals.is_empty() {
        (
            FloatImage::new(size.0, size.1),
            FloatImage::from_pixel(size.0, size.1, image::Luma([f32::NAN])),
        )
    } else {
        rigidity_from_residuals(&residuals, params)?
    };
    Ok(RigidityMaps { p, residual, fits })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::RocAccumulator;
    use crate::rigidity::{fixtures::*, *};
    use crate::testutil::small_camera;
    use image::GrayImage;

    #[test]
    fn residuals_combine_by_their_minimum_and_ramp() {
        let params = RigidityParams::default();
        let nan = f32::NAN;
        let a = FloatImage::from_raw(6, 1, vec![2.0, 5.5, 10.0, nan, nan, f32::INFINITY]).unwrap();
        let b = FloatImage::from_raw(6, 1, vec![9.0, 20.0, 4.0, 7.0, nan, nan]).unwrap();
        let (p, r) = rigidity_from_residuals(&[(1, a.clone()), (1, b.clone())], &params).unwrap();
        assert_eq!(&r.as_raw()[..4], &[2.0, 5.5, 4.0, 7.0]);
        assert!(r.as_raw()[4].is_nan());
        assert_eq!(r.as_raw()[5], f32::INFINITY);
        let want = [0.0, 0.5, 0.2, 0.8, 0.0, 1.0];
        for (got, want) in p.iter().zip(want) {
            assert!((got - want).abs() < 1e-6, "{got} {want}");
        }
        assert!(matches!(
            rigidity_from_residuals::<FloatImage>(&[], &params),
            Err(MotionError::InvalidParam { .. })
        ));
        // Over baselines the larger residual wins: a slow mover shows at the long baseline.
        let (_, r) = rigidity_from_residuals(&[(1, a.clone()), (4, b)], &params).unwrap();
        assert_eq!(&r.as_raw()[..4], &[9.0, 20.0, 10.0, 7.0]);
        let other = FloatImage::new(5, 1);
        assert!(matches!(
            rigidity_from_residuals(&[(1, a), (1, other)], &params),
            Err(MotionError::SizeMismatch { .. })
        ));
    }

    #[test]
    fn rigidity_separates_walkers_from_the_static_scene() {
        let s = synth();
        let params = RigidityParams::default();
        // Fast movers (255) against the static scene (0); slow mover pixels (128) left out.
        let mut roc = RocAccumulator::new(0.5);
        // The same maps with the slow mover pixels counted as static.
        let mut roc_all = RocAccumulator::new(0.5);
        for k in 1..SYNTH_FRAMES - 1 {
            let maps = synth_maps(k, &params);
            for fit in &maps.fits {
                let fit = fit.as_ref().expect("fit");
                assert!(fit.inlier_fraction() > 0.5, "{}", fit.inlier_fraction());
            }
            let mask = s.frames[k].2.as_raw();
            add_fast_movers(&mut roc, &maps.p, mask);
            let fast: Vec<bool> = mask.iter().map(|&m| m == 255).collect();
            roc_all.add(maps.p.as_raw(), &fast);
            let slow: Vec<bool> = mask.iter().map(|&m| m == 128).collect();
            let still: Vec<bool> = mask.iter().map(|&m| m == 0).collect();
            eprintln!(
                "frame {k}: mean P fast movers {:.3}, slow movers {:.3}, static {:.3}",
                mean_where(&maps.p, &fast),
                mean_where(&maps.p, &slow),
                mean_where(&maps.p, &still),
            );
        }
        let auc = roc.auc().expect("both classes");
        eprintln!(
            "rigidity on walking_xyz 320×240: AUC {auc:.3} (slow movers counted static: {:?}), \
             IoU(P > 0.5) {:?}, fast mover px {}",
            roc_all.auc(),
            roc.iou(),
            roc.positives()
        );
        assert!(roc.positives() > 5000, "walkers in view");
        assert!(auc > 0.85, "AUC {auc}");
    }

    #[test]
    fn rigidity_is_deterministic_and_independent_of_the_thread_count() {
        let params = RigidityParams::default();
        let bits = |m: &RigidityMaps| -> (Vec<u32>, Vec<u32>) {
            (
                m.p.iter().map(|v| v.to_bits()).collect(),
                m.residual.iter().map(|v| v.to_bits()).collect(),
            )
        };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool")
                .install(|| synth_maps(2, &params))
        };
        let a = run(1);
        let b = run(2);
        let c = run(2);
        assert_eq!(bits(&a), bits(&b));
        assert_eq!(bits(&b), bits(&c));
        assert_eq!(a.fits, b.fits);
    }

    #[test]
    fn without_neighbours_or_fits_p_is_zero() {
        let cam = small_camera();
        let (w, h) = (cam.width, cam.height);
        let gray = GrayImage::new(w, h);
        let depth = FloatImage::new(w, h); // no depth anywhere: no correspondences
        let cur = RigidFrame {
            gray: &gray,
            depth: &depth,
            offset: 0,
        };
        let params = RigidityParams::default();
        let maps = rigidity_probability(&cur, &[cur], &cam, &params).unwrap();
        assert!(maps.p.iter().all(|&v| v == 0.0));
        assert!(maps.residual.iter().all(|v| v.is_nan()));
        assert!(matches!(
            maps.fits[0],
            Err(RigidFitError::TooFewCorrespondences { got: 0, .. })
        ));
        let maps = rigidity_probability(&cur, &[], &cam, &params).unwrap();
        assert!(maps.fits.is_empty() && maps.p.iter().all(|&v| v == 0.0));
        let small = GrayImage::new(w - 1, h);
        let nb = RigidFrame {
            gray: &small,
            depth: &depth,
            offset: 1,
        };
        assert!(matches!(
            rigidity_probability(&cur, &[nb], &cam, &params),
            Err(MotionError::SizeMismatch { .. })
        ));
    }
}
