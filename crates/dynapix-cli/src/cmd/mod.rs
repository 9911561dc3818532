//! Subcommands, one module each.
pub mod eval;
pub mod flow;
pub mod motion;
pub mod slam;
pub mod synth;
pub mod vocab;
pub mod run;
pub mod experiment;
pub mod demo;
