//! Synthetic dynamic RGB-D data (`dynapix-synth`) through the library: the `synth` presets
//! rendered frame by frame in memory or written as a sequence folder, and the augmentation of
//! a real sequence with virtual movers, as `dynapix synth` makes them.

use std::path::Path;

use dynapix_synth::output;
use dynapix_synth::{Preset, SensorParams, SynthError, SynthParams};
use image::{GrayImage, ImageBuffer, Luma, RgbImage};

/// A 16-bit single-channel image (raw depth).
type Gray16Image = ImageBuffer<Luma<u16>, Vec<u16>>;

use crate::input::{Camera, CameraSource};
use crate::{Error, Result};

/// How realistic the simulated sensor is (`dynapix synth --realism`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Realism {
    /// Exact depth, no noise, no blur.
    Clean,
    /// Kinect-like depth (noise ∝ depth², quantisation, holes) and mild image noise.
    #[default]
    Kinect,
    /// Kinect plus exposure changes and motion blur.
    Full,
}

impl Realism {
    /// Parses `clean`, `kinect` or `full`.
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "clean" => Ok(Self::Clean),
            "kinect" => Ok(Self::Kinect),
            "full" => Ok(Self::Full),
            other => Err(Error::config(format!(
                "unknown realism {other:?} (expected clean, kinect or full)"
            ))),
        }
    }
}

/// What defines a synthetic sequence (the `dynapix synth` flags).
#[derive(Clone, Debug, PartialEq)]
pub struct SynthOptions {
    /// Preset name (`static`, `walking_xyz`, …; see [`SynthOptions::preset_names`]).
    pub preset: String,
    /// Number of frames (30 Hz).
    pub frames: usize,
    /// Seed: the same preset and seed give the same bytes.
    pub seed: u64,
    /// Image width; the height follows the 4:3 default unless given. Default 640.
    pub width: Option<u32>,
    /// Image height.
    pub height: Option<u32>,
    /// Sensor realism.
    pub realism: Realism,
}

impl Default for SynthOptions {
    fn default() -> Self {
        Self {
            preset: "walking_xyz".into(),
            frames: 300,
            seed: 0,
            width: None,
            height: None,
            realism: Realism::Kinect,
        }
    }
}

impl SynthOptions {
    /// The names of the presets (the values of [`SynthOptions::preset`]).
    pub fn preset_names() -> Vec<&'static str> {
        Preset::ALL.iter().map(|p| p.name()).collect()
    }
}

/// The library error of a generator error.
fn synth_error(e: SynthError) -> Error {
    match e {
        SynthError::UnknownPreset { .. } | SynthError::InvalidParams(_) => {
            Error::config(e.to_string())
        }
        SynthError::Io { path, source } => Error::file(path, source.to_string()),
        SynthError::Image { path, source } => Error::file(path, source.to_string()),
        SynthError::Format { path, what } => Error::file(path, what),
        SynthError::Dataset(e) => Error::Io(e),
        SynthError::Flow(e) => Error::Input(e.to_string()),
    }
}

impl SynthOptions {
    /// The generator parameters (as `dynapix synth` builds them from its flags).
    pub fn params(&self) -> Result<SynthParams> {
        let preset: Preset = self.preset.parse().map_err(synth_error)?;
        if self.frames == 0 {
            return Err(Error::config("frames must be at least 1"));
        }
        let mut cam = dynapix_geometry::PinholeCamera::tum_fr3();
        if self.width.is_some() || self.height.is_some() {
            let w = self.width.unwrap_or(cam.width);
            let h = self
                .height
                .unwrap_or((cam.height as f64 * w as f64 / cam.width as f64).round() as u32);
            if w < 16 || h < 16 {
                return Err(Error::config(format!(
                    "image size {w}×{h} is too small (at least 16×16)"
                )));
            }
            cam = cam.resized(w, h);
        }
        let sensor = match self.realism {
            Realism::Clean => SensorParams::clean(),
            Realism::Kinect => SensorParams::default(),
            Realism::Full => SensorParams::full(),
        };
        Ok(SynthParams {
            preset,
            frames: self.frames,
            seed: self.seed,
            scene: dynapix_synth::SceneParams::for_width(cam.width),
            camera: cam,
            sensor,
            ..SynthParams::default()
        })
    }
}

/// One rendered frame.
#[derive(Clone, Debug)]
pub struct SyntheticFrame {
    /// Index in the sequence.
    pub index: usize,
    /// Time, seconds.
    pub t: f64,
    /// Ground-truth camera-to-world pose.
    pub pose_wc: dynapix_geometry::Se3,
    /// Colour image with the movers.
    pub rgb: RgbImage,
    /// Raw depth (units of [`SyntheticSequence::depth_factor`] per metre, 0 = none).
    pub depth: Gray16Image,
    /// Motion mask (0 static, 128 mover at rest, 255 moving).
    pub mask: GrayImage,
}

/// A synthetic sequence rendered on demand.
#[derive(Clone, Debug)]
pub struct SyntheticSequence {
    seq: dynapix_synth::Sequence,
}

impl SyntheticSequence {
    /// The generator of `options`.
    pub fn new(options: &SynthOptions) -> Result<Self> {
        let seq = dynapix_synth::Sequence::new(options.params()?).map_err(synth_error)?;
        Ok(Self { seq })
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.seq.params.frames
    }

    /// True without frames (never: at least one is required).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Raw depth units per metre.
    pub fn depth_factor(&self) -> f64 {
        dynapix_synth::sequence::DEPTH_FACTOR as f64
    }

    /// The camera of the sequence (what its written `camera.yaml` holds).
    pub fn camera(&self) -> Camera {
        Camera {
            settings: output::camera_settings(&self.seq.params.camera, self.seq.params.fps),
            source: CameraSource::Preset {
                name: format!("synthetic {}", self.seq.params.preset.name()),
            },
            size_from_frames: false,
        }
    }

    /// Renders frame `i`.
    pub fn frame(&self, i: usize) -> Result<SyntheticFrame> {
        if i >= self.len() {
            return Err(Error::Input(format!(
                "frame {i} is out of range (the sequence has {} frames)",
                self.len()
            )));
        }
        let (f, _) = self.seq.frame(i, None);
        Ok(SyntheticFrame {
            index: i,
            t: f.time,
            pose_wc: f.pose,
            rgb: f.rgb,
            depth: f.depth,
            mask: f.mask,
        })
    }

    /// Writes the whole sequence (DynaPix layout: rgb, depth, background, masks, lists,
    /// ground truth, `camera.yaml`) into `dir`, like `dynapix synth --out DIR`.
    pub fn write(&self, dir: &Path, progress: &mut dyn FnMut(usize)) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| Error::file(dir, e.to_string()))?;
        output::write_sequence(&self.seq, dir, None, progress).map_err(synth_error)
    }
}

/// Inserts `objects` flying virtual movers (seeded by `seed`) into the real sequence
/// `seq_dir` (it needs ground truth) and writes the DynaPix layout into `out_dir`, at most
/// `max_frames` frames, like `dynapix synth --augment`. Returns the frames written.
pub fn augment(
    seq_dir: &Path,
    out_dir: &Path,
    seed: u64,
    objects: usize,
    max_frames: Option<usize>,
) -> Result<usize> {
    std::fs::create_dir_all(out_dir).map_err(|e| Error::file(out_dir, e.to_string()))?;
    let params = dynapix_synth::augment::AugmentParams {
        seed,
        objects,
        ..Default::default()
    };
    output::augment_sequence(seq_dir, out_dir, &params, max_frames, &mut |_, _| {})
        .map_err(synth_error)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_follow_the_options_and_errors_are_typed() {
        let opts = SynthOptions {
            preset: "walking_static".into(),
            frames: 3,
            width: Some(160),
            realism: Realism::Clean,
            ..SynthOptions::default()
        };
        let s = SyntheticSequence::new(&opts).unwrap();
        assert_eq!(s.len(), 3);
        let f = s.frame(2).unwrap();
        assert_eq!(f.rgb.dimensions(), (160, 120));
        assert_eq!(f.depth.dimensions(), (160, 120));
        assert_eq!(s.camera().settings.width, 160);
        assert!(f.depth.as_raw().iter().any(|&d| d > 0));
        assert!(f.t > 0.0);
        assert!(matches!(s.frame(3), Err(Error::Input(_))));
        let bad = SynthOptions {
            preset: "nope".into(),
            ..SynthOptions::default()
        };
        let e = SyntheticSequence::new(&bad).unwrap_err();
        assert!(matches!(e, Error::Config { .. }), "{e}");
        assert!(e.to_string().contains("nope"));
        assert!(Realism::from_name("grainy").is_err());
    }
}
