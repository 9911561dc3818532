//! `dynapix slam`: runs the RGB-D SLAM system on a sequence folder and writes
//! `trajectory.txt` (TUM, every tracked frame, camera-to-world), `status.txt` (per frame:
//! tracked / lost / not_initialized), `keyframes.txt` and `timing.csv` into `--out`.
//! `--save-map FILE` saves the final map (`dynapix_slam::persist` format); `--localize MAP`
//! loads one and only tracks against it (localisation mode: no new keyframes or map points).

use std::path::{Path, PathBuf};
use std::sync::mpsc::sync_channel;
use std::time::Instant;

use anyhow::{Context, bail};
use dynapix_io::images::read_rgbd;
use dynapix_io::settings::SEQUENCE_SETTINGS_FILE;
use dynapix_io::trajectory::write_status;
use dynapix_io::tum::{
    DEFAULT_MAX_DIFF, associate_lists, associate_nearest, read_associations, read_list,
    resolve_path,
};
use dynapix_io::{Association, FrameStatus, Settings, StampedPose, StampedStatus, Trajectory};
use dynapix_slam::features::{Descriptor, KeyPoint};
use dynapix_slam::frame::{RgbdCamera, ScalePyramid};
use dynapix_slam::loop_closing::LoopEvent;
use dynapix_slam::orb::{OrbExtractor, OrbParams, rgb_to_gray_orbslam};
use dynapix_slam::system::{FeatureExtractor, FrameInput, System, SystemParams};
use dynapix_slam::tracking::TrackingState;
use dynapix_slam::vocab::Vocabulary;
use indicatif::{ProgressBar, ProgressStyle};

/// SLAM mode.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum Mode {
    /// Plain ORB-SLAM2 RGB-D (no motion probabilities).
    Orbslam2,
}

/// Camera presets (ORB-SLAM2 settings files).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum CameraPreset {
    /// TUM fr1 (`TUM1.yaml`, distorted).
    Tum1,
    /// TUM fr2 (`TUM2.yaml`, distorted, depth factor 5208).
    Tum2,
    /// TUM fr3 (`TUM3.yaml`).
    Tum3,
    /// GRADE (`GRADE.yaml`, depth in mm, 3000 features).
    Grade,
}

/// Arguments of `dynapix slam`.
#[derive(clap::Args)]
pub struct Args {
    /// Sequence folder (rgb.txt + depth.txt, or an association file).
    pub seq_dir: PathBuf,
    /// SLAM mode.
    #[arg(long, value_enum, default_value = "orbslam2")]
    pub mode: Mode,
    /// Camera preset (default: the folder's camera.yaml, or tumN for rgbd_dataset_freiburgN_*).
    #[arg(long, value_enum, conflicts_with = "settings")]
    pub camera: Option<CameraPreset>,
    /// ORB-SLAM2 settings YAML (Camera.*, ThDepth, DepthMapFactor, ORBextractor.*).
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// Association file (4 columns); default: association.txt / associations.txt /
    /// rgbd_assoc.txt in the folder, else every rgb.txt frame with its nearest depth.txt image
    /// within 0.02 s.
    #[arg(long)]
    pub association: Option<PathBuf>,
    /// Pair rgb and depth one-to-one like `associate.py` (drops rgb frames whose nearest depth
    /// went to a neighbour) instead of giving every rgb frame its nearest depth.
    #[arg(long)]
    pub unique_association: bool,
    /// Bag-of-words vocabulary (`dynapix vocab` binary format); default: the embedded one.
    #[arg(long, conflicts_with = "no_vocabulary")]
    pub vocabulary: Option<PathBuf>,
    /// Run without a vocabulary (brute-force keyframe matching).
    #[arg(long)]
    pub no_vocabulary: bool,
    /// Save the map at the end of the run to FILE (binary map format, written atomically;
    /// reuse it with --localize).
    #[arg(long, value_name = "FILE", conflicts_with = "localize")]
    pub save_map: Option<PathBuf>,
    /// Localisation mode: load MAP (written by --save-map with the same camera, ORB settings
    /// and vocabulary) and only track against it: frames are relocalised into the map, no
    /// keyframe or map point is created, the map file is not changed.
    #[arg(long, value_name = "MAP")]
    pub localize: Option<PathBuf>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Process at most this many frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Turn loop closing off (on by default; closed loops are listed in `OUT/loops.txt`).
    #[arg(long)]
    pub no_loop_closing: bool,
}

impl CameraPreset {
    /// The `dynapix_io` preset of the same name.
    fn settings(self) -> Settings {
        match self {
            CameraPreset::Tum1 => Settings::tum1(),
            CameraPreset::Tum2 => Settings::tum2(),
            CameraPreset::Tum3 => Settings::tum3(),
            CameraPreset::Grade => Settings::grade(),
        }
    }
}

/// Reads a settings file with `dynapix_io`'s validation; keys other than `Camera.fx fy cx
/// cy` may be missing and take the TUM values, as this command has always allowed.
pub(crate) fn read_settings(path: &Path) -> anyhow::Result<Settings> {
    let (settings, missing) = Settings::read_lenient(path)
        .with_context(|| format!("cannot use settings {}", path.display()))?;
    if !missing.is_empty() {
        tracing::debug!(
            "{}: missing keys take the TUM values: {}",
            path.display(),
            missing.join(", ")
        );
    }
    Ok(settings)
}

/// The settings of a run: `--settings`, else `--camera`, else the folder's `camera.yaml`,
/// else the preset of a `rgbd_dataset_freiburgN_*` folder, else an error.
pub(crate) fn resolve_settings(args: &Args) -> anyhow::Result<Settings> {
    if let Some(p) = &args.settings {
        return read_settings(p);
    }
    if let Some(c) = args.camera {
        return Ok(c.settings());
    }
    let own = args.seq_dir.join(SEQUENCE_SETTINGS_FILE);
    if own.is_file() {
        return read_settings(&own);
    }
    Settings::for_sequence_dir(&args.seq_dir).with_context(|| {
        format!(
            "cannot tell the camera of {}: pass --camera or --settings (or add camera.yaml)",
            args.seq_dir.display()
        )
    })
}

/// The SLAM camera of the settings (intrinsics, distortion, `bf`, `ThDepth`, fps).
pub(crate) fn rgbd_camera(s: &Settings) -> RgbdCamera {
    RgbdCamera::new(s.camera(), s.bf, s.th_depth, s.fps)
}

/// The ORB extractor parameters of the settings.
pub(crate) fn orb_params(s: &Settings) -> anyhow::Result<OrbParams> {
    let fast = |v: u32, key: &str| {
        u8::try_from(v).with_context(|| format!("ORBextractor.{key} {v} does not fit 0..=255"))
    };
    Ok(OrbParams {
        nfeatures: s.orb.n_features,
        scale_factor: s.orb.scale_factor as f32,
        nlevels: s.orb.n_levels,
        ini_th_fast: fast(s.orb.ini_th_fast, "iniThFAST")?,
        min_th_fast: fast(s.orb.min_th_fast, "minThFAST")?,
    })
}

pub(crate) fn load_frames(args: &Args) -> anyhow::Result<Vec<Association>> {
    let dir = &args.seq_dir;
    let explicit = args.association.clone().or_else(|| {
        ["association.txt", "associations.txt", "rgbd_assoc.txt"]
            .iter()
            .map(|n| dir.join(n))
            .find(|p| p.exists())
    });
    let mut frames = match explicit {
        Some(p) => read_associations(&p)?,
        None => {
            let rgb = read_list(dir.join("rgb.txt"))?;
            let depth = read_list(dir.join("depth.txt"))?;
            if args.unique_association {
                associate_lists(&rgb, &depth, 0.0, DEFAULT_MAX_DIFF)
            } else {
                associate_nearest(&rgb, &depth, DEFAULT_MAX_DIFF)
            }
        }
    };
    if let Some(m) = args.max_frames {
        frames.truncate(m);
    }
    if frames.is_empty() {
        bail!("{}: no rgb/depth pairs found", dir.display());
    }
    Ok(frames)
}

pub(crate) struct Orb(pub(crate) OrbExtractor);

impl FeatureExtractor for Orb {
    fn extract(&mut self, image: &image::GrayImage) -> (Vec<KeyPoint>, Vec<Descriptor>) {
        self.0.extract(image)
    }
    fn pyramid(&self) -> ScalePyramid {
        ScalePyramid::new(self.0.nlevels(), self.0.scale_factor())
    }
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let i = ((v.len() - 1) as f64 * p).round() as usize;
    v[i.min(v.len() - 1)]
}

/// Loads the map file `path`, checks it against the camera, ORB pyramid and vocabulary of
/// `system` and switches `system` to localisation mode on it; every error names the file.
/// Returns the summary line "localisation mode, map MAP (N keyframes, M points)".
fn enter_localization<E: FeatureExtractor>(
    system: &mut System<E>,
    path: &Path,
    settings: &Settings,
) -> anyhow::Result<String> {
    let t0 = Instant::now();
    let bytes = std::fs::read(path).map_err(|source| dynapix_slam::persist::PersistError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let t1 = Instant::now();
    let saved = dynapix_slam::persist::decode(&bytes)
        .with_context(|| format!("cannot load map {}", path.display()))?;
    let pyramid = system.map().pyramid.clone();
    saved
        .check_compatible(
            system.camera(),
            settings.depth_map_factor,
            &pyramid,
            system.vocabulary(),
        )
        .with_context(|| format!("cannot use map {} for this run", path.display()))?;
    let t2 = Instant::now();
    let note = format!(
        "localisation mode, map {} ({} keyframes, {} points)",
        path.display(),
        saved.num_keyframes(),
        saved.num_points()
    );
    let params = system.map().params.clone();
    system.enter_localization(saved.into_map(params));
    let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
    eprintln!(
        "{note}: loaded in {:.1} ms (read {:.1}, decode + check {:.1}, rebuild {:.1}; {} bytes)",
        t0.elapsed().as_secs_f64() * 1e3,
        ms(t0, t1),
        ms(t1, t2),
        t2.elapsed().as_secs_f64() * 1e3,
        bytes.len()
    );
    Ok(note)
}

/// Encodes the map of `system` and writes it atomically to `path`.
fn save_map<E: FeatureExtractor>(
    path: &Path,
    system: &System<E>,
    depth_factor: f64,
) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let bytes = dynapix_slam::persist::encode(
        system.map(),
        system.camera(),
        depth_factor,
        system.vocabulary(),
    )
    .with_context(|| format!("cannot save map {}", path.display()))?;
    let t1 = Instant::now();
    dynapix_io::write_atomic(path, &bytes)
        .with_context(|| format!("cannot save map {}", path.display()))?;
    eprintln!(
        "map saved to {} ({} keyframes, {} points, {:.2} MB; encode {:.1} ms, write {:.1} ms)",
        path.display(),
        system.map().num_keyframes(),
        system.map().num_points(),
        bytes.len() as f64 / 1e6,
        (t1 - t0).as_secs_f64() * 1e3,
        t1.elapsed().as_secs_f64() * 1e3
    );
    Ok(())
}

/// Runs `dynapix slam`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let Mode::Orbslam2 = args.mode;
    let settings = resolve_settings(&args)?;
    if !(100.0..=100_000.0).contains(&settings.depth_map_factor) {
        tracing::warn!(
            "implausible DepthMapFactor {} (expected about 1000-5208)",
            settings.depth_map_factor
        );
    }
    let frames = load_frames(&args)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let extractor = OrbExtractor::new(orb_params(&settings)?).context("bad ORB settings")?;
    let mut params = SystemParams::default();
    params.loop_closing.enabled = !args.no_loop_closing;
    let mut system = System::new(Orb(extractor), rgbd_camera(&settings), params);
    if !args.no_vocabulary {
        let vocab = match &args.vocabulary {
            Some(p) => Vocabulary::load(p)
                .with_context(|| format!("cannot load vocabulary {}", p.display()))?,
            None => Vocabulary::embedded_default().context("embedded vocabulary")?,
        };
        system = system.with_vocabulary(vocab);
    }
    let localize_note = match &args.localize {
        Some(path) => enter_localization(&mut system, path, &settings)?,
        None => String::new(),
    };

    // Images are decoded on a helper thread, a few frames ahead of tracking.
    let (tx, rx) = sync_channel(4);
    let dir = args.seq_dir.clone();
    let depth_factor = settings.depth_map_factor;
    let list = frames.clone();
    let loader = std::thread::spawn(move || {
        for a in list {
            let r = read_rgbd(
                resolve_path(&dir, &a.rgb),
                resolve_path(&dir, &a.depth),
                depth_factor,
            );
            if tx.send((a.t_rgb, r)).is_err() {
                break;
            }
        }
    });

    let pb = ProgressBar::new(frames.len() as u64);
    pb.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} {per_sec} {msg} [{elapsed_precise}]")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut status = Vec::with_capacity(frames.len());
    let mut timing =
        String::from("index,timestamp,extract_ms,track_ms,mapping_ms,loop_ms,keyframe,state\n");
    let (mut t_track, mut t_total) = (Vec::new(), Vec::new());
    for (t, r) in rx {
        let (rgb, depth) = r?;
        let gray = rgb_to_gray_orbslam(&rgb);
        let res = system.process(FrameInput {
            timestamp: t,
            gray: &gray,
            depth: &depth,
            weights: None,
            masks: None,
        })?;
        let st = frame_status(res.state);
        status.push(StampedStatus { t, status: st });
        let tr = (res.times.extract + res.times.track) * 1e3;
        t_track.push(tr);
        t_total.push(tr + (res.times.mapping + res.times.loop_closing) * 1e3);
        timing.push_str(&format!(
            "{},{:.6},{:.3},{:.3},{:.3},{:.3},{},{}\n",
            res.index,
            t,
            res.times.extract * 1e3,
            res.times.track * 1e3,
            res.times.mapping * 1e3,
            res.times.loop_closing * 1e3,
            u8::from(res.new_keyframe),
            st
        ));
        pb.set_message(format!(
            "{st} kf {} mp {}",
            system.map().num_keyframes(),
            system.map().num_points()
        ));
        pb.inc(1);
    }
    pb.finish();
    loader
        .join()
        .map_err(|_| anyhow::anyhow!("image loader thread panicked"))?;

    write_outputs(&system, &status, &args.out)?;
    dynapix_io::write_atomic(args.out.join("timing.csv"), timing.as_bytes())?;
    let tracked = status
        .iter()
        .filter(|s| s.status == FrameStatus::Tracked)
        .count();
    let n = t_track.len().max(1) as f64;
    let mean_track = t_track.iter().sum::<f64>() / n;
    let mean_total = t_total.iter().sum::<f64>() / n;
    eprintln!(
        "{} frames, {} tracked, {} keyframes, {} map points, {} loops closed; tracking ms median {:.1} mean {:.1} p95 {:.1}; total ms/frame mean {:.1}",
        status.len(),
        tracked,
        system.map().num_keyframes(),
        system.map().num_points(),
        system.loop_events().len(),
        median(&mut t_track.clone()),
        mean_track,
        percentile(&mut t_track, 0.95),
        mean_total
    );
    if !localize_note.is_empty() {
        eprintln!("{localize_note}");
    }
    if let Some(path) = &args.save_map {
        save_map(path, &system, settings.depth_map_factor)?;
    }
    Ok(())
}

/// The status-file value of a tracking state.
pub(crate) fn frame_status(state: TrackingState) -> FrameStatus {
    match state {
        TrackingState::Ok => FrameStatus::Tracked,
        TrackingState::Lost => FrameStatus::Lost,
        TrackingState::NotInitialized => FrameStatus::NotInitialized,
    }
}

/// Writes what every SLAM run leaves in `out`: `trajectory.txt` (TUM, the current estimate of
/// every tracked frame), `status.txt`, `keyframes.txt` and `loops.txt`.
pub(crate) fn write_outputs<E: FeatureExtractor>(
    system: &System<E>,
    status: &[StampedStatus],
    out: &Path,
) -> anyhow::Result<()> {
    let traj = Trajectory::new(
        system
            .trajectory()
            .into_iter()
            .filter_map(|e| e.pose_wc.map(|p| StampedPose::new(e.timestamp, p)))
            .collect(),
    );
    traj.write_tum(out.join("trajectory.txt"))?;
    write_status(out.join("status.txt"), status)?;
    let kfs = Trajectory::new(
        system
            .keyframe_trajectory()
            .into_iter()
            .map(|(t, p)| StampedPose::new(t, p))
            .collect(),
    );
    kfs.write_tum(out.join("keyframes.txt"))?;
    write_loops(&out.join("loops.txt"), system.loop_events())
}

/// Writes the closed loops, one per line: the two keyframes' timestamps, the matches and what
/// the correction did and took (essential graph and global BA times in ms).
pub(crate) fn write_loops(path: &Path, events: &[LoopEvent]) -> anyhow::Result<()> {
    let mut s = String::from(
        "# current_kf_timestamp loop_kf_timestamp matched_points corrected_keyframes fused_points essential_graph_edges essential_graph_ms global_ba_ms\n",
    );
    for e in events {
        let c = &e.correction;
        s.push_str(&format!(
            "{:.6} {:.6} {} {} {} {} {:.3} {:.3}\n",
            e.current_timestamp,
            e.loop_timestamp,
            e.matched_points,
            c.corrected_keyframes,
            c.fused_points,
            c.essential_graph_edges,
            c.essential_graph_seconds * 1e3,
            c.global_ba_seconds * 1e3,
        ));
    }
    dynapix_io::write_atomic(path, s.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}
