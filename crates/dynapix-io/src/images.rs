//! Image files: 8-bit colour PNG/JPEG, 16-bit depth PNG (converted to metres), 8-bit masks,
//! and PFM for lossless float maps (spec §2.1, §5). Motion-probability files are read and
//! written by [`crate::weights`], on top of these.
//!
//! PFM ([`write_pfm`], [`read_pfm`]) is a tiny standard format (`Pf\n<w> <h>\n<scale>\n`
//! then little-endian `f32` rows from bottom to top when scale < 0) read by OpenCV, numpy
//! scripts and most image tools.

use std::path::Path;

use image::codecs::png::PngEncoder;
use image::{DynamicImage, GrayImage, ImageBuffer, Luma, RgbImage};

use crate::atomic::{write_atomic, write_atomic_with};
use crate::error::{IoError, Result};

/// A depth map in metres; 0 means "no depth".
pub type DepthImage = ImageBuffer<Luma<f32>, Vec<f32>>;
/// A per-pixel motion probability map P ∈ [0, 1] (0 = static, 1 = moving).
pub type ProbMap = ImageBuffer<Luma<f32>, Vec<f32>>;
/// A raw 16-bit single-channel image (depth in sensor units, stored probability weights).
pub type Gray16Image = ImageBuffer<Luma<u16>, Vec<u16>>;

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

pub(crate) fn decode(path: &Path) -> Result<DynamicImage> {
    decode_image(path)
}

pub(crate) fn describe(img: &DynamicImage) -> String {
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
