//! ORB-SLAM2 settings files (`TUM1.yaml`, `TUM3.yaml`, `GRADE.yaml`, a sequence's
//! `camera.yaml`; spec §2.8, §5.1, §5.2) and the built-in camera presets `tum1 tum2 tum3 grade
//! bonn`.
//!
//! The files are OpenCV YAML: a `%YAML:1.0` first line and flat keys with dots
//! (`Camera.fx: 535.4`). They are parsed with `serde-saphyr` after two OpenCV tolerances are
//! applied line by line (numbering kept): the `%YAML` line is blanked, and `key:value` without
//! a space (upstream `TUM3.yaml` has `Viewer.PointSize:2`) gets its space. A repeated key keeps
//! the later value (upstream `TUM3.yaml` repeats `Camera.width`). Unknown keys (viewer, …) are
//! ignored. `Camera.k3` is optional (0), as are `Camera.width`/`Camera.height` (ORB-SLAM2
//! ignores them; 640×480, the TUM and GRADE image size, when absent). Every value is
//! validated; errors name the file and the line of the offending key.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

use dynapix_geometry::PinholeCamera;
use serde::Deserialize;

use crate::atomic::write_atomic;
use crate::datasets::Dataset;
use crate::depth::DepthLimits;
use crate::error::{IoError, Result};
use crate::text::read_text;

/// Names of the built-in presets, for CLI help and error messages.
pub const PRESET_NAMES: [&str; 5] = ["tum1", "tum2", "tum3", "grade", "bonn"];

/// File name of the per-sequence settings that every command uses when present.
pub const SEQUENCE_SETTINGS_FILE: &str = "camera.yaml";

/// Image size assumed when a settings file has no `Camera.width`/`Camera.height`.
const DEFAULT_SIZE: (u32, u32) = (640, 480);

/// ORB extractor parameters (`ORBextractor.*`).
#[derive(Clone, Debug, PartialEq)]
pub struct OrbSettings {
    /// `ORBextractor.nFeatures`: features per image (TUM 1000, GRADE 3000).
    pub n_features: usize,
    /// `ORBextractor.scaleFactor`: scale between pyramid levels (1.2).
    pub scale_factor: f64,
    /// `ORBextractor.nLevels`: pyramid levels (8).
    pub n_levels: usize,
    /// `ORBextractor.iniThFAST`: initial FAST threshold (20).
    pub ini_th_fast: u32,
    /// `ORBextractor.minThFAST`: fallback FAST threshold for low-contrast cells (7).
    pub min_th_fast: u32,
}

impl Default for OrbSettings {
    /// The ORB-SLAM2 TUM values: 1000 features, 1.2, 8 levels, FAST 20/7.
    fn default() -> Self {
        Self {
            n_features: 1000,
            scale_factor: 1.2,
            n_levels: 8,
            ini_th_fast: 20,
            min_th_fast: 7,
        }
    }
}

/// The content of an ORB-SLAM2 RGB-D settings file.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    /// `Camera.fx`, pixels.
    pub fx: f64,
    /// `Camera.fy`, pixels.
    pub fy: f64,
    /// `Camera.cx`, pixels.
    pub cx: f64,
    /// `Camera.cy`, pixels.
    pub cy: f64,
    /// `Camera.k1 k2 p1 p2 k3` (OpenCV radial-tangential distortion).
    pub dist: [f64; 5],
    /// `Camera.width`, pixels.
    pub width: u32,
    /// `Camera.height`, pixels.
    pub height: u32,
    /// `Camera.fps`: frame rate (Hz).
    pub fps: f64,
    /// `Camera.bf`: baseline times fx (the virtual stereo baseline of RGB-D, pixel·m).
    pub bf: f64,
    /// `Camera.RGB`: true when images are RGB ordered (1), false for BGR (0).
    pub rgb: bool,
    /// `ThDepth`: close/far threshold in baselines.
    pub th_depth: f64,
    /// `DepthMapFactor`: depth PNG units per metre (TUM 5000, GRADE 1000).
    pub depth_map_factor: f64,
    /// `ORBextractor.*` parameters.
    pub orb: OrbSettings,
    /// The camera's depth limits (`depth_saturation`: the raw value it writes at saturation,
    /// `null` for none; `depth_max_m`: its largest plausible depth in metres), `None` where
    /// the file states none: a run's configuration overrides them, the defaults of
    /// [`crate::DepthValidity`] fill the rest.
    pub depth_limits: DepthLimits,
}

/// The raw keys as read; all optional so that a missing key gets our own message.
#[derive(Deserialize)]
struct RawSettings {
    #[serde(rename = "Camera.fx")]
    fx: Option<f64>,
    #[serde(rename = "Camera.fy")]
    fy: Option<f64>,
    #[serde(rename = "Camera.cx")]
    cx: Option<f64>,
    #[serde(rename = "Camera.cy")]
    cy: Option<f64>,
    #[serde(rename = "Camera.k1")]
    k1: Option<f64>,
    #[serde(rename = "Camera.k2")]
    k2: Option<f64>,
    #[serde(rename = "Camera.p1")]
    p1: Option<f64>,
    #[serde(rename = "Camera.p2")]
    p2: Option<f64>,
    #[serde(rename = "Camera.k3")]
    k3: Option<f64>,
    #[serde(rename = "Camera.width")]
    width: Option<i64>,
    #[serde(rename = "Camera.height")]
    height: Option<i64>,
    #[serde(rename = "Camera.fps")]
    fps: Option<f64>,
    #[serde(rename = "Camera.bf")]
    bf: Option<f64>,
    #[serde(rename = "Camera.RGB")]
    rgb: Option<i64>,
    #[serde(rename = "ThDepth")]
    th_depth: Option<f64>,
    #[serde(rename = "DepthMapFactor")]
    depth_map_factor: Option<f64>,
    #[serde(rename = "ORBextractor.nFeatures")]
    n_features: Option<i64>,
    #[serde(rename = "ORBextractor.scaleFactor")]
    scale_factor: Option<f64>,
    #[serde(rename = "ORBextractor.nLevels")]
    n_levels: Option<i64>,
    #[serde(rename = "ORBextractor.iniThFAST")]
    ini_th_fast: Option<i64>,
    #[serde(rename = "ORBextractor.minThFAST")]
    min_th_fast: Option<i64>,
    /// Absent: `None`; `null`: `Some(None)` (no saturation value).
    #[serde(default, deserialize_with = "stated")]
    depth_saturation: Option<Option<i64>>,
    depth_max_m: Option<f64>,
}

/// A key that may be given as `null`: `Some(None)` then, `None` when absent (`default`).
fn stated<'de, D, T>(d: D) -> std::result::Result<Option<Option<T>>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de>,
{
    Option::<T>::deserialize(d).map(Some)
}

impl RawSettings {
    /// Fills every missing key except `Camera.fx fy cx cy` from [`Settings::tum3`]; returns
    /// the keys filled (`Camera.k3` is optional anyway).
    fn fill_defaults(&mut self) -> Vec<&'static str> {
        let d = Settings::tum3();
        let mut filled = Vec::new();
        fn fill<T>(slot: &mut Option<T>, v: T, key: &'static str, filled: &mut Vec<&'static str>) {
            if slot.is_none() {
                *slot = Some(v);
                filled.push(key);
            }
        }
        let f = &mut filled;
        fill(&mut self.k1, d.dist[0], "Camera.k1", f);
        fill(&mut self.k2, d.dist[1], "Camera.k2", f);
        fill(&mut self.p1, d.dist[2], "Camera.p1", f);
        fill(&mut self.p2, d.dist[3], "Camera.p2", f);
        fill(&mut self.width, i64::from(d.width), "Camera.width", f);
        fill(&mut self.height, i64::from(d.height), "Camera.height", f);
        fill(&mut self.fps, d.fps, "Camera.fps", f);
        fill(&mut self.bf, d.bf, "Camera.bf", f);
        fill(&mut self.rgb, i64::from(d.rgb), "Camera.RGB", f);
        fill(&mut self.th_depth, d.th_depth, "ThDepth", f);
        fill(
            &mut self.depth_map_factor,
            d.depth_map_factor,
            "DepthMapFactor",
            f,
        );
        let o = &d.orb;
        let n = |v: usize| i64::try_from(v).unwrap_or(i64::MAX);
        fill(
            &mut self.n_features,
            n(o.n_features),
            "ORBextractor.nFeatures",
            f,
        );
        fill(
            &mut self.scale_factor,
            o.scale_factor,
            "ORBextractor.scaleFactor",
            f,
        );
        fill(&mut self.n_levels, n(o.n_levels), "ORBextractor.nLevels", f);
        fill(
            &mut self.ini_th_fast,
            i64::from(o.ini_th_fast),
            "ORBextractor.iniThFAST",
            f,
        );
        fill(
            &mut self.min_th_fast,
            i64::from(o.min_th_fast),
            "ORBextractor.minThFAST",
            f,
        );
        filled
    }
}

/// Applies the OpenCV-YAML tolerances (see the module doc) without changing line numbers.
fn preprocess(text: &str) -> String {
    // A UTF-8 byte-order mark (editors on Windows write one) is not part of the first key.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut out = String::with_capacity(text.len() + 16);
    for line in text.split('\n') {
        let trimmed = line.trim_start();
        if trimmed.starts_with("%YAML") {
            out.push('\n');
            continue;
        }
        let fixed = match line.split_once(':') {
            Some((key, value))
                if !trimmed.starts_with('#')
                    && !key.trim().is_empty()
                    && key
                        .trim()
                        .chars()
                        .all(|c| c.is_ascii_alphanumeric() || c == '.' || c == '_')
                    && value.chars().next().is_some_and(|c| !c.is_whitespace()) =>
            {
                format!("{key}: {value}")
            }
            _ => line.to_string(),
        };
        out.push_str(&fixed);
        out.push('\n');
    }
    out
}

/// A top-level key given twice with different values is an error naming both lines (upstream
/// ORB-SLAM2 files repeat some keys with the same value, which is accepted).
fn check_duplicates(text: &str, path: &Path) -> Result<()> {
    let mut seen: HashMap<&str, (usize, &str)> = HashMap::new();
    for (i, line) in text.split('\n').enumerate() {
        if line.starts_with([' ', '\t', '#']) {
            continue;
        }
        let Some((key, value)) = line.split_once(':') else {
            continue;
        };
        let (key, value) = (key.trim(), value.trim());
        if key.is_empty() {
            continue;
        }
        match seen.get(key) {
            Some(&(first, v)) if v != value => {
                return Err(IoError::parse(
                    path,
                    i + 1,
                    format!(
                        "{key} is given twice with different values (line {first}: {v}, line {}: {value})",
                        i + 1
                    ),
                ));
            }
            Some(_) => {}
            None => {
                seen.insert(key, (i + 1, value));
            }
        }
    }
    Ok(())
}

/// 1-based line of each top-level key (the last occurrence, matching the value kept).
fn key_lines(text: &str) -> HashMap<String, usize> {
    let mut map = HashMap::new();
    for (i, line) in text.split('\n').enumerate() {
        let t = line.trim();
        if t.starts_with('#') || t.starts_with('%') {
            continue;
        }
        if let Some((key, _)) = t.split_once(':') {
            map.insert(key.trim().to_string(), i + 1);
        }
    }
    map
}

/// One failed validation rule: the key concerned and what is wrong.
struct Problem {
    key: &'static str,
    message: String,
}

/// What a bad `depth_saturation` is told.
fn saturation_range(v: i64) -> String {
    format!("must be a raw depth value in 1..=65535 (null: none), got {v}")
}

fn problem(key: &'static str, message: impl Into<String>) -> Problem {
    Problem {
        key,
        message: message.into(),
    }
}

impl Settings {
    /// Reads and validates a settings file.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::parse(&read_text(path)?, path)
    }

    /// Parses and validates settings text; `path` is only used in error messages.
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        Self::parse_impl(text, path, false).map(|(s, _)| s)
    }

    /// Reads a settings file in which only `Camera.fx fy cx cy` are required: every other
    /// missing key takes its [`Settings::tum3`] value (no distortion, 640×480, 30 Hz,
    /// `bf` 40, `ThDepth` 40, `DepthMapFactor` 5000, the default ORB extractor), as the CLI
    /// has always accepted short camera files. The result is validated like
    /// [`Settings::read`]. Also returns the keys that were missing, in file-key order.
    pub fn read_lenient(path: impl AsRef<Path>) -> Result<(Self, Vec<&'static str>)> {
        let path = path.as_ref();
        Self::parse_lenient(&read_text(path)?, path)
    }

    /// Parses settings text like [`Settings::read_lenient`]; `path` is only used in error
    /// messages.
    pub fn parse_lenient(text: &str, path: &Path) -> Result<(Self, Vec<&'static str>)> {
        Self::parse_impl(text, path, true)
    }

    fn parse_impl(text: &str, path: &Path, lenient: bool) -> Result<(Self, Vec<&'static str>)> {
        let pre = preprocess(text);
        check_duplicates(&pre, path)?;
        let lines = key_lines(&pre);
        let options = serde_saphyr::options! {
            // Upstream files repeat keys with the same value; different values are refused
            // by `check_duplicates` before this parse.
            duplicate_keys: serde_saphyr::DuplicateKeyPolicy::LastWins,
            with_snippet: false,
        };
        let mut raw: RawSettings =
            serde_saphyr::from_str_with_options(&pre, options).map_err(|e| {
                let msg = e.to_string();
                match e.location() {
                    Some(loc) if loc.line() > 0 => {
                        let line = loc.line() as usize;
                        // Name the key of that line (a value of the wrong type).
                        let msg = match lines.iter().find(|&(_, &l)| l == line) {
                            Some((key, _)) if !msg.contains(key.as_str()) => {
                                format!("{key}: {msg}")
                            }
                            _ => msg,
                        };
                        IoError::parse(path, line, msg)
                    }
                    _ => IoError::invalid(path, msg),
                }
            })?;
        let at = |p: Problem| match lines.get(p.key) {
            Some(&line) => IoError::parse(path, line, format!("{}: {}", p.key, p.message)),
            None => IoError::invalid(path, format!("{}: {}", p.key, p.message)),
        };
        let defaulted = if lenient {
            raw.fill_defaults()
        } else {
            Vec::new()
        };
        let s = Self::from_raw(raw).map_err(at)?;
        s.check().map_err(at)?;
        Ok((s, defaulted))
    }

    fn from_raw(r: RawSettings) -> std::result::Result<Self, Problem> {
        fn need<T>(v: Option<T>, key: &'static str) -> std::result::Result<T, Problem> {
            v.ok_or_else(|| problem(key, "missing key"))
        }
        fn count<T: TryFrom<i64>>(v: i64, key: &'static str) -> std::result::Result<T, Problem> {
            T::try_from(v).map_err(|_| problem(key, format!("{v} is out of range")))
        }
        let width = match r.width {
            Some(w) => count(w, "Camera.width")?,
            None => DEFAULT_SIZE.0,
        };
        let height = match r.height {
            Some(h) => count(h, "Camera.height")?,
            None => DEFAULT_SIZE.1,
        };
        let saturation = match r.depth_saturation {
            Some(Some(v)) => {
                Some(Some(u16::try_from(v).map_err(|_| {
                    problem("depth_saturation", saturation_range(v))
                })?))
            }
            other => other.map(|_| None),
        };
        let rgb = match need(r.rgb, "Camera.RGB")? {
            0 => false,
            1 => true,
            v => return Err(problem("Camera.RGB", format!("expected 0 or 1, got {v}"))),
        };
        Ok(Self {
            fx: need(r.fx, "Camera.fx")?,
            fy: need(r.fy, "Camera.fy")?,
            cx: need(r.cx, "Camera.cx")?,
            cy: need(r.cy, "Camera.cy")?,
            dist: [
                need(r.k1, "Camera.k1")?,
                need(r.k2, "Camera.k2")?,
                need(r.p1, "Camera.p1")?,
                need(r.p2, "Camera.p2")?,
                r.k3.unwrap_or(0.0),
            ],
            width,
            height,
            fps: need(r.fps, "Camera.fps")?,
            bf: need(r.bf, "Camera.bf")?,
            rgb,
            th_depth: need(r.th_depth, "ThDepth")?,
            depth_map_factor: need(r.depth_map_factor, "DepthMapFactor")?,
            orb: OrbSettings {
                n_features: count(
                    need(r.n_features, "ORBextractor.nFeatures")?,
                    "ORBextractor.nFeatures",
                )?,
                scale_factor: need(r.scale_factor, "ORBextractor.scaleFactor")?,
                n_levels: count(
                    need(r.n_levels, "ORBextractor.nLevels")?,
                    "ORBextractor.nLevels",
                )?,
                ini_th_fast: count(
                    need(r.ini_th_fast, "ORBextractor.iniThFAST")?,
                    "ORBextractor.iniThFAST",
                )?,
                min_th_fast: count(
                    need(r.min_th_fast, "ORBextractor.minThFAST")?,
                    "ORBextractor.minThFAST",
                )?,
            },
            depth_limits: DepthLimits {
                saturation,
                max_depth: r.depth_max_m.map(|m| m as f32),
            },
        })
    }

    /// The validation rules; the first failure is reported.
    fn check(&self) -> std::result::Result<(), Problem> {
        let positive = |v: f64, key: &'static str| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(problem(key, format!("must be a positive number, got {v}")))
            }
        };
        positive(self.fx, "Camera.fx")?;
        positive(self.fy, "Camera.fy")?;
        if self.width == 0 {
            return Err(problem("Camera.width", "must be positive"));
        }
        if self.height == 0 {
            return Err(problem("Camera.height", "must be positive"));
        }
        if !(self.cx.is_finite() && (0.0..=self.width as f64).contains(&self.cx)) {
            return Err(problem(
                "Camera.cx",
                format!("must lie in [0, width = {}], got {}", self.width, self.cx),
            ));
        }
        if !(self.cy.is_finite() && (0.0..=self.height as f64).contains(&self.cy)) {
            return Err(problem(
                "Camera.cy",
                format!("must lie in [0, height = {}], got {}", self.height, self.cy),
            ));
        }
        const DIST_KEYS: [&str; 5] = [
            "Camera.k1",
            "Camera.k2",
            "Camera.p1",
            "Camera.p2",
            "Camera.k3",
        ];
        for (v, key) in self.dist.iter().zip(DIST_KEYS) {
            if !v.is_finite() {
                return Err(problem(key, format!("must be finite, got {v}")));
            }
        }
        positive(self.fps, "Camera.fps")?;
        positive(self.bf, "Camera.bf")?;
        positive(self.th_depth, "ThDepth")?;
        positive(self.depth_map_factor, "DepthMapFactor")?;
        if let Some(Some(0)) = self.depth_limits.saturation {
            return Err(problem("depth_saturation", saturation_range(0)));
        }
        if let Some(m) = self.depth_limits.max_depth
            && !(m.is_finite() && m > 0.0 && m <= 1000.0)
        {
            return Err(problem(
                "depth_max_m",
                format!("must lie in (0, 1000] metres, got {m}"),
            ));
        }
        if self.orb.n_features == 0 {
            return Err(problem("ORBextractor.nFeatures", "must be positive"));
        }
        if !(self.orb.scale_factor.is_finite() && self.orb.scale_factor > 1.0) {
            return Err(problem(
                "ORBextractor.scaleFactor",
                format!("must be > 1, got {}", self.orb.scale_factor),
            ));
        }
        if self.orb.n_levels == 0 || self.orb.n_levels > 32 {
            return Err(problem(
                "ORBextractor.nLevels",
                format!("must be in 1..=32, got {}", self.orb.n_levels),
            ));
        }
        if self.orb.ini_th_fast == 0 || self.orb.ini_th_fast > 255 {
            return Err(problem(
                "ORBextractor.iniThFAST",
                format!("must be in 1..=255, got {}", self.orb.ini_th_fast),
            ));
        }
        if self.orb.min_th_fast == 0 || self.orb.min_th_fast > self.orb.ini_th_fast {
            return Err(problem(
                "ORBextractor.minThFAST",
                format!(
                    "must be in 1..=iniThFAST ({}), got {}",
                    self.orb.ini_th_fast, self.orb.min_th_fast
                ),
            ));
        }
        Ok(())
    }

    /// Checks the validation rules of [`Settings::read`] on settings built in code; the
    /// error names `path` (where they came from or will go) and the key.
    pub fn validate(&self, path: &Path) -> Result<()> {
        self.check()
            .map_err(|p| IoError::invalid(path, format!("{}: {}", p.key, p.message)))
    }

    /// The camera intrinsics and distortion.
    pub fn camera(&self) -> PinholeCamera {
        PinholeCamera {
            width: self.width,
            height: self.height,
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            dist: self.dist,
        }
    }

    /// Virtual stereo baseline `bf / fx` in metres (fr3: 0.0747 m).
    pub fn baseline(&self) -> f64 {
        self.bf / self.fx
    }

    /// The settings-file text (`%YAML:1.0` header, keys in ORB-SLAM2 order), readable by
    /// ORB-SLAM2 and by [`Settings::parse`].
    pub fn to_yaml_string(&self) -> String {
        let mut s = String::from("%YAML:1.0\n\n# Camera calibration and distortion (OpenCV)\n");
        let mut kv = |key: &str, v: String| {
            let _ = writeln!(s, "{key}: {v}");
        };
        // `{:?}` prints the shortest text that reads back to the same f64, always with a
        // decimal point or exponent, so YAML sees a float.
        kv("Camera.fx", format!("{:?}", self.fx));
        kv("Camera.fy", format!("{:?}", self.fy));
        kv("Camera.cx", format!("{:?}", self.cx));
        kv("Camera.cy", format!("{:?}", self.cy));
        for (key, v) in ["k1", "k2", "p1", "p2", "k3"].iter().zip(self.dist) {
            kv(&format!("Camera.{key}"), format!("{v:?}"));
        }
        kv("Camera.width", self.width.to_string());
        kv("Camera.height", self.height.to_string());
        kv("Camera.fps", format!("{:?}", self.fps));
        kv("Camera.bf", format!("{:?}", self.bf));
        kv("Camera.RGB", u8::from(self.rgb).to_string());
        kv("ThDepth", format!("{:?}", self.th_depth));
        kv("DepthMapFactor", format!("{:?}", self.depth_map_factor));
        kv("ORBextractor.nFeatures", self.orb.n_features.to_string());
        kv(
            "ORBextractor.scaleFactor",
            format!("{:?}", self.orb.scale_factor),
        );
        kv("ORBextractor.nLevels", self.orb.n_levels.to_string());
        kv("ORBextractor.iniThFAST", self.orb.ini_th_fast.to_string());
        kv("ORBextractor.minThFAST", self.orb.min_th_fast.to_string());
        if let Some(v) = self.depth_limits.saturation {
            kv(
                "depth_saturation",
                v.map_or("null".into(), |v| v.to_string()),
            );
        }
        if let Some(m) = self.depth_limits.max_depth {
            kv("depth_max_m", format!("{m:?}"));
        }
        s
    }

    /// Validates and writes the settings file atomically.
    pub fn write(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        self.validate(path)?;
        write_atomic(path, self.to_yaml_string().as_bytes())
    }

    fn tum_common(fx: f64, fy: f64, cx: f64, cy: f64, dist: [f64; 5], factor: f64) -> Self {
        Self {
            fx,
            fy,
            cx,
            cy,
            dist,
            width: 640,
            height: 480,
            fps: 30.0,
            bf: 40.0,
            rgb: true,
            th_depth: 40.0,
            depth_map_factor: factor,
            orb: OrbSettings::default(),
            depth_limits: DepthLimits::default(),
        }
    }

    /// ORB-SLAM2 `TUM1.yaml` (Kinect of the freiburg1 sequences, distorted).
    pub fn tum1() -> Self {
        Self::tum_common(
            517.306408,
            516.469215,
            318.643040,
            255.313989,
            [0.262383, -0.953104, -0.005358, 0.002628, 1.163314],
            5000.0,
        )
    }

    /// ORB-SLAM2 `TUM2.yaml` (freiburg2, distorted, depth factor 5208).
    pub fn tum2() -> Self {
        Self::tum_common(
            520.908620,
            521.007327,
            325.141442,
            249.701764,
            [0.231222, -0.784899, -0.003257, -0.000105, 0.917205],
            5208.0,
        )
    }

    /// ORB-SLAM2 `TUM3.yaml` (freiburg3, the dynamic walking sequences; no distortion).
    pub fn tum3() -> Self {
        Self::tum_common(535.4, 539.2, 320.1, 247.6, [0.0; 5], 5000.0)
    }

    /// DynaPix `GRADE.yaml` (synthetic Isaac Sim sequences: depth in mm, 3000 features).
    pub fn grade() -> Self {
        let mut s = Self::tum_common(325.9103, 399.3103, 320.0, 240.0, [0.0; 5], 1000.0);
        s.orb.n_features = 3000;
        s
    }

    /// The Kinect of the Bonn RGB-D Dynamic Dataset (intrinsics and radial-tangential
    /// distortion as the dataset publishes them; depth factor, `bf` and `ThDepth` as TUM).
    pub fn bonn() -> Self {
        Self::tum_common(
            542.822841,
            542.576870,
            315.593520,
            237.756098,
            [0.039903, -0.099343, -0.000730, -0.000144, 0.0],
            5000.0,
        )
    }

    /// The preset called `name` (one of [`PRESET_NAMES`], case-insensitive).
    pub fn preset(name: &str) -> Option<Self> {
        match name.to_ascii_lowercase().as_str() {
            "tum1" => Some(Self::tum1()),
            "tum2" => Some(Self::tum2()),
            "tum3" => Some(Self::tum3()),
            "grade" => Some(Self::grade()),
            "bonn" => Some(Self::bonn()),
            _ => None,
        }
    }

    /// The settings of a sequence folder: its `camera.yaml` if present, else the preset of
    /// its dataset ([`Dataset::of_dir`]: a `rgbd_dataset_freiburgN_*` or `rgbd_bonn_*` folder,
    /// or a folder linking to one), else an error saying that the camera cannot be told (the
    /// caller should then ask for `--camera`/`--settings`).
    pub fn for_sequence_dir(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref();
        let file = dir.join(SEQUENCE_SETTINGS_FILE);
        if file.is_file() {
            return Self::read(&file);
        }
        // `.` or `seq/..` have no useful name: the dataset is told from the resolved folder.
        std::fs::canonicalize(dir).map_err(|e| IoError::io(dir, e))?;
        Dataset::of_dir(dir)
            .and_then(|d| Self::preset(d.preset_name()))
            .ok_or_else(|| {
                IoError::invalid(
                    dir,
                    format!(
                        "cannot tell the camera: no {SEQUENCE_SETTINGS_FILE} in the folder and \
                         its name is neither rgbd_dataset_freiburgN_* nor rgbd_bonn_*; give a \
                         settings file or a preset ({})",
                        PRESET_NAMES.join(", ")
                    ),
                )
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    #[test]
    fn lenient_fills_missing_keys_and_still_validates() {
        let p = Path::new("cam.yaml");
        let short = "%YAML:1.0\nCamera.fx: 500.0\nCamera.fy: 501.0\nCamera.cx: 300.0\n\
                     Camera.cy: 200.0\nDepthMapFactor: 1000.0\nORBextractor.nFeatures: 3000\n";
        assert!(
            Settings::parse(short, p).is_err(),
            "strict parse must refuse"
        );
        let (s, missing) = Settings::parse_lenient(short, p).unwrap();
        assert_eq!((s.fx, s.fy, s.cx, s.cy), (500.0, 501.0, 300.0, 200.0));
        assert_eq!(s.depth_map_factor, 1000.0);
        assert_eq!(s.orb.n_features, 3000);
        let d = Settings::tum3();
        assert_eq!(
            (s.width, s.height, s.bf, s.th_depth),
            (d.width, d.height, d.bf, d.th_depth)
        );
        assert_eq!(s.dist, [0.0; 5]);
        assert!(missing.contains(&"Camera.width") && missing.contains(&"Camera.bf"));
        assert!(!missing.contains(&"DepthMapFactor") && !missing.contains(&"Camera.fx"));
        // A complete file has nothing missing and parses as strictly.
        let (full, none) = Settings::parse_lenient(FR3_LIKE, p).unwrap();
        assert!(none.is_empty(), "{none:?}");
        assert_eq!(full, Settings::parse(FR3_LIKE, p).unwrap());
        // The four intrinsics stay required, and bad values are still refused with a line.
        let e = Settings::parse_lenient("Camera.fx: 500.0\nCamera.fy: 500.0\nCamera.cx: 1.0\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("Camera.cy") && e.contains("missing"), "{e}");
        let bad = short.replace("DepthMapFactor: 1000.0", "DepthMapFactor: -1.0");
        let e = Settings::parse_lenient(&bad, p).unwrap_err().to_string();
        assert!(e.contains("DepthMapFactor") && e.contains(":6"), "{e}");
    }

    #[test]
    fn depth_limit_keys_are_optional_read_written_and_checked_by_name() {
        let p = Path::new("seq/camera.yaml");
        let (s, _) = Settings::parse_lenient(FR3_LIKE, p).unwrap();
        assert!(s.depth_limits.is_empty());
        let text = format!("{FR3_LIKE}depth_saturation: 4095\ndepth_max_m: 4.5\n");
        let (s, missing) = Settings::parse_lenient(&text, p).unwrap();
        assert!(missing.is_empty(), "{missing:?}");
        assert_eq!(s.depth_limits.saturation, Some(Some(4095)));
        assert_eq!(s.depth_limits.max_depth, Some(4.5));
        assert_eq!(Settings::parse(&s.to_yaml_string(), p).unwrap(), s);
        let off = format!("{FR3_LIKE}depth_saturation: null\n");
        let s = Settings::parse(&off, p).unwrap();
        assert_eq!(s.depth_limits.saturation, Some(None));
        assert_eq!(Settings::parse(&s.to_yaml_string(), p).unwrap(), s);
        let line = FR3_LIKE.split('\n').count();
        for (bad, key) in [
            ("depth_max_m: -2.0", "depth_max_m"),
            ("depth_max_m: 0", "depth_max_m"),
            ("depth_max_m: .inf", "depth_max_m"),
            ("depth_saturation: 70000", "depth_saturation"),
            ("depth_saturation: 0", "depth_saturation"),
            ("depth_saturation: -1", "depth_saturation"),
        ] {
            let e = Settings::parse_lenient(&format!("{FR3_LIKE}{bad}\n"), p)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("seq/camera.yaml") && e.contains(key) && e.contains(&format!(":{line}")),
                "{bad}: {e}"
            );
        }
    }

    /// An ORB-SLAM2-style file with the quirks of the upstream ones: `%YAML:1.0`, comments,
    /// a string key, a repeated key, `key:value` without a space, viewer keys.
    const FR3_LIKE: &str = "%YAML:1.0\n\
        \n\
        # Camera Parameters\n\
        Camera.type: \"PinHole\"\n\
        Camera.fx: 535.4\n\
        Camera.fy: 539.2\n\
        Camera.cx: 320.1\n\
        Camera.cy: 247.6\n\
        \n\
        Camera.k1: 0.0\n\
        Camera.k2: 0.0\n\
        Camera.p1: 0.0\n\
        Camera.p2: 0.0\n\
        Camera.width: 640\n\
        Camera.height: 480\n\
        Camera.fps: 30.0\n\
        Camera.bf: 40.0\n\
        Camera.RGB: 1\n\
        ThDepth: 40.0\n\
        DepthMapFactor: 5000.0\n\
        Camera.width: 640\n\
        Camera.height: 480\n\
        ORBextractor.nFeatures: 1000\n\
        ORBextractor.scaleFactor: 1.2\n\
        ORBextractor.nLevels: 8\n\
        ORBextractor.iniThFAST: 20\n\
        ORBextractor.minThFAST: 7\n\
        Viewer.KeyFrameSize: 0.05\n\
        Viewer.PointSize:2\n\
        Viewer.ViewpointF: 500\n";

    fn err(text: &str) -> String {
        Settings::parse(text, Path::new("cam.yaml"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn parses_upstream_style_file_into_the_tum3_preset() {
        let s = Settings::parse(FR3_LIKE, Path::new("TUM3.yaml")).unwrap();
        assert_eq!(s, Settings::tum3());
        assert!((s.baseline() - 0.074711).abs() < 1e-6);
        let cam = s.camera();
        assert_eq!(
            (cam.width, cam.height, cam.fx, cam.cy),
            (640, 480, 535.4, 247.6)
        );
        assert!(!cam.is_distorted());
    }

    #[test]
    fn presets_round_trip_through_the_writer() {
        let dir = tempfile::tempdir().unwrap();
        for name in PRESET_NAMES {
            let s = Settings::preset(name).unwrap();
            let p = dir.path().join(format!("{name}.yaml"));
            s.write(&p).unwrap();
            let text = std::fs::read_to_string(&p).unwrap();
            assert!(text.starts_with("%YAML:1.0\n"));
            assert_eq!(Settings::read(&p).unwrap(), s, "{name}");
        }
        assert_eq!(Settings::tum1().camera().dist[4], 1.163314);
        assert_eq!(Settings::tum2().depth_map_factor, 5208.0);
        assert_eq!(Settings::grade().orb.n_features, 3000);
        assert_eq!(Settings::grade().depth_map_factor, 1000.0);
        assert!(Settings::preset("TUM3").is_some());
        assert!(Settings::preset("kitti").is_none());
    }

    #[test]
    fn byte_order_mark_is_accepted_and_duplicate_keys_are_errors() {
        let text = Settings::tum1().to_yaml_string();
        let with_bom = format!("\u{feff}{text}");
        let s = Settings::parse(&with_bom, Path::new("camera.yaml")).unwrap();
        assert_eq!(s, Settings::parse(&text, Path::new("camera.yaml")).unwrap());
        let dup = format!("{text}Camera.fx: 500.0\n");
        let e = Settings::parse(&dup, Path::new("camera.yaml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("camera.yaml") && e.contains("Camera.fx is given twice"),
            "{e}"
        );
        // The same value twice (as upstream files have) is fine.
        let same = format!("{text}Camera.width: 640\n");
        assert!(Settings::parse(&same, Path::new("camera.yaml")).is_ok());
    }

    #[test]
    fn optional_keys_take_their_defaults() {
        let text = FR3_LIKE
            .replace("Camera.width: 640\n", "")
            .replace("Camera.height: 480\n", "")
            .replace("Camera.p2: 0.0\n", "Camera.p2: 0.0\nCamera.k3: 0.5\n");
        let s = Settings::parse(&text, Path::new("x")).unwrap();
        assert_eq!((s.width, s.height), (640, 480));
        assert_eq!(s.dist[4], 0.5);
    }

    #[test]
    fn bad_settings_name_file_line_and_key() {
        // Line numbers: FR3_LIKE has Camera.fx on line 5, Camera.fps on 16, DepthMapFactor on 20.
        let e = err(&FR3_LIKE.replace("Camera.fx: 535.4", "Camera.fx: -535.4"));
        assert!(
            e.contains("cam.yaml:5") && e.contains("Camera.fx") && e.contains("positive"),
            "{e}"
        );
        let e = err(&FR3_LIKE.replace("Camera.fps: 30.0", "Camera.fps: 0"));
        assert!(e.contains("cam.yaml:16") && e.contains("Camera.fps"), "{e}");
        let e = err(&FR3_LIKE.replace("DepthMapFactor: 5000.0", "DepthMapFactor: 0.0"));
        assert!(
            e.contains("cam.yaml:20") && e.contains("DepthMapFactor"),
            "{e}"
        );
        let e = err(&FR3_LIKE.replace("Camera.fx: 535.4", "Camera.fx: abc"));
        assert!(e.contains("cam.yaml:5"), "{e}");
        let e = err(&FR3_LIKE.replace("Camera.RGB: 1", "Camera.RGB: 3"));
        assert!(e.contains("cam.yaml:18") && e.contains("Camera.RGB"), "{e}");
        let e = err(&FR3_LIKE.replace("ORBextractor.minThFAST: 7", "ORBextractor.minThFAST: 30"));
        assert!(e.contains("cam.yaml:27") && e.contains("minThFAST"), "{e}");
        let e = err(&FR3_LIKE.replace("Camera.cx: 320.1", "Camera.cx: 1320.1"));
        assert!(e.contains("cam.yaml:7") && e.contains("Camera.cx"), "{e}");
        let e = err(&FR3_LIKE.replace("ORBextractor.nLevels: 8", "ORBextractor.nLevels: -8"));
        assert!(e.contains("cam.yaml:25") && e.contains("nLevels"), "{e}");
        let e = err(&FR3_LIKE.replace("Camera.fy: 539.2\n", ""));
        assert!(
            e.contains("cam.yaml") && e.contains("Camera.fy") && e.contains("missing"),
            "{e}"
        );
        let e = err(&FR3_LIKE.replace("Camera.k1: 0.0", "Camera.k1: [0.0"));
        assert!(e.contains("cam.yaml:"), "{e}");
        let e = err("");
        assert!(e.contains("cam.yaml"), "{e}");
        let e = Settings::read("/no/such/camera.yaml").unwrap_err();
        assert!(matches!(e, IoError::Io { .. }), "{e}");
        let mut s = Settings::tum3();
        s.fx = f64::NAN;
        let e = s
            .write(Path::new("/tmp/never-written.yaml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("Camera.fx"), "{e}");
    }

    #[test]
    fn settings_for_a_sequence_folder() {
        let root = tempfile::tempdir().unwrap();
        let fr3 = root.path().join("rgbd_dataset_freiburg3_walking_xyz");
        std::fs::create_dir(&fr3).unwrap();
        assert_eq!(Settings::for_sequence_dir(&fr3).unwrap(), Settings::tum3());
        assert_eq!(
            Settings::for_sequence_dir(fr3.join(".")).unwrap(),
            Settings::tum3()
        );
        Settings::grade()
            .write(fr3.join(SEQUENCE_SETTINGS_FILE))
            .unwrap();
        assert_eq!(Settings::for_sequence_dir(&fr3).unwrap(), Settings::grade());
        let other = root.path().join("my_sequence");
        std::fs::create_dir(&other).unwrap();
        let e = Settings::for_sequence_dir(&other).unwrap_err().to_string();
        assert!(
            e.contains("my_sequence") && e.contains("cannot tell the camera"),
            "{e}"
        );
        let bonn = root.path().join("rgbd_bonn_crowd");
        std::fs::create_dir(&bonn).unwrap();
        let b = Settings::for_sequence_dir(&bonn).unwrap();
        assert_eq!(b, Settings::bonn());
        assert_eq!(
            (b.fx, b.fy, b.cx, b.cy),
            (542.822841, 542.576870, 315.593520, 237.756098)
        );
        assert_eq!(b.dist, [0.039903, -0.099343, -0.000730, -0.000144, 0.0]);
        assert_eq!((b.width, b.height, b.depth_map_factor), (640, 480, 5000.0));
        assert_eq!((b.bf, b.th_depth, b.fps), (40.0, 40.0, 30.0));
        assert!(b.camera().is_distorted());
        assert_eq!(Settings::preset("BONN"), Some(Settings::bonn()));
        let real = PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../../shared/data/tum/rgbd_dataset_freiburg1_xyz"
        ));
        let real_bonn = real.join("../../bonn/rgbd_bonn_crowd");
        if real_bonn.is_dir() {
            assert_eq!(
                Settings::for_sequence_dir(&real_bonn).unwrap(),
                Settings::bonn()
            );
        }
        if real.is_dir() {
            assert_eq!(Settings::for_sequence_dir(&real).unwrap(), Settings::tum1());
        } else {
            eprintln!("skipped real-data part: {} not found", real.display());
        }
    }
}
