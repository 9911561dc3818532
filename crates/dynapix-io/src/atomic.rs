//! Atomic file writing: the content goes to a temporary file in the destination folder, which
//! is then renamed over the destination. A reader (or a crashed run) therefore sees either the
//! old file or the complete new one, never a half-written file (design.md §3).
//!
//! The temporary file is not `fsync`ed: the guarantee is against process failure (panic, kill,
//! error half-way), not against power loss, which keeps writing thousands of per-frame maps cheap.

use std::fs;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::{IoError, Result};

/// Distinguishes temporary files of concurrent writers in the same process.
static COUNTER: AtomicU64 = AtomicU64::new(0);

/// Temporary path beside `path`: `<name>.<pid>.<n>.tmp` in the same folder, so the final
/// rename never crosses a file system.
fn temp_path(path: &Path) -> Result<PathBuf> {
    let name = path
        .file_name()
        .ok_or_else(|| IoError::invalid(path, "cannot write: the path has no file name"))?;
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let mut tmp_name = name.to_os_string();
    tmp_name.push(format!(".{}.{n}.tmp", std::process::id()));
    Ok(path.with_file_name(tmp_name))
}

/// Writes `bytes` to `path` atomically (temporary file in the same folder, then rename).
/// The parent folder must exist. Errors name `path` (or the temporary file).
pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Like [`write_atomic`], but the content is produced by `fill`, which writes into a buffered
/// writer on the temporary file (useful for encoders that stream). If `fill` fails, the
/// temporary file is removed and the destination is left untouched.
pub fn write_atomic_with<F>(path: impl AsRef<Path>, fill: F) -> Result<()>
where
    F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
{
    let path = path.as_ref();
    let tmp = temp_path(path)?;
    let file = fs::File::create(&tmp).map_err(|e| IoError::io(&tmp, e))?;
    let mut writer = BufWriter::new(file);
    let written = fill(&mut writer).and_then(|()| writer.flush());
    drop(writer);
    if let Err(e) = written {
        let _ = fs::remove_file(&tmp);
        return Err(IoError::io(path, e));
    }
    if let Err(e) = fs::rename(&tmp, path) {
        let _ = fs::remove_file(&tmp);
        return Err(IoError::io(path, e));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_and_replaces_without_leaving_temporaries() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        write_atomic(&p, b"first").unwrap();
        write_atomic(&p, b"second").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"second");
        let entries: Vec<_> = fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(entries.len(), 1, "temporary file left behind");
    }

    #[test]
    fn failed_fill_keeps_old_content() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        write_atomic(&p, b"old").unwrap();
        let err = write_atomic_with(&p, |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("encoder failed"))
        })
        .unwrap_err();
        assert!(err.to_string().contains("a.txt"), "{err}");
        assert_eq!(fs::read(&p).unwrap(), b"old");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn missing_folder_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("no_such_dir").join("x.txt");
        let err = write_atomic(&p, b"x").unwrap_err();
        assert!(err.to_string().contains("x.txt"), "{err}");
    }
}
