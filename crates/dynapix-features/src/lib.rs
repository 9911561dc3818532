//! ORB features for the SLAM backend: keypoint and descriptor types, the ORB-SLAM2-style
//! extractor ([`orb`]), the scale pyramid the keypoint octaves refer to, the
//! [`FeatureExtractor`] trait the SLAM system is generic over, and the bag-of-words
//! vocabulary ([`vocab`]). No file access beyond explicit vocabulary load/save calls, and no
//! knowledge of frames or maps.
//!
//! Layers (each module imports only the ones above it): [`keypoint`], [`pyramid`], [`orb`],
//! [`vocab`], [`extractor`].

pub mod extractor;
pub mod keypoint;
pub mod orb;
pub mod pyramid;
pub mod vocab;

pub use extractor::FeatureExtractor;
pub use keypoint::{Descriptor, KeyPoint, hamming};
pub use orb::{FastCorners, KeepMask, OrbError, OrbExtractor, OrbParams};
pub use pyramid::ScalePyramid;
pub use vocab::{TrainParams, VocabError, Vocabulary};
