//! `dynapix vocab train` / `import` end to end.

use dynapix_slam::vocab::Vocabulary;
use std::path::{Path, PathBuf};
use std::process::Command;

fn dynapix() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dynapix"))
}

fn tmpdir() -> tempfile::TempDir {
    tempfile::tempdir().unwrap_or_else(|e| panic!("tempdir: {e}"))
}

fn fr1_xyz_rgb() -> Option<PathBuf> {
    let p = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz/rgb"
    ));
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("skipping: {} not found", p.display());
        None
    }
}

/// A 2×2 vocabulary in ORB-SLAM2's text format (with the trailing empty line upstream has).
fn tiny_orbvoc() -> String {
    let row = |parent: u32, leaf: u8, byte: u8, w: f32| {
        let bytes: Vec<String> = (0..32).map(|_| byte.to_string()).collect();
        format!("{parent} {leaf} {} {w}\n", bytes.join(" "))
    };
    let mut s = String::from("2 2 0 0\n");
    s += &row(0, 0, 0, 0.0);
    s += &row(0, 0, 255, 0.0);
    s += &row(1, 1, 0, 0.5);
    s += &row(1, 1, 15, 1.5);
    s += &row(2, 1, 255, 2.0);
    s += &row(2, 1, 15, 0.7);
    s + "\n"
}

fn run_ok(cmd: &mut Command) -> String {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run dynapix: {e}"));
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "dynapix failed: {stderr}");
    stderr
}

fn run_err(cmd: &mut Command) -> String {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run dynapix: {e}"));
    assert!(!out.status.success(), "dynapix should have failed");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn load(p: &Path) -> Vocabulary {
    Vocabulary::load(p).unwrap_or_else(|e| panic!("loading {}: {e}", p.display()))
}

#[test]
fn import_converts_text_vocabulary() {
    let dir = tmpdir();
    let txt = dir.path().join("ORBvoc.txt");
    std::fs::write(&txt, tiny_orbvoc()).unwrap_or_else(|e| panic!("{e}"));
    let out = dir.path().join("voc.dpxvoc");
    run_ok(
        dynapix()
            .args(["vocab", "import"])
            .arg(&txt)
            .arg("--out")
            .arg(&out),
    );
    let v = load(&out);
    assert_eq!((v.branching(), v.levels(), v.word_count()), (2, 2, 4));
    assert_eq!(v.word_of(&[0xFF; 32]), (2, 2.0));
    assert!(!dir.path().join("voc.dpxvoc.tmp").exists());
}

#[test]
fn import_reports_corrupt_input() {
    let dir = tmpdir();
    let txt = dir.path().join("bad.txt");
    std::fs::write(&txt, tiny_orbvoc().replacen(" 255 ", " 999 ", 1))
        .unwrap_or_else(|e| panic!("{e}"));
    let out = dir.path().join("voc.dpxvoc");
    let err = run_err(
        dynapix()
            .args(["vocab", "import"])
            .arg(&txt)
            .arg("--out")
            .arg(&out),
    );
    assert!(err.contains("line 3"), "{err}");
    assert!(!out.exists());
    let err = run_err(
        dynapix()
            .args(["vocab", "import"])
            .arg(dir.path().join("missing.txt"))
            .arg("--out")
            .arg(&out),
    );
    assert!(err.contains("missing.txt"), "{err}");
}

#[test]
fn train_on_generated_images() {
    let dir = tmpdir();
    // Textured images: random rectangles, different per image.
    for i in 0..4u32 {
        let mut img = image::GrayImage::from_pixel(320, 240, image::Luma([90]));
        let mut s = 12345u32.wrapping_mul(i + 1);
        for _ in 0..300 {
            s = s.wrapping_mul(1_103_515_245).wrapping_add(12345);
            let (x, y) = ((s >> 8) % 300, (s >> 20) % 220);
            let v = (s >> 3) as u8;
            for yy in y..y + 12 {
                for xx in x..x + 15 {
                    img.put_pixel(xx.min(319), yy.min(239), image::Luma([v]));
                }
            }
        }
        img.save(dir.path().join(format!("img{i}.png")))
            .unwrap_or_else(|e| panic!("{e}"));
    }
    let out = dir.path().join("voc.dpxvoc");
    let log = run_ok(
        dynapix()
            .args(["vocab", "train"])
            .arg(dir.path().join("img*.png"))
            .args(["--levels", "2", "--k", "8"])
            .arg("--out")
            .arg(&out),
    );
    assert!(log.contains("trained on 4 images"), "{log}");
    let v = load(&out);
    assert_eq!((v.branching(), v.levels()), (8, 2));
    assert!(
        v.word_count() > 8 && v.word_count() <= 64,
        "{}",
        v.word_count()
    );
    // No images → error; a folder without images → error.
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap_or_else(|e| panic!("{e}"));
    let err = run_err(
        dynapix()
            .args(["vocab", "train"])
            .arg(&empty)
            .arg("--out")
            .arg(&out),
    );
    assert!(err.contains("no PNG"), "{err}");
}

#[test]
fn train_on_real_frames() {
    let Some(rgb) = fr1_xyz_rgb() else { return };
    let dir = tmpdir();
    let out = dir.path().join("voc.dpxvoc");
    let log = run_ok(
        dynapix()
            .args(["vocab", "train"])
            .arg(&rgb)
            .args(["--max-images", "6", "--levels", "3"])
            .arg("--out")
            .arg(&out),
    );
    assert!(log.contains("trained on 6 images"), "{log}");
    let v = load(&out);
    assert_eq!((v.branching(), v.levels()), (10, 3));
    assert!(v.word_count() > 300, "{}", v.word_count());
}
