//! Errors of the library, with the context a user needs (file, frame, key).

use std::path::PathBuf;

pub use crate::pass::BadFrame;

/// Everything that can go wrong in a DynaPix run.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing a file of a sequence, a trajectory or a map.
    #[error(transparent)]
    Io(#[from] dynapix_io::IoError),
    /// A configuration file or value is not valid.
    #[error("configuration{}: {message}", path.as_ref().map(|p| format!(" {}", p.display())).unwrap_or_default())]
    Config {
        /// The file, when the value came from one.
        path: Option<PathBuf>,
        /// What is wrong.
        message: String,
    },
    /// The inputs do not fit together (camera, poses, frames, maps).
    #[error("{0}")]
    Input(String),
    /// The motion maps of a sequence.
    #[error("motion maps: {0}")]
    Motion(#[from] dynapix_motion::SequenceError),
    /// The motion map of one frame (online mode).
    #[error("motion map: {0}")]
    MotionFrame(#[from] dynapix_motion::MotionError),
    /// The SLAM system refused a frame.
    #[error(transparent)]
    Process(#[from] dynapix_slam::system::ProcessError),
    /// The ORB extractor settings.
    #[error("ORB settings: {0}")]
    Orb(#[from] dynapix_slam::orb::OrbError),
    /// A vocabulary file.
    #[error("vocabulary {}: {source}", path.display())]
    Vocabulary {
        /// The file (or `<embedded>`).
        path: PathBuf,
        /// What went wrong.
        source: dynapix_slam::vocab::VocabError,
    },
    /// Reading a saved SLAM map.
    #[error(transparent)]
    Persist(#[from] dynapix_slam::persist::PersistError),
    /// A saved SLAM map that cannot be decoded, used or written.
    #[error("{context}: {source}")]
    Map {
        /// What was being done, naming the file.
        context: String,
        /// What went wrong.
        source: dynapix_slam::persist::PersistError,
    },
    /// A frame whose files cannot be used (see [`BadFrame`]).
    #[error("{0}")]
    Frame(BadFrame),
    /// A SLAM pass stopped part-way; what it had computed is kept.
    #[error("{label}: {error}")]
    Stopped {
        /// The pass (its progress label, e.g. `first pass (rigidity)`).
        label: String,
        /// Why it stopped.
        error: Box<Error>,
        /// The pass up to the frame before the one that stopped it.
        partial: Box<crate::pass::PassOutput>,
    },
    /// The first pass of a DynaPix run tracked no frame, so there are no poses for the
    /// motion maps; it carries that pass ([`crate::OfflineRunner::run`] ends the run with it
    /// instead of failing).
    #[error(
        "the first pass tracked no frame: no poses for the motion maps (all-zero depth, black \
         or featureless frames, or a camera that does not match the images?)"
    )]
    NothingTracked(Box<crate::pass::FirstPassResult>),
    /// A file that is not one of the formats above (`motion.json`, run records).
    #[error("{}: {message}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

impl Error {
    /// The frame that caused this error, when it is a [`BadFrame`] (also inside a stopped
    /// pass or the motion maps).
    pub fn bad_frame(&self) -> Option<&BadFrame> {
        match self {
            Error::Frame(b) => Some(b),
            Error::Stopped { error, .. } => error.bad_frame(),
            Error::Motion(dynapix_motion::SequenceError::Load { source, .. }) => {
                source.downcast_ref::<Error>().and_then(Error::bad_frame)
            }
            _ => None,
        }
    }

    /// What a SLAM pass had computed when it stopped (see [`Error::Stopped`]).
    pub fn partial_pass(&self) -> Option<&crate::pass::PassOutput> {
        match self {
            Error::Stopped { partial, .. } => Some(partial),
            _ => None,
        }
    }

    /// A configuration error without a file.
    pub(crate) fn config(message: impl Into<String>) -> Self {
        Error::Config {
            path: None,
            message: message.into(),
        }
    }

    /// An error about a file.
    pub(crate) fn file(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::File {
            path: path.into(),
            message: message.into(),
        }
    }
}

/// Result with the library's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
