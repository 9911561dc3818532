//! End-to-end tests of `dynapix motion` on a tiny generated sequence: a textured wall seen by
//! a sliding camera, with a textured panel moving in front of it (rendered with and without
//! the panel for `background/`), written in the DynaPix folder layout.

use std::path::Path;
use std::process::Command;

use image::{ImageBuffer, Luma, Rgb, RgbImage};

const W: u32 = 192;
const H: u32 = 144;
const F: f64 = 160.0;
const N: usize = 8;

fn texture(x: f64, y: f64, seed: f64) -> [u8; 3] {
    use std::f64::consts::TAU;
    let mut out = [0u8; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let ph = seed + c as f64 * 1.3;
        let v = 128.0
            + 55.0 * (TAU * x / 0.37 + ph).sin() * (TAU * y / 0.29 + 0.5 * ph).cos()
            + 35.0 * (TAU * (x + 0.6 * y) / 0.8 + ph).sin();
        *o = v.round().clamp(0.0, 255.0) as u8;
    }
    out
}

/// Camera at (cam_x, 0, 0) looking along +z; wall at z = 3, panel at z = 1.5 centred at
/// `mover_x`. Returns colour, depth (16-bit, ×5000) and the panel mask.
fn render(
    cam_x: f64,
    mover: Option<f64>,
) -> (RgbImage, ImageBuffer<Luma<u16>, Vec<u16>>, image::GrayImage) {
    let mut rgb = RgbImage::new(W, H);
    let mut depth = ImageBuffer::new(W, H);
    let mut mask = image::GrayImage::new(W, H);
    let (cx, cy) = (W as f64 / 2.0 - 0.5, H as f64 / 2.0 - 0.5);
    for y in 0..H {
        for x in 0..W {
            let (dx, dy) = ((x as f64 - cx) / F, (y as f64 - cy) / F);
            let mut z = 3.0;
            let mut c = texture(cam_x + dx * 3.0, dy * 3.0, 0.0);
            if let Some(mx) = mover {
                let (px, py) = (cam_x + dx * 1.5, dy * 1.5);
                if (px - mx).abs() < 0.2 && (-0.3..0.4).contains(&py) {
                    z = 1.5;
                    c = texture(px - mx, py, 4.0);
                    mask.put_pixel(x, y, Luma([255]));
                }
            }
            rgb.put_pixel(x, y, Rgb(c));
            depth.put_pixel(x, y, Luma([(z * 5000.0) as u16]));
        }
    }
    (rgb, depth, mask)
}

fn write_sequence(dir: &Path) {
    for sub in ["rgb", "depth", "background", "depth_bg", "mask"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
    }
    let mut assoc = String::new();
    let mut gt = String::from("# timestamp tx ty tz qx qy qz qw\n");
    for i in 0..N {
        let t = format!("{:.6}", i as f64 / 30.0);
        let cam_x = 0.02 * i as f64;
        let (rgb, depth, mask) = render(cam_x, Some(-0.3 + 0.07 * i as f64));
        let (bg, bgd, _) = render(cam_x, None);
        rgb.save(dir.join(format!("rgb/{t}.png"))).unwrap();
        depth.save(dir.join(format!("depth/{t}.png"))).unwrap();
        bg.save(dir.join(format!("background/{t}.png"))).unwrap();
        bgd.save(dir.join(format!("depth_bg/{t}.png"))).unwrap();
        mask.save(dir.join(format!("mask/{t}.png"))).unwrap();
        assoc.push_str(&format!("{t} rgb/{t}.png {t} depth/{t}.png\n"));
        gt.push_str(&format!("{t} {cam_x:.6} 0 0 0 0 0 1\n"));
    }
    std::fs::write(dir.join("association.txt"), assoc).unwrap();
    std::fs::write(dir.join("groundtruth.txt"), gt).unwrap();
    std::fs::write(
        dir.join("camera.yaml"),
        format!(
            "%YAML:1.0\nCamera.fx: {F}\nCamera.fy: {F}\nCamera.cx: {}\nCamera.cy: {}\n\
             Camera.width: {W}\nCamera.height: {H}\nDepthMapFactor: 5000.0\n",
            W as f64 / 2.0 - 0.5,
            H as f64 / 2.0 - 0.5
        ),
    )
    .unwrap();
}

fn dynapix(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dynapix"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn writes_reference_format_maps_and_resumes() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path();
    write_sequence(seq);
    let s = seq.to_str().unwrap();
    let out = dynapix(&[
        "motion",
        "--cues",
        "paper",
        s,
        "--eval-masks",
        "--float-maps",
        "--pictures",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // One 16-bit map per rgb image, same file name.
    for entry in std::fs::read_dir(seq.join("rgb")).unwrap() {
        let name = entry.unwrap().file_name();
        let p = image::open(seq.join("prob").join(&name)).unwrap();
        let p = p.as_luma16().expect("16-bit grey").clone();
        assert_eq!(p.dimensions(), (W, H));
        assert!(p.iter().all(|&v| v <= 1000));
        assert!(seq.join("prob_vis").join(&name).exists());
    }
    // The moving panel has a lower static weight than the wall.
    let name = "0.133333.png";
    let p = image::open(seq.join("prob").join(name))
        .unwrap()
        .to_luma16();
    let mask = image::open(seq.join("mask").join(name)).unwrap().to_luma8();
    let mean = |want: bool| {
        let v: Vec<f64> = p
            .iter()
            .zip(mask.iter())
            .filter(|&(_, &m)| (m == 255) == want)
            .map(|(&w, _)| w as f64)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    assert!(
        mean(true) < 600.0 && mean(false) > 950.0,
        "{} vs {}",
        mean(true),
        mean(false)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(seq.join("prob/motion.json")).unwrap())
            .unwrap();
    assert_eq!(json["status"], "complete");
    assert_eq!(json["config"]["background"]["source"], "folder");
    assert_eq!(json["config"]["poses"]["origin"]["source"], "ground_truth");
    let auc = json["results"]["eval"]["roc_auc"].as_f64().unwrap();
    assert!(auc > 0.9, "auc {auc}");
    assert!(stdout.contains("ROC-AUC"));

    // Second run: everything exists, nothing is recomputed.
    let out = dynapix(&["motion", "--cues", "paper", s]);
    assert!(out.status.success());
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(seq.join("prob/motion.json")).unwrap())
            .unwrap();
    assert_eq!(json["results"]["frames_computed"], 0);
    assert_eq!(json["results"]["frames_skipped"], N);
    // Other settings on top of existing results are refused without --force.
    let out = dynapix(&["motion", "--cues", "paper", s, "--mode", "reference"]);
    assert!(!out.status.success());
    let out = dynapix(&[
        "motion",
        "--cues",
        "paper",
        s,
        "--mode",
        "reference",
        "--force",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn reconstructed_background_runs_without_background_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path();
    write_sequence(seq);
    std::fs::rename(seq.join("background"), seq.join("background_truth")).unwrap();
    let s = seq.to_str().unwrap();
    let out = dynapix(&[
        "motion",
        "--cues",
        "paper",
        s,
        "--background",
        "reconstruct",
        "--bg-radius",
        "4",
        "--bg-step",
        "1",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(seq.join("prob/motion.json")).unwrap())
            .unwrap();
    assert_eq!(json["config"]["background"]["source"], "reconstruct");
    assert_eq!(std::fs::read_dir(seq.join("prob")).unwrap().count(), N + 1);
}

#[test]
fn bad_input_lists_every_offending_frame_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path();
    write_sequence(seq);
    // Frame 2: background missing; frame 5: all-zero depth; frame 7: no pose.
    std::fs::remove_file(seq.join("background/0.066667.png")).unwrap();
    ImageBuffer::<Luma<u16>, Vec<u16>>::new(W, H)
        .save(seq.join("depth/0.166667.png"))
        .unwrap();
    let gt = std::fs::read_to_string(seq.join("groundtruth.txt")).unwrap();
    let kept: Vec<&str> = gt.lines().take(N - 1).collect(); // header + frames 0..5
    std::fs::write(seq.join("groundtruth.txt"), kept.join("\n") + "\n").unwrap();
    let out = dynapix(&[
        "motion",
        "--cues",
        "paper",
        seq.to_str().unwrap(),
        "--background",
        "folder",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("frame 2") && err.contains("background"),
        "{err}"
    );
    assert!(err.contains("frame 5") && err.contains("all zero"), "{err}");
    assert!(err.contains("frame 7") && err.contains("no pose"), "{err}");
    assert!(!seq.join("prob").exists());
}
