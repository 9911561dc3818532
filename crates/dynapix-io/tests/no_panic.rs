//! Robustness of every text parser on arbitrary input: no panic, and every error names the
//! file (and, for line errors, a line that exists).

use std::path::Path;

use dynapix_io::{IoError, Settings, Trajectory, trajectory, tum};
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
