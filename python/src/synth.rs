//! Synthetic data: the `synth` presets rendered in memory or written as a sequence folder,
//! and the augmentation of real sequences with virtual movers.

use std::path::PathBuf;

use dynapix::synthetic::{Realism, SynthOptions};
use pyo3::prelude::*;

use crate::arrays;
use crate::camera::Camera;
use crate::errors::{compute, guard};

/// One rendered synthetic frame: ``t``, ``rgb`` (H×W×3 uint8), ``depth`` (H×W uint16, see
/// ``SyntheticSequence.depth_factor``), ``mask`` (H×W uint8: 0 static, 128 mover at rest,
/// 255 moving) and ``pose`` (4×4 camera-to-world ground truth).
#[pyclass(name = "SyntheticFrame", module = "dynapix._dynapix", frozen, get_all)]
pub struct SyntheticFrame {
    /// Index in the sequence.
    pub index: usize,
    /// Time (s).
    pub t: f64,
    /// Colour image with the movers, H×W×3 uint8.
    pub rgb: Py<PyAny>,
    /// Raw depth, H×W uint16 (0 = none).
    pub depth: Py<PyAny>,
    /// Motion mask, H×W uint8.
    pub mask: Py<PyAny>,
    /// Ground-truth camera-to-world pose, 4×4 float64.
    pub pose: Py<PyAny>,
}

#[pymethods]
impl SyntheticFrame {
    fn __repr__(&self) -> String {
        format!("SyntheticFrame(index={}, t={:.6})", self.index, self.t)
    }
}

/// A synthetic dynamic RGB-D sequence with exact ground truth (``dynapix synth``), rendered
/// frame by frame on demand: ``SyntheticSequence("walking_xyz", frames=60, seed=0,
/// width=320)``. Presets: see ``synth_presets()``. ``realism`` is ``clean``, ``kinect``
/// (default) or ``full``. Same preset and seed give the same bytes.
#[pyclass(name = "SyntheticSequence", module = "dynapix._dynapix", frozen)]
pub struct SyntheticSequence {
    inner: dynapix::synthetic::SyntheticSequence,
}

#[pymethods]
impl SyntheticSequence {
    #[new]
    #[pyo3(signature = (preset="walking_xyz", *, frames=300, seed=0, width=None, height=None, realism="kinect"))]
    fn new(
        py: Python<'_>,
        preset: &str,
        frames: usize,
        seed: u64,
        width: Option<u32>,
        height: Option<u32>,
        realism: &str,
    ) -> PyResult<Self> {
        let options = SynthOptions {
            preset: preset.to_string(),
            frames,
            seed,
            width,
            height,
            realism: guard(|| Realism::from_name(realism))?,
        };
        let inner = compute(py, move || {
            dynapix::synthetic::SyntheticSequence::new(&options)
        })?;
        Ok(Self { inner })
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// The camera of the sequence.
    #[getter]
    fn camera(&self) -> Camera {
        Camera {
            inner: self.inner.camera(),
        }
    }

    /// Raw depth units per metre (5000).
    #[getter]
    fn depth_factor(&self) -> f64 {
        self.inner.depth_factor()
    }

    /// Renders frame ``i`` (the GIL is released while it renders).
    fn frame(&self, py: Python<'_>, i: usize) -> PyResult<SyntheticFrame> {
        let f = compute(py, || self.inner.frame(i))?;
        let (w, h) = f.rgb.dimensions();
        Ok(SyntheticFrame {
            index: f.index,
            t: f.t,
            rgb: arrays::image_array(py, f.rgb.into_raw(), w, h, 3)?.unbind(),
            depth: arrays::image_array(py, f.depth.into_raw(), w, h, 0)?.unbind(),
            mask: arrays::image_array(py, f.mask.into_raw(), w, h, 0)?.unbind(),
            pose: arrays::pose_array(py, &f.pose_wc)?.into_any().unbind(),
        })
    }

    /// Writes the whole sequence into ``out_dir`` in the DynaPix layout (rgb, depth,
    /// background, depth_bg, mask, instance, TUM lists, ground truth, camera.yaml), the same
    /// bytes as ``dynapix synth --out``. Returns the folder.
    fn write(&self, py: Python<'_>, out_dir: PathBuf) -> PyResult<PathBuf> {
        let dir = out_dir.clone();
        compute(py, || self.inner.write(&dir, &mut |_| {}))?;
        Ok(out_dir)
    }

    fn __repr__(&self) -> String {
        let c = self.inner.camera();
        format!(
            "SyntheticSequence({} frames, {}×{})",
            self.inner.len(),
            c.settings.width,
            c.settings.height
        )
    }
}

/// The names of the synthetic presets.
#[pyfunction]
pub fn synth_presets() -> Vec<&'static str> {
    dynapix::synthetic::SynthOptions::preset_names()
}

/// Inserts ``objects`` flying virtual movers into the real sequence ``seq_dir`` (it needs
/// ``groundtruth.txt``) and writes the DynaPix layout (with masks) into ``out_dir``, at most
/// ``max_frames`` frames, like ``dynapix synth --augment``. Returns the frames written.
#[pyfunction]
#[pyo3(signature = (seq_dir, out_dir, *, seed=0, objects=3, max_frames=None))]
pub fn augment(
    py: Python<'_>,
    seq_dir: PathBuf,
    out_dir: PathBuf,
    seed: u64,
    objects: usize,
    max_frames: Option<usize>,
) -> PyResult<usize> {
    compute(py, move || {
        dynapix::synthetic::augment(&seq_dir, &out_dir, seed, objects, max_frames)
    })
}
