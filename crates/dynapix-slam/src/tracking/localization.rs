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

use super::{TrackOutcome, Tracker, TrackingState};
use crate::frame::{Frame, normalized};
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
        let mut out = TrackOutcome {
            state: self.state,
            pose: None,
            reference: None,
            new_keyframe: None,
            inliers: 0,
            reset_requested: false,
            relocalised: false,
        };
        self.refresh_last_frame(map);
        let mut ok;
        if self.state == TrackingState::Ok {
            let just_relocalised = frame.id < self.last_reloc_frame + 2;
            if self.velocity.is_none() || just_relocalised {
                ok = self.track_reference_keyframe(map, &mut frame, vocab);
            } else {
                ok = self.track_with_motion_model(map, &mut frame);
                if !ok {
                    ok = self.track_reference_keyframe(map, &mut frame, vocab);
                }
            }
        } else {
            if let Some(v) = vocab {
                frame.compute_bow(v, self.params.bow_group_depth);
            }
            ok = map.num_keyframes() > 0 && self.relocalize(map, &mut frame);
            out.relocalised = ok;
        }
        frame.reference = self.reference_kf;
        if ok {
            ok = self.track_local_map(map, &mut frame);
        }
        self.state = if ok {
            TrackingState::Ok
        } else {
            TrackingState::Lost
        };
        out.state = self.state;
        out.inliers = self.inliers;
        if ok {
            if let (Some(cur), Some(last)) =
                (frame.pose, self.last_frame.as_ref().and_then(|l| l.pose))
            {
                self.velocity = Some(normalized(&(cur * last.inverse())));
            } else {
                self.velocity = None;
            }
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
