//! The typed error of all readers and writers: always names the file, and the line when the
//! problem is inside a text file.

use std::path::PathBuf;

/// Result alias of this crate.
pub type Result<T> = std::result::Result<T, IoError>;

/// An error reading or writing a dynapix file.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The operating system failed to open, read or write the file.
    #[error("{path}: {source}")]
    Io {
        /// File concerned.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// A text file has bad content on a given line (1-based).
    #[error("{path}:{line}: {message}")]
    Parse {
        /// File concerned.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong (expected vs got).
        message: String,
    },
    /// A file has bad content that is not tied to one line (image format, size, …).
    #[error("{path}: {message}")]
    Invalid {
        /// File concerned.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

impl IoError {
    /// Wraps an OS error for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }

    /// A parse error at `path:line`.
    pub fn parse(path: impl Into<PathBuf>, line: usize, message: impl Into<String>) -> Self {
        Self::Parse {
            path: path.into(),
            line,
            message: message.into(),
        }
    }

    /// The file concerned.
    pub fn path(&self) -> &std::path::Path {
        match self {
            Self::Io { path, .. } | Self::Parse { path, .. } | Self::Invalid { path, .. } => path,
        }
    }

    /// What is wrong, without the file name (with the line for a parse error).
    pub fn reason(&self) -> String {
        match self {
            Self::Io { source, .. } => source.to_string(),
            Self::Parse { line, message, .. } => format!("line {line}: {message}"),
            Self::Invalid { message, .. } => message.clone(),
        }
    }

    /// A whole-file content error.
    pub fn invalid(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Invalid {
            path: path.into(),
            message: message.into(),
        }
    }
}
