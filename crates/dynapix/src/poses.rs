//! Poses for splatting, one per frame, with a record of where they came from: ground truth,
//! a trajectory file, or a pass of the system itself (the first pass, or weighted pass k for
//! the maps of pass k + 1).
//!
//! A pass's trajectory is used as written to its `trajectory.txt` (TUM text, 9 decimals), so
//! the maps can be recomputed from the files a run leaves; frames the pass did not track take
//! the nearest tracked pose.

use dynapix_geometry::Se3;
use dynapix_io::{Sequence, StampedPose, Trajectory};
use serde::Serialize;

use crate::config::PoseSource;
use crate::error::{Error, Result};
use crate::hash::Fnv64;

/// The pose at `t`: SLERP between the poses around it, provided the nearest pose is within
/// `max_gap` seconds (a frame just outside the trajectory's time range takes the nearest).
pub fn pose_at(traj: &Trajectory, t: f64, max_gap: f64) -> Option<Se3> {
    let after = traj.poses.partition_point(|p| p.t <= t);
    let cands = [after.checked_sub(1), Some(after)];
    let nearest = cands
        .iter()
        .flatten()
        .filter_map(|&i| traj.poses.get(i))
        .min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs()))?;
    if (nearest.t - t).abs() > max_gap {
        return None;
    }
    traj.interpolate(t, f64::INFINITY).or(Some(nearest.pose))
}

/// `traj` as it reads back from its TUM text (what a pass leaves in `trajectory.txt`).
pub fn as_written(traj: &Trajectory) -> Result<Trajectory> {
    Ok(crate::pass::as_written(traj)?)
}

/// A pose for every frame time in `stamps` from a (possibly incomplete) trajectory: tracked
/// frames keep theirs, the others take the nearest tracked pose. Returns the trajectory and
/// how many frames were filled in.
pub fn fill_untracked(traj: &Trajectory, stamps: &[f64]) -> Result<(Trajectory, usize)> {
    if traj.poses.is_empty() {
        return Err(Error::Input(
            "the pass tracked no frame: no poses for the motion maps".into(),
        ));
    }
    let mut filled = 0;
    let mut poses = Vec::with_capacity(stamps.len());
    for &t in stamps {
        let k = traj.poses.partition_point(|p| p.t < t);
        let cands = [k.checked_sub(1), Some(k)];
        let best = cands
            .iter()
            .flatten()
            .filter_map(|&i| traj.poses.get(i))
            .min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs()));
        let Some(b) = best else { continue };
        if (b.t - t).abs() > 1e-4 {
            filled += 1;
        }
        poses.push(StampedPose::new(t, b.pose));
    }
    Ok((Trajectory::new(poses), filled))
}

/// The poses of `source` for the frames of `sequence` at `stamps` (each within `max_gap`
/// seconds of a pose; frames without one get the identity and are listed in the second
/// value): the sequence's ground truth (camera poses, read once with the sequence), a TUM
/// trajectory file, or for [`PoseSource::Own`] the trajectory of the system's own pass
/// `own` returns (the pass's index, its trajectory; untracked frames take the nearest tracked
/// pose, [`FramePoses::from_pass`]). The one lookup of `dynapix run` and `dynapix motion`.
pub fn from_source(
    source: &PoseSource,
    sequence: &Sequence,
    stamps: &[f64],
    max_gap: f64,
    own: impl FnOnce() -> Result<(usize, Trajectory)>,
) -> Result<(FramePoses, Vec<usize>)> {
    match source {
        PoseSource::GroundTruth => {
            let path = sequence
                .dir
                .join(dynapix_io::ground_truth::GROUNDTRUTH_FILE);
            let gt = sequence.groundtruth.as_ref().ok_or_else(|| {
                Error::Input(format!(
                    "ground-truth poses asked for, but {} does not exist",
                    path.display()
                ))
            })?;
            Ok(FramePoses::lookup(
                gt,
                stamps,
                max_gap,
                PoseOrigin::GroundTruth { path },
            ))
        }
        PoseSource::File(path) => {
            let t = Trajectory::read_tum(path)?;
            Ok(FramePoses::lookup(
                &t,
                stamps,
                max_gap,
                PoseOrigin::File { path: path.clone() },
            ))
        }
        PoseSource::Own => {
            let (pass, t) = own()?;
            Ok((FramePoses::from_pass(&t, stamps, pass)?, Vec::new()))
        }
    }
}

/// Where the poses of a set of motion maps came from.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "source", rename_all = "snake_case")]
pub enum PoseOrigin {
    /// The sequence's ground truth (an oracle: ground truth used at run time).
    GroundTruth {
        /// The file.
        path: std::path::PathBuf,
    },
    /// A trajectory file given by the user.
    File {
        /// The file.
        path: std::path::PathBuf,
    },
    /// A pass of this run: 0 = the first (unweighted) pass, k = weighted pass k.
    Pass {
        /// The pass.
        pass: usize,
        /// Frames the pass did not track (they took the nearest tracked pose).
        filled_frames: usize,
    },
    /// None needed (no moving term and a given background).
    Unused,
}

impl PoseOrigin {
    /// True when ground truth was used.
    pub fn is_ground_truth(&self) -> bool {
        matches!(self, PoseOrigin::GroundTruth { .. })
    }

    /// Where the poses came from, for messages: the file, `the first pass`, `weighted pass
    /// k`, or nothing for [`PoseOrigin::Unused`].
    pub fn describe(&self) -> String {
        match self {
            PoseOrigin::GroundTruth { path } | PoseOrigin::File { path } => {
                path.display().to_string()
            }
            PoseOrigin::Pass { pass: 0, .. } => "the first pass".into(),
            PoseOrigin::Pass { pass, .. } => format!("weighted pass {pass}"),
            PoseOrigin::Unused => String::new(),
        }
    }
}

/// One pose per frame and where they came from.
#[derive(Clone, Debug, PartialEq)]
pub struct FramePoses {
    /// Camera-to-world pose of every frame.
    pub poses: Vec<Se3>,
    /// Their origin.
    pub origin: PoseOrigin,
}

impl FramePoses {
    /// Looks up every frame time of `stamps` in `traj` (`pose_at` within `max_gap`); frames
    /// without a pose get the identity and are listed in the second value.
    pub fn lookup(
        traj: &Trajectory,
        stamps: &[f64],
        max_gap: f64,
        origin: PoseOrigin,
    ) -> (Self, Vec<usize>) {
        let mut missing = Vec::new();
        let poses: Vec<Se3> = stamps
            .iter()
            .enumerate()
            .map(|(i, &t)| {
                pose_at(traj, t, max_gap).unwrap_or_else(|| {
                    missing.push(i);
                    Se3::identity()
                })
            })
            .collect();
        (Self { poses, origin }, missing)
    }

    /// [`FramePoses::lookup`] that fails, listing the frames, when a frame has no pose.
    pub fn from_trajectory(
        traj: &Trajectory,
        stamps: &[f64],
        max_gap: f64,
        origin: PoseOrigin,
    ) -> Result<Self> {
        let (poses, missing) = Self::lookup(traj, stamps, max_gap, origin);
        poses.complete(&missing, stamps, max_gap)
    }

    /// These poses when `missing` (frames without a pose within `max_gap` of their time in
    /// `stamps`) is empty; else an error listing the frames.
    pub fn complete(self, missing: &[usize], stamps: &[f64], max_gap: f64) -> Result<Self> {
        let poses = self;
        if missing.is_empty() {
            return Ok(poses);
        }
        let total = missing.len();
        let list: Vec<String> = missing
            .iter()
            .take(10)
            .map(|&i| format!("frame {i} (t = {:.6})", stamps[i]))
            .collect();
        Err(Error::Input(format!(
            "{total} frame(s) have no pose within {max_gap} s in the {} poses: {}{}",
            match &poses.origin {
                PoseOrigin::GroundTruth { .. } => "ground-truth",
                PoseOrigin::File { .. } => "file's",
                _ => "pass's",
            },
            list.join(", "),
            if total > 10 { ", …" } else { "" }
        )))
    }

    /// The poses of a pass's trajectory for the frames `stamps`: untracked frames take the
    /// nearest tracked pose, and the poses are those of the written trajectory file.
    pub fn from_pass(traj: &Trajectory, stamps: &[f64], pass: usize) -> Result<Self> {
        let (filled, n) = fill_untracked(traj, stamps)?;
        let written = as_written(&filled)?;
        Self::from_trajectory(
            &written,
            stamps,
            0.05,
            PoseOrigin::Pass {
                pass,
                filled_frames: n,
            },
        )
    }

    /// Identity poses (for maps that need none).
    pub fn unused(n: usize) -> Self {
        Self {
            poses: vec![Se3::identity(); n],
            origin: PoseOrigin::Unused,
        }
    }

    /// A fingerprint of the pose values (part of the motion-map cache key).
    pub fn content_hash(&self) -> String {
        let mut h = Fnv64::new();
        for p in &self.poses {
            for v in p.to_homogeneous().iter() {
                h.write(&v.to_le_bytes());
            }
        }
        h.hex()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn traj(ts: &[f64]) -> Trajectory {
        Trajectory::new(
            ts.iter()
                .map(|&t| StampedPose::new(t, Se3::translation(t, 0.0, 0.0)))
                .collect(),
        )
    }

    #[test]
    fn lookup_interpolates_within_the_gap_and_names_missing_frames() {
        let t = traj(&[0.0, 0.1, 0.2]);
        let p = pose_at(&t, 0.05, 0.06).unwrap();
        assert!((p.translation.x - 0.05).abs() < 1e-12);
        assert!(pose_at(&t, 0.3, 0.05).is_none());
        assert!(
            pose_at(&t, 0.24, 0.05).is_some(),
            "just outside takes the nearest"
        );
        let e = FramePoses::from_trajectory(
            &t,
            &[0.0, 0.5],
            0.05,
            PoseOrigin::File { path: "x".into() },
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("frame 1 (t = 0.500000)"), "{e}");
    }

    #[test]
    fn pass_poses_fill_untracked_frames_and_read_like_the_file() {
        let tracked = traj(&[0.0, 0.2]);
        let p = FramePoses::from_pass(&tracked, &[0.0, 0.09, 0.2], 0).unwrap();
        assert_eq!(
            p.origin,
            PoseOrigin::Pass {
                pass: 0,
                filled_frames: 1
            }
        );
        assert_eq!(p.poses[1].translation.x, 0.0, "the nearest tracked pose");
        assert!(fill_untracked(&traj(&[]), &[0.0]).is_err());
        let q = FramePoses::from_pass(&tracked, &[0.0, 0.09, 0.2], 0).unwrap();
        assert_eq!(p.content_hash(), q.content_hash());
    }
}
