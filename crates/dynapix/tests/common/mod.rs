//! Helpers shared by the integration tests of this crate.

use std::path::Path;

use dynapix::Trajectory;

/// Copies the folder `src` into `dst`, recursively.
pub fn copy_dir(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        let to = dst.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to);
        } else {
            std::fs::copy(e.path(), to).unwrap();
        }
    }
}

/// ATE RMSE of `traj` against the sequence's `groundtruth.txt`.
pub fn ate(seq: &Path, traj: &Trajectory) -> f64 {
    let gt = dynapix_eval::files::read_trajectory(&seq.join("groundtruth.txt")).unwrap();
    let est: Vec<_> = traj.poses.iter().map(|p| (p.t, p.pose)).collect();
    let ev = dynapix_eval::evaluate(&gt, &est, None, &dynapix_eval::EvalParams::default()).unwrap();
    ev.ate.stats.rmse
}
