//! Loop correction on hand-built maps with known truth: keyframes on a circle in a square room
//! observe wall points from their TRUE poses (pixel and depth noise), while the map holds
//! drifted keyframe poses and points triangulated with them, and the points seen at the end of
//! the loop are duplicates of those seen at its start.

use std::collections::{BTreeSet, HashMap};

use dynapix_geometry::{PinholeCamera, Se3, align::align_se3, se3};
use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::features::ScalePyramid;
use crate::features::{Descriptor, KeyPoint};
use crate::frame::FeatureGrid;
use crate::local_mapping::{LocalMapper, LocalMappingParams};
use crate::map::{KeyFrame, MapParams};

/// How the synthetic map is made.
#[derive(Clone, Debug)]
struct Opts {
    /// Keyframes (the last one coincides with the first when `arc` is 2π).
    n_kf: usize,
    /// Heading swept from the first to the last keyframe (radians).
    arc: f64,
    /// σ of the odometry yaw error per step (radians).
    yaw_drift: f64,
    /// σ of the odometry translation error per step (metres, camera x and z axes).
    trans_drift: f64,
    /// Keypoint noise σ in pixels.
    pixel_noise: f64,
    /// Points seen at both ends of the loop get two map points (start side and end side).
    split_seam: bool,
    /// Every `moving_every`-th world point moves by `moving_step` per keyframe, observed with
    /// keypoint weight `moving_weight` (None: a static world).
    moving: Option<(usize, Vector3<f64>, f32)>,
    /// Mean of the per-step yaw error in units of its σ `yaw_drift` (the translation error has
    /// zero mean).
    bias: f64,
    seed: u64,
}

impl Opts {
    fn loop_scene() -> Self {
        Self {
            n_kf: 25,
            arc: std::f64::consts::TAU,
            yaw_drift: 0.3f64.to_radians(),
            trans_drift: 0.005,
            pixel_noise: 0.5,
            split_seam: true,
            moving: None,
            bias: 2.0,
            seed: 7,
        }
    }
}

struct Scene {
    map: Map,
    cam: RgbdCamera,
    kfs: Vec<KeyFrameId>,
    /// True `T_cw` per keyframe.
    truth: Vec<Se3>,
    /// Map point per (world point, end-of-loop side).
    instance: HashMap<(usize, bool), MapPointId>,
    /// World point of each keypoint, per keyframe.
    keypoint_point: Vec<Vec<usize>>,
}

fn camera() -> RgbdCamera {
    RgbdCamera::new(
        PinholeCamera::new(640, 480, 320.0, 320.0, 320.0, 240.0),
        40.0,
        40.0,
        30.0,
    )
}

fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random_range(1e-12..1.0);
    let u2: f64 = rng.random_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Points on the four walls of an 8 m × 8 m room, 0.2 m apart, 9 rows.
fn walls() -> Vec<Vector3<f64>> {
    let mut pts = Vec::new();
    for r in 0..9 {
        let y = -1.2 + 0.3 * r as f64;
        for c in 0..40 {
            let s = -4.0 + 0.1 + 0.2 * c as f64;
            pts.push(Vector3::new(s, y, 4.0));
            pts.push(Vector3::new(4.0, y, -s));
            pts.push(Vector3::new(-s, y, -4.0));
            pts.push(Vector3::new(-4.0, y, s));
        }
    }
    pts
}

/// True `T_cw` of keyframe i: on a circle of radius 1 m, looking outwards.
fn true_pose(o: &Opts, i: usize) -> Se3 {
    let theta = o.arc * i as f64 / (o.n_kf - 1) as f64;
    let rot = UnitQuaternion::from_euler_angles(0.0, theta, 0.0);
    let centre = Vector3::new(theta.sin(), 0.0, theta.cos());
    let t_wc = Se3::from_parts(Translation3::from(centre), rot);
    t_wc.inverse()
}

fn build(o: &Opts) -> Scene {
    let cam = camera();
    let bounds = cam.image_bounds();
    let mut rng = ChaCha8Rng::seed_from_u64(o.seed);
    let world = walls();
    let base: Vec<Descriptor> = (0..world.len()).map(|_| rng.random()).collect();
    let truth: Vec<Se3> = (0..o.n_kf).map(|i| true_pose(o, i)).collect();
    // Drifted odometry: each step's relative motion is perturbed by a yaw and a sideways error.
    let mut est_wc = vec![truth[0].inverse()];
    for i in 1..o.n_kf {
        let rel = truth[i - 1] * truth[i].inverse();
        let err = se3::exp(&Vector6::new(
            0.0,
            o.yaw_drift * (o.bias + gaussian(&mut rng)),
            0.0,
            o.trans_drift * gaussian(&mut rng),
            0.0,
            o.trans_drift * gaussian(&mut rng),
        ));
        let prev = est_wc[i - 1];
        est_wc.push(prev * rel * err);
    }
    let est: Vec<Se3> = est_wc.iter().map(|t| t.inverse()).collect();
    let position = |j: usize, i: usize| -> Vector3<f64> {
        match o.moving {
            Some((every, step, _)) if j.is_multiple_of(every) => world[j] + step * i as f64,
            _ => world[j],
        }
    };

    // Observations from the true poses.
    let mut keyframes = Vec::new();
    let mut keypoint_point = Vec::new();
    for (i, t) in truth.iter().enumerate() {
        let mut keys = Vec::new();
        let mut descs = Vec::new();
        let mut depth = Vec::new();
        let mut u_right = Vec::new();
        let mut weights = Vec::new();
        let mut pts = Vec::new();
        for (j, base_desc) in base.iter().enumerate() {
            let pc = transform(t, &position(j, i));
            if pc.z < 0.3 {
                continue;
            }
            let Some((u, v, _)) = cam.project(&pc) else {
                continue;
            };
            let u = u + o.pixel_noise * gaussian(&mut rng);
            let v = v + o.pixel_noise * gaussian(&mut rng);
            if !bounds.contains(u, v) {
                continue;
            }
            let z = pc.z * (1.0 + 0.002 * gaussian(&mut rng));
            let mut d = *base_desc;
            for _ in 0..4 {
                let b = rng.random_range(0..256usize);
                d[b / 8] ^= 1 << (b % 8);
            }
            keys.push(KeyPoint {
                x: u as f32,
                y: v as f32,
                angle: 0.0,
                response: 1.0,
                octave: 0,
                size: 31.0,
            });
            descs.push(d);
            depth.push(z as f32);
            u_right.push((u - cam.bf / z) as f32);
            weights.push(match o.moving {
                Some((every, _, w)) if j.is_multiple_of(every) => w,
                _ => 1.0,
            });
            pts.push(j);
        }
        let n = keys.len();
        keyframes.push(KeyFrame {
            seq: 0,
            frame_id: i as u64,
            timestamp: i as f64,
            pose: est[i],
            grid: FeatureGrid::new(bounds, &keys),
            keys_un: keys.clone(),
            keys,
            descriptors: descs,
            depth,
            u_right,
            weights,
            dynamic_class: vec![false; n],
            map_points: vec![None; n],
            bow: vec![],
            feat: vec![],
            connections: Default::default(),
            ordered: vec![],
            parent: None,
            children: BTreeSet::new(),
            loop_edges: BTreeSet::new(),
        });
        keypoint_point.push(pts);
    }

    // Which side of the seam each observation belongs to, and how many observers each has.
    let mut observers: HashMap<usize, Vec<usize>> = HashMap::new();
    for (i, pts) in keypoint_point.iter().enumerate() {
        for &j in pts {
            observers.entry(j).or_default().push(i);
        }
    }
    let side = |j: usize, i: usize| -> bool {
        if !o.split_seam {
            return false;
        }
        let obs = &observers[&j];
        let wraps = obs.iter().any(|&a| a < o.n_kf / 4) && obs.iter().any(|&a| a > 3 * o.n_kf / 4);
        wraps && i > o.n_kf / 2
    };
    let mut group_size: HashMap<(usize, bool), usize> = HashMap::new();
    for (&j, obs) in &observers {
        for &i in obs {
            *group_size.entry((j, side(j, i))).or_default() += 1;
        }
    }

    // Incremental map building, as SLAM would: a point is born in its first observer with the
    // drifted pose, later observers attach to it.
    let mut map = Map::new(ScalePyramid::new(8, 1.2), MapParams::default());
    let mut kfs = Vec::new();
    let mut instance: HashMap<(usize, bool), MapPointId> = HashMap::new();
    for (i, kf) in keyframes.into_iter().enumerate() {
        let id = map.insert_keyframe(kf);
        kfs.push(id);
        for (idx, &j) in keypoint_point[i].iter().enumerate() {
            let g = (j, side(j, i));
            if group_size[&g] < 2 {
                continue;
            }
            match instance.get(&g) {
                Some(&mp) => {
                    map.add_observation(mp, id, idx);
                    map.set_keyframe_match(id, idx, Some(mp));
                }
                None => {
                    let x = transform(&(est[i].inverse() * truth[i]), &position(j, i));
                    if let Some(mp) = map.create_point(x, id, idx) {
                        instance.insert(g, mp);
                    }
                }
            }
        }
        map.update_connections(id);
    }
    for &mp in instance.values() {
        map.compute_distinctive_descriptor(mp);
        map.update_normal_and_depth(mp);
    }
    for &k in &kfs {
        map.update_connections(k);
    }
    Scene {
        map,
        cam,
        kfs,
        truth,
        instance,
        keypoint_point,
    }
}

/// The loop as detection would hand it over: last keyframe ↔ first keyframe, relative pose
/// from the truth, matches to the start-side twins of the current keyframe's points.
fn loop_match(s: &Scene) -> LoopMatch {
    let (cur, lkf) = (*s.kfs.last().unwrap(), s.kfs[0]);
    let n = s.kfs.len();
    let t_cm = s.truth[n - 1] * s.truth[0].inverse();
    let corrected_pose = t_cm * s.map.keyframe(lkf).unwrap().pose;
    let matched_points = s.keypoint_point[n - 1]
        .iter()
        .map(|&j| {
            let end = s.instance.get(&(j, true))?;
            let start = s.instance.get(&(j, false))?;
            (end != start).then_some(*start)
        })
        .collect();
    let mut loop_points = Vec::new();
    let mut seen = BTreeSet::new();
    let k0 = s.map.keyframe(lkf).unwrap();
    for kf in std::iter::once(lkf).chain(k0.ordered.iter().map(|&(o, _)| o)) {
        for &mp in s.map.keyframe(kf).unwrap().map_points.iter().flatten() {
            if seen.insert(mp) {
                loop_points.push(mp);
            }
        }
    }
    LoopMatch {
        current: cur,
        loop_kf: lkf,
        corrected_pose,
        matched_points,
        loop_points,
    }
}

/// RMSE of the keyframe centres against the truth after a rigid (Horn) alignment.
fn centre_error(s: &Scene) -> f64 {
    let est: Vec<Point3<f64>> = s
        .kfs
        .iter()
        .map(|&k| Point3::from(s.map.keyframe(k).unwrap().center()))
        .collect();
    let tru: Vec<Point3<f64>> = s
        .truth
        .iter()
        .map(|t| Point3::from(t.inverse().translation.vector))
        .collect();
    let a = align_se3(&est, &tru).unwrap();
    let se: f64 = est
        .iter()
        .zip(&tru)
        .map(|(e, t)| (a.apply(e) - t).norm_squared())
        .sum();
    (se / est.len() as f64).sqrt()
}

/// Start/end twins whose two map points are both still alive and distinct.
fn live_duplicates(s: &Scene) -> usize {
    s.instance
        .iter()
        .filter(|((_, end), _)| *end)
        .filter(|&(&(j, _), &b)| {
            let Some(&a) = s.instance.get(&(j, false)) else {
                return false;
            };
            match (s.map.resolve(a), s.map.resolve(b)) {
                (Some(x), Some(y)) => x != y,
                _ => false,
            }
        })
        .count()
}

#[test]
fn loop_correction_removes_drift_and_duplicates() {
    let mut s = build(&Opts::loop_scene());
    let m = loop_match(&s);
    let err_before = centre_error(&s);
    let dups_before = live_duplicates(&s);
    let points_before = s.map.num_points();
    let origin_before = s.map.keyframe(s.kfs[0]).unwrap().pose;
    let stats = correct_loop(&mut s.map, &s.cam, &m, &CorrectionParams::default());
    let err_after = centre_error(&s);
    let dups_after = live_duplicates(&s);
    eprintln!(
        "error {err_before:.4} → {err_after:.4} m, duplicates {dups_before} → {dups_after}, \
         points {points_before} → {}, {stats:?}",
        s.map.num_points()
    );
    assert!(err_before > 0.05, "the scene must drift: {err_before}");
    assert!(err_after * 2.0 <= err_before, "{err_before} → {err_after}");
    assert!(err_after < 0.02, "{err_after}");
    let cur = s.map.keyframe(m.current).unwrap();
    let lkf = s.map.keyframe(m.loop_kf).unwrap();
    assert!(cur.loop_edges.contains(&m.loop_kf));
    assert!(lkf.loop_edges.contains(&m.current));
    // Every removed point is a fused twin, and most twins are gone.
    assert!(dups_before > 100, "{dups_before}");
    assert_eq!(points_before - s.map.num_points(), dups_before - dups_after);
    assert_eq!(stats.removed_points, dups_before - dups_after);
    assert!(dups_after * 4 < dups_before, "{dups_before} → {dups_after}");
    assert_eq!(s.map.keyframe(s.kfs[0]).unwrap().pose, origin_before);
    assert!(stats.loop_edges > 0 && stats.essential_graph_edges >= s.kfs.len() - 1);
    assert!(stats.essential_graph_final_cost < stats.essential_graph_initial_cost);
    assert!(stats.global_ba_edges > 0);
}

#[test]
fn essential_graph_alone_reduces_drift_and_global_ba_keeps_or_improves() {
    let o = Opts::loop_scene();
    let mut eg_only = build(&o);
    let m = loop_match(&eg_only);
    let err_before = centre_error(&eg_only);
    let no_gba = CorrectionParams {
        global_ba: false,
        ..CorrectionParams::default()
    };
    let st = correct_loop(&mut eg_only.map, &eg_only.cam, &m, &no_gba);
    assert_eq!(st.global_ba_edges, 0);
    let err_eg = centre_error(&eg_only);
    let mut full = build(&o);
    let m = loop_match(&full);
    correct_loop(&mut full.map, &full.cam, &m, &CorrectionParams::default());
    let err_gba = centre_error(&full);
    eprintln!("error {err_before:.4} → essential graph {err_eg:.4} → + GBA {err_gba:.4} m");
    assert!(err_eg * 2.0 <= err_before, "{err_before} → {err_eg}");
    assert!(err_gba <= err_eg * 1.05, "{err_eg} → {err_gba}");
}

/// Pose error (centre RMSE, no alignment: the origin is fixed at the truth) after a global BA
/// started from the true poses, with moving points observed at weight `w`.
fn gba_error_with_moving_weight(w: f32) -> f64 {
    let o = Opts {
        n_kf: 8,
        arc: 60f64.to_radians(),
        yaw_drift: 0.0,
        trans_drift: 0.0,
        pixel_noise: 0.3,
        split_seam: false,
        moving: Some((3, Vector3::new(0.04, 0.0, 0.0), w)),
        bias: 0.0,
        seed: 11,
    };
    let mut s = build(&o);
    // Paper weighting with γ_del = 1, so the BA weight clamp [1 − γ_del, 1] lets w through
    // unchanged: this measures the optimiser's weighting itself.
    s.map.params.dynapix.gamma_del = 1.0;
    global_ba::run(&mut s.map, &s.cam, &CorrectionParams::default());
    let se: f64 = s
        .kfs
        .iter()
        .zip(&s.truth)
        .map(|(&k, t)| {
            (s.map.keyframe(k).unwrap().center() - t.inverse().translation.vector).norm_squared()
        })
        .sum();
    (se / s.kfs.len() as f64).sqrt()
}

#[test]
fn weighted_global_ba_is_pulled_less_by_down_weighted_moving_points() {
    let full = gba_error_with_moving_weight(1.0);
    let low = gba_error_with_moving_weight(0.1);
    let lower = gba_error_with_moving_weight(0.01);
    eprintln!(
        "pose error with moving points at w=1: {full:.5}, w=0.1: {low:.5}, w=0.01: {lower:.5}"
    );
    assert!(
        full > 0.005,
        "moving points must pull the unweighted BA: {full}"
    );
    assert!(low < 0.5 * full, "{full} → {low}");
    assert!(lower < low, "{low} → {lower}");
}

#[test]
fn keyframes_with_loop_edges_survive_culling() {
    let o = Opts {
        split_seam: false,
        ..Opts::loop_scene()
    };
    let mut mapper = LocalMapper::new(camera(), LocalMappingParams::default());
    // Control: without a loop edge, some of keyframe 12's covisibles are redundant.
    let mut control = build(&o);
    let culled = mapper.cull_keyframes(&mut control.map, control.kfs[12]);
    let victims: Vec<usize> = (0..o.n_kf)
        .filter(|&i| control.map.keyframe(control.kfs[i]).is_none())
        .collect();
    assert!(
        culled > 0 && !victims.is_empty(),
        "the scene must be redundant"
    );
    let mut s = build(&o);
    for &v in &victims {
        s.map.add_loop_edge(s.kfs[v], s.kfs[0]);
    }
    mapper.cull_keyframes(&mut s.map, s.kfs[12]);
    for &v in &victims {
        assert!(
            s.map.keyframe(s.kfs[v]).is_some(),
            "keyframe {v} has a loop edge"
        );
    }
}

#[test]
fn correction_is_deterministic() {
    let run = || {
        let mut s = build(&Opts::loop_scene());
        let m = loop_match(&s);
        let stats = correct_loop(&mut s.map, &s.cam, &m, &CorrectionParams::default());
        let poses: Vec<Se3> = s
            .kfs
            .iter()
            .map(|&k| s.map.keyframe(k).unwrap().pose)
            .collect();
        let pts: Vec<(MapPointId, Vector3<f64>)> = s
            .map
            .point_ids()
            .into_iter()
            .map(|p| (p, s.map.point(p).unwrap().position))
            .collect();
        let mut stats = stats;
        stats.essential_graph_seconds = 0.0;
        stats.global_ba_seconds = 0.0;
        (poses, pts, stats)
    };
    assert_eq!(run(), run());
}

#[test]
fn stale_loop_leaves_the_map_untouched() {
    let mut s = build(&Opts::loop_scene());
    let mut m = loop_match(&s);
    m.loop_kf = m.current;
    let before: Vec<Se3> = s
        .kfs
        .iter()
        .map(|&k| s.map.keyframe(k).unwrap().pose)
        .collect();
    let stats = correct_loop(&mut s.map, &s.cam, &m, &CorrectionParams::default());
    assert_eq!(stats, CorrectionStats::default());
    let after: Vec<Se3> = s
        .kfs
        .iter()
        .map(|&k| s.map.keyframe(k).unwrap().pose)
        .collect();
    assert_eq!(before, after);
}

#[test]
fn keyframes_and_points_outside_the_global_ba_follow_parent_and_reference() {
    let mut s = build(&Opts::loop_scene());
    let m = loop_match(&s);
    // A keyframe without usable observations (a descriptor but no undistorted keypoint), child
    // of keyframe 10, holding the only observation of a point.
    let parent = s.kfs[10];
    let parent_pose = s.map.keyframe(parent).unwrap().pose;
    let pose = se3::exp(&Vector6::new(0.0, 0.1, 0.0, 0.05, 0.0, -0.1)) * parent_pose;
    let extra = s.map.insert_keyframe(KeyFrame {
        seq: 0,
        frame_id: 999,
        timestamp: 999.0,
        pose,
        keys: vec![],
        keys_un: vec![],
        descriptors: vec![[0u8; 32]],
        depth: vec![2.0],
        u_right: vec![-1.0],
        weights: vec![1.0],
        dynamic_class: vec![false],
        map_points: vec![None],
        grid: FeatureGrid::empty(),
        bow: vec![],
        feat: vec![],
        connections: Default::default(),
        ordered: vec![],
        parent: Some(parent),
        children: BTreeSet::new(),
        loop_edges: BTreeSet::new(),
    });
    s.map.keyframe_mut(parent).unwrap().children.insert(extra);
    let x = transform(&pose.inverse(), &Vector3::new(0.1, -0.2, 2.0));
    let mp = s.map.create_point(x, extra, 0).unwrap();
    let rel_before = pose * parent_pose.inverse();
    let stats = correct_loop(&mut s.map, &s.cam, &m, &CorrectionParams::default());
    assert_eq!(stats.global_ba_propagated, 2, "{stats:?}");
    let parent_after = s.map.keyframe(parent).unwrap().pose;
    let pose_after = s.map.keyframe(extra).unwrap().pose;
    assert!(
        (parent_after.translation.vector - parent_pose.translation.vector).norm() > 1e-3,
        "the parent must have moved for this test to mean anything"
    );
    let rel_after = pose_after * parent_after.inverse();
    assert!(se3::log(&(rel_after * rel_before.inverse())).norm() < 1e-6);
    let xc = transform(&pose_after, &s.map.point(mp).unwrap().position);
    assert!((xc - Vector3::new(0.1, -0.2, 2.0)).norm() < 1e-6, "{xc:?}");
}
