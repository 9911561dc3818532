//! Writes a generated sequence in the DynaPix folder layout: `rgb/`, `depth/`, `background/`,
//! `depth_bg/`, `mask/`, `instance/` PNGs named `<timestamp>.png`, optional `flow/<ts>.flo`
//! (Middlebury), `groundtruth.txt` (camera-to-world, TUM format), `rgb.txt`, `depth.txt`,
//! `association.txt` and `camera.yaml` (ORB-SLAM2 settings).
//!
//! Every file is written to `<name>.tmp` in the same folder and renamed into place, so an
//! interrupted run never leaves a truncated file. PNG encoding is deterministic (fixed
//! compression and filter), so the same seed gives the same bytes.
// TODO(io): switch to dynapix_io writers once the `io` branch lands.

use crate::SynthError;
use crate::sequence::{Flow, Frame, Gray16Image, Sequence};
use dynapix_geometry::PinholeCamera;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ExtendedColorType, GrayImage, ImageEncoder, RgbImage};
use nalgebra::Isometry3;
use rayon::prelude::*;
use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Sub-folders of the layout, in the order they are written.
pub const FOLDERS: [&str; 6] = ["rgb", "depth", "background", "depth_bg", "mask", "instance"];

fn io_err(path: &Path, source: std::io::Error) -> SynthError {
    SynthError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Writes `bytes` to `path` atomically (temporary file in the same folder, then rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), SynthError> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let mut f = std::fs::File::create(&tmp).map_err(|e| io_err(&tmp, e))?;
    f.write_all(bytes).map_err(|e| io_err(&tmp, e))?;
    f.sync_data().ok();
    drop(f);
    std::fs::rename(&tmp, path).map_err(|e| io_err(path, e))
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

/// Middlebury `.flo` bytes: magic 202021.25, width, height (i32), then (u, v) f32 pairs, little endian.
pub fn flo_bytes(flow: &Flow) -> Vec<u8> {
    let mut out = Vec::with_capacity(12 + flow.data.len() * 8);
    out.extend_from_slice(&202021.25f32.to_le_bytes());
    out.extend_from_slice(&(flow.width as i32).to_le_bytes());
    out.extend_from_slice(&(flow.height as i32).to_le_bytes());
    for [u, v] in &flow.data {
        out.extend_from_slice(&u.to_le_bytes());
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Reads a Middlebury `.flo` file.
pub fn read_flo(path: &Path) -> Result<Flow, SynthError> {
    let bytes = std::fs::read(path).map_err(|e| io_err(path, e))?;
    let bad = |what: String| SynthError::Format {
        path: path.to_path_buf(),
        what,
    };
    let word = |k: usize| -> Result<[u8; 4], SynthError> {
        bytes
            .get(4 * k..4 * k + 4)
            .and_then(|s| s.try_into().ok())
            .ok_or_else(|| bad(format!("file ends at byte {}", bytes.len())))
    };
    let magic = f32::from_le_bytes(word(0)?);
    if magic != 202021.25 {
        return Err(bad(format!("magic {magic}, expected 202021.25")));
    }
    let w = i32::from_le_bytes(word(1)?);
    let h = i32::from_le_bytes(word(2)?);
    if w <= 0 || h <= 0 {
        return Err(bad(format!("size {w}x{h}")));
    }
    let n = w as usize * h as usize;
    if bytes.len() != 12 + 8 * n {
        return Err(bad(format!(
            "{} bytes, expected {} for {w}x{h}",
            bytes.len(),
            12 + 8 * n
        )));
    }
    let data = (0..n)
        .map(|i| {
            let u = f32::from_le_bytes(word(3 + 2 * i)?);
            let v = f32::from_le_bytes(word(4 + 2 * i)?);
            Ok([u, v])
        })
        .collect::<Result<Vec<_>, SynthError>>()?;
    Ok(Flow {
        width: w as usize,
        height: h as usize,
        data,
    })
}

/// One line of a TUM trajectory: `t tx ty tz qx qy qz qw`.
pub fn tum_line(ts: &str, pose: &Isometry3<f64>) -> String {
    let t = pose.translation.vector;
    let q = pose.rotation.coords; // (x, y, z, w)
    format!(
        "{ts} {:.6} {:.6} {:.6} {:.6} {:.6} {:.6} {:.6}",
        t.x, t.y, t.z, q.x, q.y, q.z, q.w
    )
}

/// ORB-SLAM2 settings for the sequence camera (depth factor 5000, TUM-like ORB settings).
pub fn camera_yaml(cam: &PinholeCamera, fps: f64) -> String {
    let d = cam.dist;
    format!(
        "%YAML:1.0\n\
# Written by dynapix synth: camera of the synthetic sequence (ideal pinhole).\n\
Camera.fx: {:.6}\nCamera.fy: {:.6}\nCamera.cx: {:.6}\nCamera.cy: {:.6}\n\
Camera.k1: {:.6}\nCamera.k2: {:.6}\nCamera.p1: {:.6}\nCamera.p2: {:.6}\nCamera.k3: {:.6}\n\
Camera.width: {}\nCamera.height: {}\nCamera.fps: {:.1}\nCamera.bf: 40.0\nCamera.RGB: 1\n\
ThDepth: 40.0\nDepthMapFactor: 5000.0\n\
ORBextractor.nFeatures: 1000\nORBextractor.scaleFactor: 1.2\nORBextractor.nLevels: 8\n\
ORBextractor.iniThFAST: 20\nORBextractor.minThFAST: 7\n",
        cam.fx, cam.fy, cam.cx, cam.cy, d[0], d[1], d[2], d[3], d[4], cam.width, cam.height, fps
    )
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
            write_atomic(path, &bytes)
        })
        .collect::<Result<Vec<()>, SynthError>>()?;
    if let Some(f) = flow {
        write_atomic(&dir.join("flow").join(format!("{ts}.flo")), &flo_bytes(f))?;
    }
    Ok(())
}

/// Writes the list files, ground truth and camera settings for frames `0..n` of `seq`.
pub fn write_lists(dir: &Path, seq: &Sequence, n: usize) -> Result<(), SynthError> {
    let mut rgb = String::from("# color images\n# file: 'dynapix synth'\n# timestamp filename\n");
    let mut depth = String::from("# depth maps\n# file: 'dynapix synth'\n# timestamp filename\n");
    let mut assoc = String::new();
    let mut gt = String::from(
        "# ground truth trajectory (camera-to-world)\n# file: 'dynapix synth'\n# timestamp tx ty tz qx qy qz qw\n",
    );
    for i in 0..n {
        let ts = seq.timestamp(i);
        let _ = writeln!(rgb, "{ts} rgb/{ts}.png");
        let _ = writeln!(depth, "{ts} depth/{ts}.png");
        let _ = writeln!(assoc, "{ts} rgb/{ts}.png {ts} depth/{ts}.png");
        let _ = writeln!(gt, "{}", tum_line(&ts, &seq.pose(i)));
    }
    write_atomic(&dir.join("rgb.txt"), rgb.as_bytes())?;
    write_atomic(&dir.join("depth.txt"), depth.as_bytes())?;
    write_atomic(&dir.join("association.txt"), assoc.as_bytes())?;
    write_atomic(&dir.join("groundtruth.txt"), gt.as_bytes())?;
    write_atomic(
        &dir.join("camera.yaml"),
        camera_yaml(&seq.params.camera, seq.params.fps).as_bytes(),
    )
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
