//! Loop correction (ORB-SLAM2 `LoopClosing::CorrectLoop`, spec §6.6; global BA weighting
//! spec §2.7), run synchronously with the scale fixed to 1 as for RGB-D:
//!
//! 1. the current keyframe and its covisible neighbourhood take corrected poses (each keeps
//!    its pose relative to the current keyframe, whose corrected pose detection estimated),
//!    and their map points move rigidly with the keyframe that corrects them first;
//! 2. loop fusion: the matched loop-side points replace or join the current keyframe's
//!    matches, then the loop-side points are fused into every corrected keyframe (loop-side
//!    point wins, as in ORB-SLAM2's `SearchAndFuse`);
//! 3. the covisibility links the loop created give the loop connections, and a loop edge joins
//!    the current and the loop keyframe;
//! 4. essential-graph optimisation ([`essential_graph`]);
//! 5. weighted global bundle adjustment ([`global_ba`]).
//!
//! Everything runs to completion in one call, so ORB-SLAM2's "abort GBA" and "propagate to
//! keyframes created meanwhile" reduce to correcting whatever the GBA could not include.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::time::Instant;

use dynapix_geometry::Se3;
use dynapix_optim::BaParams;
use nalgebra::Vector3;

use crate::camera::RgbdCamera;
use crate::features::hamming;
use crate::ids::{KeyFrameId, MapPointId};
use crate::map::Map;
use crate::matcher::MatcherParams;
use crate::pose::{normalized, transform};
use crate::weighting::{BirthSource, may_birth_in_keyframe};

use super::LoopMatch;

pub mod essential_graph;
pub mod global_ba;
#[cfg(test)]
mod tests;

/// Parameters of loop correction (ORB-SLAM2 values).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct CorrectionParams {
    /// Search radius factor of loop fusion, multiplied by the predicted level's scale (4).
    pub fuse_radius: f32,
    /// Descriptor thresholds of loop fusion (`TH_LOW` = 50 accepts a match). ORB-SLAM2 builds
    /// its fusion matcher with a 0.8 ratio, but projection fusion never applies a ratio test.
    pub matcher: MatcherParams,
    /// Covisibility edges of at least this weight enter the essential graph (100).
    pub essential_graph_min_weight: usize,
    /// Levenberg–Marquardt iterations of the essential-graph optimisation (20).
    pub essential_graph_iterations: usize,
    /// Run the global bundle adjustment after the essential graph (true).
    pub global_ba: bool,
    /// Iterations of the global bundle adjustment (10).
    pub global_ba_iterations: usize,
    /// Huber kernel in the global bundle adjustment (false, as ORB-SLAM2 after a loop).
    pub global_ba_robust: bool,
    /// Weight mode, weight clamp and χ² thresholds of the global BA; the system copies the
    /// local-mapping ones so local and global BA weigh observations identically. Its iteration
    /// counts and kernel flag are not used (see the `global_ba_*` fields).
    pub ba: BaParams,
}

impl Default for CorrectionParams {
    fn default() -> Self {
        Self {
            fuse_radius: 4.0,
            matcher: MatcherParams::default(),
            essential_graph_min_weight: 100,
            essential_graph_iterations: 20,
            global_ba: true,
            global_ba_iterations: 10,
            global_ba_robust: false,
            ba: BaParams::default(),
        }
    }
}

/// What one loop correction did (counts and measured times).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CorrectionStats {
    /// Keyframes whose pose was corrected before the essential graph (current + covisibles).
    pub corrected_keyframes: usize,
    /// Map points moved with those keyframes.
    pub corrected_points: usize,
    /// Matched loop points that replaced or joined the current keyframe's matches, plus loop
    /// points fused into the corrected keyframes.
    pub fused_points: usize,
    /// Map points removed as duplicates by the fusion (map size before − after).
    pub removed_points: usize,
    /// New keyframe pairs linked by the loop (ORB-SLAM2 `LoopConnections`, each pair once).
    pub loop_edges: usize,
    /// Edges of the essential graph.
    pub essential_graph_edges: usize,
    /// Essential-graph cost Σ rᵀΩr before optimisation.
    pub essential_graph_initial_cost: f64,
    /// Essential-graph cost after optimisation.
    pub essential_graph_final_cost: f64,
    /// Wall-clock time of the essential-graph step in seconds (measurement only).
    pub essential_graph_seconds: f64,
    /// Observations (edges) in the global BA (0 when it did not run).
    pub global_ba_edges: usize,
    /// Global-BA edges classified as outliers at the end (kept in the map, as ORB-SLAM2 does).
    pub global_ba_outliers: usize,
    /// Keyframes and points the global BA could not include, corrected through the spanning
    /// tree or their reference keyframe instead.
    pub global_ba_propagated: usize,
    /// Wall-clock time of the global BA step in seconds (measurement only).
    pub global_ba_seconds: f64,
}

/// Corrects the map for the accepted loop `m` (see the module documentation). A loop whose
/// current or loop keyframe is no longer in the map leaves the map untouched.
pub fn correct_loop(
    map: &mut Map,
    cam: &RgbdCamera,
    m: &LoopMatch,
    params: &CorrectionParams,
) -> CorrectionStats {
    let mut stats = CorrectionStats::default();
    if m.current == m.loop_kf
        || map.keyframe(m.current).is_none()
        || map.keyframe(m.loop_kf).is_none()
    {
        return stats;
    }
    let points_before = map.num_points();

    // 1. Pose propagation to the current keyframe's neighbourhood.
    let prop = propagate(map, m);
    stats.corrected_keyframes = prop.neighbourhood.len();
    stats.corrected_points = prop.corrected_by.len();

    // 2. Loop fusion.
    stats.fused_points = attach_matched_points(map, m);
    for &kf in &prop.neighbourhood {
        let Some(pose) = prop.corrected.get(&kf).copied() else {
            continue;
        };
        stats.fused_points += fuse_with_pose(map, kf, &pose, &m.loop_points, cam, params);
    }
    stats.removed_points = points_before.saturating_sub(map.num_points());

    // 3. Loop connections and the loop edge.
    let loop_connections = loop_connections(map, &prop.neighbourhood);
    stats.loop_edges = count_pairs(&loop_connections);
    map.add_loop_edge(m.current, m.loop_kf);

    // 4. Essential graph.
    let t0 = Instant::now();
    let eg = essential_graph::optimize(
        map,
        &essential_graph::Input {
            current: m.current,
            loop_kf: m.loop_kf,
            non_corrected: &prop.non_corrected,
            loop_connections: &loop_connections,
            corrected_by: &prop.corrected_by,
        },
        params,
    );
    stats.essential_graph_seconds = t0.elapsed().as_secs_f64();
    stats.essential_graph_edges = eg.edges;
    stats.essential_graph_initial_cost = eg.initial_cost;
    stats.essential_graph_final_cost = eg.final_cost;

    // 5. Global BA.
    if params.global_ba {
        let t1 = Instant::now();
        let g = global_ba::run(map, cam, params);
        stats.global_ba_seconds = t1.elapsed().as_secs_f64();
        stats.global_ba_edges = g.edges;
        stats.global_ba_outliers = g.outliers;
        stats.global_ba_propagated = g.propagated_keyframes + g.propagated_points;
    }
    tracing::debug!(
        corrected = stats.corrected_keyframes,
        fused = stats.fused_points,
        removed = stats.removed_points,
        loop_edges = stats.loop_edges,
        eg_edges = stats.essential_graph_edges,
        eg_ms = stats.essential_graph_seconds * 1e3,
        gba_ms = stats.global_ba_seconds * 1e3,
        gba_outliers = stats.global_ba_outliers,
        "loop corrected"
    );
    stats
}

/// Result of step 1.
struct Propagation {
    /// Current keyframe first, then its covisibles by decreasing weight.
    neighbourhood: Vec<KeyFrameId>,
    /// Corrected pose per neighbourhood keyframe (ORB-SLAM2 `CorrectedSim3`).
    corrected: HashMap<KeyFrameId, Se3>,
    /// Pose before correction per neighbourhood keyframe (`NonCorrectedSim3`).
    non_corrected: HashMap<KeyFrameId, Se3>,
    /// Map point → keyframe that moved it (`mnCorrectedByKF`/`mnCorrectedReference`).
    corrected_by: HashMap<MapPointId, KeyFrameId>,
}

/// Step 1: corrected poses `T_iw' = T_ic · T_cw'` with `T_ic = T_iw · T_cw⁻¹`, points moved by
/// `X' = T_iw'⁻¹ · T_iw · X` with the first neighbourhood keyframe that sees them. The loop
/// keyframe and the origin are never part of the neighbourhood: both stay fixed in the
/// essential graph, so moving them here would only be undone inconsistently.
fn propagate(map: &mut Map, m: &LoopMatch) -> Propagation {
    map.update_connections(m.current);
    let mut neighbourhood = vec![m.current];
    if let Some(k) = map.keyframe(m.current) {
        neighbourhood.extend(k.ordered.iter().map(|&(o, _)| o).filter(|&o| {
            o != m.loop_kf && Some(o) != map.origin && o != m.current && map.keyframe(o).is_some()
        }));
    }
    let t_wc = map
        .keyframe(m.current)
        .map_or(Se3::identity(), |k| k.pose.inverse());
    let mut corrected = HashMap::new();
    let mut non_corrected = HashMap::new();
    for &kf in &neighbourhood {
        let Some(k) = map.keyframe(kf) else { continue };
        let t_iw = k.pose;
        let t_iw_corr = if kf == m.current {
            m.corrected_pose
        } else {
            (t_iw * t_wc) * m.corrected_pose
        };
        non_corrected.insert(kf, t_iw);
        corrected.insert(kf, normalized(&t_iw_corr));
    }
    let mut corrected_by: HashMap<MapPointId, KeyFrameId> = HashMap::new();
    let mut moved: Vec<MapPointId> = Vec::new();
    for &kf in &neighbourhood {
        let (Some(t_old), Some(t_new)) = (non_corrected.get(&kf), corrected.get(&kf)) else {
            continue;
        };
        let delta = t_new.inverse() * t_old;
        let Some(k) = map.keyframe(kf) else { continue };
        let mps: Vec<MapPointId> = k.map_points.iter().flatten().copied().collect();
        for mp in mps {
            if corrected_by.contains_key(&mp) {
                continue;
            }
            let Some(p) = map.point_mut(mp) else { continue };
            p.position = transform(&delta, &p.position);
            corrected_by.insert(mp, kf);
            moved.push(mp);
        }
    }
    for &kf in &neighbourhood {
        if let (Some(k), Some(t)) = (map.keyframe_mut(kf), corrected.get(&kf)) {
            k.pose = *t;
        }
    }
    // Normals depend on every observer's centre, so they are recomputed once all poses moved.
    for &mp in &moved {
        map.update_normal_and_depth(mp);
    }
    for &kf in &neighbourhood {
        map.update_connections(kf);
    }
    Propagation {
        neighbourhood,
        corrected,
        non_corrected,
        corrected_by,
    }
}

/// Step 2a: each matched loop point replaces the current keyframe's point at that keypoint, or
/// becomes its match when there is none (ORB-SLAM2 `Replace` / `AddMapPoint`). Returns how
/// many keypoints changed.
fn attach_matched_points(map: &mut Map, m: &LoopMatch) -> usize {
    let mut n = 0;
    let len = map
        .keyframe(m.current)
        .map_or(0, |k| k.map_points.len())
        .min(m.matched_points.len());
    for i in 0..len {
        let Some(loop_mp) = m.matched_points[i].and_then(|p| map.resolve(p)) else {
            continue;
        };
        let cur = map
            .keyframe(m.current)
            .and_then(|k| k.map_points.get(i).copied().flatten())
            .filter(|&c| map.point(c).is_some());
        match cur {
            Some(c) if c == loop_mp => continue,
            Some(c) => map.replace_point(c, loop_mp),
            None => {
                // A point can match one keypoint per keyframe only.
                if map.is_in_keyframe(loop_mp, m.current) {
                    continue;
                }
                map.set_keyframe_match(m.current, i, Some(loop_mp));
                map.add_observation(loop_mp, m.current, i);
            }
        }
        map.compute_distinctive_descriptor(loop_mp);
        map.update_normal_and_depth(loop_mp);
        n += 1;
    }
    n
}

/// Step 2b: projects `points` into keyframe `kf` with the explicit pose `t_kw` and fuses each
/// with its best keypoint (ORB-SLAM2 `Fuse(KeyFrame*, Scw, points, th, replace)`): an existing
/// point there is replaced by the fused one (the loop side wins), otherwise the point gains the
/// observation (subject to the DynaPix fusion gate). Replacements are applied after the scan,
/// as in ORB-SLAM2. Returns the number of fused points.
pub(crate) fn fuse_with_pose(
    map: &mut Map,
    kf: KeyFrameId,
    t_kw: &Se3,
    points: &[MapPointId],
    cam: &RgbdCamera,
    params: &CorrectionParams,
) -> usize {
    let center = t_kw.inverse().translation.vector;
    let mut replace: Vec<(MapPointId, MapPointId)> = Vec::new();
    let mut fused = 0;
    for &mp in points {
        let Some(best) = best_fuse_keypoint(map, kf, t_kw, &center, mp, cam, params) else {
            continue;
        };
        let existing = map
            .keyframe(kf)
            .and_then(|k| k.map_points.get(best).copied().flatten())
            .filter(|&e| map.point(e).is_some());
        match existing {
            Some(e) if e == mp => continue,
            Some(e) => replace.push((e, mp)),
            None => {
                if !may_birth_in_keyframe(map, kf, best, BirthSource::Fusion) {
                    continue;
                }
                map.add_observation(mp, kf, best);
                map.set_keyframe_match(kf, best, Some(mp));
            }
        }
        fused += 1;
    }
    for (old, new) in replace {
        // Earlier replacements may have merged either side already.
        if let (Some(o), Some(n)) = (map.resolve(old), map.resolve(new))
            && o != n
        {
            map.replace_point(o, n);
        }
    }
    fused
}

/// Best keypoint of `kf` for map point `mp` projected with `t_kw` (None when the point is not
/// fusible there: already observed, outside the image or the scale range, seen too obliquely,
/// or no descriptor within `TH_LOW`).
fn best_fuse_keypoint(
    map: &Map,
    kf: KeyFrameId,
    t_kw: &Se3,
    center: &Vector3<f64>,
    mp: MapPointId,
    cam: &RgbdCamera,
    params: &CorrectionParams,
) -> Option<usize> {
    let k = map.keyframe(kf)?;
    let p = map.point(mp)?;
    if p.observations.contains_key(&kf) {
        return None;
    }
    let pc = transform(t_kw, &p.position);
    let (u, v, _) = cam.project(&pc)?;
    if !k.grid.bounds.contains(u, v) {
        return None;
    }
    let po = p.position - center;
    let dist = po.norm();
    if dist < 0.8 * p.min_distance || dist > 1.2 * p.max_distance {
        return None;
    }
    if po.dot(&p.normal) < 0.5 * dist {
        return None;
    }
    let pyr = &map.pyramid;
    let level = p.predict_scale(dist, pyr) as i32;
    let radius = params.fuse_radius * pyr.scale_of(level as usize);
    let mut best: Option<(u32, usize)> = None;
    for idx in k.grid.features_in_area(u as f32, v as f32, radius, -1, -1) {
        let Some(kp) = k.keys_un.get(idx) else {
            continue;
        };
        let kl = kp.octave as i32;
        if kl < level - 1 || kl > level {
            continue;
        }
        let Some(d) = k.descriptors.get(idx).map(|d| hamming(&p.descriptor, d)) else {
            continue;
        };
        if best.is_none_or(|(bd, _)| d < bd) {
            best = Some((d, idx));
        }
    }
    best.filter(|&(d, _)| d <= params.matcher.th_low)
        .map(|(_, i)| i)
}

/// Step 3: per neighbourhood keyframe, the keyframes it became connected to through the fusion
/// (connections after − before − the neighbourhood itself).
fn loop_connections(
    map: &mut Map,
    neighbourhood: &[KeyFrameId],
) -> BTreeMap<KeyFrameId, BTreeSet<KeyFrameId>> {
    let members: BTreeSet<KeyFrameId> = neighbourhood.iter().copied().collect();
    let mut out = BTreeMap::new();
    for &kf in neighbourhood {
        let Some(before) = map
            .keyframe(kf)
            .map(|k| k.connections.keys().copied().collect::<BTreeSet<_>>())
        else {
            continue;
        };
        map.update_connections(kf);
        let Some(k) = map.keyframe(kf) else { continue };
        let new: BTreeSet<KeyFrameId> = k
            .connections
            .keys()
            .filter(|o| !before.contains(o) && !members.contains(o))
            .copied()
            .collect();
        if !new.is_empty() {
            out.insert(kf, new);
        }
    }
    out
}

/// Number of distinct unordered keyframe pairs in a connection map.
fn count_pairs(conns: &BTreeMap<KeyFrameId, BTreeSet<KeyFrameId>>) -> usize {
    let mut pairs = BTreeSet::new();
    for (&a, set) in conns {
        for &b in set {
            pairs.insert((a.min(b), a.max(b)));
        }
    }
    pairs.len()
}
