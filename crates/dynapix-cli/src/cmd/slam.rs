//! `dynapix slam`: runs the RGB-D SLAM system (ORB-SLAM2 mode, no motion probabilities) on a
//! sequence folder and writes `trajectory.txt` (TUM, every tracked frame, camera-to-world),
//! `status.txt` (per frame: tracked / lost / not_initialized), `keyframes.txt`, `loops.txt`,
//! `timing.csv` and `slam.json` (the sequence, the configuration, the counters, the skipped
//! frames and whether the run completed) into `--out`, which is replaced as a whole at the end
//! (written beside it first; see [`dynapix::OutputFolder`]). `--save-map FILE` saves the final
//! map (a versioned header with CRC-32, then the map); `--localize MAP` loads one and only
//! tracks against it (localisation mode: no new keyframes or map points). The work and the
//! files are the library's ([`dynapix::SlamPass`], [`dynapix::SlamRecord`]); this module
//! parses, shows progress and prints.

use std::path::{Path, PathBuf};

use anyhow::Context;
use dynapix::VocabularyChoice;
use dynapix::{MapFileStats, Method, OutputFolder, PassOutput, SlamPass, SlamRecord};

use super::common::{
    Bars, RESULT_MARKERS, SequenceArgs, check_out, partial_pass, report, skipped_note, stop_reason,
};

/// `--mode`: the paper/reference switch of every command; `orbslam2` is the older spelling
/// of this command's only method and is still accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ModeArg {
    /// Paper behaviour (default).
    Paper,
    /// Reference behaviour.
    Reference,
    /// `slam` always runs plain ORB-SLAM2 (use `dynapix run --method` for the others).
    Orbslam2,
}

/// Arguments of `dynapix slam`.
#[derive(clap::Args)]
pub struct Args {
    /// The sequence.
    #[command(flatten)]
    pub seq: SequenceArgs,
    /// Paper or reference behaviour (`orbslam2`, this command's only method, is accepted for
    /// older command lines).
    #[arg(long, value_enum)]
    pub mode: Option<ModeArg>,
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
    /// Turn loop closing off (on by default; closed loops are listed in `OUT/loops.txt`).
    #[arg(long)]
    pub no_loop_closing: bool,
    /// Exit 0 even when no frame was tracked (otherwise a warning and exit code 1; the
    /// outputs are written either way).
    #[arg(long)]
    pub allow_untracked: bool,
    /// A frame whose rgb or depth file cannot be used (missing, truncated, undecodable, of
    /// another size) is recorded lost and SLAM goes on with the next one; the skipped frames
    /// are listed in `slam.json`. Without it the run stops at such a frame with an error
    /// naming it, keeping the trajectory and status up to it (`"complete": false`).
    #[arg(long)]
    pub skip_bad_frames: bool,
    /// The Rerun viewer.
    #[command(flatten)]
    pub viz: super::viz::VizArgs,
}

fn median(v: &mut [f64]) -> f64 {
    dynapix_geometry::stats::upper_median_by(v, f64::total_cmp).unwrap_or(0.0)
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let i = ((v.len() - 1) as f64 * p).round() as usize;
    v[i.min(v.len() - 1)]
}

/// "read 1.0, decode + check 2.0, rebuild 3.0": the steps of a map load or save.
fn steps(m: &MapFileStats) -> String {
    let parts: Vec<String> = m
        .steps_ms
        .iter()
        .map(|(name, ms)| format!("{name} {ms:.1}"))
        .collect();
    parts.join(", ")
}

/// Loads the map file `path` (localisation mode, [`SlamPass::load_map`]) and returns the
/// summary line "localisation mode, map MAP (N keyframes, M points)".
fn enter_localization(slam: &mut SlamPass, path: &Path) -> anyhow::Result<String> {
    let l = slam.load_map(path)?;
    let note = format!(
        "localisation mode, map {} ({} keyframes, {} points)",
        path.display(),
        l.keyframes,
        l.points
    );
    let total: f64 = l.steps_ms.iter().map(|(_, ms)| ms).sum();
    eprintln!(
        "{note}: loaded in {total:.1} ms ({}; {} bytes)",
        steps(&l),
        l.bytes
    );
    Ok(note)
}

/// Saves the map to `path` ([`SlamPass::save_map`]).
fn save_map(path: &Path, slam: &SlamPass) -> anyhow::Result<()> {
    let s = slam.save_map(path)?;
    let ms: Vec<String> = s
        .steps_ms
        .iter()
        .map(|(name, ms)| format!("{name} {ms:.1} ms"))
        .collect();
    eprintln!(
        "map saved to {} ({} keyframes, {} points, {:.2} MB; {})",
        path.display(),
        s.keyframes,
        s.points,
        s.bytes as f64 / 1e6,
        ms.join(", ")
    );
    Ok(())
}

/// Writes the files of a pass into `dir`: trajectory, status, keyframes, loops and the
/// per-frame step times (`timing.csv`).
fn write_outputs(dir: &Path, pass: &PassOutput) -> anyhow::Result<()> {
    pass.write_files(dir)?;
    pass.write_timing(&dir.join("timing.csv"))?;
    Ok(())
}

/// The summary line of a finished pass.
fn summary(pass: &PassOutput, skipping: bool) -> String {
    let (mut t_track, mut t_total) = (Vec::new(), Vec::new());
    for f in &pass.timings {
        let tr = f.extract_ms + f.track_ms;
        t_track.push(tr);
        t_total.push(tr + f.mapping_ms + f.loop_ms);
    }
    let n = t_track.len().max(1) as f64;
    let mean_track = t_track.iter().sum::<f64>() / n;
    let mean_total = t_total.iter().sum::<f64>() / n;
    format!(
        "{} frames, {} tracked, {} keyframes, {} map points, {} loops closed{}; tracking ms median {:.1} mean {:.1} p95 {:.1}; total ms/frame mean {:.1}",
        pass.status.len(),
        pass.stats.tracked,
        pass.stats.keyframes,
        pass.stats.map_points,
        pass.stats.loops_closed,
        skipped_note(&pass.skipped, skipping),
        median(&mut t_track.clone()),
        mean_track,
        percentile(&mut t_track, 0.95),
        mean_total
    )
}

/// Runs `dynapix slam`.
pub fn run(args: Args, bars: &Bars) -> anyhow::Result<()> {
    let mode = match args.mode {
        Some(ModeArg::Paper) => Some(dynapix::Mode::Paper),
        Some(ModeArg::Reference) => Some(dynapix::Mode::Reference),
        Some(ModeArg::Orbslam2) | None => None,
    };
    let mut config = args.seq.base_config(mode)?.with_method(Method::Orbslam2);
    if args.no_loop_closing {
        config.slam.params.loop_closing.enabled = false;
    }
    if args.no_vocabulary {
        config.slam.vocabulary = VocabularyChoice::None;
    } else if let Some(p) = &args.vocabulary {
        config.slam.vocabulary = VocabularyChoice::File(p.clone());
    }
    if args.skip_bad_frames {
        config.sequence.skip_bad_frames = true;
    }
    // Where the results go, before any work.
    let mut keep = vec![("the sequence", args.seq.seq_dir.as_path())];
    if let Some(m) = &args.localize {
        keep.push(("the map to load", m.as_path()));
    }
    check_out(&args.out, &keep)?;
    if let Some(p) = &args.save_map {
        let dir = p.parent().unwrap_or(Path::new(""));
        OutputFolder::check_writable(dir)
            .with_context(|| format!("cannot save the map to {}", p.display()))?;
    }
    let input = args.seq.open(&config)?;
    let mut slam = SlamPass::new(&input, &config)?;
    let localize_note = match &args.localize {
        Some(path) => enter_localization(&mut slam, path)?,
        None => String::new(),
    };
    let viz = args
        .viz
        .open(&format!("slam {}", args.seq.seq_dir.display()))?;
    let staged = OutputFolder::begin(&args.out, RESULT_MARKERS)?;
    let observer = viz.as_ref().map(super::viz::Viz::observer);
    let result = slam.run(&input, bars, observer.as_deref());
    if let Some(v) = viz {
        v.finish()?;
    }
    let mut record = SlamRecord::new(&input, &config);
    record.localize = args.localize.clone();
    record.save_map = args.save_map.clone();
    let skipping = config.sequence.skip_bad_frames;
    let record_path = staged.path().join("slam.json");
    let pass = match result {
        Ok(pass) => pass,
        Err(e) => {
            let e = anyhow::Error::from(e);
            // Keep what was computed: the pass up to the frame that stopped it.
            if let Some(p) = partial_pass(&e) {
                if let Err(w) = write_outputs(staged.path(), p) {
                    tracing::warn!("partial results: {}", report(&w));
                }
                record.set_pass(p, false);
            }
            let (why, frame) = stop_reason(&e);
            record.mark_incomplete(why, frame);
            record.write(&record_path)?;
            let out = staged.commit()?;
            eprintln!(
                "the run stopped; {} keeps what it computed (marked incomplete)",
                out.display()
            );
            return Err(e);
        }
    };
    write_outputs(staged.path(), &pass)?;
    record.set_pass(&pass, true);
    record.write(&record_path)?;
    staged.commit()?;
    eprintln!("{}", summary(&pass, skipping));
    if !localize_note.is_empty() {
        eprintln!("{localize_note}");
    }
    if let Some(path) = &args.save_map {
        save_map(path, &slam)?;
    }
    super::common::check_tracked(&args.seq.seq_dir, pass.stats.tracked, args.allow_untracked)
}
