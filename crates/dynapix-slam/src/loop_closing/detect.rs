//! Loop detection: keyframe database, candidates, consistency groups and the SE3 estimate.
