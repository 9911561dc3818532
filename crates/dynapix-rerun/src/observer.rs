//! [`RerunObserver`]: the run's passes and frames, logged to a Rerun recording.

use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use dynapix::{FrameView, PassInfo, PassOutput, RunObserver, Trajectory};
use dynapix_eval::{AteParams, ate};
use dynapix_io::FrameStatus;
use nalgebra::Isometry3;
use rerun::RecordingStream;

use crate::{Error, Result, colors, layout};

/// Where a recording goes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Target {
    /// A viewer on this machine: connects to one listening on 127.0.0.1 (port 9876), or
    /// starts `rerun` (from `pip install rerun-sdk==0.36.*`) when none is.
    Spawn,
    /// A viewer at this gRPC address (`rerun+http://127.0.0.1:9876/proxy`).
    Connect(String),
    /// An `.rrd` file (open it later with `rerun FILE.rrd`).
    Save(PathBuf),
}

impl std::fmt::Display for Target {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Target::Spawn => write!(f, "a viewer on 127.0.0.1"),
            Target::Connect(url) => write!(f, "the viewer at {url}"),
            Target::Save(p) => write!(f, "{}", p.display()),
        }
    }
}

/// What is logged and how often.
#[derive(Clone, Debug, PartialEq)]
pub struct RerunParams {
    /// Log the colour image, P and depth of every n-th frame (1: all).
    pub images_every: usize,
    /// Log the images in every pass; by default only in the run's last pass
    /// ([`dynapix::PassInfo::last`]), the earlier passes log poses, trajectories, map,
    /// keypoints, events and scalars.
    pub images_in_all_passes: bool,
    /// JPEG quality of the colour images (1–100).
    pub jpeg_quality: u8,
    /// The depth image is logged at 1/`depth_downscale` of its size.
    pub depth_downscale: u32,
    /// The trajectories, the ATE so far, the map points and the removed points are logged
    /// every n-th frame (and at every keyframe and at the end of a pass).
    pub trajectory_every: usize,
}

impl Default for RerunParams {
    fn default() -> Self {
        Self {
            images_every: 1,
            images_in_all_passes: false,
            jpeg_quality: 80,
            depth_downscale: 2,
            trajectory_every: 5,
        }
    }
}

impl RerunParams {
    /// Whether `pass` logs images.
    pub fn images_in(&self, pass: &PassInfo<'_>) -> bool {
        pass.last || self.images_in_all_passes
    }
}

/// The state of the pass being logged.
#[derive(Default)]
struct PassState {
    timeline: String,
    /// Estimated camera-to-world poses so far.
    estimate: Vec<(f64, Isometry3<f64>)>,
    /// Ground-truth poses of the sequence.
    ground_truth: Vec<(f64, Isometry3<f64>)>,
    /// Points removed as moving so far.
    removed: Vec<[f32; 3]>,
    /// Points removed since `removed` was last logged.
    removed_new: bool,
    /// Scratch buffer of the P overlay.
    overlay: Vec<u8>,
    /// This pass logs images ([`RerunParams::images_in`]).
    images: bool,
    /// This pass is the run's last.
    last: bool,
    /// Frames seen.
    frames: usize,
}

/// Logs a run to Rerun (see the crate documentation for what goes where).
pub struct RerunObserver {
    rec: RecordingStream,
    target: String,
    params: RerunParams,
    state: Mutex<PassState>,
    /// The static entities were logged ([`RerunObserver::log_statics`]).
    statics_sent: AtomicBool,
}

impl RerunObserver {
    /// A recording named `name` (e.g. the sequence) sent to `target`.
    pub fn open(target: &Target, name: &str, params: RerunParams) -> Result<Self> {
        let builder = rerun::RecordingStreamBuilder::new("dynapix").recording_name(name);
        let rec = match target {
            Target::Spawn => builder.spawn(),
            Target::Connect(url) => builder.connect_grpc_opts(url.clone()),
            Target::Save(path) => builder.save(path),
        }
        .map_err(|source| Error::Open {
            target: target.to_string(),
            source,
        })?;
        Ok(Self::with_stream(rec, target.to_string(), params))
    }

    /// An observer logging to `rec` (e.g. a memory sink), described as `target` in errors.
    pub fn with_stream(rec: RecordingStream, target: String, params: RerunParams) -> Self {
        Self {
            rec,
            target,
            params,
            state: Mutex::new(PassState::default()),
            statics_sent: AtomicBool::new(false),
        }
    }

    /// Where the recording goes.
    pub fn target(&self) -> &str {
        &self.target
    }

    /// The recording stream.
    pub fn stream(&self) -> &RecordingStream {
        &self.rec
    }

    /// Sends everything logged so far to the sink (a file is complete after this).
    pub fn finish(&self) -> Result<()> {
        self.rec.flush_blocking().map_err(|e| Error::Flush {
            target: self.target.clone(),
            reason: e.to_string(),
        })
    }

    fn state(&self) -> std::sync::MutexGuard<'_, PassState> {
        // A panic while logging leaves nothing half-updated that matters for a viewer.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Logs `what` at `path`; a logging error is reported once in the log, never stops a run.
    fn log<A: rerun::AsComponents + ?Sized>(&self, path: &str, what: &A) {
        if let Err(e) = self.rec.log(path, what) {
            tracing::warn!("rerun: cannot log {path}: {e}");
        }
    }

    fn log_static<A: rerun::AsComponents + ?Sized>(&self, path: &str, what: &A) {
        if let Err(e) = self.rec.log_static(path, what) {
            tracing::warn!("rerun: cannot log {path}: {e}");
        }
    }

    fn event(&self, text: String, level: &str) {
        self.log(
            "events",
            &rerun::TextLog::new(text).with_level(rerun::TextLogLevel::from(level)),
        );
    }

    fn scalar(&self, path: &str, v: f64) {
        self.log(path, &rerun::Scalars::single(v));
    }

    /// The trajectories, the ATE so far, the map (with a frame) and the removed points.
    fn log_trajectories(&self, st: &mut PassState, frame: Option<&FrameView<'_>>) {
        let strip = |poses: &[(f64, Isometry3<f64>)]| -> Vec<[f32; 3]> {
            poses.iter().map(|(_, p)| point(p)).collect()
        };
        if st.estimate.len() >= 2 {
            self.log(
                "world/trajectory/estimate",
                &rerun::LineStrips3D::new([strip(&st.estimate)])
                    .with_colors([colors::ESTIMATE])
                    .with_radii([rerun::Radius::new_ui_points(1.5)]),
            );
        }
        if st.ground_truth.len() >= 3 && st.estimate.len() >= 3 {
            match ate(&st.ground_truth, &st.estimate, &AteParams::default()) {
                Ok(r) => {
                    // The ground truth in the estimate's frame: the inverse of the alignment.
                    let inverse = r.alignment.se3().inverse();
                    let gt_in_est: Vec<[f32; 3]> = st
                        .ground_truth
                        .iter()
                        .filter(|(t, _)| {
                            *t >= st.estimate[0].0 - 0.02
                                && *t <= st.estimate[st.estimate.len() - 1].0 + 0.02
                        })
                        .map(|(_, p)| {
                            let q = inverse * nalgebra::Point3::from(p.translation.vector);
                            [q.x as f32, q.y as f32, q.z as f32]
                        })
                        .collect();
                    self.log(
                        "world/trajectory/ground_truth",
                        &rerun::LineStrips3D::new([gt_in_est])
                            .with_colors([colors::GROUND_TRUTH])
                            .with_radii([rerun::Radius::new_ui_points(1.0)]),
                    );
                    self.scalar("plots/ate_rmse_m", r.stats.rmse);
                }
                Err(e) => tracing::debug!("rerun: no ATE yet: {e}"),
            }
        }
        if let Some(f) = frame {
            let (pos, col): (Vec<[f32; 3]>, Vec<[u8; 4]>) = f
                .map_points()
                .map(|p| {
                    (
                        [
                            p.position.x as f32,
                            p.position.y as f32,
                            p.position.z as f32,
                        ],
                        colors::weight(p.weight),
                    )
                })
                .unzip();
            self.log(
                "world/map/points",
                &rerun::Points3D::new(pos)
                    .with_colors(col)
                    .with_radii([rerun::Radius::new_ui_points(2.0)]),
            );
            let kfs: Vec<[f32; 3]> = f.keyframe_poses().iter().map(|(_, p)| point(p)).collect();
            self.log(
                "world/map/keyframes",
                &rerun::Points3D::new(kfs)
                    .with_colors([colors::KEYFRAME])
                    .with_radii([rerun::Radius::new_ui_points(4.0)]),
            );
        }
        if st.removed_new {
            self.log(
                "world/map/removed",
                &rerun::Points3D::new(st.removed.iter().copied())
                    .with_colors([colors::REMOVED])
                    .with_radii([rerun::Radius::new_ui_points(2.5)]),
            );
            st.removed_new = false;
        }
    }

    /// What does not change during a recording, logged once (with the first pass): the
    /// axes, the camera's pinhole and the colours of the P overlay, on the overlay's entity
    /// and on `world`. Logged at every pass and on the overlay's entity only, the viewer
    /// (0.36) drew the overlay of a multi-pass recording in its automatic class colours
    /// (blue, green, yellow) instead of the ones logged (seen in screenshots of the Bonn
    /// window; which of the two changes mattered was not isolated).
    fn log_statics(&self, pass: &PassInfo<'_>) {
        self.log_static("world", &rerun::ViewCoordinates::RDF());
        let c = pass.camera;
        self.log_static(
            "world/camera/image",
            &rerun::Pinhole::from_focal_length_and_resolution(
                [c.fx as f32, c.fy as f32],
                [c.width as f32, c.height as f32],
            )
            .with_principal_point([c.cx as f32, c.cy as f32])
            .with_image_plane_distance(0.25),
        );
        let context = rerun::AnnotationContext::new(
            (0..=colors::P_LEVELS)
                .map(|k| {
                    let [r, g, b, a] = colors::motion_class(k);
                    let label = format!("P ≈ {:.2}", f32::from(k) / f32::from(colors::P_LEVELS));
                    (
                        u16::from(k),
                        label.as_str(),
                        rerun::Rgba32::from_unmultiplied_rgba(r, g, b, a),
                    )
                        .into()
                })
                .collect::<Vec<rerun::datatypes::ClassDescriptionMapElem>>(),
        );
        // On the overlay itself (the 2D view) and on `world` (the 3D view's frustum).
        self.log_static("world/camera/image/motion", &context);
        self.log_static("world", &context);
    }

    /// The colour image, P overlay, keypoints and depth of a frame.
    fn log_images(&self, st: &mut PassState, f: &FrameView<'_>) {
        if let Some(rgb) = f.rgb {
            match crate::encode::jpeg(rgb, self.params.jpeg_quality) {
                Ok(jpeg) => self.log(
                    "world/camera/image",
                    &rerun::EncodedImage::from_file_contents(jpeg)
                        .with_media_type(rerun::MediaType::jpeg()),
                ),
                Err(e) => tracing::warn!("rerun: cannot encode frame {}: {e}", f.index),
            }
        }
        match f.weights {
            Some(w) => {
                // Classes of P, coloured by the annotation context of the entity: one byte a
                // pixel, and drawn by the viewer as a translucent layer over the image.
                let img = w.as_image();
                colors::motion_classes(img.as_raw(), &mut st.overlay);
                self.log(
                    "world/camera/image/motion",
                    &rerun::SegmentationImage::new(
                        std::mem::take(&mut st.overlay),
                        rerun::components::ImageFormat::segmentation(
                            [img.width(), img.height()],
                            rerun::datatypes::ChannelDatatype::U8,
                        ),
                    )
                    .with_opacity(0.8)
                    .with_draw_order(5.0),
                );
            }
            None => self.log("world/camera/image/motion", &rerun::Clear::flat()),
        }
        let (bytes, size) = crate::encode::depth_mm(f.depth, self.params.depth_downscale);
        self.log(
            "depth",
            &rerun::DepthImage::from_gray16(bytes, size)
                .with_meter(1000.0)
                .with_colormap(rerun::components::Colormap::Turbo),
        );
    }
}

/// The position of a pose as `f32`.
fn point(p: &Isometry3<f64>) -> [f32; 3] {
    let t = p.translation.vector;
    [t.x as f32, t.y as f32, t.z as f32]
}

impl RunObserver for RerunObserver {
    fn pass_begins(&self, pass: &PassInfo<'_>) {
        let timeline = format!("pass{}", pass.number);
        {
            let mut st = self.state();
            *st = PassState {
                timeline: timeline.clone(),
                images: self.params.images_in(pass),
                last: pass.last,
                ground_truth: pass
                    .ground_truth
                    .map(|g| g.poses.iter().map(|p| (p.t, p.pose)).collect())
                    .unwrap_or_default(),
                ..PassState::default()
            };
        }
        if let Err(e) = layout::blueprint(&timeline).send(
            &self.rec,
            rerun::blueprint::BlueprintActivation {
                make_active: true,
                make_default: true,
            },
        ) {
            tracing::warn!("rerun: cannot send the layout: {e}");
        }
        if !self.statics_sent.swap(true, Ordering::Relaxed) {
            self.log_statics(pass);
        }
        // The previous pass's time must not stick to this pass's rows.
        self.rec.reset_time();
        if let Ok(name) = rerun::TimelineName::try_new(&timeline) {
            self.rec.set_time_sequence(name, 0);
        }
        self.event(
            format!(
                "pass {} begins: {} ({} frames{}{})",
                pass.number,
                pass.label,
                pass.frames,
                if pass.weighted { ", weighted by P" } else { "" },
                if pass.ground_truth.is_some() {
                    ", ground truth shown aligned"
                } else {
                    ""
                }
            ),
            rerun::TextLogLevel::INFO,
        );
    }

    fn frame(&self, f: &FrameView<'_>) {
        let mut st = self.state();
        if let Ok(name) = rerun::TimelineName::try_new(&st.timeline) {
            self.rec.set_time_sequence(name, f.index as i64);
        }
        st.frames += 1;
        if let Some(p) = f.pose_wc {
            st.estimate.push((f.t, p));
            let q = p.rotation;
            self.log(
                "world/camera",
                &rerun::Transform3D::from_translation(point(&p)).with_quaternion(
                    rerun::Quaternion::from_xyzw([q.i as f32, q.j as f32, q.k as f32, q.w as f32]),
                ),
            );
        }
        let every = |n: usize| n <= 1 || f.index.is_multiple_of(n);
        if st.images && every(self.params.images_every) {
            self.log_images(&mut st, f);
        }
        let (pos, col): (Vec<[f32; 2]>, Vec<[u8; 4]>) = f
            .keypoints()
            .map(|k| ([k.x, k.y], colors::keypoint(k.usage)))
            .unzip();
        self.log(
            "world/camera/image/keypoints",
            &rerun::Points2D::new(pos)
                .with_colors(col)
                .with_radii([rerun::Radius::new_ui_points(3.0)])
                .with_draw_order(10.0),
        );
        // Logged with the map (every few frames), not every frame: the set only grows.
        let removed = f.removed_points();
        if !removed.is_empty() {
            st.removed
                .extend(removed.iter().map(|p| [p.x as f32, p.y as f32, p.z as f32]));
            st.removed_new = true;
        }
        let state = match f.status {
            FrameStatus::Tracked => 1.0,
            FrameStatus::Lost => 0.0,
            _ => -1.0,
        };
        self.scalar("plots/tracking_state", state);
        self.scalar("plots/tracked_map_points", f.tracked_points as f64);
        self.scalar("plots/map_points", f.num_map_points() as f64);
        if let Some(w) = f.weights {
            self.scalar("plots/mean_p", crate::encode::mean_p(w.as_image().as_raw()));
        }
        let t = f.times;
        if let Some(m) = t.motion_ms {
            self.scalar("timings/motion_ms", m);
        }
        self.scalar("timings/extract_ms", t.extract_ms);
        self.scalar("timings/track_ms", t.track_ms);
        self.scalar("timings/mapping_ms", t.mapping_ms);
        self.scalar("timings/loop_ms", t.loop_ms);
        if f.keyframe {
            self.event(
                format!("frame {}: keyframe {}", f.index, f.num_keyframes()),
                rerun::TextLogLevel::DEBUG,
            );
        }
        if let Some((t_old, matched)) = f.loop_closed {
            self.event(
                format!(
                    "frame {}: loop closed with the keyframe of t = {t_old:.3} ({matched} points)",
                    f.index
                ),
                rerun::TextLogLevel::INFO,
            );
        }
        if f.status != FrameStatus::Tracked && st.frames > 1 {
            self.event(
                format!("frame {}: {}", f.index, f.status.as_str()),
                rerun::TextLogLevel::WARN,
            );
        }
        if f.keyframe || every(self.params.trajectory_every) {
            self.log_trajectories(&mut st, Some(f));
        }
    }

    fn wants_images(&self, pass: &PassInfo<'_>) -> bool {
        self.params.images_in(pass)
    }

    fn pass_ends(&self, pass: &PassInfo<'_>, output: &PassOutput) {
        self.end(pass, &output.trajectory);
    }

    fn online_ends(&self, pass: &PassInfo<'_>, refined: &Trajectory) {
        self.end(pass, refined);
    }
}

impl RerunObserver {
    /// The end of a pass: its final (refined) trajectory against the ground truth.
    fn end(&self, pass: &PassInfo<'_>, trajectory: &Trajectory) {
        let mut st = self.state();
        st.estimate = trajectory.poses.iter().map(|p| (p.t, p.pose)).collect();
        self.log_trajectories(&mut st, None);
        self.event(
            format!(
                "pass {} ends: {} of {} frames tracked",
                pass.number,
                trajectory.len(),
                pass.frames
            ),
            rerun::TextLogLevel::INFO,
        );
        if st.last {
            // The run's result is complete: what is logged reaches the file or viewer now,
            // within the run's time (the caller's `finish` then has nothing left to send).
            if let Err(e) = self.rec.flush_blocking() {
                tracing::warn!("rerun: cannot flush the recording: {e}");
            }
        }
    }
}
