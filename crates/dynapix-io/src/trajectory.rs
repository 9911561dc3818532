//! Trajectory files: the TUM format (`timestamp tx ty tz qx qy qz qw`, camera-to-world, as
//! written by ORB-SLAM2's `SaveTrajectoryTUM` and read by the TUM benchmark tools, spec §2.8
//! and §4.2), the KITTI format (3×4 row-major matrices, no timestamps), the per-frame status
//! file that makes lost frames explicit, and SLERP interpolation of a trajectory at any time.
//!
//! Reading follows the TUM tools: `#` lines are comments, commas and tabs separate fields.
//! Timestamps must not decrease; a repeated timestamp keeps the later line, like the Python
//! dictionary of `read_file_list` (real TUM ground-truth files such as fr3/walking_static
//! contain such duplicates). Quaternions are normalised on reading.
//!
//! Writing follows ORB-SLAM2: the timestamp with 6 decimals and the values with 9 decimals
//! (ORB-SLAM2 sets `fixed` before `setprecision(9)`, so its "9 digits" are 9 decimals), so
//! timestamps round-trip exactly through the text and match the association file.

use std::fmt::Write as _;
use std::path::Path;

use dynapix_geometry::Se3;
use nalgebra::{Matrix3, Quaternion, Rotation3, Translation3, UnitQuaternion};

use crate::atomic::write_atomic;
use crate::error::{IoError, Result};
use crate::text::{data_lines, expect_columns, parse_f64, read_text};

/// Default maximal gap (s) between two poses for [`Trajectory::interpolate`] on ground truth
/// (TUM motion capture runs at 100 Hz, so 0.05 s tolerates a few dropped samples).
pub const DEFAULT_MAX_GAP: f64 = 0.05;

/// Relative tolerance on the norm of a quaternion read from a file: TUM ground truth has 4
/// decimals, so its norms are within about 1e-4 of one; a larger deviation means a wrong column.
const QUAT_NORM_TOL: f64 = 1e-2;

/// A pose with its timestamp (seconds). `pose` maps camera coordinates to world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StampedPose {
    /// Timestamp in seconds (TUM: Unix time; GRADE/synthetic: seconds from 0).
    pub t: f64,
    /// Camera-to-world transform `T_wc`.
    pub pose: Se3,
}

impl StampedPose {
    /// A pose at time `t`.
    pub fn new(t: f64, pose: Se3) -> Self {
        Self { t, pose }
    }
}

/// A camera trajectory: poses sorted by non-decreasing timestamp.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectory {
    /// The poses, sorted by time.
    pub poses: Vec<StampedPose>,
}

/// Largest translation (mm) between two poses given for one timestamp that the strict reader
/// takes as one sample written twice.
pub const DUPLICATE_MM: f64 = 5.0;
/// Largest rotation (degrees) between two poses given for one timestamp that the strict reader
/// takes as one sample written twice.
pub const DUPLICATE_DEG: f64 = 1.0;

/// Whether two poses of one timestamp are the same sample within its noise.
fn same_sample(a: &Se3, b: &Se3) -> bool {
    (a.translation.vector - b.translation.vector).norm() * 1000.0 <= DUPLICATE_MM
        && a.rotation.angle_to(&b.rotation).to_degrees() <= DUPLICATE_DEG
}

impl Trajectory {
    /// A trajectory from poses (the caller keeps them sorted by time).
    pub fn new(poses: Vec<StampedPose>) -> Self {
        Self { poses }
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when there is no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// The timestamps, in order.
    pub fn timestamps(&self) -> Vec<f64> {
        self.poses.iter().map(|p| p.t).collect()
    }

    /// The poses as `(timestamp, camera-to-world pose)` pairs, in order (what the evaluation
    /// takes).
    pub fn pairs(&self) -> Vec<(f64, Se3)> {
        self.poses.iter().map(|p| (p.t, p.pose)).collect()
    }

    /// Reads a TUM trajectory file (see the module doc for the accepted syntax).
    pub fn read_tum(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::parse_tum(&read_text(path)?, path)
    }

    /// Parses TUM trajectory text; `path` is only used in error messages.
    pub fn parse_tum(text: &str, path: &Path) -> Result<Self> {
        Self::parse_tum_with(text, path, false)
    }

    /// Like [`Trajectory::read_tum`], but a timestamp given twice with poses further apart
    /// than one sample's noise ([`DUPLICATE_MM`] mm or [`DUPLICATE_DEG`]°) is an error naming
    /// the file and both lines. For evaluation, where either pose would change the score.
    /// Closer duplicates keep the later line, as the TUM tools do: the official ground truth
    /// of TUM fr3 `walking_static` repeats a stamp with poses 0.5 mm / 0.2° apart.
    pub fn read_tum_strict(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::parse_tum_with(&read_text(path)?, path, true)
    }

    /// [`Trajectory::read_tum_strict`] of TUM text; `path` is only used in error messages.
    pub fn parse_tum_strict(text: &str, path: &Path) -> Result<Self> {
        Self::parse_tum_with(text, path, true)
    }

    /// Parses TUM text; with `refuse_conflicts`, the same timestamp with another pose is an
    /// error.
    fn parse_tum_with(text: &str, path: &Path, refuse_conflicts: bool) -> Result<Self> {
        let mut poses: Vec<StampedPose> = Vec::new();
        let mut prev_values = [0.0; 8];
        let mut prev_line = 0;
        for line in data_lines(text) {
            expect_columns(path, &line, 8, "timestamp tx ty tz qx qy qz qw")?;
            let mut v = [0.0; 8];
            const NAMES: [&str; 8] = ["timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw"];
            for (k, (field, name)) in line.fields.iter().zip(NAMES).enumerate() {
                v[k] = parse_f64(path, line.no, field, name)?;
            }
            let q = Quaternion::new(v[7], v[4], v[5], v[6]);
            let norm = q.norm();
            if (norm - 1.0).abs() > QUAT_NORM_TOL {
                return Err(IoError::parse(
                    path,
                    line.no,
                    format!("quaternion (qx qy qz qw) has norm {norm}, expected 1"),
                ));
            }
            let pose = Se3::from_parts(
                Translation3::new(v[1], v[2], v[3]),
                UnitQuaternion::from_quaternion(q),
            );
            let sp = StampedPose::new(v[0], pose);
            match poses.last_mut() {
                Some(last) if sp.t < last.t => {
                    return Err(IoError::parse(
                        path,
                        line.no,
                        format!(
                            "timestamps not sorted: {} comes after {} (line {prev_line})",
                            line.fields[0], last.t
                        ),
                    ));
                }
                Some(last)
                    if sp.t == prev_values[0]
                        && refuse_conflicts
                        && !same_sample(&last.pose, &sp.pose) =>
                {
                    return Err(IoError::parse(
                        path,
                        line.no,
                        format!(
                            "timestamp {} is also on line {prev_line} with a pose {:.1} mm / \
                             {:.2}° away (more than one sample's noise, {DUPLICATE_MM} mm / \
                             {DUPLICATE_DEG}°); give one pose per timestamp (remove one of the \
                             two lines)",
                            line.fields[0],
                            (last.pose.translation.vector - sp.pose.translation.vector).norm()
                                * 1000.0,
                            last.pose.rotation.angle_to(&sp.pose.rotation).to_degrees(),
                        ),
                    ));
                }
                // Same timestamp twice: the TUM tools keep the later line.
                Some(last) if sp.t == last.t => *last = sp,
                _ => poses.push(sp),
            }
            prev_line = line.no;
            prev_values = v;
        }
        Ok(Self { poses })
    }

    /// The TUM text of this trajectory (one `timestamp tx ty tz qx qy qz qw` line per pose,
    /// no header).
    pub fn to_tum_string(&self) -> String {
        let mut s = String::with_capacity(self.poses.len() * 100);
        for p in &self.poses {
            let t = &p.pose.translation.vector;
            let q = &p.pose.rotation;
            let _ = writeln!(
                s,
                "{:.6} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
                p.t, t.x, t.y, t.z, q.i, q.j, q.k, q.w
            );
        }
        s
    }

    /// Writes the trajectory in TUM format, atomically. Fails (writing nothing) if a value is
    /// not finite or the timestamps decrease, so the file can always be read back.
    pub fn write_tum(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        self.check_writable(path)?;
        write_atomic(path, self.to_tum_string().as_bytes())
    }

    /// The KITTI text of this trajectory: per pose one line with the 3×4 matrix `[R | t]` of
    /// the camera-to-world transform, row-major, 9 decimals. Timestamps are not written.
    pub fn to_kitti_string(&self) -> String {
        let mut s = String::with_capacity(self.poses.len() * 150);
        for p in &self.poses {
            let m = p.pose.to_homogeneous();
            let mut first = true;
            for r in 0..3 {
                for c in 0..4 {
                    if !first {
                        s.push(' ');
                    }
                    first = false;
                    let _ = write!(s, "{:.9}", m[(r, c)]);
                }
            }
            s.push('\n');
        }
        s
    }

    /// Writes the trajectory in KITTI format (see [`Trajectory::to_kitti_string`]), atomically.
    pub fn write_kitti(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        self.check_writable(path)?;
        write_atomic(path, self.to_kitti_string().as_bytes())
    }

    fn check_writable(&self, path: &Path) -> Result<()> {
        let mut prev = f64::NEG_INFINITY;
        for (i, p) in self.poses.iter().enumerate() {
            let h = p.pose.to_homogeneous();
            if !p.t.is_finite() || h.iter().any(|v| !v.is_finite()) {
                return Err(IoError::invalid(
                    path,
                    format!("pose {i} (t = {}) has a non-finite value", p.t),
                ));
            }
            if p.t < prev {
                return Err(IoError::invalid(
                    path,
                    format!("pose {i}: timestamp {} is before the previous {prev}", p.t),
                ));
            }
            prev = p.t;
        }
        Ok(())
    }

    /// The pose at time `t`: translation interpolated linearly and rotation by SLERP between
    /// the two poses around `t`. `None` when `t` lies outside the trajectory, when those two
    /// poses are more than `max_gap` seconds apart (see [`DEFAULT_MAX_GAP`]). SLERP takes the
    /// shorter arc (`q` and `-q` are the same rotation). A pose exactly at `t` is returned as is.
    pub fn interpolate(&self, t: f64, max_gap: f64) -> Option<Se3> {
        if !t.is_finite() {
            return None;
        }
        let after = self.poses.partition_point(|p| p.t <= t);
        let a = self.poses.get(after.checked_sub(1)?)?;
        if a.t == t {
            return Some(a.pose);
        }
        let b = self.poses.get(after)?;
        let gap = b.t - a.t;
        if gap > max_gap {
            return None;
        }
        let s = (t - a.t) / gap;
        let trans = a
            .pose
            .translation
            .vector
            .lerp(&b.pose.translation.vector, s);
        // `try_slerp` only declines when the rotations are numerically identical.
        let rot = a
            .pose
            .rotation
            .try_slerp(&b.pose.rotation, s, 1e-12)
            .unwrap_or(a.pose.rotation);
        Some(Se3::from_parts(Translation3::from(trans), rot))
    }

    /// Reads a KITTI trajectory (12 values per line, row-major `[R | t]`). KITTI files carry
    /// no time, so pose `i` gets timestamp `i` (a frame index); rotations are re-orthonormalised.
    pub fn read_kitti(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = read_text(path)?;
        let mut poses = Vec::new();
        for line in data_lines(&text) {
            expect_columns(
                path,
                &line,
                12,
                "r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz",
            )?;
            let mut v = [0.0; 12];
            for (k, field) in line.fields.iter().enumerate() {
                v[k] = parse_f64(path, line.no, field, &format!("value {}", k + 1))?;
            }
            let m = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
            let det = m.determinant();
            if (det - 1.0).abs() > QUAT_NORM_TOL {
                return Err(IoError::parse(
                    path,
                    line.no,
                    format!("rotation part has determinant {det}, expected 1"),
                ));
            }
            let rot = Rotation3::from_matrix_eps(&m, 1e-12, 100, Rotation3::identity());
            let pose = Se3::from_parts(
                Translation3::new(v[3], v[7], v[11]),
                UnitQuaternion::from_rotation_matrix(&rot),
            );
            poses.push(StampedPose::new(poses.len() as f64, pose));
        }
        Ok(Self { poses })
    }
}

/// Tracking state of one frame, as recorded in a status file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FrameStatus {
    /// The frame has a pose.
    Tracked,
    /// Tracking was lost at this frame (no pose).
    Lost,
    /// The system was not initialised yet (no pose).
    NotInitialized,
}

impl FrameStatus {
    /// The word used in status files: `tracked`, `lost` or `not_initialized`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Tracked => "tracked",
            Self::Lost => "lost",
            Self::NotInitialized => "not_initialized",
        }
    }

    /// Parses a status word (also accepts the British `not_initialised`).
    pub fn from_word(word: &str) -> Option<Self> {
        match word {
            "tracked" => Some(Self::Tracked),
            "lost" => Some(Self::Lost),
            "not_initialized" | "not_initialised" => Some(Self::NotInitialized),
            _ => None,
        }
    }
}

impl std::fmt::Display for FrameStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The status of the frame at time `t` (one line `timestamp status` of a status file).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StampedStatus {
    /// Frame timestamp in seconds (written with 6 decimals, like trajectories).
    pub t: f64,
    /// Tracking state of the frame.
    pub status: FrameStatus,
}

/// Reads a status file: lines `timestamp status` with strictly increasing timestamps and
/// status `tracked`, `lost` or `not_initialized`; `#` comments allowed.
pub fn read_status(path: impl AsRef<Path>) -> Result<Vec<StampedStatus>> {
    let path = path.as_ref();
    parse_status(&read_text(path)?, path)
}

/// Parses status-file text; `path` is only used in error messages.
pub fn parse_status(text: &str, path: &Path) -> Result<Vec<StampedStatus>> {
    let mut out: Vec<StampedStatus> = Vec::new();
    for line in data_lines(text) {
        expect_columns(path, &line, 2, "timestamp status")?;
        let t = parse_f64(path, line.no, line.fields[0], "timestamp")?;
        let word = line.fields[1];
        let status = FrameStatus::from_word(word).ok_or_else(|| {
            IoError::parse(
                path,
                line.no,
                format!("status: expected tracked, lost or not_initialized, got `{word}`"),
            )
        })?;
        if let Some(last) = out.last()
            && t <= last.t
        {
            return Err(IoError::parse(
                path,
                line.no,
                format!(
                    "timestamps not strictly increasing: {} after {}",
                    line.fields[0], last.t
                ),
            ));
        }
        out.push(StampedStatus { t, status });
    }
    Ok(out)
}

/// The text of a status file, with a `#` header line naming the columns.
pub fn status_to_string(entries: &[StampedStatus]) -> String {
    let mut s = String::from("# timestamp status\n");
    for e in entries {
        let _ = writeln!(s, "{:.6} {}", e.t, e.status);
    }
    s
}

/// Writes a status file atomically (see [`status_to_string`]); timestamps must be finite and
/// strictly increasing (as the reader requires), else nothing is written.
pub fn write_status(path: impl AsRef<Path>, entries: &[StampedStatus]) -> Result<()> {
    let path = path.as_ref();
    let mut prev = f64::NEG_INFINITY;
    for (i, e) in entries.iter().enumerate() {
        if !e.t.is_finite() || e.t <= prev {
            return Err(IoError::invalid(
                path,
                format!(
                    "entry {i}: timestamp {} is not finite or not after {prev}",
                    e.t
                ),
            ));
        }
        prev = e.t;
    }
    write_atomic(path, status_to_string(entries).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    use crate::testutil::data_dir;

    fn pose(t: [f64; 3], axis_angle: [f64; 3]) -> Se3 {
        Se3::new(Vector3::from(t), Vector3::from(axis_angle))
    }

    fn sample() -> Trajectory {
        Trajectory::new(vec![
            StampedPose::new(1305031102.175304, pose([1.0, 2.0, 3.0], [0.1, 0.2, 0.3])),
            StampedPose::new(1305031102.211214, pose([-1.5, 0.25, 7.0], [-0.4, 0.0, 1.2])),
            StampedPose::new(1305031102.243211, pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])),
        ])
    }

    fn parse_err(text: &str) -> String {
        Trajectory::parse_tum(text, Path::new("traj.txt"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn tum_round_trip_keeps_timestamps_and_poses() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.txt");
        let traj = sample();
        traj.write_tum(&p).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.starts_with("1305031102.175304 1.000000000 2.000000000 3.000000000 "));
        let back = Trajectory::read_tum(&p).unwrap();
        assert_eq!(back.len(), 3);
        for (a, b) in traj.poses.iter().zip(&back.poses) {
            assert_eq!(format!("{:.6}", a.t), format!("{:.6}", b.t));
            assert!((a.pose.translation.vector - b.pose.translation.vector).norm() < 1e-8);
            assert!(a.pose.rotation.angle_to(&b.pose.rotation) < 1e-8);
        }
    }

    #[test]
    fn tum_accepts_comments_commas_tabs_and_crlf() {
        let text = "# header\n\n1.0,0,0,0,0,0,0,1\r\n  # indented comment\n2.0\t1 2 3\t0 0 0 1\n";
        let t = Trajectory::parse_tum(text, Path::new("x")).unwrap();
        assert_eq!(t.timestamps(), vec![1.0, 2.0]);
        assert_eq!(
            t.poses[1].pose.translation.vector,
            Vector3::new(1.0, 2.0, 3.0)
        );
    }

    #[test]
    fn tum_normalises_quaternion_and_keeps_later_duplicate() {
        let text = "1 0 0 0 0 0 0 1\n1 5 0 0 0 0 0.70711 0.70711\n";
        let t = Trajectory::parse_tum(text, Path::new("x")).unwrap();
        assert_eq!(t.len(), 1);
        assert_eq!(t.poses[0].pose.translation.x, 5.0);
        assert!((t.poses[0].pose.rotation.angle() - std::f64::consts::FRAC_PI_2).abs() < 1e-4);
        assert!((t.poses[0].pose.rotation.norm() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_strict_reader_refuses_a_timestamp_with_two_poses() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("est.txt");
        std::fs::write(
            &p,
            "# h\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n2 5 0 0 0 0 0 1\n3 0 0 0 0 0 0 1\n",
        )
        .unwrap();
        let e = Trajectory::read_tum_strict(&p).unwrap_err().to_string();
        assert!(
            e.contains("est.txt:4") && e.contains("line 3") && e.contains("timestamp 2"),
            "{e}"
        );
        // The lenient reader keeps the later line; the same pose twice is no conflict.
        assert_eq!(Trajectory::read_tum(&p).unwrap().len(), 3);
        std::fs::write(&p, "1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n2 1 0 0 0 0 0 1\n").unwrap();
        assert_eq!(Trajectory::read_tum_strict(&p).unwrap().len(), 2);
        // One sample written twice within its noise (as in TUM fr3 walking_static's ground
        // truth: 0.5 mm, 0.2°) keeps the later line; 6 mm apart is refused.
        std::fs::write(
            &p,
            "1 0 0 0 0 0 0 1\n1 0.0005 0 0 0.0017 0 0 0.9999985\n2 1 0 0 0 0 0 1\n",
        )
        .unwrap();
        let t = Trajectory::read_tum_strict(&p).unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!(t.poses[0].pose.translation.vector.x, 0.0005);
        std::fs::write(&p, "1 0 0 0 0 0 0 1\n1 0.006 0 0 0 0 0 1\n").unwrap();
        let e = Trajectory::read_tum_strict(&p).unwrap_err().to_string();
        assert!(e.contains("6.0 mm"), "{e}");
    }

    #[test]
    fn tum_bad_inputs_name_file_and_line() {
        let e = parse_err("# c\n1 0 0 0 0 0 0 1\n2 0 0 x 0 0 0 1\n");
        assert!(
            e.contains("traj.txt:3") && e.contains("tz") && e.contains("`x`"),
            "{e}"
        );
        let e = parse_err("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n");
        assert!(
            e.contains("traj.txt:2") && e.contains("expected 8 columns"),
            "{e}"
        );
        let e = parse_err("2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n");
        assert!(e.contains("traj.txt:2") && e.contains("not sorted"), "{e}");
        let e = parse_err("1 0 0 0 0 0 0 1\n2 NaN 0 0 0 0 0 1\n");
        assert!(e.contains("traj.txt:2") && e.contains("finite"), "{e}");
        let e = parse_err("1 0 0 0 0 0 0 0\n");
        assert!(e.contains("traj.txt:1") && e.contains("norm"), "{e}");
        let e = Trajectory::read_tum("/no/such/dir/gt.txt").unwrap_err();
        assert!(matches!(e, IoError::Io { .. }));
        assert!(e.to_string().contains("/no/such/dir/gt.txt"), "{e}");
    }

    #[test]
    fn write_rejects_non_finite_and_unsorted_and_writes_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.txt");
        let mut t = sample();
        t.poses[1].pose.translation.x = f64::NAN;
        let e = t.write_tum(&p).unwrap_err();
        assert!(e.to_string().contains("pose 1"), "{e}");
        let mut t = sample();
        t.poses.swap(0, 2);
        assert!(t.write_kitti(&p).is_err());
        assert!(!p.exists());
    }

    #[test]
    fn interpolation_is_slerp_with_max_gap() {
        let a = pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]);
        let b = pose([2.0, -4.0, 1.0], [0.0, 0.0, std::f64::consts::FRAC_PI_2]);
        let traj = Trajectory::new(vec![
            StampedPose::new(10.0, a),
            StampedPose::new(10.04, b),
            StampedPose::new(10.2, a),
        ]);
        let m = traj.interpolate(10.01, 0.05).unwrap();
        assert!((m.translation.vector - Vector3::new(0.5, -1.0, 0.25)).norm() < 1e-9);
        let expected = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::PI / 8.0);
        assert!(m.rotation.angle_to(&expected) < 1e-9);
        assert_eq!(traj.interpolate(10.04, 0.05), Some(b));
        assert_eq!(traj.interpolate(10.0, 0.05), Some(a));
        assert_eq!(traj.interpolate(10.2, 0.05), Some(a));
        // Gap of 0.16 s between the 2nd and 3rd pose.
        assert!(traj.interpolate(10.1, 0.05).is_none());
        assert!(traj.interpolate(10.1, 0.2).is_some());
        assert!(traj.interpolate(9.99, 0.05).is_none());
        assert!(traj.interpolate(10.21, 0.05).is_none());
        assert!(traj.interpolate(f64::NAN, 0.05).is_none());
        assert!(Trajectory::default().interpolate(1.0, 1.0).is_none());
    }

    #[test]
    fn interpolation_takes_the_short_arc_for_sign_flipped_quaternions() {
        let q1 = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.2);
        let q2 = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.4);
        let q2_neg = UnitQuaternion::new_unchecked(-q2.into_inner());
        let traj = Trajectory::new(vec![
            StampedPose::new(0.0, Se3::from_parts(Translation3::identity(), q1)),
            StampedPose::new(1.0, Se3::from_parts(Translation3::identity(), q2_neg)),
        ]);
        let m = traj.interpolate(0.5, 2.0).unwrap();
        let expected = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3);
        assert!(m.rotation.angle_to(&expected) < 1e-9);
    }

    #[test]
    fn kitti_round_trip_and_bad_input() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("k.txt");
        let traj = sample();
        traj.write_kitti(&p).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        let first: Vec<&str> = text.lines().next().unwrap().split(' ').collect();
        assert_eq!(first.len(), 12);
        assert_eq!(first[3], "1.000000000");
        assert_eq!(first[11], "3.000000000");
        let back = Trajectory::read_kitti(&p).unwrap();
        assert_eq!(back.timestamps(), vec![0.0, 1.0, 2.0]);
        for (a, b) in traj.poses.iter().zip(&back.poses) {
            assert!((a.pose.translation.vector - b.pose.translation.vector).norm() < 1e-8);
            assert!(a.pose.rotation.angle_to(&b.pose.rotation) < 1e-8);
        }
        std::fs::write(&p, "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n").unwrap();
        let e = Trajectory::read_kitti(&p).unwrap_err().to_string();
        assert!(e.contains("k.txt:2") && e.contains("12 columns"), "{e}");
        std::fs::write(&p, "2 0 0 0 0 1 0 0 0 0 1 0\n").unwrap();
        let e = Trajectory::read_kitti(&p).unwrap_err().to_string();
        assert!(e.contains("k.txt:1") && e.contains("determinant"), "{e}");
    }

    #[test]
    fn status_round_trip_and_bad_input() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("status.txt");
        let entries = vec![
            StampedStatus {
                t: 0.0,
                status: FrameStatus::NotInitialized,
            },
            StampedStatus {
                t: 1305031102.175304,
                status: FrameStatus::Tracked,
            },
            StampedStatus {
                t: 1305031102.211214,
                status: FrameStatus::Lost,
            },
        ];
        write_status(&p, &entries).unwrap();
        assert_eq!(read_status(&p).unwrap(), entries);
        let mut twice = entries.clone();
        twice[2].t = twice[1].t;
        assert!(write_status(&p, &twice).is_err());
        assert_eq!(
            read_status(&p).unwrap(),
            entries,
            "failed write left the file alone"
        );
        let bad = |text: &str| {
            parse_status(text, Path::new("st.txt"))
                .unwrap_err()
                .to_string()
        };
        let e = bad("1 tracked\n2 flying\n");
        assert!(e.contains("st.txt:2") && e.contains("flying"), "{e}");
        let e = bad("1 tracked\n1 lost\n");
        assert!(e.contains("st.txt:2") && e.contains("increasing"), "{e}");
        let e = bad("# x\n1 tracked extra\n");
        assert!(e.contains("st.txt:2") && e.contains("2 columns"), "{e}");
        let e = bad("abc tracked\n");
        assert!(e.contains("st.txt:1") && e.contains("timestamp"), "{e}");
        assert_eq!(
            parse_status("5 not_initialised\n", Path::new("x")).unwrap()[0].status,
            FrameStatus::NotInitialized
        );
    }

    #[test]
    fn real_ground_truth_files() {
        let Some(d) = data_dir() else { return };
        let gt =
            Trajectory::read_tum(d.join("tum/rgbd_dataset_freiburg1_xyz/groundtruth.txt")).unwrap();
        assert_eq!(gt.len(), 3000);
        assert_eq!(format!("{:.4}", gt.poses[0].t), "1305031098.6659");
        assert!((gt.poses[0].pose.translation.x - 1.3563).abs() < 1e-12);
        // walking_static has one repeated timestamp (1341846251.4587): 2484 lines, 2483 poses.
        let ws = d.join("tum-walking-meta/rgbd_dataset_freiburg3_walking_static/groundtruth.txt");
        let ws = Trajectory::read_tum(ws).unwrap();
        assert_eq!(ws.len(), 2483);
        assert!(ws.poses.windows(2).all(|w| w[0].t < w[1].t));
        // DynaSLAM output (fixed 6/9 decimals): our writer reproduces the timestamp and
        // translation text exactly; quaternions differ only by the normalisation on reading.
        let est = d.join(
            "reference-trajectories/dynaslam_rerun_yubaoliu/fr3_walk_xyz_CameraTrajectory.txt",
        );
        let text = std::fs::read_to_string(&est).unwrap();
        let traj = Trajectory::read_tum(&est).unwrap();
        assert_eq!(traj.len(), 757);
        let ours = traj.to_tum_string();
        assert_eq!(ours.lines().count(), 757);
        for (a, b) in ours.lines().zip(text.lines()) {
            let fa: Vec<&str> = a.split(' ').collect();
            let fb: Vec<&str> = b.split(' ').collect();
            assert_eq!(fa[..4], fb[..4]);
            for k in 4..8 {
                let (x, y): (f64, f64) = (fa[k].parse().unwrap(), fb[k].parse().unwrap());
                assert!((x - y).abs() < 1e-6, "{a} vs {b}");
            }
        }
    }
}
