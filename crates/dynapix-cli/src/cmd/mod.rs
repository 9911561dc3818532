//! Subcommands, one module each.
pub mod eval;
pub mod flow;
pub mod motion;
pub mod slam;
pub mod synth;
pub mod vocab;
