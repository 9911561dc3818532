//! Writes a generated sequence in the DynaPix folder layout: `rgb/`, `depth/`, `background/`,
//! `depth_bg/`, `mask/`, `instance/` PNGs named `<timestamp>.png`, optional `flow/<ts>.flo`
//! (Middlebury), `groundtruth.txt` (camera-to-world, TUM format), `rgb.txt`, `depth.txt`,
//! `association.txt` and `camera.yaml` (ORB-SLAM2 settings).
//!
//! Every file is written to `<name>.tmp` in the same folder and renamed into place, so an
//! interrupted run never leaves a truncated file. PNG encoding is deterministic (fixed
//! compression and filter), so the same seed gives the same bytes.

use crate::SynthError;
use crate::sequence::{Flow, Frame, Gray16Image, Sequence};
use dynapix_geometry::PinholeCamera;
use dynapix_io::tum::{self, Association, ListEntry};
use dynapix_io::{StampedPose, Trajectory, write_atomic};
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ExtendedColorType, GrayImage, ImageEncoder, RgbImage};
use nalgebra::Isometry3;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Sub-folders of the layout, in the order they are written.
pub const FOLDERS: [&str; 6] = ["rgb", "depth", "background", "depth_bg", "mask", "instance"];

fn io_err(path: &Path, source: std::io::Error) -> SynthError {
    SynthError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn png_bytes(
    path: &Path,
    data: &[u8],
    w: u32,
    h: u32,
    ty: ExtendedColorType,
) -> Result<Vec<u8>, SynthError> {
    let mut out = Vec::new();
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Sub)
        .write_image(data, w, h, ty)
        .map_err(|e| SynthError::Image {
            path: path.to_path_buf(),
            source: e,
        })?;
    Ok(out)
}

/// Encodes an 8-bit RGB image as PNG bytes.
pub fn rgb_png(path: &Path, img: &RgbImage) -> Result<Vec<u8>, SynthError> {
    png_bytes(
        path,
        img.as_raw(),
        img.width(),
        img.height(),
        ExtendedColorType::Rgb8,
    )
}

/// Encodes an 8-bit grey image as PNG bytes.
pub fn gray_png(path: &Path, img: &GrayImage) -> Result<Vec<u8>, SynthError> {
    png_bytes(
        path,
        img.as_raw(),
        img.width(),
        img.height(),
        ExtendedColorType::L8,
    )
}

/// Encodes a 16-bit grey image as PNG bytes (big-endian samples, as PNG requires).
pub fn gray16_png(path: &Path, img: &Gray16Image) -> Result<Vec<u8>, SynthError> {
    let bytes: Vec<u8> = img.as_raw().iter().flat_map(|v| v.to_be_bytes()).collect();
    // The encoder takes native-endian u16 data as bytes; it swaps to big endian itself.
    let native: Vec<u8> = img.as_raw().iter().flat_map(|v| v.to_ne_bytes()).collect();
    let _ = bytes;
    png_bytes(
        path,
        &native,
        img.width(),
        img.height(),
        ExtendedColorType::L16,
    )
}

/// ORB-SLAM2 settings of a synthetic sequence: its camera, depth factor 5000, and the TUM
/// values for the rest (bf 40, ThDepth 40, 1000 ORB features, FAST 20/7).
///
/// `bf` stays 40 at every image size, although the simulated sensor's baseline (0.075 m)
/// would give `bf` ≈ 20 at 320×240: with 20 the close/far threshold falls to 3 m, the
/// room's walls become far points, and on five 320×240 walking runs ORB-SLAM2 mode went
/// from 0.03–0.25 m to 0.24–0.59 m ATE and DynaPix (four runs) from a mean of 0.018 to
/// 0.022 m (issue 15 note, 2026-12-02). All 320×240 results in this repository were
/// measured with 40.
pub fn camera_settings(cam: &PinholeCamera, fps: f64) -> dynapix_io::Settings {
    dynapix_io::Settings {
        fx: cam.fx,
        fy: cam.fy,
        cx: cam.cx,
        cy: cam.cy,
        dist: cam.dist,
        width: cam.width,
        height: cam.height,
        fps,
        depth_map_factor: crate::sequence::DEPTH_FACTOR as f64,
        ..dynapix_io::Settings::tum3()
    }
}

/// Creates the layout folders under `dir` (and `flow/` when asked).
pub fn create_layout(dir: &Path, with_flow: bool) -> Result<(), SynthError> {
    for f in FOLDERS.iter().copied().chain(with_flow.then_some("flow")) {
        let p = dir.join(f);
        std::fs::create_dir_all(&p).map_err(|e| io_err(&p, e))?;
    }
    Ok(())
}

/// Writes the images of one frame (and its flow) under `dir`.
pub fn write_frame(
    dir: &Path,
    ts: &str,
    frame: &Frame,
    flow: Option<&Flow>,
) -> Result<(), SynthError> {
    let name = format!("{ts}.png");
    let jobs: Vec<(PathBuf, usize)> = FOLDERS
        .iter()
        .enumerate()
        .map(|(k, f)| (dir.join(f).join(&name), k))
        .collect();
    jobs.par_iter()
        .map(|(path, k)| {
            let bytes = match k {
                0 => rgb_png(path, &frame.rgb)?,
                1 => gray16_png(path, &frame.depth)?,
                2 => rgb_png(path, &frame.background)?,
                3 => gray16_png(path, &frame.depth_bg)?,
                4 => gray_png(path, &frame.mask)?,
                _ => gray16_png(path, &frame.instance)?,
            };
            Ok(write_atomic(path, &bytes)?)
        })
        .collect::<Result<Vec<()>, SynthError>>()?;
    if let Some(f) = flow {
        dynapix_flow::write_flo(dir.join("flow").join(format!("{ts}.flo")), f)?;
    }
    Ok(())
}

/// Writes the list files, ground truth and camera settings for frames `0..n` of `seq`.
pub fn write_lists(dir: &Path, seq: &Sequence, n: usize) -> Result<(), SynthError> {
    let list = |sub: &str| -> Vec<ListEntry> {
        (0..n)
            .map(|i| ListEntry {
                t: seq.time(i),
                path: format!("{sub}/{}.png", seq.timestamp(i)),
            })
            .collect()
    };
    let (rgb, depth) = (list("rgb"), list("depth"));
    write_lists_of(dir, &rgb, &depth)?;
    let gt = Trajectory::new(
        (0..n)
            .map(|i| StampedPose::new(seq.time(i), seq.pose(i)))
            .collect(),
    );
    gt.write_tum(dir.join("groundtruth.txt"))?;
    camera_settings(&seq.params.camera, seq.params.fps).write(dir.join("camera.yaml"))?;
    Ok(())
}

/// Writes `rgb.txt`, `depth.txt` and `association.txt` (rgb and depth paired in order).
fn write_lists_of(dir: &Path, rgb: &[ListEntry], depth: &[ListEntry]) -> Result<(), SynthError> {
    tum::write_list(dir.join("rgb.txt"), rgb, "color images")?;
    tum::write_list(dir.join("depth.txt"), depth, "depth maps")?;
    let assoc: Vec<Association> = rgb
        .iter()
        .zip(depth)
        .map(|(r, d)| Association {
            t_rgb: r.t,
            rgb: r.path.clone(),
            t_depth: d.t,
            depth: d.path.clone(),
        })
        .collect();
    tum::write_associations(dir.join("association.txt"), &assoc)?;
    Ok(())
}

/// Generates and writes the whole sequence into `dir`; `flow_step` adds flow to frame `i+k`
/// for every `i` with `i + k < frames`; `progress(i)` is called after each frame.
pub fn write_sequence(
    seq: &Sequence,
    dir: &Path,
    flow_step: Option<usize>,
    progress: &mut dyn FnMut(usize),
) -> Result<(), SynthError> {
    let n = seq.params.frames;
    create_layout(dir, flow_step.is_some())?;
    for i in 0..n {
        let step = flow_step.filter(|&k| k > 0 && i + k < n);
        let (frame, flow) = seq.frame(i, step);
        write_frame(dir, &seq.timestamp(i), &frame, flow.as_ref())?;
        progress(i);
    }
    write_lists(dir, seq, n)
}

/// Augments the real sequence in `seq_dir` with flying movers (see [`crate::augment`]) and
/// writes the DynaPix layout into `out_dir`. Frames without a ground-truth pose are skipped.
/// `max_frames` limits the number of frames written. Returns the number written.
pub fn augment_sequence(
    seq_dir: &Path,
    out_dir: &Path,
    params: &crate::augment::AugmentParams,
    max_frames: Option<usize>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<usize, SynthError> {
    use crate::augment::{Augmenter, median_depth};
    // One output per depth image (files are named like it), so each depth image may serve
    // one frame only: pair rgb and depth one-to-one like `associate.py`.
    let opts = dynapix_io::SequenceOptions {
        pairing: dynapix_io::Pairing::OneToOne,
        ..Default::default()
    };
    let seq = dynapix_io::Sequence::open_with(seq_dir, &opts)?;
    let settings = seq.settings()?.clone();
    let cam = settings.camera();
    let k = crate::render::Intrinsics::from(&cam);
    let factor = seq.depth_factor as f32;
    let frames: Vec<(&dynapix_io::FrameInfo, Isometry3<f64>)> = seq
        .frames
        .iter()
        .filter_map(|f| seq.gt_pose_at(f.t).map(|p| (f, p)))
        .take(max_frames.unwrap_or(usize::MAX))
        .collect();
    let Some((first, first_pose)) = frames.first() else {
        return Err(SynthError::Format {
            path: seq_dir.to_path_buf(),
            what: "no frame has a ground-truth pose (groundtruth.txt missing or not covering the frames)".into(),
        });
    };
    let first_depth = dynapix_io::images::read_depth_raw(&first.depth)?;
    let med = median_depth(&first_depth, factor).ok_or_else(|| SynthError::Format {
        path: first.depth.clone(),
        what: "first depth image has no valid pixel".into(),
    })?;
    let aug = Augmenter::new(params.clone(), first_pose, med)?;
    create_layout(out_dir, false)?;
    let t0 = first.t;
    let dt = if frames.len() > 1 {
        (frames[frames.len() - 1].0.t - t0) / (frames.len() - 1) as f64
    } else {
        1.0 / 30.0
    };
    let file_name = |p: &Path| -> Result<String, SynthError> {
        p.file_name()
            .and_then(|n| n.to_str())
            .map(str::to_string)
            .ok_or_else(|| SynthError::Format {
                path: p.to_path_buf(),
                what: "file name is not UTF-8".into(),
            })
    };
    let (mut rgb_list, mut depth_list) = (Vec::new(), Vec::new());
    for (n, (info, pose)) in frames.iter().enumerate() {
        let rgb = dynapix_io::images::read_rgb(&info.rgb)?;
        let depth = dynapix_io::images::read_depth_raw(&info.depth)?;
        if rgb.dimensions() != (cam.width, cam.height)
            || depth.dimensions() != (cam.width, cam.height)
        {
            return Err(SynthError::Format {
                path: info.rgb.clone(),
                what: format!(
                    "image size {:?} / depth {:?}, camera {}x{}",
                    rgb.dimensions(),
                    depth.dimensions(),
                    cam.width,
                    cam.height
                ),
            });
        }
        let c = aug.composite(&k, info.t - t0, dt, pose, &rgb, &depth, factor);
        let rgb_name = file_name(&info.rgb)?;
        let depth_name = file_name(&info.depth)?;
        let jobs: Vec<(PathBuf, usize)> = vec![
            (out_dir.join("rgb").join(&rgb_name), 0),
            (out_dir.join("background").join(&rgb_name), 1),
            (out_dir.join("depth").join(&depth_name), 2),
            (out_dir.join("depth_bg").join(&depth_name), 3),
            (out_dir.join("mask").join(&rgb_name), 4),
            (out_dir.join("instance").join(&rgb_name), 5),
        ];
        jobs.par_iter()
            .map(|(path, kind)| {
                let bytes = match kind {
                    0 => rgb_png(path, &c.rgb)?,
                    1 => rgb_png(path, &rgb)?,
                    2 => gray16_png(path, &c.depth)?,
                    3 => gray16_png(path, &depth)?,
                    4 => gray_png(path, &c.mask)?,
                    _ => gray16_png(path, &c.instance)?,
                };
                Ok(write_atomic(path, &bytes)?)
            })
            .collect::<Result<Vec<()>, SynthError>>()?;
        rgb_list.push(ListEntry {
            t: info.t,
            path: format!("rgb/{rgb_name}"),
        });
        depth_list.push(ListEntry {
            t: info.t_depth,
            path: format!("depth/{depth_name}"),
        });
        progress(n, frames.len());
    }
    write_lists_of(out_dir, &rgb_list, &depth_list)?;
    let gt_src = seq_dir.join("groundtruth.txt");
    if seq.gt_convention.needs_conversion() {
        // The source holds marker poses (Bonn); the output folder is a plain dynapix
        // sequence, whose ground truth is read as camera poses: write the converted ones.
        if let Some(gt) = &seq.groundtruth {
            gt.write_tum(out_dir.join("groundtruth.txt"))?;
        }
    } else {
        let gt = std::fs::read(&gt_src).map_err(|e| io_err(&gt_src, e))?;
        write_atomic(out_dir.join("groundtruth.txt"), &gt)?;
    }
    settings.write(out_dir.join("camera.yaml"))?;
    Ok(frames.len())
}
