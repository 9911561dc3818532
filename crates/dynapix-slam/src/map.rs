//! The SLAM map: keyframes and map points in generational arenas with typed ids, the
//! covisibility graph and the spanning tree (ORB-SLAM2 `Map`, `KeyFrame`, `MapPoint`
//! bookkeeping, spec §6.5). The map is the single owner of persistent state; stages receive
//! `&Map`/`&mut Map` for the duration of a step and keep only ids across calls. A stale id
//! (entity culled or replaced) is detected by its generation.

mod arena;
mod entities;

use std::collections::{BTreeMap, BTreeSet, HashMap};

use dynapix_geometry::Se3;
use nalgebra::Vector3;

use crate::features::{Descriptor, ScalePyramid, hamming};
use crate::weighting::params::DynaPixParams;
use arena::Arena;

use crate::ids::{KeyFrameId, MapPointId};
pub use entities::{CulledLink, KeyFrame, MapPoint};

/// Parameters of the map bookkeeping.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct MapParams {
    /// Minimum shared points for a covisibility edge (15).
    pub covisibility_threshold: usize,
    /// DynaPix rules (birth gate, per-point probability, deletion).
    pub dynapix: DynaPixParams,
}

impl Default for MapParams {
    fn default() -> Self {
        Self {
            covisibility_threshold: 15,
            dynapix: DynaPixParams::default(),
        }
    }
}

/// The map: sole owner of keyframes and map points.
pub struct Map {
    keyframes: Arena<KeyFrame>,
    points: Arena<MapPoint>,
    /// Culled keyframes → parent links (for trajectory recomposition).
    culled: HashMap<KeyFrameId, CulledLink>,
    /// Replaced map points → the point that absorbed them.
    replaced: HashMap<MapPointId, MapPointId>,
    next_kf_seq: u64,
    next_mp_seq: u64,
    /// Bookkeeping parameters.
    pub params: MapParams,
    /// Scale pyramid of the keypoints (level scales and σ²).
    pub pyramid: ScalePyramid,
    /// The first keyframe (origin of the spanning tree).
    pub origin: Option<KeyFrameId>,
}

/// Dense rebuilding for map persistence ([`crate::persist`]).
impl Map {
    /// A map whose keyframe `i` has id `KeyFrameId::dense(i)` and point `j` id
    /// `MapPointId::dense(j)`; nothing culled or replaced. References inside the entities must
    /// already use dense ids (an out-of-range one is simply a stale id).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn from_dense(
        pyramid: ScalePyramid,
        params: MapParams,
        keyframes: Vec<KeyFrame>,
        points: Vec<MapPoint>,
        origin: Option<KeyFrameId>,
        next_kf_seq: u64,
        next_mp_seq: u64,
    ) -> Self {
        let mut map = Self::new(pyramid, params);
        map.keyframes = Arena::from_values(keyframes);
        map.points = Arena::from_values(points);
        map.next_kf_seq = next_kf_seq;
        map.next_mp_seq = next_mp_seq;
        map.origin = origin;
        map
    }

    /// Next map point sequence number (the one [`Map::create_point`] assigns).
    pub fn next_point_seq(&self) -> u64 {
        self.next_mp_seq
    }
}

impl Map {
    /// An empty map for keypoints from `pyramid`.
    pub fn new(pyramid: ScalePyramid, params: MapParams) -> Self {
        Self {
            keyframes: Arena::new(),
            points: Arena::new(),
            culled: HashMap::new(),
            replaced: HashMap::new(),
            next_kf_seq: 0,
            next_mp_seq: 0,
            params,
            pyramid,
            origin: None,
        }
    }

    /// Removes everything (system reset); parameters are kept.
    pub fn clear(&mut self) {
        let pyr = self.pyramid.clone();
        let params = self.params.clone();
        let seq = self.next_kf_seq;
        *self = Self::new(pyr, params);
        // Keep sequence numbers increasing across resets so culling ages stay consistent.
        self.next_kf_seq = seq;
    }

    /// Number of keyframes.
    pub fn num_keyframes(&self) -> usize {
        self.keyframes.len
    }

    /// Number of map points.
    pub fn num_points(&self) -> usize {
        self.points.len
    }

    /// Next keyframe sequence number (the one [`Map::insert_keyframe`] assigns).
    pub fn next_keyframe_seq(&self) -> u64 {
        self.next_kf_seq
    }

    /// A keyframe by id (None when stale).
    pub fn keyframe(&self, id: KeyFrameId) -> Option<&KeyFrame> {
        self.keyframes.get(id.index, id.generation)
    }

    /// Mutable keyframe by id.
    pub fn keyframe_mut(&mut self, id: KeyFrameId) -> Option<&mut KeyFrame> {
        self.keyframes.get_mut(id.index, id.generation)
    }

    /// A map point by id (None when stale).
    pub fn point(&self, id: MapPointId) -> Option<&MapPoint> {
        self.points.get(id.index, id.generation)
    }

    /// Mutable map point by id.
    pub fn point_mut(&mut self, id: MapPointId) -> Option<&mut MapPoint> {
        self.points.get_mut(id.index, id.generation)
    }

    /// All keyframe ids in arena order.
    pub fn keyframe_ids(&self) -> Vec<KeyFrameId> {
        self.keyframes
            .iter()
            .map(|(index, generation, _)| KeyFrameId { index, generation })
            .collect()
    }

    /// All keyframes sorted by sequence number.
    pub fn keyframes_sorted(&self) -> Vec<(KeyFrameId, &KeyFrame)> {
        let mut v: Vec<_> = self
            .keyframes
            .iter()
            .map(|(index, generation, k)| (KeyFrameId { index, generation }, k))
            .collect();
        v.sort_by_key(|(_, k)| k.seq);
        v
    }

    /// All map point ids in arena order.
    pub fn point_ids(&self) -> Vec<MapPointId> {
        self.points
            .iter()
            .map(|(index, generation, _)| MapPointId { index, generation })
            .collect()
    }

    /// Follows replacements: the live point that stands for `id`, if any.
    pub fn resolve(&self, id: MapPointId) -> Option<MapPointId> {
        let mut cur = id;
        for _ in 0..64 {
            if self.point(cur).is_some() {
                return Some(cur);
            }
            cur = *self.replaced.get(&cur)?;
        }
        None
    }

    /// Inserts a keyframe; assigns its sequence number.
    pub fn insert_keyframe(&mut self, mut kf: KeyFrame) -> KeyFrameId {
        kf.seq = self.next_kf_seq;
        self.next_kf_seq += 1;
        let (index, generation) = self.keyframes.insert(kf);
        let id = KeyFrameId { index, generation };
        if self.origin.is_none() {
            self.origin = Some(id);
        }
        id
    }

    /// Creates a map point at `position` first seen by `kf` at keypoint `idx` and registers
    /// the observation (descriptor, normal and depth range are computed).
    pub fn create_point(
        &mut self,
        position: Vector3<f64>,
        kf: KeyFrameId,
        idx: usize,
    ) -> Option<MapPointId> {
        let k = self.keyframe(kf)?;
        let first_kf_seq = k.seq;
        let descriptor = *k.descriptors.get(idx)?;
        let weight = k.weights.get(idx).copied().unwrap_or(1.0);
        let mp = MapPoint {
            seq: self.next_mp_seq,
            position,
            normal: Vector3::zeros(),
            min_distance: 0.0,
            max_distance: 0.0,
            descriptor,
            observations: BTreeMap::new(),
            num_obs: 0,
            reference: kf,
            first_kf_seq,
            visible: 1,
            found: 1,
            weight,
            descriptor_basis: (Vec::new(), descriptor),
        };
        self.next_mp_seq += 1;
        let (index, generation) = self.points.insert(mp);
        let id = MapPointId { index, generation };
        self.add_observation(id, kf, idx);
        if let Some(k) = self.keyframe_mut(kf)
            && let Some(slot) = k.map_points.get_mut(idx)
        {
            *slot = Some(id);
        }
        self.update_normal_and_depth(id);
        Some(id)
    }

    /// True when `mp` is observed by `kf`.
    pub fn is_in_keyframe(&self, mp: MapPointId, kf: KeyFrameId) -> bool {
        self.point(mp)
            .is_some_and(|p| p.observations.contains_key(&kf))
    }

    /// Registers that `kf` observes `mp` at keypoint `idx` (point side only).
    pub fn add_observation(&mut self, mp: MapPointId, kf: KeyFrameId, idx: usize) {
        let stereo = self
            .keyframe(kf)
            .and_then(|k| k.u_right.get(idx))
            .is_some_and(|&u| u >= 0.0);
        if let Some(p) = self.point_mut(mp) {
            if p.observations.contains_key(&kf) {
                return;
            }
            p.observations.insert(kf, idx);
            p.num_obs += if stereo { 2 } else { 1 };
        }
    }

    /// Sets keypoint `idx` of `kf` to `mp` (keyframe side only).
    pub fn set_keyframe_match(&mut self, kf: KeyFrameId, idx: usize, mp: Option<MapPointId>) {
        if let Some(k) = self.keyframe_mut(kf)
            && let Some(slot) = k.map_points.get_mut(idx)
        {
            *slot = mp;
        }
    }

    /// Removes the observation of `mp` by `kf` on both sides; a point left with ≤ 2
    /// observations is culled (ORB-SLAM2 `EraseObservation`).
    pub fn erase_observation(&mut self, mp: MapPointId, kf: KeyFrameId) {
        let stereo_of = |map: &Map, idx: usize| {
            map.keyframe(kf)
                .and_then(|k| k.u_right.get(idx))
                .is_some_and(|&u| u >= 0.0)
        };
        let Some(idx) = self
            .point(mp)
            .and_then(|p| p.observations.get(&kf).copied())
        else {
            return;
        };
        let stereo = stereo_of(self, idx);
        if let Some(k) = self.keyframe_mut(kf)
            && let Some(slot) = k.map_points.get_mut(idx)
            && *slot == Some(mp)
        {
            *slot = None;
        }
        let mut bad = false;
        if let Some(p) = self.point_mut(mp) {
            p.observations.remove(&kf);
            p.num_obs = p.num_obs.saturating_sub(if stereo { 2 } else { 1 });
            if p.reference == kf
                && let Some((&first, _)) = p.observations.iter().next()
            {
                p.reference = first;
            }
            bad = p.num_obs <= 2;
        }
        if bad {
            self.cull_point(mp);
        }
    }

    /// Removes a map point and every keyframe match to it (ORB-SLAM2 `SetBadFlag`).
    pub fn cull_point(&mut self, mp: MapPointId) {
        let Some(p) = self.points.remove(mp.index, mp.generation) else {
            return;
        };
        for (&kf, &idx) in &p.observations {
            if let Some(k) = self.keyframe_mut(kf)
                && let Some(slot) = k.map_points.get_mut(idx)
                && *slot == Some(mp)
            {
                *slot = None;
            }
        }
    }

    /// Merges `old` into `new`: observations move over, statistics add up, `old` is removed
    /// (ORB-SLAM2 `MapPoint::Replace`).
    pub fn replace_point(&mut self, old: MapPointId, new: MapPointId) {
        if old == new || self.point(new).is_none() {
            return;
        }
        let Some(p) = self.points.remove(old.index, old.generation) else {
            return;
        };
        for (&kf, &idx) in &p.observations {
            if self.is_in_keyframe(new, kf) {
                if let Some(k) = self.keyframe_mut(kf)
                    && let Some(slot) = k.map_points.get_mut(idx)
                    && *slot == Some(old)
                {
                    *slot = None;
                }
            } else {
                self.set_keyframe_match(kf, idx, Some(new));
                self.add_observation(new, kf, idx);
            }
        }
        if let Some(n) = self.point_mut(new) {
            n.found += p.found;
            n.visible += p.visible;
        }
        self.replaced.insert(old, new);
        self.compute_distinctive_descriptor(new);
    }

    /// Recomputes the representative descriptor: the observation descriptor with the least
    /// median Hamming distance to the others.
    pub fn compute_distinctive_descriptor(&mut self, mp: MapPointId) {
        let Some(p) = self.point(mp) else { return };
        let mut basis = Vec::with_capacity(p.observations.len());
        let mut descs: Vec<Descriptor> = Vec::with_capacity(p.observations.len());
        for (&kf, &idx) in &p.observations {
            if let Some(d) = self.keyframe(kf).and_then(|k| k.descriptors.get(idx)) {
                basis.push((kf, idx));
                descs.push(*d);
            }
        }
        if descs.is_empty() {
            return;
        }
        // Keyframe descriptors never change: the same observations give the same choice, so
        // the quadratic search below runs only when they changed since the last one.
        if p.descriptor_basis.0 == basis && p.descriptor_basis.1 == p.descriptor {
            return;
        }
        let n = descs.len();
        // The distance matrix is symmetric: each pair is computed once, and the median of a
        // row is selected, not sorted for (same value, so the same descriptor is chosen).
        let mut dist = vec![0u32; n * n];
        for i in 0..n {
            for j in i + 1..n {
                let d = hamming(&descs[i], &descs[j]);
                dist[i * n + j] = d;
                dist[j * n + i] = d;
            }
        }
        let mut best = (u32::MAX, 0usize);
        for (i, row) in dist.chunks_exact_mut(n).enumerate() {
            let (_, &mut median, _) = row.select_nth_unstable((n - 1) / 2);
            if median < best.0 {
                best = (median, i);
            }
        }
        let d = descs[best.1];
        if let Some(p) = self.point_mut(mp) {
            p.descriptor = d;
            p.descriptor_basis = (basis, d);
        }
    }

    /// Recomputes the mean viewing direction and the scale-invariance distances from the
    /// reference keyframe (ORB-SLAM2 `UpdateNormalAndDepth`).
    pub fn update_normal_and_depth(&mut self, mp: MapPointId) {
        let Some(p) = self.point(mp) else { return };
        let pos = p.position;
        let mut normal = Vector3::zeros();
        let mut n = 0usize;
        for &kf in p.observations.keys() {
            if let Some(k) = self.keyframe(kf) {
                let d = pos - k.center();
                let norm = d.norm();
                if norm > 0.0 {
                    normal += d / norm;
                    n += 1;
                }
            }
        }
        let Some(r) = self.keyframe(p.reference) else {
            return;
        };
        let Some(&ridx) = p.observations.get(&p.reference) else {
            return;
        };
        let dist = (pos - r.center()).norm();
        let level = r.keys_un.get(ridx).map_or(0, |k| k.octave as usize);
        let level_scale = self.pyramid.scale.get(level).copied().unwrap_or(1.0) as f64;
        let top = self.pyramid.scale.last().copied().unwrap_or(1.0) as f64;
        let max_distance = dist * level_scale;
        let min_distance = max_distance / top;
        if let Some(p) = self.point_mut(mp) {
            p.max_distance = max_distance;
            p.min_distance = min_distance;
            if n > 0 {
                p.normal = normal / n as f64;
                let nn = p.normal.norm();
                if nn > 0.0 {
                    p.normal /= nn;
                }
            }
        }
    }

    /// Rebuilds the covisibility edges of `kf` from shared map points and attaches it to the
    /// spanning tree on its first connection (ORB-SLAM2 `UpdateConnections`).
    pub fn update_connections(&mut self, kf: KeyFrameId) {
        let Some(k) = self.keyframe(kf) else { return };
        let mut counter: BTreeMap<KeyFrameId, usize> = BTreeMap::new();
        for mp in k.map_points.iter().flatten() {
            if let Some(p) = self.point(*mp) {
                for &other in p.observations.keys() {
                    if other != kf {
                        *counter.entry(other).or_insert(0) += 1;
                    }
                }
            }
        }
        if counter.is_empty() {
            return;
        }
        let th = self.params.covisibility_threshold;
        let mut best: Option<(KeyFrameId, usize)> = None;
        for (&o, &w) in &counter {
            if best.is_none_or(|(_, bw)| w > bw) {
                best = Some((o, w));
            }
        }
        let mut edges: Vec<(KeyFrameId, usize)> = counter
            .iter()
            .filter(|(_, w)| **w >= th)
            .map(|(&o, &w)| (o, w))
            .collect();
        if edges.is_empty()
            && let Some(b) = best
        {
            edges.push(b);
        }
        for &(o, w) in &edges {
            self.add_connection(o, kf, w);
        }
        edges.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let is_origin = self.origin == Some(kf);
        let Some(k) = self.keyframe_mut(kf) else {
            return;
        };
        k.connections = edges.iter().copied().collect();
        k.ordered = edges.clone();
        let needs_parent = k.parent.is_none() && !is_origin;
        if needs_parent && let Some(&(p, _)) = edges.first() {
            k.parent = Some(p);
            if let Some(pk) = self.keyframe_mut(p) {
                pk.children.insert(kf);
            }
        }
    }

    fn add_connection(&mut self, kf: KeyFrameId, other: KeyFrameId, w: usize) {
        if let Some(k) = self.keyframe_mut(kf) {
            k.connections.insert(other, w);
            let mut v: Vec<(KeyFrameId, usize)> =
                k.connections.iter().map(|(&a, &b)| (a, b)).collect();
            v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
            k.ordered = v;
        }
    }

    fn erase_connection(&mut self, kf: KeyFrameId, other: KeyFrameId) {
        if let Some(k) = self.keyframe_mut(kf)
            && k.connections.remove(&other).is_some()
        {
            k.ordered.retain(|(o, _)| *o != other);
        }
    }

    /// Number of map points of `kf` with at least `min_obs` observations.
    pub fn tracked_points(&self, kf: KeyFrameId, min_obs: usize) -> usize {
        let Some(k) = self.keyframe(kf) else { return 0 };
        k.map_points
            .iter()
            .flatten()
            .filter(|&&mp| self.point(mp).is_some_and(|p| p.num_obs >= min_obs))
            .count()
    }

    /// Removes a keyframe (culling): its observations go, its children are re-attached to
    /// the best-connected candidate parent, and the link to its parent is remembered
    /// (ORB-SLAM2 `KeyFrame::SetBadFlag`). The origin keyframe is never removed.
    pub fn cull_keyframe(&mut self, kf: KeyFrameId) {
        if self.origin == Some(kf) {
            return;
        }
        let Some(k) = self.keyframe(kf) else { return };
        let connected: Vec<KeyFrameId> = k.connections.keys().copied().collect();
        let observed: Vec<MapPointId> = k.map_points.iter().flatten().copied().collect();
        let mut children: BTreeSet<KeyFrameId> = k.children.clone();
        let parent = k.parent;
        let pose = k.pose;
        for o in connected {
            self.erase_connection(o, kf);
        }
        for mp in observed {
            self.erase_observation(mp, kf);
        }
        let mut candidates: BTreeSet<KeyFrameId> = parent.into_iter().collect();
        while !children.is_empty() {
            let mut best: Option<(KeyFrameId, KeyFrameId, usize)> = None;
            for &c in &children {
                let Some(ck) = self.keyframe(c) else { continue };
                for &(o, w) in &ck.ordered {
                    if candidates.contains(&o) && best.is_none_or(|(_, _, bw)| w > bw) {
                        best = Some((c, o, w));
                    }
                }
            }
            let Some((c, p, _)) = best else { break };
            self.change_parent(c, p);
            candidates.insert(c);
            children.remove(&c);
        }
        if let Some(p) = parent {
            for &c in &children {
                self.change_parent(c, p);
            }
            if let Some(pk) = self.keyframe_mut(p) {
                pk.children.remove(&kf);
            }
            if let Some(pk) = self.keyframe(p) {
                let t_cp = pose * pk.pose.inverse();
                self.culled.insert(kf, CulledLink { parent: p, t_cp });
            }
        }
        self.keyframes.remove(kf.index, kf.generation);
    }

    fn change_parent(&mut self, child: KeyFrameId, parent: KeyFrameId) {
        if let Some(c) = self.keyframe_mut(child) {
            c.parent = Some(parent);
        }
        if let Some(p) = self.keyframe_mut(parent) {
            p.children.insert(child);
        }
    }

    /// `T_kw` of a keyframe, also for a culled one (composed through its parent links).
    pub fn keyframe_pose(&self, kf: KeyFrameId) -> Option<Se3> {
        let mut cur = kf;
        let mut acc = Se3::identity();
        for _ in 0..100_000 {
            if let Some(k) = self.keyframe(cur) {
                return Some(acc * k.pose);
            }
            let link = self.culled.get(&cur)?;
            acc *= link.t_cp;
            cur = link.parent;
        }
        None
    }

    /// Pyramid level of keypoint `idx` of `kf`.
    pub fn keypoint_octave(&self, kf: KeyFrameId, idx: usize) -> Option<u8> {
        self.keyframe(kf)?.keys_un.get(idx).map(|k| k.octave)
    }

    /// Links `a` and `b` by a loop edge on both keyframes (ORB-SLAM2 `AddLoopEdge` called on
    /// each side). Nothing happens when either id is stale or both are the same keyframe.
    pub fn add_loop_edge(&mut self, a: KeyFrameId, b: KeyFrameId) {
        if a == b || self.keyframe(a).is_none() || self.keyframe(b).is_none() {
            return;
        }
        if let Some(k) = self.keyframe_mut(a) {
            k.loop_edges.insert(b);
        }
        if let Some(k) = self.keyframe_mut(b) {
            k.loop_edges.insert(a);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::KeyPoint;
    use crate::frame::FeatureGrid;

    fn kf_with(n: usize) -> KeyFrame {
        let kp = KeyPoint {
            x: 10.0,
            y: 10.0,
            angle: 0.0,
            response: 1.0,
            octave: 0,
            size: 31.0,
        };
        KeyFrame {
            seq: 0,
            frame_id: 0,
            timestamp: 0.0,
            pose: Se3::identity(),
            keys: vec![kp; n],
            keys_un: vec![kp; n],
            descriptors: (0..n).map(|i| [i as u8; 32]).collect(),
            depth: vec![1.0; n],
            u_right: vec![5.0; n],
            weights: vec![1.0; n],
            dynamic_class: vec![false; n],
            map_points: vec![None; n],
            grid: FeatureGrid::empty(),
            bow: vec![],
            feat: vec![],
            connections: BTreeMap::new(),
            ordered: vec![],
            parent: None,
            children: BTreeSet::new(),
            loop_edges: BTreeSet::new(),
        }
    }

    fn map() -> Map {
        Map::new(ScalePyramid::new(8, 1.2), MapParams::default())
    }

    #[test]
    fn stale_ids_are_detected_after_removal_and_reuse() {
        let mut m = map();
        let k = m.insert_keyframe(kf_with(3));
        let p = m.create_point(Vector3::new(0.0, 0.0, 1.0), k, 0).unwrap();
        assert!(m.point(p).is_some());
        m.cull_point(p);
        assert!(m.point(p).is_none());
        assert_eq!(m.keyframe(k).unwrap().map_points[0], None);
        let q = m.create_point(Vector3::new(0.0, 0.0, 2.0), k, 1).unwrap();
        assert_ne!(p, q);
        assert!(
            m.point(p).is_none(),
            "old id must stay stale after slot reuse"
        );
    }

    /// The representative descriptor, by brute force over every observation.
    fn distinctive_by_brute_force(m: &Map, p: MapPointId) -> Descriptor {
        let descs: Vec<Descriptor> = m
            .point(p)
            .unwrap()
            .observations
            .iter()
            .map(|(&k, &i)| m.keyframe(k).unwrap().descriptors[i])
            .collect();
        let median = |d: &Descriptor| {
            let mut row: Vec<u32> = descs.iter().map(|o| hamming(d, o)).collect();
            row.sort_unstable();
            row[(row.len() - 1) / 2]
        };
        let mut best = descs[0];
        for d in &descs {
            if median(d) < median(&best) {
                best = *d;
            }
        }
        best
    }

    #[test]
    fn the_distinctive_descriptor_follows_the_observations_and_survives_overwrites() {
        let mut m = map();
        let mut with = |bits: [u8; 4]| {
            let mut k = kf_with(1);
            k.descriptors[0] = [0; 32];
            k.descriptors[0][..4].copy_from_slice(&bits);
            m.insert_keyframe(k)
        };
        let ks = [
            with([0xff, 0, 0, 0]),
            with([0x0f, 0, 0, 0]),
            with([0x0f, 0x01, 0, 0]),
            with([0, 0xff, 0xff, 0]),
        ];
        let p = m
            .create_point(Vector3::new(0.0, 0.0, 1.0), ks[0], 0)
            .unwrap();
        for &k in &ks[1..3] {
            m.add_observation(p, k, 0);
        }
        m.compute_distinctive_descriptor(p);
        assert_eq!(
            m.point(p).unwrap().descriptor,
            distinctive_by_brute_force(&m, p)
        );
        // Unchanged observations, a descriptor overwritten by hand: computed again.
        m.point_mut(p).unwrap().descriptor = [7; 32];
        m.compute_distinctive_descriptor(p);
        assert_eq!(
            m.point(p).unwrap().descriptor,
            distinctive_by_brute_force(&m, p)
        );
        // A new observation changes the choice.
        let before = m.point(p).unwrap().descriptor;
        m.add_observation(p, ks[3], 0);
        m.compute_distinctive_descriptor(p);
        assert_eq!(
            m.point(p).unwrap().descriptor,
            distinctive_by_brute_force(&m, p)
        );
        m.erase_observation(p, ks[3]);
        m.compute_distinctive_descriptor(p);
        assert_eq!(m.point(p).unwrap().descriptor, before);
    }

    #[test]
    fn covisibility_and_spanning_tree() {
        let mut m = map();
        let a = m.insert_keyframe(kf_with(20));
        let b = m.insert_keyframe(kf_with(20));
        let c = m.insert_keyframe(kf_with(20));
        // a and b share 16 points, c shares 5 with b.
        for i in 0..16 {
            let p = m.create_point(Vector3::new(0.0, 0.0, 1.0), a, i).unwrap();
            m.add_observation(p, b, i);
            m.set_keyframe_match(b, i, Some(p));
            if i < 5 {
                m.add_observation(p, c, i);
                m.set_keyframe_match(c, i, Some(p));
            }
        }
        m.update_connections(a);
        m.update_connections(b);
        m.update_connections(c);
        assert_eq!(m.keyframe(b).unwrap().weight(a), 16);
        assert_eq!(m.keyframe(b).unwrap().parent, Some(a));
        // c has no edge ≥ 15: linked to its best (a and b tie at 5, lowest id first).
        assert!(m.keyframe(c).unwrap().parent.is_some());
        assert_eq!(m.keyframe(a).unwrap().parent, None);
        // Culling b re-parents nothing wrongly and keeps a pose link.
        let pose_b = m.keyframe(b).unwrap().pose;
        m.cull_keyframe(b);
        assert!(m.keyframe(b).is_none());
        let back = m.keyframe_pose(b).unwrap();
        assert!((back.translation.vector - pose_b.translation.vector).norm() < 1e-12);
        assert_eq!(m.keyframe(a).unwrap().weight(b), 0);
    }

    #[test]
    fn erase_observation_culls_weak_points_and_replace_merges() {
        let mut m = map();
        let a = m.insert_keyframe(kf_with(4));
        let b = m.insert_keyframe(kf_with(4));
        let p = m.create_point(Vector3::new(0.0, 0.0, 1.0), a, 0).unwrap();
        m.add_observation(p, b, 0);
        m.set_keyframe_match(b, 0, Some(p));
        assert_eq!(m.point(p).unwrap().num_obs, 4);
        let q = m.create_point(Vector3::new(0.0, 0.0, 1.0), b, 1).unwrap();
        m.replace_point(q, p);
        assert!(m.point(q).is_none());
        assert_eq!(m.resolve(q), Some(p));
        // b already observes p, so q's observation in b is dropped rather than duplicated.
        assert_eq!(m.keyframe(b).unwrap().map_points[1], None);
        m.erase_observation(p, b);
        assert!(m.point(p).is_none(), "≤ 2 observations left: culled");
        assert_eq!(m.keyframe(a).unwrap().map_points[0], None);
    }
}
