//! Motion maps of a sequence on disk: what determines them ([`MapJob`]), their computation
//! (over [`dynapix_motion::SequenceMotion`] with the sequence as frame loader), the folder
//! they live in with its `motion.json` record ([`MapFolder`]), and the cache that reuses a
//! folder only when its record matches the job exactly ([`cached_maps`]).
//!
//! A folder holds one 16-bit PNG per frame, named like the rgb image (`trunc((1 − P)·1000)`,
//! the reference format), and `motion.json`: `{"sequence", "config", "status", "results"}`.
//! `config` lists everything that determines the maps (frame list, poses and a fingerprint of
//! their values, background, flow, camera, parameters, the code version of the maps); the
//! cache key is a hash of it. Reading a folder back gives its provenance, so maps made with
//! ground-truth poses are reported as such.
//!
//! A complete record also lists every map file with its size and FNV-64 checksum (`files`).
//! A cache folder is reused only when each file still matches ([`MapFolder::check_cache`]):
//! a truncated, missing or swapped map makes the whole folder be recomputed, with a warning
//! naming the file, instead of stopping a run half-way.

use std::path::Path;

use dynapix_flow::dis::DisFlow;
use dynapix_io::MotionProbability;
use dynapix_io::images::{read_depth_raw, read_rgb};
use dynapix_motion::{
    Backgrounds, BoxError, FloatImage, FrameLoader, FrameMotion, MotionParams, RgbdImages,
    RigidityParams, SequenceMotion, SequenceStats, StaticBackground, StaticDepthParams,
};
use rayon::prelude::*;
use serde_json::{Value, json};

use crate::combine::FrameCues;
use crate::config::{Config, Cues, FlowPreset};
use crate::cues::{GeometricInput, RigidityJob};
use crate::error::{Error, Result};
use crate::input::Input;
use crate::poses::FramePoses;
use crate::progress::{Progress, Task};
use crate::record::MapsStatus;
pub(crate) use crate::record::as_read_back;
use crate::store::MapSink;
pub use crate::store::{MapFolder, MapSet};

/// Version of the motion-map computation, part of every cache key: bump it when a change of
/// the motion algorithms changes their output without changing a parameter (2: splatting
/// through the lens distortion of distorted cameras; 3: cues combined by noisy-or).
pub const MOTION_MAPS_VERSION: u32 = 3;

/// The frames of an [`Input`] as a motion-map frame loader.
pub struct SequenceLoader<'a> {
    input: &'a Input,
    use_depth_bg: bool,
}

impl<'a> SequenceLoader<'a> {
    /// Loads frames of `input`; with `use_depth_bg` the given backgrounds take their depth
    /// from `depth_bg/`, else from the frame.
    pub fn new(input: &'a Input, use_depth_bg: bool) -> Self {
        Self {
            input,
            use_depth_bg,
        }
    }
}

impl FrameLoader for SequenceLoader<'_> {
    fn len(&self) -> usize {
        self.input.len()
    }

    fn available(&self, i: usize) -> bool {
        !self.input.is_bad(i)
    }

    fn frame(&self, i: usize) -> std::result::Result<RgbdImages, BoxError> {
        let (rgb, depth) = self.input.load_rgbd(i)?;
        Ok(RgbdImages { rgb, depth })
    }

    fn background(
        &self,
        i: usize,
        frame: &RgbdImages,
    ) -> std::result::Result<StaticBackground, BoxError> {
        let info = self.input.sequence.info(i)?;
        let path = info
            .background
            .as_ref()
            .ok_or_else(|| format!("no background image for {}", info.rgb.display()))?;
        let depth = if self.use_depth_bg {
            let p = info
                .depth_bg
                .as_ref()
                .ok_or_else(|| format!("no background depth for {}", info.rgb.display()))?;
            self.input.sequence.read_depth(p)?
        } else {
            frame.depth.clone()
        };
        Ok(StaticBackground {
            rgb: read_rgb(path)?,
            depth,
        })
    }
}

/// Everything that determines the motion maps of a sequence.
pub struct MapJob<'a> {
    /// The sequence.
    pub input: &'a Input,
    /// Poses for splatting.
    pub poses: &'a FramePoses,
    /// Motion-probability parameters (with the method's terms).
    pub params: MotionParams,
    /// Optical-flow preset.
    pub flow: FlowPreset,
    /// Background source.
    pub backgrounds: Backgrounds,
    /// Given backgrounds take their depth from `depth_bg/`.
    pub use_depth_bg: bool,
    /// Largest frame-to-pose time distance used to look the poses up (recorded).
    pub max_pose_gap: f64,
    /// Extra facts about the poses (e.g. added noise), recorded with them.
    pub pose_notes: Value,
    /// The cues that make up P.
    pub cues: Cues,
    /// Parameters of the geometric cue.
    pub static_depth: StaticDepthParams,
    /// Parameters of the rigidity cue.
    pub rigidity_params: RigidityParams,
    /// Precomputed rigidity maps of the sequence (made with [`MapJob::rigidity_job`]);
    /// without them the rigidity cue is computed frame by frame.
    pub rigidity: Option<MapSet>,
    /// The rigidity cue takes the relative poses of `poses` as priors of the pairs' motions
    /// (`motion.rigidity_pose_prior`, for poses from a pass of the run only).
    pub rigidity_pose_prior: bool,
}

/// What the per-frame consumer of [`MapJob::run`] gets.
#[derive(Debug)]
pub struct FrameMaps<'a> {
    /// Frame index.
    pub index: usize,
    /// The motion probability of the frame: the enabled cues combined by noisy-or.
    pub p: FloatImage,
    /// The paper's terms of the frame (P = D·M, D, M, images, background), when that cue is
    /// on.
    pub paper: Option<FrameMotion<'a>>,
}

impl<'a> MapJob<'a> {
    /// The job of `config` (its method's terms, flow preset, background choice) on `input`.
    pub fn new(input: &'a Input, config: &Config, poses: &'a FramePoses) -> Self {
        let has_folder = input
            .sequence
            .frames
            .first()
            .is_some_and(|f| f.background.is_some());
        let backgrounds = config.backgrounds(has_folder);
        let use_depth_bg = !backgrounds.reconstructs()
            && input
                .sequence
                .frames
                .first()
                .is_some_and(|f| f.depth_bg.is_some());
        Self {
            input,
            poses,
            params: config.motion_params(),
            flow: config.motion.flow,
            backgrounds,
            use_depth_bg,
            max_pose_gap: config.motion.max_pose_gap,
            pose_notes: Value::Null,
            cues: config.cues(),
            static_depth: config.motion.static_depth.clone(),
            rigidity_params: config.motion.rigidity.clone(),
            rigidity: None,
            rigidity_pose_prior: config.motion.rigidity_pose_prior
                && matches!(poses.origin, crate::poses::PoseOrigin::Pass { .. }),
        }
    }

    /// The rigidity job of these maps: pose-free, or with the priors of `poses`
    /// ([`MapJob::rigidity_pose_prior`]).
    pub fn rigidity_job(&self) -> RigidityJob<'a> {
        let job = RigidityJob::new(self.input, self.rigidity_params.clone());
        if self.rigidity_pose_prior {
            job.with_priors(self.poses)
        } else {
            job
        }
    }

    /// This job with the sequence's precomputed rigidity maps.
    pub fn with_rigidity(mut self, maps: Option<MapSet>) -> Self {
        self.rigidity = maps;
        self
    }

    /// True when this job's maps use poses.
    fn uses_poses(&self) -> bool {
        (self.cues.paper && SequenceMotion::needs_poses(&self.params, &self.backgrounds))
            || self.cues.geometric
    }

    /// True when the maps of `config` on `input` use poses.
    pub fn needs_poses(input: &Input, config: &Config) -> bool {
        let has_folder = input
            .sequence
            .frames
            .first()
            .is_some_and(|f| f.background.is_some());
        let cues = config.cues();
        (cues.paper
            && SequenceMotion::needs_poses(
                &config.motion_params(),
                &config.backgrounds(has_folder),
            ))
            || cues.geometric
    }

    /// The flow provider.
    pub fn flow_provider(&self) -> DisFlow {
        DisFlow::with_preset(self.flow.preset())
    }

    /// The `config` document of `motion.json`: everything that determines the maps.
    pub fn record(&self) -> Value {
        let seq = &self.input.sequence;
        let cam = self.input.camera.pinhole();
        let mut r = json!({
            "maps_version": MOTION_MAPS_VERSION,
            "frames": seq.len(),
            "frame_list": seq.frame_list,
            "frames_hash": self.input.frames_hash(),
            "poses": {
                "origin": self.poses.origin,
                "interpolation": "slerp",
                "max_gap_s": self.max_pose_gap,
                "content_hash": self.poses.content_hash(),
                "notes": self.pose_notes,
            },
            "background": match &self.backgrounds {
                Backgrounds::Reconstruct(r) => json!({"source": "reconstruct", "params": r}),
                Backgrounds::Given => json!({
                    "source": "folder",
                    "depth": if self.use_depth_bg { "depth_bg" } else { "depth (dynamic)" },
                }),
            },
            "flow": {
                "provider": "dis",
                "preset": self.flow.name(),
                "params": self.flow_provider().params,
            },
            "camera": cam,
            "depth_factor": seq.depth_factor,
            "depth_validity": seq.depth_validity,
            "params": self.params,
            "cues": {
                "combine": "noisy-or: P = 1 - prod(1 - P_cue)",
                "paper": self.cues.paper,
                "geometric": self.cues.geometric.then_some(&self.static_depth),
                "rigidity": self.cues.rigidity.then(|| self.rigidity_job().record()),
            },
            "output": "uint16 trunc((1 - P) * 1000), 16-bit PNG named like the rgb image",
        });
        if let Some(b) = self.input.bad_frames_record() {
            r["bad_frames_skipped"] = b;
        }
        r
    }

    /// Checks every frame's files before anything is computed: sizes against the camera,
    /// unreadable or all-zero depth, missing backgrounds; `masks` also checks `mask/`, and
    /// `missing_poses` lists frames without a pose (with `poses_from` naming the file).
    pub fn check_inputs(
        &self,
        masks: bool,
        missing_poses: &[usize],
        poses_from: &str,
    ) -> Vec<String> {
        use rayon::prelude::*;
        let seq = &self.input.sequence;
        let cam = self.input.camera.pinhole();
        let size = (cam.width, cam.height);
        let needs_poses = self.uses_poses();
        let given = self.cues.paper && !self.backgrounds.reconstructs();
        (0..seq.len())
            .into_par_iter()
            .flat_map_iter(|i| {
                let f = &seq.frames[i];
                let name = f
                    .rgb
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let mut p = Vec::new();
                let mut check = |path: Option<&Path>, what: &str, expected: &Path| match path {
                    None => p.push(format!(
                        "frame {i} ({name}): {what} {}: missing",
                        expected.display()
                    )),
                    Some(path) => match dynapix_io::images::image_size(path) {
                        Ok(d) if d == size => {}
                        Ok(d) => p.push(format!(
                            "frame {i} ({name}): {what} {} is {}×{}, expected {}×{}",
                            path.display(),
                            d.0,
                            d.1,
                            size.0,
                            size.1
                        )),
                        Err(e) => p.push(format!("frame {i} ({name}): {what} {e}")),
                    },
                };
                check(Some(&f.rgb), "rgb", &f.rgb);
                check(Some(&f.depth), "depth", &f.depth);
                if given {
                    let bg = seq.dir.join("background").join(&name);
                    check(f.background.as_deref(), "background", &bg);
                    if self.use_depth_bg {
                        let dbg = seq.dir.join("depth_bg").join(&name);
                        check(f.depth_bg.as_deref(), "background depth", &dbg);
                    }
                }
                if masks {
                    let m = seq.dir.join("mask").join(&name);
                    check(f.mask.as_deref(), "mask", &m);
                }
                if needs_poses && missing_poses.binary_search(&i).is_ok() {
                    p.push(format!(
                        "frame {i} ({name}): no pose within {} s of t = {:.6} in {poses_from}",
                        self.max_pose_gap, f.t
                    ));
                }
                if p.is_empty() {
                    match read_depth_raw(&f.depth) {
                        Ok(d) if d.iter().all(|&v| v == 0) => {
                            p.push(format!("frame {i} ({name}): depth is all zero"))
                        }
                        Ok(_) => {}
                        Err(e) => p.push(format!("frame {i} ({name}): {e}")),
                    }
                }
                p
            })
            .collect()
    }

    /// Computes the maps of `frames`: `map` gets every frame's result (in parallel), its
    /// output goes to `fold` in frame order.
    pub fn run<R, F, G>(&self, frames: &[usize], map: F, mut fold: G) -> Result<SequenceStats>
    where
        R: Send,
        F: Fn(FrameMaps<'_>) -> std::result::Result<R, BoxError> + Sync,
        G: FnMut(usize, R),
    {
        let started = std::time::Instant::now();
        // The paper's terms visit the frames in their own order: every depth is read first.
        // Otherwise the chunks below read the depths each needs, a window of the sequence.
        let geo = match (self.cues.geometric, self.cues.paper) {
            (false, _) => None,
            (true, true) => Some(GeometricInput::load(
                self.input,
                self.poses,
                &self.static_depth,
            )?),
            (true, false) => Some(GeometricInput::windowed(
                self.input,
                self.poses,
                &self.static_depth,
            )?),
        };
        let rig_job = self.rigidity_job();
        let cam = self.input.camera.pinhole();
        // P of frame `i` from its paper terms (when that cue is on) and the other cues.
        let combined =
            |i: usize, paper: Option<FloatImage>| -> std::result::Result<FloatImage, BoxError> {
                let geometric = match &geo {
                    Some(g) => Some(g.frame(i)?),
                    None => None,
                };
                let rigidity = match (&self.rigidity, self.cues.rigidity) {
                    (_, false) => None,
                    (Some(set), true) => Some(set.probability(self.input, i)?.into_image()),
                    (None, true) => Some(rig_job.frame(i)?),
                };
                let cues = FrameCues {
                    paper,
                    geometric,
                    rigidity,
                };
                Ok(cues.combine(cam.width, cam.height)?)
            };
        if self.cues.paper {
            let loader = SequenceLoader::new(self.input, self.use_depth_bg);
            let flow = self.flow_provider();
            let cam = self.input.camera.pinhole();
            let seq = SequenceMotion {
                loader: &loader,
                poses: &self.poses.poses,
                camera: &cam,
                flow: &flow,
                params: &self.params,
                backgrounds: &self.backgrounds,
            };
            let mut stats = seq.run(
                frames,
                |m| {
                    let p = combined(m.index, Some(m.maps.p.clone()))?;
                    map(FrameMaps {
                        index: m.index,
                        p,
                        paper: Some(m),
                    })
                },
                fold,
            )?;
            if self.cues.geometric || self.cues.rigidity {
                stats.compute_seconds = started.elapsed().as_secs_f64();
            }
            return Ok(stats);
        }
        // Frames in parallel chunks, in order; every chunk ends with all threads waiting for
        // its slowest frame, so chunks are long (32 frames on 2 threads: 8 made the threads
        // wait measurably). What a frame gets does not depend on the chunking.
        let chunk = 16 * rayon::current_num_threads().max(1);
        for part in frames.chunks(chunk) {
            if let Some(g) = &geo {
                g.prepare(self.input, part)?;
            }
            let out = part
                .par_iter()
                .map(|&i| {
                    combined(i, None)
                        .and_then(|p| {
                            map(FrameMaps {
                                index: i,
                                p,
                                paper: None,
                            })
                        })
                        // Typed, so the file that failed (e.g. in the cache) stays known.
                        .map_err(|e| {
                            Error::Motion(dynapix_motion::SequenceError::Consumer {
                                index: i,
                                source: e,
                            })
                        })
                })
                .collect::<Result<Vec<R>>>()?;
            for (&i, r) in part.iter().zip(out) {
                fold(i, r);
            }
        }
        Ok(SequenceStats {
            frames: frames.len(),
            compute_seconds: started.elapsed().as_secs_f64(),
        })
    }
}

/// The maps of `job`, with the cache folder `root` when given: a folder `maps-<key>` is
/// reused when its record matches the job exactly and every map exists, else the maps are
/// computed and written there as they come. Without a cache they go to a temporary file the
/// run owns ([`crate::spill::SpilledMaps`]) and nothing else is written.
pub fn cached_maps(
    job: &MapJob<'_>,
    root: Option<&Path>,
    label: &str,
    progress: &dyn Progress,
) -> Result<MapSet> {
    let config = job.record();
    let ground_truth = job.poses.origin.is_ground_truth();
    let Some(root) = root else {
        let spilled = compute_maps(job, None, &config, label, progress)?.0;
        return Ok(MapSet {
            folder: None,
            spilled,
            record: json!({
                "source": "computed (no cache)",
                "dir": null,
                "poses": job.poses.origin,
                "ground_truth_poses": ground_truth,
                "config": config,
            }),
            ground_truth: Some(ground_truth),
        });
    };
    let (folder, key, reused) = MapFolder::in_cache(root, "maps", job.input, &config);
    if !reused {
        compute_maps(job, Some(&folder), &config, label, progress)?;
    }
    let record = json!({
        "source": if reused { "cache (key matched)" } else { "computed" },
        "dir": folder.dir,
        "key": key,
        "poses": job.poses.origin,
        "ground_truth_poses": ground_truth,
        "config": config,
    });
    Ok(MapSet {
        folder: Some(folder),
        spilled: None,
        record,
        ground_truth: Some(ground_truth),
    })
}

/// Computes every frame of `job` (but the bad frames of a run that skips them) into `folder`
/// when given (recorded complete at the end), else into a temporary file (returned).
fn compute_maps(
    job: &MapJob<'_>,
    folder: Option<&MapFolder>,
    config: &Value,
    label: &str,
    progress: &dyn Progress,
) -> Result<(Option<crate::spill::SpilledMaps>, SequenceStats)> {
    let _phase = tracing::info_span!(target: "dynapix::phase", "motion maps").entered();
    let n = job.input.len();
    if let Some(f) = folder {
        f.write_record(job.input, config, MapsStatus::Running, Value::Null)?;
    }
    let sink = MapSink::new(job.input, folder)?;
    let all: Vec<usize> = (0..n).filter(|&i| !job.input.is_bad(i)).collect();
    let task = Task::begin(progress, label, all.len());
    let stats = job.run(
        &all,
        |m| {
            sink.put(m.index, &MotionProbability::new(m.p))?;
            Ok(())
        },
        |_, ()| task.step(""),
    )?;
    drop(task);
    if let Some(f) = folder {
        f.write_record(
            job.input,
            config,
            MapsStatus::Complete,
            json!({
                "frames_computed": stats.frames,
                "compute_seconds": stats.compute_seconds,
                "threads": rayon::current_num_threads(),
            }),
        )?;
    }
    Ok((sink.finish(), stats))
}
