//! Ground truth as camera poses. TUM RGB-D and dynapix's own sequences store the
//! camera-to-world pose in `groundtruth.txt`; the Bonn RGB-D Dynamic Dataset stores the pose
//! `T` of the motion-capture **marker body** in the motion-capture world. The dataset's own
//! tools map it to the camera pose as
//!
//! `C = T_ros · T · T_ros · T_m`
//!
//! with `T_ros` (a 180° rotation about (0, 1, 1)/√2, its own inverse) re-expressing the
//! motion-capture world and `T_ros · T_m` the fixed marker-to-camera offset. The 3×3 block of
//! the published `T_m` is not orthonormal (it is close to a rotation scaled by 1.06); it is
//! projected onto the nearest rotation (SVD) so that `C` stays a rigid transform.
//!
//! Which convention a file follows is told by the dataset of the folder it really lives in
//! ([`crate::datasets::Dataset`]): the file `groundtruth.txt` of a `rgbd_bonn_*` folder holds
//! marker poses, every other ground-truth file camera poses. Callers that need camera poses
//! (splatting with ground-truth poses, evaluation, RPE) use [`camera_trajectory`] or
//! [`read_ground_truth`]; [`crate::Sequence`] converts on opening. Published Bonn results
//! are computed against the raw file, so [`GtFrame::Raw`] keeps it as it is.

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use dynapix_geometry::{Se3, se3};
use nalgebra::Matrix4;

use crate::datasets::Dataset;
use crate::error::Result;
use crate::trajectory::{StampedPose, Trajectory};

/// File name of the ground truth inside a sequence folder.
pub const GROUNDTRUTH_FILE: &str = "groundtruth.txt";

/// `T_ros` of the Bonn dataset tools, row-major.
pub const BONN_T_ROS: [[f64; 4]; 4] = [
    [-1.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// `T_m` of the Bonn dataset tools (marker-to-camera calibration), row-major, as published
/// (its 3×3 block is not exactly a rotation; see the module doc).
pub const BONN_T_M: [[f64; 4]; 4] = [
    [1.0157, 0.1828, -0.2389, 0.0113],
    [0.0009, -0.8431, -0.6413, -0.0098],
    [-0.3009, 0.6147, -0.8085, 0.0111],
    [0.0, 0.0, 0.0, 1.0],
];

/// Which frame a caller wants ground-truth poses in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum GtFrame {
    /// Camera-to-world poses of the colour camera (converted when the file holds marker
    /// poses).
    #[default]
    Camera,
    /// The file as it is (for Bonn: marker-body poses, what published Bonn numbers use).
    Raw,
}

impl GtFrame {
    /// `"camera"` or `"raw"`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Camera => "camera",
            Self::Raw => "raw",
        }
    }
}

impl fmt::Display for GtFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for GtFrame {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "camera" => Ok(Self::Camera),
            "raw" => Ok(Self::Raw),
            _ => Err(format!(
                "unknown ground-truth frame {s:?} (expected camera or raw)"
            )),
        }
    }
}

/// What the poses of a ground-truth file are.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum GroundTruthConvention {
    /// Camera-to-world poses (TUM RGB-D, dynapix synthetic sequences, GRADE).
    #[default]
    Camera,
    /// Bonn RGB-D Dynamic: poses of the motion-capture marker body, converted to the camera by
    /// [`bonn_marker_to_camera`].
    BonnMarker,
}

impl GroundTruthConvention {
    /// The convention of a ground-truth file: [`Self::BonnMarker`] for the `groundtruth.txt`
    /// of a `rgbd_bonn_*` folder (symbolic links resolved), [`Self::Camera`] otherwise.
    pub fn of_file(path: &Path) -> Self {
        let is_gt_file = path.file_name().is_some_and(|n| n == GROUNDTRUTH_FILE);
        match Dataset::of_file(path) {
            Some(Dataset::Bonn) if is_gt_file => Self::BonnMarker,
            _ => Self::Camera,
        }
    }

    /// True when the poses are not camera poses and need [`Self::to_camera`].
    pub fn needs_conversion(self) -> bool {
        self != Self::Camera
    }

    /// The camera-to-world pose of one ground-truth pose.
    pub fn to_camera(self, pose: &Se3) -> Se3 {
        match self {
            Self::Camera => *pose,
            Self::BonnMarker => bonn_marker_to_camera(pose),
        }
    }

    /// The trajectory in `frame`: converted pose by pose for [`GtFrame::Camera`], unchanged
    /// for [`GtFrame::Raw`].
    pub fn trajectory_in(self, raw: Trajectory, frame: GtFrame) -> Trajectory {
        if frame == GtFrame::Raw || !self.needs_conversion() {
            return raw;
        }
        Trajectory::new(
            raw.poses
                .into_iter()
                .map(|p| StampedPose::new(p.t, self.to_camera(&p.pose)))
                .collect(),
        )
    }

    /// `"camera"` or `"bonn-marker"`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Camera => "camera",
            Self::BonnMarker => "bonn-marker",
        }
    }
}

/// A 4×4 matrix from its rows.
fn from_rows(rows: &[[f64; 4]; 4]) -> Matrix4<f64> {
    Matrix4::from_fn(|r, c| rows[r][c])
}

/// `T_ros` as a rigid transform (a proper rotation: determinant +1, its own inverse).
pub fn bonn_t_ros() -> Se3 {
    // An exact rotation: the projection in `from_matrix` returns it unchanged.
    se3::from_matrix(&from_rows(&BONN_T_ROS)).unwrap_or_else(Se3::identity)
}

/// `T_m` with its 3×3 block projected onto the nearest rotation (SVD).
pub fn bonn_t_m() -> Se3 {
    // The published block is a rotation scaled by about 1.06 (positive determinant), so the
    // projection exists; the tests check it.
    se3::from_matrix(&from_rows(&BONN_T_M)).unwrap_or_else(Se3::identity)
}

/// The camera pose of a Bonn marker pose `T`: `T_ros · T · T_ros · T_m`.
pub fn bonn_marker_to_camera(marker: &Se3) -> Se3 {
    let ros = bonn_t_ros();
    ros * marker * ros * bonn_t_m()
}

/// A ground-truth trajectory with the frame it is in.
#[derive(Clone, Debug, PartialEq)]
pub struct GroundTruth {
    /// The poses, in [`Self::frame`].
    pub trajectory: Trajectory,
    /// What the file holds.
    pub convention: GroundTruthConvention,
    /// The frame the poses were asked in.
    pub frame: GtFrame,
}

impl GroundTruth {
    /// True when the poses were converted from the file's (marker) poses.
    pub fn converted(&self) -> bool {
        self.frame == GtFrame::Camera && self.convention.needs_conversion()
    }

    /// One line saying which poses these are, for reports.
    pub fn description(&self) -> &'static str {
        match (self.frame, self.convention) {
            (GtFrame::Camera, GroundTruthConvention::Camera) => {
                "camera poses (the file holds camera-to-world poses)"
            }
            (GtFrame::Camera, GroundTruthConvention::BonnMarker) => {
                "camera poses (Bonn marker poses converted: T_ros·T·T_ros·T_m)"
            }
            (GtFrame::Raw, GroundTruthConvention::Camera) => {
                "raw file (it holds camera-to-world poses)"
            }
            (GtFrame::Raw, GroundTruthConvention::BonnMarker) => {
                "raw file: Bonn marker-body poses, not the camera (as published Bonn results)"
            }
        }
    }
}

/// Reads a TUM-format ground-truth file in `frame`, deciding its convention with
/// [`GroundTruthConvention::of_file`]: the one ground-truth reader (sequences, evaluation,
/// pose sources). It is strict ([`Trajectory::read_tum_strict`]): a timestamp given twice
/// with poses further apart than one sample's noise is an error naming both lines, since
/// either pose would change a score; closer duplicates keep the later line.
pub fn read_ground_truth(path: impl AsRef<Path>, frame: GtFrame) -> Result<GroundTruth> {
    let path = path.as_ref();
    let convention = GroundTruthConvention::of_file(path);
    let raw = Trajectory::read_tum_strict(path)?;
    Ok(GroundTruth {
        trajectory: convention.trajectory_in(raw, frame),
        convention,
        frame,
    })
}

/// The camera-to-world trajectory of a ground-truth file (Bonn marker poses converted).
/// Use this wherever ground truth stands for the camera: poses for splatting, evaluation.
pub fn camera_trajectory(path: impl AsRef<Path>) -> Result<Trajectory> {
    Ok(read_ground_truth(path, GtFrame::Camera)?.trajectory)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, UnitQuaternion, Vector3};

    use crate::testutil::data_dir;

    #[test]
    fn t_ros_is_a_self_inverse_rotation_and_t_m_is_projected() {
        let ros = bonn_t_ros();
        assert!((ros.to_homogeneous() - from_rows(&BONN_T_ROS)).norm() < 1e-12);
        assert!(((ros * ros).to_homogeneous() - Matrix4::identity()).norm() < 1e-12);
        let m = bonn_t_m();
        let r = m.rotation.to_rotation_matrix();
        assert!((r.matrix().determinant() - 1.0).abs() < 1e-12);
        assert!(
            (r.matrix() * r.matrix().transpose() - nalgebra::Matrix3::identity()).norm() < 1e-12
        );
        assert_eq!(m.translation.vector, Vector3::new(0.0113, -0.0098, 0.0111));
        // The published block is that rotation scaled by about 1.06.
        let published = from_rows(&BONN_T_M);
        let block = published.fixed_view::<3, 3>(0, 0).into_owned();
        let scale = block.determinant().cbrt();
        assert!((scale - 1.06).abs() < 0.01, "{scale}");
        let off = (block / scale - r.matrix()).norm();
        assert!(off < 0.01, "{off}");
    }

    #[test]
    fn conversion_is_the_published_formula() {
        // C = T_ros·T·T_ros·T_m with matrices, against the composition of rigid transforms.
        let t = se3::exp(&nalgebra::Vector6::new(0.3, -0.2, 0.5, 1.0, -2.0, 0.7));
        let ros = from_rows(&BONN_T_ROS);
        let expect = ros * t.to_homogeneous() * ros * bonn_t_m().to_homogeneous();
        let got = bonn_marker_to_camera(&t).to_homogeneous();
        assert!((got - expect).norm() < 1e-12);
        // Camera convention and the raw frame leave poses alone.
        assert_eq!(GroundTruthConvention::Camera.to_camera(&t), t);
        let tr = Trajectory::new(vec![StampedPose::new(1.0, t)]);
        assert_eq!(
            GroundTruthConvention::BonnMarker.trajectory_in(tr.clone(), GtFrame::Raw),
            tr
        );
        assert_eq!("RAW".parse::<GtFrame>(), Ok(GtFrame::Raw));
        assert!("marker".parse::<GtFrame>().is_err());
    }

    #[test]
    fn relative_motion_of_the_camera_is_a_conjugate_of_the_markers() {
        // Between two marker poses A and B, the camera moves by (T_ros T_m)⁻¹ A⁻¹B (T_ros T_m):
        // same rotation angle, and the conversion is invertible pose by pose.
        let a = se3::exp(&nalgebra::Vector6::new(0.1, 0.2, -0.3, 0.5, 0.1, 1.2));
        let b = se3::exp(&nalgebra::Vector6::new(0.15, 0.1, -0.2, 0.6, 0.0, 1.1));
        let (ca, cb) = (bonn_marker_to_camera(&a), bonn_marker_to_camera(&b));
        let rel_m = a.inverse() * b;
        let rel_c = ca.inverse() * cb;
        assert!((rel_m.rotation.angle() - rel_c.rotation.angle()).abs() < 1e-12);
        let p = Point3::new(0.2, -0.1, 1.5);
        let off = bonn_t_ros() * bonn_t_m();
        assert!(((off.inverse() * rel_m * off) * p - rel_c * p).norm() < 1e-12);
    }

    #[test]
    fn convention_follows_the_folder_and_the_file_name() {
        let root = tempfile::tempdir().unwrap();
        let bonn = root.path().join("rgbd_bonn_balloon");
        let tum = root.path().join("rgbd_dataset_freiburg3_walking_xyz");
        let mine = root.path().join("my_sequence");
        let line = "1.0 0.5 -0.2 1.0 0.1 0.2 0.3 0.927362\n";
        for d in [&bonn, &tum, &mine] {
            std::fs::create_dir(d).unwrap();
            std::fs::write(d.join(GROUNDTRUTH_FILE), line).unwrap();
        }
        std::fs::write(bonn.join("camera_poses.txt"), line).unwrap();
        let conv = |d: &Path| GroundTruthConvention::of_file(&d.join(GROUNDTRUTH_FILE));
        assert_eq!(conv(&bonn), GroundTruthConvention::BonnMarker);
        assert_eq!(conv(&tum), GroundTruthConvention::Camera);
        assert_eq!(conv(&mine), GroundTruthConvention::Camera);
        assert_eq!(
            GroundTruthConvention::of_file(&bonn.join("camera_poses.txt")),
            GroundTruthConvention::Camera,
            "only the dataset's own groundtruth.txt holds marker poses"
        );
        let raw = read_ground_truth(bonn.join(GROUNDTRUTH_FILE), GtFrame::Raw).unwrap();
        let cam = read_ground_truth(bonn.join(GROUNDTRUTH_FILE), GtFrame::Camera).unwrap();
        assert!(!raw.converted() && cam.converted());
        assert!(cam.description().contains("converted"));
        assert!(raw.description().contains("marker"));
        let marker = raw.trajectory.poses[0].pose;
        let camera = cam.trajectory.poses[0].pose;
        assert_eq!(camera, bonn_marker_to_camera(&marker));
        assert_eq!(
            camera_trajectory(tum.join(GROUNDTRUTH_FILE)).unwrap().poses[0].pose,
            marker,
            "TUM poses are already camera poses"
        );
        #[cfg(unix)]
        {
            // Through a link (dynapix run's cache folders), the real folder decides.
            let shadow = root.path().join("shadow");
            std::fs::create_dir(&shadow).unwrap();
            std::os::unix::fs::symlink(bonn.join(GROUNDTRUTH_FILE), shadow.join(GROUNDTRUTH_FILE))
                .unwrap();
            assert_eq!(conv(&shadow), GroundTruthConvention::BonnMarker);
        }
        let e = read_ground_truth(root.path().join("none.txt"), GtFrame::Camera).unwrap_err();
        assert!(e.to_string().contains("none.txt"), "{e}");
    }

    /// The one reader is strict: a sequence whose ground truth gives one timestamp two poses
    /// far apart does not open (the message names both lines), one sample written twice
    /// within its noise keeps the later line, in the reader and in the sequence alike.
    #[test]
    fn ground_truth_duplicates_are_refused_unless_within_noise_everywhere() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path();
        std::fs::create_dir(dir.join("rgb")).unwrap();
        std::fs::create_dir(dir.join("depth")).unwrap();
        let mut assoc = String::new();
        for k in 0..3 {
            let t = 1.0 + k as f64 * 0.1;
            image::GrayImage::new(4, 4)
                .save(dir.join(format!("rgb/{k}.png")))
                .unwrap();
            image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(4, 4)
                .save(dir.join(format!("depth/{k}.png")))
                .unwrap();
            assoc.push_str(&format!("{t:.6} rgb/{k}.png {t:.6} depth/{k}.png\n"));
        }
        std::fs::write(dir.join("association.txt"), assoc).unwrap();
        let gt = |second_x: f64| {
            format!(
                "1.0 0 0 0 0 0 0 1\n1.1 0.1 0 0 0 0 0 1\n1.1 {second_x} 0 0 0 0 0 1\n1.2 0.2 0 0 0 0 0 1\n"
            )
        };
        let path = dir.join(GROUNDTRUTH_FILE);
        // 0.5 mm apart: one sample, the later line kept.
        std::fs::write(&path, gt(0.1005)).unwrap();
        let read = read_ground_truth(&path, GtFrame::Camera).unwrap();
        assert_eq!(read.trajectory.len(), 3);
        assert_eq!(read.trajectory.poses[1].pose.translation.x, 0.1005);
        let seq = crate::Sequence::open(dir).unwrap();
        assert_eq!(seq.groundtruth.as_ref(), Some(&read.trajectory));
        // 5 cm apart: refused by both, naming the lines.
        std::fs::write(&path, gt(0.15)).unwrap();
        let e = read_ground_truth(&path, GtFrame::Camera)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("groundtruth.txt:3") && e.contains("line 2"),
            "{e}"
        );
        let e = crate::Sequence::open(dir).unwrap_err().to_string();
        assert!(
            e.contains("groundtruth.txt:3") && e.contains("line 2"),
            "{e}"
        );
    }

    /// The first pose of the Bonn `crowd` ground truth against the camera pose computed
    /// independently (numpy, same formula, SVD projection of `T_m`).
    #[test]
    fn real_bonn_first_pose_matches_an_independent_computation() {
        let Some(d) = data_dir() else { return };
        let path = d.join("bonn/rgbd_bonn_crowd").join(GROUNDTRUTH_FILE);
        let gt = read_ground_truth(&path, GtFrame::Camera).unwrap();
        assert_eq!(gt.convention, GroundTruthConvention::BonnMarker);
        let first = gt.trajectory.poses[0];
        assert_eq!(format!("{:.6}", first.t), "1548339819.894270");
        let t = first.pose.translation.vector;
        let expect_t = Vector3::new(0.206865, 1.455774, -1.443427);
        assert!((t - expect_t).norm() < 2e-6, "{t:?}");
        let q = first.pose.rotation;
        let expect_q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            0.126501, 0.921095, 0.055406, -0.364020,
        ));
        assert!(q.angle_to(&expect_q) < 1e-5, "{:?}", q.coords);
    }
}
