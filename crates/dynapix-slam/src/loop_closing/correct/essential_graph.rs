//! Essential-graph optimisation after a loop (ORB-SLAM2 `Optimizer::OptimizeEssentialGraph`,
//! spec §6.6) with the scale fixed to 1: relative-pose edges from the new loop connections,
//! the spanning tree, earlier loop edges and strong covisibility (weight ≥ 100), identity
//! information, the loop keyframe and the origin held fixed; then every map point moves with
//! the keyframe that corrected it (or its reference keyframe).
//!
//! Measurements follow ORB-SLAM2: the loop connections are taken between the poses as they
//! are after step 1 (corrected for the neighbourhood), so they carry the loop constraint; all
//! other edges are taken between the poses before the correction (`NonCorrectedSim3`), so they
//! carry the odometry over which the loop error is spread.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use dynapix_geometry::Se3;
use dynapix_optim::{PoseGraphEdge, PoseGraphParams, optimize_pose_graph};
use nalgebra::Matrix6;

use crate::ids::{KeyFrameId, MapPointId};
use crate::map::Map;
use crate::pose::{normalized, transform};

use super::CorrectionParams;

/// What the essential-graph step receives from the earlier correction steps.
pub struct Input<'a> {
    /// The keyframe that closed the loop.
    pub current: KeyFrameId,
    /// The matched loop keyframe (held fixed).
    pub loop_kf: KeyFrameId,
    /// Poses before step 1 of the corrected keyframes.
    pub non_corrected: &'a HashMap<KeyFrameId, Se3>,
    /// New links created by the loop, per corrected keyframe.
    pub loop_connections: &'a BTreeMap<KeyFrameId, BTreeSet<KeyFrameId>>,
    /// Map points moved in step 1 and the keyframe that moved them.
    pub corrected_by: &'a HashMap<MapPointId, KeyFrameId>,
}

/// Counters of the essential-graph step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Output {
    /// Edges in the graph.
    pub edges: usize,
    /// Cost before optimisation.
    pub initial_cost: f64,
    /// Cost after optimisation.
    pub final_cost: f64,
}

/// Builds and optimises the essential graph over all keyframes and writes the poses and the
/// moved points back into `map`.
pub fn optimize(map: &mut Map, input: &Input<'_>, params: &CorrectionParams) -> Output {
    let kfs: Vec<KeyFrameId> = map.keyframes_sorted().iter().map(|(id, _)| *id).collect();
    if kfs.len() < 2 {
        return Output::default();
    }
    let index: HashMap<KeyFrameId, usize> = kfs.iter().enumerate().map(|(i, &k)| (k, i)).collect();
    // Poses after step 1 (ORB-SLAM2 `vScw`) and before it.
    let mut current_pose = Vec::with_capacity(kfs.len());
    for &k in &kfs {
        match map.keyframe(k) {
            Some(kf) => current_pose.push(kf.pose),
            None => return Output::default(),
        }
    }
    let before: Vec<Se3> = kfs
        .iter()
        .zip(&current_pose)
        .map(|(k, p)| input.non_corrected.get(k).copied().unwrap_or(*p))
        .collect();

    let min_w = params.essential_graph_min_weight;
    let mut edges: Vec<PoseGraphEdge> = Vec::new();
    let mut inserted: BTreeSet<(usize, usize)> = BTreeSet::new();
    let mut push = |i: usize, j: usize, poses: &[Se3], edges: &mut Vec<PoseGraphEdge>| {
        if i == j || !inserted.insert((i.min(j), i.max(j))) {
            return;
        }
        edges.push(PoseGraphEdge {
            i,
            j,
            t_ij: poses[i] * poses[j].inverse(),
            information: Matrix6::identity(),
        });
    };

    // Loop connections, between the corrected poses; weak ones only for current ↔ loop KF.
    for (&a, conns) in input.loop_connections {
        let (Some(&ia), Some(ka)) = (index.get(&a), map.keyframe(a)) else {
            continue;
        };
        for &b in conns {
            let Some(&ib) = index.get(&b) else { continue };
            let is_loop_pair = a == input.current && b == input.loop_kf;
            if !is_loop_pair && ka.weight(b) < min_w {
                continue;
            }
            push(ia, ib, &current_pose, &mut edges);
        }
    }
    // The loop itself, even when fusion left the pair below the covisibility threshold.
    if let (Some(&ic), Some(&il)) = (index.get(&input.current), index.get(&input.loop_kf)) {
        push(ic, il, &current_pose, &mut edges);
    }
    // Spanning tree, earlier loop edges and strong covisibility, between the poses before
    // the correction; each pair once, from the later keyframe.
    for (i, &k) in kfs.iter().enumerate() {
        let Some(kf) = map.keyframe(k) else { continue };
        if let Some(&ip) = kf.parent.and_then(|p| index.get(&p)) {
            push(i, ip, &before, &mut edges);
        }
        for l in &kf.loop_edges {
            if let Some(&il) = index.get(l)
                && il < i
            {
                push(i, il, &before, &mut edges);
            }
        }
        for &(n, w) in &kf.ordered {
            if w < min_w {
                break;
            }
            if Some(n) == kf.parent || kf.children.contains(&n) || kf.loop_edges.contains(&n) {
                continue;
            }
            if let Some(&i_n) = index.get(&n)
                && i_n < i
            {
                push(i, i_n, &before, &mut edges);
            }
        }
    }

    let fixed: Vec<bool> = kfs
        .iter()
        .map(|&k| k == input.loop_kf || Some(k) == map.origin)
        .collect();
    let result = optimize_pose_graph(
        &current_pose,
        &fixed,
        &edges,
        &PoseGraphParams {
            iterations: params.essential_graph_iterations,
        },
    );

    for (i, &k) in kfs.iter().enumerate() {
        if fixed[i] {
            continue;
        }
        if let (Some(kf), Some(p)) = (map.keyframe_mut(k), result.poses.get(i)) {
            kf.pose = normalized(p);
        }
    }
    // Each point follows the keyframe that corrected it, else its reference keyframe:
    // X' = T_rw'⁻¹ · T_rw · X with T_rw the pose the graph started from.
    for mp in map.point_ids() {
        let Some(p) = map.point(mp) else { continue };
        let r = input.corrected_by.get(&mp).copied().unwrap_or(p.reference);
        let Some(&ir) = index.get(&r) else { continue };
        let (Some(t_old), Some(t_new)) = (current_pose.get(ir), map.keyframe(r).map(|k| k.pose))
        else {
            continue;
        };
        let delta = t_new.inverse() * t_old;
        if let Some(p) = map.point_mut(mp) {
            p.position = transform(&delta, &p.position);
        }
        map.update_normal_and_depth(mp);
    }
    Output {
        edges: edges.len(),
        initial_cost: result.initial_cost,
        final_cost: result.final_cost,
    }
}
