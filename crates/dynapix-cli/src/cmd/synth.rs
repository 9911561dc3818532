//! `dynapix synth`: generate a synthetic dynamic RGB-D sequence (DynaPix folder layout), a
//! contact sheet of all presets, or a rendering benchmark.

use anyhow::{Context, bail};
use dynapix_synth::output;
use dynapix_synth::preview;
use dynapix_synth::{Layers, Preset, SensorParams, Sequence, SynthParams};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::time::Instant;

/// Sensor realism levels.
#[derive(Clone, Copy, Debug, Default, clap::ValueEnum)]
pub enum Realism {
    /// Exact depth, no noise, no blur.
    Clean,
    /// Kinect-like depth (noise ∝ depth², quantisation, holes) and mild image noise (default).
    #[default]
    Kinect,
    /// Kinect plus exposure changes and motion blur.
    Full,
}

/// The preset names as the closed set of values of `--preset`.
pub(crate) fn preset_names() -> clap::builder::PossibleValuesParser {
    clap::builder::PossibleValuesParser::new(Preset::ALL.map(|p| p.name()))
}

/// Arguments of `dynapix synth`.
#[derive(clap::Args, Debug, Default)]
pub struct Args {
    /// Scenario.
    #[arg(long, default_value = "walking_xyz", value_parser = preset_names())]
    pub preset: String,
    /// Number of frames (30 Hz; default 300, placing_box 450). With --augment: at most this
    /// many frames.
    #[arg(long)]
    pub frames: Option<usize>,
    /// Seed: same preset and seed give identical bytes.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder (DynaPix layout).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Also write ground-truth flow from frame t to t+K (`flow/<ts>.flo`, Middlebury).
    #[arg(long, value_name = "K")]
    pub flow: Option<usize>,
    /// Write a contact sheet of all presets to this PNG: a 4×4 grid of blocks in the order
    /// static, walking_xyz, walking_static, walking_rpy / walking_halfsphere, sitting,
    /// flying, occlusion / loop, person_tracking, crowd, moving_box / placing_box, balloon;
    /// in each block rows are t = 0, 2, 4 s and columns rgb, background, mask, depth.
    #[arg(long, value_name = "OUT.png")]
    pub preview: Option<PathBuf>,
    /// Sensor realism.
    #[arg(long, value_enum, default_value = "kinect")]
    pub realism: Realism,
    /// Image width (px); intrinsics scale with it unless given.
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (px).
    #[arg(long)]
    pub height: Option<u32>,
    /// Focal length x (px).
    #[arg(long)]
    pub fx: Option<f64>,
    /// Focal length y (px).
    #[arg(long)]
    pub fy: Option<f64>,
    /// Principal point x (px).
    #[arg(long)]
    pub cx: Option<f64>,
    /// Principal point y (px).
    #[arg(long)]
    pub cy: Option<f64>,
    /// Time the renderer on this many frames (both versions per frame) and print the figures.
    #[arg(long, value_name = "FRAMES")]
    pub bench: Option<usize>,
    /// Insert virtual movers into the real TUM sequence SEQ_DIR (uses its ground truth and
    /// depth) and write the DynaPix layout into --out.
    #[arg(long, value_name = "SEQ_DIR")]
    pub augment: Option<PathBuf>,
    /// Number of virtual objects for --augment.
    #[arg(long, default_value_t = 3)]
    pub objects: usize,
    /// --augment: boxes that rest in view for 3 s, are pushed across it and rest again.
    #[arg(long, default_value_t = 0)]
    pub boxes: usize,
    /// --augment: balls thrown back and forth across the view.
    #[arg(long, default_value_t = 0)]
    pub balls: usize,
    /// --augment: people walking across the view close to the camera (a crowd).
    #[arg(long, default_value_t = 0)]
    pub crowd: usize,
}

/// The generator parameters of the arguments (the demo uses it too).
pub(crate) fn params(args: &Args) -> anyhow::Result<SynthParams> {
    let preset: Preset = args.preset.parse()?;
    let mut cam = dynapix_geometry::PinholeCamera::tum_fr3();
    if args.width.is_some() || args.height.is_some() {
        let w = args.width.unwrap_or(cam.width);
        let s = w as f64 / cam.width as f64;
        let h = args
            .height
            .unwrap_or((cam.height as f64 * s).round() as u32);
        cam = cam.resized(w, h);
    }
    if let Some(v) = args.fx {
        cam.fx = v;
    }
    if let Some(v) = args.fy {
        cam.fy = v;
    }
    if let Some(v) = args.cx {
        cam.cx = v;
    }
    if let Some(v) = args.cy {
        cam.cy = v;
    }
    let sensor = match args.realism {
        Realism::Clean => SensorParams::clean(),
        Realism::Kinect => SensorParams::default(),
        Realism::Full => SensorParams::full(),
    };
    Ok(SynthParams {
        preset,
        frames: args.frames.unwrap_or(preset.default_frames()),
        seed: args.seed,
        scene: dynapix_synth::SceneParams::for_width(cam.width),
        camera: cam,
        sensor,
        ..SynthParams::default()
    })
}

/// Runs `dynapix synth`.
pub fn run(args: Args, bars: &super::common::Bars) -> anyhow::Result<()> {
    let p = params(&args)?;
    if args.out.is_none() && args.preview.is_none() && args.bench.is_none() {
        bail!("nothing to do: give --out DIR, --preview OUT.png or --bench N");
    }
    if let Some(seq_dir) = &args.augment {
        let Some(out) = &args.out else {
            bail!("--augment needs --out DIR");
        };
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let params = dynapix_synth::augment::AugmentParams {
            seed: args.seed,
            objects: args.objects,
            boxes: args.boxes,
            balls: args.balls,
            crowd: args.crowd,
            ..Default::default()
        };
        let bar = bars.adopt(ProgressBar::new(0));
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} augment [{bar:40}] {pos}/{len} frames, eta {eta}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        let n = output::augment_sequence(seq_dir, out, &params, args.frames, &mut |i, total| {
            bar.set_length(total as u64);
            bar.set_position(i as u64 + 1);
        })
        .with_context(|| format!("augmenting {} into {}", seq_dir.display(), out.display()))?;
        bar.finish();
        tracing::info!(
            "augmented {n} frames of {} into {}",
            seq_dir.display(),
            out.display()
        );
        return Ok(());
    }
    if let Some(n) = args.bench {
        bench(&p, n)?;
    }
    if let Some(path) = &args.preview {
        let sheet = preview::contact_sheet(&p, &Preset::ALL, &[0.0, 2.0, 4.0], 200)?;
        let bytes = output::rgb_png(path, &sheet)?;
        super::common::write_bytes(path, &bytes)?;
        eprintln!("contact sheet written to {}", path.display());
    }
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let seq = Sequence::new(p.clone())?;
        let bar = bars.adopt(ProgressBar::new(p.frames as u64));
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} synth {msg} [{bar:40}] {pos}/{len} frames, {per_sec}, eta {eta}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar.set_message(p.preset.name());
        output::write_sequence(&seq, dir, args.flow, &mut |_| bar.inc(1))
            .with_context(|| format!("writing sequence into {}", dir.display()))?;
        bar.finish();
        tracing::info!(
            "wrote {} frames of {} into {}",
            p.frames,
            p.preset.name(),
            dir.display()
        );
    }
    Ok(())
}

use dynapix_io::usage::cpu_seconds;

fn bench(p: &SynthParams, n: usize) -> anyhow::Result<()> {
    let n = n.max(1);
    let (t0, c0) = (Instant::now(), cpu_seconds());
    let seq = Sequence::new(SynthParams {
        frames: n,
        ..p.clone()
    })?;
    let (build, build_cpu) = (
        t0.elapsed().as_secs_f64(),
        cpu_seconds().zip(c0).map(|(a, b)| a - b),
    );
    let mut layers = Layers::default();
    // Warm-up frame (allocations), then timed renders of both versions.
    seq.render_at(0.0, &mut layers);
    let (t1, c1) = (Instant::now(), cpu_seconds());
    for i in 0..n {
        seq.render_at(seq.time(i), &mut layers);
    }
    let render = t1.elapsed().as_secs_f64() / n as f64;
    let render_cpu = cpu_seconds().zip(c1).map(|(a, b)| (a - b) / n as f64);
    let m = n.min(30);
    let (t2, c2) = (Instant::now(), cpu_seconds());
    for i in 0..m {
        let _ = seq.frame(i, None);
    }
    let frame = t2.elapsed().as_secs_f64() / m as f64;
    let frame_cpu = cpu_seconds().zip(c2).map(|(a, b)| (a - b) / m as f64);
    let ms = |x: Option<f64>| x.map_or("n/a".to_string(), |v| format!("{:.1}", v * 1e3));
    println!(
        "preset {} {}x{}, {} rayon threads, {n} frames\n\
         scene build: wall {:.2} s, cpu {} ms\n\
         render both versions: wall {:.1} ms/frame ({:.1} frames/s), cpu {} ms/frame\n\
         full frame (render + sensor + mask, no PNG): wall {:.1} ms, cpu {} ms",
        p.preset.name(),
        p.camera.width,
        p.camera.height,
        rayon::current_num_threads(),
        build,
        ms(build_cpu),
        render * 1e3,
        1.0 / render,
        ms(render_cpu),
        frame * 1e3,
        ms(frame_cpu),
    );
    Ok(())
}
