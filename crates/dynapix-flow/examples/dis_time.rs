//! Times DIS on two images (default: the first two TUM fr1_xyz frames): best, median and mean
//! wall time and process CPU time per run, for every preset.
//!
//! `cargo run --release -p dynapix-flow --example dis_time -- [A.png B.png] [--repeat N]`

use dynapix_flow::{DisFlow, FlowProvider, Preset};
use std::time::Instant;

/// Process CPU time (user + system, all threads) in milliseconds, if the OS tells it.
fn cpu_ms() -> Option<f64> {
    dynapix_io::usage::cpu_seconds().map(|s| s * 1e3)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut paths = Vec::new();
    let mut repeat = 30usize;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--repeat" {
            repeat = args.next().ok_or("--repeat needs a value")?.parse()?;
        } else {
            paths.push(std::path::PathBuf::from(a));
        }
    }
    if paths.is_empty() {
        let dir = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz/rgb"
        );
        let mut v: Vec<_> = std::fs::read_dir(dir)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "png"))
            .collect();
        v.sort();
        paths = v.into_iter().take(2).collect();
    }
    let [pa, pb] = paths.as_slice() else {
        return Err("need two images".into());
    };
    let a = image::open(pa)?.to_luma8();
    let b = image::open(pb)?.to_luma8();
    for preset in [Preset::Medium, Preset::Fast, Preset::Ultrafast] {
        let dis = DisFlow::with_preset(preset);
        let _ = dis.flow(&a, &b)?;
        let mut t = Vec::with_capacity(repeat);
        let c0 = cpu_ms();
        for _ in 0..repeat.max(1) {
            let s = Instant::now();
            let f = dis.flow(&a, &b)?;
            t.push(s.elapsed().as_secs_f64() * 1e3);
            std::hint::black_box(f);
        }
        let cpu = match (c0, cpu_ms()) {
            (Some(x), Some(y)) => (y - x) / t.len() as f64,
            _ => f64::NAN,
        };
        let mean = t.iter().sum::<f64>() / t.len() as f64;
        t.sort_by(f64::total_cmp);
        println!(
            "dynapix {preset:?}: best {:.1} median {:.1} mean {mean:.1} cpu/run {cpu:.1} ms ({} runs, {}x{})",
            t[0],
            t[t.len() / 2],
            t.len(),
            a.width(),
            a.height()
        );
    }
    Ok(())
}
