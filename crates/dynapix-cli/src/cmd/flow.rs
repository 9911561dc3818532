//! `dynapix flow`: dense optical flow between two images with the built-in DIS
//! (`dynapix_flow::DisFlow`). Writes the flow from A to B (`B(x + f(x)) ≈ A(x)`) as a
//! Middlebury `.flo` file and, optionally, its colour-wheel picture. Colour images are
//! converted to grey (ITU-R 601 luma, as the `image` crate does).

use anyhow::bail;
use dynapix_flow::{
    DisFlow, FlowProvider, Preset, flow_to_color, flow_to_color_with_max, write_flo,
};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `dynapix flow`.
#[derive(clap::Args)]
pub struct Args {
    /// First image (A).
    pub a: PathBuf,
    /// Second image (B), same size as A.
    pub b: PathBuf,
    /// Output `.flo` file (flow from A to B).
    #[arg(long)]
    pub out: PathBuf,
    /// DIS preset (OpenCV's presets).
    #[arg(long, value_enum, default_value = "medium")]
    pub preset: dynapix::FlowPreset,
    /// Also write the Middlebury colour-wheel picture of the flow (PNG).
    #[arg(long)]
    pub viz: Option<PathBuf>,
    /// Flow magnitude (pixels) shown fully saturated in the picture; default: the largest.
    #[arg(long)]
    pub viz_max: Option<f32>,
}

/// Reads an image as grey with the one decoder of every command (format by content).
fn load_gray(path: &Path) -> anyhow::Result<image::GrayImage> {
    Ok(dynapix_io::images::read_gray(path)?)
}

/// Runs `dynapix flow`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let preset: Preset = args.preset.preset();
    if let Some(m) = args.viz_max
        && !(m.is_finite() && m > 0.0)
    {
        bail!("--viz-max must be a positive number of pixels, got {m}");
    }
    let a = load_gray(&args.a)?;
    let b = load_gray(&args.b)?;
    if a.dimensions() != b.dimensions() {
        bail!(
            "images differ in size: {} is {}x{}, {} is {}x{}",
            args.a.display(),
            a.width(),
            a.height(),
            args.b.display(),
            b.width(),
            b.height()
        );
    }
    let dis = DisFlow::with_preset(preset);
    let t = Instant::now();
    let flow = dis.flow(&a, &b)?;
    tracing::info!(
        "DIS {:?} on {}x{}: {:.1} ms",
        preset,
        a.width(),
        a.height(),
        t.elapsed().as_secs_f64() * 1e3
    );
    write_flo(&args.out, &flow)?;
    if let Some(viz) = &args.viz {
        let img = match args.viz_max {
            Some(m) => flow_to_color_with_max(&flow, m),
            None => flow_to_color(&flow),
        };
        dynapix_io::images::write_rgb(viz, &img)?;
    }
    Ok(())
}
