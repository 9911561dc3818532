//! Predicted local-map tracking (see [`super::TrackingParams::predicted_frames`]) and the
//! consistency check of a pose found with few matches (see
//! [`super::TrackingParams::pose_consistency`]).
//!
//! A predicted frame has no evidence of its own: its matches were searched within a window
//! around the projections of the local map at the predicted pose. A pose consistent with
//! those matches therefore moves the projections of the map by no more than that window.
//! When a mover covers most of the view, the few static matches left (10–20, in one corner)
//! let the pose-only optimisation slide far along a poorly constrained direction; the
//! projections of the rest of the map then move by more than the window in which any match
//! could have been found, and the pose is refused.

use dynapix_geometry::Se3;

use super::Tracker;
use crate::camera::{ImageBounds, RgbdCamera};
use crate::frame::Frame;
use crate::map::MapPoint;
use crate::pose::{normalized, transform};

impl Tracker {
    /// Predicted local-map tracking (see [`TrackingParams::predicted_frames`]): the pose is the
    /// constant-velocity extrapolation from the last tracked frame, matches are left to the
    /// local-map search.
    pub(super) fn predict(&mut self, frame: &mut Frame) -> bool {
        let Some((v, last, id)) = self.coast else {
            return false;
        };
        let gap = frame.id.saturating_sub(id);
        if gap == 0 || gap > self.params.predicted_frames || self.local_kfs.is_empty() {
            return false;
        }
        let mut pose = last;
        for _ in 0..gap {
            pose = normalized(&(v * pose));
        }
        frame.pose = Some(pose);
        frame.map_points.iter_mut().for_each(|m| *m = None);
        frame.outlier.iter_mut().for_each(|o| *o = false);
        self.predicted = true;
        tracing::debug!(frame = frame.id, gap, "predicted local-map tracking");
        true
    }
}

/// The largest search window (px at level 0) of the local-map search with radius factor
/// `th`: the matcher's widest viewing-angle radius (4) times `th`.
pub(crate) fn search_window(th: f32) -> f64 {
    4.0 * th as f64
}

/// Median image displacement (px) of `points` seen from `from` (in front of the camera and
/// inside `bounds`) when the camera moves from `from` to `to`; `None` without such a point.
pub(crate) fn median_shift<'a>(
    cam: &RgbdCamera,
    points: impl Iterator<Item = &'a MapPoint>,
    bounds: &ImageBounds,
    from: &Se3,
    to: &Se3,
) -> Option<f64> {
    let mut shifts: Vec<f64> = points
        .filter_map(|p| {
            let (u0, v0, _) = cam.project(&transform(from, &p.position))?;
            if !bounds.contains(u0, v0) {
                return None;
            }
            let (u1, v1, _) = cam.project(&transform(to, &p.position))?;
            Some(((u1 - u0).powi(2) + (v1 - v0).powi(2)).sqrt())
        })
        .collect();
    if shifts.is_empty() {
        return None;
    }
    let mid = shifts.len() / 2;
    let (_, m, _) = shifts.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

/// Whether moving the camera from `from` to `to` moves the median projection of `kf`'s map
/// points by more than the widest local-map search window with radius factor `th` (the check of
/// [`super::TrackingParams::pose_consistency`] for the final pose refinement).
pub(crate) fn moves_the_map(
    cam: &RgbdCamera,
    map: &crate::map::Map,
    kf: &crate::map::KeyFrame,
    from: &Se3,
    to: &Se3,
    th: f32,
) -> bool {
    let points = kf
        .map_points
        .iter()
        .flatten()
        .filter_map(|&id| map.point(id));
    median_shift(cam, points, &cam.image_bounds(), from, to).is_some_and(|s| s > search_window(th))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_window_is_the_matchers_widest_radius() {
        assert_eq!(search_window(5.0), 20.0);
        assert_eq!(search_window(1.0), 4.0);
    }
}
