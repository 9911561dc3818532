//! `dynapix slam`: runs the RGB-D SLAM system (ORB-SLAM2 mode, no motion probabilities) on a
//! sequence folder and writes `trajectory.txt` (TUM, every tracked frame, camera-to-world),
//! `status.txt` (per frame: tracked / lost / not_initialized), `keyframes.txt`, `loops.txt`,
//! `timing.csv` and `slam.json` (the sequence, the configuration, the counters, the skipped
//! frames and whether the run completed) into `--out`, which is replaced as a whole at the
//! end (written beside it first; see `dynapix_io::output`). `--save-map FILE` saves the final map
//! (`dynapix_slam::persist` format); `--localize MAP` loads one and only tracks against it
//! (localisation mode: no new keyframes or map points). The work is the library's
//! (`dynapix::slam`); this module parses, shows progress and writes files.

use std::path::{Path, PathBuf};

use anyhow::Context;
use dynapix::PassOutput;
use dynapix::stages::{PassWeights, SlamSession, Watch, load_vocabulary, run_pass_observed};
use dynapix::{Input, Method, VocabularyChoice};
use dynapix_io::OutputFolder;
use serde_json::json;

use super::common::{
    Bars, RESULT_MARKERS, SequenceArgs, check_out, incomplete, merge, partial_pass, report,
    skipped_note, write_json, write_pass,
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

/// Loads the map file `path` into the session (localisation mode, [`SlamSession::load_map`])
/// and returns the summary line "localisation mode, map MAP (N keyframes, M points)".
fn enter_localization(
    session: &mut SlamSession,
    path: &Path,
    input: &Input,
) -> anyhow::Result<String> {
    let l = session.load_map(path, input.camera.settings.depth_map_factor)?;
    let note = format!(
        "localisation mode, map {} ({} keyframes, {} points)",
        path.display(),
        l.keyframes,
        l.points
    );
    eprintln!(
        "{note}: loaded in {:.1} ms (read {:.1}, decode + check {:.1}, rebuild {:.1}; {} bytes)",
        l.read_ms + l.check_ms + l.rebuild_ms,
        l.read_ms,
        l.check_ms,
        l.rebuild_ms,
        l.bytes
    );
    Ok(note)
}

/// Saves the map of the session to `path` ([`SlamSession::save_map`]).
fn save_map(path: &Path, session: &SlamSession, depth_factor: f64) -> anyhow::Result<()> {
    let s = session.save_map(path, depth_factor)?;
    eprintln!(
        "map saved to {} ({} keyframes, {} points, {:.2} MB; encode {:.1} ms, write {:.1} ms)",
        path.display(),
        s.keyframes,
        s.points,
        s.bytes as f64 / 1e6,
        s.encode_ms,
        s.write_ms
    );
    Ok(())
}

/// Writes the files of a pass into `dir`: trajectory, status, keyframes, loops and the
/// per-frame step times (`timing.csv`).
fn write_outputs(dir: &Path, pass: &PassOutput) -> anyhow::Result<()> {
    write_pass(dir, pass)?;
    let mut timing =
        String::from("index,timestamp,extract_ms,track_ms,mapping_ms,loop_ms,keyframe,state\n");
    for f in &pass.timings {
        timing.push_str(&format!(
            "{},{:.6},{:.3},{:.3},{:.3},{:.3},{},{}\n",
            f.index,
            f.timestamp,
            f.extract_ms,
            f.track_ms,
            f.mapping_ms,
            f.loop_ms,
            u8::from(f.keyframe),
            f.status
        ));
    }
    dynapix_io::write_atomic(dir.join("timing.csv"), timing.as_bytes())?;
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
        dynapix_io::output::check_writable_dir(dir)
            .with_context(|| format!("cannot save the map to {}", p.display()))?;
    }
    let input = args.seq.open(&config)?;
    let vocabulary = load_vocabulary(&config.slam.vocabulary)?;
    let mut session = SlamSession::new(&input.camera, config.system_params(), vocabulary)?;
    let localize_note = match &args.localize {
        Some(path) => enter_localization(&mut session, path, &input)?,
        None => String::new(),
    };
    let viz = args
        .viz
        .open(&format!("slam {}", args.seq.seq_dir.display()))?;
    let staged = OutputFolder::begin(&args.out, RESULT_MARKERS)?;
    let observer = viz.as_ref().map(super::viz::Viz::observer);
    let watch = observer.as_deref().map(|o| Watch {
        observer: o,
        number: 1,
        last: true,
    });
    let result = run_pass_observed(
        &input,
        &mut session,
        PassWeights::None,
        None,
        "slam",
        bars,
        watch,
    );
    if let Some(v) = viz {
        v.finish()?;
    }
    let mut record = json!({
        "command": "slam",
        "method": Method::Orbslam2.name(),
        "sequence": input.record(),
        "localize": args.localize,
        "save_map": args.save_map,
        "config": config.to_json_value(),
    });
    let skipping = config.sequence.skip_bad_frames;
    let pass = match result {
        Ok(pass) => pass,
        Err(e) => {
            let e = anyhow::Error::from(e);
            // Keep what was computed: the pass up to the frame that stopped it.
            if let Some(p) = partial_pass(&e) {
                if let Err(w) = write_outputs(staged.path(), p) {
                    tracing::warn!("partial results: {}", report(&w));
                }
                record["stats"] = json!(p.stats);
                record["skipped_frames"] = json!(p.skipped);
            }
            merge(&mut record, incomplete(&e));
            write_json(&staged.path().join("slam.json"), &record)?;
            let out = staged.commit()?;
            eprintln!(
                "the run stopped; {} keeps what it computed (marked incomplete)",
                out.display()
            );
            return Err(e);
        }
    };
    write_outputs(staged.path(), &pass)?;
    record["complete"] = json!(true);
    record["stats"] = json!(pass.stats);
    record["skipped_frames"] = json!(pass.skipped);
    write_json(&staged.path().join("slam.json"), &record)?;
    staged.commit()?;
    eprintln!("{}", summary(&pass, skipping));
    if !localize_note.is_empty() {
        eprintln!("{localize_note}");
    }
    if let Some(path) = &args.save_map {
        save_map(path, &session, input.camera.settings.depth_map_factor)?;
    }
    super::common::check_tracked(&args.seq.seq_dir, pass.stats.tracked, args.allow_untracked)
}
