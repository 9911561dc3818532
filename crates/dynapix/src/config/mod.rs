//! The one configuration of a DynaPix run: method, paper/reference mode, sequence reading,
//! motion maps, SLAM, passes and the online schedule, with the paper's defaults.
//!
//! [`Config::mode`] is the one place that says paper or reference: [`Config::new`] builds
//! every mode-dependent default from it, a configuration file's missing values take the
//! defaults of the file's `mode`, and [`Config::validate`] refuses nested mode fields (kept in
//! the parameter structs of the algorithm crates) that disagree with it. The method decides
//! the rest: which motion terms the maps use and whether the SLAM backend weights
//! ([`Config::motion_params`], [`Config::system_params`]).
//!
//! Files are JSON (`.json`) or YAML (anything else); every section and every parameter
//! struct is optional field by field. Unknown keys, duplicate keys and values of the wrong
//! type are errors naming the key. Every number has a documented range, checked before any
//! work starts ([`Config::validate`], through the [`dynapix_params::Validate`] implementation
//! of each parameter struct): an error names the key path and the range, e.g.
//! `slam.params.tracking.pose.rounds must lie in [1, 100], got 1000000000000`. The whole
//! resolved configuration is written into `run.json`.
//!
//! The DynaPix thresholds of the SLAM backend are the flat section [`Config::dynapix`]
//! (`dynapix: {gamma_add: 0.05, gamma_del: 0.1, update: {ema: {alpha: 0.2}}}`); the SLAM
//! parameters follow from it ([`Config::system_params`]). Files that still give them at their
//! old place, `slam.params.map.dynapix`, are read as if they were in the flat section (with
//! a warning naming the new key); giving both with different values is an error.

use std::path::{Path, PathBuf};

use dynapix_flow::dis::{DisParams, Preset};
use dynapix_io::Pairing;
use dynapix_motion::{
    Backgrounds, MotionParams, ReconstructParams, RigidityParams, StaticDepthParams, Variant,
};
use dynapix_params::{Checked, InvalidParam, Validate, above, each, nested, optional, range};
use dynapix_slam::system::SystemParams;
use dynapix_slam::weighting::{DynaPixParams, ProbUpdate};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::error::{Error, Result};
use crate::method::{Method, Mode, Terms};

mod depth;
mod parse;
mod validate;

pub use depth::CameraOr;

use parse::*;

/// The configuration of a run. `Default` = DynaPix in paper mode with the paper's values.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Config {
    /// Paper or reference behaviour (motion maps and SLAM weighting).
    pub mode: Mode,
    /// The method.
    pub method: Method,
    /// The DynaPix thresholds of the SLAM backend (γ_add, γ_del, the per-point update rule);
    /// `slam.params.map.dynapix` follows from them and from `mode`.
    pub dynapix: DynaPixConfig,
    /// How the sequence folder is read.
    pub sequence: SequenceConfig,
    /// Motion maps.
    pub motion: MotionConfig,
    /// The SLAM system.
    pub slam: SlamConfig,
    /// Offline passes.
    pub passes: PassConfig,
    /// The online (streaming) schedule.
    pub online: OnlineConfig,
}

/// The DynaPix thresholds of the SLAM backend, in one flat section (paper §3.2): a keypoint
/// gives birth to a map point only when its motion probability P ≤ γ_add, a map point is
/// removed once its own probability reaches γ_del, and that probability follows its
/// observations by `update`. The weighting behaviour itself follows [`Config::mode`] and the
/// method.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DynaPixConfig {
    /// γ_add in [0, 1] (0.05): the birth gate of map points; also the threshold of the
    /// `threshold` ablation.
    pub gamma_add: f32,
    /// γ_del in (0, 1] (0.1): a map point is removed once its motion probability reaches it
    /// (0 would remove every point on its first observation, so it is refused).
    pub gamma_del: f32,
    /// How a map point's probability follows its observations (paper mode: EMA with
    /// α = 0.2, α in (0, 1]; reference mode: the latest observation).
    pub update: ProbUpdate,
}

impl DynaPixConfig {
    /// The values of `mode`.
    pub fn for_mode(mode: Mode) -> Self {
        let d = DynaPixParams::new(mode.weighting());
        Self {
            gamma_add: d.gamma_add,
            gamma_del: d.gamma_del,
            update: d.update,
        }
    }

    /// The SLAM backend's parameters with these thresholds and `weighting`.
    pub fn params(&self, weighting: dynapix_slam::weighting::Weighting) -> DynaPixParams {
        DynaPixParams {
            weighting,
            gamma_add: self.gamma_add,
            gamma_del: self.gamma_del,
            update: self.update,
        }
    }
}

impl Default for DynaPixConfig {
    fn default() -> Self {
        Self::for_mode(Mode::Paper)
    }
}

impl Validate for DynaPixConfig {
    fn validate(&self) -> Checked {
        self.params(dynapix_slam::weighting::Weighting::Paper)
            .validate()
    }
}

/// How the sequence folder is read (one reader, one association policy).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SequenceConfig {
    /// Pairing of `rgb.txt` and `depth.txt` (nearest depth for every rgb frame).
    pub pairing: Pairing,
    /// Largest rgb/depth time difference (s, 0.02).
    pub max_diff: f64,
    /// Use only the first N frames.
    pub max_frames: Option<usize>,
    /// A frame whose rgb or depth file cannot be used (missing, truncated, undecodable, of
    /// another size) is skipped: recorded lost, no motion map, SLAM goes on with the next
    /// frame, and the run lists it. Off: the run stops at that frame with an error naming it.
    pub skip_bad_frames: bool,
    /// Memory (MiB) for decoded frames kept between the passes of an offline DynaPix run, so
    /// each frame's images are decoded once instead of once per pass (0: decode every time;
    /// single-pass runs and the online mode keep nothing). Frames are
    /// kept in the order they are first read until the budget is spent (a pass reads the
    /// sequence in order, so a least-recently-used policy would keep nothing useful). The
    /// cache leaves 1/64 of the budget unused as a margin for what keeping frames costs
    /// beyond their bytes, so the run's peak memory stays within its peak without a cache
    /// plus this budget.
    pub decoded_cache_mib: usize,
    /// The raw depth value the camera writes at saturation; such pixels are read as missing
    /// by every consumer (SLAM, the cues, the paper's terms), with a warning giving their
    /// count per frame. `null`: every raw value is a depth. `"camera"` (the default): the
    /// camera's `depth_saturation` (its settings file), else 65535.
    pub depth_saturation: CameraOr<Option<u16>>,
    /// Depths beyond this many metres (in (0, 1000]) are no measurement of the camera and
    /// are read as missing, like saturated ones. `"camera"` (the default): the camera's
    /// `depth_max_m`, else 20.
    pub max_depth: CameraOr<f32>,
}

impl SequenceConfig {
    /// The depth limits this configuration sets (the others are the camera's).
    pub fn depth_limits(&self) -> dynapix_io::DepthLimits {
        dynapix_io::DepthLimits {
            saturation: self.depth_saturation.stated(),
            max_depth: self.max_depth.stated(),
        }
    }
}

impl Default for SequenceConfig {
    fn default() -> Self {
        Self {
            pairing: Pairing::Nearest,
            max_diff: dynapix_io::tum::DEFAULT_MAX_DIFF,
            max_frames: None,
            skip_bad_frames: false,
            decoded_cache_mib: 1024,
            depth_saturation: CameraOr::Camera,
            max_depth: CameraOr::Camera,
        }
    }
}

/// DIS optical-flow preset (OpenCV's presets).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum FlowPreset {
    /// Coarsest and fastest.
    Ultrafast,
    /// The motion maps' default.
    #[default]
    Fast,
    /// Finest of the three.
    Medium,
}

impl FlowPreset {
    /// The flow crate's preset.
    pub fn preset(self) -> Preset {
        match self {
            FlowPreset::Ultrafast => Preset::Ultrafast,
            FlowPreset::Fast => Preset::Fast,
            FlowPreset::Medium => Preset::Medium,
        }
    }

    /// The name on command lines and in records.
    pub fn name(self) -> &'static str {
        match self {
            FlowPreset::Ultrafast => "ultrafast",
            FlowPreset::Fast => "fast",
            FlowPreset::Medium => "medium",
        }
    }
}

/// Where the static background of the motion maps comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum BackgroundSource {
    /// `background/` when the sequence has it, else reconstructed.
    #[default]
    Auto,
    /// The sequence's `background/` (and `depth_bg/` when present) folders.
    Folder,
    /// Reconstructed from neighbouring frames splatted into the current view.
    Reconstruct,
}

/// Poses for splatting in the motion maps.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseSource {
    /// The system's own first pass (no ground truth at run time; the default).
    #[default]
    Own,
    /// The sequence's `groundtruth.txt` (the paper's oracle setting).
    GroundTruth,
    /// A TUM trajectory file.
    File(PathBuf),
}

/// Motion-map configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct MotionConfig {
    /// The motion-probability parameters (the method may switch a term off).
    pub params: MotionParams,
    /// Optical-flow preset.
    pub flow: FlowPreset,
    /// Background source.
    pub background: BackgroundSource,
    /// Background reconstruction.
    pub reconstruct: ReconstructParams,
    /// Poses for splatting (offline runs).
    pub poses: PoseSource,
    /// Largest distance (s) from a frame to the nearest pose of a trajectory (0.05).
    pub max_pose_gap: f64,
    /// Which cues make up P (combined by noisy-or: P = 1 − Π(1 − P_cue)).
    pub cues: Cues,
    /// Static depth and the geometric cue.
    pub static_depth: StaticDepthParams,
    /// The pose-free rigidity cue (and the rigidity-weighted first pass).
    pub rigidity: RigidityParams,
    /// The rigidity cue of the maps of weighted pass k ≥ 1 chooses each frame pair's motion
    /// with the relative pose of the two frames in the previous pass's trajectory as a prior
    /// (issue 33, crowds that fill the view): the dominant motion is kept unchanged when it
    /// agrees with the fit seeded by the prior, else (movers dominate, or no motion does)
    /// the seeded fit gives the residual ([`dynapix_motion::PriorChoice`]). The first pass,
    /// which has no poses yet, and runs with fixed poses (ground truth, a file) keep the
    /// pose-free maps. Off (the default in both modes, decided by the first measurements:
    /// it took `crowd` 640×480 to a median of 0.0042 m over seeds 0–2, but the Bonn window
    /// from 0.0156 to 0.0185 m, person_tracking s0 from 0.0052 to 0.0069 m and the tracking
    /// rate of `crowd` 320×240 s0 to 0.92; BENCHMARKS.md, "Hard scenes: the rigidity cue
    /// with a pose prior"): every pass uses the pose-free maps.
    pub rigidity_pose_prior: bool,
}

/// The cues of the motion probability. Each is a switch, a line in `motion.json` and an
/// ablation row; the enabled ones combine by noisy-or, `P = 1 − Π(1 − P_cue)` (a pixel is
/// static only when no cue says it moves).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(default)]
pub struct Cues {
    /// The paper's terms: P = D·M (movable × moving; the ablation methods switch one off).
    pub paper: bool,
    /// The geometric cue: a pixel much nearer than the static depth that a wide window of
    /// views (seconds, past and future, splatted with the poses) sees there is not static.
    pub geometric: bool,
    /// The rigidity cue: the residual of each pixel against the dominant rigid motion to its
    /// neighbour frames, fitted by RANSAC on depth-backed optical flow (needs no poses).
    pub rigidity: bool,
}

impl Cues {
    /// The paper's terms alone (the reference and the paper).
    pub const PAPER: Cues = Cues {
        paper: true,
        geometric: false,
        rigidity: false,
    };

    /// The defaults of `mode`. Paper mode: the geometric and the rigidity cue. The paper's
    /// terms are a switch: on the Bonn window they changed the ATE by less than a millimetre
    /// (0.0159 m with them, 0.0162 m without) at six times the compute (BENCHMARKS.md), since
    /// a background reconstructed from ±15 frames cannot see behind people who stay. Reference
    /// mode: the paper's terms alone.
    pub fn for_mode(mode: Mode) -> Self {
        match mode {
            Mode::Paper => Cues {
                paper: false,
                geometric: true,
                rigidity: true,
            },
            Mode::Reference => Cues::PAPER,
        }
    }

    /// The names of the enabled cues, e.g. `paper+geometric+rigidity`.
    pub fn name(&self) -> String {
        let mut v = Vec::new();
        if self.paper {
            v.push("paper");
        }
        if self.geometric {
            v.push("geometric");
        }
        if self.rigidity {
            v.push("rigidity");
        }
        if v.is_empty() {
            "none".into()
        } else {
            v.join("+")
        }
    }
}

/// One cue, by name (command lines: `--cues paper,geometric,rigidity`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Cue {
    /// The paper's terms, D·M.
    Paper,
    /// The geometric cue.
    Geometric,
    /// The rigidity cue.
    Rigidity,
}

impl Cues {
    /// Exactly the cues listed.
    pub fn only(list: &[Cue]) -> Self {
        Cues {
            paper: list.contains(&Cue::Paper),
            geometric: list.contains(&Cue::Geometric),
            rigidity: list.contains(&Cue::Rigidity),
        }
    }
}

impl Default for Cues {
    fn default() -> Self {
        Cues::for_mode(Mode::Paper)
    }
}

/// The bag-of-words vocabulary of the SLAM system.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VocabularyChoice {
    /// The embedded default (trained on TUM fr1_xyz).
    #[default]
    Embedded,
    /// None: brute-force keyframe matching.
    None,
    /// A file (`dynapix vocab` binary format).
    File(PathBuf),
}

/// SLAM configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SlamConfig {
    /// Parameters of every stage. `params.map.dynapix` is not a key of this section: it
    /// follows from the flat section [`Config::dynapix`], [`Config::mode`] and the method
    /// ([`Config::system_params`]); a value changed here in code instead is refused by
    /// [`Config::validate`].
    pub params: SystemParams,
    /// The vocabulary.
    pub vocabulary: VocabularyChoice,
    /// Added to the relocalisation seed (run k of `--runs` uses `seed + k`).
    pub seed: u64,
}

impl Default for MotionConfig {
    fn default() -> Self {
        Config::default().motion
    }
}

impl Default for SlamConfig {
    fn default() -> Self {
        Config::default().slam
    }
}

/// The pass that gives the poses of the first motion maps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum FirstPass {
    /// Plain ORB-SLAM2 over the whole sequence (the paper).
    #[default]
    Orbslam2,
    /// The method's SLAM weighted by the pose-free rigidity cue alone: a first pass that
    /// does not follow a crowd, so the first splatted maps start from usable poses.
    Rigidity,
}

impl FirstPass {
    /// The name in records.
    pub fn name(self) -> &'static str {
        match self {
            FirstPass::Orbslam2 => "orbslam2",
            FirstPass::Rigidity => "rigidity",
        }
    }
}

/// Offline passes: first pass → maps → weighted pass, repeated `weighted` times, the maps of
/// pass k + 1 splatted with the trajectory of pass k.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PassConfig {
    /// The first pass.
    pub first: FirstPass,
    /// Number of weighted passes (paper mode 2: the maps of the second are splatted with the
    /// poses of the first; reference mode 1, the paper's schedule).
    pub weighted: usize,
}

impl PassConfig {
    /// The defaults of `mode`: a rigidity-weighted first pass and two weighted passes in
    /// paper mode; ORB-SLAM2 and one weighted pass (the paper's schedule) in reference mode.
    pub fn for_mode(mode: Mode) -> Self {
        match mode {
            Mode::Paper => Self {
                first: FirstPass::Rigidity,
                weighted: 2,
            },
            Mode::Reference => Self {
                first: FirstPass::Orbslam2,
                weighted: 1,
            },
        }
    }
}

impl Default for PassConfig {
    fn default() -> Self {
        Self::for_mode(Mode::Paper)
    }
}

/// The online schedule ([`crate::OnlineDynaPix`], [`crate::run_online`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct OnlineConfig {
    /// Frames of latency allowed: the pose of frame n is reported when frame n + lookahead
    /// arrives, and its background may use those later frames (0 = no latency).
    pub lookahead: usize,
    /// Past frames kept as neighbours for the moving term and as background sources (the
    /// memory bound together with `background_keyframes`).
    pub window: usize,
    /// Past keyframes kept (images and poses) as sources of the reconstructed background.
    pub background_keyframes: usize,
    /// Offsets of past neighbours used by the moving term (negative, `[-2, -1]`).
    pub past_offsets: Vec<i64>,
    /// The rigidity flow's working width online: replaces
    /// `motion.rigidity.flow_working_width` (offline default 160) in online runs; 0 (the
    /// default) computes the flow on the preset's own finest level. Online, the static depth
    /// sees only the past, so the rigidity cue carries more of P. On the Bonn window without
    /// lookahead the 160-px level gave 0.073 / 0.027 / 0.076 / 0.069 m over four RANSAC
    /// seeds against 0.029 / 0.023 / 0.026 / 0.064 m with the finer level (BENCHMARKS.md,
    /// "Rigidity flow at a fixed working width"), so online keeps the finer flow.
    pub rigidity_flow_working_width: u32,
    /// The DIS parameters of the rigidity flow online, in place of
    /// `motion.rigidity.flow_preset` (`None`, the default: that preset, medium). A cheaper
    /// flow, [`OnlineConfig::cheap_rigidity_flow`], meets 15 frames/s at 640×480 on the
    /// 2-core machine, but cost about 10 % of ATE on the Bonn window over eight RANSAC seeds
    /// (trimmed means 0.0266 → 0.0294 m without lookahead, 0.0202 → 0.0222 m with 15 frames),
    /// while fr1_xyz and synth walking_xyz 640×480 were as good or better (BENCHMARKS.md,
    /// "Online: mapping beside the motion map, and a cheaper rigidity flow measured"). Keys
    /// left out of a value given in a file take the medium preset's values.
    pub rigidity_flow: Option<DisParams>,
    /// When the next frame has already arrived (frames read from files, a camera faster than
    /// the system, or a frame waiting in the lookahead), compute its rigidity cue beside the
    /// feature extraction and tracking of the current frame instead of in its own push
    /// (true). The poses are the same either way (the early cue is used only for the same
    /// frame with the same neighbours); on the 2-core machine it raised DynaPix online at
    /// 640×480 from 14.0–14.4 to 15.6–16.0 frames/s (BENCHMARKS.md, "Online: the next frame's
    /// rigidity cue beside tracking").
    pub rigidity_ahead: bool,
}

impl Default for OnlineConfig {
    fn default() -> Self {
        Self {
            lookahead: 0,
            window: 15,
            background_keyframes: 8,
            // Two past neighbours measured better than one on the synth walking presets
            // (walking_halfsphere 0.018 m vs 0.032 m; BENCHMARKS.md, online mode).
            past_offsets: vec![-2, -1],
            rigidity_flow_working_width: 0,
            rigidity_flow: None,
            rigidity_ahead: true,
        }
    }
}

impl OnlineConfig {
    /// A cheaper value of [`OnlineConfig::rigidity_flow`] for real time at 640×480: the
    /// medium preset with OpenCV's `fast` patch search (stride 4, 16 descent iterations) and 2
    /// variational iterations. In a file: `online: {rigidity_flow: {patch_stride: 4,
    /// grad_descent_iterations: 16, variational: {fixed_point_iterations: 2}}}`.
    pub fn cheap_rigidity_flow() -> DisParams {
        let fast = DisParams::preset(Preset::Fast);
        let mut p = DisParams::preset(Preset::Medium);
        p.patch_stride = fast.patch_stride;
        p.grad_descent_iterations = fast.grad_descent_iterations;
        p.variational.fixed_point_iterations = 2;
        p
    }
}

impl Default for Config {
    fn default() -> Self {
        Self::new(Mode::Paper)
    }
}

impl Config {
    /// Every default of `mode` (TUM variant of the motion constants), method DynaPix.
    pub fn new(mode: Mode) -> Self {
        Self::with_variant(mode, Variant::Tum)
    }

    /// Every default of `mode` with the motion constants of `variant`.
    pub fn with_variant(mode: Mode, variant: Variant) -> Self {
        Self {
            mode,
            method: Method::Dynapix,
            dynapix: DynaPixConfig::for_mode(mode),
            sequence: SequenceConfig::default(),
            motion: MotionConfig {
                params: MotionParams::new(variant, mode.motion()),
                flow: FlowPreset::Fast,
                background: BackgroundSource::Auto,
                reconstruct: ReconstructParams::default(),
                poses: PoseSource::Own,
                max_pose_gap: 0.05,
                cues: Cues::for_mode(mode),
                static_depth: StaticDepthParams::default(),
                rigidity: RigidityParams::default(),
                rigidity_pose_prior: false,
            },
            slam: SlamConfig {
                params: Self::slam_defaults(mode),
                vocabulary: VocabularyChoice::Embedded,
                seed: 0,
            },
            passes: PassConfig::for_mode(mode),
            online: OnlineConfig::default(),
        }
    }

    /// The SLAM defaults of `mode`. Paper mode adds two safeguards among movers to the
    /// paper's weighting: keypoints are extracted only where w ≥ 0.5 (a frame's feature
    /// budget is not spent on people), and when every tracking method fails the local map is
    /// tracked from the constant-velocity prediction for up to 30 frames (a crowd in front of
    /// the camera does not lose it). Offline, at the end of each pass every tracked frame
    /// that is not a keyframe is optimised again against the final map, without the points
    /// culled since (`final_pose_refinement`). Reference mode keeps ORB-SLAM2's behaviour.
    pub fn slam_defaults(mode: Mode) -> SystemParams {
        let mut p = SystemParams::default().with_dynapix(DynaPixParams::new(mode.weighting()));
        if mode == Mode::Paper {
            p.static_features_min_weight = Some(0.5);
            p.tracking.predicted_frames = 30;
            p.tracking.local_relocalisation = true;
            p.tracking.pose_consistency = true;
            p.final_pose_refinement = true;
        }
        p
    }

    /// The cues of the method's maps: the paper's ablations (no-movable, no-moving) are
    /// ablations of the paper's terms and always use them.
    pub fn cues(&self) -> Cues {
        let mut c = self.motion.cues;
        if matches!(
            self.method.terms(),
            Some(Terms::NoMovable | Terms::NoMoving)
        ) {
            c.paper = true;
        }
        c
    }

    /// This configuration with `method`.
    pub fn with_method(mut self, method: Method) -> Self {
        self.method = method;
        self
    }

    /// Reads a configuration file: JSON when the name ends in `.json`, YAML otherwise.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        Self::load_with(Some(path.as_ref()), None)
    }

    /// The configuration of an optional file with an optional mode that replaces the file's
    /// (its defaults then follow the given mode): what a command line with `--config FILE`
    /// and `--mode MODE` means.
    pub fn load_with(path: Option<&Path>, mode: Option<Mode>) -> Result<Self> {
        let mut v = match path {
            None => Value::Object(Default::default()),
            Some(path) => Self::read_value(path)?,
        };
        if let (Some(m), Value::Object(map)) = (mode, &mut v) {
            map.insert("mode".into(), Value::String(m.name().into()));
        }
        Self::from_value(v).map_err(|e| match (e, path) {
            (
                Error::Config {
                    path: None,
                    message,
                },
                Some(p),
            ) => Error::Config {
                path: Some(p.to_path_buf()),
                message,
            },
            (other, _) => other,
        })
    }

    /// The parsed document of a configuration file (JSON or YAML by extension).
    fn read_value(path: &Path) -> Result<Value> {
        let bad = |message: String| Error::Config {
            path: Some(path.to_path_buf()),
            message,
        };
        let text = std::fs::read_to_string(path).map_err(|e| bad(format!("cannot read: {e}")))?;
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"))
        {
            parse_json(&text).map_err(bad)
        } else if text.trim().is_empty() {
            Ok(Value::Null)
        } else {
            parse_yaml(&text).map_err(bad)
        }
    }

    /// Parses a JSON configuration (see [`Config::from_value`]).
    pub fn from_json_str(text: &str) -> Result<Self> {
        Self::from_value(parse_json(text).map_err(Error::config)?)
    }

    /// Parses a YAML configuration (see [`Config::from_value`]).
    pub fn from_yaml_str(text: &str) -> Result<Self> {
        if text.trim().is_empty() {
            return Ok(Self::default());
        }
        Self::from_value(parse_yaml(text).map_err(Error::config)?)
    }

    /// Builds a configuration from a parsed document: its `mode` (and motion variant) pick
    /// the defaults, its values replace them key by key. Unknown keys, values of the wrong
    /// type (named by key), values out of their range and nested mode fields that disagree
    /// with `mode` are errors. DynaPix thresholds at their old place
    /// (`slam.params.map.dynapix`) are read into the flat section `dynapix`.
    pub fn from_value(v: Value) -> Result<Self> {
        let mut v = match v {
            Value::Null => Value::Object(Default::default()),
            Value::Object(_) => v,
            other => {
                return Err(Error::config(format!(
                    "expected a map of sections, got {other}"
                )));
            }
        };
        let mode: Mode = match v.get("mode") {
            Some(m) => serde_json::from_value(m.clone())
                .map_err(|e| Error::config(format!("mode: {e} (paper or reference)")))?,
            None => Mode::Paper,
        };
        let variant: Variant = match v.pointer("/motion/params/variant") {
            Some(m) => serde_json::from_value(m.clone())
                .map_err(|e| Error::config(format!("motion.params.variant: {e}")))?,
            None => Variant::Tum,
        };
        move_nested_dynapix(&mut v, mode)?;
        let base = Self::with_variant(mode, variant);
        let base_value = base.to_json_value();
        let mut merged = base_value.clone();
        check_known_keys(&v, &merged, "")?;
        merge(&mut merged, v.clone());
        let mut config: Config = serde_json::from_value(merged).map_err(|e| {
            Error::config(blame_type_error(&base_value, &v).unwrap_or_else(|| e.to_string()))
        })?;
        // The section a file cannot set follows from the ones it can.
        config.slam.params.map.dynapix = config.dynapix.params(config.mode.weighting());
        config.validate()?;
        Ok(config)
    }

    /// The configuration as a JSON value (what `run.json` records). Goes through the JSON
    /// text so `f32` parameters read as written (0.9, not 0.8999999761581421).
    /// `slam.params.map.dynapix` is left out: it follows from `dynapix` and `mode`.
    pub fn to_json_value(&self) -> Value {
        let mut v = serde_json::to_string(self)
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .unwrap_or(Value::Null);
        if let Some(map) = v
            .pointer_mut("/slam/params/map")
            .and_then(Value::as_object_mut)
        {
            map.remove("dynapix");
        }
        v
    }

    /// Checks the values before any work: nested mode fields agree with [`Config::mode`],
    /// every number lies in its documented range (each parameter struct's
    /// [`dynapix_params::Validate`]); the error names the key path and the range.
    pub fn validate(&self) -> Result<()> {
        Validate::validate(self).map_err(|e| Error::config(e.to_string()))
    }

    /// The motion parameters of the method: the ablations switch a term off.
    pub fn motion_params(&self) -> MotionParams {
        let mut p = self.motion.params.clone();
        match self.method.terms() {
            Some(Terms::NoMovable) => p.use_movable = false,
            Some(Terms::NoMoving) => p.use_moving = false,
            _ => {}
        }
        p
    }

    /// The optical-flow parameters of the configured preset.
    pub fn flow_params(&self) -> DisParams {
        DisParams::preset(self.motion.flow.preset())
    }

    /// The background source of the maps for a sequence that has (`has_folder`) or has not a
    /// `background/` folder.
    pub fn backgrounds(&self, has_folder: bool) -> Backgrounds {
        let folder = match self.motion.background {
            BackgroundSource::Auto => has_folder,
            BackgroundSource::Folder => true,
            BackgroundSource::Reconstruct => false,
        };
        if folder {
            Backgrounds::Given
        } else {
            Backgrounds::Reconstruct(self.motion.reconstruct.clone())
        }
    }

    /// The SLAM parameters of the method: its weighting in [`Config::mode`] (off for ORB-SLAM2
    /// and the threshold ablation).
    pub fn system_params(&self) -> SystemParams {
        let mut p = self.slam.params.clone();
        p.map.dynapix = self.dynapix.params(self.method.weighting(self.mode));
        if self.method == Method::Orbslam2 {
            // ORB-SLAM2 mode is ORB-SLAM2: no static-feature mask, no predicted tracking.
            p.static_features_min_weight = None;
            p.tracking.predicted_frames = 0;
            p.tracking.local_relocalisation = false;
            p.tracking.pose_consistency = false;
            p.final_global_ba = false;
            p.final_pose_refinement = false;
        }
        p
    }

    /// The SLAM parameters of an unweighted pass (the first pass, ORB-SLAM2 mode).
    pub fn orbslam2_params(&self) -> SystemParams {
        self.clone().with_method(Method::Orbslam2).system_params()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynapix_slam::weighting::{ProbUpdate, Weighting};

    #[test]
    fn default_is_the_paper_and_reference_is_consistent() {
        let p = Config::default();
        p.validate().unwrap();
        assert_eq!(p.mode, Mode::Paper);
        // ORB-SLAM2 mode is ORB-SLAM2: unweighted, no static-feature mask, no prediction.
        let orb = p.clone().with_method(Method::Orbslam2).system_params();
        assert_eq!(orb.tracking, SystemParams::default().tracking);
        assert_eq!(orb.static_features_min_weight, None);
        assert_eq!(orb.map.dynapix.weighting, Weighting::Off);
        assert_eq!(p.system_params().static_features_min_weight, Some(0.5));
        assert_eq!(p.system_params().tracking.predicted_frames, 30);
        assert!(p.system_params().tracking.local_relocalisation);
        assert!(p.system_params().tracking.pose_consistency);
        // The final refinements are offline DynaPix only.
        assert!(p.system_params().final_pose_refinement);
        assert!(!orb.final_pose_refinement && !orb.final_global_ba);
        // Local BA runs every iteration (ORB-SLAM2's schedule) unless told to stop when
        // converged; the option is checked.
        assert_eq!(orb.mapping, SystemParams::default().mapping);
        assert_eq!(p.system_params().mapping.ba.min_relative_decrease, 0.0);
        let c = Config::from_yaml_str(
            "slam: {params: {mapping: {ba: {min_relative_decrease: 1.0e-4}}}}\n",
        )
        .unwrap();
        assert_eq!(
            c.with_method(Method::Orbslam2)
                .system_params()
                .mapping
                .ba
                .min_relative_decrease,
            1e-4
        );
        for bad in [-1e-4, 1.0, f64::NAN] {
            let mut c = p.clone();
            c.slam.params.mapping.ba.min_relative_decrease = bad;
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains("min_relative_decrease"), "{e}");
        }
        // Local BA waits for the next keyframe within 0.05 s of the last one, in every mode;
        // a config file can turn that off, and a bad value is refused by name.
        assert_eq!(orb.mapping.ba_min_interval_s, 0.05);
        assert_eq!(p.system_params().mapping.ba_min_interval_s, 0.05);
        let c =
            Config::from_yaml_str("slam: {params: {mapping: {ba_min_interval_s: 0}}}\n").unwrap();
        assert_eq!(c.system_params().mapping.ba_min_interval_s, 0.0);
        for bad in [-0.1, f64::NAN, f64::INFINITY] {
            let mut c = p.clone();
            c.slam.params.mapping.ba_min_interval_s = bad;
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains("ba_min_interval_s"), "{e}");
        }
        let mut all = p.clone();
        all.slam.params.final_global_ba = true;
        let orb_all = all.with_method(Method::Orbslam2).system_params();
        assert!(!orb_all.final_pose_refinement && !orb_all.final_global_ba);
        assert!(
            !Config::new(Mode::Reference)
                .system_params()
                .final_pose_refinement
        );
        assert_eq!(p.passes.first, FirstPass::Rigidity);
        assert!(p.cues().geometric && p.cues().rigidity);
        let r = Config::new(Mode::Reference);
        r.validate().unwrap();
        assert_eq!(r.motion.params.splat.mode, dynapix_motion::Mode::Reference);
        assert_eq!(r.slam.params.map.dynapix.update, ProbUpdate::Latest);
        assert_eq!(r.motion.cues, Cues::PAPER);
        assert_eq!(r.passes, PassConfig::for_mode(Mode::Reference));
        assert_eq!(r.slam.params.static_features_min_weight, None);
        assert_eq!(
            r.clone()
                .with_method(Method::Orbslam2)
                .system_params()
                .map
                .dynapix
                .weighting,
            Weighting::Off
        );
        assert_eq!(
            r.system_params().map.dynapix.weighting,
            Weighting::Reference
        );
        let nm = Config::default()
            .with_method(Method::NoMoving)
            .motion_params();
        assert!(nm.use_movable && !nm.use_moving);
    }

    #[test]
    fn files_take_the_defaults_of_their_mode_and_refuse_contradictions() {
        // Only the mode: every mode-dependent value follows.
        let c = Config::from_yaml_str("mode: reference\n").unwrap();
        assert_eq!(c, Config::new(Mode::Reference));
        let c = Config::from_json_str(
            r#"{"method": "no-movable", "motion": {"flow": "medium", "params": {"offsets": [-2, 2]}},
                "slam": {"params": {"tracking": {"motion_th": 10.0}, "map": {"dynapix": {"gamma_del": 0.2}}}}}"#,
        )
        .unwrap();
        assert_eq!(c.method, Method::NoMovable);
        assert_eq!(c.motion.flow, FlowPreset::Medium);
        assert_eq!(c.motion.params.offsets, vec![-2, 2]);
        assert_eq!(c.motion.params.movable, MotionParams::default().movable);
        assert_eq!(c.slam.params.tracking.motion_th, 10.0);
        // The old place of the DynaPix thresholds still reads, into the flat section.
        assert_eq!(c.dynapix.gamma_del, 0.2);
        assert_eq!(c.system_params().map.dynapix.gamma_del, 0.2);
        assert_eq!(c.slam.params.map.dynapix.gamma_del, 0.2);
        assert_eq!(c.slam.params.map.dynapix.gamma_add, 0.05);
        // A full record reads back to the same configuration.
        let text = serde_json::to_string_pretty(&c.to_json_value()).unwrap();
        assert_eq!(Config::from_json_str(&text).unwrap(), c);
        // Contradictions, typos and bad values are errors naming the key.
        let e = Config::from_yaml_str(
            "mode: paper\nmotion:\n  params:\n    splat:\n      mode: reference\n",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("motion.params.splat.mode"), "{e}");
        let e = Config::from_yaml_str("slam:\n  parms: {}\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown key slam.parms"), "{e}");
        let e = Config::from_yaml_str("passes:\n  weighted: 0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("passes.weighted"), "{e}");
        let e = Config::from_yaml_str("mode: fancy\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("mode"), "{e}");
        let e = Config::from_json_str(r#"{"motion": {"poses": {"file": 3}}}"#).unwrap_err();
        assert!(matches!(e, Error::Config { .. }), "{e}");
        let c = Config::from_yaml_str("motion:\n  poses:\n    file: traj.txt\n").unwrap();
        assert_eq!(c.motion.poses, PoseSource::File("traj.txt".into()));
    }

    #[test]
    fn cues_are_switches_and_every_cue_off_is_an_error() {
        let c = Config::from_yaml_str("motion:\n  cues: {paper: true, rigidity: false}\n").unwrap();
        assert_eq!(
            c.motion.cues,
            Cues {
                paper: true,
                geometric: true,
                rigidity: false
            }
        );
        assert_eq!(c.cues().name(), "paper+geometric");
        assert_eq!(Cues::only(&[Cue::Rigidity]).name(), "rigidity");
        let e = Config::from_yaml_str(
            "motion:\n  cues: {paper: false, geometric: false, rigidity: false}\n",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("motion.cues"), "{e}");
        // ORB-SLAM2 needs no cue; the paper's ablations always use the paper's terms.
        let mut off = Config::default().with_method(Method::Orbslam2);
        off.motion.cues = Cues::only(&[]);
        off.validate().unwrap();
        let nm = Config::default().with_method(Method::NoMoving);
        assert!(nm.cues().paper);
        let e = Config::from_yaml_str("motion:\n  rigidity: {offsets: [0, 1]}\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("offsets"), "{e}");
        let mut c = Config::default();
        c.dynapix.update = dynapix_slam::weighting::ProbUpdate::Ema { alpha: 2.0 };
        let e = c.validate().unwrap_err().to_string();
        assert!(
            e.contains("dynapix.update.ema.alpha must lie in (0, 1]"),
            "{e}"
        );
        c.dynapix.update = dynapix_slam::weighting::ProbUpdate::Ema { alpha: f32::NAN };
        assert!(c.validate().is_err());
        let c = Config::from_yaml_str("sequence: {skip_bad_frames: true}\n").unwrap();
        assert!(c.sequence.skip_bad_frames && !Config::default().sequence.skip_bad_frames);
        let e = Config::from_yaml_str("slam:\n  params: {static_features_min_weight: 2.0}\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("static_features_min_weight"), "{e}");
    }

    /// The numbers of a configuration document with their key paths (`a.b[2]`), nulls
    /// (unset options) included.
    fn numeric_leaves(v: &Value, at: &str, out: &mut Vec<(String, String)>) {
        let pointer = |key: &str| format!("/{}", key.replace(['.', '['], "/").replace(']', ""));
        match v {
            Value::Object(m) => {
                for (k, child) in m {
                    let key = if at.is_empty() {
                        k.clone()
                    } else {
                        format!("{at}.{k}")
                    };
                    numeric_leaves(child, &key, out);
                }
            }
            Value::Array(a) => {
                for (i, child) in a.iter().enumerate() {
                    numeric_leaves(child, &format!("{at}[{i}]"), out);
                }
            }
            Value::Number(_) | Value::Null => out.push((at.to_string(), pointer(at))),
            _ => {}
        }
    }

    /// Every number of the serialised configuration is checked up front: set to ±10¹² (an
    /// integer where the default is one), the configuration is refused with an error naming
    /// the key, so a new field without a range fails here.
    #[test]
    fn every_number_has_a_range_checked_up_front() {
        // Seeds take any value of their type.
        const ANY_U64: [&str; 4] = [
            "slam.seed",
            "slam.params.tracking.reloc.seed",
            "slam.params.loop_closing.detection.seed",
            "motion.rigidity.seed",
        ];
        for mode in [Mode::Paper, Mode::Reference] {
            let mut c = Config::new(mode);
            c.online.rigidity_flow = Some(OnlineConfig::cheap_rigidity_flow());
            c.sequence.max_frames = Some(100);
            let base = c.to_json_value();
            assert_eq!(Config::from_value(base.clone()).unwrap(), c);
            let mut leaves = Vec::new();
            numeric_leaves(&base, "", &mut leaves);
            assert!(leaves.len() > 150, "{}", leaves.len());
            for (key, pointer) in &leaves {
                let integer = base
                    .pointer(pointer)
                    .is_some_and(|v| v.is_i64() || v.is_u64());
                for sign in [1i64, -1] {
                    if sign > 0 && ANY_U64.contains(&key.as_str()) {
                        continue;
                    }
                    let absurd = if integer || base.pointer(pointer) == Some(&Value::Null) {
                        serde_json::json!(sign * 1_000_000_000_000)
                    } else {
                        serde_json::json!(sign as f64 * 1e12)
                    };
                    let mut doc = base.clone();
                    *doc.pointer_mut(pointer).unwrap() = absurd.clone();
                    let e = match Config::from_value(doc) {
                        Ok(_) => panic!("{key} = {absurd} was accepted"),
                        Err(e) => e.to_string(),
                    };
                    assert!(e.contains(key.as_str()), "{key} = {absurd}: {e}");
                }
            }
        }
        // The cases of issue 36, with the range in the message.
        for (doc, want) in [
            (
                r#"{"slam": {"params": {"tracking": {"matcher": {"histo_len": 1000000000000}}}}}"#,
                "slam.params.tracking.matcher.histo_len must lie in [1, 360], got 1000000000000",
            ),
            (
                r#"{"motion": {"params": {"moving": {"lowpass_sigma": 1e12}}}}"#,
                "motion.params.moving.lowpass_sigma must lie in [0, 100], got 1000000000000",
            ),
            (
                r#"{"passes": {"weighted": 1000000000000}}"#,
                "passes.weighted must lie in [1, 10], got 1000000000000",
            ),
            (
                r#"{"motion": {"rigidity": {"refine_rounds": 1000000000000}}}"#,
                "motion.rigidity.refine_rounds must lie in [0, 100], got 1000000000000",
            ),
            (
                r#"{"slam": {"params": {"tracking": {"pose": {"rounds": 1000000000000}}}}}"#,
                "slam.params.tracking.pose.rounds must lie in [1, 100], got 1000000000000",
            ),
            (
                r#"{"slam": {"params": {"tracking": {"reloc": {"probability": -1}}}}}"#,
                "slam.params.tracking.reloc.probability must lie in (0, 1], got -1",
            ),
            (
                r#"{"dynapix": {"gamma_del": 0}}"#,
                "dynapix.gamma_del must lie in (0, 1], got 0",
            ),
            (
                r#"{"motion": {"params": {"movable": {"clip_lo": 40}}}}"#,
                "motion.params.movable.clip_hi must exceed clip_lo (35 ≤ 40)",
            ),
        ] {
            let e = Config::from_json_str(doc).unwrap_err().to_string();
            assert!(e.contains(want), "{doc}: {e}");
        }
    }

    #[test]
    fn duplicate_keys_and_type_errors_name_the_key() {
        let e = Config::from_json_str(r#"{"passes": {"weighted": 2, "weighted": 3}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("duplicate key passes.weighted"), "{e}");
        let e = Config::from_yaml_str("passes:\n  weighted: 2\n  weighted: 3\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("weighted"), "{e}");
        let e = Config::from_json_str(r#"{"mode": "paper", "mode": "reference"}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("duplicate key mode"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let j = dir.path().join("c.json");
        std::fs::write(&j, r#"{"online": {"window": 3, "window": 4}}"#).unwrap();
        let e = Config::load(&j).unwrap_err().to_string();
        assert!(
            e.contains("c.json") && e.contains("duplicate key online.window"),
            "{e}"
        );
        for (doc, key) in [
            (
                r#"{"slam": {"params": {"tracking": {"pose": {"rounds": "four"}}}}}"#,
                "slam.params.tracking.pose.rounds",
            ),
            (r#"{"online": {"window": -3}}"#, "online.window"),
            (
                r#"{"motion": {"params": {"offsets": [1, "x"]}}}"#,
                "motion.params.offsets",
            ),
            (
                r#"{"sequence": {"skip_bad_frames": 1}}"#,
                "sequence.skip_bad_frames",
            ),
        ] {
            let e = Config::from_json_str(doc).unwrap_err().to_string();
            assert!(e.contains(key), "{doc}: {e}");
        }
    }

    #[test]
    fn the_flat_dynapix_section_gives_the_slam_thresholds() {
        // Defaults: the paper's thresholds, as before the section existed.
        let p = Config::default().system_params().map.dynapix;
        assert_eq!(
            p,
            DynaPixParams::new(dynapix_slam::weighting::Weighting::Paper)
        );
        let r = Config::new(Mode::Reference).system_params().map.dynapix;
        assert_eq!(
            r,
            DynaPixParams::new(dynapix_slam::weighting::Weighting::Reference)
        );
        let c = Config::from_yaml_str("dynapix: {gamma_add: 0.02, gamma_del: 0.3, update: max}\n")
            .unwrap();
        let d = c.system_params().map.dynapix;
        assert_eq!(
            (d.gamma_add, d.gamma_del, d.update),
            (0.02, 0.3, ProbUpdate::Max)
        );
        // ORB-SLAM2 mode keeps the thresholds but weighs nothing.
        let orb = c.clone().with_method(Method::Orbslam2).system_params();
        assert_eq!(
            orb.map.dynapix.weighting,
            dynapix_slam::weighting::Weighting::Off
        );
        // The record has the flat section and not the old place; it reads back.
        let v = c.to_json_value();
        assert_eq!(v["dynapix"]["gamma_add"], serde_json::json!(0.02));
        assert!(v.pointer("/slam/params/map/dynapix").is_none());
        assert_eq!(Config::from_value(v).unwrap(), c);
        // The old place is read into the new one; both with different values is an error.
        let old = Config::from_yaml_str(
            "slam: {params: {map: {dynapix: {gamma_add: 0.02, gamma_del: 0.3, update: max}}}}\n",
        )
        .unwrap();
        assert_eq!(old, c);
        let e = Config::from_yaml_str(
            "dynapix: {gamma_add: 0.03}\nslam: {params: {map: {dynapix: {gamma_add: 0.02}}}}\n",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("dynapix.gamma_add"), "{e}");
        let e = Config::from_yaml_str("slam: {params: {map: {dynapix: {weighting: off}}}}\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("slam.params.map.dynapix.weighting"), "{e}");
        // A threshold changed in code at the old place is not silently ignored.
        let mut c = Config::default();
        c.slam.params.map.dynapix.gamma_add = 0.2;
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("dynapix.gamma_add"), "{e}");
        let mut c = Config::default();
        c.dynapix.gamma_add = 0.2;
        c.validate().unwrap();
        assert_eq!(c.system_params().map.dynapix.gamma_add, 0.2);
    }

    /// YAML made of the keys and values a configuration has, so documents are often
    /// almost valid.
    fn near_yaml() -> impl proptest::strategy::Strategy<Value = String> {
        use proptest::prelude::*;
        proptest::collection::vec(
            prop_oneof![
                Just("mode: "),
                Just("paper"),
                Just("reference"),
                Just("method: "),
                Just("dynapix"),
                Just("orbslam2"),
                Just("sequence:"),
                Just("motion:"),
                Just("slam:"),
                Just("passes:"),
                Just("online:"),
                Just("params:"),
                Just("cues:"),
                Just("max_frames: "),
                Just("skip_bad_frames: "),
                Just("weighted: "),
                Just("window: "),
                Just("offsets: "),
                Just("past_offsets: "),
                Just("max_diff: "),
                Just("true"),
                Just("0"),
                Just("-1"),
                Just("1e400"),
                Just(".nan"),
                Just("~"),
                Just("[0, 1]"),
                Just("{"),
                Just("}"),
                Just("["),
                Just("]"),
                Just(":"),
                Just(","),
                Just("\n"),
                Just("  "),
                Just("- "),
                Just("\""),
                Just("&a "),
                Just("*a"),
                Just("!!str "),
                Just("#"),
            ],
            0..40,
        )
        .prop_map(|v| v.concat())
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(256))]

        /// A configuration document of any text is a configuration or an error, never a panic.
        #[test]
        fn config_parsers_never_panic(near in near_yaml(), any in proptest::prelude::any::<String>()) {
            for text in [&near, &any] {
                if let Ok(c) = Config::from_yaml_str(text) {
                    proptest::prop_assert!(c.validate().is_ok());
                }
                let _ = Config::from_json_str(text);
            }
        }
    }

    #[test]
    fn load_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.yaml");
        std::fs::write(&p, "method: threshold\nsequence:\n  max_frames: 20\n").unwrap();
        let c = Config::load(&p).unwrap();
        assert_eq!(
            (c.method, c.sequence.max_frames),
            (Method::Threshold, Some(20))
        );
        std::fs::write(&p, "method: [1\n").unwrap();
        let e = Config::load(&p).unwrap_err().to_string();
        assert!(e.contains("c.yaml"), "{e}");
        let j = dir.path().join("c.json");
        std::fs::write(&j, r#"{"mode": "reference"}"#).unwrap();
        assert_eq!(Config::load(&j).unwrap().mode, Mode::Reference);
    }
}
