//! CLI contract of `dynapix synth`: layout, file formats, seed determinism, rgb == background
//! outside movers, flow files.

use std::path::Path;
use std::process::Command;

fn synth(args: &[&str]) {
    synth_threads(args, None);
}

/// Runs `dynapix synth`, optionally with a fixed number of rayon threads.
fn synth_threads(args: &[&str], threads: Option<usize>) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_dynapix"));
    if let Some(n) = threads {
        cmd.env("RAYON_NUM_THREADS", n.to_string());
    }
    let out = cmd.arg("synth").args(args).output().expect("run dynapix");
    assert!(
        out.status.success(),
        "dynapix synth {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn lines(p: &Path) -> Vec<String> {
    std::fs::read_to_string(p)
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(str::to_string)
        .collect()
}

#[test]
fn writes_layout_deterministically() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let a = tmp.path().join("a");
    let b = tmp.path().join("b");
    let common = [
        "--preset",
        "walking_xyz",
        "--frames",
        "4",
        "--seed",
        "7",
        "--width",
        "160",
        "--flow",
        "2",
    ];
    // Different thread counts must not change a byte.
    synth_threads(
        &[&common[..], &["--out", a.to_str().expect("utf8")]].concat(),
        Some(1),
    );
    synth_threads(
        &[&common[..], &["--out", b.to_str().expect("utf8")]].concat(),
        Some(3),
    );

    let assoc = lines(&a.join("association.txt"));
    assert_eq!(assoc.len(), 4);
    for (i, l) in assoc.iter().enumerate() {
        let f: Vec<&str> = l.split_whitespace().collect();
        assert_eq!(f.len(), 4, "{l}");
        assert_eq!(f[0], format!("{:.6}", i as f64 / 30.0));
        assert_eq!(f[1], format!("rgb/{}.png", f[0]));
        assert_eq!(f[3], format!("depth/{}.png", f[2]));
        let flo = a.join("flow").join(format!("{}.flo", f[0]));
        if flo.exists() {
            assert_eq!(
                std::fs::read(&flo).expect("flo"),
                std::fs::read(b.join("flow").join(format!("{}.flo", f[0]))).expect("flo b")
            );
        }
        for dir in ["rgb", "depth", "background", "depth_bg", "mask", "instance"] {
            let p = a.join(dir).join(format!("{}.png", f[0]));
            let pb = b.join(dir).join(format!("{}.png", f[0]));
            let bytes = std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            assert_eq!(
                bytes,
                std::fs::read(&pb).expect("same file in b"),
                "{} differs between runs",
                p.display()
            );
        }
    }
    let gt = lines(&a.join("groundtruth.txt"));
    assert_eq!(gt.len(), 4);
    for l in &gt {
        let v: Vec<f64> = l
            .split_whitespace()
            .map(|x| x.parse().expect("number"))
            .collect();
        assert_eq!(v.len(), 8);
        let qn = (v[4] * v[4] + v[5] * v[5] + v[6] * v[6] + v[7] * v[7]).sqrt();
        assert!((qn - 1.0).abs() < 1e-5);
    }
    assert_eq!(lines(&a.join("rgb.txt")).len(), 4);
    assert_eq!(lines(&a.join("depth.txt")).len(), 4);
    let yaml = std::fs::read_to_string(a.join("camera.yaml")).expect("camera.yaml");
    assert!(yaml.starts_with("%YAML:1.0"));
    assert!(yaml.contains("DepthMapFactor: 5000.0") && yaml.contains("Camera.width: 160"));

    // Image formats: 8-bit RGB, 16-bit depth, 8-bit mask with the three levels only.
    let ts = "0.066667";
    let rgb = image::open(a.join("rgb").join(format!("{ts}.png")))
        .expect("rgb")
        .to_rgb8();
    let bg = image::open(a.join("background").join(format!("{ts}.png")))
        .expect("bg")
        .to_rgb8();
    let mask = image::open(a.join("mask").join(format!("{ts}.png"))).expect("mask");
    let depth = image::open(a.join("depth").join(format!("{ts}.png"))).expect("depth");
    assert!(matches!(depth, image::DynamicImage::ImageLuma16(_)));
    assert!(matches!(mask, image::DynamicImage::ImageLuma8(_)));
    let mask = mask.to_luma8();
    assert_eq!(rgb.dimensions(), (160, 120));
    let mut movers = 0;
    for (x, y, m) in mask.enumerate_pixels() {
        assert!([0, 128, 255].contains(&m[0]));
        if m[0] == 0 {
            assert_eq!(rgb.get_pixel(x, y), bg.get_pixel(x, y));
        } else {
            movers += 1;
        }
    }
    assert!(movers > 0);

    // Flow for frames 0 and 1 (to 2 and 3), none for the last two.
    let flo = std::fs::read(a.join("flow").join("0.000000.flo")).expect("flo");
    assert_eq!(
        f32::from_le_bytes(flo[0..4].try_into().expect("4")),
        202021.25
    );
    assert_eq!(i32::from_le_bytes(flo[4..8].try_into().expect("4")), 160);
    assert_eq!(i32::from_le_bytes(flo[8..12].try_into().expect("4")), 120);
    assert_eq!(flo.len(), 12 + 160 * 120 * 8);
    assert!(a.join("flow").join("0.033333.flo").exists());
    assert!(!a.join("flow").join("0.066667.flo").exists());

    // The dataset reader of dynapix-io sees a DynaPix sequence with all its parts.
    let seq = dynapix_io::Sequence::open(&a).expect("dynapix-io opens the output");
    assert_eq!(seq.layout, dynapix_io::Layout::DynaPix);
    assert_eq!(seq.frames.len(), 4);
    assert_eq!(seq.depth_factor, 5000.0);
    let cam = seq.settings().expect("settings").camera();
    assert_eq!((cam.width, cam.height), (160, 120));
    assert!((cam.fx - 535.4 / 4.0).abs() < 1e-9);
    let f = seq.load_frame(2).expect("frame 2");
    assert!(f.background.is_some() && f.depth_bg.is_some() && f.mask.is_some());
    let pose = f.gt_pose.expect("ground-truth pose");
    let line = &gt[2];
    let tx: f64 = line
        .split_whitespace()
        .nth(1)
        .expect("tx")
        .parse()
        .expect("number");
    assert!((pose.translation.vector.x - tx).abs() < 1e-9);
}

#[test]
fn rejects_unknown_preset() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = Command::new(env!("CARGO_BIN_EXE_dynapix"))
        .args(["synth", "--preset", "nope", "--frames", "1", "--out"])
        .arg(tmp.path())
        .output()
        .expect("run");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("walking_xyz"));
}

#[test]
fn augment_keeps_real_pixels_outside_movers() {
    let seq = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz"
    ));
    if !seq.is_dir() {
        eprintln!("skipping: {} not found", seq.display());
        return;
    }
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("aug");
    synth(&[
        "--augment",
        seq.to_str().expect("utf8"),
        "--frames",
        "3",
        "--seed",
        "2",
        "--out",
        out.to_str().expect("utf8"),
    ]);
    let assoc = lines(&out.join("association.txt"));
    assert_eq!(assoc.len(), 3);
    let mut mover_px = 0;
    for l in &assoc {
        let f: Vec<&str> = l.split_whitespace().collect();
        assert_eq!(f.len(), 4);
        let rgb_name = Path::new(f[1]).file_name().expect("name");
        let depth_name = Path::new(f[3]).file_name().expect("name");
        let orig_rgb = image::open(seq.join("rgb").join(rgb_name))
            .expect("orig rgb")
            .to_rgb8();
        let orig_depth = image::open(seq.join("depth").join(depth_name))
            .expect("orig depth")
            .to_luma16();
        let rgb = image::open(out.join("rgb").join(rgb_name))
            .expect("rgb")
            .to_rgb8();
        let bg = image::open(out.join("background").join(rgb_name))
            .expect("bg")
            .to_rgb8();
        let depth = image::open(out.join("depth").join(depth_name))
            .expect("depth")
            .to_luma16();
        let depth_bg = image::open(out.join("depth_bg").join(depth_name))
            .expect("depth_bg")
            .to_luma16();
        let mask = image::open(out.join("mask").join(rgb_name))
            .expect("mask")
            .to_luma8();
        assert_eq!(bg, orig_rgb);
        assert_eq!(depth_bg, orig_depth);
        for (x, y, m) in mask.enumerate_pixels() {
            if m[0] == 0 {
                assert_eq!(rgb.get_pixel(x, y), orig_rgb.get_pixel(x, y));
                assert_eq!(depth.get_pixel(x, y), orig_depth.get_pixel(x, y));
            } else {
                mover_px += 1;
                // Depth-tested: the mover is in front of the real surface (or that had no depth).
                let (d, o) = (depth.get_pixel(x, y)[0], orig_depth.get_pixel(x, y)[0]);
                assert!(
                    d > 0 && (o == 0 || d < o),
                    "({x},{y}): mover {d} behind real {o}"
                );
            }
        }
    }
    assert!(
        mover_px > 1000,
        "movers cover only {mover_px} px over 3 frames"
    );
    assert!(
        std::fs::read_to_string(out.join("camera.yaml"))
            .expect("yaml")
            .contains("517.3")
    );
}

#[test]
fn preview_writes_a_contact_sheet_of_all_presets() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("sheet.png");
    synth(&["--preview", out.to_str().expect("utf8"), "--width", "64"]);
    let sheet = image::open(&out).expect("sheet").to_rgb8();
    // 4×4 blocks (14 presets); each 4 thumbnails of 200×150 wide and 3 frames tall, plus a
    // 4 px border.
    assert_eq!(sheet.dimensions(), (4 * (4 * 200 + 4), 4 * (3 * 150 + 4)));
    // Masks of the static preset (first block, third column) are black; flying (block 7, third
    // of the second row) is not.
    let mask_px =
        |bx: u32, by: u32, x: u32, y: u32| sheet.get_pixel(bx * 804 + 2 * 200 + x, by * 454 + y)[0];
    assert!(
        (0..150)
            .step_by(7)
            .all(|y| (0..200).step_by(7).all(|x| mask_px(0, 0, x, y) == 0))
    );
    assert!((0..450).any(|y| (0..200).any(|x| mask_px(2, 1, x, y) > 100)));
}
