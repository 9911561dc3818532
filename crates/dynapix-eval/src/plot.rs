//! Plots of an ATE evaluation, as SVG and PNG: the top view (x–y plane) of the ground truth
//! and the aligned estimate, and the per-pair ATE over time. Text is rendered with the
//! embedded DejaVu Sans font (Bitstream Vera licence, see `assets/DejaVuSans-LICENSE.txt`),
//! so no system font is needed. Files are written atomically (temporary name, then rename).

use crate::ate::AteResult;
use crate::error::{EvalError, Result};
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
/// Font family name the plots ask for.
const FAMILY: &str = "sans-serif";
/// Plot size in pixels.
const SIZE: (u32, u32) = (900, 700);

fn ensure_font() -> Result<()> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| register_font(FAMILY, FontStyle::Normal, FONT).is_ok());
    if ok {
        Ok(())
    } else {
        Err(EvalError::Plot {
            path: PathBuf::from("assets/DejaVuSans.ttf"),
            reason: "embedded font could not be loaded".into(),
        })
    }
}

fn plot_err(path: &Path, e: impl std::fmt::Display) -> EvalError {
    EvalError::Plot {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}

/// Range with a margin; a zero-width range is widened so plotters can draw it.
fn padded(lo: f64, hi: f64) -> (f64, f64) {
    let span = (hi - lo).max(1e-3);
    (lo - 0.05 * span, hi + 0.05 * span)
}

fn draw_top_view<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    ate: &AteResult,
) -> std::result::Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let pts = ate.pairs.iter().flat_map(|p| [p.gt, p.est_aligned]);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in pts {
        x0 = x0.min(p[0]);
        x1 = x1.max(p[0]);
        y0 = y0.min(p[1]);
        y1 = y1.max(p[1]);
    }
    // Equal scale on both axes, so the shape of the path is not distorted.
    let (w, h) = (SIZE.0 as f64 - 120.0, SIZE.1 as f64 - 120.0);
    let per_px = ((x1 - x0) / w).max((y1 - y0) / h).max(1e-6);
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (xr, yr) = (
        padded(cx - 0.5 * per_px * w, cx + 0.5 * per_px * w),
        padded(cy - 0.5 * per_px * h, cy + 0.5 * per_px * h),
    );
    let title = format!(
        "Top view (x-y), ATE RMSE {:.4} m, {} pairs",
        ate.stats.rmse, ate.stats.count
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FAMILY, 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("x [m]")
        .y_desc("y [m]")
        .label_style((FAMILY, 14))
        .draw()
        .map_err(|e| e.to_string())?;
    let gt_color = RGBColor(40, 40, 40);
    let est_color = RGBColor(30, 110, 220);
    chart
        .draw_series(LineSeries::new(
            ate.pairs.iter().map(|p| (p.gt[0], p.gt[1])),
            gt_color.stroke_width(2),
        ))
        .map_err(|e| e.to_string())?
        .label("ground truth")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], gt_color));
    chart
        .draw_series(LineSeries::new(
            ate.pairs
                .iter()
                .map(|p| (p.est_aligned[0], p.est_aligned[1])),
            est_color.stroke_width(2),
        ))
        .map_err(|e| e.to_string())?
        .label("estimate (aligned)")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], est_color));
    draw_legend(&mut chart)?;
    root.present().map_err(|e| e.to_string())
}

/// The legend box both plots share (upper right, translucent white, black border).
fn draw_legend<'a, DB: DrawingBackend + 'a>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
) -> std::result::Result<(), String> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FAMILY, 14))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| e.to_string())
}

fn draw_error_over_time<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    ate: &AteResult,
) -> std::result::Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let t0 = ate.pairs.first().map_or(0.0, |p| p.t_gt);
    let t1 = ate.pairs.last().map_or(1.0, |p| p.t_gt) - t0;
    let emax = ate.stats.max.max(1e-6) * 1.1;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("ATE over time (RMSE {:.4} m)", ate.stats.rmse),
            (FAMILY, 22),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..t1.max(1e-3), 0.0..emax)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("time since first pair [s]")
        .y_desc("position error [m]")
        .label_style((FAMILY, 14))
        .draw()
        .map_err(|e| e.to_string())?;
    let color = RGBColor(200, 60, 40);
    chart
        .draw_series(LineSeries::new(
            ate.pairs.iter().map(|p| (p.t_gt - t0, p.error)),
            color.stroke_width(1),
        ))
        .map_err(|e| e.to_string())?
        .label("ATE")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
    let rmse = ate.stats.rmse;
    let rmse_color = RGBColor(90, 90, 90);
    chart
        .draw_series(LineSeries::new(
            [(0.0, rmse), (t1.max(1e-3), rmse)],
            rmse_color.stroke_width(1),
        ))
        .map_err(|e| e.to_string())?
        .label("RMSE")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], rmse_color));
    draw_legend(&mut chart)?;
    root.present().map_err(|e| e.to_string())
}

#[derive(Clone, Copy)]
enum Kind {
    TopView,
    ErrorOverTime,
}

fn draw<DB: DrawingBackend>(
    kind: Kind,
    root: DrawingArea<DB, plotters::coord::Shift>,
    ate: &AteResult,
) -> std::result::Result<(), String> {
    match kind {
        Kind::TopView => draw_top_view(root, ate),
        Kind::ErrorOverTime => draw_error_over_time(root, ate),
    }
}

fn render(dir: &Path, stem: &str, ate: &AteResult, kind: Kind) -> Result<()> {
    ensure_font()?;
    let svg_path = dir.join(format!("{stem}.svg"));
    let mut text = String::new();
    draw(
        kind,
        SVGBackend::with_string(&mut text, SIZE).into_drawing_area(),
        ate,
    )
    .map_err(|e| plot_err(&svg_path, e))?;
    dynapix_io::write_atomic(&svg_path, text.as_bytes()).map_err(|e| plot_err(&svg_path, e))?;

    let png_path = dir.join(format!("{stem}.png"));
    let mut buf = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
    draw(
        kind,
        BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area(),
        ate,
    )
    .map_err(|e| plot_err(&png_path, e))?;
    let bytes = encode_png(&buf, SIZE).map_err(|e| plot_err(&png_path, e))?;
    dynapix_io::write_atomic(&png_path, &bytes).map_err(|e| plot_err(&png_path, e))
}

fn encode_png(rgb: &[u8], size: (u32, u32)) -> std::result::Result<Vec<u8>, String> {
    let mut out = Vec::new();
    let enc = image::codecs::png::PngEncoder::new(&mut out);
    image::ImageEncoder::write_image(enc, rgb, size.0, size.1, image::ExtendedColorType::Rgb8)
        .map_err(|e| e.to_string())?;
    Ok(out)
}

/// Writes `trajectory_xy.svg`/`.png` (top view) and `ate_over_time.svg`/`.png` into `dir`
/// (which must exist). Returns the written paths.
pub fn write_plots(dir: &Path, ate: &AteResult) -> Result<Vec<PathBuf>> {
    if ate.pairs.is_empty() {
        return Err(plot_err(dir, "nothing to plot (no pairs)"));
    }
    render(dir, "trajectory_xy", ate, Kind::TopView)?;
    render(dir, "ate_over_time", ate, Kind::ErrorOverTime)?;
    Ok(["trajectory_xy", "ate_over_time"]
        .iter()
        .flat_map(|s| [dir.join(format!("{s}.svg")), dir.join(format!("{s}.png"))])
        .collect())
}
