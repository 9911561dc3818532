//! `Camera`: intrinsics with distortion, depth factor and ORB settings — a preset, an
//! ORB-SLAM2 settings file, a sequence folder's own camera, or values given in code.

use std::path::PathBuf;

use dynapix::Settings;
use dynapix::{Camera as LibCamera, CameraChoice, CameraPreset, CameraSource, SequenceConfig};
use pyo3::prelude::*;
use pyo3::types::PyString;

use crate::config::to_python;
use crate::errors::{compute, config, guard};

/// An RGB-D camera: pinhole intrinsics with radial-tangential distortion
/// (k1 k2 p1 p2 k3), image size, depth factor (raw units per metre), stereo baseline ``bf``,
/// close/far threshold and ORB extractor settings.
///
/// Made by ``Camera.preset("tum1")`` (``tum1 tum2 tum3 grade bonn``),
/// ``Camera.from_settings("cam.yaml")`` (ORB-SLAM2 settings file), ``Camera.from_sequence(dir)``
/// (the folder's ``camera.yaml`` or the preset its name implies) or
/// ``Camera(fx, fy, cx, cy, width, height, ...)``.
#[pyclass(name = "Camera", module = "dynapix._dynapix", frozen)]
#[derive(Clone)]
pub struct Camera {
    /// The library's camera.
    pub inner: LibCamera,
}

fn preset_named(name: &str) -> PyResult<CameraPreset> {
    CameraPreset::ALL
        .into_iter()
        .find(|p| p.name().eq_ignore_ascii_case(name))
        .ok_or_else(|| {
            let names: Vec<&str> = CameraPreset::ALL.iter().map(|p| p.name()).collect();
            config(format!(
                "unknown camera preset {name:?} (expected one of {})",
                names.join(", ")
            ))
        })
}

#[pymethods]
impl Camera {
    /// A camera from values; unnamed values take the TUM fr3 settings (no distortion, 30 Hz,
    /// ``bf`` 40, ``th_depth`` 40, 1000 ORB features).
    #[new]
    #[pyo3(signature = (fx, fy, cx, cy, width, height, *, dist=None, depth_factor=5000.0, fps=30.0, bf=40.0, th_depth=40.0, n_features=1000))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        width: u32,
        height: u32,
        dist: Option<[f64; 5]>,
        depth_factor: f64,
        fps: f64,
        bf: f64,
        th_depth: f64,
        n_features: usize,
    ) -> PyResult<Self> {
        let mut s = Settings::tum3();
        (s.fx, s.fy, s.cx, s.cy, s.width, s.height) = (fx, fy, cx, cy, width, height);
        s.dist = dist.unwrap_or([0.0; 5]);
        (s.depth_map_factor, s.fps, s.bf, s.th_depth) = (depth_factor, fps, bf, th_depth);
        s.orb.n_features = n_features;
        s.validate(std::path::Path::new("Camera(...)"))
            .map_err(|e| config(e.to_string()))?;
        Ok(Self {
            inner: LibCamera {
                settings: s,
                source: CameraSource::Preset {
                    name: "python".into(),
                },
                size_from_frames: false,
            },
        })
    }

    /// A preset: ``tum1``, ``tum2``, ``tum3``, ``grade`` or ``bonn``.
    #[staticmethod]
    fn preset(name: &str) -> PyResult<Self> {
        let p = preset_named(name)?;
        Ok(Self {
            inner: LibCamera {
                settings: p.settings(),
                source: CameraSource::Preset {
                    name: p.name().into(),
                },
                size_from_frames: false,
            },
        })
    }

    /// The camera of an ORB-SLAM2 settings YAML (``Camera.fx`` … ``DepthMapFactor``,
    /// ``ORBextractor.*``); missing keys take the TUM fr3 values.
    #[staticmethod]
    fn from_settings(path: PathBuf) -> PyResult<Self> {
        let (settings, missing) = guard(|| Ok(Settings::read_lenient(&path)?))?;
        Ok(Self {
            inner: LibCamera {
                settings,
                source: CameraSource::SettingsFile {
                    path,
                    missing_keys: missing.iter().map(|k| k.to_string()).collect(),
                },
                size_from_frames: false,
            },
        })
    }

    /// The camera a run on the sequence folder ``seq_dir`` uses by default (its
    /// ``camera.yaml``, else the preset its name implies; the image size of the first frame
    /// when the settings state none).
    #[staticmethod]
    fn from_sequence(py: Python<'_>, seq_dir: PathBuf) -> PyResult<Self> {
        let input = compute(py, || {
            dynapix::Input::open(
                &seq_dir,
                &SequenceConfig::default(),
                &CameraChoice::Sequence,
            )
        })?;
        Ok(Self {
            inner: input.camera,
        })
    }

    /// Focal length x (px).
    #[getter]
    fn fx(&self) -> f64 {
        self.inner.settings.fx
    }
    /// Focal length y (px).
    #[getter]
    fn fy(&self) -> f64 {
        self.inner.settings.fy
    }
    /// Principal point x (px).
    #[getter]
    fn cx(&self) -> f64 {
        self.inner.settings.cx
    }
    /// Principal point y (px).
    #[getter]
    fn cy(&self) -> f64 {
        self.inner.settings.cy
    }
    /// Image width (px).
    #[getter]
    fn width(&self) -> u32 {
        self.inner.settings.width
    }
    /// Image height (px).
    #[getter]
    fn height(&self) -> u32 {
        self.inner.settings.height
    }
    /// Distortion ``(k1, k2, p1, p2, k3)``.
    #[getter]
    fn dist(&self) -> [f64; 5] {
        self.inner.settings.dist
    }
    /// Raw depth units per metre (5000 for TUM).
    #[getter]
    fn depth_factor(&self) -> f64 {
        self.inner.settings.depth_map_factor
    }
    /// Frame rate (Hz).
    #[getter]
    fn fps(&self) -> f64 {
        self.inner.settings.fps
    }
    /// Stereo baseline times fx (``Camera.bf``).
    #[getter]
    fn bf(&self) -> f64 {
        self.inner.settings.bf
    }
    /// Close/far threshold in baselines (``ThDepth``).
    #[getter]
    fn th_depth(&self) -> f64 {
        self.inner.settings.th_depth
    }

    /// Everything a run records about the camera (source, pinhole, ``bf``, ORB settings).
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let v = serde_json::to_value(self.inner.record())
            .map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string()))?;
        to_python(py, &v)
    }

    /// The ORB-SLAM2 settings YAML text of the camera.
    fn to_yaml(&self) -> String {
        self.inner.settings.to_yaml_string()
    }

    fn __eq__(&self, other: &Bound<'_, PyAny>) -> bool {
        other
            .cast::<Camera>()
            .is_ok_and(|o| o.get().inner.settings == self.inner.settings)
    }

    fn __repr__(&self) -> String {
        let s = &self.inner.settings;
        format!(
            "Camera({}×{}, fx={}, fy={}, cx={}, cy={}, depth_factor={})",
            s.width, s.height, s.fx, s.fy, s.cx, s.cy, s.depth_map_factor
        )
    }
}

/// The camera choice of an optional argument: a `Camera`, a preset name, a settings file
/// path, or None (the sequence's own).
pub fn choice_arg(obj: Option<&Bound<'_, PyAny>>) -> PyResult<(CameraChoice, Option<LibCamera>)> {
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return Ok((CameraChoice::Sequence, None));
    };
    if let Ok(c) = obj.cast::<Camera>() {
        return Ok((CameraChoice::Sequence, Some(c.get().inner.clone())));
    }
    if obj.is_instance_of::<PyString>() || obj.hasattr("__fspath__")? {
        let p: PathBuf = obj.extract()?;
        let s = p.to_string_lossy();
        if let Some(preset) = CameraPreset::ALL
            .into_iter()
            .find(|x| x.name().eq_ignore_ascii_case(&s))
        {
            return Ok((CameraChoice::Preset(preset), None));
        }
        if p.is_file() || s.ends_with(".yaml") || s.ends_with(".yml") {
            return Ok((CameraChoice::Settings(p), None));
        }
        return Err(preset_named(&s).err().unwrap_or_else(|| config("camera")));
    }
    Err(config(format!(
        "camera must be a Camera, a preset name or a settings file path, got {}",
        obj.get_type().name()?
    )))
}

/// The camera of an argument that must name one (online mode): a `Camera`, a preset name or
/// a settings file.
pub fn camera_arg(obj: &Bound<'_, PyAny>) -> PyResult<LibCamera> {
    match choice_arg(Some(obj))? {
        (_, Some(c)) => Ok(c),
        (CameraChoice::Preset(p), None) => Ok(Camera::preset(p.name())?.inner),
        (CameraChoice::Settings(p), None) => Ok(Camera::from_settings(p)?.inner),
        (CameraChoice::Sequence, None) => Err(config("a camera is required")),
    }
}
