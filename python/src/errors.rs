//! The exception hierarchy and the conversion of library errors and panics into it.

use std::panic::{AssertUnwindSafe, catch_unwind};

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

create_exception!(
    dynapix,
    DynapixError,
    PyException,
    "Base class of every error raised by dynapix (the message is the library's)."
);
create_exception!(
    dynapix,
    ConfigError,
    DynapixError,
    "A configuration value, key, preset or parameter is not valid (the message names it)."
);
create_exception!(
    dynapix,
    DataError,
    DynapixError,
    "Input data that cannot be used: arrays of the wrong dtype, shape or size, frames out of \
     order, inputs that do not fit together, too few poses to evaluate."
);
create_exception!(
    dynapix,
    IoError,
    DynapixError,
    "Reading or writing a file failed (the message names the file)."
);

/// The Python exception of a library error.
pub fn to_py(e: dynapix::Error) -> PyErr {
    let message = e.to_string();
    match kind(&e) {
        Kind::Config => ConfigError::new_err(message),
        Kind::Io => IoError::new_err(message),
        Kind::Data => DataError::new_err(message),
    }
}

/// The exception class of an error.
enum Kind {
    Config,
    Io,
    Data,
}

fn kind(e: &dynapix::Error) -> Kind {
    use dynapix::Error as E;
    match e {
        E::Config { .. } | E::Orb(_) => Kind::Config,
        E::Io(_) | E::File { .. } | E::Vocabulary { .. } => Kind::Io,
        E::Stopped { error, .. } => kind(error),
        _ => Kind::Data,
    }
}

/// A `DataError` with `message`.
pub fn data(message: impl Into<String>) -> PyErr {
    DataError::new_err(message.into())
}

/// A `ConfigError` with `message`.
pub fn config(message: impl Into<String>) -> PyErr {
    ConfigError::new_err(message.into())
}

/// Runs `f` with the GIL released; a library error becomes its exception and a panic a
/// `DynapixError` (nothing unwinds into Python).
pub fn compute<T: Send>(
    py: Python<'_>,
    f: impl FnOnce() -> dynapix::Result<T> + Send,
) -> PyResult<T> {
    let r = py.detach(|| catch_unwind(AssertUnwindSafe(f)));
    match r {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(to_py(e)),
        Err(panic) => Err(panicked(panic)),
    }
}

/// Like [`compute`] while holding the GIL (short work).
pub fn guard<T>(f: impl FnOnce() -> dynapix::Result<T>) -> PyResult<T> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(to_py(e)),
        Err(panic) => Err(panicked(panic)),
    }
}

/// The `DynapixError` of a caught panic.
fn panicked(panic: Box<dyn std::any::Any + Send>) -> PyErr {
    let what = panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into());
    DynapixError::new_err(format!("internal error in dynapix (please report): {what}"))
}
