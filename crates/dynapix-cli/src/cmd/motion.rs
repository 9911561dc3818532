//! `dynapix motion`: per-pixel motion probability maps for a sequence (paper §3.1, spec §1).
//!
//! Reads `association.txt` (or `rgb.txt` + `depth.txt`), the camera (`camera.yaml`, `--camera`,
//! or the TUM preset of `rgbd_dataset_freiburgN_*` folders), poses (ground truth with
//! SLERP, or any TUM trajectory) and a background source (`background/` + `depth_bg/`
//! folders, or a reconstruction from neighbouring frames), and writes
//! `SEQ_DIR/prob/<rgb file name>` (16-bit, `trunc((1 − P)·1000)`, the reference format) plus
//! `prob/motion.json` recording every source and parameter. All frames are checked before
//! anything is written; each output file is written atomically, and frames whose output
//! exists are skipped unless `--force`, so an interrupted run resumes.

use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, bail};
use dynapix_geometry::Se3;
use dynapix_io::settings::SEQUENCE_SETTINGS_FILE;
use dynapix_io::{Settings, StampedPose, Trajectory};
use dynapix_motion::background::{ReconstructParams, Source, reconstruct_background};
use dynapix_motion::metrics::{RocAccumulator, psnr_masked};
use dynapix_motion::{
    FloatImage, FrameImages, Mode, MotionParams, Neighbour, Variant, motion_probability,
};
use image::{Rgb, RgbImage};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde_json::json;

/// Where the static background comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BackgroundSource {
    /// `background/` (and `depth_bg/` if present) next to `rgb/`.
    Folder,
    /// Median of neighbouring frames splatted into the current view.
    Reconstruct,
    /// `folder` when `background/` exists, else `reconstruct`.
    Auto,
}

/// Paper or reference behaviour.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ModeArg {
    /// The paper's method with the reference's defects fixed.
    Paper,
    /// The reference code's behaviour, constant by constant.
    Reference,
}

/// Reference constant set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum VariantArg {
    /// TUM script constants (neighbours ±1, flow clip [1, 4] px).
    Tum,
    /// GRADE script constants (neighbours ±2, flow clip [0.5, 2.5] px).
    Grade,
}

/// Arguments of `dynapix motion`.
#[derive(clap::Args)]
pub struct Args {
    /// Sequence folder (with association.txt or rgb.txt + depth.txt).
    pub seq_dir: PathBuf,
    /// Poses for splatting: `gt` (SEQ_DIR/groundtruth.txt, SLERP at frame time) or a TUM
    /// trajectory file.
    #[arg(long, default_value = "gt")]
    pub poses: String,
    /// Largest allowed distance (s) from a frame to the nearest pose.
    #[arg(long, default_value_t = 0.05)]
    pub max_pose_gap: f64,
    /// Static background source.
    #[arg(long, value_enum, default_value_t = BackgroundSource::Auto)]
    pub background: BackgroundSource,
    /// Paper method (default) or reference behaviour.
    #[arg(long, value_enum, default_value_t = ModeArg::Paper)]
    pub mode: ModeArg,
    /// Reference constant set.
    #[arg(long, value_enum, default_value_t = VariantArg::Tum)]
    pub variant: VariantArg,
    /// Neighbour offsets J, comma separated (default ±1 for tum, ±2 for grade).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub offsets: Option<Vec<i64>>,
    /// Ablation: no movable term (D = 1).
    #[arg(long)]
    pub no_movable: bool,
    /// Ablation: no moving term (M = 1).
    #[arg(long)]
    pub no_moving: bool,
    /// DIS preset: ultrafast, fast or medium.
    #[arg(long, default_value = "fast")]
    pub flow_preset: String,
    /// Background reconstruction: largest frame offset.
    #[arg(long, default_value_t = 15)]
    pub bg_radius: usize,
    /// Refine the rotation of every relative pose by this many image-alignment iterations
    /// before splatting (for noisy poses, e.g. from a SLAM run); 0 trusts the poses.
    #[arg(long, default_value_t = 0)]
    pub refine_rotation: usize,
    /// Background reconstruction: offset step.
    #[arg(long, default_value_t = 3)]
    pub bg_step: usize,
    /// Recompute frames whose output already exists.
    #[arg(long)]
    pub force: bool,
    /// Also write P losslessly as `prob/<stem>.pfm`.
    #[arg(long)]
    pub float_maps: bool,
    /// Also write pictures (moving regions in red over the frame) to `SEQ_DIR/prob_vis/`.
    #[arg(long)]
    pub pictures: bool,
    /// Also write reconstructed backgrounds to `SEQ_DIR/background_rec/`.
    #[arg(long)]
    pub save_background: bool,
    /// Measure the maps against `mask/` (255 = moving): ROC-AUC and IoU at P > 0.5; with a
    /// reconstructed background and a `background/` folder, also its PSNR inside the movers.
    #[arg(long)]
    pub eval_masks: bool,
    /// Perturb every pose: RMS translation (m) and rotation (degrees), e.g. `0.01,1`.
    #[arg(long, value_delimiter = ',', num_args = 1)]
    pub pose_noise: Option<Vec<f64>>,
    /// Seed of `--pose-noise`.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Write the poses used (after noise) as a TUM trajectory.
    #[arg(long)]
    pub write_poses: Option<PathBuf>,
    /// Camera settings file (ORB-SLAM2 YAML); default SEQ_DIR/camera.yaml.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Only the first N frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
}

/// One frame of the sequence, paths resolved.
struct FrameInfo {
    t: f64,
    name: String,
    rgb: PathBuf,
    depth: PathBuf,
    background: PathBuf,
    depth_bg: PathBuf,
    mask: PathBuf,
}

/// Replaces the first path component equal to `from` by `to` (e.g. `rgb/1.png` →
/// `background/1.png`), as the reference derives the background path from the rgb path.
fn sibling(dir: &Path, written: &str, from: &str, to: &str) -> PathBuf {
    let mut done = false;
    let parts: Vec<String> = Path::new(written.trim_start_matches('/'))
        .components()
        .map(|c| {
            let s = c.as_os_str().to_string_lossy().to_string();
            if !done && s == from {
                done = true;
                to.to_string()
            } else {
                s
            }
        })
        .collect();
    let rel: PathBuf = parts.iter().collect();
    dir.join(rel)
}

fn read_frames(seq: &Path) -> anyhow::Result<Vec<FrameInfo>> {
    let assoc_path = seq.join("association.txt");
    let assoc = if assoc_path.exists() {
        dynapix_io::tum::read_associations(&assoc_path)?
    } else if seq.join("rgb.txt").exists() && seq.join("depth.txt").exists() {
        let rgb = dynapix_io::tum::read_list(seq.join("rgb.txt"))?;
        let depth = dynapix_io::tum::read_list(seq.join("depth.txt"))?;
        dynapix_io::tum::associate_lists(&rgb, &depth, 0.0, dynapix_io::tum::DEFAULT_MAX_DIFF)
    } else {
        bail!(
            "{}: no association.txt and no rgb.txt + depth.txt",
            seq.display()
        );
    };
    if assoc.is_empty() {
        bail!("{}: the sequence has no frames", seq.display());
    }
    Ok(assoc
        .iter()
        .map(|a| {
            let rgb = dynapix_io::tum::resolve_path(seq, &a.rgb);
            let name = rgb
                .file_name()
                .map(|n| n.to_string_lossy().to_string())
                .unwrap_or_else(|| a.rgb.clone());
            FrameInfo {
                t: a.t_rgb,
                name,
                depth: dynapix_io::tum::resolve_path(seq, &a.depth),
                background: sibling(seq, &a.rgb, "rgb", "background"),
                depth_bg: sibling(seq, &a.depth, "depth", "depth_bg"),
                mask: sibling(seq, &a.rgb, "rgb", "mask"),
                rgb,
            }
        })
        .collect())
}

/// The pose at `t`: SLERP between the poses around it, provided the nearest pose is within
/// `max_gap` seconds (the nearest pose itself just outside the trajectory's time range).
fn pose_at(traj: &Trajectory, t: f64, max_gap: f64) -> Option<Se3> {
    let after = traj.poses.partition_point(|p| p.t <= t);
    let cands = [after.checked_sub(1), Some(after)];
    let nearest = cands
        .iter()
        .flatten()
        .filter_map(|&i| traj.poses.get(i))
        .min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs()))?;
    if (nearest.t - t).abs() > max_gap {
        return None;
    }
    traj.interpolate(t, f64::INFINITY).or(Some(nearest.pose))
}

/// Images of one frame held in memory.
struct Loaded {
    rgb: RgbImage,
    depth: FloatImage,
}

/// A background and its depth.
struct Bg {
    rgb: RgbImage,
    depth: FloatImage,
}

/// Runs `dynapix motion`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let seq = args.seq_dir.clone();
    let started = Instant::now();
    let mut frames = read_frames(&seq)?;
    if let Some(n) = args.max_frames {
        if n == 0 {
            bail!("--max-frames must be at least 1");
        }
        frames.truncate(n);
    }
    let n = frames.len();

    // Camera.
    // `--camera FILE`, else SEQ_DIR/camera.yaml, else the TUM preset of a
    // `rgbd_dataset_freiburgN_*` folder. Short files are accepted (missing keys take the
    // TUM values); without a stated image size the first frame's size is used.
    let cam_path = args
        .camera
        .clone()
        .unwrap_or_else(|| seq.join(SEQUENCE_SETTINGS_FILE));
    let (settings, size_stated) = if args.camera.is_some() || cam_path.is_file() {
        let (s, missing) = Settings::read_lenient(&cam_path)
            .with_context(|| format!("cannot use camera settings {}", cam_path.display()))?;
        let stated = !missing.contains(&"Camera.width") && !missing.contains(&"Camera.height");
        (s, stated)
    } else {
        let s = Settings::for_sequence_dir(&seq).with_context(|| {
            format!(
                "cannot tell the camera: no {} (give --camera FILE)",
                cam_path.display()
            )
        })?;
        (s, true)
    };
    let depth_factor = settings.depth_map_factor;
    let mut cam = settings.camera();
    let first_size = image::image_dimensions(&frames[0].rgb)
        .with_context(|| format!("reading {}", frames[0].rgb.display()))?;
    if !size_stated {
        cam.width = first_size.0;
        cam.height = first_size.1;
    }
    let size = (cam.width, cam.height);
    if cam.is_distorted() {
        tracing::warn!("the camera has distortion; splatting uses the ideal pinhole model");
    }

    // Parameters.
    let mode = match args.mode {
        ModeArg::Paper => Mode::Paper,
        ModeArg::Reference => Mode::Reference,
    };
    let variant = match args.variant {
        VariantArg::Tum => Variant::Tum,
        VariantArg::Grade => Variant::Grade,
    };
    let mut params = MotionParams::new(variant, mode);
    if let Some(o) = &args.offsets {
        if o.contains(&0) {
            bail!("--offsets must not contain 0");
        }
        params.offsets = o.clone();
    }
    params.use_movable = !args.no_movable;
    params.use_moving = !args.no_moving;
    let bg_source = match args.background {
        BackgroundSource::Auto => {
            if frames[0].background.exists() {
                BackgroundSource::Folder
            } else {
                BackgroundSource::Reconstruct
            }
        }
        b => b,
    };
    params.moving.refine_iterations = args.refine_rotation;
    let recon = ReconstructParams {
        radius: args.bg_radius,
        step: args.bg_step,
        refine_iterations: args.refine_rotation,
        ..Default::default()
    };
    let preset: dynapix_flow::dis::Preset = args
        .flow_preset
        .parse()
        .map_err(|e| anyhow::anyhow!("--flow-preset: {e}"))?;
    let flow = dynapix_flow::dis::DisFlow::with_preset(preset);
    let use_depth_bg = bg_source == BackgroundSource::Folder && frames[0].depth_bg.exists();

    // Poses.
    let needs_poses = params.use_moving || bg_source == BackgroundSource::Reconstruct;
    let (traj_path, pose_kind) = if args.poses == "gt" {
        (seq.join("groundtruth.txt"), "gt")
    } else {
        (PathBuf::from(&args.poses), "file")
    };
    let mut poses: Vec<Option<Se3>> = vec![None; n];
    if needs_poses {
        let traj = Trajectory::read_tum(&traj_path)?;
        for (p, f) in poses.iter_mut().zip(&frames) {
            *p = pose_at(&traj, f.t, args.max_pose_gap);
        }
    }
    let noise = match &args.pose_noise {
        None => None,
        Some(v) if v.len() == 2 && v.iter().all(|x| *x >= 0.0) => Some((v[0], v[1])),
        Some(v) => bail!("--pose-noise wants METRES,DEGREES, got {v:?}"),
    };

    // Validate every frame before writing anything.
    let mut problems: Vec<String> = frames
        .par_iter()
        .enumerate()
        .flat_map_iter(|(i, f)| {
            let mut p = Vec::new();
            let mut check = |path: &Path, what: &str| match image::image_dimensions(path) {
                Ok(d) if d == size => {}
                Ok(d) => p.push(format!(
                    "frame {i} ({}): {what} {} is {}×{}, expected {}×{}",
                    f.name,
                    path.display(),
                    d.0,
                    d.1,
                    size.0,
                    size.1
                )),
                Err(e) => p.push(format!(
                    "frame {i} ({}): {what} {}: {e}",
                    f.name,
                    path.display()
                )),
            };
            check(&f.rgb, "rgb");
            check(&f.depth, "depth");
            if bg_source == BackgroundSource::Folder {
                check(&f.background, "background");
                if use_depth_bg {
                    check(&f.depth_bg, "background depth");
                }
            }
            if args.eval_masks {
                check(&f.mask, "mask");
            }
            if needs_poses && poses[i].is_none() {
                p.push(format!(
                    "frame {i} ({}): no pose within {} s of t = {:.6} in {}",
                    f.name,
                    args.max_pose_gap,
                    f.t,
                    traj_path.display()
                ));
            }
            if p.is_empty() {
                match dynapix_io::images::read_depth_raw(&f.depth) {
                    Ok(d) if d.iter().all(|&v| v == 0) => {
                        p.push(format!("frame {i} ({}): depth is all zero", f.name))
                    }
                    Ok(_) => {}
                    Err(e) => p.push(format!("frame {i} ({}): {e}", f.name)),
                }
            }
            p
        })
        .collect();
    if !problems.is_empty() {
        let total = problems.len();
        problems.truncate(30);
        let more = if total > 30 {
            format!("\n  … and {} more", total - 30)
        } else {
            String::new()
        };
        bail!(
            "{total} problem(s) in {}:\n  {}{more}",
            seq.display(),
            problems.join("\n  ")
        );
    }
    let mut poses: Vec<Se3> = poses
        .into_iter()
        .map(|p| p.unwrap_or_else(Se3::identity))
        .collect();
    if let Some((st, sr)) = noise {
        poses = dynapix_motion::noise::perturb_poses(&poses, st, sr, args.seed);
    }
    if let Some(path) = &args.write_poses {
        let traj = Trajectory::new(
            frames
                .iter()
                .zip(&poses)
                .map(|(f, p)| StampedPose::new(f.t, *p))
                .collect(),
        );
        traj.write_tum(path)?;
    }

    // Configuration record; a resumed run must use the same one.
    let out_dir = seq.join("prob");
    let config = json!({
        "frames": n,
        "poses": {
            "source": pose_kind,
            "path": if pose_kind == "gt" { "groundtruth.txt".to_string() } else { traj_path.display().to_string() },
            "interpolation": "slerp",
            "max_gap_s": args.max_pose_gap,
            "noise": noise.map(|(t, r)| json!({"rms_translation_m": t, "rms_rotation_deg": r, "seed": args.seed})),
        },
        "background": match bg_source {
            BackgroundSource::Reconstruct => json!({"source": "reconstruct", "params": recon}),
            _ => json!({"source": "folder", "depth": if use_depth_bg { "depth_bg" } else { "depth (dynamic)" }}),
        },
        "flow": {"provider": "dis", "preset": args.flow_preset, "params": flow.params},
        "camera": cam,
        "depth_factor": depth_factor,
        "params": params,
        "output": "uint16 trunc((1 - P) * 1000), 16-bit PNG named like the rgb image",
    });
    let json_path = out_dir.join("motion.json");
    if json_path.exists() && !args.force {
        let old: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(&json_path)
                .with_context(|| format!("reading {}", json_path.display()))?,
        )
        .with_context(|| format!("parsing {}", json_path.display()))?;
        if old.get("config") != Some(&config) {
            bail!(
                "{} was written with other settings; use --force to recompute all frames",
                json_path.display()
            );
        }
    }
    std::fs::create_dir_all(&out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let vis_dir = seq.join("prob_vis");
    let bgrec_dir = seq.join("background_rec");
    if args.pictures {
        std::fs::create_dir_all(&vis_dir)?;
    }
    if args.save_background && bg_source == BackgroundSource::Reconstruct {
        std::fs::create_dir_all(&bgrec_dir)?;
    }
    let write_json = |status: &str, extra: serde_json::Value| -> anyhow::Result<()> {
        let doc = json!({
            "sequence": seq.display().to_string(),
            "config": config,
            "status": status,
            "results": extra,
        });
        dynapix_io::write_atomic(&json_path, serde_json::to_string_pretty(&doc)?.as_bytes())?;
        Ok(())
    };
    write_json("running", json!(null))?;

    let out_path = |i: usize| out_dir.join(&frames[i].name).with_extension("png");
    let todo: Vec<usize> = (0..n)
        .filter(|&i| args.force || !out_path(i).exists())
        .collect();
    let skipped: Vec<usize> = (0..n).filter(|i| !todo.contains(i)).collect();
    if !skipped.is_empty() {
        tracing::info!("{} frame(s) already done, skipping", skipped.len());
    }

    let in_range = |j: i64| (j >= 0 && (j as usize) < n).then_some(j as usize);
    let moving_offsets: Vec<i64> = if params.use_moving {
        params.offsets.clone()
    } else {
        Vec::new()
    };
    let bg_offsets = recon.offsets();
    let load = |i: usize| -> anyhow::Result<Loaded> {
        let f = &frames[i];
        Ok(Loaded {
            rgb: dynapix_io::images::read_rgb(&f.rgb)?,
            depth: dynapix_io::images::read_depth(&f.depth, depth_factor)?,
        })
    };

    let bar = ProgressBar::new(todo.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} frames {elapsed} (eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut frame_cache: HashMap<usize, Arc<Loaded>> = HashMap::new();
    let mut bg_cache: HashMap<usize, Arc<Bg>> = HashMap::new();
    let mut roc = RocAccumulator::new(0.5);
    // Squared error sums and pixel counts of the reconstructed background and of the frame
    // itself against the true background: inside all movers (mask > 0), then inside the
    // moving ones (mask 255).
    let mut psnr_acc = [0.0f64; 6];
    let mut compute_secs = 0.0f64;
    let chunk_len = 2 * rayon::current_num_threads().max(1) * 4;
    for chunk in todo.chunks(chunk_len) {
        // Frames whose images and backgrounds this chunk needs.
        let mut need_bg = BTreeSet::new();
        for &i in chunk {
            need_bg.insert(i);
            for &o in &moving_offsets {
                if let Some(j) = in_range(i as i64 + o) {
                    need_bg.insert(j);
                }
            }
        }
        let mut need_frames = need_bg.clone();
        if bg_source == BackgroundSource::Reconstruct {
            for &b in &need_bg {
                for &o in &bg_offsets {
                    if let Some(j) = in_range(b as i64 + o) {
                        need_frames.insert(j);
                    }
                }
            }
        }
        frame_cache.retain(|k, _| need_frames.contains(k));
        bg_cache.retain(|k, _| need_bg.contains(k));
        let missing: Vec<usize> = need_frames
            .iter()
            .copied()
            .filter(|k| !frame_cache.contains_key(k))
            .collect();
        let loaded = missing
            .par_iter()
            .map(|&i| load(i).map(|l| (i, Arc::new(l))))
            .collect::<anyhow::Result<Vec<_>>>()?;
        frame_cache.extend(loaded);
        let missing_bg: Vec<usize> = need_bg
            .iter()
            .copied()
            .filter(|k| !bg_cache.contains_key(k))
            .collect();
        let t0 = Instant::now();
        let bgs = missing_bg
            .par_iter()
            .map(|&i| -> anyhow::Result<(usize, Arc<Bg>)> {
                let f = &frames[i];
                let bg = match bg_source {
                    BackgroundSource::Reconstruct => {
                        let cur = &frame_cache[&i];
                        let t_wc_inv = poses[i].inverse();
                        let srcs: Vec<(usize, Arc<Loaded>)> = bg_offsets
                            .iter()
                            .filter_map(|&o| in_range(i as i64 + o))
                            .map(|j| (j, frame_cache[&j].clone()))
                            .collect();
                        let sources: Vec<Source> = srcs
                            .iter()
                            .map(|(j, l)| Source {
                                rgb: &l.rgb,
                                depth: &l.depth,
                                t_ts: t_wc_inv * poses[*j],
                            })
                            .collect();
                        let b = reconstruct_background(
                            &cur.rgb,
                            &cur.depth,
                            &sources,
                            &cam,
                            &recon,
                            Some(&flow),
                        )
                        .with_context(|| format!("frame {i} ({}): background", f.name))?;
                        if args.save_background {
                            dynapix_io::images::write_rgb(
                                bgrec_dir.join(&f.name).with_extension("png"),
                                &b.image,
                            )?;
                        }
                        Bg {
                            rgb: b.image,
                            depth: b.depth,
                        }
                    }
                    _ => Bg {
                        rgb: dynapix_io::images::read_rgb(&f.background)?,
                        depth: if use_depth_bg {
                            dynapix_io::images::read_depth(&f.depth_bg, depth_factor)?
                        } else {
                            frame_cache[&i].depth.clone()
                        },
                    },
                };
                Ok((i, Arc::new(bg)))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        bg_cache.extend(bgs);
        compute_secs += t0.elapsed().as_secs_f64();

        let t0 = Instant::now();
        let results = chunk
            .par_iter()
            .map(|&i| -> anyhow::Result<(RocAccumulator, [f64; 6])> {
                let f = &frames[i];
                let view = |k: usize| FrameImages {
                    rgb: &frame_cache[&k].rgb,
                    depth: &frame_cache[&k].depth,
                    background: &bg_cache[&k].rgb,
                    background_depth: &bg_cache[&k].depth,
                };
                let t_cw = poses[i].inverse();
                let nbs: Vec<Neighbour> = moving_offsets
                    .iter()
                    .filter_map(|&o| in_range(i as i64 + o))
                    .map(|j| Neighbour {
                        frame: view(j),
                        t_cn: t_cw * poses[j],
                    })
                    .collect();
                let maps = motion_probability(&view(i), &nbs, &cam, &flow, &params)
                    .with_context(|| format!("frame {i} ({})", f.name))?;
                dynapix_io::images::write_prob_png(out_path(i), &maps.p)?;
                if args.float_maps {
                    dynapix_io::images::write_prob_pfm(
                        out_dir.join(&f.name).with_extension("pfm"),
                        &maps.p,
                    )?;
                }
                if args.pictures {
                    dynapix_io::images::write_rgb(
                        vis_dir.join(&f.name).with_extension("png"),
                        &overlay(&frame_cache[&i].rgb, &maps.p),
                    )?;
                }
                let mut acc = RocAccumulator::new(0.5);
                let mut ps = [0.0f64; 6];
                if args.eval_masks {
                    let mask = dynapix_io::images::read_mask(&f.mask)?;
                    let pos: Vec<bool> = mask.iter().map(|&m| m == 255).collect();
                    acc.add(maps.p.as_raw(), &pos);
                    if bg_source == BackgroundSource::Reconstruct && f.background.exists() {
                        let truth = dynapix_io::images::read_rgb(&f.background)?;
                        for (slot, sel) in [(0usize, 1u8), (3, 255)] {
                            let movers: Vec<bool> = mask.iter().map(|&m| m >= sel).collect();
                            let k = movers.iter().filter(|&&m| m).count() as f64;
                            let mse = |a: &RgbImage| {
                                psnr_masked(a, &truth, &movers)
                                    .map(|p| 255.0f64.powi(2) / 10f64.powf(p / 10.0))
                                    .unwrap_or(0.0)
                            };
                            if k > 0.0 {
                                ps[slot] = mse(&bg_cache[&i].rgb) * k;
                                ps[slot + 1] = mse(&frame_cache[&i].rgb) * k;
                                ps[slot + 2] = k;
                            }
                        }
                    }
                }
                bar.inc(1);
                Ok((acc, ps))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        compute_secs += t0.elapsed().as_secs_f64();
        for (acc, ps) in results {
            roc.merge(&acc);
            for (a, p) in psnr_acc.iter_mut().zip(ps) {
                *a += p;
            }
        }
    }
    bar.finish_and_clear();

    if args.eval_masks {
        for &i in &skipped {
            let p = dynapix_io::images::read_prob_png(out_path(i))?;
            let mask = dynapix_io::images::read_mask(&frames[i].mask)?;
            let pos: Vec<bool> = mask.iter().map(|&m| m == 255).collect();
            roc.add(p.as_raw(), &pos);
        }
    }
    let wall = started.elapsed().as_secs_f64();
    let mut results = json!({
        "frames_computed": todo.len(),
        "frames_skipped": skipped.len(),
        "wall_seconds": wall,
        "compute_seconds": compute_secs,
        "ms_per_frame": if todo.is_empty() { 0.0 } else { 1000.0 * compute_secs / todo.len() as f64 },
        "threads": rayon::current_num_threads(),
    });
    println!(
        "motion: {} frame(s) computed, {} skipped, {:.1} s ({:.0} ms/frame on {} threads) → {}",
        todo.len(),
        skipped.len(),
        wall,
        results["ms_per_frame"].as_f64().unwrap_or(0.0),
        rayon::current_num_threads(),
        out_dir.display()
    );
    if args.eval_masks {
        let auc = roc.auc();
        let iou = roc.iou();
        let psnr =
            |se: f64, n: f64| (n > 0.0).then(|| 10.0 * (255.0f64.powi(2) / (se / n)).log10());
        let bg_psnr = psnr(psnr_acc[0], psnr_acc[2]);
        let raw_psnr = psnr(psnr_acc[1], psnr_acc[2]);
        let bg_psnr_moving = psnr(psnr_acc[3], psnr_acc[5]);
        let raw_psnr_moving = psnr(psnr_acc[4], psnr_acc[5]);
        let best = roc.best_iou();
        println!(
            "eval: ROC-AUC {} IoU(P>0.5) {} best IoU {} over {} moving / {} other pixels",
            auc.map_or("n/a".into(), |v| format!("{v:.4}")),
            iou.map_or("n/a".into(), |v| format!("{v:.4}")),
            best.map_or("n/a".into(), |(t, v)| format!("{v:.4} (P>{t:.3})")),
            roc.positives(),
            roc.negatives()
        );
        if let (Some(b), Some(r)) = (bg_psnr, raw_psnr) {
            println!(
                "eval: reconstructed background PSNR inside all movers {b:.2} dB (frame itself: {r:.2} dB)"
            );
        }
        if let (Some(b), Some(r)) = (bg_psnr_moving, raw_psnr_moving) {
            println!(
                "eval: reconstructed background PSNR inside moving movers {b:.2} dB (frame itself: {r:.2} dB)"
            );
        }
        results["eval"] = json!({
            "roc_auc": auc, "iou_p_gt_0_5": iou,
            "best_iou": best.map(|b| b.1), "best_iou_threshold": best.map(|b| b.0),
            "moving_pixels": roc.positives(), "other_pixels": roc.negatives(),
            "background_psnr_in_movers_db": bg_psnr, "frame_psnr_in_movers_db": raw_psnr,
            "background_psnr_in_moving_db": bg_psnr_moving,
            "frame_psnr_in_moving_db": raw_psnr_moving,
        });
    }
    write_json("complete", results)?;
    Ok(())
}

/// Fig.-1-style picture: the frame with moving regions tinted red in proportion to P.
fn overlay(rgb: &RgbImage, p: &FloatImage) -> RgbImage {
    let mut out = rgb.clone();
    for (o, v) in out.pixels_mut().zip(p.iter()) {
        let a = 0.7 * v.clamp(0.0, 1.0);
        let mix = |c: u8, t: f32| ((1.0 - a) * c as f32 + a * t).round() as u8;
        *o = Rgb([mix(o.0[0], 255.0), mix(o.0[1], 0.0), mix(o.0[2], 0.0)]);
    }
    out
}
