//! The interface the SLAM system extracts features through, and ORB-SLAM2's extractor as its
//! implementation. A system is generic over it so tests can feed synthetic features.

use std::sync::Arc;

use image::GrayImage;

use crate::keypoint::{Descriptor, KeyPoint};
use crate::orb::{FastCorners, KeepMask, OrbExtractor};
use crate::pyramid::ScalePyramid;

/// Produces keypoints (level-0 image coordinates) and descriptors from a grey image.
pub trait FeatureExtractor {
    /// Extracts features.
    fn extract(&mut self, image: &GrayImage) -> (Vec<KeyPoint>, Vec<Descriptor>);
    /// Extracts features only where `keep` allows, spending the whole budget there. The
    /// default ignores the mask.
    fn extract_where(
        &mut self,
        image: &GrayImage,
        keep: Option<&KeepMask>,
    ) -> (Vec<KeyPoint>, Vec<Descriptor>) {
        let _ = keep;
        self.extract(image)
    }
    /// [`FeatureExtractor::extract_where`], reusing the frame's FAST corners from an earlier
    /// extraction of the same image where the extractor can (see
    /// [`OrbExtractor::extract_cached`]); the result must be the same as without.
    /// The default ignores the cache.
    fn extract_where_cached(
        &mut self,
        image: &GrayImage,
        keep: Option<&KeepMask>,
        corners: &mut Option<Arc<FastCorners>>,
    ) -> (Vec<KeyPoint>, Vec<Descriptor>) {
        let _ = corners;
        self.extract_where(image, keep)
    }
    /// The FAST corners of `image` on their own, for a later
    /// [`FeatureExtractor::extract_where_cached`] of the same image, where the extractor has
    /// such a cache ([`OrbExtractor::detect_corners`]). The default has none.
    fn fast_corners(&self, image: &GrayImage) -> Option<Arc<FastCorners>> {
        let _ = image;
        None
    }
    /// The pyramid the keypoint octaves refer to.
    fn pyramid(&self) -> ScalePyramid;
}

/// ORB-SLAM2's extractor is the system's feature extractor.
impl FeatureExtractor for OrbExtractor {
    fn extract(&mut self, image: &GrayImage) -> (Vec<KeyPoint>, Vec<Descriptor>) {
        OrbExtractor::extract(self, image)
    }
    fn extract_where(
        &mut self,
        image: &GrayImage,
        keep: Option<&KeepMask>,
    ) -> (Vec<KeyPoint>, Vec<Descriptor>) {
        OrbExtractor::extract_where(self, image, keep)
    }
    fn extract_where_cached(
        &mut self,
        image: &GrayImage,
        keep: Option<&KeepMask>,
        corners: &mut Option<Arc<FastCorners>>,
    ) -> (Vec<KeyPoint>, Vec<Descriptor>) {
        OrbExtractor::extract_cached(self, image, keep, corners)
    }
    fn fast_corners(&self, image: &GrayImage) -> Option<Arc<FastCorners>> {
        Some(self.detect_corners(image))
    }
    fn pyramid(&self) -> ScalePyramid {
        ScalePyramid::new(self.nlevels(), self.scale_factor())
    }
}
