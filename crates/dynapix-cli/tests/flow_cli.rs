//! `dynapix flow` end to end: a textured image shifted by a known sub-pixel translation must
//! give that flow in the `.flo` (the contract used by automated checks), colour input works,
//! and bad input gives clear errors.

use dynapix_flow::{FlowField, pairs, read_flo};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dynapix"))
}

#[test]
fn flow_cli_writes_the_flow_from_a_to_b() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (160, 120);
    let b = pairs::texture(w, h);
    let gt = FlowField::constant(w, h, [1.6, -0.7]);
    let a = pairs::make_a(&b, &gt).unwrap();
    // A as colour (grey replicated) to exercise the conversion.
    let a_rgb = image::DynamicImage::ImageLuma8(a).to_rgb8();
    a_rgb.save(dir.path().join("a.png")).unwrap();
    b.save(dir.path().join("b.png")).unwrap();
    let out = dir.path().join("flow.flo");
    let viz = dir.path().join("flow.png");
    let st = bin()
        .args(["flow"])
        .arg(dir.path().join("a.png"))
        .arg(dir.path().join("b.png"))
        .arg("--out")
        .arg(&out)
        .args(["--preset", "fast", "--viz"])
        .arg(&viz)
        .status()
        .unwrap();
    assert!(st.success());
    let f = read_flo(&out).unwrap();
    assert_eq!((f.width, f.height), (w, h));
    let mut err = 0.0f64;
    let mut n = 0usize;
    for y in 16..h - 16 {
        for x in 16..w - 16 {
            let v = f.get(x, y);
            err += (((v[0] - 1.6).powi(2) + (v[1] + 0.7).powi(2)) as f64).sqrt();
            n += 1;
        }
    }
    let epe = err / n as f64;
    assert!(epe < 0.1, "interior EPE {epe}");
    let img = image::open(&viz).unwrap();
    assert_eq!((img.width(), img.height()), (w, h));
}

#[test]
fn flow_cli_reports_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    pairs::texture(20, 10)
        .save(dir.path().join("a.png"))
        .unwrap();
    pairs::texture(21, 10)
        .save(dir.path().join("b.png"))
        .unwrap();
    let run = |b: &str, preset: &str| {
        bin()
            .arg("flow")
            .arg(dir.path().join("a.png"))
            .arg(dir.path().join(b))
            .arg("--out")
            .arg(dir.path().join("o.flo"))
            .args(["--preset", preset])
            .output()
            .unwrap()
    };
    let o = run("b.png", "medium");
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("differ in size"));
    let o = run("missing.png", "medium");
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("missing.png"));
    let o = run("a.png", "slow");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("invalid value 'slow'") && err.contains("ultrafast, fast, medium"),
        "{err}"
    );
    assert!(!dir.path().join("o.flo").exists());
    // A saturation of 0 (or not a number) is refused before any work.
    for bad in ["0", "-1", "nan"] {
        let o = bin()
            .arg("flow")
            .arg(dir.path().join("a.png"))
            .arg(dir.path().join("a.png"))
            .arg("--out")
            .arg(dir.path().join("o.flo"))
            .args(["--viz"])
            .arg(dir.path().join("o.png"))
            .arg(format!("--viz-max={bad}"))
            .output()
            .unwrap();
        assert!(!o.status.success(), "--viz-max {bad}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("--viz-max must be a positive"), "{err}");
        assert!(!dir.path().join("o.flo").exists());
    }
}
