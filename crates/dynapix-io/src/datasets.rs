//! Which public dataset a sequence folder comes from, told by the folder name the dataset
//! ships it under: TUM RGB-D `rgbd_dataset_freiburgN_*` (N = 1, 2, 3) and the Bonn RGB-D
//! Dynamic Dataset `rgbd_bonn_*`. The dataset decides the camera preset when the folder has
//! no `camera.yaml` ([`crate::settings::Settings::for_sequence_dir`]) and how its
//! `groundtruth.txt` is read ([`crate::ground_truth`]).
//!
//! A folder whose own name says nothing may still hold a dataset's files through symbolic
//! links (`dynapix run` links a sequence's files into a cache folder before it computes
//! motion maps there): then the folder that its list and ground-truth files really live in
//! is asked.

use std::path::Path;

/// Association file names looked for, in this order (TUM tools, DynaSLAM, DynaPix, GRADE).
pub const ASSOCIATION_FILES: [&str; 4] = [
    "association.txt",
    "associations.txt",
    "rgbd_assoc.txt",
    "assoc.txt",
];

/// Folder-name prefix of the TUM RGB-D sequences (`rgbd_dataset_freiburg1_xyz`, …).
pub const TUM_PREFIX: &str = "rgbd_dataset_freiburg";

/// Folder-name prefix of the Bonn RGB-D Dynamic sequences (`rgbd_bonn_crowd`, …).
pub const BONN_PREFIX: &str = "rgbd_bonn_";

/// A public RGB-D dataset dynapix knows the camera and ground-truth convention of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dataset {
    /// TUM RGB-D, Kinect `freiburg` 1, 2 or 3: ground truth is the camera pose.
    Tum {
        /// The Kinect number N of `rgbd_dataset_freiburgN_*` (1, 2 or 3).
        freiburg: u8,
    },
    /// Bonn RGB-D Dynamic: ground truth is the pose of the motion-capture marker body.
    Bonn,
}

impl Dataset {
    /// The dataset implied by a folder name, `None` for any other name.
    pub fn from_folder_name(name: &str) -> Option<Self> {
        if let Some(rest) = name.strip_prefix(TUM_PREFIX) {
            let (n, tail) = rest.split_at_checked(1)?;
            let freiburg = match n {
                "1" => 1,
                "2" => 2,
                "3" => 3,
                _ => return None,
            };
            return tail.starts_with('_').then_some(Self::Tum { freiburg });
        }
        // `rgbd_bonn_` alone names no sequence.
        let rest = name.strip_prefix(BONN_PREFIX)?;
        (!rest.is_empty()).then_some(Self::Bonn)
    }

    /// The dataset of the folder that `path` really lives in (symbolic links resolved); `None`
    /// when the path cannot be resolved or its folder has no dataset name.
    pub fn of_file(path: &Path) -> Option<Self> {
        let resolved = std::fs::canonicalize(path).ok()?;
        let name = resolved.parent()?.file_name()?.to_str()?;
        Self::from_folder_name(name)
    }

    /// The dataset of a sequence folder: its own name (`.` and `..` resolved), else the folder
    /// its `rgb.txt`, `depth.txt`, association file or `groundtruth.txt` links to.
    pub fn of_dir(dir: &Path) -> Option<Self> {
        let own = std::fs::canonicalize(dir)
            .ok()
            .and_then(|d| d.file_name()?.to_str().and_then(Self::from_folder_name));
        if own.is_some() {
            return own;
        }
        ["rgb.txt", "depth.txt", "groundtruth.txt"]
            .into_iter()
            .chain(ASSOCIATION_FILES)
            .map(|f| dir.join(f))
            .filter(|p| p.is_file())
            .find_map(|p| Self::of_file(&p))
    }

    /// The camera preset of the dataset ([`crate::settings::Settings::preset`]).
    pub fn preset_name(self) -> &'static str {
        match self {
            Self::Tum { freiburg: 1 } => "tum1",
            Self::Tum { freiburg: 2 } => "tum2",
            Self::Tum { .. } => "tum3",
            Self::Bonn => "bonn",
        }
    }

    /// A human-readable name (`TUM RGB-D fr1`, `Bonn RGB-D Dynamic`).
    pub fn label(self) -> String {
        match self {
            Self::Tum { freiburg } => format!("TUM RGB-D fr{freiburg}"),
            Self::Bonn => "Bonn RGB-D Dynamic".to_string(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folder_names() {
        assert_eq!(
            Dataset::from_folder_name("rgbd_dataset_freiburg3_walking_xyz"),
            Some(Dataset::Tum { freiburg: 3 })
        );
        assert_eq!(
            Dataset::from_folder_name("rgbd_bonn_crowd"),
            Some(Dataset::Bonn)
        );
        assert_eq!(
            Dataset::from_folder_name("rgbd_bonn_person_tracking2"),
            Some(Dataset::Bonn)
        );
        for other in [
            "rgbd_bonn_",
            "rgbd_bonn",
            "bonn_crowd",
            "rgbd_dataset_freiburg4_x",
            "rgbd_dataset_freiburg1xyz",
            "rgbd_dataset_freiburg",
            "my_sequence",
            "",
        ] {
            assert_eq!(Dataset::from_folder_name(other), None, "{other}");
        }
        assert_eq!(Dataset::Bonn.preset_name(), "bonn");
        assert_eq!(Dataset::Tum { freiburg: 2 }.preset_name(), "tum2");
        assert_eq!(Dataset::Tum { freiburg: 1 }.label(), "TUM RGB-D fr1");
    }

    #[cfg(unix)]
    #[test]
    fn a_folder_of_links_is_told_by_where_its_files_live() {
        let root = tempfile::tempdir().unwrap();
        let bonn = root.path().join("rgbd_bonn_walk");
        std::fs::create_dir(&bonn).unwrap();
        std::fs::write(bonn.join("rgb.txt"), "").unwrap();
        assert_eq!(Dataset::of_dir(&bonn), Some(Dataset::Bonn));
        assert_eq!(Dataset::of_dir(&bonn.join(".")), Some(Dataset::Bonn));
        let shadow = root.path().join("cache").join("gt-full");
        std::fs::create_dir_all(&shadow).unwrap();
        assert_eq!(Dataset::of_dir(&shadow), None);
        std::os::unix::fs::symlink(bonn.join("rgb.txt"), shadow.join("rgb.txt")).unwrap();
        assert_eq!(Dataset::of_dir(&shadow), Some(Dataset::Bonn));
        assert_eq!(
            Dataset::of_file(&shadow.join("rgb.txt")),
            Some(Dataset::Bonn)
        );
        assert_eq!(Dataset::of_file(&shadow.join("missing.txt")), None);
    }
}
