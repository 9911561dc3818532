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
//! Two processes never share a target: [`OutputFolder::begin`] takes an advisory lock on
//! `OUT.lock` beside the target (an OS file lock, released by the kernel when the process
//! ends, even by SIGKILL) and holds it for the whole run, swap included. A second run on the
//! same target is refused with an error naming the process that holds it. Leftover staging
//! and old folders are removed only under that lock and only when the process named in
//! their suffix is gone, so a live run's staging folder is never touched.
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
/// Suffix of the lock file beside the target: `OUT.lock`.
const LOCK: &str = ".lock";

/// The exclusive right to replace one output folder, held from [`OutputLock::acquire`] until
/// dropped: an advisory OS lock on the file `OUT.lock` beside the target, which holds the
/// owner's process id. Dropping it removes the file, then releases the lock.
#[derive(Debug)]
pub struct OutputLock {
    path: PathBuf,
    file: fs::File,
}

impl OutputLock {
    /// Takes the lock of the output folder `out`, or fails at once with an error naming the
    /// process that holds it (`another dynapix run (pid N) is writing …`).
    pub fn acquire(out: &Path) -> Result<Self> {
        let (parent, name) = split(out)?;
        let mut lock_name = name;
        lock_name.push(LOCK);
        let path = parent.join(lock_name);
        // A holder that is finishing removes the file and then unlocks: a lock won on a file
        // that is no longer (or no longer the same) `OUT.lock` is retried on the new one.
        for _ in 0..16 {
            let file = fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .map_err(|e| IoError::io(&path, e))?;
            match file.try_lock() {
                Ok(()) => {}
                Err(fs::TryLockError::WouldBlock) => {
                    let holder = fs::read_to_string(&path).unwrap_or_default();
                    let holder = holder.trim();
                    let who = if holder.is_empty() {
                        "another dynapix run".to_string()
                    } else {
                        format!("another dynapix run (pid {holder})")
                    };
                    return Err(IoError::invalid(
                        out,
                        format!(
                            "{who} is writing this output folder (lock {}); wait for it to \
                             finish or give another --out",
                            path.display()
                        ),
                    ));
                }
                Err(fs::TryLockError::Error(e)) => return Err(IoError::io(&path, e)),
            }
            if same_file(&file, &path) {
                let mut lock = Self { path, file };
                lock.record_pid()?;
                return Ok(lock);
            }
        }
        Err(IoError::invalid(
            &path,
            "cannot take the output folder's lock: the lock file keeps being replaced",
        ))
    }

    /// The lock file (`OUT.lock`).
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn record_pid(&mut self) -> Result<()> {
        use std::io::{Seek, Write};
        let pid = std::process::id().to_string();
        self.file
            .set_len(0)
            .and_then(|()| self.file.seek(std::io::SeekFrom::Start(0)))
            .and_then(|_| self.file.write_all(pid.as_bytes()))
            .map_err(|e| IoError::io(&self.path, e))
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Removed while still locked, so no other process can win a lock on a file that is
        // about to disappear without noticing (see `acquire`).
        let _ = fs::remove_file(&self.path);
        let _ = self.file.unlock();
    }
}

/// True when the open `file` is the file at `path` (same device and inode).
#[cfg(unix)]
fn same_file(file: &fs::File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

/// True when the open `file` is the file at `path` (elsewhere: the path still exists).
#[cfg(not(unix))]
fn same_file(_file: &fs::File, path: &Path) -> bool {
    path.exists()
}

/// True when process `pid` is running (or may be: when it cannot be told, it is assumed
/// alive, so its folders are kept).
#[cfg(target_os = "linux")]
fn process_alive(pid: u32) -> bool {
    pid == std::process::id()
        || Path::new("/proc").join(pid.to_string()).exists()
        || !Path::new("/proc/self").exists()
}

/// True when process `pid` is running (or may be: when it cannot be told, it is assumed
/// alive, so its folders are kept).
#[cfg(not(target_os = "linux"))]
fn process_alive(_pid: u32) -> bool {
    true
}

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
    /// Held until the value is gone (after the swap, or after the staging folder's removal).
    _lock: OutputLock,
}

impl OutputFolder {
    /// Checks, before any work, that `out` can be (re)made as a whole
    /// ([`check_output_folder`]).
    pub fn check(out: &Path, markers: &[&str]) -> Result<()> {
        check_output_folder(out, markers)
    }

    /// Checks that files can be created in `dir` ([`check_writable_dir`]).
    pub fn check_writable(dir: &Path) -> Result<()> {
        check_writable_dir(dir)
    }

    /// Takes the folder's lock ([`OutputLock::acquire`]: refused when another process holds
    /// it), checks `out` ([`check_output_folder`] with `markers`), removes staging and replaced
    /// folders of earlier interrupted runs on it whose process is gone, and creates an empty
    /// staging folder beside it. The lock is held until the commit is done or the value is
    /// dropped.
    pub fn begin(out: &Path, markers: &[&str]) -> Result<Self> {
        Self::check(out, markers)?;
        let lock = OutputLock::acquire(out)?;
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
            let owner = [STAGING, OLD].iter().find_map(|s| {
                file.strip_prefix(&name)
                    .and_then(|rest| rest.strip_prefix(s))
                    .filter(|pid| !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()))
                    .map(|pid| pid.parse::<u32>().unwrap_or(u32::MAX))
            });
            // Our own pid's leftovers come from an earlier process that had our pid.
            if owner.is_some_and(|pid| pid == std::process::id() || !process_alive(pid)) {
                remove_dir_or_file(&e.path())?;
            }
        }
        let staging = parent.join(format!("{name}{STAGING}{}", std::process::id()));
        fs::create_dir(&staging).map_err(|e| IoError::io(&staging, e))?;
        Ok(Self {
            target: out.to_path_buf(),
            staging,
            committed: false,
            _lock: lock,
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
        // Pids above any system's pid_max: their processes are gone.
        for leftover in ["out.tmp-999999999", "out.old-999999998"] {
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

    #[test]
    fn a_second_writer_is_refused_while_the_first_runs_and_finishes_complete() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        let first = OutputFolder::begin(&out, MARKERS).unwrap();
        fs::write(first.path().join("run.json"), "first").unwrap();
        fs::create_dir(first.path().join("passes")).unwrap();
        fs::write(first.path().join("trajectory.txt"), "poses").unwrap();
        // Another open of the lock file conflicts like another process would (flock).
        let e = OutputFolder::begin(&out, MARKERS).unwrap_err().to_string();
        let pid = std::process::id().to_string();
        assert!(
            e.contains(&format!("pid {pid}")) && e.contains("out.lock") && e.contains("--out"),
            "{e}"
        );
        let e = OutputLock::acquire(&out).unwrap_err().to_string();
        assert!(e.contains(&pid), "{e}");
        // The refusal touched nothing of the live run.
        assert_eq!(
            fs::read_to_string(first.path().join("run.json")).unwrap(),
            "first"
        );
        assert_eq!(
            fs::read_to_string(tmp.path().join("out.lock")).unwrap(),
            pid
        );
        first.commit().unwrap();
        assert_eq!(names(&out), ["passes", "run.json", "trajectory.txt"]);
        assert_eq!(
            names(tmp.path()),
            ["out"],
            "the lock file goes with the lock"
        );
        // Released: the next run may begin; a dropped (failed) one releases too.
        let again = OutputFolder::begin(&out, MARKERS).unwrap();
        drop(again);
        let lock = OutputLock::acquire(&out).unwrap();
        assert_eq!(lock.path(), tmp.path().join("out.lock"));
        drop(lock);
        assert_eq!(names(tmp.path()), ["out"]);
    }

    #[test]
    fn a_stale_lock_file_does_not_block_and_live_leftovers_are_kept() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        // A lock file left by a killed run holds a pid but no lock: the kernel dropped it.
        fs::write(tmp.path().join("out.lock"), "999999999").unwrap();
        // A staging folder whose process (pid 1, always running) is alive is not ours to remove.
        fs::create_dir(tmp.path().join("out.tmp-1")).unwrap();
        fs::write(tmp.path().join("out.tmp-1/run.json"), "live").unwrap();
        let f = OutputFolder::begin(&out, MARKERS).unwrap();
        assert_eq!(
            fs::read_to_string(tmp.path().join("out.lock")).unwrap(),
            std::process::id().to_string()
        );
        fs::write(f.path().join("run.json"), "new").unwrap();
        f.commit().unwrap();
        if Path::new("/proc/1").exists() {
            assert_eq!(
                fs::read_to_string(tmp.path().join("out.tmp-1/run.json")).unwrap(),
                "live"
            );
        }
        assert_eq!(fs::read_to_string(out.join("run.json")).unwrap(), "new");
    }
}
