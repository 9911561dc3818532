//! Tracking (ORB-SLAM2 `Tracking`, RGB-D path, spec §6.3/§6.4/§6.8): RGB-D initialisation,
//! motion-model and reference-keyframe tracking, local-map tracking, the keyframe decision and
//! keyframe creation with close map points, and relocalisation. Scratch state (local
//! keyframes and points, candidate lists) lives here, keyed by id, never in the map entities.

mod keyframes;
mod local_reloc;
mod localization;
mod params;
mod predicted;
mod relocalization;

use std::collections::{BTreeMap, HashSet};

use dynapix_geometry::Se3;
use dynapix_optim::{Observation, PoseOnlyProblem};
use nalgebra::Vector3;

use crate::camera::{RgbdCamera, stereo_camera};
use crate::frame::Frame;
use crate::ids::{KeyFrameId, MapPointId};
use crate::map::{KeyFrame, Map};
use crate::matcher::{self, ProjectionCandidate};
use crate::pose::{normalized, transform};
use crate::vocab::Vocabulary;
use crate::weighting::{BirthSource, may_birth_in_frame};

pub use params::TrackingParams;
pub(crate) use predicted::moves_the_map;
pub use relocalization::RelocParams;

/// Tracking state (ORB-SLAM2 `eTrackingState`, without the pre-input states).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrackingState {
    /// No map yet (waiting for a frame with enough features).
    NotInitialized,
    /// Tracking.
    Ok,
    /// Tracking lost; relocalisation is attempted on every frame.
    Lost,
}

/// What tracking did with one frame.
#[derive(Clone, Debug)]
pub struct TrackOutcome {
    /// State after the frame.
    pub state: TrackingState,
    /// Pose `T_cw` when tracked.
    pub pose: Option<Se3>,
    /// Reference keyframe of the frame.
    pub reference: Option<KeyFrameId>,
    /// Keyframe created from this frame (local mapping must process it).
    pub new_keyframe: Option<KeyFrameId>,
    /// Inlier map-point matches after local-map tracking.
    pub inliers: usize,
    /// Tracking was lost with a tiny map: the caller should reset the map.
    pub reset_requested: bool,
    /// The frame was relocalised.
    pub relocalised: bool,
}

/// The tracking stage.
pub struct Tracker {
    /// Parameters.
    pub params: TrackingParams,
    cam: RgbdCamera,
    state: TrackingState,
    last_frame: Option<Frame>,
    /// `(reference keyframe, T_lr)` of the last frame, to refresh its pose after BA.
    last_relative: Option<(KeyFrameId, Se3)>,
    velocity: Option<Se3>,
    reference_kf: Option<KeyFrameId>,
    last_kf_frame: u64,
    last_reloc_frame: u64,
    local_kfs: Vec<KeyFrameId>,
    local_points: Vec<MapPointId>,
    inliers: usize,
    last_known_pose: Option<Se3>,
    /// `(velocity, pose, frame id)` of the last tracked frame, for predicted tracking.
    coast: Option<(Se3, Se3, u64)>,
    /// The current frame is tracked from a prediction (wider local-map search).
    predicted: bool,
    /// World positions of the map points removed as moving while tracking the last frame,
    /// when recorded ([`Tracker::record_removed_points`]; `None`: not recorded, no cost).
    pub(crate) removed: Option<Vec<Vector3<f64>>>,
}

impl Tracker {
    /// A tracker for `cam`.
    pub fn new(cam: RgbdCamera, params: TrackingParams) -> Self {
        Self {
            params,
            cam,
            state: TrackingState::NotInitialized,
            last_frame: None,
            last_relative: None,
            velocity: None,
            reference_kf: None,
            last_kf_frame: 0,
            last_reloc_frame: 0,
            local_kfs: Vec::new(),
            local_points: Vec::new(),
            inliers: 0,
            last_known_pose: None,
            coast: None,
            predicted: false,
            removed: None,
        }
    }

    /// Records (or stops recording) the map points removed as moving at each frame
    /// ([`Tracker::removed_points`]).
    pub fn record_removed_points(&mut self, on: bool) {
        self.removed = on.then(Vec::new);
    }

    /// World positions of the map points removed as moving (γ_del) while tracking the last
    /// frame; empty unless recorded.
    pub fn removed_points(&self) -> &[Vector3<f64>] {
        self.removed.as_deref().unwrap_or(&[])
    }

    /// Current state.
    pub fn state(&self) -> TrackingState {
        self.state
    }

    /// Forgets everything tied to the map (after a map reset). The last known pose is kept so a
    /// re-initialised map continues in the same world frame.
    pub fn reset(&mut self) {
        let keep = self.last_known_pose;
        let removed = self.removed.take();
        *self = Self::new(self.cam.clone(), self.params.clone());
        self.last_known_pose = keep;
        self.removed = removed;
    }

    fn max_frames(&self) -> u64 {
        self.cam.fps.max(1.0).round() as u64
    }

    /// Tracks one frame: initialises, tracks or relocalises, then decides on a keyframe
    /// (ORB-SLAM2 `Tracking::Track`).
    pub fn track(
        &mut self,
        map: &mut Map,
        mut frame: Frame,
        vocab: Option<&Vocabulary>,
    ) -> TrackOutcome {
        let mut out = self.empty_outcome();
        if let Some(r) = self.removed.as_mut() {
            r.clear();
        }
        if self.state == TrackingState::NotInitialized {
            tracing::debug!(
                frame = frame.id,
                keypoints = frame.len(),
                needed = self.params.init_min_features + 1,
                "initialisation"
            );
            if frame.len() > self.params.init_min_features
                && frame.depth.iter().filter(|&&d| d > 0.0).count() > 0
            {
                let kf = self.initialize(map, &mut frame);
                out.new_keyframe = Some(kf);
                out.state = TrackingState::Ok;
                out.pose = frame.pose;
                out.reference = Some(kf);
                out.inliers = frame.map_points.iter().flatten().count();
                self.record_last(map, frame);
            }
            return out;
        }
        let ok = self.track_against_map(map, &mut frame, vocab, &mut out);
        if ok {
            // Matches to points that lost all observations are dropped.
            for m in frame.map_points.iter_mut() {
                if let Some(id) = m
                    && map.point(*id).is_none_or(|p| p.num_obs < 1)
                {
                    *m = None;
                }
            }
            if self.need_new_keyframe(map, &frame) {
                out.new_keyframe = self.create_keyframe(map, &mut frame);
            }
            for i in 0..frame.len() {
                if frame.outlier[i] {
                    frame.map_points[i] = None;
                }
            }
            out.pose = frame.pose;
            self.last_known_pose = frame.pose;
        } else {
            self.velocity = None;
            if map.num_keyframes() <= self.params.reset_max_keyframes {
                out.reset_requested = true;
                out.reference = frame.reference.or(self.reference_kf);
                return out;
            }
        }
        if frame.reference.is_none() {
            frame.reference = self.reference_kf;
        }
        out.reference = frame.reference;
        if ok {
            self.record_last(map, frame);
        } else {
            // Keep the previous last frame for relocalisation bookkeeping; a lost frame has no
            // pose to propagate.
            self.last_relative = None;
        }
        out
    }

    /// The tracking steps both modes share (ORB-SLAM2 `Tracking::Track` between the state
    /// check and the keyframe decision): last-frame refresh, motion-model or reference-keyframe
    /// tracking while tracked and relocalisation otherwise, local-map tracking, then state,
    /// inlier count and the constant-velocity model. Returns whether the frame is tracked.
    pub(crate) fn track_against_map(
        &mut self,
        map: &mut Map,
        frame: &mut Frame,
        vocab: Option<&Vocabulary>,
        out: &mut TrackOutcome,
    ) -> bool {
        self.refresh_last_frame(map);
        self.predicted = false;
        let mut ok;
        if self.state == TrackingState::Ok {
            let just_relocalised = frame.id < self.last_reloc_frame + 2;
            if self.velocity.is_none() || just_relocalised {
                ok = self.track_reference_keyframe(map, frame, vocab);
            } else {
                ok = self.track_with_motion_model(map, frame);
                if !ok {
                    ok = self.track_reference_keyframe(map, frame, vocab);
                }
            }
        } else {
            if let Some(v) = vocab {
                frame.compute_bow(v, self.params.bow_group_depth);
            }
            ok = map.num_keyframes() > 0 && self.relocalize(map, frame);
            out.relocalised = ok;
        }
        if !ok {
            ok = self.predict(frame);
        }
        frame.reference = self.reference_kf;
        if ok {
            ok = self.track_local_map(map, frame);
        }
        if !ok && self.state == TrackingState::Lost && self.params.local_relocalisation {
            ok = self.relocalize_local_map(map, frame);
            if ok {
                frame.reference = self.reference_kf;
                ok = self.track_local_map(map, frame);
            }
            out.relocalised = ok;
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
            if let Some(cur) = frame.pose {
                let v = match (self.velocity, self.last_frame.as_ref()) {
                    // Per-frame velocity: after a gap the last tracked frame is further back.
                    (Some(v), Some(l)) if frame.id == l.id + 1 => v,
                    _ => self.coast.map(|c| c.0).unwrap_or_else(Se3::identity),
                };
                self.coast = Some((v, cur, frame.id));
            }
        }
        ok
    }

    /// An outcome with the current state and nothing tracked yet.
    fn empty_outcome(&self) -> TrackOutcome {
        TrackOutcome {
            state: self.state,
            pose: None,
            reference: None,
            new_keyframe: None,
            inliers: 0,
            reset_requested: false,
            relocalised: false,
        }
    }

    /// The last frame tracking saw, with its map-point matches as tracking left them.
    pub(crate) fn last_frame(&self) -> Option<&Frame> {
        self.last_frame.as_ref()
    }

    fn record_last(&mut self, map: &Map, frame: Frame) {
        self.last_relative = match (frame.reference, frame.pose) {
            (Some(r), Some(p)) => map.keyframe_pose(r).map(|rp| (r, p * rp.inverse())),
            _ => None,
        };
        self.last_frame = Some(frame);
    }

    /// ORB-SLAM2 `UpdateLastFrame`: the last pose follows its reference keyframe (moved by BA);
    /// replaced map points are followed, stale ones dropped.
    fn refresh_last_frame(&mut self, map: &Map) {
        let Some(last) = self.last_frame.as_mut() else {
            return;
        };
        if let Some((r, tlr)) = self.last_relative
            && let Some(rp) = map.keyframe_pose(r)
        {
            last.pose = Some(tlr * rp);
        }
        for m in last.map_points.iter_mut() {
            if let Some(id) = *m {
                *m = map.resolve(id);
            }
        }
    }

    /// RGB-D initialisation: first keyframe at the last known pose (identity at start) with a
    /// map point for every keypoint with depth (ORB-SLAM2 `StereoInitialization`).
    fn initialize(&mut self, map: &mut Map, frame: &mut Frame) -> KeyFrameId {
        let pose = self.last_known_pose.unwrap_or_else(Se3::identity);
        frame.pose = Some(pose);
        let kf = map.insert_keyframe(KeyFrame::from_frame(frame, 0, pose));
        for i in 0..frame.len() {
            if may_birth_in_frame(&map.params.dynapix, frame, i, BirthSource::Initialization)
                && let Some(x) = frame.unproject(i, &self.cam)
                && let Some(mp) = map.create_point(x, kf, i)
            {
                frame.map_points[i] = Some(mp);
            }
        }
        frame.reference = Some(kf);
        self.reference_kf = Some(kf);
        self.last_kf_frame = frame.id;
        self.local_kfs = vec![kf];
        self.local_points = map
            .keyframe(kf)
            .map(|k| k.map_points.iter().flatten().copied().collect())
            .unwrap_or_default();
        self.state = TrackingState::Ok;
        self.velocity = None;
        kf
    }

    /// Pose-only optimisation of `frame` against its matched map points; sets the outlier
    /// flags and returns the inlier count (ORB-SLAM2 `PoseOptimization`).
    pub(crate) fn optimize_pose(&self, map: &Map, frame: &mut Frame) -> usize {
        let Some(pose) = frame.pose else { return 0 };
        let mut idx = Vec::new();
        let mut points = Vec::new();
        let mut obs = Vec::new();
        let pyr = &map.pyramid;
        for i in 0..frame.len() {
            let Some(id) = frame.map_points[i] else {
                continue;
            };
            let Some(p) = map.point(id) else {
                frame.map_points[i] = None;
                continue;
            };
            frame.outlier[i] = false;
            let kp = &frame.keys_un[i];
            let ur = frame.u_right[i];
            idx.push(i);
            points.push(p.position);
            obs.push(Observation {
                uv: [kp.x as f64, kp.y as f64],
                u_right: (ur >= 0.0).then_some(ur as f64),
                inv_sigma2: pyr.inv_sigma2_of(kp.octave as usize) as f64,
                weight: frame.weights[i] as f64,
            });
        }
        if idx.len() < 3 {
            return 0;
        }
        let problem = PoseOnlyProblem {
            camera: stereo_camera(&self.cam),
            pose,
            points,
            observations: obs,
        };
        let params = crate::weighting::pose_params(&self.params.pose, &map.params.dynapix);
        let result = dynapix_optim::optimize_pose(&problem, &params);
        frame.pose = Some(normalized(&result.pose));
        for (k, &i) in idx.iter().enumerate() {
            frame.outlier[i] = !result.inlier.get(k).copied().unwrap_or(false);
        }
        result.num_inliers
    }

    /// Drops outlier matches and counts inliers that are real map points.
    fn discard_outliers(&self, map: &Map, frame: &mut Frame) -> usize {
        let mut n = 0;
        for i in 0..frame.len() {
            let Some(id) = frame.map_points[i] else {
                continue;
            };
            if frame.outlier[i] {
                frame.map_points[i] = None;
                frame.outlier[i] = false;
            } else if map.point(id).is_some_and(|p| p.num_obs > 0) {
                n += 1;
            }
        }
        n
    }

    fn track_reference_keyframe(
        &mut self,
        map: &mut Map,
        frame: &mut Frame,
        vocab: Option<&Vocabulary>,
    ) -> bool {
        if let Some(v) = vocab {
            frame.compute_bow(v, self.params.bow_group_depth);
        }
        let Some(rk) = self.reference_kf.and_then(|r| map.keyframe(r)) else {
            return false;
        };
        let (matches, n) = matcher::search_keyframe_to_frame(
            rk,
            frame,
            map,
            self.params.ref_ratio,
            true,
            &self.params.matcher,
        );
        if n < self.params.ref_min_matches {
            return false;
        }
        frame.map_points = matches;
        frame.pose = self.last_frame.as_ref().and_then(|l| l.pose);
        if frame.pose.is_none() {
            return false;
        }
        self.optimize_pose(map, frame);
        self.discard_outliers(map, frame) >= self.params.min_inliers_frame
    }

    fn track_with_motion_model(&mut self, map: &mut Map, frame: &mut Frame) -> bool {
        let (Some(v), Some(last)) = (self.velocity, self.last_frame.as_ref()) else {
            return false;
        };
        let Some(lp) = last.pose else { return false };
        frame.pose = Some(normalized(&(v * lp)));
        frame.map_points.iter_mut().for_each(|m| *m = None);
        let th = self.params.motion_th;
        let mut n = matcher::search_frame_by_projection(
            frame,
            last,
            map,
            &self.cam,
            th,
            true,
            &self.params.matcher,
        );
        if n < self.params.motion_min_matches {
            frame.map_points.iter_mut().for_each(|m| *m = None);
            n = matcher::search_frame_by_projection(
                frame,
                last,
                map,
                &self.cam,
                2.0 * th,
                true,
                &self.params.matcher,
            );
        }
        if n < self.params.motion_min_matches {
            return false;
        }
        self.optimize_pose(map, frame);
        let good = self.discard_outliers(map, frame);
        tracing::debug!(frame = frame.id, matches = n, good, "motion model");
        good >= self.params.min_inliers_frame
    }

    /// Local keyframes: all sharing points with the frame, plus per keyframe one new best
    /// covisible, one child and the parent (ORB-SLAM2 `UpdateLocalKeyFrames`, without its
    /// early `break` quirk). The reference keyframe becomes the one sharing most points.
    fn update_local_keyframes(&mut self, map: &Map, frame: &mut Frame) {
        let mut counter: BTreeMap<KeyFrameId, usize> = BTreeMap::new();
        for m in frame.map_points.iter_mut() {
            let Some(id) = *m else { continue };
            match map.point(id) {
                Some(p) => {
                    for &k in p.observations.keys() {
                        *counter.entry(k).or_insert(0) += 1;
                    }
                }
                None => *m = None,
            }
        }
        if counter.is_empty() {
            return;
        }
        let mut best: Option<(KeyFrameId, usize)> = None;
        let mut local: Vec<KeyFrameId> = Vec::with_capacity(counter.len() * 2);
        let mut in_local: HashSet<KeyFrameId> = HashSet::new();
        for (&k, &c) in &counter {
            if map.keyframe(k).is_none() {
                continue;
            }
            if best.is_none_or(|(_, bc)| c > bc) {
                best = Some((k, c));
            }
            local.push(k);
            in_local.insert(k);
        }
        let first_ring = local.clone();
        for k in first_ring {
            if local.len() > self.params.max_local_keyframes {
                break;
            }
            let Some(kf) = map.keyframe(k) else { continue };
            for n in kf.best_covisibles(10) {
                if in_local.insert(n) {
                    local.push(n);
                    break;
                }
            }
            for &c in &kf.children {
                if map.keyframe(c).is_some() && in_local.insert(c) {
                    local.push(c);
                    break;
                }
            }
            if let Some(p) = kf.parent
                && map.keyframe(p).is_some()
                && in_local.insert(p)
            {
                local.push(p);
            }
        }
        self.local_kfs = local;
        if let Some((b, _)) = best {
            self.reference_kf = Some(b);
            frame.reference = Some(b);
        }
    }

    fn update_local_points(&mut self, map: &Map) {
        let mut seen: HashSet<MapPointId> = HashSet::new();
        self.local_points.clear();
        for &k in &self.local_kfs {
            let Some(kf) = map.keyframe(k) else { continue };
            for id in kf.map_points.iter().flatten() {
                if map.point(*id).is_some() && seen.insert(*id) {
                    self.local_points.push(*id);
                }
            }
        }
    }

    /// Frustum test (ORB-SLAM2 `Frame::isInFrustum`): projection, scale-invariance distance
    /// and viewing angle; yields the candidate with its predicted level.
    fn frustum(&self, map: &Map, frame: &Frame, id: MapPointId) -> Option<ProjectionCandidate> {
        let p = map.point(id)?;
        let pose = frame.pose?;
        let pc = transform(&pose, &p.position);
        let (u, v, ur) = self.cam.project(&pc)?;
        if !frame.grid.bounds.contains(u, v) {
            return None;
        }
        let center = pose.inverse().translation.vector;
        let po = p.position - center;
        let dist = po.norm();
        if dist < 0.8 * p.min_distance || dist > 1.2 * p.max_distance {
            return None;
        }
        let view_cos = po.dot(&p.normal) / dist;
        if view_cos < self.params.view_cos_min {
            return None;
        }
        Some(ProjectionCandidate {
            point: id,
            u,
            v,
            u_right: ur,
            level: p.predict_scale(dist, &map.pyramid),
            view_cos,
        })
    }

    fn search_local_points(&mut self, map: &mut Map, frame: &mut Frame) {
        let mut matched: HashSet<MapPointId> = HashSet::new();
        for m in frame.map_points.iter_mut() {
            let Some(id) = *m else { continue };
            match map.point_mut(id) {
                Some(p) => {
                    p.visible += 1;
                    matched.insert(id);
                }
                None => *m = None,
            }
        }
        let mut cands = Vec::new();
        for &id in &self.local_points {
            if matched.contains(&id) {
                continue;
            }
            if let Some(c) = self.frustum(map, frame, id) {
                cands.push(c);
            }
        }
        for c in &cands {
            if let Some(p) = map.point_mut(c.point) {
                p.visible += 1;
            }
        }
        if cands.is_empty() {
            return;
        }
        let th = if frame.id < self.last_reloc_frame + 2 || self.predicted {
            self.params.local_th_reloc
        } else {
            self.params.local_th
        };
        matcher::search_local_by_projection(
            frame,
            map,
            &cands,
            th,
            self.params.local_ratio,
            &self.params.matcher,
        );
    }

    fn track_local_map(&mut self, map: &mut Map, frame: &mut Frame) -> bool {
        let prior = frame.pose.filter(|_| self.predicted);
        self.update_local_keyframes(map, frame);
        self.update_local_points(map);
        self.search_local_points(map, frame);
        self.optimize_pose(map, frame);
        if self.params.pose_consistency
            && let (Some(from), Some(to)) = (prior, frame.pose)
            && let Some(shift) = predicted::median_shift(
                &self.cam,
                self.local_points.iter().filter_map(|&id| map.point(id)),
                &frame.grid.bounds,
                &from,
                &to,
            )
            && shift > predicted::search_window(self.params.local_th_reloc)
        {
            tracing::debug!(frame = frame.id, shift, "predicted pose refused: map moved");
            return false;
        }
        let upd = crate::weighting::update_matched_points_logged(map, frame, self.removed.as_mut());
        if upd.deleted > 0 {
            tracing::debug!(
                frame = frame.id,
                deleted = upd.deleted,
                "map points removed at γ_del"
            );
        }
        let mut inliers = 0;
        for i in 0..frame.len() {
            let Some(id) = frame.map_points[i] else {
                continue;
            };
            if !frame.outlier[i] {
                if let Some(p) = map.point_mut(id) {
                    p.found += 1;
                    if p.num_obs > 0 {
                        inliers += 1;
                    }
                }
            } else {
                frame.map_points[i] = None;
            }
        }
        self.inliers = inliers;
        tracing::debug!(
            frame = frame.id,
            local_kfs = self.local_kfs.len(),
            local_points = self.local_points.len(),
            inliers,
            "local map tracked"
        );
        if frame.id < self.last_reloc_frame + self.max_frames()
            && inliers < self.params.local_min_inliers_reloc
        {
            return false;
        }
        if self.predicted {
            // A predicted pose needs only as many inliers as a motion-model pose.
            return inliers >= self.params.min_inliers_frame;
        }
        inliers >= self.params.local_min_inliers
    }

    fn relocalize(&mut self, map: &mut Map, frame: &mut Frame) -> bool {
        let ok = relocalization::relocalize(self, map, frame);
        if ok {
            self.last_reloc_frame = frame.id;
        }
        ok
    }

    /// Relocalisation against the last local map (see
    /// [`TrackingParams::local_relocalisation`]); counts as a relocalisation for the stricter
    /// local-map check of the following frames.
    fn relocalize_local_map(&mut self, map: &mut Map, frame: &mut Frame) -> bool {
        self.predicted = false;
        let ok = local_reloc::relocalize_local_map(self, map, frame);
        if ok {
            self.last_reloc_frame = frame.id;
        }
        ok
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::KeyPoint;
    use crate::features::ScalePyramid;
    use crate::frame::DepthImage;
    use crate::map::MapParams;
    use dynapix_geometry::PinholeCamera;
    use image::Luma;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A static world of textured points seen by a pinhole RGB-D camera: keypoints are exact
    /// projections, descriptors are per-point random bit strings, depth is exact.
    struct World {
        points: Vec<Vector3<f64>>,
        descs: Vec<[u8; 32]>,
        cam: RgbdCamera,
    }

    impl World {
        fn new(n: usize, seed: u64) -> Self {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let points = (0..n)
                .map(|_| {
                    Vector3::new(
                        rng.random_range(-1.5..1.5),
                        rng.random_range(-1.1..1.1),
                        rng.random_range(1.5..3.0),
                    )
                })
                .collect();
            let descs = (0..n).map(|_| rng.random()).collect();
            Self {
                points,
                descs,
                cam: RgbdCamera::new(PinholeCamera::tum_fr3(), 40.0, 40.0, 30.0),
            }
        }

        fn frame(&self, id: u64, tcw: &Se3) -> Frame {
            let mut keys = Vec::new();
            let mut descs = Vec::new();
            let mut depth = DepthImage::new(640, 480);
            for (p, d) in self.points.iter().zip(&self.descs) {
                let pc = transform(tcw, p);
                let Some((u, v, _)) = self.cam.project(&pc) else {
                    continue;
                };
                if !(1.0..639.0).contains(&u) || !(1.0..479.0).contains(&v) {
                    continue;
                }
                keys.push(KeyPoint {
                    x: u as f32,
                    y: v as f32,
                    angle: 0.0,
                    response: 1.0,
                    octave: 0,
                    size: 31.0,
                });
                descs.push(*d);
                depth.put_pixel(u as u32, v as u32, Luma([pc.z as f32]));
            }
            Frame::new(
                id,
                id as f64 / 30.0,
                keys,
                descs,
                &depth,
                None,
                &self.cam,
                self.cam.image_bounds(),
            )
        }
    }

    fn pose_at(i: u64) -> Se3 {
        let s = i as f64;
        Se3::from_parts(
            Translation3::new(0.01 * s, -0.004 * s, 0.006 * s),
            UnitQuaternion::from_euler_angles(0.002 * s, -0.003 * s, 0.001 * s),
        )
    }

    #[test]
    fn tracks_a_synthetic_sequence_and_recovers_the_poses() {
        let world = World::new(1500, 7);
        let mut map = Map::new(ScalePyramid::new(8, 1.2), MapParams::default());
        let mut tracker = Tracker::new(world.cam.clone(), TrackingParams::default());
        let first = world.frame(0, &pose_at(0));
        assert!(first.len() > 500);
        let out = tracker.track(&mut map, first, None);
        assert_eq!(out.state, TrackingState::Ok);
        assert!(out.new_keyframe.is_some());
        // World frame = first camera, so later poses are relative to pose 0.
        let t0_inv = pose_at(0).inverse();
        for i in 1..12 {
            let truth = pose_at(i) * t0_inv;
            let out = tracker.track(&mut map, world.frame(i, &pose_at(i)), None);
            assert_eq!(out.state, TrackingState::Ok, "frame {i}");
            let est = out.pose.unwrap();
            let dt = (est.translation.vector - truth.translation.vector).norm();
            let dr = est.rotation.angle_to(&truth.rotation);
            assert!(dt < 1e-3 && dr < 1e-3, "frame {i}: {dt} m, {dr} rad");
            assert!(out.inliers > 300, "frame {i}: {} inliers", out.inliers);
        }
    }

    #[test]
    fn a_frame_without_features_is_lost_and_not_initialised_before_a_map() {
        let world = World::new(1500, 3);
        let mut map = Map::new(ScalePyramid::new(8, 1.2), MapParams::default());
        let mut tracker = Tracker::new(world.cam.clone(), TrackingParams::default());
        let empty = Frame::new(
            0,
            0.0,
            vec![],
            vec![],
            &DepthImage::new(640, 480),
            None,
            &world.cam,
            world.cam.image_bounds(),
        );
        let out = tracker.track(&mut map, empty.clone(), None);
        assert_eq!(out.state, TrackingState::NotInitialized);
        tracker.track(&mut map, world.frame(1, &pose_at(0)), None);
        let mut lost = empty;
        lost.id = 2;
        let out = tracker.track(&mut map, lost, None);
        assert_eq!(out.state, TrackingState::Lost);
        // A one-keyframe map is reset by the system.
        assert!(out.reset_requested);
    }

    /// Tracks frames 0..10 of `world`, then `occluded` frames without a keypoint, then the
    /// frames after; returns the state and pose error of each returning frame.
    fn occlusion_run(
        params: TrackingParams,
        occluded: u64,
        returning: impl Fn(u64) -> Frame,
        world: &World,
    ) -> Vec<(TrackingState, f64)> {
        let mut map = Map::new(ScalePyramid::new(8, 1.2), MapParams::default());
        let mut tracker = Tracker::new(world.cam.clone(), params);
        for i in 0..10 {
            tracker.track(&mut map, world.frame(i, &pose_at(i)), None);
        }
        let empty = |id: u64| {
            Frame::new(
                id,
                id as f64 / 30.0,
                vec![],
                vec![],
                &DepthImage::new(640, 480),
                None,
                &world.cam,
                world.cam.image_bounds(),
            )
        };
        for i in 10..10 + occluded {
            let out = tracker.track(&mut map, empty(i), None);
            assert_eq!(out.state, TrackingState::Lost, "occluded frame {i}");
        }
        let t0_inv = pose_at(0).inverse();
        (10 + occluded..15 + occluded)
            .map(|i| {
                let out = tracker.track(&mut map, returning(i), None);
                let err = out.pose.map_or(f64::INFINITY, |p| {
                    let truth = pose_at(i) * t0_inv;
                    (p.translation.vector - truth.translation.vector).norm()
                });
                (out.state, err)
            })
            .collect()
    }

    /// Bag-of-words relocalisation made impossible, to see the local-map one alone.
    fn no_bow_reloc(local: bool) -> TrackingParams {
        let mut p = TrackingParams::default();
        p.reloc.min_matches = usize::MAX;
        p.local_relocalisation = local;
        p
    }

    #[test]
    fn local_map_relocalisation_recovers_when_static_features_return() {
        let world = World::new(1500, 11);
        // 40 frames of full occlusion: longer than any predicted tracking (off here).
        let on = occlusion_run(
            no_bow_reloc(true),
            40,
            |i| world.frame(i, &pose_at(i)),
            &world,
        );
        assert_eq!(on[0].0, TrackingState::Ok, "first returning frame");
        for (k, (state, err)) in on.iter().enumerate() {
            assert_eq!(*state, TrackingState::Ok, "returning frame {k}");
            assert!(*err < 1e-3, "returning frame {k}: {err} m");
        }
        let off = occlusion_run(
            no_bow_reloc(false),
            40,
            |i| world.frame(i, &pose_at(i)),
            &world,
        );
        assert!(
            off.iter().all(|(s, _)| *s == TrackingState::Lost),
            "{off:?}"
        );
    }

    #[test]
    fn local_map_relocalisation_refuses_another_place() {
        let world = World::new(1500, 11);
        // After the occlusion the camera sees another world: no pose may be accepted.
        let other = World::new(1500, 12);
        let out = occlusion_run(
            no_bow_reloc(true),
            5,
            |i| other.frame(i, &pose_at(i)),
            &world,
        );
        assert!(
            out.iter().all(|(s, _)| *s == TrackingState::Lost),
            "{out:?}"
        );
    }
}
