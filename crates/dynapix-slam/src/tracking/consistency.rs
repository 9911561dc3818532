//! The consistency check of predicted tracking (see
//! [`super::TrackingParams::predicted_consistency`]).
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
use crate::frame::Frame;
use crate::map::Map;
use crate::pose::transform;

/// The largest search window (px at level 0) of the local-map search with radius factor
/// `th`: the matcher's widest viewing-angle radius (4) times `th`.
pub(super) fn search_window(th: f32) -> f64 {
    4.0 * th as f64
}

/// Median image displacement (px) of the local map points seen from `from` (in front of the
/// camera and inside the image) when the frame's pose moves from `from` to `to`; `None`
/// without such a point.
pub(super) fn median_shift(
    tracker: &Tracker,
    map: &Map,
    frame: &Frame,
    from: &Se3,
    to: &Se3,
) -> Option<f64> {
    let mut shifts: Vec<f64> = tracker
        .local_points
        .iter()
        .filter_map(|&id| {
            let p = map.point(id)?;
            let (u0, v0, _) = tracker.cam.project(&transform(from, &p.position))?;
            if !frame.grid.bounds.contains(u0, v0) {
                return None;
            }
            let (u1, v1, _) = tracker.cam.project(&transform(to, &p.position))?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_window_is_the_matchers_widest_radius() {
        assert_eq!(search_window(5.0), 20.0);
        assert_eq!(search_window(1.0), 4.0);
    }
}
