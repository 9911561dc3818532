//! The offline runner (paper §3, offline schedule): sequence → first pass → motion maps →
//! weighted pass(es), all in this process.
//!
//! - The **first pass** ([`FirstPass`]: the method's SLAM weighted by the pose-free rigidity
//!   cue in paper mode, plain ORB-SLAM2 in reference mode) gives the poses of the first maps
//!   when they come from the system itself ([`PoseSource::Own`]); its trajectory is cached by
//!   a hash of what determines it (frames, camera, SLAM parameters, rigidity maps,
//!   vocabulary, seed).
//! - The **rigidity maps** need no poses: computed once per sequence and cached
//!   ([`crate::cues`]).
//! - The **motion maps** of weighted pass k are computed by [`crate::maps`] with the poses of
//!   pass k − 1 (pass 0 = the first pass), or with fixed poses (ground truth, a file) for
//!   every pass; they are cached by a hash of everything that determines them, and a
//!   sequence's own `prob/` folder is used for the first weighted pass when present (its
//!   `motion.json` tells whether ground truth made it).
//! - **Weighted passes**: `passes.weighted` of them (paper mode 2, reference mode 1 = the
//!   paper's schedule); P of each combines the enabled cues ([`crate::Cues`]) by noisy-or.
//!
//! Everything is passed within the process: the maps of a pass are kept in their stored
//! 16-bit form in the cache folder, or without a cache ([`RunOptions::cache_dir`] `None`) in
//! a temporary file the run owns ([`crate::store`], [`crate::spill`]), so a run with a fresh
//! cache, a run from the cache and a run without a cache track with the same weights. A pass
//! reads each frame's map when it reaches it; what is kept in memory per frame is small
//! (poses, statuses, counters), so memory does not grow with the sequence beyond that.
//!
//! Nothing here parses command lines or prints; progress goes to a [`Progress`] callback and
//! the outputs (trajectories, status, the provenance record) are returned for the caller to
//! write.

pub use crate::pass::FirstPassResult;
use std::path::{Path, PathBuf};

use dynapix_io::Trajectory;
use serde_json::{Value, json};

use crate::config::{Config, FirstPass, PoseSource};
use crate::cues::{RigidityJob, cached_rigidity};
use crate::error::{Error, Result};
use crate::hash::Fnv64;
use crate::input::Input;
use crate::maps::{MapFolder, MapJob, MapSet, as_read_back, cached_maps};
use crate::method::{Method, Terms};
use crate::observe::RunObserver;
use crate::poses::{FramePoses, as_written};
use crate::progress::Progress;
use crate::record::{
    FileFingerprint, MapsStatus, PassCacheRecord, PassRecord, RunRecord, WeightingRecord,
};
use crate::slam::{
    PassOutput, PassWeights, SlamSession, Watch, load_vocabulary, run_pass_observed,
};

/// Version of the SLAM passes, part of the first-pass cache key: bump it when a change of
/// the SLAM system changes trajectories without changing a parameter.
pub const SLAM_PASS_VERSION: u32 = 2;

/// Options of a run that are about files, not about the method.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Cache of first passes and motion maps: what is found there is reused, what is
    /// computed is written there as a side effect. `None`: no cache, nothing is written
    /// (everything is computed in memory). Callers that want the usual place give
    /// [`RunOptions::default_cache_dir`] (`<sequence>/dynapix_cache`, or a folder under the user's cache
    /// directory when the sequence folder cannot be written).
    pub cache_dir: Option<PathBuf>,
    /// Ignore the sequence's own `prob/` folder and compute the maps.
    pub recompute_maps: bool,
    /// DynaPix+ masks (8-bit, non-zero = dynamic class) named like the rgb images; default
    /// `<sequence>/mask`.
    pub masks_dir: Option<PathBuf>,
    /// Frames without a probability map run unweighted (counted) instead of failing.
    pub allow_missing_maps: bool,
    /// The first pass's trajectory when the caller already has it (e.g. an ORB-SLAM2 run of
    /// the same configuration), as read from its `trajectory.txt`.
    pub first_pass: Option<Trajectory>,
}

impl RunOptions {
    /// The usual cache folder of the sequence folder `seq_dir`: `<seq_dir>/dynapix_cache` when
    /// it can be written, else a folder under the user's cache directory.
    pub fn default_cache_dir(seq_dir: &Path) -> PathBuf {
        default_cache_dir(seq_dir)
    }

    /// True when the user's cache directory is the temporary directory (no `HOME` nor
    /// `XDG_CACHE_HOME`), so a default cache outside the sequence folder does not last.
    pub fn user_cache_is_temporary() -> bool {
        user_cache_is_temporary()
    }
}

/// The default cache of the sequence in `seq_dir`: `<seq_dir>/dynapix_cache` when it (or, before
/// it exists, `seq_dir`) can be written, else `dynapix/<folder name>-<hash of its path>` under
/// the user's cache directory (`$XDG_CACHE_HOME`, else `$HOME/.cache`, else the temporary
/// directory), so read-only datasets need no `--cache`.
pub(crate) fn default_cache_dir(seq_dir: &Path) -> PathBuf {
    cache_dir_for(seq_dir, writable, &user_cache_root())
}

/// [`default_cache_dir`] with the writability test and the user cache root given.
fn cache_dir_for(seq_dir: &Path, writable: impl Fn(&Path) -> bool, user_root: &Path) -> PathBuf {
    let local = seq_dir.join("dynapix_cache");
    let probe = if local.exists() { &local } else { seq_dir };
    if writable(probe) {
        return local;
    }
    let canonical = seq_dir
        .canonicalize()
        .unwrap_or_else(|_| seq_dir.to_path_buf());
    let mut h = Fnv64::new();
    h.write(canonical.as_os_str().as_encoded_bytes());
    let name = canonical
        .file_name()
        .map_or_else(|| "sequence".into(), |n| n.to_string_lossy().into_owned());
    user_root
        .join("dynapix")
        .join(format!("{name}-{}", h.hex()))
}

/// The user's cache directory: `$XDG_CACHE_HOME`, else `$HOME/.cache`, else the temporary
/// directory.
fn user_cache_root() -> PathBuf {
    let from = |var: &str| {
        std::env::var_os(var)
            .map(PathBuf::from)
            .filter(|p| p.is_absolute())
    };
    from("XDG_CACHE_HOME")
        .or_else(|| from("HOME").map(|h| h.join(".cache")))
        .unwrap_or_else(std::env::temp_dir)
}

/// True when the user's cache directory is the temporary directory (no `HOME` nor
/// `XDG_CACHE_HOME`).
pub(crate) fn user_cache_is_temporary() -> bool {
    user_cache_root() == std::env::temp_dir()
}

/// Checks, before any work, that the cache folder `dir` can be written (created when
/// missing), so an unwritable cache stops a run before it starts, not after its first pass.
pub(crate) fn check_cache_dir(dir: &Path) -> Result<()> {
    dynapix_io::output::check_writable_dir(dir).map_err(|e| {
        Error::Input(format!(
            "the cache {} cannot be used: {}; pass --cache DIR with a writable folder",
            dir.display(),
            e.reason()
        ))
    })
}

/// Whether `dir` may be written by this process and is not marked read-only (see
/// `writable`): a sequence folder that is not is never written into.
pub fn folder_writable(dir: &Path) -> bool {
    writable(dir)
}

/// Whether this process may create files in `dir` (the effective permissions, read-only
/// mounts included), and the folder is not marked read-only for everyone (a privileged user
/// could write there, but the dataset says it is not to be written).
fn writable(dir: &Path) -> bool {
    if std::fs::metadata(dir).is_ok_and(|m| m.permissions().readonly()) {
        return false;
    }
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        let Ok(c) = std::ffi::CString::new(dir.as_os_str().as_bytes()) else {
            return false;
        };
        // SAFETY: `c` is a valid NUL-terminated string that outlives the call.
        unsafe { libc::access(c.as_ptr(), libc::W_OK) == 0 }
    }
    #[cfg(not(unix))]
    {
        dir.is_dir()
    }
}

/// Writes a first pass into its cache folder `dir`: `trajectory.txt`, then `pass.json`
/// (the completion record: the key document `doc`, the pose count, the trajectory file's
/// size and checksum).
fn write_first_pass_cache(dir: &Path, doc: &Value, out: &PassOutput) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| dynapix_io::IoError::io(dir, e))?;
    let traj_path = dir.join("trajectory.txt");
    out.trajectory.write_tum(&traj_path)?;
    let bytes = std::fs::read(&traj_path).map_err(|e| dynapix_io::IoError::io(&traj_path, e))?;
    PassCacheRecord {
        config: doc.clone(),
        status: MapsStatus::Complete,
        stats: out.stats,
        poses: Some(out.trajectory.len() as u64),
        trajectory: Some(FileFingerprint::of(&bytes)),
    }
    .write_in(dir)
}

/// The cached first-pass trajectory in `dir` when its record says `doc` and the file is the
/// one recorded (size, checksum, pose count); `None` when there is none, with a warning when
/// there is one that is damaged (the pass is then run again).
fn read_cached_first_pass(dir: &Path, doc: &Value) -> Option<Trajectory> {
    let rec_path = dir.join(PassCacheRecord::FILE);
    let traj_path = dir.join("trajectory.txt");
    let parsed = PassCacheRecord::read_in(dir)?;
    let check = || -> std::result::Result<Trajectory, String> {
        let rec = parsed?;
        if !as_read_back(doc).eq(&rec.config) || rec.status != MapsStatus::Complete {
            return Err(format!(
                "{} does not describe a complete first pass of this key",
                rec_path.display()
            ));
        }
        let (Some(poses), Some(expected)) = (rec.poses, rec.trajectory) else {
            return Err(format!(
                "{} lists no pose count or checksum (written by an older version)",
                rec_path.display()
            ));
        };
        let bytes =
            std::fs::read(&traj_path).map_err(|e| format!("{}: {e}", traj_path.display()))?;
        if FileFingerprint::of(&bytes) != expected {
            return Err(format!(
                "{}: {} bytes, not the {} bytes with the checksum the record lists",
                traj_path.display(),
                bytes.len(),
                expected.bytes
            ));
        }
        let t = Trajectory::read_tum(&traj_path).map_err(|e| e.to_string())?;
        if t.len() as u64 != poses {
            return Err(format!(
                "{}: {} poses, the record says {poses}",
                traj_path.display(),
                t.len()
            ));
        }
        Ok(t)
    };
    match check() {
        Ok(t) => Some(t),
        Err(why) => {
            tracing::warn!("the cached first pass is damaged ({why}); running it again");
            None
        }
    }
}

/// What an offline run produced.
#[derive(Clone, Debug)]
pub struct OfflineOutput {
    /// The first pass, when one was needed.
    pub first_pass: Option<FirstPassResult>,
    /// The maps of every weighted pass.
    pub maps: Vec<MapSet>,
    /// The passes: the weighted passes in order, or the single ORB-SLAM2 pass.
    pub passes: Vec<PassOutput>,
    /// The provenance record of the run (the body of `run.json`, without results).
    pub record: RunRecord,
}

impl OfflineOutput {
    /// The last pass (the run's result; a run always has one).
    pub fn final_pass(&self) -> Option<&PassOutput> {
        self.passes.last()
    }

    /// The maps of the last weighted pass.
    pub fn final_maps(&self) -> Option<&MapSet> {
        self.maps.last()
    }
}

/// Runs one method offline on one sequence.
pub struct OfflineRunner<'a> {
    config: &'a Config,
    /// The input of this runner, with a decoded-frame cache of its own ([`Input::for_run`]):
    /// runners that share an input (`experiment --jobs`) never switch each other's cache.
    input: Input,
    options: RunOptions,
    /// The rigidity maps, once computed or found (they need no poses: one set per runner).
    rigidity: std::sync::OnceLock<MapSet>,
    /// The first pass, once run or found (the same for every run of the runner).
    first: std::sync::OnceLock<FirstPassResult>,
    /// Who watches the passes ([`OfflineRunner::with_observer`]), and the passes run so far.
    observer: Option<(
        std::sync::Arc<dyn RunObserver>,
        std::sync::atomic::AtomicUsize,
    )>,
}

impl<'a> OfflineRunner<'a> {
    /// A runner for `config` on `input`; checks the configuration and the method's inputs
    /// (DynaPix+ masks).
    pub fn new(config: &'a Config, input: &'a Input, options: RunOptions) -> Result<Self> {
        config.validate()?;
        // Only runs that cache (DynaPix: first pass and maps) need it, so an ORB-SLAM2 run
        // creates no cache folder.
        if config.method.terms().is_some()
            && let Some(dir) = &options.cache_dir
        {
            check_cache_dir(dir)?;
        }
        let r = Self {
            config,
            input: input.for_run(),
            options,
            rigidity: std::sync::OnceLock::new(),
            first: std::sync::OnceLock::new(),
            observer: None,
        };
        if config.method.needs_masks() {
            let d = r.masks_dir();
            if !d.is_dir() {
                return Err(Error::Input(format!(
                    "dynapix+ needs semantic masks: {} is not a folder (pass --masks DIR)",
                    d.display()
                )));
            }
        }
        Ok(r)
    }

    /// Shows every SLAM pass of the runner to `observer` (numbered from 1 in the order they
    /// run); the results are the same as without it.
    pub fn with_observer(mut self, observer: std::sync::Arc<dyn RunObserver>) -> Self {
        self.observer = Some((observer, std::sync::atomic::AtomicUsize::new(0)));
        self
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        self.config
    }

    /// The input this runner reads: the caller's, with a decoded-frame cache of the run's
    /// own ([`Input::for_run`]; e.g. [`Input::decoded_peak_bytes`] of this run).
    pub fn input(&self) -> &Input {
        &self.input
    }

    /// The cache folder, when the run has one ([`RunOptions::cache_dir`]).
    pub fn cache_dir(&self) -> Option<&Path> {
        self.options.cache_dir.as_deref()
    }

    /// The DynaPix+ mask folder.
    pub fn masks_dir(&self) -> PathBuf {
        self.options
            .masks_dir
            .clone()
            .unwrap_or_else(|| self.input.sequence.dir.join("mask"))
    }

    /// One SLAM pass with the method's weighting (`maps` = `None` runs unweighted ORB-SLAM2)
    /// and relocalisation seed `seed`, shown to the observer as a run's last pass
    /// ([`crate::PassInfo::last`]).
    pub fn pass(
        &self,
        method: Method,
        maps: Option<&MapSet>,
        seed: u64,
        label: &str,
        progress: &dyn Progress,
    ) -> Result<PassOutput> {
        self.pass_watched(method, maps, seed, label, progress, true)
    }

    /// [`OfflineRunner::pass`], shown to the observer as the run's last pass when `last`.
    fn pass_watched(
        &self,
        method: Method,
        maps: Option<&MapSet>,
        seed: u64,
        label: &str,
        progress: &dyn Progress,
        last: bool,
    ) -> Result<PassOutput> {
        let _phase = tracing::info_span!(target: "dynapix::phase", "SLAM passes").entered();
        let config = self.config.clone().with_method(method);
        let mut params = config.system_params();
        params.tracking.reloc.seed = params.tracking.reloc.seed.wrapping_add(seed);
        let vocabulary = load_vocabulary(&config.slam.vocabulary)?;
        let mut session = SlamSession::new(&self.input.camera, params, vocabulary)?;
        let weights = match maps {
            None => PassWeights::None,
            Some(m) => PassWeights::Maps {
                maps: m,
                threshold: method.thresholds().then_some(config.dynapix.gamma_add),
                allow_missing: self.options.allow_missing_maps,
            },
        };
        let masks = method.needs_masks().then(|| self.masks_dir());
        let watch = self.observer.as_ref().map(|(o, n)| Watch {
            observer: o.as_ref(),
            number: n.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1,
            last,
        });
        run_pass_observed(
            &self.input,
            &mut session,
            weights,
            masks.as_deref(),
            label,
            progress,
            watch,
        )
    }

    /// The sequence's rigidity maps (cached), when the run uses them: for the rigidity cue or
    /// the rigidity first pass.
    pub fn rigidity_maps(&self, progress: &dyn Progress) -> Result<Option<MapSet>> {
        let c = self.config;
        let wanted = c.method.terms().is_some()
            && (c.cues().rigidity || c.passes.first == FirstPass::Rigidity);
        if !wanted {
            return Ok(None);
        }
        if let Some(m) = self.rigidity.get() {
            return Ok(Some(m.clone()));
        }
        let _ = self.input.bad_frames();
        let job = RigidityJob::new(&self.input, c.motion.rigidity.clone());
        let maps = cached_rigidity(&job, self.cache_dir(), "rigidity maps", progress)?;
        Ok(Some(self.rigidity.get_or_init(|| maps).clone()))
    }

    /// The cache key document of the first pass.
    fn first_pass_record(&self) -> Value {
        let c = self.config;
        let (params, weights) = match c.passes.first {
            FirstPass::Orbslam2 => (c.orbslam2_params(), Value::Null),
            FirstPass::Rigidity => (
                c.system_params(),
                RigidityJob::new(&self.input, c.motion.rigidity.clone()).record(),
            ),
        };
        let mut r = json!({
            "kind": c.passes.first,
            "version": SLAM_PASS_VERSION,
            "frames_hash": self.input.frames_hash(),
            "frames": self.input.len(),
            "camera": self.input.camera.record(),
            "depth_validity": self.input.sequence.depth_validity,
            "params": params,
            "weights": weights,
            "method": c.method.name(),
            "vocabulary": c.slam.vocabulary,
            "seed": c.slam.seed,
        });
        if let Some(b) = self.input.bad_frames_record() {
            r["bad_frames_skipped"] = b;
        }
        r
    }

    /// The first pass: given by the caller, found in the cache, or run now (and cached).
    pub fn first_pass(&self, progress: &dyn Progress) -> Result<FirstPassResult> {
        if let Some(t) = &self.options.first_pass {
            return Ok(FirstPassResult {
                trajectory: t.clone(),
                output: None,
                record: json!({"source": "given by the caller"}),
            });
        }
        if let Some(f) = self.first.get() {
            return Ok(f.clone());
        }
        let doc = self.first_pass_record();
        let key = Fnv64::of(doc.to_string().as_bytes());
        let dir = self
            .cache_dir()
            .map(|c| c.join(format!("first-pass-{key}")));
        if let Some(dir) = &dir
            && let Some(trajectory) = read_cached_first_pass(dir, &doc)
        {
            return Ok(FirstPassResult {
                trajectory,
                output: None,
                record: json!({"source": "cache (key matched)", "dir": dir, "key": key}),
            });
        }
        let out = match self.config.passes.first {
            FirstPass::Orbslam2 => self.pass_watched(
                Method::Orbslam2,
                None,
                self.config.slam.seed,
                "first pass (orbslam2)",
                progress,
                false,
            )?,
            FirstPass::Rigidity => {
                let rigidity = self
                    .rigidity_maps(progress)?
                    .ok_or_else(|| Error::Input("the rigidity first pass needs maps".into()))?;
                let method = match self.config.method {
                    Method::Orbslam2 => Method::Dynapix,
                    m => m,
                };
                self.pass_watched(
                    method,
                    Some(&rigidity),
                    self.config.slam.seed,
                    "first pass (rigidity)",
                    progress,
                    false,
                )?
            }
        };
        let source = match &dir {
            Some(dir) => {
                write_first_pass_cache(dir, &doc, &out)?;
                "computed"
            }
            None => "computed (no cache)",
        };
        let result = FirstPassResult {
            trajectory: as_written(&out.trajectory)?,
            record: json!({"source": source, "dir": dir, "key": key, "stats": out.stats}),
            output: Some(out),
        };
        Ok(self.first.get_or_init(|| result).clone())
    }

    /// Poses for the maps of weighted pass `k` (1-based): the configured fixed source, or the
    /// trajectory of the previous pass (`previous`, as written) for [`PoseSource::Own`].
    fn poses_for(&self, k: usize, previous: Option<&Trajectory>) -> Result<FramePoses> {
        let stamps = self.input.timestamps();
        let gap = self.config.motion.max_pose_gap;
        if !MapJob::needs_poses(&self.input, self.config) {
            return Ok(FramePoses::unused(stamps.len()));
        }
        let (poses, missing) = crate::poses::from_source(
            &self.config.motion.poses,
            &self.input.sequence,
            &stamps,
            gap,
            || {
                let prev = previous.ok_or_else(|| {
                    Error::Input(format!("no trajectory before weighted pass {k}"))
                })?;
                Ok((k - 1, prev.clone()))
            },
        )?;
        poses.complete(&missing, &stamps, gap)
    }

    /// The maps of weighted pass `k` (1-based) with `poses`: the sequence's own `prob/` for
    /// the first pass when allowed, else from the cache or computed.
    fn maps_for(&self, k: usize, poses: &FramePoses, progress: &dyn Progress) -> Result<MapSet> {
        let job = MapJob::new(&self.input, self.config, poses);
        let rigidity = if !self.config.cues().rigidity {
            None
        } else if job.rigidity_pose_prior {
            let label = format!("rigidity maps with pose priors (pass {k})");
            Some(cached_rigidity(
                &job.rigidity_job(),
                self.cache_dir(),
                &label,
                progress,
            )?)
        } else {
            self.rigidity_maps(progress)?
        };
        let job = job.with_rigidity(rigidity);
        let label = format!("motion maps (pass {k})");
        cached_maps(&job, self.cache_dir(), &label, progress)
    }

    /// The sequence's own maps, when this run uses them for the first weighted pass.
    fn sequence_maps(&self) -> Result<Option<MapSet>> {
        let own = self.input.sequence.prob_dir.clone();
        let usable = self.config.method.terms() == Some(Terms::Full)
            && !self.options.recompute_maps
            && own.is_dir();
        if !usable {
            return Ok(None);
        }
        MapSet::existing(MapFolder::new(own), "sequence prob/ folder").map(Some)
    }

    /// The first pass (when needed) and the maps of the first weighted pass, without the
    /// weighted pass itself (what a batch of runs prepares once). `None` for ORB-SLAM2.
    pub fn prepare(
        &self,
        progress: &dyn Progress,
    ) -> Result<(Option<FirstPassResult>, Option<MapSet>)> {
        if self.config.method.terms().is_none() {
            return Ok((None, None));
        }
        // Bad frames are found once, here, before any parallel work asks for them.
        let _ = self.input.bad_frames();
        if let Some(m) = self.sequence_maps()? {
            return Ok((None, Some(m)));
        }
        let needs_first = MapJob::needs_poses(&self.input, self.config)
            && self.config.motion.poses == PoseSource::Own;
        let first = if needs_first {
            Some(self.first_pass(progress)?)
        } else {
            None
        };
        if let Some(f) = first.as_ref().filter(|f| f.trajectory.is_empty()) {
            return Err(Error::NothingTracked(Box::new(f.clone())));
        }
        let poses = self.poses_for(1, first.as_ref().map(|f| &f.trajectory))?;
        let maps = self.maps_for(1, &poses, progress)?;
        Ok((first, Some(maps)))
    }

    /// The whole run: first pass, maps and weighted passes (or one ORB-SLAM2 pass), with
    /// relocalisation seed `config.slam.seed`.
    pub fn run(&self, progress: &dyn Progress) -> Result<OfflineOutput> {
        self.run_with_seed(self.config.slam.seed, progress)
    }

    /// [`OfflineRunner::run`] whose final pass uses relocalisation seed `seed` (run k of a
    /// multi-run experiment uses `seed + k`; the first pass and maps do not depend on it).
    pub fn run_with_seed(&self, seed: u64, progress: &dyn Progress) -> Result<OfflineOutput> {
        // Every DynaPix run reads each frame several times (rigidity maps, passes, geometric
        // depths): decode once, keep them for the run, free them at its end.
        let multi_pass = self.config.method.terms().is_some();
        self.input.keep_decoded_frames(multi_pass);
        let out = self.run_passes(seed, progress);
        if multi_pass {
            self.input.keep_decoded_frames(false);
        }
        out
    }

    /// The run that ends with its first pass because that pass tracked no frame: the first
    /// pass (every frame without a pose) is the result, with no maps and no weighted pass, so
    /// the caller writes its trajectory and status like any run that tracked nothing.
    fn untracked_output(&self, mut record: RunRecord, first: FirstPassResult) -> OfflineOutput {
        let pass = first.output.clone().unwrap_or_else(|| PassOutput {
            trajectory: Trajectory::default(),
            status: self
                .input
                .timestamps()
                .into_iter()
                .map(|t| dynapix_io::StampedStatus {
                    t,
                    status: dynapix_io::FrameStatus::NotInitialized,
                })
                .collect(),
            keyframes: Trajectory::default(),
            loops: Vec::new(),
            timings: Vec::new(),
            stats: crate::slam::PassStats {
                frames: self.input.len(),
                ..Default::default()
            },
            skipped: Vec::new(),
        });
        record.first_pass = Some(first.record.clone());
        record.prob = None;
        record.nothing_tracked = Some(
            "the first pass tracked no frame: no motion maps and no weighted pass; the result \
             is the first pass"
                .into(),
        );
        record.passes = Some(vec![PassRecord {
            maps: None,
            stats: pass.stats,
        }]);
        OfflineOutput {
            first_pass: Some(first),
            maps: Vec::new(),
            passes: vec![pass],
            record,
        }
    }

    fn run_passes(&self, seed: u64, progress: &dyn Progress) -> Result<OfflineOutput> {
        let method = self.config.method;
        let mut record = self.base_record();
        if method.terms().is_none() {
            let out = self.pass(method, None, seed, &format!("{method} 0"), progress)?;
            record.passes = Some(vec![PassRecord {
                maps: None,
                stats: out.stats,
            }]);
            return Ok(OfflineOutput {
                first_pass: None,
                maps: Vec::new(),
                passes: vec![out],
                record,
            });
        }
        let (first, first_maps) = match self.prepare(progress) {
            Ok(p) => p,
            Err(Error::NothingTracked(first)) => return Ok(self.untracked_output(record, *first)),
            Err(e) => return Err(e),
        };
        let mut maps = Vec::new();
        let mut passes: Vec<PassOutput> = Vec::new();
        let n = self.config.passes.weighted;
        let fixed = self.config.motion.poses != PoseSource::Own;
        let mut untracked = None;
        for k in 1..=n {
            let own_poses = !fixed && MapJob::needs_poses(&self.input, self.config);
            if own_poses && passes.last().is_some_and(|p| p.trajectory.is_empty()) {
                // No poses for the next pass's maps: the pass that tracked nothing is the
                // result, like a first pass that tracked nothing.
                untracked = Some(format!(
                    "weighted pass {} tracked no frame: no poses for the maps of pass {k}, \
                     which was not run; the result is pass {}",
                    k - 1,
                    k - 1
                ));
                break;
            }
            let m = if k == 1 {
                first_maps
                    .clone()
                    .ok_or_else(|| Error::Input("no maps".into()))?
            } else if fixed || !MapJob::needs_poses(&self.input, self.config) {
                maps.last()
                    .cloned()
                    .ok_or_else(|| Error::Input("no maps".into()))?
            } else {
                let last = passes
                    .last()
                    .ok_or_else(|| Error::Input("no pass".into()))?;
                let prev = as_written(&last.trajectory)?;
                let poses = self.poses_for(k, Some(&prev))?;
                self.maps_for(k, &poses, progress)?
            };
            let label = if n == 1 {
                format!("{method} 0")
            } else {
                format!("{method} pass {k}")
            };
            let out = self.pass_watched(method, Some(&m), seed, &label, progress, k == n)?;
            // The maps of the passes before are done with: their temporary files go (a set
            // that `m` shares stays); the records stay.
            maps.iter_mut().for_each(MapSet::release);
            maps.push(m);
            passes.push(out);
        }
        let gt_used = maps
            .iter()
            .try_fold(false, |acc, m| m.ground_truth.map(|g| acc || g));
        record.ground_truth_used_at_run_time = gt_used;
        record.decoded_cache = Some(self.input.decoded_record());
        if let Some(why) = untracked {
            record.nothing_tracked = Some(why);
        } else if passes.last().is_some_and(|p| p.trajectory.is_empty()) {
            record.nothing_tracked = Some("the final weighted pass tracked no frame".into());
        }
        record.first_pass = first.as_ref().map(|f| f.record.clone());
        record.prob = maps.first().map(|m| m.record.clone());
        record.passes = Some(
            maps.iter()
                .zip(&passes)
                .map(|(m, p)| PassRecord {
                    maps: Some(m.record.clone()),
                    stats: p.stats,
                })
                .collect(),
        );
        Ok(OfflineOutput {
            first_pass: first,
            maps,
            passes,
            record,
        })
    }

    /// The record fields every run has (the body of `run.json` before any pass; a caller
    /// whose run stopped writes this).
    pub fn record(&self) -> RunRecord {
        self.base_record()
    }

    /// The record fields every run has.
    fn base_record(&self) -> RunRecord {
        let c = self.config;
        let p = c.system_params();
        let d = &p.map.dynapix;
        let dynapix = c.method.terms().is_some();
        RunRecord {
            cues: dynapix.then(|| c.cues().name()),
            first_pass_kind: dynapix.then(|| c.passes.first.name().to_string()),
            weighted_passes: dynapix.then_some(c.passes.weighted),
            oracle_poses: Some(c.motion.poses == PoseSource::GroundTruth),
            loop_closing: Some(p.loop_closing.enabled),
            masks: c.method.needs_masks().then(|| self.masks_dir()),
            dynapix: Some(WeightingRecord {
                weighting: format!("{:?}", d.weighting),
                gamma_add: f64::from(d.gamma_add),
                gamma_del: f64::from(d.gamma_del),
                update: format!("{:?}", d.update),
                ba_weight_clamp: dynapix_slam::weighting::ba_weight_clamp(d),
                threshold: c.method.thresholds().then_some(f64::from(d.gamma_add)),
            }),
            ..RunRecord::new(self.input.record(), c)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_leaves_a_read_only_sequence_folder_alone() {
        let tmp = tempfile::tempdir().unwrap();
        let seq = tmp.path().join("rgbd_x");
        std::fs::create_dir_all(&seq).unwrap();
        let user = tmp.path().join("user-cache");
        // Writable: inside the sequence, as before.
        assert_eq!(
            cache_dir_for(&seq, |_| true, &user),
            seq.join("dynapix_cache")
        );
        // Not writable: under the user's cache, named after the folder, stable.
        let a = cache_dir_for(&seq, |_| false, &user);
        assert!(a.starts_with(user.join("dynapix")), "{}", a.display());
        let name = a.file_name().unwrap().to_string_lossy().into_owned();
        assert!(name.starts_with("rgbd_x-"), "{name}");
        assert_eq!(a, cache_dir_for(&seq, |_| false, &user));
        // Another folder of the same name elsewhere gets another cache.
        let other = tmp.path().join("elsewhere").join("rgbd_x");
        std::fs::create_dir_all(&other).unwrap();
        assert_ne!(a, cache_dir_for(&other, |_| false, &user));
        // An existing cache folder is what is tested, not the sequence folder.
        std::fs::create_dir_all(seq.join("dynapix_cache")).unwrap();
        let probed = std::cell::RefCell::new(Vec::new());
        let _ = cache_dir_for(
            &seq,
            |p| {
                probed.borrow_mut().push(p.to_path_buf());
                true
            },
            &user,
        );
        assert_eq!(*probed.borrow(), vec![seq.join("dynapix_cache")]);
        // This process can write its own temporary folder; a folder without write bits is
        // left alone even by a privileged user.
        assert!(writable(tmp.path()));
        assert!(!writable(&tmp.path().join("missing")));
        let ro = tmp.path().join("ro");
        std::fs::create_dir_all(&ro).unwrap();
        let mut perm = std::fs::metadata(&ro).unwrap().permissions();
        perm.set_readonly(true);
        std::fs::set_permissions(&ro, perm.clone()).unwrap();
        assert!(!writable(&ro));
        #[allow(clippy::permissions_set_readonly_false)]
        perm.set_readonly(false);
        std::fs::set_permissions(&ro, perm).unwrap();
    }
}
