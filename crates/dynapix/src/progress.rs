//! Progress of long runs, reported through a callback (a command-line tool turns it into
//! progress bars; a library user may log it or ignore it). Callbacks may come from several
//! threads (motion maps are computed in parallel), hence `Sync`.

/// One progress event of a task (a SLAM pass, the motion maps of a pass, …).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProgressEvent<'a> {
    /// A task starts with `total` units (frames).
    Begin {
        /// Task label, e.g. `first pass (orbslam2)`.
        task: &'a str,
        /// Units of work.
        total: u64,
    },
    /// One unit of a task is done.
    Step {
        /// Task label.
        task: &'a str,
        /// A short status (tracking state, map size), may be empty.
        message: &'a str,
    },
    /// The task is finished.
    End {
        /// Task label.
        task: &'a str,
    },
}

/// Receives progress events.
pub trait Progress: Sync {
    /// Handles one event.
    fn event(&self, event: ProgressEvent<'_>);
}

/// `()` ignores every event: pass `&()` for no progress reports.
impl Progress for () {
    fn event(&self, _: ProgressEvent<'_>) {}
}

impl<F: Fn(ProgressEvent<'_>) + Sync> Progress for F {
    fn event(&self, event: ProgressEvent<'_>) {
        self(event)
    }
}

/// Begin/step/end helper for one task.
pub(crate) struct Task<'a> {
    progress: &'a dyn Progress,
    label: &'a str,
}

impl<'a> Task<'a> {
    /// Reports the start of `label` with `total` units.
    pub(crate) fn begin(progress: &'a dyn Progress, label: &'a str, total: usize) -> Self {
        progress.event(ProgressEvent::Begin {
            task: label,
            total: total as u64,
        });
        Self { progress, label }
    }

    /// One unit done.
    pub(crate) fn step(&self, message: &str) {
        self.progress.event(ProgressEvent::Step {
            task: self.label,
            message,
        });
    }
}

impl Drop for Task<'_> {
    fn drop(&mut self) {
        self.progress.event(ProgressEvent::End { task: self.label });
    }
}
