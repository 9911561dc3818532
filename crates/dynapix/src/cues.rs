//! The cues beyond the paper's terms on a sequence (see [`crate::Cues`]):
//!
//! - the **rigidity cue** needs no poses, so its maps are computed once per sequence and
//!   cached ([`RigidityJob`], [`cached_rigidity`]); they weight the rigidity first pass and
//!   enter every later pass's P;
//! - the **geometric cue** needs the depth of every frame at a working resolution and the
//!   poses of the pass before ([`GeometricInput`]).
//!
//! Maps are stored like motion maps (16-bit PNG of `trunc((1 − P)·1000)` named like the rgb
//! image, with a `motion.json` record), so a folder of rigidity maps is a valid map folder.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use dynapix_flow::dis::DisFlow;
use dynapix_geometry::{PinholeCamera, Se3};
use dynapix_io::MotionProbability;
use dynapix_motion::moving::to_gray;
use dynapix_motion::static_depth::{WorkingDepth, geometric_frame, select_views};
use dynapix_motion::{
    FloatImage, PairResiduals, PriorChoice, RigidFit, RigidFitError, RigidFrame, RigidityParams,
    StaticDepthParams,
};
use image::GrayImage;
use rayon::prelude::*;
use serde_json::{Value, json};

use crate::error::{Error, Result};
use crate::input::Input;
use crate::poses::FramePoses;
use crate::progress::{Progress, Task};
use crate::record::MapsStatus;
use crate::store::{MapFolder, MapSet, MapSink};

/// Version of the rigidity computation, part of its cache key.
pub const RIGIDITY_MAPS_VERSION: u32 = 1;

/// Everything that determines the rigidity maps of a sequence.
pub struct RigidityJob<'a> {
    /// The sequence.
    pub input: &'a Input,
    /// The cue's parameters (offsets, flow preset, noise model, RANSAC).
    pub params: RigidityParams,
    /// Camera-to-world poses of every frame (a previous pass's trajectory) whose relative
    /// poses are the priors of the pairs' motions ([`dynapix_motion::pair_residuals_with_prior`]);
    /// `None`: the pose-free cue.
    pub priors: Option<&'a FramePoses>,
}

/// Counters of the rigidity fits of a run: pairs (frame, neighbour) by outcome.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct RigidityStats {
    /// Pairs whose dominant motion was fitted and used.
    pub pairs_used: usize,
    /// Pairs whose best motion explained too few correspondences (movers may dominate).
    pub pairs_ambiguous: usize,
    /// Pairs without a fit (too few correspondences, degenerate).
    pub pairs_failed: usize,
    /// With a pose prior: pairs whose dominant motion agreed with it (kept unchanged).
    pub prior_agrees: usize,
    /// With a pose prior: pairs whose dominant motion disagreed with it (the fit seeded by
    /// the prior was used).
    pub prior_disagrees: usize,
    /// With a pose prior: ambiguous pairs that the fit seeded by the prior made usable.
    pub prior_ambiguous: usize,
    /// With a pose prior: pairs whose prior had too few inliers (pose-free outcome kept).
    pub prior_unsupported: usize,
}

impl RigidityStats {
    /// The counts of one frame's fits.
    fn of(fits: &[std::result::Result<RigidFit, RigidFitError>]) -> Self {
        let mut stats = Self::default();
        for f in fits {
            match f {
                Ok(_) => stats.pairs_used += 1,
                Err(RigidFitError::Ambiguous { .. }) => stats.pairs_ambiguous += 1,
                Err(_) => stats.pairs_failed += 1,
            }
        }
        stats
    }

    /// Counts the prior choices of a frame's pairs.
    fn with_choices(mut self, choices: impl IntoIterator<Item = PriorChoice>) -> Self {
        for c in choices {
            match c {
                PriorChoice::Agrees => self.prior_agrees += 1,
                PriorChoice::Disagrees => self.prior_disagrees += 1,
                PriorChoice::Ambiguous => self.prior_ambiguous += 1,
                PriorChoice::Unsupported => self.prior_unsupported += 1,
                PriorChoice::NoPrior | PriorChoice::Failed => {}
            }
        }
        self
    }

    fn add(&mut self, o: RigidityStats) {
        self.pairs_used += o.pairs_used;
        self.pairs_ambiguous += o.pairs_ambiguous;
        self.pairs_failed += o.pairs_failed;
        self.prior_agrees += o.prior_agrees;
        self.prior_disagrees += o.prior_disagrees;
        self.prior_ambiguous += o.prior_ambiguous;
        self.prior_unsupported += o.prior_unsupported;
    }
}

/// The grey image and depth of one frame.
type GrayDepth = Arc<(GrayImage, FloatImage)>;

impl<'a> RigidityJob<'a> {
    /// The job of `params` on `input` (pose-free).
    pub fn new(input: &'a Input, params: RigidityParams) -> Self {
        Self {
            input,
            params,
            priors: None,
        }
    }

    /// This job with the pose priors of `poses` (one camera-to-world pose per frame).
    pub fn with_priors(mut self, poses: &'a FramePoses) -> Self {
        self.priors = Some(poses);
        self
    }

    /// The prior of the motion a → b (camera-a points into camera b), `T_wb⁻¹ · T_wa`.
    fn prior(&self, a: usize, b: usize) -> Option<Se3> {
        let p = &self.priors?.poses;
        Some(p.get(b)?.inverse() * p.get(a)?)
    }

    /// The `config` document of the maps' `motion.json`: everything that determines them.
    pub fn record(&self) -> Value {
        let seq = &self.input.sequence;
        let mut r = json!({
            "cue": "rigidity",
            "version": RIGIDITY_MAPS_VERSION,
            "frames": seq.len(),
            "frame_list": seq.frame_list,
            "frames_hash": self.input.frames_hash(),
            "camera": self.input.camera.pinhole(),
            "depth_factor": seq.depth_factor,
            "depth_validity": seq.depth_validity,
            "poses": match self.priors {
                None => json!("none (pose-free cue)"),
                Some(p) => json!({
                    "use": "prior of each pair's motion",
                    "origin": p.origin,
                    "hash": p.content_hash(),
                }),
            },
            "params": self.params,
            "output": "uint16 trunc((1 - P) * 1000), 16-bit PNG named like the rgb image",
        });
        if let Some(b) = self.input.bad_frames_record() {
            r["bad_frames_skipped"] = b;
        }
        r
    }

    /// The cache key: a hash of [`RigidityJob::record`].
    #[cfg(test)]
    pub fn key(&self) -> String {
        crate::hash::Fnv64::of(self.record().to_string().as_bytes())
    }

    fn load(&self, i: usize) -> Result<GrayDepth> {
        let (rgb, depth) = self.input.load_rgbd(i)?;
        Ok(Arc::new((to_gray(&rgb), depth)))
    }

    /// The neighbours of frame `i` that exist and are not bad frames.
    fn neighbours(&self, i: usize) -> Vec<(i64, usize)> {
        let n = self.input.len() as i64;
        self.params
            .offsets
            .iter()
            .filter_map(|&o| {
                let j = i as i64 + o;
                ((0..n).contains(&j) && !self.input.is_bad(j as usize)).then_some((o, j as usize))
            })
            .collect()
    }

    /// The frame pairs `(a, b)`, `a < b`, whose fits frame `i` needs (one per neighbour).
    fn pairs_of(&self, i: usize) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.neighbours(i)
            .into_iter()
            .map(move |(_, j)| (i.min(j), i.max(j)))
    }

    /// The fits and residuals of the pairs `keys` (computed in parallel, each once, in both
    /// directions when the later frame needs the earlier), with the frames in `loaded`.
    fn compute_pairs(
        &self,
        keys: &[(usize, usize)],
        loaded: &HashMap<usize, GrayDepth>,
        cam: &PinholeCamera,
        flow: &DisFlow,
    ) -> Result<Vec<((usize, usize), PairResiduals)>> {
        let out: Vec<Result<((usize, usize), PairResiduals)>> = keys
            .par_iter()
            .map(|&(a, b)| {
                let ga = get_loaded(loaded, a)?;
                let gb = get_loaded(loaded, b)?;
                let backward = self.neighbours(b).iter().any(|&(_, j)| j == a);
                let prior = self.prior(a, b);
                let pair = dynapix_motion::pair_residuals_with_prior(
                    &rigid_frame(ga, 0),
                    &rigid_frame(gb, b as i64 - a as i64),
                    cam,
                    flow,
                    &self.params,
                    backward,
                    prior.as_ref(),
                )
                .map_err(|e| Error::Input(format!("frames {a} and {b}: rigidity: {e}")))?;
                if !matches!(pair.choice, PriorChoice::NoPrior | PriorChoice::Agrees) {
                    let inliers = pair.fit.as_ref().map_or(0, |f| f.inliers);
                    tracing::debug!(
                        target: "dynapix::rigidity",
                        "pair {a}-{b}: {:?} ({inliers} inliers)",
                        pair.choice
                    );
                }
                Ok(((a, b), pair))
            })
            .collect();
        out.into_iter().collect()
    }

    /// P of frame `i` from the shared pairs in `pairs` (which must hold every pair of
    /// [`RigidityJob::pairs_of`]): the earlier frame of a pair takes its forward residual,
    /// the later one its backward residual, under the inverse motion.
    fn frame_from_pairs(
        &self,
        i: usize,
        pairs: &HashMap<(usize, usize), PairResiduals>,
        cam: &PinholeCamera,
    ) -> Result<(FloatImage, RigidityStats)> {
        let mut per = Vec::new();
        let mut choices = Vec::new();
        for (o, j) in self.neighbours(i) {
            let key = (i.min(j), i.max(j));
            let pair = pairs
                .get(&key)
                .ok_or_else(|| Error::Input(format!("rigidity: pair {key:?} not computed")))?;
            choices.push(pair.choice);
            // The residual images are borrowed, not copied.
            per.push(if j > i {
                (o, pair.fit.clone(), pair.forward.as_ref())
            } else {
                (o, pair.inverse_fit(), pair.backward.as_ref())
            });
        }
        let maps = dynapix_motion::rigidity_from_pairs(per, (cam.width, cam.height), &self.params)
            .map_err(|e| Error::Input(format!("frame {i}: rigidity: {e}")))?;
        Ok((maps.p, RigidityStats::of(&maps.fits).with_choices(choices)))
    }

    /// P of frame `i` with the frames in `loaded` (which must hold `i` and its neighbours),
    /// each frame computing its own flows.
    fn frame_with(
        &self,
        i: usize,
        loaded: &HashMap<usize, GrayDepth>,
        cam: &PinholeCamera,
        flow: &DisFlow,
    ) -> Result<(FloatImage, RigidityStats)> {
        let cur = get_loaded(loaded, i)?;
        let nbs: Vec<(i64, GrayDepth)> = self
            .neighbours(i)
            .into_iter()
            .map(|(o, j)| Ok((o, get_loaded(loaded, j)?.clone())))
            .collect::<Result<_>>()?;
        let frames: Vec<RigidFrame<'_>> = nbs.iter().map(|(o, g)| rigid_frame(g, *o)).collect();
        let priors: Vec<Option<Se3>> = self
            .neighbours(i)
            .into_iter()
            .map(|(_, j)| self.prior(i, j))
            .collect();
        let me = rigid_frame(cur, 0);
        let maps = dynapix_motion::rigidity_probability_with_priors(
            &me,
            &frames,
            &priors,
            cam,
            flow,
            &self.params,
        )
        .map_err(|e| Error::Input(format!("frame {i}: rigidity: {e}")))?;
        Ok((maps.p, RigidityStats::of(&maps.fits)))
    }

    /// P of frame `i` (loads the frame and its neighbours).
    pub fn frame(&self, i: usize) -> Result<FloatImage> {
        let mut loaded = HashMap::new();
        loaded.insert(i, self.load(i)?);
        for (_, j) in self.neighbours(i) {
            loaded.insert(j, self.load(j)?);
        }
        let cam = self.input.camera.pinhole();
        let flow = self.params.flow_for_width(cam.width);
        if self.params.shared_pairs {
            let keys: Vec<(usize, usize)> = self.pairs_of(i).collect();
            let pairs = self.compute_pairs(&keys, &loaded, &cam, &flow)?;
            let pairs: HashMap<_, _> = pairs.into_iter().collect();
            return Ok(self.frame_from_pairs(i, &pairs, &cam)?.0);
        }
        Ok(self.frame_with(i, &loaded, &cam, &flow)?.0)
    }

    /// Computes every frame, in parallel chunks in frame order (each frame's images are
    /// decoded once per chunk that needs them); `each` gets every frame's P on the thread
    /// that computed it (so writing the maps is parallel too), in no particular order within
    /// a chunk. With [`RigidityParams::shared_pairs`], the pairs a chunk needs are computed
    /// first, each once, and kept until their later frame is done. The first error in frame
    /// order is returned. Bad frames ([`Input::bad_frames`]) get no map.
    pub fn run(
        &self,
        progress: &dyn Progress,
        label: &str,
        each: impl Fn(usize, FloatImage) -> Result<()> + Sync,
    ) -> Result<RigidityStats> {
        self.params
            .validate()
            .map_err(|e| Error::config(format!("motion.rigidity: {e}")))?;
        let n = self.input.len();
        let cam = self.input.camera.pinhole();
        let flow = self.params.flow_for_width(cam.width);
        // Frames in parallel chunks, in order; every chunk ends with all threads waiting for
        // its slowest frame, so chunks are long (32 frames on 2 threads: 8 made the threads
        // wait measurably). What a frame gets does not depend on the chunking.
        let chunk = 16 * rayon::current_num_threads().max(1);
        let all: Vec<usize> = (0..n).filter(|&i| !self.input.is_bad(i)).collect();
        let task = Task::begin(progress, label, all.len());
        let mut loaded: HashMap<usize, GrayDepth> = HashMap::new();
        let mut pairs: HashMap<(usize, usize), PairResiduals> = HashMap::new();
        let mut stats = RigidityStats::default();
        for frames in all.chunks(chunk) {
            let mut need: Vec<usize> = frames
                .iter()
                .flat_map(|&i| {
                    std::iter::once(i).chain(self.neighbours(i).into_iter().map(|(_, j)| j))
                })
                .collect();
            need.sort_unstable();
            need.dedup();
            loaded.retain(|k, _| need.binary_search(k).is_ok());
            let missing: Vec<usize> = need
                .into_iter()
                .filter(|k| !loaded.contains_key(k))
                .collect();
            // Collected before the first error is taken, so the error is the same every run.
            let new: Vec<Result<(usize, GrayDepth)>> = missing
                .par_iter()
                .map(|&k| Ok((k, self.load(k)?)))
                .collect();
            for r in new {
                let (k, g) = r?;
                loaded.insert(k, g);
            }
            if self.params.shared_pairs {
                let mut keys: Vec<(usize, usize)> =
                    frames.iter().flat_map(|&i| self.pairs_of(i)).collect();
                keys.sort_unstable();
                keys.dedup();
                keys.retain(|k| !pairs.contains_key(k));
                pairs.extend(self.compute_pairs(&keys, &loaded, &cam, &flow)?);
            }
            let out: Vec<Result<RigidityStats>> = frames
                .par_iter()
                .map(|&i| {
                    let (p, s) = if self.params.shared_pairs {
                        self.frame_from_pairs(i, &pairs, &cam)?
                    } else {
                        self.frame_with(i, &loaded, &cam, &flow)?
                    };
                    each(i, p)?;
                    Ok(s)
                })
                .collect();
            for s in out {
                stats.add(s?);
                task.step("");
            }
            // Both frames of a pair are done once its later frame is.
            if let Some(&last) = frames.last() {
                pairs.retain(|&(_, b), _| b > last);
            }
        }
        Ok(stats)
    }
}

/// Frame `k` of `loaded`, or an error naming it.
fn get_loaded(loaded: &HashMap<usize, GrayDepth>, k: usize) -> Result<&GrayDepth> {
    loaded
        .get(&k)
        .ok_or_else(|| Error::Input(format!("rigidity: frame {k} not loaded")))
}

/// The rigidity view of a loaded frame at `offset`.
fn rigid_frame(g: &GrayDepth, offset: i64) -> RigidFrame<'_> {
    RigidFrame {
        gray: &g.0,
        depth: &g.1,
        offset,
    }
}

/// The rigidity maps of `job`, with the cache folder `root` when given: a folder
/// `rigidity-<key>` is reused when its record matches the job exactly and every map exists,
/// else the maps are computed and written there as they come. Without a cache they go to a
/// temporary file the run owns and nothing else is written.
pub fn cached_rigidity(
    job: &RigidityJob<'_>,
    root: Option<&Path>,
    label: &str,
    progress: &dyn Progress,
) -> Result<MapSet> {
    let config = job.record();
    let cache = root.map(|r| MapFolder::in_cache(r, "rigidity", job.input, &config));
    let reused = cache.as_ref().is_some_and(|c| c.2);
    let spilled = if reused {
        None
    } else {
        compute_rigidity(job, cache.as_ref().map(|c| &c.0), &config, label, progress)?
    };
    let source = match (&cache, reused) {
        (None, _) => "computed (no cache)",
        (Some(_), true) => "cache (key matched)",
        (Some(_), false) => "computed",
    };
    let (folder, key) = match cache {
        Some((f, k, _)) => (Some(f), Some(k)),
        None => (None, None),
    };
    Ok(MapSet {
        record: json!({
            "source": source,
            "dir": folder.as_ref().map(|f| &f.dir),
            "key": key,
            "config": config,
        }),
        folder,
        spilled,
        ground_truth: Some(false),
    })
}

/// Computes the rigidity maps of `job` into `folder` when given (recorded complete at the
/// end), else into a temporary file (returned).
fn compute_rigidity(
    job: &RigidityJob<'_>,
    folder: Option<&MapFolder>,
    config: &Value,
    label: &str,
    progress: &dyn Progress,
) -> Result<Option<crate::spill::SpilledMaps>> {
    let _phase = tracing::info_span!(target: "dynapix::phase", "rigidity maps").entered();
    if let Some(f) = folder {
        f.write_record(job.input, config, MapsStatus::Running, Value::Null)?;
    }
    let started = std::time::Instant::now();
    let sink = MapSink::new(job.input, folder)?;
    let stats = job.run(progress, label, |i, p| {
        sink.put(i, &MotionProbability::new(p))
    })?;
    if let Some(f) = folder {
        f.write_record(
            job.input,
            config,
            MapsStatus::Complete,
            json!({
                "frames_computed": job.input.len() - job.input.bad_frames().len(),
                "seconds": started.elapsed().as_secs_f64(),
                "threads": rayon::current_num_threads(),
                "fits": stats,
            }),
        )?;
    }
    Ok(sink.finish())
}

/// The inputs of the geometric cue for a sequence: the depth of the frames at the working
/// resolution (all of them, or a window around the frames being computed), the frame times
/// and the poses of the pass before.
pub struct GeometricInput {
    /// Every frame's depth slot; a slot outside the window holds an empty image and is
    /// marked not loaded.
    depths: std::sync::RwLock<(Vec<WorkingDepth>, Vec<bool>)>,
    stamps: Vec<f64>,
    poses: Vec<Option<Se3>>,
    camera: PinholeCamera,
    params: StaticDepthParams,
}

impl GeometricInput {
    /// Reads every frame's depth (in parallel) and takes the poses; a bad frame
    /// ([`Input::bad_frames`]) is left out (no depth, no pose).
    pub fn load(input: &Input, poses: &FramePoses, params: &StaticDepthParams) -> Result<Self> {
        let g = Self::windowed(input, poses, params)?;
        let all: Vec<usize> = (0..input.len()).collect();
        g.prepare(input, &all)?;
        Ok(g)
    }

    /// Takes the poses and reads no depth yet: [`GeometricInput::prepare`] reads the depths a
    /// group of frames needs and drops the others, so memory holds a window of frames, not
    /// the sequence.
    pub fn windowed(input: &Input, poses: &FramePoses, params: &StaticDepthParams) -> Result<Self> {
        params
            .validate()
            .map_err(|e| Error::config(format!("motion.static_depth: {e}")))?;
        let n = input.len();
        if poses.poses.len() != n {
            return Err(Error::Input(format!(
                "geometric cue: {} poses for {n} frames",
                poses.poses.len()
            )));
        }
        let empty = || WorkingDepth {
            factor: 1,
            full_size: (0, 0),
            depth: FloatImage::new(0, 0),
        };
        Ok(Self {
            depths: std::sync::RwLock::new(((0..n).map(|_| empty()).collect(), vec![false; n])),
            stamps: input.timestamps(),
            poses: (poses.poses.iter().enumerate())
                .map(|(i, p)| (!input.is_bad(i)).then_some(*p))
                .collect(),
            camera: input.camera.pinhole(),
            params: params.clone(),
        })
    }

    /// The frames whose depth the geometric cue of `frames` reads: each frame and the views
    /// it selects (the selection of [`geometric_frame`], which depends on times and poses
    /// only), sorted.
    fn needed(&self, frames: &[usize]) -> Vec<usize> {
        let n = self.stamps.len();
        let usable = |s: usize| matches!(self.poses.get(s), Some(Some(_))) && s < n;
        let mut need: Vec<usize> = frames
            .iter()
            .flat_map(|&t| {
                std::iter::once(t).chain(select_views(&self.stamps, t, usable, &self.params))
            })
            .filter(|&s| s < n)
            .collect();
        need.sort_unstable();
        need.dedup();
        need
    }

    /// Reads (in parallel) the depths that the geometric cue of `frames` needs and not yet
    /// read, and drops every other depth.
    pub fn prepare(&self, input: &Input, frames: &[usize]) -> Result<()> {
        let need = self.needed(frames);
        let missing: Vec<usize> = {
            let d = self
                .depths
                .read()
                .map_err(|_| Error::Input("geometric cue: a worker thread panicked".into()))?;
            need.iter().copied().filter(|&k| !d.1[k]).collect()
        };
        let cam = &self.camera;
        let params = &self.params;
        let new = missing
            .par_iter()
            .map(|&i| {
                if input.is_bad(i) {
                    let zero = FloatImage::new(cam.width, cam.height);
                    return Ok((i, WorkingDepth::new(&zero, params)));
                }
                let d = input.load_depth(i)?;
                Ok((i, WorkingDepth::new(&d, params)))
            })
            .collect::<Vec<Result<_>>>()
            .into_iter()
            .collect::<Result<Vec<_>>>()?;
        let mut d = self
            .depths
            .write()
            .map_err(|_| Error::Input("geometric cue: a worker thread panicked".into()))?;
        let (depths, loaded) = &mut *d;
        for (k, (depth, held)) in depths.iter_mut().zip(loaded.iter_mut()).enumerate() {
            if *held && need.binary_search(&k).is_err() {
                depth.depth = FloatImage::new(0, 0);
                *held = false;
            }
        }
        for (k, w) in new {
            depths[k] = w;
            loaded[k] = true;
        }
        Ok(())
    }

    /// Number of frames whose depth is held now.
    #[cfg(test)]
    pub fn frames_held(&self) -> usize {
        self.depths
            .read()
            .map_or(0, |d| d.1.iter().filter(|&&l| l).count())
    }

    /// The geometric cue of frame `i` (full resolution); its depth and its views' must have
    /// been read ([`GeometricInput::prepare`]).
    pub fn frame(&self, i: usize) -> Result<FloatImage> {
        let d = self
            .depths
            .read()
            .map_err(|_| Error::Input("geometric cue: a worker thread panicked".into()))?;
        if !d.1.get(i).copied().unwrap_or(false) {
            return Err(Error::Input(format!(
                "frame {i}: geometric cue: its depth was not read"
            )));
        }
        geometric_frame(
            &self.camera,
            i,
            &self.stamps,
            &self.poses,
            &d.0,
            &self.params,
        )
        .map_err(|e| Error::Input(format!("frame {i}: geometric cue: {e}")))
    }
}
