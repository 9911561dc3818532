//! Image files: 8-bit colour PNG/JPEG, 16-bit depth PNG (converted to metres), 8-bit masks,
//! motion-probability maps, and PFM for lossless float maps (spec §1.8, §2.1, §5).
//!
//! Probability maps in the reference format are 16-bit single-channel PNGs storing the
//! static weight `trunc((1 − P)·1000)` (computed in `f32` like the reference's float arrays),
//! named like the rgb image under `prob/` ([`prob_png_path`]). The lossless variant stores P
//! itself as a greyscale PFM ([`prob_pfm_path`], [`write_pfm`]): a tiny standard format
//! (`Pf\n<w> <h>\n<scale>\n` then little-endian `f32` rows from bottom to top when scale < 0)
//! read by OpenCV, numpy scripts and most image tools.

use std::path::{Path, PathBuf};

use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{DynamicImage, GrayImage, ImageBuffer, Luma, RgbImage};

use crate::atomic::{write_atomic, write_atomic_with};
use crate::error::{IoError, Result};
use crate::weights::{MotionProbability, StaticWeights};

/// A depth map in metres; 0 means "no depth".
pub type DepthImage = ImageBuffer<Luma<f32>, Vec<f32>>;
/// A per-pixel motion probability map P ∈ [0, 1] (0 = static, 1 = moving).
pub type ProbMap = ImageBuffer<Luma<f32>, Vec<f32>>;
/// A raw 16-bit single-channel image (depth in sensor units, stored probability weights).
pub type Gray16Image = ImageBuffer<Luma<u16>, Vec<u16>>;

/// Scale of the stored probability weight: `stored = trunc((1 − P)·1000)`.
pub const PROB_PNG_SCALE: f32 = 1000.0;

/// Opens `path` for decoding with its format told by its content (the magic bytes), not by
/// its name: a JPEG file named `.png` decodes, and a file that is no image fails the same way
/// whatever its extension.
fn open_sniffed(path: &Path) -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>> {
    // Not `ImageReader::open`: it takes the format from the extension, which the content
    // would then only override when recognised.
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let reader = image::ImageReader::new(std::io::BufReader::new(file))
        .with_guessed_format()
        .map_err(|e| IoError::io(path, e))?;
    if reader.format().is_none() {
        return Err(IoError::invalid(
            path,
            "cannot decode image: the content is neither PNG nor JPEG",
        ));
    }
    Ok(reader)
}

fn image_error(path: &Path, e: image::ImageError) -> IoError {
    match e {
        image::ImageError::IoError(io) => IoError::io(path, io),
        other => IoError::invalid(path, format!("cannot decode image: {other}")),
    }
}

/// Decodes the image file `path`, its format told by its content: the one image decoder of
/// dynapix (every command reads images through it, so a file decodes everywhere or fails
/// everywhere with the same message). Errors name the file.
pub fn decode_image(path: impl AsRef<Path>) -> Result<DynamicImage> {
    let path = path.as_ref();
    open_sniffed(path)?
        .decode()
        .map_err(|e| image_error(path, e))
}

/// The width and height of the image file `path`, read from its header with the format told
/// by its content (like [`decode_image`]); the pixels are not decoded.
pub fn image_size(path: impl AsRef<Path>) -> Result<(u32, u32)> {
    let path = path.as_ref();
    open_sniffed(path)?
        .into_dimensions()
        .map_err(|e| image_error(path, e))
}

fn decode(path: &Path) -> Result<DynamicImage> {
    decode_image(path)
}

fn describe(img: &DynamicImage) -> String {
    format!("{:?}", img.color())
}

/// Reads an 8-bit colour image (PNG or JPEG). Grey and RGBA 8-bit images are converted to
/// RGB; 16-bit or float images are an error.
pub fn read_rgb(path: impl AsRef<Path>) -> Result<RgbImage> {
    let path = path.as_ref();
    match decode(path)? {
        DynamicImage::ImageRgb8(img) => Ok(img),
        img @ (DynamicImage::ImageRgba8(_)
        | DynamicImage::ImageLuma8(_)
        | DynamicImage::ImageLumaA8(_)) => Ok(img.to_rgb8()),
        other => Err(IoError::invalid(
            path,
            format!("expected an 8-bit colour image, got {}", describe(&other)),
        )),
    }
}

/// Reads an 8-bit image (grey, grey + alpha, colour or colour + alpha) as grey, with the
/// ITU-R 601 luma of the `image` crate; 16-bit or float images are an error.
pub fn read_gray(path: impl AsRef<Path>) -> Result<GrayImage> {
    let path = path.as_ref();
    match decode(path)? {
        DynamicImage::ImageLuma8(img) => Ok(img),
        img @ (DynamicImage::ImageRgb8(_)
        | DynamicImage::ImageRgba8(_)
        | DynamicImage::ImageLumaA8(_)) => Ok(img.to_luma8()),
        other => Err(IoError::invalid(
            path,
            format!("expected an 8-bit image, got {}", describe(&other)),
        )),
    }
}

/// Reads a 16-bit single-channel depth PNG without conversion (sensor units).
/// An 8-bit or multi-channel image is an error: depth would be silently wrong.
pub fn read_depth_raw(path: impl AsRef<Path>) -> Result<Gray16Image> {
    let path = path.as_ref();
    match decode(path)? {
        DynamicImage::ImageLuma16(img) => Ok(img),
        other => Err(IoError::invalid(
            path,
            format!(
                "expected a 16-bit single-channel depth image, got {}",
                describe(&other)
            ),
        )),
    }
}

/// Converts raw depth to metres like ORB-SLAM2: `value · (1/depth_factor)` in `f32`
/// (TUM: factor 5000, GRADE: 1000). 0 stays 0 (no depth).
pub fn depth_to_metres(raw: &Gray16Image, depth_factor: f64) -> DepthImage {
    let scale = 1.0f32 / depth_factor as f32;
    let metres: Vec<f32> = raw.as_raw().iter().map(|&v| v as f32 * scale).collect();
    ImageBuffer::from_raw(raw.width(), raw.height(), metres)
        .unwrap_or_else(|| ImageBuffer::new(raw.width(), raw.height()))
}

/// Reads a 16-bit depth PNG and converts it to metres (see [`depth_to_metres`]).
/// `depth_factor` must be positive and finite.
pub fn read_depth(path: impl AsRef<Path>, depth_factor: f64) -> Result<DepthImage> {
    let path = path.as_ref();
    if !(depth_factor.is_finite() && depth_factor > 0.0) {
        return Err(IoError::invalid(
            path,
            format!("depth factor must be positive, got {depth_factor}"),
        ));
    }
    Ok(depth_to_metres(&read_depth_raw(path)?, depth_factor))
}

/// Errors (naming both files) unless the two images have the same size.
pub fn check_same_size(
    path_a: &Path,
    size_a: (u32, u32),
    path_b: &Path,
    size_b: (u32, u32),
) -> Result<()> {
    if size_a == size_b {
        Ok(())
    } else {
        Err(IoError::invalid(
            path_a,
            format!(
                "size {}x{} differs from {} ({}x{})",
                size_a.0,
                size_a.1,
                path_b.display(),
                size_b.0,
                size_b.1
            ),
        ))
    }
}

/// Reads an rgb image and its depth (metres), checking that the sizes agree.
pub fn read_rgbd(
    rgb_path: impl AsRef<Path>,
    depth_path: impl AsRef<Path>,
    depth_factor: f64,
) -> Result<(RgbImage, DepthImage)> {
    let (rp, dp) = (rgb_path.as_ref(), depth_path.as_ref());
    let rgb = read_rgb(rp)?;
    let depth = read_depth(dp, depth_factor)?;
    check_same_size(rp, rgb.dimensions(), dp, depth.dimensions())?;
    Ok((rgb, depth))
}

fn write_png<P>(path: &Path, img: &ImageBuffer<P, Vec<P::Subpixel>>) -> Result<()>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
{
    write_atomic_with(path, |w| {
        img.write_with_encoder(PngEncoder::new(w))
            .map_err(std::io::Error::other)
    })
}

/// Writes an 8-bit colour PNG atomically.
pub fn write_rgb(path: impl AsRef<Path>, img: &RgbImage) -> Result<()> {
    write_png(path.as_ref(), img)
}

/// Writes a raw 16-bit single-channel PNG atomically.
pub fn write_gray16(path: impl AsRef<Path>, img: &Gray16Image) -> Result<()> {
    write_png(path.as_ref(), img)
}

/// Converts metres to raw 16-bit depth: `round(d · depth_factor)`. Depths that are not
/// finite, not positive, or beyond the 16-bit range become 0 (no depth) rather than a
/// wrong clamped value.
pub fn metres_to_depth(depth: &DepthImage, depth_factor: f64) -> Gray16Image {
    ImageBuffer::from_fn(depth.width(), depth.height(), |x, y| {
        let v = (depth.get_pixel(x, y)[0] as f64 * depth_factor).round();
        Luma([if v.is_finite() && v > 0.0 && v <= u16::MAX as f64 {
            v as u16
        } else {
            0
        }])
    })
}

/// Writes a depth map (metres) as a 16-bit PNG with `depth_factor` units per metre.
pub fn write_depth(path: impl AsRef<Path>, depth: &DepthImage, depth_factor: f64) -> Result<()> {
    let path = path.as_ref();
    if !(depth_factor.is_finite() && depth_factor > 0.0) {
        return Err(IoError::invalid(
            path,
            format!("depth factor must be positive, got {depth_factor}"),
        ));
    }
    write_gray16(path, &metres_to_depth(depth, depth_factor))
}

/// Reads an 8-bit single-channel mask as stored (no value mapping). dynapix masks use
/// non-zero = dynamic; DynaSLAM/Mask R-CNN masks use 0 = person, 1 = static (convert them
/// with [`mask_from_dynaslam`]).
pub fn read_mask(path: impl AsRef<Path>) -> Result<GrayImage> {
    let path = path.as_ref();
    match decode(path)? {
        DynamicImage::ImageLuma8(img) => Ok(img),
        img @ DynamicImage::ImageLumaA8(_) => Ok(img.to_luma8()),
        other => Err(IoError::invalid(
            path,
            format!(
                "expected an 8-bit single-channel mask, got {}",
                describe(&other)
            ),
        )),
    }
}

/// Converts a DynaSLAM-convention mask (0 = dynamic object, non-zero = static) into the
/// dynapix convention (255 = dynamic, 0 = static).
pub fn mask_from_dynaslam(mask: &GrayImage) -> GrayImage {
    GrayImage::from_fn(mask.width(), mask.height(), |x, y| {
        Luma([if mask.get_pixel(x, y)[0] == 0 { 255 } else { 0 }])
    })
}

/// Writes an 8-bit single-channel mask PNG atomically.
pub fn write_mask(path: impl AsRef<Path>, mask: &GrayImage) -> Result<()> {
    write_png(path.as_ref(), mask)
}

/// Reads a reference probability PNG without conversion: the stored static weight
/// `trunc((1 − P)·1000)` ∈ [0, 1000], as the reference SLAM consumes it (w = stored/1000).
pub fn read_prob_png_raw(path: impl AsRef<Path>) -> Result<Gray16Image> {
    let path = path.as_ref();
    let img = match decode(path)? {
        DynamicImage::ImageLuma16(img) => img,
        other => {
            return Err(IoError::invalid(
                path,
                format!(
                    "expected a 16-bit single-channel probability map, got {}",
                    describe(&other)
                ),
            ));
        }
    };
    if img.as_raw().iter().any(|&v| v > 1000)
        && let Some((x, y, p)) = img.enumerate_pixels().find(|(_, _, p)| p[0] > 1000)
    {
        return Err(IoError::invalid(
            path,
            format!("pixel ({x}, {y}) stores {} > 1000", p[0]),
        ));
    }
    Ok(img)
}

/// Reads a reference probability PNG as P = 1 − stored/1000 (see [`read_prob_png_raw`]).
pub fn read_prob_png(path: impl AsRef<Path>) -> Result<ProbMap> {
    Ok(read_motion_probability(path)?.into_image())
}

/// Reads a reference probability PNG as a typed [`MotionProbability`].
pub fn read_motion_probability(path: impl AsRef<Path>) -> Result<MotionProbability> {
    Ok(MotionProbability::from_stored(&read_prob_png_raw(path)?))
}

/// Reads a reference probability PNG as the [`StaticWeights`] the SLAM backend uses
/// (w = stored/1000, as the reference reads it).
pub fn read_static_weights(path: impl AsRef<Path>) -> Result<StaticWeights> {
    Ok(StaticWeights::from_stored(&read_prob_png_raw(path)?))
}

/// Quantises P like the reference: `trunc((1 − P)·1000)` in `f32`, P clamped to [0, 1].
/// Stored 1000 ⇔ P == 0; P = 0.1 → 900, P = 0.1000001 → 899; stored 0 for P ≳ 0.999
/// (in `f32`, P = 0.999 already gives 0). The codec is [`MotionProbability::to_stored`].
pub fn prob_to_stored(prob: &ProbMap) -> Gray16Image {
    crate::weights::stored_image(prob)
}

/// Writes P as a reference probability PNG (see [`prob_to_stored`]), atomically.
/// A NaN probability is an error.
pub fn write_prob_png(path: impl AsRef<Path>, prob: &ProbMap) -> Result<()> {
    let path = path.as_ref();
    check_finite(path, prob)?;
    write_gray16(path, &prob_to_stored(prob))
}

/// Writes a typed motion probability as a reference probability PNG, atomically (a NaN
/// probability is an error).
pub fn write_motion_probability(path: impl AsRef<Path>, prob: &MotionProbability) -> Result<()> {
    let path = path.as_ref();
    check_finite(path, prob.as_image())?;
    // Maps are written once per pass and read back at once: fast compression with the `Up`
    // row filter (lossless like any PNG). On a 640×480 map against the encoder's defaults:
    // write 2.3 → 2.0 ms, read 1.3 → 0.4 ms, 25 → 35 KB (no filter: 540 KB and slower).
    let stored = prob.to_stored();
    write_atomic_with(path, |w| {
        stored
            .write_with_encoder(PngEncoder::new_with_quality(
                w,
                CompressionType::Fast,
                FilterType::Up,
            ))
            .map_err(std::io::Error::other)
    })
}

fn check_finite(path: &Path, map: &ImageBuffer<Luma<f32>, Vec<f32>>) -> Result<()> {
    if !map.as_raw().iter().any(|p| p.is_nan()) {
        return Ok(());
    }
    match map.enumerate_pixels().find(|(_, _, p)| p[0].is_nan()) {
        Some((x, y, _)) => Err(IoError::invalid(
            path,
            format!("refusing to write: pixel ({x}, {y}) is NaN"),
        )),
        None => Ok(()),
    }
}

/// Where the reference SLAM looks for the probability map of an rgb image:
/// `<sequence>/prob/<rgb file name>` (e.g. `prob/1341846434.710184.png`, `prob/12.png`).
pub fn prob_png_path(seq_dir: &Path, rgb_path: &Path) -> PathBuf {
    let name = rgb_path.file_name().unwrap_or(rgb_path.as_os_str());
    seq_dir.join("prob").join(name)
}

/// Path of the lossless probability map: `<sequence>/prob/<rgb file stem>.pfm`.
pub fn prob_pfm_path(seq_dir: &Path, rgb_path: &Path) -> PathBuf {
    prob_png_path(seq_dir, rgb_path).with_extension("pfm")
}

/// Writes a single-channel float map as greyscale PFM (little-endian), atomically. Lossless.
pub fn write_pfm(path: impl AsRef<Path>, map: &ImageBuffer<Luma<f32>, Vec<f32>>) -> Result<()> {
    let (w, h) = map.dimensions();
    let mut bytes = format!("Pf\n{w} {h}\n-1.0\n").into_bytes();
    bytes.reserve(w as usize * h as usize * 4);
    // PFM stores rows from the bottom of the image to the top.
    for y in (0..h).rev() {
        for x in 0..w {
            bytes.extend_from_slice(&map.get_pixel(x, y)[0].to_le_bytes());
        }
    }
    write_atomic(path, &bytes)
}

/// Reads a greyscale PFM (`Pf`, either byte order) into a float map.
pub fn read_pfm(path: impl AsRef<Path>) -> Result<ImageBuffer<Luma<f32>, Vec<f32>>> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
    let bad = |m: &str| IoError::invalid(path, format!("not a greyscale PFM file: {m}"));
    // Header: three whitespace-terminated lines: magic, "width height", scale.
    let mut pos = 0;
    let mut header_line = |what: &str| -> Result<String> {
        let rest = bytes.get(pos..).unwrap_or_default();
        let end = rest
            .iter()
            .position(|&b| b == b'\n')
            .filter(|&e| e < 64)
            .ok_or_else(|| bad(&format!("missing {what} line")))?;
        let line = std::str::from_utf8(&rest[..end])
            .map_err(|_| bad(&format!("{what} line is not text")))?
            .trim()
            .to_string();
        pos += end + 1;
        Ok(line)
    };
    let magic = header_line("magic")?;
    if magic != "Pf" {
        return Err(bad(&format!("magic `{magic}`, expected `Pf`")));
    }
    let dims = header_line("size")?;
    let mut it = dims.split_whitespace().map(str::parse::<u32>);
    let (w, h) = match (it.next(), it.next(), it.next()) {
        (Some(Ok(w)), Some(Ok(h)), None) => (w, h),
        _ => return Err(bad(&format!("size line `{dims}`"))),
    };
    let scale_line = header_line("scale")?;
    let scale: f64 = scale_line
        .parse()
        .map_err(|_| bad(&format!("scale `{scale_line}`")))?;
    if scale == 0.0 || !scale.is_finite() {
        return Err(bad(&format!("scale `{scale_line}`")));
    }
    let data = bytes.get(pos..).unwrap_or_default();
    let expected = w as u64 * h as u64 * 4;
    if data.len() as u64 != expected {
        return Err(IoError::invalid(
            path,
            format!(
                "PFM {w}x{h} needs {expected} data bytes, found {}",
                data.len()
            ),
        ));
    }
    let little = scale < 0.0;
    let mut out = ImageBuffer::new(w, h);
    for (i, chunk) in data.chunks_exact(4).enumerate() {
        let b = [chunk[0], chunk[1], chunk[2], chunk[3]];
        let v = if little {
            f32::from_le_bytes(b)
        } else {
            f32::from_be_bytes(b)
        };
        let (x, row) = ((i % w as usize) as u32, (i / w as usize) as u32);
        out.put_pixel(x, h - 1 - row, Luma([v]));
    }
    Ok(out)
}

/// Writes P losslessly as PFM (see [`write_pfm`]); NaN is an error.
pub fn write_prob_pfm(path: impl AsRef<Path>, prob: &ProbMap) -> Result<()> {
    let path = path.as_ref();
    check_finite(path, prob)?;
    write_pfm(path, prob)
}

/// Reads a lossless probability map written by [`write_prob_pfm`]; values must lie in [0, 1].
pub fn read_prob_pfm(path: impl AsRef<Path>) -> Result<ProbMap> {
    let path = path.as_ref();
    let map = read_pfm(path)?;
    if let Some((x, y, p)) = map
        .enumerate_pixels()
        .find(|(_, _, p)| !(0.0..=1.0).contains(&p[0]))
    {
        return Err(IoError::invalid(
            path,
            format!("pixel ({x}, {y}) has probability {} outside [0, 1]", p[0]),
        ));
    }
    Ok(map)
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::testutil::data_dir;

    #[test]
    fn depth_to_metres_scales_every_pixel_in_place_as_orbslam2() {
        let raw = Gray16Image::from_fn(7, 5, |x, y| Luma([(x * 1000 + y * 7) as u16]));
        let m = depth_to_metres(&raw, 5000.0);
        assert_eq!(m.dimensions(), (7, 5));
        let scale = 1.0f32 / 5000.0;
        for (x, y, p) in m.enumerate_pixels() {
            let want = raw.get_pixel(x, y)[0] as f32 * scale;
            assert_eq!(p[0].to_bits(), want.to_bits(), "pixel ({x}, {y})");
        }
        assert_eq!(m.get_pixel(0, 0)[0], 0.0, "no depth stays 0");
        assert_eq!(m.get_pixel(6, 4)[0], 6028.0 * scale);
    }

    #[test]
    fn depth_round_trip_and_metres() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("d.png");
        let depth = DepthImage::from_fn(7, 5, |x, y| Luma([(x + 10 * y) as f32 * 0.0002]));
        write_depth(&p, &depth, 5000.0).unwrap();
        let raw = read_depth_raw(&p).unwrap();
        assert_eq!(raw.get_pixel(3, 2)[0], 23);
        let back = read_depth(&p, 5000.0).unwrap();
        for (a, b) in depth.pixels().zip(back.pixels()) {
            assert!((a[0] - b[0]).abs() < 1e-6);
        }
        // Out-of-range and invalid depths become 0, never a clamped value.
        let odd = DepthImage::from_fn(3, 1, |x, _| Luma([[-1.0, f32::NAN, 20.0][x as usize]]));
        assert!(metres_to_depth(&odd, 5000.0).pixels().all(|p| p[0] == 0));
        assert!(write_depth(&p, &depth, 0.0).is_err());
    }

    #[test]
    fn eight_bit_depth_and_size_mismatch_are_errors_naming_files() {
        let dir = tempfile::tempdir().unwrap();
        let d8 = dir.path().join("depth8.png");
        write_mask(&d8, &GrayImage::new(4, 4)).unwrap();
        let e = read_depth(&d8, 5000.0).unwrap_err().to_string();
        assert!(e.contains("depth8.png") && e.contains("16-bit"), "{e}");
        let rgb = dir.path().join("rgb.png");
        write_rgb(&rgb, &RgbImage::new(4, 3)).unwrap();
        let d16 = dir.path().join("depth16.png");
        write_gray16(&d16, &Gray16Image::new(4, 4)).unwrap();
        let e = read_rgbd(&rgb, &d16, 5000.0).unwrap_err().to_string();
        assert!(e.contains("rgb.png") && e.contains("depth16.png"), "{e}");
        assert!(read_rgb(&d16).is_err());
        let junk = dir.path().join("junk.png");
        std::fs::write(&junk, b"not a png at all").unwrap();
        let e = read_rgb(&junk).unwrap_err().to_string();
        assert!(e.contains("junk.png"), "{e}");
        let e = read_rgb(dir.path().join("missing.png")).unwrap_err();
        assert!(matches!(e, IoError::Io { .. }) && e.to_string().contains("missing.png"));
    }

    #[test]
    fn images_are_decoded_by_content_not_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let img = RgbImage::from_fn(16, 8, |x, y| {
            image::Rgb([(x * 15) as u8, (y * 30) as u8, 7])
        });
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode_image(&img)
            .unwrap();
        // JPEG bytes under a .png name (and PNG bytes under .jpg) decode everywhere.
        let named_png = dir.path().join("frame.png");
        std::fs::write(&named_png, &jpeg).unwrap();
        assert_eq!(read_rgb(&named_png).unwrap().dimensions(), (16, 8));
        assert_eq!(read_gray(&named_png).unwrap().dimensions(), (16, 8));
        assert_eq!(image_size(&named_png).unwrap(), (16, 8));
        let named_jpg = dir.path().join("frame.jpg");
        write_rgb(&named_jpg, &img).unwrap();
        assert_eq!(read_rgb(&named_jpg).unwrap(), img);
        // Content that is no image fails with one message whatever the name says.
        let msgs: Vec<String> = ["a.png", "a.jpg", "a.txt"]
            .iter()
            .map(|n| {
                let p = dir.path().join(n);
                std::fs::write(&p, b"# timestamp filename\n").unwrap();
                let e = read_rgb(&p).unwrap_err().to_string();
                assert_eq!(image_size(&p).unwrap_err().to_string(), e);
                e.replace(&p.display().to_string(), "FILE")
            })
            .collect();
        assert!(msgs.iter().all(|m| m == &msgs[0]), "{msgs:?}");
        assert!(msgs[0].contains("neither PNG nor JPEG"), "{}", msgs[0]);
        // A truncated PNG names the file.
        let full = dir.path().join("full.png");
        write_rgb(&full, &img).unwrap();
        let bytes = std::fs::read(&full).unwrap();
        let cut = dir.path().join("cut.png");
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let e = read_rgb(&cut).unwrap_err().to_string();
        assert!(e.contains("cut.png"), "{e}");
        // 16-bit images are not grey frames.
        let d16 = dir.path().join("d16.png");
        write_gray16(&d16, &Gray16Image::new(4, 4)).unwrap();
        assert!(read_gray(&d16).unwrap_err().to_string().contains("8-bit"));
    }

    #[test]
    fn prob_png_quantisation_matches_the_reference() {
        // In f32, 1 − 0.998 = 0.0019999743, so 0.998 stores 1 (truncation, as in numpy).
        let ps = [0.0f32, 0.1, 0.1000001, 0.5, 0.998, 0.9991, 1.0, -0.5, 1.5];
        let prob = ProbMap::from_fn(ps.len() as u32, 1, |x, _| Luma([ps[x as usize]]));
        let stored: Vec<u16> = prob_to_stored(&prob).pixels().map(|p| p[0]).collect();
        assert_eq!(stored, vec![1000, 900, 899, 500, 1, 0, 0, 1000, 0]);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("1.png");
        write_prob_png(&p, &prob).unwrap();
        let back = read_prob_png(&p).unwrap();
        assert_eq!(back.get_pixel(0, 0)[0], 0.0);
        assert!((back.get_pixel(3, 0)[0] - 0.5).abs() < 1e-6);
        assert_eq!(back.get_pixel(6, 0)[0], 1.0);
        let nan = ProbMap::from_pixel(2, 2, Luma([f32::NAN]));
        let e = write_prob_png(&p, &nan).unwrap_err().to_string();
        assert!(e.contains("NaN"), "{e}");
        write_gray16(&p, &Gray16Image::from_pixel(2, 2, Luma([1001]))).unwrap();
        let e = read_prob_png(&p).unwrap_err().to_string();
        assert!(e.contains("1.png") && e.contains("1001"), "{e}");
    }

    #[test]
    fn prob_paths_follow_the_rgb_name() {
        let seq = Path::new("/seq");
        assert_eq!(
            prob_png_path(seq, Path::new("rgb/1341846434.710184.png")),
            Path::new("/seq/prob/1341846434.710184.png")
        );
        assert_eq!(
            prob_pfm_path(seq, Path::new("/seq/rgb/12.png")),
            Path::new("/seq/prob/12.pfm")
        );
    }

    #[test]
    fn pfm_is_lossless_and_bad_pfm_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.pfm");
        let prob = ProbMap::from_fn(5, 3, |x, y| Luma([(x * 3 + y) as f32 / 15.0 + 1e-7]));
        write_prob_pfm(&p, &prob).unwrap();
        assert_eq!(read_prob_pfm(&p).unwrap(), prob);
        let bytes = std::fs::read(&p).unwrap();
        assert!(bytes.starts_with(b"Pf\n5 3\n-1.0\n"));
        // First stored row is the bottom image row.
        let first = f32::from_le_bytes(bytes[12..16].try_into().unwrap());
        assert_eq!(first, prob.get_pixel(0, 2)[0]);
        std::fs::write(&p, &bytes[..bytes.len() - 1]).unwrap();
        let e = read_pfm(&p).unwrap_err().to_string();
        assert!(e.contains("p.pfm") && e.contains("data bytes"), "{e}");
        for bad in [
            &b"PF\n1 1\n-1\n"[..],
            b"Pf\n1\n-1\n",
            b"Pf\n1 1\n0\n",
            b"Pf",
            b"",
        ] {
            std::fs::write(&p, bad).unwrap();
            let e = read_pfm(&p).unwrap_err().to_string();
            assert!(e.contains("p.pfm"), "{e}");
        }
        let big = ProbMap::from_pixel(1, 1, Luma([2.0]));
        write_pfm(&p, &big).unwrap();
        assert!(
            read_prob_pfm(&p)
                .unwrap_err()
                .to_string()
                .contains("outside")
        );
    }

    #[test]
    fn real_tum_frames_and_masks() {
        let Some(d) = data_dir() else { return };
        let seq = d.join("tum/rgbd_dataset_freiburg1_xyz");
        let (rgb, depth) = read_rgbd(
            seq.join("rgb/1305031102.175304.png"),
            seq.join("depth/1305031102.160407.png"),
            5000.0,
        )
        .unwrap();
        assert_eq!(rgb.dimensions(), (640, 480));
        let valid: Vec<f32> = depth.pixels().map(|p| p[0]).filter(|&v| v > 0.0).collect();
        assert!(valid.len() > 640 * 480 / 2, "{} valid depths", valid.len());
        let max = valid.iter().cloned().fold(0.0, f32::max);
        let min = valid.iter().cloned().fold(f32::INFINITY, f32::min);
        assert!(min > 0.3 && max < 10.0, "depth range {min}..{max}");
        let m = d.join("tum-walking-meta/rgbd_dataset_freiburg3_walking_xyz/sample_frames/mask_dynaslam_maskrcnn/1341846313.592026.png");
        // The sample masks follow DynaSLAM: values {0, 1}, 0 = person (checked visually:
        // two people at the desks); about 35 % of this frame is person.
        let mask = read_mask(&m).unwrap();
        assert!(mask.pixels().all(|p| p[0] <= 1));
        let person = mask_from_dynaslam(&mask);
        let on = person.pixels().filter(|p| p[0] == 255).count();
        assert!(
            on > 640 * 480 / 4 && on < 640 * 480 / 2,
            "{on} person pixels"
        );
        assert_eq!(on, mask.pixels().filter(|p| p[0] == 0).count());
        // An rgb image is not a mask.
        assert!(read_mask(seq.join("rgb/1305031102.175304.png")).is_err());
    }
}
