//! A command's output folder, replaced as a whole (design.md §3: a run never leaves a
//! half-written result).
//!
//! A run writes its result set into a staging folder beside the target (`OUT.tmp-<pid>`), then
//! [`OutputFolder::commit`] swaps it in: the old folder is renamed away (`OUT.old-<pid>`), the
//! new one renamed into place, the old one removed. A reader therefore sees the earlier result
//! set or the new one, never a mix, and a finished run leaves no file of an earlier one. Both
//! renames stay in one parent folder, so they never cross a file system. Staging and old
//! folders left by interrupted runs are removed when the next run on the same target begins.
//!
//! Because the target is replaced, [`check_output_folder`] refuses up front a target that
//! holds anything but an earlier result (a folder without any of the caller's marker files),
//! so a mistyped `--out` never deletes a user's folder.

use std::fs;
use std::path::{Path, PathBuf};

use crate::error::{IoError, Result};

/// Suffix of staging folders: `OUT.tmp-<pid>`.
const STAGING: &str = ".tmp-";
/// Suffix of replaced folders awaiting removal: `OUT.old-<pid>`.
const OLD: &str = ".old-";

/// Checks that files can be created in `dir` (created with its parents when missing) by
/// creating and removing a probe file. Errors name the folder.
pub fn check_writable_dir(dir: &Path) -> Result<()> {
    let shown = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    fs::create_dir_all(shown)
        .map_err(|e| IoError::invalid(shown, format!("cannot create the folder: {e}")))?;
    let probe = shown.join(format!(".dynapix-probe-{}", std::process::id()));
    fs::write(&probe, b"")
        .map_err(|e| IoError::invalid(shown, format!("cannot write into the folder: {e}")))?;
    fs::remove_file(&probe).map_err(|e| IoError::io(&probe, e))?;
    Ok(())
}

/// The folder that holds `out`, and `out`'s file name.
fn split(out: &Path) -> Result<(PathBuf, std::ffi::OsString)> {
    let name = out
        .file_name()
        .ok_or_else(|| {
            IoError::invalid(out, "an output folder needs a name (not `.`, `..` or `/`)")
        })?
        .to_os_string();
    let parent = out.parent().map(Path::to_path_buf).unwrap_or_default();
    Ok((parent, name))
}

/// Checks, before any work, that `out` can be (re)made as a whole: its parent folder is
/// writable (created when missing), and `out` is absent, empty, or an earlier result set,
/// i.e. a folder that holds at least one of `markers` (e.g. `run.json`). Anything else is
/// refused with an error naming the path: the folder would be replaced.
pub fn check_output_folder(out: &Path, markers: &[&str]) -> Result<()> {
    let (parent, _) = split(out)?;
    check_writable_dir(&parent)?;
    match fs::symlink_metadata(out) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(IoError::io(out, e)),
        Ok(m) if !m.is_dir() => Err(IoError::invalid(
            out,
            "exists and is not a folder; give a folder for the results",
        )),
        Ok(_) => {
            let mut entries = fs::read_dir(out).map_err(|e| IoError::io(out, e))?;
            let empty = entries.next().is_none();
            if empty || markers.iter().any(|m| out.join(m).exists()) {
                Ok(())
            } else {
                Err(IoError::invalid(
                    out,
                    format!(
                        "exists and holds no earlier result (none of {}); a run replaces its \
                         output folder as a whole, so give a new or empty folder",
                        markers.join(", ")
                    ),
                ))
            }
        }
    }
}

/// A result set being written into a staging folder, to replace the target folder on
/// [`OutputFolder::commit`]. Dropped without a commit (a panic), the staging folder is removed
/// and the target is untouched.
#[derive(Debug)]
pub struct OutputFolder {
    target: PathBuf,
    staging: PathBuf,
    committed: bool,
}

impl OutputFolder {
    /// Checks `out` ([`check_output_folder`] with `markers`), removes staging and replaced
    /// folders of earlier interrupted runs on it, and creates an empty staging folder beside it.
    pub fn begin(out: &Path, markers: &[&str]) -> Result<Self> {
        check_output_folder(out, markers)?;
        let (parent, name) = split(out)?;
        let listed = if parent.as_os_str().is_empty() {
            Path::new(".")
        } else {
            parent.as_path()
        };
        let name = name.to_string_lossy().into_owned();
        for e in fs::read_dir(listed).map_err(|e| IoError::io(listed, e))? {
            let e = e.map_err(|e| IoError::io(listed, e))?;
            let file = e.file_name().to_string_lossy().into_owned();
            let leftover = [STAGING, OLD].iter().any(|s| {
                file.strip_prefix(&name)
                    .and_then(|rest| rest.strip_prefix(s))
                    .is_some_and(|pid| !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()))
            });
            if leftover {
                remove_dir_or_file(&e.path())?;
            }
        }
        let staging = parent.join(format!("{name}{STAGING}{}", std::process::id()));
        fs::create_dir(&staging).map_err(|e| IoError::io(&staging, e))?;
        Ok(Self {
            target: out.to_path_buf(),
            staging,
            committed: false,
        })
    }

    /// Where the result set is written until [`OutputFolder::commit`].
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// The folder the result set will replace.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Swaps the staging folder in for the target: the old folder is renamed away, the new one
    /// renamed into place, the old one removed. Returns the target.
    pub fn commit(mut self) -> Result<PathBuf> {
        let (parent, name) = split(&self.target)?;
        let mut old_name = name.clone();
        old_name.push(format!("{OLD}{}", std::process::id()));
        let old = parent.join(old_name);
        let had_old = match fs::symlink_metadata(&self.target) {
            Ok(_) => {
                fs::rename(&self.target, &old).map_err(|e| IoError::io(&self.target, e))?;
                true
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => false,
            Err(e) => return Err(IoError::io(&self.target, e)),
        };
        if let Err(e) = fs::rename(&self.staging, &self.target) {
            if had_old {
                // Put the earlier result back rather than leave nothing.
                let _ = fs::rename(&old, &self.target);
            }
            return Err(IoError::io(&self.target, e));
        }
        self.committed = true;
        if had_old {
            remove_dir_or_file(&old)?;
        }
        Ok(self.target.clone())
    }
}

impl Drop for OutputFolder {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.staging);
        }
    }
}

fn remove_dir_or_file(p: &Path) -> Result<()> {
    let r = match fs::symlink_metadata(p) {
        Ok(m) if m.is_dir() => fs::remove_dir_all(p),
        Ok(_) => fs::remove_file(p),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(e),
    };
    r.map_err(|e| IoError::io(p, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    const MARKERS: &[&str] = &["run.json"];

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_run_replaces_the_folder_as_a_whole() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        let f = OutputFolder::begin(&out, MARKERS).unwrap();
        fs::write(f.path().join("run.json"), "1").unwrap();
        fs::write(f.path().join("stale.txt"), "x").unwrap();
        assert!(!out.exists(), "nothing appears before the commit");
        f.commit().unwrap();
        assert_eq!(names(&out), ["run.json", "stale.txt"]);
        // A second run: the earlier files are gone, the new set is in place.
        let f = OutputFolder::begin(&out, MARKERS).unwrap();
        fs::write(f.path().join("run.json"), "2").unwrap();
        assert_eq!(fs::read_to_string(out.join("run.json")).unwrap(), "1");
        f.commit().unwrap();
        assert_eq!(names(&out), ["run.json"]);
        assert_eq!(fs::read_to_string(out.join("run.json")).unwrap(), "2");
        assert_eq!(names(tmp.path()), ["out"], "no staging or old folder left");
    }

    #[test]
    fn leftovers_are_removed_and_an_uncommitted_run_changes_nothing() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        fs::create_dir(&out).unwrap();
        fs::write(out.join("run.json"), "old").unwrap();
        for leftover in ["out.tmp-12345", "out.old-77"] {
            fs::create_dir(tmp.path().join(leftover)).unwrap();
        }
        // Not leftovers of this folder.
        fs::create_dir(tmp.path().join("out.tmp-x")).unwrap();
        fs::create_dir(tmp.path().join("outer.tmp-1")).unwrap();
        let f = OutputFolder::begin(&out, MARKERS).unwrap();
        fs::write(f.path().join("half.txt"), "x").unwrap();
        drop(f);
        assert_eq!(names(tmp.path()), ["out", "out.tmp-x", "outer.tmp-1"]);
        assert_eq!(fs::read_to_string(out.join("run.json")).unwrap(), "old");
    }

    #[test]
    fn foreign_folders_files_and_unwritable_parents_are_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let foreign = tmp.path().join("photos");
        fs::create_dir(&foreign).unwrap();
        fs::write(foreign.join("cat.jpg"), "x").unwrap();
        let e = OutputFolder::begin(&foreign, MARKERS)
            .unwrap_err()
            .to_string();
        assert!(e.contains("photos") && e.contains("run.json"), "{e}");
        assert!(foreign.join("cat.jpg").exists());
        let file = tmp.path().join("f.txt");
        fs::write(&file, "x").unwrap();
        let e = check_output_folder(&file, MARKERS).unwrap_err().to_string();
        assert!(e.contains("f.txt") && e.contains("not a folder"), "{e}");
        // An empty folder and a missing one are fine; the parent is created.
        fs::create_dir(tmp.path().join("empty")).unwrap();
        check_output_folder(&tmp.path().join("empty"), MARKERS).unwrap();
        check_output_folder(&tmp.path().join("a/b/c"), MARKERS).unwrap();
        assert!(tmp.path().join("a/b").is_dir());
        // A parent that is a file cannot be written into.
        let e = check_output_folder(&file.join("out"), MARKERS)
            .unwrap_err()
            .to_string();
        assert!(e.contains("f.txt"), "{e}");
        let e = check_writable_dir(&file).unwrap_err().to_string();
        assert!(e.contains("f.txt"), "{e}");
    }
}
