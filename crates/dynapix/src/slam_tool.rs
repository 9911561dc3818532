//! `dynapix slam` as a library type ([`SlamPass`]): one ORB-SLAM2-mode pass over a sequence
//! with a saved map loaded first (localisation) or the final map saved after, and the files a
//! pass leaves ([`PassOutput::write_files`], [`PassOutput::write_timing`]).

use std::path::Path;

use crate::config::Config;
use crate::error::{Error, Result};
use crate::input::Input;
use crate::observe::RunObserver;
use crate::pass::PassOutput;
use crate::progress::Progress;
use crate::slam::{MapFileStats, PassWeights, SlamSession, Watch, load_vocabulary};

/// One SLAM pass in ORB-SLAM2 mode (no motion probabilities) with map persistence: build it,
/// optionally [`load_map`](Self::load_map) (localisation mode: frames are relocalised into
/// the map, nothing is added to it), [`run`](Self::run) the sequence, optionally
/// [`save_map`](Self::save_map).
pub struct SlamPass {
    session: SlamSession,
    depth_factor: f64,
}

impl SlamPass {
    /// The system of `config` (SLAM parameters, vocabulary) for the camera of `input`.
    pub fn new(input: &Input, config: &Config) -> Result<Self> {
        let vocabulary = load_vocabulary(&config.slam.vocabulary)?;
        Ok(Self {
            session: SlamSession::new(&input.camera, config.system_params(), vocabulary)?,
            depth_factor: input.camera.settings.depth_map_factor,
        })
    }

    /// Loads the saved map `path` (written by [`save_map`](Self::save_map) with the same
    /// camera, ORB settings and vocabulary) and switches to localisation mode on it. Errors
    /// name the file.
    pub fn load_map(&mut self, path: &Path) -> Result<MapFileStats> {
        self.session.load_map(path, self.depth_factor)
    }

    /// Runs the pass over every frame of `input`, shown to `observer` when given (the same
    /// results either way). A frame that stops the pass gives [`Error::Stopped`], which keeps
    /// the pass up to the frame before.
    pub fn run(
        &mut self,
        input: &Input,
        progress: &dyn Progress,
        observer: Option<&dyn RunObserver>,
    ) -> Result<PassOutput> {
        let watch = observer.map(|observer| Watch {
            observer,
            number: 1,
            last: true,
        });
        crate::slam::run_pass_observed(
            input,
            &mut self.session,
            PassWeights::None,
            None,
            "slam",
            progress,
            watch,
        )
    }

    /// Encodes the map (a versioned header with CRC-32, then the map) and writes it to `path`
    /// atomically.
    pub fn save_map(&self, path: &Path) -> Result<MapFileStats> {
        self.session.save_map(path, self.depth_factor)
    }
}

impl PassOutput {
    /// Writes what every SLAM pass leaves in `dir` (created when missing): `trajectory.txt`
    /// (TUM, the current estimate of every tracked frame), `status.txt`, `keyframes.txt` and
    /// `loops.txt` (per closed loop: the two keyframes' timestamps, the matches and what the
    /// correction did and took).
    pub fn write_files(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| dynapix_io::IoError::io(dir, e))?;
        self.trajectory.write_tum(dir.join("trajectory.txt"))?;
        dynapix_io::trajectory::write_status(dir.join("status.txt"), &self.status)?;
        self.keyframes.write_tum(dir.join("keyframes.txt"))?;
        let mut s = String::from(
            "# current_kf_timestamp loop_kf_timestamp matched_points corrected_keyframes fused_points essential_graph_edges essential_graph_ms global_ba_ms\n",
        );
        for e in &self.loops {
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
        dynapix_io::write_atomic(dir.join("loops.txt"), s.as_bytes())?;
        Ok(())
    }

    /// Writes the per-frame step times as CSV to `path`, atomically.
    pub fn write_timing(&self, path: &Path) -> Result<()> {
        let mut timing =
            String::from("index,timestamp,extract_ms,track_ms,mapping_ms,loop_ms,keyframe,state\n");
        for f in &self.timings {
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
        dynapix_io::write_atomic(path, timing.as_bytes()).map_err(Error::from)
    }
}
