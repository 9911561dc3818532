//! Relocalisation against the local map (see [`super::TrackingParams::local_relocalisation`]).
//!
//! After a full occlusion (an object filling the view, a crowd in front of the camera) the
//! tracker is lost. The bag-of-words relocalisation of ORB-SLAM2 needs one keyframe sharing
//! enough words and ≥ 50 PnP inliers with the frame; with the few static keypoints DynaPix
//! keeps among movers it can take many frames. Yet the camera is still close to where it was
//! last tracked, and the points it saw then are the ones that come back into view. So while
//! lost, the frame is matched against the last local map (keyframes and points of the last
//! tracked frame) by projection from two pose hypotheses, the last tracked pose held and the
//! constant-velocity extrapolation over the gap, with a wide search radius. The hypothesis
//! with more inliers after pose-only optimisation is kept when it has at least the
//! relocalisation's RANSAC minimum; the caller then tracks the local map as after any
//! relocalisation, which accepts only with ≥ `local_min_inliers_reloc` inliers.
//!
//! The search does not touch the map points' visibility counters: a rejected hypothesis leaves
//! no trace in the map.

use dynapix_geometry::Se3;

use super::Tracker;
use crate::frame::Frame;
use crate::ids::MapPointId;
use crate::map::Map;
use crate::matcher;
use crate::pose::normalized;

/// The pose hypotheses of a frame `gap` frames after the last tracked pose `last` with
/// per-frame velocity `v`: the held pose, then the extrapolation (when it differs).
pub(super) fn hypotheses(v: &Se3, last: &Se3, gap: u64) -> Vec<Se3> {
    let mut out = vec![*last];
    let mut pose = *last;
    for _ in 0..gap {
        pose = normalized(&(v * pose));
    }
    let moved = (pose.translation.vector - last.translation.vector).norm()
        + pose.rotation.angle_to(&last.rotation);
    if moved > 1e-9 {
        out.push(pose);
    }
    out
}

/// Inliers of `frame` matched to `points` from its current pose, after pose-only optimisation
/// (the frame keeps the optimised pose and the inlier matches).
fn match_and_optimize(
    tracker: &Tracker,
    map: &Map,
    frame: &mut Frame,
    points: &[MapPointId],
    th: f32,
) -> usize {
    frame.map_points.iter_mut().for_each(|m| *m = None);
    frame.outlier.iter_mut().for_each(|o| *o = false);
    let cands: Vec<_> = points
        .iter()
        .filter_map(|&id| tracker.frustum(map, frame, id))
        .collect();
    if cands.is_empty() {
        return 0;
    }
    let n = matcher::search_local_by_projection(
        frame,
        map,
        &cands,
        th,
        tracker.params.local_ratio,
        &tracker.params.matcher,
    );
    if n < tracker.params.reloc.min_inliers {
        return 0;
    }
    let good = tracker.optimize_pose(map, frame);
    for i in 0..frame.len() {
        if frame.outlier[i] {
            frame.map_points[i] = None;
            frame.outlier[i] = false;
        }
    }
    good
}

/// Tries to relocalise `frame` against the last local map; on success the frame holds the
/// pose and its inlier matches.
pub(super) fn relocalize_local_map(tracker: &mut Tracker, map: &Map, frame: &mut Frame) -> bool {
    let Some((v, last, id)) = tracker.coast else {
        return false;
    };
    if tracker.local_kfs.is_empty() {
        return false;
    }
    tracker.update_local_points(map);
    let points = tracker.local_points.clone();
    let gap = frame.id.saturating_sub(id);
    let th = tracker.params.local_reloc_th;
    let mut best: Option<(usize, Se3, Vec<Option<MapPointId>>)> = None;
    for h in hypotheses(&v, &last, gap) {
        frame.pose = Some(h);
        // Two rounds: the wide search from the hypothesis, then the local search radius
        // after a relocalisation from the optimised pose.
        let mut good = match_and_optimize(tracker, map, frame, &points, th);
        if good >= tracker.params.reloc.min_inliers {
            let first = (frame.pose, frame.map_points.clone());
            let again =
                match_and_optimize(tracker, map, frame, &points, tracker.params.local_th_reloc);
            if again >= good {
                good = again;
            } else {
                (frame.pose, frame.map_points) = first;
            }
        }
        tracing::debug!(
            frame = frame.id,
            gap,
            good,
            "local-map relocalisation hypothesis"
        );
        if good >= tracker.params.reloc.min_inliers
            && best.as_ref().is_none_or(|(b, _, _)| good > *b)
            && let Some(pose) = frame.pose
        {
            best = Some((good, pose, frame.map_points.clone()));
        }
    }
    match best {
        Some((_, pose, matches)) => {
            frame.pose = Some(pose);
            frame.map_points = matches;
            frame.outlier.iter_mut().for_each(|o| *o = false);
            true
        }
        None => {
            frame.pose = None;
            frame.map_points.iter_mut().for_each(|m| *m = None);
            frame.outlier.iter_mut().for_each(|o| *o = false);
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn hypotheses_are_the_held_pose_then_the_extrapolation() {
        let last = Se3::from_parts(
            Translation3::new(0.1, 0.2, 0.3),
            UnitQuaternion::from_euler_angles(0.01, 0.02, 0.03),
        );
        let v = Se3::from_parts(
            Translation3::new(0.01, 0.0, 0.0),
            UnitQuaternion::identity(),
        );
        let h = hypotheses(&v, &last, 5);
        assert_eq!(h.len(), 2);
        assert_eq!(h[0], last);
        let dx = h[1].translation.vector - last.translation.vector;
        assert!((dx - nalgebra::Vector3::new(0.05, 0.0, 0.0)).norm() < 1e-12);
        // A camera at rest gives one hypothesis.
        assert_eq!(hypotheses(&Se3::identity(), &last, 5).len(), 1);
        assert_eq!(hypotheses(&v, &last, 0).len(), 1);
    }
}
