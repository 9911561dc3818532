//! Map persistence on a map built by the full [`System`] on a generated sequence: lossless,
//! byte-stable round trips, typed errors (never panics) on damaged files, compatibility checks,
//! and localisation mode on the reloaded map.

use std::sync::OnceLock;

use dynapix_geometry::{PinholeCamera, Se3};
use image::{GrayImage, Luma};
use nalgebra::{Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::features::FeatureExtractor;
use crate::features::{Descriptor, KeyPoint};
use crate::frame::DepthImage;
use crate::ids::KeyFrameId;
use crate::pose::transform;
use crate::system::{FrameInput, FrameResult, System, SystemParams};
use crate::tracking::TrackingState;

const W: u32 = 640;
const H: u32 = 480;
const FRAMES: u64 = 70;
const DEPTH_FACTOR: f64 = 5000.0;

/// Textured 3-D points with fixed random descriptors, seen by a pinhole RGB-D camera.
struct World {
    points: Vec<Vector3<f64>>,
    descs: Vec<Descriptor>,
}

fn camera() -> RgbdCamera {
    RgbdCamera::new(PinholeCamera::tum_fr3(), 40.0, 40.0, 30.0)
}

fn world() -> &'static World {
    static WORLD: OnceLock<World> = OnceLock::new();
    WORLD.get_or_init(|| {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let points = (0..5000)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-2.0..10.0),
                    rng.random_range(-1.5..1.5),
                    rng.random_range(1.5..3.5),
                )
            })
            .collect();
        let descs = (0..5000).map(|_| rng.random()).collect();
        World { points, descs }
    })
}

fn pose_at(i: u64) -> Se3 {
    let s = i as f64;
    Se3::from_parts(
        Translation3::new(-0.06 * s, -0.004 * s, 0.008 * s),
        UnitQuaternion::from_euler_angles(0.002 * s, -0.006 * s, 0.001 * s),
    )
}

/// Exact projections of the world at `tcw` and a depth image holding their depths.
fn render(tcw: &Se3) -> (Vec<KeyPoint>, Vec<Descriptor>, DepthImage) {
    let cam = camera();
    let w = world();
    let (mut keys, mut descs) = (Vec::new(), Vec::new());
    let mut depth = DepthImage::new(W, H);
    for (p, d) in w.points.iter().zip(&w.descs) {
        let pc = transform(tcw, p);
        let Some((u, v, _)) = cam.project(&pc) else {
            continue;
        };
        if !(1.0..(W - 1) as f64).contains(&u) || !(1.0..(H - 1) as f64).contains(&v) {
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
    (keys, descs, depth)
}

/// Hands out the features of the planned shots in order (the image is ignored): `Some(i)` is
/// the view from `offset · pose_at(i)` (`offset` moves the camera in its own frame), `None` a
/// featureless frame.
struct Synthetic {
    shots: Vec<Option<u64>>,
    offset: Se3,
    pos: usize,
}

impl Synthetic {
    fn new(shots: &[Option<u64>]) -> Self {
        Self::with_offset(shots, Se3::identity())
    }

    fn with_offset(shots: &[Option<u64>], offset: Se3) -> Self {
        Self {
            shots: shots.to_vec(),
            offset,
            pos: 0,
        }
    }
}

impl FeatureExtractor for Synthetic {
    fn extract(&mut self, _image: &GrayImage) -> (Vec<KeyPoint>, Vec<Descriptor>) {
        let shot = self.shots.get(self.pos).copied().flatten();
        self.pos += 1;
        match shot {
            Some(i) => {
                let (k, d, _) = render(&(self.offset * pose_at(i)));
                (k, d)
            }
            None => (Vec::new(), Vec::new()),
        }
    }
    fn pyramid(&self) -> ScalePyramid {
        ScalePyramid::new(8, 1.2)
    }
}

fn vocab() -> &'static Vocabulary {
    static V: OnceLock<Vocabulary> = OnceLock::new();
    V.get_or_init(|| Vocabulary::embedded_default().expect("embedded vocabulary"))
}

fn all_frames() -> Vec<Option<u64>> {
    (0..FRAMES).map(Some).collect()
}

/// Runs `system` over `shots` (the ones its extractor was made with).
fn run_shots(
    system: &mut System<Synthetic>,
    shots: &[Option<u64>],
    offset: &Se3,
) -> Vec<FrameResult> {
    let gray = GrayImage::new(W, H);
    shots
        .iter()
        .enumerate()
        .map(|(n, shot)| {
            let depth = match shot {
                Some(i) => render(&(offset * pose_at(*i))).2,
                None => DepthImage::new(W, H),
            };
            system
                .process(FrameInput {
                    timestamp: n as f64 / 30.0,
                    gray: &gray,
                    depth: &depth,
                    weights: None,
                    masks: None,
                })
                .expect("frames of the camera's size")
        })
        .collect()
}

/// Runs `system` over the whole sequence; returns the tracked poses `T_cw`.
fn run(system: &mut System<Synthetic>) -> Vec<Option<Se3>> {
    run_shots(system, &all_frames(), &Se3::identity())
        .into_iter()
        .map(|r| {
            (r.state == TrackingState::Ok)
                .then_some(r.pose_cw)
                .flatten()
        })
        .collect()
}

/// A localisation-mode system on the saved test map for `shots` seen with `offset`.
fn localiser(shots: &[Option<u64>], offset: Se3) -> System<Synthetic> {
    let saved = decode(&built().bytes).expect("decode");
    System::from_map(
        Synthetic::with_offset(shots, offset),
        camera(),
        SystemParams::default(),
        saved.into_map(MapParams::default()),
        Some(vocab().clone()),
    )
}

struct Built {
    saved: SavedMap,
    bytes: Vec<u8>,
    poses: Vec<Option<Se3>>,
}

/// The map of a mapping run (built once per test binary).
fn built() -> &'static Built {
    static B: OnceLock<Built> = OnceLock::new();
    B.get_or_init(|| {
        let mut system = System::new(
            Synthetic::new(&all_frames()),
            camera(),
            SystemParams::default(),
        )
        .with_vocabulary(vocab().clone());
        let poses = run(&mut system);
        let saved = SavedMap::from_map(system.map(), &camera(), DEPTH_FACTOR, Some(vocab()));
        let bytes = encode(system.map(), &camera(), DEPTH_FACTOR, Some(vocab())).expect("encode");
        Built {
            saved,
            bytes,
            poses,
        }
    })
}

#[test]
fn the_test_map_exercises_every_structure() {
    let m = &built().saved.map;
    assert!(m.keyframes.len() >= 4, "{} keyframes", m.keyframes.len());
    assert!(m.points.len() > 500);
    assert!(m.keyframes.iter().skip(1).all(|k| k.parent.is_some()));
    assert!(m.keyframes.iter().any(|k| !k.children.is_empty()));
    assert!(
        m.keyframes
            .iter()
            .all(|k| !k.bow.is_empty() && !k.feat.is_empty())
    );
    assert!(m.keyframes.iter().all(|k| !k.covisibility.is_empty()));
    assert!(m.points.iter().any(|p| p.observations.len() >= 3));
    assert!(
        built().poses.iter().all(Option::is_some),
        "mapping run lost frames"
    );
}

#[test]
fn round_trip_is_lossless_and_byte_identical() {
    let b = built();
    let decoded = decode(&b.bytes).expect("decode");
    assert_eq!(decoded, b.saved, "decoded map differs from the saved one");
    let map = decoded.clone().into_map(MapParams::default());
    let again = encode(&map, &camera(), DEPTH_FACTOR, Some(vocab())).expect("encode");
    assert!(again == b.bytes, "re-encoding changed the bytes");
    assert_eq!(map.num_keyframes(), b.saved.num_keyframes());
    assert_eq!(map.num_points(), b.saved.num_points());
    assert_eq!(map.pyramid, ScalePyramid::new(8, 1.2));
    assert_eq!(map.origin, Some(KeyFrameId::dense(0)));
}

#[test]
fn reloaded_keyframes_match_the_originals_including_grids_and_links() {
    // Rebuild the original live map once more and compare live structures with the reload.
    let mut system = System::new(
        Synthetic::new(&all_frames()),
        camera(),
        SystemParams::default(),
    )
    .with_vocabulary(vocab().clone());
    run(&mut system);
    let orig = system.map();
    let loaded = decode(&encode(orig, &camera(), DEPTH_FACTOR, Some(vocab())).expect("encode"))
        .expect("decode")
        .into_map(MapParams::default());
    let a = orig.keyframes_sorted();
    let b = loaded.keyframes_sorted();
    assert_eq!(a.len(), b.len());
    let to_new = |id: KeyFrameId| a.iter().position(|(x, _)| *x == id).map(|i| b[i].0);
    for ((_, ka), (_, kb)) in a.iter().zip(&b) {
        assert_eq!(ka.seq, kb.seq);
        assert_eq!(ka.pose, kb.pose);
        assert_eq!(ka.keys, kb.keys);
        assert_eq!(ka.keys_un, kb.keys_un);
        assert_eq!(ka.descriptors, kb.descriptors);
        assert_eq!(ka.depth, kb.depth);
        assert_eq!(ka.u_right, kb.u_right);
        assert_eq!(ka.grid, kb.grid, "grid rebuilt differently");
        assert_eq!(ka.bow, kb.bow);
        assert_eq!(ka.feat, kb.feat);
        assert_eq!(ka.parent.and_then(to_new), kb.parent);
        let ordered: Vec<_> = ka
            .ordered
            .iter()
            .map(|&(k, w)| (to_new(k).expect("live"), w))
            .collect();
        assert_eq!(ordered, kb.ordered);
        assert_eq!(kb.connections.len(), kb.ordered.len());
        for (i, (ma, mb)) in ka.map_points.iter().zip(&kb.map_points).enumerate() {
            let pa = ma.and_then(|m| orig.point(m));
            let pb = mb.and_then(|m| loaded.point(m));
            assert_eq!(pa.map(|p| p.seq), pb.map(|p| p.seq), "keypoint {i}");
            if let (Some(pa), Some(pb)) = (pa, pb) {
                assert_eq!(pa.position, pb.position);
                assert_eq!(pa.num_obs, pb.num_obs);
                assert_eq!(pa.observations.len(), pb.observations.len());
            }
        }
    }
}

#[test]
fn loop_edges_survive_a_round_trip() {
    let mut saved = built().saved.clone();
    let n = saved.map.keyframes.len() as u32;
    saved.map.keyframes[0].loop_edges = vec![n - 1];
    saved.map.keyframes[(n - 1) as usize].loop_edges = vec![0];
    let decoded = decode(&saved.to_bytes().expect("encode")).expect("decode");
    assert_eq!(decoded, saved);
    let map = decoded.into_map(MapParams::default());
    let kfs = map.keyframes_sorted();
    assert!(kfs[0].1.loop_edges.contains(&kfs[(n - 1) as usize].0));
}

#[test]
fn localisation_mode_tracks_every_frame_and_never_maps() {
    let b = built();
    let saved = decode(&b.bytes).expect("decode");
    saved
        .check_compatible(
            &camera(),
            DEPTH_FACTOR,
            &ScalePyramid::new(8, 1.2),
            Some(vocab()),
        )
        .expect("compatible");
    let (nk, np) = (saved.num_keyframes(), saved.num_points());
    let mut system = System::from_map(
        Synthetic::new(&all_frames()),
        camera(),
        SystemParams::default(),
        saved.into_map(MapParams::default()),
        Some(vocab().clone()),
    );
    assert!(system.is_localization());
    let poses = run(&mut system);
    assert_eq!(system.map().num_keyframes(), nk);
    assert_eq!(system.map().num_points(), np);
    for (i, (p, q)) in poses.iter().zip(&b.poses).enumerate() {
        let (p, q) = (p.expect("localised"), q.expect("mapped"));
        let dt = (p.translation.vector - q.translation.vector).norm();
        assert!(dt < 5e-3, "frame {i}: {dt} m from the mapping run");
    }
    // The truth is pose_at(i) relative to the first camera.
    let t0 = pose_at(0).inverse();
    let last = poses[FRAMES as usize - 1].expect("tracked");
    let truth = pose_at(FRAMES - 1) * t0;
    assert!((last.translation.vector - truth.translation.vector).norm() < 5e-3);
}

#[test]
fn every_truncation_is_an_error() {
    let bytes = &built().bytes;
    for n in 0..bytes.len() {
        assert!(decode(&bytes[..n]).is_err(), "prefix of {n} bytes decoded");
    }
    assert!(matches!(
        decode(&bytes[..bytes.len() - 1]),
        Err(PersistError::Truncated)
    ));
    let mut longer = bytes.clone();
    longer.push(0);
    assert!(matches!(decode(&longer), Err(PersistError::Corrupt { .. })));
}

#[test]
fn truncated_payloads_never_panic_the_parser() {
    // Bypasses the checksum so the parser itself sees every kind of cut.
    let payload = &built().bytes[HEADER_LEN..];
    let step = (payload.len() / 3000).max(1);
    for n in (0..payload.len()).step_by(step).chain(0..200) {
        assert!(decode_payload(&payload[..n]).is_err(), "payload prefix {n}");
    }
    assert!(decode_payload(payload).is_ok());
}

#[test]
fn random_byte_flips_are_errors_and_never_panic() {
    let bytes = &built().bytes;
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    for _ in 0..300 {
        let mut b = bytes.clone();
        let flips = rng.random_range(1..=4);
        let mut at = Vec::new();
        while at.len() < flips {
            let i = rng.random_range(0..b.len());
            if !at.contains(&i) {
                at.push(i);
            }
        }
        for &i in &at {
            b[i] ^= rng.random_range(1..=255u8);
        }
        assert!(decode(&b).is_err(), "flips at {at:?} went unnoticed");
    }
    // Behind a recomputed checksum the parser and the validation must cope on their own.
    let payload = &bytes[HEADER_LEN..];
    let (mut ok, mut err) = (0, 0);
    for _ in 0..300 {
        let mut p = payload.to_vec();
        for _ in 0..rng.random_range(1..=8) {
            let i = rng.random_range(0..p.len());
            p[i] ^= rng.random_range(1..=255u8);
        }
        match decode_payload(&p) {
            Ok(_) => ok += 1,
            Err(_) => err += 1,
        }
    }
    assert!(err > 0 && ok + err == 300);
}

#[test]
fn random_bytes_behind_a_valid_header_never_panic() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for len in [0usize, 1, 7, 64, 500, 4096] {
        for _ in 0..50 {
            let payload: Vec<u8> = (0..len).map(|_| rng.random()).collect();
            let mut b = MAGIC.to_vec();
            b.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
            b.extend_from_slice(&0u32.to_le_bytes());
            b.extend_from_slice(&(len as u64).to_le_bytes());
            b.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
            b.extend_from_slice(&payload);
            assert!(decode(&b).is_err());
        }
    }
}

#[test]
fn bad_magic_and_version_give_specific_errors() {
    let mut b = built().bytes.clone();
    b[0] = b'X';
    let e = decode(&b).unwrap_err();
    assert!(matches!(e, PersistError::BadMagic), "{e}");
    assert!(e.to_string().contains("not a dynapix map"));
    assert!(matches!(decode(b"hello"), Err(PersistError::BadMagic)));
    assert!(matches!(decode(b"DPX"), Err(PersistError::Truncated)));

    let mut b = built().bytes.clone();
    b[8..12].copy_from_slice(&7u32.to_le_bytes());
    let e = decode(&b).unwrap_err();
    assert!(
        matches!(
            e,
            PersistError::UnsupportedVersion {
                found: 7,
                supported: FORMAT_VERSION
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("version 7"), "{e}");

    let mut b = built().bytes.clone();
    let last = b.len() - 1;
    b[last] ^= 1;
    assert!(matches!(decode(&b), Err(PersistError::Checksum)));
}

#[test]
fn structural_corruption_is_reported_as_corrupt() {
    let base = &built().saved;
    let np = base.map.points.len() as u32;
    let nk = base.map.keyframes.len() as u32;
    type Edit = fn(&mut SavedMap, u32, u32);
    let edits: [(&str, Edit); 9] = [
        ("word", |s, _, _| {
            s.map.keyframes[2].bow.push((u32::MAX - 1, 0.0))
        }),
        ("map point", |s, np, _| {
            s.map.keyframes[1].map_points[0] = Some(np)
        }),
        ("keypoints", |s, _, _| {
            s.map.keyframes[0].depth.pop();
        }),
        ("pose", |s, _, _| {
            s.map.keyframes[0].pose.translation.vector.x = f64::NAN
        }),
        ("cycle", |s, _, _| s.map.keyframes[0].parent = Some(1)),
        ("observed by", |s, _, nk| {
            s.map.points[0].observations.push((nk, 0))
        }),
        ("keypoint", |s, _, _| {
            s.map.keyframes[0].keys_un[3].octave = 8
        }),
        ("covisibility", |s, _, _| {
            s.map.keyframes[0].covisibility.push((0, 20))
        }),
        ("origin", |s, _, nk| s.map.origin = Some(nk)),
    ];
    for (what, edit) in edits {
        let mut s = base.clone();
        edit(&mut s, np, nk);
        match decode(&s.to_bytes().expect("encode")) {
            Err(PersistError::Corrupt { what: msg }) => {
                assert!(msg.contains(what), "{what}: got {msg}")
            }
            other => panic!("{what}: expected Corrupt, got {other:?}"),
        }
        // Even unvalidated, rebuilding must not panic.
        let _ = s.into_map(MapParams::default());
    }
}

#[test]
fn incompatible_camera_pyramid_or_vocabulary_are_refused() {
    let s = &built().saved;
    let pyr = ScalePyramid::new(8, 1.2);
    assert!(
        s.check_compatible(&camera(), DEPTH_FACTOR, &pyr, Some(vocab()))
            .is_ok()
    );
    let mut cam = camera();
    cam.pinhole.fx += 1.0;
    let e = s
        .check_compatible(&cam, DEPTH_FACTOR, &pyr, Some(vocab()))
        .unwrap_err();
    assert!(matches!(e, PersistError::CameraMismatch { .. }) && e.to_string().contains("fx"));
    let e = s
        .check_compatible(&camera(), 1000.0, &pyr, Some(vocab()))
        .unwrap_err();
    assert!(e.to_string().contains("DepthMapFactor"), "{e}");
    let e = s
        .check_compatible(
            &camera(),
            DEPTH_FACTOR,
            &ScalePyramid::new(4, 1.2),
            Some(vocab()),
        )
        .unwrap_err();
    assert!(matches!(e, PersistError::PyramidMismatch { .. }), "{e}");
    let e = s
        .check_compatible(&camera(), DEPTH_FACTOR, &pyr, None)
        .unwrap_err();
    let msg = e.to_string();
    let id = VocabularyId::of(vocab()).to_string();
    assert_eq!(msg, format!("map was built with vocabulary {id}, got none"));
}

#[test]
fn localisation_enters_the_map_anywhere_and_recovers_after_losing_track() {
    let b = built();
    let (nk, np) = (b.saved.num_keyframes(), b.saved.num_points());
    // Start in the middle of the sequence, lose track on two featureless frames, go on.
    let mut shots: Vec<Option<u64>> = (35..50).map(Some).collect();
    shots.extend([None, None]);
    shots.extend((52..FRAMES).map(Some));
    let mut system = localiser(&shots, Se3::identity());
    let res = run_shots(&mut system, &shots, &Se3::identity());
    assert!(res[0].relocalised && res[0].state == TrackingState::Ok);
    for (r, shot) in res.iter().zip(&shots) {
        assert!(!r.new_keyframe && !r.reset && r.mapping.is_none());
        match shot {
            None => assert_eq!(r.state, TrackingState::Lost),
            Some(i) => {
                assert_eq!(r.state, TrackingState::Ok, "frame {i}");
                let est = r.pose_cw.expect("pose");
                let truth = pose_at(*i) * pose_at(0).inverse();
                let dt = (est.translation.vector - truth.translation.vector).norm();
                assert!(dt < 5e-3, "frame {i}: {dt} m");
            }
        }
    }
    let back = shots.iter().position(|s| *s == Some(52)).expect("frame 52");
    assert!(
        res[back].relocalised,
        "tracking resumed without relocalisation"
    );
    assert_eq!(system.map().num_keyframes(), nk);
    assert_eq!(system.map().num_points(), np);
    // Lost frames have no trajectory pose; tracked ones do.
    let traj = system.trajectory();
    assert_eq!(traj.len(), shots.len());
    assert!(
        traj.iter()
            .zip(&shots)
            .all(|(t, s)| t.pose_wc.is_some() == s.is_some())
    );
}

#[test]
fn a_missing_point_reference_falls_back_to_the_first_observer() {
    let mut saved = built().saved.clone();
    let i = saved
        .map
        .points
        .iter()
        .position(|p| p.observations.len() >= 2)
        .expect("a point seen twice");
    let first = saved.map.points[i].observations[0].0;
    saved.map.points[i].reference = None;
    let map = decode(&saved.to_bytes().expect("encode"))
        .expect("decode")
        .into_map(MapParams::default());
    let again = SavedMap::from_map(&map, &camera(), DEPTH_FACTOR, Some(vocab()));
    assert_eq!(again.map.points[i].reference, Some(first));
    // From then on the file is stable.
    let bytes = again.to_bytes().expect("encode");
    let map2 = decode(&bytes)
        .expect("decode")
        .into_map(MapParams::default());
    assert!(encode(&map2, &camera(), DEPTH_FACTOR, Some(vocab())).expect("encode") == bytes);
}

#[test]
fn localisation_follows_a_different_path_through_the_mapped_scene() {
    // Same scene, a path 10 cm to the side and 5 cm higher, turned by 3°: no frame was seen
    // while mapping.
    let offset = Se3::from_parts(
        Translation3::new(0.10, -0.05, 0.0),
        UnitQuaternion::from_euler_angles(0.0, 0.05, 0.0),
    );
    let shots = all_frames();
    let mut system = localiser(&shots, offset);
    let res = run_shots(&mut system, &shots, &offset);
    for (r, i) in res.iter().zip(0..) {
        assert_eq!(r.state, TrackingState::Ok, "frame {i}");
        let truth = offset * pose_at(i) * pose_at(0).inverse();
        let est = r.pose_cw.expect("pose");
        let dt = (est.translation.vector - truth.translation.vector).norm();
        let dr = est.rotation.angle_to(&truth.rotation);
        assert!(dt < 5e-3 && dr < 2e-3, "frame {i}: {dt} m, {dr} rad");
        assert!(!r.new_keyframe);
    }
    assert_eq!(system.map().num_keyframes(), built().saved.num_keyframes());
}

#[test]
fn the_payload_is_the_postcard_encoding_of_the_saved_map() {
    let b = built();
    let payload = &b.bytes[HEADER_LEN..];
    let direct: SavedMap = postcard::from_bytes(payload).expect("postcard");
    assert_eq!(direct, b.saved);
    assert_eq!(postcard::to_allocvec(&b.saved).expect("postcard"), payload);
}

#[test]
fn a_huge_claimed_length_is_a_truncation() {
    // The producer string claims 2^32 - 1 bytes: postcard must fail on the missing bytes
    // instead of allocating them.
    assert!(matches!(
        decode_payload(&[0xff, 0xff, 0xff, 0xff, 0x0f, b'd']),
        Err(PersistError::Truncated)
    ));
    // A keyframe list claiming u64::MAX entries right after a valid map header part.
    let mut s = built().saved.clone();
    s.map.keyframes.clear();
    s.map.points.clear();
    s.map.origin = None;
    let mut p = postcard::to_allocvec(&s).expect("postcard");
    // The two trailing zero bytes are the empty keyframe and point counts.
    assert_eq!(p[p.len() - 2..], [0, 0]);
    p.truncate(p.len() - 2);
    p.extend_from_slice(&[0xff; 9]);
    p.push(0x01);
    assert!(matches!(decode_payload(&p), Err(PersistError::Truncated)));
}
