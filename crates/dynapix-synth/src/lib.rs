//! dynapix-synth: synthetic dynamic RGB-D sequences with exact ground truth, rendered on the
//! CPU in the spirit of the GRADE dataset — every frame twice, with and without the moving
//! objects — plus augmentation of real TUM sequences with virtual movers.
//!
//! Pipeline: [`scene::Scene::generate`] builds a textured room from a seed;
//! [`sequence::Sequence`] combines it with a camera motion ([`trajectory`]) and movers
//! ([`movers`]) for a named [`sequence::Preset`]; [`render::render`] ray-casts both versions;
//! [`sensor`] adds Kinect-like depth and image effects; [`output`] writes the DynaPix folder
//! layout (rgb, depth, background, depth_bg, mask, instance, flow, TUM lists, camera.yaml).
//!
//! Sensor defaults ([`SensorParams::default`]): Kinect-like depth on (disparity noise giving
//! σz ≈ 1.6 mm·z², 1/8 px disparity quantisation, holes at depth discontinuities, outside
//! 0.4–5 m) and mild image noise (σ = 1.5 grey levels) on, because the SLAM and flow code must
//! cope with them; exposure changes and motion blur off (opt in with [`SensorParams::full`]);
//! [`SensorParams::clean`] gives exact data for tests. Noise is the same in both versions of a
//! frame, so `rgb == background` on mask-0 pixels holds byte for byte with every setting;
//! `depth` and `depth_bg` can differ next to movers (holes at the mover's depth edges).
//!
//! Augmentation of real sequences: [`augment`] and [`output::augment_sequence`].

#![forbid(unsafe_code)]

pub mod augment;
pub mod body;
pub mod hard;
pub mod movers;
pub mod output;
pub mod preview;
pub mod render;
pub mod scene;
pub mod script;
pub mod sensor;
pub mod sequence;
pub mod shape;
pub mod texture;
pub mod trajectory;

pub use render::{Intrinsics, Layers, RenderParams};
pub use scene::{Scene, SceneParams};
pub use sensor::SensorParams;
pub use sequence::{Flow, Frame, Preset, Sequence, SynthParams};

use std::path::PathBuf;

/// Errors of the synthetic data generator.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// An image could not be encoded or decoded.
    #[error("{path}: {source}")]
    Image {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: image::ImageError,
    },
    /// A file has an unexpected content.
    #[error("{path}: {what}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// A preset name is not known.
    #[error("unknown preset '{name}' (known: {known})")]
    UnknownPreset {
        /// The name given.
        name: String,
        /// The known names.
        known: String,
    },
    /// Parameters are out of range.
    #[error("invalid parameters: {0}")]
    InvalidParams(String),
    /// Reading or writing a dataset failed (from `dynapix-io`).
    #[error(transparent)]
    Dataset(#[from] dynapix_io::IoError),
    /// Writing a flow file failed.
    #[error(transparent)]
    Flow(#[from] dynapix_flow::FlowError),
}
