//! Localisation-only tracking against a fixed map (ORB-SLAM2 `ActivateLocalizationMode`,
//! `Tracking::Track` with `mbOnlyTracking`): motion-model or reference-keyframe tracking then
//! local-map tracking while tracked, relocalisation (BoW candidates + PnP RANSAC) otherwise.
//! No keyframe, no map point, no local mapping, no map reset: the map's structure never
//! changes. Only the per-point tracking statistics (visible/found counters, DynaPix point
//! weights) are updated, as in ORB-SLAM2.
//!
//! ORB-SLAM2's visual-odometry fallback (`mbVO`: keep tracking from matches to the last
//! frame's temporary points when few map points are matched) is not implemented: a frame
//! whose local-map tracking fails is LOST and the next frame relocalises. Temporary VO points
//! would need the last-frame point creation ORB-SLAM2 does only in that mode; on maps of the
//! same scene relocalisation recovers within a frame.

use super::{TrackOutcome, Tracker};
use crate::frame::Frame;
use crate::map::Map;
use crate::vocab::Vocabulary;

impl Tracker {
    /// Tracks one frame against `map` without changing its structure. A fresh tracker (state
    /// `NotInitialized`) starts by relocalising, so a loaded map is entered wherever the
    /// camera is.
    pub fn track_localization(
        &mut self,
        map: &mut Map,
        mut frame: Frame,
        vocab: Option<&Vocabulary>,
    ) -> TrackOutcome {
        let mut out = self.empty_outcome();
        let ok = self.track_against_map(map, &mut frame, vocab, &mut out);
        if ok {
            for i in 0..frame.len() {
                if frame.outlier[i] {
                    frame.map_points[i] = None;
                }
            }
            out.pose = frame.pose;
            self.last_known_pose = frame.pose;
            out.reference = frame.reference;
            self.record_last(map, frame);
        } else {
            self.velocity = None;
            self.last_relative = None;
            out.reference = frame.reference;
        }
        out
    }
}
