//! Subcommands, one module each, and what they share.
pub mod bench;
pub mod common;
pub mod demo;
pub mod eval;
pub mod experiment;
pub mod flow;
pub mod motion;
pub mod run;
pub mod slam;
pub mod synth;
pub mod viz;
pub mod vocab;
