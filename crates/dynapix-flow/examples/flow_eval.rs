//! Writes image pairs with known flow (warps of real TUM frames) and runs our DIS on them.
//!
//! `cargo run --release -p dynapix-flow --example flow_eval -- OUT_DIR [PRESET...] [--repeat N]`
//!
//! For each case, `OUT_DIR/<case>/` receives `a.png`, `b.png`, `gt.flo`, `ours_<preset>.flo`,
//! and `OUT_DIR/ours.json` lists per case and preset the error statistics, the best and
//! median wall time of `--repeat` runs (default 5) and the process CPU time per run (Linux
//! `/proc/self/stat`, all threads). `scripts/compare-flow-opencv.py` reads these.

use dynapix_flow::metrics::visible_mask;
use dynapix_flow::{DisFlow, FlowProvider, Preset, flow_error, pairs, write_flo};
use std::path::PathBuf;
use std::time::Instant;

/// Process CPU time (user + system, all threads) in milliseconds, if the OS tells it.
fn cpu_ms() -> Option<f64> {
    dynapix_io::usage::cpu_seconds().map(|s| s * 1e3)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let out: PathBuf = args
        .next()
        .ok_or("usage: flow_eval OUT_DIR [PRESET...] [--repeat N]")?
        .into();
    let mut presets = Vec::new();
    let mut repeat = 5usize;
    while let Some(a) = args.next() {
        if a == "--repeat" {
            repeat = args.next().ok_or("--repeat needs a value")?.parse()?;
        } else {
            presets.push(a);
        }
    }
    if presets.is_empty() {
        presets = vec!["ultrafast".into(), "fast".into(), "medium".into()];
    }
    let data = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz/rgb"
    );
    let mut frames: Vec<PathBuf> = std::fs::read_dir(data)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    frames.sort();
    let pick = |i: usize| -> Result<image::GrayImage, Box<dyn std::error::Error>> {
        let p = frames.get(i).ok_or("not enough frames")?;
        Ok(image::open(p)?.to_luma8())
    };
    let (w, h) = (640, 480);
    let cases: Vec<(&str, usize, dynapix_flow::FlowField)> = vec![
        ("translation", 0, pairs::translation(w, h, [3.37, -1.62])),
        ("affine", 100, pairs::affine(w, h, 2.0, 1.03, [2.2, 1.4])),
        ("nonrigid", 200, pairs::smooth_nonrigid(w, h, 6.0)),
        (
            "translation_large",
            250,
            pairs::translation(w, h, [-14.6, 9.3]),
        ),
    ];
    let mut json = String::from("{\n");
    for (ci, (name, frame, gt)) in cases.iter().enumerate() {
        let b = pick(*frame)?;
        let a = pairs::make_a(&b, gt)?;
        let dir = out.join(name);
        std::fs::create_dir_all(&dir)?;
        a.save(dir.join("a.png"))?;
        b.save(dir.join("b.png"))?;
        write_flo(dir.join("gt.flo"), gt)?;
        let mask = visible_mask(gt, 0);
        json += &format!("  \"{name}\": {{\n");
        for (pi, preset) in presets.iter().enumerate() {
            let dis = DisFlow::with_preset(preset.parse::<Preset>()?);
            let mut times = Vec::new();
            let mut flow = None;
            let cpu0 = cpu_ms();
            for _ in 0..repeat.max(1) {
                let t = Instant::now();
                let f = dis.flow(&a, &b)?;
                times.push(t.elapsed().as_secs_f64() * 1e3);
                flow = Some(f);
            }
            let cpu = match (cpu0, cpu_ms()) {
                (Some(a), Some(b)) => (b - a) / repeat.max(1) as f64,
                _ => f64::NAN,
            };
            let flow = flow.ok_or("no run")?;
            write_flo(dir.join(format!("ours_{preset}.flo")), &flow)?;
            let s = flow_error(&flow, gt, Some(&mask))?;
            times.sort_by(f64::total_cmp);
            let best = times[0];
            let median = times[times.len() / 2];
            println!(
                "{name:18} {preset:9} EPE {:.3}  >1px {:5.2}%  >3px {:5.2}%  best {best:.1} ms  median {median:.1} ms  CPU {cpu:.1} ms/run",
                s.epe,
                100.0 * s.over_1px,
                100.0 * s.over_3px
            );
            json += &format!(
                "    \"{preset}\": {{\"epe\": {}, \"over_1px\": {}, \"over_3px\": {}, \"best_ms\": {best}, \"median_ms\": {median}, \"cpu_ms\": {}}}{}\n",
                s.epe,
                s.over_1px,
                s.over_3px,
                if cpu.is_finite() {
                    format!("{cpu}")
                } else {
                    "null".to_string()
                },
                if pi + 1 < presets.len() { "," } else { "" }
            );
        }
        json += &format!("  }}{}\n", if ci + 1 < cases.len() { "," } else { "" });
    }
    json += "}\n";
    std::fs::write(out.join("ours.json"), json)?;
    Ok(())
}
