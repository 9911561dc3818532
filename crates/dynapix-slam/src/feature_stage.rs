//! The feature extraction of a SLAM system on its own: a frame's keypoints and descriptors from
//! its grey image and, optionally, its static weights (the DynaPix feature budget).

use std::sync::Arc;
use std::time::Instant;

use dynapix_io::StaticWeights;
use image::GrayImage;

use crate::features::{Descriptor, FeatureExtractor, KeyPoint};
use crate::orb::{FastCorners, KeepMask};

/// Keypoints and descriptors of one frame, from [`FeatureStage::extract`].
#[derive(Clone, Debug)]
pub struct Features {
    /// Keypoints, level-0 image coordinates.
    pub keys: Vec<KeyPoint>,
    /// Their descriptors.
    pub descriptors: Vec<Descriptor>,
    /// Wall-clock seconds the extraction took (measurement only).
    pub seconds: f64,
}

/// The feature extraction of a [`System`] on its own. It depends only on the frame (its grey
/// image and, with [`SystemParams::static_features_min_weight`], its weights), never on the
/// map, so a copy ([`System::feature_stage`]) can run ahead of tracking on another thread and
/// gives exactly the features [`System::process`] would extract (see
/// [`System::process_features`]).
///
/// [`System`]: crate::system::System
/// [`System::feature_stage`]: crate::system::System::feature_stage
/// [`System::process`]: crate::system::System::process
/// [`System::process_features`]: crate::system::System::process_features
/// [`SystemParams::static_features_min_weight`]: crate::system::SystemParams::static_features_min_weight
#[derive(Clone, Debug)]
pub struct FeatureStage<E> {
    pub(crate) extractor: E,
    pub(crate) static_features_min_weight: Option<f32>,
}

impl<E: FeatureExtractor> FeatureStage<E> {
    /// Extracts the features of a frame with grey image `gray` and static weights `weights`.
    pub fn extract(&mut self, gray: &GrayImage, weights: Option<&StaticWeights>) -> Features {
        self.extract_cached(gray, weights, &mut None)
    }

    /// [`FeatureStage::extract`] reusing `corners`, the FAST corners of an earlier extraction
    /// of the same grey image (another pass over the same frame), or storing them there; the
    /// features are the same either way.
    pub fn extract_cached(
        &mut self,
        gray: &GrayImage,
        weights: Option<&StaticWeights>,
        corners: &mut Option<Arc<FastCorners>>,
    ) -> Features {
        let t0 = Instant::now();
        let _stage = tracing::info_span!(target: "dynapix::stage", "orb extraction").entered();
        let keep = match (self.static_features_min_weight, weights) {
            (Some(th), Some(w)) if w.dimensions() == gray.dimensions() => KeepMask::new(
                w.as_image().width(),
                w.as_image().height(),
                w.as_image()
                    .as_raw()
                    .iter()
                    .map(|&v| v.is_nan() || v >= th)
                    .collect(),
            ),
            _ => None,
        };
        let (keys, descriptors) = self
            .extractor
            .extract_where_cached(gray, keep.as_ref(), corners);
        Features {
            keys,
            descriptors,
            seconds: t0.elapsed().as_secs_f64(),
        }
    }

    /// The FAST corners of `gray` for a later [`FeatureStage::extract_cached`] of the same
    /// image, detected on their own: they depend on the image only, not on the weights, so
    /// they can be found while the weights are computed. `None` when the extractor keeps no
    /// corners.
    pub fn fast_corners(&self, gray: &GrayImage) -> Option<Arc<FastCorners>> {
        let _stage = tracing::info_span!(target: "dynapix::stage", "orb extraction").entered();
        self.extractor.fast_corners(gray)
    }
}
