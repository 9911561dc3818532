//! The camera of a run: presets, the caller's choice, where the settings came from, and the
//! resolved [`Camera`] (SLAM camera, pinhole camera, ORB parameters, its record).

use std::path::PathBuf;

use dynapix_io::Settings;
use dynapix_slam::RgbdCamera;
use dynapix_slam::orb::OrbParams;
use serde::Serialize;

use crate::error::{Error, Result};
use crate::record::{CameraRecord, CameraSource, OrbRecord};

/// Camera presets (ORB-SLAM2 settings files).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum CameraPreset {
    /// TUM fr1 (`TUM1.yaml`, distorted).
    Tum1,
    /// TUM fr2 (`TUM2.yaml`, distorted, depth factor 5208).
    Tum2,
    /// TUM fr3 (`TUM3.yaml`).
    Tum3,
    /// GRADE (`GRADE.yaml`, depth in mm, 3000 features).
    Grade,
    /// Bonn RGB-D Dynamic (the dataset's Kinect calibration, distorted).
    Bonn,
}

impl CameraPreset {
    /// Every preset.
    pub const ALL: [CameraPreset; 5] = [
        CameraPreset::Tum1,
        CameraPreset::Tum2,
        CameraPreset::Tum3,
        CameraPreset::Grade,
        CameraPreset::Bonn,
    ];

    /// The preset's name.
    pub fn name(self) -> &'static str {
        match self {
            CameraPreset::Tum1 => "tum1",
            CameraPreset::Tum2 => "tum2",
            CameraPreset::Tum3 => "tum3",
            CameraPreset::Grade => "grade",
            CameraPreset::Bonn => "bonn",
        }
    }

    /// The settings of the preset.
    pub fn settings(self) -> Settings {
        match self {
            CameraPreset::Tum1 => Settings::tum1(),
            CameraPreset::Tum2 => Settings::tum2(),
            CameraPreset::Tum3 => Settings::tum3(),
            CameraPreset::Grade => Settings::grade(),
            CameraPreset::Bonn => Settings::bonn(),
        }
    }
}

/// How the camera of a run is chosen.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum CameraChoice {
    /// From the sequence folder (`camera.yaml`, folder name, GRADE layout).
    #[default]
    Sequence,
    /// A preset.
    Preset(CameraPreset),
    /// An ORB-SLAM2 settings file (missing keys take the TUM values).
    Settings(PathBuf),
}

/// The camera of a run.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// The settings (intrinsics, distortion, depth factor, ORB parameters).
    pub settings: Settings,
    /// Where they came from.
    pub source: CameraSource,
    /// The settings stated no image size and the first frame's size was used.
    pub size_from_frames: bool,
}

impl Camera {
    /// The SLAM camera (intrinsics, distortion, `bf`, `ThDepth`, fps).
    pub fn rgbd(&self) -> RgbdCamera {
        let s = &self.settings;
        RgbdCamera::new(s.camera(), s.bf, s.th_depth, s.fps)
    }

    /// The pinhole camera of the motion maps.
    pub fn pinhole(&self) -> dynapix_geometry::PinholeCamera {
        self.settings.camera()
    }

    /// The ORB extractor parameters of the settings.
    pub fn orb_params(&self) -> Result<OrbParams> {
        let o = &self.settings.orb;
        let fast = |v: u32, key: &str| {
            u8::try_from(v)
                .map_err(|_| Error::Input(format!("ORBextractor.{key} {v} does not fit 0..=255")))
        };
        Ok(OrbParams {
            nfeatures: o.n_features,
            scale_factor: o.scale_factor as f32,
            nlevels: o.n_levels,
            ini_th_fast: fast(o.ini_th_fast, "iniThFAST")?,
            min_th_fast: fast(o.min_th_fast, "minThFAST")?,
        })
    }

    /// What outputs record about the camera.
    pub fn record(&self) -> CameraRecord {
        let s = &self.settings;
        CameraRecord {
            source: self.source.clone(),
            pinhole: s.camera(),
            bf: s.bf,
            th_depth: s.th_depth,
            fps: s.fps,
            depth_map_factor: s.depth_map_factor,
            orb: OrbRecord {
                n_features: s.orb.n_features,
                scale_factor: s.orb.scale_factor,
                n_levels: s.orb.n_levels,
                ini_th_fast: s.orb.ini_th_fast,
                min_th_fast: s.orb.min_th_fast,
            },
            size_from_frames: self.size_from_frames,
        }
    }
}
