//! Robustness of every parser of user files on arbitrary input: text files (trajectories,
//! ground truth, frame lists, associations, status, ORB-SLAM2 settings, a sequence folder's
//! lists), images (rgb, grey, masks, 16-bit depth and probability maps, PFM) and the stored
//! weight codec. Each returns `Ok` or `Err`, never panics; text errors name the file (and, for
//! line errors, a line that exists).

use std::path::Path;

use dynapix_io::images::{self, Gray16Image};
use dynapix_io::weights;
use dynapix_io::{
    GtFrame, IoError, MotionProbability, Settings, StaticWeights, Trajectory, trajectory, tum,
};
use image::{ImageBuffer, Luma, Rgb};
use proptest::prelude::*;

/// Text made of the characters that matter to the parsers, so inputs are often almost valid.
fn near_text() -> impl Strategy<Value = String> {
    proptest::collection::vec(
        prop_oneof![
            Just("0"),
            Just("1"),
            Just("7"),
            Just("."),
            Just("-"),
            Just("e"),
            Just(" "),
            Just(","),
            Just("\t"),
            Just("\n"),
            Just("\r\n"),
            Just("#"),
            Just(":"),
            Just("nan"),
            Just("inf"),
            Just("rgb/1.png"),
            Just("/depth/2.png"),
            Just("tracked"),
            Just("lost"),
            Just("Camera.fx"),
            Just("DepthMapFactor"),
            Just("%YAML:1.0\n"),
            Just("["),
            Just("\""),
            Just("1305031102.175304"),
            Just("0.0 0.0 0.0 0.0 0.0 0.0 1.0"),
        ],
        0..60,
    )
    .prop_map(|v| v.concat())
}

fn check(err: IoError, text: &str, name: &str) {
    let msg = err.to_string();
    assert!(msg.contains(name), "{msg}");
    if let IoError::Parse { line, .. } = err {
        let lines = text.split('\n').count();
        assert!(
            line >= 1 && line <= lines + 1,
            "line {line} of {lines}: {msg}"
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn tum_trajectory_never_panics(text in near_text()) {
        if let Err(e) = Trajectory::parse_tum(&text, Path::new("traj.txt")) {
            check(e, &text, "traj.txt");
        }
    }

    #[test]
    fn lists_and_associations_never_panic(text in near_text()) {
        if let Err(e) = tum::parse_list(&text, Path::new("rgb.txt")) {
            check(e, &text, "rgb.txt");
        }
        if let Err(e) = tum::parse_associations(&text, Path::new("assoc.txt")) {
            check(e, &text, "assoc.txt");
        }
    }

    #[test]
    fn status_never_panics(text in near_text()) {
        if let Err(e) = trajectory::parse_status(&text, Path::new("status.txt")) {
            check(e, &text, "status.txt");
        }
    }

    #[test]
    fn settings_never_panic(text in near_text()) {
        if let Err(e) = Settings::parse(&text, Path::new("camera.yaml")) {
            check(e, &text, "camera.yaml");
        }
    }

    #[test]
    fn pfm_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..64), header in 0usize..4) {
        let heads: [&[u8]; 4] = [b"", b"Pf\n", b"Pf\n2 1\n", b"Pf\n2 1\n-1.0\n"];
        let mut data = heads[header].to_vec();
        data.extend_from_slice(&bytes);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.pfm");
        std::fs::write(&p, &data).unwrap();
        if let Err(e) = dynapix_io::images::read_pfm(&p) {
            prop_assert!(e.to_string().contains("m.pfm"));
        }
    }
}

/// Every image reader of the crate on the file `p`; none may panic.
fn read_every_way(p: &Path) {
    let _ = images::decode_image(p);
    let _ = images::image_size(p);
    let _ = images::read_rgb(p);
    let _ = images::read_gray(p);
    let _ = images::read_mask(p);
    let _ = images::read_depth_raw(p);
    let _ = images::read_depth(p, 5000.0);
    let _ = weights::read_prob_png_raw(p);
    let _ = weights::read_static_weights(p);
    let _ = weights::read_motion_probability(p);
    let _ = weights::read_prob_pfm(p);
}

/// Small valid files of every kind the readers take, as bytes: rgb PNG, 16-bit depth PNG,
/// 16-bit probability PNG, 8-bit mask PNG, JPEG.
fn valid_images() -> Vec<Vec<u8>> {
    let dir = tempfile::tempdir().unwrap();
    let rgb = ImageBuffer::from_fn(9, 7, |x, y| Rgb([(x * 20) as u8, (y * 30) as u8, 99]));
    let depth = Gray16Image::from_fn(9, 7, |x, y| Luma([(x * 700 + y * 11) as u16]));
    let prob = Gray16Image::from_fn(9, 7, |x, y| Luma([((x * 100 + y) % 1001) as u16]));
    let mask = image::GrayImage::from_fn(9, 7, |x, _| Luma([if x > 4 { 255 } else { 0 }]));
    let paths = ["rgb.png", "depth.png", "prob.png", "mask.png"].map(|n| dir.path().join(n));
    images::write_rgb(&paths[0], &rgb).unwrap();
    images::write_gray16(&paths[1], &depth).unwrap();
    images::write_gray16(&paths[2], &prob).unwrap();
    images::write_mask(&paths[3], &mask).unwrap();
    let mut out: Vec<Vec<u8>> = paths.iter().map(|p| std::fs::read(p).unwrap()).collect();
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
        .encode_image(&rgb)
        .unwrap();
    out.push(jpeg);
    out
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// Any text at all (not only near-valid text) in every text parser.
    #[test]
    fn text_parsers_never_panic_on_any_text(text in any::<String>()) {
        let p = Path::new("f.txt");
        if let Err(e) = Trajectory::parse_tum(&text, p) { check(e, &text, "f.txt"); }
        if let Err(e) = tum::parse_list(&text, p) { check(e, &text, "f.txt"); }
        if let Err(e) = tum::parse_associations(&text, p) { check(e, &text, "f.txt"); }
        if let Err(e) = trajectory::parse_status(&text, p) { check(e, &text, "f.txt"); }
        if let Err(e) = Settings::parse(&text, p) { check(e, &text, "f.txt"); }
    }

    /// Ground truth (as written, as camera poses, Bonn marker poses) and KITTI trajectories
    /// read from files.
    #[test]
    fn ground_truth_and_kitti_files_never_panic(text in near_text(), bonn in any::<bool>()) {
        let dir = tempfile::tempdir().unwrap();
        let d = if bonn { dir.path().join("rgbd_bonn_crowd") } else { dir.path().to_path_buf() };
        std::fs::create_dir_all(&d).unwrap();
        let p = d.join("groundtruth.txt");
        std::fs::write(&p, &text).unwrap();
        for frame in [GtFrame::Camera, GtFrame::Raw] {
            if let Err(e) = dynapix_io::read_ground_truth(&p, frame) {
                prop_assert!(e.to_string().contains("groundtruth.txt"), "{}", e);
            }
        }
        if let Err(e) = dynapix_io::camera_trajectory(&p) {
            prop_assert!(e.to_string().contains("groundtruth.txt"), "{}", e);
        }
        if let Err(e) = Trajectory::read_kitti(&p) {
            prop_assert!(e.to_string().contains("groundtruth.txt"), "{}", e);
        }
    }

    /// A sequence folder whose frame lists are arbitrary text opens or is an error.
    #[test]
    fn sequence_lists_never_panic(rgb in near_text(), depth in near_text(), assoc in any::<bool>()) {
        let dir = tempfile::tempdir().unwrap();
        if assoc {
            std::fs::write(dir.path().join("association.txt"), &rgb).unwrap();
        } else {
            std::fs::write(dir.path().join("rgb.txt"), &rgb).unwrap();
            std::fs::write(dir.path().join("depth.txt"), &depth).unwrap();
        }
        std::fs::write(dir.path().join("camera.yaml"), &depth).unwrap();
        let _ = dynapix_io::Sequence::open(dir.path());
    }

    /// Arbitrary bytes behind the magic of each image format, in every image reader.
    #[test]
    fn image_readers_never_panic_on_arbitrary_bytes(
        head in 0usize..5,
        bytes in proptest::collection::vec(any::<u8>(), 0..200),
    ) {
        let heads: [&[u8]; 5] = [
            b"",
            b"\x89PNG\r\n\x1a\n",
            b"\x89PNG\r\n\x1a\n\x00\x00\x00\x0dIHDR\x00\x00\x00\x09\x00\x00\x00\x07\x10\x00",
            b"\xff\xd8\xff",
            b"Pf\n3 2\n-1.0\n",
        ];
        let mut data = heads[head].to_vec();
        data.extend_from_slice(&bytes);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.png");
        std::fs::write(&p, &data).unwrap();
        read_every_way(&p);
    }

    /// Valid images of every kind, truncated and with bytes changed, in every image reader.
    #[test]
    fn damaged_images_never_panic(
        kind in 0usize..5,
        cut in 0.0f64..1.0,
        flips in proptest::collection::vec((0.0f64..1.0, any::<u8>()), 0..6),
    ) {
        static VALID: std::sync::OnceLock<Vec<Vec<u8>>> = std::sync::OnceLock::new();
        let mut data = VALID.get_or_init(valid_images)[kind].clone();
        for (at, b) in flips {
            let i = ((data.len() - 1) as f64 * at) as usize;
            data[i] ^= b;
        }
        let keep = ((data.len() as f64) * (0.5 + cut / 2.0)) as usize;
        data.truncate(keep.max(1));
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("y.png");
        std::fs::write(&p, &data).unwrap();
        read_every_way(&p);
    }

    /// The stored-weight codec of probability maps takes any 16-bit content (values above
    /// 1000 too, which the file reader refuses) without panicking; P stays in [0, 1].
    #[test]
    fn stored_weight_codec_never_panics(
        w in 0u32..6,
        h in 0u32..6,
        values in proptest::collection::vec(any::<u16>(), 36),
    ) {
        let img = Gray16Image::from_fn(w, h, |x, y| Luma([values[(y * 6 + x) as usize]]));
        let p = MotionProbability::from_stored(&img);
        let s = StaticWeights::from_stored(&img);
        prop_assert!(p.as_image().iter().all(|v| (0.0..=1.0).contains(v)));
        prop_assert!(s.as_image().iter().all(|v| v.is_finite() && *v >= 0.0));
        let _ = p.to_stored();
        let _ = s.thresholded(0.5);
    }
}
