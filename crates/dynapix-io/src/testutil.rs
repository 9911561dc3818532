//! Helpers shared by the unit tests of this crate.

use std::path::PathBuf;

/// `../shared/data` beside the repository, or `None` with a skip message when it is missing.
pub(crate) fn data_dir() -> Option<PathBuf> {
    let d = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data"));
    if d.is_dir() {
        Some(d)
    } else {
        eprintln!("skipped real-data part: {} not found", d.display());
        None
    }
}
