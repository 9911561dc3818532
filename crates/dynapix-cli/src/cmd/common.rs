//! What the subcommands share: the sequence and camera flags (the same meaning in every
//! command), the configuration file, progress bars for the library's progress callback,
//! and the files a SLAM pass leaves.

use std::collections::HashMap;
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::Context;
use clap::builder::{PossibleValue, TypedValueParser};
use dynapix::PassOutput;
use dynapix::{CameraChoice, CameraPreset, Config, Input, Progress, ProgressEvent};
use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};

/// `--camera PRESET`; a file name is refused with a message naming `--settings` (the old
/// `motion --camera FILE` spelling).
#[derive(Clone, Copy, Debug)]
pub struct CameraParser;

impl TypedValueParser for CameraParser {
    type Value = CameraPreset;

    fn parse_ref(
        &self,
        cmd: &clap::Command,
        arg: Option<&clap::Arg>,
        value: &OsStr,
    ) -> Result<Self::Value, clap::Error> {
        let s = value.to_string_lossy();
        if let Some(p) = CameraPreset::ALL
            .into_iter()
            .find(|p| p.name().eq_ignore_ascii_case(&s))
        {
            return Ok(p);
        }
        let names: Vec<&str> = CameraPreset::ALL.iter().map(|p| p.name()).collect();
        let hint = if Path::new(&*s).is_file() || s.ends_with(".yaml") || s.ends_with(".yml") {
            format!(
                "`--camera` takes a preset ({}); for a settings file use `--settings {s}`",
                names.join(", ")
            )
        } else {
            format!(
                "unknown camera preset {s:?} (expected one of {})",
                names.join(", ")
            )
        };
        let mut e = clap::Error::raw(clap::error::ErrorKind::InvalidValue, format!("{hint}\n"));
        e = e.with_cmd(cmd);
        let _ = arg;
        Err(e)
    }

    fn possible_values(&self) -> Option<Box<dyn Iterator<Item = PossibleValue> + '_>> {
        Some(Box::new(
            CameraPreset::ALL
                .into_iter()
                .map(|p| PossibleValue::new(p.name())),
        ))
    }
}

/// How the camera is given (the same flags in every command).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct CameraArgs {
    /// Camera preset (default: the folder's camera.yaml, else tumN for
    /// rgbd_dataset_freiburgN_* and bonn for rgbd_bonn_*).
    #[arg(long, value_parser = CameraParser, conflicts_with = "settings")]
    pub camera: Option<CameraPreset>,
    /// ORB-SLAM2 settings YAML (Camera.*, ThDepth, DepthMapFactor, ORBextractor.*); missing
    /// keys take the TUM values, a missing image size the first frame's.
    #[arg(long, value_name = "YAML")]
    pub settings: Option<PathBuf>,
}

impl CameraArgs {
    /// The library's camera choice.
    pub fn choice(&self) -> CameraChoice {
        match (&self.settings, self.camera) {
            (Some(p), _) => CameraChoice::Settings(p.clone()),
            (None, Some(c)) => CameraChoice::Preset(c),
            (None, None) => CameraChoice::Sequence,
        }
    }
}

/// A sequence folder and how to read it (the same flags in every command).
#[derive(clap::Args, Clone, Debug)]
pub struct SequenceArgs {
    /// Sequence folder (an association file, or rgb.txt + depth.txt, or numbered rgb/1.png …).
    pub seq_dir: PathBuf,
    /// Camera.
    #[command(flatten)]
    pub camera: CameraArgs,
    /// Association file (4 columns) instead of the folder's frame list; default:
    /// association.txt / associations.txt / rgbd_assoc.txt / assoc.txt in the folder, else
    /// every rgb.txt frame with its nearest depth.txt image within 0.02 s.
    #[arg(long, value_name = "FILE")]
    pub association: Option<PathBuf>,
    /// Pair rgb.txt and depth.txt one-to-one like `associate.py` (drops rgb frames whose
    /// nearest depth went to a neighbour) instead of giving every rgb frame its nearest depth.
    #[arg(long)]
    pub unique_association: bool,
    /// Process at most this many frames.
    #[arg(long, value_name = "N")]
    pub max_frames: Option<usize>,
    /// Configuration file (JSON or YAML, see `dynapix::Config`); flags override its values.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

impl SequenceArgs {
    /// The configuration file's content (or the defaults) in `mode` when given, with the
    /// sequence flags applied.
    pub fn base_config(&self, mode: Option<dynapix::Mode>) -> anyhow::Result<Config> {
        let mut c = Config::load_with(self.config.as_deref(), mode)?;
        if self.unique_association {
            c.sequence.pairing = dynapix::Pairing::OneToOne;
        }
        if let Some(n) = self.max_frames {
            anyhow::ensure!(n > 0, "--max-frames must be at least 1");
            c.sequence.max_frames = Some(n);
        }
        Ok(c)
    }

    /// Opens the sequence with the configuration's sequence options.
    pub fn open(&self, config: &Config) -> anyhow::Result<Input> {
        Input::open_with(
            &self.seq_dir,
            &config.sequence,
            &self.camera.choice(),
            self.association.as_deref(),
        )
        .with_context(|| format!("cannot read the sequence {}", self.seq_dir.display()))
    }
}

/// Progress bars (indicatif) for the library's progress events; hidden with `--quiet`.
pub struct Bars {
    multi: MultiProgress,
    bars: Mutex<HashMap<String, ProgressBar>>,
    quiet: bool,
}

impl Bars {
    /// Bars on stderr, or none when `quiet`.
    pub fn new(quiet: bool) -> Self {
        let multi = MultiProgress::new();
        if quiet {
            multi.set_draw_target(ProgressDrawTarget::hidden());
        }
        Self {
            multi,
            bars: Mutex::new(HashMap::new()),
            quiet,
        }
    }

    /// A bar or spinner made by a command itself, hidden with `--quiet`.
    pub fn adopt(&self, bar: ProgressBar) -> ProgressBar {
        if self.quiet {
            bar.set_draw_target(ProgressDrawTarget::hidden());
        }
        bar
    }
}

impl Progress for Bars {
    fn event(&self, e: ProgressEvent<'_>) {
        let Ok(mut bars) = self.bars.lock() else {
            return;
        };
        match e {
            ProgressEvent::Begin { task, total } => {
                let pb = self.multi.add(ProgressBar::new(total));
                pb.set_style(
                    ProgressStyle::with_template(
                        "{prefix:>24} {bar:30} {pos}/{len} {per_sec} {msg} [{elapsed_precise}]",
                    )
                    .unwrap_or_else(|_| ProgressStyle::default_bar()),
                );
                pb.set_prefix(task.to_string());
                bars.insert(task.to_string(), pb);
            }
            ProgressEvent::Step { task, message } => {
                if let Some(pb) = bars.get(task) {
                    if !message.is_empty() {
                        pb.set_message(message.to_string());
                    }
                    pb.inc(1);
                }
            }
            ProgressEvent::End { task } => {
                if let Some(pb) = bars.remove(task) {
                    pb.finish_and_clear();
                    self.multi.remove(&pb);
                }
            }
        }
    }
}

/// Files that mark a folder as an earlier result set of `slam` or `run`: such a folder (or an
/// empty one) may be replaced by a run; any other is refused.
pub const RESULT_MARKERS: &[&str] = &["run.json", "slam.json", "trajectory.txt", "status.txt"];

/// `p` with its longest existing ancestor resolved (links, `..`) and the rest appended.
fn resolve(p: &Path) -> PathBuf {
    let abs = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let mut rest = Vec::new();
    let mut cur = abs.as_path();
    loop {
        if let Ok(c) = cur.canonicalize() {
            return rest.iter().rev().fold(c, |acc: PathBuf, n| acc.join(n));
        }
        match (cur.parent(), cur.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                cur = parent;
            }
            _ => return abs,
        }
    }
}

/// True when `p` lies inside (or is) the existing folder `dir`.
fn inside(p: &Path, dir: &Path) -> bool {
    dir.exists() && resolve(p).starts_with(resolve(dir))
}

/// Checks `--out` up front, before any work: its parent is writable, it is new, empty or an
/// earlier result set ([`RESULT_MARKERS`]), and none of `keep` (what → path: the sequence, the
/// cache, a map to load) lies inside it, since a run replaces the folder as a whole.
pub fn check_out(out: &Path, keep: &[(&str, &Path)]) -> anyhow::Result<()> {
    dynapix::OutputFolder::check(out, RESULT_MARKERS)?;
    for (what, p) in keep {
        if inside(p, out) {
            anyhow::bail!(
                "{what} {} lies inside --out {}, which a run replaces as a whole; keep it \
                 outside the output folder",
                p.display(),
                out.display()
            );
        }
    }
    Ok(())
}

/// The first library error in the chain of `e`.
fn library_error(e: &anyhow::Error) -> Option<&dynapix::Error> {
    e.chain().find_map(|c| c.downcast_ref::<dynapix::Error>())
}

/// The files named by the library errors in the chain of `e` (a stopped pass's cause
/// included).
fn error_paths(e: &anyhow::Error) -> Vec<PathBuf> {
    fn of(e: &dynapix::Error, out: &mut Vec<PathBuf>) {
        match e {
            dynapix::Error::Io(io) => out.push(io.path().to_path_buf()),
            dynapix::Error::File { path, .. } => out.push(path.clone()),
            dynapix::Error::Stopped { error, .. } => of(error, out),
            _ => {}
        }
    }
    let mut out = Vec::new();
    for c in e.chain() {
        if let Some(l) = c.downcast_ref::<dynapix::Error>() {
            of(l, &mut out);
        } else if let Some(io) = c.downcast_ref::<dynapix::IoError>() {
            out.push(io.path().to_path_buf());
        }
    }
    out
}

/// The file inside the cache folder `cache` that made `e`, when the cache is at fault: such
/// a run must not replace an earlier result with a partial one.
pub fn cache_fault(e: &anyhow::Error, cache: &Path) -> Option<PathBuf> {
    let cache = resolve(cache);
    error_paths(e)
        .into_iter()
        .find(|p| resolve(p).starts_with(&cache))
}

/// What a pass had computed when `e` stopped it.
pub fn partial_pass(e: &anyhow::Error) -> Option<&PassOutput> {
    library_error(e).and_then(dynapix::Error::partial_pass)
}

/// Why a run stopped and the frame that stopped it, when a frame did (for
/// [`dynapix::RunRecord::mark_incomplete`]).
pub fn stop_reason(e: &anyhow::Error) -> (String, Option<dynapix::BadFrame>) {
    (
        report(e),
        library_error(e)
            .and_then(dynapix::Error::bad_frame)
            .cloned(),
    )
}

/// The summary words about skipped frames: `, 2 bad frame(s) skipped (frames 3, 9)`, or
/// nothing when no frame was skipped and skipping is off.
pub fn skipped_note(skipped: &[dynapix::BadFrame], skipping: bool) -> String {
    if skipped.is_empty() && !skipping {
        return String::new();
    }
    let list: Vec<String> = skipped
        .iter()
        .take(10)
        .map(|b| b.index.to_string())
        .collect();
    let more = if skipped.len() > 10 { ", …" } else { "" };
    if skipped.is_empty() {
        ", no bad frame skipped".into()
    } else {
        format!(
            ", {} bad frame(s) skipped (frames {}{more})",
            skipped.len(),
            list.join(", ")
        )
    }
}

/// Writes what every SLAM pass leaves in `out` ([`PassOutput::write_files`]).
pub fn write_pass(out: &Path, pass: &PassOutput) -> anyhow::Result<()> {
    pass.write_files(out)
        .with_context(|| format!("cannot write the pass into {}", out.display()))
}

/// Writes `bytes` to `path`, atomically: the one writer of the CLI's own files (reports,
/// pictures).
pub fn write_bytes(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    dynapix_io::write_atomic(path, bytes)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

/// Writes `text` to `path`, atomically.
pub fn write_text(path: &Path, text: &str) -> anyhow::Result<()> {
    write_bytes(path, text.as_bytes())
}

/// Writes `value` as pretty JSON, atomically.
pub fn write_json(path: &Path, value: &serde_json::Value) -> anyhow::Result<()> {
    write_text(path, &serde_json::to_string_pretty(value)?)
}

/// "Nothing tracked" is not a success: a warning naming the sequence, then an error unless
/// the user allowed it (`--allow-untracked`). The outputs are already written.
pub fn check_tracked(seq: &Path, tracked: usize, allow: bool) -> anyhow::Result<()> {
    if tracked > 0 {
        return Ok(());
    }
    eprintln!(
        "warning: no frame of {} was tracked (all-zero depth, black or featureless frames, or \
         a camera that does not match the images?)",
        seq.display()
    );
    if allow {
        Ok(())
    } else {
        anyhow::bail!(
            "nothing tracked in {} (outputs written; pass --allow-untracked to exit 0)",
            seq.display()
        )
    }
}

/// The message of `e` and its causes, joined by ": ", each cause once: a cause whose text the
/// message before it already ends with (an error that prints its source, like
/// `path: No such file or directory (os error 2)`) is not repeated.
pub fn report(e: &anyhow::Error) -> String {
    let mut parts: Vec<String> = Vec::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if text.is_empty() || parts.last().is_some_and(|p| p.ends_with(&text)) {
            continue;
        }
        parts.push(text);
    }
    parts.join(": ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_names_every_cause_once() {
        let os = std::io::Error::from(std::io::ErrorKind::NotFound);
        let os_text = os.to_string();
        let io = dynapix::IoError::io("seq/rgb/1.png", os);
        let e = anyhow::Error::new(io).context("cannot read the sequence seq");
        let r = report(&e);
        assert_eq!(r.matches(&os_text).count(), 1, "{r}");
        assert!(
            r.starts_with("cannot read the sequence seq: seq/rgb/1.png"),
            "{r}"
        );
        // Causes that add something are kept.
        let e = anyhow::anyhow!("inner").context("outer");
        assert_eq!(report(&e), "outer: inner");
    }
}
