//! Global bundle adjustment after a loop (ORB-SLAM2 `Optimizer::GlobalBundleAdjustemnt` as
//! called by `RunGlobalBundleAdjustment`: 10 iterations, no robust kernel, spec §2.7 with the
//! DynaPix per-observation weights exactly as in local BA) over all keyframes and map points,
//! the origin held fixed.
//!
//! Since correction is synchronous, every keyframe and point exists when the BA starts; what
//! remains of ORB-SLAM2's propagation step is correcting what the BA could not include: a
//! keyframe without observations follows its spanning-tree parent, a point without usable
//! observations follows its reference keyframe. Outlier observations are only counted: ORB-SLAM2
//! keeps them after a global BA, and local BA removes them later.

use std::collections::HashMap;

use dynapix_geometry::Se3;
use dynapix_optim::{BaParams, BaProblem, bundle_adjust};

use crate::camera::RgbdCamera;
use crate::camera::stereo_camera;
use crate::ids::{KeyFrameId, MapPointId};
use crate::local_mapping::weighted_ba_edges;
use crate::map::Map;
use crate::pose::{normalized, transform};

use super::CorrectionParams;

/// Counters of the global BA step.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Output {
    /// Observations in the problem.
    pub edges: usize,
    /// Observations classified as outliers after the last iteration.
    pub outliers: usize,
    /// Keyframes left out (no observation) and moved with their spanning-tree parent.
    pub propagated_keyframes: usize,
    /// Points left out (no usable observation) and moved with their reference keyframe.
    pub propagated_points: usize,
}

/// The BA parameters of a global BA: `params.ba` thresholds with the weighting of the DynaPix
/// behaviour `dynapix` (the same per-edge weights as local BA, spec §2.7), one stage of
/// `global_ba_iterations` iterations, kernel per `global_ba_robust`.
pub fn ba_params(params: &CorrectionParams, dynapix: &crate::weighting::DynaPixParams) -> BaParams {
    BaParams {
        iterations_robust: params.global_ba_iterations,
        iterations_refine: 0,
        robust: params.global_ba_robust,
        ..crate::weighting::ba_params(&params.ba, dynapix)
    }
}

/// Runs the global BA on `map` and writes poses and points back.
pub fn run(map: &mut Map, cam: &RgbdCamera, params: &CorrectionParams) -> Output {
    let mut out = Output::default();
    let kfs: Vec<KeyFrameId> = map.keyframes_sorted().iter().map(|(id, _)| *id).collect();
    let Some(&first) = kfs.first() else {
        return out;
    };
    let anchor = map
        .origin
        .filter(|o| map.keyframe(*o).is_some())
        .unwrap_or(first);
    let pose_index: HashMap<KeyFrameId, usize> =
        kfs.iter().enumerate().map(|(i, &k)| (k, i)).collect();
    let all_points = map.point_ids();
    let (all_edges, _) = weighted_ba_edges(map, &all_points, &pose_index);

    // Keep only points with observations; a point without any would make its block singular.
    let mut point_slot: Vec<Option<usize>> = vec![None; all_points.len()];
    let mut points: Vec<MapPointId> = Vec::new();
    let mut positions = Vec::new();
    for e in &all_edges {
        if point_slot[e.point].is_none()
            && let Some(p) = map.point(all_points[e.point])
        {
            point_slot[e.point] = Some(points.len());
            points.push(all_points[e.point]);
            positions.push(p.position);
        }
    }
    let mut edges = Vec::with_capacity(all_edges.len());
    let mut observed = vec![false; kfs.len()];
    for e in &all_edges {
        if let Some(slot) = point_slot[e.point] {
            let mut e = *e;
            e.point = slot;
            observed[e.pose] = true;
            edges.push(e);
        }
    }
    out.edges = edges.len();
    if edges.is_empty() {
        return out;
    }
    let mut poses_before = Vec::with_capacity(kfs.len());
    for &k in &kfs {
        match map.keyframe(k) {
            Some(kf) => poses_before.push(kf.pose),
            None => return out,
        }
    }
    let pose_fixed: Vec<bool> = kfs
        .iter()
        .zip(&observed)
        .map(|(&k, &o)| k == anchor || !o)
        .collect();
    let problem = BaProblem {
        camera: stereo_camera(cam),
        poses: poses_before.clone(),
        pose_fixed: pose_fixed.clone(),
        points: positions,
        edges,
    };
    let result = bundle_adjust(&problem, &ba_params(params, &map.params.dynapix));
    out.outliers = result.inlier.iter().filter(|&&ok| !ok).count();

    for (i, &k) in kfs.iter().enumerate() {
        if !pose_fixed[i]
            && let (Some(kf), Some(p)) = (map.keyframe_mut(k), result.poses.get(i))
        {
            kf.pose = normalized(p);
        }
    }
    // Unobserved keyframes keep their pose relative to their parent (in seq order, so a parent
    // is settled before its children).
    let mut delta_of: HashMap<KeyFrameId, Se3> = HashMap::new();
    for (i, &k) in kfs.iter().enumerate() {
        let after = map.keyframe(k).map(|kf| kf.pose);
        if !observed[i] {
            let parent = map.keyframe(k).and_then(|kf| kf.parent);
            if let Some(d) = parent.and_then(|p| delta_of.get(&p)).copied() {
                // T' = T · T_pw⁻¹ · T_pw' = T · d⁻¹ with d = T_pw'⁻¹ · T_pw.
                if let Some(kf) = map.keyframe_mut(k) {
                    kf.pose = normalized(&(kf.pose * d.inverse()));
                }
                out.propagated_keyframes += 1;
            }
        }
        if let Some(now) = map.keyframe(k).map(|kf| kf.pose).or(after) {
            delta_of.insert(k, now.inverse() * poses_before[i]);
        }
    }
    for (slot, &mp) in points.iter().enumerate() {
        if let (Some(p), Some(x)) = (map.point_mut(mp), result.points.get(slot)) {
            p.position = *x;
        }
    }
    for (i, &mp) in all_points.iter().enumerate() {
        if point_slot[i].is_none() {
            let Some(r) = map.point(mp).map(|p| p.reference) else {
                continue;
            };
            let Some(d) = delta_of.get(&r).copied() else {
                continue;
            };
            if let Some(p) = map.point_mut(mp) {
                p.position = transform(&d, &p.position);
                out.propagated_points += 1;
            }
        }
        map.update_normal_and_depth(mp);
    }
    out
}
