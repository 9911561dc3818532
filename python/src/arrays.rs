//! numpy ↔ library types: images in (checked dtype, shape and size, one copy into the
//! library's owned buffer), poses and images out (the library's buffers handed to numpy
//! without a further copy).

use dynapix_geometry::Se3;
use image::{GrayImage, ImageBuffer, Luma, RgbImage};
use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion};
use numpy::prelude::*;
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayDyn, PyUntypedArray};
use pyo3::prelude::*;

use crate::errors::data;

/// A trajectory as arrays: timestamps (N) and camera-to-world poses (N×4×4).
pub type Stamped<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray3<f64>>);

/// Depth in metres as the library takes it.
pub type DepthImage = ImageBuffer<Luma<f32>, Vec<f32>>;

/// The numpy array behind `obj`, or a `DataError` naming `what`.
fn untyped<'a, 'py>(
    obj: &'a Bound<'py, PyAny>,
    what: &str,
) -> PyResult<&'a Bound<'py, PyUntypedArray>> {
    obj.cast::<PyUntypedArray>().map_err(|_| {
        let ty = obj
            .get_type()
            .name()
            .map(|n| n.to_string())
            .unwrap_or_else(|_| "?".into());
        data(format!("{what} must be a numpy array, got {ty}"))
    })
}

/// `(dtype, shape)` of an array for messages.
fn describe(a: &Bound<'_, PyUntypedArray>) -> String {
    format!("{} array of shape {:?}", a.dtype(), a.shape())
}

/// The elements of an array of `T` in C order: one copy (a `memcpy` when contiguous).
fn elements<T: numpy::Element + Copy>(a: &Bound<'_, PyUntypedArray>) -> PyResult<Vec<T>> {
    let typed = a
        .cast::<PyArrayDyn<T>>()
        .map_err(|_| data(format!("unexpected {}", describe(a))))?;
    let ro = typed
        .try_readonly()
        .map_err(|e| data(format!("array is being written elsewhere: {e}")))?;
    Ok(match ro.as_slice() {
        Ok(s) => s.to_vec(),
        Err(_) => ro.as_array().iter().copied().collect(),
    })
}

/// Checks that `a` has dtype `T` and the shape `expect` (None = any size on that axis).
fn check<T: numpy::Element>(
    a: &Bound<'_, PyUntypedArray>,
    what: &str,
    layout: &str,
    expect: &[Option<usize>],
) -> PyResult<()> {
    let py = a.py();
    let shape = a.shape();
    let ok_dtype = a.dtype().is_equiv_to(&numpy::dtype::<T>(py));
    let ok_shape = shape.len() == expect.len()
        && shape
            .iter()
            .zip(expect)
            .all(|(s, e)| e.is_none_or(|e| e == *s));
    if ok_dtype && ok_shape {
        Ok(())
    } else {
        Err(data(format!(
            "{what} must be a {layout} {} array, got {}",
            numpy::dtype::<T>(py),
            describe(a)
        )))
    }
}

/// Checks an image's size against the camera's.
fn check_size(what: &str, shape: &[usize], size: (u32, u32)) -> PyResult<()> {
    if shape[0] != size.1 as usize || shape[1] != size.0 as usize {
        return Err(data(format!(
            "{what} is {}×{} (H×W = {}×{}), the camera is {}×{}",
            shape[1], shape[0], shape[0], shape[1], size.0, size.1
        )));
    }
    Ok(())
}

/// An H×W×3 uint8 colour image of the camera's size.
pub fn rgb_image(obj: &Bound<'_, PyAny>, size: (u32, u32)) -> PyResult<RgbImage> {
    let a = untyped(obj, "rgb")?;
    check::<u8>(a, "rgb", "H×W×3", &[None, None, Some(3)])?;
    check_size("rgb", a.shape(), size)?;
    let v = elements::<u8>(a)?;
    RgbImage::from_raw(size.0, size.1, v).ok_or_else(|| data("rgb: buffer size mismatch"))
}

/// An H×W depth image: uint16 raw (divided by `depth_factor` like the sequence reader) or
/// float32 metres.
pub fn depth_image(
    obj: &Bound<'_, PyAny>,
    size: (u32, u32),
    depth_factor: f64,
) -> PyResult<DepthImage> {
    let a = untyped(obj, "depth")?;
    let py = obj.py();
    let metres = if a.dtype().is_equiv_to(&numpy::dtype::<u16>(py)) {
        check::<u16>(a, "depth", "H×W", &[None, None])?;
        check_size("depth", a.shape(), size)?;
        // The reader's conversion, bit for bit: value · (1 / factor) in f32.
        let scale = 1.0f32 / depth_factor as f32;
        elements::<u16>(a)?
            .into_iter()
            .map(|v| v as f32 * scale)
            .collect()
    } else if a.dtype().is_equiv_to(&numpy::dtype::<f32>(py)) {
        check::<f32>(a, "depth", "H×W", &[None, None])?;
        check_size("depth", a.shape(), size)?;
        elements::<f32>(a)?
    } else {
        return Err(data(format!(
            "depth must be an H×W uint16 (raw, divided by the camera's depth factor) or \
             float32 (metres) array, got {}",
            describe(a)
        )));
    };
    DepthImage::from_raw(size.0, size.1, metres).ok_or_else(|| data("depth: buffer size mismatch"))
}

/// An H×W uint8 mask (non-zero = dynamic).
pub fn mask_image(obj: &Bound<'_, PyAny>, size: (u32, u32)) -> PyResult<GrayImage> {
    let a = untyped(obj, "mask")?;
    check::<u8>(a, "mask", "H×W", &[None, None])?;
    check_size("mask", a.shape(), size)?;
    GrayImage::from_raw(size.0, size.1, elements::<u8>(a)?)
        .ok_or_else(|| data("mask: buffer size mismatch"))
}

/// The 4×4 matrix of a pose, row-major.
pub fn matrix(p: &Se3) -> [f64; 16] {
    let m = p.to_homogeneous();
    let mut out = [0.0; 16];
    for r in 0..4 {
        for c in 0..4 {
            out[r * 4 + c] = m[(r, c)];
        }
    }
    out
}

/// N poses as an N×4×4 float64 array.
pub fn poses_array<'py>(
    py: Python<'py>,
    poses: impl Iterator<Item = Se3>,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let mut v = Vec::new();
    for p in poses {
        v.extend_from_slice(&matrix(&p));
    }
    let n = v.len() / 16;
    PyArray1::from_vec(py, v).reshape([n, 4, 4])
}

/// One pose as a 4×4 float64 array.
pub fn pose_array<'py>(py: Python<'py>, p: &Se3) -> PyResult<Bound<'py, PyArray2<f64>>> {
    PyArray1::from_vec(py, matrix(p).to_vec()).reshape([4, 4])
}

/// A float vector as a 1-D array.
pub fn vec_array(py: Python<'_>, v: Vec<f64>) -> Bound<'_, PyArray1<f64>> {
    PyArray1::from_vec(py, v)
}

/// An image buffer handed to numpy as H×W×C (C = 0: H×W) without a copy.
pub fn image_array<'py, T: numpy::Element>(
    py: Python<'py>,
    raw: Vec<T>,
    width: u32,
    height: u32,
    channels: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let a = PyArray1::from_vec(py, raw);
    let (w, h) = (width as usize, height as usize);
    Ok(if channels == 0 {
        a.reshape([h, w])?.into_any()
    } else {
        a.reshape([h, w, channels])?.into_any()
    })
}

/// A pose from a 4×4 matrix (row-major); the rotation block must be a rotation.
fn pose_from_matrix(m: &[f64], row: usize) -> PyResult<Se3> {
    let r = Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
    let err = (r.transpose() * r - Matrix3::identity()).abs().max();
    if !(err < 1e-6 && r.determinant() > 0.0) || m.iter().any(|x| !x.is_finite()) {
        return Err(data(format!(
            "pose {row}: the upper-left 3×3 block is not a rotation (|RᵀR − I| = {err:.2e})"
        )));
    }
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    Ok(Se3::from_parts(Translation3::new(m[3], m[7], m[11]), q))
}

/// Stamped poses from `(timestamps, poses)` (N and N×4×4) or an N×8 TUM array
/// (`t x y z qx qy qz qw`).
pub fn stamped_poses(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<(f64, Se3)>> {
    if let Ok(a) = obj.cast::<PyUntypedArray>() {
        check::<f64>(a, what, "N×8 (t x y z qx qy qz qw)", &[None, Some(8)])?;
        let v = elements::<f64>(a)?;
        return v
            .chunks_exact(8)
            .enumerate()
            .map(|(i, r)| {
                let q = nalgebra::Quaternion::new(r[7], r[4], r[5], r[6]);
                if r.iter().any(|x| !x.is_finite()) || q.norm() <= 1e-9 {
                    return Err(data(format!("{what} row {i}: not a pose")));
                }
                Ok((
                    r[0],
                    Se3::from_parts(
                        Translation3::new(r[1], r[2], r[3]),
                        UnitQuaternion::from_quaternion(q),
                    ),
                ))
            })
            .collect();
    }
    let (t, p): (Bound<'_, PyAny>, Bound<'_, PyAny>) = obj.extract().map_err(|_| {
        data(format!(
            "{what} must be a path, a (timestamps, poses) pair of N and N×4×4 float64 arrays, \
             or an N×8 float64 array"
        ))
    })?;
    let ta = untyped(&t, &format!("{what} timestamps"))?;
    check::<f64>(ta, &format!("{what} timestamps"), "N", &[None])?;
    let n = ta.shape()[0];
    let pa = untyped(&p, &format!("{what} poses"))?;
    check::<f64>(
        pa,
        &format!("{what} poses"),
        "N×4×4",
        &[Some(n), Some(4), Some(4)],
    )?;
    let ts = elements::<f64>(ta)?;
    let ms = elements::<f64>(pa)?;
    ts.into_iter()
        .zip(ms.chunks_exact(16))
        .enumerate()
        .map(|(i, (t, m))| Ok((t, pose_from_matrix(m, i)?)))
        .collect()
}

/// A float64 vector (frame stamps).
pub fn stamps(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<f64>> {
    let a = untyped(obj, what)?;
    check::<f64>(a, what, "N", &[None])?;
    elements::<f64>(a)
}
