//! The online mode: `Online(camera, config)` takes frames as numpy arrays one at a time
//! (`push`) and returns each frame's result when it is known.

use std::sync::Mutex;

use dynapix::{OnlineDynaPix, RgbdFrame};
use numpy::PyArray1;
use numpy::prelude::*;
use pyo3::prelude::*;

use crate::arrays;
use crate::camera::{Camera, camera_arg};
use crate::config::config_arg;
use crate::errors::{compute, data, guard};

/// The result of one frame of the online mode.
#[pyclass(name = "FrameResult", module = "dynapix._dynapix", frozen)]
pub struct FrameResult {
    /// Index of the frame in push order (0-based).
    #[pyo3(get)]
    pub index: usize,
    /// Frame time (s).
    #[pyo3(get)]
    pub t: f64,
    /// ``tracked``, ``lost`` or ``not_initialized``.
    #[pyo3(get)]
    pub status: &'static str,
    /// The frame became a keyframe.
    #[pyo3(get)]
    pub keyframe: bool,
    /// Frames pushed after this one before its result came (the lookahead).
    #[pyo3(get)]
    pub latency_frames: usize,
    /// Mean motion probability P of the frame.
    #[pyo3(get)]
    pub mean_probability: f32,
    /// Milliseconds spent on the motion map.
    #[pyo3(get)]
    pub motion_ms: f64,
    /// Milliseconds spent on tracking (and the mapping run in this push).
    #[pyo3(get)]
    pub slam_ms: f64,
    /// The pose as the library reported it (exact, for the TUM writer).
    pub pose_wc: Option<dynapix_geometry::Se3>,
}

#[pymethods]
impl FrameResult {
    /// Camera-to-world pose as a 4×4 float64 array, or None when the frame was not tracked.
    #[getter]
    fn pose<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.pose_wc
            .as_ref()
            .map(|p| {
                Ok(PyArray1::from_vec(py, arrays::matrix(p).to_vec())
                    .reshape([4, 4])?
                    .into_any())
            })
            .transpose()
    }

    /// True when the frame has a pose.
    #[getter]
    fn tracked(&self) -> bool {
        self.pose_wc.is_some()
    }

    fn __repr__(&self) -> String {
        format!(
            "FrameResult(index={}, t={:.6}, status={:?}, keyframe={})",
            self.index, self.t, self.status, self.keyframe
        )
    }
}

impl From<dynapix::FrameResult> for FrameResult {
    fn from(r: dynapix::FrameResult) -> Self {
        Self {
            index: r.index,
            t: r.t,
            status: r.status.as_str(),
            keyframe: r.keyframe,
            latency_frames: r.latency_frames,
            mean_probability: r.mean_probability,
            motion_ms: r.motion_ms,
            slam_ms: r.slam_ms,
            pose_wc: r.pose_wc,
        }
    }
}

/// DynaPix online: frames are pushed one at a time, the motion of each frame comes from past
/// frames (plus ``lookahead`` later ones), memory stays bounded by the configured window.
///
/// ``Online(camera, config=None, lookahead=None)``: ``camera`` is a ``Camera``, a preset
/// name or a settings file; ``config`` a ``Config``, dict or file. ``push(t, rgb, depth)``
/// takes rgb as H×W×3 uint8 and depth as H×W uint16 (raw, divided by the camera's depth
/// factor) or float32 metres, of the camera's size; ``finish()`` returns the frames still
/// waiting. The GIL is released while a frame is processed.
#[pyclass(name = "Online", module = "dynapix._dynapix")]
pub struct Online {
    inner: Mutex<Option<OnlineDynaPix>>,
    camera: dynapix::Camera,
    needs_masks: bool,
    pushed: usize,
    finished: bool,
    last_t: Option<f64>,
}

impl Online {
    fn size(&self) -> (u32, u32) {
        (self.camera.settings.width, self.camera.settings.height)
    }

    /// A frame of the library from numpy arrays (checked; one copy each).
    fn frame(
        &self,
        t: f64,
        rgb: &Bound<'_, PyAny>,
        depth: &Bound<'_, PyAny>,
        mask: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<RgbdFrame> {
        let size = self.size();
        let rgb = arrays::rgb_image(rgb, size)?;
        let depth = arrays::depth_image(depth, size, self.camera.settings.depth_map_factor)?;
        let mask = mask
            .filter(|m| !m.is_none())
            .map(|m| arrays::mask_image(m, size))
            .transpose()?;
        if self.needs_masks && mask.is_none() {
            return Err(data(
                "the dynapix+ method needs a mask with every frame (mask=...)",
            ));
        }
        Ok(RgbdFrame {
            t,
            rgb,
            depth,
            mask,
        })
    }
}

#[pymethods]
impl Online {
    #[new]
    #[pyo3(signature = (camera, config=None, *, lookahead=None))]
    fn new(
        py: Python<'_>,
        camera: &Bound<'_, PyAny>,
        config: Option<&Bound<'_, PyAny>>,
        lookahead: Option<usize>,
    ) -> PyResult<Self> {
        let camera = camera_arg(camera)?;
        let mut config = config_arg(config)?;
        if let Some(k) = lookahead {
            config.online.lookahead = k;
        }
        let needs_masks = config.method.needs_masks();
        let cam = camera.clone();
        let inner = compute(py, move || OnlineDynaPix::new(&cam, &config))?;
        Ok(Self {
            inner: Mutex::new(Some(inner)),
            camera,
            needs_masks,
            pushed: 0,
            finished: false,
            last_t: None,
        })
    }

    /// Pushes the frame at time ``t`` (s, increasing). Returns the ``FrameResult`` of the
    /// frame ``lookahead`` frames back (this frame without lookahead), or None while the
    /// lookahead fills. ``mask`` (H×W uint8, non-zero = dynamic class) is required by
    /// ``dynapix+``. Raises ``DataError`` for a wrong dtype, shape or size or a time that
    /// does not increase.
    ///
    /// ``next``, the frame that will be pushed after this one as ``(t, rgb, depth)`` (or
    /// ``(t, rgb, depth, mask)``), when the caller already has it (frames read from files, a
    /// camera queue): the part of its motion map that needs no pose is then computed beside
    /// this frame's tracking, as ``dynapix run --online`` does. The results are the same with
    /// or without it.
    #[pyo3(signature = (t, rgb, depth, mask=None, *, next=None))]
    fn push(
        &mut self,
        py: Python<'_>,
        t: f64,
        rgb: &Bound<'_, PyAny>,
        depth: &Bound<'_, PyAny>,
        mask: Option<&Bound<'_, PyAny>>,
        next: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Option<FrameResult>> {
        if !t.is_finite() {
            return Err(data(format!("t must be a finite time in seconds, got {t}")));
        }
        if let Some(last) = self.last_t.filter(|&last| t <= last) {
            return Err(data(format!(
                "frame {} (t = {t:.6}) is not after the previous frame (t = {last:.6})",
                self.pushed
            )));
        }
        let frame = self.frame(t, rgb, depth, mask)?;
        let next = match next.filter(|n| !n.is_none()) {
            None => None,
            Some(n) => {
                let items: Vec<Bound<'_, PyAny>> = n.extract().map_err(|_| {
                    data("next must be a tuple (t, rgb, depth) or (t, rgb, depth, mask)")
                })?;
                if !(3..=4).contains(&items.len()) {
                    return Err(data(
                        "next must be a tuple (t, rgb, depth) or (t, rgb, depth, mask)",
                    ));
                }
                let nt: f64 = items[0]
                    .extract()
                    .map_err(|_| data("next: t must be a number"))?;
                Some(self.frame(nt, &items[1], &items[2], items.get(3))?)
            }
        };
        let mut guard_ = self
            .inner
            .lock()
            .map_err(|_| data("the online system is unusable after an internal error"))?;
        let online = guard_
            .as_mut()
            .filter(|_| !self.finished)
            .ok_or_else(|| data("finish() was called: make a new Online to push more frames"))?;
        let r = compute(py, || online.push_before(frame, next.as_ref()))?;
        self.pushed += 1;
        self.last_t = Some(t);
        Ok(r.map(FrameResult::from))
    }

    /// Processes the frames still waiting for their lookahead and the last keyframe's
    /// mapping; returns their results in order. No frame can be pushed afterwards.
    fn finish(&mut self, py: Python<'_>) -> PyResult<Vec<FrameResult>> {
        let mut g = self
            .inner
            .lock()
            .map_err(|_| data("the online system is unusable after an internal error"))?;
        let Some(online) = g.as_mut() else {
            return Ok(Vec::new());
        };
        let out = compute(py, || online.finish())?;
        self.finished = true;
        Ok(out.into_iter().map(FrameResult::from).collect())
    }

    /// ``(timestamps, poses)`` of the system's current estimate of every tracked frame
    /// (refined by bundle adjustment and loop closing since it was reported), what
    /// ``dynapix run --online`` writes to ``trajectory_refined.txt``.
    fn refined_trajectory<'py>(&self, py: Python<'py>) -> PyResult<arrays::Stamped<'py>> {
        let g = self
            .inner
            .lock()
            .map_err(|_| data("the online system is unusable after an internal error"))?;
        let online = g.as_ref().ok_or_else(|| data("no online system"))?;
        let entries = guard(|| Ok(online.system().trajectory()))?;
        let tracked: Vec<_> = entries
            .into_iter()
            .filter_map(|e| e.pose_wc.map(|p| (e.timestamp, p)))
            .collect();
        Ok((
            arrays::vec_array(py, tracked.iter().map(|p| p.0).collect()),
            arrays::poses_array(py, tracked.into_iter().map(|p| p.1))?,
        ))
    }

    /// The camera frames must match.
    #[getter]
    fn camera(&self) -> Camera {
        Camera {
            inner: self.camera.clone(),
        }
    }

    /// Frames pushed so far.
    #[getter]
    fn frames_pushed(&self) -> usize {
        self.pushed
    }

    /// Keyframes in the map now.
    #[getter]
    fn keyframes(&self) -> PyResult<usize> {
        let g = self.inner.lock().map_err(|_| data("unusable"))?;
        Ok(g.as_ref().map_or(0, |o| o.system().map().num_keyframes()))
    }

    /// Map points in the map now.
    #[getter]
    fn map_points(&self) -> PyResult<usize> {
        let g = self.inner.lock().map_err(|_| data("unusable"))?;
        Ok(g.as_ref().map_or(0, |o| o.system().map().num_points()))
    }

    /// The latency in frames: a frame's result comes when this many later frames arrived.
    #[getter]
    fn lookahead(&self) -> PyResult<usize> {
        let g = self.inner.lock().map_err(|_| data("unusable"))?;
        Ok(g.as_ref().map_or(0, |o| o.lookahead()))
    }

    fn __repr__(&self) -> String {
        format!(
            "Online({}×{}, {} frames pushed)",
            self.camera.settings.width, self.camera.settings.height, self.pushed
        )
    }
}
