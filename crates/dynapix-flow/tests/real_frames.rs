//! DIS on real TUM frames (`../shared/data/tum/rgbd_dataset_freiburg1_xyz/rgb`) warped by
//! known flows: translation, a similarity/affine motion and a smooth non-rigid field. Measures
//! the average end-point error and the share of pixels above 1 px and 3 px on the pixels whose
//! match stays inside the image. Skips (with a message) when the data is missing.
//!
//! Bounds are about 2× the errors measured when this was written (medium preset: EPE
//! 0.07 / 0.11 / 0.19 px; OpenCV's DIS medium on the same pairs: 0.08 / 0.14 / 0.22 px).

use dynapix_flow::metrics::visible_mask;
use dynapix_flow::{DisFlow, FlowField, FlowProvider, Preset, flow_error, pairs};
use std::path::PathBuf;

fn frames() -> Option<Vec<PathBuf>> {
    let dir = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz/rgb"
    );
    let Ok(rd) = std::fs::read_dir(dir) else {
        eprintln!("skipping: TUM frames not found at {dir}");
        return None;
    };
    let mut v: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    v.sort();
    if v.len() < 201 {
        eprintln!("skipping: only {} TUM frames at {dir}", v.len());
        return None;
    }
    Some(v)
}

fn check(name: &str, frame: &PathBuf, gt: &FlowField, preset: Preset, max_epe: f64, max_3px: f64) {
    let b = image::open(frame).unwrap().to_luma8();
    let a = pairs::make_a(&b, gt).unwrap();
    let f = DisFlow::with_preset(preset).flow(&a, &b).unwrap();
    assert!(f.is_finite());
    let s = flow_error(&f, gt, Some(&visible_mask(gt, 0))).unwrap();
    eprintln!(
        "{name:12} {preset:?}: EPE {:.3} px, >1px {:.2} %, >3px {:.2} % ({} px)",
        s.epe,
        100.0 * s.over_1px,
        100.0 * s.over_3px,
        s.count
    );
    assert!(s.count > 200_000);
    assert!(s.epe < max_epe, "{name}: EPE {} >= {max_epe}", s.epe);
    assert!(s.over_3px < max_3px, "{name}: >3px share {}", s.over_3px);
}

#[test]
fn warped_real_frames_medium() {
    let Some(fr) = frames() else { return };
    let (w, h) = (640, 480);
    let t = pairs::translation(w, h, [3.37, -1.62]);
    check("translation", &fr[0], &t, Preset::Medium, 0.17, 0.01);
    let a = pairs::affine(w, h, 2.0, 1.03, [2.2, 1.4]);
    check("affine", &fr[100], &a, Preset::Medium, 0.25, 0.01);
    let n = pairs::smooth_nonrigid(w, h, 6.0);
    check("nonrigid", &fr[200], &n, Preset::Medium, 0.45, 0.03);
}

#[test]
fn warped_real_frames_fast_presets() {
    let Some(fr) = frames() else { return };
    let (w, h) = (640, 480);
    let gt = pairs::affine(w, h, 2.0, 1.03, [2.2, 1.4]);
    check("affine", &fr[100], &gt, Preset::Fast, 0.7, 0.03);
    check("affine", &fr[100], &gt, Preset::Ultrafast, 1.3, 0.06);
}
