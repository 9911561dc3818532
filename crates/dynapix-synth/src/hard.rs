//! Movers (and the following camera) of the hard-scene presets: scenes where one of the
//! pixel-motion cues has a blind spot (issue 33).
//!
//! - `person_tracking`: the camera follows one walker around the room from behind, so the
//!   person stays near the image centre while the room moves;
//! - `crowd`: six people walking close to the camera, covering more than half of the image
//!   at times;
//! - `moving_box`: a box rests in view, is picked up, carried 1.7 m and set down again;
//! - `placing_box`: a person carries a box in, sets it down, walks away, comes back later and
//!   carries it off;
//! - `balloon`: a ball thrown back and forth across the view 1.5 m from the camera at 3.5 m/s
//!   horizontal speed, plus a walker behind it.
//!
//! The room's free floor is `x ∈ [-1.3, 1.4]`, `y ∈ [-0.5, 1.9]` (see [`crate::scene`]); the
//! default camera rig stands at `(0, -1.5, 1.35)` looking along `+y`.

use crate::movers::{Mover, MoverKind, Path, PersonLook};
use crate::script::{BoxPlace, CarriedBox, Script, Throw};
use crate::shape::Shape;
use crate::trajectory::Follow;
use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use std::f32::consts::PI;

/// Default number of frames of the `placing_box` preset (15 s at 30 Hz): the box rests for
/// 8 s between being set down and picked up again.
pub const PLACING_BOX_FRAMES: usize = 450;

fn walker(path: Path, speed: f32, offset: f32, look: PersonLook) -> Mover {
    Mover {
        kind: MoverKind::Walker {
            path,
            speed,
            start_delay: 0.0,
            offset,
        },
        look,
    }
}

fn object_look(m: usize) -> PersonLook {
    PersonLook {
        shirt: m,
        trousers: m,
        skin: m,
        head: m,
    }
}

/// `person_tracking`: the walker (around an ellipse over the free floor) and the camera that
/// follows it.
pub fn person_tracking(rng: &mut ChaCha8Rng, look: PersonLook) -> (Vec<Mover>, Follow) {
    let follow = Follow {
        centre: [0.1, 0.35],
        radii: [1.2, 0.95],
        speed: rng.random_range(0.65..0.75),
        offset: rng.random_range(0.0..8.0),
        lag: 1.15,
        widen: 0.15,
        eye_z: 1.45,
        aim_z: 1.0,
    };
    let path = Path::Ellipse {
        centre: [follow.centre[0] as f32, follow.centre[1] as f32],
        radii: [follow.radii[0] as f32, follow.radii[1] as f32],
    };
    let m = walker(path, follow.speed as f32, follow.offset as f32, look);
    (vec![m], follow)
}

/// `crowd`: six people walking back and forth 1–3 m in front of the camera: four crossing the
/// view (two each way) and two walking towards the camera and back.
pub fn crowd(rng: &mut ChaCha8Rng, looks: &[PersonLook; 4]) -> Vec<Mover> {
    let group = rng.random_range(0.0..2.0);
    let lanes: [([f32; 2], [f32; 2], f32); 6] = [
        ([-1.1, -0.45], [1.1, -0.4], 0.0),
        ([-1.35, 0.15], [1.35, 0.2], 0.5),
        ([1.6, 0.55], [-1.6, 0.6], 0.3),
        ([1.6, 1.05], [-1.6, 1.1], 0.8),
        ([0.35, 1.7], [0.15, -0.35], 1.5),
        ([-0.45, 1.6], [-0.3, -0.3], 3.0),
    ];
    lanes
        .iter()
        .enumerate()
        .map(|(k, &(a, b, lag))| {
            walker(
                Path::PingPong { a, b },
                rng.random_range(0.8..0.95),
                group + lag + rng.random_range(0.0..0.4),
                looks[k % looks.len()],
            )
        })
        .collect()
}

/// A person's heading from `a` to `b`.
fn heading(a: [f32; 2], b: [f32; 2]) -> f32 {
    (b[1] - a[1]).atan2(b[0] - a[0])
}

fn box_half(rng: &mut ChaCha8Rng) -> Vector3<f32> {
    Vector3::new(
        rng.random_range(0.2..0.28),
        rng.random_range(0.2..0.28),
        rng.random_range(0.2..0.28),
    )
}

/// `moving_box`: a box rests on the floor 2.4 m in front of the camera for 3.5 s; a person
/// walks up, lifts it (3.5–4.3 s), carries it 1.7 m across the view (4.3–7.4 s), sets it down
/// (7.4–8.2 s) and walks away; the box rests again.
pub fn moving_box(rng: &mut ChaCha8Rng, look: PersonLook, box_material: usize) -> Vec<Mover> {
    let half = box_half(rng);
    let y = rng.random_range(0.8..1.0);
    let start = [-1.9, 0.25];
    // Where the person stands to pick the box up (box in front, facing +x) and sets it down.
    let pick = [rng.random_range(-1.25..-1.1), y];
    let put = [pick[0] + 1.7, y];
    let away = [1.3, 1.75];
    let h0 = heading(start, pick);
    let h1 = heading(put, away);
    let carrier = Script::from_keys(&[
        (1.2, start, h0, 0.0),
        (2.6, pick, h0, 0.0),
        (3.2, pick, 0.0, 0.0),
        (3.6, pick, 0.0, 1.0),
        (4.3, pick, 0.0, 1.0),
        (7.4, put, 0.0, 1.0),
        (8.2, put, 0.0, 1.0),
        (8.5, put, 0.0, 0.0),
        (9.1, put, h1, 0.0),
        (10.6, away, h1, 0.0),
    ]);
    let rest0 = carrier.floor_below_hands(3.5, &half);
    let rest1 = carrier.floor_below_hands(7.4, &half);
    let b = CarriedBox {
        half,
        carrier: carrier.clone(),
        keys: vec![
            (3.5, rest0),
            (4.3, BoxPlace::Held),
            (7.4, BoxPlace::Held),
            (8.2, rest1),
        ],
    };
    vec![
        Mover {
            kind: MoverKind::Scripted(carrier),
            look,
        },
        Mover {
            kind: MoverKind::Carried(b),
            look: object_look(box_material),
        },
    ]
}

/// `placing_box`: a person carries a box in from the right (0.3–3.3 s), sets it down
/// (3.3–4.1 s), walks away to the back right (5.0–7.6 s), waits, comes back (9.0–11.6 s), picks
/// the box up (12.4–13.2 s) and carries it off the way it came.
pub fn placing_box(rng: &mut ChaCha8Rng, look: PersonLook, box_material: usize) -> Vec<Mover> {
    let half = box_half(rng);
    let start = [1.9, -0.3];
    let place = [rng.random_range(0.0..0.2), rng.random_range(0.7..0.9)];
    let away = [2.0, 1.7];
    let h_in = heading(start, place);
    let h_away = heading(place, away);
    let h_back = heading(away, place);
    let h_out = h_in + PI;
    let carrier = Script::from_keys(&[
        (0.3, start, h_in, 1.0),
        (3.3, place, h_in, 1.0),
        (4.1, place, h_in, 1.0),
        (4.4, place, h_in, 0.0),
        (5.0, place, h_away, 0.0),
        (7.6, away, h_away, 0.0),
        (8.4, away, h_back, 0.0),
        (9.0, away, h_back, 0.0),
        (11.6, place, h_back, 0.0),
        (12.1, place, h_in, 0.0),
        (12.4, place, h_in, 1.0),
        (13.2, place, h_in, 1.0),
        (13.8, place, h_out, 1.0),
        (16.8, start, h_out, 1.0),
    ]);
    let rest = carrier.floor_below_hands(3.3, &half);
    let b = CarriedBox {
        half,
        carrier: carrier.clone(),
        keys: vec![
            (3.3, BoxPlace::Held),
            (4.1, rest),
            (12.4, rest),
            (13.2, BoxPlace::Held),
        ],
    };
    vec![
        Mover {
            kind: MoverKind::Scripted(carrier),
            look,
        },
        Mover {
            kind: MoverKind::Carried(b),
            look: object_look(box_material),
        },
    ]
}

/// `balloon`: a ball of 0.11–0.14 m radius thrown back and forth across the view 1.4 m in
/// front of the camera (2.4 m between the ends, 3.5 m/s horizontal speed, held 1.2 s at the
/// edges of the view at each end), and a person walking back and forth 2.5–2.8 m away.
pub fn balloon(rng: &mut ChaCha8Rng, look: PersonLook, ball_material: usize) -> Vec<Mover> {
    let (l, vx) = (2.4f32, 3.5f32);
    let y = rng.random_range(-0.2..-0.1);
    let z = rng.random_range(0.9..1.0);
    let ball = Throw {
        shape: Shape::Sphere {
            r: rng.random_range(0.11..0.14),
        },
        a: Vector3::new(-l / 2.0, y, z),
        b: Vector3::new(l / 2.0, y + 0.1, z),
        flight: l / vx,
        hold: 1.2,
        offset: rng.random_range(0.0..1.0),
        spin_axis: Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            1.0,
        ),
        spin: rng.random_range(4.0..8.0),
    };
    vec![
        Mover {
            kind: MoverKind::Thrown(ball),
            look: object_look(ball_material),
        },
        walker(
            Path::PingPong {
                a: [-1.2, 1.0],
                b: [1.2, 1.3],
            },
            rng.random_range(0.7..0.9),
            rng.random_range(0.0..3.0),
            look,
        ),
    ]
}

/// Statistics of the hard presets, computed from rendered masks, instance ids and poses of
/// the full default frame count at 160×120, printed and checked against issue 33's list.
#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensor::SensorParams;
    use crate::sequence::{Preset, Sequence, SynthParams};
    use nalgebra::Point3;
    use rayon::prelude::*;

    /// Per-frame figures of one mover.
    #[derive(Clone, Copy, Debug, Default)]
    struct Obj {
        px: usize,
        moving: usize,
        cx: f64,
        cy: f64,
        /// Position of its first part (torso of a person, the box, the ball).
        pos: Point3<f64>,
    }

    struct Stats {
        w: usize,
        h: usize,
        fps: f64,
        cam: Vec<Point3<f64>>,
        cam_pose: Vec<nalgebra::Isometry3<f64>>,
        moving_share: Vec<f64>,
        objs: Vec<Vec<Obj>>,
        movers: Vec<Mover>,
    }

    fn stats(preset: Preset, seed: u64) -> Stats {
        let mut p = SynthParams::at_size(preset, preset.default_frames(), seed, 160, 120);
        p.sensor = SensorParams::clean();
        let seq = Sequence::new(p).expect("sequence");
        let (w, h) = (160usize, 120usize);
        let n_movers = seq.movers.len();
        let first_part: Vec<usize> = seq
            .movers
            .iter()
            .scan(0, |acc, m| {
                let f = *acc;
                *acc += m.part_count();
                Some(f)
            })
            .collect();
        let frames: Vec<_> = (0..seq.params.frames)
            .into_par_iter()
            .map(|i| {
                let (f, _) = seq.frame(i, None);
                let mut objs = vec![Obj::default(); n_movers];
                let mut moving = 0usize;
                for (j, (&m, &id)) in f.mask.as_raw().iter().zip(f.instance.as_raw()).enumerate() {
                    if m == 255 {
                        moving += 1;
                    }
                    if id == 0 {
                        continue;
                    }
                    let o = &mut objs[id as usize - 1];
                    o.px += 1;
                    o.moving += (m == 255) as usize;
                    o.cx += (j % w) as f64;
                    o.cy += (j / w) as f64;
                }
                let (parts, _) = seq.parts_at(seq.time(i));
                for (k, o) in objs.iter_mut().enumerate() {
                    if o.px > 0 {
                        o.cx /= o.px as f64;
                        o.cy /= o.px as f64;
                    }
                    o.pos = parts[first_part[k]]
                        .pose
                        .translation
                        .vector
                        .cast::<f64>()
                        .into();
                }
                (seq.pose(i), moving as f64 / (w * h) as f64, objs)
            })
            .collect();
        Stats {
            w,
            h,
            fps: seq.params.fps,
            cam: frames
                .iter()
                .map(|f| f.0.translation.vector.into())
                .collect(),
            cam_pose: frames.iter().map(|f| f.0).collect(),
            moving_share: frames.iter().map(|f| f.1).collect(),
            objs: frames.into_iter().map(|f| f.2).collect(),
            movers: seq.movers.clone(),
        }
    }

    fn path_length(p: impl Iterator<Item = Point3<f64>>) -> f64 {
        let v: Vec<_> = p.collect();
        v.windows(2).map(|w| (w[1] - w[0]).xy().norm()).sum()
    }

    fn frac(v: impl Iterator<Item = bool>) -> f64 {
        let (mut yes, mut n) = (0usize, 0usize);
        for b in v {
            yes += b as usize;
            n += 1;
        }
        yes as f64 / n.max(1) as f64
    }

    fn median(mut v: Vec<f64>) -> f64 {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    }

    #[test]
    fn person_tracking_keeps_the_walker_centred_and_close() {
        for seed in 0..3 {
            let s = stats(Preset::PersonTracking, seed);
            let n = s.cam.len();
            let npx = (s.w * s.h) as f64;
            let walker: Vec<Obj> = s.objs.iter().map(|o| o[0]).collect();
            let centred = frac(
                walker
                    .iter()
                    .map(|o| o.px > 0 && o.cx > s.w as f64 / 3.0 && o.cx < 2.0 * s.w as f64 / 3.0),
            );
            let centred_v = frac(
                walker
                    .iter()
                    .map(|o| o.px > 0 && o.cy > s.h as f64 / 3.0 && o.cy < 2.0 * s.h as f64 / 3.0),
            );
            let shares: Vec<f64> = walker.iter().map(|o| o.px as f64 / npx).collect();
            let in_range = frac(shares.iter().map(|&x| (0.15..=0.40).contains(&x)));
            let dist: Vec<f64> = (0..n)
                .map(|i| (walker[i].pos - s.cam[i]).xy().norm())
                .collect();
            let walked = path_length(walker.iter().map(|o| o.pos));
            let cam_path = path_length(s.cam.iter().copied());
            let (dmin, dmax) = dist
                .iter()
                .fold((f64::MAX, 0.0f64), |(a, b), &d| (a.min(d), b.max(d)));
            eprintln!(
                "person_tracking seed {seed}: {n} frames, walker centre in the middle third \
                 (x) {:.0} % (y {:.0} %), walker share median {:.3} (min {:.3}, max {:.3}), \
                 in 15–40 % {:.0} %, distance {dmin:.2}–{dmax:.2} m, walked {walked:.2} m, \
                 camera path {cam_path:.2} m",
                100.0 * centred,
                100.0 * centred_v,
                median(shares.clone()),
                shares.iter().copied().fold(f64::MAX, f64::min),
                shares.iter().copied().fold(0.0, f64::max),
                100.0 * in_range,
            );
            assert!(n >= 300);
            assert!(centred >= 0.8, "centred {centred}");
            assert!(in_range >= 0.8, "share in range {in_range}");
            assert!(dmin >= 1.0 && dmax <= 2.0, "distance {dmin}..{dmax}");
            assert!(walked >= 4.0 && cam_path >= 3.0, "{walked} {cam_path}");
        }
    }

    #[test]
    fn crowd_covers_over_half_of_the_image_often() {
        for seed in 0..3 {
            let s = stats(Preset::Crowd, seed);
            let people = s
                .movers
                .iter()
                .filter(|m| matches!(m.kind, MoverKind::Walker { .. }))
                .count();
            let over_half = frac(s.moving_share.iter().map(|&x| x > 0.5));
            // Distance of each person from the camera while visible.
            let near: Vec<f64> = (0..people)
                .map(|k| {
                    median(
                        (0..s.cam.len())
                            .filter(|&i| s.objs[i][k].px > 20)
                            .map(|i| (s.objs[i][k].pos - s.cam[i]).xy().norm())
                            .collect(),
                    )
                })
                .collect();
            let visible: Vec<f64> = (0..people)
                .map(|k| frac(s.objs.iter().map(|o| o[k].px > 20)))
                .collect();
            eprintln!(
                "crowd seed {seed}: {people} people, moving share median {:.3}, max {:.3}, > 50 % in {:.0} % of {} frames; median distance while visible {near:.2?} m, visible in {visible:.2?} of the frames",
                median(s.moving_share.clone()),
                s.moving_share.iter().copied().fold(0.0, f64::max),
                100.0 * over_half,
                s.cam.len(),
            );
            assert!((4..=6).contains(&people));
            assert!(over_half >= 0.2, "over half moving in {over_half}");
            assert!(near.iter().all(|&d| d <= 3.0), "{near:?}");
            assert!(visible.iter().all(|&v| v > 0.1), "{visible:?}");
        }
    }

    /// Runs of consecutive frames `(start, len, value)` of a per-frame label.
    fn runs<T: PartialEq + Copy>(v: &[T]) -> Vec<(usize, usize, T)> {
        let mut out: Vec<(usize, usize, T)> = Vec::new();
        for (i, &x) in v.iter().enumerate() {
            match out.last_mut() {
                Some(r) if r.2 == x => r.1 += 1,
                _ => out.push((i, 1, x)),
            }
        }
        out
    }

    /// Per frame of the box (mover `k`): rests (no pixel moving, pose unchanged), moves, or is
    /// out of view; checks that the mask marks it moving exactly while its pose changes.
    #[derive(Clone, Copy, Debug, PartialEq)]
    enum BoxState {
        Rest,
        Moving,
        Hidden,
    }

    fn box_states(s: &Stats, k: usize) -> Vec<BoxState> {
        let n = s.cam.len();
        (0..n)
            .map(|i| {
                let o = s.objs[i][k];
                let moved = [i.saturating_sub(1), (i + 1).min(n - 1)]
                    .iter()
                    .any(|&j| (s.objs[j][k].pos - o.pos).norm() > 5e-4);
                if o.px < 30 {
                    BoxState::Hidden
                } else if moved {
                    assert!(o.moving > 0, "frame {i}: box moves but no pixel is 255");
                    BoxState::Moving
                } else {
                    assert_eq!(o.moving, 0, "frame {i}: box rests but pixels are 255");
                    BoxState::Rest
                }
            })
            .collect()
    }

    fn box_size(m: &Mover) -> f64 {
        match &m.kind {
            MoverKind::Carried(b) => 2.0 * b.half.max() as f64,
            _ => 0.0,
        }
    }

    #[test]
    fn moving_box_rests_is_carried_across_the_view_and_rests_again() {
        for seed in 0..3 {
            let s = stats(Preset::MovingBox, seed);
            let st = box_states(&s, 1);
            let r = runs(&st);
            let secs = |len: usize| len as f64 / s.fps;
            eprintln!(
                "moving_box seed {seed}: box {:.2} m; runs (start s, seconds, state): {:?}",
                box_size(&s.movers[1]),
                r.iter()
                    .map(|&(a, l, x)| (format!("{:.1}", secs(a)), format!("{:.1}", secs(l)), x))
                    .collect::<Vec<_>>()
            );
            // Rest ≥ 3 s in view, then one carry in view, then rest again.
            assert_eq!(r.len(), 3, "{r:?}");
            assert!(r[0].2 == BoxState::Rest && secs(r[0].1) >= 3.0);
            assert_eq!(r[1].2, BoxState::Moving);
            assert!(r[2].2 == BoxState::Rest && secs(r[2].1) >= 1.0);
            let (p0, p1) = (s.objs[0][1].pos, s.objs[s.cam.len() - 1][1].pos);
            let carried = (p1 - p0).xy().norm();
            eprintln!("moving_box seed {seed}: carried {carried:.2} m in view");
            assert!(carried >= 1.5, "{carried}");
            assert!((0.4..=0.6).contains(&box_size(&s.movers[1])));
        }
    }

    #[test]
    fn placing_box_is_carried_in_set_down_left_and_picked_up() {
        for seed in 0..3 {
            let s = stats(Preset::PlacingBox, seed);
            let st = box_states(&s, 1);
            let r = runs(&st);
            let secs = |len: usize| len as f64 / s.fps;
            // Largest person–box distance while the box rests: the person walked away.
            let rest = r
                .iter()
                .find(|x| x.2 == BoxState::Rest)
                .copied()
                .unwrap_or((0, 0, BoxState::Hidden));
            let away = (rest.0..rest.0 + rest.1)
                .map(|i| (s.objs[i][0].pos - s.objs[i][1].pos).xy().norm())
                .fold(0.0, f64::max);
            let person_gone = frac((rest.0..rest.0 + rest.1).map(|i| s.objs[i][0].px < 30));
            eprintln!(
                "placing_box seed {seed}: {} frames, box {:.2} m; runs (start s, seconds, state): {:?}; person up to {away:.2} m from the resting box, out of view {:.0} % of the rest",
                s.cam.len(),
                box_size(&s.movers[1]),
                r.iter()
                    .map(|&(a, l, x)| (format!("{:.1}", secs(a)), format!("{:.1}", secs(l)), x))
                    .collect::<Vec<_>>(),
                100.0 * person_gone,
            );
            // Carried in (moving; it may enter from out of view), rests, carried off.
            let visible: Vec<_> = r.iter().filter(|x| x.2 != BoxState::Hidden).collect();
            assert_eq!(visible.len(), 3, "{r:?}");
            assert_eq!(visible[0].2, BoxState::Moving);
            assert!(visible[1].2 == BoxState::Rest && secs(visible[1].1) >= 3.0);
            assert_eq!(visible[2].2, BoxState::Moving);
            assert!(away >= 1.5, "the person stays near the box ({away} m)");
        }
    }

    #[test]
    fn balloon_is_thrown_across_the_view_close_and_fast() {
        for seed in 0..3 {
            let s = stats(Preset::Balloon, seed);
            let n = s.cam.len();
            let (mut dists, mut speeds) = (Vec::new(), Vec::new());
            let mut crossings = 0;
            let mut xs: Vec<f64> = Vec::new();
            for i in 1..n - 1 {
                let o = s.objs[i][0];
                let MoverKind::Thrown(th) = &s.movers[0].kind else {
                    panic!("the first mover is the thrown ball");
                };
                // Speed from the ball's motion over ±1 ms around the frame.
                let t = (i as f64 / s.fps) as f32;
                let at = |dt: f32| th.pose(t + dt).translation.vector;
                let (d1, d2) = ((at(0.0) - at(-1e-3)).norm(), (at(1e-3) - at(0.0)).norm());
                let v = (d1 + d2) as f64 / 2e-3;
                // In flight over the whole ±1 ms (not launched or caught within it).
                if o.px > 3 && d1 > 0.0 && d2 > 0.0 && (d1 - d2).abs() < 0.2 * d1.max(d2) {
                    // Depth along the optical axis.
                    dists.push((s.cam_pose[i].inverse() * o.pos).z);
                    speeds.push(v);
                    xs.push(o.cx);
                } else if !xs.is_empty() {
                    let (a, b) = (xs[0], xs[xs.len() - 1]);
                    if a.min(b) < s.w as f64 * 0.25 && a.max(b) > s.w as f64 * 0.75 {
                        crossings += 1;
                    }
                    xs.clear();
                }
            }
            let range = |v: &[f64]| {
                v.iter()
                    .fold((f64::MAX, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)))
            };
            let (d0, d1) = range(&dists);
            let (v0, v1) = range(&speeds);
            let walker = frac(s.objs.iter().map(|o| o[1].px > 20));
            eprintln!(
                "balloon seed {seed}: {} frames with the ball in flight in view, {crossings} crossings of the view, distance {d0:.2}–{d1:.2} m, speed {v0:.2}–{v1:.2} m/s (median {:.2}); walker visible in {:.0} % of the frames",
                dists.len(),
                median(speeds.clone()),
                100.0 * walker,
            );
            assert!(crossings >= 2, "{crossings}");
            assert!(d0 >= 1.0 && d1 <= 2.0, "{d0}..{d1}");
            assert!(v0 >= 3.0 && v1 <= 5.0, "{v0}..{v1}");
            assert!(walker > 0.3);
        }
    }
}
