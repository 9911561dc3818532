//! Trajectory evaluation for dynapix (spec §4): timestamp association like the TUM tools,
//! ATE after Horn (or Umeyama-with-scale) alignment, RPE with a time or frame delta, the
//! tracking rate TR with the reference missing-interval rule, ATR = mean ATE / mean TR, the
//! motionless floor (the ATE of a camera that never moves, on the same pairs),
//! multi-run / multi-sequence tables (Markdown, CSV, JSON) and plots (SVG, PNG).
//!
//! The algorithms ([`associate`](mod@associate), [`ate`](mod@ate), [`rpe`](mod@rpe), [`tracking`], [`aggregate`], [`report`], [`run`](mod@run))
//! work on in-memory slices `&[(timestamp, camera-to-world pose)]`; [`files`] and [`plot`]
//! are the thin file layer.

#![forbid(unsafe_code)]

pub mod aggregate;
pub mod associate;
pub mod ate;
pub mod error;
pub mod files;
pub mod plot;
pub mod report;
pub mod rpe;
pub mod run;
pub mod stats;
pub mod tracking;

pub use aggregate::{
    MethodSummary, PaperTable, RunResult, SequenceSummary, paper_table, summarize_with_floors,
};
pub use associate::{AssocParams, associate};
pub use ate::{AteParams, AteResult, ate, motionless_floor};
pub use error::{EvalError, Result};
pub use report::{EvalParams, Evaluation, Report, evaluate};
pub use rpe::{RpeDelta, RpeParams, RpeResult, rpe};
pub use run::{RunEvaluation, RunScore, evaluate_run_poses, score_run};
pub use stats::ErrorStats;
pub use tracking::{TrackingParams, TrackingResult, tracking_rate};
