//! Local mapping (ORB-SLAM2 `LocalMapping`, spec §6.5/§6.7), run synchronously on each new
//! keyframe: keyframe insertion (observations, covisibility, spanning tree), culling of recent
//! map points, triangulation with the best covisible keyframes, fusion with first- and
//! second-order neighbours, weighted local bundle adjustment and keyframe culling.

use std::collections::{HashMap, HashSet};

use crate::weighting::{BirthSource, may_birth_in_keyframe};
use dynapix_optim::{BaEdge, BaParams, BaProblem, Observation};
use nalgebra::{Matrix4, Vector3};

use crate::camera::RgbdCamera;
use crate::camera::stereo_camera;
use crate::frame::bow_vectors;
use crate::ids::{KeyFrameId, MapPointId};
use crate::map::Map;
use crate::matcher::{self, MatcherParams};
use crate::pose::transform;
use crate::vocab::Vocabulary;

/// Local-mapping parameters (ORB-SLAM2 RGB-D defaults).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct LocalMappingParams {
    /// Recent points with found/visible below this are culled (0.25).
    pub cull_found_ratio: f32,
    /// Recent points with at most this many observations … (3 for RGB-D) …
    pub cull_max_obs: usize,
    /// … are culled once this many keyframes have passed since creation (2).
    pub cull_age: u64,
    /// Points leave the recent list after this many keyframes (3).
    pub recent_window: u64,
    /// Covisible keyframes used for triangulation (10).
    pub triangulation_neighbours: usize,
    /// Scale-consistency slack factor (1.5 × scale factor).
    pub ratio_factor_slack: f32,
    /// Reprojection χ² threshold of mono observations when triangulating (5.991).
    pub chi2_mono: f64,
    /// Reprojection χ² threshold of stereo observations when triangulating (7.8).
    pub chi2_stereo: f64,
    /// First-order neighbours for fusion (10).
    pub fuse_neighbours: usize,
    /// Second-order neighbours per first-order one (5).
    pub fuse_second: usize,
    /// Fusion search radius factor (3).
    pub fuse_th: f32,
    /// Local BA runs when the map has more keyframes than this (2).
    pub ba_min_keyframes: usize,
    /// Keyframe culling: redundant fraction of close points (0.9).
    pub kf_redundancy: f32,
    /// Keyframe culling: other keyframes that must see a point (3).
    pub kf_cull_observers: usize,
    /// Vocabulary tree depth at which features are grouped for BoW matching (2).
    pub bow_group_depth: usize,
    /// Most covisible keyframes optimised by local BA (by shared points; others observing the
    /// local points are held fixed). ORB-SLAM2 takes all covisibles, which makes every local
    /// BA global when the whole map is covisible (small static scenes); 20 keeps it local.
    pub ba_max_local_keyframes: usize,
    /// Local BA of a keyframe is left to the next keyframe's when the last local BA ran on a
    /// keyframe taken less than this many seconds (of sequence time) before it (0.05; 0 runs
    /// it on every keyframe). The next BA's window holds the skipped keyframe, its best
    /// covisible, so it is optimised one frame later. ORB-SLAM2's mapping thread does the
    /// same when keyframes arrive faster than it maps them (it skips fusion, BA and keyframe
    /// culling while a keyframe waits, and aborts a running BA when one arrives), at times
    /// set by the thread scheduler; here the frame times decide, so runs stay identical.
    /// Only the BA waits here: fusion and keyframe culling run on every keyframe. At
    /// 30 frames/s, 0.05 s means: no local BA on two consecutive frames.
    pub ba_min_interval_s: f64,
    /// Bundle adjustment parameters.
    pub ba: BaParams,
    /// Matcher thresholds.
    pub matcher: MatcherParams,
}

impl Default for LocalMappingParams {
    fn default() -> Self {
        Self {
            cull_found_ratio: 0.25,
            cull_max_obs: 3,
            cull_age: 2,
            recent_window: 3,
            triangulation_neighbours: 10,
            ratio_factor_slack: 1.5,
            chi2_mono: 5.991,
            chi2_stereo: 7.8,
            fuse_neighbours: 10,
            fuse_second: 5,
            fuse_th: 3.0,
            ba_min_keyframes: 2,
            kf_redundancy: 0.9,
            kf_cull_observers: 3,
            bow_group_depth: 2,
            ba_max_local_keyframes: 20,
            ba_min_interval_s: 0.05,
            ba: BaParams::default(),
            matcher: MatcherParams::default(),
        }
    }
}

/// Counters of one local-mapping step.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MappingStats {
    /// Recent points culled.
    pub culled_points: usize,
    /// Points created by triangulation.
    pub new_points: usize,
    /// Fused matches.
    pub fused: usize,
    /// Observations rejected by local BA.
    pub ba_outliers: usize,
    /// Keyframes culled.
    pub culled_keyframes: usize,
    /// Local BA was left to the next keyframe ([`LocalMappingParams::ba_min_interval_s`]).
    pub ba_skipped: bool,
}

/// The local-mapping stage.
pub struct LocalMapper {
    /// Parameters.
    pub params: LocalMappingParams,
    cam: RgbdCamera,
    recent: Vec<MapPointId>,
    /// Time stamp of the keyframe of the last local BA.
    last_ba_time: Option<f64>,
}

impl LocalMapper {
    /// A local mapper for `cam`.
    pub fn new(cam: RgbdCamera, params: LocalMappingParams) -> Self {
        Self {
            params,
            cam,
            recent: Vec::new(),
            last_ba_time: None,
        }
    }

    /// Forgets scratch state (after a map reset).
    pub fn reset(&mut self) {
        self.recent.clear();
        self.last_ba_time = None;
    }

    /// True when the local BA of a keyframe taken at `time` waits for the next keyframe's
    /// (see [`LocalMappingParams::ba_min_interval_s`]).
    fn defers_ba(&self, time: Option<f64>) -> bool {
        match (time, self.last_ba_time) {
            // Times that go backwards never defer: the BA runs and becomes the new reference.
            (Some(t), Some(last)) => (0.0..self.params.ba_min_interval_s).contains(&(t - last)),
            _ => false,
        }
    }

    /// Runs all local-mapping steps on keyframe `kf`.
    pub fn process(
        &mut self,
        map: &mut Map,
        kf: KeyFrameId,
        vocab: Option<&Vocabulary>,
    ) -> MappingStats {
        let mut stats = MappingStats::default();
        if let Some(v) = vocab
            && let Some(k) = map.keyframe_mut(kf)
            && k.bow.is_empty()
        {
            (k.bow, k.feat) = bow_vectors(v, &k.descriptors, self.params.bow_group_depth);
        }
        let t0 = std::time::Instant::now();
        {
            let _stage =
                tracing::info_span!(target: "dynapix::stage", "mapping: insert and cull points")
                    .entered();
            self.insert_keyframe(map, kf);
            stats.culled_points = self.cull_points(map, kf);
        }
        let t1 = std::time::Instant::now();
        {
            let _stage =
                tracing::info_span!(target: "dynapix::stage", "mapping: triangulation").entered();
            stats.new_points = self.triangulate(map, kf);
        }
        let t2 = std::time::Instant::now();
        {
            let _stage = tracing::info_span!(target: "dynapix::stage", "mapping: fusion").entered();
            stats.fused = self.search_in_neighbors(map, kf);
        }
        let t3 = std::time::Instant::now();
        let time = map.keyframe(kf).map(|k| k.timestamp);
        stats.ba_skipped = self.defers_ba(time);
        if !stats.ba_skipped && map.num_keyframes() > self.params.ba_min_keyframes {
            self.last_ba_time = time;
            let _stage =
                tracing::info_span!(target: "dynapix::stage", "mapping: local BA").entered();
            stats.ba_outliers = self.local_bundle_adjustment(map, kf);
        }
        let t4 = std::time::Instant::now();
        {
            let _stage =
                tracing::info_span!(target: "dynapix::stage", "mapping: cull keyframes").entered();
            stats.culled_keyframes = self.cull_keyframes(map, kf);
        }
        tracing::debug!(
            insert_ms = (t1 - t0).as_secs_f64() * 1e3,
            triangulate_ms = (t2 - t1).as_secs_f64() * 1e3,
            fuse_ms = (t3 - t2).as_secs_f64() * 1e3,
            ba_ms = (t4 - t3).as_secs_f64() * 1e3,
            cull_ms = t4.elapsed().as_secs_f64() * 1e3,
            covisibles = map.keyframe(kf).map_or(0, |k| k.ordered.len()),
            "local mapping"
        );
        stats
    }

    fn insert_keyframe(&mut self, map: &mut Map, kf: KeyFrameId) {
        let Some(k) = map.keyframe(kf) else { return };
        let mps: Vec<(usize, MapPointId)> = k
            .map_points
            .iter()
            .enumerate()
            .filter_map(|(i, m)| m.map(|m| (i, m)))
            .collect();
        for (i, mp) in mps {
            if map.point(mp).is_none() {
                map.set_keyframe_match(kf, i, None);
                continue;
            }
            if !map.is_in_keyframe(mp, kf) {
                map.add_observation(mp, kf, i);
                map.update_normal_and_depth(mp);
                map.compute_distinctive_descriptor(mp);
            } else {
                self.recent.push(mp);
            }
        }
        map.update_connections(kf);
    }

    fn cull_points(&mut self, map: &mut Map, kf: KeyFrameId) -> usize {
        let Some(cur_seq) = map.keyframe(kf).map(|k| k.seq) else {
            return 0;
        };
        let p = &self.params;
        let mut culled = 0;
        let mut keep = Vec::with_capacity(self.recent.len());
        for &mp in &self.recent {
            let Some(pt) = map.point(mp) else { continue };
            let age = cur_seq.saturating_sub(pt.first_kf_seq);
            if pt.found_ratio() < p.cull_found_ratio
                || (age >= p.cull_age && pt.num_obs <= p.cull_max_obs)
            {
                map.cull_point(mp);
                culled += 1;
            } else if age < p.recent_window {
                keep.push(mp);
            }
        }
        self.recent = keep;
        culled
    }

    /// Triangulates new points from unmatched keypoints with the best covisible keyframes
    /// (ORB-SLAM2 `CreateNewMapPoints`, RGB-D branch).
    fn triangulate(&mut self, map: &mut Map, kf1: KeyFrameId) -> usize {
        let Some(k1) = map.keyframe(kf1) else {
            return 0;
        };
        let neighbours = k1.best_covisibles(self.params.triangulation_neighbours);
        let cam = self.cam.clone();
        let p = &cam.pinhole;
        let pyr = map.pyramid.clone();
        let ratio_factor = self.params.ratio_factor_slack * pyr.scale_factor;
        let mut created = 0;
        let mut gated = 0usize;
        for kf2 in neighbours {
            let (Some(k1), Some(k2)) = (map.keyframe(kf1), map.keyframe(kf2)) else {
                continue;
            };
            let o1 = k1.center();
            let o2 = k2.center();
            if (o2 - o1).norm() < cam.baseline() {
                continue;
            }
            let f12 = matcher::fundamental(k1, k2, &cam);
            let pairs =
                matcher::search_for_triangulation(k1, k2, &f12, &cam, &pyr, &self.params.matcher);
            let t1 = k1.pose;
            let t2 = k2.pose;
            let r1w = t1.inverse().rotation;
            let r2w = t2.inverse().rotation;
            let mut new_points: Vec<(Vector3<f64>, usize, usize)> = Vec::new();
            for (i1, i2) in pairs {
                let kp1 = &k1.keys_un[i1];
                let kp2 = &k2.keys_un[i2];
                let ur1 = k1.u_right[i1] as f64;
                let ur2 = k2.u_right[i2] as f64;
                let (s1, s2) = (ur1 >= 0.0, ur2 >= 0.0);
                let xn1 = Vector3::new(
                    (kp1.x as f64 - p.cx) / p.fx,
                    (kp1.y as f64 - p.cy) / p.fy,
                    1.0,
                );
                let xn2 = Vector3::new(
                    (kp2.x as f64 - p.cx) / p.fx,
                    (kp2.y as f64 - p.cy) / p.fy,
                    1.0,
                );
                let ray1 = r1w * xn1;
                let ray2 = r2w * xn2;
                let cos_rays = ray1.dot(&ray2) / (ray1.norm() * ray2.norm());
                let b = cam.baseline();
                let cps1 = if s1 {
                    (2.0 * (b / 2.0).atan2(k1.depth[i1] as f64)).cos()
                } else {
                    cos_rays + 1.0
                };
                let cps2 = if s2 {
                    (2.0 * (b / 2.0).atan2(k2.depth[i2] as f64)).cos()
                } else {
                    cos_rays + 1.0
                };
                let cps = cps1.min(cps2);
                let x3d = if cos_rays < cps && cos_rays > 0.0 && (s1 || s2 || cos_rays < 0.9998) {
                    match linear_triangulation(&xn1, &xn2, &t1, &t2) {
                        Some(x) => x,
                        None => continue,
                    }
                } else if s1 && cps1 < cps2 {
                    match k1.unproject(i1, &cam) {
                        Some(x) => x,
                        None => continue,
                    }
                } else if s2 && cps2 < cps1 {
                    match k2.unproject(i2, &cam) {
                        Some(x) => x,
                        None => continue,
                    }
                } else {
                    continue;
                };
                let pc1 = transform(&t1, &x3d);
                let pc2 = transform(&t2, &x3d);
                if pc1.z <= 0.0 || pc2.z <= 0.0 {
                    continue;
                }
                let reproj_ok =
                    |pc: &Vector3<f64>, kp: &crate::features::KeyPoint, ur: f64, st: bool| {
                        let Some((u, v, uru)) = cam.project(pc) else {
                            return false;
                        };
                        let s2 = pyr.sigma2_of(kp.octave as usize) as f64;
                        let (ex, ey) = (u - kp.x as f64, v - kp.y as f64);
                        if st {
                            let er = uru - ur;
                            ex * ex + ey * ey + er * er <= self.params.chi2_stereo * s2
                        } else {
                            ex * ex + ey * ey <= self.params.chi2_mono * s2
                        }
                    };
                if !reproj_ok(&pc1, kp1, ur1, s1) || !reproj_ok(&pc2, kp2, ur2, s2) {
                    continue;
                }
                let d1 = (x3d - o1).norm();
                let d2 = (x3d - o2).norm();
                if d1 == 0.0 || d2 == 0.0 {
                    continue;
                }
                let ratio_dist = (d2 / d1) as f32;
                let ratio_oct =
                    pyr.scale_of(kp1.octave as usize) / pyr.scale_of(kp2.octave as usize);
                if ratio_dist * ratio_factor < ratio_oct || ratio_dist > ratio_oct * ratio_factor {
                    continue;
                }
                new_points.push((x3d, i1, i2));
            }
            for (x, i1, i2) in new_points {
                // Earlier neighbours may have claimed these keypoints in the meantime.
                let taken1 = map
                    .keyframe(kf1)
                    .is_none_or(|k| k.map_points.get(i1).is_none_or(|m| m.is_some()));
                let taken2 = map
                    .keyframe(kf2)
                    .is_none_or(|k| k.map_points.get(i2).is_none_or(|m| m.is_some()));
                if taken1 || taken2 {
                    continue;
                }
                if !may_birth_in_keyframe(map, kf1, i1, BirthSource::Triangulation)
                    || !may_birth_in_keyframe(map, kf2, i2, BirthSource::Triangulation)
                {
                    gated += 1;
                    continue;
                }
                if let Some(id) = map.create_point(x, kf1, i1) {
                    map.add_observation(id, kf2, i2);
                    map.set_keyframe_match(kf2, i2, Some(id));
                    map.compute_distinctive_descriptor(id);
                    map.update_normal_and_depth(id);
                    self.recent.push(id);
                    created += 1;
                }
            }
        }
        if gated > 0 {
            tracing::debug!(gated, created, "triangulated points not born (γ_add)");
        }
        created
    }

    /// Fuses the keyframe's points into its neighbours and theirs into it (ORB-SLAM2
    /// `SearchInNeighbors`).
    fn search_in_neighbors(&mut self, map: &mut Map, kf: KeyFrameId) -> usize {
        let Some(k) = map.keyframe(kf) else { return 0 };
        let mut targets: Vec<KeyFrameId> = Vec::new();
        let mut seen: HashSet<KeyFrameId> = HashSet::new();
        seen.insert(kf);
        for n in k.best_covisibles(self.params.fuse_neighbours) {
            if seen.insert(n) {
                targets.push(n);
            }
        }
        let first: Vec<KeyFrameId> = targets.clone();
        for n in first {
            if let Some(nk) = map.keyframe(n) {
                for n2 in nk.best_covisibles(self.params.fuse_second) {
                    if seen.insert(n2) {
                        targets.push(n2);
                    }
                }
            }
        }
        let cam = self.cam.clone();
        let mut fused = 0;
        for &t in &targets {
            let Some(k) = map.keyframe(kf) else {
                return fused;
            };
            let own: Vec<MapPointId> = k.map_points.iter().flatten().copied().collect();
            fused += matcher::fuse(
                map,
                t,
                &own,
                &cam,
                self.params.fuse_th,
                &self.params.matcher,
            );
        }
        let mut cands: Vec<MapPointId> = Vec::new();
        let mut cseen: HashSet<MapPointId> = HashSet::new();
        for &t in &targets {
            let Some(tk) = map.keyframe(t) else { continue };
            for &m in tk.map_points.iter().flatten() {
                if map.point(m).is_some() && cseen.insert(m) {
                    cands.push(m);
                }
            }
        }
        fused += matcher::fuse(
            map,
            kf,
            &cands,
            &cam,
            self.params.fuse_th,
            &self.params.matcher,
        );
        let own: Vec<MapPointId> = map
            .keyframe(kf)
            .map(|k| k.map_points.iter().flatten().copied().collect())
            .unwrap_or_default();
        for m in own {
            map.compute_distinctive_descriptor(m);
            map.update_normal_and_depth(m);
        }
        map.update_connections(kf);
        fused
    }

    /// Weighted local BA over the keyframe, its best covisibles and their points, with observers
    /// outside the window held fixed; outlier observations are erased. Returns how many.
    fn local_bundle_adjustment(&mut self, map: &mut Map, kf: KeyFrameId) -> usize {
        let Some(k) = map.keyframe(kf) else { return 0 };
        let mut local: Vec<KeyFrameId> = vec![kf];
        local.extend(
            k.ordered
                .iter()
                .map(|(o, _)| *o)
                .filter(|o| map.keyframe(*o).is_some())
                .take(self.params.ba_max_local_keyframes),
        );
        let mut pose_index: HashMap<KeyFrameId, usize> = HashMap::new();
        for (i, &l) in local.iter().enumerate() {
            pose_index.insert(l, i);
        }
        let mut points: Vec<MapPointId> = Vec::new();
        let mut pseen: HashSet<MapPointId> = HashSet::new();
        for &l in &local {
            let Some(lk) = map.keyframe(l) else { continue };
            for &m in lk.map_points.iter().flatten() {
                if map.point(m).is_some() && pseen.insert(m) {
                    points.push(m);
                }
            }
        }
        let mut kf_ids: Vec<KeyFrameId> = local.clone();
        for &m in &points {
            let Some(p) = map.point(m) else { continue };
            for &o in p.observations.keys() {
                if !pose_index.contains_key(&o) && map.keyframe(o).is_some() {
                    pose_index.insert(o, kf_ids.len());
                    kf_ids.push(o);
                }
            }
        }
        let n_local = local.len();
        let origin = map.origin;
        let mut poses = Vec::with_capacity(kf_ids.len());
        let mut fixed = Vec::with_capacity(kf_ids.len());
        for (i, &id) in kf_ids.iter().enumerate() {
            let Some(k) = map.keyframe(id) else { return 0 };
            poses.push(k.pose);
            fixed.push(i >= n_local || Some(id) == origin);
        }
        let mut pts = Vec::with_capacity(points.len());
        for &m in &points {
            let Some(p) = map.point(m) else { return 0 };
            pts.push(p.position);
        }
        let (edges, edge_ref) = weighted_ba_edges(map, &points, &pose_index);
        if edges.is_empty() {
            return 0;
        }
        let problem = BaProblem {
            camera: stereo_camera(&self.cam),
            poses,
            pose_fixed: fixed,
            points: pts,
            edges,
        };
        let params = crate::weighting::ba_params(&self.params.ba, &map.params.dynapix);
        let result = dynapix_optim::bundle_adjust(&problem, &params);
        let mut outliers = 0;
        for (e, &(m, o)) in edge_ref.iter().enumerate() {
            if !result.inlier.get(e).copied().unwrap_or(true) {
                map.erase_observation(m, o);
                outliers += 1;
            }
        }
        for (i, &id) in kf_ids.iter().enumerate().take(n_local) {
            if let (Some(k), Some(p)) = (map.keyframe_mut(id), result.poses.get(i)) {
                k.pose = crate::pose::normalized(p);
            }
        }
        for (pi, &m) in points.iter().enumerate() {
            if let (Some(p), Some(x)) = (map.point_mut(m), result.points.get(pi)) {
                p.position = *x;
            } else {
                continue;
            }
            map.update_normal_and_depth(m);
        }
        outliers
    }

    /// Culls covisible keyframes whose close points are ≥ 90 % seen by ≥ 3 other keyframes at
    /// the same or finer scale (ORB-SLAM2 `KeyFrameCulling`).
    pub(crate) fn cull_keyframes(&mut self, map: &mut Map, kf: KeyFrameId) -> usize {
        let Some(k) = map.keyframe(kf) else { return 0 };
        let covis: Vec<KeyFrameId> = k.ordered.iter().map(|(o, _)| *o).collect();
        let th_obs = self.params.kf_cull_observers;
        let mut culled = 0;
        for c in covis {
            if Some(c) == map.origin {
                continue;
            }
            let Some(ck) = map.keyframe(c) else { continue };
            // ORB-SLAM2 never erases a keyframe with loop edges (`mbNotErase`): the essential
            // graph and later loop corrections rely on them.
            if !ck.loop_edges.is_empty() {
                continue;
            }
            let mut n_mps = 0usize;
            let mut n_redundant = 0usize;
            for (i, m) in ck.map_points.iter().enumerate() {
                let Some(m) = m else { continue };
                let Some(p) = map.point(*m) else { continue };
                let d = ck.depth[i] as f64;
                if d > self.cam.th_depth || d < 0.0 {
                    continue;
                }
                n_mps += 1;
                if p.num_obs > th_obs {
                    let level = ck.keys_un[i].octave as i32;
                    let mut n_obs = 0;
                    for (&o, &oi) in &p.observations {
                        if o == c {
                            continue;
                        }
                        let Some(ol) = map.keypoint_octave(o, oi) else {
                            continue;
                        };
                        if ol as i32 <= level + 1 {
                            n_obs += 1;
                            if n_obs >= th_obs {
                                break;
                            }
                        }
                    }
                    if n_obs >= th_obs {
                        n_redundant += 1;
                    }
                }
            }
            if n_redundant as f32 > self.params.kf_redundancy * n_mps as f32 {
                map.cull_keyframe(c);
                culled += 1;
            }
        }
        culled
    }
}

/// Weighted BA edges of `points` (edge `point` = index into `points`) as seen from the
/// keyframes of `pose_index` (edge `pose` = its value), one per observation in keyframe-id
/// order, each carrying the DynaPix weight of the observing keypoint (spec §2.7). Shared by
/// local BA and loop closing's global BA so both weigh observations identically. Also returns
/// the `(point, keyframe)` of each edge for outlier handling.
pub(crate) fn weighted_ba_edges(
    map: &Map,
    points: &[MapPointId],
    pose_index: &HashMap<KeyFrameId, usize>,
) -> (Vec<BaEdge>, Vec<(MapPointId, KeyFrameId)>) {
    let pyr = &map.pyramid;
    // `pose_index` by arena slot: one lookup per observation without hashing.
    let mut by_slot: Vec<Option<(KeyFrameId, usize)>> = Vec::new();
    for (&k, &i) in pose_index {
        if by_slot.len() <= k.slot() {
            by_slot.resize(k.slot() + 1, None);
        }
        by_slot[k.slot()] = Some((k, i));
    }
    let mut edges = Vec::new();
    let mut edge_ref: Vec<(MapPointId, KeyFrameId)> = Vec::new();
    for (pi, &m) in points.iter().enumerate() {
        let Some(p) = map.point(m) else { continue };
        for (&o, &idx) in &p.observations {
            let Some(ki) = by_slot
                .get(o.slot())
                .copied()
                .flatten()
                .and_then(|(k, i)| (k == o).then_some(i))
            else {
                continue;
            };
            let Some(k) = map.keyframe(o) else { continue };
            let Some(kp) = k.keys_un.get(idx) else {
                continue;
            };
            let ur = k.u_right.get(idx).copied().unwrap_or(-1.0);
            edges.push(BaEdge {
                pose: ki,
                point: pi,
                obs: Observation {
                    uv: [kp.x as f64, kp.y as f64],
                    u_right: (ur >= 0.0).then_some(ur as f64),
                    inv_sigma2: pyr.inv_sigma2_of(kp.octave as usize) as f64,
                    weight: k.weights.get(idx).copied().unwrap_or(1.0) as f64,
                },
            });
            edge_ref.push((m, o));
        }
    }
    (edges, edge_ref)
}

/// Linear (DLT) triangulation from normalised coordinates in two views with poses `T_cw`.
fn linear_triangulation(
    xn1: &Vector3<f64>,
    xn2: &Vector3<f64>,
    t1: &dynapix_geometry::Se3,
    t2: &dynapix_geometry::Se3,
) -> Option<Vector3<f64>> {
    let p1 = t1.to_homogeneous();
    let p2 = t2.to_homogeneous();
    let mut a = Matrix4::zeros();
    a.set_row(0, &(xn1.x * p1.row(2) - p1.row(0)));
    a.set_row(1, &(xn1.y * p1.row(2) - p1.row(1)));
    a.set_row(2, &(xn2.x * p2.row(2) - p2.row(0)));
    a.set_row(3, &(xn2.y * p2.row(2) - p2.row(1)));
    let svd = a.svd(false, true);
    let vt = svd.v_t?;
    let (imin, _) = svd
        .singular_values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let x = vt.row(imin);
    if x[3].abs() < 1e-12 {
        return None;
    }
    Some(Vector3::new(x[0] / x[3], x[1] / x[3], x[2] / x[3]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynapix_geometry::Se3;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn dlt_triangulation_recovers_a_point() {
        let x = Vector3::new(0.2, -0.1, 2.0);
        let t1 = Se3::identity();
        let t2 = Se3::from_parts(
            Translation3::new(-0.3, 0.05, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.05, 0.0),
        );
        let n = |t: &Se3| {
            let c = transform(t, &x);
            Vector3::new(c.x / c.z, c.y / c.z, 1.0)
        };
        let r = linear_triangulation(&n(&t1), &n(&t2), &t1, &t2).unwrap();
        assert!((r - x).norm() < 1e-9, "{r:?}");
    }
}
