//! `dynapix demo`: the one-command demonstration (README). Generates the synthetic walking
//! presets (xyz, static, rpy, halfsphere) with the synth library, runs `orbslam2` and
//! `dynapix` on each, in this process, with no ground
//! truth at run time (DynaPix's splatting poses come from the ORB-SLAM2 run, which is its own
//! first pass), prints the paper-style table and writes `report.md` with the trajectory plots,
//! the ATE over time and a strip of Fig.-1-style probability overlays.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use dynapix::RunOptions;
use dynapix::{CameraChoice, Config, FlowPreset, Input, Method, PoseSource};
use dynapix_eval::{SequenceSummary, paper_table};
use image::{Rgb, RgbImage};

use super::common::Bars;
use super::run::{self, RunSpec};

/// Arguments of `dynapix demo`.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Output folder.
    #[arg(long, default_value = "dynapix-demo")]
    pub out: PathBuf,
    /// Frames per sequence (30 Hz).
    #[arg(long, default_value_t = 200)]
    pub frames: usize,
    /// Image width (intrinsics scale with it).
    #[arg(long, default_value_t = 320)]
    pub width: u32,
    /// Image height.
    #[arg(long, default_value_t = 240)]
    pub height: u32,
    /// Synth seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Presets (comma separated).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "walking_xyz,walking_static,walking_rpy,walking_halfsphere",
        value_parser = super::synth::preset_names()
    )]
    pub presets: Vec<String>,
    /// DIS preset of the motion maps.
    #[arg(long, value_enum, default_value = "fast")]
    pub flow_preset: FlowPreset,
    /// Use ground-truth poses for the motion maps (the paper's setting).
    #[arg(long)]
    pub oracle_poses: bool,
}

/// Fig.-1-style overlay: the frame with the motion probability in red.
fn overlay(rgb: &RgbImage, prob_png: &Path) -> anyhow::Result<RgbImage> {
    let prob = dynapix::MotionProbability::read(prob_png)?;
    if prob.dimensions() != rgb.dimensions() {
        bail!("{}: size differs from the frame", prob_png.display());
    }
    let prob = prob.into_image();
    Ok(RgbImage::from_fn(rgb.width(), rgb.height(), |x, y| {
        let p = prob.get_pixel(x, y).0[0];
        let a = 0.7 * p.clamp(0.0, 1.0);
        let c = rgb.get_pixel(x, y).0;
        let g = 0.299 * c[0] as f32 + 0.587 * c[1] as f32 + 0.114 * c[2] as f32;
        Rgb([
            ((1.0 - a) * g + a * 255.0) as u8,
            ((1.0 - a) * g) as u8,
            ((1.0 - a) * g) as u8,
        ])
    }))
}

/// Generates `preset` into `seq` with the synth library (what `dynapix synth` does).
fn synthesize(args: &Args, preset: &str, seq: &Path, bars: &Bars) -> anyhow::Result<()> {
    use dynapix::Progress;
    let sa = super::synth::Args {
        preset: preset.to_string(),
        frames: Some(args.frames),
        seed: args.seed,
        width: Some(args.width),
        height: Some(args.height),
        ..super::synth::Args::default()
    };
    let p = super::synth::params(&sa)?;
    std::fs::create_dir_all(seq).with_context(|| format!("creating {}", seq.display()))?;
    let synth = dynapix_synth::Sequence::new(p.clone())?;
    let label = format!("synth {preset}");
    bars.event(dynapix::ProgressEvent::Begin {
        task: &label,
        total: p.frames as u64,
    });
    let r = dynapix_synth::output::write_sequence(&synth, seq, None, &mut |_| {
        bars.event(dynapix::ProgressEvent::Step {
            task: &label,
            message: "",
        })
    });
    bars.event(dynapix::ProgressEvent::End { task: &label });
    r.with_context(|| format!("writing sequence into {}", seq.display()))?;
    Ok(())
}

/// Runs `dynapix demo`.
pub fn run(args: Args, bars: &Bars) -> anyhow::Result<()> {
    let t0 = Instant::now();
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let mut summaries = Vec::new();
    let mut strip: Vec<(RgbImage, RgbImage)> = Vec::new();
    let mut sections = String::new();
    let n = args.presets.len();
    for (i, preset) in args.presets.iter().enumerate() {
        let seq = args.out.join("data").join(preset);
        eprintln!(
            "[{}/{n}] {preset}: generating {} frames",
            i + 1,
            args.frames
        );
        if !seq.join("groundtruth.txt").exists() {
            synthesize(&args, preset, &seq, bars)?;
        }
        let base = Config::default();
        let input = Input::open(&seq, &base.sequence, &CameraChoice::Sequence)?;
        let gt = input
            .sequence
            .groundtruth
            .as_ref()
            .with_context(|| format!("{} has no groundtruth.txt", seq.display()))?;
        let stamps = gt.timestamps();
        let mut methods = Vec::new();
        // The ORB-SLAM2 run is DynaPix's first pass (same system, same seed).
        let mut first_pass = None;
        for method in [Method::Orbslam2, Method::Dynapix] {
            let out = args.out.join("runs").join(preset).join(method.name());
            let mut config = base.clone().with_method(method);
            config.motion.flow = args.flow_preset;
            // As a camera's data: the rendered background/ folder is never used.
            config.motion.background = dynapix::BackgroundSource::Reconstruct;
            if args.oracle_poses {
                config.motion.poses = PoseSource::GroundTruth;
            }
            let options = RunOptions {
                // The ORB-SLAM2 run serves as the first pass only when the configuration's
                // first pass is ORB-SLAM2 (reference mode).
                first_pass: if args.oracle_poses
                    || config.passes.first != dynapix::FirstPass::Orbslam2
                {
                    None
                } else {
                    first_pass.clone()
                },
                cache_dir: run::cache_for(&input, None, false),
                ..Default::default()
            };
            eprintln!("[{}/{n}] {preset}: {}", i + 1, method.name());
            let o = run::execute(
                RunSpec {
                    input: &input,
                    config,
                    options,
                    out,
                    runs: 1,
                    first_run: 0,
                    observer: None,
                },
                bars,
            )?;
            if method == Method::Orbslam2 {
                first_pass = o.written_trajectory.clone();
            }
            // Scored from memory, as the trajectory file reads back.
            let est = o
                .written_trajectory
                .as_ref()
                .with_context(|| format!("{preset}: the run left no trajectory"))?;
            let rr = dynapix_eval::evaluate_run_poses(
                &gt.pairs(),
                &est.pairs(),
                &o.trajectory,
                Some(&stamps),
                &dynapix_eval::EvalParams::default(),
            );
            methods.push(dynapix_eval::aggregate::summarize_with_floors(
                method.name(),
                vec![rr.result],
                vec![rr.motionless_floor_m],
            ));
            if method == Method::Dynapix
                && let Some(pd) = &o.prob_dir
            {
                // Middle frame of the sequence for the overlay strip.
                let mid = input.len() / 2;
                let f = &input.sequence.frames[mid].rgb;
                if let Some(name) = input.map_name(mid) {
                    let rgb = dynapix_io::images::read_rgb(f)?;
                    match overlay(&rgb, &pd.join(name)) {
                        Ok(ov) => strip.push((rgb, ov)),
                        Err(e) => tracing::warn!("overlay: {}", super::common::report(&e)),
                    }
                }
            }
        }
        let rel = |m: &str, f: &str| format!("runs/{preset}/{m}/{f}");
        sections.push_str(&format!(
            "### {preset}\n\n| ORB-SLAM2 | DynaPix |\n|---|---|\n| ![]({}) | ![]({}) |\n| ![]({}) | ![]({}) |\n\n",
            rel("orbslam2", "trajectory_xy.png"),
            rel("dynapix", "trajectory_xy.png"),
            rel("orbslam2", "ate_over_time.png"),
            rel("dynapix", "ate_over_time.png"),
        ));
        summaries.push(SequenceSummary {
            sequence: preset.clone(),
            methods,
        });
    }
    let table = paper_table(summaries);
    dynapix_eval::files::write_table(&args.out, &table)?;
    if let Some((w, h)) = strip.first().map(|s| s.0.dimensions()) {
        let mut img = RgbImage::new(w * strip.len() as u32, 2 * h);
        for (k, (a, b)) in strip.iter().enumerate() {
            if a.dimensions() == (w, h) && b.dimensions() == (w, h) {
                image::imageops::replace(&mut img, a, (k as u32 * w) as i64, 0);
                image::imageops::replace(&mut img, b, (k as u32 * w) as i64, h as i64);
            }
        }
        let mut bytes = Vec::new();
        img.write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )?;
        super::common::write_bytes(&args.out.join("overlays.png"), &bytes)?;
    }
    let secs = t0.elapsed().as_secs_f64();
    let md = table.to_markdown();
    let report = format!(
        "# dynapix demo\n\nSynthetic walking sequences ({} frames, {}×{}, seed {}), ORB-SLAM2 vs \
DynaPix. Ground truth used at run time: {}. ATE RMSE in metres (lower is better), TR = tracking \
rate (higher is better), ATR = average ATE / average TR.\n\n{md}\n\n\
## Motion probability (Fig. 1 style)\n\nTop: frames; bottom: motion probability P in red.\n\n\
![](overlays.png)\n\n## Trajectories (top view) and ATE over time\n\n{sections}\
Total time: {secs:.0} s.\n",
        args.frames,
        args.width,
        args.height,
        args.seed,
        if args.oracle_poses {
            "poses for the motion maps (oracle)"
        } else {
            "none (motion maps from DynaPix's own passes; background reconstructed, the rendered \
             background/ folder is not used)"
        }
    );
    super::common::write_bytes(&args.out.join("report.md"), report.as_bytes())?;
    println!("{md}");
    println!(
        "report: {} ({secs:.0} s)",
        args.out.join("report.md").display()
    );
    Ok(())
}
