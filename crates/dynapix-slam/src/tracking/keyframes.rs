//! The keyframe decision of tracking and the creation of a keyframe from the current frame
//! (RGB-D with synchronous local mapping: close points born from the frame's depth, only
//! where the frame's weights allow a birth).

use super::*;

impl Tracker {
    /// Keyframe decision for RGB-D with synchronous local mapping (always idle here).
    pub(super) fn need_new_keyframe(&self, map: &Map, frame: &Frame) -> bool {
        let n_kfs = map.num_keyframes() as u64;
        let max_frames = self.max_frames();
        if frame.id < self.last_reloc_frame + max_frames && n_kfs > max_frames {
            return false;
        }
        let min_obs = if n_kfs <= 2 { 2 } else { 3 };
        let n_ref = self
            .reference_kf
            .map_or(0, |r| map.tracked_points(r, min_obs)) as f32;
        let (mut tracked_close, mut untracked_close) = (0usize, 0usize);
        for i in 0..frame.len() {
            let d = frame.depth[i] as f64;
            if d > 0.0 && d < self.cam.th_depth {
                if frame.map_points[i].is_some() && !frame.outlier[i] {
                    tracked_close += 1;
                } else {
                    untracked_close += 1;
                }
            }
        }
        let need_close = tracked_close < self.params.kf_close_tracked
            && untracked_close > self.params.kf_close_untracked;
        let th_ref = if n_kfs < 2 {
            self.params.kf_ref_ratio_few
        } else {
            self.params.kf_ref_ratio
        };
        let inl = self.inliers as f32;
        let idle = true;
        let c1a = frame.id >= self.last_kf_frame + max_frames;
        let c1b = frame.id >= self.last_kf_frame + self.params.min_frames && idle;
        let c1c = inl < n_ref * self.params.kf_c1c_ratio || need_close;
        let c2 = (inl < n_ref * th_ref || need_close) && self.inliers > self.params.kf_min_inliers;
        (c1a || c1b || c1c) && c2
    }

    /// New keyframe from the frame, with map points for the close untracked keypoints
    /// (sorted by depth; at least `kf_new_points`, all closer than `th_depth`).
    pub(super) fn create_keyframe(
        &mut self,
        map: &mut Map,
        frame: &mut Frame,
    ) -> Option<KeyFrameId> {
        let pose = frame.pose?;
        let kf = map.insert_keyframe(KeyFrame::from_frame(frame, 0, pose));
        self.reference_kf = Some(kf);
        frame.reference = Some(kf);
        let mut by_depth: Vec<(f32, usize)> = (0..frame.len())
            .filter(|&i| frame.depth[i] > 0.0)
            .map(|i| (frame.depth[i], i))
            .collect();
        by_depth.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut n_points = 0;
        let mut gated = 0usize;
        for (z, i) in by_depth {
            let create = match frame.map_points[i] {
                None => true,
                Some(id) => map.point(id).is_none_or(|p| p.num_obs < 1),
            };
            if create {
                frame.map_points[i] = None;
                map.set_keyframe_match(kf, i, None);
                let born = may_birth_in_frame(
                    &map.params.dynapix,
                    frame,
                    i,
                    BirthSource::TrackingKeyFrame,
                );
                gated += usize::from(!born);
                if born
                    && let Some(x) = frame.unproject(i, &self.cam)
                    && let Some(id) = map.create_point(x, kf, i)
                {
                    frame.map_points[i] = Some(id);
                }
            }
            n_points += 1;
            if z as f64 > self.cam.th_depth && n_points > self.params.kf_new_points {
                break;
            }
        }
        if gated > 0 {
            tracing::debug!(frame = frame.id, gated, "keyframe points not born (γ_add)");
        }
        self.last_kf_frame = frame.id;
        Some(kf)
    }
}
