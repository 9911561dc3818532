//! `dynapix slam`: runs the RGB-D SLAM system on a sequence folder and writes
//! `trajectory.txt` (TUM, every tracked frame, camera-to-world), `status.txt` (per frame:
//! tracked / lost / not_initialized), `keyframes.txt` and `timing.csv` into `--out`.

use std::path::{Path, PathBuf};
use std::sync::mpsc::sync_channel;

use anyhow::{Context, bail};
use dynapix_geometry::PinholeCamera;
use dynapix_io::images::read_rgbd;
use dynapix_io::trajectory::write_status;
use dynapix_io::tum::{
    DEFAULT_MAX_DIFF, associate_lists, read_associations, read_list, resolve_path,
};
use dynapix_io::{Association, FrameStatus, ListEntry, StampedPose, StampedStatus, Trajectory};
use dynapix_slam::features::{Descriptor, KeyPoint};
use dynapix_slam::frame::{RgbdCamera, ScalePyramid};
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
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Process at most this many frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
}

/// Everything read from a settings file or preset.
#[derive(Clone, Debug)]
pub(crate) struct Settings {
    pub(crate) camera: RgbdCamera,
    pub(crate) depth_factor: f64,
    pub(crate) orb: OrbParams,
}

fn preset(p: CameraPreset) -> Settings {
    let (fx, fy, cx, cy, dist, depth_factor, nfeatures) = match p {
        CameraPreset::Tum1 => (
            517.306408,
            516.469215,
            318.643040,
            255.313989,
            [0.262383, -0.953104, -0.005358, 0.002628, 1.163314],
            5000.0,
            1000,
        ),
        CameraPreset::Tum2 => (
            520.908620,
            521.007327,
            325.141442,
            249.701764,
            [0.231222, -0.784899, -0.003257, -0.000105, 0.917205],
            5208.0,
            1000,
        ),
        CameraPreset::Tum3 => (535.4, 539.2, 320.1, 247.6, [0.0; 5], 5000.0, 1000),
        CameraPreset::Grade => (325.9103, 399.3103, 320.0, 240.0, [0.0; 5], 1000.0, 3000),
    };
    let mut pin = PinholeCamera::new(640, 480, fx, fy, cx, cy);
    pin.dist = dist;
    Settings {
        camera: RgbdCamera::new(pin, 40.0, 40.0, 30.0),
        depth_factor,
        orb: OrbParams {
            nfeatures,
            ..OrbParams::default()
        },
    }
}

/// Minimal reader of ORB-SLAM2 settings (`key: value` lines; `%YAML` header and comments
/// ignored). Missing camera keys are an error; other keys default to ORB-SLAM2's values.
fn read_settings(path: &Path) -> anyhow::Result<Settings> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read settings {}", path.display()))?;
    let mut kv = std::collections::HashMap::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() || line.starts_with('%') || line == "---" {
            continue;
        }
        if let Some((k, v)) = line.split_once(':') {
            let v = v.trim();
            if v.is_empty() {
                continue;
            }
            if let Ok(x) = v.parse::<f64>() {
                kv.insert(k.trim().to_string(), x);
            } else {
                tracing::debug!("{}:{}: ignoring non-numeric key {k}", path.display(), n + 1);
            }
        }
    }
    let get = |k: &str| -> anyhow::Result<f64> {
        kv.get(k)
            .copied()
            .with_context(|| format!("{}: missing key {k}", path.display()))
    };
    let opt = |k: &str, d: f64| kv.get(k).copied().unwrap_or(d);
    let mut pin = PinholeCamera::new(
        opt("Camera.width", 640.0) as u32,
        opt("Camera.height", 480.0) as u32,
        get("Camera.fx")?,
        get("Camera.fy")?,
        get("Camera.cx")?,
        get("Camera.cy")?,
    );
    pin.dist = [
        opt("Camera.k1", 0.0),
        opt("Camera.k2", 0.0),
        opt("Camera.p1", 0.0),
        opt("Camera.p2", 0.0),
        opt("Camera.k3", 0.0),
    ];
    let camera = RgbdCamera::new(
        pin,
        opt("Camera.bf", 40.0),
        opt("ThDepth", 40.0),
        opt("Camera.fps", 30.0),
    );
    let d = OrbParams::default();
    Ok(Settings {
        camera,
        depth_factor: opt("DepthMapFactor", 5000.0),
        orb: OrbParams {
            nfeatures: opt("ORBextractor.nFeatures", d.nfeatures as f64) as usize,
            scale_factor: opt("ORBextractor.scaleFactor", d.scale_factor as f64) as f32,
            nlevels: opt("ORBextractor.nLevels", d.nlevels as f64) as usize,
            ini_th_fast: opt("ORBextractor.iniThFAST", d.ini_th_fast as f64) as u8,
            min_th_fast: opt("ORBextractor.minThFAST", d.min_th_fast as f64) as u8,
        },
    })
}

pub(crate) fn resolve_settings(args: &Args) -> anyhow::Result<Settings> {
    if let Some(p) = &args.settings {
        return read_settings(p);
    }
    if let Some(c) = args.camera {
        return Ok(preset(c));
    }
    let own = args.seq_dir.join("camera.yaml");
    if own.exists() {
        return read_settings(&own);
    }
    let name = args
        .seq_dir
        .canonicalize()
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_default();
    for (prefix, c) in [
        ("rgbd_dataset_freiburg1_", CameraPreset::Tum1),
        ("rgbd_dataset_freiburg2_", CameraPreset::Tum2),
        ("rgbd_dataset_freiburg3_", CameraPreset::Tum3),
    ] {
        if name.starts_with(prefix) {
            return Ok(preset(c));
        }
    }
    bail!(
        "cannot tell the camera of {}: pass --camera or --settings (or add camera.yaml)",
        args.seq_dir.display()
    )
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
                nearest_depth(&rgb, &depth, DEFAULT_MAX_DIFF)
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

/// Every rgb frame with the depth image nearest in time (within `max_diff`; a depth image may
/// serve two rgb frames), so no rgb frame is skipped and the tracking rate is measured against
/// the full rgb list. `associate.py`'s one-to-one pairing drops a few frames instead.
fn nearest_depth(rgb: &[ListEntry], depth: &[ListEntry], max_diff: f64) -> Vec<Association> {
    rgb.iter()
        .filter_map(|r| {
            let d = depth
                .iter()
                .min_by(|a, b| (a.t - r.t).abs().total_cmp(&(b.t - r.t).abs()))?;
            ((d.t - r.t).abs() < max_diff).then(|| Association {
                t_rgb: r.t,
                rgb: r.path.clone(),
                t_depth: d.t,
                depth: d.path.clone(),
            })
        })
        .collect()
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

/// Runs `dynapix slam`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let Mode::Orbslam2 = args.mode;
    let settings = resolve_settings(&args)?;
    if !(100.0..=100_000.0).contains(&settings.depth_factor) {
        tracing::warn!(
            "implausible DepthMapFactor {} (expected about 1000-5208)",
            settings.depth_factor
        );
    }
    let frames = load_frames(&args)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let extractor = OrbExtractor::new(settings.orb.clone()).context("bad ORB settings")?;
    let mut system = System::new(
        Orb(extractor),
        settings.camera.clone(),
        SystemParams::default(),
    );
    if !args.no_vocabulary {
        let vocab = match &args.vocabulary {
            Some(p) => Vocabulary::load(p)
                .with_context(|| format!("cannot load vocabulary {}", p.display()))?,
            None => Vocabulary::embedded_default().context("embedded vocabulary")?,
        };
        system = system.with_vocabulary(vocab);
    }

    // Images are decoded on a helper thread, a few frames ahead of tracking.
    let (tx, rx) = sync_channel(4);
    let dir = args.seq_dir.clone();
    let depth_factor = settings.depth_factor;
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
        String::from("index,timestamp,extract_ms,track_ms,mapping_ms,keyframe,state\n");
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
        });
        let st = match res.state {
            TrackingState::Ok => FrameStatus::Tracked,
            TrackingState::Lost => FrameStatus::Lost,
            TrackingState::NotInitialized => FrameStatus::NotInitialized,
        };
        status.push(StampedStatus { t, status: st });
        let tr = (res.times.extract + res.times.track) * 1e3;
        t_track.push(tr);
        t_total.push(tr + res.times.mapping * 1e3);
        timing.push_str(&format!(
            "{},{:.6},{:.3},{:.3},{:.3},{},{}\n",
            res.index,
            t,
            res.times.extract * 1e3,
            res.times.track * 1e3,
            res.times.mapping * 1e3,
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

    let traj = Trajectory::new(
        system
            .trajectory()
            .into_iter()
            .filter_map(|e| e.pose_wc.map(|p| StampedPose::new(e.timestamp, p)))
            .collect(),
    );
    traj.write_tum(args.out.join("trajectory.txt"))?;
    write_status(args.out.join("status.txt"), &status)?;
    let kfs = Trajectory::new(
        system
            .keyframe_trajectory()
            .into_iter()
            .map(|(t, p)| StampedPose::new(t, p))
            .collect(),
    );
    kfs.write_tum(args.out.join("keyframes.txt"))?;
    dynapix_io::write_atomic(args.out.join("timing.csv"), timing.as_bytes())?;
    let tracked = status
        .iter()
        .filter(|s| s.status == FrameStatus::Tracked)
        .count();
    let n = t_track.len().max(1) as f64;
    let mean_track = t_track.iter().sum::<f64>() / n;
    let mean_total = t_total.iter().sum::<f64>() / n;
    eprintln!(
        "{} frames, {} tracked, {} keyframes, {} map points; tracking ms median {:.1} mean {:.1} p95 {:.1}; total ms/frame mean {:.1}",
        status.len(),
        tracked,
        system.map().num_keyframes(),
        system.map().num_points(),
        median(&mut t_track.clone()),
        mean_track,
        percentile(&mut t_track, 0.95),
        mean_total
    );
    Ok(())
}
