//! Error type of the evaluation crate.

use std::path::PathBuf;

/// Everything that can go wrong while evaluating trajectories.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Association produced too few pairs to align and measure.
    #[error(
        "only {pairs} timestamp pairs matched within {max_diff} s (need at least {needed}); \
         check that ground truth and estimate use the same clock (TUM: Unix time) and the offset"
    )]
    TooFewPairs {
        /// Pairs found.
        pairs: usize,
        /// Pairs needed.
        needed: usize,
        /// Association tolerance used, seconds.
        max_diff: f64,
    },
    /// A trajectory file holds no pose at all.
    #[error("{path}: holds no poses (the file is empty or has only comments); nothing to evaluate")]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// A trajectory has fewer poses than an ATE needs (a sequence of one or two frames).
    #[error(
        "the {which} trajectory holds {got} pose(s); an ATE needs at least {needed} (a \
         sequence of {got} frame(s) is too short to be scored)"
    )]
    TooFewPoses {
        /// `estimated` or `ground-truth`.
        which: &'static str,
        /// Poses it holds.
        got: usize,
        /// Poses needed.
        needed: usize,
    },
    /// The alignment failed (degenerate geometry).
    #[error("alignment failed: {0}")]
    Align(#[from] dynapix_geometry::align::AlignError),
    /// Too few reference frames inside the evaluation window for a tracking rate.
    #[error("tracking rate needs at least 2 reference frames inside the window, got {got}")]
    TooFewReferenceFrames {
        /// Frames inside the window.
        got: usize,
    },
    /// A parameter is outside its valid range.
    #[error("invalid parameter {name}: {reason}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// No RPE pairs could be formed for the given delta.
    #[error("no relative-pose pairs for the requested delta ({0})")]
    NoRpePairs(String),
    /// An input pose or a result is not a finite number (e.g. a translation of 1e200 whose
    /// square overflows): no figure is reported rather than NaN.
    #[error("not finite: {0}")]
    NonFinite(String),
    /// Reading a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A trajectory or list file could not be parsed.
    #[error("{path}:{line}: {reason}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// Reading or writing a file through `dynapix-io` failed (the message names the file and
    /// line). Its message already contains the cause, so it is not chained again as a
    /// `source` (that would print the OS error twice).
    #[error("{0}")]
    File(dynapix_io::IoError),
    /// Plot rendering failed.
    #[error("plot {path}: {reason}")]
    Plot {
        /// Output file.
        path: PathBuf,
        /// Backend message.
        reason: String,
    },
    /// A runs folder has an unexpected layout.
    #[error("{path}: {reason}")]
    Layout {
        /// The folder.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

impl From<dynapix_io::IoError> for EvalError {
    fn from(e: dynapix_io::IoError) -> Self {
        Self::File(e)
    }
}

/// Result alias of the crate.
pub type Result<T> = std::result::Result<T, EvalError>;
