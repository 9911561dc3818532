//! `dynapix._dynapix`: the PyO3 extension module of the `dynapix` Python package, a thin
//! binding of the `dynapix` crate's API (configuration, cameras, sequences, the offline
//! runner, the online mode, evaluation, synthetic data). The Pythonic layer (progress bars,
//! `evo` conversion) is `python/dynapix/__init__.py`.
//!
//! Rules of the boundary: every library error becomes a Python exception of the
//! `errors` hierarchy carrying the library's message; a panic inside the library is caught
//! and raised as `DynapixError` too; long computations release the GIL (`Python::detach`);
//! arrays are checked for dtype, shape and size with messages that name them.

mod arrays;
mod camera;
mod config;
mod errors;
mod evaluation;
mod offline;
mod online;
mod synth;

use pyo3::prelude::*;

/// The extension module.
#[pymodule]
fn _dynapix(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("DynapixError", py.get_type::<errors::DynapixError>())?;
    m.add("ConfigError", py.get_type::<errors::ConfigError>())?;
    m.add("DataError", py.get_type::<errors::DataError>())?;
    m.add("IoError", py.get_type::<errors::IoError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<config::Config>()?;
    m.add_class::<camera::Camera>()?;
    m.add_class::<offline::Sequence>()?;
    m.add_class::<offline::RunResult>()?;
    m.add_function(wrap_pyfunction!(offline::run, m)?)?;
    m.add_function(wrap_pyfunction!(offline::read_probability, m)?)?;
    m.add_class::<online::Online>()?;
    m.add_class::<online::FrameResult>()?;
    m.add_function(wrap_pyfunction!(evaluation::evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(evaluation::read_trajectory, m)?)?;
    m.add_function(wrap_pyfunction!(evaluation::read_ground_truth, m)?)?;
    m.add_function(wrap_pyfunction!(evaluation::save_trajectory, m)?)?;
    m.add_class::<synth::SyntheticSequence>()?;
    m.add_class::<synth::SyntheticFrame>()?;
    m.add_function(wrap_pyfunction!(synth::augment, m)?)?;
    m.add_function(wrap_pyfunction!(synth::synth_presets, m)?)?;
    Ok(())
}
