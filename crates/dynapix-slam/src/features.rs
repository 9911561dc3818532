//! The feature layer of the SLAM crate: keypoint and descriptor types, the scale pyramid and
//! the [`FeatureExtractor`] interface, all from `dynapix-features` (which also holds the ORB
//! extractor and the vocabulary, re-exported at the crate root as `orb` and `vocab`).

pub use dynapix_features::extractor::FeatureExtractor;
pub use dynapix_features::keypoint::{Descriptor, KeyPoint, hamming};
pub use dynapix_features::pyramid::ScalePyramid;
