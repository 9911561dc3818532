//! The single stages of a run, for tools that run one of them on its own (`dynapix motion`
//! computes and keeps a sequence's maps, `dynapix slam` runs one pass with its own outputs):
//! a map job and its folder, a SLAM session and one pass, the frame poses the maps are made
//! with. A whole run goes through [`crate::OfflineRunner`] or [`crate::run_online`] instead.

pub use crate::cues::{GeometricInput, RigidityJob};
pub use crate::maps::{CacheCheck, MapFolder, MapJob, MapSet, compute_into};
pub use crate::offline::folder_writable;
pub use crate::poses::{FramePoses, PoseOrigin, from_source as poses_from_source};
pub use crate::slam::{
    MapLoad, MapSave, PassWeights, SlamSession, Watch, load_vocabulary, run_pass, run_pass_observed,
};
